//! The kernels' checks (host `#[test]`s and `cargo fw-test` on the emulated
//! M4, listed in [`crate::selftest`]): the kernels in use and the portable
//! ones equal plain per-pixel loops.

use super::{bilinear, pinhole, portable, Strongest, FRAC_BITS};
use crate::grid::MAX_GRID_SIDE;
use crate::selftest::{xorshift32, Outcome};

/// Deterministic bytes around 128, within `spread` of it (any byte from 256 up).
fn fill(buffer: &mut [u8], mut state: u32, spread: u32) {
    for byte in buffer.iter_mut() {
        let random = xorshift32(&mut state);
        *byte = if spread >= 256 { random as u8 } else { 128u32.wrapping_add(random % (2 * spread + 1)).wrapping_sub(spread) as u8 };
    }
}

/// Whether [`super::add_to_columns`] (the backend's and the portable one),
/// adding hot flags (`a`'s low bits) and ground residues (`b`) at
/// `columns` three times over, leaves totals other than the plain sums,
/// taken over the grid's width in pieces 1, 2, 5 and 15 columns wide.
fn column_totals_differ(a: &[u8], b: &[u8], columns: core::ops::Range<usize>) -> bool {
    let hot: [u8; MAX_GRID_SIDE] = core::array::from_fn(|c| a.get(c).map_or(0, |&v| v & 1));
    let ground = &b[..MAX_GRID_SIDE];
    let mut differs = false;
    for px in [1, 2, 5, 15] {
        let mut totals = [super::ColumnTotals::EMPTY, super::ColumnTotals::EMPTY];
        for _ in 0..3 {
            let expected: u32 = hot[columns.clone()].iter().map(|&h| u32::from(h)).sum();
            let counted = [super::add_to_columns(&hot, ground, columns.clone(), &mut totals[0]), portable::add_to_columns(&hot, ground, columns.clone(), &mut totals[1])];
            differs |= counted != [expected; 2];
        }
        for totals in &mut totals {
            let mut pieces = [super::PieceSums::ZERO; MAX_GRID_SIDE];
            let count = totals.take_pieces(px, MAX_GRID_SIDE, &mut pieces);
            differs |= count != MAX_GRID_SIDE.div_ceil(px);
            for (k, piece) in pieces[..count].iter().enumerate() {
                let columns_of_piece = k * px..((k + 1) * px).min(MAX_GRID_SIDE);
                let within = columns_of_piece.start.max(columns.start)..columns_of_piece.end.min(columns.end).max(columns_of_piece.start.max(columns.start));
                let plain = |bytes: &[u8]| 3 * bytes[within.clone()].iter().map(|&v| u32::from(v)).sum::<u32>();
                differs |= (piece.hot(), piece.pixels(), piece.ground()) != (plain(&hot), 3 * within.len() as u32, plain(ground));
            }
            // Taken: all 0 again.
            totals.take_pieces(px, MAX_GRID_SIDE, &mut pieces);
            differs |= pieces.iter().any(|&piece| piece != super::PieceSums::ZERO);
        }
    }
    differs
}

/// Every length 0..=300, unaligned starts, random and edge values
/// (0, 255, the seed levels and their neighbours), every window width.
pub fn dsp_kernels_equal_portable() -> Outcome {
    let mut a = [0u8; 307];
    let mut b = [0u8; 314];
    for (round, spread) in [(1u32, 256u32), (2, 60), (3, 30), (4, 3)].into_iter() {
        fill(&mut a, 0x9E37_79B9 ^ round, spread);
        fill(&mut b, 0x85EB_CA6B ^ (round * 7), spread);
        if round == 1 {
            // Exact edges: |diff| of 30, 31, 50, 51, 255.
            let edges = [(0u8, 30u8), (31, 0), (100, 50), (49, 100), (0, 255), (255, 0), (200, 149), (7, 7)];
            for (n, (x, y)) in edges.iter().enumerate() {
                a[n] = *x;
                b[n] = *y;
            }
        }
        for start in 0..4 {
            for length in 0..=300 {
                let (x, y) = (&a[start..start + length], &b[3 - start..3 - start + length]);
                let plain_sad = |y: &[u8]| x.iter().zip(y).map(|(&p, &q)| u32::from(p.abs_diff(q))).sum::<u32>();
                if super::sad(x, y) != plain_sad(y) || portable::sad(x, y) != plain_sad(y) {
                    return Err("sad differs from the per-pixel loop");
                }
                if length <= 250 && column_totals_differ(&a, &b, start..start + length) {
                    return Err("add_to_columns differs from the per-pixel loop");
                }
                let mut expected = [0u32; 256];
                for (&p, &q) in x.iter().zip(y) {
                    expected[usize::from(p.abs_diff(q))] += 1;
                }
                let mut histogram = super::DiffHistogram::EMPTY;
                histogram.add(x, y);
                let mut portable_histogram = [[0u32; 256]; portable::HISTOGRAM_LANES];
                portable::diff_histogram(x, y, &mut portable_histogram);
                if histogram.counts() != expected || portable_histogram != [expected] {
                    return Err("diff_histogram differs from the per-pixel loop");
                }
                for shifts in 1..=7 {
                    let reference = &b[3 - start..3 - start + length + shifts - 1];
                    let mut sums = [7u32; 7];
                    super::sad_shifts(x, reference, &mut sums[..shifts]);
                    for (k, &sum) in sums[..shifts].iter().enumerate() {
                        if sum != 7 + plain_sad(&reference[k..]) {
                            return Err("sad_shifts differs from the per-pixel loop");
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// Bytes of the long rows below, longer than two of NEON's u16 sums
/// (each 128 blocks of 16 bytes) with every tail. Statics, in flash on
/// the M4, which runs these checks too.
const LONG: usize = 4200;
static ZEROS: [u8; LONG] = [0; LONG];
static FULL: [u8; LONG] = [255; LONG];
static NOISE: [[u8; LONG]; 2] = [noise(0x2545_F491), noise(0x6C07_8965)];

/// [`xorshift32`]'s bytes from `state` (not 0), at compile time.
const fn noise(mut state: u32) -> [u8; LONG] {
    let mut bytes = [0; LONG];
    let mut n = 0;
    while n < LONG {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        bytes[n] = state as u8;
        n += 1;
    }
    bytes
}

/// `sad` and `sad_shifts` (3, 5 and 7 shifts, those the SIMD backends
/// do at once) of rows thousands of bytes long equal the per-pixel sums:
/// |diff| of 255 everywhere (the most a lane can add) and random bytes,
/// lengths across 2,048 and 4,096 bytes (where the NEON kernels carry
/// their u16 lanes over to u32) with every kind of tail.
pub fn sad_of_long_rows_equals_plain() -> Outcome {
    for (a, b) in [(&ZEROS, &FULL), (&FULL, &ZEROS), (&NOISE[0], &NOISE[1])] {
        for length in [2047, 2048, 2049, 2063, 2064, 2072, 2079, 4095, 4096, 4111, 4127, LONG - 6] {
            let x = &a[..length];
            let plain = |y: &[u8]| x.iter().zip(y).map(|(&p, &q)| u32::from(p.abs_diff(q))).sum::<u32>();
            if super::sad(x, &b[..length]) != plain(b) || portable::sad(x, &b[..length]) != plain(b) {
                return Err("sad of a long row differs from the per-pixel loop");
            }
            for shifts in [3, 5, 7] {
                let reference = &b[..length + shifts - 1];
                let mut sums = [7u32; 7];
                super::sad_shifts(x, reference, &mut sums[..shifts]);
                for (k, &sum) in sums[..shifts].iter().enumerate() {
                    if sum != 7 + plain(&reference[k..]) {
                        return Err("sad_shifts of a long row differs from the per-pixel loop");
                    }
                }
            }
        }
    }
    Ok(())
}

/// The seed's statistics from a histogram equal a per-pixel loop.
pub fn seed_statistics_equal_plain() -> Outcome {
    let mut a = [0u8; 1000];
    let mut b = [0u8; 1000];
    fill(&mut a, 0x1234_5678, 256);
    fill(&mut b, 0x0BAD_F00D, 256);
    let mut histogram = super::DiffHistogram::EMPTY;
    histogram.add(&a, &b);
    let (mut sum_above, mut count_above) = (0u32, 0u32);
    for (&x, &y) in a.iter().zip(&b) {
        let d = x.abs_diff(y);
        if d > super::SUM_LEVEL {
            sum_above += u32::from(d);
        }
        if d > super::COUNT_LEVEL {
            count_above += 1;
        }
    }
    if super::seed_statistics(&histogram.counts()) != (sum_above, count_above) {
        return Err("seed_statistics differs from the per-pixel loop");
    }
    // Without the histogram: every length and start up to a few words.
    for start in 0..4 {
        for length in (0..=40).chain([997 - start]) {
            let (x, y) = (&a[start..start + length], &b[start..start + length]);
            let plain = x.iter().zip(y).map(|(&x, &y)| x.abs_diff(y)).fold((0u32, 0u32), |(sum, count), d| {
                (sum + if d > super::SUM_LEVEL { u32::from(d) } else { 0 }, count + u32::from(d > super::COUNT_LEVEL))
            });
            if super::seed_sums(x, y) != plain || portable::seed_sums(x, y) != plain {
                return Err("seed_sums differs from the per-pixel loop");
            }
        }
    }
    Ok(())
}

/// The bilinear kernel in use and the portable one equal a per-pixel loop:
/// every length 0..=300, unaligned starts of `upper`, `lower` and `out`
/// (independently), edge weights (0, 1, 128, 255) and random ones, random
/// pixels, pixels near the middle, and all-0 / all-255 / alternating 0-255
/// lines (the extremes of the intermediate sums).
pub fn bilinear_line_equals_plain() -> Outcome {
    let mut upper = [0u8; 310];
    let mut lower = [0u8; 310];
    let mut out = [0u8; 310];
    let mut state = 0x1234_5678u32;
    let mut random = move || xorshift32(&mut state);
    for round in 0..6u32 {
        match round {
            0 | 1 => {
                fill(&mut upper, 0x2545_F491 ^ round, if round == 0 { 256 } else { 3 });
                fill(&mut lower, 0x6C07_8965 ^ (round * 3), if round == 0 { 256 } else { 3 });
                upper[..4].copy_from_slice(&[255, 0, 255, 255]);
                lower[..4].copy_from_slice(&[255, 255, 0, 255]);
            }
            2 => {
                upper.fill(255);
                lower.fill(255);
            }
            3 => {
                upper.fill(0);
                lower.fill(0);
            }
            4 => {
                for (n, (u, l)) in upper.iter_mut().zip(lower.iter_mut()).enumerate() {
                    *u = if n % 2 == 0 { 255 } else { 0 };
                    *l = if n % 3 == 0 { 0 } else { 255 };
                }
            }
            _ => {
                for (n, (u, l)) in upper.iter_mut().zip(lower.iter_mut()).enumerate() {
                    *u = if n % 2 == 0 { 0 } else { 255 };
                    *l = if n % 2 == 0 { 255 } else { 0 };
                }
            }
        }
        let mut weights = [(0u32, 0u32), (255, 255), (0, 255), (255, 0), (128, 1), (1, 128), (128, 128), (1, 1), (77, 201), (0, 0), (0, 0), (0, 0)];
        for pair in weights[9..].iter_mut() {
            let r = random();
            *pair = (r & 0xFF, (r >> 8) & 0xFF);
        }
        for (n, &(wx, wy)) in weights.iter().enumerate() {
            for (length, kernel) in (0..=600).map(|k| (k / 2, k % 2)) {
                let r = random() as usize;
                let (su, sl, so) = ((n + length) % 4, (r >> 4) % 4, (r >> 8) % 4);
                let (u, l) = (&upper[su..su + length + 1], &lower[sl..sl + length + 1]);
                out.fill(0xA5);
                let target = &mut out[so..so + length];
                if kernel == 0 {
                    super::bilinear_line(u, l, wx, wy, target);
                } else {
                    portable::bilinear_line(u, l, wx, wy, target);
                }
                for (c, &got) in target.iter().enumerate() {
                    if u32::from(got) != bilinear_formula((u, l), c, wx, wy) {
                        return Err("bilinear_line differs from the per-pixel formula");
                    }
                }
                if out[..so].iter().chain(&out[so + length..]).any(|&b| b != 0xA5) {
                    return Err("bilinear_line wrote outside its output");
                }
            }
        }
    }
    Ok(())
}

/// The bilinear sample between rows `upper` and `lower` at column `x`
/// and weights `wx`, `wy` (of 256), as the kernels define it.
fn bilinear_formula((upper, lower): (&[u8], &[u8]), x: usize, wx: u32, wy: u32) -> u32 {
    let top = u32::from(upper[x]) * (256 - wx) + u32::from(upper[x + 1]) * wx;
    let bottom = u32::from(lower[x]) * (256 - wx) + u32::from(lower[x + 1]) * wx;
    (top * (256 - wy) + bottom * wy + (1 << 15)) >> 16
}

/// `bilinear_stretch` (the selected backend's and the portable one)
/// equals the per-pixel formula at every step: lengths 0..=200, column
/// steps from under to over a pixel both ways and none, row steps either
/// way (the row weight crossing 0 and 255), rows of random, extreme and
/// alternating pixels, unaligned starts; nothing written outside `out`.
pub fn bilinear_stretch_equals_plain() -> Outcome {
    let mut upper = [0u8; 260];
    let mut lower = [0u8; 260];
    let mut out = [0u8; 210];
    let mut state = 0x5EED_0A11u32;
    let mut random = move || xorshift32(&mut state);
    for round in 0..4u32 {
        match round {
            0 => {
                fill(&mut upper, 0x2545_F491, 256);
                fill(&mut lower, 0x6C07_8965, 256);
            }
            1 => {
                upper.fill(255);
                lower.fill(255);
            }
            _ => {
                for (n, (u, l)) in upper.iter_mut().zip(lower.iter_mut()).enumerate() {
                    *u = if (n + round as usize).is_multiple_of(2) { 255 } else { 0 };
                    *l = if n % 3 == 0 { 0 } else { 255 };
                }
            }
        }
        for case in 0..400usize {
            let length = case % 201;
            let i_step = match case % 5 {
                0 => 1 << 24,
                1 => 0,
                2 => (random() % (3 << 23)) + (1 << 22),
                3 => ((random() % (1 << 24)) as i32).wrapping_neg() as u32,
                _ => (random() % (1 << 25)) as i32 as u32,
            };
            let j_step = (random() % (1 << 22)) as i32 - (1 << 21);
            let span = i64::from(i_step as i32) * length.saturating_sub(1) as i64;
            // A first position that keeps every x + 1 within the rows.
            let room = ((255i64 << 24) - span.abs()).max(0);
            let start = (random() as i64 % (room + 1)) + (-span).max(0);
            if length > 0 && !(0..255i64 << 24).contains(&(start + span)) {
                continue;
            }
            let (i, j) = (start as u32, random());
            let (su, sl, so) = (case % 4, (case / 4) % 4, (case / 16) % 4);
            let (u, l) = (&upper[su..su + 256], &lower[sl..sl + 256]);
            for kernel in 0..2 {
                out.fill(0xA5);
                let target = &mut out[so..so + length];
                if kernel == 0 {
                    super::bilinear_stretch(u, l, (i, i_step), (j, j_step as u32), target);
                } else {
                    portable::bilinear_stretch(u, l, (i, i_step), (j, j_step as u32), target);
                }
                for (n, &got) in target.iter().enumerate() {
                    let (ip, jp) = (i.wrapping_add(i_step.wrapping_mul(n as u32)), j.wrapping_add((j_step as u32).wrapping_mul(n as u32)));
                    let (x, wx, wy) = ((ip >> 24) as usize, (ip >> 16) & 0xFF, (jp >> 16) & 0xFF);
                    if u32::from(got) != bilinear_formula((u, l), x, wx, wy) {
                        return Err("bilinear_stretch differs from the per-pixel formula");
                    }
                }
                if out[..so].iter().chain(&out[so + length..]).any(|&b| b != 0xA5) {
                    return Err("bilinear_stretch wrote outside its output");
                }
            }
        }
    }
    Ok(())
}

/// Random rows (and a 0/255 pattern at the start), widths 1..=70 at
/// unaligned starts, wy and wx of 0, 1, 128, 255 and random, steps from
/// 0 to over 2 px both ways, runs that start at column 0 and runs that
/// end on the last column (the `x1` clamp) or just before it.
pub fn pinhole_rows_equal_bilinear() -> Outcome {
    let mut state = 0x1234_5679u32;
    let mut upper = [0u8; 75];
    let mut lower = [0u8; 75];
    let mut line = pinhole::Line::ZERO;
    let (mut fast, mut portable) = ([0u8; 40], [0u8; 40]);
    let steps = [0i32, 1, 0xFF, 0x100, 0x3FFF, 0x8000, 0xFFFF, 0x1_0000, 0x1_0001, 0x1_8080, 0x2_3456];
    let lengths = [1usize, 2, 3, 4, 5, 7, 8, 9, 13, 32, 37];
    for (case, width) in [1usize, 2, 3, 4, 5, 6, 7, 8, 9, 17, 64, 70].into_iter().enumerate() {
        for byte in upper.iter_mut().chain(lower.iter_mut()) {
            *byte = xorshift32(&mut state) as u8;
        }
        if case % 2 == 0 {
            upper[..4].copy_from_slice(&[255, 0, 255, 255]);
            lower[..4].copy_from_slice(&[255, 255, 0, 255]);
        }
        let start = case % 4;
        let (up, low) = (&upper[start..start + width], &lower[start..start + width]);
        let max_u = ((width as i32) - 1) << FRAC_BITS;
        for wy in [0i32, 1, 128, 255, (xorshift32(&mut state) & 0xFF) as i32] {
            let v = (3 << FRAC_BITS) | (wy << 8) | (xorshift32(&mut state) & 0xFF) as i32;
            for &magnitude in &steps {
                for step in [magnitude, -magnitude] {
                    for &n in &lengths {
                        let span = i64::from(step) * (n as i64 - 1);
                        for anchor in 0..10 {
                            // Fractions giving wx = 0, 1, 128, 255 (plus low bits).
                            let frac = [0, 0x1AB, 0x80FF, 0xFF01, 0x7F][anchor % 5];
                            // The first five runs start at the left, the rest end at the right.
                            let (low_u, high_u) = if anchor < 5 { (frac, frac + span.abs()) } else {
                                let high = i64::from(max_u) - [0, 1, 0xFF, 0x100, 0x8000][anchor % 5];
                                (high - span.abs(), high)
                            };
                            if low_u < 0 || high_u > i64::from(max_u) {
                                continue;
                            }
                            let u = if step >= 0 { low_u } else { high_u } as i32;
                            let (fast, portable) = (&mut fast[..n], &mut portable[..n]);
                            pinhole::sample_row(up, low, u, step, v, &mut line, fast);
                            if !pinhole::sample_row_portable(up, low, u, step, v, &mut line, portable) {
                                return Err("an in-image pinhole row was sampled per pixel");
                            }
                            for c in 0..n {
                                let expected = bilinear(up, low, u.wrapping_add(step.wrapping_mul(c as i32)), v);
                                if fast[c] != expected {
                                    return Err("pinhole row (kernels in use) differs from per-pixel bilinear");
                                }
                                if portable[c] != expected {
                                    return Err("pinhole row (portable) differs from per-pixel bilinear");
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// `mean_4x4` equals the rounded mean of each 4x4 block: 0 to 20 outputs
/// (rows of any start, unaligned too), values up to 255.
pub fn mean_4x4_equals_plain() -> Outcome {
    let mut state = 0x4D45_414Eu32;
    let mut rows = [[0u8; 84]; 4];
    for (r, row) in rows.iter_mut().enumerate() {
        fill(row, xorshift32(&mut state), if r == 3 { 0 } else { 256 });
    }
    rows[3].fill(255);
    for n in 0..=20 {
        for start in 0..4 {
            let mut out = [0xA5u8; 22];
            super::mean_4x4(core::array::from_fn(|r| &rows[r][start..start + 4 * n]), &mut out[1..1 + n]);
            for (k, &value) in out[1..1 + n].iter().enumerate() {
                let sum: u32 = rows.iter().flat_map(|row| &row[start + 4 * k..start + 4 * k + 4]).map(|&v| u32::from(v)).sum();
                if u32::from(value) != (sum + 8) / 16 {
                    return Err("mean_4x4 differs from the rounded block mean");
                }
            }
            if out[0] != 0xA5 || out[1 + n..].iter().any(|&b| b != 0xA5) {
                return Err("mean_4x4 wrote outside its output");
            }
        }
    }
    Ok(())
}

/// `strongest_gradients` equals a per-column loop over each block (the
/// first of equal strengths kept, blocks stronger already left alone):
/// rows of 0 to 24 pixels of full and narrow spread (many ties), and with
/// the strongest gradient, 510, every third column; every column range,
/// block sides 1 to 5, strides 1 to 3.
pub fn strongest_gradients_equal_plain() -> Outcome {
    let mut state = 0x5354_524Fu32;
    let mut lines = [[0u8; 24]; 3];
    for round in 0..3 {
        for line in lines.iter_mut() {
            fill(line, xorshift32(&mut state), if round == 1 { 2 } else { 256 });
        }
        if round == 2 {
            // Column 3n + 1: 255 left, 0 right, 0 above and 255 below.
            let [up, row, down] = &mut lines;
            for n in (1..24).step_by(3) {
                (row[n - 1], row[n], up[n], down[n]) = (255, 0, 0, 255);
                if n + 1 < 24 {
                    row[n + 1] = 0;
                }
            }
        }
        // Blocks found strong already, or not (strength 0), per round.
        let before: [Strongest; 25] = core::array::from_fn(|b| {
            let strength = [0, 2, 509, 510][(b + round) % 4];
            Strongest { strength, column: 0xEE, row: 0xDD }
        });
        for width in 0..=24 {
            let [up, row, down] = lines.each_ref().map(|line| &line[..width]);
            let rows = super::GradientRows { up, row, down };
            for start in 0..=width {
                for end in start..=width + 1 {
                    for side in 1..=5 {
                        for stride in 1..=3 {
                            let mut expected = before;
                            let blocks = width.div_ceil(side);
                            let inside = start.max(1)..end.min(width.saturating_sub(1));
                            for i in inside.clone() {
                                let block = &mut expected[i / side];
                                if (i - inside.start.max(i / side * side)) % stride == 0 {
                                    let strength = u16::from(row[i + 1].abs_diff(row[i - 1])) + u16::from(down[i].abs_diff(up[i]));
                                    if strength > block.strength {
                                        *block = Strongest { strength, column: i as u8, row: 7 };
                                    }
                                }
                            }
                            let mut fast = before;
                            super::strongest_gradients(rows, 7, start..end, side, stride, &mut fast[..blocks]);
                            if fast != expected {
                                return Err("strongest_gradients (kernels in use) differs from the per-column loop");
                            }
                            let mut portable = before;
                            if !inside.is_empty() {
                                portable::strongest_gradients(rows, 7, inside, side, stride, &mut portable[..blocks]);
                            }
                            if portable != expected {
                                return Err("strongest_gradients (portable) differs from the per-column loop");
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// `add_normal_terms` equals the plain loop bit for bit: 0 to 20 terms
/// onto sums already under way, values of mixed sign and magnitude.
pub fn normal_terms_equal_plain() -> Outcome {
    let mut state = 0x4E4F_524Du32;
    let mut value = move || {
        let bits = xorshift32(&mut state);
        (bits % 20_001) as f32 / 1000.0 - 10.0 + (bits >> 24) as f32 * 1e-3
    };
    let jacobians: [[f32; 7]; 20] = core::array::from_fn(|_| core::array::from_fn(|_| value()));
    let mut terms = [super::NormalTerm::EMPTY; 20];
    for (term, jacobian) in terms.iter_mut().zip(&jacobians) {
        *term = super::NormalTerm { weight: value().abs(), residual: value(), brightness: 10.0 * value(), jacobian };
    }
    for n in 0..=20 {
        let start: [[f32; 9]; 9] = core::array::from_fn(|_| core::array::from_fn(|_| value()));
        let start_g: [f32; 9] = core::array::from_fn(|_| value());
        let (mut h, mut g) = (start, start_g);
        super::add_normal_terms(&terms[..n], &mut h, &mut g);
        let (mut plain_h, mut plain_g) = (start, start_g);
        portable::add_normal_terms(&terms[..n], &mut plain_h, &mut plain_g);
        let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        if !same(&g, &plain_g) || !(0..9).all(|r| same(&h[r][r..], &plain_h[r][r..]) && same(&h[r][..r], &start[r][..r])) {
            return Err("add_normal_terms differs from the plain loop");
        }
    }
    Ok(())
}

/// The block matcher's `dot_shifts` equals per-product loops: rows of 0
/// to 20 pairs (the tails included), 1 to 7 shifts, patch values up to the
/// Q4 gray levels' 4,080 and the 2^15 - 1 the M4's signed lanes allow.
pub fn dot_shifts_equal_plain() -> Outcome {
    let mut state = 0xC0FF_EE11u32;
    let mut row = [0u8; 40];
    let mut patch = [0u16; 48];
    for round in 0..3 {
        let top = [4081u32, 32768, 256][round];
        for value in row.iter_mut() {
            *value = xorshift32(&mut state) as u8;
        }
        for value in patch.iter_mut() {
            *value = (xorshift32(&mut state) % top) as u16;
        }
        for pairs_len in 0..=20 {
            let mut pairs = [0u32; 20];
            super::pack_pairs(&row[..2 * pairs_len], &mut pairs[..pairs_len]);
            for shifts in 1..=7 {
                let mut sums = [5u32; 7];
                super::dot_shifts(&pairs[..pairs_len], &patch[1..], &mut sums[..shifts]);
                for (k, &sum) in sums[..shifts].iter().enumerate() {
                    let plain = (0..2 * pairs_len).map(|x| u32::from(row[x]) * u32::from(patch[1 + k + x])).fold(5u32, u32::wrapping_add);
                    if sum != plain {
                        return Err("dot_shifts differs from the per-product loop");
                    }
                }
            }
        }
    }
    Ok(())
}

/// The row copy (`ldm`/`stm` on the M4 when word aligned, unaligned words else) equals
/// `copy_from_slice` for every length 0..=70 and alignment.
pub fn copy_row_copies() -> Outcome {
    #[repr(align(4))]
    struct Words([u8; 80]);
    let mut state = 0x0BAD_F00Du32;
    let mut src = Words([0; 80]);
    for byte in src.0.iter_mut() {
        *byte = xorshift32(&mut state) as u8;
    }
    let mut dst = Words([0; 80]);
    for length in 0..=70 {
        for (from, to) in [(0, 0), (0, 1), (1, 0), (2, 2), (3, 1), (4, 8)] {
            dst.0.fill(0xA5);
            super::copy_row(&mut dst.0[to..to + length], &src.0[from..from + length]);
            let untouched = dst.0[..to].iter().chain(&dst.0[to + length..]).all(|&b| b == 0xA5);
            if dst.0[to..to + length] != src.0[from..from + length] || !untouched {
                return Err("copy_row differs from copy_from_slice");
            }
        }
    }
    Ok(())
}

/// The tolerant residues equal the per-pixel definition: lengths 0 to 40
/// (every tail), any start, every tolerance, thresholds at the edges, bytes
/// anywhere and close together (ties between the neighbours); nothing is
/// written past the row.
pub fn residues_equal_plain() -> Outcome {
    let mut state = 0x7E51_D0E5u32;
    let mut bytes = [[0u8; 48]; 4];
    for (round, spread) in [256u32, 8, 1, 256].into_iter().enumerate() {
        for (k, line) in bytes.iter_mut().enumerate() {
            fill(line, state ^ (round as u32 * 31 + k as u32), spread);
        }
        xorshift32(&mut state);
        let [row, centre, up, down] = &bytes;
        for threshold in [0u8, 3, 30, 254, 255] {
            for start in 0..3 {
                for len in 0..=40 {
                    let (row, centre, up, down) = (&row[start..start + len], &centre[start..start + len + 2], &up[start..][..len], &down[start..][..len]);
                    let lines = super::ResidueLines { row, centre, up, down };
                    for full in [(false, false), (true, false), (false, true), (true, true)] {
                        let mut plain = ([0u8; 40], [0u8; 40]);
                        for c in 0..len {
                            let (value, sideways, along) = (row[c], [centre[c], centre[c + 2]], [up[c], down[c]]);
                            let (wide, ground) = match full {
                                (false, false) => super::residue_pair::<false, false>(value, centre[c + 1], sideways, along),
                                (true, false) => super::residue_pair::<true, false>(value, centre[c + 1], sideways, along),
                                (false, true) => super::residue_pair::<false, true>(value, centre[c + 1], sideways, along),
                                (true, true) => super::residue_pair::<true, true>(value, centre[c + 1], sideways, along),
                            };
                            plain.0[c] = u8::from(wide > threshold);
                            plain.1[c] = ground;
                        }
                        let portable_residues = match full {
                            (false, false) => portable::residues::<false, false>,
                            (true, false) => portable::residues::<true, false>,
                            (false, true) => portable::residues::<false, true>,
                            (true, true) => portable::residues::<true, true>,
                        };
                        // One byte more than asked for: it must stay untouched.
                        let (mut hot, mut ground) = ([9u8; 41], [9u8; 41]);
                        super::residues(lines, full, threshold, &mut hot[..len + 1], &mut ground[..len + 1]);
                        let (mut portable_hot, mut portable_ground) = ([9u8; 41], [9u8; 41]);
                        portable_residues(lines, threshold, &mut portable_hot[..len], &mut portable_ground[..len]);
                        let same = |out: &[u8; 41], expected: &[u8; 40]| out[..len] == expected[..len] && out[len..].iter().all(|&b| b == 9);
                        if !(same(&hot, &plain.0) && same(&ground, &plain.1) && same(&portable_hot, &plain.0) && same(&portable_ground, &plain.1)) {
                            return Err("residues differ from the per-pixel definition");
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// `sqrtf` and `i64_to_f32` give libm's and the language's results bit
/// for bit: square roots of zero, subnormals, normals across the whole
/// exponent range and infinity (NaN stays NaN); conversions of the i32
/// edges, every power of two and its neighbours to 2^62, ties at every
/// scale (odd multiples of half a unit in the last place), and random
/// values of every magnitude, both signs.
pub fn float_kernels_equal_reference() -> Outcome {
    let mut state = 0x5EED_F10Au32;
    let same_root = |x: f32| {
        let (fast, reference) = (super::sqrtf(x), libm::sqrtf(x));
        fast.to_bits() == reference.to_bits() || (fast.is_nan() && reference.is_nan())
    };
    for x in [0.0, -0.0, f32::MIN_POSITIVE, f32::MAX, f32::INFINITY, -1.0, f32::NAN, 1.0, 2.0] {
        if !same_root(x) {
            return Err("sqrtf differs from libm at an edge value");
        }
    }
    for _ in 0..20_000 {
        // Random bits of a positive float: every exponent, subnormals too.
        let x = f32::from_bits(xorshift32(&mut state) & 0x7F7F_FFFF);
        if !same_root(x) {
            return Err("sqrtf differs from libm");
        }
    }
    let same_float = |v: i64| super::i64_to_f32(v).to_bits() == (v as f32).to_bits();
    for v in [0, 1, -1, i64::from(i32::MAX), i64::from(i32::MAX) + 1, i64::from(i32::MIN), i64::from(i32::MIN) - 1, (1 << 62) - 1, -(1 << 62) + 1, i64::MAX, i64::MIN] {
        if !same_float(v) {
            return Err("i64_to_f32 differs from `as f32` at an edge value");
        }
    }
    for bit in 24..62 {
        let power = 1i64 << bit;
        // A tie: half a unit in the last place (24 bits) past an odd or even mantissa.
        let half_unit = 1i64 << (bit - 24);
        for v in [power - 1, power, power + 1, power + half_unit, power + 3 * half_unit, power + half_unit + 1, power + 3 * half_unit - 1] {
            if !(same_float(v) && same_float(-v)) {
                return Err("i64_to_f32 differs from `as f32` near a power of two");
            }
        }
    }
    for _ in 0..20_000 {
        let bits = (u64::from(xorshift32(&mut state)) << 32) | u64::from(xorshift32(&mut state));
        // Every magnitude: shifted down by 0 to 63 bits.
        let v = (bits >> (xorshift32(&mut state) % 64)) as i64;
        if !same_float(v) {
            return Err("i64_to_f32 differs from `as f32`");
        }
    }
    Ok(())
}

/// `floorf` and `roundf` give libm's results bit for bit: zeros of both
/// signs, the ends of their own range, infinities and NaN; every float
/// within 8 ulps of each integer and half below 1,024 (GTI's samples), and
/// random floats of every magnitude, both signs.
pub fn floor_round_equal_libm() -> Outcome {
    let mut state = 0x466C_6F72u32;
    let same = |x: f32| {
        let pairs = [(super::floorf(x), libm::floorf(x)), (super::roundf(x), libm::roundf(x))];
        pairs.iter().all(|(fast, reference)| fast.to_bits() == reference.to_bits() || (fast.is_nan() && reference.is_nan()))
    };
    let edges = [0.0, -0.0, 0.5, 8_388_607.5, 8_388_608.0, 8_388_609.0, f32::MIN_POSITIVE, f32::INFINITY, f32::NEG_INFINITY, f32::NAN];
    for x in edges {
        if !same(x) || !same(-x) {
            return Err("floorf or roundf differs from libm at an edge value");
        }
    }
    for halves in 1..2048u32 {
        let bits = (halves as f32 * 0.5).to_bits();
        for x in (bits - 8..=bits + 8).map(f32::from_bits) {
            if !same(x) || !same(-x) {
                return Err("floorf or roundf differs from libm near an integer or a half");
            }
        }
    }
    for _ in 0..30_000 {
        let x = f32::from_bits(xorshift32(&mut state));
        if !same(x) {
            return Err("floorf or roundf differs from libm");
        }
    }
    Ok(())
}

/// `hypotf` gives libm's result bit for bit: random operands of every
/// magnitude and sign (both scaled paths too), operands 0 to 30 binades
/// apart, equal ones, zeros, infinities, NaN, and sums that fall close to
/// halfway between two floats (mantissas of all ones and of one bit).
pub fn hypotf_equals_libm() -> Outcome {
    let mut state = 0x4879_7074u32;
    let same = |x: f32, y: f32| {
        let (fast, reference) = (super::hypotf(x, y), libm::hypotf(x, y));
        fast.to_bits() == reference.to_bits() || (fast.is_nan() && reference.is_nan())
    };
    let edges = [0.0, -0.0, 1.0, f32::MIN_POSITIVE, f32::MAX, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 3.0e-19, 7.0e18];
    for &x in &edges {
        for &y in &edges {
            if !same(x, y) {
                return Err("hypotf differs from libm at an edge value");
            }
        }
    }
    for _ in 0..30_000 {
        let x = f32::from_bits(xorshift32(&mut state));
        // y within 30 binades of x, or anywhere.
        let apart = xorshift32(&mut state) % 31;
        let y = match xorshift32(&mut state) % 4 {
            0 => f32::from_bits(xorshift32(&mut state)),
            1 => x,
            2 => f32::from_bits((x.to_bits() & 0x807F_FFFF) | ((x.to_bits() >> 23 & 0xFF).saturating_sub(apart) << 23) ^ (xorshift32(&mut state) & 0x7FFF)),
            _ => f32::from_bits(((x.to_bits() >> 23 & 0xFF).saturating_sub(apart) << 23) | [0x7F_FFFF, 0x40_0001, 1, 0x7F_FFFE][(xorshift32(&mut state) % 4) as usize]),
        };
        if !same(x, y) {
            return Err("hypotf differs from libm");
        }
    }
    Ok(())
}

/// `sincosf` equals `libm::sincosf` bit for bit: the edges of its own
/// range, 30,000 random angles there and anywhere, both signs. (The host
/// also walks every 61st `f32` of its range: `kernels::tests`.)
pub fn sincosf_equals_libm() -> Outcome {
    let mut state = 0x5369_6E43u32;
    let same = |x: f32| {
        let ((s, c), (ls, lc)) = (super::sincosf(x), libm::sincosf(x));
        (s.to_bits() == ls.to_bits() && c.to_bits() == lc.to_bits()) || (s.is_nan() && ls.is_nan())
    };
    let (first, last) = (*super::SINCOSF_OWN.start(), *super::SINCOSF_OWN.end());
    let edges = [first, first - 1, last, last + 1, 0, 0x7F80_0000, 0x7FC0_0000, 0x3F80_0000];
    for bits in edges {
        if !same(f32::from_bits(bits)) || !same(-f32::from_bits(bits)) {
            return Err("sincosf differs from libm at an edge value");
        }
    }
    for _ in 0..30_000 {
        let random = xorshift32(&mut state);
        let bits = match random % 4 {
            0 => xorshift32(&mut state),
            _ => first + xorshift32(&mut state) % (last + 1 - first),
        };
        if !same(f32::from_bits(bits)) || !same(-f32::from_bits(bits)) {
            return Err("sincosf differs from libm");
        }
    }
    Ok(())
}

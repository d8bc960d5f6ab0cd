//! Plain Rust kernels: the reference the SIMD ones are checked against
//! (`checks`), the SIMD ones' tails, and the kernels of targets without
//! SIMD ones. Same functions as `sse2`, `neon` and `dsp`.

/// The sums of `columns` cut `px` wide from its start (the last piece
/// short where it ends), as many as `pieces` holds.
pub fn take_pieces(totals: &super::ColumnTotals, px: usize, columns: core::ops::Range<usize>, pieces: &mut [super::PieceSums]) {
    let columns = totals.tallies[columns.clone()].chunks(px).zip(totals.ground[columns].chunks(px));
    for (piece, (tallies, ground)) in pieces.iter_mut().zip(columns) {
        let (mut tally, mut pixels, mut sum) = (0u32, 0u32, 0u32);
        for (&t, &g) in tallies.iter().zip(ground) {
            tally += u32::from(t);
            pixels += u32::from(t >> 4);
            sum += u32::from(g);
        }
        *piece = super::PieceSums::pack(tally, pixels, sum);
    }
}

#[inline]
pub fn seed_sums(a: &[u8], b: &[u8]) -> (u32, u32) {
    let (mut sum, mut count) = (0u32, 0u32);
    for (&x, &y) in a.iter().zip(b) {
        let d = x.abs_diff(y);
        if d > super::SUM_LEVEL {
            sum = sum.wrapping_add(u32::from(d));
        }
        count = count.wrapping_add(u32::from(d > super::COUNT_LEVEL));
    }
    (sum, count)
}

#[inline]
pub fn add_to_columns(hot: &[u8], ground: &[u8], columns: core::ops::Range<usize>, totals: &mut super::ColumnTotals) -> u32 {
    let mut hot_pixels = 0;
    for c in columns {
        totals.add(c, hot[c], ground[c]);
        hot_pixels += u32::from(hot[c]);
    }
    hot_pixels
}

pub fn sad(a: &[u8], b: &[u8]) -> u32 {
    // u16 lanes over blocks of 256 cannot overflow and vectorise well.
    let mut total = 0u32;
    for (a, b) in a.chunks(256).zip(b.chunks(256)) {
        let block: u16 = a.iter().zip(b).map(|(&x, &y)| u16::from(x.abs_diff(y))).fold(0u16, u16::wrapping_add);
        total += u32::from(block);
    }
    total
}

#[inline]
pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
    for (k, sum) in sums.iter_mut().enumerate() {
        *sum += sad(current, &reference[k..]);
    }
}

/// One lane (`sse2` and `neon` interleave four; see there).
pub const HISTOGRAM_LANES: usize = 1;

#[inline]
pub fn diff_histogram(a: &[u8], b: &[u8], [histogram]: &mut [[u32; 256]; HISTOGRAM_LANES]) {
    for (&x, &y) in a.iter().zip(b) {
        histogram[usize::from(x.abs_diff(y))] += 1;
    }
}

/// The SIMD backends' `diff_histogram` (`sse2`, `neon`): the |diff|s of 16
/// pixels at a time, `diff16(at)` for `a` and `b` at `at..at + 16` (always
/// within both), counted into four lanes in turn; the tail into lane 0 here.
#[inline(always)]
pub fn diff_histogram_in_four_lanes(a: &[u8], b: &[u8], lanes: &mut [[u32; 256]; 4], diff16: impl Fn(usize) -> [u8; 16]) {
    let n = a.len().min(b.len());
    let mut done = 0;
    while done + 16 <= n {
        for quad in diff16(done).chunks_exact(4) {
            lanes[0][usize::from(quad[0])] += 1;
            lanes[1][usize::from(quad[1])] += 1;
            lanes[2][usize::from(quad[2])] += 1;
            lanes[3][usize::from(quad[3])] += 1;
        }
        done += 16;
    }
    diff_histogram(&a[done..n], &b[done..n], core::array::from_mut(&mut lanes[0]));
}

#[inline]
pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
    let (ax, ay) = (256 - wx, 256 - wy);
    for ((pixel, u), l) in out.iter_mut().zip(upper.windows(2)).zip(lower.windows(2)) {
        let top = u32::from(u[0]) * ax + u32::from(u[1]) * wx;
        let bottom = u32::from(l[0]) * ax + u32::from(l[1]) * wx;
        *pixel = ((top * ay + bottom * wy + (1 << 15)) >> 16) as u8;
    }
}

#[inline]
pub fn bilinear_stretch(upper: &[u8], lower: &[u8], (mut i, i_step): (u32, u32), (mut j, j_step): (u32, u32), out: &mut [u8]) {
    for pixel in out {
        let (x, wx, wy) = ((i >> 24) as usize, (i >> 16) & 0xFF, (j >> 16) & 0xFF);
        let top = u32::from(upper[x]) * (256 - wx) + u32::from(upper[x + 1]) * wx;
        let bottom = u32::from(lower[x]) * (256 - wx) + u32::from(lower[x + 1]) * wx;
        *pixel = ((top * (256 - wy) + bottom * wy + (1 << 15)) >> 16) as u8;
        i = i.wrapping_add(i_step);
        j = j.wrapping_add(j_step);
    }
}

// ------------------------------------------------------------ pinhole rows

#[inline]
pub fn pinhole_vertical(upper: &[u8], lower: &[u8], wy: u32, line: &mut [u16]) {
    pinhole_vertical_flipped(upper, lower, wy, line, 0);
}

/// # Safety
/// Every pixel's `x0 + 1` indexes `line` (see `pinhole::Horizontal`).
#[inline]
pub unsafe fn pinhole_horizontal(line: &[u16], u: i32, step: i32, out: &mut [u8]) {
    // SAFETY: the caller's contract.
    unsafe { pinhole_horizontal_flipped(line, u, step, out, 0) }
}

/// The vertical pass storing `V ^ flip` (the x86_64 and M4 kernels'
/// line holds `V ^ 0x8000`; they use this for the vectorised x86 pass and
/// for the M4's tail).
#[inline]
pub fn pinhole_vertical_flipped(upper: &[u8], lower: &[u8], wy: u32, line: &mut [u16], flip: u16) {
    let (ay, wy) = ((256 - wy) as u16, wy as u16);
    for ((v, &a), &b) in line.iter_mut().zip(upper).zip(lower) {
        // <= 255 * 256: no overflow.
        *v = (u16::from(a) * ay + u16::from(b) * wy) ^ flip;
    }
}

/// The horizontal pass from a line holding `V ^ flip` (the x86_64 and
/// M4 kernels' tails).
///
/// # Safety
/// Every pixel's `x0 + 1` indexes `line` (see `pinhole::Horizontal`).
#[inline]
pub unsafe fn pinhole_horizontal_flipped(line: &[u16], u: i32, step: i32, out: &mut [u8], flip: u16) {
    let mut u = u as u32;
    let base = line.as_ptr();
    for pixel in out {
        let x = (u >> 16) as usize;
        let wx = (u >> 8) & 0xFF;
        // SAFETY: x + 1 < line.len() (the caller's contract).
        let (v0, v1) = unsafe { (u32::from(*base.add(x) ^ flip), u32::from(*base.add(x + 1) ^ flip)) };
        *pixel = ((v0 * (256 - wx) + v1 * wx + (1 << 15)) >> 16) as u8;
        u = u.wrapping_add(step as u32);
    }
}

/// `dst.copy_from_slice(src)` (same length); see [`super::copy_row`].
#[inline]
pub fn copy_row(dst: &mut [u8], src: &[u8]) {
    dst.copy_from_slice(src);
}

#[inline]
pub fn dot_shifts(pairs: &[u32], patch: &[u16], sums: &mut [u32]) {
    for (k, sum) in sums.iter_mut().enumerate() {
        let products = pairs.iter().zip(patch[k..].chunks_exact(2)).map(|(&pair, two)| (pair & 0xFFFF) * u32::from(two[0]) + (pair >> 16) * u32::from(two[1]));
        *sum = products.fold(*sum, u32::wrapping_add);
    }
}

#[inline(always)]
pub fn residues<const FULL_K: bool, const FULL_G: bool>(lines: super::ResidueLines, threshold: u8, hot: &mut [u8], ground: &mut [u8]) {
    let super::ResidueLines { row, centre, up, down } = lines;
    let sideways = centre.windows(3);
    let inputs = row.iter().zip(sideways).zip(up).zip(down);
    for ((((&value, window), &up), &down), (hot, ground)) in inputs.zip(hot.iter_mut().zip(ground.iter_mut())) {
        let (wide, residue) = super::residue_pair::<FULL_K, FULL_G>(value, window[1], [window[0], window[2]], [up, down]);
        *hot = u8::from(wide > threshold);
        *ground = residue;
    }
}

#[inline]
pub fn mean_4x4(rows: [&[u8]; 4], out: &mut [u8]) {
    for (k, out) in out.iter_mut().enumerate() {
        let sum: u32 = rows.iter().flat_map(|row| &row[4 * k..4 * k + 4]).map(|&v| u32::from(v)).sum();
        *out = ((sum + 8) / 16) as u8;
    }
}

#[inline]
pub fn strongest_gradients(rows: super::GradientRows, row: u8, columns: core::ops::Range<usize>, side: usize, stride: usize, strongest: &mut [super::Strongest]) {
    let first_block_start = columns.start - columns.start % side;
    for block_start in (first_block_start..columns.end).step_by(side) {
        let block = &mut strongest[block_start / side];
        for i in (block_start.max(columns.start)..(block_start + side).min(columns.end)).step_by(stride) {
            let strength = super::gradient_strength(rows, i);
            if strength > u32::from(block.strength) {
                *block = super::Strongest { strength: strength as u16, column: i as u8, row };
            }
        }
    }
}

#[inline]
pub fn add_normal_terms(terms: &[super::NormalTerm], h: &mut [[f32; super::NORMAL_UNKNOWNS]; super::NORMAL_UNKNOWNS], g: &mut [f32; super::NORMAL_UNKNOWNS]) {
    for term in terms {
        let mut j = [0.0f32; super::NORMAL_UNKNOWNS];
        j[..7].copy_from_slice(term.jacobian);
        (j[7], j[8]) = (term.brightness, 1.0);
        for a in 0..super::NORMAL_UNKNOWNS {
            let wa = term.weight * j[a];
            g[a] += wa * term.residual;
            for (h, &jb) in h[a][a..].iter_mut().zip(&j[a..]) {
                *h += wa * jb;
            }
        }
    }
}

//! One warped line read at several constant offsets (the parallax
//! hypotheses): its positions are stepped once, and each offset's samples
//! are made from them and differenced with the current row as they come,
//! never stored. Line k moved by (di, dj) has, at every column, the
//! position of line k plus (di, dj) (the same wrapping sums), so its
//! samples are exactly [`Keyframe::sample_line`]'s.

#[cfg(not(flatland_dsp))]
use super::blend;
use super::{coordinate_bounds, Keyframe};
#[cfg(not(flatland_dsp))]
use crate::gpa::warp::pixel_and_weight;
use crate::gpa::warp::{offset_q24, RowWarp};
use crate::grid::MAX_GRID_SIDE;
use core::ops::Range;

/// A line's keyframe positions (Q8.24 modulo 2^32, [`RowWarp::positions`])
/// at some columns, each with the current row's value there (one pointer
/// walks both). A moved line's positions are these plus its offset,
/// exact wherever it lies inside the grid (every line [`MovedLines::add`]
/// keeps).
pub(in crate::gpa) struct LinePositions {
    line: RowWarp,
    columns: Range<usize>,
    /// The offsets (di, dj), each between its two bounds, that keep the
    /// line inside the grid at all its columns (see [`MovedLines::add`]).
    inside_offsets: [(i32, i32); 2],
    /// Position of column `columns.start + t` at `t`, and the value.
    at: [Position; MAX_GRID_SIDE],
}

/// 12 bytes, the layout the M4's walk reads.
#[derive(Clone, Copy)]
#[repr(C)]
struct Position {
    i: u32,
    j: u32,
    value: u32,
}

impl LinePositions {
    /// 3 KB: kept with the row stages' sums (the workspace), off the stack.
    pub(in crate::gpa) const EMPTY: LinePositions =
        LinePositions { line: RowWarp::LEVEL, columns: 0..0, inside_offsets: [(1, 0); 2], at: [Position { i: 0, j: 0, value: 0 }; MAX_GRID_SIDE] };
}

/// The line of [`LinePositions`] moved by up to `N` offsets, each kept
/// (with a key the caller names it by) only where it lies inside the grid
/// at every one of the line's columns.
pub(in crate::gpa) struct MovedLines<'a, const N: usize> {
    keyframe: &'a Keyframe<'a>,
    positions: &'a LinePositions,
    offsets: heapless::Vec<(usize, (i32, i32)), N>,
}

impl Keyframe<'_> {
    /// Steps `line` over `columns` (at most the grid's width) into
    /// `positions`, with current row `row`'s values there.
    pub(in crate::gpa) fn step_positions(&self, line: RowWarp, columns: Range<usize>, row: &[u8], positions: &mut LinePositions) {
        positions.line = line;
        positions.columns = columns.clone();
        // By its coordinates' bounds, as `sample_line` finds first (it then
        // samples every column): where the moved line's start does not
        // wrap, its bounds are the line's moved, and `surely_inside` of it
        // holds for offsets from -least to limit - 1 - most.
        let offsets = |(start, step, bend), limit: i32| {
            let (least, most) = coordinate_bounds(start, step, bend, columns.clone());
            let (start, limit) = (i64::from(start), i64::from(limit));
            let lowest = (-least).max(i64::from(i32::MIN) - start).max(i64::from(i32::MIN));
            let highest = (limit - 1 - most).min(i64::from(i32::MAX) - start).min(i64::from(i32::MAX));
            if lowest <= highest { (lowest as i32, highest as i32) } else { (1, 0) }
        };
        positions.inside_offsets = match columns.is_empty() {
            true => [(1, 0); 2],
            false => [offsets((line.i_start, line.i_step, line.i_bend), self.columns_limit()), offsets((line.j_start, line.j_step, line.j_bend), self.rows_limit())],
        };
        let at = &mut positions.at[..columns.len()];
        let row = &row[columns.clone()];
        Self::for_positions(line, columns, |t, (i, j)| {
            // SAFETY: t < columns.len() = at.len() = row.len().
            unsafe { *at.get_unchecked_mut(t) = Position { i: i.q24(), j: j.q24(), value: u32::from(*row.get_unchecked(t)) } };
        });
    }

    /// The line of `positions`, moved by no offset yet.
    pub(in crate::gpa) fn moved_lines<'a, const N: usize>(&'a self, positions: &'a LinePositions) -> MovedLines<'a, N> {
        MovedLines { keyframe: self, positions, offsets: heapless::Vec::new() }
    }
}

impl<const N: usize> MovedLines<'_, N> {
    /// Adds the line moved by (`di`, `dj`), as `key`, if it lies inside
    /// the grid at all its columns; returns whether it did (not when `N`
    /// are).
    pub(in crate::gpa) fn add(&mut self, key: usize, (di, dj): (i32, i32)) -> bool {
        let [(i_low, i_high), (j_low, j_high)] = self.positions.inside_offsets;
        let inside = (i_low..=i_high).contains(&di) && (j_low..=j_high).contains(&dj);
        let (line, columns) = (self.positions.line, self.positions.columns.clone());
        debug_assert!(!inside || self.keyframe.surely_inside(line.moved(di, dj), columns));
        inside && self.offsets.push((key, (di, dj))).is_ok()
    }

    /// Whether no line was added.
    pub(in crate::gpa) fn is_empty(&self) -> bool {
        self.offsets.is_empty()
    }

    /// Calls `f(key, sum)` for each added line (in the order added), sum
    /// being its |current value - sample| summed over `columns`, which lie
    /// within the line's.
    #[inline(always)]
    pub(in crate::gpa) fn sads(&self, columns: Range<usize>, mut f: impl FnMut(usize, u32)) {
        let (keyframe, positions) = (self.keyframe, self.positions);
        let first = columns.start - positions.columns.start;
        let at = &positions.at[..positions.columns.len()][first..first + columns.len()];
        let image = &keyframe.images[keyframe.key_half][..keyframe.height * keyframe.width];
        #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
        if !at.is_empty() && N <= avx2::LANES && crate::kernels::avx2() {
            let offsets: heapless::Vec<(u32, u32), N> = self.offsets.iter().map(|&(_, (di, dj))| (offset_q24(di), offset_q24(dj))).collect();
            let mut sums = [0u32; avx2::LANES];
            // SAFETY: the CPU has AVX2, and each added line lies inside the
            // grid at each of its columns (`Self::add`).
            if unsafe { avx2::sads(image, keyframe.width, at, &offsets, &mut sums) } {
                for (&(key, _), sum) in self.offsets.iter().zip(sums) {
                    f(key, sum);
                }
                return;
            }
        }
        for &(key, offset) in &self.offsets {
            let sum = if at.is_empty() {
                0
            } else {
                // SAFETY: each added line lies inside the grid at each of its
                // columns (`Self::add`): its row index is at most height - 2
                // and its column at most width - 2, so every pixel read
                // (index + width + 1 at most) is below height * width.
                unsafe { moved_sad(image, keyframe.width, at, (offset_q24(offset.0), offset_q24(offset.1))) }
            };
            f(key, sum);
        }
    }
}

/// [`MovedLines::sads`]' sum of the positions `at` (not empty), each moved by
/// `(di, dj)` (Q8.24) and lying inside the grid of `image` (`width` wide).
#[cfg(not(flatland_dsp))]
#[inline(always)]
unsafe fn moved_sad(image: &[u8], width: usize, at: &[Position], (di, dj): (u32, u32)) -> u32 {
    let mut sum = 0;
    for &Position { i, j, value } in at {
        let ((i0, wx), (j0, wy)) = (pixel_and_weight(i.wrapping_add(di)), pixel_and_weight(j.wrapping_add(dj)));
        let index = j0 * width + i0;
        // SAFETY: the caller's (see above).
        let sample = unsafe {
            let pixel = image.as_ptr().add(index);
            blend(*pixel, *pixel.add(1), *pixel.add(width), *pixel.add(width + 1), wx, wy)
        };
        sum += u32::from(sample).abs_diff(value);
    }
    sum
}

/// [`blend`] on the M4 as LLVM will not schedule it: one `ldrd` walks the
/// positions, the current value sits beside them, and `usada8` adds the
/// |difference| (28 instructions a pixel, no spill). The blend is the
/// same integer: `top = p00 << 8 + (p01 - p00) wx` (likewise `bottom`),
/// `(top << 8 + (bottom - top) wy + 2^15) >> 16`, at most 255.
#[cfg(flatland_dsp)]
#[inline(always)]
unsafe fn moved_sad(image: &[u8], width: usize, at: &[Position], (di, dj): (u32, u32)) -> u32 {
    let mut sum = 0u32;
    // SAFETY: reads the `at.len()` (> 0) positions of 12 bytes, and per
    // position four pixels the caller vouches for.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrd {i}, {j}, [{p}], #12",
            "add {i}, {i}, {di}",
            "add {j}, {j}, {dj}",
            "lsr {t}, {j}, #24",
            "mla {t}, {t}, {w}, {image}",
            "add {t}, {t}, {i}, lsr #24",    // &p00
            "ldrb {a}, [{t}]",
            "ldrb {b}, [{t}, #1]",
            "sub {b}, {b}, {a}",
            "ubfx {i}, {i}, #16, #8",        // wx
            "mul {b}, {b}, {i}",
            "add {a}, {b}, {a}, lsl #8",     // top
            "add {t}, {t}, {w}",
            "ldrb {b}, [{t}]",
            "ldrb {t}, [{t}, #1]",
            "sub {t}, {t}, {b}",
            "mul {t}, {t}, {i}",
            "add {b}, {t}, {b}, lsl #8",     // bottom
            "sub {b}, {b}, {a}",
            "ubfx {j}, {j}, #16, #8",        // wy
            "mul {b}, {b}, {j}",
            "add {b}, {b}, {a}, lsl #8",
            "add {b}, {b}, #32768",
            "lsr {b}, {b}, #16",             // the sample
            "ldr {a}, [{p}, #-4]",           // the current value
            "usada8 {sum}, {b}, {a}, {sum}",
            "cmp {p}, {end}",
            "bne 2b",
            p = inout(reg) at.as_ptr() => _,
            end = in(reg) at.as_ptr_range().end,
            image = in(reg) image.as_ptr(),
            w = in(reg) width,
            di = in(reg) di,
            dj = in(reg) dj,
            sum = inout(reg) sum,
            i = out(reg) _, j = out(reg) _, t = out(reg) _, a = out(reg) _, b = out(reg) _,
            options(readonly, nostack)
        );
    }
    sum
}

/// `MovedLines::sads` on x86_64 with AVX2 (detected at run time): the
/// lines' samples at one column, eight lines a vector, each sample's two
/// pixel pairs gathered and blended across by `vpmaddwd`
/// (`p00 (256 - wx) + p01 wx` is `blend`'s `p00 << 8 + (p01 - p00) wx`),
/// then down as `blend` does. A cell segment is 5-15 columns, too short to
/// run along; the lines are as many as the hypotheses, all at once.
#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
mod avx2 {
    use super::Position;
    use core::arch::x86_64::*;

    /// Lines a call takes: two vectors.
    pub(super) const LANES: usize = 16;

    /// Adds to `sums[k]` the SAD of line k (`offsets[k]`, Q8.24, at most
    /// [`LANES`]) over the positions `at`; false, with nothing added, when
    /// a gather could read past the image's end (its last row's last two
    /// pixels: a gather reads four bytes from a pixel pair's first).
    ///
    /// # Safety
    /// The CPU has AVX2, and every line moved by its offset lies inside the
    /// grid at every position of `at` (`MovedLines::add`).
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn sads(image: &[u8], width: usize, at: &[Position], offsets: &[(u32, u32)], sums: &mut [u32; LANES]) -> bool {
        let Some(&first) = offsets.first() else { return true };
        // Unused lanes repeat the first line (inside), their sums dropped.
        let lane = |k: usize| offsets.get(k).copied().unwrap_or(first);
        let vector = |k0: usize, part: fn((u32, u32)) -> u32| {
            let v: [u32; 8] = core::array::from_fn(|k| part(lane(k0 + k)));
            // SAFETY: 32 bytes from an array of 8 u32.
            unsafe { _mm256_loadu_si256(v.as_ptr().cast()) }
        };
        let di = [vector(0, |o| o.0), vector(8, |o| o.0)];
        let dj = [vector(0, |o| o.1), vector(8, |o| o.1)];
        let halves = if offsets.len() > 8 { 2 } else { 1 };
        let (low_byte, second_byte) = (_mm256_set1_epi32(0xFF), _mm256_set1_epi32(0xFF00));
        let (full, half) = (_mm256_set1_epi32(256), _mm256_set1_epi32(1 << 15));
        let stride = _mm256_set1_epi32(width as i32);
        let limit = _mm256_set1_epi32(image.len().saturating_sub(width + 4) as i32);
        let mut acc = [_mm256_setzero_si256(); 2];
        let mut beyond = _mm256_setzero_si256();
        for position in at {
            let (i, j, value) = (_mm256_set1_epi32(position.i as i32), _mm256_set1_epi32(position.j as i32), _mm256_set1_epi32(position.value as i32));
            for h in 0..halves {
                let i = _mm256_add_epi32(i, di[h]);
                let j = _mm256_add_epi32(j, dj[h]);
                let index = _mm256_add_epi32(_mm256_mullo_epi32(_mm256_srli_epi32::<24>(j), stride), _mm256_srli_epi32::<24>(i));
                let out = _mm256_cmpgt_epi32(index, limit);
                beyond = _mm256_or_si256(beyond, out);
                // A lane that could read past the end reads the image's first
                // pixels instead (and the call adds nothing).
                let index = _mm256_andnot_si256(out, index);
                let wx = _mm256_and_si256(_mm256_srli_epi32::<16>(i), low_byte);
                let wy = _mm256_and_si256(_mm256_srli_epi32::<16>(j), low_byte);
                let weights = _mm256_or_si256(_mm256_sub_epi32(full, wx), _mm256_slli_epi32::<16>(wx));
                // A gathered word's two low bytes as two 16-bit lanes.
                let pair = |word: __m256i| _mm256_or_si256(_mm256_and_si256(word, low_byte), _mm256_slli_epi32::<8>(_mm256_and_si256(word, second_byte)));
                // SAFETY: every index is at most the image's length - width - 4
                // (lanes beyond were set to 0 above), so both rows' four bytes
                // lie inside `image`.
                let (upper, lower) = unsafe {
                    (_mm256_i32gather_epi32::<1>(image.as_ptr().cast(), index), _mm256_i32gather_epi32::<1>(image.as_ptr().add(width).cast(), index))
                };
                let top = _mm256_madd_epi16(pair(upper), weights);
                let bottom = _mm256_madd_epi16(pair(lower), weights);
                let down = _mm256_mullo_epi32(_mm256_sub_epi32(bottom, top), wy);
                let sample = _mm256_srli_epi32::<16>(_mm256_add_epi32(_mm256_add_epi32(_mm256_slli_epi32::<8>(top), down), half));
                acc[h] = _mm256_add_epi32(acc[h], _mm256_abs_epi32(_mm256_sub_epi32(sample, value)));
            }
        }
        if _mm256_movemask_epi8(beyond) != 0 {
            return false;
        }
        let mut lanes = [0u32; LANES];
        // SAFETY: 2 x 32 bytes into an array of 16 u32.
        unsafe {
            _mm256_storeu_si256(lanes.as_mut_ptr().cast(), acc[0]);
            _mm256_storeu_si256(lanes.as_mut_ptr().add(8).cast(), acc[1]);
        }
        for (sum, lane) in sums.iter_mut().zip(lanes).take(offsets.len()) {
            *sum += lane;
        }
        true
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    /// The AVX2 sums equal the plain loop's, line by line: up to 11 lines
    /// (as many as the hypotheses), positions anywhere in the grid, and
    /// some at its last row and column, where a gather could pass the
    /// image's end: there the call must refuse, adding nothing.
    #[test]
    fn avx2_sads_equal_the_plain_ones() {
        if !crate::kernels::avx2() {
            std::println!("this CPU has no AVX2: its kernel is not run here");
            return;
        }
        let (width, height) = (141usize, 97usize);
        let mut seed = 0xA5A5_0001u32;
        let mut next = |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        let image: std::vec::Vec<u8> = (0..width * height).map(|_| next(256) as u8).collect();
        let (mut compared, mut refused) = (0, 0);
        for round in 0..3_000 {
            let lines = 1 + next(11) as usize;
            // Offsets within +-8 px; positions leave them room inside.
            let offsets: std::vec::Vec<(u32, u32)> = (0..lines).map(|_| ((next(16 << 24) as i32 - (8 << 24)) as u32, (next(16 << 24) as i32 - (8 << 24)) as u32)).collect();
            let edge = round % 10 == 0;
            let at: std::vec::Vec<Position> = (0..1 + next(15))
                .map(|_| {
                    let (i, j) = if edge { (width as u32 - 10, height as u32 - 10) } else { (8 + next(width as u32 - 26), 8 + next(height as u32 - 26)) };
                    // Q8.24: whole pixels, the weight's byte, finer bits.
                    Position { i: (i << 24) | next(1 << 24), j: (j << 24) | next(1 << 24), value: next(256) }
                })
                .collect();
            let mut sums = [7u32; avx2::LANES];
            // SAFETY: the CPU has AVX2; every moved position lies 8 px or more inside.
            let done = unsafe { avx2::sads(&image, width, &at, &offsets, &mut sums) };
            if !done {
                assert!(sums.iter().all(|&sum| sum == 7), "a refused call added to its sums");
                refused += 1;
                continue;
            }
            for (k, &offset) in offsets.iter().enumerate() {
                // SAFETY: as above.
                let plain = unsafe { moved_sad(&image, width, &at, offset) };
                assert_eq!(sums[k], 7 + plain, "line {k} of {lines}, round {round}");
            }
            compared += 1;
        }
        assert!(compared > 2_000, "too few calls compared: {compared} ({refused} refused)");
    }
}

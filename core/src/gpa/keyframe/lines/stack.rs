//! The search band's stacks of lines a keyframe row apart
//! ([`Keyframe::sample_lines`](super::Keyframe::sample_lines)) on an
//! x86_64 with AVX2 (`crate::kernels::avx2()`): eight columns at a time.
//! [`sample_column`] is one column as `Keyframe::sample_stack`'s plain loop
//! makes it (written out there, so that the M4's loop compiles as before):
//! the AVX2 path's fallback and its tests' reference.

use super::between;
use crate::gpa::band::BAND_WIDTH;
use crate::gpa::warp::pixel_and_weight;

/// The column at Q8.24 position (`i`, `j`) of `N` lines a keyframe row
/// apart, into `out + t`, `out + BAND_WIDTH + t`, ... (band row k's sample).
///
/// # Safety
/// Line N - 1 at (i, j + N - 1 px) lies inside the grid of `image`
/// (`width` wide): its row index is at most height - 2 and its column at
/// most width - 2, so every pixel read (index + N width + 1 at most) is
/// inside `image`. `out + k BAND_WIDTH + t` is writable for every k < N.
#[inline(always)]
pub(super) unsafe fn sample_column<const N: usize>(image: &[u8], width: usize, (i, j): (u32, u32), out: *mut u8, t: usize) {
    let ((i0, wx), (j0, wy)) = (pixel_and_weight(i), pixel_and_weight(j));
    // One pointer walks down the rows (the M4 then loads at an offset
    // from it, with no index to rebuild per row).
    let across = |pixel: *const u8| {
        // SAFETY: the caller's.
        let (left, right) = unsafe { (*pixel, *pixel.add(1)) };
        (i32::from(left) << 8) + (i32::from(right) - i32::from(left)) * wx
    };
    // SAFETY: the caller's (see above).
    let mut pixel = unsafe { image.as_ptr().add(j0 * width + i0) };
    let mut top = across(pixel);
    for k in 0..N {
        // SAFETY: the caller's.
        unsafe {
            pixel = pixel.add(width);
            let bottom = across(pixel);
            *out.add(k * BAND_WIDTH + t) = between(top, bottom, wy);
            top = bottom;
        }
    }
}

/// [`sample_column`] eight columns at a time with AVX2. Gathers cost more
/// here than the plain column's loads; but a band line steps about a pixel
/// a column and drifts across keyframe rows slowly, so eight columns mostly
/// read one keyframe row's pixels within 16 bytes: each row's 16 bytes are
/// loaded once and the eight pixel pairs picked out by `vpshufb`, blended
/// across by `vpmaddwd` (`p0 (256 - wx) + p1 wx` is `p0 << 8 + (p1 - p0)
/// wx`), then down as [`between`] does. The same integers, so the same
/// bytes. Eight columns across two keyframe rows, or spread wider, go by
/// the plain column.
#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
pub(super) mod avx2 {
    use super::sample_column;
    use crate::gpa::band::BAND_WIDTH;
    use crate::gpa::warp::RowWarp;
    use core::arch::x86_64::*;

    /// Samples the columns `first..first + count` of `line` as
    /// [`sample_column`] does, column `first` into `out`, the next into
    /// `out + 1`, ...
    ///
    /// # Safety
    /// The CPU has AVX2, and [`sample_column`]'s contract holds at each of
    /// the columns, with `out + t` for column `first + t`.
    #[target_feature(enable = "avx2")]
    pub(in crate::gpa::keyframe) unsafe fn sample_columns<const N: usize>(image: &[u8], width: usize, line: RowWarp, first: usize, count: usize, out: *mut u8) {
        // The first pixel whose N + 1 rows' 16 bytes lie inside from no further.
        let last_start = image.len().checked_sub(N * width + 16).map_or(-1, |last| last.min(i32::MAX as usize) as i32);
        let (last_start, stride) = (_mm256_set1_epi32(last_start), _mm256_set1_epi32(width as i32));
        let low_byte = _mm256_set1_epi32(0xFF);
        let (full, half) = (_mm256_set1_epi32(256), _mm256_set1_epi32(1 << 15));
        // A column's pair p0, p1 within the 16 bytes: offset o picks bytes o
        // and o + 1 into the low bytes of two 16-bit lanes (0x80: zero).
        let (pair_bytes, widest) = (_mm256_set1_epi32(0x8001_8000u32 as i32), _mm256_set1_epi32(14));
        // Columns t..t + 8 as lanes, stepped eight columns at a time by the
        // same wrapping differences as `Positions` steps one: the lanes'
        // positions s + t d + t (t - 1) / 2 e and differences d + t e,
        // then eight columns on s + 8 d + 28 e and d + 8 e.
        let lanes = |(s, d, e): (u32, u32, u32)| {
            let t = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
            let pairs = _mm256_setr_epi32(0, 0, 1, 3, 6, 10, 15, 21);
            let (d, e) = (_mm256_set1_epi32(d as i32), _mm256_set1_epi32(e as i32));
            let sums = _mm256_add_epi32(_mm256_add_epi32(_mm256_set1_epi32(s as i32), _mm256_mullo_epi32(t, d)), _mm256_mullo_epi32(pairs, e));
            let differences = _mm256_add_epi32(d, _mm256_mullo_epi32(t, e));
            (sums, differences, _mm256_slli_epi32::<3>(e), _mm256_mullo_epi32(_mm256_set1_epi32(28), e))
        };
        let advance = |(sums, differences, eight, twenty_eight): &mut (__m256i, __m256i, __m256i, __m256i)| {
            *sums = _mm256_add_epi32(_mm256_add_epi32(*sums, _mm256_slli_epi32::<3>(*differences)), *twenty_eight);
            *differences = _mm256_add_epi32(*differences, *eight);
        };
        let (i, j) = line.positions(first).take::<true>();
        let (mut i_lanes, mut j_lanes) = (lanes(i.differences()), lanes(j.differences()));
        let first_lane = |v: __m256i| _mm256_broadcastd_epi32(_mm256_castsi256_si128(v));
        let mut t = 0;
        while t + 8 <= count {
            let (iv, jv) = (i_lanes.0, j_lanes.0);
            advance(&mut i_lanes);
            advance(&mut j_lanes);
            let (i0, j0) = (_mm256_srli_epi32::<24>(iv), _mm256_srli_epi32::<24>(jv));
            // Offsets from the first column's pixel, each in 0..=14; all
            // on one keyframe row, whose N + 1 rows' 16 bytes are inside.
            let offsets = _mm256_sub_epi32(i0, first_lane(i0));
            let one_row = _mm256_cmpeq_epi32(j0, first_lane(j0));
            let near = _mm256_cmpeq_epi32(_mm256_max_epu32(offsets, widest), widest);
            let start = first_lane(_mm256_add_epi32(_mm256_mullo_epi32(j0, stride), i0));
            let inside = _mm256_cmpgt_epi32(_mm256_add_epi32(last_start, _mm256_set1_epi32(1)), start);
            if _mm256_movemask_epi8(_mm256_and_si256(_mm256_and_si256(one_row, near), inside)) != -1 {
                let (mut i, mut j) = ([0u32; 8], [0u32; 8]);
                // SAFETY: 32 bytes into arrays of 8 u32.
                unsafe {
                    _mm256_storeu_si256(i.as_mut_ptr().cast(), iv);
                    _mm256_storeu_si256(j.as_mut_ptr().cast(), jv);
                }
                for k in 0..8 {
                    // SAFETY: the caller's, at column first + t + k.
                    unsafe { sample_column::<N>(image, width, (i[k], j[k]), out, t + k) };
                }
                t += 8;
                continue;
            }
            let start = _mm256_cvtsi256_si32(start) as usize;
            let picks = _mm256_add_epi32(_mm256_or_si256(offsets, _mm256_slli_epi32::<16>(offsets)), pair_bytes);
            let wx = _mm256_and_si256(_mm256_srli_epi32::<16>(iv), low_byte);
            let wy = _mm256_and_si256(_mm256_srli_epi32::<16>(jv), low_byte);
            let weights = _mm256_or_si256(_mm256_sub_epi32(full, wx), _mm256_slli_epi32::<16>(wx));
            // SAFETY: start + N width + 16 <= image.len() (checked above):
            // each of the N + 1 rows' 16 bytes lies inside `image`.
            let across = |row: usize| unsafe {
                let bytes = _mm256_broadcastsi128_si256(_mm_loadu_si128(image.as_ptr().add(start + row * width).cast()));
                _mm256_madd_epi16(_mm256_shuffle_epi8(bytes, picks), weights)
            };
            let mut top = across(0);
            for k in 0..N {
                let bottom = across(k + 1);
                let down = _mm256_mullo_epi32(_mm256_sub_epi32(bottom, top), wy);
                // At most 255 (a blend of bytes): the packs keep it whole.
                let sample = _mm256_srli_epi32::<16>(_mm256_add_epi32(_mm256_add_epi32(_mm256_slli_epi32::<8>(top), down), half));
                let words = _mm_packus_epi32(_mm256_castsi256_si128(sample), _mm256_extracti128_si256::<1>(sample));
                // SAFETY: band row k's columns t..t + 8, within the caller's `count`.
                unsafe { _mm_storel_epi64(out.add(k * BAND_WIDTH + t).cast(), _mm_packus_epi16(words, words)) };
                top = bottom;
            }
            t += 8;
        }
        let mut positions = line.positions(first + t);
        for t in t..count {
            let (i, j) = positions.take::<true>();
            // SAFETY: the caller's, at column first + t.
            unsafe { sample_column::<N>(image, width, (i.q24(), j.q24()), out, t) };
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::gpa::warp::RowWarp;

    /// The AVX2 stacks equal the plain columns, byte for byte: straight,
    /// yawed and bent lines at random places in the grid, down to its last
    /// rows and columns (where the 16-byte loads give way to the plain column),
    /// 1 to 7 lines, every length from 0 to 40 columns, from the line's
    /// column 0 to 19.
    #[test]
    fn avx2_stacks_equal_the_plain_columns() {
        if !crate::kernels::avx2() {
            std::println!("this CPU has no AVX2: its kernel is not run here");
            return;
        }
        let (width, height) = (141usize, 97usize);
        let mut seed = 0x5EED_57ACu32;
        let mut next = |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        let image: std::vec::Vec<u8> = (0..width * height).map(|_| next(256) as u8).collect();
        let mut checked = 0;
        for round in 0..4_000 {
            let lines = [1usize, 3, 5, 7][round % 4];
            let columns = next(41) as usize;
            // The stack's first column: its positions are the line's there.
            let first = next(20) as usize;
            // Start and steps (Q16) that keep every column inside: i steps
            // by 1/4 to 5/4 px, j drifts by up to 1/8 px a column, bends
            // up to 1/2048 px a column squared (Q24), under 2 px by column 60.
            let i_step = (next(1 << 16) as i32) + (1 << 14);
            let j_step = next(1 << 14) as i32 - (1 << 13);
            let (i_bend, j_bend) = if round % 3 == 0 { (0, 0) } else { (next(1 << 14) as i32 - (1 << 13), next(1 << 14) as i32 - (1 << 13)) };
            let i_room = width as i32 - 2 - ((first + columns) as i32 * 5 / 4) - 3;
            let j_room = height as i32 - 2 - lines as i32 - 10;
            let line = if round % 5 == 0 {
                // Level, its last line on the grid's second last row and its
                // last column on the second last column: 16 bytes read from
                // there would pass the image's end.
                let (i0, j0) = (width as i32 - 2 - (first + columns) as i32, height as i32 - 1 - lines as i32);
                RowWarp { i_start: (i0 << 16) | next(1 << 16) as i32, i_step: 1 << 16, i_bend: 0, j_start: (j0 << 16) | next(1 << 16) as i32, j_step: 0, j_bend: 0 }
            } else {
                let (i0, j0) = (2 + next(i_room as u32) as i32, 10 + next((j_room - 10) as u32) as i32);
                RowWarp { i_start: (i0 << 16) | next(1 << 16) as i32, i_step, i_bend, j_start: (j0 << 16) | next(1 << 16) as i32, j_step, j_bend }
            };
            let (mut plain, mut fast) = ([[0u8; BAND_WIDTH]; 7], [[0u8; BAND_WIDTH]; 7]);
            let mut positions = line.positions(first);
            for t in 0..columns {
                let (i, j) = positions.take::<true>();
                // SAFETY: every position lies inside with the lines below it
                // (the room left above); t < BAND_WIDTH.
                unsafe {
                    let out = plain.as_mut_ptr().cast::<u8>();
                    match lines {
                        1 => sample_column::<1>(&image, width, (i.q24(), j.q24()), out, t),
                        3 => sample_column::<3>(&image, width, (i.q24(), j.q24()), out, t),
                        5 => sample_column::<5>(&image, width, (i.q24(), j.q24()), out, t),
                        _ => sample_column::<7>(&image, width, (i.q24(), j.q24()), out, t),
                    }
                }
            }
            let out = fast.as_mut_ptr().cast::<u8>();
            // SAFETY: the CPU has AVX2; as above.
            unsafe {
                match lines {
                    1 => avx2::sample_columns::<1>(&image, width, line, first, columns, out),
                    3 => avx2::sample_columns::<3>(&image, width, line, first, columns, out),
                    5 => avx2::sample_columns::<5>(&image, width, line, first, columns, out),
                    _ => avx2::sample_columns::<7>(&image, width, line, first, columns, out),
                }
            }
            for k in 0..lines {
                assert_eq!(plain[k][..columns], fast[k][..columns], "round {round}: line {k} of {lines}, {line:?}");
                assert!(fast[k][columns..].iter().all(|&b| b == 0), "round {round}: written past the columns");
            }
            checked += usize::from(columns >= 8);
        }
        assert!(checked > 3_000, "too few stacks of eight columns or more: {checked}");
    }
}

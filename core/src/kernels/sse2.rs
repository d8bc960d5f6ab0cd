//! x86_64 kernels with SSE2, which is baseline there (no runtime
//! detection, which `no_std` could not do anyway): `psadbw` for sums of 16
//! absolute differences, saturating subtractions for |diff|, `pmaddwd` for
//! the bilinear blends. Same functions as `portable`, whose versions do the
//! tails.

use super::pinhole::FLIP;
use super::portable;
use core::arch::x86_64::*;

/// Low and high 64-bit lanes of a `psadbw` accumulator, added.
#[inline(always)]
fn total(v: __m128i) -> u32 {
    // SAFETY: SSE2 is part of the x86_64 baseline.
    unsafe { (_mm_cvtsi128_si64(v) + _mm_cvtsi128_si64(_mm_unpackhi_epi64(v, v))) as u32 }
}

#[inline]
pub fn sad(a: &[u8], b: &[u8]) -> u32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut done = 0;
    // SAFETY: SSE2 is baseline on x86_64; every load reads 16 (or 8)
    // bytes inside `a[..n]` and `b[..n]` (unaligned loads).
    let acc = unsafe {
        let mut acc = _mm_setzero_si128();
        while done + 16 <= n {
            let x = _mm_loadu_si128(a.as_ptr().add(done).cast());
            let y = _mm_loadu_si128(b.as_ptr().add(done).cast());
            acc = _mm_add_epi64(acc, _mm_sad_epu8(x, y));
            done += 16;
        }
        if done + 8 <= n {
            let x = _mm_loadl_epi64(a.as_ptr().add(done).cast());
            let y = _mm_loadl_epi64(b.as_ptr().add(done).cast());
            acc = _mm_add_epi64(acc, _mm_sad_epu8(x, y));
            done += 8;
        }
        acc
    };
    total(acc) + portable::sad(&a[done..], &b[done..])
}

#[inline]
pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
    match sums.len() {
        3 => shifts::<3>(current, reference, sums),
        5 => shifts::<5>(current, reference, sums),
        7 => shifts::<7>(current, reference, sums),
        _ => portable::sad_shifts(current, reference, sums),
    }
}

/// Each 16-byte block of `current` is loaded once for all N shifts.
#[inline(always)]
fn shifts<const N: usize>(current: &[u8], reference: &[u8], sums: &mut [u32]) {
    let n = current.len();
    let mut done = 0;
    // SAFETY: SSE2 is baseline on x86_64; loads read current[done..done + 16]
    // (<= n) and reference[done + k..done + k + 16] (<= n + N - 1 <= len,
    // checked by the caller `super::sad_shifts`).
    let acc = unsafe {
        let mut acc = [_mm_setzero_si128(); N];
        while done + 16 <= n {
            let x = _mm_loadu_si128(current.as_ptr().add(done).cast());
            for (k, acc) in acc.iter_mut().enumerate() {
                let y = _mm_loadu_si128(reference.as_ptr().add(done + k).cast());
                *acc = _mm_add_epi64(*acc, _mm_sad_epu8(x, y));
            }
            done += 16;
        }
        acc
    };
    for (k, (sum, acc)) in sums.iter_mut().zip(acc).enumerate() {
        *sum += total(acc) + portable::sad(&current[done..], &reference[done + k..]);
    }
}

/// Neighbouring pixels of flat ground have equal |diff|; with one lane every
/// increment would wait for the previous one's store.
pub const HISTOGRAM_LANES: usize = 4;

/// |diff| of 16 pixels at a time, counted into the four lanes in turn.
#[inline]
pub fn diff_histogram(a: &[u8], b: &[u8], lanes: &mut [[u32; 256]; HISTOGRAM_LANES]) {
    portable::diff_histogram_in_four_lanes(a, b, lanes, |at| {
        let mut diffs = [0u8; 16];
        // SAFETY: SSE2 is baseline on x86_64; loads read a/b[at..at + 16],
        // within both (the caller's promise).
        unsafe {
            let x = _mm_loadu_si128(a.as_ptr().add(at).cast());
            let y = _mm_loadu_si128(b.as_ptr().add(at).cast());
            let d = _mm_or_si128(_mm_subs_epu8(x, y), _mm_subs_epu8(y, x));
            _mm_storeu_si128(diffs.as_mut_ptr().cast(), d);
        }
        diffs
    });
}

/// 16 samples per step. `top` (<= 65,280) fits u16 lanes; the vertical
/// blend uses `pmaddwd` on (top - 2^15, bottom - 2^15) pairs, which are
/// i16, and adds back 2^15 * 256: the same integer as the portable sum.
#[inline]
pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
    let n = out.len().min(upper.len().saturating_sub(1)).min(lower.len().saturating_sub(1));
    let mut done = 0;
    // SAFETY: SSE2 is baseline on x86_64; loads read upper/lower[done..done + 17]
    // (< n + 1 <= len) and stores write out[done..done + 16] (<= n).
    unsafe {
        let zero = _mm_setzero_si128();
        let ax = _mm_set1_epi16((256 - wx) as i16);
        let wxv = _mm_set1_epi16(wx as i16);
        let weights = _mm_set1_epi32(((wy as i32) << 16) | (256 - wy) as i32);
        let bias = _mm_set1_epi32((1 << 23) + (1 << 15));
        let flip = _mm_set1_epi16(i16::MIN);
        let (pu, pl, po) = (upper.as_ptr(), lower.as_ptr(), out.as_mut_ptr());
        while done + 16 <= n {
            let u0 = _mm_loadu_si128(pu.add(done).cast());
            let u1 = _mm_loadu_si128(pu.add(done + 1).cast());
            let l0 = _mm_loadu_si128(pl.add(done).cast());
            let l1 = _mm_loadu_si128(pl.add(done + 1).cast());
            let horizontal = |p0: __m128i, p1: __m128i, high: bool| {
                let (a, b) = if high {
                    (_mm_unpackhi_epi8(p0, zero), _mm_unpackhi_epi8(p1, zero))
                } else {
                    (_mm_unpacklo_epi8(p0, zero), _mm_unpacklo_epi8(p1, zero))
                };
                _mm_xor_si128(_mm_add_epi16(_mm_mullo_epi16(a, ax), _mm_mullo_epi16(b, wxv)), flip)
            };
            let vertical = |top: __m128i, bottom: __m128i| {
                let lo = _mm_madd_epi16(_mm_unpacklo_epi16(top, bottom), weights);
                let hi = _mm_madd_epi16(_mm_unpackhi_epi16(top, bottom), weights);
                let lo = _mm_srli_epi32(_mm_add_epi32(lo, bias), 16);
                let hi = _mm_srli_epi32(_mm_add_epi32(hi, bias), 16);
                _mm_packs_epi32(lo, hi)
            };
            let first = vertical(horizontal(u0, u1, false), horizontal(l0, l1, false));
            let second = vertical(horizontal(u0, u1, true), horizontal(l0, l1, true));
            _mm_storeu_si128(po.add(done).cast(), _mm_packus_epi16(first, second));
            done += 16;
        }
    }
    portable::bilinear_line(&upper[done..], &lower[done..], wx, wy, &mut out[done..n]);
}

// ------------------------------------------------------------ pinhole rows
// The line holds `V ^ FLIP` as on the M4, so that `pmaddwd` (signed 16x16,
// summed in pairs) blends `[V'[x0] | V'[x0 + 1]]` with `[256 - wx | wx]`
// like `smlad` does.

/// Vectorises to 8 u16 lanes (`pmullw`); the flip is one `pxor`.
#[inline]
pub fn pinhole_vertical(upper: &[u8], lower: &[u8], wy: u32, line: &mut [u16]) {
    portable::pinhole_vertical_flipped(upper, lower, wy, line, FLIP);
}

/// Eight pixels per step: the pairs are scalar (unaligned) 32-bit
/// loads, the weights `(wx << 16) | (256 - wx)` are computed in i32
/// lanes from the four u's, `pmaddwd` gives `V'0 * (256 - wx) +
/// V'1 * wx`, and `2^23 + 2^15` restores the bias and rounds: the
/// sum is `bilinear`'s, < 2^24, and its bits 16..24 the pixel.
///
/// # Safety
/// Every pixel's `x0 + 1` indexes `line` (see `pinhole::Horizontal`).
#[inline]
pub unsafe fn pinhole_horizontal(line: &[u16], u: i32, step: i32, out: &mut [u8]) {
    let n = out.len();
    let base = line.as_ptr();
    let mut u = u;
    let mut done = 0;
    // SAFETY: SSE2 is baseline on x86_64; the caller guarantees each
    // pixel's x0 and x0 + 1 index `line` (read as one unaligned
    // u32 at x0); stores write out[done..done + 8] (<= n).
    unsafe {
        let pair = |u: i32| (base.add((u as u32 >> 16) as usize) as *const i32).read_unaligned();
        let lanes = _mm_set_epi32(3i32.wrapping_mul(step), 2i32.wrapping_mul(step), step, 0);
        let step4 = 4i32.wrapping_mul(step);
        let (byte, c256) = (_mm_set1_epi32(0xFF), _mm_set1_epi32(256));
        let bias = _mm_set1_epi32((1 << 23) + (1 << 15));
        let four = |u: i32| {
            let us = _mm_add_epi32(_mm_set1_epi32(u), lanes);
            let wx = _mm_and_si128(_mm_srli_epi32(us, 8), byte);
            let weights = _mm_or_si128(_mm_slli_epi32(wx, 16), _mm_sub_epi32(c256, wx));
            let (u1, u2, u3) = (u.wrapping_add(step), u.wrapping_add(step.wrapping_mul(2)), u.wrapping_add(step.wrapping_mul(3)));
            let pairs = _mm_set_epi32(pair(u3), pair(u2), pair(u1), pair(u));
            _mm_srli_epi32(_mm_add_epi32(_mm_madd_epi16(pairs, weights), bias), 16)
        };
        while done + 8 <= n {
            let low = four(u);
            let high = four(u.wrapping_add(step4));
            let bytes = _mm_packus_epi16(_mm_packs_epi32(low, high), _mm_setzero_si128());
            _mm_storel_epi64(out.as_mut_ptr().add(done).cast(), bytes);
            u = u.wrapping_add(step4).wrapping_add(step4);
            done += 8;
        }
    }
    // SAFETY: the caller's contract, for the remaining pixels.
    unsafe { portable::pinhole_horizontal_flipped(line, u, step, &mut out[done..], FLIP) }
}

/// No faster row copy than `copy_from_slice` (memcpy) here.
pub use super::portable::{add_normal_terms, add_to_columns, bilinear_stretch, copy_row, dot_shifts, mean_4x4, seed_sums, strongest_gradients, take_pieces};

/// Sixteen pixels a step: `pminub`/`pmaxub` for the ranges, `pavgb`
/// (which rounds up, as the halfway reach does) for the reach, `psubusb`
/// for the residues.
#[inline(always)]
pub fn residues<const FULL_K: bool, const FULL_G: bool>(lines: super::ResidueLines, threshold: u8, hot: &mut [u8], ground: &mut [u8]) {
    let super::ResidueLines { row, centre, up, down } = lines;
    let n = lines.len().min(hot.len()).min(ground.len());
    let blocks = n / 16;
    // SAFETY: SSE2 is part of the x86_64 baseline; every access covers 16
    // bytes at c, c + 1 or c + 2 with c + 16 <= n, within slices of n (row,
    // up, down, hot, ground) and n + 2 (centre) bytes.
    unsafe {
        let ones = _mm_set1_epi8(1);
        let threshold16 = _mm_set1_epi8(threshold as i8);
        let load = |slice: &[u8], at: usize| _mm_loadu_si128(slice.as_ptr().add(at).cast());
        for b in 0..blocks {
            let c = 16 * b;
            let (value, left, here, right) = (load(row, c), load(centre, c), load(centre, c + 1), load(centre, c + 2));
            let (along_up, along_down) = (load(up, c), load(down, c));
            let (k_low, k_high) = (_mm_min_epu8(left, right), _mm_max_epu8(left, right));
            let (g_low, g_high) = (_mm_min_epu8(along_up, along_down), _mm_max_epu8(along_up, along_down));
            let wide_low = _mm_min_epu8(here, _mm_min_epu8(k_low, g_low));
            let wide_high = _mm_max_epu8(here, _mm_max_epu8(k_high, g_high));
            let wide = _mm_or_si128(_mm_subs_epu8(value, wide_high), _mm_subs_epu8(wide_low, value));
            let reach = |other: __m128i, full: bool| if full { other } else { _mm_avg_epu8(here, other) };
            let low = _mm_min_epu8(here, _mm_min_epu8(reach(k_low, FULL_K), reach(g_low, FULL_G)));
            let high = _mm_max_epu8(here, _mm_max_epu8(reach(k_high, FULL_K), reach(g_high, FULL_G)));
            let residue = _mm_or_si128(_mm_subs_epu8(value, high), _mm_subs_epu8(low, value));
            _mm_storeu_si128(hot.as_mut_ptr().add(c).cast(), _mm_min_epu8(_mm_subs_epu8(wide, threshold16), ones));
            _mm_storeu_si128(ground.as_mut_ptr().add(c).cast(), residue);
        }
    }
    let c = 16 * blocks;
    portable::residues::<FULL_K, FULL_G>(lines.columns(c..n), threshold, &mut hot[c..n], &mut ground[c..n]);
}

//! aarch64 kernels with NEON, which is baseline there (no runtime
//! detection, which `no_std` could not do anyway): `uabd` for |diff|,
//! summed by widening pairwise adds (`uadalp`), unsigned widening
//! multiply-adds (`umull`, `umlal`) for the bilinear blends, `urhadd` for
//! the residues' halfway reach. Same functions as `portable`, whose
//! versions do the tails. No vector is reinterpreted as lanes of another
//! width: nothing here assumes a byte order.

use super::portable;
use core::arch::aarch64::*;

/// 16-byte blocks whose |diff|s a u16 lane of `uadalp` may sum: each
/// block adds two, at most 510, and 128 * 510 < 2^16.
const BLOCKS_PER_U16: usize = 128;

#[inline]
pub fn sad(a: &[u8], b: &[u8]) -> u32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut done = 0;
    // SAFETY: NEON is baseline on aarch64; every load reads 16 (or 8)
    // bytes inside `a[..n]` and `b[..n]`.
    let total = unsafe {
        let mut acc = vdupq_n_u32(0);
        while done + 16 <= n {
            let end = done + 16 * ((n - done) / 16).min(BLOCKS_PER_U16);
            let mut lanes = vdupq_n_u16(0);
            while done < end {
                let x = vld1q_u8(a.as_ptr().add(done));
                let y = vld1q_u8(b.as_ptr().add(done));
                lanes = vpadalq_u8(lanes, vabdq_u8(x, y));
                done += 16;
            }
            acc = vpadalq_u16(acc, lanes);
        }
        let mut total = vaddvq_u32(acc);
        if done + 8 <= n {
            let x = vld1_u8(a.as_ptr().add(done));
            let y = vld1_u8(b.as_ptr().add(done));
            total += u32::from(vaddlv_u8(vabd_u8(x, y)));
            done += 8;
        }
        total
    };
    total + portable::sad(&a[done..], &b[done..])
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
    // SAFETY: NEON is baseline on aarch64; loads read current[done..done + 16]
    // (<= n) and reference[done + k..done + k + 16] (<= n + N - 1 <= len,
    // checked by the caller `super::sad_shifts`).
    let acc = unsafe {
        let mut acc = [vdupq_n_u32(0); N];
        while done + 16 <= n {
            let end = done + 16 * ((n - done) / 16).min(BLOCKS_PER_U16);
            let mut lanes = [vdupq_n_u16(0); N];
            while done < end {
                let x = vld1q_u8(current.as_ptr().add(done));
                for (k, lanes) in lanes.iter_mut().enumerate() {
                    let y = vld1q_u8(reference.as_ptr().add(done + k));
                    *lanes = vpadalq_u8(*lanes, vabdq_u8(x, y));
                }
                done += 16;
            }
            for (acc, lanes) in acc.iter_mut().zip(lanes) {
                *acc = vpadalq_u16(*acc, lanes);
            }
        }
        acc
    };
    for (k, (sum, acc)) in sums.iter_mut().zip(acc).enumerate() {
        // SAFETY: NEON is baseline on aarch64 (a register-only add).
        *sum += unsafe { vaddvq_u32(acc) } + portable::sad(&current[done..], &reference[done + k..]);
    }
}

/// Neighbouring pixels of flat ground have equal |diff|; with one lane every
/// increment would wait for the previous one's store (as in `sse2`).
pub const HISTOGRAM_LANES: usize = 4;

/// |diff| of 16 pixels at a time, counted into the four lanes in turn.
#[inline]
pub fn diff_histogram(a: &[u8], b: &[u8], lanes: &mut [[u32; 256]; HISTOGRAM_LANES]) {
    portable::diff_histogram_in_four_lanes(a, b, lanes, |at| {
        let mut diffs = [0u8; 16];
        // SAFETY: NEON is baseline on aarch64; loads read a/b[at..at + 16],
        // within both (the caller's promise); the store writes `diffs`.
        unsafe {
            let x = vld1q_u8(a.as_ptr().add(at));
            let y = vld1q_u8(b.as_ptr().add(at));
            vst1q_u8(diffs.as_mut_ptr(), vabdq_u8(x, y));
        }
        diffs
    });
}

/// `p0 * (256 - w) + p1 * w` in u16 lanes (`w` <= 255 in every lane):
/// `p0 << 8`, minus `p0 * w`, plus `p1 * w`, since 256 fits no byte lane.
/// The result is at most 65,280 and no step goes below 0: exact.
#[inline(always)]
fn blend(p0: uint8x8_t, p1: uint8x8_t, w: uint8x8_t) -> uint16x8_t {
    // SAFETY: NEON is part of the aarch64 baseline (register-only operations).
    unsafe { vmlal_u8(vmlsl_u8(vshll_n_u8::<8>(p0), p0, w), p1, w) }
}

/// 16 samples per step: the horizontal blends in u16 lanes (`blend`),
/// the vertical one in u32 lanes (`top * (256 - wy) + bottom * wy` <
/// 2^24), and `urshrn #16` adds 2^15 and shifts: the portable integer.
#[inline]
pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
    let n = out.len().min(upper.len().saturating_sub(1)).min(lower.len().saturating_sub(1));
    let mut done = 0;
    // SAFETY: NEON is baseline on aarch64; loads read upper/lower[done..done + 17]
    // (< n + 1 <= len) and stores write out[done..done + 16] (<= n).
    unsafe {
        let wxv = vdup_n_u8(wx as u8);
        let (ay, wy16) = ((256 - wy) as u16, wy as u16);
        let (pu, pl, po) = (upper.as_ptr(), lower.as_ptr(), out.as_mut_ptr());
        let vertical = |top: uint16x8_t, bottom: uint16x8_t| {
            let low = vmlal_n_u16(vmull_n_u16(vget_low_u16(top), ay), vget_low_u16(bottom), wy16);
            let high = vmlal_high_n_u16(vmull_high_n_u16(top, ay), bottom, wy16);
            // (sum + 2^15) >> 16 <= 255: the narrowing to bytes is exact.
            vmovn_u16(vrshrn_high_n_u32::<16>(vrshrn_n_u32::<16>(low), high))
        };
        while done + 16 <= n {
            let (u0, u1) = (vld1q_u8(pu.add(done)), vld1q_u8(pu.add(done + 1)));
            let (l0, l1) = (vld1q_u8(pl.add(done)), vld1q_u8(pl.add(done + 1)));
            let first = vertical(blend(vget_low_u8(u0), vget_low_u8(u1), wxv), blend(vget_low_u8(l0), vget_low_u8(l1), wxv));
            let second = vertical(blend(vget_high_u8(u0), vget_high_u8(u1), wxv), blend(vget_high_u8(l0), vget_high_u8(l1), wxv));
            vst1q_u8(po.add(done), vcombine_u8(first, second));
            done += 16;
        }
    }
    portable::bilinear_line(&upper[done..], &lower[done..], wx, wy, &mut out[done..n]);
}

// ------------------------------------------------------------ pinhole rows
// The line holds `V` itself, as `portable`'s does: the multiplies here are
// unsigned and widen, so the x86 and M4 kernels' `V ^ FLIP` (for their
// signed 16x16 multiply-adds) would gain nothing, and the tails can be the
// portable functions.

/// 16 columns per step, `blend` at `wy`, stored as two u16 vectors.
#[inline]
pub fn pinhole_vertical(upper: &[u8], lower: &[u8], wy: u32, line: &mut [u16]) {
    let n = line.len().min(upper.len()).min(lower.len());
    let mut done = 0;
    // SAFETY: NEON is baseline on aarch64; loads read upper/lower[done..done + 16]
    // and stores write line[done..done + 16], all <= n.
    unsafe {
        let wyv = vdup_n_u8(wy as u8);
        let (pu, pl, pv) = (upper.as_ptr(), lower.as_ptr(), line.as_mut_ptr());
        while done + 16 <= n {
            let (a, b) = (vld1q_u8(pu.add(done)), vld1q_u8(pl.add(done)));
            vst1q_u16(pv.add(done), blend(vget_low_u8(a), vget_low_u8(b), wyv));
            vst1q_u16(pv.add(done + 8), blend(vget_high_u8(a), vget_high_u8(b), wyv));
            done += 16;
        }
    }
    portable::pinhole_vertical(&upper[done..n], &lower[done..n], wy, &mut line[done..n]);
}

/// Eight pixels per step: the pairs `V[x0]`, `V[x0 + 1]` are gathered by
/// scalar loads (NEON has no gather), the weights `wx` come from the
/// eight u's in u32 lanes, `umull`/`umlal` give `V0 * (256 - wx) + V1 *
/// wx` (< 2^24) and `urshrn #16` adds 2^15 and shifts: `bilinear`'s pixel.
///
/// # Safety
/// Every pixel's `x0 + 1` indexes `line` (see `pinhole::Horizontal`).
#[inline]
pub unsafe fn pinhole_horizontal(line: &[u16], u: i32, step: i32, out: &mut [u8]) {
    let n = out.len();
    let base = line.as_ptr();
    let (mut u, step) = (u as u32, step as u32);
    let mut done = 0;
    // SAFETY: NEON is baseline on aarch64; the caller guarantees each
    // pixel's x0 and x0 + 1 index `line`; the store writes
    // out[done..done + 8] (<= n).
    unsafe {
        let offsets: [u32; 4] = core::array::from_fn(|k| step.wrapping_mul(k as u32));
        let (offsets, step4) = (vld1q_u32(offsets.as_ptr()), vdupq_n_u32(step.wrapping_mul(4)));
        let (byte, c256) = (vdupq_n_u16(0xFF), vdupq_n_u16(256));
        while done + 8 <= n {
            let low_u = vaddq_u32(vdupq_n_u32(u), offsets);
            let high_u = vaddq_u32(low_u, step4);
            // Bits 8..16 of each u.
            let wx = vandq_u16(vcombine_u16(vshrn_n_u32::<8>(low_u), vshrn_n_u32::<8>(high_u)), byte);
            let ax = vsubq_u16(c256, wx);
            let (mut v0, mut v1) = ([0u16; 8], [0u16; 8]);
            for k in 0..8 {
                let x = (u.wrapping_add(step.wrapping_mul(k as u32)) >> 16) as usize;
                (v0[k], v1[k]) = (*base.add(x), *base.add(x + 1));
            }
            let (v0, v1) = (vld1q_u16(v0.as_ptr()), vld1q_u16(v1.as_ptr()));
            let low = vmlal_u16(vmull_u16(vget_low_u16(v0), vget_low_u16(ax)), vget_low_u16(v1), vget_low_u16(wx));
            let high = vmlal_high_u16(vmull_high_u16(v0, ax), v1, wx);
            vst1_u8(out.as_mut_ptr().add(done), vmovn_u16(vrshrn_high_n_u32::<16>(vrshrn_n_u32::<16>(low), high)));
            u = u.wrapping_add(step.wrapping_mul(8));
            done += 8;
        }
    }
    // SAFETY: the caller's contract, for the remaining pixels.
    unsafe { portable::pinhole_horizontal(line, u as i32, step as i32, &mut out[done..]) }
}

/// No faster row copy than `copy_from_slice` (memcpy) here.
pub use super::portable::{add_normal_terms, add_to_columns, bilinear_stretch, copy_row, dot_shifts, mean_4x4, seed_sums, strongest_gradients, take_pieces};

/// Sixteen pixels a step: `umin`/`umax` for the ranges, `urhadd` (which
/// rounds up, as the halfway reach does) for the reach, `uqsub` for the
/// residues.
#[inline(always)]
pub fn residues<const FULL_K: bool, const FULL_G: bool>(lines: super::ResidueLines, threshold: u8, hot: &mut [u8], ground: &mut [u8]) {
    let super::ResidueLines { row, centre, up, down } = lines;
    let n = lines.len().min(hot.len()).min(ground.len());
    let blocks = n / 16;
    // SAFETY: NEON is baseline on aarch64; every access covers 16 bytes at
    // c, c + 1 or c + 2 with c + 16 <= n, within slices of n (row, up,
    // down, hot, ground) and n + 2 (centre) bytes.
    unsafe {
        let ones = vdupq_n_u8(1);
        let threshold16 = vdupq_n_u8(threshold);
        let load = |slice: &[u8], at: usize| vld1q_u8(slice.as_ptr().add(at));
        for b in 0..blocks {
            let c = 16 * b;
            let (value, left, here, right) = (load(row, c), load(centre, c), load(centre, c + 1), load(centre, c + 2));
            let (along_up, along_down) = (load(up, c), load(down, c));
            let (k_low, k_high) = (vminq_u8(left, right), vmaxq_u8(left, right));
            let (g_low, g_high) = (vminq_u8(along_up, along_down), vmaxq_u8(along_up, along_down));
            let wide_low = vminq_u8(here, vminq_u8(k_low, g_low));
            let wide_high = vmaxq_u8(here, vmaxq_u8(k_high, g_high));
            let wide = vorrq_u8(vqsubq_u8(value, wide_high), vqsubq_u8(wide_low, value));
            let reach = |other: uint8x16_t, full: bool| if full { other } else { vrhaddq_u8(here, other) };
            let low = vminq_u8(here, vminq_u8(reach(k_low, FULL_K), reach(g_low, FULL_G)));
            let high = vmaxq_u8(here, vmaxq_u8(reach(k_high, FULL_K), reach(g_high, FULL_G)));
            let residue = vorrq_u8(vqsubq_u8(value, high), vqsubq_u8(low, value));
            vst1q_u8(hot.as_mut_ptr().add(c), vminq_u8(vqsubq_u8(wide, threshold16), ones));
            vst1q_u8(ground.as_mut_ptr().add(c), residue);
        }
    }
    let c = 16 * blocks;
    portable::residues::<FULL_K, FULL_G>(lines.columns(c..n), threshold, &mut hot[c..n], &mut ground[c..n]);
}

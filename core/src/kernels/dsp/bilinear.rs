//! Bilinear lines: the blends two products at a time (`smlad`).

use crate::kernels::portable;

/// Vertical blend first (exact integers, so the same value as the
/// portable horizontal-first order): `V[x] = upper[x] * (256 - wy) +
/// lower[x] * wy` (<= 65,280), then `out[n] = (V[n] * (256 - wx) +
/// V[n + 1] * wx + 2^15) >> 16`. Both steps are `smlad`s with one
/// accumulator constant `K = 2^23 + 2^15`:
/// - vertical: `smlad((u, l), (256 - wy, wy), K)` = `V + K`, whose low
///   halfword is `V + 2^15 mod 2^16`, i.e. `V - 2^15` as an i16 (V < 2^16);
/// - horizontal: `smlad((V[n] - 2^15, V[n + 1] - 2^15), (256 - wx, wx), K)`
///   = `V[n] * (256 - wx) + V[n + 1] * wx - 2^15 * 256 + 2^23 + 2^15`,
///   the portable sum before the shift (< 2^24, so bits 24..31 are zero).
///
/// 4 samples per iteration, 26 instructions; `V` of the last column is
/// carried to the next iteration. The tail (< 4 samples) is portable.
#[inline]
pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
    const K: u32 = (1 << 23) + (1 << 15);
    let n = out.len().min(upper.len().saturating_sub(1)).min(lower.len().saturating_sub(1));
    let words = n / 4;
    if words > 0 {
        let wxs = (256 - wx) | (wx << 16);
        let wys = (256 - wy) | (wy << 16);
        let v0 = u32::from(upper[0]) * (256 - wy) + u32::from(lower[0]) * wy + K;
        // SAFETY: iteration i reads the words upper/lower[4i + 1..4i + 5]
        // (the last ends at 4 * words + 1 <= n + 1 <= len) and writes the
        // word out[4i..4i + 4] (<= n <= out.len()); unaligned ldr/str are
        // fine on the M4. Register arithmetic only otherwise.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {u}, [{pu}], #4",            // bytes u1 u2 u3 u4
                "ldr {l}, [{pl}], #4",
                "pkhbt {a}, {u}, {l}, lsl #16",   // bytes u1 u2 l1 l2
                "pkhtb {b}, {l}, {u}, asr #16",   // bytes u3 u4 l3 l4
                "uxtb16 {u}, {a}",                // (u1, l1)
                "smlad {u}, {u}, {wy}, {k}",      // V1 + K
                "uxtb16 {a}, {a}, ror #8",        // (u2, l2)
                "smlad {a}, {a}, {wy}, {k}",      // V2 + K
                "pkhbt {v}, {v}, {u}, lsl #16",   // (V0, V1) - 2^15
                "smlad {v}, {v}, {wx}, {k}",      // out0 << 16
                "pkhbt {u}, {u}, {a}, lsl #16",   // (V1, V2) - 2^15
                "smlad {u}, {u}, {wx}, {k}",      // out1 << 16
                "uxtb16 {l}, {b}",                // (u3, l3)
                "smlad {l}, {l}, {wy}, {k}",      // V3 + K
                "pkhbt {a}, {a}, {l}, lsl #16",   // (V2, V3) - 2^15
                "smlad {a}, {a}, {wx}, {k}",      // out2 << 16
                "pkhtb {a}, {a}, {v}, asr #16",   // out0 | out2 << 16
                "uxtb16 {b}, {b}, ror #8",        // (u4, l4)
                "smlad {v}, {b}, {wy}, {k}",      // V4 + K: V0 of the next iteration
                "pkhbt {l}, {l}, {v}, lsl #16",   // (V3, V4) - 2^15
                "smlad {l}, {l}, {wx}, {k}",      // out3 << 16
                "pkhtb {l}, {l}, {u}, asr #16",   // out1 | out3 << 16
                "orr {a}, {a}, {l}, lsl #8",
                "str {a}, [{po}], #4",
                "subs {n}, {n}, #1",
                "bne 2b",
                pu = inout(reg) upper[1..].as_ptr() => _, pl = inout(reg) lower[1..].as_ptr() => _,
                po = inout(reg) out.as_mut_ptr() => _, n = inout(reg) words => _,
                v = inout(reg) v0 => _,
                u = out(reg) _, l = out(reg) _, a = out(reg) _, b = out(reg) _,
                wx = in(reg) wxs, wy = in(reg) wys, k = in(reg) K,
                options(nostack)
            );
        }
    }
    let done = 4 * words;
    portable::bilinear_line(&upper[done..], &lower[done..], wx, wy, &mut out[done..n]);
}

/// A sample a step, 22 instructions (the compiled per-pixel loop with
/// its row index took ~27): each row's pair of pixels is one (unaligned)
/// halfword load; packed as `u0 u1 l0 l1` and spread by `uxtb16` into
/// the lanes `(u0, l0)` and `(u1, l1)`, `smuad` with the weights
/// `[256 - wy | wy]` blends each column down (`wy << 16` is the row
/// position masked, less itself shifted down, plus 256: `256 - wy >= 1`
/// never borrows); then across, `((V0 << 8) + (V1 - V0) wx + 2^15) >> 16`,
/// the portable sum in the other order (exact integers, the same value).
#[inline]
pub fn bilinear_stretch(upper: &[u8], lower: &[u8], (i, i_step): (u32, u32), (j, j_step): (u32, u32), out: &mut [u8]) {
    if out.is_empty() {
        return;
    }
    // SAFETY: every step's x + 1 indexes `upper` and `lower` (checked by
    // `kernels::bilinear_stretch`), so the halfwords at x lie inside them;
    // `out.len()` bytes are written; unaligned ldrh is fine on the M4.
    unsafe {
        core::arch::asm!(
            "2:",
            "lsr {t}, {i}, #24",
            "ldrh {a}, [{pu}, {t}]",           // u0 u1
            "ldrh {b}, [{pl}, {t}]",           // l0 l1
            "pkhbt {a}, {a}, {b}, lsl #16",    // u0 u1 l0 l1
            "uxtb16 {b}, {a}, ror #8",         // (u1, l1)
            "uxtb16 {a}, {a}",                 // (u0, l0)
            "and {w}, {j}, #0xFF0000",         // wy << 16
            "sub {w}, {w}, {w}, lsr #16",
            "add {w}, {w}, #256",              // [256 - wy | wy]
            "smuad {a}, {a}, {w}",             // V0
            "smuad {b}, {b}, {w}",             // V1
            "ubfx {w}, {i}, #16, #8",          // wx
            "sub {b}, {b}, {a}",
            "mul {b}, {b}, {w}",
            "add {a}, {b}, {a}, lsl #8",
            "add {a}, {a}, #32768",
            "lsr {a}, {a}, #16",
            "strb {a}, [{po}], #1",
            "add {i}, {i}, {di}",
            "add {j}, {j}, {dj}",
            "subs {n}, {n}, #1",
            "bne 2b",
            pu = in(reg) upper.as_ptr(), pl = in(reg) lower.as_ptr(),
            po = inout(reg) out.as_mut_ptr() => _, n = inout(reg) out.len() => _,
            i = inout(reg) i => _, j = inout(reg) j => _, di = in(reg) i_step, dj = in(reg) j_step,
            t = out(reg) _, a = out(reg) _, b = out(reg) _, w = out(reg) _,
            options(nostack)
        );
    }
}

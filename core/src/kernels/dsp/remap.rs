//! The remap's rows: the pinhole rows (`kernels::pinhole`) and the ring's
//! row copy (`ldm`/`stm`).

use crate::kernels::portable;
use crate::kernels::pinhole::FLIP;

// ------------------------------------------------------------ pinhole rows
// The line holds `V ^ FLIP`: V <= 65,280, so as i16 that is exactly
// `V - 2^15` (`smlad` multiplies signed halves).

/// Four columns per step: a word of each row, split into even and
/// odd bytes as halfword lanes (`uxtb16`). A plain 32-bit `mul` by a
/// weight <= 256 is then two lane products at once: each is at most
/// 255 * 256 = 65,280 < 2^16, so nothing carries into the other lane,
/// and neither does the sum of the two rows' products (same bound).
/// `pkhbt`/`pkhtb` put the lanes back in column order.
pub fn pinhole_vertical(upper: &[u8], lower: &[u8], wy: u32, line: &mut [u16]) {
    let n = line.len().min(upper.len()).min(lower.len());
    let groups = n / 4;
    if groups > 0 {
        // SAFETY: reads `groups` words of `upper` and `lower` (at least
        // 4 * groups bytes each; unaligned ldr is fine on the M4) and
        // writes `groups` pairs of words to `line` (4 * groups halfwords,
        // word aligned: `Line` is align(4) and starts every row at 0).
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {a}, [{pu}], #4",
                "ldr {b}, [{pl}], #4",
                "uxtb16 {t}, {a}",               // [u0 | u2]
                "uxtb16 {a}, {a}, ror #8",       // [u1 | u3]
                "mul {t}, {t}, {ay}",            // [u0 * ay | u2 * ay]
                "mul {a}, {a}, {ay}",
                "uxtb16 {c}, {b}",               // [l0 | l2]
                "uxtb16 {b}, {b}, ror #8",       // [l1 | l3]
                "mla {t}, {c}, {wy}, {t}",       // [V0 | V2]
                "mla {a}, {b}, {wy}, {a}",       // [V1 | V3]
                "pkhbt {c}, {t}, {a}, lsl #16",  // [V0 | V1]
                "pkhtb {a}, {a}, {t}, asr #16",  // [V2 | V3]
                "eor {c}, {c}, #0x80008000",     // V ^ 0x8000 per lane
                "eor {a}, {a}, #0x80008000",
                "strd {c}, {a}, [{pv}], #8",
                "subs {n}, {n}, #1",
                "bne 2b",
                pu = inout(reg) upper.as_ptr() => _,
                pl = inout(reg) lower.as_ptr() => _,
                pv = inout(reg) line.as_mut_ptr() => _,
                n = inout(reg) groups => _,
                ay = in(reg) 256 - wy,
                wy = in(reg) wy,
                a = out(reg) _, b = out(reg) _, t = out(reg) _, c = out(reg) _,
                options(nostack)
            );
        }
    }
    let done = 4 * groups;
    portable::pinhole_vertical_flipped(&upper[done..n], &lower[done..n], wy, &mut line[done..n], FLIP);
}

/// Four pixels per step, 7.5 instructions each: the pair
/// `[V'[x0] | V'[x0 + 1]]` is one (unaligned) word load at byte
/// 2 * x0; the weights `[256 - wx | wx]` are `wx * 0xFFFF + 256`
/// (one `mla`: `(wx << 16) - wx + 256`, and `256 - wx >= 1` never
/// borrows); `smlad` sums `V'0 * (256 - wx) + V'1 * wx` onto
/// `2^23 + 2^15`, which restores the `- 2^15 * 256` of the bias and
/// adds the rounding: the result is `bilinear`'s sum, < 2^24, so the
/// pixel is its bits 16..24 and bits 24..32 are 0. Two pixels' sums
/// `s0`, `s1` go out as one halfword: `pkhtb` makes
/// `[s0 >> 16 | s1 >> 16] = p0 + (p1 << 16)`, and `orr` with itself
/// shifted right by 8 puts `p0 + (p1 << 8)` in the low half.
///
/// # Safety
/// Every pixel's `x0 + 1` indexes `line` (see `pinhole::Horizontal`).
pub unsafe fn pinhole_horizontal(line: &[u16], u: i32, step: i32, out: &mut [u8]) {
    const BIAS: u32 = (1 << 23) + (1 << 15);
    let groups = out.len() / 4;
    let mut u = u;
    if groups > 0 {
        // One pixel's sum into `{acc}`. Written out rather than with
        // `.rept`: LLVM sizes an asm block by its lines, and branches
        // around a block it underestimates can end up out of range.
        macro_rules! pixel {
            ($acc:literal) => {
                concat!(
                    "lsr {t}, {u}, #16\n",            // x0
                    "ldr {t}, [{pv}, {t}, lsl #1]\n", // [V'[x0] | V'[x0 + 1]]
                    "uxtb {w}, {u}, ror #8\n",        // wx
                    "mla {w}, {w}, {k}, {c256}\n",    // [256 - wx | wx]
                    "smlad ", $acc, ", {t}, {w}, {bias}\n",
                    "add {u}, {u}, {step}\n",
                )
            };
        }
        // Two pixels' sums in `{s0}`, `{s1}` out as one halfword.
        macro_rules! pair {
            () => {
                concat!(
                    pixel!("{s0}"),
                    pixel!("{s1}"),
                    "pkhtb {s0}, {s1}, {s0}, asr #16\n",
                    "orr {s0}, {s0}, {s0}, lsr #8\n",
                    "strh {s0}, [{po}], #2\n",
                )
            };
        }
        // SAFETY: the caller guarantees every x0 (and x0 + 1) indexes
        // `line`; writes `4 * groups` bytes of `out` (unaligned strh
        // is fine on the M4).
        unsafe {
            core::arch::asm!(
                "2:",
                pair!(),
                pair!(),
                "subs {n}, {n}, #1",
                "bne 2b",
                u = inout(reg) u,
                po = inout(reg) out.as_mut_ptr() => _,
                n = inout(reg) groups => _,
                step = in(reg) step,
                pv = in(reg) line.as_ptr(),
                k = in(reg) 0xFFFFu32,
                c256 = in(reg) 256u32,
                bias = in(reg) BIAS,
                t = out(reg) _, w = out(reg) _, s0 = out(reg) _, s1 = out(reg) _,
                options(nostack)
            );
        }
    }
    // SAFETY: the caller's contract, for the remaining pixels.
    unsafe { portable::pinhole_horizontal_flipped(line, u, step, &mut out[4 * groups..], FLIP) }
}

/// `dst.copy_from_slice(src)` (same length). That is compiler_builtins'
/// memcpy, ~300 instructions for a 256-pixel row (~900 unaligned); when
/// both ends are word aligned, `ldm`/`stm` of four words takes ~70, else
/// unaligned words ~260.
#[inline]
pub fn copy_row(dst: &mut [u8], src: &[u8]) {
    let blocks = dst.len().min(src.len()) / 16;
    if blocks > 0 && (dst.as_ptr() as usize | src.as_ptr() as usize).is_multiple_of(4) {
        // SAFETY: both pointers are word aligned (ldm/stm need that) and
        // `src`, `dst` hold at least 16 * blocks bytes; fixed registers
        // because an `ldm` list must be in ascending order.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldmia {s}!, {{r2, r3, r4, r5}}",
                "stmia {d}!, {{r2, r3, r4, r5}}",
                "subs {n}, {n}, #1",
                "bne 2b",
                s = inout(reg) src.as_ptr() => _,
                d = inout(reg) dst.as_mut_ptr() => _,
                n = inout(reg) blocks => _,
                out("r2") _, out("r3") _, out("r4") _, out("r5") _,
                options(nostack)
            );
        }
        let done = 16 * blocks;
        dst[done..].copy_from_slice(&src[done..]);
        return;
    }
    // Either end unaligned (a KG row of an odd width into its image): word
    // loads and stores, which the M4 takes unaligned (not `ldm`/`stm`);
    // compiler_builtins' memcpy would go a byte at a time, ~3.5 a byte.
    let words = dst.len().min(src.len()) / 4;
    if words > 0 {
        // SAFETY: `src` and `dst` hold at least 4 * words bytes each;
        // unaligned word accesses are fine on the M4.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {x}, [{s}], #4",
                "str {x}, [{d}], #4",
                "subs {n}, {n}, #1",
                "bne 2b",
                s = inout(reg) src.as_ptr() => _,
                d = inout(reg) dst.as_mut_ptr() => _,
                n = inout(reg) words => _,
                x = out(reg) _,
                options(nostack)
            );
        }
    }
    let done = 4 * words;
    dst[done..].copy_from_slice(&src[done..]);
}

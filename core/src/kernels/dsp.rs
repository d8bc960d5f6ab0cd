//! Cortex-M4/M7 kernels (`thumbv7em`, cfg `flatland_dsp` from build.rs)
//! with the DSP extension through `asm!` (LLVM never emits these):
//! `usada8` adds four absolute differences in one instruction, `usub8` +
//! `sel` compare and select four bytes, `smlad` does the bilinear blends two
//! products at a time, `ldm`/`stm` copy rows. Same functions as `portable`,
//! whose versions do the tails.

use super::pinhole::FLIP;
use super::portable;
use core::ops::Range;

#[inline]
pub fn sad(a: &[u8], b: &[u8]) -> u32 {
    let n = a.len().min(b.len());
    let words = n / 4;
    let mut acc = 0u32;
    if words > 0 {
        // SAFETY: reads `words` words (unaligned ldr is fine on M4) from
        // `a` and `b`, which hold at least 4 * words bytes each.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {x}, [{pa}], #4",
                "ldr {y}, [{pb}], #4",
                "usada8 {acc}, {x}, {y}, {acc}",
                "subs {n}, {n}, #1",
                "bne 2b",
                pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                n = inout(reg) words => _, acc = inout(reg) acc,
                x = out(reg) _, y = out(reg) _,
                options(readonly, nostack)
            );
        }
    }
    acc + portable::sad(&a[4 * words..n], &b[4 * words..n])
}

/// Four columns a step: the hot flags counted by `usada8` against zero
/// and added to the tallies with 16 each in one `add` (no byte carries:
/// tallies stay below 256); the ground residues' bytes widened to
/// halfword pairs (`uxtb16`, `pkhbt`/`pkhtb`) and added two columns at a
/// time (`uadd16`): 19 instructions per 4 columns.
#[inline]
pub fn add_to_columns(hot: &[u8], ground: &[u8], columns: Range<usize>, totals: &mut super::ColumnTotals) -> u32 {
    let (start, end) = (columns.start, columns.end);
    let words = (end - start) / 4;
    let mut hot_pixels = 0u32;
    if words > 0 {
        // SAFETY: the caller (`super::add_to_columns`) keeps `columns`
        // within `hot`, `ground` and the grid (the totals' MAX_GRID_SIDE
        // columns): the `words` words read at `start`, and the totals'
        // words there, lie in them. Unaligned words are fine on the M4.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {h}, [{ph}], #4",
                "ldr {g}, [{pg}], #4",
                "usada8 {count}, {h}, {zero}, {count}",
                "ldr {t}, [{pt}]",
                "orr {h}, {h}, #0x10101010",
                "add {t}, {t}, {h}",
                "str {t}, [{pt}], #4",
                "uxtb16 {h}, {g}",
                "uxtb16 {g}, {g}, ror #8",
                "pkhbt {t}, {h}, {g}, lsl #16",
                "pkhtb {g}, {g}, {h}, asr #16",
                "ldr {h}, [{ps}]",
                "uadd16 {h}, {h}, {t}",
                "str {h}, [{ps}], #4",
                "ldr {h}, [{ps}]",
                "uadd16 {h}, {h}, {g}",
                "str {h}, [{ps}], #4",
                "subs {n}, {n}, #1",
                "bne 2b",
                ph = inout(reg) hot.as_ptr().add(start) => _,
                pg = inout(reg) ground.as_ptr().add(start) => _,
                pt = inout(reg) totals.tallies.as_mut_ptr().add(start) => _,
                ps = inout(reg) totals.ground.as_mut_ptr().add(start) => _,
                n = inout(reg) words => _,
                count = inout(reg) hot_pixels,
                zero = in(reg) 0u32,
                h = out(reg) _, g = out(reg) _, t = out(reg) _,
                options(nostack)
            );
        }
    }
    hot_pixels + portable::add_to_columns(hot, ground, start + 4 * words..end, totals)
}

/// A column a step, a piece's sums packed into one word and stored (7
/// instructions a column, 8 a piece); the last, short piece in `portable`.
#[inline]
pub fn take_pieces(totals: &super::ColumnTotals, px: usize, columns: Range<usize>, pieces: &mut [super::PieceSums]) {
    let (start, width) = (columns.start, columns.end);
    let whole = ((width - start) / px).min(pieces.len());
    if whole > 0 {
        // SAFETY: `whole * px` columns from `start` of the tallies (bytes)
        // and of the ground sums (halfwords) are read, within `columns`,
        // which end at most at MAX_GRID_SIDE (`ColumnTotals::take_pieces`), and `whole` words
        // written to `pieces` (`PieceSums` is a transparent u32).
        unsafe {
            core::arch::asm!(
                "3:",
                "add {end}, {pt}, {px}",
                "movs {tally}, #0",
                "movs {pixels}, #0",
                "movs {sum}, #0",
                "2:",
                "ldrb {t}, [{pt}], #1",
                "add {tally}, {tally}, {t}",
                "add {pixels}, {pixels}, {t}, lsr #4",
                "ldrh {t}, [{pg}], #2",
                "add {sum}, {sum}, {t}",
                "cmp {pt}, {end}",
                "bne 2b",
                "sub {tally}, {tally}, {pixels}, lsl #4",
                "orr {tally}, {tally}, {pixels}, lsl #8",
                "orr {tally}, {tally}, {sum}, lsl #16",
                "str {tally}, [{out}], #4",
                "subs {n}, {n}, #1",
                "bne 3b",
                pt = inout(reg) totals.tallies.as_ptr().add(start) => _,
                pg = inout(reg) totals.ground.as_ptr().add(start) => _,
                out = inout(reg) pieces.as_mut_ptr() => _,
                n = inout(reg) whole => _,
                px = in(reg) px,
                end = out(reg) _, tally = out(reg) _, pixels = out(reg) _, sum = out(reg) _, t = out(reg) _,
                options(nostack)
            );
        }
    }
    portable::take_pieces(totals, px, start + whole * px..width, &mut pieces[whole..]);
}

/// Five shifts (the default ±2 window) per current word: the reference
/// word of shift 4 is the next word's shift 0, so 1 + 4 loads feed
/// 5 `usada8` (12 instructions per 4 pixels and 5 shifts). Other window
/// widths run `sad` per shift.
#[inline]
pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
    let n = current.len();
    let words = n / 4;
    if sums.len() != 5 || words == 0 {
        for (k, sum) in sums.iter_mut().enumerate() {
            *sum += sad(current, &reference[k..]);
        }
        return;
    }
    let mut acc = [0u32; 5];
    // SAFETY: reads `words` words of `current` (4 * words <= n bytes) and
    // reference bytes below 4 * words + 4 <= n + 4 <= reference.len()
    // (checked by `super::sad_shifts`); unaligned ldr is fine on the M4.
    unsafe {
        core::arch::asm!(
            "ldr {r0}, [{pr}]",
            "2:",
            "ldr {c}, [{pc}], #4",
            "usada8 {a0}, {c}, {r0}, {a0}",
            "ldr {t}, [{pr}, #1]",
            "usada8 {a1}, {c}, {t}, {a1}",
            "ldr {t}, [{pr}, #2]",
            "usada8 {a2}, {c}, {t}, {a2}",
            "ldr {t}, [{pr}, #3]",
            "usada8 {a3}, {c}, {t}, {a3}",
            "ldr {r0}, [{pr}, #4]!",          // shift 4 now, shift 0 next word
            "usada8 {a4}, {c}, {r0}, {a4}",
            "subs {n}, {n}, #1",
            "bne 2b",
            pc = inout(reg) current.as_ptr() => _, pr = inout(reg) reference.as_ptr() => _,
            n = inout(reg) words => _,
            c = out(reg) _, t = out(reg) _, r0 = out(reg) _,
            a0 = inout(reg) acc[0], a1 = inout(reg) acc[1], a2 = inout(reg) acc[2],
            a3 = inout(reg) acc[3], a4 = inout(reg) acc[4],
            options(readonly, nostack)
        );
    }
    // At most 3 pixels left: the row's last word, whose leading bytes the
    // loop counted, shifted out of the current and the reference words
    // alike (zeros add nothing), one `usada8` a shift (a byte loop costs
    // ~5 instructions a pixel and shift).
    let left = n - 4 * words;
    if left > 0 {
        let shift = 8 * (4 - left) as u32;
        // SAFETY: n >= 4 here, and the last word of shift k ends at
        // n + k <= n + 4 <= reference.len() (see above).
        let word = |bytes: &[u8], end: usize| unsafe { bytes.as_ptr().add(end - 4).cast::<u32>().read_unaligned() } >> shift;
        let last = word(current, n);
        for (k, acc) in acc.iter_mut().enumerate() {
            *acc = usada8(last, word(reference, n + k), *acc);
        }
    }
    for (sum, acc) in sums.iter_mut().zip(acc) {
        *sum += acc;
    }
}

/// `acc` plus the |differences| of the four bytes of `a` and `b`.
#[inline(always)]
fn usada8(a: u32, b: u32, acc: u32) -> u32 {
    let sum;
    // SAFETY: register arithmetic only.
    unsafe { core::arch::asm!("usada8 {s}, {a}, {b}, {acc}", s = lateout(reg) sum, a = in(reg) a, b = in(reg) b, acc = in(reg) acc, options(pure, nomem, nostack)) };
    sum
}

/// Four pixels a step: |diff| by `usub8`/`sel`; the bytes above each
/// level made 0xFF (`uqsub8` the level, `usub8` from 0, `sel`), the
/// differences above 30 kept by that mask and summed, the 0xFF bytes
/// above 50 summed (255 a pixel) by `usada8` (16 instructions per 4).
#[inline]
pub fn seed_sums(a: &[u8], b: &[u8]) -> (u32, u32) {
    let words = a.len().min(b.len()) / 4;
    let (mut sum, mut above) = (0u32, 0u32);
    if words > 0 {
        // SAFETY: reads `words` words of `a` and `b` (at least 4 * words
        // bytes each); unaligned words are fine on the M4.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {x}, [{pa}], #4",
                "ldr {y}, [{pb}], #4",
                "usub8 {t}, {x}, {y}",
                "usub8 {y}, {y}, {x}",
                "sel {x}, {y}, {t}",
                "uqsub8 {t}, {x}, {sum_level}",
                "usub8 {t}, {zero}, {t}",
                "sel {t}, {zero}, {bytes}",
                "and {t}, {t}, {x}",
                "usada8 {sum}, {t}, {zero}, {sum}",
                "uqsub8 {t}, {x}, {count_level}",
                "usub8 {t}, {zero}, {t}",
                "sel {t}, {zero}, {bytes}",
                "usada8 {above}, {t}, {zero}, {above}",
                "subs {n}, {n}, #1",
                "bne 2b",
                pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                n = inout(reg) words => _,
                sum = inout(reg) sum, above = inout(reg) above,
                zero = in(reg) 0u32, bytes = in(reg) u32::MAX,
                sum_level = in(reg) u32::from(super::SUM_LEVEL) * 0x0101_0101,
                count_level = in(reg) u32::from(super::COUNT_LEVEL) * 0x0101_0101,
                x = out(reg) _, y = out(reg) _, t = out(reg) _,
                options(nostack, readonly)
            );
        }
    }
    let (tail_sum, tail_count) = portable::seed_sums(&a[4 * words..], &b[4 * words..]);
    (sum.wrapping_add(tail_sum), (above / 255).wrapping_add(tail_count))
}

/// One lane: the M4 has no store-to-load stall to hide (1 KB).
pub const HISTOGRAM_LANES: usize = 1;

/// |diff| of four pixels with `usub8`/`sel` (the GE flags must survive
/// from `usub8` to `sel`, hence one `asm!` block), then four increments.
#[inline]
pub fn diff_histogram(a: &[u8], b: &[u8], lanes: &mut [[u32; 256]; HISTOGRAM_LANES]) {
    let [histogram] = &mut *lanes;
    let n = a.len().min(b.len());
    let words = n / 4;
    if words > 0 {
        // SAFETY: reads `words` words of `a` and `b` (at least 4 * words
        // bytes each); every index is a byte (< 256) into `histogram`.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {x}, [{pa}], #4",
                "ldr {y}, [{pb}], #4",
                "usub8 {t}, {x}, {y}",            // GE[i] = x >= y
                "usub8 {y}, {y}, {x}",            // GE[i] = y >= x
                "sel {x}, {y}, {t}",              // x = |x - y| per byte
                "uxtb {t}, {x}",
                "ldr {y}, [{h}, {t}, lsl #2]",
                "add {y}, {y}, #1",
                "str {y}, [{h}, {t}, lsl #2]",
                "uxtb {t}, {x}, ror #8",
                "ldr {y}, [{h}, {t}, lsl #2]",
                "add {y}, {y}, #1",
                "str {y}, [{h}, {t}, lsl #2]",
                "uxtb {t}, {x}, ror #16",
                "ldr {y}, [{h}, {t}, lsl #2]",
                "add {y}, {y}, #1",
                "str {y}, [{h}, {t}, lsl #2]",
                "lsr {t}, {x}, #24",
                "ldr {y}, [{h}, {t}, lsl #2]",
                "add {y}, {y}, #1",
                "str {y}, [{h}, {t}, lsl #2]",
                "subs {n}, {n}, #1",
                "bne 2b",
                pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                n = inout(reg) words => _, h = in(reg) histogram.as_mut_ptr(),
                x = out(reg) _, y = out(reg) _, t = out(reg) _,
                options(nostack)
            );
        }
    }
    portable::diff_histogram(&a[4 * words..n], &b[4 * words..n], lanes);
}

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
    // `super::bilinear_stretch`), so the halfwords at x lie inside them;
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

/// `usada8` against zero sums a word's four bytes: one per row and output
/// pixel, 4 loads + 4 `usada8` per 16 pixels, 13 instructions (the plain loop takes ~10 a pixel).
#[inline]
pub fn mean_4x4(rows: [&[u8]; 4], out: &mut [u8]) {
    let n = out.len();
    if n == 0 {
        return;
    }
    // SAFETY: reads `n` words (unaligned ldr is fine on the M4) from each
    // row, which hold at least 4 * n bytes (checked by `super::mean_4x4`),
    // and writes `n` bytes of `out`.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldr {x}, [{r0}], #4",
            "usad8 {s}, {x}, {zero}",
            "ldr {x}, [{r1}], #4",
            "usada8 {s}, {x}, {zero}, {s}",
            "ldr {x}, [{r2}], #4",
            "usada8 {s}, {x}, {zero}, {s}",
            "ldr {x}, [{r3}], #4",
            "usada8 {s}, {x}, {zero}, {s}",
            "adds {s}, {s}, #8",
            "lsrs {s}, {s}, #4",
            "strb {s}, [{o}], #1",
            "subs {n}, {n}, #1",
            "bne 2b",
            r0 = inout(reg) rows[0].as_ptr() => _, r1 = inout(reg) rows[1].as_ptr() => _,
            r2 = inout(reg) rows[2].as_ptr() => _, r3 = inout(reg) rows[3].as_ptr() => _,
            o = inout(reg) out.as_mut_ptr() => _, n = inout(reg) n => _,
            zero = in(reg) 0u32,
            x = out(reg) _, s = out(reg) _,
            options(nostack)
        );
    }
}

/// The choice's strides (1 and 2) as immediates; others are portable.
#[inline]
pub fn strongest_gradients(rows: super::GradientRows, row: u8, columns: core::ops::Range<usize>, side: usize, stride: usize, strongest: &mut [super::Strongest]) {
    match stride {
        1 => strongest_gradients_by::<1>(rows, row, columns, side, strongest),
        2 => strongest_gradients_by::<2>(rows, row, columns, side, strongest),
        _ => portable::strongest_gradients(rows, row, columns, side, stride, strongest),
    }
}

/// The row's blocks in one `asm!` block, a column a step in registers (10
/// instructions a column, ~12 a block; the compiled loops took ~35 and
/// ~50). One pointer walks the row, post-incremented by the last load, and
/// reaches the rows above and below at fixed offsets; the block's side and
/// the row's end wait on the stack. `usad8` of two bytes is their
/// |difference| and `usada8` adds the other axis's; a new maximum, a branch
/// seldom taken, is stored at once as the block's word: strength, then
/// (column, row) from the pointer plus a constant of the row.
#[inline(always)]
fn strongest_gradients_by<const STRIDE: usize>(rows: super::GradientRows, row: u8, columns: core::ops::Range<usize>, side: usize, strongest: &mut [super::Strongest]) {
    let super::GradientRows { up, row: pixels, down } = rows;
    let first_block = columns.start / side;
    // `left` points at pixels[i - 1] of column i, so column i's pixel
    // above is at `left + up - pixels + 1`, likewise below; after its
    // column's last load it has stepped to `pixels + i - 1 + STRIDE`.
    let left = |i: usize| pixels.as_ptr().wrapping_add(i).wrapping_sub(1);
    let offset_to = |line: &[u8]| (line.as_ptr() as u32).wrapping_sub(pixels.as_ptr() as u32).wrapping_add(1);
    // Strength s found with `left` stepped to p: the block's word
    // s | column << 16 | row << 24 is s + (p << 16) + this (mod 2^32).
    let stepped_to_word = (u32::from(row) << 24).wrapping_add((1u32.wrapping_sub(STRIDE as u32).wrapping_sub(pixels.as_ptr() as u32)) << 16);
    // SAFETY: reads pixels[i - 1], pixels[i + 1], up[i] and down[i] at the
    // visited columns i of `columns`, which `super::strongest_gradients`
    // keeps from 1 and below the rows' common width less 1, and writes
    // strongest[i / side] (kept below strongest.len() * side); pushes 8
    // bytes and pops them.
    unsafe {
        core::arch::asm!(
            "str {right}, [sp, #-8]!",
            "str {end}, [sp, #4]",
            "3:",
            "ldrh {most}, [{block}]",
            "ldr {end}, [sp, #4]",
            "cmp {next_block}, {end}",
            "it lo",
            "movlo {end}, {next_block}",
            "2:",
            "ldrb {right}, [{left}, #2]",
            "ldrb {strength}, [{left}, {below}]",
            "ldrb {previous}, [{left}, {above}]",
            "usad8 {strength}, {strength}, {previous}",
            "ldrb {previous}, [{left}], #{stride}",
            "usada8 {strength}, {right}, {previous}, {strength}",
            "cmp {strength}, {most}",
            "bls 4f",
            "mov {most}, {strength}",
            "add {previous}, {strength}, {stepped_to_word}",
            "add {previous}, {previous}, {left}, lsl #16",
            "str {previous}, [{block}]",
            "4:",
            "cmp {left}, {end}",
            "blo 2b",
            "adds {block}, {block}, #4",
            "mov {left}, {next_block}",
            "ldr {right}, [sp]",
            "add {next_block}, {next_block}, {right}",
            "ldr {end}, [sp, #4]",
            "cmp {left}, {end}",
            "blo 3b",
            "add sp, sp, #8",
            left = inout(reg) left(columns.start) => _,
            next_block = inout(reg) left((first_block + 1) * side) => _,
            end = inout(reg) left(columns.end) => _,
            // The side until it is on the stack, then pixels[i + 1].
            right = inout(reg) side => _,
            block = inout(reg) strongest[first_block..].as_mut_ptr() => _,
            below = in(reg) offset_to(down), above = in(reg) offset_to(up),
            stepped_to_word = in(reg) stepped_to_word,
            most = out(reg) _, previous = out(reg) _, strength = out(reg) _,
            stride = const STRIDE,
        );
    }
}

// ------------------------------------------------------- normal equations

/// The 54 sums do not fit the FPU's 32 registers (the compiler's loop
/// spills them every term, ~200 instructions a term): three passes over
/// the terms, rows 0-2, 3-5 and 6-8 of `h` with their `g`, each with its
/// sums in registers (~95 instructions a term in all). `vmla` rounds its
/// product as `*h += wa * jb` does, so the sums are the plain loop's.
/// `asm!` takes no FPU register on this target, so each pass saves and
/// restores the ones it uses.
#[inline]
pub fn add_normal_terms(terms: &[super::NormalTerm], h: &mut [[f32; super::NORMAL_UNKNOWNS]; super::NORMAL_UNKNOWNS], g: &mut [f32; super::NORMAL_UNKNOWNS]) {
    let n = terms.len();
    if n == 0 {
        return;
    }
    // A term: weight +0, residual +4, brightness +8, jacobian pointer +12.
    const _: () = assert!(core::mem::size_of::<super::NormalTerm>() == 16);
    let (h, g) = (h.as_mut_ptr().cast::<f32>(), g.as_mut_ptr());
    // SAFETY (all three): reads `n` 16-byte terms and the 7 floats each
    // points to; reads and writes the upper triangle of `h` (81 floats,
    // row-major) and `g` (9) at the offsets named; s0-s31 saved and restored.
    unsafe {
        // Rows 0-2: h[0][0..9] s0-s8, h[1][1..9] s9-s16, h[2][2..9] s17-s23,
        // g[0..3] s24-s26; w j0, w j1, w j2 in s27-s29.
        core::arch::asm!(
            "vpush {{d0-d15}}",
            "vldmia {h}, {{s0-s8}}",
            "add {t}, {h}, #40",
            "vldmia {t}, {{s9-s16}}",
            "add {t}, {h}, #80",
            "vldmia {t}, {{s17-s23}}",
            "vldmia {g}, {{s24-s26}}",
            "2:",
            "vldr s31, [{term}]",
            "ldr {t}, [{term}, #12]",
            "vldr s30, [{t}]",
            "vmul.f32 s27, s31, s30",
            "vmla.f32 s0, s27, s30",
            "vldr s30, [{t}, #4]",
            "vmul.f32 s28, s31, s30",
            "vmla.f32 s1, s27, s30",
            "vmla.f32 s9, s28, s30",
            "vldr s30, [{t}, #8]",
            "vmul.f32 s29, s31, s30",
            "vmla.f32 s2, s27, s30",
            "vmla.f32 s10, s28, s30",
            "vmla.f32 s17, s29, s30",
            "vldr s30, [{t}, #12]",
            "vmla.f32 s3, s27, s30",
            "vmla.f32 s11, s28, s30",
            "vmla.f32 s18, s29, s30",
            "vldr s30, [{t}, #16]",
            "vmla.f32 s4, s27, s30",
            "vmla.f32 s12, s28, s30",
            "vmla.f32 s19, s29, s30",
            "vldr s30, [{t}, #20]",
            "vmla.f32 s5, s27, s30",
            "vmla.f32 s13, s28, s30",
            "vmla.f32 s20, s29, s30",
            "vldr s30, [{t}, #24]",
            "vmla.f32 s6, s27, s30",
            "vmla.f32 s14, s28, s30",
            "vmla.f32 s21, s29, s30",
            "vldr s30, [{term}, #8]",
            "vmla.f32 s7, s27, s30",
            "vmla.f32 s15, s28, s30",
            "vmla.f32 s22, s29, s30",
            "vadd.f32 s8, s8, s27",
            "vadd.f32 s16, s16, s28",
            "vadd.f32 s23, s23, s29",
            "vldr s31, [{term}, #4]",
            "vmla.f32 s24, s27, s31",
            "vmla.f32 s25, s28, s31",
            "vmla.f32 s26, s29, s31",
            "adds {term}, #16",
            "subs {n}, #1",
            "bne 2b",
            "vstmia {g}, {{s24-s26}}",
            "add {t}, {h}, #80",
            "vstmia {t}, {{s17-s23}}",
            "add {t}, {h}, #40",
            "vstmia {t}, {{s9-s16}}",
            "vstmia {h}, {{s0-s8}}",
            "vpop {{d0-d15}}",
            h = in(reg) h, g = in(reg) g,
            term = inout(reg) terms.as_ptr() => _, n = inout(reg) n => _,
            t = out(reg) _,
            options(nostack)
        );
        // Rows 3-5: h[3][3..9] s0-s5, h[4][4..9] s6-s10, h[5][5..9] s11-s14,
        // g[3..6] s15-s17; w j3, w j4, w j5 in s18-s20.
        core::arch::asm!(
            "vpush {{d0-d15}}",
            "add {t}, {h}, #120",
            "vldmia {t}, {{s0-s5}}",
            "add {t}, {h}, #160",
            "vldmia {t}, {{s6-s10}}",
            "add {t}, {h}, #200",
            "vldmia {t}, {{s11-s14}}",
            "add {t}, {g}, #12",
            "vldmia {t}, {{s15-s17}}",
            "2:",
            "vldr s31, [{term}]",
            "ldr {t}, [{term}, #12]",
            "vldr s30, [{t}, #12]",
            "vmul.f32 s18, s31, s30",
            "vmla.f32 s0, s18, s30",
            "vldr s30, [{t}, #16]",
            "vmul.f32 s19, s31, s30",
            "vmla.f32 s1, s18, s30",
            "vmla.f32 s6, s19, s30",
            "vldr s30, [{t}, #20]",
            "vmul.f32 s20, s31, s30",
            "vmla.f32 s2, s18, s30",
            "vmla.f32 s7, s19, s30",
            "vmla.f32 s11, s20, s30",
            "vldr s30, [{t}, #24]",
            "vmla.f32 s3, s18, s30",
            "vmla.f32 s8, s19, s30",
            "vmla.f32 s12, s20, s30",
            "vldr s30, [{term}, #8]",
            "vmla.f32 s4, s18, s30",
            "vmla.f32 s9, s19, s30",
            "vmla.f32 s13, s20, s30",
            "vadd.f32 s5, s5, s18",
            "vadd.f32 s10, s10, s19",
            "vadd.f32 s14, s14, s20",
            "vldr s31, [{term}, #4]",
            "vmla.f32 s15, s18, s31",
            "vmla.f32 s16, s19, s31",
            "vmla.f32 s17, s20, s31",
            "adds {term}, #16",
            "subs {n}, #1",
            "bne 2b",
            "add {t}, {g}, #12",
            "vstmia {t}, {{s15-s17}}",
            "add {t}, {h}, #200",
            "vstmia {t}, {{s11-s14}}",
            "add {t}, {h}, #160",
            "vstmia {t}, {{s6-s10}}",
            "add {t}, {h}, #120",
            "vstmia {t}, {{s0-s5}}",
            "vpop {{d0-d15}}",
            h = in(reg) h, g = in(reg) g,
            term = inout(reg) terms.as_ptr() => _, n = inout(reg) n => _,
            t = out(reg) _,
            options(nostack)
        );
        // Rows 6-8: h[6][6..9] s0-s2, h[7][7..9] s3-s4, h[8][8] s5, g[6..9]
        // s6-s8; w j6, w j7 in s9-s10 (w j8 is w).
        core::arch::asm!(
            "vpush {{d0-d15}}",
            "add {t}, {h}, #240",
            "vldmia {t}, {{s0-s2}}",
            "add {t}, {h}, #280",
            "vldmia {t}, {{s3-s4}}",
            "add {t}, {h}, #320",
            "vldr s5, [{t}]",
            "add {t}, {g}, #24",
            "vldmia {t}, {{s6-s8}}",
            "2:",
            "vldr s31, [{term}]",
            "ldr {t}, [{term}, #12]",
            "vldr s30, [{t}, #24]",
            "vmul.f32 s9, s31, s30",
            "vmla.f32 s0, s9, s30",
            "vldr s30, [{term}, #8]",
            "vmul.f32 s10, s31, s30",
            "vmla.f32 s1, s9, s30",
            "vmla.f32 s3, s10, s30",
            "vadd.f32 s2, s2, s9",
            "vadd.f32 s4, s4, s10",
            "vadd.f32 s5, s5, s31",
            "vldr s30, [{term}, #4]",
            "vmla.f32 s6, s9, s30",
            "vmla.f32 s7, s10, s30",
            "vmla.f32 s8, s31, s30",
            "adds {term}, #16",
            "subs {n}, #1",
            "bne 2b",
            "add {t}, {g}, #24",
            "vstmia {t}, {{s6-s8}}",
            "add {t}, {h}, #320",
            "vstr s5, [{t}]",
            "add {t}, {h}, #280",
            "vstmia {t}, {{s3-s4}}",
            "add {t}, {h}, #240",
            "vstmia {t}, {{s0-s2}}",
            "vpop {{d0-d15}}",
            h = in(reg) h, g = in(reg) g,
            term = inout(reg) terms.as_ptr() => _, n = inout(reg) n => _,
            t = out(reg) _,
            options(nostack)
        );
    }
}

// ------------------------------------------------------- block matching

/// Per shift, four pairs (eight products) per iteration: `ldrd` two block
/// words (the packed row is word aligned), `ldr` the patch's halfword
/// pairs (unaligned at odd shifts, fine on the M4), `smlad` two products
/// each (12 instructions per 8 products). The tail (< 4 pairs) is portable.
#[inline]
pub fn dot_shifts(pairs: &[u32], patch: &[u16], sums: &mut [u32]) {
    if let (Ok(pairs), Ok(seven)) = (<&[u32; 8]>::try_from(pairs), <&mut [u32; 7]>::try_from(&mut *sums)) {
        if patch.len() >= 22 {
            dot_seven_shifts(pairs, patch, seven);
            return;
        }
    }
    let quads = pairs.len() / 4;
    let done = 4 * quads;
    for (k, sum) in sums.iter_mut().enumerate() {
        let mut acc = *sum;
        if quads > 0 {
            // SAFETY: reads the 4 * quads words of `pairs` and the
            // 8 * quads halfwords of patch[k..] (within `patch`: checked
            // by `super::dot_shifts`); register arithmetic otherwise.
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldrd {b0}, {b1}, [{pb}], #8",
                    "ldr {p0}, [{pp}], #4",
                    "ldr {p1}, [{pp}], #4",
                    "smlad {acc}, {b0}, {p0}, {acc}",
                    "smlad {acc}, {b1}, {p1}, {acc}",
                    "ldrd {b0}, {b1}, [{pb}], #8",
                    "ldr {p0}, [{pp}], #4",
                    "ldr {p1}, [{pp}], #4",
                    "smlad {acc}, {b0}, {p0}, {acc}",
                    "smlad {acc}, {b1}, {p1}, {acc}",
                    "subs {n}, {n}, #1",
                    "bne 2b",
                    pb = inout(reg) pairs.as_ptr() => _, pp = inout(reg) patch[k..].as_ptr() => _,
                    n = inout(reg) quads => _, acc = inout(reg) acc,
                    b0 = out(reg) _, b1 = out(reg) _, p0 = out(reg) _, p1 = out(reg) _,
                    options(readonly, nostack)
                );
            }
        }
        let mut tail = [acc];
        portable::dot_shifts(&pairs[done..], &patch[k + 2 * done..], &mut tail);
        *sum = tail[0];
    }
}

/// [`dot_shifts`] for a 16-pixel block row and 7 shifts, the block
/// matcher's every call: the seven sums stay in registers, the block words
/// are loaded two at a time, and each patch word serves both: word m's
/// shift k reads the patch at 2k + 4m bytes, which is word m + 1's shift
/// k - 2 (per two block words 1 + 9 loads and 14 `smlad`, against 2 + 14
/// and 14 a word at a time).
#[inline]
/// `patch` holds at least 22 values (the caller checks).
fn dot_seven_shifts(pairs: &[u32; 8], patch: &[u16], sums: &mut [u32; 7]) {
    let [mut a0, mut a1, mut a2, mut a3, mut a4, mut a5, mut a6] = *sums;
    // SAFETY: reads the 8 words of `pairs` (word aligned, for `ldrd`) and
    // halfwords 0..22 of `patch` (the last word read starts at byte
    // 8 * 3 + 2 * 8 = 40: halfwords 20 and 21), unaligned word loads being
    // fine on the M4; register arithmetic otherwise.
    unsafe {
        core::arch::asm!(
            "ldrd {b0}, {b1}, [{pb}, #0]",
            "ldr {p}, [{pp}, #0]",
            "smlad {a0}, {b0}, {p}, {a0}",
            "ldr {p}, [{pp}, #2]",
            "smlad {a1}, {b0}, {p}, {a1}",
            "ldr {p}, [{pp}, #4]",
            "smlad {a2}, {b0}, {p}, {a2}",
            "smlad {a0}, {b1}, {p}, {a0}",
            "ldr {p}, [{pp}, #6]",
            "smlad {a3}, {b0}, {p}, {a3}",
            "smlad {a1}, {b1}, {p}, {a1}",
            "ldr {p}, [{pp}, #8]",
            "smlad {a4}, {b0}, {p}, {a4}",
            "smlad {a2}, {b1}, {p}, {a2}",
            "ldr {p}, [{pp}, #10]",
            "smlad {a5}, {b0}, {p}, {a5}",
            "smlad {a3}, {b1}, {p}, {a3}",
            "ldr {p}, [{pp}, #12]",
            "smlad {a6}, {b0}, {p}, {a6}",
            "smlad {a4}, {b1}, {p}, {a4}",
            "ldr {p}, [{pp}, #14]",
            "smlad {a5}, {b1}, {p}, {a5}",
            "ldr {p}, [{pp}, #16]",
            "smlad {a6}, {b1}, {p}, {a6}",
            "ldrd {b0}, {b1}, [{pb}, #8]",
            "ldr {p}, [{pp}, #8]",
            "smlad {a0}, {b0}, {p}, {a0}",
            "ldr {p}, [{pp}, #10]",
            "smlad {a1}, {b0}, {p}, {a1}",
            "ldr {p}, [{pp}, #12]",
            "smlad {a2}, {b0}, {p}, {a2}",
            "smlad {a0}, {b1}, {p}, {a0}",
            "ldr {p}, [{pp}, #14]",
            "smlad {a3}, {b0}, {p}, {a3}",
            "smlad {a1}, {b1}, {p}, {a1}",
            "ldr {p}, [{pp}, #16]",
            "smlad {a4}, {b0}, {p}, {a4}",
            "smlad {a2}, {b1}, {p}, {a2}",
            "ldr {p}, [{pp}, #18]",
            "smlad {a5}, {b0}, {p}, {a5}",
            "smlad {a3}, {b1}, {p}, {a3}",
            "ldr {p}, [{pp}, #20]",
            "smlad {a6}, {b0}, {p}, {a6}",
            "smlad {a4}, {b1}, {p}, {a4}",
            "ldr {p}, [{pp}, #22]",
            "smlad {a5}, {b1}, {p}, {a5}",
            "ldr {p}, [{pp}, #24]",
            "smlad {a6}, {b1}, {p}, {a6}",
            "ldrd {b0}, {b1}, [{pb}, #16]",
            "ldr {p}, [{pp}, #16]",
            "smlad {a0}, {b0}, {p}, {a0}",
            "ldr {p}, [{pp}, #18]",
            "smlad {a1}, {b0}, {p}, {a1}",
            "ldr {p}, [{pp}, #20]",
            "smlad {a2}, {b0}, {p}, {a2}",
            "smlad {a0}, {b1}, {p}, {a0}",
            "ldr {p}, [{pp}, #22]",
            "smlad {a3}, {b0}, {p}, {a3}",
            "smlad {a1}, {b1}, {p}, {a1}",
            "ldr {p}, [{pp}, #24]",
            "smlad {a4}, {b0}, {p}, {a4}",
            "smlad {a2}, {b1}, {p}, {a2}",
            "ldr {p}, [{pp}, #26]",
            "smlad {a5}, {b0}, {p}, {a5}",
            "smlad {a3}, {b1}, {p}, {a3}",
            "ldr {p}, [{pp}, #28]",
            "smlad {a6}, {b0}, {p}, {a6}",
            "smlad {a4}, {b1}, {p}, {a4}",
            "ldr {p}, [{pp}, #30]",
            "smlad {a5}, {b1}, {p}, {a5}",
            "ldr {p}, [{pp}, #32]",
            "smlad {a6}, {b1}, {p}, {a6}",
            "ldrd {b0}, {b1}, [{pb}, #24]",
            "ldr {p}, [{pp}, #24]",
            "smlad {a0}, {b0}, {p}, {a0}",
            "ldr {p}, [{pp}, #26]",
            "smlad {a1}, {b0}, {p}, {a1}",
            "ldr {p}, [{pp}, #28]",
            "smlad {a2}, {b0}, {p}, {a2}",
            "smlad {a0}, {b1}, {p}, {a0}",
            "ldr {p}, [{pp}, #30]",
            "smlad {a3}, {b0}, {p}, {a3}",
            "smlad {a1}, {b1}, {p}, {a1}",
            "ldr {p}, [{pp}, #32]",
            "smlad {a4}, {b0}, {p}, {a4}",
            "smlad {a2}, {b1}, {p}, {a2}",
            "ldr {p}, [{pp}, #34]",
            "smlad {a5}, {b0}, {p}, {a5}",
            "smlad {a3}, {b1}, {p}, {a3}",
            "ldr {p}, [{pp}, #36]",
            "smlad {a6}, {b0}, {p}, {a6}",
            "smlad {a4}, {b1}, {p}, {a4}",
            "ldr {p}, [{pp}, #38]",
            "smlad {a5}, {b1}, {p}, {a5}",
            "ldr {p}, [{pp}, #40]",
            "smlad {a6}, {b1}, {p}, {a6}",
            pb = in(reg) pairs.as_ptr(), pp = in(reg) patch.as_ptr(),
            b0 = out(reg) _, b1 = out(reg) _, p = out(reg) _,
            a0 = inout(reg) a0, a1 = inout(reg) a1, a2 = inout(reg) a2, a3 = inout(reg) a3,
            a4 = inout(reg) a4, a5 = inout(reg) a5, a6 = inout(reg) a6,
            options(readonly, nostack, preserves_flags)
        );
    }
    *sums = [a0, a1, a2, a3, a4, a5, a6];
}

// ------------------------------------------------------ coarse search

/// Two cells a word: `usub16` both ways and `sel` give |a - b| per lane;
/// a lane's bit 15 in `a | b` marks an unseen cell (seen values are below
/// 2^15), which becomes a lane mask that clears its difference and a lane
/// count of the seen ones; `smlad` by (1, 1) adds the two differences.
/// 12 instructions per two cells. The odd last cell is portable.
#[inline]
pub fn seen_difference(a: &[u16], b: &[u16]) -> (u32, u32) {
    let n = a.len().min(b.len());
    let words = n / 2;
    let (mut sum, mut lanes) = (0u32, 0u32);
    if words > 0 {
        // SAFETY: reads `words` words of `a` and of `b` (2 * words <= n
        // halfwords of each; unaligned word loads are fine on the M4);
        // register arithmetic otherwise. Each lane of `lanes` counts at
        // most `words` < 2^16 cells.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {x}, [{pa}], #4",
                "ldr {y}, [{pb}], #4",
                "usub16 {d}, {x}, {y}",
                "usub16 {e}, {y}, {x}",          // GE per lane: y >= x
                "sel {d}, {e}, {d}",             // |x - y| per lane
                "orr {x}, {x}, {y}",
                "and {x}, {ones}, {x}, lsr #15", // 1 per unseen lane
                "rsb {e}, {x}, {x}, lsl #16",    // 0xFFFF per unseen lane
                "bic {d}, {d}, {e}",
                "eor {x}, {x}, {ones}",          // 1 per seen lane
                "smlad {sum}, {d}, {ones}, {sum}",
                "uadd16 {lanes}, {lanes}, {x}",
                "subs {n}, {n}, #1",
                "bne 2b",
                pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                n = inout(reg) words => _, ones = in(reg) 0x0001_0001u32,
                sum = inout(reg) sum, lanes = inout(reg) lanes,
                x = out(reg) _, y = out(reg) _, d = out(reg) _, e = out(reg) _,
                options(readonly, nostack)
            );
        }
    }
    let (tail_sum, tail_count) = portable::seen_difference(&a[2 * words..n], &b[2 * words..n]);
    (sum + tail_sum, (lanes & 0xFFFF) + (lanes >> 16) + tail_count)
}

// ------------------------------------------------------ tolerant residue

/// Per byte: (max(a, b), min(a, b)): `usub8` sets a GE flag per byte where
/// a >= b, and `sel` picks by them.
#[inline(always)]
fn max_min(a: u32, b: u32) -> (u32, u32) {
    let (max, min);
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!(
            "usub8 {t}, {a}, {b}",
            "sel {max}, {a}, {b}",
            "sel {min}, {b}, {a}",
            a = in(reg) a, b = in(reg) b, t = out(reg) _, max = out(reg) max, min = out(reg) min,
            options(pure, nomem, nostack)
        );
    }
    (max, min)
}

/// Per byte: max(a, b), or with `MIN` min(a, b) (`usub8` + one `sel`).
#[inline(always)]
fn extreme<const MIN: bool>(a: u32, b: u32) -> u32 {
    let (first, second) = if MIN { (b, a) } else { (a, b) };
    let picked;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!(
            "usub8 {t}, {a}, {b}",
            "sel {picked}, {first}, {second}",
            a = in(reg) a, b = in(reg) b, first = in(reg) first, second = in(reg) second, t = out(reg) _, picked = lateout(reg) picked,
            options(pure, nomem, nostack)
        );
    }
    picked
}

/// Per byte: a - b, or 0 below.
#[inline(always)]
fn saturating_sub(a: u32, b: u32) -> u32 {
    let difference;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!("uqsub8 {d}, {a}, {b}", a = in(reg) a, b = in(reg) b, d = out(reg) difference, options(pure, nomem, nostack));
    }
    difference
}

/// Per byte: (a + b + 1) >> 1, as a - ((a - b) >> 1): `uhsub8` halves the
/// 9-bit difference rounding down, so the result is exact (and a byte).
#[inline(always)]
fn rounded_half(a: u32, b: u32) -> u32 {
    let half: u32;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!("uhsub8 {h}, {a}, {b}", "usub8 {h}, {a}, {h}", a = in(reg) a, b = in(reg) b, h = out(reg) half, options(pure, nomem, nostack));
    }
    half
}

/// Per byte of `x`: 1 above `threshold` (replicated in each byte), 0
/// elsewhere: `usub8` from 0 flags the bytes that are 0 after the
/// subtraction, `sel` makes the others 1.
#[inline(always)]
fn above(x: u32, threshold: u32) -> u32 {
    let flags;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!(
            "uqsub8 {x}, {x}, {threshold}",
            "usub8 {x}, {zero}, {x}",
            "sel {flags}, {zero}, {ones}",
            x = inout(reg) x => _, threshold = in(reg) threshold, zero = in(reg) 0u32, ones = in(reg) 0x0101_0101u32,
            flags = lateout(reg) flags,
            options(pure, nomem, nostack)
        );
    }
    flags
}

/// Four pixels a step, every operation per byte: min and max by `usub8` +
/// `sel`, the halfway reach by `uhadd8`, the residues by `uqsub8`; a word
/// of each output stored at once.
#[inline(always)]
pub fn residues<const FULL_K: bool, const FULL_G: bool>(lines: super::ResidueLines, threshold: u8, hot: &mut [u8], ground: &mut [u8]) {
    let super::ResidueLines { row, centre, up, down } = lines;
    let n = lines.len().min(hot.len()).min(ground.len());
    let words = n / 4;
    let threshold4 = u32::from(threshold) * 0x0101_0101;
    for w in 0..words {
        let c = 4 * w;
        // SAFETY: c + 4 <= n, so the words at row, up, down, hot, ground + c
        // and at centre + c, c + 1, c + 2 lie within their slices (centre
        // has n + 2 bytes); unaligned word accesses are fine on the M4.
        let (value, left, here, right, along_up, along_down) = unsafe {
            let word = |slice: &[u8], at: usize| core::ptr::read_unaligned(slice.as_ptr().add(at).cast::<u32>());
            (word(row, c), word(centre, c), word(centre, c + 1), word(centre, c + 2), word(up, c), word(down, c))
        };
        let (k_high, k_low) = max_min(left, right);
        let (g_high, g_low) = max_min(along_up, along_down);
        let (min, max) = (extreme::<true>, extreme::<false>);
        // The halfway reach is monotone and leaves `here` where it is, so
        // min(here, half(a), half(b)) = half(min(here, a, b)) (max alike):
        // the ground range's ends are the reaches of the ranges of `here`
        // and the neighbours along the axes that take the half.
        let half = |ends: u32| rounded_half(here, ends);
        let (wide_low, wide_high, low, high) = match (FULL_K, FULL_G) {
            (false, false) => {
                let (low, high) = (min(here, min(k_low, g_low)), max(here, max(k_high, g_high)));
                (low, high, half(low), half(high))
            }
            (true, false) => {
                let (low, high) = (min(here, g_low), max(here, g_high));
                (min(k_low, low), max(k_high, high), min(k_low, half(low)), max(k_high, half(high)))
            }
            (false, true) => {
                let (low, high) = (min(here, k_low), max(here, k_high));
                (min(g_low, low), max(g_high, high), min(g_low, half(low)), max(g_high, half(high)))
            }
            (true, true) => {
                let (low, high) = (min(here, min(k_low, g_low)), max(here, max(k_high, g_high)));
                (low, high, low, high)
            }
        };
        let wide = saturating_sub(value, wide_high) | saturating_sub(wide_low, value);
        let residue = saturating_sub(value, high) | saturating_sub(low, value);
        // SAFETY: as above.
        unsafe {
            core::ptr::write_unaligned(hot.as_mut_ptr().add(c).cast::<u32>(), above(wide, threshold4));
            core::ptr::write_unaligned(ground.as_mut_ptr().add(c).cast::<u32>(), residue);
        }
    }
    let c = 4 * words;
    portable::residues::<FULL_K, FULL_G>(lines.columns(c..n), threshold, &mut hot[c..n], &mut ground[c..n]);
}

//! Block matching: the patch's dot products per shift (`smlad`).

use crate::kernels::portable;

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
            // by `kernels::dot_shifts`); register arithmetic otherwise.
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

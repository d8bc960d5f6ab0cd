//! SAD and the shift search (`usada8`), the seed's sums and its |diff|
//! histogram (`usub8`/`sel`).

use crate::kernels::{self, portable};

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
    // (checked by `kernels::sad_shifts`); unaligned ldr is fine on the M4.
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
                sum_level = in(reg) u32::from(kernels::SUM_LEVEL) * 0x0101_0101,
                count_level = in(reg) u32::from(kernels::COUNT_LEVEL) * 0x0101_0101,
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

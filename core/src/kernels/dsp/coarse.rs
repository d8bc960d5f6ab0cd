//! The coarse search: |difference| of seen cells, two a word (`usub16`);
//! of cells all seen, four a loop.

use crate::kernels::portable;

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

/// [`seen_difference`] where every cell is seen: no lane masks, so
/// `usub16` both ways, `sel` and `smlad` per word, two words a loop
/// (values below 2^15, so `smlad`'s signed lanes hold every difference).
/// The last one to three cells are portable.
#[inline]
pub fn plain_difference(a: &[u16], b: &[u16]) -> u32 {
    let n = a.len().min(b.len());
    let quads = n / 4;
    let mut sum = 0u32;
    if quads > 0 {
        // SAFETY: reads `quads` double words of `a` and of `b` (4 * quads
        // <= n halfwords of each; unaligned word loads are fine on the M4);
        // register arithmetic otherwise. The sum of at most 2^16 differences
        // below 2^15 fits in 32 bits.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {x}, [{pa}], #4",
                "ldr {y}, [{pb}], #4",
                "usub16 {d}, {x}, {y}",
                "usub16 {e}, {y}, {x}",
                "sel {d}, {e}, {d}",
                "ldr {x}, [{pa}], #4",
                "ldr {y}, [{pb}], #4",
                "smlad {sum}, {d}, {ones}, {sum}",
                "usub16 {d}, {x}, {y}",
                "usub16 {e}, {y}, {x}",
                "sel {d}, {e}, {d}",
                "smlad {sum}, {d}, {ones}, {sum}",
                "subs {n}, {n}, #1",
                "bne 2b",
                pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                n = inout(reg) quads => _, ones = in(reg) 0x0001_0001u32,
                sum = inout(reg) sum,
                x = out(reg) _, y = out(reg) _, d = out(reg) _, e = out(reg) _,
                options(readonly, nostack)
            );
        }
    }
    sum + portable::plain_difference(&a[4 * quads..n], &b[4 * quads..n])
}

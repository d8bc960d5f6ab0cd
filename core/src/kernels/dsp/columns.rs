//! A cell row's residues summed per grid column and taken per cell
//! (`kernels::ColumnTotals`).

use crate::kernels::{self, portable};
use core::ops::Range;

/// Four columns a step: the hot flags counted by `usada8` against zero
/// and added to the tallies with 16 each in one `add` (no byte carries:
/// tallies stay below 256); the ground residues' bytes widened to
/// halfword pairs (`uxtb16`, `pkhbt`/`pkhtb`) and added two columns at a
/// time (`uadd16`): 19 instructions per 4 columns.
#[inline]
pub fn add_to_columns(hot: &[u8], ground: &[u8], columns: Range<usize>, totals: &mut kernels::ColumnTotals) -> u32 {
    let (start, end) = (columns.start, columns.end);
    let words = (end - start) / 4;
    let mut hot_pixels = 0u32;
    if words > 0 {
        // SAFETY: the caller (`kernels::add_to_columns`) keeps `columns`
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
pub fn take_pieces(totals: &kernels::ColumnTotals, px: usize, columns: Range<usize>, pieces: &mut [kernels::PieceSums]) {
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

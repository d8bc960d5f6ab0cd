//! The pyramid's kernels: the 4x4 mean and the strongest gradient per
//! block (`usada8`).

use crate::kernels::{self, portable};

/// `usada8` against zero sums a word's four bytes: one per row and output
/// pixel, 4 loads + 4 `usada8` per 16 pixels, 13 instructions (the plain loop takes ~10 a pixel).
#[inline]
pub fn mean_4x4(rows: [&[u8]; 4], out: &mut [u8]) {
    let n = out.len();
    if n == 0 {
        return;
    }
    // SAFETY: reads `n` words (unaligned ldr is fine on the M4) from each
    // row, which hold at least 4 * n bytes (checked by `kernels::mean_4x4`),
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
pub fn strongest_gradients(rows: kernels::GradientRows, row: u8, columns: core::ops::Range<usize>, side: usize, stride: usize, strongest: &mut [kernels::Strongest]) {
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
fn strongest_gradients_by<const STRIDE: usize>(rows: kernels::GradientRows, row: u8, columns: core::ops::Range<usize>, side: usize, strongest: &mut [kernels::Strongest]) {
    let kernels::GradientRows { up, row: pixels, down } = rows;
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
    // visited columns i of `columns`, which `kernels::strongest_gradients`
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

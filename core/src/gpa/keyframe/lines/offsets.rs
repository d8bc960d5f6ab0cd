//! One warped line read at several constant offsets (the parallax
//! hypotheses): its positions are stepped once, and each offset's samples
//! are made from them and differenced with the current row as they come,
//! never stored. Line k moved by (di, dj) has, at every column, the
//! position of line k plus (di, dj) (the same wrapping sums), so its
//! samples are exactly [`Keyframe::sample_line`]'s.

#[cfg(not(flatland_dsp))]
use super::blend;
use super::{coordinate_bounds, Keyframe};
#[cfg(not(flatland_dsp))]
use crate::gpa::warp::pixel_and_weight;
use crate::gpa::warp::{offset_q24, RowWarp};
use crate::grid::MAX_GRID_SIDE;
use core::ops::Range;

/// A line's keyframe positions (Q8.24 modulo 2^32, [`RowWarp::positions`])
/// at some columns, each with the current row's value there (one pointer
/// walks both). A moved line's positions are these plus its offset,
/// exact wherever it lies inside the grid (every line [`MovedLines::add`]
/// keeps).
pub(in crate::gpa) struct LinePositions {
    line: RowWarp,
    columns: Range<usize>,
    /// The offsets (di, dj), each between its two bounds, that keep the
    /// line inside the grid at all its columns (see [`MovedLines::add`]).
    inside_offsets: [(i32, i32); 2],
    /// Position of column `columns.start + t` at `t`, and the value.
    at: [Position; MAX_GRID_SIDE],
}

/// 12 bytes, the layout the M4's walk reads.
#[derive(Clone, Copy)]
#[repr(C)]
struct Position {
    i: u32,
    j: u32,
    value: u32,
}

impl LinePositions {
    /// 3 KB: kept with the row stages' sums (the workspace), off the stack.
    pub(in crate::gpa) const EMPTY: LinePositions =
        LinePositions { line: RowWarp::LEVEL, columns: 0..0, inside_offsets: [(1, 0); 2], at: [Position { i: 0, j: 0, value: 0 }; MAX_GRID_SIDE] };
}

/// The line of [`LinePositions`] moved by up to `N` offsets, each kept
/// (with a key the caller names it by) only where it lies inside the grid
/// at every one of the line's columns.
pub(in crate::gpa) struct MovedLines<'a, const N: usize> {
    keyframe: &'a Keyframe<'a>,
    positions: &'a LinePositions,
    offsets: heapless::Vec<(usize, (i32, i32)), N>,
}

impl Keyframe<'_> {
    /// Steps `line` over `columns` (at most the grid's width) into
    /// `positions`, with current row `row`'s values there.
    pub(in crate::gpa) fn step_positions(&self, line: RowWarp, columns: Range<usize>, row: &[u8], positions: &mut LinePositions) {
        positions.line = line;
        positions.columns = columns.clone();
        // By its coordinates' bounds, as `sample_line` finds first (it then
        // samples every column): where the moved line's start does not
        // wrap, its bounds are the line's moved, and `surely_inside` of it
        // holds for offsets from -least to limit - 1 - most.
        let offsets = |(start, step, bend), limit: i32| {
            let (least, most) = coordinate_bounds(start, step, bend, columns.clone());
            let (start, limit) = (i64::from(start), i64::from(limit));
            let lowest = (-least).max(i64::from(i32::MIN) - start).max(i64::from(i32::MIN));
            let highest = (limit - 1 - most).min(i64::from(i32::MAX) - start).min(i64::from(i32::MAX));
            if lowest <= highest { (lowest as i32, highest as i32) } else { (1, 0) }
        };
        positions.inside_offsets = match columns.is_empty() {
            true => [(1, 0); 2],
            false => [offsets((line.i_start, line.i_step, line.i_bend), self.columns_limit()), offsets((line.j_start, line.j_step, line.j_bend), self.rows_limit())],
        };
        let at = &mut positions.at[..columns.len()];
        let row = &row[columns.clone()];
        Self::for_positions(line, columns, |t, (i, j)| {
            // SAFETY: t < columns.len() = at.len() = row.len().
            unsafe { *at.get_unchecked_mut(t) = Position { i: i.q24(), j: j.q24(), value: u32::from(*row.get_unchecked(t)) } };
        });
    }

    /// The line of `positions`, moved by no offset yet.
    pub(in crate::gpa) fn moved_lines<'a, const N: usize>(&'a self, positions: &'a LinePositions) -> MovedLines<'a, N> {
        MovedLines { keyframe: self, positions, offsets: heapless::Vec::new() }
    }
}

impl<const N: usize> MovedLines<'_, N> {
    /// Adds the line moved by (`di`, `dj`), as `key`, if it lies inside
    /// the grid at all its columns; returns whether it did (not when `N`
    /// are).
    pub(in crate::gpa) fn add(&mut self, key: usize, (di, dj): (i32, i32)) -> bool {
        let [(i_low, i_high), (j_low, j_high)] = self.positions.inside_offsets;
        let inside = (i_low..=i_high).contains(&di) && (j_low..=j_high).contains(&dj);
        let (line, columns) = (self.positions.line, self.positions.columns.clone());
        debug_assert!(!inside || self.keyframe.surely_inside(line.moved(di, dj), columns));
        inside && self.offsets.push((key, (di, dj))).is_ok()
    }

    /// Whether no line was added.
    pub(in crate::gpa) fn is_empty(&self) -> bool {
        self.offsets.is_empty()
    }

    /// Calls `f(key, sum)` for each added line (in the order added), sum
    /// being its |current value - sample| summed over `columns`, which lie
    /// within the line's.
    #[inline(always)]
    pub(in crate::gpa) fn sads(&self, columns: Range<usize>, mut f: impl FnMut(usize, u32)) {
        let (keyframe, positions) = (self.keyframe, self.positions);
        let first = columns.start - positions.columns.start;
        let at = &positions.at[..positions.columns.len()][first..first + columns.len()];
        let image = &keyframe.images[keyframe.key_half][..keyframe.height * keyframe.width];
        for &(key, offset) in &self.offsets {
            let sum = if at.is_empty() {
                0
            } else {
                // SAFETY: each added line lies inside the grid at each of its
                // columns (`Self::add`): its row index is at most height - 2
                // and its column at most width - 2, so every pixel read
                // (index + width + 1 at most) is below height * width.
                unsafe { moved_sad(image, keyframe.width, at, (offset_q24(offset.0), offset_q24(offset.1))) }
            };
            f(key, sum);
        }
    }
}

/// [`MovedLines::sads`]' sum of the positions `at` (not empty), each moved by
/// `(di, dj)` (Q8.24) and lying inside the grid of `image` (`width` wide).
#[cfg(not(flatland_dsp))]
#[inline(always)]
unsafe fn moved_sad(image: &[u8], width: usize, at: &[Position], (di, dj): (u32, u32)) -> u32 {
    let mut sum = 0;
    for &Position { i, j, value } in at {
        let ((i0, wx), (j0, wy)) = (pixel_and_weight(i.wrapping_add(di)), pixel_and_weight(j.wrapping_add(dj)));
        let index = j0 * width + i0;
        // SAFETY: the caller's (see above).
        let sample = unsafe {
            let pixel = image.as_ptr().add(index);
            blend(*pixel, *pixel.add(1), *pixel.add(width), *pixel.add(width + 1), wx, wy)
        };
        sum += u32::from(sample).abs_diff(value);
    }
    sum
}

/// [`blend`] on the M4 as LLVM will not schedule it: one `ldrd` walks the
/// positions, the current value sits beside them, and `usada8` adds the
/// |difference| (28 instructions a pixel, no spill). The blend is the
/// same integer: `top = p00 << 8 + (p01 - p00) wx` (likewise `bottom`),
/// `(top << 8 + (bottom - top) wy + 2^15) >> 16`, at most 255.
#[cfg(flatland_dsp)]
#[inline(always)]
unsafe fn moved_sad(image: &[u8], width: usize, at: &[Position], (di, dj): (u32, u32)) -> u32 {
    let mut sum = 0u32;
    // SAFETY: reads the `at.len()` (> 0) positions of 12 bytes, and per
    // position four pixels the caller vouches for.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrd {i}, {j}, [{p}], #12",
            "add {i}, {i}, {di}",
            "add {j}, {j}, {dj}",
            "lsr {t}, {j}, #24",
            "mla {t}, {t}, {w}, {image}",
            "add {t}, {t}, {i}, lsr #24",    // &p00
            "ldrb {a}, [{t}]",
            "ldrb {b}, [{t}, #1]",
            "sub {b}, {b}, {a}",
            "ubfx {i}, {i}, #16, #8",        // wx
            "mul {b}, {b}, {i}",
            "add {a}, {b}, {a}, lsl #8",     // top
            "add {t}, {t}, {w}",
            "ldrb {b}, [{t}]",
            "ldrb {t}, [{t}, #1]",
            "sub {t}, {t}, {b}",
            "mul {t}, {t}, {i}",
            "add {b}, {t}, {b}, lsl #8",     // bottom
            "sub {b}, {b}, {a}",
            "ubfx {j}, {j}, #16, #8",        // wy
            "mul {b}, {b}, {j}",
            "add {b}, {b}, {a}, lsl #8",
            "add {b}, {b}, #32768",
            "lsr {b}, {b}, #16",             // the sample
            "ldr {a}, [{p}, #-4]",           // the current value
            "usada8 {sum}, {b}, {a}, {sum}",
            "cmp {p}, {end}",
            "bne 2b",
            p = inout(reg) at.as_ptr() => _,
            end = in(reg) at.as_ptr_range().end,
            image = in(reg) image.as_ptr(),
            w = in(reg) width,
            di = in(reg) di,
            dj = in(reg) dj,
            sum = inout(reg) sum,
            i = out(reg) _, j = out(reg) _, t = out(reg) _, a = out(reg) _, b = out(reg) _,
            options(readonly, nostack)
        );
    }
    sum
}


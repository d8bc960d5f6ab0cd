//! The keyframe and the current frame: two KG images. The current frame's
//! rows are stored as they stream in; at the frame's end the motion is
//! measured between the two whole images and the rows are compared; a
//! frame that becomes the keyframe just swaps halves (no copy).

use super::config::GpaConfig;
use super::kernels;
use super::warp::{RowWarp, BEND_FRAC, FRAC};
use crate::grid::KgGrid;
use crate::motion::Motion;
use core::ops::Range;

pub(super) struct Keyframe<'b> {
    /// Two images, `width * height` bytes each (a target may keep them
    /// in different RAM banks).
    images: [&'b mut [u8]; 2],
    width: usize,
    height: usize,
    /// Which half holds the keyframe (0 or 1); the other takes the current frame.
    key_half: usize,
    /// Frame the keyframe was taken at; None: no keyframe, the next frame
    /// becomes one and reports nothing.
    taken_at: Option<u32>,
    /// The current frame replaces the keyframe at its end.
    replacing: bool,
}

impl<'b> Keyframe<'b> {
    pub(super) const EMPTY: Keyframe<'static> = Keyframe {
        // An empty slice: nothing to read or write until `init` gives the buffer.
        // SAFETY: a dangling, aligned, non-null pointer with length 0 is a valid slice.
        images: [
            unsafe { core::slice::from_raw_parts_mut(core::ptr::NonNull::<u8>::dangling().as_ptr(), 0) },
            // SAFETY: as above.
            unsafe { core::slice::from_raw_parts_mut(core::ptr::NonNull::<u8>::dangling().as_ptr(), 0) },
        ],
        width: 0,
        height: 0,
        key_half: 0,
        taken_at: None,
        replacing: false,
    };

    /// Bytes each of the two images needs for this grid.
    pub(super) fn image_bytes(grid: &KgGrid) -> usize {
        grid.len()
    }

    /// Takes two buffers of at least [`Self::image_bytes`]; no keyframe yet.
    pub(super) fn new(first: &'b mut [u8], second: &'b mut [u8], grid: &KgGrid) -> Keyframe<'b> {
        Keyframe { images: [first, second], width: grid.width(), height: grid.height(), ..Keyframe::EMPTY }
    }

    pub(super) fn taken_at(&self) -> Option<u32> {
        self.taken_at
    }

    pub(super) fn forget(&mut self) {
        self.taken_at = None;
    }

    /// This frame starts afresh: no keyframe to compare with, and the frame
    /// becomes the keyframe.
    pub(super) fn restart(&mut self) {
        self.taken_at = None;
        self.replacing = true;
    }

    /// Whether the current frame replaces the keyframe at its end.
    pub(super) fn plan(&mut self, replace: bool) {
        self.replacing = replace;
    }

    /// Stores row `j` of the current frame.
    pub(super) fn write_row(&mut self, j: usize, row: &[u8]) {
        let width = self.width;
        self.images[1 - self.key_half][j * width..][..width].copy_from_slice(row);
    }

    /// Pixels a row (the grid's width).
    pub(super) fn width(&self) -> usize {
        self.width
    }

    /// Row `j` of the current frame.
    pub(super) fn current_row(&self, j: usize) -> &[u8] {
        &self.current_image()[j * self.width..][..self.width]
    }

    /// The whole current frame (rows written so far), row-major.
    pub(super) fn current_image(&self) -> &[u8] {
        &self.images[1 - self.key_half][..self.height * self.width]
    }

    /// The whole keyframe, row-major.
    pub(super) fn keyframe_image(&self) -> &[u8] {
        &self.images[self.key_half][..self.height * self.width]
    }

    /// The complete frame `frame` ends; returns whether it became the keyframe.
    pub(super) fn finish(&mut self, frame: u32) -> bool {
        if self.replacing {
            self.key_half = 1 - self.key_half;
            self.taken_at = Some(frame);
        }
        self.replacing
    }

    #[inline(always)]
    fn row(&self, j: usize) -> &[u8] {
        &self.images[self.key_half][j * self.width..][..self.width]
    }

    /// Whether the 2x2 neighbourhood of (i, j) Q16.16 lies in the grid
    /// (the per-pixel reference's test and the wrapping lines').
    #[inline(always)]
    pub(super) fn inside(&self, i: i32, j: i32) -> bool {
        let rows_limit = (self.height as i32 - 1) << FRAC;
        i >= 0 && (i >> FRAC) + 1 < self.width as i32 && j >= 0 && j < rows_limit
    }

    /// Bilinear sample at (i, j) Q16.16; the caller checked [`Self::inside`].
    /// The definition every line path reproduces.
    #[inline(always)]
    pub(super) fn sample(&self, i: i32, j: i32) -> u8 {
        let (i0, j0) = ((i >> FRAC) as usize, (j >> FRAC) as usize);
        let wx = ((i >> 8) & 0xFF) as u32;
        let wy = ((j >> 8) & 0xFF) as u32;
        let upper = self.row(j0);
        let lower = self.row(j0 + 1);
        let top = u32::from(upper[i0]) * (256 - wx) + u32::from(upper[i0 + 1]) * wx;
        let bottom = u32::from(lower[i0]) * (256 - wx) + u32::from(lower[i0 + 1]) * wx;
        ((top * (256 - wy) + bottom * wy + (1 << 15)) >> 16) as u8
    }

    /// Samples the keyframe along `line` at `columns` into `out[c]`, bilinear
    /// exactly as [`Self::sample`]; returns the columns whose 2x2
    /// neighbourhood is inside the grid, and writes 0 at the others.
    /// Insideness is linear in c (a warp step is a rotation, |step| <= 1 px,
    /// so nothing wraps), hence one interval.
    pub(super) fn sample_line(&self, line: RowWarp, columns: Range<usize>, out: &mut [u8]) -> Range<usize> {
        if columns.is_empty() {
            return columns;
        }
        if line.is_translation() {
            // Pure translation (no yaw, the common case): one pair of
            // keyframe rows and constant weights along the whole line.
            let rows_limit = (self.height as i32 - 1) << FRAC;
            let i0 = i64::from(line.i_start >> FRAC);
            let (lo, hi) = if line.j_start >= 0 && line.j_start < rows_limit {
                let lo = (columns.start as i64).max(-i0);
                let hi = (columns.end as i64).min(self.width as i64 - 1 - i0);
                (lo, hi.max(lo))
            } else {
                (columns.start as i64, columns.start as i64)
            };
            let (lo, hi) = (lo as usize, hi as usize);
            out[columns.start..lo].fill(0);
            out[hi..columns.end].fill(0);
            if hi > lo {
                let j0 = (line.j_start >> FRAC) as usize;
                let start = (i0 + lo as i64) as usize;
                let wx = ((line.i_start >> 8) & 0xFF) as u32;
                let wy = ((line.j_start >> 8) & 0xFF) as u32;
                let upper = &self.row(j0)[start..=start + (hi - lo)];
                let lower = &self.row(j0 + 1)[start..=start + (hi - lo)];
                kernels::bilinear_line(upper, lower, wx, wy, &mut out[lo..hi]);
            }
            return lo..hi;
        }
        // A yawed or bent line: the position steps in Q16 (the same sums as
        // `line.at(c)`) and the 2x2 neighbourhood is read from one offset
        // without slicing. Each coordinate is linear (or, bent, quadratic)
        // in c: when it stays in i32 at both ends nothing wraps, and unless
        // a bent coordinate turns outside the grid between the columns
        // found inside from both ends, they are one interval and no pixel
        // in it needs a test.
        let (i_limit, j_limit) = (self.columns_limit(), self.rows_limit());
        let exact = |c: usize| {
            let along = |start: i32, step: i32, bend: i32| {
                let c = c as i64;
                i64::from(start) + c * i64::from(step) + ((c * c * i64::from(bend)) >> (BEND_FRAC - FRAC))
            };
            (along(line.i_start, line.i_step, line.i_bend), along(line.j_start, line.j_step, line.j_bend))
        };
        let fits = |(i, j): (i64, i64)| i32::try_from(i).is_ok() && i32::try_from(j).is_ok();
        if !(fits(exact(columns.start)) && fits(exact(columns.end - 1))) {
            return self.sample_line_checked(line, columns, out);
        }
        let inside = |c: usize| {
            let (i, j) = exact(c);
            (0..i64::from(i_limit)).contains(&i) && (0..i64::from(j_limit)).contains(&j)
        };
        let Some(first) = columns.clone().find(|&c| inside(c)) else {
            out[columns.clone()].fill(0);
            return columns.start..columns.start;
        };
        let end = (first + 1..columns.end).rev().find(|&c| inside(c)).map_or(first + 1, |c| c + 1);
        if line.is_bent() {
            // A quadratic's turning point, -step / (2 bend), is where it could leave the grid.
            let turning = |step: i32, bend: i32| {
                (bend != 0).then(|| -(f64::from(step) * (1u64 << (BEND_FRAC - FRAC)) as f64) / (2.0 * f64::from(bend)))
            };
            let leaves = |turn: Option<f64>| {
                turn.is_some_and(|t| t > first as f64 && t < (end - 1) as f64 && [t as usize, t as usize + 1].iter().any(|&c| !inside(c)))
            };
            if leaves(turning(line.i_step, line.i_bend)) || leaves(turning(line.j_step, line.j_bend)) {
                return self.sample_line_checked(line, columns, out);
            }
        }
        out[columns.start..first].fill(0);
        out[end..columns.end].fill(0);
        let image: &[u8] = &self.images[self.key_half][..self.height * self.width];
        let width = self.width;
        let read = |(i, j): (i32, i32)| {
            let index = (j >> FRAC) as usize * width + (i >> FRAC) as usize;
            // SAFETY: every position from `first` to `end` lies in
            // 0..(width - 1) << 16 by 0..(height - 1) << 16 (both ends do,
            // a linear line does not wrap and a bent one does not turn
            // outside), so the row index is at most height - 2, the column
            // at most width - 2, and index + width + 1 < height * width =
            // image.len().
            let (p00, p01, p10, p11) = unsafe {
                (
                    *image.get_unchecked(index),
                    *image.get_unchecked(index + 1),
                    *image.get_unchecked(index + width),
                    *image.get_unchecked(index + width + 1),
                )
            };
            blend(p00, p01, p10, p11, i, j)
        };
        if line.is_bent() {
            let mut positions = line.positions(first);
            for slot in &mut out[first..end] {
                *slot = read(positions.take());
            }
        } else {
            let (mut i, mut j) = line.at(first);
            for slot in &mut out[first..end] {
                *slot = read((i, j));
                i = i.wrapping_add(line.i_step);
                j = j.wrapping_add(line.j_step);
            }
        }
        first..end
    }

    /// [`Self::sample_line`] pixel by pixel, for lines whose positions
    /// leave i32 and wrap (far beyond the grid: a degenerate warp).
    fn sample_line_checked(&self, line: RowWarp, columns: Range<usize>, out: &mut [u8]) -> Range<usize> {
        let (mut first, mut end) = (usize::MAX, 0);
        for c in columns.clone() {
            let (i, j) = line.at(c);
            out[c] = if self.inside(i, j) {
                first = first.min(c);
                end = c + 1;
                self.sample(i, j)
            } else {
                0
            };
        }
        if first == usize::MAX {
            columns.start..columns.start
        } else {
            first..end
        }
    }

    /// Q16 column positions below this have their right neighbour in the grid.
    #[inline(always)]
    fn columns_limit(&self) -> i32 {
        (self.width as i32 - 1) << FRAC
    }

    /// Q16 row positions below this have their lower neighbour in the grid.
    #[inline(always)]
    fn rows_limit(&self) -> i32 {
        (self.height as i32 - 1) << FRAC
    }
}

/// The bilinear sample of [`Keyframe::sample`] from its four pixels at
/// (i, j) Q16.16: the same integer, with the weights' complements folded
/// (`a (256 - w) + b w = 256 a + (b - a) w` exactly), a multiply less.
#[inline(always)]
fn blend(p00: u8, p01: u8, p10: u8, p11: u8, i: i32, j: i32) -> u8 {
    let wx = (i >> 8) & 0xFF;
    let wy = (j >> 8) & 0xFF;
    let top = (i32::from(p00) << 8) + (i32::from(p01) - i32::from(p00)) * wx;
    let bottom = (i32::from(p10) << 8) + (i32::from(p11) - i32::from(p10)) * wx;
    (((top << 8) + (bottom - top) * wy + (1 << 15)) >> 16) as u8
}

/// Fraction of the keyframe baseline (travel or turn) within which a frame
/// counts as having reached it.
const KEYFRAME_SLACK: f64 = 0.01;

/// Whether the frame at `predicted` from the keyframe (`step` since the
/// last frame) replaces it: once the baseline is long enough, and also
/// when the next frame, moving like this one, would overshoot by half
/// again: a slightly short step must not make the next baseline twice as
/// long (less overlap, too far to update in place).
pub(super) fn is_due(predicted: &Motion, step: &Motion, config: &GpaConfig) -> bool {
    let (travel, turn) = (predicted.distance_mm(), libm::fabs(predicted.dyaw_deg));
    let (step_travel, step_turn) = (step.distance_mm(), libm::fabs(step.dyaw_deg));
    // The measured travel is good to a fraction of a pixel: a robot whose
    // steps add up to the baseline exactly must not have its schedule
    // flip on that noise.
    let slack = KEYFRAME_SLACK * config.keyframe_travel_mm;
    let turn_slack = KEYFRAME_SLACK * config.keyframe_yaw_deg;
    travel >= config.keyframe_travel_mm - slack
        || turn >= config.keyframe_yaw_deg - turn_slack
        || travel + step_travel >= 1.5 * config.keyframe_travel_mm
        || turn + step_turn >= 1.5 * config.keyframe_yaw_deg
}

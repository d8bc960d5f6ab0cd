//! The keyframe: the one stored KG image each frame is compared with, the
//! last frame at least `keyframe_travel_mm` back (so slow steps still see
//! parallax).
//!
//! A frame that becomes the new keyframe is written *in place* while the old
//! one is still read, through a row-circular buffer with
//! [`KEYFRAME_SPARE_ROWS`] spare rows (no second image): new row j goes that
//! many slots before old row j, into rows the reads have left behind.

use super::config::GpaConfig;
use super::kernels;
use super::warp::{RowWarp, FRAC};
use crate::grid::KgGrid;
use crate::limits::KEYFRAME_SPARE_ROWS;
use crate::motion::Motion;
use core::ops::Range;

pub(super) struct Keyframe<'b> {
    data: &'b mut [u8],
    width: usize,
    height: usize,
    /// Slots of the ring: the grid's rows plus the spare rows.
    rows: usize,
    /// Slot of keyframe row 0.
    base: usize,
    /// Frame the keyframe was taken at; None: no keyframe, the next frame
    /// becomes one and reports nothing.
    taken_at: Option<u32>,
    /// This frame replaces the keyframe...
    replacing: bool,
    /// ...with its row 0 at this slot.
    new_base: usize,
}

impl<'b> Keyframe<'b> {
    pub(super) const EMPTY: Keyframe<'static> = Keyframe {
        // An empty slice: nothing to read or write until `init` gives the buffer.
        // SAFETY: a dangling, aligned, non-null pointer with length 0 is a valid slice.
        data: unsafe { core::slice::from_raw_parts_mut(core::ptr::NonNull::<u8>::dangling().as_ptr(), 0) },
        width: 0,
        height: 0,
        rows: 0,
        base: 0,
        taken_at: None,
        replacing: false,
        new_base: 0,
    };

    /// Bytes the buffer needs for this grid.
    pub(super) fn bytes(grid: &KgGrid) -> usize {
        (grid.height() + KEYFRAME_SPARE_ROWS) * grid.width()
    }

    /// Takes a buffer of at least [`Self::bytes`]; no keyframe yet.
    pub(super) fn new(data: &'b mut [u8], grid: &KgGrid) -> Keyframe<'b> {
        Keyframe {
            data,
            width: grid.width(),
            height: grid.height(),
            rows: grid.height() + KEYFRAME_SPARE_ROWS,
            ..Keyframe::EMPTY
        }
    }

    pub(super) fn taken_at(&self) -> Option<u32> {
        self.taken_at
    }

    pub(super) fn forget(&mut self) {
        self.taken_at = None;
    }

    /// This frame starts afresh: no keyframe to compare with, and the frame
    /// becomes the keyframe, written over the old one from its own base.
    pub(super) fn restart(&mut self) {
        self.taken_at = None;
        self.replacing = true;
        self.new_base = self.base;
    }

    /// This frame is compared with the keyframe, and replaces it if
    /// `replace`: then its row 0 goes [`KEYFRAME_SPARE_ROWS`] slots before
    /// the old row 0, so the write runs that far behind the reads.
    pub(super) fn plan(&mut self, replace: bool) {
        self.replacing = replace;
        self.new_base = (self.base + self.rows - KEYFRAME_SPARE_ROWS) % self.rows;
    }

    pub(super) fn replacing(&self) -> bool {
        self.replacing
    }

    /// Stores row `j` of the frame that replaces the keyframe.
    pub(super) fn write_row(&mut self, j: usize, row: &[u8]) {
        // Written S+2+lead rows behind the reads by construction of new_base.
        let mut slot = self.new_base + j;
        if slot >= self.rows {
            slot -= self.rows;
        }
        self.data[slot * self.width..][..self.width].copy_from_slice(row);
    }

    /// The frame that was replacing the keyframe stopped after writing
    /// `rows_written` rows: a partly overwritten keyframe is gone.
    pub(super) fn abort(&mut self, rows_written: usize) {
        if self.replacing && rows_written > 0 {
            self.taken_at = None;
        }
    }

    /// The complete frame `frame` ends; returns whether it became the keyframe.
    pub(super) fn finish(&mut self, frame: u32) -> bool {
        if self.replacing {
            self.base = self.new_base;
            self.taken_at = Some(frame);
        }
        self.replacing
    }

    #[inline(always)]
    fn row(&self, j: usize) -> &[u8] {
        // base < rows and j < height < rows: one subtraction replaces `%`.
        let mut slot = self.base + j;
        if slot >= self.rows {
            slot -= self.rows;
        }
        &self.data[slot * self.width..][..self.width]
    }

    /// Whether the 2x2 neighbourhood of (i, j) Q16.16 lies in the grid.
    #[inline(always)]
    pub(super) fn inside(&self, i: i32, j: i32) -> bool {
        let rows_limit = (self.height as i32 - 1) << FRAC;
        i >= 0 && (i >> FRAC) + 1 < self.width as i32 && j >= 0 && j < rows_limit
    }

    /// Bilinear sample at (i, j) Q16.16; the caller checked [`Self::inside`].
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
}

/// Whether the frame at `predicted` from the keyframe (`step` since the
/// last frame) replaces it: once the baseline is long enough, and also
/// when the next frame, moving like this one, would overshoot by half
/// again: a slightly short step must not make the next baseline twice as
/// long (less overlap, too far to update in place).
pub(super) fn is_due(predicted: &Motion, step: &Motion, config: &GpaConfig) -> bool {
    let (travel, turn) = (predicted.distance_mm(), libm::fabs(predicted.dyaw_deg));
    let (step_travel, step_turn) = (step.distance_mm(), libm::fabs(step.dyaw_deg));
    travel >= config.keyframe_travel_mm
        || turn >= config.keyframe_yaw_deg
        || travel + step_travel >= 1.5 * config.keyframe_travel_mm
        || turn + step_turn >= 1.5 * config.keyframe_yaw_deg
}

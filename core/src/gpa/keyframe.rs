//! The keyframe and the current frame: two KG images. The current frame's
//! rows are stored as they stream in; at the frame's end the motion is
//! measured between the two whole images and the rows are compared; a
//! frame that becomes the keyframe just swaps halves (no copy).

use super::config::GpaConfig;
use crate::grid::KgGrid;
use crate::motion::Motion;

mod lines;

pub(super) use lines::LinePositions;

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
        crate::kernels::copy_row(&mut self.images[1 - self.key_half][j * width..][..width], row);
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
    let turn_slack = KEYFRAME_SLACK * config.keyframe_yaw_deg;
    travel >= full_baseline_mm(config)
        || turn >= config.keyframe_yaw_deg - turn_slack
        || travel + step_travel >= 1.5 * config.keyframe_travel_mm
        || turn + step_turn >= 1.5 * config.keyframe_yaw_deg
}

/// The shortest travel at which a keyframe is due (see [`is_due`]): a full baseline.
pub(super) fn full_baseline_mm(config: &GpaConfig) -> f64 {
    config.keyframe_travel_mm - KEYFRAME_SLACK * config.keyframe_travel_mm
}

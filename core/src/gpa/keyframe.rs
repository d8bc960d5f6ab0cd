//! The keyframe and the current frame: two KG images. The current frame's
//! rows are stored as they stream in; at the frame's end the motion is
//! measured between the two whole images and the rows are compared; a
//! frame that becomes the keyframe just swaps halves (no copy).

use super::config::{GpaConfig, KEYFRAME_TRAVEL_PX};
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

/// The smallest obstacle's parallax (grid pixels) a longer keyframe travel
/// gives it (see [`KeyframeTravel`]).
const LONGER_PARALLAX_PX: f64 = 1.5;
/// The longest keyframe travel: twice the floor's, in grid pixels and in
/// the configured travel (a car's camera, whose 12 px floor is already
/// metres, keeps it: over twice that, real_kitti_queue_a's worst frame cost
/// 18 % more with odometry and 66 % more without).
const LONGEST_TRAVEL_FLOORS: f64 = 2.0;
/// A longer travel is taken only when it is at least this many times the floor's.
const LONGER_AT_LEAST: f64 = 1.5;

/// How far back the keyframe is renewed. The floor is
/// `GpaConfig::keyframe_travel_mm` (after `GpaConfig::for_grid`). A camera
/// high above a coarse grid sees the smallest obstacle (h,
/// `min_obstacle_height_mm`) move T h / (H - h) past the ground: under a
/// pixel at the floor's travel, below what a frame tells from the ground.
/// There the keyframe lies back as far as gives it [`LONGER_PARALLAX_PX`],
/// up to [`LONGEST_TRAVEL_FLOORS`]. Only when that is well past the floor: a
/// longer travel costs the far edge (past the grid's 100 mm travel margin
/// the keyframe no longer covers the farthest rows) and, in a turn, the
/// sides, so while turning the floor holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct KeyframeTravel {
    /// Where the keyframe is renewed off a turn: the floor or longer.
    longer_mm: f64,
}

impl KeyframeTravel {
    pub(super) const NONE: KeyframeTravel = KeyframeTravel { longer_mm: 0.0 };

    /// The travels of a camera `camera_height_mm` above the ground of
    /// `grid`, under `config` as configured (not yet `for_grid`).
    pub(super) fn new(config: &GpaConfig, grid: &KgGrid, camera_height_mm: f64) -> KeyframeTravel {
        let (floor_mm, h) = (config.for_grid(grid).keyframe_travel_mm, config.min_obstacle_height_mm);
        let for_parallax = LONGER_PARALLAX_PX * grid.mm_per_px * (camera_height_mm - h) / h;
        let longest = LONGEST_TRAVEL_FLOORS * (KEYFRAME_TRAVEL_PX * grid.mm_per_px).min(config.keyframe_travel_mm);
        let longer = for_parallax.min(longest);
        KeyframeTravel { longer_mm: if longer >= LONGER_AT_LEAST * floor_mm { longer } else { floor_mm } }
    }

    /// The travel that renews the keyframe for a frame at `predicted` from
    /// it, `step` since the last frame, under `config` (after `for_grid`):
    /// the floor while the two turn through half the keyframe turn.
    fn for_frame(&self, predicted: &Motion, step: &Motion, config: &GpaConfig) -> f64 {
        let turning = libm::fabs(predicted.dyaw_deg) + libm::fabs(step.dyaw_deg) >= 0.5 * config.keyframe_yaw_deg;
        if turning { config.keyframe_travel_mm } else { self.longer_mm }
    }
}

/// Whether the frame at `predicted` from the keyframe (`step` since the
/// last frame) replaces it: once the baseline is long enough, and also
/// when the next frame, moving like this one, would overshoot by half
/// again: a slightly short step must not make the next baseline twice as
/// long (less overlap, too far to update in place).
pub(super) fn is_due(predicted: &Motion, step: &Motion, travels: &KeyframeTravel, config: &GpaConfig) -> bool {
    let (travel, turn) = (predicted.distance_mm(), libm::fabs(predicted.dyaw_deg));
    let (step_travel, step_turn) = (step.distance_mm(), libm::fabs(step.dyaw_deg));
    let keyframe_travel = travels.for_frame(predicted, step, config);
    // The measured travel is good to a fraction of a pixel: a robot whose
    // steps add up to the baseline exactly must not have its schedule
    // flip on that noise.
    let turn_slack = KEYFRAME_SLACK * config.keyframe_yaw_deg;
    travel >= full_baseline(keyframe_travel)
        || turn >= config.keyframe_yaw_deg - turn_slack
        || travel + step_travel >= 1.5 * keyframe_travel
        || turn + step_turn >= 1.5 * config.keyframe_yaw_deg
}

/// The shortest travel at which a keyframe is due on the floor's schedule
/// (see [`is_due`]): a full baseline.
pub(super) fn full_baseline_mm(config: &GpaConfig) -> f64 {
    full_baseline(config.keyframe_travel_mm)
}

/// A keyframe travel less the slack within which a frame reaches it.
fn full_baseline(travel_mm: f64) -> f64 {
    travel_mm - KEYFRAME_SLACK * travel_mm
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(mm_per_px: f64) -> KgGrid {
        KgGrid { mm_per_px, x_left_mm: -500.0, z_far_mm: 2000.0, width: 100, height: 100 }
    }

    fn straight(tz_mm: f64) -> Motion {
        Motion { tx_mm: 0.0, tz_mm, dyaw_deg: 0.0 }
    }

    #[test]
    fn a_high_camera_on_a_coarse_grid_waits_for_the_smallest_obstacles_parallax() {
        let config = GpaConfig::default();
        // 1.5 px of 8 mm for 20 mm at 600 mm: 348 mm, held to 24 px.
        let travels = KeyframeTravel::new(&config, &grid(8.0), 600.0);
        assert_eq!(travels.longer_mm, 24.0 * 8.0);
        let step = straight(60.0);
        assert!(!is_due(&straight(120.0), &step, &travels, &config), "the floor's 100 mm no longer renews it");
        assert!(is_due(&straight(191.0), &step, &travels, &config));
        // The smallest obstacle moves T h / (H - h) past the ground: the
        // floor's 100 mm leaves it under half a pixel.
        let parallax_px = |travel: f64| travel * 20.0 / (600.0 - 20.0) / 8.0;
        assert!(parallax_px(config.keyframe_travel_mm) < 0.5 && parallax_px(travels.longer_mm) > 0.8);
    }

    #[test]
    fn where_the_floor_already_shows_it_or_little_is_gained_the_floor_holds() {
        // 400 mm over a 5.75 mm grid: 1.5 px at 164 mm, held to 24 px = 138
        // mm, less than half again the 100 mm floor.
        let config = GpaConfig::default();
        assert_eq!(KeyframeTravel::new(&config, &grid(5.75), 400.0).longer_mm, 100.0);
        // A low camera: 1.5 px of 4 mm at 120 mm is 30 mm.
        assert_eq!(KeyframeTravel::new(&config, &grid(4.0), 120.0).longer_mm, 100.0);
        // A camera below the smallest obstacle.
        assert_eq!(KeyframeTravel::new(&config, &grid(4.0), 15.0).longer_mm, 100.0);
        // A car's camera 1.66 m up over a 53.6 mm grid: its floor, 12 px
        // (643 mm), leaves 20 mm at 0.14 px, and stays.
        let travels = KeyframeTravel::new(&config, &grid(53.625), 1657.0);
        assert_eq!((config.for_grid(&grid(53.625)).keyframe_travel_mm, travels.longer_mm), (12.0 * 53.625, 12.0 * 53.625));
    }

    #[test]
    fn while_turning_the_floor_travel_renews_it() {
        let config = GpaConfig::default();
        let travels = KeyframeTravel::new(&config, &grid(8.0), 600.0);
        let turning = |tz_mm: f64, dyaw_deg: f64| Motion { tx_mm: 0.0, tz_mm, dyaw_deg };
        // 2 + 1 degrees: half the 6 degree keyframe turn.
        assert!(is_due(&turning(120.0, 2.0), &turning(60.0, 1.0), &travels, &config));
        assert!(!is_due(&turning(120.0, 1.0), &turning(60.0, 0.5), &travels, &config));
    }
}

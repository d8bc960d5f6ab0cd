//! The detector's tuning, in physical units so it carries across cameras
//! and grids.

use super::GpaError;
use crate::grid::KgGrid;
use crate::limits::MAX_SEARCH_RADIUS;

/// The least keyframe travel, in grid pixels ([`GpaConfig::for_grid`]).
pub const KEYFRAME_TRAVEL_PX: f64 = 12.0;

/// Tuning, in physical units so it carries across cameras and grids.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpaConfig {
    /// Search radius S in KG pixels around the predicted shift.
    pub search_radius: usize,
    /// Travel since the keyframe at which the current frame becomes the keyframe.
    pub keyframe_travel_mm: f64,
    /// Turn since the keyframe at which the current frame becomes the keyframe:
    /// turning shrinks the ground both frames see (a turn of 6 degrees
    /// moves the far edge sideways by a tenth of its distance). A tighter
    /// limit cuts a gentle arc's baseline short of the travel a height
    /// needs: at 3 degrees a robot arcing 6 deg/s at 10 frames/s compared
    /// over 60-75 mm, not 100.
    pub keyframe_yaw_deg: f64,
    /// A residue pixel exceeds `max(residue_floor, noise_factor * noise)`.
    pub residue_floor: u8,
    pub noise_factor: f64,
    /// Side of a coherence cell, mm of ground.
    pub cell_mm: f64,
    /// A cell joins a blob when this percentage of its valid pixels are residue.
    pub active_cell_percent: u32,
    /// A blob is an obstacle when one of its cells reaches this percentage...
    pub peak_cell_percent: u32,
    /// ...and its residue covers at least this ground area (mm²).
    pub min_residue_mm2: f64,
    /// Parallax test: a cell is elevated when its best height hypothesis
    /// lowers the cell's SAD by this percentage of the ground hypothesis...
    pub parallax_gain_percent: u32,
    /// ...and by at least this many gray levels per pixel (or the noise level, if higher);
    /// one that wins by less only joins elevated cells into groups.
    pub parallax_min_gain: f64,
    /// Obstacles are at least this tall (mm), drops at least this deep;
    /// lower bumps and shallower dips are ground.
    pub min_obstacle_height_mm: f64,
    /// The deepest drop the depth hypotheses look for (mm below the ground);
    /// a deeper one matches the deepest hypothesis and is reported at it.
    pub max_drop_mm: f64,
    /// Odometry error to tolerate, as a fraction of the step since the last
    /// frame (the part of the motion the shift search has not refined yet):
    /// height hypotheses whose displacement stays within it count as ground.
    pub odometry_error_fraction: f64,
    /// Heading error to tolerate over that step, degrees: it moves ground at
    /// distance z sideways by z * error.
    pub odometry_yaw_error_deg: f64,
    /// The odometry prior of the motion estimate, one sigma per step:
    /// this fraction of the step plus a constant, and a heading error.
    pub odometry_sigma_fraction: f64,
    pub odometry_sigma_mm: f64,
    pub odometry_sigma_yaw_deg: f64,
    /// Without odometry: the largest step (mm) and turn (degrees) between
    /// frames the estimate searches for when it knows no velocity yet. The
    /// step is at least a fifth of the grid's depth, whatever the camera.
    pub max_step_mm: f64,
    pub max_step_yaw_deg: f64,
    /// Without odometry, before a velocity is measured: the fastest the
    /// robot drives, in depths of the grid's view per second (a robot
    /// that covers its view faster outruns its own warning). The first
    /// step is searched for only as far as that allows over the frame
    /// interval (at 30 frames/s a fifteenth of the view's depth, not a
    /// fifth): a wider search meets more aliases of a periodic floor.
    pub max_speed_view_depths_per_s: f64,
    /// Without odometry, once a velocity is measured: how far the robot
    /// may depart from it between frames, as the largest acceleration
    /// (mm/s², deg/s²) over the frames' interval. A constant-velocity
    /// prior is then tight at 30 frames/s and wide at 1.
    pub max_acceleration_mm_s2: f64,
    pub max_yaw_acceleration_deg_s2: f64,
    /// One sigma of an IMU's attitude change between two frames, degrees.
    pub imu_sigma_deg: f64,
    /// Without an IMU: the largest attitude change from the keyframe, degrees.
    pub max_attitude_change_deg: f64,
    /// Drops are looked for only while the attitude change from the
    /// keyframe is measured: by the images, or by an IMU whose sigma is
    /// within this (degrees). A guessed change (level, `max_attitude_change_deg`
    /// / 3) errs at the far AOI edge by as much as a drop's parallax
    /// (which is small: T*d/(H+d)). Obstacles standing up are unaffected.
    pub drop_imu_sigma_limit_deg: f64,
}

impl Default for GpaConfig {
    fn default() -> Self {
        GpaConfig::DEFAULT
    }
}

impl GpaConfig {
    /// The defaults (a constant, so [`super::Gpa::EMPTY`] can hold it).
    pub const DEFAULT: GpaConfig = GpaConfig {
        search_radius: 2,
        keyframe_travel_mm: 100.0,
        keyframe_yaw_deg: 6.0,
        residue_floor: 16,
        noise_factor: 4.0,
        cell_mm: 30.0,
        active_cell_percent: 12,
        peak_cell_percent: 35,
        min_residue_mm2: 800.0,
        parallax_gain_percent: 30,
        parallax_min_gain: 3.0,
        min_obstacle_height_mm: 20.0,
        max_drop_mm: 300.0,
        odometry_error_fraction: 0.05,
        odometry_yaw_error_deg: 0.1,
        odometry_sigma_fraction: 0.1,
        odometry_sigma_mm: 5.0,
        odometry_sigma_yaw_deg: 0.5,
        max_step_mm: 250.0,
        max_step_yaw_deg: 24.0,
        max_speed_view_depths_per_s: 2.0,
        max_acceleration_mm_s2: 6000.0,
        max_yaw_acceleration_deg_s2: 300.0,
        imu_sigma_deg: 0.1,
        max_attitude_change_deg: 3.0,
        drop_imu_sigma_limit_deg: 0.5,
    };

    /// The configuration a grid of `grid`'s resolution runs with: the
    /// keyframe travel at least [`KEYFRAME_TRAVEL_PX`] grid pixels, so a
    /// coarse grid (a car's camera, ~50 mm a pixel) compares over a
    /// baseline whose parallax spans pixels, as a fine one does over
    /// 100 mm.
    pub(super) fn for_grid(self, grid: &KgGrid) -> GpaConfig {
        GpaConfig { keyframe_travel_mm: self.keyframe_travel_mm.max(KEYFRAME_TRAVEL_PX * grid.mm_per_px), ..self }
    }

    /// [`GpaError::Config`] unless the search radius is in
    /// 1..=[`MAX_SEARCH_RADIUS`] and every real value is finite and positive.
    pub(super) fn check(&self) -> Result<(), GpaError> {
        let finite = [
            self.keyframe_travel_mm,
            self.keyframe_yaw_deg,
            self.noise_factor,
            self.cell_mm,
            self.min_residue_mm2,
            self.parallax_min_gain,
            self.min_obstacle_height_mm,
            self.max_drop_mm,
            self.odometry_error_fraction,
            self.odometry_yaw_error_deg,
            self.odometry_sigma_fraction,
            self.odometry_sigma_mm,
            self.odometry_sigma_yaw_deg,
            self.max_step_mm,
            self.max_step_yaw_deg,
            self.max_speed_view_depths_per_s,
            self.max_acceleration_mm_s2,
            self.max_yaw_acceleration_deg_s2,
            self.imu_sigma_deg,
            self.max_attitude_change_deg,
            self.drop_imu_sigma_limit_deg,
        ];
        if self.search_radius == 0 || self.search_radius > MAX_SEARCH_RADIUS || !finite.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(GpaError::Config);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A car camera's coarse grid (53.6 mm a pixel) compares over at least
    /// 12 of its pixels; a robot's fine grid keeps the configured 100 mm.
    #[test]
    fn the_keyframe_travel_spans_pixels_of_the_grid() {
        let grid = |mm_per_px| KgGrid { mm_per_px, x_left_mm: -1000.0, z_far_mm: 2000.0, width: 64, height: 64 };
        let config = GpaConfig::DEFAULT;
        assert_eq!(config.for_grid(&grid(5.75)).keyframe_travel_mm, 100.0);
        assert_eq!(config.for_grid(&grid(53.625)).keyframe_travel_mm, 12.0 * 53.625);
    }
}

//! GPA + GTI combined (issue 4; the seed's §3.3): GPA says whether and where
//! there is an obstacle, GTI how high it is.
//!
//! One home for the combination, so the host's `flatland detect` and the
//! firmware's frame loop agree report for report:
//! - [`GtiStage`] wraps the GTI stage with the frame bookkeeping both need
//!   (rows from the remap callback, odometry gaps, abandoned frames);
//! - [`GtiStage::enrich`] fills `FrameReport::obstacle_h_mm` from GTI's
//!   heights inside GPA's obstacle, and lets GTI alone raise an alarm for a
//!   confirmed obstacle point at least `min_obstacle_mm` (20 mm) high by
//!   three standard errors of its height.
//!
//! GTI's own alarm: GPA decides from a keyframe pair, and holds or drops an
//! obstacle by its parallax over that baseline; GTI integrates a feature's
//! locus over up to 16 frames, so it sees low obstacles on short baselines
//! where GPA's parallax is below its blob thresholds. GTI alarms only on a
//! good point that clears the minimum height by `CERTAIN_SIGMAS` of its
//! standard error, backed by `MIN_SUPPORT` agreeing
//! points nearby (`Gti::nearest_obstacle_point`), never on one stray track.

use crate::geometry::Rig;
use crate::grid::KgGrid;
use crate::gti::{Gti, GtiConfig, GtiError, RegionMm};
use crate::motion::{Attitude, Motion};
use crate::report::FrameReport;
use core::ops::Range;
use libm::roundf;

/// Depth (mm, from its nearest point) of the box over which GTI's heights
/// are read for a GPA obstacle: GPA reports only the near edge, and an
/// obstacle's top edges lie up to its depth behind it.
pub const OBSTACLE_DEPTH_MM: f32 = 300.0;
/// Margin (mm) around GPA's obstacle box: GPA's footprint is cell-coarse.
pub const OBSTACLE_MARGIN_MM: f32 = 60.0;
/// Lateral reach (mm) of a GTI-raised obstacle around its nearest point,
/// when it reports left and right.
pub const GTI_OBSTACLE_HALF_WIDTH_MM: f32 = 100.0;

/// The GTI stage of the pipeline, as the host and the firmware run it.
pub struct GtiStage {
    gti: Gti,
    aoi: RegionMm,
    /// A row of this frame was refused: the frame's samples are incomplete.
    row_fault: bool,
}

impl GtiStage {
    pub fn new(rig: &Rig, grid: &KgGrid) -> Result<GtiStage, GtiError> {
        let mut stage = GtiStage::UNCONFIGURED;
        stage.configure(rig, grid)?;
        Ok(stage)
    }

    /// For a `static`, set up in place by [`GtiStage::configure`].
    pub const UNCONFIGURED: GtiStage =
        GtiStage { gti: Gti::UNCONFIGURED, aoi: RegionMm { x_min: 0.0, x_max: 0.0, z_min: 0.0, z_max: 0.0 }, row_fault: false };

    /// Sets the stage up for a rig (default GTI configuration), in place.
    pub fn configure(&mut self, rig: &Rig, grid: &KgGrid) -> Result<(), GtiError> {
        self.gti.configure(rig, grid, GtiConfig::DEFAULT)?;
        let aoi = rig.aoi();
        self.aoi = RegionMm {
            x_min: -aoi.half_width_mm as f32,
            x_max: aoi.half_width_mm as f32,
            z_min: aoi.near_mm as f32,
            z_max: aoi.far_mm as f32,
        };
        self.row_fault = false;
        Ok(())
    }

    /// The GTI state (points, tracks) for `flatland heights`.
    pub fn gti(&self) -> &Gti {
        &self.gti
    }

    /// Feeds KG row `row` from the streaming remap's callback.
    pub fn on_kg_row(&mut self, row: usize, kg_row: &[u8], valid_columns: Range<usize>) {
        if self.gti.on_kg_row(row, kg_row, valid_columns).is_err() {
            self.row_fault = true;
        }
    }

    /// The frame stopped mid-way: its rows are dropped.
    pub fn abort_frame(&mut self) {
        self.gti.abort_frame();
        self.row_fault = false;
    }

    /// Ends the frame. `odometry` is the motion from the frame just before,
    /// None after a gap (the first frame, a missing frame or pose, time going
    /// backwards): then the tracks cannot be continued and GTI starts over
    /// from this frame.
    /// `attitude` is the body's attitude relative to the nominal one.
    pub fn end_frame(&mut self, odometry: Option<Motion>, attitude: Attitude) {
        if core::mem::take(&mut self.row_fault) {
            self.gti.abort_frame();
            self.gti.restart();
            return;
        }
        match odometry {
            Some(motion) => self.gti.end_frame(&motion, &attitude),
            None => {
                self.gti.restart();
                self.gti.end_frame(&Motion::default(), &attitude);
            }
        }
    }

    /// Adds GTI's heights to GPA's report (call after [`GtiStage::end_frame`]).
    ///
    /// - GPA alarm on an obstacle (a drop keeps GPA's depth): `obstacle_h_mm` is GTI's height over the obstacle's box
    ///   (`left_mm..right_mm`, `nearest_mm..nearest_mm + OBSTACLE_DEPTH_MM`,
    ///   grown by `OBSTACLE_MARGIN_MM`) when GTI has a supported height there
    ///   of at least the minimum obstacle height; a lower GTI reading means
    ///   GTI has tracked only the floor around it so far, so GPA's parallax
    ///   height stands.
    /// - No GPA alarm: GTI's nearest confirmed obstacle point in the AOI, if
    ///   any, raises the alarm (see the module docs).
    pub fn enrich(&self, report: &mut FrameReport) {
        let min_obstacle = self.gti.config().min_obstacle_mm;
        if report.alarm {
            // A drop's depth is GPA's own: GTI's heights over the hole's box
            // belong to the floor before its edge.
            if report.obstacle_h_mm.is_some_and(|h| h < 0) {
                return;
            }
            let (Some(near), Some(left), Some(right)) = (report.nearest_mm, report.left_mm, report.right_mm) else {
                return;
            };
            let region = RegionMm {
                x_min: left as f32 - OBSTACLE_MARGIN_MM,
                x_max: right as f32 + OBSTACLE_MARGIN_MM,
                z_min: near as f32 - OBSTACLE_MARGIN_MM,
                z_max: near as f32 + OBSTACLE_DEPTH_MM + OBSTACLE_MARGIN_MM,
            };
            if let Some(h) = self.gti.height_in_region(&region).filter(|&h| h as f32 >= min_obstacle) {
                report.obstacle_h_mm = Some(h);
            }
            return;
        }
        let Some(point) = self.gti.nearest_obstacle_point(&self.aoi) else { return };
        let half = GTI_OBSTACLE_HALF_WIDTH_MM;
        let region = RegionMm {
            x_min: point.x_mm - half,
            x_max: point.x_mm + half,
            z_min: point.z_mm - OBSTACLE_MARGIN_MM,
            z_max: point.z_mm + OBSTACLE_DEPTH_MM,
        };
        report.alarm = true;
        report.nearest_mm = Some(roundf(point.z_mm) as i32);
        report.left_mm = Some(roundf(region.x_min.max(self.aoi.x_min)) as i32);
        report.right_mm = Some(roundf(region.x_max.min(self.aoi.x_max)) as i32);
        report.obstacle_h_mm =
            Some(self.gti.height_in_region(&region).filter(|&h| h as f32 >= min_obstacle).unwrap_or(roundf(point.h_mm) as i32));
    }
}

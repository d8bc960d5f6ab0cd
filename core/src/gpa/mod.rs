//! GPA: the ground plane assumption detector (seed §3.1), streaming.
//!
//! One KG image, the keyframe, is stored. Each new frame's KG rows stream
//! by once; for every row the keyframe is warped by the predicted motion
//! into a small band of `2S+1` rows, and a single pass accumulates the
//! seed's shift search, a misregistration-tolerant residue and per-cell
//! height hypotheses. At the frame's end the sums decide the refined
//! motion, the noise level and the obstacle.
//!
//! The rooms, in the order a row passes them:
//! - `keyframe`: the stored keyframe, a row-circular buffer updated in
//!   place while it is read.
//! - `prediction`: the chained prediction keyframe -> now (refined motion
//!   then odometry) and the learned odometry scale.
//! - `warp`: the prediction as a Q16.16 line per row, and the columns
//!   where a comparison is possible.
//! - `band`: the keyframe warped onto the row, `2S+1` rows, as a ring.
//! - `residue`: the tolerant residue, counted per coherence cell.
//! - `parallax`: height hypotheses per cell, and each cell's height.
//! - `shift_search`: the seed's `(2S+1)^2` SADs and statistics, the best
//!   shift to sub-pixel, the refined motion.
//! - `obstacles`: blobs of cells and where they stand.
//! - `decision`: the noise model and the alarm (held on short baselines).
//! - `row`: one row through the stages, and its per-pixel reference.
//! - `layout`: the AOI and the coherence cells on the grid; `config`: the tuning.
//!
//! `Gpa` owns one of each and passes each stage the others' results, so
//! every stage borrows only what it reads and writes.

mod band;
/// gpa's checks, listed in [`crate::selftest`].
#[cfg(any(test, feature = "selftest"))]
pub mod checks;
mod coarse;
mod config;
mod decision;
mod direct;
mod estimate;
mod hazard_mask;
mod homography;
mod keyframe;
mod layout;
mod obstacles;
mod parallax;
mod prediction;
mod profile;
mod pyramid;
mod residue;
mod row;
#[cfg(test)]
mod scenes;
mod shift_search;
mod warp;
mod workspace;

/// The difference kernels the stages run (one name to change with them).
use crate::kernels;

pub use config::GpaConfig;
pub use decision::AlarmSource;
pub use obstacles::Blob;
pub use parallax::{DROP_STEPS, HEIGHT_FRACTIONS};
pub use profile::GpaProfile;
pub use shift_search::{SEED_COUNT_LEVEL, SEED_SUM_LEVEL};

use crate::geometry::Rig;
use crate::grid::{KgGrid, MAX_GRID_SIDE};
use crate::limits::MAX_BLOBS;
use crate::motion::{Attitude, GroundMotion, Motion};
use crate::remap::RemapTable;
use crate::report::{FrameReport, NotJudged, Status, ANGLE_SCALE, MOTION_SCALE, SHIFT_SCALE};
use crate::scan::{Scan, ScanLayout, View};
use decision::{Alarm, Noise};
use estimate::{Estimate, Estimator, GroundAttitude, KeyframeAttitude, Prior, Scene, TypicalMisregistration, Unmeasured};
use hazard_mask::HazardMask;
use homography::SinCosMemo;
use keyframe::{Keyframe, KeyframeTravel};
use layout::{Layout, MAX_CELL_PX};
use parallax::{Hypotheses, Parallax};
use prediction::Prediction;
use profile::Profiler;
use warp::{Coverage, KeptRuns, RowWarp, Warp};
use workspace::Workspace;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GpaError {
    /// search_radius is 0 or above [`crate::limits::MAX_SEARCH_RADIUS`], or a value is not finite/positive.
    Config,
    /// An image buffer is smaller than [`Gpa::image_bytes`].
    BufferTooSmall { needed: usize },
    /// The grid does not match the remap table.
    GridMismatch,
}

impl core::fmt::Display for GpaError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GpaError::Config => f.write_str("GPA config: search radius out of range, or a value not finite and positive"),
            GpaError::BufferTooSmall { needed } => write!(f, "image buffer too small: {needed} bytes needed"),
            GpaError::GridMismatch => f.write_str("the grid does not match the remap table"),
        }
    }
}

impl core::error::Error for GpaError {}

/// What the last frame measured in one cell ([`Gpa::cell_evidence`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CellEvidence {
    /// Parallax height, mm (negative below the ground; 0: ground or undecided).
    pub height_mm: i16,
    /// The height beat the ground by less than the absolute gain: it shows
    /// only that a surface goes on there.
    pub weak: bool,
    /// It moves with the robot (a lag hypothesis won): its height is unknown.
    pub moving: bool,
    /// Share of its pixels that are residue no motion explains, percent.
    pub residue_percent: u32,
}

impl CellEvidence {
    /// The height the obstacle groups read: 0 for a weak one.
    pub fn measured_height_mm(&self) -> i16 {
        if self.weak {
            0
        } else {
            self.height_mm
        }
    }

    /// Moves with the robot, and not weakly (as the moving obstacle reads it).
    pub fn moves_with_robot(&self) -> bool {
        self.moving && !self.weak
    }
}

/// What a frame's baseline can tell from the ground ([`Gpa::resolution`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resolution {
    pub least_height_mm: f64,
    pub shallowest_drop_mm: f64,
}

/// The streaming GPA detector. See the module docs.
pub struct Gpa<'b> {
    config: GpaConfig,
    layout: Layout,
    coverage: Coverage,
    keyframe: Keyframe<'b>,
    /// How far back the keyframe is renewed (set up with the grid).
    keyframe_travel: KeyframeTravel,
    prediction: Prediction,
    /// The motion estimate's memory and the row stages' sums, in turns.
    workspace: Workspace,
    /// The odometry and IMU given for this frame (None: no such sensor).
    odometry: Option<Motion>,
    imu: Option<Attitude>,
    /// The IMU's attitude when the keyframe was taken.
    keyframe_imu: Option<Attitude>,
    /// The keyframe body's attitude relative to the nominal one: the
    /// measured changes chained from the first keyframe of a run (taken as
    /// nominal; a keyframe that follows no comparison is too), refined by
    /// each comparison with it.
    keyframe_attitude: KeyframeAttitude,
    /// The body's attitude relative to the ground, filtered over frames:
    /// where each new keyframe's starts.
    ground_attitude: GroundAttitude,
    /// What a trusted alignment leaves on this camera (the estimate's test).
    typical_misregistration: TypicalMisregistration,
    /// Where the last judged frame saw hazards: the estimate leaves them out.
    hazard_mask: HazardMask,
    /// The keyframe body's attitude as the measured changes chain it,
    /// leaking back to nominal ([`chain_keyframe`]): smooth from frame to
    /// frame, for GTI's tracks.
    keyframe_chain: Attitude,
    /// This frame's body attitude relative to the run's first keyframe,
    /// as the measured changes chain it; nominal when not compared.
    body_attitude: Attitude,
    /// This frame's motion from the keyframe, as measured (or predicted).
    measured: GroundMotion,
    /// Whether this frame's odometry disagreed with the ground.
    odometry_fault: Option<bool>,
    /// The last frame's step from the frame before, if it was compared.
    last_step: Option<Motion>,
    /// The interval since the last frame (s), if known, the one before it,
    /// and whether the last frame's step was measured by the images (so
    /// the velocity is known).
    elapsed_s: Option<f64>,
    last_elapsed_s: Option<f64>,
    velocity_known: bool,
    /// This frame's motion as a warp.
    warp: Warp,
    /// Whether this frame's shift search sums its (2S+1)^2 shifts, or only
    /// its histogram at the prediction (see [`Self::compare_with`]).
    search_shifts: bool,
    /// The warps of the current cell row's rows so far, by row within it:
    /// its hypotheses' pass reads them again at its last row (a tilted
    /// body's row costs a few thousand M4 instructions of `f64`).
    cell_row_warps: [RowWarp; MAX_CELL_PX],
    /// And their usable runs, where few.
    cell_row_runs: [KeptRuns; MAX_CELL_PX],
    parallax: Parallax,
    noise: Noise,
    alarm: Alarm,
    blobs: heapless::Vec<Blob, MAX_BLOBS>,
    /// The last compared frame's polar scan.
    scan: Scan,
    /// The frame in progress (begun, not yet ended or aborted).
    frame: u32,
    frame_active: bool,
    rows_seen: usize,
    profiler: Profiler,
    /// Tests: run the plain per-pixel reference instead of the fast paths.
    #[cfg(test)]
    reference: bool,
}

impl<'b> Gpa<'b> {
    /// Bytes of image memory [`Gpa::new`] needs for this grid: the
    /// keyframe and the current frame.
    pub fn keyframe_bytes(grid: &KgGrid) -> usize {
        2 * Keyframe::image_bytes(grid)
    }

    /// Bytes of each of the two buffers [`Gpa::init_split`] takes.
    pub fn image_bytes(grid: &KgGrid) -> usize {
        Keyframe::image_bytes(grid)
    }

    /// A detector with no rig and no keyframe buffer: a constant, so a
    /// target can hold it in a `static` and [`Gpa::init`] it in place (by
    /// value it is ~13 KB, and LLVM keeps stack temporaries of it).
    pub const EMPTY: Gpa<'static> = Gpa {
        config: GpaConfig::DEFAULT,
        layout: Layout::EMPTY,
        coverage: Coverage::EMPTY,
        keyframe: Keyframe::EMPTY,
        keyframe_travel: KeyframeTravel::NONE,
        prediction: Prediction::START,
        workspace: Workspace::EMPTY,
        odometry: None,
        imu: None,
        keyframe_imu: None,
        keyframe_attitude: KeyframeAttitude::NOMINAL,
        ground_attitude: GroundAttitude::NOMINAL,
        typical_misregistration: TypicalMisregistration(None),
        hazard_mask: HazardMask::EMPTY,
        keyframe_chain: Attitude { pitch_deg: 0.0, roll_deg: 0.0 },
        body_attitude: Attitude { pitch_deg: 0.0, roll_deg: 0.0 },
        measured: GroundMotion {
            planar: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
            attitude: Attitude { pitch_deg: 0.0, roll_deg: 0.0 },
        },
        odometry_fault: None,
        last_step: None,
        elapsed_s: None,
        last_elapsed_s: None,
        velocity_known: false,
        warp: Warp::NONE,
        search_shifts: true,
        cell_row_warps: [RowWarp::LEVEL; MAX_CELL_PX],
        cell_row_runs: [KeptRuns::NONE; MAX_CELL_PX],
        parallax: Parallax::EMPTY,
        noise: Noise::NONE,
        alarm: Alarm::NONE,
        blobs: heapless::Vec::new(),
        scan: Scan::EMPTY,
        frame: 0,
        frame_active: false,
        rows_seen: 0,
        profiler: Profiler::OFF,
        #[cfg(test)]
        reference: false,
    };

    /// Builds a detector by value (host convenience; see [`Gpa::init`]).
    pub fn new(
        rig: &Rig,
        grid: &KgGrid,
        table: &RemapTable,
        config: GpaConfig,
        keyframe: &'b mut [u8],
    ) -> Result<Gpa<'b>, GpaError> {
        let mut gpa = Gpa::EMPTY;
        gpa.init(rig, grid, table, config, keyframe)?;
        Ok(gpa)
    }

    /// (Re)initialises the detector in place for a rig, its two images in
    /// `images` ([`Gpa::keyframe_bytes`]); every earlier state (keyframe,
    /// noise, obstacle) is forgotten. On error it is left unchanged.
    pub fn init(&mut self, rig: &Rig, grid: &KgGrid, table: &RemapTable, config: GpaConfig, images: &'b mut [u8]) -> Result<(), GpaError> {
        let half = images.len() / 2;
        let (first, second) = images.split_at_mut(half);
        self.init_split(rig, grid, table, config, first, second)
    }

    /// As [`Gpa::init`], with the two images in buffers of their own
    /// ([`Gpa::image_bytes`] each), e.g. in two RAM banks.
    pub fn init_split(
        &mut self,
        rig: &Rig,
        grid: &KgGrid,
        table: &RemapTable,
        config: GpaConfig,
        first: &'b mut [u8],
        second: &'b mut [u8],
    ) -> Result<(), GpaError> {
        config.check()?;
        if table.grid_width() != grid.width() || table.grid_height() != grid.height() {
            return Err(GpaError::GridMismatch);
        }
        let needed = Self::image_bytes(grid);
        if first.len() < needed || second.len() < needed {
            return Err(GpaError::BufferTooSmall { needed });
        }
        self.config = config.for_grid(grid);
        self.keyframe_travel = KeyframeTravel::new(&config, grid, rig.height_mm());
        self.layout = Layout::new(rig, grid, config.cell_mm);
        self.coverage.init(grid, table, config.search_radius);
        self.keyframe = Keyframe::new(first, second, grid);
        self.prediction = Prediction::START;
        self.warp = Warp::NONE;
        self.workspace = Workspace::EMPTY;
        self.parallax.hypotheses = Hypotheses::NONE;
        self.parallax.clear(self.layout.camera_height_mm);
        self.noise = Noise::new(&config);
        self.typical_misregistration = TypicalMisregistration::default();
        self.hazard_mask.forget();
        self.ground_attitude = GroundAttitude::NOMINAL;
        self.alarm = Alarm::within(self.layout.aoi_mm());
        self.blobs = heapless::Vec::new();
        self.scan = Scan::new(scan_layout(&self.layout));
        self.frame = 0;
        self.frame_active = false;
        self.rows_seen = 0;
        self.profiler.profile = GpaProfile::default();
        Ok(())
    }

    /// Profiles `on_kg_row` per stage with `clock` (any monotonic counter;
    /// the firmware gives TIM2's instruction count). None turns it off.
    pub fn set_clock(&mut self, clock: Option<fn() -> u32>) {
        self.profiler.clock = clock;
    }

    /// Per-stage ticks of the current (or last) frame; see [`GpaProfile`].
    pub fn profile(&self) -> GpaProfile {
        self.profiler.profile
    }

    /// Forgets the keyframe: after a gap in frames or odometry the motion
    /// since the keyframe is unknown, so the next frame starts afresh
    /// instead of raising a false alarm.
    pub fn reset_keyframe(&mut self) {
        self.keyframe.forget();
        self.frame_active = false;
        self.alarm.forget();
        self.scan.forget();
        self.hazard_mask.forget();
    }

    /// Frame the current keyframe was taken at (if any).
    pub fn keyframe_frame(&self) -> Option<u32> {
        self.keyframe.taken_at()
    }

    /// Starts frame `frame`; `odometry` is the wheels' motion since the
    /// previous frame and `attitude` the IMU's (None: no such sensor).
    /// A frame that does not follow the last one restarts the keyframe.
    pub fn begin_frame(&mut self, frame: u32, odometry: Option<Motion>, attitude: Option<Attitude>) {
        self.begin_frame_at(frame, None, odometry, attitude);
    }

    /// [`Self::begin_frame`], `elapsed_s` after the last frame: without
    /// odometry the prior of the motion scales with it (tight at video
    /// rate, wide at a frame a second).
    pub fn begin_frame_at(&mut self, frame: u32, elapsed_s: Option<f64>, odometry: Option<Motion>, attitude: Option<Attitude>) {
        self.last_elapsed_s = self.elapsed_s;
        self.elapsed_s = elapsed_s.filter(|t| t.is_finite() && *t > 0.0);
        self.profiler.profile = GpaProfile::default();
        self.frame = frame;
        self.frame_active = true;
        self.rows_seen = 0;
        self.odometry = odometry;
        self.imu = attitude;
        self.odometry_fault = None;
        if !(self.keyframe.taken_at().is_some() && self.prediction.follows(frame)) {
            self.keyframe.forget();
        }
        if self.keyframe.taken_at().is_none() {
            self.velocity_known = false;
            self.start_keyframe();
            return;
        }
        let interval_ratio = self.elapsed_s.zip(self.last_elapsed_s).map(|(now, last)| now / last);
        self.prediction.predict(odometry.as_ref(), interval_ratio);
        self.keyframe.plan(false);
    }

    /// This frame has nothing to compare with: it only becomes the keyframe.
    fn start_keyframe(&mut self) {
        self.keyframe.restart();
        self.prediction.start_keyframe();
    }

    /// Lends the remap the memory the frame's end compares in, idle while
    /// the rows stream in: its ring of camera rows
    /// ([`crate::remap::StreamingRemap::store_row`]). The compare takes it
    /// back at the frame's end, so it holds no rows across frames.
    pub fn lend_ring(&mut self) -> &mut [u8] {
        self.workspace.ring()
    }

    /// Feeds KG row `j` of the current frame (rows arrive in order 0..height):
    /// it is stored; the comparison runs at the frame's end, once the
    /// motion has been measured on the whole image.
    pub fn on_kg_row(&mut self, j: usize, row: &[u8]) {
        let grid = &self.layout.grid;
        if !self.frame_active || j >= grid.height() || row.len() != grid.width() {
            return;
        }
        self.rows_seen = j + 1;
        let start = self.profiler.now();
        self.keyframe.write_row(j, row);
        self.profiler.charge(start, |p| &mut p.keyframe_update);
    }

    /// Abandons the current frame (dropped or broken mid-frame). The
    /// keyframe is untouched, but the next frame does not follow this one.
    pub fn abort_frame(&mut self) {
        self.frame_active = false;
    }

    /// Finishes the frame: measures the motion, compares every row, decides.
    /// Returns None for a frame that had no keyframe to compare with (the
    /// first one, one after [`Gpa::reset_keyframe`]): it only started the
    /// keyframe. A frame whose motion could not be measured, with no
    /// odometry either, restarts the keyframe from itself and gets a report
    /// that says so ([`NotJudged::NoMotion`], the alarm asserted).
    pub fn end_frame(&mut self) -> Option<FrameReport> {
        self.last_step = None;
        self.body_attitude = Attitude::default();
        if !self.frame_active {
            return None;
        }
        self.frame_active = false;
        if self.rows_seen < self.layout.grid.height() {
            // Incomplete: dropped. It is not taken as the last frame, so the
            // next one does not follow and restarts the keyframe.
            return None;
        }
        let report = self.keyframe.taken_at().map(|keyframe_frame| self.compare(keyframe_frame));
        let compared = report.as_ref().is_some_and(FrameReport::is_judged);
        self.last_step = compared.then_some(self.prediction.step);
        let new_keyframe = self.keyframe.finish(self.frame);
        if new_keyframe {
            self.keyframe_imu = self.imu;
            // The new keyframe's attitude relative to the ground starts
            // from GroundAttitude's, never from a failed frame's.
            self.keyframe_attitude = self.ground_attitude.keyframe();
            self.keyframe_chain = match compared {
                true => chain_keyframe(&self.keyframe_chain, &self.measured.attitude),
                false => Attitude::default(),
            };
        }
        self.prediction.finish(self.frame, new_keyframe);
        report
    }

    /// The prior for this frame's motion: the prediction, as sure as the
    /// odometry (or, without it, the largest step the robot may make), and
    /// the IMU's attitude change when there is one.
    fn prior(&self) -> Prior {
        let predicted = self.prediction.predicted;
        let config = &self.config;
        let grid = &self.layout.grid;
        let view_depth_mm = grid.height() as f64 * grid.mm_per_px;
        // The widest reach: a fifth of the view's depth (a car's 1.2 m, a
        // small robot's 200 mm), 3 sigma.
        let reach_mm = config.max_step_mm.max(0.2 * view_depth_mm);
        let (translation, yaw) = match (self.odometry, self.velocity_known, self.elapsed_s) {
            (Some(step), _, _) => (config.odometry_sigma_fraction * step.distance_mm() + config.odometry_sigma_mm, config.odometry_sigma_yaw_deg + 0.2 * libm::fabs(step.dyaw_deg)),
            (None, true, Some(dt)) => (
                (config.max_acceleration_mm_s2 * dt * dt).clamp(grid.mm_per_px, reach_mm / 3.0),
                (config.max_yaw_acceleration_deg_s2 * dt * dt).clamp(0.2, config.max_step_yaw_deg / 3.0),
            ),
            // No velocity yet: as far as the robot may have driven since
            // the last frame, at most the widest reach.
            (None, _, dt) => {
                let driven_mm = dt.map_or(reach_mm, |dt| (config.max_speed_view_depths_per_s * view_depth_mm * dt).max(3.0 * grid.mm_per_px));
                (reach_mm.min(driven_mm) / 3.0, config.max_step_yaw_deg / 3.0)
            }
        };
        let (attitude, tilt_sigma) = match (self.imu, self.keyframe_imu) {
            (Some(now), Some(then)) => (now.since(&then), config.imu_sigma_deg),
            _ => (Attitude::default(), config.max_attitude_change_deg / 3.0),
        };
        Prior { motion: GroundMotion { planar: predicted, attitude }, sigma: [translation, translation, yaw, tilt_sigma, tilt_sigma] }
    }

    /// Measures the motion, compares the stored rows with the keyframe and
    /// decides; a report not judged ([`NotJudged::NoMotion`]) when the
    /// motion cannot be known (no odometry and a ground without texture):
    /// the frame restarts the keyframe instead.
    fn compare(&mut self, keyframe_frame: u32) -> FrameReport {
        let prior = self.prior();
        let estimate = self.estimate(&prior);
        self.compare_with(keyframe_frame, prior, estimate)
    }

    /// The motion from the keyframe, measured on the two images.
    // Not inlined, nor is `compare_with`: the estimate's deep calls then
    // stand on a small frame, not on the row stages' locals (3.6 KB).
    #[inline(never)]
    fn estimate(&mut self, prior: &Prior) -> Option<Estimate> {
        let scene = Scene {
            keyframe: self.keyframe.keyframe_image(),
            current: self.keyframe.current_image(),
            grid: &self.layout.grid,
            coverage: &self.coverage,
            height_mm: self.layout.camera_height_mm,
            keyframe_attitude: self.keyframe_attitude,
            typical: self.typical_misregistration,
            hazards: self.hazard_mask.moved(self.frame, self.prediction.step.tz_mm / self.layout.grid.mm_per_px),
            sin_cos: SinCosMemo::new(),
        };
        let since = self.profiler.now();
        let clock = self.profiler.clock;
        let mut parts = GpaProfile::default();
        let mut estimate = None;
        let mut prediction_untrusted = false;
        // A predicted motion (the odometry's, or the last measured velocity)
        // under a prior wider than the alignment reaches: the prediction is
        // tried first, and step 1 searches only when its alignment fails.
        let predicted = self.odometry.is_some() || self.velocity_known;
        if predicted && !prior.within_alignment_reach(&self.layout.grid) {
            let estimator = self.workspace.estimator();
            estimator.profiler = Profiler { clock, profile: parts };
            match estimator.estimate_from_prediction(&scene, prior) {
                Ok(found) => estimate = Some(found),
                Err(unmeasured) => prediction_untrusted = unmeasured == Unmeasured::Untrusted,
            }
            parts = estimator.profiler.profile;
        }
        if estimate.is_none() {
            let coarse_since = self.profiler.now();
            let start = Estimator::coarse_start(|| self.workspace.coarse(), &scene, prior);
            self.profiler.charge(coarse_since, |p| &mut p.estimate_coarse);
            let estimator = self.workspace.estimator();
            estimator.profiler = Profiler { clock, profile: parts };
            estimate = estimator.estimate(&scene, prior, start, prediction_untrusted);
            parts = estimator.profiler.profile;
        }
        self.typical_misregistration = self.workspace.estimator().typical;
        self.profiler.charge(since, |p| &mut p.estimate);
        let profile = &mut self.profiler.profile;
        (profile.estimate_pyramids, profile.estimate_align, profile.estimate_nearest_surface, profile.estimate_lower_level) =
            (parts.estimate_pyramids, parts.estimate_align, parts.estimate_nearest_surface, parts.estimate_lower_level);
        estimate
    }

    /// The rest of [`Self::compare`]: the frame compared under the
    /// measured motion (or the prior's), and decided.
    #[inline(never)]
    fn compare_with(&mut self, keyframe_frame: u32, prior: Prior, estimate: Option<Estimate>) -> FrameReport {
        if let Some(estimate) = &estimate {
            self.keyframe_attitude = estimate.keyframe_attitude;
            self.ground_attitude.measured(estimate, self.config.max_attitude_change_deg as f32);
        } else {
            self.ground_attitude.unmeasured();
        }
        self.velocity_known = estimate.is_some();
        let measured = match (estimate, self.odometry) {
            (Some(estimate), _) => estimate.motion,
            (None, Some(_)) => prior.motion,
            (None, None) => {
                // Not judged: the alarm is asserted, and its hold and the
                // scan keep the last judged frame's hazards (no clear is
                // decided here).
                self.keyframe.restart();
                self.prediction.start_keyframe();
                return FrameReport::not_judged(self.frame, keyframe_frame, NotJudged::NoMotion);
            }
        };
        self.body_attitude = self.keyframe_chain.then(&measured.attitude);
        // An exposure step between the frames: the current rows are
        // brought to the keyframe's brightness, or every textured pixel
        // would differ. (Within 1 % a gain is left alone: noise.)
        let gain = estimate.map_or(1.0, |estimate| estimate.gain);
        let exposure = (libm::fabsf(gain - 1.0) > 0.01).then(|| exposure_table(gain));
        // The seed's own search around the prediction: the report's shift
        // and statistics are what the seed's GPA, trusting it, would see.
        let seed_apart = measured != prior.motion;
        // The search around the measured motion needs its shifts only to
        // refine a motion the images did not measure, or to be the seed's
        // search too; else its histogram (the noise) is all that is read,
        // and the band needs only the residue's rows.
        self.search_shifts = estimate.is_none() || !seed_apart;
        // The rows are read from the store while the stages write their sums.
        let mut store = core::mem::replace(&mut self.keyframe, Keyframe::EMPTY);
        let due = self.compare_at(&store, measured, exposure.as_ref());
        if seed_apart {
            let start = self.profiler.now();
            self.search_prediction(&store, &prior.motion, exposure.as_ref());
            self.profiler.charge(start, |p| &mut p.seed_search);
        }
        store.plan(due);
        self.keyframe = store;
        self.odometry_fault = self.odometry.map(|odometry| self.disagrees(&odometry, &self.prediction.step, estimate.is_some()));
        // Without an estimate the attitude change is the prior's: an IMU's
        // measurement, or without one a guess (level, 1 degree).
        let drops_looked_for = estimate.is_some() || prior.sigma[3].max(prior.sigma[4]) <= self.config.drop_imu_sigma_limit_deg;
        self.decide(keyframe_frame, &prior.motion.planar, seed_apart, drops_looked_for, estimate.is_some())
    }

    /// Fills the seed's search (`self.seed`) around the `predicted` motion:
    /// the shift search's part of the row step, on every AOI row. As the
    /// seed sees it: its rig is level and it knows the planar motion only,
    /// so its rows are straight; and it shifts the motion-compensated
    /// keyframe in the current frame's rows, so the band rolls on by a line
    /// a row, turning or not.
    // Not inlined, nor is `compare_at`: their row buffers stay out of
    // `compare_with`'s frame, which the obstacle search stands on.
    #[inline(never)]
    fn search_prediction(&mut self, store: &Keyframe, predicted: &GroundMotion, exposure: Option<&[u8; 256]>) {
        let s = self.config.search_radius;
        let level = GroundMotion { planar: predicted.planar, attitude: Attitude::default() };
        let warp = Warp::new(&self.layout.grid, &level, &Attitude::default(), self.layout.camera_height_mm);
        let (grid, aoi) = (&self.layout.grid, &self.layout.aoi);
        let rows = self.workspace.rows();
        rows.seed.clear();
        rows.band.forget();
        let mut runs = warp::Runs::new();
        let mut adjusted = [0u8; MAX_GRID_SIDE];
        for j in aoi.top..aoi.bottom.min(self.layout.analysis_rows) {
            let Some(seen) = self.coverage.seen(j) else { continue };
            // Only the AOI's columns are searched: the band is sampled there.
            let searched = |r: usize| self.coverage.seen_within(r, grid).map(|seen| seen.start.max(aoi.left)..seen.end.min(aoi.right)).filter(|c| !c.is_empty());
            let row_warp = rows.band.sample_current_rows(store, j, &warp, s, searched);
            self.coverage.usable_runs(row_warp, seen, grid, &mut runs);
            let row = exposed(store.current_row(j), exposure, &mut adjusted);
            rows.seed.add_row(row, &rows.band.rows(s), s, &runs, aoi, self.layout.in_far_half(j), true, false);
        }
    }

    /// Compares every stored row of the current frame with the keyframe in
    /// `store` at the motion `measured` (keyframe -> now), through
    /// `exposure` (current level -> keyframe brightness) when there is one;
    /// returns whether this frame, so far from the keyframe, replaces it.
    #[inline(never)]
    fn compare_at(&mut self, store: &Keyframe, measured: GroundMotion, exposure: Option<&[u8; 256]>) -> bool {
        self.measured = measured;
        let to_last = self.prediction.to_last();
        let planar = measured.planar;
        let step = Motion { tx_mm: planar.tx_mm - to_last.tx_mm, tz_mm: planar.tz_mm - to_last.tz_mm, dyaw_deg: planar.dyaw_deg - to_last.dyaw_deg };
        self.prediction.predicted = planar;
        self.prediction.step = step;
        let grid = &self.layout.grid;
        self.parallax.hypotheses = Hypotheses::plan(&planar, &step, grid, &self.config, self.layout.camera_height_mm);
        self.warp = Warp::new(grid, &measured, &self.keyframe_attitude.attitude(), self.layout.camera_height_mm);
        let rows = self.workspace.rows();
        rows.search.clear();
        rows.residue.clear();
        rows.band.forget();
        self.parallax.clear(self.layout.camera_height_mm);
        let mut adjusted = [0u8; MAX_GRID_SIDE];
        for j in 0..self.layout.analysis_rows {
            let row = exposed(store.current_row(j), exposure, &mut adjusted);
            #[cfg(test)]
            if self.reference {
                self.compare_row_reference(store, j, row);
                continue;
            }
            self.compare_row(store, j, row, exposure);
        }
        keyframe::is_due(&planar, &step, &self.keyframe_travel, &self.config)
    }

    /// Whether the odometry's step disagrees with the step seen on the
    /// ground beyond their noise (slip, a wrong wheel size).
    fn disagrees(&self, odometry: &Motion, seen: &Motion, measured: bool) -> bool {
        if !measured {
            return false;
        }
        let config = &self.config;
        let apart = libm::hypot(odometry.tx_mm - seen.tx_mm, odometry.tz_mm - seen.tz_mm);
        let allowed = 3.0 * (config.odometry_sigma_fraction * odometry.distance_mm() + config.odometry_sigma_mm);
        apart > allowed || libm::fabs(odometry.dyaw_deg - seen.dyaw_deg) > 3.0 * config.odometry_sigma_yaw_deg + 0.6 * libm::fabs(odometry.dyaw_deg)
    }

    /// The frame's sums decide: refined motion, noise, obstacle, alarm.
    /// `predicted` is the prediction; `seed_apart`: the seed's search ran
    /// around it apart from the measured motion's (else they are one).
    /// `drops_looked_for`: the attitude change was measured (else drops,
    /// whose parallax an attitude error mimics, are not looked for).
    fn decide(&mut self, keyframe_frame: u32, predicted: &Motion, seed_apart: bool, drops_looked_for: bool, estimated: bool) -> FrameReport {
        let (seed_sum, seed_count, seed_fit) = self.settle_searches(predicted, seed_apart, estimated);
        let (shift_k, shift_g) = (seed_fit.shift_k, seed_fit.shift_g);
        let rows = self.workspace.rows();
        let baseline_mm = self.prediction.predicted.distance_mm();
        let short_baseline = baseline_mm < 0.5 * self.config.keyframe_travel_mm;
        let (layout, config) = (&self.layout, &self.config);
        self.scan.begin(self.frame);
        let last_frame = self.hazard_mask.moved(self.frame, self.prediction.step.tz_mm / layout.grid.mm_per_px);
        let evidence = obstacles::parallax_obstacle(layout, &self.parallax.height, &rows.residue, config, short_baseline, drops_looked_for, last_frame, &mut self.scan);
        let parallax = evidence.hazard;
        self.alarm.sees_beyond_the_aoi(evidence.beyond);
        self.blobs = obstacles::residue_blobs(layout, &rows.residue, config);
        let residue = obstacles::nearest_residue_obstacle(&self.blobs, layout, &rows.residue, config);
        let moving = obstacles::moving_obstacle(layout, &self.parallax.height);
        let (parallax, residue, placed_by_moving) = obstacles::weigh_moving(parallax, residue, moving, evidence.moves_along, layout.cell_mm());
        self.alarm.sees_drops_from(self.parallax.hypotheses.shallowest_drop_mm);
        let hazard = self.alarm.decide(parallax, residue, baseline_mm, drops_looked_for, config, &self.prediction.step);
        if placed_by_moving {
            self.alarm.placed_by_a_thing_moving_along();
        }
        self.hazard_mask.record(self.frame, layout.cells, &self.parallax.height, &rows.residue, config);
        let obstacle = hazard.map(|(footprint, _)| footprint);
        self.finish_scan(obstacle);
        let motion = self.prediction.to_last();
        let angle = |degrees: f64| libm::round(degrees * f64::from(ANGLE_SCALE)) as i32;
        FrameReport {
            frame: self.frame,
            ref_frame: keyframe_frame,
            alarm: obstacle.is_some(),
            nearest_mm: obstacle.map(|o| o.near_mm),
            left_mm: obstacle.map(|o| o.left_mm),
            right_mm: obstacle.map(|o| o.right_mm),
            sad: seed_sum,
            count50: seed_count,
            shift_k: libm::round(shift_k * f64::from(SHIFT_SCALE)) as i32,
            shift_g: libm::round(shift_g * f64::from(SHIFT_SCALE)) as i32,
            tx: libm::round(motion.tx_mm * f64::from(MOTION_SCALE)) as i32,
            tz: libm::round(motion.tz_mm * f64::from(MOTION_SCALE)) as i32,
            obstacle_h_mm: hazard.and_then(|(_, height)| height),
            dyaw: angle(motion.dyaw_deg),
            dpitch: angle(self.measured.attitude.pitch_deg),
            droll: angle(self.measured.attitude.roll_deg),
            odometry_fault: self.odometry_fault,
            status: Status::Ok,
        }
    }

    /// The shift searches' part of [`Self::decide`]: the motion refined
    /// and the noise level updated from the search around the measured
    /// motion; the report's statistics (sum and count of the large
    /// differences) and shift from the seed's.
    // Not inlined: its two 1 KB histograms stay off the obstacle search's stack.
    #[inline(never)]
    fn settle_searches(&mut self, predicted: &Motion, seed_apart: bool, estimated: bool) -> (u32, u32, shift_search::ShiftFit) {
        let measured = self.prediction.predicted;
        let rows = self.workspace.rows();
        // The estimate's motion stands: it modelled what is not ground (a
        // drop's lower level, a box) that the search's one shift over the
        // AOI averages in. Without one, the search refines the prior.
        let refined = if estimated { Some(measured) } else { rows.search.fit(self.config.search_radius, &measured, &self.layout).refined };
        self.prediction.settle(refined, self.layout.grid.mm_per_px);
        self.noise.update(&rows.search.histogram(), &self.config);
        // The seed's own search summed its statistics; the one around the
        // measured motion keeps them in its histogram.
        let (seed, (sum, count)) = if seed_apart { (&rows.seed, rows.seed.seed_sums) } else { (&rows.search, kernels::seed_statistics(&rows.search.histogram())) };
        (sum, count, seed.fit(self.config.search_radius, predicted, &self.layout))
    }

    /// The scan's last steps: the last frame's hazards held when the alarm
    /// is (a baseline too short to see them, and nothing new found), the
    /// decided obstacle, the view; then this frame's hazards are kept for
    /// the next.
    fn finish_scan(&mut self, obstacle: Option<obstacles::Footprint>) {
        if self.alarm.source() == AlarmSource::Held {
            self.scan.hold(&self.prediction.step);
        }
        if let Some(o) = obstacle {
            self.scan.add_span(f64::from(o.near_mm), f64::from(o.left_mm), f64::from(o.right_mm));
        }
        let (layout, residue) = (&self.layout, &self.workspace.rows().residue);
        let (grid, cells) = (&layout.grid, &layout.cells);
        let per_mm = (1.0 / grid.mm_per_px) as f32;
        let (x_left, z_far) = (grid.x_left_mm as f32, grid.z_far_mm as f32);
        let (width, rows) = (grid.width(), layout.analysis_rows);
        let cell_pixels = (cells.px * cells.px) as u32;
        let step_mm = layout.cell_mm() as f32;
        // Ground is seen where the frame compared at least half of its cell;
        // sampled a cell apart.
        self.scan.mark_view(step_mm, |x, z| {
            let (i, j) = ((x - x_left) * per_mm, (z_far - z) * per_mm);
            if j >= rows as f32 {
                return View::Blind;
            }
            if !(i >= 0.0 && j >= 0.0 && i < width as f32) {
                return View::Unseen;
            }
            let cell = (j as usize / cells.px) * cells.wide + i as usize / cells.px;
            match residue.cell_valid.get(cell) {
                Some(&valid) if u32::from(valid) * 2 >= cell_pixels => View::Seen,
                _ => View::Unseen,
            }
        });
        self.scan.keep();
    }

    /// The last compared frame's polar scan (its frame is the report's).
    pub fn scan(&self) -> &Scan {
        &self.scan
    }

    /// Puts the frame's final report's obstacle (after fusion, which may
    /// raise it from GTI's heights) into the scan, so the scan never shows
    /// clear where the report claims an obstacle.
    pub fn scan_report(&mut self, report: &FrameReport) {
        if let (true, Some(near), Some(left), Some(right)) = (report.alarm, report.nearest_mm, report.left_mm, report.right_mm) {
            if report.frame == self.scan.frame() {
                self.scan.add_span(f64::from(near), f64::from(left), f64::from(right));
            }
        }
    }

    /// Blobs found in the last frame (for pictures and tests).
    pub fn blobs(&self) -> &[Blob] {
        &self.blobs
    }
    /// What the last frame measured in a cell (row 0 the farthest), for
    /// pictures and `flatland detect --cells`: nothing outside the cells.
    pub fn cell_evidence(&self, row: usize, column: usize) -> CellEvidence {
        let cells = &self.layout.cells;
        if row >= cells.high || column >= cells.wide {
            return CellEvidence::default();
        }
        let cell = row * cells.wide + column;
        let height = &self.parallax.height;
        CellEvidence {
            height_mm: height.any(cell),
            weak: height.is_weak(cell),
            moving: height.moving(cell),
            residue_percent: self.workspace.rows_ref().map_or(0, |rows| rows.residue.percent(cell, cells.px)),
        }
    }

    /// How certain the last frame's heights are: the least height and the
    /// shallowest drop its baseline tells from the ground (a cell's height
    /// below them is noise, however textured the cell). Infinite when the
    /// frame compared nothing.
    pub fn resolution(&self) -> Resolution {
        let hypotheses = &self.parallax.hypotheses;
        Resolution { least_height_mm: hypotheses.least_height_mm, shallowest_drop_mm: hypotheses.shallowest_drop_mm }
    }

    /// Coherence cells (rows, columns).
    pub fn cells(&self) -> (usize, usize) {
        (self.layout.cells.high, self.layout.cells.wide)
    }
    pub fn cell_px(&self) -> usize {
        self.layout.cells.px
    }
    /// Which evidence raised the last frame's alarm.
    pub fn alarm_source(&self) -> AlarmSource {
        self.alarm.source()
    }
    pub fn predicted(&self) -> Motion {
        self.prediction.predicted
    }
    /// The ground's motion from the frame before to the last frame, as
    /// its comparison measured it; None when the last frame was not
    /// compared (it started a keyframe, or was dropped).
    pub fn measured_step(&self) -> Option<Motion> {
        self.last_step
    }

    /// The last frame's body attitude relative to the nominal one, as
    /// measured; nominal when it was not compared.
    pub fn body_attitude(&self) -> Attitude {
        self.body_attitude
    }
}

/// Over how many keyframes the chained attitude leaks back to nominal.
/// Each measured change carries a small bias (-0.01 to -0.04 deg of pitch
/// per pair on the level sample recordings), so the bare chain drifts
/// without bound over a long run. Step 6's fit is bounded but scatters
/// (0.07-0.37 deg off on the same recordings), too much for GTI's heights.
/// Nominal is the body's mean attitude by definition (the mount is
/// calibrated over a drive), so what departs from it (braking, a bump, a
/// camber) is the body's own and passes; leaking 1/16 per keyframe (1.6 m
/// of travel at the 100 mm spacing) bounds the drift to 16 biases.
const CHAIN_LEAK_KEYFRAMES: f64 = 16.0;

/// The next keyframe's chained attitude: the last one's and the measured
/// change to it, 1/[`CHAIN_LEAK_KEYFRAMES`] of it leaked back to nominal.
fn chain_keyframe(last: &Attitude, change: &Attitude) -> Attitude {
    let chained = last.then(change);
    let keep = 1.0 - 1.0 / CHAIN_LEAK_KEYFRAMES;
    Attitude { pitch_deg: keep * chained.pitch_deg, roll_deg: keep * chained.roll_deg }
}

/// The scan's sectors for a rig: wide enough for every analysed grid
/// column seen from the AOI's near edge, out to the AOI's far corners
/// (every obstacle the report can name is in range).
fn scan_layout(layout: &Layout) -> ScanLayout {
    let aoi = layout.aoi_mm();
    let grid = &layout.grid;
    let (x_left, _) = grid.pixel_to_ground(0.0, 0.0);
    let (x_right, _) = grid.pixel_to_ground(grid.width() as f64, 0.0);
    let half_angle = libm::atan2(libm::fabs(x_left).max(libm::fabs(x_right)), aoi.near.max(1.0)).to_degrees();
    ScanLayout::new(half_angle, aoi.near, libm::hypot(aoi.half_width, aoi.far))
}

/// Maps a current gray level to the keyframe's brightness under `gain`
/// (current over keyframe).
fn exposure_table(gain: f32) -> [u8; 256] {
    core::array::from_fn(|level| libm::roundf(level as f32 / gain).clamp(0.0, 255.0) as u8)
}

/// `row` through `exposure` into `adjusted`, or `row` itself without one.
fn exposed<'r>(row: &'r [u8], exposure: Option<&[u8; 256]>, adjusted: &'r mut [u8; MAX_GRID_SIDE]) -> &'r [u8] {
    let Some(table) = exposure else { return row };
    for (out, &value) in adjusted.iter_mut().zip(row) {
        *out = table[usize::from(value)];
    }
    &adjusted[..row.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A run of a thousand keyframes (100 m) whose every measured change
    /// is 0.03 deg off: the bare chain would end 30 deg off, the leaking
    /// one stays within 16 biases; and of a braking dip of 1.5 deg, half
    /// is still there 1.1 m later (11 keyframes: 1.5 x (15/16)^11 = 0.74).
    #[test]
    fn the_chained_attitude_drifts_no_further_than_16_biases() {
        let bias = Attitude { pitch_deg: -0.03, roll_deg: 0.03 };
        let mut chain = Attitude::default();
        for _ in 0..1000 {
            chain = chain_keyframe(&chain, &bias);
        }
        let bound = 0.03 * CHAIN_LEAK_KEYFRAMES;
        assert!(libm::fabs(chain.pitch_deg) <= bound && libm::fabs(chain.roll_deg) <= bound, "{chain:?}");
        let level = Attitude::default();
        let mut chain = chain_keyframe(&level, &Attitude { pitch_deg: 1.5, roll_deg: 0.0 });
        for _ in 0..10 {
            chain = chain_keyframe(&chain, &level);
        }
        assert!((chain.pitch_deg - 0.7375).abs() < 1e-3, "{chain:?}");
    }

    /// Without odometry and before a velocity is measured, the first step
    /// is searched for only as far as the robot drives over the frame
    /// interval at `max_speed_view_depths_per_s` (a third of that is the
    /// prior's sigma), never beyond the widest reach: at 30 frames/s the
    /// bound decides, at 1 frame/s the reach does, and without a frame
    /// time the reach.
    #[test]
    fn the_first_step_without_odometry_is_bounded_by_the_frame_interval() {
        let rig = row::tests::rig();
        let grid = KgGrid::for_rig(&rig, &crate::grid::GridConfig::default()).unwrap();
        let table = crate::remap::RemapTable::new(&rig, &grid).unwrap();
        let mut keyframe = std::vec![0u8; Gpa::keyframe_bytes(&grid)];
        let config = GpaConfig::default();
        let mut gpa = Gpa::new(&rig, &grid, &table, config, &mut keyframe).unwrap();
        let depth_mm = grid.height() as f64 * grid.mm_per_px;
        let reach_mm = config.max_step_mm.max(0.2 * depth_mm);
        for (elapsed_s, expected_mm) in [(Some(1.0 / 30.0), 2.0 * depth_mm / 30.0), (Some(1.0), reach_mm), (None, reach_mm)] {
            gpa.begin_frame_at(1, elapsed_s, None, None);
            let prior = gpa.prior();
            assert!((3.0 * prior.sigma[0] - expected_mm).abs() < 1e-9, "{elapsed_s:?}: {:?} vs {expected_mm}", prior.sigma);
            assert_eq!(prior.sigma[0], prior.sigma[1]);
        }
        assert!(2.0 * depth_mm / 30.0 < reach_mm, "the 30 frames/s case must be bounded by the speed");
    }
}

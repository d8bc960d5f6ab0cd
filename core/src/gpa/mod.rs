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
mod config;
mod decision;
mod keyframe;
mod layout;
mod obstacles;
mod parallax;
mod prediction;
mod residue;
mod row;
#[cfg(test)]
mod scenes;
mod shift_search;
mod warp;

/// The difference kernels the stages run (one name to change with them).
use crate::kernels;

pub use crate::limits::KEYFRAME_SPARE_ROWS;
pub use config::GpaConfig;
pub use decision::AlarmSource;
pub use obstacles::Blob;
pub use parallax::{DROP_STEPS, HEIGHT_FRACTIONS};
pub use shift_search::{SEED_COUNT_LEVEL, SEED_SUM_LEVEL};

use crate::geometry::Rig;
use crate::grid::KgGrid;
use crate::limits::MAX_BLOBS;
use crate::motion::Motion;
use crate::remap::RemapTable;
use crate::report::{FrameReport, MOTION_SCALE, SHIFT_SCALE};
use band::Band;
use decision::{Alarm, Noise};
use keyframe::Keyframe;
use layout::Layout;
use parallax::{Hypotheses, Parallax};
use prediction::Prediction;
use residue::Residue;
use shift_search::ShiftSearch;
use warp::{Coverage, Warp};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GpaError {
    /// search_radius is 0 or above [`crate::limits::MAX_SEARCH_RADIUS`], or a value is not finite/positive.
    Config,
    /// The keyframe buffer is smaller than [`Gpa::keyframe_bytes`].
    BufferTooSmall { needed: usize },
    /// The grid does not match the remap table.
    GridMismatch,
}

impl core::fmt::Display for GpaError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GpaError::Config => f.write_str("GPA config: search radius out of range, or a value not finite and positive"),
            GpaError::BufferTooSmall { needed } => write!(f, "keyframe buffer too small: {needed} bytes needed"),
            GpaError::GridMismatch => f.write_str("the grid does not match the remap table"),
        }
    }
}

impl core::error::Error for GpaError {}

/// Where one frame's `on_kg_row` time went, in ticks of the clock given to
/// [`Gpa::set_clock`] (0 without one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GpaProfile {
    /// Usable columns and the warped keyframe band (2S+1 rows per KG row).
    pub warp: u32,
    /// Tolerant residue and the per-cell residue counts.
    pub residue: u32,
    /// Height hypotheses: warped samples, per-cell SADs, per-cell decision.
    pub parallax: u32,
    /// The (2S+1)^2-shift SAD with the seed's statistics, and the |diff| histogram.
    pub shift_search: u32,
    /// Copying the row into the new keyframe.
    pub keyframe_update: u32,
}

/// The benchmark clock and what it measured.
struct Profiler {
    /// Instructions or ns; None: no profiling.
    clock: Option<fn() -> u32>,
    profile: GpaProfile,
}

impl Profiler {
    #[inline(always)]
    fn now(&self) -> u32 {
        match self.clock {
            Some(clock) => clock(),
            None => 0,
        }
    }

    /// Charges the ticks since `since` to `stage`; returns now.
    #[inline(always)]
    fn charge(&mut self, since: u32, stage: fn(&mut GpaProfile) -> &mut u32) -> u32 {
        let now = self.now();
        let total = stage(&mut self.profile);
        *total = total.wrapping_add(now.wrapping_sub(since));
        now
    }
}

/// The streaming GPA detector. See the module docs.
pub struct Gpa<'b> {
    config: GpaConfig,
    layout: Layout,
    coverage: Coverage,
    keyframe: Keyframe<'b>,
    prediction: Prediction,
    /// This frame's prediction as a warp.
    warp: Warp,
    band: Band,
    residue: Residue,
    parallax: Parallax,
    search: ShiftSearch,
    noise: Noise,
    alarm: Alarm,
    blobs: heapless::Vec<Blob, MAX_BLOBS>,
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
    /// Bytes the keyframe buffer needs for this grid.
    pub fn keyframe_bytes(grid: &KgGrid) -> usize {
        Keyframe::bytes(grid)
    }

    /// A detector with no rig and no keyframe buffer: a constant, so a
    /// target can hold it in a `static` and [`Gpa::init`] it in place (by
    /// value it is ~13 KB, and LLVM keeps stack temporaries of it).
    pub const EMPTY: Gpa<'static> = Gpa {
        config: GpaConfig::DEFAULT,
        layout: Layout::EMPTY,
        coverage: Coverage::EMPTY,
        keyframe: Keyframe::EMPTY,
        prediction: Prediction::START,
        warp: Warp::NONE,
        band: Band::EMPTY,
        residue: Residue::EMPTY,
        parallax: Parallax::EMPTY,
        search: ShiftSearch::EMPTY,
        noise: Noise::NONE,
        alarm: Alarm::NONE,
        blobs: heapless::Vec::new(),
        frame: 0,
        frame_active: false,
        rows_seen: 0,
        profiler: Profiler { clock: None, profile: GpaProfile { warp: 0, residue: 0, parallax: 0, shift_search: 0, keyframe_update: 0 } },
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

    /// (Re)initialises the detector in place for a rig; every earlier state
    /// (keyframe, noise, obstacle) is forgotten. On error it is left unchanged.
    pub fn init(
        &mut self,
        rig: &Rig,
        grid: &KgGrid,
        table: &RemapTable,
        config: GpaConfig,
        keyframe: &'b mut [u8],
    ) -> Result<(), GpaError> {
        config.check()?;
        if table.grid_width() != grid.width() || table.grid_height() != grid.height() {
            return Err(GpaError::GridMismatch);
        }
        let needed = Self::keyframe_bytes(grid);
        if keyframe.len() < needed {
            return Err(GpaError::BufferTooSmall { needed });
        }
        self.config = config;
        self.layout = Layout::new(rig, grid, config.cell_mm);
        self.coverage.init(grid, table, config.search_radius);
        self.keyframe = Keyframe::new(keyframe, grid);
        self.prediction = Prediction::START;
        self.warp = Warp::NONE;
        self.band.clear();
        self.search.clear();
        self.residue.clear();
        self.parallax.hypotheses = Hypotheses::NONE;
        self.parallax.clear();
        self.noise = Noise::new(&config);
        self.alarm = Alarm::NONE;
        self.blobs = heapless::Vec::new();
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
    }

    /// Frame the current keyframe was taken at (if any).
    pub fn keyframe_frame(&self) -> Option<u32> {
        self.keyframe.taken_at()
    }

    /// Starts frame `frame`; `odometry` is the motion since the previous
    /// frame (None if unknown: the keyframe is reset).
    pub fn begin_frame(&mut self, frame: u32, odometry: Option<Motion>) {
        self.profiler.profile = GpaProfile::default();
        self.band.forget();
        self.frame = frame;
        self.frame_active = true;
        self.rows_seen = 0;
        let consecutive = self.keyframe.taken_at().is_some() && self.prediction.follows(frame);
        match odometry {
            Some(step) if consecutive => self.prediction.predict(&step),
            _ => self.keyframe.forget(),
        }
        if self.keyframe.taken_at().is_none() {
            self.start_keyframe();
            return;
        }
        let (predicted, step) = (self.prediction.predicted, self.prediction.step);
        let grid = &self.layout.grid;
        self.parallax.hypotheses = Hypotheses::plan(&predicted, &step, grid, &self.config, self.layout.camera_height_mm);
        let replace = keyframe::is_due(&predicted, &step, &self.config);
        if replace && !self.parallax.hypotheses.keep_clear_of_update(&predicted, grid, self.config.search_radius) {
            // Moved too far to compare in place: start afresh from this frame.
            self.start_keyframe();
            return;
        }
        self.keyframe.plan(replace);
        self.warp = Warp::predicted(grid, &predicted);
        self.search.clear();
        self.residue.clear();
        self.parallax.clear();
    }

    /// This frame has nothing to compare with: it only becomes the keyframe.
    fn start_keyframe(&mut self) {
        self.keyframe.restart();
        self.prediction.start_keyframe();
    }

    /// Feeds KG row `j` of the current frame (rows arrive in order 0..height).
    pub fn on_kg_row(&mut self, j: usize, row: &[u8]) {
        let grid = &self.layout.grid;
        if !self.frame_active || j >= grid.height() || row.len() != grid.width() {
            return;
        }
        self.rows_seen = j + 1;
        if self.keyframe.taken_at().is_some() && j < self.layout.analysis_rows {
            #[cfg(test)]
            if self.reference {
                self.compare_row_reference(j, row);
            } else {
                self.compare_row(j, row);
            }
            #[cfg(not(test))]
            self.compare_row(j, row);
        }
        if self.keyframe.replacing() {
            let start = self.profiler.now();
            self.keyframe.write_row(j, row);
            self.profiler.charge(start, |p| &mut p.keyframe_update);
        }
    }

    /// Abandons the current frame (dropped or broken mid-frame). If it was
    /// overwriting the keyframe, the keyframe is gone too.
    pub fn abort_frame(&mut self) {
        if self.frame_active {
            self.keyframe.abort(self.rows_seen);
        }
        self.frame_active = false;
    }

    /// Finishes the frame. Returns None for a frame that only (re)started the keyframe.
    pub fn end_frame(&mut self) -> Option<FrameReport> {
        if !self.frame_active {
            return None;
        }
        self.frame_active = false;
        if self.rows_seen < self.layout.grid.height() {
            // Incomplete: dropped. It is not taken as the last frame, so the
            // next one does not follow and restarts the keyframe.
            return None;
        }
        let report = self.keyframe.taken_at().map(|keyframe_frame| self.decide(keyframe_frame));
        let new_keyframe = self.keyframe.finish(self.frame);
        self.prediction.finish(self.frame, new_keyframe);
        report
    }

    /// The frame's sums decide: refined motion, noise, obstacle, alarm.
    fn decide(&mut self, keyframe_frame: u32) -> FrameReport {
        let fit = self.search.fit(self.config.search_radius, &self.prediction.predicted, &self.layout);
        self.prediction.settle(fit.refined, self.layout.grid.mm_per_px);
        let histogram = self.search.histogram();
        let (seed_sum, seed_count) = kernels::seed_statistics(&histogram);
        self.noise.update(&histogram, &self.config);
        let baseline_mm = self.prediction.predicted.distance_mm();
        let short_baseline = baseline_mm < 0.5 * self.config.keyframe_travel_mm;
        let (layout, config) = (&self.layout, &self.config);
        let parallax = obstacles::parallax_obstacle(layout, &self.parallax.height, &self.residue, config, short_baseline);
        self.blobs = obstacles::residue_blobs(layout, &self.residue, config);
        let residue = obstacles::nearest_residue_obstacle(&self.blobs, layout, &self.residue, config);
        let hazard = self.alarm.decide(parallax, residue, baseline_mm, config, &self.prediction.step);
        let obstacle = hazard.map(|(footprint, _)| footprint);
        let motion = self.prediction.to_last();
        FrameReport {
            frame: self.frame,
            ref_frame: keyframe_frame,
            alarm: obstacle.is_some(),
            nearest_mm: obstacle.map(|o| o.near_mm),
            left_mm: obstacle.map(|o| o.left_mm),
            right_mm: obstacle.map(|o| o.right_mm),
            sad: seed_sum,
            count50: seed_count,
            shift_k: libm::round(fit.shift_k * f64::from(SHIFT_SCALE)) as i32,
            shift_g: libm::round(fit.shift_g * f64::from(SHIFT_SCALE)) as i32,
            tx: libm::round(motion.tx_mm * f64::from(MOTION_SCALE)) as i32,
            tz: libm::round(motion.tz_mm * f64::from(MOTION_SCALE)) as i32,
            obstacle_h_mm: hazard.and_then(|(_, height)| height),
        }
    }

    /// Blobs found in the last frame (for pictures and tests).
    pub fn blobs(&self) -> &[Blob] {
        &self.blobs
    }
    /// Parallax height (mm) of a cell in the last frame, 0 for ground,
    /// negative below it (a drop's lower level).
    pub fn cell_height(&self, row: usize, column: usize) -> i16 {
        let cells = &self.layout.cells;
        if row >= cells.high || column >= cells.wide {
            return 0;
        }
        self.parallax.height.get(row * cells.wide + column)
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
}

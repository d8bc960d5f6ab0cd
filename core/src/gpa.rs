//! GPA: the ground plane assumption detector (seed §3.1), streaming.
//!
//! One KG image, the keyframe, is stored. Each new frame's KG rows stream
//! by once; for every row the keyframe is warped by the predicted motion
//! (translation *and* yaw, a rotation in the KG plane about the robot
//! origin) into a small band of `2S+1` rows, and a single pass accumulates:
//! - the SAD of every shift in the `(2S+1)^2` window (the seed's search), plus
//!   the seed's statistics (sum of |diff| > 30, count of |diff| > 50);
//! - a misregistration-tolerant residue: each pixel against the *range* of
//!   its 3x3 neighbours in the warped keyframe, so sharp ground edges that
//!   are a pixel off leave nothing while displaced texture on an obstacle does;
//! - per-cell residue counts on a coarse grid, for blob coherence.
//!
//! Beyond the seed:
//! - **Keyframe**: the reference is the last frame at least
//!   `keyframe_travel_mm` back, so slow steps still see parallax. The new
//!   keyframe is written *in place* while the old one is read, through a
//!   row-circular buffer with spare rows (no second image).
//! - **Chained prediction**: the prediction for frame n is the *refined*
//!   motion keyframe->n-1 followed by odometry n-1->n, so odometry error
//!   never accumulates over the keyframe baseline.
//! - **Sub-pixel refinement**: a parabola through the SAD minimum per axis.
//! - **Normalised decision**: the pixel threshold follows the measured noise;
//!   blobs are measured in mm² of ground, so thresholds carry across cameras.
//! - **Look beyond the AOI**: the whole grid ahead of the AOI is analysed and
//!   a blob counts when its *base* (nearest point) lies in the AOI.
//! - **Obstacle position** from the nearest blob: distance ahead and lateral
//!   extent, in the robot frame.

use crate::geometry::Rig;
use crate::grid::{KgGrid, PixelRect, MAX_GRID_SIDE};
use crate::motion::Motion;
use crate::remap::RemapTable;
use crate::report::{FrameReport, MOTION_SCALE, SHIFT_SCALE};

/// Largest search radius S (the window is `(2S+1)^2` shifts).
pub const MAX_SEARCH_RADIUS: usize = 3;
const MAX_WINDOW: usize = 2 * MAX_SEARCH_RADIUS + 1;
/// Spare keyframe rows: how far (rows) the in-place keyframe update may run
/// ahead of the rows still being read. Bounds the travel per keyframe swap.
pub const KEYFRAME_SPARE_ROWS: usize = 64;
/// Coarse cells for blob analysis, per side.
pub const MAX_CELLS_SIDE: usize = 64;
/// Blobs tracked per frame.
pub const MAX_BLOBS: usize = 16;
/// The seed's levels: |diff| above 30 is summed, above 50 counted.
pub const SEED_SUM_LEVEL: u8 = 30;
pub const SEED_COUNT_LEVEL: u8 = 50;

/// Tuning, in physical units so it carries across cameras and grids.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpaConfig {
    /// Search radius S in KG pixels around the predicted shift.
    pub search_radius: usize,
    /// Travel since the keyframe at which the current frame becomes the keyframe.
    pub keyframe_travel_mm: f64,
    /// A residue pixel exceeds `max(residue_floor, noise_factor * noise)`.
    pub residue_floor: u8,
    pub noise_factor: f64,
    /// Side of a coherence cell, mm of ground.
    pub cell_mm: f64,
    /// A cell is hot when this percentage of its valid pixels are residue.
    pub hot_cell_percent: u32,
    /// Smallest blob (ground area of its hot cells) that counts as an obstacle.
    pub min_blob_area_mm2: f64,
}

impl Default for GpaConfig {
    fn default() -> Self {
        GpaConfig {
            search_radius: 2,
            keyframe_travel_mm: 100.0,
            residue_floor: 16,
            noise_factor: 4.0,
            cell_mm: 30.0,
            hot_cell_percent: 30,
            min_blob_area_mm2: 3000.0,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpaError {
    /// search_radius is 0 or above [`MAX_SEARCH_RADIUS`], or a value is not finite/positive.
    Config,
    /// The keyframe buffer is smaller than [`Gpa::keyframe_bytes`].
    BufferTooSmall { needed: usize },
    /// The grid does not match the remap table.
    GridMismatch,
}

/// A connected group of hot cells.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Blob {
    /// Cell bounds (inclusive).
    pub cell_left: u8,
    pub cell_right: u8,
    pub cell_top: u8,
    pub cell_bottom: u8,
    pub cells: u16,
    /// Residue pixels in the blob.
    pub pixels: u32,
}

/// Where the keyframe comes from for this frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum KeyframeState {
    /// No keyframe: the next frame becomes one and reports nothing.
    Empty,
    Valid,
}

/// Per-row warp: reference position of current column 0 and its per-column step, Q16.16.
#[derive(Clone, Copy, Debug, Default)]
struct RowWarp {
    i_start: i32,
    i_step: i32,
    j_start: i32,
    j_step: i32,
}

const FRAC: u32 = 16;

fn to_q16(value: f64) -> i32 {
    libm::round(value * 65536.0).clamp(-1.0e9, 1.0e9) as i32
}

/// The streaming GPA detector. See the module docs.
pub struct Gpa<'b> {
    config: GpaConfig,
    grid: KgGrid,
    aoi: PixelRect,
    /// Rows analysed: from the top of the grid (beyond the AOI) to the AOI's near edge.
    analysis_rows: usize,
    /// Valid reference columns for a sample centred on row j' (all taps in view), per row.
    reference_valid: [(u16, u16); MAX_GRID_SIDE],
    /// Current-frame valid columns per row.
    current_valid: [(u16, u16); MAX_GRID_SIDE],
    cell_px: usize,
    cells_wide: usize,
    cells_high: usize,

    keyframe: &'b mut [u8],
    keyframe_rows: usize,
    /// Slot of keyframe row 0 in the row-circular buffer.
    keyframe_base: usize,
    keyframe_state: KeyframeState,
    keyframe_frame: u32,
    /// Refined motion keyframe -> last frame.
    motion_to_last: Motion,
    last_frame: u32,

    // Per-frame state.
    frame: u32,
    predicted: Motion,
    becomes_keyframe: bool,
    /// Slot where the new keyframe's row 0 goes when this frame becomes the keyframe.
    new_base: usize,
    frame_active: bool,
    rows_seen: usize,
    warp_origin: (f64, f64),
    warp_column: (f64, f64),
    warp_row: (f64, f64),
    band: [[u8; MAX_GRID_SIDE + 2 * MAX_SEARCH_RADIUS]; MAX_WINDOW],
    sad: [[u32; MAX_WINDOW]; MAX_WINDOW],
    seed_sum: [[u32; MAX_WINDOW]; MAX_WINDOW],
    seed_count: [[u32; MAX_WINDOW]; MAX_WINDOW],
    compared_pixels: u32,
    /// Histogram of the plain |diff| at the predicted shift over the AOI (noise estimate).
    diff_hist: [u32; 256],
    cell_residue: [u8; MAX_CELLS_SIDE * MAX_CELLS_SIDE],
    cell_valid: [u8; MAX_CELLS_SIDE * MAX_CELLS_SIDE],
    /// Residue pixels per grid row (for the blob base).
    row_residue: [u16; MAX_GRID_SIDE],
    /// Noise level (gray levels, x16) measured on earlier frames.
    noise_x16: u32,
    residue_threshold: u8,
    previous_alarm: bool,
    blobs: heapless::Vec<Blob, MAX_BLOBS>,
}

impl<'b> Gpa<'b> {
    /// Bytes the keyframe buffer needs for this grid.
    pub fn keyframe_bytes(grid: &KgGrid) -> usize {
        (grid.height() + KEYFRAME_SPARE_ROWS) * grid.width()
    }

    pub fn new(
        rig: &Rig,
        grid: &KgGrid,
        table: &RemapTable,
        config: GpaConfig,
        keyframe: &'b mut [u8],
    ) -> Result<Gpa<'b>, GpaError> {
        let finite = [config.keyframe_travel_mm, config.noise_factor, config.cell_mm, config.min_blob_area_mm2];
        if config.search_radius == 0
            || config.search_radius > MAX_SEARCH_RADIUS
            || !finite.iter().all(|v| v.is_finite() && *v > 0.0)
        {
            return Err(GpaError::Config);
        }
        if table.grid_width() != grid.width() || table.grid_height() != grid.height() {
            return Err(GpaError::GridMismatch);
        }
        let needed = Self::keyframe_bytes(grid);
        if keyframe.len() < needed {
            return Err(GpaError::BufferTooSmall { needed });
        }
        let aoi = grid.aoi_pixels(rig);
        let cell_px = (libm::round(config.cell_mm / grid.mm_per_px) as usize).clamp(3, 15);
        let cells_wide = grid.width().div_ceil(cell_px).min(MAX_CELLS_SIDE);
        let cells_high = aoi.bottom.div_ceil(cell_px).min(MAX_CELLS_SIDE);
        let mut current_valid = [(0u16, 0u16); MAX_GRID_SIDE];
        for (j, slot) in current_valid.iter_mut().enumerate().take(grid.height()) {
            let range = table.valid_columns(j);
            *slot = (range.start as u16, range.end as u16);
        }
        // A reference sample around row j' touches rows j'-S-1 ..= j'+S+2 and
        // columns i'-S-1 ..= i'+S+2: keep the columns where all of them are in view.
        let reach = config.search_radius + 1;
        let mut reference_valid = [(0u16, 0u16); MAX_GRID_SIDE];
        for (j, slot) in reference_valid.iter_mut().enumerate().take(grid.height()) {
            let (mut lo, mut hi) = (0usize, grid.width());
            for r in j as isize - reach as isize..=(j + reach + 1) as isize {
                let range = if r < 0 || r as usize >= grid.height() { 0..0 } else { table.valid_columns(r as usize) };
                lo = lo.max(range.start);
                hi = hi.min(range.end);
            }
            let (lo, hi) = (lo + reach, hi.saturating_sub(reach + 1));
            *slot = if hi > lo { (lo as u16, hi as u16) } else { (0, 0) };
        }
        Ok(Gpa {
            config,
            grid: *grid,
            aoi,
            analysis_rows: aoi.bottom,
            reference_valid,
            current_valid,
            cell_px,
            cells_wide,
            cells_high,
            keyframe,
            keyframe_rows: grid.height() + KEYFRAME_SPARE_ROWS,
            keyframe_base: 0,
            keyframe_state: KeyframeState::Empty,
            keyframe_frame: 0,
            motion_to_last: Motion::default(),
            last_frame: 0,
            frame: 0,
            predicted: Motion::default(),
            becomes_keyframe: false,
            new_base: 0,
            frame_active: false,
            rows_seen: 0,
            warp_origin: (0.0, 0.0),
            warp_column: (0.0, 0.0),
            warp_row: (0.0, 0.0),
            band: [[0; MAX_GRID_SIDE + 2 * MAX_SEARCH_RADIUS]; MAX_WINDOW],
            sad: [[0; MAX_WINDOW]; MAX_WINDOW],
            seed_sum: [[0; MAX_WINDOW]; MAX_WINDOW],
            seed_count: [[0; MAX_WINDOW]; MAX_WINDOW],
            compared_pixels: 0,
            diff_hist: [0; 256],
            cell_residue: [0; MAX_CELLS_SIDE * MAX_CELLS_SIDE],
            cell_valid: [0; MAX_CELLS_SIDE * MAX_CELLS_SIDE],
            row_residue: [0; MAX_GRID_SIDE],
            noise_x16: 0,
            residue_threshold: config.residue_floor,
            previous_alarm: false,
            blobs: heapless::Vec::new(),
        })
    }

    /// Forgets the keyframe: after a gap in frames or odometry the motion
    /// since the keyframe is unknown, so the next frame starts afresh
    /// instead of raising a false alarm.
    pub fn reset_keyframe(&mut self) {
        self.keyframe_state = KeyframeState::Empty;
        self.frame_active = false;
        self.previous_alarm = false;
    }

    /// Frame the current keyframe was taken at (if any).
    pub fn keyframe_frame(&self) -> Option<u32> {
        (self.keyframe_state == KeyframeState::Valid).then_some(self.keyframe_frame)
    }

    /// Starts frame `frame`; `odometry` is the motion since the previous
    /// frame (None if unknown: the keyframe is reset).
    pub fn begin_frame(&mut self, frame: u32, odometry: Option<Motion>) {
        self.frame = frame;
        self.frame_active = true;
        self.rows_seen = 0;
        let consecutive = self.keyframe_state == KeyframeState::Valid && frame == self.last_frame.wrapping_add(1);
        match odometry {
            Some(step) if consecutive => {
                self.predicted = self.motion_to_last.then(&step);
            }
            _ => self.keyframe_state = KeyframeState::Empty,
        }
        if self.keyframe_state == KeyframeState::Empty {
            self.predicted = Motion::default();
            self.becomes_keyframe = true;
            self.new_base = self.keyframe_base;
            return;
        }
        // This frame replaces the keyframe if the baseline is long enough and
        // the in-place update stays behind the rows still being read.
        let shift_rows = self.predicted.tz_mm / self.grid.mm_per_px;
        let yaw_rows = libm::fabs(libm::sin(self.predicted.dyaw_deg.to_radians())) * self.grid.width() as f64;
        let lead = libm::ceil(libm::fabs(shift_rows) + yaw_rows) as usize + self.config.search_radius + 2;
        self.becomes_keyframe =
            self.predicted.distance_mm() >= self.config.keyframe_travel_mm && lead < KEYFRAME_SPARE_ROWS;
        self.new_base = (self.keyframe_base + self.keyframe_rows - KEYFRAME_SPARE_ROWS) % self.keyframe_rows;

        // Current pixel (i, j) -> keyframe pixel: ground point, then back through the motion.
        let warp = |i: f64, j: f64| {
            let (x, z) = self.grid.pixel_to_ground(i, j);
            let (xk, zk) = self.predicted.to_earlier_frame(x, z);
            self.grid.ground_to_pixel(xk, zk)
        };
        let origin = warp(0.0, 0.0);
        let along = warp(1.0, 0.0);
        let down = warp(0.0, 1.0);
        self.warp_origin = origin;
        self.warp_column = (along.0 - origin.0, along.1 - origin.1);
        self.warp_row = (down.0 - origin.0, down.1 - origin.1);

        self.sad = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.seed_sum = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.seed_count = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.compared_pixels = 0;
        self.diff_hist = [0; 256];
        self.cell_residue = [0; MAX_CELLS_SIDE * MAX_CELLS_SIDE];
        self.cell_valid = [0; MAX_CELLS_SIDE * MAX_CELLS_SIDE];
        self.row_residue = [0; MAX_GRID_SIDE];
    }

    fn row_warp(&self, j: usize) -> RowWarp {
        let jf = j as f64;
        RowWarp {
            i_start: to_q16(self.warp_origin.0 + self.warp_row.0 * jf),
            i_step: to_q16(self.warp_column.0),
            j_start: to_q16(self.warp_origin.1 + self.warp_row.1 * jf),
            j_step: to_q16(self.warp_column.1),
        }
    }

    fn keyframe_row(&self, base: usize, j: usize) -> &[u8] {
        let slot = (base + j) % self.keyframe_rows;
        &self.keyframe[slot * self.grid.width()..][..self.grid.width()]
    }

    /// Bilinear sample of the keyframe at (i, j) Q16.16; the caller guarantees
    /// the 2x2 neighbourhood is inside the grid.
    fn sample_keyframe(&self, i: i32, j: i32) -> u8 {
        let (i0, j0) = ((i >> FRAC) as usize, (j >> FRAC) as usize);
        let wx = ((i >> 8) & 0xFF) as u32;
        let wy = ((j >> 8) & 0xFF) as u32;
        let upper = self.keyframe_row(self.keyframe_base, j0);
        let lower = self.keyframe_row(self.keyframe_base, j0 + 1);
        let top = u32::from(upper[i0]) * (256 - wx) + u32::from(upper[i0 + 1]) * wx;
        let bottom = u32::from(lower[i0]) * (256 - wx) + u32::from(lower[i0 + 1]) * wx;
        ((top * (256 - wy) + bottom * wy + (1 << 15)) >> 16) as u8
    }

    /// Feeds KG row `j` of the current frame (rows arrive in order 0..height).
    pub fn on_kg_row(&mut self, j: usize, row: &[u8]) {
        if !self.frame_active || j >= self.grid.height() || row.len() != self.grid.width() {
            return;
        }
        self.rows_seen = j + 1;
        if self.keyframe_state == KeyframeState::Valid && j < self.analysis_rows {
            self.compare_row(j, row);
        }
        if self.becomes_keyframe {
            // Written S+2+lead rows behind the reads by construction of new_base.
            let slot = (self.new_base + j) % self.keyframe_rows;
            let width = self.grid.width();
            self.keyframe[slot * width..][..width].copy_from_slice(row);
        }
    }

    fn compare_row(&mut self, j: usize, row: &[u8]) {
        let s = self.config.search_radius;
        let width = self.grid.width();
        let warp = self.row_warp(j);
        let (cur_lo, cur_hi) = self.current_valid[j];
        let (cur_lo, cur_hi) = (usize::from(cur_lo), usize::from(cur_hi));
        if cur_hi <= cur_lo {
            return;
        }
        // Warp the keyframe into the band: band[dg + S][c + S] = keyframe at
        // warp(c) + (0, dg), for columns c in [cur_lo - S, cur_hi + S).
        let rows_limit = (self.grid.height() as i32 - 1) << FRAC;
        let mut usable = [false; MAX_GRID_SIDE];
        for c in cur_lo..cur_hi {
            let i_ref = warp.i_start.wrapping_add((c as i32).wrapping_mul(warp.i_step));
            let j_ref = warp.j_start.wrapping_add((c as i32).wrapping_mul(warp.j_step));
            let (i0, j0) = (i_ref >> FRAC, j_ref >> FRAC);
            usable[c] = j_ref >= 0
                && j_ref < rows_limit
                && i0 >= 0
                && (i0 as usize) < width
                && {
                    let (lo, hi) = self.reference_valid[j0 as usize];
                    (i0 as usize) >= usize::from(lo) && (i0 as usize) < usize::from(hi)
                };
        }
        let first = cur_lo.saturating_sub(s);
        let last = (cur_hi + s).min(width);
        for dg in 0..=2 * s {
            for c in first..last {
                let i_ref = warp.i_start.wrapping_add((c as i32).wrapping_mul(warp.i_step));
                let j_ref = warp.j_start.wrapping_add((c as i32).wrapping_mul(warp.j_step)) + ((dg as i32 - s as i32) << FRAC);
                let inside = i_ref >= 0 && (i_ref >> FRAC) + 1 < width as i32 && j_ref >= 0 && j_ref < rows_limit;
                let value = if inside { self.sample_keyframe(i_ref, j_ref) } else { 0 };
                self.band[dg][c + MAX_SEARCH_RADIUS] = value;
            }
        }
        let in_aoi_row = j >= self.aoi.top && j < self.aoi.bottom;
        let cell_row = j / self.cell_px;
        let threshold = self.residue_threshold;
        for c in cur_lo..cur_hi {
            if !usable[c] {
                continue;
            }
            let value = row[c];
            let centre = c + MAX_SEARCH_RADIUS;
            // Tolerant residue against the 3x3 neighbourhood of the prediction.
            let (mut low, mut high) = (u8::MAX, u8::MIN);
            for dg in s - 1..=s + 1 {
                for dk in 0..3 {
                    let v = self.band[dg][centre + dk - 1];
                    low = low.min(v);
                    high = high.max(v);
                }
            }
            let residue = value.saturating_sub(high).max(low.saturating_sub(value));
            let cell = cell_row * MAX_CELLS_SIDE + c / self.cell_px;
            if cell_row < self.cells_high && c / self.cell_px < self.cells_wide {
                self.cell_valid[cell] = self.cell_valid[cell].saturating_add(1);
                if residue > threshold {
                    self.cell_residue[cell] = self.cell_residue[cell].saturating_add(1);
                    self.row_residue[j] = self.row_residue[j].saturating_add(1);
                }
            }
            if in_aoi_row && c >= self.aoi.left && c < self.aoi.right {
                self.diff_hist[usize::from(value.abs_diff(self.band[s][centre]))] += 1;
                self.compared_pixels += 1;
                for dg in 0..=2 * s {
                    for dk in 0..=2 * s {
                        let reference = self.band[dg][centre + dk - s];
                        let diff = value.abs_diff(reference);
                        self.sad[dg][dk] += u32::from(diff);
                        if diff > SEED_SUM_LEVEL {
                            self.seed_sum[dg][dk] += u32::from(diff);
                        }
                        if diff > SEED_COUNT_LEVEL {
                            self.seed_count[dg][dk] += 1;
                        }
                    }
                }
            }
        }
    }

    /// Abandons the current frame (dropped or broken mid-frame). If it was
    /// overwriting the keyframe, the keyframe is gone too.
    pub fn abort_frame(&mut self) {
        if self.frame_active && self.becomes_keyframe && self.rows_seen > 0 {
            self.keyframe_state = KeyframeState::Empty;
        }
        self.frame_active = false;
    }

    /// Finishes the frame. Returns None for a frame that only (re)started the keyframe.
    pub fn end_frame(&mut self) -> Option<FrameReport> {
        if !self.frame_active {
            return None;
        }
        self.frame_active = false;
        if self.rows_seen < self.grid.height() {
            // Incomplete frame: treat as dropped.
            self.abort_frame();
            return None;
        }
        let had_keyframe = self.keyframe_state == KeyframeState::Valid;
        let report = if had_keyframe { Some(self.decide()) } else { None };
        self.last_frame = self.frame;
        if self.becomes_keyframe {
            self.keyframe_base = self.new_base;
            self.keyframe_state = KeyframeState::Valid;
            self.keyframe_frame = self.frame;
            self.motion_to_last = Motion::default();
        }
        report
    }

    fn decide(&mut self) -> FrameReport {
        let s = self.config.search_radius;
        // Best integer shift, then a parabola per axis for the sub-pixel part.
        let (mut best_g, mut best_k) = (s, s);
        for dg in 0..=2 * s {
            for dk in 0..=2 * s {
                if self.sad[dg][dk] < self.sad[best_g][best_k] {
                    best_g = dg;
                    best_k = dk;
                }
            }
        }
        let parabola = |minus: u32, centre: u32, plus: u32| -> f64 {
            let (a, b, c) = (f64::from(minus), f64::from(centre), f64::from(plus));
            let curvature = a - 2.0 * b + c;
            if curvature > 0.0 {
                (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        };
        let interior_k = best_k > 0 && best_k < 2 * s;
        let interior_g = best_g > 0 && best_g < 2 * s;
        let sub_k = if interior_k {
            parabola(self.sad[best_g][best_k - 1], self.sad[best_g][best_k], self.sad[best_g][best_k + 1])
        } else {
            0.0
        };
        let sub_g = if interior_g {
            parabola(self.sad[best_g - 1][best_k], self.sad[best_g][best_k], self.sad[best_g + 1][best_k])
        } else {
            0.0
        };
        let shift_k = best_k as f64 - s as f64 + sub_k;
        let shift_g = best_g as f64 - s as f64 + sub_g;
        // The keyframe matched at +shift: the current pixel lies that much
        // farther along K (x) and back along G (-z) in the keyframe.
        let refined = Motion {
            tx_mm: self.predicted.tx_mm + shift_k * self.grid.mm_per_px,
            tz_mm: self.predicted.tz_mm - shift_g * self.grid.mm_per_px,
            dyaw_deg: self.predicted.dyaw_deg,
        };
        // A minimum on the window's edge is not a measurement: keep odometry.
        self.motion_to_last = if interior_k && interior_g { refined } else { self.predicted };

        self.update_noise();
        let alarm_blob = self.find_blobs();
        let alarm = alarm_blob.is_some();
        self.previous_alarm = alarm;
        let (nearest_mm, left_mm, right_mm) = match alarm_blob {
            Some(blob) => {
                let (near, left, right) = self.locate(&blob);
                (Some(near), Some(left), Some(right))
            }
            None => (None, None, None),
        };
        FrameReport {
            frame: self.frame,
            ref_frame: self.keyframe_frame,
            alarm,
            nearest_mm,
            left_mm,
            right_mm,
            sad: self.seed_sum[best_g][best_k],
            count50: self.seed_count[best_g][best_k],
            shift_k: libm::round(shift_k * f64::from(SHIFT_SCALE)) as i32,
            shift_g: libm::round(shift_g * f64::from(SHIFT_SCALE)) as i32,
            tx: libm::round(self.motion_to_last.tx_mm * f64::from(MOTION_SCALE)) as i32,
            tz: libm::round(self.motion_to_last.tz_mm * f64::from(MOTION_SCALE)) as i32,
            obstacle_h_mm: None,
        }
    }

    /// Noise level from this frame's |diff| at the predicted shift, for the
    /// next frame's residue threshold. The median is robust while obstacles
    /// cover less than half the AOI; for Gaussian noise on both images it is
    /// 0.674 * sqrt(2) * sigma.
    fn update_noise(&mut self) {
        let total: u32 = self.diff_hist.iter().sum();
        if total == 0 {
            return;
        }
        let mut seen = 0;
        let mut median = 0u32;
        for (level, &count) in self.diff_hist.iter().enumerate() {
            seen += count;
            if seen * 2 >= total {
                median = level as u32;
                break;
            }
        }
        // sigma = median / (0.674 * 1.414) ~= median * 1.05
        let sigma = f64::from(median) * 1.05;
        self.noise_x16 = libm::round(sigma * 16.0) as u32;
        let threshold = libm::round(self.config.noise_factor * sigma) as u32;
        self.residue_threshold = threshold.clamp(u32::from(self.config.residue_floor), 120) as u8;
    }

    /// Labels hot cells into blobs; returns the nearest blob whose base is in the AOI.
    fn find_blobs(&mut self) -> Option<Blob> {
        self.blobs.clear();
        let (w, h) = (self.cells_wide, self.cells_high);
        let mut label = [0u8; MAX_CELLS_SIDE * MAX_CELLS_SIDE];
        let hot = |cell: usize| {
            let valid = u32::from(self.cell_valid[cell]);
            valid * 2 >= (self.cell_px * self.cell_px) as u32
                && u32::from(self.cell_residue[cell]) * 100 >= valid * self.config.hot_cell_percent
        };
        let mut stack: heapless::Vec<u16, 512> = heapless::Vec::new();
        let mut next_label = 1u8;
        for start in 0..h * w {
            let (sr, sc) = (start / w, start % w);
            let start_cell = sr * MAX_CELLS_SIDE + sc;
            if label[start_cell] != 0 || !hot(start_cell) || usize::from(next_label) > MAX_BLOBS {
                continue;
            }
            let mut blob = Blob {
                cell_left: sc as u8,
                cell_right: sc as u8,
                cell_top: sr as u8,
                cell_bottom: sr as u8,
                cells: 0,
                pixels: 0,
            };
            label[start_cell] = next_label;
            stack.clear();
            let _ = stack.push(start_cell as u16);
            while let Some(cell) = stack.pop() {
                let cell = usize::from(cell);
                let (r, c) = (cell / MAX_CELLS_SIDE, cell % MAX_CELLS_SIDE);
                blob.cells += 1;
                blob.pixels += u32::from(self.cell_residue[cell]);
                blob.cell_left = blob.cell_left.min(c as u8);
                blob.cell_right = blob.cell_right.max(c as u8);
                blob.cell_top = blob.cell_top.min(r as u8);
                blob.cell_bottom = blob.cell_bottom.max(r as u8);
                for (dr, dc) in [(-1i32, -1i32), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)] {
                    let (nr, nc) = (r as i32 + dr, c as i32 + dc);
                    if nr < 0 || nc < 0 || nr as usize >= h || nc as usize >= w {
                        continue;
                    }
                    let neighbour = nr as usize * MAX_CELLS_SIDE + nc as usize;
                    if label[neighbour] == 0 && hot(neighbour) {
                        label[neighbour] = next_label;
                        // A full stack only truncates this blob's growth.
                        let _ = stack.push(neighbour as u16);
                    }
                }
            }
            next_label += 1;
            let _ = self.blobs.push(blob);
        }
        let cell_area_mm2 = (self.cell_px as f64 * self.grid.mm_per_px) * (self.cell_px as f64 * self.grid.mm_per_px);
        let min_cells = libm::ceil(self.config.min_blob_area_mm2 / cell_area_mm2).max(1.0) as u16;
        let mut best: Option<Blob> = None;
        for blob in self.blobs.iter() {
            if blob.cells < min_cells {
                continue;
            }
            // Base: the blob's nearest row must be inside the AOI rows and the
            // blob must overlap the AOI's columns.
            let base_row = (usize::from(blob.cell_bottom) + 1) * self.cell_px - 1;
            let left_px = usize::from(blob.cell_left) * self.cell_px;
            let right_px = (usize::from(blob.cell_right) + 1) * self.cell_px;
            let in_aoi = base_row >= self.aoi.top && right_px > self.aoi.left && left_px < self.aoi.right;
            if in_aoi && best.is_none_or(|b| blob.cell_bottom > b.cell_bottom) {
                best = Some(*blob);
            }
        }
        best
    }

    /// Nearest point and lateral extent of a blob, robot frame mm.
    fn locate(&self, blob: &Blob) -> (i32, i32, i32) {
        let top = usize::from(blob.cell_top) * self.cell_px;
        let bottom = ((usize::from(blob.cell_bottom) + 1) * self.cell_px).min(self.analysis_rows);
        // Base row: the nearest row in the blob with residue, clipped to the AOI.
        let mut base = bottom.saturating_sub(1);
        while base > top && self.row_residue[base] < 2 {
            base -= 1;
        }
        let base = base.min(self.aoi.bottom.saturating_sub(1));
        let (_, z) = self.grid.pixel_to_ground(0.0, base as f64);
        let left_px = usize::from(blob.cell_left) * self.cell_px;
        let right_px = ((usize::from(blob.cell_right) + 1) * self.cell_px).min(self.grid.width()) - 1;
        let (left, _) = self.grid.pixel_to_ground(left_px as f64, 0.0);
        let (right, _) = self.grid.pixel_to_ground(right_px as f64, 0.0);
        (libm::round(z) as i32, libm::round(left) as i32, libm::round(right) as i32)
    }

    /// Blobs found in the last frame (for pictures and tests).
    pub fn blobs(&self) -> &[Blob] {
        &self.blobs
    }
    pub fn cell_px(&self) -> usize {
        self.cell_px
    }
    pub fn residue_threshold(&self) -> u8 {
        self.residue_threshold
    }
    pub fn predicted(&self) -> Motion {
        self.predicted
    }
}

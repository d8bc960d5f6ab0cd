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
use crate::sad;
use core::ops::Range;

/// Largest search radius S (the window is `(2S+1)^2` shifts).
pub const MAX_SEARCH_RADIUS: usize = 3;
const MAX_WINDOW: usize = 2 * MAX_SEARCH_RADIUS + 1;
/// Band row length: the grid plus S columns each side.
const BAND_WIDTH: usize = MAX_GRID_SIDE + 2 * MAX_SEARCH_RADIUS;
/// Spare keyframe rows: how far (rows) the in-place keyframe update may run
/// ahead of the rows still being read. Bounds the travel per keyframe swap.
pub const KEYFRAME_SPARE_ROWS: usize = 48;
/// Coarse cells for blob analysis, per side.
pub const MAX_CELLS_SIDE: usize = 52;
/// Coarse cells in all, stored `cells_wide` apart: the 40,000 px default grid
/// cap at the 30 mm default cell stays within ~1,600; larger grids get
/// larger cells.
pub const MAX_CELLS: usize = 1_700;
/// Height hypotheses for the per-cell parallax test, as fractions of the
/// camera height H (index 0 is the ground). A point at height h = f*H shows,
/// beyond the ground prediction, an extra displacement of T * f / (1 - f).
pub const HEIGHT_FRACTIONS: [f64; 8] = [0.0, 0.04, 0.08, 0.13, 0.19, 0.27, 0.37, 0.5];
const HYPOTHESES: usize = HEIGHT_FRACTIONS.len();
/// Blobs tracked per frame.
pub const MAX_BLOBS: usize = 16;
/// Cells whose footprints a parallax blob keeps for its statistics.
const MAX_BLOB_CELLS: usize = 128;
/// The seed's levels: |diff| above 30 is summed, above 50 counted.
pub const SEED_SUM_LEVEL: u8 = sad::SUM_LEVEL;
pub const SEED_COUNT_LEVEL: u8 = sad::COUNT_LEVEL;

/// Tuning, in physical units so it carries across cameras and grids.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpaConfig {
    /// Search radius S in KG pixels around the predicted shift.
    pub search_radius: usize,
    /// Travel since the keyframe at which the current frame becomes the keyframe.
    pub keyframe_travel_mm: f64,
    /// Turn since the keyframe at which the current frame becomes the keyframe:
    /// turning shrinks the ground both frames see.
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
    /// ...and by at least this many gray levels per pixel (or the noise level, if higher).
    pub parallax_min_gain: f64,
    /// Obstacles are at least this tall (mm); lower bumps are ground.
    pub min_obstacle_height_mm: f64,
    /// Odometry error to tolerate, as a fraction of the step since the last
    /// frame (the part of the motion the shift search has not refined yet):
    /// height hypotheses whose displacement stays within it count as ground.
    pub odometry_error_fraction: f64,
    /// Heading error to tolerate over that step, degrees: it moves ground at
    /// distance z sideways by z * error.
    pub odometry_yaw_error_deg: f64,
}

impl Default for GpaConfig {
    fn default() -> Self {
        GpaConfig::DEFAULT
    }
}

impl GpaConfig {
    /// The defaults (a constant, so [`Gpa::EMPTY`] can hold it).
    pub const DEFAULT: GpaConfig = GpaConfig {
            search_radius: 2,
            keyframe_travel_mm: 100.0,
            keyframe_yaw_deg: 3.0,
            residue_floor: 16,
            noise_factor: 4.0,
            cell_mm: 30.0,
            active_cell_percent: 12,
            peak_cell_percent: 35,
            min_residue_mm2: 800.0,
            parallax_gain_percent: 30,
            parallax_min_gain: 3.0,
            min_obstacle_height_mm: 20.0,
            odometry_error_fraction: 0.05,
            odometry_yaw_error_deg: 0.1,
    };
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
    /// Highest residue percentage of any of its cells.
    pub peak_percent: u8,
}

/// Which evidence raised (or held) the last frame's alarm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AlarmSource {
    #[default]
    None,
    /// Cells whose parallax says they stand above the ground.
    Parallax,
    /// Residue that no height explains (moving or deforming things).
    Residue,
    /// Too short a baseline to decide: the last obstacle, held.
    Held,
}

/// Where the keyframe comes from for this frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum KeyframeState {
    /// No keyframe: the next frame becomes one and reports nothing.
    Empty,
    Valid,
}

/// Visits the cells connected to `start` (neighbours within `radius` cells,
/// in a grid of `size` = (columns, rows) cells stored row by row)
/// for which `member` holds, marking them in `seen`; `visit` gets (cell,
/// row, column). The work stack is bounded: a full one truncates the growth.
fn flood_cells(
    size: (usize, usize),
    radius: i32,
    start: usize,
    seen: &mut [bool],
    member: impl Fn(usize) -> bool,
    mut visit: impl FnMut(usize, usize, usize),
) {
    let (w, h) = size;
    let mut stack: heapless::Vec<u16, 256> = heapless::Vec::new();
    seen[start] = true;
    let _ = stack.push(start as u16);
    while let Some(cell) = stack.pop() {
        let cell = usize::from(cell);
        let (r, c) = (cell / w, cell % w);
        visit(cell, r, c);
        for dr in -radius..=radius {
            for dc in -radius..=radius {
                let (nr, nc) = (r as i32 + dr, c as i32 + dc);
                if nr < 0 || nc < 0 || nr as usize >= h || nc as usize >= w {
                    continue;
                }
                let neighbour = nr as usize * w + nc as usize;
                if !seen[neighbour] && member(neighbour) {
                    seen[neighbour] = true;
                    let _ = stack.push(neighbour as u16);
                }
            }
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct AoiMm {
    near: f64,
    far: f64,
    half_width: f64,
}

/// Per-row warp: reference position of current column 0 and its per-column step, Q16.16.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
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
    /// H, the camera's height above the ground (mm).
    camera_height_mm: f64,
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
    /// The search band, a ring of 2S+1 rows: band row dg (0..=2S) is
    /// `band[(band_first + dg) % (2S+1)]` (see [`logical_band`]).
    band: [[u8; BAND_WIDTH]; MAX_WINDOW],
    band_first: usize,
    /// Row, warp and columns the band was last sampled for (this frame).
    band_source: Option<(usize, RowWarp, Range<usize>)>,
    /// SAD per shift [dg][dk] over the near half of the AOI rows; the far
    /// half apart: a yaw error shifts far rows sideways more than near ones,
    /// which is how it is measured.
    sad_near: [[u32; MAX_WINDOW]; MAX_WINDOW],
    /// The same over the far half.
    sad_far: [[u32; MAX_WINDOW]; MAX_WINDOW],
    compared_pixels: u32,
    /// Histogram of the plain |diff| at the predicted shift over the AOI:
    /// the seed's statistics and the noise estimate.
    diff_hist: sad::DiffHistogram,
    /// Extra keyframe offset (KG px, Q16.16) per hypothesis this frame.
    hypothesis_offset: [(i32, i32); HYPOTHESES],
    /// Hypotheses whose samples stay clear of the in-place keyframe update.
    usable_hypotheses: usize,
    /// Per axis (K, G): may the odometry error exceed half a pixel this frame?
    full_tolerance: (bool, bool),
    /// Hypotheses 0..ground_like whose displacement the odometry error could
    /// explain: they all stand for the ground.
    ground_like: usize,
    /// Per-hypothesis SAD of the cells of the current cell row.
    cell_row_sad: [[u32; MAX_CELLS_SIDE]; HYPOTHESES],
    cell_row_pixels: [[u16; MAX_CELLS_SIDE]; HYPOTHESES],
    /// Parallax height (mm, 0 = ground or undecided) per cell, this frame.
    cell_height: [u8; MAX_CELLS],
    cell_residue: [u8; MAX_CELLS],
    cell_valid: [u8; MAX_CELLS],
    /// Residue pixels per grid row (for the blob base).
    row_residue: [u16; MAX_GRID_SIDE],
    /// Noise level (gray levels, x16) measured on earlier frames.
    noise_x16: u32,
    /// Median plain |diff| per pixel (gray levels) on the last frame: the
    /// floor noise puts under every plain SAD.
    noise_floor: u8,
    residue_threshold: u8,
    /// The last decided obstacle (nearest, left, right mm), held through
    /// frames whose baseline is too short to see it.
    previous_obstacle: Option<(i32, i32, i32)>,
    /// Odometry since the previous frame, scale-corrected.
    step: Motion,
    /// Refined motion keyframe -> previous frame, when this frame began.
    motion_before_step: Motion,
    /// Measured ratio of true to odometry travel (1.0 until measured).
    odometry_scale: f64,
    /// Parallax height of the obstacle found this frame (mm).
    obstacle_height_mm: Option<i32>,
    alarm_source: AlarmSource,
    blobs: heapless::Vec<Blob, MAX_BLOBS>,
    /// Benchmark clock (instructions or ns); None: no profiling.
    clock: Option<fn() -> u32>,
    profile: GpaProfile,
    /// Tests: run the plain per-pixel reference instead of the fast paths.
    #[cfg(test)]
    reference: bool,
}

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

/// Read access to the row-circular keyframe (split from `Gpa` so the band
/// can be written while the keyframe is read).
struct KeyframeView<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
    rows: usize,
    base: usize,
}

impl KeyframeView<'_> {
    #[inline(always)]
    fn row(&self, j: usize) -> &[u8] {
        // base < rows and j < height < rows: one subtraction replaces `%`.
        let mut slot = self.base + j;
        if slot >= self.rows {
            slot -= self.rows;
        }
        &self.data[slot * self.width..][..self.width]
    }

    #[inline(always)]
    fn inside(&self, i: i32, j: i32) -> bool {
        let rows_limit = (self.height as i32 - 1) << FRAC;
        i >= 0 && (i >> FRAC) + 1 < self.width as i32 && j >= 0 && j < rows_limit
    }

    /// Bilinear sample at (i, j) Q16.16; the caller checked [`Self::inside`].
    #[inline(always)]
    fn sample(&self, i: i32, j: i32) -> u8 {
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
    fn sample_line(&self, line: RowWarp, columns: Range<usize>, out: &mut [u8]) -> Range<usize> {
        if columns.is_empty() {
            return columns;
        }
        if line.i_step == 1 << FRAC && line.j_step == 0 {
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
                sad::bilinear_line(upper, lower, wx, wy, &mut out[lo..hi]);
            }
            return lo..hi;
        }
        let (mut first, mut end) = (usize::MAX, 0);
        for c in columns.clone() {
            let i = line.i_start.wrapping_add((c as i32).wrapping_mul(line.i_step));
            let j = line.j_start.wrapping_add((c as i32).wrapping_mul(line.j_step));
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

/// Tolerant residue of `value` against the warped keyframe around it (see
/// `compare_row`): `full_k`/`full_g` widen the range to the whole neighbour.
#[inline(always)]
fn tolerant_residue<const FULL_K: bool, const FULL_G: bool>(value: u8, here: u8, neighbours: [u8; 4]) -> u8 {
    let reach = |other: u8, full: bool| if full { other } else { ((u16::from(here) + u16::from(other) + 1) >> 1) as u8 };
    let values = [
        reach(neighbours[0], FULL_K),
        reach(neighbours[1], FULL_K),
        reach(neighbours[2], FULL_G),
        reach(neighbours[3], FULL_G),
    ];
    let (mut low, mut high) = (here, here);
    for v in values {
        low = low.min(v);
        high = high.max(v);
    }
    value.saturating_sub(high).max(low.saturating_sub(value))
}

/// The band's rows in order dg = 0..window (entries beyond `window` repeat row 0).
fn logical_band(band: &[[u8; BAND_WIDTH]; MAX_WINDOW], first: usize, window: usize) -> [&[u8; BAND_WIDTH]; MAX_WINDOW] {
    let mut rows = [&band[0]; MAX_WINDOW];
    for (dg, row) in rows.iter_mut().take(window).enumerate() {
        *row = &band[(first + dg) % window];
    }
    rows
}

/// Residues of `row[c]` for `c` in `columns` into `out[c]`; `band` rows are
/// indexed `c + MAX_SEARCH_RADIUS` (centre row `s`).
fn residue_line<const FULL_K: bool, const FULL_G: bool>(
    row: &[u8],
    band: &[&[u8; BAND_WIDTH]; MAX_WINDOW],
    s: usize,
    columns: Range<usize>,
    out: &mut [u8],
) {
    let (a, b) = (columns.start, columns.end);
    let r = MAX_SEARCH_RADIUS;
    let centre = &band[s][a + r..b + r];
    let left = &band[s][a + r - 1..b + r - 1];
    let right = &band[s][a + r + 1..b + r + 1];
    let up = &band[s - 1][a + r..b + r];
    let down = &band[s + 1][a + r..b + r];
    for (n, slot) in out[a..b].iter_mut().enumerate() {
        *slot = tolerant_residue::<FULL_K, FULL_G>(row[a + n], centre[n], [left[n], right[n], up[n], down[n]]);
    }
}

impl<'b> Gpa<'b> {
    /// Bytes the keyframe buffer needs for this grid.
    pub fn keyframe_bytes(grid: &KgGrid) -> usize {
        (grid.height() + KEYFRAME_SPARE_ROWS) * grid.width()
    }

    /// A detector with no rig and no keyframe buffer: a constant, so a
    /// target can hold it in a `static` and [`Gpa::init`] it in place (by
    /// value it is ~13 KB, and LLVM keeps stack temporaries of it).
    pub const EMPTY: Gpa<'static> = Gpa {
        config: GpaConfig::DEFAULT,
        grid: KgGrid { mm_per_px: 1.0, x_left_mm: 0.0, z_far_mm: 0.0, width: 0, height: 0 },
        camera_height_mm: 0.0,
        aoi: PixelRect { left: 0, right: 0, top: 0, bottom: 0 },
        analysis_rows: 0,
        reference_valid: [(0, 0); MAX_GRID_SIDE],
        current_valid: [(0, 0); MAX_GRID_SIDE],
        cell_px: 5,
        cells_wide: 0,
        cells_high: 0,
        // An empty slice: nothing to read or write until `init` gives the buffer.
        // SAFETY: a dangling, aligned, non-null pointer with length 0 is a valid slice.
        keyframe: unsafe { core::slice::from_raw_parts_mut(core::ptr::NonNull::<u8>::dangling().as_ptr(), 0) },
        keyframe_rows: 0,
        keyframe_base: 0,
        keyframe_state: KeyframeState::Empty,
        keyframe_frame: 0,
        motion_to_last: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        last_frame: 0,
        frame: 0,
        predicted: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        becomes_keyframe: false,
        new_base: 0,
        frame_active: false,
        rows_seen: 0,
        warp_origin: (0.0, 0.0),
        warp_column: (0.0, 0.0),
        warp_row: (0.0, 0.0),
        band: [[0; BAND_WIDTH]; MAX_WINDOW],
        band_first: 0,
        band_source: None,
        sad_near: [[0; MAX_WINDOW]; MAX_WINDOW],
        sad_far: [[0; MAX_WINDOW]; MAX_WINDOW],
        compared_pixels: 0,
        diff_hist: sad::DiffHistogram::EMPTY,
        hypothesis_offset: [(0, 0); HYPOTHESES],
        usable_hypotheses: 0,
        ground_like: 1,
        full_tolerance: (false, false),
        cell_row_sad: [[0; MAX_CELLS_SIDE]; HYPOTHESES],
        cell_row_pixels: [[0; MAX_CELLS_SIDE]; HYPOTHESES],
        cell_height: [0; MAX_CELLS],
        cell_residue: [0; MAX_CELLS],
        cell_valid: [0; MAX_CELLS],
        row_residue: [0; MAX_GRID_SIDE],
        noise_x16: 0,
        noise_floor: 0,
        residue_threshold: 0,
        previous_obstacle: None,
        step: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        motion_before_step: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        odometry_scale: 1.0,
        obstacle_height_mm: None,
        alarm_source: AlarmSource::None,
        blobs: heapless::Vec::new(),
        clock: None,
        profile: GpaProfile { warp: 0, residue: 0, parallax: 0, shift_search: 0, keyframe_update: 0 },
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
        let finite = [
            config.keyframe_travel_mm,
            config.keyframe_yaw_deg,
            config.noise_factor,
            config.cell_mm,
            config.min_residue_mm2,
            config.parallax_min_gain,
            config.min_obstacle_height_mm,
            config.odometry_error_fraction,
            config.odometry_yaw_error_deg,
        ];
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
        // At least 5 px: a coherent sample for the parallax test; and large
        // enough that the cells fit MAX_CELLS_SIDE per side and MAX_CELLS in all.
        let mut cell_px = (libm::round(config.cell_mm / grid.mm_per_px) as usize).clamp(5, 15);
        while grid.width().div_ceil(cell_px) * aoi.bottom.div_ceil(cell_px) > MAX_CELLS
            || grid.width().div_ceil(cell_px) > MAX_CELLS_SIDE
            || aoi.bottom.div_ceil(cell_px) > MAX_CELLS_SIDE
        {
            cell_px += 1;
        }
        self.current_valid = [(0, 0); MAX_GRID_SIDE];
        for (j, slot) in self.current_valid.iter_mut().enumerate().take(grid.height()) {
            let range = table.valid_columns(j);
            *slot = (range.start as u16, range.end as u16);
        }
        // A reference sample around row j' touches rows j'-S-1 ..= j'+S+2 and
        // columns i'-S-1 ..= i'+S+2: keep the columns where all of them are in view.
        let reach = config.search_radius + 1;
        self.reference_valid = [(0, 0); MAX_GRID_SIDE];
        for (j, slot) in self.reference_valid.iter_mut().enumerate().take(grid.height()) {
            let (mut lo, mut hi) = (0usize, grid.width());
            for r in j as isize - reach as isize..=(j + reach + 1) as isize {
                let range = if r < 0 || r as usize >= grid.height() { 0..0 } else { table.valid_columns(r as usize) };
                lo = lo.max(range.start);
                hi = hi.min(range.end);
            }
            let (lo, hi) = (lo + reach, hi.saturating_sub(reach + 1));
            *slot = if hi > lo { (lo as u16, hi as u16) } else { (0, 0) };
        }
        self.config = config;
        self.grid = *grid;
        self.camera_height_mm = rig.height_mm();
        self.aoi = aoi;
        self.analysis_rows = aoi.bottom;
        self.cell_px = cell_px;
        self.cells_wide = grid.width().div_ceil(cell_px);
        self.cells_high = aoi.bottom.div_ceil(cell_px);
        self.keyframe = keyframe;
        self.keyframe_rows = grid.height() + KEYFRAME_SPARE_ROWS;
        self.keyframe_base = 0;
        self.keyframe_state = KeyframeState::Empty;
        self.keyframe_frame = 0;
        self.motion_to_last = Motion::default();
        self.last_frame = 0;
        self.frame = 0;
        self.predicted = Motion::default();
        self.becomes_keyframe = false;
        self.new_base = 0;
        self.frame_active = false;
        self.rows_seen = 0;
        self.warp_origin = (0.0, 0.0);
        self.warp_column = (0.0, 0.0);
        self.warp_row = (0.0, 0.0);
        self.band = [[0; BAND_WIDTH]; MAX_WINDOW];
        self.sad_near = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.sad_far = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.compared_pixels = 0;
        self.diff_hist.clear();
        self.hypothesis_offset = [(0, 0); HYPOTHESES];
        self.usable_hypotheses = 0;
        self.ground_like = 1;
        self.full_tolerance = (false, false);
        self.cell_row_sad = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
        self.cell_row_pixels = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
        self.cell_height = [0; MAX_CELLS];
        self.cell_residue = [0; MAX_CELLS];
        self.cell_valid = [0; MAX_CELLS];
        self.row_residue = [0; MAX_GRID_SIDE];
        self.noise_x16 = 0;
        self.noise_floor = 0;
        self.residue_threshold = config.residue_floor;
        self.previous_obstacle = None;
        self.step = Motion::default();
        self.motion_before_step = Motion::default();
        self.odometry_scale = 1.0;
        self.obstacle_height_mm = None;
        self.alarm_source = AlarmSource::None;
        self.blobs = heapless::Vec::new();
        self.profile = GpaProfile::default();
        Ok(())
    }

    /// Profiles `on_kg_row` per stage with `clock` (any monotonic counter;
    /// the firmware gives TIM2's instruction count). None turns it off.
    pub fn set_clock(&mut self, clock: Option<fn() -> u32>) {
        self.clock = clock;
    }

    /// Per-stage ticks of the current (or last) frame; see [`GpaProfile`].
    pub fn profile(&self) -> GpaProfile {
        self.profile
    }

    #[inline(always)]
    fn tick(&self) -> u32 {
        match self.clock {
            Some(clock) => clock(),
            None => 0,
        }
    }

    /// Forgets the keyframe: after a gap in frames or odometry the motion
    /// since the keyframe is unknown, so the next frame starts afresh
    /// instead of raising a false alarm.
    pub fn reset_keyframe(&mut self) {
        self.keyframe_state = KeyframeState::Empty;
        self.frame_active = false;
        self.previous_obstacle = None;
    }

    /// Frame the current keyframe was taken at (if any).
    pub fn keyframe_frame(&self) -> Option<u32> {
        (self.keyframe_state == KeyframeState::Valid).then_some(self.keyframe_frame)
    }

    /// Starts frame `frame`; `odometry` is the motion since the previous
    /// frame (None if unknown: the keyframe is reset).
    pub fn begin_frame(&mut self, frame: u32, odometry: Option<Motion>) {
        self.profile = GpaProfile::default();
        self.band_source = None;
        self.frame = frame;
        self.frame_active = true;
        self.rows_seen = 0;
        let consecutive = self.keyframe_state == KeyframeState::Valid && frame == self.last_frame.wrapping_add(1);
        match odometry {
            Some(step) if consecutive => {
                // Wheel odometry with a constant scale error (a worn tyre) is
                // corrected by the scale the shift search has been measuring.
                self.step = Motion {
                    tx_mm: step.tx_mm * self.odometry_scale,
                    tz_mm: step.tz_mm * self.odometry_scale,
                    dyaw_deg: step.dyaw_deg,
                };
                self.motion_before_step = self.motion_to_last;
                self.predicted = self.motion_to_last.then(&self.step);
            }
            _ => self.keyframe_state = KeyframeState::Empty,
        }
        if self.keyframe_state == KeyframeState::Empty {
            self.predicted = Motion::default();
            self.becomes_keyframe = true;
            self.new_base = self.keyframe_base;
            return;
        }
        // Height hypotheses: extra keyframe offset T * f / (1 - f), in KG px.
        let (di, dj) = (self.predicted.tx_mm / self.grid.mm_per_px, -self.predicted.tz_mm / self.grid.mm_per_px);
        for (slot, f) in self.hypothesis_offset.iter_mut().zip(HEIGHT_FRACTIONS) {
            let g = f / (1.0 - f);
            *slot = (to_q16(di * g), to_q16(dj * g));
        }
        let error = self.config.odometry_error_fraction;
        let half_px = 0.5 * self.grid.mm_per_px;
        self.full_tolerance = (
            error * libm::fabs(self.step.tx_mm) > half_px,
            error * libm::fabs(self.step.tz_mm) > half_px,
        );
        let tolerance_mm = error * self.step.distance_mm() + half_px;
        let baseline = self.predicted.distance_mm();
        self.ground_like = HEIGHT_FRACTIONS.iter().take_while(|f| baseline * **f / (1.0 - **f) <= tolerance_mm).count().max(1);
        // This frame replaces the keyframe once the baseline is long enough.
        // The in-place update runs KEYFRAME_SPARE_ROWS ahead of the write
        // position, so reads must stay within that lead: hypotheses that would
        // reach further are left out for this frame.
        let yaw_rows = libm::fabs(libm::sin(self.predicted.dyaw_deg.to_radians())) * self.grid.width() as f64;
        let base_lead = libm::fabs(dj) + yaw_rows + (self.config.search_radius + 3) as f64;
        // Also swap when the next frame, moving like this one, would overshoot
        // by half again: a slightly short step must not make the next
        // baseline twice as long (less overlap, too far to update in place).
        let (travel, turn) = (self.predicted.distance_mm(), libm::fabs(self.predicted.dyaw_deg));
        let (step_travel, step_turn) = (self.step.distance_mm(), libm::fabs(self.step.dyaw_deg));
        self.becomes_keyframe = travel >= self.config.keyframe_travel_mm
            || turn >= self.config.keyframe_yaw_deg
            || travel + step_travel >= 1.5 * self.config.keyframe_travel_mm
            || turn + step_turn >= 1.5 * self.config.keyframe_yaw_deg;
        self.usable_hypotheses = HYPOTHESES;
        if self.becomes_keyframe {
            self.usable_hypotheses = HEIGHT_FRACTIONS
                .iter()
                .take_while(|f| base_lead + libm::fabs(dj) * **f / (1.0 - **f) < KEYFRAME_SPARE_ROWS as f64)
                .count();
            if self.usable_hypotheses == 0 {
                // Moved too far to compare in place: start afresh from this frame.
                self.keyframe_state = KeyframeState::Empty;
                self.predicted = Motion::default();
                self.new_base = self.keyframe_base;
                return;
            }
        }
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

        self.sad_near = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.sad_far = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.compared_pixels = 0;
        self.diff_hist.clear();
        self.cell_residue = [0; MAX_CELLS];
        self.cell_valid = [0; MAX_CELLS];
        self.row_residue = [0; MAX_GRID_SIDE];
        self.cell_height = [0; MAX_CELLS];
        self.cell_row_sad = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
        self.cell_row_pixels = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
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

    #[cfg(test)]
    fn keyframe_view(&self) -> KeyframeView<'_> {
        KeyframeView {
            data: self.keyframe,
            width: self.grid.width(),
            height: self.grid.height(),
            rows: self.keyframe_rows,
            base: self.keyframe_base,
        }
    }

    /// Feeds KG row `j` of the current frame (rows arrive in order 0..height).
    pub fn on_kg_row(&mut self, j: usize, row: &[u8]) {
        if !self.frame_active || j >= self.grid.height() || row.len() != self.grid.width() {
            return;
        }
        self.rows_seen = j + 1;
        if self.keyframe_state == KeyframeState::Valid && j < self.analysis_rows {
            #[cfg(test)]
            if self.reference {
                self.compare_row_reference(j, row);
            } else {
                self.compare_row(j, row);
            }
            #[cfg(not(test))]
            self.compare_row(j, row);
        }
        if self.becomes_keyframe {
            let start = self.tick();
            // Written S+2+lead rows behind the reads by construction of new_base.
            let mut slot = self.new_base + j;
            if slot >= self.keyframe_rows {
                slot -= self.keyframe_rows;
            }
            let width = self.grid.width();
            self.keyframe[slot * width..][..width].copy_from_slice(row);
            self.profile.keyframe_update = self.profile.keyframe_update.wrapping_add(self.tick().wrapping_sub(start));
        }
    }

    /// One KG row against the warped keyframe: band, residue, hypotheses,
    /// shift search. Same results as the per-pixel reference below, organised
    /// as whole-line passes: keyframe rows looked up once per line, constant
    /// bilinear weights on translation rows, per-cell sums over column
    /// segments, and the shift search as block kernels (`sad.rs`).
    fn compare_row(&mut self, j: usize, row: &[u8]) {
        let s = self.config.search_radius;
        let width = self.grid.width();
        let warp = self.row_warp(j);
        let Some((cur_lo, cur_hi)) = self.seen_columns(j) else {
            self.close_cell_row(j);
            return;
        };
        let cell_row = j / self.cell_px;
        let t_start = self.tick();
        // Usable columns (whole search neighbourhood in the keyframe's view),
        // as runs. A translation row has one; a yawed row may have several.
        let mut runs = [(0u16, 0u16); MAX_GRID_SIDE / 2 + 1];
        let mut run_count = 0;
        let rows_limit = (self.grid.height() as i32 - 1) << FRAC;
        if warp.i_step == 1 << FRAC && warp.j_step == 0 {
            if warp.j_start >= 0 && warp.j_start < rows_limit {
                let (lo, hi) = self.reference_valid[(warp.j_start >> FRAC) as usize];
                let i0 = i64::from(warp.i_start >> FRAC);
                let first = (i64::from(lo) - i0).max(cur_lo as i64);
                let end = (i64::from(hi) - i0).min(cur_hi as i64);
                if end > first {
                    runs[0] = (first as u16, end as u16);
                    run_count = 1;
                }
            }
        } else {
            let mut open: Option<usize> = None;
            for c in cur_lo..=cur_hi {
                let usable = c < cur_hi && {
                    let i_ref = warp.i_start.wrapping_add((c as i32).wrapping_mul(warp.i_step));
                    let j_ref = warp.j_start.wrapping_add((c as i32).wrapping_mul(warp.j_step));
                    let (i0, j0) = (i_ref >> FRAC, j_ref >> FRAC);
                    j_ref >= 0 && j_ref < rows_limit && i0 >= 0 && (i0 as usize) < width && {
                        let (lo, hi) = self.reference_valid[j0 as usize];
                        (i0 as usize) >= usize::from(lo) && (i0 as usize) < usize::from(hi)
                    }
                };
                match (usable, open) {
                    (true, None) => open = Some(c),
                    (false, Some(first)) => {
                        runs[run_count] = (first as u16, c as u16);
                        run_count += 1;
                        open = None;
                    }
                    _ => {}
                }
            }
        }
        let runs = &runs[..run_count];
        // The search band: band[dg][c + MAX_SEARCH_RADIUS] = keyframe at warp(c) + (0, dg - S).
        let view = KeyframeView {
            data: self.keyframe,
            width,
            height: self.grid.height(),
            rows: self.keyframe_rows,
            base: self.keyframe_base,
        };
        let band_columns = cur_lo.saturating_sub(s)..(cur_hi + s).min(width);
        // On translation rows the next row's warp is usually this one moved down
        // exactly one keyframe row: then its band row dg is this row's dg + 1
        // (a sample depends only on the line and the column), so the band
        // rolls up (the ring's first row moves on, no bytes are copied) and
        // only the last row is sampled. Nothing reads outside `band_columns`.
        let window = 2 * s + 1;
        let rolls = matches!(&self.band_source, Some((previous_j, previous, columns))
            if *previous_j + 1 == j
                && RowWarp { j_start: previous.j_start.wrapping_add(1 << FRAC), ..*previous } == warp
                && columns.start <= band_columns.start
                && band_columns.end <= columns.end);
        let first_sampled = if rolls {
            self.band_first = (self.band_first + 1) % window;
            2 * s
        } else {
            0
        };
        for dg in first_sampled..=2 * s {
            let line = RowWarp { j_start: warp.j_start + ((dg as i32 - s as i32) << FRAC), ..warp };
            let slot = (self.band_first + dg) % window;
            view.sample_line(line, band_columns.clone(), &mut self.band[slot][MAX_SEARCH_RADIUS..]);
        }
        self.band_source = Some((j, warp, band_columns.clone()));
        let band = logical_band(&self.band, self.band_first, window);
        let t_warp = self.tick();
        self.profile.warp = self.profile.warp.wrapping_add(t_warp.wrapping_sub(t_start));

        // Residue and the per-cell statistics, one cell segment at a time.
        let cell_px = self.cell_px;
        let in_cells = cell_row < self.cells_high;
        let cells_end = (self.cells_wide * cell_px).min(width);
        let clip = |(a, b): (u16, u16), lo: usize, hi: usize| usize::from(a).max(lo)..usize::from(b).min(hi);
        // Calls `f(cell_column, columns)` for the cell segments of `columns`
        // (generic so `f` inlines; one division per run, not per segment).
        #[inline(always)]
        fn segments(columns: Range<usize>, cell_px: usize, mut f: impl FnMut(usize, Range<usize>)) {
            let mut c = columns.start;
            let mut cell_column = c / cell_px;
            while c < columns.end {
                let end = ((cell_column + 1) * cell_px).min(columns.end);
                f(cell_column, c..end);
                c = end;
                cell_column += 1;
            }
        }
        if in_cells {
            // Two tolerant residues (see compare_row_reference): the ground
            // hypothesis's (half a pixel, or a full one along an axis the
            // odometry may be that far off, sideways also where a heading
            // error moves far ground by more than half a pixel) and the wide
            // one (full neighbours) that flags anything unexplained.
            let (_, row_z) = self.grid.pixel_to_ground(0.0, j as f64);
            let yaw_blur = row_z * self.config.odometry_yaw_error_deg.to_radians() > 0.5 * self.grid.mm_per_px;
            let tolerance = (self.full_tolerance.0 || yaw_blur, self.full_tolerance.1);
            let mut residues = [0u8; MAX_GRID_SIDE];
            let mut unexplained = [0u8; MAX_GRID_SIDE];
            let threshold = self.residue_threshold;
            let cell_base = cell_row * self.cells_wide;
            for &run in runs {
                let columns = clip(run, 0, cells_end);
                if columns.is_empty() {
                    continue;
                }
                match tolerance {
                    (false, false) => residue_line::<false, false>(row, &band, s, columns.clone(), &mut residues),
                    (true, false) => residue_line::<true, false>(row, &band, s, columns.clone(), &mut residues),
                    (false, true) => residue_line::<false, true>(row, &band, s, columns.clone(), &mut residues),
                    (true, true) => residue_line::<true, true>(row, &band, s, columns.clone(), &mut residues),
                }
                if tolerance == (true, true) {
                    unexplained[columns.clone()].copy_from_slice(&residues[columns.clone()]);
                } else {
                    residue_line::<true, true>(row, &band, s, columns.clone(), &mut unexplained);
                }
                let mut row_residue = 0u32;
                segments(columns, cell_px, |cell_column, columns| {
                    let cell = cell_base + cell_column;
                    let n = columns.len();
                    let (mut hot, mut sum) = (0u32, 0u32);
                    for (&r, &wide) in residues[columns.clone()].iter().zip(&unexplained[columns]) {
                        hot += u32::from(wide > threshold);
                        sum += u32::from(r);
                    }
                    self.cell_valid[cell] = self.cell_valid[cell].saturating_add(n.min(255) as u8);
                    self.cell_residue[cell] = self.cell_residue[cell].saturating_add(hot.min(255) as u8);
                    row_residue += hot;
                    // The ground is the null hypothesis: it gets the half-pixel
                    // tolerance, the heights must beat it outright.
                    self.cell_row_pixels[0][cell_column] += n as u16;
                    self.cell_row_sad[0][cell_column] += sum;
                });
                self.row_residue[j] = self.row_residue[j].saturating_add(row_residue.min(u32::from(u16::MAX)) as u16);
            }
        }
        let t_residue = self.tick();
        self.profile.residue = self.profile.residue.wrapping_add(t_residue.wrapping_sub(t_warp));

        // Height hypotheses (0 = the ground prediction itself, band[S]):
        // columns whose sample is off the keyframe skip that hypothesis.
        if in_cells {
            let mut samples = [0u8; MAX_GRID_SIDE];
            for k in 1..self.usable_hypotheses {
                let (oi, oj) = self.hypothesis_offset[k];
                let line = RowWarp {
                    i_start: warp.i_start.wrapping_add(oi),
                    j_start: warp.j_start.wrapping_add(oj),
                    ..warp
                };
                let seen = view.sample_line(line, cur_lo..cur_hi, &mut samples);
                for &run in runs {
                    let columns = clip(run, seen.start, seen.end.min(cells_end));
                    if columns.is_empty() {
                        continue;
                    }
                    // Cell segments are 5-15 px. On the M4 `usada8` sums them
                    // in place; elsewhere a per-segment kernel call costs more
                    // than the work, so |diff| is taken over the whole line
                    // (vectorised) and the segments sum bytes.
                    #[cfg(not(flatland_dsp))]
                    for (d, &value) in samples[columns.clone()].iter_mut().zip(&row[columns.clone()]) {
                        *d = d.abs_diff(value);
                    }
                    segments(columns, cell_px, |cell_column, columns| {
                        self.cell_row_pixels[k][cell_column] += columns.len() as u16;
                        #[cfg(flatland_dsp)]
                        let sum = sad::sad(&row[columns.clone()], &samples[columns]);
                        #[cfg(not(flatland_dsp))]
                        let sum: u32 = samples[columns].iter().map(|&d| u32::from(d)).sum();
                        self.cell_row_sad[k][cell_column] += sum;
                    });
                }
            }
        }
        let t_parallax = self.tick();
        self.profile.parallax = self.profile.parallax.wrapping_add(t_parallax.wrapping_sub(t_residue));

        // The shift search over the AOI, and the |diff| histogram at the prediction.
        if j >= self.aoi.top && j < self.aoi.bottom {
            // The far half of the AOI gets its own SADs: a yaw error shifts
            // far rows sideways more than near ones, which is how it is measured.
            let far_half = j < (self.aoi.top + self.aoi.bottom) / 2;
            let r = MAX_SEARCH_RADIUS;
            let window = 2 * s + 1;
            for &run in runs {
                let columns = clip(run, self.aoi.left, self.aoi.right);
                if columns.is_empty() {
                    continue;
                }
                let current = &row[columns.clone()];
                self.diff_hist.add(current, &band[s][columns.start + r..columns.end + r]);
                self.compared_pixels += columns.len() as u32;
                // Shift dk of band row dg compares current[c] with band[dg][c + dk - s].
                let reference = columns.start + r - s..columns.end + r + s;
                let sums = if far_half { &mut self.sad_far } else { &mut self.sad_near };
                for (sums, band) in sums.iter_mut().zip(&band).take(window) {
                    sad::sad_shifts(current, &band[reference.clone()], &mut sums[..window]);
                }
            }
        }
        let t_shift = self.tick();
        self.profile.shift_search = self.profile.shift_search.wrapping_add(t_shift.wrapping_sub(t_parallax));
        self.close_cell_row(j);
        self.profile.parallax = self.profile.parallax.wrapping_add(self.tick().wrapping_sub(t_shift));
    }

    /// The plain per-pixel form of [`Self::compare_row`], kept as its
    /// reference: the tests check that both leave identical state.
    #[cfg(test)]
    // Indexed loops on purpose: the reference is written pixel by pixel.
    #[allow(clippy::needless_range_loop)]
    fn compare_row_reference(&mut self, j: usize, row: &[u8]) {
        let s = self.config.search_radius;
        let width = self.grid.width();
        let warp = self.row_warp(j);
        let Some((cur_lo, cur_hi)) = self.seen_columns(j) else {
            self.close_cell_row(j);
            return;
        };
        let cell_row = j / self.cell_px;
        let rows_limit = (self.grid.height() as i32 - 1) << FRAC;
        let reference_at = |c: usize| {
            let i = warp.i_start.wrapping_add((c as i32).wrapping_mul(warp.i_step));
            let jr = warp.j_start.wrapping_add((c as i32).wrapping_mul(warp.j_step));
            (i, jr)
        };
        // Columns whose whole search neighbourhood lies in the keyframe's view.
        let mut usable = [false; MAX_GRID_SIDE];
        for c in cur_lo..cur_hi {
            let (i_ref, j_ref) = reference_at(c);
            let (i0, j0) = (i_ref >> FRAC, j_ref >> FRAC);
            usable[c] = j_ref >= 0 && j_ref < rows_limit && i0 >= 0 && (i0 as usize) < width && {
                let (lo, hi) = self.reference_valid[j0 as usize];
                (i0 as usize) >= usize::from(lo) && (i0 as usize) < usize::from(hi)
            };
        }
        // The search band: band[dg][c + MAX_SEARCH_RADIUS] = keyframe at warp(c) + (0, dg - S).
        self.band_first = 0;
        let first = cur_lo.saturating_sub(s);
        let last = (cur_hi + s).min(width);
        for dg in 0..=2 * s {
            for c in first..last {
                let (i_ref, j_ref) = reference_at(c);
                let (i, jr) = (i_ref, j_ref + ((dg as i32 - s as i32) << FRAC));
                let view = self.keyframe_view();
                let value = if view.inside(i, jr) { view.sample(i, jr) } else { 0 };
                self.band[dg][c + MAX_SEARCH_RADIUS] = value;
            }
        }
        // Height hypotheses (0 = the ground prediction itself, band[S]).
        // A sample off the keyframe is None: that hypothesis skips the pixel.
        let mut hypothesis_rows = [[None; MAX_GRID_SIDE]; HYPOTHESES];
        for k in 1..self.usable_hypotheses {
            let (oi, oj) = self.hypothesis_offset[k];
            let view = self.keyframe_view();
            for c in cur_lo..cur_hi {
                let (i_ref, j_ref) = reference_at(c);
                let (i, jr) = (i_ref.wrapping_add(oi), j_ref.wrapping_add(oj));
                hypothesis_rows[k][c] = view.inside(i, jr).then(|| view.sample(i, jr));
            }
        }
        let in_aoi_row = j >= self.aoi.top && j < self.aoi.bottom;
        // A heading error moves far ground sideways by more than half a pixel.
        let (_, row_z) = self.grid.pixel_to_ground(0.0, j as f64);
        let yaw_blur = row_z * self.config.odometry_yaw_error_deg.to_radians() > 0.5 * self.grid.mm_per_px;
        // The far half of the AOI gets its own SADs: a yaw error shifts far
        // rows sideways more than near ones, which is how it is measured.
        let far_half = j < (self.aoi.top + self.aoi.bottom) / 2;
        let threshold = self.residue_threshold;
        for c in cur_lo..cur_hi {
            if !usable[c] {
                continue;
            }
            let value = row[c];
            let centre = c + MAX_SEARCH_RADIUS;
            // Tolerant residue (Birchfield-Tomasi style): the current value
            // against the range the warped keyframe spans within half a pixel
            // of the prediction, along K and along G.
            // Two tolerant residues (Birchfield-Tomasi style): the current
            // value against the range the warped keyframe spans around the
            // prediction. For the parallax test's ground hypothesis the range
            // reaches half a pixel (a full pixel along an axis where the
            // odometry may be that far off); the residue that flags anything
            // unexplained always reaches the full neighbours, so a shift
            // search that lands a pixel away cannot light up ground edges.
            let here = self.band[s][centre];
            let sideways = [self.band[s][centre - 1], self.band[s][centre + 1]];
            let along = [self.band[s - 1][centre], self.band[s + 1][centre]];
            let half = |other: u8| ((u16::from(here) + u16::from(other) + 1) >> 1) as u8;
            let (full_k, full_g) = (self.full_tolerance.0 || yaw_blur, self.full_tolerance.1);
            let (mut low, mut high) = (here, here);
            let (mut wide_low, mut wide_high) = (here, here);
            for (v, full) in [(sideways[0], full_k), (sideways[1], full_k), (along[0], full_g), (along[1], full_g)] {
                let reached = if full { v } else { half(v) };
                low = low.min(reached);
                high = high.max(reached);
                wide_low = wide_low.min(v);
                wide_high = wide_high.max(v);
            }
            let residue = value.saturating_sub(high).max(low.saturating_sub(value));
            let unexplained = value.saturating_sub(wide_high).max(wide_low.saturating_sub(value));
            let cell_column = c / self.cell_px;
            if cell_row < self.cells_high && cell_column < self.cells_wide {
                let cell = cell_row * self.cells_wide + cell_column;
                self.cell_valid[cell] = self.cell_valid[cell].saturating_add(1);
                if unexplained > threshold {
                    self.cell_residue[cell] = self.cell_residue[cell].saturating_add(1);
                    self.row_residue[j] = self.row_residue[j].saturating_add(1);
                }
                // The ground is the null hypothesis: it gets the half-pixel
                // tolerance, the heights must beat it outright.
                self.cell_row_pixels[0][cell_column] += 1;
                self.cell_row_sad[0][cell_column] += u32::from(residue);
                for k in 1..self.usable_hypotheses {
                    if let Some(sample) = hypothesis_rows[k][c] {
                        self.cell_row_pixels[k][cell_column] += 1;
                        self.cell_row_sad[k][cell_column] += u32::from(value.abs_diff(sample));
                    }
                }
            }
            if in_aoi_row && c >= self.aoi.left && c < self.aoi.right {
                self.diff_hist.add_one(value.abs_diff(here));
                self.compared_pixels += 1;
                for dg in 0..=2 * s {
                    for dk in 0..=2 * s {
                        let diff = u32::from(value.abs_diff(self.band[dg][centre + dk - s]));
                        if far_half {
                            self.sad_far[dg][dk] += diff;
                        } else {
                            self.sad_near[dg][dk] += diff;
                        }
                    }
                }
            }
        }
        self.close_cell_row(j);
    }

    /// Columns `[lo, hi)` of current row `j` that the camera sees, or None.
    fn seen_columns(&self, j: usize) -> Option<(usize, usize)> {
        let (lo, hi) = self.current_valid[j];
        (hi > lo).then_some((usize::from(lo), usize::from(hi)))
    }

    /// After row `j`: decides its cell row if `j` was that row's last.
    fn close_cell_row(&mut self, j: usize) {
        if (j + 1).is_multiple_of(self.cell_px) || j + 1 == self.analysis_rows {
            self.finish_cell_row(j / self.cell_px);
        }
    }

    /// Decides the parallax height of each cell of a finished cell row.
    fn finish_cell_row(&mut self, cell_row: usize) {
        if cell_row >= self.cells_high {
            return;
        }
        let min_pixels = (self.cell_px * self.cell_px / 2) as u16;
        let noise = f64::from(self.noise_x16) / 16.0;
        let min_gain = self.config.parallax_min_gain.max(noise);
        for column in 0..self.cells_wide {
            let pixels = self.cell_row_pixels[0][column];
            let cell = cell_row * self.cells_wide + column;
            self.cell_height[cell] = 0;
            if pixels < min_pixels || self.usable_hypotheses < 2 {
                continue;
            }
            // Each hypothesis' SAD scaled to the cell's pixel count; one that
            // saw less than 3/4 of the cell (off the keyframe) does not compete.
            let mut sads = [u32::MAX; HYPOTHESES];
            for (k, sad) in sads.iter_mut().enumerate().take(self.usable_hypotheses) {
                let seen = u32::from(self.cell_row_pixels[k][column]);
                if seen * 4 >= u32::from(pixels) * 3 {
                    *sad = ((u64::from(self.cell_row_sad[k][column]) * u64::from(pixels)) / u64::from(seen.max(1))) as u32;
                }
            }
            if let Some(fraction) = self.parallax_fraction(&sads[..self.usable_hypotheses], pixels, min_gain) {
                let height = fraction * self.camera_height_mm;
                self.cell_height[cell] = libm::round(height).clamp(1.0, 255.0) as u8;
            }
        }
        self.cell_row_sad = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
        self.cell_row_pixels = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
    }

    /// The height (as a fraction of H) that a cell's hypothesis SADs point
    /// at, or None if the ground explains the cell as well.
    fn parallax_fraction(&self, sads: &[u32], pixels: u16, min_gain: f64) -> Option<f64> {
        // The ground: the tolerant residue, or any height so small that the
        // odometry error alone could produce its displacement.
        let ground_like = self.ground_like.min(sads.len());
        let ground = sads[..ground_like].iter().copied().min().unwrap_or(u32::MAX);
        let mut best = 0;
        for k in ground_like..sads.len() {
            if best == 0 || sads[k] < sads[best] {
                best = k;
            }
        }
        if best == 0 || sads[best] >= ground {
            return None;
        }
        let best_sad = sads[best];
        let gain = ground - best_sad;
        // Sensor noise puts a floor under every plain SAD (the ground's
        // tolerant residue sits lower); compare what lies above it.
        let floor = u32::from(self.noise_floor) * u32::from(pixels);
        let above = |sad: u32| u64::from(sad.saturating_sub(floor));
        let keep = u64::from(100 - self.config.parallax_gain_percent);
        let relative = above(best_sad) * 100 <= u64::from(ground) * keep;
        let absolute = f64::from(gain) >= min_gain * f64::from(pixels);
        // Uniqueness, as in stereo matching: structure that is uniform along
        // the motion (a tape strip driven along) matches every height
        // equally; only a distinct minimum is a measurement.
        let runner_up = (1..sads.len()).filter(|k| k.abs_diff(best) > 1).map(|k| sads[k]).min().unwrap_or(0);
        let distinct = above(best_sad) * 100 <= above(runner_up) * keep;
        if !(relative && absolute && distinct) {
            return None;
        }
        // Parabola through the neighbouring hypotheses, in the displacement
        // they stand for (f / (1 - f)), not in index.
        let g = |k: usize| HEIGHT_FRACTIONS[k] / (1.0 - HEIGHT_FRACTIONS[k]);
        if best + 1 >= sads.len() || sads[best + 1] == u32::MAX {
            return Some(HEIGHT_FRACTIONS[best]);
        }
        let (a, b, c) = (f64::from(sads[best - 1]), f64::from(best_sad), f64::from(sads[best + 1]));
        let curvature = a - 2.0 * b + c;
        let offset = if curvature > 0.0 { (0.5 * (a - c) / curvature).clamp(-0.5, 0.5) } else { 0.0 };
        let displacement = if offset < 0.0 {
            g(best) + offset * (g(best) - g(best - 1))
        } else {
            g(best) + offset * (g(best + 1) - g(best))
        };
        Some(displacement / (1.0 + displacement))
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
        let mut sad = self.sad_near;
        for (row, far) in sad.iter_mut().zip(&self.sad_far) {
            for (sum, &far) in row.iter_mut().zip(far) {
                *sum += far;
            }
        }
        // Best integer shift, then a parabola per axis for the sub-pixel part.
        let (mut best_g, mut best_k) = (s, s);
        for dg in 0..=2 * s {
            for dk in 0..=2 * s {
                if sad[dg][dk] < sad[best_g][best_k] {
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
            parabola(sad[best_g][best_k - 1], sad[best_g][best_k], sad[best_g][best_k + 1])
        } else {
            0.0
        };
        let sub_g = if interior_g {
            parabola(sad[best_g - 1][best_k], sad[best_g][best_k], sad[best_g + 1][best_k])
        } else {
            0.0
        };
        let shift_k = best_k as f64 - s as f64 + sub_k;
        let shift_g = best_g as f64 - s as f64 + sub_g;
        // The keyframe matched at +shift: the current pixel lies that much
        // farther along K (x) and back along G (-z) in the keyframe.
        let mut refined = Motion {
            tx_mm: self.predicted.tx_mm + shift_k * self.grid.mm_per_px,
            tz_mm: self.predicted.tz_mm - shift_g * self.grid.mm_per_px,
            dyaw_deg: self.predicted.dyaw_deg,
        };
        if let Some((yaw_deg, tx_mm)) = self.yaw_refinement(best_g, parabola) {
            refined.dyaw_deg += yaw_deg;
            refined.tx_mm = tx_mm;
        }
        // A minimum on the window's edge is not a measurement: keep odometry.
        self.motion_to_last = if interior_k && interior_g { refined } else { self.predicted };
        if interior_k && interior_g {
            self.learn_odometry_scale();
        }

        let histogram = self.diff_hist.counts();
        let (seed_sum, seed_count) = sad::seed_statistics(&histogram);
        self.update_noise(&histogram);
        // Parallax first: it measures height and footprint directly. The
        // residue blob catches what has no consistent parallax (moving things).
        let parallax = self.find_parallax_obstacle();
        let residue = self.find_blobs().map(|blob| self.locate(&blob));
        let evidence = parallax.map(|(near, left, right, _)| (near, left, right)).or(residue);
        self.alarm_source = match (parallax, residue) {
            (Some(_), _) => AlarmSource::Parallax,
            (None, Some(_)) => AlarmSource::Residue,
            (None, None) => AlarmSource::None,
        };
        self.obstacle_height_mm = parallax.map(|(_, _, _, height)| height);
        // Too short a baseline shows too little parallax to clear an alarm:
        // hold the last obstacle, moved by the odometry, until a frame with
        // enough baseline decides again.
        let short_baseline = self.predicted.distance_mm() < 0.5 * self.config.keyframe_travel_mm;
        let obstacle = match (evidence, self.previous_obstacle) {
            (Some(found), _) => Some(found),
            (None, Some((near, left, right))) if short_baseline => {
                self.alarm_source = AlarmSource::Held;
                let (dx, dz) = (self.step.tx_mm, self.step.tz_mm);
                let moved = |v: i32, d: f64| libm::round(f64::from(v) - d) as i32;
                Some((moved(near, dz), moved(left, dx), moved(right, dx)))
            }
            _ => None,
        };
        self.previous_obstacle = obstacle;
        let alarm = obstacle.is_some();
        let (nearest_mm, left_mm, right_mm) = match obstacle {
            Some((near, left, right)) => (Some(near), Some(left), Some(right)),
            None => (None, None, None),
        };
        FrameReport {
            frame: self.frame,
            ref_frame: self.keyframe_frame,
            alarm,
            nearest_mm,
            left_mm,
            right_mm,
            sad: seed_sum,
            count50: seed_count,
            shift_k: libm::round(shift_k * f64::from(SHIFT_SCALE)) as i32,
            shift_g: libm::round(shift_g * f64::from(SHIFT_SCALE)) as i32,
            tx: libm::round(self.motion_to_last.tx_mm * f64::from(MOTION_SCALE)) as i32,
            tz: libm::round(self.motion_to_last.tz_mm * f64::from(MOTION_SCALE)) as i32,
            obstacle_h_mm: if alarm { self.obstacle_height_mm } else { None },
        }
    }

    /// Updates the odometry scale from this frame's refined step: a slow
    /// average, so random per-step errors cancel and a constant one remains.
    fn learn_odometry_scale(&mut self) {
        // The step as measured: refined keyframe->now, minus keyframe->before.
        let (dx, dz) = (
            self.motion_to_last.tx_mm - self.motion_before_step.tx_mm,
            self.motion_to_last.tz_mm - self.motion_before_step.tz_mm,
        );
        let odometry = self.step.distance_mm() / self.odometry_scale;
        // Short steps measure the scale poorly.
        if odometry < 4.0 * self.grid.mm_per_px {
            return;
        }
        let measured = libm::hypot(dx, dz) / odometry;
        if (0.8..=1.25).contains(&measured) {
            self.odometry_scale = (0.8 * self.odometry_scale + 0.2 * measured).clamp(0.8, 1.25);
        }
    }

    /// Yaw error from the K shift of the far and the near half of the AOI:
    /// an extra turn e moves the keyframe match by -e*z sideways, so the two
    /// halves disagree by -e*(z_far - z_near). Returns (extra yaw in degrees,
    /// corrected tx) or None when either half has no clear minimum.
    fn yaw_refinement(&self, best_g: usize, parabola: impl Fn(u32, u32, u32) -> f64) -> Option<(f64, f64)> {
        let s = self.config.search_radius;
        let row_of = |half: &dyn Fn(usize) -> u32| -> Option<f64> {
            let best = (0..=2 * s).min_by_key(|&k| half(k))?;
            if best == 0 || best == 2 * s {
                return None;
            }
            Some(best as f64 - s as f64 + parabola(half(best - 1), half(best), half(best + 1)))
        };
        let far = row_of(&|k| self.sad_far[best_g][k])?;
        let near = row_of(&|k| self.sad_near[best_g][k])?;
        let middle = (self.aoi.top + self.aoi.bottom) / 2;
        let (_, z_far) = self.grid.pixel_to_ground(0.0, (self.aoi.top + middle) as f64 / 2.0);
        let (_, z_near) = self.grid.pixel_to_ground(0.0, (middle + self.aoi.bottom) as f64 / 2.0);
        let mm = self.grid.mm_per_px;
        let extra_yaw = -(far - near) * mm / (z_far - z_near);
        // Beyond a couple of degrees this is not an odometry error but a bad match.
        if libm::fabs(extra_yaw) > 2f64.to_radians() {
            return None;
        }
        let tx_mm = self.predicted.tx_mm + near * mm + extra_yaw * z_near;
        Some((extra_yaw.to_degrees(), tx_mm))
    }

    /// Noise level from this frame's |diff| at the predicted shift, for the
    /// next frame's residue threshold. The median is robust while obstacles
    /// cover less than half the AOI; for Gaussian noise on both images it is
    /// 0.674 * sqrt(2) * sigma.
    fn update_noise(&mut self, histogram: &[u32; 256]) {
        let total: u32 = histogram.iter().sum();
        if total == 0 {
            return;
        }
        let mut seen = 0;
        let mut median = 0u32;
        for (level, &count) in histogram.iter().enumerate() {
            seen += count;
            if seen * 2 >= total {
                median = level as u32;
                break;
            }
        }
        self.noise_floor = median.min(255) as u8;
        // sigma = median / (0.674 * 1.414) ~= median * 1.05
        let sigma = f64::from(median) * 1.05;
        self.noise_x16 = libm::round(sigma * 16.0) as u32;
        let threshold = libm::round(self.config.noise_factor * sigma) as u32;
        self.residue_threshold = threshold.clamp(u32::from(self.config.residue_floor), 120) as u8;
    }

    /// Percentage of a cell's pixels that are residue (0 for cells mostly out of view).
    fn residue_percent(&self, cell: usize) -> u32 {
        let valid = u32::from(self.cell_valid[cell]);
        if valid * 2 < (self.cell_px * self.cell_px) as u32 {
            return 0;
        }
        u32::from(self.cell_residue[cell]) * 100 / valid
    }

    /// Groups cells whose parallax height reaches the obstacle height; returns
    /// the nearest footprint inside the AOI: (nearest z, left x, right x, height).
    ///
    /// A cell at apparent ground position p with height h stands on p*(H-h)/H,
    /// so every cell of a vertical face points at the face's own footprint.
    fn find_parallax_obstacle(&self) -> Option<(i32, i32, i32, i32)> {
        let (w, h) = (self.cells_wide, self.cells_high);
        let min_height = self.config.min_obstacle_height_mm;
        let tall = |cell: usize| f64::from(self.cell_height[cell]) >= min_height;
        let aoi = self.aoi_mm();
        let mut seen = [false; MAX_CELLS];
        let mut best: Option<(f64, f64, f64, f64)> = None;
        for start in 0..h * w {
            let start_cell = start;
            if seen[start_cell] || !tall(start_cell) {
                continue;
            }
            let mut with_residue = false;
            let mut footprints: heapless::Vec<f64, MAX_BLOB_CELLS> = heapless::Vec::new();
            let (mut left, mut right, mut tallest) = (f64::MAX, f64::MIN, 0.0f64);
            let mut cells = 0usize;
            // Parallax is measured only where there is texture, so a face can
            // leave a cell out here and there: bridge one-cell gaps (radius 2).
            flood_cells((w, h), 2, start_cell, &mut seen, tall, |cell, r, c| {
                cells += 1;
                with_residue |= self.residue_percent(cell) >= self.config.active_cell_percent;
                let height = f64::from(self.cell_height[cell]);
                // The cell's measured height belongs to its centre.
                let scale = (self.camera_height_mm - height) / self.camera_height_mm;
                let centre_row = (r as f64 + 0.5) * self.cell_px as f64 - 0.5;
                let (x_left, z_centre) = self.grid.pixel_to_ground((c * self.cell_px) as f64, centre_row);
                let (x_right, _) = self.grid.pixel_to_ground(((c + 1) * self.cell_px) as f64 - 1.0, 0.0);
                let _ = footprints.push(z_centre * scale);
                left = left.min(x_left * scale);
                right = right.max(x_right * scale);
                tallest = tallest.max(height);
            });
            // One cell alone is too easily a fluke of texture, and a small
            // patch of parallax without any residue is a blur difference on a
            // sharp ground edge (the camera resolves it differently from
            // another distance). Smooth obstacles leave little residue but
            // parallax over a wider patch.
            // A short baseline measures heights coarsely, so its footprints
            // wander: there a blob must be large to raise an alarm by itself.
            let short_baseline = self.predicted.distance_mm() < 0.5 * self.config.keyframe_travel_mm;
            if cells < 3 || (!with_residue && cells < 4) || (short_baseline && cells < 8) {
                continue;
            }
            // Every cell of a vertical face points at the same footprint; the
            // lower quartile is robust to the odd cell whose height is off.
            footprints.sort_unstable_by(|a, b| a.total_cmp(b));
            let nearest = footprints[(footprints.len() - 1) / 4];
            let inside = nearest <= aoi.far
                && nearest >= aoi.near - self.cell_px as f64 * self.grid.mm_per_px
                && right >= -aoi.half_width
                && left <= aoi.half_width;
            if inside && best.is_none_or(|b| nearest < b.0) {
                best = Some((nearest, left.max(-aoi.half_width), right.min(aoi.half_width), tallest));
            }
        }
        best.map(|(z, left, right, height)| {
            let z = z.max(aoi.near);
            (libm::round(z) as i32, libm::round(left) as i32, libm::round(right) as i32, libm::round(height) as i32)
        })
    }

    /// The AOI in mm (robot frame).
    fn aoi_mm(&self) -> AoiMm {
        let (left, far) = self.grid.pixel_to_ground(self.aoi.left as f64, self.aoi.top as f64);
        let (_, near) = self.grid.pixel_to_ground(0.0, self.aoi.bottom as f64 - 1.0);
        AoiMm { near, far, half_width: -left }
    }

    /// Labels active cells into blobs; returns the nearest obstacle blob whose
    /// base (nearest point, corrected for where parallax becomes visible)
    /// lies in the AOI.
    fn find_blobs(&mut self) -> Option<Blob> {
        let mut blobs: heapless::Vec<Blob, MAX_BLOBS> = heapless::Vec::new();
        let (w, h) = (self.cells_wide, self.cells_high);
        let mut label = [false; MAX_CELLS];
        let percent = |cell: usize| self.residue_percent(cell);
        let active = |cell: usize| percent(cell) >= self.config.active_cell_percent;
        for start in 0..h * w {
            let start_cell = start;
            if label[start_cell] || !active(start_cell) {
                continue;
            }
            let (sr, sc) = ((start / w) as u8, (start % w) as u8);
            let mut blob =
                Blob { cell_left: sc, cell_right: sc, cell_top: sr, cell_bottom: sr, cells: 0, pixels: 0, peak_percent: 0 };
            flood_cells((w, h), 1, start_cell, &mut label, active, |cell, r, c| {
                blob.cells += 1;
                blob.pixels += u32::from(self.cell_residue[cell]);
                blob.peak_percent = blob.peak_percent.max(percent(cell).min(100) as u8);
                blob.cell_left = blob.cell_left.min(c as u8);
                blob.cell_right = blob.cell_right.max(c as u8);
                blob.cell_top = blob.cell_top.min(r as u8);
                blob.cell_bottom = blob.cell_bottom.max(r as u8);
            });
            if blobs.push(blob).is_err() {
                break;
            }
        }
        self.blobs = blobs;
        let pixel_mm2 = self.grid.mm_per_px * self.grid.mm_per_px;
        let mut best: Option<Blob> = None;
        for blob in self.blobs.iter() {
            let obstacle = u32::from(blob.peak_percent) >= self.config.peak_cell_percent
                && f64::from(blob.pixels) * pixel_mm2 >= self.config.min_residue_mm2;
            if !obstacle {
                continue;
            }
            let left_px = usize::from(blob.cell_left) * self.cell_px;
            let right_px = (usize::from(blob.cell_right) + 1) * self.cell_px;
            let (_, base_z) = self.base_of(blob);
            let aoi = self.aoi;
            let (_, aoi_far_z) = self.grid.pixel_to_ground(0.0, aoi.top as f64);
            let in_aoi = base_z <= aoi_far_z + 0.5 * self.grid.mm_per_px && right_px > aoi.left && left_px < aoi.right;
            if in_aoi && best.is_none_or(|b| blob.cell_bottom > b.cell_bottom) {
                best = Some(*blob);
            }
        }
        best
    }

    /// Nearest residue row of a blob and its apparent ground distance (mm).
    /// Residue of anything standing up appears beyond its footprint, so this
    /// never places a static obstacle nearer than it is: the residue path
    /// cannot raise an early alarm, and parallax measures the true footprint.
    fn base_of(&self, blob: &Blob) -> (usize, f64) {
        let top = usize::from(blob.cell_top) * self.cell_px;
        let bottom = ((usize::from(blob.cell_bottom) + 1) * self.cell_px).min(self.analysis_rows);
        let mut base = bottom.saturating_sub(1);
        while base > top && self.row_residue[base] < 2 {
            base -= 1;
        }
        let (_, apparent_z) = self.grid.pixel_to_ground(0.0, base as f64);
        (base, apparent_z)
    }

    /// Nearest point and lateral extent of a blob, robot frame mm.
    fn locate(&self, blob: &Blob) -> (i32, i32, i32) {
        let (_, near_z) = self.base_of(blob);
        let (_, aoi_near_z) = self.grid.pixel_to_ground(0.0, (self.aoi.bottom.saturating_sub(1)) as f64);
        let near_z = near_z.max(aoi_near_z);
        let left_px = usize::from(blob.cell_left) * self.cell_px;
        let right_px = ((usize::from(blob.cell_right) + 1) * self.cell_px).min(self.grid.width()) - 1;
        let (left, _) = self.grid.pixel_to_ground(left_px as f64, 0.0);
        let (right, _) = self.grid.pixel_to_ground(right_px as f64, 0.0);
        (libm::round(near_z) as i32, libm::round(left) as i32, libm::round(right) as i32)
    }

    /// Blobs found in the last frame (for pictures and tests).
    pub fn blobs(&self) -> &[Blob] {
        &self.blobs
    }
    /// (residue pixels, valid pixels) of coherence cell (row, column) in the last frame.
    pub fn cell_counts(&self, row: usize, column: usize) -> (u8, u8) {
        if row >= self.cells_high || column >= self.cells_wide {
            return (0, 0);
        }
        let cell = row * self.cells_wide + column;
        (self.cell_residue[cell], self.cell_valid[cell])
    }
    /// Parallax height (mm) of a cell in the last frame, 0 for ground.
    pub fn cell_height(&self, row: usize, column: usize) -> u8 {
        if row >= self.cells_high || column >= self.cells_wide {
            return 0;
        }
        self.cell_height[row * self.cells_wide + column]
    }
    /// Coherence cells (rows, columns).
    pub fn cells(&self) -> (usize, usize) {
        (self.cells_high, self.cells_wide)
    }
    pub fn cell_px(&self) -> usize {
        self.cell_px
    }
    /// Which evidence raised the last frame's alarm.
    pub fn alarm_source(&self) -> AlarmSource {
        self.alarm_source
    }
    pub fn predicted(&self) -> Motion {
        self.predicted
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Aoi, Intrinsics, Mount};
    use crate::grid::GridConfig;
    use crate::motion::Pose;

    fn rig() -> Rig {
        Rig::new_checked(
            Intrinsics { width: 256, height: 256, fx: 240.0, fy: 240.0, cx: 127.5, cy: 127.5, distortion: None },
            Mount { height_mm: 400.0, tilt_deg: 32.0 },
            Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 },
        )
        .unwrap()
    }

    /// Ground texture at world (x, z): smooth structure, edges and noise-like detail.
    fn texture(x: f64, z: f64) -> u8 {
        let smooth = 90.0 * libm::sin(x * 0.031) * libm::cos(z * 0.027);
        let edges = if (libm::floor(x / 37.0) as i64 + libm::floor(z / 53.0) as i64) % 3 == 0 { 45.0 } else { 0.0 };
        let hash = ((libm::floor(x / 3.0) as i64).wrapping_mul(73_856_093) ^ (libm::floor(z / 3.0) as i64).wrapping_mul(19_349_663)) & 31;
        (120.0 + smooth + edges + hash as f64).clamp(0.0, 255.0) as u8
    }

    /// The KG image seen from `pose`, with a box-like patch that breaks the ground model.
    fn kg_image(grid: &KgGrid, table: &RemapTable, pose: &Pose, frame: u32) -> std::vec::Vec<u8> {
        let yaw = pose.yaw_deg.to_radians();
        let mut image = std::vec![0u8; grid.len()];
        for j in 0..grid.height() {
            for i in table.valid_columns(j) {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let (wx, wz) = (pose.x_mm + x * libm::cos(yaw) - z * libm::sin(yaw), pose.z_mm + x * libm::sin(yaw) + z * libm::cos(yaw));
                let mut value = texture(wx, wz);
                if (x - 40.0).abs() < 60.0 && (wz - 1700.0).abs() < 40.0 {
                    value = value.wrapping_add((frame as u8).wrapping_mul(37));
                }
                image[j * grid.width() + i] = value;
            }
        }
        image
    }

    /// Everything a row leaves behind; the band as its logical rows over
    /// `band_columns` (nothing reads the rest).
    fn state(gpa: &Gpa, band_columns: Range<usize>) -> std::vec::Vec<u32> {
        let mut v = std::vec::Vec::new();
        v.extend(gpa.sad_near.iter().flatten());
        v.extend(gpa.sad_far.iter().flatten());
        v.extend(gpa.diff_hist.counts().iter());
        v.push(gpa.compared_pixels);
        v.extend(gpa.cell_residue.iter().map(|&x| u32::from(x)));
        v.extend(gpa.cell_valid.iter().map(|&x| u32::from(x)));
        v.extend(gpa.cell_height.iter().map(|&x| u32::from(x)));
        v.extend(gpa.row_residue.iter().map(|&x| u32::from(x)));
        let window = 2 * gpa.config.search_radius + 1;
        let span = band_columns.start + MAX_SEARCH_RADIUS..band_columns.end + MAX_SEARCH_RADIUS;
        for row in logical_band(&gpa.band, gpa.band_first, window).iter().take(window) {
            v.extend(row[span.clone()].iter().map(|&x| u32::from(x)));
        }
        v
    }

    /// The fast row paths leave exactly the state of the per-pixel reference,
    /// on translation (integer and fractional), yaw, reverse, and keyframe swaps.
    #[test]
    fn fast_rows_equal_reference() {
        let rig = rig();
        for mm_per_px in [None, Some(5.0), Some(4.3)] {
            let grid = KgGrid::for_rig(&rig, &GridConfig { mm_per_px, ..GridConfig::default() }).unwrap();
            let table = RemapTable::new(&rig, &grid).unwrap();
            let (mut kf_fast, mut kf_ref) = (std::vec![0u8; Gpa::keyframe_bytes(&grid)], std::vec![0u8; Gpa::keyframe_bytes(&grid)]);
            let mut fast = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut kf_fast).unwrap();
            let mut reference = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut kf_ref).unwrap();
            reference.reference = true;
            let steps = [(0.0, 100.0, 0.0), (0.0, 50.0, 0.0), (13.7, 61.3, 0.0), (-20.0, 40.0, 2.0), (5.0, 30.0, -1.5), (0.0, -35.0, 0.0), (30.0, 60.0, 0.0), (0.0, 45.5, 0.4)];
            let mut pose = Pose::default();
            let mut poses = std::vec![pose];
            for &(tx, tz, dyaw) in steps.iter().cycle().take(14) {
                let yaw = pose.yaw_deg.to_radians();
                pose = Pose {
                    x_mm: pose.x_mm + tx * libm::cos(yaw) - tz * libm::sin(yaw),
                    z_mm: pose.z_mm + tx * libm::sin(yaw) + tz * libm::cos(yaw),
                    yaw_deg: pose.yaw_deg + dyaw,
                };
                poses.push(pose);
            }
            let mut compared = 0;
            for (n, p) in poses.iter().enumerate() {
                let image = kg_image(&grid, &table, p, n as u32);
                let odometry = (n > 0).then(|| Motion::between(&poses[n - 1], p));
                for gpa in [&mut fast, &mut reference] {
                    gpa.begin_frame(n as u32, odometry);
                    for (j, row) in image.chunks_exact(grid.width()).enumerate() {
                        gpa.on_kg_row(j, row);
                    }
                }
                let (a, b) = (fast.end_frame(), reference.end_frame());
                assert_eq!(a, b, "frame {n}");
                let band_columns = fast.band_source.as_ref().map_or(0..0, |(_, _, columns)| columns.clone());
                assert!(state(&fast, band_columns.clone()) == state(&reference, band_columns), "frame {n}: state differs");
                compared += usize::from(a.is_some());
            }
            assert!(compared >= 10 && fast.compared_pixels > 1000, "too little compared: {compared}");
        }
    }
}

//! GTI: heights from motion on GT-images (the seed's §3.2, eq. 11-12).
//!
//! A point at height h projects onto the KG (ground) image at its *apparent*
//! ground position `p_app = s * p`, where p is its true ground position (its
//! foot) relative to the robot and `s = H / (H - h)`. When the robot travels
//! ds, the apparent position moves by `s * ds`: flat markings move with the
//! floor (s = 1), higher points faster. So along a line parallel to the
//! translation, each feature traces a straight locus against distance
//! travelled (the GT-image), and its slope gives `h = H (1 - 1/s)`.
//!
//! Pipeline, fed row by row so the firmware can run it beside the remap:
//! 1. [`Gti::on_kg_row`] samples N lines (parallel to the translation) from
//!    each KG row as it streams out of the remap: one sample per KG row per
//!    line, averaged over a few pixels across the line.
//! 2. [`Gti::end_frame`] takes the odometry since the previous frame, finds
//!    edges on each line (gradient extrema above the line's own noise, with
//!    sub-pixel positions), associates them with the tracks of that line
//!    (prediction from each track's fitted locus, gating, polarity and a small
//!    patch correlation), fits every locus with a robust line fit, and turns
//!    the slopes into heights.
//!
//! Bookkeeping is in millimetres, not pixels: an observation is the apparent
//! position rotated into the odometry world (`q = R(yaw) p_app`), which obeys
//! `q = s (P - C)` with P the point and C the robot position. Projected on a
//! fixed direction u per track this is the line `y = A - s c`, where
//! `c = C . u` is the distance travelled along u: exact for straight runs,
//! sideways runs and arcs alike, and the distance is odometry, never time.
//!
//! Tracks survive [`GtiConfig::max_misses`] frames without a match (the seed's
//! Fig. 7: features that disappear and reappear), and good tracks that end are
//! kept as points of a small map so the points seen so far stay reported.
//!
//! Memory: everything is fixed capacity (see the `MAX_*` constants); the
//! whole state is one [`Gti`] value: 23.4 KB on the host (a test holds it
//! to 24 KB), 19.6 KB on the Cortex-M4F. [`Gti::UNCONFIGURED`] and
//! [`Gti::configure`] set it up in place in a static.

// `!(x > 0.0)` is deliberate, as in geometry.rs: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::geometry::Rig;
use crate::grid::{KgGrid, MAX_GRID_SIDE};
use crate::motion::Motion;
use core::ops::Range;
use heapless::Deque;
use libm::{atan2f, cosf, fabsf, floorf, roundf, sinf, sqrtf};

/// Most GT lines across the AOI (the default uses all of them: each line's
/// samples cost a KG column of RAM).
pub const MAX_LINES: usize = 8;
/// Most tracks alive at once, over all lines.
pub const MAX_TRACKS: usize = 128;
/// Observations kept per track (a sliding window over the latest frames).
pub const MAX_OBSERVATIONS: usize = 16;
/// Most edges considered per line and frame (the strongest win).
pub const MAX_EDGES_PER_LINE: usize = 24;
/// Weaker edges per line that established tracks may continue on
/// (hysteresis: a track's prediction vouches for them).
pub const MAX_WEAK_EDGES_PER_LINE: usize = 64;
/// Threshold of the weak edges relative to the detection threshold.
const WEAK_EDGE_SCALE: f32 = 0.5;
/// Points of ended tracks kept in the map.
pub const MAX_MAP_POINTS: usize = 64;
/// Samples either side of an edge in its matching patch.
pub const PATCH_RADIUS: usize = 3;
const PATCH: usize = 2 * PATCH_RADIUS + 1;
/// Samples per line: one per KG row.
pub const MAX_LINE_SAMPLES: usize = MAX_GRID_SIDE;
/// Most pixels averaged across a line.
pub const MAX_LINE_WIDTH_PX: usize = 7;

/// Observation storage unit: 1/4 mm in i16 (tracks span at most +-8 m).
const OBS_UNITS_PER_MM: f32 = 4.0;
const OBS_LIMIT_MM: f32 = (i16::MAX as f32 - 1.0) / OBS_UNITS_PER_MM;

/// Tuning; one default for every rig (nothing here is per recording).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtiConfig {
    /// GT lines across the AOI, 1..=[`MAX_LINES`].
    pub lines: usize,
    /// KG pixels averaged across each line (odd, 1..=[`MAX_LINE_WIDTH_PX`]):
    /// suppresses floor texture that no line follows.
    pub line_width_px: usize,
    /// Edge threshold in robust standard deviations of the line's gradient.
    pub edge_threshold_sigma: f32,
    /// Edge threshold floor, gray levels per sample (noise-free images).
    pub min_edge_contrast: f32,
    /// Frames a track may go unmatched before it ends.
    pub max_misses: u8,
    /// Slope range s = H/(H-h) searched for a track with one observation:
    /// from slightly below the floor to this many times the travel.
    pub max_initial_slope: f32,
    /// Patch correlation (ZNCC) an association needs.
    pub min_patch_correlation: f32,
    /// Base association gate, KG pixels (sub-pixel noise plus edge jitter).
    pub gate_px: f32,
    /// Observations a track needs before it yields a point.
    pub min_observations: usize,
    /// Quality (0..=100) a point needs to count for [`Gti::height_in_region`]
    /// and the GTI alarm.
    pub good_quality: u8,
    /// Points need this quality to be reported at all.
    pub min_point_quality: u8,
    /// GTI alone never raises an alarm below this height, mm.
    pub min_obstacle_mm: f32,
    /// Odometry's step length error (sigma, fraction of the step): weighs
    /// odometry against the floor's measurement of each step.
    pub odometry_sigma: f32,
    /// Turns the lines follow at most this far from the G axis, degrees
    /// (one sample per KG row needs the line to be steeper than 45 degrees).
    pub max_line_angle_deg: f32,
}

impl Default for GtiConfig {
    fn default() -> Self {
        GtiConfig {
            lines: 8,
            line_width_px: 3,
            edge_threshold_sigma: 1.5,
            min_edge_contrast: 4.0,
            max_misses: 3,
            max_initial_slope: 3.0,
            min_patch_correlation: 0.6,
            gate_px: 1.5,
            min_observations: 5,
            good_quality: 30,
            min_point_quality: 10,
            min_obstacle_mm: 20.0,
            odometry_sigma: 0.03,
            max_line_angle_deg: 40.0,
        }
    }
}

/// Why a configuration or a KG row was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GtiError {
    /// A configuration value is out of range.
    Config,
    /// The KG grid has more rows than [`MAX_LINE_SAMPLES`].
    GridTooLarge,
    /// A KG row's length is not the grid width.
    RowLength,
    /// A KG row index is outside the grid or not after the previous row.
    RowIndex,
}

impl core::fmt::Display for GtiError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            GtiError::Config => "GTI configuration out of range",
            GtiError::GridTooLarge => "KG grid taller than the GTI line buffers",
            GtiError::RowLength => "KG row length is not the grid width",
            GtiError::RowIndex => "KG row index out of range or out of order",
        })
    }
}

// ---------------------------------------------------------------------------
// Pure parts: slope <-> height, sub-pixel peak, robust line fit.

/// Height (mm) of a point whose apparent ground position moves `slope` times
/// the distance travelled: eq. (12), h = H (1 - 1/s).
pub fn height_from_slope(mount_height_mm: f32, slope: f32) -> f32 {
    mount_height_mm * (1.0 - 1.0 / slope)
}

/// Inverse of [`height_from_slope`]: s = H / (H - h).
pub fn slope_from_height(mount_height_mm: f32, height_mm: f32) -> f32 {
    mount_height_mm / (mount_height_mm - height_mm)
}

/// Offset in (-0.5, 0.5) of the vertex of the parabola through three equally
/// spaced samples whose middle one is a maximum; 0 when they are collinear.
pub fn subpixel_peak(before: f32, peak: f32, after: f32) -> f32 {
    let curvature = before - 2.0 * peak + after;
    if !(curvature < 0.0) {
        return 0.0;
    }
    (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
}

/// A straight-line fit `y = intercept + slope * x`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineFit {
    pub slope: f32,
    pub intercept: f32,
    /// Robust residual scale of the inliers (RMS), in y units.
    pub residual: f32,
    /// Points the final fit used.
    pub inliers: usize,
    /// Sum of squared x deviations of the inliers (for the slope's error).
    pub sxx: f32,
}

/// Median of a slice, reordering it; None when empty.
fn median(values: &mut [f32]) -> Option<f32> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    values.sort_unstable_by(|a, b| a.total_cmp(b));
    let upper = *values.get(n / 2)?;
    if n % 2 == 1 {
        Some(upper)
    } else {
        Some(0.5 * (*values.get(n / 2 - 1)? + upper))
    }
}

/// Robust line fit of up to [`MAX_OBSERVATIONS`] points: Theil-Sen (median
/// of pairwise slopes, median intercept), then least squares over the points
/// within 3 robust sigmas of it. None with fewer than 2 points, unequal
/// lengths, or all x equal.
pub fn robust_line_fit(x: &[f32], y: &[f32]) -> Option<LineFit> {
    let n = x.len();
    if n < 2 || n != y.len() || n > MAX_OBSERVATIONS {
        return None;
    }
    let mut slopes = [0f32; MAX_OBSERVATIONS * (MAX_OBSERVATIONS - 1) / 2];
    let mut count = 0;
    for a in 0..n {
        for b in a + 1..n {
            let dx = x[b] - x[a];
            if fabsf(dx) > 1e-6 {
                if let Some(slot) = slopes.get_mut(count) {
                    *slot = (y[b] - y[a]) / dx;
                    count += 1;
                }
            }
        }
    }
    let slope = median(slopes.get_mut(..count)?)?;
    let mut scratch = [0f32; MAX_OBSERVATIONS];
    for (slot, (xi, yi)) in scratch.iter_mut().zip(x.iter().zip(y)) {
        *slot = yi - slope * xi;
    }
    let intercept = median(scratch.get_mut(..n)?)?;
    for (slot, (xi, yi)) in scratch.iter_mut().zip(x.iter().zip(y)) {
        *slot = fabsf(yi - intercept - slope * xi);
    }
    let mad = median(scratch.get_mut(..n)?)?;
    // Floor on the gate: exact data has MAD 0 and every point is an inlier.
    let gate = 3.0 * 1.4826 * mad + 1e-3 * (1.0 + fabsf(intercept));
    let inlier = |i: usize| fabsf(y[i] - intercept - slope * x[i]) <= gate;
    let (mut sx, mut sy, mut m) = (0f32, 0f32, 0usize);
    for i in (0..n).filter(|&i| inlier(i)) {
        sx += x[i];
        sy += y[i];
        m += 1;
    }
    if m < 2 {
        return None;
    }
    let (mx, my) = (sx / m as f32, sy / m as f32);
    let (mut sxx, mut sxy) = (0f32, 0f32);
    for i in (0..n).filter(|&i| inlier(i)) {
        sxx += (x[i] - mx) * (x[i] - mx);
        sxy += (x[i] - mx) * (y[i] - my);
    }
    if !(sxx > 1e-6) {
        return None;
    }
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let mut sum_sq = 0f32;
    for i in (0..n).filter(|&i| inlier(i)) {
        let r = y[i] - intercept - slope * x[i];
        sum_sq += r * r;
    }
    // Unbiased with two fitted parameters; a 2-point fit has no residual.
    let residual = if m > 2 { sqrtf(sum_sq / (m - 2) as f32) } else { 0.0 };
    Some(LineFit { slope, intercept, residual, inliers: m, sxx })
}

/// Zero-mean normalised cross-correlation of two patches; 0 if either is flat.
fn zncc(a: &[u8; PATCH], b: &[u8; PATCH]) -> f32 {
    let mean = |p: &[u8; PATCH]| p.iter().map(|&v| f32::from(v)).sum::<f32>() / PATCH as f32;
    let (ma, mb) = (mean(a), mean(b));
    let (mut sab, mut saa, mut sbb) = (0f32, 0f32, 0f32);
    for (&va, &vb) in a.iter().zip(b) {
        let (da, db) = (f32::from(va) - ma, f32::from(vb) - mb);
        sab += da * db;
        saa += da * da;
        sbb += db * db;
    }
    if saa < 1e-3 || sbb < 1e-3 {
        return 0.0;
    }
    sab / sqrtf(saa * sbb)
}

// ---------------------------------------------------------------------------
// State.

/// One GT line: fixed in the robot frame for a frame, parallel to the
/// translation. Points on it are `offset * normal + t * direction` (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtLine {
    /// Unit direction (x, z), forward.
    pub direction: [f32; 2],
    /// Unit normal (x, z), to the right of the direction.
    pub normal: [f32; 2],
    /// Signed distance of the line from the robot origin along the normal.
    pub offset_mm: f32,
}

impl GtLine {
    /// Ground point (robot frame) at KG row position `row` (fractional).
    pub fn point_at_row(&self, grid: &KgGrid, row: f32) -> [f32; 2] {
        let z = grid.z_far_mm as f32 - row * grid.mm_per_px as f32;
        let t = self.t_at_z(z);
        [self.offset_mm * self.normal[0] + t * self.direction[0], z]
    }
    fn t_at_z(&self, z: f32) -> f32 {
        (z - self.offset_mm * self.normal[1]) / self.direction[1]
    }
    /// KG row position (fractional) where the line passes the ground point's
    /// projection onto it, and the point's distance from the line (mm).
    pub fn row_of(&self, grid: &KgGrid, point: [f32; 2]) -> (f32, f32) {
        let t = point[0] * self.direction[0] + point[1] * self.direction[1];
        let lateral = point[0] * self.normal[0] + point[1] * self.normal[1] - self.offset_mm;
        let z = self.offset_mm * self.normal[1] + t * self.direction[1];
        ((grid.z_far_mm as f32 - z) / grid.mm_per_px as f32, lateral)
    }
}

/// One line's samples for the current frame, indexed by KG row.
#[derive(Clone, Copy, Debug)]
struct LineSamples {
    values: [u8; MAX_LINE_SAMPLES],
    /// First contiguous run of valid samples, `[start, end)`.
    start: u16,
    end: u16,
    /// The run ended (a gap was seen): later samples are ignored.
    closed: bool,
}

impl LineSamples {
    const EMPTY: LineSamples = LineSamples { values: [0; MAX_LINE_SAMPLES], start: 0, end: 0, closed: false };
    fn valid(&self) -> Range<usize> {
        usize::from(self.start)..usize::from(self.end)
    }
}

/// An edge on a line in the current frame.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Edge {
    /// Sub-pixel KG row.
    row: f32,
    /// Gradient magnitude over the local threshold (> 1).
    strength: f32,
    rising: bool,
    patch: [u8; PATCH],
}

/// One feature's locus: observations `(c, y)` in 1/4 mm, relative to its
/// first, where c is the distance travelled along `axis` and y the apparent
/// position along it (module docs).
#[derive(Clone, Debug)]
struct Track {
    id: u32,
    line: u8,
    rising: bool,
    misses: u8,
    patch: [u8; PATCH],
    /// Gradient magnitude of the latest edge, 1/16 gray level per sample:
    /// weak tracks give way to strong new edges when a line is full.
    strength: u16,
    /// World direction u (unit) of the locus, and its normal.
    axis: [f32; 2],
    /// Robot position (odometry world) at the first observation. f32 is
    /// enough: its rounding shifts all of a track's c equally (slope unchanged).
    origin: [f32; 2],
    /// Apparent position along u at the first observation, mm.
    y0: f32,
    /// Latest apparent position across u (mm) and travel across u then.
    w_last: f32,
    across_last: f32,
    observations: Deque<[i16; 2], MAX_OBSERVATIONS>,
    /// KG row (1/64) of the observation matched this frame (for drawing).
    matched_row: Option<u16>,
}

/// A tracked point's estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeightPoint {
    /// Robot frame of the current frame, true (not apparent) position, mm.
    pub x_mm: f32,
    pub z_mm: f32,
    /// Height above the ground, mm.
    pub h_mm: f32,
    /// 0..=100: observations, travel span and fit residual (see [`Gti`]).
    pub quality: u8,
    /// Standard error of the height, mm.
    pub h_sigma_mm: f32,
}

/// A map point: an ended track's estimate, in the odometry world.
#[derive(Clone, Copy, Debug, PartialEq)]
struct MapPoint {
    world: [f32; 2],
    h_mm: f32,
    quality: u8,
    h_sigma_mm: f32,
}

/// A live track as the host draws it on the GT-image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackView {
    pub id: u32,
    pub line: usize,
    /// Observed sub-pixel KG row this frame, if matched.
    pub observed_row: Option<f32>,
    /// Row the fitted locus predicts for this frame.
    pub fitted_row: Option<f32>,
    /// Current estimate, once the track has enough observations.
    pub point: Option<HeightPoint>,
}

/// A robot-frame rectangle, mm (inclusive).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RegionMm {
    pub x_min: f32,
    pub x_max: f32,
    pub z_min: f32,
    pub z_max: f32,
}

impl RegionMm {
    pub fn contains(&self, x: f32, z: f32) -> bool {
        x >= self.x_min && x <= self.x_max && z >= self.z_min && z <= self.z_max
    }
}

/// The GTI stage. Quality of a point is
/// `100 * min(1, n / FULL_QUALITY_OBSERVATIONS) * QUALITY_SIGMA_MM / (QUALITY_SIGMA_MM + sigma_h)`
/// with n observations and sigma_h the height's standard error from the fit.
pub struct Gti {
    config: GtiConfig,
    grid: KgGrid,
    mount_height_mm: f32,
    aoi_half_width_mm: f32,
    aoi_mid_z_mm: f32,
    lines: [GtLine; MAX_LINES],
    samples: [LineSamples; MAX_LINES],
    next_row: u16,
    /// A row of the current frame arrived (the samples are this frame's).
    frame_started: bool,
    /// Line angle for the next frame (from this frame's translation).
    next_line_angle: Option<f32>,
    tracks: [Option<Track>; MAX_TRACKS],
    map: Deque<MapPoint, MAX_MAP_POINTS>,
    next_id: u32,
    /// Odometry world pose of the current frame.
    position: [f64; 2],
    yaw_rad: f64,
    /// Step lengths the floor measured, and odometry's for the same steps.
    travel_sums: [f64; 2],
    frames: u32,
}

/// Observations at which the quality stops growing with their count.
pub const FULL_QUALITY_OBSERVATIONS: usize = 10;
/// Height error (mm) at which quality is halved.
pub const QUALITY_SIGMA_MM: f32 = 3.0;
/// Points within this height (or this fraction of it) support each other in
/// [`Gti::height_in_region`].
const SUPPORT_TOLERANCE_MM: f32 = 6.0;
const SUPPORT_TOLERANCE_FRACTION: f32 = 0.06;
/// Travel (mm) measured by the floor before its scale is applied to odometry.
const SCALE_MIN_TRAVEL_MM: f64 = 100.0;
/// Largest odometry scale error corrected (a factor): beyond it, the floor
/// measurement is more likely wrong than the wheels.
const MAX_SCALE_ERROR: f32 = 1.2;
/// Floor tracks the travel correction needs in a frame.
const MIN_FLOOR_TRACKS: usize = 6;
/// Fitted slopes within this of 1 count as floor for the travel correction
/// (wide enough for a few % of odometry scale error before correction).
const FLOOR_SLOPE_BAND: f32 = 0.08;
/// Good points [`Gti::height_in_region`] needs at one height.
pub const MIN_SUPPORT: usize = 3;

impl Gti {
    /// A GTI stage for a rig and the KG grid its remap fills.
    pub fn new(rig: &Rig, grid: &KgGrid, config: GtiConfig) -> Result<Gti, GtiError> {
        let mut gti = Gti::UNCONFIGURED;
        gti.configure(rig, grid, config)?;
        Ok(gti)
    }

    /// A stage with no rig yet, for a `static` ([`Gti::configure`] sets it
    /// up in place: a ~20 KB value must not pass through a small stack).
    pub const UNCONFIGURED: Gti = {
        const NO_TRACK: Option<Track> = None;
        const LINE: GtLine = GtLine { direction: [0.0, 1.0], normal: [1.0, 0.0], offset_mm: 0.0 };
        Gti {
            config: GtiConfig {
                lines: 1,
                line_width_px: 1,
                edge_threshold_sigma: 1.0,
                min_edge_contrast: 0.0,
                max_misses: 0,
                max_initial_slope: 2.0,
                min_patch_correlation: 1.0,
                gate_px: 1.0,
                min_observations: 3,
                good_quality: 100,
                min_point_quality: 100,
                min_obstacle_mm: 0.0,
                odometry_sigma: 1.0,
                max_line_angle_deg: 0.0,
            },
            grid: KgGrid { mm_per_px: 1.0, x_left_mm: 0.0, z_far_mm: 0.0, width: 0, height: 0 },
            mount_height_mm: 1.0,
            aoi_half_width_mm: 0.0,
            aoi_mid_z_mm: 0.0,
            lines: [LINE; MAX_LINES],
            samples: [LineSamples::EMPTY; MAX_LINES],
            next_row: 0,
            frame_started: false,
            next_line_angle: None,
            tracks: [NO_TRACK; MAX_TRACKS],
            map: Deque::new(),
            next_id: 0,
            position: [0.0; 2],
            yaw_rad: 0.0,
            travel_sums: [0.0; 2],
            frames: 0,
        }
    };

    /// Sets the stage up for a rig and the KG grid its remap fills, in
    /// place; everything from an earlier rig is forgotten. On error the
    /// stage is left unchanged.
    pub fn configure(&mut self, rig: &Rig, grid: &KgGrid, config: GtiConfig) -> Result<(), GtiError> {
        let c = &config;
        let config_ok = (1..=MAX_LINES).contains(&c.lines)
            && (1..=MAX_LINE_WIDTH_PX).contains(&c.line_width_px)
            && c.line_width_px % 2 == 1
            && c.edge_threshold_sigma > 0.0
            && c.min_edge_contrast >= 0.0
            && c.max_initial_slope > 1.0
            && c.min_patch_correlation <= 1.0
            && c.gate_px > 0.0
            && (3..=MAX_OBSERVATIONS).contains(&c.min_observations)
            && c.good_quality <= 100
            && c.min_point_quality <= c.good_quality
            && c.min_obstacle_mm.is_finite()
            && c.odometry_sigma > 0.0
            && c.odometry_sigma.is_finite()
            && c.max_line_angle_deg >= 0.0
            && c.max_line_angle_deg <= 45.0;
        if !config_ok {
            return Err(GtiError::Config);
        }
        if grid.height() > MAX_LINE_SAMPLES {
            return Err(GtiError::GridTooLarge);
        }
        let aoi = rig.aoi();
        self.config = config;
        self.grid = *grid;
        self.mount_height_mm = rig.height_mm() as f32;
        self.aoi_half_width_mm = aoi.half_width_mm as f32;
        self.aoi_mid_z_mm = (0.5 * (aoi.near_mm + aoi.far_mm)) as f32;
        for samples in self.samples.iter_mut() {
            samples.start = 0;
            samples.end = 0;
            samples.closed = false;
        }
        self.next_row = 0;
        self.frame_started = false;
        self.next_line_angle = None;
        self.restart();
        self.next_id = 0;
        self.position = [0.0; 2];
        self.yaw_rad = 0.0;
        self.travel_sums = [0.0; 2];
        self.frames = 0;
        self.place_lines(0.0);
        Ok(())
    }

    pub fn config(&self) -> &GtiConfig {
        &self.config
    }
    pub fn grid(&self) -> &KgGrid {
        &self.grid
    }
    /// The lines sampled in the current frame.
    pub fn lines(&self) -> &[GtLine] {
        self.lines.get(..self.config.lines).unwrap_or(&[])
    }
    /// Frames completed so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Lines parallel to `angle` (from the G axis, positive to the right),
    /// spread evenly across the AOI at its middle depth.
    fn place_lines(&mut self, angle: f32) {
        let (sin, cos) = (sinf(angle), cosf(angle));
        let n = self.config.lines;
        let spacing = 2.0 * self.aoi_half_width_mm / n as f32;
        for (l, line) in self.lines.iter_mut().take(n).enumerate() {
            let x = -self.aoi_half_width_mm + (l as f32 + 0.5) * spacing;
            let normal = [cos, -sin];
            *line = GtLine {
                direction: [sin, cos],
                normal,
                offset_mm: x * normal[0] + self.aoi_mid_z_mm * normal[1],
            };
        }
    }

    /// Samples the lines from KG row `row` of the current frame; call it from
    /// the streaming remap's callback with the columns the camera sees
    /// (`RemapTable::valid_columns`). Rows must come in increasing order.
    pub fn on_kg_row(&mut self, row: usize, kg_row: &[u8], valid_columns: Range<usize>) -> Result<(), GtiError> {
        if kg_row.len() != self.grid.width() {
            return Err(GtiError::RowLength);
        }
        if !self.frame_started {
            self.clear_samples();
            self.frame_started = true;
        }
        if row >= self.grid.height() || row < usize::from(self.next_row) {
            return Err(GtiError::RowIndex);
        }
        self.next_row = row as u16 + 1;
        let valid = valid_columns.start..valid_columns.end.min(kg_row.len());
        let half = (self.config.line_width_px / 2) as f32;
        let grid = self.grid;
        for (line, samples) in self.lines.iter().zip(self.samples.iter_mut()).take(self.config.lines) {
            if samples.closed {
                continue;
            }
            let [x, _] = line.point_at_row(&grid, row as f32);
            let centre = (x - grid.x_left_mm as f32) / grid.mm_per_px as f32;
            let value = sample_across(kg_row, &valid, centre, half);
            match value {
                Some(v) => {
                    if samples.start == samples.end {
                        samples.start = row as u16;
                    } else if usize::from(samples.end) != row {
                        samples.closed = true;
                        continue;
                    }
                    if let Some(slot) = samples.values.get_mut(row) {
                        *slot = v;
                    }
                    samples.end = row as u16 + 1;
                }
                None => {
                    if samples.start != samples.end {
                        samples.closed = true;
                    }
                }
            }
        }
        Ok(())
    }

    /// Starts a frame: forget the last frame's samples, turn the lines.
    fn clear_samples(&mut self) {
        if let Some(angle) = self.next_line_angle.take() {
            self.place_lines(angle);
        }
        for samples in self.samples.iter_mut() {
            samples.start = 0;
            samples.end = 0;
            samples.closed = false;
        }
        self.next_row = 0;
    }

    /// The latest frame's samples of line `l` (indexed by KG row) and the
    /// valid rows; kept until the next frame's first row.
    pub fn line_samples(&self, l: usize) -> Option<(&[u8], Range<usize>)> {
        let samples = self.samples.get(l).filter(|_| l < self.config.lines)?;
        Some((&samples.values[..self.grid.height().min(MAX_LINE_SAMPLES)], samples.valid()))
    }

    /// Drops the current frame's rows (a frame abandoned mid-way): the next
    /// row starts a new frame.
    pub fn abort_frame(&mut self) {
        self.frame_started = false;
    }

    /// Forgets every track and map point (the odometry has a gap, so the
    /// loci cannot be continued); the current frame's rows and the learned
    /// odometry scale (a property of the wheels) are kept.
    pub fn restart(&mut self) {
        for slot in self.tracks.iter_mut() {
            *slot = None;
        }
        self.map.clear();
    }

    /// Ends the frame: `motion` is the odometry from the previous frame to
    /// this one (in the previous robot frame; zero for the first frame).
    pub fn end_frame(&mut self, motion: &Motion) {
        if !self.frame_started {
            self.clear_samples(); // no rows arrived: nothing to see this frame
        }
        self.frame_started = false;
        let before = self.position;
        let scale = f64::from(self.odometry_scale());
        let scaled = Motion { tx_mm: motion.tx_mm * scale, tz_mm: motion.tz_mm * scale, dyaw_deg: motion.dyaw_deg };
        self.advance_pose(&scaled);
        let step = [self.position[0] - before[0], self.position[1] - before[1]];
        if let Some(measured) = self.correct_travel(step) {
            self.travel_sums[0] += f64::from(measured);
            self.travel_sums[1] += motion.distance_mm();
        }
        for track in self.tracks.iter_mut().flatten() {
            track.matched_row = None;
        }
        for l in 0..self.config.lines {
            let mut edges: heapless::Vec<Edge, MAX_EDGES_PER_LINE> = heapless::Vec::new();
            let mut weak_edges: heapless::Vec<Edge, MAX_WEAK_EDGES_PER_LINE> = heapless::Vec::new();
            if let Some(samples) = self.samples.get(l) {
                find_edges(samples, &self.config, 1.0, &mut edges);
                find_edges(samples, &self.config, WEAK_EDGE_SCALE, &mut weak_edges);
            }
            self.associate_line(l, &edges, &weak_edges);
        }
        self.end_lost_tracks();
        // Next frame's lines follow this frame's translation (the best guess
        // of the next one); without translation they keep their direction.
        if motion.distance_mm() > 1.0 {
            let limit = self.config.max_line_angle_deg.to_radians();
            let angle = atan2f(motion.tx_mm as f32, motion.tz_mm as f32).clamp(-limit, limit);
            self.next_line_angle = Some(angle);
        }
        self.frames = self.frames.saturating_add(1);
    }

    fn advance_pose(&mut self, motion: &Motion) {
        let (sin, cos) = (libm::sin(self.yaw_rad), libm::cos(self.yaw_rad));
        // Robot frame -> world, as `Pose::robot_to_world`.
        self.position[0] += motion.tx_mm * cos - motion.tz_mm * sin;
        self.position[1] += motion.tx_mm * sin + motion.tz_mm * cos;
        self.yaw_rad += motion.dyaw_deg.to_radians();
    }

    /// Corrects this frame's odometry step (`step`, world, mm) along its
    /// direction with the floor: a floor feature's apparent position moves by
    /// exactly the travel (slope 1), so the floor tracks' displacements
    /// measure the true step. Odometry scale errors (wheel wear, slip) would
    /// otherwise scale every slope: +2 % of travel reads the floor at
    /// -H/50 = -8 mm on a 400 mm mount. The visual step is the median over
    /// floor tracks matched in the previous frame, blended with odometry by
    /// their variances (`odometry_sigma` against the tracks' spread), so a
    /// bare floor or a scene filled by one obstacle falls back on odometry.
    /// Returns the corrected step length when the floor measured it.
    fn correct_travel(&mut self, step: [f64; 2]) -> Option<f32> {
        let length = libm::hypot(step[0], step[1]) as f32;
        if !(length > 1.0) {
            return None;
        }
        let d = [step[0] as f32 / length, step[1] as f32 / length];
        let mm_per_px = self.grid.mm_per_px as f32;
        let mut deltas: heapless::Vec<f32, MAX_TRACKS> = heapless::Vec::new();
        for l in 0..self.config.lines {
            let Some(line) = self.lines.get(l).copied() else { continue };
            let mut edges: heapless::Vec<Edge, MAX_EDGES_PER_LINE> = heapless::Vec::new();
            if let Some(samples) = self.samples.get(l) {
                find_edges(samples, &self.config, 1.0, &mut edges);
            }
            for track in self.tracks.iter().flatten().filter(|t| usize::from(t.line) == l) {
                if let Some(delta) = self.floor_displacement(track, &line, &edges, d, length, mm_per_px) {
                    let _ = deltas.push(delta);
                }
            }
        }
        if deltas.len() < MIN_FLOOR_TRACKS {
            return None;
        }
        let visual = median(&mut deltas)?;
        let mut spread: heapless::Vec<f32, MAX_TRACKS> = deltas.iter().map(|v| fabsf(v - visual)).collect();
        let per_track = (1.4826 * median(&mut spread).unwrap_or(0.0)).max(0.1 * mm_per_px);
        // Median of n: ~1.25 sigma / sqrt(n).
        let visual_var = {
            let s = 1.25 * per_track / sqrtf(deltas.len() as f32);
            s * s
        };
        let odometry_var = {
            let s = self.config.odometry_sigma * length;
            s * s
        };
        let correction = visual * odometry_var / (odometry_var + visual_var);
        self.position[0] += f64::from(correction * d[0]);
        self.position[1] += f64::from(correction * d[1]);
        Some(length + correction)
    }

    /// Odometry's scale as the floor measured it so far (1 until it has):
    /// a constant error (wheel diameter) is then gone from the steps before
    /// the floor corrects them, and from steps where it cannot.
    pub fn odometry_scale(&self) -> f32 {
        let [measured, odometry] = self.travel_sums;
        if !(odometry > SCALE_MIN_TRAVEL_MM) {
            return 1.0;
        }
        ((measured / odometry) as f32).clamp(1.0 / MAX_SCALE_ERROR, MAX_SCALE_ERROR)
    }

    /// For a floor track (matched last frame, slope near 1): the
    /// travel (mm, along `d`) beyond the odometry step that its edge in this
    /// frame implies, if it finds one.
    fn floor_displacement(
        &self,
        track: &Track,
        line: &GtLine,
        edges: &[Edge],
        d: [f32; 2],
        length: f32,
        mm_per_px: f32,
    ) -> Option<f32> {
        // Three observations give a slope to tell floor from obstacle; waiting
        // for more would leave the first steps' error in every track.
        if track.misses != 0 || track.observations.len() < 3 {
            return None;
        }
        let along = d[0] * track.axis[0] + d[1] * track.axis[1];
        if along < 0.7 {
            return None; // the track's axis is not the travel's: its y says little
        }
        let fit = Self::fit(track)?;
        if fabsf(-fit.slope - 1.0) > FLOOR_SLOPE_BAND {
            return None;
        }
        // Where it is with slope 1 and the odometry step.
        let predicted = self.predict_apparent(track, 1.0, None)?;
        let (row, lateral) = line.row_of(&self.grid, predicted);
        if fabsf(lateral) > 2.0 * mm_per_px {
            return None;
        }
        let window = self.config.gate_px + 3.0 * self.config.odometry_sigma * length / mm_per_px;
        let mut best: Option<(f32, f32)> = None;
        for edge in edges.iter().filter(|e| e.rising == track.rising && fabsf(e.row - row) <= window) {
            if zncc(&track.patch, &edge.patch) < self.config.min_patch_correlation {
                continue;
            }
            let distance = fabsf(edge.row - row);
            if best.is_none_or(|(_, b)| distance < b) {
                best = Some((edge.row, distance));
            }
        }
        let (observed_row, _) = best?;
        let u = track.axis;
        let y_of = |p: [f32; 2]| {
            let q = self.to_world_rotation(p);
            q[0] * u[0] + q[1] * u[1]
        };
        let y_predicted = y_of(line.point_at_row(&self.grid, row));
        let y_observed = y_of(line.point_at_row(&self.grid, observed_row));
        Some((y_predicted - y_observed) / along)
    }

    /// Robot frame -> world-rotated (not translated) vector, and back.
    fn to_world_rotation(&self, p: [f32; 2]) -> [f32; 2] {
        let (sin, cos) = (libm::sin(self.yaw_rad) as f32, libm::cos(self.yaw_rad) as f32);
        [p[0] * cos - p[1] * sin, p[0] * sin + p[1] * cos]
    }
    fn to_robot_rotation(&self, q: [f32; 2]) -> [f32; 2] {
        let (sin, cos) = (libm::sin(self.yaw_rad) as f32, libm::cos(self.yaw_rad) as f32);
        [q[0] * cos + q[1] * sin, -q[0] * sin + q[1] * cos]
    }

    /// Distance travelled along and across a track's axis since its origin.
    fn travel(&self, track: &Track) -> (f32, f32) {
        let d = [
            (self.position[0] - f64::from(track.origin[0])) as f32,
            (self.position[1] - f64::from(track.origin[1])) as f32,
        ];
        let u = track.axis;
        (d[0] * u[0] + d[1] * u[1], d[0] * u[1] - d[1] * u[0])
    }

    /// Apparent position (robot frame, mm) of a track's feature in the
    /// current frame, for slope `slope`, from its latest observation.
    fn predict_apparent(&self, track: &Track, slope: f32, fit: Option<&LineFit>) -> Option<[f32; 2]> {
        let (c_now, across_now) = self.travel(track);
        let &[c_last, y_last] = track.observations.back()?;
        let (c_last, y_last) = (f32::from(c_last) / OBS_UNITS_PER_MM, f32::from(y_last) / OBS_UNITS_PER_MM);
        let y = match fit {
            Some(fit) => fit.intercept + fit.slope * c_now,
            None => y_last - slope * (c_now - c_last),
        } + track.y0;
        let w = track.w_last - slope * (across_now - track.across_last);
        let u = track.axis;
        // q = y u + w u_perp, with u_perp = (u_z, -u_x) as in `travel`.
        Some(self.to_robot_rotation([y * u[0] + w * u[1], y * u[1] - w * u[0]]))
    }

    fn fit(track: &Track) -> Option<LineFit> {
        let mut c = [0f32; MAX_OBSERVATIONS];
        let mut y = [0f32; MAX_OBSERVATIONS];
        let n = track.observations.len();
        for (i, &[ci, yi]) in track.observations.iter().enumerate() {
            if let (Some(cs), Some(ys)) = (c.get_mut(i), y.get_mut(i)) {
                *cs = f32::from(ci) / OBS_UNITS_PER_MM;
                *ys = f32::from(yi) / OBS_UNITS_PER_MM;
            }
        }
        robust_line_fit(c.get(..n)?, y.get(..n)?)
    }

    /// Slope range the fit allows (h from below the floor to near the camera).
    fn slope_plausible(slope: f32) -> bool {
        (0.7..=20.0).contains(&slope)
    }

    fn associate_line(&mut self, l: usize, edges: &[Edge], weak_edges: &[Edge]) {
        let Some(line) = self.lines.get(l).copied() else { return };
        let grid = self.grid;
        let mm_per_px = grid.mm_per_px as f32;
        let mut taken = [false; MAX_EDGES_PER_LINE];
        let mut weak_taken = [false; MAX_WEAK_EDGES_PER_LINE];
        // Oldest tracks first: their predictions are the tightest.
        let mut order: heapless::Vec<(usize, usize), MAX_TRACKS> = heapless::Vec::new();
        for (index, track) in self.tracks.iter().enumerate() {
            if let Some(track) = track.as_ref().filter(|t| usize::from(t.line) == l) {
                let _ = order.push((track.observations.len(), index));
            }
        }
        order.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        for &(_, index) in order.iter() {
            let Some(track) = self.tracks.get(index).and_then(|t| t.as_ref()) else { continue };
            let fit = if track.observations.len() >= 2 { Self::fit(track) } else { None };
            // Window of rows where the feature may be, and the preferred row.
            let misses = f32::from(track.misses);
            let (window, preferred) = match fit {
                Some(fit) if track.observations.len() >= 3 => {
                    let slope = -fit.slope;
                    let Some(p) = self.predict_apparent(track, slope, Some(&fit)) else { continue };
                    let (row, lateral) = line.row_of(&grid, p);
                    if fabsf(lateral) > 2.0 * mm_per_px {
                        continue;
                    }
                    let gate = (self.config.gate_px * (1.0 + 0.5 * misses)) + 3.0 * fit.residual / mm_per_px;
                    ((row - gate, row + gate), Some(row))
                }
                _ => {
                    // One or two observations: any slope in the initial range.
                    let slope_hint = fit.map(|f| -f.slope).filter(|s| Self::slope_plausible(*s));
                    let (low, high) = match slope_hint {
                        Some(s) => (s * 0.85, s * 1.15),
                        None => (0.85, self.config.max_initial_slope),
                    };
                    let (Some(a), Some(b)) =
                        (self.predict_apparent(track, low, None), self.predict_apparent(track, high, None))
                    else {
                        continue;
                    };
                    let ((ra, la), (rb, lb)) = (line.row_of(&grid, a), line.row_of(&grid, b));
                    if fabsf(la).min(fabsf(lb)) > 2.0 * mm_per_px {
                        continue;
                    }
                    let gate = self.config.gate_px * (1.0 + 0.5 * misses);
                    ((ra.min(rb) - gate, ra.max(rb) + gate), None)
                }
            };
            let established = preferred.is_some();
            let track_patch = track.patch;
            let track_rising = track.rising;
            let pick = |list: &[Edge], used: &[bool]| -> Option<usize> {
                let mut best: Option<(usize, f32)> = None;
                for (e, edge) in list.iter().enumerate() {
                    if used.get(e).copied().unwrap_or(true) || edge.rising != track_rising {
                        continue;
                    }
                    if edge.row < window.0 || edge.row > window.1 {
                        continue;
                    }
                    let correlation = zncc(&track_patch, &edge.patch);
                    if correlation < self.config.min_patch_correlation {
                        continue;
                    }
                    let half_width = 0.5 * (window.1 - window.0);
                    let distance_penalty = preferred.map_or(0.0, |row| 0.2 * fabsf(edge.row - row) / half_width);
                    let score = correlation - distance_penalty;
                    if best.is_none_or(|(_, s)| score > s) {
                        best = Some((e, score));
                    }
                }
                best.map(|(e, _)| e)
            };
            let matched = match pick(edges, &taken) {
                Some(e) => {
                    if let Some(flag) = taken.get_mut(e) {
                        *flag = true;
                    }
                    edges.get(e).copied()
                }
                None if established => {
                    // Continue on a weaker edge that no strong edge claimed.
                    let weak = pick(weak_edges, &weak_taken);
                    if let Some(flag) = weak.and_then(|e| weak_taken.get_mut(e)) {
                        *flag = true;
                    }
                    weak.and_then(|e| weak_edges.get(e)).copied()
                }
                None => None,
            };
            if let Some(edge) = matched {
                // The strong and weak lists share edges: claim it in both.
                for (e, other) in edges.iter().enumerate() {
                    if fabsf(other.row - edge.row) < 1e-3 {
                        if let Some(flag) = taken.get_mut(e) {
                            *flag = true;
                        }
                    }
                }
                for (e, other) in weak_edges.iter().enumerate() {
                    if fabsf(other.row - edge.row) < 1e-3 {
                        if let Some(flag) = weak_taken.get_mut(e) {
                            *flag = true;
                        }
                    }
                }
                let point = line.point_at_row(&grid, edge.row);
                self.observe(index, point, &edge);
            } else if let Some(track) = self.tracks.get_mut(index).and_then(|t| t.as_mut()) {
                track.misses = track.misses.saturating_add(1);
            }
        }
        // Unmatched edges start tracks, strongest first, within the line's
        // share; when it is full, a much stronger edge replaces the weakest
        // track (floor texture must not crowd out an obstacle's edges).
        let share = MAX_TRACKS / self.config.lines;
        for (e, edge) in edges.iter().enumerate() {
            if taken.get(e).copied().unwrap_or(true) {
                continue;
            }
            let strength = encode_strength(edge.strength);
            let on_line = self.tracks.iter().flatten().filter(|t| usize::from(t.line) == l).count();
            let slot = if on_line < share {
                self.tracks.iter().position(|t| t.is_none())
            } else {
                let weakest = self
                    .tracks
                    .iter()
                    .enumerate()
                    .filter_map(|(i, t)| t.as_ref().filter(|t| usize::from(t.line) == l).map(|t| (i, t.strength)))
                    .min_by_key(|&(_, s)| s);
                match weakest {
                    Some((i, s)) if u32::from(strength) * 2 > u32::from(s) * 3 => {
                        self.end_track(i);
                        Some(i)
                    }
                    _ => None,
                }
            };
            let Some(slot) = slot else { continue };
            let point = line.point_at_row(&grid, edge.row);
            let q = self.to_world_rotation(point);
            let axis = self.to_world_rotation(line.direction);
            let mut observations = Deque::new();
            let _ = observations.push_back([0i16, 0i16]);
            let track = Track {
                id: self.next_id,
                line: l as u8,
                rising: edge.rising,
                misses: 0,
                patch: edge.patch,
                strength,
                axis,
                origin: [self.position[0] as f32, self.position[1] as f32],
                y0: q[0] * axis[0] + q[1] * axis[1],
                w_last: q[0] * axis[1] - q[1] * axis[0],
                across_last: 0.0,
                observations,
                matched_row: encode_row(edge.row),
            };
            self.next_id = self.next_id.wrapping_add(1);
            if let Some(s) = self.tracks.get_mut(slot) {
                *s = Some(track);
            }
        }
    }

    /// Records a matched edge (at ground point `point`, robot frame) on a track.
    fn observe(&mut self, index: usize, point: [f32; 2], edge: &Edge) {
        let q = self.to_world_rotation(point);
        let Some(track) = self.tracks.get(index).and_then(|t| t.as_ref()) else { return };
        let (c, across) = self.travel(track);
        let u = track.axis;
        let y = q[0] * u[0] + q[1] * u[1] - track.y0;
        let w = q[0] * u[1] - q[1] * u[0];
        let Some(track) = self.tracks.get_mut(index).and_then(|t| t.as_mut()) else { return };
        if fabsf(c) > OBS_LIMIT_MM || fabsf(y) > OBS_LIMIT_MM {
            track.misses = u8::MAX; // outgrew its storage: end it
            return;
        }
        if track.observations.is_full() {
            track.observations.pop_front();
        }
        let _ = track.observations.push_back([roundf(c * OBS_UNITS_PER_MM) as i16, roundf(y * OBS_UNITS_PER_MM) as i16]);
        track.w_last = w;
        track.across_last = across;
        track.misses = 0;
        track.patch = edge.patch;
        track.strength = encode_strength(edge.strength);
        track.matched_row = encode_row(edge.row);
    }

    /// Ends tracks missed too often or with an implausible locus; good ones
    /// become map points.
    fn end_lost_tracks(&mut self) {
        for index in 0..MAX_TRACKS {
            let Some(track) = self.tracks.get(index).and_then(|t| t.as_ref()) else { continue };
            let fit = if track.observations.len() >= 3 { Self::fit(track) } else { None };
            let implausible = fit.is_some_and(|f| !Self::slope_plausible(-f.slope));
            if track.misses <= self.config.max_misses && !implausible {
                continue;
            }
            self.end_track(index);
        }
    }

    /// Ends a track; a good one becomes a map point.
    fn end_track(&mut self, index: usize) {
        {
            let Some(track) = self.tracks.get(index).and_then(|t| t.as_ref()) else { return };
            if let Some(point) = self.estimate(track) {
                if point.quality >= self.config.good_quality {
                    let (sin, cos) = (libm::sin(self.yaw_rad), libm::cos(self.yaw_rad));
                    let (x, z) = (f64::from(point.x_mm), f64::from(point.z_mm));
                    let world = [
                        (self.position[0] + x * cos - z * sin) as f32,
                        (self.position[1] + x * sin + z * cos) as f32,
                    ];
                    if self.map.is_full() {
                        self.map.pop_front();
                    }
                    let _ = self.map.push_back(MapPoint {
                        world,
                        h_mm: point.h_mm,
                        quality: point.quality,
                        h_sigma_mm: point.h_sigma_mm,
                    });
                }
            }
        }
        if let Some(slot) = self.tracks.get_mut(index) {
            *slot = None;
        }
    }

    /// A track's point in the current robot frame, once it has enough
    /// observations and a plausible slope.
    fn estimate(&self, track: &Track) -> Option<HeightPoint> {
        let n = track.observations.len();
        if n < self.config.min_observations {
            return None;
        }
        let fit = Self::fit(track)?;
        let slope = -fit.slope;
        if !Self::slope_plausible(slope) {
            return None;
        }
        let apparent = self.predict_apparent(track, slope, Some(&fit))?;
        let h = height_from_slope(self.mount_height_mm, slope);
        // Sub-pixel floor on the residual: a perfect fit is not infinitely sure.
        let position_sigma = fit.residual.max(0.05 * self.grid.mm_per_px as f32);
        let slope_sigma = position_sigma / sqrtf(fit.sxx.max(1e-6));
        let h_sigma = self.mount_height_mm / (slope * slope) * slope_sigma;
        let count_factor = (fit.inliers as f32 / FULL_QUALITY_OBSERVATIONS as f32).min(1.0);
        let quality = 100.0 * count_factor * QUALITY_SIGMA_MM / (QUALITY_SIGMA_MM + h_sigma);
        Some(HeightPoint {
            x_mm: apparent[0] / slope,
            z_mm: apparent[1] / slope,
            h_mm: h,
            quality: roundf(quality).clamp(0.0, 100.0) as u8,
            h_sigma_mm: h_sigma,
        })
    }

    /// Every point seen so far (live tracks and the map) with at least
    /// `min_point_quality`, in the current robot frame; map points behind
    /// the robot are left out.
    pub fn points(&self) -> impl Iterator<Item = HeightPoint> + '_ {
        let min_quality = self.config.min_point_quality;
        let live = self.tracks.iter().flatten().filter_map(|t| self.estimate(t));
        let (sin, cos) = (libm::sin(self.yaw_rad), libm::cos(self.yaw_rad));
        let mapped = self.map.iter().map(move |m| {
            let (dx, dz) = (f64::from(m.world[0]) - self.position[0], f64::from(m.world[1]) - self.position[1]);
            HeightPoint {
                x_mm: (dx * cos + dz * sin) as f32,
                z_mm: (-dx * sin + dz * cos) as f32,
                h_mm: m.h_mm,
                quality: m.quality,
                h_sigma_mm: m.h_sigma_mm,
            }
        });
        live.chain(mapped.filter(|p| p.z_mm > 0.0)).filter(move |p| p.quality >= min_quality)
    }

    /// Edges of line `l` in the latest frame: (sub-pixel KG row, gradient
    /// magnitude, rising), strongest first. Recomputed on each call.
    pub fn line_edges(&self, l: usize) -> heapless::Vec<(f32, f32, bool), MAX_EDGES_PER_LINE> {
        let mut edges: heapless::Vec<Edge, MAX_EDGES_PER_LINE> = heapless::Vec::new();
        if let Some(samples) = self.samples.get(l).filter(|_| l < self.config.lines) {
            find_edges(samples, &self.config, 1.0, &mut edges);
        }
        edges.iter().map(|e| (e.row, e.strength, e.rising)).collect()
    }

    /// Live tracks, for drawing GT-images with their loci.
    pub fn tracks(&self) -> impl Iterator<Item = TrackView> + '_ {
        self.tracks.iter().flatten().map(|track| {
            let fitted_row = Self::fit(track)
                .filter(|_| track.observations.len() >= 3)
                .and_then(|fit| self.predict_apparent(track, -fit.slope, Some(&fit)))
                .and_then(|p| self.lines.get(usize::from(track.line)).map(|line| line.row_of(&self.grid, p).0));
            TrackView {
                id: track.id,
                line: usize::from(track.line),
                observed_row: track.matched_row.map(|r| f32::from(r) / ROW_UNITS),
                fitted_row,
                point: self.estimate(track),
            }
        })
    }

    /// Estimated obstacle height (whole mm) inside a robot-frame region: the
    /// height that at least [`MIN_SUPPORT`] good points reach together (see
    /// [`top_supported_height`]). None when no such group lies in the region.
    pub fn height_in_region(&self, region: &RegionMm) -> Option<i32> {
        let mut heights: heapless::Vec<f32, { MAX_TRACKS + MAX_MAP_POINTS }> = heapless::Vec::new();
        for p in self.points() {
            if p.quality >= self.config.good_quality && region.contains(p.x_mm, p.z_mm) {
                let _ = heights.push(p.h_mm);
            }
        }
        top_supported_height(&mut heights).map(|h| roundf(h) as i32)
    }

    /// GTI's own alarm: the nearest good point inside the AOI at least
    /// `min_obstacle_mm` high and backed by [`MIN_SUPPORT`] points within the
    /// support tolerance of its height and 100 mm of it on the ground.
    pub fn nearest_obstacle_point(&self, aoi: &RegionMm) -> Option<HeightPoint> {
        let good = |p: &HeightPoint| p.quality >= self.config.good_quality;
        let mut nearest: Option<HeightPoint> = None;
        for p in self.points().filter(good) {
            if p.h_mm < self.config.min_obstacle_mm || !aoi.contains(p.x_mm, p.z_mm) {
                continue;
            }
            let tolerance = support_tolerance(p.h_mm);
            let support = self
                .points()
                .filter(good)
                .filter(|o| fabsf(o.h_mm - p.h_mm) <= tolerance && fabsf(o.x_mm - p.x_mm) <= 100.0 && fabsf(o.z_mm - p.z_mm) <= 100.0)
                .count();
            if support >= MIN_SUPPORT && nearest.is_none_or(|n| p.z_mm < n.z_mm) {
                nearest = Some(p);
            }
        }
        nearest
    }
}

const ROW_UNITS: f32 = 64.0;
fn encode_row(row: f32) -> Option<u16> {
    (row >= 0.0 && row * ROW_UNITS < f32::from(u16::MAX)).then(|| roundf(row * ROW_UNITS) as u16)
}
fn encode_strength(strength: f32) -> u16 {
    roundf((strength * 16.0).clamp(0.0, f32::from(u16::MAX))) as u16
}

fn support_tolerance(h_mm: f32) -> f32 {
    SUPPORT_TOLERANCE_MM.max(SUPPORT_TOLERANCE_FRACTION * fabsf(h_mm))
}

/// The height that at least [`MIN_SUPPORT`] heights reach together: the
/// highest run of [`MIN_SUPPORT`] consecutive heights (sorted) spanning at
/// most the support tolerance, and its median. A lone stray point cannot set
/// it, and lower points on an obstacle's side do not drag it down.
/// Reorders `heights`.
pub fn top_supported_height(heights: &mut [f32]) -> Option<f32> {
    heights.sort_unstable_by(|a, b| b.total_cmp(a));
    heights
        .windows(MIN_SUPPORT)
        .find(|run| match (run.first(), run.last()) {
            (Some(&top), Some(&bottom)) => top - bottom <= support_tolerance(top),
            _ => false,
        })
        .and_then(|run| run.get(MIN_SUPPORT / 2).copied())
}

/// Average of `2 * half + 1` linearly interpolated pixels centred on
/// fractional column `centre`; None if any tap leaves the valid columns.
fn sample_across(row: &[u8], valid: &Range<usize>, centre: f32, half: f32) -> Option<u8> {
    let first = centre - half;
    let floor = floorf(first);
    if !(floor >= valid.start as f32) {
        return None;
    }
    let frac = first - floor;
    let base = floor as usize;
    let taps = 2 * half as usize + 1;
    if base + taps >= valid.end {
        return None;
    }
    let mut sum = 0f32;
    for k in 0..taps {
        let (a, b) = (row.get(base + k)?, row.get(base + k + 1)?);
        sum += f32::from(*a) * (1.0 - frac) + f32::from(*b) * frac;
    }
    Some(roundf(sum / taps as f32).clamp(0.0, 255.0) as u8)
}

/// Samples per block in which a line's noise is measured.
const NOISE_BLOCK: usize = 32;

/// Edges of one line: extrema of the smoothed gradient above
/// `edge_threshold_sigma` robust sigmas of the gradient around them (floor
/// texture and sensor noise), strongest (relative to that) first, at most
/// [`MAX_EDGES_PER_LINE`].
fn find_edges<const N: usize>(
    samples: &LineSamples,
    config: &GtiConfig,
    threshold_scale: f32,
    edges: &mut heapless::Vec<Edge, N>,
) {
    let valid = samples.valid();
    let values = &samples.values;
    let n = valid.len();
    // Smoothing [1 2 1], then the difference across +-2 samples: responds to
    // the contrast of a step spread over a few samples (far ground is
    // magnified in the KG image, so its edges are soft) more than to
    // single-sample floor texture. Gradient at row r uses r-3..=r+3.
    const REACH: usize = 3;
    if n < 2 * (PATCH_RADIUS + REACH) + 3 {
        return;
    }
    let value = |r: usize| values.get(r).map_or(0.0, |&v| f32::from(v));
    let smooth = |r: usize| 0.25 * (value(r - 1) + 2.0 * value(r) + value(r + 1));
    let mut gradient = [0f32; MAX_LINE_SAMPLES];
    let (first, last) = (valid.start + REACH, valid.end - REACH); // gradient defined on [first, last)
    for r in first..last {
        if let Some(g) = gradient.get_mut(r) {
            *g = 0.25 * (smooth(r + 2) - smooth(r - 2));
        }
    }
    // The line's noise (sensor noise plus floor texture) is measured locally,
    // per block of NOISE_BLOCK samples: the near floor's sharp texture must
    // not hide the soft edges of far, magnified ground.
    let mut block_sigma = [0f32; MAX_LINE_SAMPLES / NOISE_BLOCK + 1];
    for (b, sigma) in block_sigma.iter_mut().enumerate() {
        let start = first + b * NOISE_BLOCK;
        if start >= last {
            break;
        }
        // A short last block borrows samples from its predecessor.
        let end = (start + NOISE_BLOCK).min(last);
        let start = end.saturating_sub(NOISE_BLOCK).max(first);
        let mut magnitudes = [0f32; NOISE_BLOCK];
        for (slot, g) in magnitudes.iter_mut().zip(gradient.get(start..end).unwrap_or(&[])) {
            *slot = fabsf(*g);
        }
        // Median |g| of a zero-mean Gaussian is 0.6745 sigma.
        *sigma = magnitudes.get_mut(..end - start).and_then(median).unwrap_or(0.0) / 0.6745;
    }
    let floor = config.min_edge_contrast * 0.5;
    let threshold_at = |r: usize| {
        let sigma = block_sigma.get((r - first) / NOISE_BLOCK).copied().unwrap_or(0.0);
        threshold_scale * (config.edge_threshold_sigma * sigma).max(floor)
    };
    let magnitude = |r: usize| gradient.get(r).map_or(0.0, |g| fabsf(*g));
    // Patches must lie inside the valid run.
    for r in (first + 1).max(valid.start + PATCH_RADIUS)..(last - 1).min(valid.end - PATCH_RADIUS) {
        let (before, here, after) = (magnitude(r - 1), magnitude(r), magnitude(r + 1));
        let threshold = threshold_at(r);
        if !(here > threshold && here >= before && here > after) {
            continue;
        }
        let mut patch = [0u8; PATCH];
        for (k, slot) in patch.iter_mut().enumerate() {
            *slot = values.get(r + k - PATCH_RADIUS).copied().unwrap_or(0);
        }
        let edge = Edge {
            row: r as f32 + subpixel_peak(before, here, after),
            strength: here / threshold,
            rising: gradient.get(r).is_some_and(|g| *g > 0.0),
            patch,
        };
        if edges.is_full() {
            // Replace the weakest if this one is stronger.
            let weakest = edges.iter().enumerate().min_by(|a, b| a.1.strength.total_cmp(&b.1.strength)).map(|(i, e)| (i, e.strength));
            if let Some((i, strength)) = weakest {
                if edge.strength > strength {
                    if let Some(slot) = edges.get_mut(i) {
                        *slot = edge;
                    }
                }
            }
        } else {
            let _ = edges.push(edge);
        }
    }
    edges.sort_unstable_by(|a, b| b.strength.total_cmp(&a.strength));
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may panic
mod tests {
    use super::*;

    #[test]
    fn slope_and_height_invert() {
        assert!((height_from_slope(400.0, 1.0)).abs() < 1e-6);
        let s = slope_from_height(400.0, 120.0);
        assert!((s - 400.0 / 280.0).abs() < 1e-6);
        assert!((height_from_slope(400.0, s) - 120.0).abs() < 1e-3);
    }

    #[test]
    fn subpixel_peak_finds_parabola_vertex() {
        // Samples of -(x - 0.3)^2 at x = -1, 0, 1.
        let f = |x: f32| -(x - 0.3) * (x - 0.3);
        assert!((subpixel_peak(f(-1.0), f(0.0), f(1.0)) - 0.3).abs() < 1e-5);
        assert_eq!(subpixel_peak(1.0, 1.0, 1.0), 0.0);
    }

    #[test]
    fn robust_fit_ignores_outliers() {
        let x: [f32; 12] = core::array::from_fn(|i| i as f32 * 20.0);
        let mut y: [f32; 12] = core::array::from_fn(|i| 50.0 - 1.4286 * x[i] + if i % 2 == 0 { 0.3 } else { -0.3 });
        y[3] += 40.0;
        y[8] -= 25.0;
        let fit = robust_line_fit(&x, &y).unwrap();
        assert!((fit.slope + 1.4286).abs() < 0.005, "slope {}", fit.slope);
        assert!((fit.intercept - 50.0).abs() < 1.0);
        assert_eq!(fit.inliers, 10);
        assert!(fit.residual < 0.5);
        assert_eq!(robust_line_fit(&[1.0, 1.0], &[0.0, 3.0]), None);
        assert_eq!(robust_line_fit(&[1.0], &[0.0]), None);
    }

    #[test]
    fn top_supported_height_needs_agreement() {
        let mut heights = [3.0, 118.0, 250.0, 121.0, 60.0, 119.5, 104.0, 2.0];
        assert_eq!(top_supported_height(&mut heights), Some(119.5));
        let mut pair = [250.0, 251.0, 2.0];
        assert_eq!(top_supported_height(&mut pair), None);
    }

    #[test]
    fn edges_are_found_with_subpixel_position() {
        // A blurred step at row 100.3 over a mildly textured line.
        let mut samples = LineSamples::EMPTY;
        for r in 40..200 {
            let x = (r as f32 - 100.3) / 1.5;
            let step = 60.0 + 100.0 / (1.0 + libm::expf(-x));
            let texture = if r % 3 == 0 { 2.0 } else { -1.0 };
            samples.values[r] = (step + texture) as u8;
        }
        samples.start = 40;
        samples.end = 200;
        let mut edges: heapless::Vec<Edge, MAX_EDGES_PER_LINE> = heapless::Vec::new();
        find_edges(&samples, &GtiConfig::default(), 1.0, &mut edges);
        assert_eq!(edges.len(), 1, "{edges:?}");
        assert!(edges[0].rising);
        assert!((edges[0].row - 100.3).abs() < 0.3, "row {}", edges[0].row);
    }
}

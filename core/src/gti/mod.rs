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
//! Memory: everything is fixed capacity (the GTI section of
//! [`crate::limits`]); the whole state is one [`Gti`] value: 20.3 KB on the
//! host (a test holds it to 24 KB), about 20.6 KB on the Cortex-M4F (each
//! track keeps its fit: static RAM 152,924 -> 153,980 B).
//! [`Gti::UNCONFIGURED`] and [`Gti::configure`] set it up in place in a static.
//!
//! Rooms:
//! - `lines`: where the GT lines lie, and their samples from the KG rows;
//! - `edges`: a line's edges in a frame, strong and weak, found in one pass;
//! - `tracks`: association of edges with tracks, observations, ended tracks
//!   and the map of their points;
//! - `fits`: robust line fit of a locus, slope <-> height, quality, the
//!   height several points support;
//! - `travel`: the odometry pose, corrected by the floor, and odometry's scale;
//! - here: the configuration, the stage that composes them, and its queries.

// `!(x > 0.0)` is deliberate, as in geometry.rs: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod edges;
mod fits;
mod lines;
mod tracks;
mod travel;

pub use lines::GtLine;

use crate::geometry::Rig;
use crate::grid::KgGrid;
use crate::limits::{MAX_LINES, MAX_LINE_SAMPLES, MAX_LINE_WIDTH_PX, MAX_MAP_POINTS, MAX_OBSERVATIONS, MAX_TRACKS};
use crate::motion::{Attitude, Motion, Tilt};
use core::ops::Range;
use edges::LineEdges;
use fits::{support_tolerance, top_supported_height, MIN_SUPPORT};
use heapless::Deque;
use libm::{atan2f, fabsf, hypotf, roundf};
use lines::{LineGrid, Lines};
use tracks::{MapPoint, Track, ROW_UNITS};
use travel::{FloorPoints, Travel};

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

impl GtiConfig {
    pub const DEFAULT: GtiConfig = GtiConfig {
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
    };

    fn is_valid(&self) -> bool {
        (1..=MAX_LINES).contains(&self.lines)
            && (1..=MAX_LINE_WIDTH_PX).contains(&self.line_width_px)
            && self.line_width_px % 2 == 1
            && self.edge_threshold_sigma > 0.0
            && self.min_edge_contrast >= 0.0
            && self.max_initial_slope > 1.0
            && self.min_patch_correlation <= 1.0
            && self.gate_px > 0.0
            && (3..=MAX_OBSERVATIONS).contains(&self.min_observations)
            && self.good_quality <= 100
            && self.min_point_quality <= self.good_quality
            && self.min_obstacle_mm.is_finite()
            && self.odometry_sigma > 0.0
            && self.odometry_sigma.is_finite()
            && self.max_line_angle_deg >= 0.0
            && self.max_line_angle_deg <= 45.0
    }
}

impl Default for GtiConfig {
    fn default() -> Self {
        GtiConfig::DEFAULT
    }
}

/// Why a configuration or a KG row was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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

impl core::error::Error for GtiError {}

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
    grid: LineGrid,
    mount_height_mm: f32,
    lines: Lines,
    tracks: [Option<Track>; MAX_TRACKS],
    map: Deque<MapPoint, MAX_MAP_POINTS>,
    next_id: u32,
    travel: Travel,
    /// This frame's body tilt from the nominal attitude (None: nominal):
    /// tracks live on the level ground, the KG shows it tilted.
    tilt: Option<Tilt<f32>>,
    /// How the robot turns as it travels: [`PathBend`].
    bend: PathBend,
}

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
            grid: LineGrid::UNCONFIGURED,
            mount_height_mm: 1.0,
            lines: Lines::UNCONFIGURED,
            tracks: [NO_TRACK; MAX_TRACKS],
            map: Deque::new(),
            next_id: 0,
            travel: Travel::START,
            tilt: None,
            bend: PathBend::STRAIGHT,
        }
    };

    /// Sets the stage up for a rig and the KG grid its remap fills, in
    /// place; everything from an earlier rig is forgotten. On error the
    /// stage is left unchanged.
    pub fn configure(&mut self, rig: &Rig, grid: &KgGrid, config: GtiConfig) -> Result<(), GtiError> {
        if !config.is_valid() {
            return Err(GtiError::Config);
        }
        if grid.height() > MAX_LINE_SAMPLES {
            return Err(GtiError::GridTooLarge);
        }
        self.config = config;
        self.grid = LineGrid::new(grid);
        self.mount_height_mm = rig.height_mm() as f32;
        self.lines.configure(rig, &config);
        self.restart();
        self.next_id = 0;
        self.travel = Travel::START;
        Ok(())
    }

    pub fn config(&self) -> &GtiConfig {
        &self.config
    }

    /// The lines sampled in the current frame.
    pub fn lines(&self) -> &[GtLine] {
        self.lines.lines(self.config.lines)
    }

    /// Samples the lines from KG row `row` of the current frame; call it from
    /// the streaming remap's callback with the columns the camera sees
    /// (`RemapTable::valid_columns`). Rows must come in increasing order.
    pub fn on_kg_row(&mut self, row: usize, kg_row: &[u8], valid_columns: Range<usize>) -> Result<(), GtiError> {
        self.lines.on_kg_row(&self.config, &self.grid, row, kg_row, valid_columns)
    }

    /// The latest frame's samples of line `l` (indexed by KG row) and the
    /// valid rows; kept until the next frame's first row.
    pub fn line_samples(&self, l: usize) -> Option<(&[u8], Range<usize>)> {
        let samples = (l < self.config.lines).then(|| self.lines.samples(l))?;
        Some((&samples.values[..self.grid.height.min(MAX_LINE_SAMPLES)], samples.valid()))
    }

    /// Drops the current frame's rows (a frame abandoned mid-way): the next
    /// row starts a new frame.
    pub fn abort_frame(&mut self) {
        self.lines.abort_frame();
    }

    /// Forgets every track and map point (the odometry has a gap, so the
    /// loci cannot be continued); the current frame's rows and the learned
    /// odometry scale (a property of the wheels) are kept.
    pub fn restart(&mut self) {
        for slot in self.tracks.iter_mut() {
            *slot = None;
        }
        self.map.clear();
        self.bend = PathBend::STRAIGHT;
    }

    /// Ends the frame: `motion` is the odometry from the previous frame to
    /// this one (in the previous robot frame; zero for the first frame).
    /// `attitude` is the body's attitude now, relative to the nominal one.
    pub fn end_frame(&mut self, motion: &Motion, attitude: &Attitude) {
        self.tilt = (*attitude != Attitude::default()).then(|| Tilt::new(attitude, f64::from(self.mount_height_mm)).to_f32());
        self.bend.follow(motion);
        self.lines.end_frame(self.config.lines);
        // One line's edges at a time (found for the travel correction, then
        // again for the association): every line's at once would add ~10 KB
        // to the firmware's deepest stack.
        let mut edges = LineEdges::NONE;
        let mut found = FloorPoints::NONE;
        self.advance_pose(motion, &mut edges, &mut found);
        for track in self.tracks.iter_mut().flatten() {
            track.matched_row = None;
        }
        for l in 0..self.config.lines {
            edges.find(l, self.lines.samples(l), &self.config);
            self.associate_line(l, &edges, &found);
        }
        self.refit_stalest();
        self.end_lost_tracks();
        // Next frame's lines follow this frame's translation (the best guess
        // of the next one); without translation they keep their direction.
        if motion.distance_mm() > 1.0 {
            let limit = self.config.max_line_angle_deg.to_radians();
            self.lines.turn_next_frame(atan2f(motion.tx_mm as f32, motion.tz_mm as f32).clamp(-limit, limit));
        }
    }

    /// The level ground point that `line` shows at `row` this frame.
    fn level_point(&self, line: &GtLine, row: f32) -> [f32; 2] {
        let p = line.point_at_row(&self.grid, row);
        match self.tilt.and_then(|tilt| tilt.to_ground(p[0], p[1])) {
            Some((x, z)) => [x, z],
            None => p,
        }
    }

    /// Where on `line` this frame shows the level ground point `point`: its
    /// row and its distance from the line (mm).
    fn row_of_level(&self, line: &GtLine, point: [f32; 2]) -> (f32, f32) {
        let p = match self.tilt.and_then(|tilt| tilt.from_ground(point[0], point[1])) {
            Some((x, z)) => [x, z],
            None => point,
        };
        line.row_of(&self.grid, p)
    }

    /// Every point seen so far (live tracks and the map) with at least
    /// `min_point_quality`, in the current robot frame; map points behind
    /// the robot are left out.
    pub fn points(&self) -> impl Iterator<Item = HeightPoint> + '_ {
        let min_quality = self.config.min_point_quality;
        let live = self.tracks.iter().flatten().filter_map(|t| self.estimate(t));
        let (position, rotation) = (self.travel.position(), self.travel.rotation());
        let mapped = self.map.iter().map(move |m| {
            let [x, z] = rotation.to_robot([f64::from(m.world[0]) - position[0], f64::from(m.world[1]) - position[1]]);
            HeightPoint { x_mm: x as f32, z_mm: z as f32, h_mm: m.h_mm, quality: m.quality, h_sigma_mm: m.h_sigma_mm }
        });
        live.chain(mapped.filter(|p| p.z_mm > 0.0)).filter(move |p| p.quality >= min_quality)
    }

    /// Live tracks, for drawing GT-images with their loci.
    pub fn tracks(&self) -> impl Iterator<Item = TrackView> + '_ {
        self.tracks.iter().flatten().map(|track| {
            let fitted_row = track
                .fit()
                .filter(|_| track.observations.len() >= 3)
                .and_then(|fit| track.predict_apparent(&self.travel, -fit.slope, Some(&fit)))
                .and_then(|p| self.lines.line(usize::from(track.line)).map(|line| line.row_of(&self.grid, p).0));
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

    /// GTI's own alarm: the nearest good point inside the AOI whose height
    /// is at least `min_obstacle_mm` by [`CERTAIN_SIGMAS`] of its standard
    /// error, backed by [`MIN_SUPPORT`] good points within the support
    /// tolerance of its height and 100 mm of it on the ground.
    /// On a bending path a point's height may be an edge's slide
    /// ([`PathBend`]): by as much as it could fake, it must clear more.
    pub fn nearest_obstacle_point(&self, aoi: &RegionMm) -> Option<HeightPoint> {
        let fakeable_per_mm = self.mount_height_mm * self.bend.slide_rate();
        let fakeable_mm = |p: &HeightPoint| fakeable_per_mm * hypotf(p.x_mm, p.z_mm);
        nearest_certain_obstacle(|| self.points(), aoi, &self.config, fakeable_mm)
    }
}

/// An edge across a GT line is tracked where the two cross. The lines turn
/// with the robot, so on a bending path they sweep over the ground, a
/// point d from the camera by d per radian turned, and the crossing slides
/// along the line by that sweep times the cotangent of the angle between
/// edge and line: as if the edge stood up, by up to that share of the
/// camera's height (a flat marking's edge, read 300 mm high at 500 mm on a
/// 1.4 m-radius crawl). Edges within [`LEAST_EDGE_ANGLE_DEG`] of the line
/// barely cross it, so that angle bounds the cotangent. The path's bend
/// (turn over travel) is averaged over about a track's span of frames.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PathBend {
    /// Mean turn (rad) and travel (mm) a frame.
    turn_rad: f32,
    travel_mm: f32,
}

/// The least angle (degrees) between a tracked edge and its GT line.
const LEAST_EDGE_ANGLE_DEG: f32 = 30.0;
/// Weight of each frame in [`PathBend`]'s means: about
/// [`MAX_OBSERVATIONS`] / 2 frames.
const BEND_RATE: f32 = 2.0 / MAX_OBSERVATIONS as f32;

impl PathBend {
    const STRAIGHT: PathBend = PathBend { turn_rad: 0.0, travel_mm: 0.0 };

    fn follow(&mut self, motion: &Motion) {
        let turn = fabsf((motion.dyaw_deg as f32).to_radians());
        let travel = motion.distance_mm() as f32;
        self.turn_rad += BEND_RATE * (turn - self.turn_rad);
        self.travel_mm += BEND_RATE * (travel - self.travel_mm);
    }

    /// How far (mm) an edge's crossing may slide along its line per mm
    /// travelled, per mm it lies from the camera: times that distance,
    /// GTI's slope error at most.
    fn slide_rate(&self) -> f32 {
        if self.turn_rad <= 0.0 {
            return 0.0;
        }
        let cot = 1.0 / libm::tanf(LEAST_EDGE_ANGLE_DEG.to_radians());
        self.turn_rad / self.travel_mm.max(f32::MIN_POSITIVE) * cot
    }
}

/// Standard errors by which a GTI point's height must clear the obstacle
/// height to raise an alarm alone. A frame tests every point it tracks
/// (tens to a hundred), so a test at one or two sigma would pass a floor
/// marking's point every few frames: a 22 mm reading whose fit is good to
/// 3 mm is not told from 20 mm. Three sigma passes one floor point in a
/// few hundred.
pub const CERTAIN_SIGMAS: f32 = 3.0;

/// [`Gti::nearest_obstacle_point`] over the points `points` gives.
/// `fakeable_mm`: how much of a point's height its line's motion may fake.
fn nearest_certain_obstacle<I: Iterator<Item = HeightPoint>>(
    points: impl Fn() -> I,
    aoi: &RegionMm,
    config: &GtiConfig,
    fakeable_mm: impl Fn(&HeightPoint) -> f32,
) -> Option<HeightPoint> {
    let good = |p: &HeightPoint| p.quality >= config.good_quality;
    let mut nearest: Option<HeightPoint> = None;
    for p in points().filter(good) {
        if p.h_mm - CERTAIN_SIGMAS * p.h_sigma_mm - fakeable_mm(&p) < config.min_obstacle_mm || !aoi.contains(p.x_mm, p.z_mm) {
            continue;
        }
        let tolerance = support_tolerance(p.h_mm);
        let support = points()
            .filter(good)
            .filter(|o| fabsf(o.h_mm - p.h_mm) <= tolerance && fabsf(o.x_mm - p.x_mm) <= 100.0 && fabsf(o.z_mm - p.z_mm) <= 100.0)
            .count();
        if support >= MIN_SUPPORT && nearest.is_none_or(|n| p.z_mm < n.z_mm) {
            nearest = Some(p);
        }
    }
    nearest
}

#[cfg(test)]
mod tests {
    use super::*;

    const AOI: RegionMm = RegionMm { x_min: -200.0, x_max: 200.0, z_min: 300.0, z_max: 1000.0 };

    /// Three good points 30 mm up, 20 mm apart, each known to `sigma_mm`.
    fn three_at(sigma_mm: f32) -> [HeightPoint; 3] {
        core::array::from_fn(|k| HeightPoint { x_mm: 20.0 * k as f32, z_mm: 600.0 + 20.0 * k as f32, h_mm: 30.0, quality: 80, h_sigma_mm: sigma_mm })
    }

    /// A supported height raises GTI's alarm only when it clears the
    /// obstacle height by three of its standard errors: 30 mm known to
    /// 3 mm does, known to 4 mm (a 22 mm marking's reading is as likely)
    /// does not; nor two points however sure.
    #[test]
    fn a_height_alarms_only_when_certain() {
        let config = GtiConfig::DEFAULT;
        assert_eq!(config.min_obstacle_mm, 20.0);
        let sure = three_at(3.0);
        let found = nearest_certain_obstacle(|| sure.iter().copied(), &AOI, &config, |_| 0.0).expect("an obstacle");
        assert_eq!(found.z_mm, 600.0);
        let unsure = three_at(4.0);
        assert!(nearest_certain_obstacle(|| unsure.iter().copied(), &AOI, &config, |_| 0.0).is_none());
        let two = &three_at(0.5)[..2];
        assert!(nearest_certain_obstacle(|| two.iter().copied(), &AOI, &config, |_| 0.0).is_none());
    }

    /// On a straight run nothing slides; on a tight crawl (5 mm and 0.21
    /// degrees a frame, r1000_04's) an edge's crossing 500 mm ahead may
    /// slide 0.64 mm a mm travelled, which a 518 mm high camera reads as a
    /// height of hundreds of mm; and the same sure 30 mm point that alarms
    /// on a straight run does not where its line may fake 10 mm of it.
    #[test]
    fn on_a_bending_path_a_height_must_clear_what_the_slide_can_fake() {
        let mut straight = PathBend::STRAIGHT;
        let mut crawl = PathBend::STRAIGHT;
        for _ in 0..3 * MAX_OBSERVATIONS {
            straight.follow(&Motion { tx_mm: 0.0, tz_mm: 5.0, dyaw_deg: 0.0 });
            crawl.follow(&Motion { tx_mm: 0.0, tz_mm: 5.0, dyaw_deg: 0.21 });
        }
        assert_eq!(straight.slide_rate(), 0.0);
        let slide = crawl.slide_rate() * 500.0;
        let expected = 500.0 * 0.21f32.to_radians() / 5.0 * 3f32.sqrt();
        assert!((slide - expected).abs() < 0.01 * expected, "{slide} vs {expected}");
        assert!(518.0 * slide > 300.0);

        let config = GtiConfig::DEFAULT;
        let sure = three_at(3.0);
        assert!(nearest_certain_obstacle(|| sure.iter().copied(), &AOI, &config, |_| 10.0).is_none());
    }
}

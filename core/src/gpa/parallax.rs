//! The parallax test: does a cell stand above the ground, or lie below it?
//! A point at height h = f*H shows, beyond the ground prediction, an extra
//! displacement of T * f / (1 - f) (T the baseline); a point d below the
//! floor (the lower level past a ledge) is h = -d: it moves less than the
//! floor. Each cell's SAD is summed per height hypothesis over a cell row;
//! a hypothesis that clearly beats the ground, refined by a parabola in
//! displacement, gives the cell's signed height.

use super::config::GpaConfig;
use super::decision::Noise;
use super::keyframe::{Keyframe, LinePositions};
use super::layout::{CellSet, Cells};
use super::warp::{clip, to_q16, RowWarp};
use crate::grid::{KgGrid, MAX_GRID_SIDE};
use crate::limits::{MAX_CELLS, MAX_CELLS_SIDE};
use crate::motion::Motion;
use crate::subpixel;
use core::ops::Range;

/// Height hypotheses for the per-cell parallax test, as fractions of the
/// camera height H (index 0 is the ground). A point at height h = f*H shows,
/// beyond the ground prediction, an extra displacement of T * f / (1 - f).
pub const HEIGHT_FRACTIONS: [f64; 8] = [0.0, 0.04, 0.08, 0.13, 0.19, 0.27, 0.37, 0.5];
/// Depth hypotheses below the ground, as fractions of the displacement
/// deficit of the deepest drop looked for (`GpaConfig::max_drop_mm`, at
/// d = D it is D / (H + D)). Few: each costs a pass over the keyframe, and
/// a drop only needs its depth past the 20 mm limit and its edge, which
/// the apparent position gives. The first sits near that limit (the 10 mm
/// dip against the 25 mm drop is decided by the parabola around it), the
/// last at the deepest, with one between for the parabola.
pub const DROP_STEPS: [f64; 4] = [0.1, 0.2, 0.45, 1.0];
/// Lag hypotheses past the deepest drop, as fractions of the baseline a
/// cell lags the ground by (1: it stays where it was in the top view). A
/// thing moving along with the robot (a car ahead, slower than the robot
/// but not by much) shows the ground's parallax scaled by its own share
/// of the motion: it lags the ground by up to the whole baseline, which no
/// height or drop explains. A cell that matches one of these best moves
/// with the robot (or lies past a drop deeper than any looked for): a
/// hazard whose height the images do not give. Only those past the
/// deepest drop's lag take part ([`Hypotheses::plan`]).
pub const LAG_FRACTIONS: [f64; 3] = [0.4, 0.7, 1.0];
pub(super) const HYPOTHESES: usize = HEIGHT_FRACTIONS.len() + DROP_STEPS.len() + LAG_FRACTIONS.len();
/// Index of the first lag hypothesis (after the ground, heights and drops).
const FIRST_LAG: usize = HEIGHT_FRACTIONS.len() + DROP_STEPS.len();
/// Where the ground (index 0) sits when the hypotheses are ordered by
/// displacement: after the lags and the drops, deepest first.
const GROUND_RANK: usize = DROP_STEPS.len() + LAG_FRACTIONS.len();

/// This frame's hypotheses: where each one samples the keyframe and which
/// of them take part.
pub(super) struct Hypotheses {
    /// Extra keyframe offset (KG px, Q16.16) per hypothesis: index 0 the
    /// ground, then [`HEIGHT_FRACTIONS`], [`DROP_STEPS`], [`LAG_FRACTIONS`].
    pub(super) offset: [(i32, i32); HYPOTHESES],
    /// Extra displacement per hypothesis, as a fraction of the baseline:
    /// f / (1 - f) for a height f*H, negative below the ground.
    displacement: [f64; HYPOTHESES],
    /// Hypotheses 0..usable of the heights above the ground stay clear of
    /// the in-place keyframe update (the drops always do: they reach less
    /// far than the ground).
    pub(super) usable: usize,
    /// Lag hypotheses FIRST_LAG..lags_end take part: those that lag the
    /// ground by more than the deepest drop does.
    lags_end: usize,
    /// Per axis (K, G): may the odometry error exceed half a pixel this frame?
    pub(super) full_tolerance: (bool, bool),
    /// Ranks (hypotheses ordered by displacement) whose displacement the
    /// odometry error could explain: they all stand for the ground.
    ground_like: Range<usize>,
    /// The shallowest drop (mm) whose lag this frame tells from the ground
    /// (infinite when none: too short a baseline).
    pub(super) shallowest_drop_mm: f64,
    /// The least height (mm) whose displacement this frame tells from the
    /// ground's, as `shallowest_drop_mm` for a lag (infinite when none).
    pub(super) least_height_mm: f64,
    /// Rows above this one are far enough for a heading error to blur
    /// them sideways by more than half a pixel ([`Self::ground_tolerance`]).
    yaw_blurred_rows: usize,
}

impl Hypotheses {
    pub(super) const NONE: Hypotheses = Hypotheses {
        offset: [(0, 0); HYPOTHESES],
        displacement: [0.0; HYPOTHESES],
        usable: 0,
        lags_end: FIRST_LAG,
        full_tolerance: (false, false),
        ground_like: GROUND_RANK..GROUND_RANK + 1,
        shallowest_drop_mm: f64::INFINITY,
        least_height_mm: f64::INFINITY,
        yaw_blurred_rows: 0,
    };

    /// The hypotheses of a frame at `predicted` from the keyframe, `step`
    /// from the last frame (the part of the motion the shift search has not
    /// refined yet, so the part whose odometry error they must tolerate),
    /// for a camera `camera_height_mm` above the ground.
    pub(super) fn plan(predicted: &Motion, step: &Motion, grid: &KgGrid, config: &GpaConfig, camera_height_mm: f64) -> Hypotheses {
        let mut displacement = [0.0; HYPOTHESES];
        let deepest = -config.max_drop_mm / (camera_height_mm + config.max_drop_mm);
        let heights = HEIGHT_FRACTIONS.iter().map(|f| f / (1.0 - f));
        let drops = DROP_STEPS.iter().map(|step| step * deepest);
        let lags = LAG_FRACTIONS.iter().map(|lag| -lag);
        for (slot, g) in displacement.iter_mut().zip(heights.chain(drops).chain(lags)) {
            *slot = g;
        }
        // A lag within the drops' reach is a drop's; the rest take part.
        let lags_end = FIRST_LAG + LAG_FRACTIONS.iter().filter(|&&lag| -lag < deepest).count();
        let mut offset = [(0, 0); HYPOTHESES];
        let (di, dj) = (predicted.tx_mm / grid.mm_per_px, -predicted.tz_mm / grid.mm_per_px);
        for (slot, g) in offset.iter_mut().zip(displacement) {
            *slot = (to_q16(di * g), to_q16(dj * g));
        }
        let error = config.odometry_error_fraction;
        let half_px = 0.5 * grid.mm_per_px;
        let full_tolerance = (error * libm::fabs(step.tx_mm) > half_px, error * libm::fabs(step.tz_mm) > half_px);
        let tolerance_mm = error * step.distance_mm() + half_px;
        let baseline = predicted.distance_mm();
        let explained = |rank: &usize| baseline * libm::fabs(displacement[by_rank(*rank)]) <= tolerance_mm;
        let above = (GROUND_RANK + 1..HYPOTHESES).take_while(explained).count();
        let below = (0..GROUND_RANK).rev().take_while(explained).count();
        let ground_like = GROUND_RANK - below..GROUND_RANK + 1 + above;
        // A drop d deep lags the floor by T*d/(H+d). Displacements up to the
        // tolerance count as ground, and each such hypothesis matches a lag
        // up to half a pixel beyond it as well as the ground's own residue
        // does: a lag within both is ground to this frame.
        let hidden_lag_mm = tolerance_mm + half_px;
        let shallowest_drop_mm =
            if baseline > hidden_lag_mm { camera_height_mm * hidden_lag_mm / (baseline - hidden_lag_mm) } else { f64::INFINITY };
        // A height h moves T*h/(H-h) past the ground: as far as a lag within
        // the same reach, it is ground to this frame.
        let least_height_mm = if baseline > 0.0 { camera_height_mm * hidden_lag_mm / (baseline + hidden_lag_mm) } else { f64::INFINITY };
        // The rows where a heading error blurs the ground sideways by more
        // than half a pixel: the far ones, so the first row that is not
        // blurred, found by bisection (the test falls with the row).
        let yaw_blurred = |j: usize| {
            let (_, row_z) = grid.pixel_to_ground(0.0, j as f64);
            row_z * config.odometry_yaw_error_deg.to_radians() > half_px
        };
        let (mut blurred, mut sharp) = (0, grid.height());
        if !yaw_blurred(0) {
            sharp = 0;
        }
        while blurred + 1 < sharp {
            let middle = (blurred + sharp) / 2;
            if yaw_blurred(middle) {
                blurred = middle;
            } else {
                sharp = middle;
            }
        }
        let yaw_blurred_rows = sharp;
        Hypotheses { offset, displacement, usable: HEIGHT_FRACTIONS.len(), lags_end, full_tolerance, ground_like, shallowest_drop_mm, least_height_mm, yaw_blurred_rows }
    }

    /// The hypotheses this frame compares besides the ground.
    pub(super) fn active(&self) -> impl Iterator<Item = usize> {
        (1..self.usable).chain(if self.usable > 0 { HEIGHT_FRACTIONS.len()..self.lags_end } else { 0..0 })
    }

    /// How far (K, G) the ground hypothesis's residue of row `j` reaches: a
    /// full pixel along an axis the odometry may be that far off, sideways
    /// also where a heading error moves far ground by more than half a pixel.
    pub(super) fn ground_tolerance(&self, j: usize) -> (bool, bool) {
        (self.full_tolerance.0 || j < self.yaw_blurred_rows, self.full_tolerance.1)
    }

    /// The height (as a fraction of H, negative below the ground) that a
    /// cell's hypothesis SADs (by index, u32::MAX where not compared) point
    /// at, and whether it beats the ground by the absolute gain too (else
    /// it is [`CellHeights`]' weak kind); None if the ground explains the
    /// cell as well. `noise_floor` is the median plain |diff| per pixel.
    /// A cell best matched by a lag hypothesis is [`CellMatch::Moving`].
    fn height_fraction(&self, sads: &[u32; HYPOTHESES], pixels: u16, min_gain: f64, noise_floor: u8, gain_percent: u32) -> Option<(CellMatch, bool)> {
        // Ordered by displacement, so neighbours are neighbouring heights.
        let sad = |rank: usize| sads[by_rank(rank)];
        let g = |rank: usize| self.displacement[by_rank(rank)];
        // The ground: the tolerant residue, or any height so small that the
        // odometry error alone could produce its displacement.
        let ground = self.ground_like.clone().map(sad).min().unwrap_or(u32::MAX);
        let mut best: Option<usize> = None;
        for rank in (0..HYPOTHESES).filter(|rank| !self.ground_like.contains(rank)) {
            if sad(rank) != u32::MAX && best.is_none_or(|b| sad(rank) < sad(b)) {
                best = Some(rank);
            }
        }
        let best = best.filter(|&b| sad(b) < ground)?;
        let best_sad = sad(best);
        let gain = ground - best_sad;
        // Sensor noise puts a floor under every plain SAD (the ground's
        // tolerant residue sits lower); compare what lies above it.
        let floor = u32::from(noise_floor) * u32::from(pixels);
        let above = |sad: u32| u64::from(sad.saturating_sub(floor));
        let keep = u64::from(100 - gain_percent);
        let relative = above(best_sad) * 100 <= u64::from(ground) * keep;
        let absolute = f64::from(gain) >= min_gain * f64::from(pixels);
        // Uniqueness, as in stereo matching: structure that is uniform along
        // the motion (a tape strip driven along) matches every height
        // equally; only a distinct minimum is a measurement.
        let runner_up = (0..HYPOTHESES)
            .filter(|&rank| rank != GROUND_RANK && rank.abs_diff(best) > 1)
            .map(sad)
            .filter(|&sad| sad != u32::MAX)
            .min()
            .unwrap_or(0);
        let distinct = above(best_sad) * 100 <= above(runner_up) * keep;
        if !(relative && distinct) {
            return None;
        }
        if by_rank(best) >= FIRST_LAG {
            return Some((CellMatch::Moving, absolute));
        }
        // Parabola through the neighbouring hypotheses, in the displacement
        // they stand for (f / (1 - f)), not in index.
        let displacement = if best == 0 || best + 1 >= HYPOTHESES || sad(best + 1) == u32::MAX || sad(best - 1) == u32::MAX || by_rank(best - 1) >= FIRST_LAG {
            g(best)
        } else {
            let offset = subpixel::minimum_offset(f64::from(sad(best - 1)), f64::from(best_sad), f64::from(sad(best + 1)));
            if offset < 0.0 {
                g(best) + offset * (g(best) - g(best - 1))
            } else {
                g(best) + offset * (g(best + 1) - g(best))
            }
        };
        Some((CellMatch::Fraction(displacement / (1.0 + displacement)), absolute))
    }
}

/// What a cell's best hypothesis says of it.
enum CellMatch {
    /// Its height as a fraction of the camera's (negative below the ground).
    Fraction(f64),
    /// It lags the ground past the deepest drop: it moves with the robot.
    Moving,
}

/// The hypothesis index at `rank` in displacement order: the lags and the
/// drops deepest first, the ground, then the heights.
fn by_rank(rank: usize) -> usize {
    match rank {
        r if r < GROUND_RANK => HYPOTHESES - 1 - r,
        r => r - GROUND_RANK,
    }
}

/// Parallax height per cell (mm, 0 = ground or undecided, negative below
/// the ground): one byte and three bits a cell, for the M4's RAM. The byte
/// counts `unit_mm`, which scales with the camera's height, so
/// the highest hypothesis (half the camera's height: a car's roof from a
/// car's camera) fits whatever the rig. A weak height beat the ground
/// clearly but by less than the absolute gain (low contrast: vignetting
/// darkens the image's corners, and it shades one ground point
/// differently in two views): too uncertain to count as a measurement, it
/// only shows that a surface goes on there. A moving cell matched a lag
/// hypothesis ([`LAG_FRACTIONS`]): it moves with the robot, and its height
/// is not measured (0).
pub(super) struct CellHeights {
    magnitude: [u8; MAX_CELLS],
    below: CellSet,
    weak: CellSet,
    moving: CellSet,
    unit_mm: u8,
    /// The highest hypothesis' magnitude: a cell there may stand taller.
    top_units: u8,
}

impl CellHeights {
    pub(super) const EMPTY: CellHeights =
        CellHeights { magnitude: [0; MAX_CELLS], below: CellSet::EMPTY, weak: CellSet::EMPTY, moving: CellSet::EMPTY, unit_mm: 1, top_units: u8::MAX };

    /// No heights, counted in the unit of a camera `camera_height_mm` up:
    /// 1 mm up to a camera 510 mm up, coarser above (4 mm for a car's
    /// 1.66 m), so that half its height fits a byte.
    pub(super) fn for_camera(camera_height_mm: f64) -> CellHeights {
        let top = HEIGHT_FRACTIONS[HEIGHT_FRACTIONS.len() - 1] * camera_height_mm;
        let unit = libm::ceil(top / f64::from(u8::MAX)).clamp(1.0, f64::from(u8::MAX));
        let top = libm::round(top);
        let top_units = libm::floor(top / unit).clamp(1.0, f64::from(u8::MAX));
        CellHeights { unit_mm: unit as u8, top_units: top_units as u8, ..CellHeights::EMPTY }
    }

    /// Did the cell match the highest height hypothesis best? Its height
    /// is then a lower bound (a car's roof from its own camera's height),
    /// and where it stands an upper one.
    pub(super) fn is_at_top(&self, cell: usize) -> bool {
        self.magnitude[cell] >= self.top_units && !self.below.contains(cell)
    }

    /// A cell's measured height (0 for a weak one).
    pub(super) fn get(&self, cell: usize) -> i16 {
        if self.weak.contains(cell) {
            0
        } else {
            self.any(cell)
        }
    }

    /// A cell's height, measured or weak.
    pub(super) fn any(&self, cell: usize) -> i16 {
        let magnitude = i16::from(self.magnitude[cell]) * i16::from(self.unit_mm);
        if self.below.contains(cell) {
            -magnitude
        } else {
            magnitude
        }
    }

    /// Did the cell's height beat the ground by less than the absolute gain?
    pub(super) fn is_weak(&self, cell: usize) -> bool {
        self.weak.contains(cell)
    }

    /// Does the cell move with the robot (measured, not weak)?
    pub(super) fn is_moving(&self, cell: usize) -> bool {
        self.moving.contains(cell) && !self.weak.contains(cell)
    }

    /// Did a lag hypothesis win the cell (weak or not)?
    pub(super) fn moving(&self, cell: usize) -> bool {
        self.moving.contains(cell)
    }

    /// Marks a cell as moving with the robot (weak when `weak`); its height stays 0.
    pub(super) fn set_moving(&mut self, cell: usize, weak: bool) {
        self.moving.insert(cell);
        if weak {
            self.weak.insert(cell);
        }
    }

    /// Sets a cell's height (mm), rounded down to the unit and clamped to
    /// 255 units either way (at least one), and whether it is weak.
    pub(super) fn set(&mut self, cell: usize, height: i16, weak: bool) {
        let units = (height.unsigned_abs() / u16::from(self.unit_mm)).clamp(1, u16::from(u8::MAX));
        self.magnitude[cell] = units as u8;
        if height < 0 {
            self.below.insert(cell);
        } else {
            self.below.remove(cell);
        }
        if weak {
            self.weak.insert(cell);
        } else {
            self.weak.remove(cell);
        }
    }
}

/// Per-hypothesis SAD and pixel count of the cells of the current cell
/// row: a cell is at most [`super::layout::MAX_CELL_PX`] square, so 16
/// and 8 bits hold them.
pub(super) struct CellRowSums {
    pub(super) sad: [[u16; MAX_CELLS_SIDE]; HYPOTHESES],
    pub(super) pixels: [[u8; MAX_CELLS_SIDE]; HYPOTHESES],
    /// False while only the ground's sums can be other than 0.
    pub(super) tried: bool,
}

impl CellRowSums {
    pub(super) const EMPTY: CellRowSums =
        CellRowSums { sad: [[0; MAX_CELLS_SIDE]; HYPOTHESES], pixels: [[0; MAX_CELLS_SIDE]; HYPOTHESES], tried: false };

    pub(super) fn clear(&mut self) {
        self.sad = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
        self.pixels = [[0; MAX_CELLS_SIDE]; HYPOTHESES];
        self.tried = false;
    }

    /// [`Self::clear`] of sums only the ground's were added to.
    fn clear_ground(&mut self) {
        self.sad[0] = [0; MAX_CELLS_SIDE];
        self.pixels[0] = [0; MAX_CELLS_SIDE];
    }
}

/// Whether a cell leaves room for a height: it saw at least half its
/// pixels, and its ground's tolerant residue (hypothesis 0's SAD) reaches
/// `min_gain` per pixel. Below that a height could beat the ground only
/// in texture too faint to measure it (a weak height there would be
/// noise), so none is decided; and the hypotheses need not be tried
/// there ([`Parallax::spans_to_try`]).
struct Room {
    min_pixels: u16,
    min_gain: f64,
    /// The last pixel count and its least residue: most cells are whole.
    least: Option<(u16, u32)>,
}

impl Room {
    fn new(cells: &Cells, min_gain: f64) -> Room {
        Room { min_pixels: (cells.px * cells.px / 2) as u16, min_gain, least: None }
    }

    /// For a cell of `pixels` pixels and ground `residue`:
    /// `residue >= min_gain * pixels` in integers (for a whole residue R
    /// and a product x, R < x exactly when R < ceil(x); saturated: `as`
    /// makes a NaN or negative ceiling 0, which no R is below, as no R is
    /// below x then).
    fn for_height(&mut self, residue: u16, pixels: u16) -> bool {
        if pixels < self.min_pixels {
            return false;
        }
        let least = match self.least {
            Some((counted, ceiling)) if counted == pixels => ceiling,
            _ => {
                let ceiling = libm::ceil(self.min_gain * f64::from(pixels)) as u32;
                self.least = Some((pixels, ceiling));
                ceiling
            }
        };
        u32::from(residue) >= least
    }
}

/// Runs of grid columns, whole cells, that the hypotheses are tried in.
pub(super) type CellSpans = heapless::Vec<Range<usize>, { MAX_CELLS_SIDE / 2 + 1 }>;

/// Parallax evidence of the current frame.
pub(super) struct Parallax {
    pub(super) hypotheses: Hypotheses,
    /// Hypothesis 0, the ground, is summed by the residue stage.
    pub(super) sums: CellRowSums,
    /// Parallax height per cell, this frame.
    pub(super) height: CellHeights,
}

impl Parallax {
    pub(super) const EMPTY: Parallax =
        Parallax { hypotheses: Hypotheses::NONE, sums: CellRowSums::EMPTY, height: CellHeights::EMPTY };

    /// Starts a frame of a camera `camera_height_mm` up.
    pub(super) fn clear(&mut self, camera_height_mm: f64) {
        self.height = CellHeights::for_camera(camera_height_mm);
        self.sums.clear();
    }

    /// Sums current row `row` (warp `warp`, `seen` columns, usable `runs`)
    /// against the keyframe at every height hypothesis but the ground
    /// (columns whose sample is off the keyframe skip that hypothesis).
    /// `positions` is scratch space for the warp's keyframe positions
    /// (the caller's, so that a cell row's rows share one), `samples` for
    /// the lines sampled one by one.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_row(
        &mut self,
        keyframe: &Keyframe,
        warp: RowWarp,
        seen: Range<usize>,
        runs: &[(u16, u16)],
        row: &[u8],
        cells: &Cells,
        positions: &mut LinePositions,
        samples: &mut [u8; MAX_GRID_SIDE],
    ) {
        // A translation line reads one keyframe row pair at constant
        // weights, a whole-line kernel; a yawed or bent line's positions
        // are stepped once and serve every hypothesis, each moving them by
        // its offset, its samples differenced as they are made, cell by
        // cell for all of them at once.
        self.sums.tried = true;
        let shared = !warp.is_translation();
        if shared {
            keyframe.step_positions(warp, seen.clone(), row, positions);
        }
        let mut moved = keyframe.moved_lines::<HYPOTHESES>(positions);
        for k in self.hypotheses.active() {
            let offset = self.hypotheses.offset[k];
            if shared && moved.add(k, offset) {
                continue;
            }
            // Near the keyframe's edges: the line as sample_line finds it
            // (it writes every column of `seen`, so the scratch needs no clearing).
            let sampled = keyframe.sample_line(warp.moved(offset.0, offset.1), seen.clone(), &mut samples[..]);
            for &run in runs {
                let columns = clip(run, sampled.start, sampled.end);
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
                cells.segments(columns, |cell_column, columns| {
                    // Counted before the sum is taken: nothing stays live across it.
                    self.sums.pixels[k][cell_column] += columns.len() as u8;
                    #[cfg(flatland_dsp)]
                    let sum = super::kernels::sad(&row[columns.clone()], &samples[columns]);
                    #[cfg(not(flatland_dsp))]
                    let sum: u32 = samples[columns].iter().map(|&d| u32::from(d)).sum();
                    self.sums.sad[k][cell_column] += sum as u16;
                });
            }
        }
        let sums = &mut self.sums;
        for &run in runs.iter().filter(|_| !moved.is_empty()) {
            cells.segments(clip(run, seen.start, seen.end), |cell_column, columns| {
                let pixels = columns.len() as u8;
                moved.sads(columns, |k, sum| {
                    sums.pixels[k][cell_column] += pixels;
                    sums.sad[k][cell_column] += sum as u16;
                });
            });
        }
    }

    /// The runs of columns of the current cell row's cells in which a
    /// height may be found ([`Room::for_height`]): in the others no
    /// hypothesis is tried, and they keep height 0, as they would were
    /// every cell tried. `min_gain` is [`Self::finish_cell_row`]'s.
    pub(super) fn spans_to_try(&self, cells: &Cells, min_gain: f64, spans: &mut CellSpans) {
        spans.clear();
        if self.hypotheses.usable == 0 {
            return;
        }
        let mut room = Room::new(cells, min_gain);
        for column in 0..cells.wide {
            let pixels = u16::from(self.sums.pixels[0][column]);
            if !room.for_height(self.sums.sad[0][column], pixels) {
                continue;
            }
            let columns = column * cells.px..(column + 1) * cells.px;
            match spans.last_mut() {
                Some(last) if last.end == columns.start => last.end = columns.end,
                _ => {
                    // At most one span per two cells: never full.
                    let _ = spans.push(columns);
                }
            }
        }
    }

    /// Decides the parallax height of each cell of finished cell row
    /// `cell_row`, and starts the next cell row's sums. Only the cells a
    /// height hypothesis was tried in ([`Self::spans_to_try`]) and whose
    /// ground leaves [`Room`] for a height can get one: the others keep
    /// the 0 the frame's [`Self::clear`] gave them.
    pub(super) fn finish_cell_row(&mut self, cell_row: usize, cells: &Cells, camera_height_mm: f64, noise: &Noise, config: &GpaConfig) {
        if cell_row >= cells.high {
            return;
        }
        let min_gain = config.parallax_min_gain.max(noise.level());
        if !self.sums.tried {
            // No height hypothesis was tried: their sums are still 0.
            self.sums.clear_ground();
            return;
        }
        // A byte per cell, nonzero where any hypothesis but the ground saw
        // it: the counts ORed four cells a word.
        let words = cells.wide.min(MAX_CELLS_SIDE).div_ceil(4);
        let mut tried = [0u32; MAX_CELLS_SIDE.div_ceil(4)];
        for k in self.hypotheses.active() {
            for (tried, seen) in tried[..words].iter_mut().zip(self.sums.pixels[k].chunks_exact(4)) {
                *tried |= u32::from_le_bytes([seen[0], seen[1], seen[2], seen[3]]);
            }
        }
        let tried = |column: usize| tried[column / 4].to_le_bytes()[column % 4] != 0;
        let mut room = Room::new(cells, min_gain);
        for column in (0..cells.wide).filter(|&column| tried(column)) {
            let pixels = u16::from(self.sums.pixels[0][column]);
            if !room.for_height(self.sums.sad[0][column], pixels) {
                continue;
            }
            // Each hypothesis' SAD scaled to the cell's pixel count; one that
            // saw less than 3/4 of the cell (off the keyframe) does not compete.
            // (A u16 SAD times a u8 count fits a u32.)
            let mut sads = [u32::MAX; HYPOTHESES];
            for k in core::iter::once(0).chain(self.hypotheses.active()) {
                let sad = &mut sads[k];
                let seen = u32::from(self.sums.pixels[k][column]);
                if seen * 4 >= u32::from(pixels) * 3 {
                    *sad = u32::from(self.sums.sad[k][column]) * u32::from(pixels) / seen.max(1);
                }
            }
            let fraction = self.hypotheses.height_fraction(&sads, pixels, min_gain, noise.floor(), config.parallax_gain_percent);
            let cell = cell_row * cells.wide + column;
            match fraction {
                Some((CellMatch::Moving, strong)) => self.height.set_moving(cell, !strong),
                Some((CellMatch::Fraction(fraction), strong)) => {
                    let height = libm::round(fraction * camera_height_mm);
                    let magnitude = libm::fabs(height).clamp(1.0, f64::from(i16::MAX)) as i16;
                    self.height.set(cell, if height > 0.0 { magnitude } else { -magnitude }, !strong);
                }
                None => {}
            }
        }
        self.sums.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A car's camera, 1.66 m up, keeps the heights of a car ahead (up to
    /// half its own height) rather than clipping them at a byte's 255 mm,
    /// and a robot's camera keeps its millimetres.
    #[test]
    fn heights_scale_with_the_camera() {
        let mut car = CellHeights::for_camera(1657.0);
        car.set(0, 828, false);
        car.set(1, -300, false);
        car.set(2, 21, false);
        assert_eq!((car.get(0), car.get(1), car.get(2)), (828, -300, 20));
        let mut robot = CellHeights::for_camera(400.0);
        robot.set(0, 199, false);
        robot.set(1, 19, true);
        assert_eq!((robot.get(0), robot.any(1), robot.get(1)), (199, 19, 0));
    }

    /// The least height a frame tells from the ground falls as its
    /// baseline grows, and is the one whose displacement is what the ground
    /// hides (the odometry's error and a pixel); a drop's depth likewise.
    #[test]
    fn a_longer_baseline_tells_lower_heights_from_the_ground() {
        let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 120 };
        let config = GpaConfig::default();
        let least = |tz_mm: f64| {
            let motion = Motion { tx_mm: 0.0, tz_mm, dyaw_deg: 0.0 };
            let step = Motion { tx_mm: 0.0, tz_mm: 20.0, dyaw_deg: 0.0 };
            let hypotheses = Hypotheses::plan(&motion, &step, &grid, &config, 400.0);
            (hypotheses.least_height_mm, hypotheses.shallowest_drop_mm)
        };
        let hidden = config.odometry_error_fraction * 20.0 + 5.0;
        for tz in [20.0, 60.0, 200.0] {
            let (height, depth) = least(tz);
            assert!((tz * height / (400.0 - height) - hidden).abs() < 1e-9, "{tz}: {height}");
            assert!((tz * depth / (400.0 + depth) - hidden).abs() < 1e-9 || tz <= hidden, "{tz}: {depth}");
        }
        assert!(least(200.0).0 < least(60.0).0 && least(60.0).0 < least(20.0).0);
        assert_eq!(Hypotheses::NONE.least_height_mm, f64::INFINITY);
    }

    /// A height is decided only where the ground leaves room for one: a
    /// hypothesis that matches a cell outright, where the ground's residue
    /// is just below the least gain, gives no height even when tried, so
    /// trying only [`Parallax::spans_to_try`]'s cells loses none; over a
    /// ground with room the same sums give one.
    #[test]
    fn a_height_needs_room_over_the_ground() {
        let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 120 };
        let config = GpaConfig::default();
        let motion = Motion { tx_mm: 0.0, tz_mm: 100.0, dyaw_deg: 0.0 };
        let cells = Cells { px: 7, wide: 20, high: 17 };
        let mut parallax = Parallax::EMPTY;
        parallax.hypotheses = Hypotheses::plan(&motion, &motion, &grid, &config, 400.0);
        let min_gain = config.parallax_min_gain.max(Noise::NONE.level());
        let pixels = 49u8;
        let least = libm::ceil(min_gain * f64::from(pixels)) as u16;
        // A height 0.27 of the camera's: clear of the ground-like ones.
        let matching = 5;
        for (column, ground) in [(0, least - 1), (1, least + 200)] {
            parallax.sums.pixels[0][column] = pixels;
            parallax.sums.sad[0][column] = ground;
            for k in parallax.hypotheses.active() {
                parallax.sums.pixels[k][column] = pixels;
                parallax.sums.sad[k][column] = if k == matching { 0 } else { ground + 400 };
            }
        }
        parallax.sums.tried = true;
        let mut spans = CellSpans::new();
        parallax.spans_to_try(&cells, min_gain, &mut spans);
        assert!(spans.len() == 1 && spans[0] == (7..14), "{spans:?}");
        parallax.finish_cell_row(0, &cells, 400.0, &Noise::NONE, &config);
        assert_eq!(parallax.height.any(0), 0, "not even a weak height");
        assert_eq!((parallax.height.get(1), parallax.height.is_weak(1)), (108, false));
    }
}

//! Step 1 of the motion estimate: the planar motion (tx, tz, yaw) on both
//! KG images box-averaged to coarse cells, every candidate within the
//! prior's reach scored by its mean absolute difference after a global
//! gain match. The current image is levelled first by the prior's
//! attitude change (the IMU's), which no planar motion explains.
//!
//! A candidate's translation moves the keyframe position of every cell by
//! the same whole number of cells, so the current image is turned onto the
//! keyframe's cells once per yaw ([`Turned`]), in whole gray levels, and
//! each translation is then a byte SAD of two aligned images.

use super::estimate::Scene;
use super::homography::Params;
use crate::grid::{KgGrid, MAX_GRID_SIDE};
use crate::kernels;
use crate::limits::MAX_COARSE_CELLS;
use core::ops::RangeInclusive;

/// Ground side of a coarse cell, mm: coarse enough that the widest search
/// stays small, fine enough for floor texture to survive.
pub(super) const COARSE_CELL_MM: f32 = 25.0;

/// The fine cells' side on this grid (mm): [`COARSE_CELL_MM`], at least
/// two grid pixels. Searches on larger cells find the basin the fine
/// search around their answer refines.
pub(super) fn fine_cell_mm(grid: &KgGrid) -> f32 {
    COARSE_CELL_MM.max(2.0 * grid.mm_per_px as f32)
}

/// How much a coarse candidate's score grows per squared prior sigma from
/// the start: enough to break near-ties toward the prior (3 sigma: +9 %),
/// not enough to hide a clear minimum elsewhere within reach.
const COARSE_PRIOR_WEIGHT: f32 = 0.01;
/// Most yaw steps the coarse search takes either side of its start: 3 sigma
/// of the no-odometry prior (`GpaConfig::max_step_yaw_deg`, 24 deg) at the
/// step of a grid reaching 2.4 m on 50 mm cells (0.6 deg). Was 16, which
/// held a 1.4 m grid's search to 15 deg: short of a robot that turns 20
/// deg between frames.
const MAX_YAW_STEPS: i32 = 40;
/// Yaw steps either side of the start searched first: the whole reach
/// only when the best lies on their edge (the start is within one step
/// in most searches).
const FIRST_YAW_STEPS: i32 = 2;
/// How far over a whole number of steps 3 sigma may lie and still reach
/// that many steps (a share of a step).
const REACH_SLACK: f32 = 1e-3;
/// Most translation steps either side of the start, per axis.
const MAX_SHIFT_STEPS: i32 = 8;
/// A search on cells larger than the fine ones ranks its candidates on
/// every this many keyframe rows: it only finds the basin (its shortlist
/// is rescored exactly on every cell, and the fine search around its
/// answer, which ranks on every row, decides).
const LARGER_CELLS_ROW_STEP: u32 = 2;
/// An attitude change (degrees) above which the current image is levelled
/// before the search ([`Coarse::level`]): below, it moves the farthest
/// ground by less than a small share of a cell.
const LEVEL_ABOVE_DEG: f32 = 0.05;
/// Most rows a coarse image has (its cells are at least 2 px).
const MAX_COARSE_ROWS: usize = MAX_GRID_SIDE / 2;
/// A row's seen cells, `[start, end)`, when every cell between is seen;
/// [`MIXED`] when unseen cells lie between seen ones (rare: the camera's
/// view of the ground has no holes).
type Span = [u8; 2];
const MIXED: Span = [u8::MAX, 0];
/// What `libm::roundf` adds to a value >= 0 before it truncates: a half,
/// less a quarter ulp of 1 (so that the float just under a half rounds down).
const ROUND_HALF: f32 = 0.5 - 0.25 * f32::EPSILON;

/// The span of a row's seen cells, or [`MIXED`].
fn span_of(seen: &[bool]) -> Span {
    let Some(start) = seen.iter().position(|&seen| seen) else {
        return [0, 0];
    };
    let end = seen.len() - seen.iter().rev().position(|&seen| seen).unwrap_or(0);
    // Rows are at most MAX_GRID_SIDE / 2 = 128 cells long.
    if seen[start..end].iter().all(|&seen| seen) { [start as u8, end as u8] } else { MIXED }
}

/// The side (px) of the cells a coarse image of `cell_mm` cells averages
/// over on this grid: at least 2 px, more if the grid would need too many.
fn cell_side(grid: &KgGrid, cell_mm: f32) -> usize {
    let mut side = ((cell_mm / grid.mm_per_px as f32) as usize).max(2);
    while grid.width().div_ceil(side) * grid.height().div_ceil(side) > MAX_COARSE_CELLS {
        side += 1;
    }
    side
}

/// The ground side (mm) of the cells a search asked for `cell_mm` cells works on.
pub(super) fn cell_mm_on(grid: &KgGrid, cell_mm: f32) -> f32 {
    cell_side(grid, cell_mm) as f32 * grid.mm_per_px as f32
}

/// The yaw step that moves the grid's farthest corner by half a cell.
pub(super) fn yaw_step(grid: &KgGrid, cell_mm: f32) -> f32 {
    let far_mm = kernels::hypotf(grid.x_left_mm as f32, grid.z_far_mm as f32).max(1.0);
    (0.5 * cell_mm / far_mm).to_degrees()
}

/// A box-averaged image: `side` px cells in gray levels, and whether the
/// camera saw all of each. Bytes, so that where a row's spans say every
/// cell is seen the differences are a byte SAD (four cells an
/// instruction on the M4).
struct Coarse {
    cells: [u8; MAX_COARSE_CELLS],
    seen: [bool; MAX_COARSE_CELLS],
    /// The same cells as f32 gray levels, NaN where unseen: the bilinear
    /// samples read them without a conversion or a test per corner (a NaN
    /// corner makes the sample NaN). The workspace holds the alignment's
    /// pyramids at other times, which are larger: no RAM of its own.
    levels: [f32; MAX_COARSE_CELLS],
    /// Each row's seen cells (the difference kernel's fast path).
    spans: [Span; MAX_COARSE_ROWS],
    wide: usize,
    high: usize,
    side: usize,
}

impl Coarse {
    // All zeros: `build` writes every cell that is read (the first `wide` x
    // `high`) and the side, and a search's memory that is all zeros is set
    // up without an image of it in flash (33 KB).
    const EMPTY: Coarse = Coarse { cells: [0; MAX_COARSE_CELLS], seen: [false; MAX_COARSE_CELLS], levels: [0.0; MAX_COARSE_CELLS], spans: [[0, 0]; MAX_COARSE_ROWS], wide: 0, high: 0, side: 0 };

    /// Cell `k`'s gray level, if seen.
    #[inline(always)]
    fn value(&self, k: usize) -> Option<u8> {
        self.seen[k].then_some(self.cells[k])
    }

    /// Averages `image` over cells of `side` px ([`cell_side`]).
    fn build(&mut self, image: &[u8], scene: &Scene, side: usize) {
        let grid = scene.grid;
        let (w, h) = (grid.width(), grid.height());
        self.side = side;
        self.wide = w / side;
        self.high = h / side;
        let wide = self.wide;
        // Each pixel column summed over a row of cells first (at most 256
        // rows of 255: a u16 holds it), then each cell's columns: one pass
        // over a row, not a loop per cell and row.
        let mut columns = [0u16; MAX_GRID_SIDE];
        for cj in 0..self.high {
            // A cell counts where the camera saw its first and last column
            // in each of its rows: the cells from `valid.start` to `valid.end`.
            let mut valid = 0..wide;
            let columns = &mut columns[..wide * side];
            columns.fill(0);
            for j in cj * side..(cj + 1) * side {
                valid = match scene.coverage.seen(j) {
                    Some(seen) => valid.start.max(seen.start.div_ceil(side))..valid.end.min(seen.end / side),
                    None => 0..0,
                };
                for (column, &v) in columns.iter_mut().zip(&image[j * w..][..wide * side]) {
                    *column += u16::from(v);
                }
            }
            let sums = columns.chunks_exact(side).map(|cell| cell.iter().map(|&c| u32::from(c)).sum::<u32>());
            self.set_row(cj, sums.enumerate().map(|(ci, sum)| valid.contains(&ci).then_some((sum / (side * side) as u32) as u8)));
        }
    }

    /// Row `cj`'s cells from their gray levels (None: unseen), in both
    /// forms, and its span.
    fn set_row(&mut self, cj: usize, levels: impl Iterator<Item = Option<u8>>) {
        let row = cj * self.wide..(cj + 1) * self.wide;
        let cells = self.cells[row.clone()].iter_mut().zip(&mut self.seen[row.clone()]).zip(&mut self.levels[row.clone()]);
        for (((cell, seen), level), value) in cells.zip(levels) {
            (*cell, *seen, *level) = match value {
                Some(value) => (value, true, f32::from(value)),
                None => (0, false, f32::NAN),
            };
        }
        self.spans[cj] = span_of(&self.seen[row]);
    }

    /// Resamples the cells as a body at the keyframe's attitude would have
    /// seen them: each cell takes the value the attitude change `change`
    /// (pitch, roll, degrees) moved to it. `scratch` holds the new values
    /// meanwhile (the samples read the old ones around them).
    fn level(&mut self, scene: &Scene, change: [f32; 2], scratch: &mut Turned) {
        // The inverse of the change: from the body as it stands now back to the keyframe's.
        let keyframe = scene.keyframe_attitude.deg;
        let map = scene.images().map(&[0.0, 0.0, 0.0, -change[0], -change[1], keyframe[0] + change[0], keyframe[1] + change[1]]);
        let side = self.side as f32;
        let centre = 0.5 * (side - 1.0);
        for qj in 0..self.high {
            for qi in 0..self.wide {
                let seen = map.at(qi as f32 * side + centre, qj as f32 * side + centre).and_then(|(i, j)| self.at((i - centre) / side, (j - centre) / side));
                // Rounded as `build` rounds its box averages (down).
                let k = qj * self.wide + qi;
                (scratch.cells[k], scratch.seen[k]) = (seen.map_or(0, |value| value as u8), seen.is_some());
            }
        }
        for qj in 0..self.high {
            let row = qj * self.wide..(qj + 1) * self.wide;
            self.set_row(qj, scratch.cells[row.clone()].iter().zip(&scratch.seen[row]).map(|(&value, &seen)| seen.then_some(value)));
        }
    }

    fn mean(&self) -> f32 {
        let (mut sum, mut count) = (0u32, 0u32);
        for k in 0..self.wide * self.high {
            if let Some(value) = self.value(k) {
                sum += u32::from(value);
                count += 1;
            }
        }
        if count == 0 {
            0.0
        } else {
            sum as f32 / count as f32
        }
    }

    /// Bilinear sample at cell coordinates (u, v) (cell centres at integers).
    fn at(&self, u: f32, v: f32) -> Option<f32> {
        // Inside the cells that have a right and a lower neighbour: u0 + 1 <
        // wide is u < wide - 1 for u >= 0 (false for a NaN, or a point far off).
        if !(u >= 0.0 && v >= 0.0 && u < self.wide as f32 - 1.0 && v < self.high as f32 - 1.0) {
            return None;
        }
        let (u0, v0) = (u as usize, v as usize);
        let k = v0 * self.wide + u0;
        // SAFETY: u0 + 1 < wide and v0 + 1 < high, so every corner is below
        // wide * high, which `build` keeps within MAX_COARSE_CELLS.
        let c = unsafe {
            [
                *self.levels.get_unchecked(k),
                *self.levels.get_unchecked(k + 1),
                *self.levels.get_unchecked(k + self.wide),
                *self.levels.get_unchecked(k + self.wide + 1),
            ]
        };
        let (fu, fv) = (u - u0 as f32, v - v0 as f32);
        let value = (c[0] * (1.0 - fu) + c[1] * fu) * (1.0 - fv) + (c[2] * (1.0 - fu) + c[3] * fu) * fv;
        // NaN: a corner was not seen.
        (!value.is_nan()).then_some(value)
    }
}

/// The current coarse image turned by one yaw onto the keyframe's cells
/// and divided by the gain, rounded to whole gray levels as
/// [`Coarse`]'s, and whether the current image covers each cell. Whole
/// levels are enough to rank: the shortlist is rescored exactly.
struct Turned {
    cells: [u8; MAX_COARSE_CELLS],
    seen: [bool; MAX_COARSE_CELLS],
    /// Each row's seen cells (the difference kernel's fast path).
    spans: [Span; MAX_COARSE_ROWS],
}

impl Turned {
    // Zeros, as `Coarse::EMPTY`: `build` writes every cell that is read.
    const EMPTY: Turned = Turned { cells: [0; MAX_COARSE_CELLS], seen: [false; MAX_COARSE_CELLS], spans: [[0, 0]; MAX_COARSE_ROWS] };

    /// Samples `current` at every keyframe cell `q` through the inverse of
    /// `placement`, divided by `gain`.
    fn build(&mut self, current: &Coarse, placement: &Placement, gain: f32) {
        let Placement { sin, cos, offset } = *placement;
        let scale = 1.0 / gain;
        for qj in 0..current.high {
            let dv = qj as f32 - offset.1;
            for qi in 0..current.wide {
                let du = qi as f32 - offset.0;
                let (u, v) = (cos * du - sin * dv, sin * du + cos * dv);
                let k = qj * current.wide + qi;
                (self.cells[k], self.seen[k]) = match current.at(u, v) {
                    // libm::roundf (value >= 0): x + ROUND_HALF truncated, without the call.
                    Some(value) => (((value * scale + ROUND_HALF) as u32).min(255) as u8, true),
                    None => (0, false),
                };
            }
            self.spans[qj] = span_of(&self.seen[qj * current.wide..][..current.wide]);
        }
    }

    /// For each column shift `di` of `shifts` (`sums[n]` for the n-th), the
    /// sum of |turned(k - (di, dj)) - keyframe(k)| over the keyframe cells
    /// `k` both images see on every `row_step`-th row, and their count.
    /// All shifts of a row pair in one pass: the row's set-up is paid
    /// once, not per candidate.
    fn differences(&self, keyframe: &Coarse, dj: i32, row_step: u32, shifts: RangeInclusive<i32>, sums: &mut [(u32, u32)]) {
        let (wide, high) = (keyframe.wide as i32, keyframe.high as i32);
        let sums = &mut sums[..shifts.clone().count()];
        sums.fill((0, 0));
        for kj in (dj.max(0)..(high + dj).min(high)).filter(|kj| kj % row_step as i32 == 0) {
            let key = (kj * wide) as usize..((kj + 1) * wide) as usize;
            let turned = ((kj - dj) * wide) as usize..((kj - dj + 1) * wide) as usize;
            let (key_cells, turned_cells) = (&keyframe.cells[key.clone()], &self.cells[turned.clone()]);
            match (keyframe.spans[kj as usize], self.spans[(kj - dj) as usize]) {
                // Both rows seen throughout their spans: the cells both see
                // are where the spans overlap (the turned one moved by di),
                // within the row as the spans are.
                ([ks, ke], [ts, te]) if [ks, ke] != MIXED && [ts, te] != MIXED => {
                    let (ks, ke, ts, te) = (i32::from(ks), i32::from(ke), i32::from(ts), i32::from(te));
                    for (di, sum) in shifts.clone().zip(sums.iter_mut()) {
                        let (from, to) = (ks.max(ts + di), ke.min(te + di));
                        if from < to {
                            let (from, to, turned_from) = (from as usize, to as usize, (from - di) as usize);
                            sum.0 += kernels::sad(&key_cells[from..to], &turned_cells[turned_from..][..to - from]);
                            sum.1 += (to - from) as u32;
                        }
                    }
                }
                _ => {
                    let (key_seen, turned_seen) = (&keyframe.seen[key], &self.seen[turned]);
                    for (di, sum) in shifts.clone().zip(sums.iter_mut()) {
                        for ki in di.max(0)..(wide + di).min(wide) {
                            let (k, t) = (ki as usize, (ki - di) as usize);
                            if key_seen[k] && turned_seen[t] {
                                sum.0 += u32::from(key_cells[k].abs_diff(turned_cells[t]));
                                sum.1 += 1;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Where a candidate puts the current cells in the keyframe: keyframe
/// cell = R(yaw) cell + `offset`, in cell units (G runs against z).
#[derive(Clone, Copy)]
struct Placement {
    sin: f32,
    cos: f32,
    offset: (f32, f32),
}

/// One search's candidates: the start moved by whole steps of yaw, x and z.
struct Candidates {
    start: Params,
    /// The prior's sigmas (mm, mm, deg; pitch and roll unused).
    sigma: Params,
    cell_mm: f32,
    yaw_step: f32,
    /// Cell (0, 0)'s centre on the ground, in cells.
    origin: (f32, f32),
    /// The current image's brightness over the keyframe's.
    gain: f32,
    /// Valid current cells: a candidate must overlap a third of them.
    counted: u32,
    /// The turned image's differences read every this many rows.
    row_step: u32,
}

impl Candidates {
    fn placement(&self, dyaw: i32, dx: i32, dz: i32) -> Placement {
        let p = &self.start;
        let (origin_u, origin_v) = self.origin;
        let (sin, cos) = crate::kernels::sincosf((p[2] + dyaw as f32 * self.yaw_step).to_radians());
        let (tu, tv) = ((p[0] + dx as f32 * self.cell_mm) / self.cell_mm, (p[1] + dz as f32 * self.cell_mm) / self.cell_mm);
        let (ou, ov) = (tu + origin_u * cos - origin_v * sin, tv + origin_u * sin + origin_v * cos);
        Placement { sin, cos, offset: (ou - origin_u, origin_v - ov) }
    }

    /// What a candidate's score is multiplied by to give its cost, the
    /// prior's say: the cost grows by [`COARSE_PRIOR_WEIGHT`] per squared
    /// sigma the candidate lies from the start (a floor with little texture
    /// at this scale, or one edge across the view, scores alike along a
    /// whole line of candidates).
    fn prior_factor(&self, dyaw: i32, dx: i32, dz: i32) -> f32 {
        let squared_sigmas = |steps: i32, unit: f32, sigma: f32| {
            let sigmas = steps as f32 * unit / sigma.max(1e-9);
            sigmas * sigmas
        };
        let sigma = &self.sigma;
        let squared = squared_sigmas(dx, self.cell_mm, sigma[0]) + squared_sigmas(dz, self.cell_mm, sigma[1]) + squared_sigmas(dyaw, self.yaw_step, sigma[2]);
        1.0 + COARSE_PRIOR_WEIGHT * squared
    }

    /// The start moved by (yaw, x, z) steps.
    fn moved(&self, yaw: f32, x: f32, z: f32) -> Params {
        let mut q = self.start;
        q[2] += yaw * self.yaw_step;
        q[0] += x * self.cell_mm;
        q[1] += z * self.cell_mm;
        q
    }

    /// Whether `count` cells overlap enough to measure.
    fn overlap_measures(&self, count: u32) -> bool {
        count * 3 >= self.counted && count >= 12
    }

    /// `sum / count`, or f32::MAX when too few cells overlap to measure.
    fn mean(&self, sum: f32, count: u32) -> f32 {
        if self.overlap_measures(count) { sum / count as f32 } else { f32::MAX }
    }

    /// The mean |current - gain * keyframe| over the current cells, the
    /// keyframe sampled bilinearly where `placement` puts each.
    fn exact_score(&self, keyframe: &Coarse, current: &Coarse, placement: &Placement) -> f32 {
        self.exact_score_unless(keyframe, current, placement, |_| false).unwrap_or(f32::MAX)
    }

    /// [`Self::exact_score`], or None as soon as `hopeless` holds for a
    /// lower bound of it: the sum so far over the cells counted so far and
    /// every seen current cell still to come (the sum only grows, and at
    /// most that many cells count).
    fn exact_score_unless(&self, keyframe: &Coarse, current: &Coarse, placement: &Placement, hopeless: impl Fn(f32) -> bool) -> Option<f32> {
        let Placement { sin, cos, offset: (ou, ov) } = *placement;
        // The heading's turn of the cell axes (+u, and -z for +v).
        let (au, av, bu, bv) = (cos, sin, sin, -cos);
        let (mut sum, mut count, mut seen) = (0f32, 0u32, 0u32);
        for cj in 0..current.high {
            let most = (count + self.counted.saturating_sub(seen)).max(1) as f32;
            if hopeless(sum / most) {
                return None;
            }
            for ci in 0..current.wide {
                let level = current.levels[cj * current.wide + ci];
                if level.is_nan() {
                    continue;
                }
                seen += 1;
                let (u, v) = (ci as f32, cj as f32);
                let Some(value) = keyframe.at(au * u + bu * v + ou, -(av * u + bv * v) + ov) else {
                    continue;
                };
                sum += libm::fabsf(level - self.gain * value);
                count += 1;
            }
        }
        Some(self.mean(sum, count))
    }

    /// The same score from the current image turned by the candidate's
    /// yaw, moved by its (dx, dz) steps.
    #[cfg(test)]
    fn turned_score(&self, turned: &Turned, keyframe: &Coarse, dx: i32, dz: i32) -> f32 {
        let mut sums = [(0, 0)];
        turned.differences(keyframe, -dz, self.row_step, dx..=dx, &mut sums);
        self.turned_score_of(sums[0])
    }

    /// [`Self::turned_score`] from the sum and the count [`Turned::differences`]
    /// gave on its rows, the overlap counted over all rows.
    fn turned_score_of(&self, (sum, count): (u32, u32)) -> f32 {
        if self.overlap_measures(count * self.row_step) { self.gain * (sum as f32 / count as f32) } else { f32::MAX }
    }
}

/// Candidates the turned image ranks best, rescored exactly. The two
/// scores differ only in which image is resampled, so the exact best lies
/// among the first few: 16 judge every recording as 32 did, at half the
/// exact scores, the search's costliest part.
const SHORTLIST: usize = 16;

/// The [`SHORTLIST`] lowest costs offered, with their steps (yaw, z, x).
struct Shortlist {
    entries: [(f32, [i32; 3]); SHORTLIST],
}

impl Shortlist {
    const EMPTY: Shortlist = Shortlist { entries: [(f32::MAX, [0; 3]); SHORTLIST] };

    /// The cost an offer must get under to be kept.
    fn last_cost(&self) -> f32 {
        self.entries[SHORTLIST - 1].0
    }

    fn offer(&mut self, cost: f32, steps: [i32; 3]) {
        if cost >= self.last_cost() {
            return;
        }
        let last = SHORTLIST - 1;
        let mut k = last;
        while k > 0 && cost < self.entries[k - 1].0 {
            self.entries[k] = self.entries[k - 1];
            k -= 1;
        }
        self.entries[k] = (cost, steps);
    }

    /// The steps kept, lowest cost first.
    fn best_first(&self) -> impl Iterator<Item = [i32; 3]> + '_ {
        self.entries.iter().take_while(|(cost, _)| *cost < f32::MAX).map(|&(_, steps)| steps)
    }
}

/// The shortlist's exact scores by steps (yaw, z, x).
type Scored = heapless::Vec<([i32; 3], f32), SHORTLIST>;

/// A candidate's exact cost and its steps (yaw, z, x); the steps break a
/// tie, smaller first, so that the choice is the one a search over all
/// candidates in step order would make, whatever order they are scored in.
#[derive(Clone, Copy)]
struct Ranked {
    cost: f32,
    steps: [i32; 3],
}

impl Ranked {
    const NONE: Ranked = Ranked { cost: f32::MAX, steps: [0; 3] };

    fn beats(&self, other: &Ranked) -> bool {
        self.cost < other.cost || (self.cost == other.cost && self.steps < other.steps)
    }
}

/// What a coarse search is asked for: the runner-up costs more, as fewer
/// candidates can be given up early.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Wanted {
    Best,
    BestAndRunnerUp,
}

/// A coarse search's answer: the motion, its score (mean absolute
/// difference per cell, `f32::MAX` when nothing was measured), and the
/// next best candidate.
pub(super) struct CoarseFound {
    pub(super) p: Params,
    pub(super) score: f32,
    pub(super) runner_up: Option<Params>,
    /// The best lies on the edge of the first yaws searched, and is to be
    /// widened on larger cells ([`Widen::OnLargerCells`]).
    on_yaw_edge: bool,
}

/// How a search whose best lies on the edge of its first yaws searches
/// every yaw within reach.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Widen {
    /// On its own cells: a search a few yaw steps wide (the fine
    /// searches, whose reach is a wide cell's yaw step or two).
    InPlace,
    /// On cells twice as large (half the yaw steps, a quarter of the
    /// cells and translations: a sixteenth of the work), then its best
    /// refined on the search's own cells; the better of the two is kept.
    /// The wide search, whose reach is the prior's: up to 40 yaw steps
    /// either side.
    OnLargerCells,
    /// In place, but only past the edge facing away from the best, which
    /// lies this many degrees of yaw from the search's start (either edge
    /// when 0): a search around a runner-up whose best walks toward the
    /// yaw the best's own search ended at is walking into ground that
    /// search covered (on a turn both walked the same way, the second
    /// search for nothing).
    AwayFrom(f32),
}

impl Widen {
    /// Whether to widen past the edge on the side of `steps` (its sign).
    fn past(self, steps: i32) -> bool {
        match self {
            Widen::InPlace | Widen::OnLargerCells => true,
            Widen::AwayFrom(best) => best == 0.0 || (steps as f32) * best < 0.0,
        }
    }
}

/// The coarse search's memory: both coarse images and the turned one.
pub(super) struct CoarseSearch {
    keyframe: Coarse,
    current: Coarse,
    turned: Turned,
    /// The cell side (px) both coarse images were built at for this
    /// scene: the searches around the best and the runner-up share them.
    built_side: Option<usize>,
}

impl CoarseSearch {
    pub(super) const EMPTY: CoarseSearch = CoarseSearch { keyframe: Coarse::EMPTY, current: Coarse::EMPTY, turned: Turned::EMPTY, built_side: None };

    /// A new scene: the coarse images built for the last one are stale.
    pub(super) fn new_scene(&mut self) {
        self.built_side = None;
    }

    /// The planar motion (tx, tz, yaw) on images of `cell_mm` cells,
    /// searched over 3 `sigma` around `start`, widening its yaws as `widen`
    /// says; no runner-up.
    pub(super) fn search(&mut self, scene: &Scene, start: &Params, sigma: &Params, cell_mm: f32, widen: Widen) -> CoarseFound {
        self.search_for(scene, start, sigma, cell_mm, Wanted::Best, widen)
    }

    /// [`Self::search`] with the runner-up.
    pub(super) fn search_with_runner_up(&mut self, scene: &Scene, start: &Params, sigma: &Params, cell_mm: f32, widen: Widen) -> CoarseFound {
        self.search_for(scene, start, sigma, cell_mm, Wanted::BestAndRunnerUp, widen)
    }

    /// The yaws nearest the start first; when the best lies on their edge,
    /// every yaw within reach as `widen` says.
    fn search_for(&mut self, scene: &Scene, start: &Params, sigma: &Params, cell_mm: f32, wanted: Wanted, widen: Widen) -> CoarseFound {
        let first = self.search_window(scene, start, sigma, cell_mm, wanted, widen);
        if !first.on_yaw_edge {
            return first;
        }
        let larger = self.search_window(scene, start, sigma, 2.0 * cell_mm, Wanted::Best, Widen::InPlace);
        if larger.score == f32::MAX {
            return first;
        }
        // Its answer is good to about half its cell and yaw step: refined
        // over a whole one either side (two cells and two yaw steps here).
        let around = [2.0 * cell_mm / 3.0, 2.0 * cell_mm / 3.0, yaw_step(scene.grid, 2.0 * cell_mm) / 3.0, sigma[3], sigma[4]];
        let refined = self.search_window(scene, &larger.p, &around, cell_mm, wanted, Widen::InPlace);
        if refined.score < first.score { refined } else { first }
    }

    /// One search on `cell_mm` cells: the first yaws, then, when the best
    /// lies on their edge and `widen` says so, every yaw within reach on
    /// these cells; [`Widen::OnLargerCells`] is left to the caller
    /// (`on_yaw_edge`).
    fn search_window(&mut self, scene: &Scene, start: &Params, sigma: &Params, cell_mm: f32, wanted: Wanted, widen: Widen) -> CoarseFound {
        let p = *start;
        let unmeasured = CoarseFound { p, score: f32::MAX, runner_up: None, on_yaw_edge: false };
        let grid = scene.grid;
        let mm_per_px = grid.mm_per_px as f32;
        let side = cell_side(grid, cell_mm);
        if self.built_side != Some(side) {
            self.keyframe.build(scene.keyframe, scene, side);
            self.current.build(scene.current, scene, side);
            // Level images (no attitude change) are what a rigid planar
            // motion maps onto each other: a pitch change of 0.7 degree
            // moves ground 1 m ahead as far as 35 mm of travel.
            let change = [p[3], p[4]];
            if libm::fabsf(change[0]).max(libm::fabsf(change[1])) > LEVEL_ABOVE_DEG {
                self.current.level(scene, change, &mut self.turned);
            }
            self.built_side = Some(side);
        }
        let (key_mean, cur_mean) = (self.keyframe.mean(), self.current.mean());
        if key_mean < 1.0 || cur_mean < 1.0 {
            return unmeasured;
        }
        let gain = cur_mean / key_mean;
        let cell_mm = mm_per_px * self.current.side as f32;
        // 3 sigma in whole steps; a hair over a whole number (float
        // rounding of a sigma set as steps / 3) takes no step more.
        let steps = |sigma: f32, step: f32| libm::ceilf(3.0 * sigma / step - REACH_SLACK) as i32;
        let (reach_x, reach_z) = (steps(sigma[0], cell_mm).clamp(1, MAX_SHIFT_STEPS), steps(sigma[1], cell_mm).clamp(1, MAX_SHIFT_STEPS));
        let yaw_step = yaw_step(grid, cell_mm);
        let yaw_reach = steps(sigma[2], yaw_step).clamp(0, MAX_YAW_STEPS);
        let counted = (0..self.current.wide * self.current.high).filter(|&k| self.current.value(k).is_some()).count() as u32;
        let cell_centre = 0.5 * (self.current.side as f32 - 1.0) / self.current.side as f32;
        let origin = (grid.x_left_mm as f32 / cell_mm + cell_centre, grid.z_far_mm as f32 / cell_mm - cell_centre);
        let row_step = if side > cell_side(grid, fine_cell_mm(grid)) { LARGER_CELLS_ROW_STEP } else { 1 };
        let candidates = Candidates { start: p, sigma: *sigma, cell_mm, yaw_step, origin, gain, counted, row_step };
        // Rank the candidates on the turned image, keeping the few best, and
        // score those exactly: first the yaws nearest the start, then, if
        // the best lies on their edge, every yaw within reach.
        let mut shortlist = Shortlist::EMPTY;
        let mut sums = [(0u32, 0u32); 2 * MAX_SHIFT_STEPS as usize + 1];
        // The shortlist's exact scores, for the sub-cell steps below (the
        // best's neighbours are mostly on it).
        let mut scored = Scored::new();
        let (mut ranked, mut reach) = (None, yaw_reach.min(FIRST_YAW_STEPS));
        let (best, second, on_yaw_edge) = loop {
            for dyaw in -reach..=reach {
                if ranked.is_some_and(|ranked: i32| dyaw.abs() <= ranked) {
                    continue;
                }
                self.turned.build(&self.current, &candidates.placement(dyaw, 0, 0), gain);
                for dz in -reach_z..=reach_z {
                    // Every x step of this z at once, then offered in step
                    // order: the order ties are kept in.
                    self.turned.differences(&self.keyframe, -dz, row_step, -reach_x..=reach_x, &mut sums);
                    for (dx, &sum) in (-reach_x..=reach_x).zip(&sums) {
                        let score = candidates.turned_score_of(sum);
                        if score != f32::MAX {
                            shortlist.offer(score * candidates.prior_factor(dyaw, dx, dz), [dyaw, dz, dx]);
                        }
                    }
                }
            }
            ranked = Some(reach);
            let (best, second) = self.rescore(&shortlist, &candidates, wanted, &mut scored);
            let on_edge = best.cost < f32::MAX && best.steps[0].abs() == reach && reach < yaw_reach;
            if !on_edge || !widen.past(best.steps[0]) {
                break (best, second, false);
            }
            if widen == Widen::OnLargerCells {
                break (best, second, true);
            }
            reach = yaw_reach;
        };
        if best.cost == f32::MAX {
            return unmeasured;
        }
        let [by, bz, bx] = best.steps;
        let runner_up = (wanted == Wanted::BestAndRunnerUp && second.cost < f32::MAX).then(|| candidates.moved(second.steps[0] as f32, second.steps[2] as f32, second.steps[1] as f32));
        // Sub-cell: a parabola along each axis through the best.
        let exact = |dyaw: i32, dx: i32, dz: i32| match scored.iter().find(|(steps, _)| *steps == [dyaw, dz, dx]) {
            Some(&(_, score)) => score,
            None => candidates.exact_score(&self.keyframe, &self.current, &candidates.placement(dyaw, dx, dz)),
        };
        let centre = exact(by, bx, bz);
        let offset = |minus: f32, plus: f32| {
            if minus == f32::MAX || plus == f32::MAX {
                0.0
            } else {
                crate::subpixel::minimum_offset(minus, centre, plus).clamp(-0.5, 0.5)
            }
        };
        let yaw = by as f32 + offset(exact(by - 1, bx, bz), exact(by + 1, bx, bz));
        let x = bx as f32 + offset(exact(by, bx - 1, bz), exact(by, bx + 1, bz));
        let z = bz as f32 + offset(exact(by, bx, bz - 1), exact(by, bx, bz + 1));
        CoarseFound { p: candidates.moved(yaw, x, z), score: centre, runner_up, on_yaw_edge }
    }

    /// The shortlist scored again sampling the keyframe at each current
    /// cell: the turned image samples the current one instead, as good for
    /// ranking but rounded differently cell by cell, and the fine steps
    /// start from what is chosen here. Best first, so that the one to beat
    /// is known early and hopeless candidates are given up soon. Returns
    /// the best and the second best; `scored` gets every exact score.
    #[inline(always)] // a call of its own costs ~45 k instructions a frame on the M4
    fn rescore(&self, shortlist: &Shortlist, candidates: &Candidates, wanted: Wanted, scored: &mut Scored) -> (Ranked, Ranked) {
        let (mut best, mut second) = (Ranked::NONE, Ranked::NONE);
        scored.clear();
        for steps in shortlist.best_first() {
            let [dyaw, dz, dx] = steps;
            // A candidate that cannot beat the best so far (or the second
            // best, when the runner-up is wanted) changes nothing: it is
            // given up as soon as a lower bound shows that.
            let placement = candidates.placement(dyaw, dx, dz);
            let to_beat = match wanted {
                Wanted::Best => best,
                Wanted::BestAndRunnerUp => second,
            };
            let factor = candidates.prior_factor(dyaw, dx, dz);
            let hopeless = |bound: f32| to_beat.cost < f32::MAX && !(Ranked { cost: bound * factor, steps }).beats(&to_beat);
            let Some(score) = candidates.exact_score_unless(&self.keyframe, &self.current, &placement, hopeless) else { continue };
            // Never full: the shortlist holds SHORTLIST candidates.
            let _ = scored.push((steps, score));
            if score == f32::MAX {
                continue;
            }
            let candidate = Ranked { cost: score * factor, steps };
            if candidate.beats(&best) {
                second = best;
                best = candidate;
            } else if candidate.beats(&second) {
                second = candidate;
            }
        }
        (best, second)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_runner_up_widens_only_away_from_the_best() {
        // The best's yaw lies 1.5 degrees above the runner-up's start.
        let away = Widen::AwayFrom(1.5);
        assert!(!away.past(2), "towards the best: its own search covers it");
        assert!(away.past(-2));
        assert!(Widen::AwayFrom(0.0).past(2) && Widen::AwayFrom(0.0).past(-2), "same yaw: either side is new ground");
        assert!(Widen::InPlace.past(2) && Widen::InPlace.past(-2));
    }

    /// The turned image's rounding is libm's `roundf` on every value it
    /// can meet (>= 0), halves and the float just under a half included.
    #[test]
    fn the_turned_rounding_is_roundf() {
        let just_under_half = f32::from_bits(0.5f32.to_bits() - 1);
        let mut values = std::vec![0.0, just_under_half, 0.5, 1.5, 2.5, 4079.5, 65534.5, 1e6];
        let mut state = 0x1234_5678u32;
        for _ in 0..100_000 {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            values.push(f32::from_bits(state % 0x4780_0000));
        }
        for x in values {
            assert_eq!((x + ROUND_HALF) as u32 as f32, libm::roundf(x), "{x}");
        }
    }

    #[test]
    fn the_shortlist_keeps_the_lowest_costs_best_first() {
        let mut shortlist = Shortlist::EMPTY;
        // Costs falling then rising along the search: the lowest are the middle ones.
        for k in 0..100i32 {
            shortlist.offer((k - 50).abs() as f32, [k / 10, k % 10, 0]);
        }
        let kept: std::vec::Vec<_> = shortlist.best_first().collect();
        assert_eq!(kept.len(), SHORTLIST);
        // Cost 0 first, then each cost's two candidates in the order offered.
        let mut expected = std::vec![[5, 0, 0]];
        for d in 1..=16 {
            expected.extend([[(50 - d) / 10, (50 - d) % 10, 0], [(50 + d) / 10, (50 + d) % 10, 0]]);
        }
        expected.truncate(SHORTLIST);
        assert_eq!(kept, expected);
    }

    /// A coarse image of `wide` x `high` cells, every one valid.
    fn coarse(wide: usize, high: usize, value: impl Fn(usize, usize) -> u8) -> Coarse {
        let mut image = Coarse::EMPTY;
        (image.wide, image.high, image.side) = (wide, high, 5);
        for j in 0..high {
            image.set_row(j, (0..wide).map(|i| Some(value(i, j))));
        }
        image
    }

    #[test]
    fn a_span_is_the_seen_cells_when_none_between_is_unseen() {
        assert_eq!(span_of(&[false, true, true, false]), [1, 3]);
        assert_eq!(span_of(&[true, true]), [0, 2]);
        assert_eq!(span_of(&[false, false]), [0, 0]);
        assert_eq!(span_of(&[]), [0, 0]);
        assert_eq!(span_of(&[true, false, true]), MIXED);
    }

    /// All shifts of a row pair at once give what each shift alone gives,
    /// cell by cell on the rows read (every row, or every other), on rows
    /// seen throughout a span and on rows with holes.
    #[test]
    fn all_shifts_at_once_sum_as_each_alone() {
        let texture = |i: usize, j: usize| ((i * 37 + j * 91) % 61 * 4) as u8;
        let mut keyframe = coarse(20, 12, texture);
        // A span narrower than the row, and a hole (a mixed row): on rows
        // the ranking reads.
        keyframe.set_row(2, (0..20).map(|i| (3..17).contains(&i).then_some(texture(i, 2))));
        keyframe.set_row(6, (0..20).map(|i| (i != 9).then_some(texture(i, 6))));
        let mut current = coarse(20, 12, |i, j| texture(i + 1, j + 2));
        // The camera's trapezoid: the far rows seen narrower.
        for j in 0..5 {
            current.set_row(j, (0..20).map(|i| (j..20 - j).contains(&i).then_some(texture(i + 1, j + 2))));
        }
        let mut turned = Turned::EMPTY;
        turned.build(&current, &Placement { sin: 0.0, cos: 1.0, offset: (0.0, 0.0) }, 1.0);
        turned.seen[7 * 20 + 4] = false;
        turned.spans[7] = span_of(&turned.seen[7 * 20..][..20]);
        // Each cell's |difference| where both see it, summed by hand.
        let alone = |di: i32, dj: i32, row_step: u32| {
            let (mut sum, mut count) = (0u32, 0u32);
            for kj in (0..12i32).step_by(row_step as usize) {
                for ki in 0..20i32 {
                    let (ti, tj) = (ki - di, kj - dj);
                    if !(0..20).contains(&ti) || !(0..12).contains(&tj) {
                        continue;
                    }
                    let (k, t) = ((kj * 20 + ki) as usize, (tj * 20 + ti) as usize);
                    if keyframe.seen[k] && turned.seen[t] {
                        sum += u32::from(keyframe.cells[k].abs_diff(turned.cells[t]));
                        count += 1;
                    }
                }
            }
            (sum, count)
        };
        let mut sums = [(0, 0); 2 * MAX_SHIFT_STEPS as usize + 1];
        for (row_step, dj) in [1, LARGER_CELLS_ROW_STEP].into_iter().flat_map(|row_step| (-3..=3).map(move |dj| (row_step, dj))) {
            turned.differences(&keyframe, dj, row_step, -MAX_SHIFT_STEPS..=MAX_SHIFT_STEPS, &mut sums);
            for (di, &sum) in (-MAX_SHIFT_STEPS..=MAX_SHIFT_STEPS).zip(&sums) {
                assert_eq!(sum, alone(di, dj, row_step), "shift ({di}, {dj}), every {row_step} rows");
            }
        }
    }

    /// A ranking that reads every other row counts the rows it skipped in
    /// its overlap test: a third of the current cells overlapping measures.
    #[test]
    fn the_ranked_overlap_counts_the_skipped_rows() {
        let row_step = LARGER_CELLS_ROW_STEP;
        let candidates = Candidates { start: [0.0; 5], sigma: [50.0; 5], cell_mm: 50.0, yaw_step: 0.5, origin: (0.0, 0.0), gain: 1.0, counted: 600, row_step };
        let half = 600 / row_step;
        assert_eq!(candidates.turned_score_of((4 * half, half)), 4.0, "all of them");
        assert!(candidates.turned_score_of((0, half / 3 + 1)) < f32::MAX, "a third and a row");
        assert_eq!(candidates.turned_score_of((0, half / 3 - 1)), f32::MAX, "under a third");
    }

    #[test]
    fn turned_and_exact_scores_agree_and_find_the_shift() {
        let texture = |i: i32, j: i32| ((i * 37 + j * 91) % 61 * 4) as u8;
        // The current image is the keyframe moved by (+2, -1) cells.
        let keyframe = coarse(20, 30, |i, j| texture(i as i32, j as i32));
        let current = coarse(20, 30, |i, j| texture(i as i32 + 2, j as i32 - 1));
        let candidates = Candidates {
            start: [0.0; 5],
            sigma: [50.0, 50.0, 1.0, 1.0, 1.0],
            cell_mm: 25.0,
            yaw_step: 0.5,
            origin: (-5.0, 40.0),
            gain: 1.0,
            counted: 600,
            row_step: 1,
        };
        let mut turned = Turned::EMPTY;
        turned.build(&current, &candidates.placement(0, 0, 0), 1.0);
        for (dx, dz) in [(2, 1), (0, 0), (1, 1), (2, 0), (-1, 2)] {
            let fast = candidates.turned_score(&turned, &keyframe, dx, dz);
            let exact = candidates.exact_score(&keyframe, &current, &candidates.placement(0, dx, dz));
            assert!((fast - exact).abs() < 0.05 * exact.max(1.0), "({dx}, {dz}): {fast} vs {exact}");
            assert_eq!(fast == 0.0, (dx, dz) == (2, 1), "({dx}, {dz}): {fast}");
        }
    }
}

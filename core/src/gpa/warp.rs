//! The warp: where each current KG pixel lies in the keyframe under the
//! predicted motion (translation and yaw, a rotation in the KG plane about
//! the robot origin), one Q16.16 line per row; and which of a row's columns
//! can be compared at all.

use crate::grid::{KgGrid, MAX_GRID_SIDE};
use super::homography::PixelMap;
use crate::motion::{Attitude, GroundMotion};
use crate::remap::RemapTable;
use core::ops::Range;

/// Fraction bits of the Q16.16 keyframe positions.
pub(super) const FRAC: u32 = 16;

/// `value` in Q16.16, saturated far beyond any grid.
pub(super) fn to_q16(value: f64) -> i32 {
    libm::round(value * 65536.0).clamp(-1.0e9, 1.0e9) as i32
}

/// [`to_q16`] of an `f32` (scaled exactly: a power of two), saturated alike.
fn to_q16_f32(value: f32) -> i32 {
    libm::roundf(value * 65536.0).clamp(-1.0e9, 1.0e9) as i32
}

/// Fraction bits of a row's bend, per column squared: Q16.16 positions
/// with 8 more bits (a 1 degree roll bends by ~1/4000 px per column
/// squared, ~4,200 units; rounding to a unit moves column 255 by at most
/// 1/512 px).
pub(super) const BEND_FRAC: u32 = 24;

/// One row's warp: keyframe position of current column 0, its per-column
/// step, Q16.16, and its bend per column squared, Q24.
///
/// Under a roll a row still maps onto a line, but a projective one: its
/// columns land unevenly spaced (by r x^2 / H in ground mm), by 1.3 px in
/// the middle of a row for a 1 degree roll. A quadratic through the row's
/// ends and middle leaves under 1/16 px.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct RowWarp {
    pub(super) i_start: i32,
    pub(super) i_step: i32,
    pub(super) i_bend: i32,
    pub(super) j_start: i32,
    pub(super) j_step: i32,
    pub(super) j_bend: i32,
}

impl RowWarp {
    /// Every column onto keyframe column 0 of row 0: a placeholder.
    pub(super) const LEVEL: RowWarp = RowWarp { i_start: 0, i_step: 0, i_bend: 0, j_start: 0, j_step: 0, j_bend: 0 };

    /// No yaw: the row maps onto one keyframe row, columns a pixel apart.
    #[inline(always)]
    pub(super) fn is_translation(&self) -> bool {
        self.i_step == 1 << FRAC && self.j_step == 0 && !self.is_bent()
    }

    /// Columns unevenly spaced (an attitude change with roll).
    #[inline(always)]
    pub(super) fn is_bent(&self) -> bool {
        self.i_bend != 0 || self.j_bend != 0
    }

    /// Keyframe position (i, j) of current column `c`.
    #[inline(always)]
    pub(super) fn at(&self, c: usize) -> (i32, i32) {
        let bend = |bend: i32| ((c as i64 * c as i64 * i64::from(bend)) >> (BEND_FRAC - FRAC)) as i32;
        (
            self.i_start.wrapping_add((c as i32).wrapping_mul(self.i_step)).wrapping_add(bend(self.i_bend)),
            self.j_start.wrapping_add((c as i32).wrapping_mul(self.j_step)).wrapping_add(bend(self.j_bend)),
        )
    }

    /// [`Self::at`] of the columns `first`, `first + 1`, ... in turn, by
    /// exact differences, for columns whose positions lie inside a grid
    /// (0 <= i, j < 256 px).
    #[inline(always)]
    pub(super) fn positions(&self, first: usize) -> Positions {
        Positions { i: Coordinate::new(self.i_start, self.i_step, self.i_bend, first), j: Coordinate::new(self.j_start, self.j_step, self.j_bend, first) }
    }

    /// The same line moved by (`di`, `dj`), Q16.16.
    #[inline(always)]
    pub(super) fn moved(&self, di: i32, dj: i32) -> RowWarp {
        RowWarp { i_start: self.i_start.wrapping_add(di), j_start: self.j_start.wrapping_add(dj), ..*self }
    }
}

/// One coordinate of [`RowWarp::at`] at column `c` without its i32
/// wrapping (the two agree wherever the value fits an i32).
#[inline(always)]
pub(super) fn unwrapped(start: i32, step: i32, bend: i32, c: usize) -> i64 {
    let c = c as i64;
    i64::from(start) + c * i64::from(step) + ((c * c * i64::from(bend)) >> (BEND_FRAC - FRAC))
}

/// Whether a straight coordinate, its `start`, its `step` and its positions
/// at the columns `first` and `last` all lie within +-`bound`: the solved
/// rows and lines take only such (any sane warp's), so their differences
/// fit an i32.
pub(super) fn straight_within(start: i32, step: i32, first: usize, last: usize, bound: i64) -> bool {
    let within = |v: i64| v.abs() < bound;
    within(i64::from(start)) && within(i64::from(step)) && [first, last].iter().all(|&c| within(unwrapped(start, step, 0, c)))
}

/// `a / b` rounded up, for `b > 0`.
#[inline(always)]
pub(super) fn ceil_div(a: i32, b: i32) -> i32 {
    -((-a).div_euclid(b))
}

/// The measured motion as a map from current KG pixels to keyframe KG
/// pixels. Planar motion alone is affine; an attitude change bends it
/// (each row stays a line, its spacing and slope change with distance),
/// so then each row's line runs through its exact ends.
#[derive(Clone, Copy, Debug)]
pub(super) struct Warp {
    /// The map through the attitude ([`crate::motion::GroundMap`] as one
    /// homography); None when level. In `f32` on the M4's FPU: a row's
    /// three points in software `f64` cost ~17,000 instructions, 4 M a
    /// frame. `f32` keeps the Q16 positions within 2^-15 px of `f64`'s,
    /// far below the 2^-8 px of the bilinear weights.
    bent: Option<PixelMap<f32>>,
    grid: KgGrid,
    /// The planar part as an affine map (exact without attitude).
    origin: (f64, f64),
    /// The step along a row in Q16 (the same on every row).
    column_q16: (i32, i32),
    row: (f64, f64),
    /// `origin` and `row` in fixed point, [`FINE_BITS`] below Q16, per
    /// coordinate; None beyond the range where they settle a row's start
    /// (see [`Warp::affine_start`]).
    fine: Option<[(i64, i64); 2]>,
}

/// Bits below Q16 of [`Warp`]'s fixed-point origin and row step.
const FINE_BITS: u32 = 32;
/// The fixed-point rows' range: origin (px), row step (px) and row index
/// (|row| < 2^10) within which the f64 sum and its fixed-point value lie
/// within 2^10 units of each other (see [`Warp::affine_start`]).
const FINE_ORIGIN_PX: f64 = 2048.0;
const FINE_ROW_STEP_PX: f64 = 4.0;
const FINE_ROWS: usize = 1 << 10;
/// Fixed-point sums this close to a half Q16 unit may round either way:
/// the f64 is worked out.
const FINE_MARGIN: u32 = 1 << 12;

/// [`Warp`]'s fixed-point `origin` and `row` step, or None beyond their range.
fn fine_rows(origin: (f64, f64), row: (f64, f64)) -> Option<[(i64, i64); 2]> {
    // Scaled by a power of two (exact) and rounded: within half a unit.
    let fine = |value: f64, bound: f64| (libm::fabs(value) < bound).then(|| libm::round(value * (1u64 << (FRAC + FINE_BITS)) as f64) as i64);
    let coordinate = |origin: f64, row: f64| Some((fine(origin, FINE_ORIGIN_PX)?, fine(row, FINE_ROW_STEP_PX)?));
    Some([coordinate(origin.0, row.0)?, coordinate(origin.1, row.1)?])
}

/// How far (Q16.16) a row's line may lie from its own when it continues
/// the row above's ([`Warp::row_after`]): 1/64 px, the departure below
/// which [`Warp::row_at`] already keeps a row straight.
const CONTINUED_Q16: i64 = 1 << (FRAC - 6);

/// One pixel per column squared in [`RowWarp`]'s bend units.
const BEND_SCALE: f64 = (1u64 << BEND_FRAC) as f64;

/// Below this attitude change (degrees) a row's line is the affine one:
/// the bend moves no column by 1/64 px on any grid we build.
const LEVEL_DEG: f64 = 1e-4;

impl Warp {
    pub(super) const NONE: Warp = Warp {
        bent: None,
        grid: KgGrid { mm_per_px: 1.0, x_left_mm: 0.0, z_far_mm: 0.0, width: 0, height: 0 },
        origin: (0.0, 0.0),
        column_q16: (0, 0),
        row: (0.0, 0.0),
        fine: None,
    };

    /// The warp of `motion` from a keyframe whose body stood at `keyframe`.
    pub(super) fn new(grid: &KgGrid, motion: &GroundMotion, keyframe: &Attitude, height_mm: f64) -> Warp {
        let warp = |i: f64, j: f64| {
            let (x, z) = grid.pixel_to_ground(i, j);
            let (xk, zk) = motion.planar.to_earlier_frame(x, z);
            grid.ground_to_pixel(xk, zk)
        };
        let origin = warp(0.0, 0.0);
        let along = warp(1.0, 0.0);
        let down = warp(0.0, 1.0);
        let level = [motion.attitude, *keyframe].iter().all(|a| libm::fabs(a.pitch_deg) < LEVEL_DEG && libm::fabs(a.roll_deg) < LEVEL_DEG);
        let row = (down.0 - origin.0, down.1 - origin.1);
        Warp {
            bent: (!level).then(|| {
                let (planar, attitude) = (&motion.planar, &motion.attitude);
                let p = [planar.tx_mm, planar.tz_mm, planar.dyaw_deg, attitude.pitch_deg, attitude.roll_deg].map(|v| v as f32);
                PixelMap::new(&p, [keyframe.pitch_deg as f32, keyframe.roll_deg as f32], height_mm as f32, grid)
            }),
            grid: *grid,
            origin,
            column_q16: (to_q16(along.0 - origin.0), to_q16(along.1 - origin.1)),
            row,
            fine: fine_rows(origin, row),
        }
    }

    /// The warp of current row `j`.
    pub(super) fn row(&self, j: usize) -> RowWarp {
        self.row_at(j as isize)
    }

    /// The line of current row `j` right after row `j - 1`'s `above`:
    /// `above` moved down one keyframe row wherever that stays within
    /// [`CONTINUED_Q16`] of row `j`'s own line at every column, else its
    /// own. Continued rows let the search band roll on, sampling one line
    /// a row instead of 2S+1 (a tilted body's own lines differ from row to
    /// row by a few thousandths of a pixel). Each row is held to its own
    /// line, so the departures never add up.
    pub(super) fn row_after(&self, j: usize, above: RowWarp) -> RowWarp {
        let own = self.row(j);
        let continued = above.moved(0, 1 << FRAC);
        let last = self.grid.width().max(1) as i64 - 1;
        let apart = |a: (i32, i32, i32), b: (i32, i32, i32)| {
            let difference = |x: i32, y: i32| (i64::from(x) - i64::from(y)).abs();
            difference(a.0, b.0) + last * difference(a.1, b.1) + ((last * last * difference(a.2, b.2)) >> (BEND_FRAC - FRAC))
        };
        let within = |a: &RowWarp, b: &RowWarp| {
            apart((a.i_start, a.i_step, a.i_bend), (b.i_start, b.i_step, b.i_bend)) <= CONTINUED_Q16
                && apart((a.j_start, a.j_step, a.j_bend), (b.j_start, b.j_step, b.j_bend)) <= CONTINUED_Q16
        };
        if within(&continued, &own) {
            continued
        } else {
            own
        }
    }

    /// The warp of current row `r`, which may lie beyond the grid's rows.
    pub(super) fn row_at(&self, r: isize) -> RowWarp {
        if let Some(bent) = &self.bent {
            let jf = r as f32;
            let last = (self.grid.width().max(2) - 1) as f32;
            let at = |i: f32| bent.at(i, jf);
            let middle = libm::roundf(0.5 * last);
            if let (Some(first), Some(centre), Some(end)) = (at(0.0), at(middle), at(last)) {
                // The quadratic through the three: p(c) = first + step c + bend c^2.
                let line = |first: f32, centre: f32, end: f32| {
                    let to_end = (end - first) / last;
                    let bend = if middle > 0.0 && last > middle { (to_end - (centre - first) / middle) / (last - middle) } else { 0.0 };
                    // Below 1/64 px off the chord it stays a line.
                    let bend = if libm::fabsf(bend) * middle * (last - middle) < 1.0 / 64.0 { 0.0 } else { bend };
                    let step = to_end - bend * last;
                    (to_q16_f32(first), to_q16_f32(step), libm::roundf(bend * BEND_SCALE as f32) as i32)
                };
                let (i_start, i_step, i_bend) = line(first.0, centre.0, end.0);
                let (j_start, j_step, j_bend) = line(first.1, centre.1, end.1);
                return RowWarp { i_start, i_step, i_bend, j_start, j_step, j_bend };
            }
        }
        RowWarp {
            i_start: self.affine_start(0, r),
            i_step: self.column_q16.0,
            j_start: self.affine_start(1, r),
            j_step: self.column_q16.1,
            ..RowWarp::default()
        }
    }

    /// Row `r`'s start along `coordinate` (0: i, 1: j) under the affine
    /// map: `to_q16(origin + row * r)` as f64 rounds it, worked out in
    /// fixed point (software f64 costs ~450 instructions a coordinate on
    /// the M4). The two sums differ by under 2^10 units: the fixed-point
    /// values by half a unit per term (2^9 over the rows), the f64 sum's
    /// two roundings by 2^-53 of at most 2^13 px each (2^9). Unless the
    /// fixed-point sum lies within [`FINE_MARGIN`] of a half Q16 unit,
    /// both round to the same Q16 value, and no clamp is reached.
    fn affine_start(&self, coordinate: usize, r: isize) -> i32 {
        let (origin, row) = [(self.origin.0, self.row.0), (self.origin.1, self.row.1)][coordinate];
        if let Some(fine) = self.fine.filter(|_| r.unsigned_abs() < FINE_ROWS) {
            let (origin, row) = fine[coordinate];
            let sum = origin + row * r as i64;
            if (sum as u32).abs_diff(1 << (FINE_BITS - 1)) > FINE_MARGIN {
                return ((sum + (1 << (FINE_BITS - 1))) >> FINE_BITS) as i32;
            }
        }
        to_q16(origin + row * r as f64)
    }
}

/// One coordinate of a [`RowWarp`] stepped column by column, in Q8.24
/// modulo 2^32: `start << 8 + c step << 8 + c^2 bend` by its first and
/// second differences, two adds a column and no multiply. Wrapped sums
/// are exact modulo 2^32, so the top 24 bits are [`RowWarp::at`]'s Q16
/// value modulo 2^24 (`a + floor(b / 256) = floor((256 a + b) / 256)`):
/// the same value wherever it lies in 0..256 px, as every position of a
/// span inside a grid does.
#[derive(Clone, Copy)]
pub(super) struct Coordinate {
    sum: u32,
    difference: u32,
    second: u32,
}

impl Coordinate {
    #[inline(always)]
    fn new(start: i32, step: i32, bend: i32, c: usize) -> Coordinate {
        let (c, step, bend) = (c as u32, (step as u32) << (BEND_FRAC - FRAC), bend as u32);
        Coordinate {
            sum: ((start as u32) << (BEND_FRAC - FRAC)).wrapping_add(c.wrapping_mul(step)).wrapping_add(c.wrapping_mul(c).wrapping_mul(bend)),
            difference: step.wrapping_add((2 * c + 1).wrapping_mul(bend)),
            second: bend.wrapping_mul(2),
        }
    }

    /// Whole pixels (the top 8 bits) and the bilinear weight (the next 8).
    #[inline(always)]
    pub(super) fn pixel_and_weight(&self) -> (usize, i32) {
        pixel_and_weight(self.sum)
    }

    /// The position, Q8.24 modulo 2^32.
    #[inline(always)]
    pub(super) fn q24(&self) -> u32 {
        self.sum
    }

    /// The position and its first and second differences (Q8.24 modulo
    /// 2^32), from which a vector of columns steps on.
    #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
    #[inline(always)]
    pub(super) fn differences(&self) -> (u32, u32, u32) {
        (self.sum, self.difference, self.second)
    }

    /// On to the next column: a bent row's difference changes too.
    #[inline(always)]
    fn advance<const BENT: bool>(&mut self) {
        self.sum = self.sum.wrapping_add(self.difference);
        if BENT {
            self.difference = self.difference.wrapping_add(self.second);
        }
    }
}

/// Whole pixels and the bilinear weight of a Q8.24 position (within 0..256 px).
#[inline(always)]
pub(super) fn pixel_and_weight(q24: u32) -> (usize, i32) {
    ((q24 >> 24) as usize, ((q24 >> 16) & 0xFF) as i32)
}

/// A Q16 offset as a Q8.24 one, to add (wrapping) to [`Coordinate::q24`].
#[inline(always)]
pub(super) fn offset_q24(offset: i32) -> u32 {
    (offset as u32) << (BEND_FRAC - FRAC)
}

/// A row's keyframe positions, column by column ([`RowWarp::positions`]).
pub(super) struct Positions {
    i: Coordinate,
    j: Coordinate,
}

impl Positions {
    /// This column's position; then on to the next column (`BENT`: the
    /// row is bent; a straight one skips the second differences, zero).
    #[inline(always)]
    pub(super) fn take<const BENT: bool>(&mut self) -> (Coordinate, Coordinate) {
        let position = (self.i, self.j);
        self.i.advance::<BENT>();
        self.j.advance::<BENT>();
        position
    }
}

/// Usable columns of a row as runs `[start, end)`: a translation row has
/// one, a yawed row may have several (runs are a column apart at least).
pub(super) type Runs = heapless::Vec<(u16, u16), { MAX_GRID_SIDE / 2 + 1 }>;

/// Runs kept per row for a cell row's hypotheses pass: most rows have one
/// or two; a row with more is worked out again.
const KEPT_RUNS: usize = 4;

/// A row's usable runs, kept when few ([`KEPT_RUNS`]): a cell row's whole
/// [`Runs`] would cost ~8 KB of RAM.
#[derive(Clone, Copy)]
pub(super) struct KeptRuns {
    runs: [(u16, u16); KEPT_RUNS],
    /// The row's runs; above [`KEPT_RUNS`]: not kept.
    count: usize,
}

impl KeptRuns {
    pub(super) const NONE: KeptRuns = KeptRuns { runs: [(0, 0); KEPT_RUNS], count: usize::MAX };

    pub(super) fn keep(runs: &Runs) -> KeptRuns {
        let mut kept = KeptRuns { count: runs.len(), ..KeptRuns::NONE };
        if let Some(head) = runs.get(..KEPT_RUNS.min(runs.len())) {
            kept.runs[..head.len()].copy_from_slice(head);
        }
        kept
    }

    /// Sets `runs` to the kept ones; false (`runs` untouched) if not kept.
    pub(super) fn restore(&self, runs: &mut Runs) -> bool {
        if self.count > KEPT_RUNS {
            return false;
        }
        runs.clear();
        // Never full: KEPT_RUNS is below the capacity.
        let _ = runs.extend_from_slice(&self.runs[..self.count]);
        true
    }
}

/// The part of `run` within `lo..hi`.
#[inline(always)]
pub(super) fn clip(run: (u16, u16), lo: usize, hi: usize) -> Range<usize> {
    usize::from(run.0).max(lo)..usize::from(run.1).min(hi)
}

/// Which columns the camera sees, per grid row: in the current frame, and
/// in the keyframe all around a search neighbourhood.
pub(super) struct Coverage {
    /// Current-frame valid columns per row.
    current: [(u16, u16); MAX_GRID_SIDE],
    /// Valid reference columns for a sample centred on row j' (all taps in view), per row.
    reference: [(u16, u16); MAX_GRID_SIDE],
}

impl Coverage {
    pub(super) const EMPTY: Coverage =
        Coverage { current: [(0, 0); MAX_GRID_SIDE], reference: [(0, 0); MAX_GRID_SIDE] };

    /// Fills in place (4 KB) from the remap table's valid columns.
    pub(super) fn init(&mut self, grid: &KgGrid, table: &RemapTable, search_radius: usize) {
        self.current = [(0, 0); MAX_GRID_SIDE];
        for (j, slot) in self.current.iter_mut().enumerate().take(grid.height()) {
            let range = table.valid_columns(j);
            *slot = (range.start as u16, range.end as u16);
        }
        // A reference sample around row j' touches rows j'-S-1 ..= j'+S+2 and
        // columns i'-S-1 ..= i'+S+2: keep the columns where all of them are in view.
        let reach = search_radius + 1;
        self.reference = [(0, 0); MAX_GRID_SIDE];
        for (j, slot) in self.reference.iter_mut().enumerate().take(grid.height()) {
            let (mut lo, mut hi) = (0usize, grid.width());
            for r in j as isize - reach as isize..=(j + reach + 1) as isize {
                let range = if r < 0 || r as usize >= grid.height() { 0..0 } else { table.valid_columns(r as usize) };
                lo = lo.max(range.start);
                hi = hi.min(range.end);
            }
            let (lo, hi) = (lo + reach, hi.saturating_sub(reach + 1));
            *slot = if hi > lo { (lo as u16, hi as u16) } else { (0, 0) };
        }
    }

    /// Every column of every row seen (the tests' synthetic images).
    #[cfg(test)]
    pub(super) fn full(grid: &KgGrid) -> Coverage {
        let mut rows = [(0, 0); MAX_GRID_SIDE];
        rows[..grid.height()].fill((0, grid.width() as u16));
        Coverage { current: rows, reference: rows }
    }

    /// Seen columns `(first, end)` of the first `rows` current rows.
    pub(super) fn current_rows(&self, rows: usize) -> &[(u16, u16)] {
        &self.current[..rows]
    }

    /// Columns of current row `j` that the camera sees, or None.
    pub(super) fn seen(&self, j: usize) -> Option<Range<usize>> {
        let (lo, hi) = self.current[j];
        (hi > lo).then_some(usize::from(lo)..usize::from(hi))
    }

    /// [`Self::seen`] of any row index: None beyond the grid's rows.
    pub(super) fn seen_within(&self, j: usize, grid: &KgGrid) -> Option<Range<usize>> {
        (j < grid.height()).then(|| self.seen(j)).flatten()
    }

    /// Whether current column `c` under `warp` has its whole search
    /// neighbourhood in the keyframe's view.
    #[cfg(test)]
    pub(super) fn usable(&self, warp: RowWarp, c: usize, grid: &KgGrid) -> bool {
        self.usable_at(warp.at(c), grid)
    }

    /// [`Self::usable`] of the column `warp` puts at (`i_ref`, `j_ref`).
    #[inline(always)]
    fn usable_at(&self, (i_ref, j_ref): (i32, i32), grid: &KgGrid) -> bool {
        let rows_limit = (grid.height() as i32 - 1) << FRAC;
        let (i0, j0) = (i_ref >> FRAC, j_ref >> FRAC);
        j_ref >= 0 && j_ref < rows_limit && i0 >= 0 && (i0 as usize) < grid.width() && {
            let (lo, hi) = self.reference[j0 as usize];
            (i0 as usize) >= usize::from(lo) && (i0 as usize) < usize::from(hi)
        }
    }

    /// Sets `runs` to the usable columns among `seen` (see [`Self::usable`]).
    /// (Filled in place: returned, the 0.5 KB would be copied every row.)
    pub(super) fn usable_runs(&self, warp: RowWarp, seen: Range<usize>, grid: &KgGrid, runs: &mut Runs) {
        runs.clear();
        if warp.is_translation() {
            // One keyframe row: its reference columns, moved by the shift.
            let rows_limit = (grid.height() as i32 - 1) << FRAC;
            if warp.j_start >= 0 && warp.j_start < rows_limit {
                let (lo, hi) = self.reference[(warp.j_start >> FRAC) as usize];
                let i0 = i64::from(warp.i_start >> FRAC);
                let first = (i64::from(lo) - i0).max(seen.start as i64);
                let end = (i64::from(hi) - i0).min(seen.end as i64);
                if end > first {
                    let _ = runs.push((first as u16, end as u16));
                }
            }
            return;
        }
        if self.straight_runs(warp, seen.clone(), grid, runs) || self.bent_runs(warp, seen.clone(), grid, runs) {
            return;
        }
        let mut open: Option<usize> = None;
        for c in seen.start..=seen.end {
            let usable = c < seen.end && self.usable_at(warp.at(c), grid);
            match (usable, open) {
                (true, None) => open = Some(c),
                (false, Some(first)) => {
                    let _ = runs.push((first as u16, c as u16));
                    open = None;
                }
                _ => {}
            }
        }
    }

    /// [`Self::usable_runs`] of a straight row (no bend) whose columns step
    /// right and stay well inside the fixed point's range (any sane warp):
    /// the usable columns solved for in each keyframe row the line crosses
    /// (a few), instead of tested one by one. Adds to `runs` (cleared);
    /// false, `runs` untouched, for any other row.
    fn straight_runs(&self, warp: RowWarp, seen: Range<usize>, grid: &KgGrid, runs: &mut Runs) -> bool {
        if warp.is_bent() || warp.i_step <= 0 {
            return false;
        }
        if seen.is_empty() {
            return true;
        }
        // The start, the step and the positions of the first and last seen
        // columns, exactly. Within +-2^30 no position wraps, and every
        // difference below fits an i32 (grid positions are below 2^26).
        const SANE: i64 = 1 << 30;
        let sane = |start: i32, step: i32| straight_within(start, step, seen.start, seen.end - 1, SANE);
        if !sane(warp.i_start, warp.i_step) || !sane(warp.j_start, warp.j_step) {
            return false;
        }
        let last_row = grid.height() as i32 - 1;
        let mut c = seen.start;
        while c < seen.end {
            let (_, j) = warp.at(c);
            let j0 = j >> FRAC;
            // The first column past this keyframe row.
            let next = match warp.j_step.signum() {
                1 => c + ceil_div(((j0 + 1) << FRAC) - j, warp.j_step) as usize,
                -1 => c + ((j - (j0 << FRAC)) / -warp.j_step) as usize + 1,
                _ => seen.end,
            }
            .min(seen.end);
            // In that row the usable columns are one run: lo <= i >> FRAC < hi.
            if (0..last_row).contains(&j0) {
                let (lo, hi) = self.reference[j0 as usize];
                let column = |i: u16| ceil_div((i32::from(i) << FRAC) - warp.i_start, warp.i_step).max(0) as usize;
                let (from, to) = (column(lo).max(c), column(hi).min(next));
                if from < to {
                    extend_runs(runs, from, to);
                }
            }
            c = next;
        }
        true
    }

    /// [`Self::usable_runs`] of a bent row, the whole row at once where
    /// that decides it, else a chunk of columns at a time: a
    /// chunk whose positions all lie, by the bound below, in one keyframe
    /// row's reference columns is usable whole, one whose positions all lie
    /// outside them (or outside the rows) unusable whole, and only the
    /// others are tested column by column. Adds to `runs` (cleared); false,
    /// `runs` untouched, if the row's positions could wrap.
    fn bent_runs(&self, warp: RowWarp, seen: Range<usize>, grid: &KgGrid, runs: &mut Runs) -> bool {
        const CHUNK: usize = 32;
        const SANE: i64 = 1 << 30;
        if !warp.is_bent() {
            return false;
        }
        if seen.is_empty() {
            return true;
        }
        // The quadratic part leaves its chord by at most |bend| (n / 2)^2 over n
        // columns (in bend units), and the rounding down by under 1 more.
        let apart = |bend: i32, n: usize| ((i64::from(bend).abs() * (n * n) as i64) >> (BEND_FRAC - FRAC + 2)) + 2;
        // The range of a coordinate between two positions on its chord.
        let bounds = |a: i64, b: i64, margin: i64| (a.min(b) - margin, a.max(b) + margin);
        // The range of a coordinate over the columns first..=last.
        let range = |start: i32, step: i32, bend: i32, first: usize, last: usize| {
            bounds(unwrapped(start, step, bend, first), unwrapped(start, step, bend, last), apart(bend, last - first))
        };
        let whole = (range(warp.i_start, warp.i_step, warp.i_bend, seen.start, seen.end - 1), range(warp.j_start, warp.j_step, warp.j_bend, seen.start, seen.end - 1));
        if [whole.0 .0, whole.0 .1, whole.1 .0, whole.1 .1].iter().any(|v| v.abs() >= SANE) {
            return false;
        }
        // A steady tilt's row mostly lies along one keyframe row: then the
        // whole row is decided at once, as one chunk.
        if self.decide_span(warp, seen.clone(), whole, grid, runs) {
            return true;
        }
        // Each chunk's chord runs from its first column to the next chunk's
        // (its own last at the end), so each position is worked out once;
        // the margin of a whole chunk's span bounds every chunk's.
        let at = |c: usize| (unwrapped(warp.i_start, warp.i_step, warp.i_bend, c), unwrapped(warp.j_start, warp.j_step, warp.j_bend, c));
        let margins = (apart(warp.i_bend, CHUNK), apart(warp.j_bend, CHUNK));
        let mut first = seen.start;
        let mut from = at(first);
        while first < seen.end {
            let end = (first + CHUNK).min(seen.end);
            let to = at(if end < seen.end { end } else { end - 1 });
            let span = (bounds(from.0, to.0, margins.0), bounds(from.1, to.1, margins.1));
            from = to;
            if !self.decide_span(warp, first..end, span, grid, runs) {
                for c in first..end {
                    if self.usable_at(warp.at(c), grid) {
                        extend_runs(runs, c, c + 1);
                    }
                }
            }
            first = end;
        }
        true
    }

    /// Adds to `runs` the usable columns among `columns` of a bent row whose
    /// positions there lie within `(i_range, j_range)` (Q16, bounds on both
    /// sides), and returns true; where that bound leaves them mixed, adds
    /// nothing and returns false (the caller tests them one by one).
    fn decide_span(&self, warp: RowWarp, columns: Range<usize>, (i_range, j_range): ((i64, i64), (i64, i64)), grid: &KgGrid, runs: &mut Runs) -> bool {
        let (first, end) = (columns.start, columns.end);
        let rows_limit = i64::from(grid.height() as i32 - 1) << FRAC;
        let outside_rows = j_range.1 < 0 || j_range.0 >= rows_limit;
        let within_rows = j_range.0 >= 0 && j_range.1 < rows_limit;
        let one_row = within_rows && j_range.0 >> FRAC == j_range.1 >> FRAC;
        let (lo, hi) = if one_row { self.reference[(j_range.0 >> FRAC) as usize] } else { (0, 0) };
        let (lo, hi) = (i64::from(lo) << FRAC, i64::from(hi) << FRAC);
        // A span across a few keyframe rows is usable whole where its
        // columns lie in the reference columns of all of them (one row:
        // its own, tested first, the common case).
        let in_all_rows = || {
            let rows = (j_range.0 >> FRAC) as usize..=(j_range.1 >> FRAC) as usize;
            let (lo, hi) = self.reference[rows].iter().fold((0, u16::MAX), |(lo, hi), &(l, h)| (lo.max(l), hi.min(h)));
            i_range.0 >= i64::from(lo) << FRAC && i_range.1 < i64::from(hi) << FRAC
        };
        if one_row && i_range.0 >= lo && i_range.1 < hi || !one_row && within_rows && (j_range.1 - j_range.0) >> FRAC < 4 && in_all_rows() {
            extend_runs(runs, first, end);
        } else if one_row && !(i_range.1 < lo || i_range.0 >= hi) && rising(warp, end) {
            // One keyframe row and i rising with c: its usable columns
            // are the run where lo <= i >> FRAC < hi, found by bisection.
            let first_at_least = |limit: i64| {
                let (mut low, mut high) = (first, end);
                while low < high {
                    let middle = (low + high) / 2;
                    if i64::from(warp.at(middle).0 >> FRAC) << FRAC >= limit {
                        high = middle;
                    } else {
                        low = middle + 1;
                    }
                }
                low
            };
            let (from, to) = (first_at_least(lo), first_at_least(hi));
            if from < to {
                extend_runs(runs, from, to);
            }
        } else if !(outside_rows || one_row && (i_range.1 < lo || i_range.0 >= hi)) {
            return false;
        }
        true
    }
}

/// Whether a bent row's i rises from each column to the next up to column
/// `end`: its step outweighs the bend's change of slope there, with room
/// for the rounding down of both parts.
fn rising(warp: RowWarp, end: usize) -> bool {
    let bend_slope = (i64::from(warp.i_bend).abs() * (2 * end as i64 + 1)) >> (BEND_FRAC - FRAC);
    i64::from(warp.i_step) - bend_slope > 2
}

/// Adds the usable columns `from..to` to `runs`, joining the last run when
/// it ends at `from` (runs are kept a column apart at least).
fn extend_runs(runs: &mut Runs, from: usize, to: usize) {
    match runs.last_mut() {
        Some(run) if usize::from(run.1) == from => run.1 = to as u16,
        _ => {
            let _ = runs.push((from as u16, to as u16));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{GroundMap, Motion};

    /// The usable columns tested one by one: [`Coverage::usable_runs`]'s definition.
    fn runs_by_column(coverage: &Coverage, warp: RowWarp, seen: Range<usize>, grid: &KgGrid) -> std::vec::Vec<(u16, u16)> {
        let mut runs = std::vec::Vec::new();
        let mut open = None;
        for c in seen.start..=seen.end {
            match (c < seen.end && coverage.usable(warp, c, grid), open) {
                (true, None) => open = Some(c),
                (false, Some(first)) => {
                    runs.push((first as u16, c as u16));
                    open = None;
                }
                _ => {}
            }
        }
        runs
    }

    /// Straight rows solved per keyframe row, and bent rows a chunk at a
    /// time, give the runs the column-by-column test gives: yawed either
    /// way, bent either way, shifted past every edge, over keyframe rows
    /// whose reference columns vary (and some that have none).
    #[test]
    fn solved_runs_equal_the_column_test() {
        let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 255 };
        let mut coverage = Coverage::full(&grid);
        let mut seed = 0x2545_F491u32;
        let mut next = move |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        for (j, slot) in coverage.reference.iter_mut().enumerate().take(grid.height()) {
            let lo = next(40) as u16;
            *slot = if j % 17 == 5 { (0, 0) } else { (lo, (lo + 60 + next(50) as u16).min(141)) };
        }
        let mut checked = 0;
        for _ in 0..20_000 {
            let yaw = (next(2001) as f64 - 1000.0) * 1e-4;
            let warp = RowWarp {
                i_start: (next(200 << FRAC) as i32) - (30 << FRAC),
                i_step: to_q16(libm::cos(yaw)),
                i_bend: 0,
                j_start: (next(300 << FRAC) as i32) - (20 << FRAC),
                j_step: to_q16(libm::sin(yaw)),
                j_bend: 0,
            };
            let start = next(60) as usize;
            let seen = start..(start + next(90) as usize).min(141);
            let mut runs = Runs::new();
            assert!(coverage.straight_runs(warp, seen.clone(), &grid, &mut runs));
            assert_eq!(runs.as_slice(), runs_by_column(&coverage, warp, seen.clone(), &grid).as_slice(), "{warp:?} {seen:?}");
            checked += usize::from(!runs.is_empty());
            // The same row bent (a roll of up to ~2 degrees bends by ~1/2000 px per column squared).
            let mut bend = |range: u32| next(2 * range + 1) as i32 - range as i32;
            let bent = RowWarp { i_bend: bend(1 << 13), j_bend: bend(1 << 13), ..warp };
            if bent.is_bent() {
                let mut runs = Runs::new();
                assert!(coverage.bent_runs(bent, seen.clone(), &grid, &mut runs));
                assert_eq!(runs.as_slice(), runs_by_column(&coverage, bent, seen.clone(), &grid).as_slice(), "{bent:?} {seen:?}");
            }
        }
        assert!(checked > 5_000, "too few rows had usable columns: {checked}");
    }

    /// The level rows' starts worked out in fixed point are the f64 sums'
    /// rounding: random motions, rows beyond the grid's edges, and sums
    /// made to fall on a half Q16 unit and either side of it.
    #[test]
    fn fixed_point_rows_equal_the_f64_sums() {
        let grid = KgGrid { mm_per_px: 2.5, x_left_mm: -200.0, z_far_mm: 1000.0, width: 159, height: 247 };
        let mut seed = 0x0F1E_2D3Cu32;
        let mut next = move |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        let by_f64 = |warp: &Warp, r: isize| (to_q16(warp.origin.0 + warp.row.0 * r as f64), to_q16(warp.origin.1 + warp.row.1 * r as f64));
        let mut near_half = 0;
        for round in 0..2_000 {
            let planar = Motion { tx_mm: f64::from(next(2001)) * 0.1 - 100.0, tz_mm: f64::from(next(4001)) * 0.1 - 100.0, dyaw_deg: f64::from(next(2001)) * 0.005 - 5.0 };
            let mut warp = Warp::new(&grid, &GroundMotion { planar, attitude: Attitude::default() }, &Attitude::default(), 300.0);
            if round % 4 == 0 {
                // Row 3's i start on a half Q16 unit, or a hair either side.
                let half = (f64::from(next(100_000)) + 0.5) / 65536.0;
                warp.origin.0 = half - warp.row.0 * 3.0 + f64::from(next(3) as i32 - 1) * 1e-13;
                warp.fine = fine_rows(warp.origin, warp.row);
                let [(origin, row), _] = warp.fine.unwrap();
                near_half += usize::from(((origin + 3 * row) as u32).abs_diff(1 << (FINE_BITS - 1)) <= FINE_MARGIN);
            }
            assert!(warp.fine.is_some());
            for r in -10..grid.height() as isize + 10 {
                let row = warp.row_at(r);
                assert_eq!((row.i_start, row.j_start), by_f64(&warp, r), "{planar:?} row {r}");
            }
        }
        assert!(near_half > 300, "too few sums near a half unit: {near_half}");
    }

    /// Every column of every row lands where the exact map puts it: a roll
    /// bends the rows (projective spacing), which the quadratic follows.
    #[test]
    fn rows_follow_the_exact_map_under_pitch_and_roll() {
        let grid = KgGrid { mm_per_px: 5.75, x_left_mm: -402.5, z_far_mm: 1850.0, width: 141, height: 255 };
        for (pitch_deg, roll_deg) in [(0.0, 1.1), (0.0, -1.1), (0.5, 0.8), (-1.5, 2.0), (1.0, 0.0)] {
            let motion = GroundMotion { planar: Motion { tx_mm: 20.0, tz_mm: 110.0, dyaw_deg: 1.5 }, attitude: Attitude { pitch_deg, roll_deg } };
            let warp = Warp::new(&grid, &motion, &Attitude::default(), 400.0);
            let exact = GroundMap::new(&motion, 400.0);
            let mut worst: f64 = 0.0;
            for j in (0..grid.height()).step_by(7) {
                let row = warp.row(j);
                for c in 0..grid.width() {
                    let (x, z) = grid.pixel_to_ground(c as f64, j as f64);
                    let (xk, zk) = exact.to_keyframe(x, z).unwrap();
                    let (i_want, j_want) = grid.ground_to_pixel(xk, zk);
                    let (i, jj) = row.at(c);
                    let scale = f64::from(1u32 << FRAC);
                    worst = worst.max(libm::fabs(f64::from(i) / scale - i_want)).max(libm::fabs(f64::from(jj) / scale - j_want));
                }
            }
            // A chord through the row's ends was off by 3 px at pitch -1.5, roll 2.
            assert!(worst < 1.0 / 16.0, "pitch {pitch_deg} roll {roll_deg}: {worst} px off");
        }
    }

    /// Rows continued from the row above stay within 1/64 px of their own
    /// lines at every column, however many follow one another; a tilted
    /// body's rows mostly continue (three in four at least: the band rolls), a turning one's never
    /// (a yaw turns the rows: one keyframe row down is not the next row).
    #[test]
    fn continued_rows_stay_within_a_64th_of_their_own() {
        let grid = KgGrid { mm_per_px: 5.75, x_left_mm: -402.5, z_far_mm: 1850.0, width: 141, height: 255 };
        for (dyaw_deg, pitch_deg, roll_deg, continue_most) in [(0.0, 0.02, -0.03, true), (0.0, 0.0, 0.0, true), (0.0, 1.0, 1.5, false), (2.0, 0.02, 0.0, false)] {
            let motion = GroundMotion { planar: Motion { tx_mm: 5.0, tz_mm: 90.0, dyaw_deg }, attitude: Attitude { pitch_deg, roll_deg } };
            let warp = Warp::new(&grid, &motion, &Attitude { pitch_deg: 0.01, roll_deg: 0.02 }, 400.0);
            let (mut line, mut continued) = (warp.row(0), 0);
            for j in 1..grid.height() {
                let (next, own) = (warp.row_after(j, line), warp.row(j));
                continued += usize::from(next == line.moved(0, 1 << FRAC));
                for c in 0..grid.width() {
                    let ((i, jj), (i_own, j_own)) = (next.at(c), own.at(c));
                    // The bend's rounding down adds a unit each way.
                    assert!(i64::from(i.abs_diff(i_own)).max(i64::from(jj.abs_diff(j_own))) <= CONTINUED_Q16 + 2, "yaw {dyaw_deg} pitch {pitch_deg} roll {roll_deg}: row {j} column {c}");
                }
                line = next;
            }
            let rows = grid.height() - 1;
            if continue_most {
                assert!(continued * 4 >= rows * 3, "yaw {dyaw_deg} pitch {pitch_deg} roll {roll_deg}: {continued} of {rows} rows continued");
            } else if dyaw_deg != 0.0 {
                assert_eq!(continued, 0, "a turning row continued");
            }
        }
    }
}

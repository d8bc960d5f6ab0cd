//! The keyframe read along warped lines: bilinear samples, one line at a
//! time or a stack of lines a keyframe row apart (a search band).

use super::Keyframe;
use crate::gpa::kernels;
use crate::gpa::band::BAND_WIDTH;
use crate::gpa::warp::{ceil_div, offset_q24, straight_within, unwrapped, Coordinate, RowWarp, BEND_FRAC, FRAC};
use crate::limits::MAX_SEARCH_RADIUS;
use core::ops::Range;

/// A band row's padding before column 0 (the K shifts' reach, as
/// [`crate::gpa::band`] pads it).
const PAD: usize = MAX_SEARCH_RADIUS;

mod offsets;
#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
mod stack;
pub(in crate::gpa) use offsets::LinePositions;

impl Keyframe<'_> {
    /// Whether the 2x2 neighbourhood of (i, j) Q16.16 lies in the grid
    /// (the per-pixel reference's test and the wrapping lines').
    #[inline(always)]
    pub(in crate::gpa) fn inside(&self, i: i32, j: i32) -> bool {
        let rows_limit = (self.height as i32 - 1) << FRAC;
        i >= 0 && (i >> FRAC) + 1 < self.width as i32 && j >= 0 && j < rows_limit
    }

    /// Bilinear sample at (i, j) Q16.16; the caller checked [`Self::inside`].
    /// The definition every line path reproduces.
    #[inline(always)]
    pub(in crate::gpa) fn sample(&self, i: i32, j: i32) -> u8 {
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
    pub(in crate::gpa) fn sample_line(&self, line: RowWarp, columns: Range<usize>, out: &mut [u8]) -> Range<usize> {
        if columns.is_empty() {
            return columns;
        }
        if line.is_translation() {
            // Pure translation (no yaw, the common case): one pair of
            // keyframe rows and constant weights along the whole line.
            let rows_limit = (self.height as i32 - 1) << FRAC;
            let i0 = i64::from(line.i_start >> FRAC);
            let (lo, hi) = if line.j_start >= 0 && line.j_start < rows_limit {
                // A line wholly left of the grid (a wild warp) starts past
                // the columns' end: none inside, never a reversed range.
                let lo = (columns.start as i64).max(-i0).min(columns.end as i64);
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
                kernels::bilinear_line(upper, lower, wx, wy, &mut out[lo..hi]);
            }
            return lo..hi;
        }
        match self.inside_span(line, columns.clone()) {
            Span::Wraps => self.sample_line_checked(line, columns, out),
            Span::Inside(span) => {
                out[columns.start..span.start].fill(0);
                out[span.end..columns.end].fill(0);
                self.sample_span(line, span.clone(), out);
                span
            }
        }
    }

    /// Samples the lines `line`, `line` one keyframe row down, ... into
    /// consecutive band rows `rows` (line k at `rows[k][PAD + c]` for the
    /// `columns` c): each exactly as [`Self::sample_line`]. The lines share
    /// their columns' positions and weights, and line k's lower pixels are
    /// line k + 1's upper ones, so where all of them lie inside the grid
    /// one position and one horizontal blend per keyframe row serve the
    /// whole stack, written a band row apart from one pointer.
    pub(in crate::gpa) fn sample_lines(&self, line: RowWarp, columns: Range<usize>, rows: &mut [[u8; BAND_WIDTH]]) {
        let one_row_down = |k: usize| line.moved(0, (k as i32) << FRAC);
        let count = rows.len();
        let mut spans: [Range<usize>; MAX_STACK] = Default::default();
        let mut common = columns.clone();
        // The lines differ only by whole rows: where all of them stay
        // within the grid's rows at every column, only the columns limit
        // them, alike, and the first line's span is every line's.
        let rows_inside = !columns.is_empty() && self.rows_within(line, columns.clone(), count);
        let stackable = !line.is_translation()
            && !columns.is_empty()
            && count <= MAX_STACK
            && PAD + columns.end <= BAND_WIDTH
            && (0..count).all(|k| match if rows_inside && k > 0 { Span::Inside(spans[0].clone()) } else { self.inside_span(one_row_down(k), columns.clone()) } {
                Span::Inside(span) => {
                    common = common.start.max(span.start)..common.end.min(span.end);
                    spans[k] = span;
                    true
                }
                Span::Wraps => false,
            });
        if !stackable || common.is_empty() {
            for (k, row) in rows.iter_mut().enumerate() {
                self.sample_line(one_row_down(k), columns.clone(), &mut row[PAD..]);
            }
            return;
        }
        // Most stacks lie wholly inside the grid: their ends are empty, and
        // skipped here (an empty fill still calls memclr).
        for (k, row) in rows.iter_mut().enumerate() {
            let (span, out) = (&spans[k], &mut row[PAD..]);
            if columns.start < span.start {
                out[columns.start..span.start].fill(0);
            }
            if span.end < columns.end {
                out[span.end..columns.end].fill(0);
            }
            self.sample_span(one_row_down(k), span.start..common.start, out);
            self.sample_span(one_row_down(k), common.end..span.end, out);
        }
        match count {
            1 => self.sample_stack::<1>(line, common, rows),
            3 => self.sample_stack::<3>(line, common, rows),
            5 => self.sample_stack::<5>(line, common, rows),
            7 => self.sample_stack::<7>(line, common, rows),
            _ => {
                for (k, row) in rows.iter_mut().enumerate() {
                    self.sample_span(one_row_down(k), common.clone(), &mut row[PAD..]);
                }
            }
        }
    }

    /// The columns of a yawed or bent `line` whose 2x2 neighbourhood lies
    /// inside the grid, as one interval; or `Wraps`. Each coordinate is
    /// linear (or, bent, quadratic) in c: when it stays in i32 at both ends
    /// nothing wraps, and unless a bent coordinate turns outside the grid
    /// between the columns found inside from both ends, they are one
    /// interval and no pixel in it needs a test.
    fn inside_span(&self, line: RowWarp, columns: Range<usize>) -> Span {
        if !columns.is_empty() && self.surely_inside(line, columns.clone()) {
            return Span::Inside(columns);
        }
        let (i_limit, j_limit) = (self.columns_limit(), self.rows_limit());
        let exact = |c: usize| (unwrapped(line.i_start, line.i_step, line.i_bend, c), unwrapped(line.j_start, line.j_step, line.j_bend, c));
        let fits = |(i, j): (i64, i64)| i32::try_from(i).is_ok() && i32::try_from(j).is_ok();
        if !(fits(exact(columns.start)) && fits(exact(columns.end - 1))) {
            return Span::Wraps;
        }
        let inside = |c: usize| {
            let (i, j) = exact(c);
            (0..i64::from(i_limit)).contains(&i) && (0..i64::from(j_limit)).contains(&j)
        };
        if !line.is_bent() {
            if let Some(span) = straight_span(line, columns.clone(), (i_limit, j_limit)) {
                return Span::Inside(span);
            }
        }
        // Where to look: both ends inside (most lines) settle it; else the
        // columns certainly inside and possibly inside, from the straight
        // lines that bound a bent one (all of them when those cannot be
        // solved), and only the columns between are tested.
        let (surely, maybe) = if inside(columns.start) && inside(columns.end - 1) {
            (columns.clone(), columns.clone())
        } else {
            bent_bounds(line, columns.clone(), (i_limit, j_limit)).unwrap_or((columns.start..columns.start, columns.clone()))
        };
        let first = match surely.is_empty() {
            true => maybe.clone().find(|&c| inside(c)),
            false => (maybe.start..surely.start).find(|&c| inside(c)).or(Some(surely.start)),
        };
        let Some(first) = first else {
            return Span::Inside(columns.start..columns.start);
        };
        let floor = if surely.is_empty() { first + 1 } else { surely.end };
        let end = (floor..maybe.end).rev().find(|&c| inside(c)).map_or(floor, |c| c + 1);
        if line.is_bent() {
            // A quadratic's turning point is where it could leave the grid.
            let leaves = |step: i32, bend: i32| turning_column(step, bend, first, end - 1).is_some_and(|c| !inside(c) || !inside(c + 1));
            if leaves(line.i_step, line.i_bend) || leaves(line.j_step, line.j_bend) {
                return Span::Wraps;
            }
        }
        Span::Inside(first..end)
    }

    /// Whether `count` lines, `line` and each a row below the last, lie
    /// within the grid's rows at every one of `columns` (not empty).
    fn rows_within(&self, line: RowWarp, columns: Range<usize>, count: usize) -> bool {
        let (least, most) = coordinate_bounds(line.j_start, line.j_step, line.j_bend, columns);
        least >= 0 && most + ((count.max(1) as i64 - 1) << FRAC) < i64::from(self.rows_limit())
    }

    /// Whether `line` lies inside the grid at every one of `columns` (not
    /// empty), by the bounds of its coordinates.
    fn surely_inside(&self, line: RowWarp, columns: Range<usize>) -> bool {
        let (i_least, i_most) = coordinate_bounds(line.i_start, line.i_step, line.i_bend, columns.clone());
        i_least >= 0 && i_most < i64::from(self.columns_limit()) && self.rows_within(line, columns, 1)
    }

    /// Calls `visit(t, (i, j))` for the columns `span.start + t` of `span`
    /// in turn, their positions stepped as [`RowWarp::positions`] (every
    /// one inside the grid: whole pixels below 256).
    #[inline(always)]
    fn for_positions(line: RowWarp, span: Range<usize>, mut visit: impl FnMut(usize, (Coordinate, Coordinate))) {
        let mut positions = line.positions(span.start);
        if line.is_bent() {
            for t in 0..span.len() {
                visit(t, positions.take::<true>());
            }
        } else {
            for t in 0..span.len() {
                visit(t, positions.take::<false>());
            }
        }
    }

    /// Samples `line` at the columns of `span`, which [`Self::inside_span`]
    /// found inside the grid, into `out[c]` (on an x86_64 with AVX2 as a
    /// stack of one line, eight columns at a time).
    fn sample_span(&self, line: RowWarp, span: Range<usize>, out: &mut [u8]) {
        if span.is_empty() {
            return;
        }
        #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
        if crate::kernels::avx2() {
            let image: &[u8] = &self.images[self.key_half][..self.height * self.width];
            // A stack of one line: its sample is `blend`'s.
            // SAFETY: the CPU has AVX2; every position of the span lies
            // inside the grid (see below), and `out` holds its columns.
            unsafe { stack::avx2::sample_columns::<1>(image, self.width, line, span.start, span.len(), out[span.clone()].as_mut_ptr()) };
            return;
        }
        if !line.is_bent() {
            self.sample_straight_span(line, span, out);
            return;
        }
        let image: &[u8] = &self.images[self.key_half][..self.height * self.width];
        let width = self.width;
        let out = &mut out[span.clone()];
        Self::for_positions(line, span, |t, (i, j)| {
            let ((i0, wx), (j0, wy)) = (i.pixel_and_weight(), j.pixel_and_weight());
            let index = j0 * width + i0;
            // SAFETY: every position of the span lies in 0..(width - 1) << 16
            // by 0..(height - 1) << 16 (both ends do, a linear line does not
            // wrap and a bent one does not turn outside), so the row index
            // is at most height - 2, the column at most width - 2, and
            // index + width + 1 < height * width = image.len().
            let (p00, p01, p10, p11) = unsafe {
                (
                    *image.get_unchecked(index),
                    *image.get_unchecked(index + 1),
                    *image.get_unchecked(index + width),
                    *image.get_unchecked(index + width + 1),
                )
            };
            // SAFETY: `out` holds the span's columns, and t < span.len().
            unsafe { *out.get_unchecked_mut(t) = blend(p00, p01, p10, p11, wx, wy) };
        });
    }

    /// [`Self::sample_span`] of a straight line: a stretch of columns at a
    /// time over which it stays between the same two keyframe rows, by the
    /// kernel (positions stepped as [`RowWarp::positions`]).
    fn sample_straight_span(&self, line: RowWarp, span: Range<usize>, out: &mut [u8]) {
        if span.is_empty() {
            return;
        }
        let (i_step, j_step) = (offset_q24(line.i_step), offset_q24(line.j_step));
        let (i, j) = line.positions(span.start).take::<false>();
        let (mut i, mut j) = (i.q24(), j.q24());
        let step = i64::from(line.j_step) << (BEND_FRAC - FRAC);
        let mut c = span.start;
        while c < span.end {
            // Inside the grid the row is at most height - 2 (j < 255 px):
            // the next row's start fits the Q8.24 position.
            let row = j >> 24;
            let stays = match step.signum() {
                1 => (i64::from((row + 1) << 24) - i64::from(j) + step - 1) / step,
                -1 => (i64::from(j) - i64::from(row << 24)) / -step + 1,
                _ => i64::MAX,
            };
            let n = (span.end - c).min(stays as usize);
            let row = row as usize;
            kernels::bilinear_stretch(self.row(row), self.row(row + 1), (i, i_step), (j, j_step), &mut out[c..c + n]);
            (i, j) = (i.wrapping_add(i_step.wrapping_mul(n as u32)), j.wrapping_add(j_step.wrapping_mul(n as u32)));
            c += n;
        }
    }

    /// [`Self::sample_span`] of the `N` lines `line`, `line` one row down,
    /// ... at once over `span`, where all of them lie inside the grid, into
    /// the band rows `rows` (N of them, `PAD + span.end <= BAND_WIDTH`);
    /// eight columns at a time on an x86_64 with AVX2 (`stack`).
    #[inline(always)]
    fn sample_stack<const N: usize>(&self, line: RowWarp, span: Range<usize>, rows: &mut [[u8; BAND_WIDTH]]) {
        assert!(rows.len() == N && PAD + span.end <= BAND_WIDTH);
        let image: &[u8] = &self.images[self.key_half][..self.height * self.width];
        let width = self.width;
        // SAFETY: within the first band row (checked above).
        let out = unsafe { rows.as_mut_ptr().cast::<u8>().add(PAD + span.start) };
        #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
        if crate::kernels::avx2() {
            // SAFETY: the CPU has AVX2; line N - 1 lies inside the grid at
            // every column of the span (see `sample_span`), and band row
            // k's columns PAD + span are within it (checked above).
            unsafe { stack::avx2::sample_columns::<N>(image, width, line, span.start, span.len(), out) };
            return;
        }
        // The column as `stack::sample_column` (x86_64) makes it, written
        // out: called from there, the M4's loop took ~2,300 more
        // instructions a frame.
        Self::for_positions(line, span, #[inline(always)] |t, (i, j)| {
            let ((i0, wx), (j0, wy)) = (i.pixel_and_weight(), j.pixel_and_weight());
            let index = j0 * width + i0;
            // SAFETY: line N - 1 at this column lies inside the grid (see
            // `sample_span`): its row index j0 + N - 1 is at most height - 2,
            // so index + N * width + 1 < image.len().
            // One pointer walks down the rows (the M4 then loads at an
            // offset from it, with no index to rebuild per row).
            let across = |pixel: *const u8| {
                let (left, right) = unsafe { (*pixel, *pixel.add(1)) };
                (i32::from(left) << 8) + (i32::from(right) - i32::from(left)) * wx
            };
            let mut pixel = unsafe { image.as_ptr().add(index) };
            let mut top = across(pixel);
            for k in 0..N {
                pixel = unsafe { pixel.add(width) };
                let bottom = across(pixel);
                // SAFETY: band row k's column span.start + t (t < span.len()),
                // a fixed stride from the first: one pointer, offsets known
                // when compiled.
                unsafe { *out.add(k * BAND_WIDTH + t) = between(top, bottom, wy) };
                top = bottom;
            }
        });
    }

    /// [`Self::sample_line`] pixel by pixel, for lines whose positions
    /// leave i32 and wrap (far beyond the grid: a degenerate warp).
    fn sample_line_checked(&self, line: RowWarp, columns: Range<usize>, out: &mut [u8]) -> Range<usize> {
        let (mut first, mut end) = (usize::MAX, 0);
        for c in columns.clone() {
            let (i, j) = line.at(c);
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

    /// Q16 column positions below this have their right neighbour in the grid.
    #[inline(always)]
    fn columns_limit(&self) -> i32 {
        (self.width as i32 - 1) << FRAC
    }

    /// Q16 row positions below this have their lower neighbour in the grid.
    #[inline(always)]
    fn rows_limit(&self) -> i32 {
        (self.height as i32 - 1) << FRAC
    }
}

/// The bilinear sample of [`Keyframe::sample`] from its four pixels at
/// weights `wx`, `wy` (of 256): the same integer, with the weights' complements folded
/// (`a (256 - w) + b w = 256 a + (b - a) w` exactly), a multiply less.
#[inline(always)]
fn blend(p00: u8, p01: u8, p10: u8, p11: u8, wx: i32, wy: i32) -> u8 {
    let top = (i32::from(p00) << 8) + (i32::from(p01) - i32::from(p00)) * wx;
    let bottom = (i32::from(p10) << 8) + (i32::from(p11) - i32::from(p10)) * wx;
    between(top, bottom, wy)
}

/// The vertical step of [`blend`]: rows `top` and `bottom` (Q8, already
/// blended across) at weight `wy`.
#[inline(always)]
fn between(top: i32, bottom: i32, wy: i32) -> u8 {
    (((top << 8) + (bottom - top) * wy + (1 << 15)) >> 16) as u8
}

/// Lines [`Keyframe::sample_lines`] samples as one stack: a search band at
/// the largest radius.
const MAX_STACK: usize = crate::gpa::band::MAX_WINDOW;

/// [`Keyframe::inside_span`] of a straight line, solved instead of
/// scanned: the columns where `0 <= i < limits.0` and `0 <= j < limits.1`,
/// each coordinate linear in c, as an interval of `columns` (empty at its
/// start when there is none). None unless the starts, positions, steps and
/// limits lie within +-2^29 (any line a sane warp gives), so that every
/// difference below fits an i32 (the M4 divides those in one instruction).
fn straight_span(line: RowWarp, columns: Range<usize>, limits: (i32, i32)) -> Option<Range<usize>> {
    const SANE: i64 = 1 << 29;
    if columns.is_empty() {
        return None;
    }
    let sane = |start: i32, step: i32| straight_within(start, step, columns.start, columns.end - 1, SANE);
    let limits_sane = i64::from(limits.0) < SANE && i64::from(limits.1) < SANE;
    if columns.end as i64 >= SANE || !limits_sane || !sane(line.i_start, line.i_step) || !sane(line.j_start, line.j_step) {
        return None;
    }
    // The columns c with 0 <= start + c step < limit, as [from, to).
    let solve = |start: i32, step: i32, limit: i32| -> (i32, i32) {
        match step.signum() {
            1 => (ceil_div(-start, step), ceil_div(limit - start, step)),
            -1 => ((start - limit).div_euclid(-step) + 1, start.div_euclid(-step) + 1),
            _ if (0..limit).contains(&start) => (i32::MIN, i32::MAX),
            _ => (0, 0),
        }
    };
    let (i_from, i_to) = solve(line.i_start, line.i_step, limits.0);
    let (j_from, j_to) = solve(line.j_start, line.j_step, limits.1);
    let from = i_from.max(j_from).max(columns.start as i32);
    let to = i_to.min(j_to).min(columns.end as i32);
    Some(if from < to { from as usize..to as usize } else { columns.start..columns.start })
}

/// Bounds of a coordinate (Q16) over `columns` (not empty): its straight
/// part's and its bend's least and most there (each is monotonic in c >= 0).
fn coordinate_bounds(start: i32, step: i32, bend: i32, columns: Range<usize>) -> (i64, i64) {
    let at = |c: usize| (unwrapped(start, step, 0, c), unwrapped(0, 0, bend, c));
    let (first, last) = (at(columns.start), at(columns.end - 1));
    (first.0.min(last.0) + first.1.min(last.1), first.0.max(last.0) + first.1.max(last.1))
}

/// The columns of `columns` where a bent `line` surely lies inside the
/// limits, and those where it may: each coordinate is its straight part
/// plus c^2 bend, which over the columns ranges between its values at
/// their ends (c^2 is monotonic for c >= 0), so two straight lines bound
/// it, solved as [`straight_span`] does. None where those cannot be
/// solved (positions beyond any sane grid).
fn bent_bounds(line: RowWarp, columns: Range<usize>, limits: (i32, i32)) -> Option<(Range<usize>, Range<usize>)> {
    if columns.is_empty() {
        return None;
    }
    let bent_part = |bend: i32| {
        let at = |c: usize| unwrapped(0, 0, bend, c);
        let (a, b) = (at(columns.start), at(columns.end - 1));
        (a.min(b), a.max(b))
    };
    let ((i_low, i_high), (j_low, j_high)) = (bent_part(line.i_bend), bent_part(line.j_bend));
    const SANE: i64 = 1 << 28;
    let sane = |v: i64| v.abs() < SANE;
    if ![i_low, i_high, j_low, j_high, i64::from(limits.0), i64::from(limits.1)].into_iter().all(sane) {
        return None;
    }
    let straight = |i_shift: i64, j_shift: i64| RowWarp {
        i_start: line.i_start.checked_add(i_shift as i32).unwrap_or(i32::MAX),
        j_start: line.j_start.checked_add(j_shift as i32).unwrap_or(i32::MAX),
        i_bend: 0,
        j_bend: 0,
        ..line
    };
    let (i_spread, j_spread) = ((i_high - i_low) as i32, (j_high - j_low) as i32);
    // Surely inside: 0 <= straight + low and straight + high < limit.
    let surely = straight_span(straight(i_low, j_low), columns.clone(), (limits.0 - i_spread, limits.1 - j_spread))?;
    // Maybe inside: 0 <= straight + high and straight + low < limit.
    let maybe = straight_span(straight(i_high, j_high), columns, (limits.0 + i_spread, limits.1 + j_spread))?;
    Some((surely, maybe))
}

/// The whole part of a bent coordinate's turning point t = -step / (2 bend)
/// (columns; `step` Q16, `bend` Q24) when `first < t < last`. In integers
/// (no software f64 on the M4): each comparison multiplied by the
/// denominator, flipped when it is negative.
fn turning_column(step: i32, bend: i32, first: usize, last: usize) -> Option<usize> {
    if bend == 0 {
        return None;
    }
    let (num, den) = (-(i64::from(step) << (BEND_FRAC - FRAC)), 2 * i64::from(bend));
    let (above, below) = if den > 0 { (num > first as i64 * den, num < last as i64 * den) } else { (num < first as i64 * den, num > last as i64 * den) };
    // t > first >= 0: its whole part is |num| / |den|.
    (above && below).then(|| (num.unsigned_abs() / den.unsigned_abs()) as usize)
}

/// Where a line lies inside the grid ([`Keyframe::inside_span`]).
enum Span {
    /// These columns, and no others.
    Inside(Range<usize>),
    /// Its positions leave i32 (a degenerate warp): test pixel by pixel.
    Wraps,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scan's definition: the first and last columns inside, per column.
    fn scanned(line: RowWarp, columns: Range<usize>, (i_limit, j_limit): (i32, i32)) -> Range<usize> {
        let inside = |c: usize| {
            let (i, j) = line.at(c);
            (0..i_limit).contains(&i) && (0..j_limit).contains(&j)
        };
        match columns.clone().find(|&c| inside(c)) {
            None => columns.start..columns.start,
            Some(first) => first..columns.clone().rev().find(|&c| inside(c)).unwrap() + 1,
        }
    }

    /// The turning point's column in integers is the one the same
    /// division in f64 gives (steps and bends of either sign and any size
    /// a warp makes, turning points near whole columns included).
    #[test]
    fn turning_columns_equal_the_f64_division() {
        let mut seed = 0x7E57_0001u32;
        let mut next = move |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        let by_f64 = |step: i32, bend: i32, first: usize, last: usize| {
            (bend != 0)
                .then(|| -(f64::from(step) * (1u64 << (BEND_FRAC - FRAC)) as f64) / (2.0 * f64::from(bend)))
                .filter(|&t| t > first as f64 && t < last as f64)
                .map(|t| t as usize)
        };
        let mut inside = 0;
        for round in 0..100_000 {
            let bend = next(1 << 23) as i32 - (1 << 22);
            // Some steps put the turning point on a whole column exactly.
            let step = if round % 3 == 0 { (-2 * i64::from(bend) * i64::from(next(300)) / (1 << 16)) as i32 } else { next(1 << 18) as i32 - (1 << 17) };
            let first = next(200) as usize;
            let last = first + next(200) as usize;
            let found = turning_column(step, bend, first, last);
            assert_eq!(found, by_f64(step, bend, first, last), "step {step} bend {bend} {first}..{last}");
            inside += usize::from(found.is_some());
        }
        assert!(inside > 1_000, "too few turning points between the columns: {inside}");
    }

    /// Straight lines solved give the scan's interval: yawed either way
    /// (steps of both signs and zero), starting anywhere around the grid.
    #[test]
    fn straight_spans_equal_the_scan() {
        let limits = (140 << FRAC, 254 << FRAC);
        let mut seed = 0x1234_5678u32;
        let mut next = move |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        let mut nonempty = 0;
        for round in 0..20_000 {
            let yaw = (f64::from(next(4001)) - 2000.0) * 1e-3;
            let (sin, cos) = libm::sincos(yaw);
            let line = RowWarp {
                i_start: next(400 << FRAC) as i32 - (130 << FRAC),
                i_step: if round % 7 == 0 { 0 } else { (cos * 65536.0) as i32 },
                i_bend: 0,
                j_start: next(500 << FRAC) as i32 - (120 << FRAC),
                j_step: if round % 5 == 0 { 0 } else { (sin * 65536.0) as i32 },
                j_bend: 0,
            };
            let start = next(100) as usize;
            let columns = start..start + 1 + next(120) as usize;
            let solved = straight_span(line, columns.clone(), limits).expect("a sane line");
            assert_eq!(solved, scanned(line, columns.clone(), limits), "{line:?} {columns:?}");
            nonempty += usize::from(!solved.is_empty());
        }
        assert!(nonempty > 3_000, "too few lines inside the grid: {nonempty}");
    }

    /// Bent lines found from their bounding straight lines give the scan's
    /// interval (or wrap where a turning point could leave the grid):
    /// bends of either sign up to a few degrees of roll, lines crossing
    /// every edge of the grid.
    #[test]
    fn bent_spans_equal_the_scan() {
        let (width, height) = (141, 255);
        let (mut first, mut second) = (std::vec![0u8; width * height], std::vec![0u8; width * height]);
        let grid = crate::grid::KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: width as u16, height: height as u16 };
        let keyframe = Keyframe::new(&mut first, &mut second, &grid);
        let limits = (keyframe.columns_limit(), keyframe.rows_limit());
        let mut seed = 0xBE47_0001u32;
        let mut next = move |n: u32| crate::selftest::xorshift32(&mut seed) % n;
        let (mut nonempty, mut partial) = (0, 0);
        for _ in 0..20_000 {
            let yaw = (f64::from(next(4001)) - 2000.0) * 1e-4;
            let (sin, cos) = libm::sincos(yaw);
            let (i_start, j_start) = (next(260 << FRAC) as i32 - (60 << FRAC), next(300 << FRAC) as i32 - (20 << FRAC));
            let (i_bend, j_bend) = (next(1 << 15) as i32 - (1 << 14), next(1 << 15) as i32 - (1 << 14));
            let line = RowWarp { i_start, i_step: (cos * 65536.0) as i32, i_bend, j_start, j_step: (sin * 65536.0) as i32, j_bend };
            let start = next(60) as usize;
            let columns = start..start + 1 + next(140) as usize;
            if let Span::Inside(span) = keyframe.inside_span(line, columns.clone()) {
                let want = scanned(line, columns.clone(), limits);
                assert_eq!(span, want, "{line:?} {columns:?}");
                nonempty += usize::from(!span.is_empty());
                partial += usize::from(!span.is_empty() && span != columns);
            }
        }
        assert!(nonempty > 3_000 && partial > 1_000, "too few lines inside or across the edges: {nonempty}, {partial}");
    }
}

//! The search band: the keyframe warped onto the current row, one band row
//! per G shift (2S+1), padded by S columns each side for the K shifts.
//! A ring, so that consecutive translation rows roll it instead of
//! resampling it.
//!
//! The seed's own search reads it another way ([`Band::sample_current_rows`]):
//! band row dg is the keyframe along the warp of current row j + dg - S,
//! the seed's motion-compensated KG image shifted in the current frame's
//! rows, so every row rolls it on by one line, turning or not.

use super::keyframe::Keyframe;
use super::warp::{RowWarp, Warp, FRAC};
use crate::grid::MAX_GRID_SIDE;
use crate::limits::MAX_SEARCH_RADIUS;
use core::ops::Range;

/// Band rows (and K shifts) at the largest search radius.
pub(super) const MAX_WINDOW: usize = 2 * MAX_SEARCH_RADIUS + 1;
/// Band row length: the grid plus S columns each side.
pub(super) const BAND_WIDTH: usize = MAX_GRID_SIDE + 2 * MAX_SEARCH_RADIUS;

/// The band's rows in order dg = 0..2S+1 (entries beyond repeat row 0):
/// `rows[dg][c + MAX_SEARCH_RADIUS]` is the keyframe at warp(c) + (0, dg - S).
pub(super) type BandRows<'a> = [&'a [u8; BAND_WIDTH]; MAX_WINDOW];

pub(super) struct Band {
    /// The ring: band row dg is `ring[(first + dg) % (2S+1)]`.
    ring: [[u8; BAND_WIDTH]; MAX_WINDOW],
    first: usize,
    /// Row, warp and columns the band was last sampled for (this frame).
    source: Option<(usize, RowWarp, Range<usize>)>,
    /// The band rows (dg) that hold samples for the last sampled row; the
    /// next row rolls on from them if they reach down to the rows it needs.
    filled: Range<usize>,
    /// Read by current rows: the row last sampled, and each band row's line.
    current_row: Option<usize>,
    current_lines: [RowWarp; MAX_WINDOW],
}

impl Band {
    pub(super) const EMPTY: Band = Band {
        ring: [[0; BAND_WIDTH]; MAX_WINDOW],
        first: 0,
        source: None,
        filled: 0..0,
        current_row: None,
        current_lines: [RowWarp::LEVEL; MAX_WINDOW],
    };

    /// A new frame: nothing sampled to roll on from.
    pub(super) fn forget(&mut self) {
        self.source = None;
        self.filled = 0..0;
        self.current_row = None;
    }

    /// Samples the band of current row `j` (warp `warp`) for the columns
    /// `read` (none: nothing), and `reach` beside them: only the rows and
    /// columns within `reach` of the prediction are needed (the residue
    /// reads one either side, the shift search all S); a row that cannot
    /// roll on from the last samples no more.
    pub(super) fn sample(&mut self, keyframe: &Keyframe, j: usize, warp: RowWarp, read: Range<usize>, s: usize, reach: usize) {
        let reach = reach.min(s);
        let columns = if read.is_empty() { 0..0 } else { read.start.saturating_sub(reach)..(read.end + reach).min(keyframe.width()) };
        // On translation rows the next row's warp is usually this one moved down
        // exactly one keyframe row: then its band row dg is this row's dg + 1
        // (a sample depends only on the line and the column), so the band
        // rolls up (the ring's first row moves on, no bytes are copied), and
        // only the needed rows below what the last row left are sampled.
        let window = 2 * s + 1;
        let needed = s - reach..s + reach + 1;
        let rolls = matches!(&self.source, Some((previous_j, previous, sampled))
            if *previous_j + 1 == j
                && previous.moved(0, 1 << FRAC) == warp
                && sampled.start <= columns.start
                && columns.end <= sampled.end);
        // What the last row filled, one band row up.
        let kept = self.filled.start.max(1) - 1..self.filled.end.saturating_sub(1);
        let rolls = rolls && kept.start <= needed.start && needed.start <= kept.end;
        let to_sample = if rolls {
            self.first = (self.first + 1) % window;
            kept.end..needed.end.max(kept.end)
        } else {
            // Nothing kept: the ring starts again in dg order, so that the
            // rows sampled lie one after another.
            self.first = 0;
            needed.clone()
        };
        // Band row dg is ring slot (first + dg) mod 2S+1: the rows to sample
        // are consecutive slots, or two runs of them where the ring wraps.
        let mut dg = to_sample.start;
        while dg < to_sample.end {
            let slot = (self.first + dg) % window;
            let n = (to_sample.end - dg).min(window - slot);
            let first_line = warp.moved(0, (dg as i32 - s as i32) << FRAC);
            keyframe.sample_lines(first_line, columns.clone(), &mut self.ring[slot..slot + n]);
            dg += n;
        }
        self.current_row = None;
        self.filled = if rolls { kept.start..to_sample.end } else { to_sample };
        self.source = Some((j, warp, columns));
    }

    /// Samples the band of current row `j` read by current rows (see the
    /// module docs) under `warp`, and returns row `j`'s own line. Right
    /// after row `j - 1` only band row 2S is new, else all 2S+1 are
    /// sampled. `columns_of(r)` are the columns current row `r` compares
    /// (None: none, or beyond the grid); a band row is sampled over those
    /// of every row within S of it, widened by S.
    pub(super) fn sample_current_rows(
        &mut self,
        keyframe: &Keyframe,
        j: usize,
        warp: &Warp,
        s: usize,
        columns_of: impl Fn(usize) -> Option<Range<usize>>,
    ) -> RowWarp {
        self.source = None;
        let window = 2 * s + 1;
        let new_rows = if self.current_row.is_some_and(|previous| previous + 1 == j) {
            self.first = (self.first + 1) % window;
            2 * s..window
        } else {
            0..window
        };
        for dg in new_rows {
            let slot = (self.first + dg) % window;
            // Row j + dg - S may lie beyond the grid's edges: the warp
            // extends there, and its samples off the keyframe are 0.
            let r = j as isize + dg as isize - s as isize;
            let line = warp.row_at(r);
            let (mut lo, mut hi) = (usize::MAX, 0);
            for reader in (r - s as isize).max(0)..=r + s as isize {
                if let Some(columns) = columns_of(reader as usize) {
                    (lo, hi) = (lo.min(columns.start), hi.max(columns.end));
                }
            }
            let columns = if lo < hi { lo.saturating_sub(s)..(hi + s).min(keyframe.width()) } else { 0..0 };
            keyframe.sample_line(line, columns, &mut self.ring[slot][MAX_SEARCH_RADIUS..]);
            self.current_lines[slot] = line;
        }
        self.current_row = Some(j);
        self.current_lines[(self.first + s) % window]
    }

    /// The band rows (dg) the last sampling left filled for its row.
    #[cfg(test)]
    pub(super) fn filled(&self) -> Range<usize> {
        self.filled.clone()
    }

    /// The band's rows in order, for search radius `s`.
    pub(super) fn rows(&self, s: usize) -> BandRows<'_> {
        let window = 2 * s + 1;
        let mut rows = [&self.ring[0]; MAX_WINDOW];
        for (dg, row) in rows.iter_mut().take(window).enumerate() {
            *row = &self.ring[(self.first + dg) % window];
        }
        rows
    }

    /// Columns of the last sampled band (the tests compare them).
    #[cfg(test)]
    pub(super) fn columns(&self) -> Range<usize> {
        self.source.as_ref().map_or(0..0, |(_, _, columns)| columns.clone())
    }

    /// The ring unrolled (band row dg is `ring[dg]`), for the per-pixel reference.
    #[cfg(test)]
    pub(super) fn unrolled(&mut self) -> &mut [[u8; BAND_WIDTH]; MAX_WINDOW] {
        self.first = 0;
        &mut self.ring
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::KgGrid;
    use crate::motion::{Attitude, GroundMotion, Motion};

    /// Read by current rows, every band row of every row is the keyframe
    /// along that current row's line, sampled pixel by pixel; turning and
    /// tilted, with rows skipped (a fresh band) and rows past the edges.
    #[test]
    fn current_rows_are_the_keyframe_along_their_own_lines() {
        let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 120 };
        let (mut first, mut second) = (std::vec![0u8; grid.len()], std::vec![0u8; grid.len()]);
        let mut keyframe = Keyframe::new(&mut first, &mut second, &grid);
        for j in 0..grid.height() {
            let row: std::vec::Vec<u8> = (0..grid.width()).map(|i| ((i * 37 + j * 91 + i * j) % 251) as u8).collect();
            keyframe.write_row(j, &row);
        }
        keyframe.restart();
        keyframe.finish(0);
        let seen = |r: usize| (r < grid.height() && r % 29 != 7).then(|| (r / 10)..grid.width() - r / 12);
        for (yaw, pitch, roll) in [(0.0, 0.0, 0.0), (2.5, 0.0, 0.0), (-1.0, 0.8, -1.2)] {
            let motion = GroundMotion { planar: Motion { tx_mm: 7.0, tz_mm: 60.0, dyaw_deg: yaw }, attitude: Attitude { pitch_deg: pitch, roll_deg: roll } };
            let warp = Warp::new(&grid, &motion, &Attitude::default(), 400.0);
            let s = 2;
            let mut band = Band::EMPTY;
            for j in (0..grid.height()).filter(|&j| seen(j).is_some()) {
                let own = band.sample_current_rows(&keyframe, j, &warp, s, seen);
                assert_eq!(own, warp.row(j));
                let columns = seen(j).unwrap();
                let wide = columns.start.saturating_sub(s)..(columns.end + s).min(grid.width());
                for (dg, band_row) in band.rows(s).iter().take(2 * s + 1).enumerate() {
                    let line = warp.row_at(j as isize + dg as isize - s as isize);
                    for c in wide.clone() {
                        let (i, jr) = line.at(c);
                        let want = if keyframe.inside(i, jr) { keyframe.sample(i, jr) } else { 0 };
                        assert_eq!(band_row[c + MAX_SEARCH_RADIUS], want, "yaw {yaw} row {j} dg {dg} column {c}");
                    }
                }
            }
        }
    }
}

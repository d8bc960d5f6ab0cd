//! The search band: the keyframe warped onto the current row, one band row
//! per G shift (2S+1), padded by S columns each side for the K shifts.
//! A ring, so that consecutive translation rows roll it instead of
//! resampling it.

use super::keyframe::Keyframe;
use super::warp::{RowWarp, FRAC};
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
    /// The band rows (dg) that sampling left filled for its row: all
    /// 2S+1 make a band the next row can roll on.
    filled: Range<usize>,
}

impl Band {
    pub(super) const EMPTY: Band = Band { ring: [[0; BAND_WIDTH]; MAX_WINDOW], first: 0, source: None, filled: 0..0 };

    /// A new frame: nothing sampled to roll on from.
    pub(super) fn forget(&mut self) {
        self.source = None;
        self.filled = 0..0;
    }

    /// Samples the band of current row `j` (warp `warp`) over the `seen`
    /// columns widened by S each side; nothing reads outside them. Only
    /// the rows within `reach` of the prediction are needed (the residue
    /// reads one either side, the shift search all S): a row that cannot
    /// roll on from the last samples no more.
    pub(super) fn sample(&mut self, keyframe: &Keyframe, j: usize, warp: RowWarp, seen: Range<usize>, s: usize, reach: usize) {
        let columns = seen.start.saturating_sub(s)..(seen.end + s).min(keyframe.width());
        // On translation rows the next row's warp is usually this one moved down
        // exactly one keyframe row: then its band row dg is this row's dg + 1
        // (a sample depends only on the line and the column), so the band
        // rolls up (the ring's first row moves on, no bytes are copied) and
        // only the last row is sampled.
        let window = 2 * s + 1;
        let rolls = self.filled.len() == window
            && matches!(&self.source, Some((previous_j, previous, sampled))
            if *previous_j + 1 == j
                && previous.moved(0, 1 << FRAC) == warp
                && sampled.start <= columns.start
                && columns.end <= sampled.end);
        let reach = reach.min(s);
        let to_sample = if rolls {
            self.first = (self.first + 1) % window;
            2 * s..2 * s + 1
        } else {
            s - reach..s + reach + 1
        };
        // The ring's rows in dg order: from `first` to its end, then its start.
        let (wrapped, in_order) = self.ring[..window].split_at_mut(self.first);
        let mut lines = heapless::Vec::<&mut [u8], MAX_WINDOW>::new();
        for row in in_order.iter_mut().chain(wrapped.iter_mut()).skip(to_sample.start).take(to_sample.len()) {
            let _ = lines.push(&mut row[MAX_SEARCH_RADIUS..]);
        }
        let first_line = warp.moved(0, (to_sample.start as i32 - s as i32) << FRAC);
        keyframe.sample_lines(first_line, columns.clone(), &mut lines);
        self.filled = if rolls { 0..window } else { to_sample };
        self.source = Some((j, warp, columns));
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

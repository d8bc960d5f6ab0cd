//! The misregistration-tolerant residue: each current pixel against the
//! *range* of its neighbours in the warped keyframe (Birchfield-Tomasi
//! style), so sharp ground edges that are a pixel off leave nothing while
//! displaced texture on an obstacle does; counted per coherence cell for
//! blob coherence, and per grid row for a blob's base.
//!
//! Two residues per pixel: the ground hypothesis's (the range reaches half
//! a pixel, a full one along an axis where the odometry may be that far
//! off), which the parallax test compares heights with; and the wide one
//! (always the full neighbours) that flags anything unexplained, so a shift
//! search that lands a pixel away cannot light up ground edges.

use super::band::BandRows;
use super::layout::Cells;
use super::parallax::CellRowSums;
use crate::grid::MAX_GRID_SIDE;
use crate::limits::{MAX_CELLS, MAX_SEARCH_RADIUS};
use core::ops::Range;

/// Residue evidence of the current frame.
pub(super) struct Residue {
    /// Pixels whose wide residue exceeds the threshold, per cell.
    pub(super) cell_residue: [u8; MAX_CELLS],
    /// Pixels compared, per cell.
    pub(super) cell_valid: [u8; MAX_CELLS],
    /// Residue pixels per grid row (for the blob base).
    pub(super) row_residue: [u16; MAX_GRID_SIDE],
}

impl Residue {
    pub(super) const EMPTY: Residue =
        Residue { cell_residue: [0; MAX_CELLS], cell_valid: [0; MAX_CELLS], row_residue: [0; MAX_GRID_SIDE] };

    pub(super) fn clear(&mut self) {
        self.cell_residue = [0; MAX_CELLS];
        self.cell_valid = [0; MAX_CELLS];
        self.row_residue = [0; MAX_GRID_SIDE];
    }

    /// Residues of current row `j` (`row`) against `band` over the `runs`
    /// columns: counts the cells of cell row `cell_row`, and adds the ground
    /// hypothesis's residue to `ground` (hypothesis 0). `full` widens the
    /// ground range to the whole neighbour along (K, G); a wide residue above
    /// `threshold` counts.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_row(
        &mut self,
        j: usize,
        row: &[u8],
        band: &BandRows,
        s: usize,
        runs: &[(u16, u16)],
        full: (bool, bool),
        threshold: u8,
        cells: &Cells,
        cell_row: usize,
        ground: &mut CellRowSums,
    ) {
        let cell_base = cell_row * cells.wide;
        let lines = ResidueLines::new(row, band, s);
        let mut row_residue = 0u32;
        for &run in runs {
            let columns = usize::from(run.0)..usize::from(run.1);
            cells.segments(columns, |cell_column, columns| {
                let cell = cell_base + cell_column;
                let n = columns.len();
                let (hot, sum) = match full {
                    (false, false) => lines.segment::<false, false>(columns, threshold),
                    (true, false) => lines.segment::<true, false>(columns, threshold),
                    (false, true) => lines.segment::<false, true>(columns, threshold),
                    (true, true) => lines.segment::<true, true>(columns, threshold),
                };
                self.cell_valid[cell] = self.cell_valid[cell].saturating_add(n.min(255) as u8);
                self.cell_residue[cell] = self.cell_residue[cell].saturating_add(hot.min(255) as u8);
                row_residue += hot;
                // The ground is the null hypothesis: it gets the half-pixel
                // tolerance, the heights must beat it outright.
                ground.add(0, cell_column, n as u16, sum);
            });
        }
        self.row_residue[j] = self.row_residue[j].saturating_add(row_residue.min(u32::from(u16::MAX)) as u16);
    }

    /// Percentage of a cell's pixels that are residue (0 for cells mostly
    /// out of view; cells are `cell_px` square).
    pub(super) fn percent(&self, cell: usize, cell_px: usize) -> u32 {
        let valid = u32::from(self.cell_valid[cell]);
        if valid * 2 < (cell_px * cell_px) as u32 {
            return 0;
        }
        u32::from(self.cell_residue[cell]) * 100 / valid
    }
}

/// A current row and the band rows around the prediction, aligned by
/// column (`centre[c]` is the warped keyframe at current column `c`).
struct ResidueLines<'a> {
    row: &'a [u8],
    centre: &'a [u8],
    up: &'a [u8],
    down: &'a [u8],
}

impl<'a> ResidueLines<'a> {
    fn new(row: &'a [u8], band: &'a BandRows, s: usize) -> ResidueLines<'a> {
        // The band is padded by MAX_SEARCH_RADIUS columns: `centre` starts one
        // before column 0 so that left, here and right are consecutive.
        let r = MAX_SEARCH_RADIUS;
        ResidueLines { row, centre: &band[s][r - 1..], up: &band[s - 1][r..], down: &band[s + 1][r..] }
    }

    /// Both residues of `columns` in one pass: the count of wide residues
    /// above `threshold`, and the sum of the ground hypothesis's residues,
    /// which reach halfway to a neighbour or (`FULL_K` sideways, `FULL_G`
    /// along) all the way.
    #[inline(always)]
    fn segment<const FULL_K: bool, const FULL_G: bool>(&self, columns: Range<usize>, threshold: u8) -> (u32, u32) {
        let (a, b) = (columns.start, columns.end);
        let (mut hot, mut sum) = (0u32, 0u32);
        let sideways = self.centre[a..b + 2].windows(3);
        for (((&value, window), &up), &down) in self.row[a..b].iter().zip(sideways).zip(&self.up[a..b]).zip(&self.down[a..b]) {
            let (left, here, right) = (window[0], window[1], window[2]);
            let (wide, ground) = residues::<FULL_K, FULL_G>(value, here, [left, right], [up, down]);
            hot += u32::from(wide > threshold);
            sum += u32::from(ground);
        }
        (hot, sum)
    }
}

/// The wide and the ground residue of `value` against the warped keyframe
/// `here` and its neighbours: beyond the range they span, reached all the
/// way (wide) or halfway (the ground's, unless `FULL_K` / `FULL_G`). The
/// halfway point is monotone in the neighbour, so the range's ends are
/// those of the nearest and farthest neighbour per axis.
#[inline(always)]
fn residues<const FULL_K: bool, const FULL_G: bool>(value: u8, here: u8, sideways: [u8; 2], along: [u8; 2]) -> (u8, u8) {
    let half = |other: u8| ((u16::from(here) + u16::from(other) + 1) >> 1) as u8;
    let reach = |other: u8, full: bool| if full { other } else { half(other) };
    let (k_low, k_high) = (sideways[0].min(sideways[1]), sideways[0].max(sideways[1]));
    let (g_low, g_high) = (along[0].min(along[1]), along[0].max(along[1]));
    let beyond = |low: u8, high: u8| value.saturating_sub(high).max(low.saturating_sub(value));
    let wide = beyond(here.min(k_low).min(g_low), here.max(k_high).max(g_high));
    let ground = beyond(
        here.min(reach(k_low, FULL_K)).min(reach(g_low, FULL_G)),
        here.max(reach(k_high, FULL_K)).max(reach(g_high, FULL_G)),
    );
    (wide, ground)
}

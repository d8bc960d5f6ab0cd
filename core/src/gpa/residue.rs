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
        let mut residues = [0u8; MAX_GRID_SIDE];
        let mut unexplained = [0u8; MAX_GRID_SIDE];
        let cell_base = cell_row * cells.wide;
        for &run in runs {
            let columns = usize::from(run.0)..usize::from(run.1);
            match full {
                (false, false) => residue_line::<false, false>(row, band, s, columns.clone(), &mut residues),
                (true, false) => residue_line::<true, false>(row, band, s, columns.clone(), &mut residues),
                (false, true) => residue_line::<false, true>(row, band, s, columns.clone(), &mut residues),
                (true, true) => residue_line::<true, true>(row, band, s, columns.clone(), &mut residues),
            }
            if full == (true, true) {
                unexplained[columns.clone()].copy_from_slice(&residues[columns.clone()]);
            } else {
                residue_line::<true, true>(row, band, s, columns.clone(), &mut unexplained);
            }
            let mut row_residue = 0u32;
            cells.segments(columns, |cell_column, columns| {
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
                ground.add(0, cell_column, n as u16, sum);
            });
            self.row_residue[j] = self.row_residue[j].saturating_add(row_residue.min(u32::from(u16::MAX)) as u16);
        }
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

/// Tolerant residue of `value` against the warped keyframe `here` and its
/// neighbours (left, right, up, down): beyond the range they span, reached
/// halfway or (`FULL_K` sideways, `FULL_G` along) all the way.
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

/// Residues of `row[c]` for `c` in `columns` into `out[c]`, against band
/// row `s` (the prediction) and its neighbours.
fn residue_line<const FULL_K: bool, const FULL_G: bool>(
    row: &[u8],
    band: &BandRows,
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

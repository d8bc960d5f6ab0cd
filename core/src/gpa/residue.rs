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
use super::layout::{Cells, MAX_CELL_PX};
use super::parallax::CellRowSums;
use crate::grid::MAX_GRID_SIDE;
use crate::kernels::{self, ColumnTotals, PieceSums, ResidueLines};
use crate::limits::{MAX_CELLS, MAX_CELLS_SIDE, MAX_SEARCH_RADIUS};

/// Residue evidence of the current frame.
pub(super) struct Residue {
    /// Pixels whose wide residue exceeds the threshold, per cell.
    pub(super) cell_residue: [u8; MAX_CELLS],
    /// Pixels compared, per cell.
    pub(super) cell_valid: [u8; MAX_CELLS],
    /// Residue pixels per grid row (for the blob base).
    pub(super) row_residue: [u16; MAX_GRID_SIDE],
    /// A row's per-pixel results: 1 where the wide residue counts; the
    /// ground residue. Scratch, written before it is read (kept here, not
    /// on the stack, so that no row pays for zeroing them).
    hot_pixels: [u8; MAX_GRID_SIDE],
    ground_residues: [u8; MAX_GRID_SIDE],
    /// The current cell row's residues per column, until it ends.
    columns: ColumnTotals,
    /// Scratch: their sums per cell when it ends.
    pieces: [PieceSums; MAX_CELLS_SIDE],
}

// A cell row's rows are tallied per column in a nibble each.
const _: () = assert!(MAX_CELL_PX <= kernels::MAX_TALLIED_ROWS);

impl Residue {
    pub(super) const EMPTY: Residue =
        Residue {
            cell_residue: [0; MAX_CELLS],
            cell_valid: [0; MAX_CELLS],
            row_residue: [0; MAX_GRID_SIDE],
            hot_pixels: [0; MAX_GRID_SIDE],
            ground_residues: [0; MAX_GRID_SIDE],
            columns: ColumnTotals::EMPTY,
            pieces: [PieceSums::ZERO; MAX_CELLS_SIDE],
        };

    pub(super) fn clear(&mut self) {
        self.cell_residue = [0; MAX_CELLS];
        self.cell_valid = [0; MAX_CELLS];
        self.row_residue = [0; MAX_GRID_SIDE];
        self.columns = ColumnTotals::EMPTY;
    }

    /// Residues of current row `j` (`row`) against `band` over the `runs`
    /// columns, added to its cell row's column totals until
    /// [`Self::finish_cell_row`]. `full` widens the ground range to the
    /// whole neighbour along (K, G); a wide residue above `threshold` counts.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_row(&mut self, j: usize, row: &[u8], band: &BandRows, s: usize, runs: &[(u16, u16)], full: (bool, bool), threshold: u8) {
        let lines = residue_lines(row, band, s);
        let mut row_residue = 0u32;
        for &run in runs {
            let columns = usize::from(run.0)..usize::from(run.1);
            let (hot_run, ground_run) = (&mut self.hot_pixels[columns.clone()], &mut self.ground_residues[columns.clone()]);
            kernels::residues(lines.columns(columns.clone()), full, threshold, hot_run, ground_run);
            row_residue += kernels::add_to_columns(&self.hot_pixels, &self.ground_residues, columns, &mut self.columns);
        }
        self.row_residue[j] = self.row_residue[j].saturating_add(row_residue.min(u32::from(u16::MAX)) as u16);
    }

    /// Counts the column totals of finished cell row `cell_row` into its
    /// cells (`width` grid columns), the ground's residue into `ground`
    /// (hypothesis 0: the ground is the null hypothesis, it gets the
    /// half-pixel tolerance, the heights must beat it outright).
    pub(super) fn finish_cell_row(&mut self, cells: &Cells, cell_row: usize, width: usize, ground: &mut CellRowSums) {
        let (px, cell_base) = (cells.px, cell_row * cells.wide);
        let (Some(valid), Some(residue)) = (self.cell_valid.get_mut(cell_base..cell_base + cells.wide), self.cell_residue.get_mut(cell_base..cell_base + cells.wide)) else {
            return;
        };
        let count = self.columns.take_pieces(px, width, &mut self.pieces);
        let pieces = &self.pieces;
        let sums = valid.iter_mut().zip(residue).zip(ground.pixels[0].iter_mut().zip(&mut ground.sad[0]));
        // Each cell row is counted once a frame, into cells (and ground
        // sums) still 0 from the frame's (the cell row's) start: stored.
        for (((valid, residue), (pixels, sad)), piece) in sums.zip(&pieces[..count]) {
            debug_assert!(*valid == 0 && *residue == 0 && *pixels == 0 && *sad == 0);
            (*valid, *residue) = (piece.pixels() as u8, piece.hot() as u8);
            (*pixels, *sad) = (piece.pixels() as u8, piece.ground() as u16);
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

/// A current row and the band rows around the prediction, aligned by
/// column for [`kernels::residues`].
fn residue_lines<'a>(row: &'a [u8], band: &'a BandRows, s: usize) -> ResidueLines<'a> {
    // The band is padded by MAX_SEARCH_RADIUS columns: `centre` starts one
    // before column 0 so that left, here and right are consecutive.
    let r = MAX_SEARCH_RADIUS;
    ResidueLines { row, centre: &band[s][r - 1..], up: &band[s - 1][r..], down: &band[s + 1][r..] }
}

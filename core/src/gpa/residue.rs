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
use crate::kernels::{self, ResidueLines};
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
    /// A row's per-pixel results: 1 where the wide residue counts; the
    /// ground residue. Scratch, written before it is read (kept here, not
    /// on the stack, so that no row pays for zeroing them).
    /// (Padded for [`kernels::byte_sums`]' word reads.)
    hot_pixels: [u8; MAX_GRID_SIDE + kernels::BYTE_SUMS_PAD],
    ground_residues: [u8; MAX_GRID_SIDE + kernels::BYTE_SUMS_PAD],
}

impl Residue {
    pub(super) const EMPTY: Residue =
        Residue {
            cell_residue: [0; MAX_CELLS],
            cell_valid: [0; MAX_CELLS],
            row_residue: [0; MAX_GRID_SIDE],
            hot_pixels: [0; MAX_GRID_SIDE + kernels::BYTE_SUMS_PAD],
            ground_residues: [0; MAX_GRID_SIDE + kernels::BYTE_SUMS_PAD],
        };

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
        let lines = residue_lines(row, band, s);
        let mut row_residue = 0u32;
        for &run in runs {
            let columns = usize::from(run.0)..usize::from(run.1);
            let (hot_run, ground_run) = (&mut self.hot_pixels[columns.clone()], &mut self.ground_residues[columns.clone()]);
            kernels::residues(lines.columns(columns.clone()), full, threshold, hot_run, ground_run);
            row_residue += self.count_cells(columns, cells, cell_base, ground);
        }
        self.row_residue[j] = self.row_residue[j].saturating_add(row_residue.min(u32::from(u16::MAX)) as u16);
    }

    /// Adds the residues of a run's `columns` to their cells (cell row
    /// `cell_base / cells.wide`), the ground's to `ground`; returns the
    /// hot pixels. The run's cells are sliced once, so a segment costs its
    /// sums and four stores, with no bounds check of its own. Not inlined:
    /// a segment's few sums then keep their registers instead of sharing
    /// the row step's.
    #[inline(never)]
    fn count_cells(&mut self, columns: Range<usize>, cells: &Cells, cell_base: usize, ground: &mut CellRowSums) -> u32 {
        let px = cells.px;
        if columns.is_empty() || px == 0 {
            return 0;
        }
        let (first_cell, last_cell) = (columns.start / px, (columns.end - 1) / px);
        // Every index below lies within these, checked once a run.
        let valid = &mut self.cell_valid[cell_base + first_cell..=cell_base + last_cell];
        let residue = &mut self.cell_residue[cell_base + first_cell..=cell_base + last_cell];
        let (pixels, sads) = (&mut ground.pixels[0][first_cell..=last_cell], &mut ground.sad[0][first_cell..=last_cell]);
        let (hot, ground_residues) = (&self.hot_pixels[..columns.end + kernels::BYTE_SUMS_PAD], &self.ground_residues[..columns.end + kernels::BYTE_SUMS_PAD]);
        let mut hot_pixels = 0;
        let (mut start, mut end) = (columns.start, ((first_cell + 1) * px).min(columns.end));
        for k in 0..valid.len() {
            let n = end - start;
            let (hot_sum, sum) = kernels::byte_sums(hot, ground_residues, start..end);
            valid[k] = valid[k].saturating_add(n.min(255) as u8);
            residue[k] = residue[k].saturating_add(hot_sum.min(255) as u8);
            hot_pixels += hot_sum;
            // The ground is the null hypothesis: it gets the half-pixel
            // tolerance, the heights must beat it outright.
            pixels[k] += n as u8;
            sads[k] += sum as u16;
            (start, end) = (end, (end + px).min(columns.end));
        }
        hot_pixels
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

//! Where things are on the KG grid for one rig: the AOI, the rows analysed,
//! and the coarse coherence cells that residue and parallax are counted in.

use crate::geometry::Rig;
use crate::grid::{KgGrid, PixelRect};
use crate::limits::{MAX_CELLS, MAX_CELLS_SIDE, MAX_GRID_SIDE};
use core::ops::Range;

/// The largest cell side, px: a cell holds at most 225 pixels, so its sums
/// over a cell row fit 8 bits (count) and 16 bits (SAD, 225 * 255).
pub(super) const MAX_CELL_PX: usize = 15;
// The loop in `Layout::new` never grows cells past it: 7 px already fits
// the largest grid into the cell limits.
const _: () = assert!(
    MAX_GRID_SIDE.div_ceil(7) <= MAX_CELLS_SIDE && MAX_GRID_SIDE.div_ceil(7) * MAX_GRID_SIDE.div_ceil(7) <= MAX_CELLS
);

#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    pub(super) grid: KgGrid,
    /// H, the camera's height above the ground (mm).
    pub(super) camera_height_mm: f64,
    pub(super) aoi: PixelRect,
    /// Rows analysed: from the top of the grid (beyond the AOI) to the AOI's near edge.
    pub(super) analysis_rows: usize,
    pub(super) cells: Cells,
}

/// The coherence cells: `px` x `px` squares, `wide` x `high` of them over
/// the analysed rows, stored row by row.
#[derive(Clone, Copy, Debug)]
pub(super) struct Cells {
    pub(super) px: usize,
    pub(super) wide: usize,
    pub(super) high: usize,
}

/// The AOI's edges in mm (robot frame).
#[derive(Clone, Copy, Debug)]
pub(super) struct AoiMm {
    pub(super) near: f64,
    pub(super) far: f64,
    pub(super) half_width: f64,
}

impl Layout {
    pub(super) const EMPTY: Layout = Layout {
        grid: KgGrid { mm_per_px: 1.0, x_left_mm: 0.0, z_far_mm: 0.0, width: 0, height: 0 },
        camera_height_mm: 0.0,
        aoi: PixelRect { left: 0, right: 0, top: 0, bottom: 0 },
        analysis_rows: 0,
        cells: Cells { px: 5, wide: 0, high: 0 },
    };

    /// The layout of `rig` on `grid`, with cells of about `cell_mm`.
    pub(super) fn new(rig: &Rig, grid: &KgGrid, cell_mm: f64) -> Layout {
        let aoi = grid.aoi_pixels(rig);
        let rows = aoi.bottom;
        // At least 5 px: a coherent sample for the parallax test; and large
        // enough that the cells fit MAX_CELLS_SIDE per side and MAX_CELLS in all.
        let mut px = (libm::round(cell_mm / grid.mm_per_px) as usize).clamp(5, MAX_CELL_PX);
        while grid.width().div_ceil(px) * rows.div_ceil(px) > MAX_CELLS
            || grid.width().div_ceil(px) > MAX_CELLS_SIDE
            || rows.div_ceil(px) > MAX_CELLS_SIDE
        {
            px += 1;
        }
        Layout {
            grid: *grid,
            camera_height_mm: rig.height_mm(),
            aoi,
            analysis_rows: rows,
            cells: Cells { px, wide: grid.width().div_ceil(px), high: rows.div_ceil(px) },
        }
    }

    /// Row `j` is in the far half of the AOI (a yaw error shifts far rows
    /// sideways more than near ones, which is how it is measured).
    pub(super) fn in_far_half(&self, j: usize) -> bool {
        j < (self.aoi.top + self.aoi.bottom) / 2
    }

    /// A coherence cell's side on the ground (mm).
    pub(super) fn cell_mm(&self) -> f64 {
        self.cells.px as f64 * self.grid.mm_per_px
    }

    /// Ground distance (mm) of cell row `row`'s centre, where its
    /// measured height belongs.
    pub(super) fn centre_mm(&self, row: usize) -> f64 {
        self.grid.pixel_to_ground(0.0, (row as f64 + 0.5) * self.cells.px as f64 - 0.5).1
    }

    /// Ground distance (mm) of cell row `row`'s near side: the bottom of
    /// its last pixel row.
    pub(super) fn near_side_mm(&self, row: usize) -> f64 {
        self.grid.pixel_to_ground(0.0, ((row + 1) * self.cells.px) as f64 - 0.5).1
    }

    /// The AOI in mm (robot frame).
    pub(super) fn aoi_mm(&self) -> AoiMm {
        let (left, far) = self.grid.pixel_to_ground(self.aoi.left as f64, self.aoi.top as f64);
        let (_, near) = self.grid.pixel_to_ground(0.0, self.aoi.bottom as f64 - 1.0);
        AoiMm { near, far, half_width: -left }
    }
}

impl Cells {
    /// Calls `f(cell_column, columns)` for the cell segments of `columns`
    /// (generic so `f` inlines; one division per call, not per segment).
    #[inline(always)]
    pub(super) fn segments(&self, columns: Range<usize>, mut f: impl FnMut(usize, Range<usize>)) {
        let mut c = columns.start;
        let mut cell_column = c / self.px;
        while c < columns.end {
            let end = ((cell_column + 1) * self.px).min(columns.end);
            f(cell_column, c..end);
            c = end;
            cell_column += 1;
        }
    }
}

/// A set of cells, one bit each (a `[bool; MAX_CELLS]` would cost 1.7 KB
/// of the M4's stack per flood).
pub(super) struct CellSet([u32; MAX_CELLS.div_ceil(32)]);

impl CellSet {
    pub(super) const EMPTY: CellSet = CellSet([0; MAX_CELLS.div_ceil(32)]);

    pub(super) fn contains(&self, cell: usize) -> bool {
        self.0[cell / 32] & (1 << (cell % 32)) != 0
    }

    pub(super) fn insert(&mut self, cell: usize) {
        self.0[cell / 32] |= 1 << (cell % 32);
    }

    pub(super) fn remove(&mut self, cell: usize) {
        self.0[cell / 32] &= !(1 << (cell % 32));
    }
}

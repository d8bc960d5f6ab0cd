//! Where the last judged frame saw what is not ground, carried to this
//! frame: the motion estimate leaves those pixels out, so a view that an
//! obstacle fills (a stool's legs and two bags a step ahead) is still
//! aligned on the ground around it. Its robust weights cannot do that
//! once the obstacle has most of the high-contrast pixels. The cells that
//! stood up, weakly or not, also let a weak height seen again count
//! ([`MovedMask::stood_up`]).

use super::config::GpaConfig;
use super::layout::{CellSet, Cells};
use super::parallax::CellHeights;
use super::residue::Residue;

/// The cells of the last judged frame that were not ground: a parallax
/// height past the obstacle height either way, or active residue.
pub(super) struct HazardMask {
    cells: CellSet,
    /// The cells whose height, weak or measured, stood up at least the
    /// obstacle height.
    standing: CellSet,
    layout: Cells,
    /// The frame it was seen in; None: nothing known.
    frame: Option<u32>,
}

impl HazardMask {
    pub(super) const EMPTY: HazardMask = HazardMask { cells: CellSet::EMPTY, standing: CellSet::EMPTY, layout: Cells { px: 1, wide: 0, high: 0 }, frame: None };

    /// Records frame `frame`'s hazards.
    pub(super) fn record(&mut self, frame: u32, layout: Cells, heights: &CellHeights, residue: &Residue, config: &GpaConfig) {
        let min_height = libm::ceil(config.min_obstacle_height_mm) as i32;
        self.cells = CellSet::EMPTY;
        self.standing = CellSet::EMPTY;
        for cell in 0..layout.wide * layout.high {
            if i32::from(heights.any(cell)) >= min_height {
                self.standing.insert(cell);
            }
            if i32::from(heights.get(cell)).abs() >= min_height || residue.percent(cell, layout.px) >= config.active_cell_percent {
                self.cells.insert(cell);
            }
        }
        self.layout = layout;
        self.frame = Some(frame);
    }

    /// Nothing is known (a frame not judged, motion lost).
    pub(super) fn forget(&mut self) {
        self.frame = None;
    }

    /// The mask as frame `frame` sees it, the ground having come
    /// `step_rows` grid rows nearer since; None unless the last frame was
    /// the one before.
    pub(super) fn moved(&self, frame: u32, step_rows: f64) -> Option<MovedMask<'_>> {
        (self.frame?.wrapping_add(1) == frame && step_rows.is_finite()).then_some(MovedMask { mask: self, shift_rows: libm::round(step_rows) as i32 })
    }
}

/// [`HazardMask`] moved to the current frame.
#[derive(Clone, Copy)]
pub(super) struct MovedMask<'a> {
    mask: &'a HazardMask,
    shift_rows: i32,
}

impl MovedMask<'_> {
    /// Whether grid pixel (`i`, `j`) of the current frame may show a
    /// hazard: its cell or a neighbour of it (the step's lateral motion,
    /// turn and error, and a hazard's blurred outline) was one.
    pub(super) fn covers(&self, i: f32, j: f32) -> bool {
        self.near_one_of(&self.mask.cells, i, j)
    }

    /// Whether current cell (`row`, `column`) or a neighbour of it stood
    /// up on the last frame, weakly or not.
    pub(super) fn stood_up(&self, row: usize, column: usize) -> bool {
        let px = self.mask.layout.px as f32;
        self.near_one_of(&self.mask.standing, (column as f32 + 0.5) * px, (row as f32 + 0.5) * px)
    }

    /// Whether grid pixel (`i`, `j`)'s cell or a neighbour of it, moved
    /// back to the last frame, is one of `cells`.
    #[inline(always)]
    fn near_one_of(&self, cells: &CellSet, i: f32, j: f32) -> bool {
        let Cells { px, wide, high } = self.mask.layout;
        // Saturating: a step beyond any grid (a wild motion) covers nothing.
        let was = (libm::floorf(j) as i32).saturating_sub(self.shift_rows);
        let (row, column) = (was.div_euclid(px as i32), (i as i32).div_euclid(px as i32));
        (row - 1..=row + 1).any(|r| {
            (column - 1..=column + 1).any(|c| (0..high as i32).contains(&r) && (0..wide as i32).contains(&c) && cells.contains(r as usize * wide + c as usize))
        })
    }
}

//! One compare's scratch memory, in turns. The coarse search's images are
//! live only in step 1 of the motion estimate; the block matches from step
//! 2 until the frame's gain is read; the row stages' sums (band, residue,
//! both shift searches) from the comparison of the rows until the frame
//! is decided. So the coarse images take turns with the other two in one
//! place, which saves ~13 KB of the board's RAM.

use super::band::Band;
use super::coarse::CoarseSearch;
use super::estimate::Estimator;
use super::residue::Residue;
use super::shift_search::ShiftSearch;

/// The row stages' per-frame sums, cleared by each compare before use.
pub(super) struct RowStages {
    pub(super) band: Band,
    pub(super) residue: Residue,
    /// The shift search around the measured motion.
    pub(super) search: ShiftSearch,
    /// The seed's search around the prediction, when the measured motion
    /// differs from it (the report's shift and statistics).
    pub(super) seed: ShiftSearch,
}

/// What follows step 1.
pub(super) struct Fine {
    pub(super) estimator: Estimator,
    pub(super) rows: RowStages,
}

impl Fine {
    const EMPTY: Fine = Fine {
        estimator: Estimator::EMPTY,
        rows: RowStages { band: Band::EMPTY, residue: Residue::EMPTY, search: ShiftSearch::EMPTY, seed: ShiftSearch::EMPTY },
    };
}

/// Whichever holds the memory now.
// The variants differ in size by target (the host's histograms have more
// lanes); sharing one memory is the point, and there is no heap to box in.
#[allow(clippy::large_enum_variant)]
pub(super) enum Workspace {
    Coarse(CoarseSearch),
    Fine(Fine),
}

impl Workspace {
    pub(super) const EMPTY: Workspace = Workspace::Fine(Fine::EMPTY);

    /// Step 1's images; the block matches and row sums are gone once they
    /// have the memory.
    pub(super) fn coarse(&mut self) -> &mut CoarseSearch {
        if let Workspace::Fine(_) = self {
            *self = Workspace::Coarse(CoarseSearch::EMPTY);
        }
        match self {
            Workspace::Coarse(coarse) => coarse,
            // Just made.
            Workspace::Fine(_) => unreachable!(),
        }
    }

    /// The block matches and row sums as last left, or empty after step 1.
    pub(super) fn fine(&mut self) -> &mut Fine {
        if let Workspace::Coarse(_) = self {
            *self = Workspace::EMPTY;
        }
        match self {
            Workspace::Fine(fine) => fine,
            // Just made.
            Workspace::Coarse(_) => unreachable!(),
        }
    }

    pub(super) fn estimator(&mut self) -> &mut Estimator {
        &mut self.fine().estimator
    }

    pub(super) fn rows(&mut self) -> &mut RowStages {
        &mut self.fine().rows
    }

    /// The row stages, read-only; None while step 1 has the memory.
    #[cfg(test)]
    pub(super) fn rows_ref(&self) -> Option<&RowStages> {
        match self {
            Workspace::Fine(fine) => Some(&fine.rows),
            Workspace::Coarse(_) => None,
        }
    }
}

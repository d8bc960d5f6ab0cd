//! One compare's scratch memory, in turns: the coarse search's images in
//! step 1 of the motion estimate, the alignment's pyramids in step 2, the
//! row stages' sums (band, residue, both shift searches) from the
//! comparison of the rows until the frame is decided; and while the next
//! frame's rows stream in, the remap's ring of camera rows. None of them
//! is live while another is, so they share one place in the board's RAM.

use super::band::Band;
use super::coarse::CoarseSearch;
use super::estimate::Estimator;
use super::keyframe::LinePositions;
use super::residue::Residue;
use super::shift_search::ShiftSearch;
use crate::grid::MAX_GRID_SIDE;
use crate::limits::MAX_RING_BYTES;

/// The row stages' per-frame sums, cleared by each compare before use.
pub(super) struct RowStages {
    pub(super) band: Band,
    pub(super) residue: Residue,
    /// The shift search around the measured motion.
    pub(super) search: ShiftSearch,
    /// The seed's search around the prediction, when the measured motion
    /// differs from it (the report's shift and statistics).
    pub(super) seed: ShiftSearch,
    /// The parallax pass's keyframe positions of a row, shared by its hypotheses.
    pub(super) positions: LinePositions,
    /// The parallax pass's samples of a hypothesis' line near the keyframe's
    /// edges, and its rows brought to the keyframe's exposure.
    pub(super) samples: [u8; MAX_GRID_SIDE],
    pub(super) adjusted: [u8; MAX_GRID_SIDE],
}

impl RowStages {
    const EMPTY: RowStages = RowStages { band: Band::EMPTY, residue: Residue::EMPTY, search: ShiftSearch::EMPTY, seed: ShiftSearch::EMPTY, positions: LinePositions::EMPTY, samples: [0; MAX_GRID_SIDE], adjusted: [0; MAX_GRID_SIDE] };
}

/// Whichever holds the memory now.
// The variants differ in size by target (the host's histograms have more
// lanes); sharing one memory is the point, and there is no heap to box in.
#[allow(clippy::large_enum_variant)]
pub(super) enum Workspace {
    Coarse(CoarseSearch),
    Estimate(Estimator),
    Rows(RowStages),
    /// The remap's camera rows while a frame streams in.
    Ring([u8; MAX_RING_BYTES]),
}

// The ring takes no memory of its own: it fits in the largest of the others.
const _: () = {
    let others = [size_of::<CoarseSearch>(), size_of::<Estimator>(), size_of::<RowStages>()];
    assert!(MAX_RING_BYTES <= others[0] || MAX_RING_BYTES <= others[1] || MAX_RING_BYTES <= others[2]);
};

impl Workspace {
    pub(super) const EMPTY: Workspace = Workspace::Rows(RowStages::EMPTY);

    /// Step 1's images; whatever held the memory before is gone.
    pub(super) fn coarse(&mut self) -> &mut CoarseSearch {
        if !matches!(self, Workspace::Coarse(_)) {
            *self = Workspace::Coarse(CoarseSearch::EMPTY);
        }
        match self {
            Workspace::Coarse(coarse) => coarse,
            // Just made.
            _ => unreachable!(),
        }
    }

    /// The alignment's pyramids; whatever held the memory before is gone.
    pub(super) fn estimator(&mut self) -> &mut Estimator {
        if !matches!(self, Workspace::Estimate(_)) {
            *self = Workspace::Estimate(Estimator::EMPTY);
        }
        match self {
            Workspace::Estimate(estimator) => estimator,
            // Just made.
            _ => unreachable!(),
        }
    }

    /// The row sums as last left, or empty after the estimate.
    pub(super) fn rows(&mut self) -> &mut RowStages {
        if !matches!(self, Workspace::Rows(_)) {
            *self = Workspace::Rows(RowStages::EMPTY);
        }
        match self {
            Workspace::Rows(rows) => rows,
            // Just made.
            _ => unreachable!(),
        }
    }

    /// The remap's ring; whatever held the memory before is gone (a new
    /// ring is zeroed, one in use is kept as it is).
    pub(super) fn ring(&mut self) -> &mut [u8; MAX_RING_BYTES] {
        if !matches!(self, Workspace::Ring(_)) {
            *self = Workspace::Ring([0; MAX_RING_BYTES]);
        }
        match self {
            Workspace::Ring(ring) => ring,
            // Just made.
            _ => unreachable!(),
        }
    }

    /// The row stages, read-only; None while the estimate has the memory.
    pub(super) fn rows_ref(&self) -> Option<&RowStages> {
        match self {
            Workspace::Rows(rows) => Some(rows),
            _ => None,
        }
    }
}

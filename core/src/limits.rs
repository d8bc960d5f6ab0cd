//! Capacities and limits: every fixed size that bounds a buffer or a
//! search, in one place. Core has no heap, so these decide the RAM a target
//! reserves; algorithm parameters stay with their configs.

// GPA detector

/// Largest search radius S (the window is `(2S+1)^2` shifts).
pub const MAX_SEARCH_RADIUS: usize = 3;
/// Spare keyframe rows: how far (rows) the in-place keyframe update may run
/// ahead of the rows still being read. Bounds the travel per keyframe swap.
pub const KEYFRAME_SPARE_ROWS: usize = 48;
/// Coarse cells for blob analysis, per side.
pub const MAX_CELLS_SIDE: usize = 52;
/// Coarse cells in all, stored `cells_wide` apart: the 40,000 px default grid
/// cap at the 30 mm default cell stays within ~1,600; larger grids get
/// larger cells.
pub const MAX_CELLS: usize = 1_700;
/// Blobs tracked per frame.
pub const MAX_BLOBS: usize = 16;
/// Cells whose footprints a parallax blob keeps for its statistics.
pub const MAX_BLOB_CELLS: usize = 128;
/// Cells waiting on the stack of a blob's flood fill: a full stack
/// truncates the blob's growth.
pub const MAX_FLOOD_CELLS: usize = 256;

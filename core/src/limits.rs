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

// GTI

/// Most GT lines across the AOI (the default uses all of them: each line's
/// samples cost a KG column of RAM).
pub const MAX_LINES: usize = 8;
/// Samples per GT line: one per KG row.
pub const MAX_LINE_SAMPLES: usize = crate::grid::MAX_GRID_SIDE;
/// Most pixels averaged across a GT line.
pub const MAX_LINE_WIDTH_PX: usize = 7;
/// Most edges considered per GT line and frame (the strongest win).
pub const MAX_EDGES_PER_LINE: usize = 24;
/// Weaker edges per GT line that established tracks may continue on
/// (hysteresis: a track's prediction vouches for them).
pub const MAX_WEAK_EDGES_PER_LINE: usize = 64;
/// Most GTI tracks alive at once, over all lines.
pub const MAX_TRACKS: usize = 128;
/// Observations kept per GTI track (a sliding window over the latest frames).
pub const MAX_OBSERVATIONS: usize = 16;
/// Points of ended GTI tracks kept in the map.
pub const MAX_MAP_POINTS: usize = 64;

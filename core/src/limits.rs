//! Every capacity in one place: the sizes that fix buffers, arrays and
//! accepted inputs (no heap: each buffer is sized by one of these).
//! Algorithm parameters (levels, margins, tolerances) stay with their
//! configs; only what bounds memory or input lives here.

// ---------------------------------------------------------------- camera

/// Largest camera image side we accept: the remap's row ring and pinhole
/// line are sized by it ([`crate::geometry::Rig::new_checked`] refuses more).
pub const MAX_IMAGE_SIDE: u16 = 1024;

/// Camera rows the streaming remap may keep in a pipeline
/// ([`crate::remap::RemapTable::ring_bytes`]): 32 KB, the memory of GPA's
/// compare, idle while the rows stream, lends them ([`crate::gpa::Gpa::lend_ring`]).
/// A level QVGA mount needs 2 rows; a steep tilt or a strong lens (a
/// Duckiebot's: 41 rows of 640 px) more. A rig needing more is refused
/// (`RemapError::RingTooSmall`) on the host and on the target alike.
pub const MAX_RING_BYTES: usize = 32 * 1024;

// --------------------------------------------------------------- KG grid

/// Largest KG grid side, in pixels: the remap table's rows and every
/// per-row buffer downstream are sized by it.
pub const MAX_GRID_SIDE: usize = 256;

/// Default [`crate::grid::GridConfig::max_pixels`]: a 40 KB keyframe, which
/// leaves room for the rest of the pipeline in an STM32F4's 128 KB.
pub const DEFAULT_MAX_PIXELS: usize = 40_000;

// ------------------------------------------------------------------ PGM

/// Largest PGM side the header parser accepts; larger is treated as a
/// damaged header.
pub const MAX_PGM_SIDE: u32 = 8192;

// ------------------------------------------------------------- protocol

/// Longest serial line, `$` to `\n` inclusive. Fits the rig message with
/// every float at its longest shortest-round-trip form (see
/// `protocol::write_f64`).
pub const MAX_LINE: usize = 512;

// ---------------------------------------------------------- GPA detector

/// Largest search radius S (the window is `(2S+1)^2` shifts).
pub const MAX_SEARCH_RADIUS: usize = 3;
/// Cells of the motion estimate's coarse images (each image; larger grids
/// get larger cells).
pub const MAX_COARSE_CELLS: usize = 48 * 48;
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

/// Sectors of the polar obstacle scan (`scan::Scan`): 72 of 2.5 degrees
/// reach 90 degrees either side of straight ahead.
pub const MAX_SCAN_SECTORS: usize = 72;

// ------------------------------------------------------------------- GTI

/// Most GT lines across the AOI (the default uses all of them: each line's
/// samples cost a KG column of RAM).
pub const MAX_LINES: usize = 8;
/// Samples per GT line: one per KG row.
pub const MAX_LINE_SAMPLES: usize = MAX_GRID_SIDE;
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

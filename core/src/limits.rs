//! Fixed capacities: the core has no heap, so every buffer's size is a
//! constant, and they are all here. Algorithm parameters stay with each
//! stage's configuration.

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

//! Every capacity in one place: the sizes that fix buffers, arrays and
//! accepted inputs (no heap: each buffer is sized by one of these).
//! Algorithm parameters (levels, margins, tolerances) stay with their
//! configs; only what bounds memory or input lives here.

// ---------------------------------------------------------------- camera

/// Largest camera image side we accept: the remap's row ring and pinhole
/// line are sized by it ([`crate::geometry::Rig::new_checked`] refuses more).
pub const MAX_IMAGE_SIDE: u16 = 1024;

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

//! Pictures a person looks at: the RGB raster and its drawing (`raster`),
//! one compared frame (`frame`), the run as an animated GIF (`animation`)
//! and as one summary plot (`summary`).

pub mod animation;
pub mod frame;
pub mod raster;
pub mod summary;

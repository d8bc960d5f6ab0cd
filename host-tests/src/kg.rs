//! The KG front end on the host: grid + table + whole-frame remap, built
//! from `flatland_core` exactly as the firmware builds them.

use crate::recording::Frame;
use flatland_core::geometry::Rig;
use flatland_core::grid::{GridConfig, GridError, KgGrid};
use flatland_core::remap::{remap_frame, RemapError, RemapTable, TableError};
use std::fmt;

#[derive(Debug)]
pub enum KgError {
    Grid(GridError),
    Table(TableError),
    Remap(RemapError),
}

impl fmt::Display for KgError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KgError::Grid(e) => write!(f, "KG grid: {e}"),
            KgError::Table(e) => write!(f, "remap table: {e:?}"),
            KgError::Remap(e) => write!(f, "remap: {e}"),
        }
    }
}

impl std::error::Error for KgError {}

/// Grid, table and ring for one rig.
pub struct KgFrontEnd {
    pub grid: KgGrid,
    pub table: Box<RemapTable>,
    /// The remap's camera rows, lent to the streaming pipeline (`detect`).
    pub(crate) ring: Vec<u8>,
}

impl KgFrontEnd {
    pub fn new(rig: &Rig, config: &GridConfig) -> Result<KgFrontEnd, KgError> {
        let grid = KgGrid::for_rig(rig, config).map_err(KgError::Grid)?;
        let mut table = Box::new(RemapTable::EMPTY);
        table.build(rig, &grid).map_err(KgError::Table)?;
        let ring = vec![0; table.ring_bytes()];
        Ok(KgFrontEnd { grid, table, ring })
    }

    /// The KG image of a frame, row-major, invalid pixels 0.
    pub fn remap(&mut self, frame: &Frame) -> Result<Vec<u8>, KgError> {
        let mut out = vec![0; self.grid.len()];
        remap_frame(&self.table, &frame.pixels, &mut self.ring, &mut out).map_err(KgError::Remap)?;
        Ok(out)
    }

    /// kg.toml: the grid a KG image was drawn on.
    pub fn grid_toml(&self) -> String {
        format!(
            "# KG grid: pixel (i, j) centre at x = x_left_mm + i*mm_per_px, z = z_far_mm - j*mm_per_px\nmm_per_px = {}\nx_left_mm = {}\nz_far_mm = {}\nwidth = {}\nheight = {}\n",
            self.grid.mm_per_px, self.grid.x_left_mm, self.grid.z_far_mm, self.grid.width, self.grid.height
        )
    }
}

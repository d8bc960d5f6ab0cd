//! What a board holds: the capacities its buffers are sized by, and the
//! check that a rig fits them. The firmware refuses a rig at start-up with
//! [`FitError`]; the host asks the same of the board before it runs, so a
//! rig the board cannot run is refused on both alike.

use crate::grid::{GridConfig, KgGrid};
use crate::limits::DEFAULT_MAX_PIXELS;

/// A board's buffers (bytes; camera pixels are bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capacity {
    /// The widest camera row.
    pub camera_width: usize,
    /// The streaming remap's ring of camera rows.
    pub ring_bytes: usize,
    /// Each of GPA's two KG images: one grid.
    pub image_bytes: usize,
}

impl Capacity {
    /// The STM32F407 firmware: VGA rows, 4 of them in the ring, and images
    /// of the default grid cap (one in RAM, one in the CCM).
    pub const STM32F4: Capacity = Capacity { camera_width: 640, ring_bytes: 4 * 640, image_bytes: DEFAULT_MAX_PIXELS };

    /// Whether a camera `camera_width` wide, its remap's ring of
    /// `ring_bytes` and `grid` fit.
    pub fn fits(&self, camera_width: usize, ring_bytes: usize, grid: &KgGrid) -> Result<(), FitError> {
        if camera_width > self.camera_width {
            return Err(FitError::CameraTooWide { width: camera_width });
        }
        if ring_bytes > self.ring_bytes {
            return Err(FitError::RingTooSmall { needed: ring_bytes });
        }
        let needed = crate::gpa::Gpa::image_bytes(grid);
        if needed > self.image_bytes {
            return Err(FitError::KeyframeTooLarge { needed });
        }
        Ok(())
    }

    /// The grid choice whose default grids fit this board's images.
    pub fn grid_config(&self) -> GridConfig {
        GridConfig { max_pixels: self.image_bytes, ..GridConfig::default() }
    }
}

/// A rig the board cannot run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FitError {
    /// Camera rows wider than [`Capacity::camera_width`].
    CameraTooWide { width: usize },
    /// The remap needs more camera rows than [`Capacity::ring_bytes`] hold
    /// (a steep tilt or strong distortion).
    RingTooSmall { needed: usize },
    /// A KG image of the grid is larger than [`Capacity::image_bytes`]
    /// (a fixed resolution too fine for the AOI).
    KeyframeTooLarge { needed: usize },
}

impl core::fmt::Display for FitError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FitError::CameraTooWide { width } => write!(f, "camera rows of {width} px are wider than the board's"),
            FitError::RingTooSmall { needed } => write!(f, "the remap needs {needed} B of camera rows, more than the board's ring"),
            FitError::KeyframeTooLarge { needed } => write!(f, "a KG image of {needed} B is larger than the board's"),
        }
    }
}

impl core::error::Error for FitError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_capacity_refuses_with_its_own_error() {
        let board = Capacity::STM32F4;
        let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 255 };
        assert_eq!(board.fits(640, 2_560, &grid), Ok(()));
        assert_eq!(board.fits(641, 2_560, &grid), Err(FitError::CameraTooWide { width: 641 }));
        assert_eq!(board.fits(320, 2_561, &grid), Err(FitError::RingTooSmall { needed: 2_561 }));
        let large = KgGrid { width: 201, height: 201, ..grid };
        assert_eq!(board.fits(320, 640, &large), Err(FitError::KeyframeTooLarge { needed: 40_401 }));
    }
}

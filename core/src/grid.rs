//! The KG grid: the top view (bird's-eye) raster that the remap fills.
//!
//! On flat ground a KG image is a metric map scaled by 1/H, so the grid is
//! described in ground millimetres. Pixel (column i, row j) has its centre at
//! `x = x_left_mm + i * mm_per_px`, `z = z_far_mm - j * mm_per_px`: far at the
//! top, the robot at the bottom, as in the seed's Fig. 2.

use crate::geometry::Rig;
use crate::limits::DEFAULT_MAX_PIXELS;
use libm::ceil;

/// The grid's capacity, defined with the others in [`crate::limits`]; also
/// here because the detectors size their per-row buffers by the grid's.
pub use crate::limits::MAX_GRID_SIDE;

/// How much ground around the AOI the grid covers, and at what resolution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridConfig {
    /// Ground beyond each side of the AOI (robot translation sideways, turns).
    pub margin_lateral_mm: f64,
    /// Ground beyond the far AOI edge; `None` derives it from the AOI:
    /// [`TRAVEL_MARGIN_MM`] for the travel since the keyframe, plus room to
    /// see an obstacle standing on the far edge up to a fifth of the camera
    /// height (a point at height h reprojects H/(H-h) times farther out, so
    /// that is a quarter of the far distance again).
    pub margin_far_mm: Option<f64>,
    /// Ground before the near AOI edge (the shift search).
    pub margin_near_mm: f64,
    /// Fixed resolution; `None` chooses it from the rig. With a fixed
    /// resolution the far margin shrinks as needed to fit the 256 cap.
    pub mm_per_px: Option<f64>,
    /// Most pixels a chosen grid may have: the keyframe a target stores is
    /// one grid, so RAM bounds it. A fixed `mm_per_px` is not bound by it.
    pub max_pixels: usize,
}

/// Far margin for the travel between a keyframe and a later frame.
pub const TRAVEL_MARGIN_MM: f64 = 100.0;
/// Far margin per mm of far AOI distance, for obstacles standing on the far edge.
pub const LOOK_BEYOND_FRACTION: f64 = 0.25;

impl GridConfig {
    /// No margins: the grid is exactly the AOI (the full-frame benchmark,
    /// docs/PERFORMANCE.md). An AOI of 255 x 255 steps of `mm_per_px`
    /// gives a [`MAX_GRID_SIDE`] x [`MAX_GRID_SIDE`] grid.
    pub fn without_margins(mm_per_px: Option<f64>) -> GridConfig {
        GridConfig { margin_lateral_mm: 0.0, margin_far_mm: Some(0.0), margin_near_mm: 0.0, mm_per_px, ..GridConfig::default() }
    }
}

impl Default for GridConfig {
    fn default() -> Self {
        GridConfig {
            margin_lateral_mm: 150.0,
            margin_far_mm: None,
            margin_near_mm: 60.0,
            mm_per_px: None,
            max_pixels: DEFAULT_MAX_PIXELS,
        }
    }
}

/// One of the grid's margins around the AOI ([`GridConfig`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GridMargin {
    /// Beyond the left and right AOI edges.
    Lateral,
    /// Beyond the far AOI edge.
    Far,
    /// Before the near AOI edge.
    Near,
}

/// Why no grid could be chosen for a rig.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GridError {
    /// This margin is negative or not finite.
    Margin(GridMargin),
    /// `mm_per_px` is not positive and finite, or `max_pixels` is 0.
    Resolution,
    /// The requested resolution gives a grid side above [`MAX_GRID_SIDE`].
    TooLarge,
    /// The near AOI row is not in view, so no resolution can be derived.
    NotInView,
}

impl core::fmt::Display for GridError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            GridError::Margin(GridMargin::Lateral) => "the grid's lateral margin must be finite and >= 0",
            GridError::Margin(GridMargin::Far) => "the grid's far margin must be finite and >= 0",
            GridError::Margin(GridMargin::Near) => "the grid's near margin must be finite and >= 0",
            GridError::Resolution => "grid mm_per_px must be finite and > 0, max_pixels > 0",
            GridError::TooLarge => "grid would exceed 256x256 at this resolution",
            GridError::NotInView => "the AOI's near edge (near_mm) is not in view",
        })
    }
}

impl core::error::Error for GridError {}

/// Columns and rows of a grid `extent_x` x `extent_z` mm at `mm_per_px`,
/// both edges included.
fn sides(extent_x: f64, extent_z: f64, mm_per_px: f64) -> (usize, usize) {
    (ceil(extent_x / mm_per_px) as usize + 1, ceil(extent_z / mm_per_px) as usize + 1)
}

/// Resolution is rounded up to a multiple of this (mm), so figures stay readable.
const RESOLUTION_QUANTUM_MM: f64 = 1.0 / 16.0;

/// A KG grid; see the module docs for the pixel-centre convention.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KgGrid {
    pub mm_per_px: f64,
    pub x_left_mm: f64,
    pub z_far_mm: f64,
    pub width: u16,
    pub height: u16,
}

impl KgGrid {
    /// Chooses the grid for a rig: the AOI plus margins, at the resolution of
    /// the camera's longitudinal ground footprint at the nearest AOI row (the
    /// finest the camera resolves there), coarsened only as far as the
    /// 256x256 cap demands.
    pub fn for_rig(rig: &Rig, config: &GridConfig) -> Result<KgGrid, GridError> {
        let aoi = rig.aoi();
        let margin_far = config.margin_far_mm.unwrap_or(TRAVEL_MARGIN_MM + LOOK_BEYOND_FRACTION * aoi.far_mm);
        let margins = [
            (config.margin_lateral_mm, GridMargin::Lateral),
            (margin_far, GridMargin::Far),
            (config.margin_near_mm, GridMargin::Near),
        ];
        if let Some(&(_, margin)) = margins.iter().find(|(mm, _)| !(mm.is_finite() && *mm >= 0.0)) {
            return Err(GridError::Margin(margin));
        }
        if config.max_pixels == 0 {
            return Err(GridError::Resolution);
        }
        let extent_x = 2.0 * (aoi.half_width_mm + config.margin_lateral_mm);
        let z_near = aoi.near_mm - config.margin_near_mm;
        let mut z_far = aoi.far_mm + margin_far;
        let cap = (MAX_GRID_SIDE - 1) as f64;
        let mm_per_px = match config.mm_per_px {
            Some(fixed) => {
                if !(fixed.is_finite() && fixed > 0.0) {
                    return Err(GridError::Resolution);
                }
                // Give up far margin before refusing the resolution.
                z_far = z_far.min(z_near + cap * fixed);
                if extent_x / fixed > cap || z_far < aoi.far_mm {
                    return Err(GridError::TooLarge);
                }
                fixed
            }
            None => {
                let (lateral, longitudinal) =
                    rig.ground_footprint_mm(0.0, aoi.near_mm).ok_or(GridError::NotInView)?;
                let finest = longitudinal.max(lateral);
                let extent_z = z_far - z_near;
                let by_pixels = libm::sqrt(extent_x * extent_z / config.max_pixels.max(1) as f64);
                let chosen = finest.max(extent_x / cap).max(extent_z / cap).max(by_pixels);
                let mut quanta = ceil(chosen / RESOLUTION_QUANTUM_MM);
                // The sides round up and count both edges: coarser by a
                // quantum until the pixels fit (a target's image buffers
                // hold `max_pixels`; no grid has fewer than 2 x 2).
                let pixels = |quanta: f64| {
                    let (width, height) = sides(extent_x, extent_z, quanta * RESOLUTION_QUANTUM_MM);
                    width * height
                };
                while pixels(quanta) > config.max_pixels.max(4) {
                    quanta += 1.0;
                }
                quanta * RESOLUTION_QUANTUM_MM
            }
        };
        let extent_z = z_far - z_near;
        let (width, height) = sides(extent_x, extent_z, mm_per_px);
        if width > MAX_GRID_SIDE || height > MAX_GRID_SIDE {
            return Err(GridError::TooLarge);
        }
        Ok(KgGrid {
            mm_per_px,
            // Symmetric about the robot's axis: column centres span +-x.
            x_left_mm: -((width - 1) as f64) * mm_per_px / 2.0,
            z_far_mm: z_far,
            width: width as u16,
            height: height as u16,
        })
    }

    pub fn width(&self) -> usize {
        usize::from(self.width)
    }
    pub fn height(&self) -> usize {
        usize::from(self.height)
    }
    pub fn len(&self) -> usize {
        self.width() * self.height()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Ground point (mm) of a pixel position (fractional positions allowed).
    pub fn pixel_to_ground(&self, column: f64, row: f64) -> (f64, f64) {
        (self.x_left_mm + column * self.mm_per_px, self.z_far_mm - row * self.mm_per_px)
    }

    /// Pixel position (fractional) of a ground point.
    pub fn ground_to_pixel(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        ((x_mm - self.x_left_mm) / self.mm_per_px, (self.z_far_mm - z_mm) / self.mm_per_px)
    }

    /// The AOI as a pixel rectangle: columns `[left, right)`, rows `[top, bottom)`,
    /// the pixels whose centres lie inside the AOI.
    pub fn aoi_pixels(&self, rig: &Rig) -> PixelRect {
        let aoi = rig.aoi();
        let (left, top) = self.ground_to_pixel(-aoi.half_width_mm, aoi.far_mm);
        let (right, bottom) = self.ground_to_pixel(aoi.half_width_mm, aoi.near_mm);
        let clamp_w = |v: f64| (v.max(0.0) as usize).min(self.width());
        let clamp_h = |v: f64| (v.max(0.0) as usize).min(self.height());
        PixelRect {
            left: clamp_w(ceil(left - 1e-9)),
            right: clamp_w(libm::floor(right + 1e-9) + 1.0),
            top: clamp_h(ceil(top - 1e-9)),
            bottom: clamp_h(libm::floor(bottom + 1e-9) + 1.0),
        }
    }
}

/// A half-open pixel rectangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct PixelRect {
    pub left: usize,
    pub right: usize,
    pub top: usize,
    pub bottom: usize,
}

impl PixelRect {
    pub fn width(&self) -> usize {
        self.right.saturating_sub(self.left)
    }
    pub fn height(&self) -> usize {
        self.bottom.saturating_sub(self.top)
    }
    pub fn area(&self) -> usize {
        self.width() * self.height()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> Rig {
        crate::geometry::tests::sample_rig()
    }

    #[test]
    fn grid_covers_aoi_within_cap() {
        let rig = rig();
        let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
        assert!(grid.width() <= MAX_GRID_SIDE && grid.height() <= MAX_GRID_SIDE);
        let aoi = grid.aoi_pixels(&rig);
        let (x, z) = grid.pixel_to_ground(aoi.left as f64, aoi.top as f64);
        assert!(x >= -250.0 && x < -250.0 + grid.mm_per_px && z <= 1400.0 && z > 1400.0 - grid.mm_per_px);
        let (x, z) = grid.pixel_to_ground((aoi.right - 1) as f64, (aoi.bottom - 1) as f64);
        assert!(x <= 250.0 && x > 250.0 - grid.mm_per_px && z >= 450.0 && z < 450.0 + grid.mm_per_px);
    }

    /// The sides round up and count both edges; the grid still fits the
    /// pixels a target holds (video_rate's 161 x 251 did not fit 40,000).
    #[test]
    fn a_chosen_grid_fits_its_pixel_budget() {
        let rig = rig();
        for max_pixels in (2_000..60_000).step_by(997) {
            let grid = KgGrid::for_rig(&rig, &GridConfig { max_pixels, ..GridConfig::default() }).unwrap();
            assert!(grid.len() <= max_pixels, "{max_pixels}: {}x{}", grid.width, grid.height);
        }
    }

    #[test]
    fn fixed_resolution_is_honoured_or_refused() {
        let rig = rig();
        let config = GridConfig { mm_per_px: Some(5.0), ..GridConfig::default() };
        assert_eq!(KgGrid::for_rig(&rig, &config).unwrap().mm_per_px, 5.0);
        let config = GridConfig { mm_per_px: Some(1.0), ..GridConfig::default() };
        assert_eq!(KgGrid::for_rig(&rig, &config), Err(GridError::TooLarge));
        // A fine fixed resolution keeps the AOI and gives up far margin.
        let config = GridConfig { mm_per_px: Some(4.0), ..GridConfig::default() };
        let grid = KgGrid::for_rig(&rig, &config).unwrap();
        assert!(grid.height() <= MAX_GRID_SIDE && grid.z_far_mm >= 1400.0);
        let config = GridConfig { mm_per_px: Some(f64::NAN), ..GridConfig::default() };
        assert_eq!(KgGrid::for_rig(&rig, &config), Err(GridError::Resolution));
    }

    #[test]
    fn a_bad_margin_is_named() {
        let rig = rig();
        let cases = [
            (GridConfig { margin_lateral_mm: -1.0, ..GridConfig::default() }, GridMargin::Lateral),
            (GridConfig { margin_far_mm: Some(f64::INFINITY), ..GridConfig::default() }, GridMargin::Far),
            (GridConfig { margin_near_mm: f64::NAN, ..GridConfig::default() }, GridMargin::Near),
        ];
        for (config, margin) in cases {
            assert_eq!(KgGrid::for_rig(&rig, &config), Err(GridError::Margin(margin)));
        }
    }
}

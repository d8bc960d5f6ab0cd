//! What core's integration tests share.

use flatland_core::geometry::{Aoi, Intrinsics, Mount, Rig};

/// flat_marks' rig on a camera `side` pixels square (fx scaled with the
/// side): 400 mm high, 32 degrees down, the AOI 250 mm either side from
/// 450 to 1400 mm.
pub fn flat_marks_rig(side: u16) -> Rig {
    let f = 240.0 * f64::from(side) / 256.0;
    let c = (f64::from(side) - 1.0) / 2.0;
    Rig::new_checked(
        Intrinsics { width: side, height: side, fx: f, fy: f, cx: c, cy: c, distortion: None, readout_ms: 0.0 },
        Mount::level(400.0, 32.0),
        Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 },
    )
    .expect("flat_marks rig")
}

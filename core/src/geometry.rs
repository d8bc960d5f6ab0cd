//! Camera geometry: the rig and the seed's equations (1)-(7), with inverses.
//!
//! This is the one home of the geometry; the remap table, the detectors, the
//! host CLI and the firmware all call it.
//!
//! Conventions (RECORDING.md):
//! - Robot frame (the seed's RCC): origin on the ground under the optical
//!   centre, x right, y up, z forward, mm.
//! - Image: OpenCV convention, u right, v **down**, origin at the centre of
//!   the top-left pixel. The seed measures v up from the principal point:
//!   `v_seed = -(v - cy)`, `u_seed = u - cx`.
//! - Camera at (0, H, 0), optical axis in the y-z plane, tilted down by alpha.
//! - Equation (5) is used with f_v in the numerator (the seed prints f_u).
//!
//! Double precision throughout: this runs once per rig (table build) or a
//! few times per frame, and `libm` makes host and target bit-identical.

// `!(x > 0.0)` is deliberate throughout: it also refuses NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use libm::{cos, hypot, sin, sqrt};

use crate::limits::MAX_IMAGE_SIDE;

/// OpenCV plumb_bob lens distortion coefficients. In rig.toml and
/// camera_info: the list `[k1, k2, p1, p2, k3]`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize), serde(from = "[f64; 5]"))]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

/// Pinhole intrinsics in pixels, with optional distortion (rig.toml's `[camera]`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize), serde(deny_unknown_fields))]
pub struct Intrinsics {
    pub width: u16,
    pub height: u16,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: Option<Distortion>,
    /// Rolling shutter: the time the sensor takes to read its rows out, top
    /// first, ms (rig.toml's `readout_ms`; 0, the default, is a global
    /// shutter; negative when the rows are read bottom first). Row v is
    /// captured `readout_ms * ((v + 0.5) / height - 0.5)` after the frame's
    /// time, which is its middle row's. Only the host's calibration models
    /// it: the remap and the firmware do not, and `$FLRIG` does not carry it.
    #[cfg_attr(feature = "serde", serde(default))]
    pub readout_ms: f64,
}

/// How the camera sits on the robot (rig.toml's `[mount]`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize), serde(deny_unknown_fields))]
pub struct Mount {
    /// H: optical centre above the ground, mm.
    pub height_mm: f64,
    /// alpha: optical axis below the horizontal, degrees, in (0, 90).
    pub tilt_deg: f64,
    /// Roll about the optical axis, degrees, positive when the camera's
    /// right side dips; within +-[`MAX_MOUNT_ROLL_DEG`]. 0 on a level mount
    /// (and when rig.toml leaves it out).
    #[cfg_attr(feature = "serde", serde(default))]
    pub roll_deg: f64,
    /// The optical axis turned from the robot's z axis, degrees, positive to
    /// the left; within +-[`MAX_MOUNT_YAW_DEG`]. 0 on a straight mount.
    #[cfg_attr(feature = "serde", serde(default))]
    pub yaw_deg: f64,
}

/// Largest mount roll accepted: a crooked mount, not a camera on its side.
pub const MAX_MOUNT_ROLL_DEG: f64 = 30.0;
/// Largest mount yaw accepted: a crooked mount, not a camera looking sideways.
pub const MAX_MOUNT_YAW_DEG: f64 = 30.0;

impl Mount {
    /// A mount with the optical axis in the robot's y-z plane and no roll.
    pub const fn level(height_mm: f64, tilt_deg: f64) -> Mount {
        Mount { height_mm, tilt_deg, roll_deg: 0.0, yaw_deg: 0.0 }
    }

    /// True when the mount has roll or yaw (the general rotation applies).
    pub fn is_crooked(&self) -> bool {
        self.roll_deg != 0.0 || self.yaw_deg != 0.0
    }
}

/// Area of interest on the ground, robot frame, mm: |x| <= half_width, near <= z <= far.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize), serde(deny_unknown_fields))]
pub struct Aoi {
    pub half_width_mm: f64,
    pub near_mm: f64,
    pub far_mm: f64,
}

/// An edge of the AOI rectangle: what a refused AOI names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AoiEdge {
    /// z = near_mm.
    Near,
    /// z = far_mm.
    Far,
    /// x = -half_width_mm.
    Left,
    /// x = +half_width_mm.
    Right,
}

/// Why a rig was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RigError {
    /// A value is NaN or infinite.
    NotFinite,
    /// Image width or height is 0 or above [`MAX_IMAGE_SIDE`].
    ImageSize,
    /// fx or fy is not positive.
    FocalLength,
    /// The principal point lies outside the image.
    PrincipalPoint,
    /// Mount height is not positive.
    MountHeight,
    /// Tilt is outside (0, 90) degrees.
    Tilt,
    /// Mount roll is beyond +-[`MAX_MOUNT_ROLL_DEG`].
    Roll,
    /// Mount yaw is beyond +-[`MAX_MOUNT_YAW_DEG`].
    Yaw,
    /// The distortion is not monotonic (cannot be inverted) over the image.
    Distortion,
    /// The AOI is empty (half width or depth not positive).
    AoiEmpty,
    /// Part of the AOI is behind the camera (near edge not ahead of the robot).
    AoiBehindCamera,
    /// The AOI's far edge lies at or beyond the horizon.
    AoiBeyondHorizon,
    /// Part of the AOI projects outside the image, across the image border
    /// that this edge faces (near: the bottom, far: the top, left and right:
    /// the sides).
    AoiOutsideImage(AoiEdge),
}

impl core::fmt::Display for RigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RigError::NotFinite => "a rig value is NaN or infinite",
            RigError::ImageSize => "image width/height must be 1..=1024",
            RigError::FocalLength => "focal length fx/fy must be positive",
            RigError::PrincipalPoint => "principal point (cx, cy) lies outside the image",
            RigError::MountHeight => "mount height must be positive",
            RigError::Tilt => "tilt must be inside (0, 90) degrees",
            RigError::Roll => "mount roll must be within +-30 degrees",
            RigError::Yaw => "mount yaw must be within +-30 degrees",
            RigError::Distortion => "lens distortion cannot be inverted over the image",
            RigError::AoiEmpty => "AOI must have positive half width and far > near",
            RigError::AoiBehindCamera => "AOI near edge must be ahead of the robot (near > 0)",
            RigError::AoiBeyondHorizon => "AOI far edge (far_mm) reaches the horizon",
            RigError::AoiOutsideImage(AoiEdge::Near) => "AOI near edge (near_mm) lies below the bottom of the image",
            RigError::AoiOutsideImage(AoiEdge::Far) => "AOI far edge (far_mm) lies above the top of the image",
            RigError::AoiOutsideImage(AoiEdge::Left) => "AOI left edge (half_width_mm) lies beyond the left of the image",
            RigError::AoiOutsideImage(AoiEdge::Right) => "AOI right edge (half_width_mm) lies beyond the right of the image",
        })
    }
}

impl core::error::Error for RigError {}

/// A point in the seed's KG plane: K = x / (H - y), G = z / (H - y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kg {
    pub k: f64,
    pub g: f64,
}

/// An image position in OpenCV pixel coordinates (v down).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pixel {
    pub u: f64,
    pub v: f64,
}

/// A point in the robot frame, mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// A validated rig: camera, mount and AOI. Construct with [`Rig::new_checked`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rig {
    camera: Intrinsics,
    mount: Mount,
    aoi: Aoi,
    sin_tilt: f64,
    cos_tilt: f64,
    /// Robot frame (relative to the optical centre) -> camera frame (X right,
    /// Y up, Z along the axis) when the mount has roll or yaw; None on a
    /// level mount, which keeps the seed's own arithmetic (bit for bit).
    rotation: Option<[[f64; 3]; 3]>,
    /// Undistorted normalised radius² up to which the distortion is monotonic
    /// and which covers the whole image (infinite without distortion).
    max_radius_sq: f64,
}

/// Newton iterations for undistortion; converges in 3-5 on sane lenses.
const UNDISTORT_ITERATIONS: usize = 20;
/// Round-trip tolerance (pixels) for accepting an undistortion.
const UNDISTORT_TOLERANCE_PX: f64 = 1e-4;

impl From<[f64; 5]> for Distortion {
    fn from(coefficients: [f64; 5]) -> Distortion {
        Distortion::from_coefficients(coefficients)
    }
}

impl Distortion {
    /// From OpenCV's coefficient order `[k1, k2, p1, p2, k3]` (rig.toml, the wire).
    pub const fn from_coefficients([k1, k2, p1, p2, k3]: [f64; 5]) -> Distortion {
        Distortion { k1, k2, p1, p2, k3 }
    }

    /// In OpenCV's coefficient order `[k1, k2, p1, p2, k3]`.
    pub const fn coefficients(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Applies plumb_bob to normalised coordinates (x right, y down).
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Jacobian of [`Distortion::apply`]: (dxd/dx, dxd/dy, dyd/dx, dyd/dy).
    fn jacobian(&self, x: f64, y: f64) -> (f64, f64, f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d(radial)/d(r2)
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let dxx = radial + x * dradial * 2.0 * x + 2.0 * self.p1 * y + self.p2 * 6.0 * x;
        let dxy = x * dradial * 2.0 * y + 2.0 * self.p1 * x + self.p2 * 2.0 * y;
        let dyx = y * dradial * 2.0 * x + self.p1 * 2.0 * x + 2.0 * self.p2 * y;
        let dyy = radial + y * dradial * 2.0 * y + self.p1 * 6.0 * y + 2.0 * self.p2 * x;
        (dxx, dxy, dyx, dyy)
    }

    /// Inverts [`Distortion::apply`] by Newton's method.
    pub fn invert(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let (fx, fy) = self.apply(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            let (a, b, c, d) = self.jacobian(x, y);
            let det = a * d - b * c;
            if !(det > 1e-9) {
                return None;
            }
            x -= (d * ex - b * ey) / det;
            y -= (a * ey - c * ex) / det;
            if !(x.is_finite() && y.is_finite()) {
                return None;
            }
        }
        let (fx, fy) = self.apply(x, y);
        let err = (fx - xd).abs() + (fy - yd).abs();
        (err < 1e-9).then_some((x, y))
    }

    fn all_finite(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3].iter().all(|c| c.is_finite())
    }
}

fn is_finite_all(values: &[f64]) -> bool {
    values.iter().all(|v| v.is_finite())
}

impl Rig {
    /// Validates and builds a rig.
    pub fn new_checked(camera: Intrinsics, mount: Mount, aoi: Aoi) -> Result<Rig, RigError> {
        let numbers = [
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
            camera.readout_ms,
            mount.height_mm,
            mount.tilt_deg,
            mount.roll_deg,
            mount.yaw_deg,
            aoi.half_width_mm,
            aoi.near_mm,
            aoi.far_mm,
        ];
        if !is_finite_all(&numbers) || !camera.distortion.is_none_or(|d| d.all_finite()) {
            return Err(RigError::NotFinite);
        }
        if camera.width == 0
            || camera.height == 0
            || camera.width > MAX_IMAGE_SIDE
            || camera.height > MAX_IMAGE_SIDE
        {
            return Err(RigError::ImageSize);
        }
        if !(camera.fx > 0.0 && camera.fy > 0.0) {
            return Err(RigError::FocalLength);
        }
        let (w, h) = (f64::from(camera.width), f64::from(camera.height));
        if !(camera.cx >= -0.5 && camera.cx <= w - 0.5 && camera.cy >= -0.5 && camera.cy <= h - 0.5) {
            return Err(RigError::PrincipalPoint);
        }
        if !(mount.height_mm > 0.0) {
            return Err(RigError::MountHeight);
        }
        if !(mount.tilt_deg > 0.0 && mount.tilt_deg < 90.0) {
            return Err(RigError::Tilt);
        }
        if !(mount.roll_deg.abs() <= MAX_MOUNT_ROLL_DEG) {
            return Err(RigError::Roll);
        }
        if !(mount.yaw_deg.abs() <= MAX_MOUNT_YAW_DEG) {
            return Err(RigError::Yaw);
        }
        if !(aoi.half_width_mm > 0.0 && aoi.far_mm > aoi.near_mm) {
            return Err(RigError::AoiEmpty);
        }
        if !(aoi.near_mm > 0.0) {
            return Err(RigError::AoiBehindCamera);
        }
        let tilt = mount.tilt_deg.to_radians();
        let mut rig = Rig {
            camera,
            mount,
            aoi,
            sin_tilt: sin(tilt),
            cos_tilt: cos(tilt),
            rotation: mount.is_crooked().then(|| mount_rotation(&mount)),
            max_radius_sq: f64::INFINITY,
        };
        if let Some(distortion) = camera.distortion {
            rig.max_radius_sq = monotonic_radius_sq(&camera, &distortion)?;
        }
        rig.check_aoi_in_view()?;
        Ok(rig)
    }

    pub fn camera(&self) -> &Intrinsics {
        &self.camera
    }
    pub fn mount(&self) -> &Mount {
        &self.mount
    }
    pub fn aoi(&self) -> &Aoi {
        &self.aoi
    }
    pub fn height_mm(&self) -> f64 {
        self.mount.height_mm
    }

    /// The AOI's four edges, sampled (edge midpoints matter with distortion),
    /// must project inside the image, ahead of the camera and below the
    /// horizon. A point outside the image names the AOI edge that faces the
    /// image border it crosses most.
    fn check_aoi_in_view(&self) -> Result<(), RigError> {
        let a = &self.aoi;
        // Every finite ground point ahead lies below the horizon, so "beyond
        // the horizon" means within one pixel of it, where the ground is
        // compressed to nothing and the KG image would be empty.
        let horizon_margin = 1.0 / self.camera.fy;
        const SAMPLES: usize = 8;
        for i in 0..=SAMPLES {
            let t = i as f64 / SAMPLES as f64;
            let x = -a.half_width_mm + 2.0 * a.half_width_mm * t;
            let z = a.near_mm + (a.far_mm - a.near_mm) * t;
            let edge_points = [
                (x, a.near_mm),
                (x, a.far_mm),
                (-a.half_width_mm, z),
                (a.half_width_mm, z),
            ];
            for (px, pz) in edge_points {
                let (x_cam, y_cam, z_cam) = self.camera_ray(Point3 { x: px, y: 0.0, z: pz });
                let beyond = match &self.rotation {
                    None => z_cam <= 0.0 || y_cam / z_cam >= self.sin_tilt / self.cos_tilt - horizon_margin,
                    // The horizon is the line a x + b y + c = 0 of normalised
                    // (x, y up) coordinates whose rays are level (robot y = 0):
                    // (a, b, c) is the rotation's y column. Below it is negative.
                    Some(r) => {
                        let (a, b, c) = (r[0][1], r[1][1], r[2][1]);
                        z_cam <= 0.0 || (a * x_cam / z_cam + b * y_cam / z_cam + c) / hypot(a, b) >= -horizon_margin
                    }
                };
                if beyond {
                    return Err(RigError::AoiBeyondHorizon);
                }
                let edge = match self.ground_to_pixel(px, pz) {
                    Some(pixel) if self.pixel_in_image(pixel) => continue,
                    Some(pixel) => self.edge_facing(pixel),
                    // Beyond the lens's reach: the pinhole pixel tells the side.
                    None => self.ground_to_undistorted_pixel(px, pz).map_or(AoiEdge::Far, |p| self.edge_facing(p)),
                };
                return Err(RigError::AoiOutsideImage(edge));
            }
        }
        Ok(())
    }

    /// The AOI edge that faces the image border a pixel lies farthest beyond
    /// (or, inside the image, nearest to): the bottom of the image sees the
    /// near edge, the top the far edge, the sides the left and right edges.
    fn edge_facing(&self, p: Pixel) -> AoiEdge {
        let (last_u, last_v) = (f64::from(self.camera.width) - 1.0, f64::from(self.camera.height) - 1.0);
        let beyond = [(p.v - last_v, AoiEdge::Near), (-p.v, AoiEdge::Far), (-p.u, AoiEdge::Left), (p.u - last_u, AoiEdge::Right)];
        beyond.into_iter().max_by(|a, b| a.0.total_cmp(&b.0)).map_or(AoiEdge::Far, |(_, edge)| edge)
    }

    /// True if the pixel lies inside the image (pixel centres span 0..=w-1).
    pub fn pixel_in_image(&self, p: Pixel) -> bool {
        p.u >= 0.0
            && p.v >= 0.0
            && p.u <= f64::from(self.camera.width) - 1.0
            && p.v <= f64::from(self.camera.height) - 1.0
    }

    /// Equation (1): robot frame -> camera frame (X right, Y up in the image, Z along the axis).
    fn camera_ray(&self, p: Point3) -> (f64, f64, f64) {
        let y_rel = p.y - self.mount.height_mm;
        if let Some(r) = &self.rotation {
            let q = [p.x, y_rel, p.z];
            let row = |i: usize| r[i][0] * q[0] + r[i][1] * q[1] + r[i][2] * q[2];
            return (row(0), row(1), row(2));
        }
        let x_cam = p.x;
        let y_cam = p.z * self.sin_tilt + y_rel * self.cos_tilt;
        let z_cam = p.z * self.cos_tilt - y_rel * self.sin_tilt;
        (x_cam, y_cam, z_cam)
    }

    /// Normalised (x right, y down) undistorted coordinates -> pixel, with distortion.
    pub fn normalised_to_pixel(&self, xn: f64, yn: f64) -> Option<Pixel> {
        let (xd, yd) = match &self.camera.distortion {
            None => (xn, yn),
            Some(d) => {
                if xn * xn + yn * yn > self.max_radius_sq {
                    return None; // folds back: not seen through this lens
                }
                d.apply(xn, yn)
            }
        };
        Some(Pixel { u: self.camera.fx * xd + self.camera.cx, v: self.camera.fy * yd + self.camera.cy })
    }

    /// Pixel -> normalised undistorted coordinates (x right, y down).
    pub fn pixel_to_normalised(&self, p: Pixel) -> Option<(f64, f64)> {
        let xd = (p.u - self.camera.cx) / self.camera.fx;
        let yd = (p.v - self.camera.cy) / self.camera.fy;
        match &self.camera.distortion {
            None => Some((xd, yd)),
            Some(d) => d.invert(xd, yd),
        }
    }

    /// Largest undistorted normalised radius² that the lens maps monotonically
    /// (infinite without distortion). Points beyond it are not seen: the exact
    /// projection refuses them, and so does the remap table.
    pub fn max_undistorted_radius_sq(&self) -> f64 {
        self.max_radius_sq
    }

    /// Robot frame -> camera frame rotation (X right, Y up, Z along the
    /// axis) of this mount, also for a level one (the seed's equation (1)).
    pub fn camera_rotation(&self) -> [[f64; 3]; 3] {
        self.rotation.unwrap_or_else(|| mount_rotation(&self.mount))
    }

    /// A ground point in camera axes (x right, y down, z along the axis), mm
    /// from the optical centre: the remap's rows are affine in it.
    pub fn ground_to_camera(&self, x_mm: f64, z_mm: f64) -> (f64, f64, f64) {
        let (x_cam, y_cam, z_cam) = self.camera_ray(Point3 { x: x_mm, y: 0.0, z: z_mm });
        (x_cam, -y_cam, z_cam)
    }

    /// A ground point -> normalised undistorted coordinates (x right, y down),
    /// None if behind the camera.
    pub fn ground_to_normalised(&self, x_mm: f64, z_mm: f64) -> Option<(f64, f64)> {
        let (x_cam, y_cam, z_cam) = self.camera_ray(Point3 { x: x_mm, y: 0.0, z: z_mm });
        if !(z_cam > 1e-9) {
            return None;
        }
        Some((x_cam / z_cam, -y_cam / z_cam))
    }

    /// A ground point -> pixel of an ideal pinhole camera with the same
    /// intrinsics (no distortion). None if behind the camera.
    pub fn ground_to_undistorted_pixel(&self, x_mm: f64, z_mm: f64) -> Option<Pixel> {
        let (x_cam, y_cam, z_cam) = self.camera_ray(Point3 { x: x_mm, y: 0.0, z: z_mm });
        if !(z_cam > 1e-9) {
            return None;
        }
        Some(Pixel { u: self.camera.fx * x_cam / z_cam + self.camera.cx, v: -self.camera.fy * y_cam / z_cam + self.camera.cy })
    }

    /// Equations (1)+(2): a point in the robot frame -> pixel (None if behind the camera).
    pub fn point_to_pixel(&self, p: Point3) -> Option<Pixel> {
        let (x_cam, y_cam, z_cam) = self.camera_ray(p);
        if !(z_cam > 1e-9) {
            return None;
        }
        // v_seed = f_v Y/Z points up; the image's v points down.
        self.normalised_to_pixel(x_cam / z_cam, -y_cam / z_cam)
    }

    /// A ground point (y = 0) -> pixel.
    pub fn ground_to_pixel(&self, x_mm: f64, z_mm: f64) -> Option<Pixel> {
        self.point_to_pixel(Point3 { x: x_mm, y: 0.0, z: z_mm })
    }

    /// A point at height h above ground position (x, z) -> pixel.
    #[cfg(test)]
    fn point_at_height_to_pixel(&self, x_mm: f64, z_mm: f64, h_mm: f64) -> Option<Pixel> {
        self.point_to_pixel(Point3 { x: x_mm, y: h_mm, z: z_mm })
    }

    /// Equations (5)+(6): pixel -> (K, G). None above the horizon.
    pub fn pixel_to_kg(&self, p: Pixel) -> Option<Kg> {
        let (xn, yn) = self.pixel_to_normalised(p)?;
        if let Some(r) = &self.rotation {
            // The ray in the robot frame (rotation transposed); K and G are
            // its x and z over its drop -y.
            let ray = [xn, -yn, 1.0];
            let column = |j: usize| r[0][j] * ray[0] + r[1][j] * ray[1] + r[2][j] * ray[2];
            let drop = -column(1);
            if !(drop > 1e-12) {
                return None;
            }
            return Some(Kg { k: column(0) / drop, g: column(2) / drop });
        }
        // In the seed's terms u/f_u = xn and v/f_v = -yn (v up).
        let v_over_fv = -yn;
        let denominator = self.sin_tilt - v_over_fv * self.cos_tilt;
        if !(denominator > 1e-12) {
            return None;
        }
        let g = (self.cos_tilt + v_over_fv * self.sin_tilt) / denominator; // (5), f_v version
        let k = xn * (g * self.cos_tilt + self.sin_tilt); // (6)
        Some(Kg { k, g })
    }

    /// Inverse of (5)+(6): (K, G) -> pixel. (K, G) is a ray through the optical centre.
    #[cfg(test)]
    fn kg_to_pixel(&self, kg: Kg) -> Option<Pixel> {
        // Any point on the ray: y' = H - y = 1 mm.
        self.point_to_pixel(Point3 { x: kg.k, y: self.mount.height_mm - 1.0, z: kg.g })
    }

    /// Equations (3)+(4): (K, G) and a height h -> point in the robot frame.
    pub fn kg_to_point(&self, kg: Kg, h_mm: f64) -> Point3 {
        let y_prime = self.mount.height_mm - h_mm;
        Point3 { x: kg.k * y_prime, y: h_mm, z: kg.g * y_prime }
    }

    /// Pixel -> ground point (x, z) in mm, None above the horizon.
    pub fn pixel_to_ground(&self, p: Pixel) -> Option<(f64, f64)> {
        let kg = self.pixel_to_kg(p)?;
        let point = self.kg_to_point(kg, 0.0);
        Some((point.x, point.z))
    }

    /// Ground footprint of one camera pixel at ground point (x, z): (lateral, longitudinal) mm.
    pub fn ground_footprint_mm(&self, x_mm: f64, z_mm: f64) -> Option<(f64, f64)> {
        let centre = self.ground_to_pixel(x_mm, z_mm)?;
        let right = self.pixel_to_ground(Pixel { u: centre.u + 0.5, v: centre.v })?;
        let left = self.pixel_to_ground(Pixel { u: centre.u - 0.5, v: centre.v })?;
        let down = self.pixel_to_ground(Pixel { u: centre.u, v: centre.v + 0.5 })?;
        let up = self.pixel_to_ground(Pixel { u: centre.u, v: centre.v - 0.5 })?;
        let lateral = hypot(right.0 - left.0, right.1 - left.1);
        let longitudinal = hypot(up.0 - down.0, up.1 - down.1);
        Some((lateral, longitudinal))
    }

}

/// Robot frame -> camera frame (X right, Y up, Z along the axis) of a
/// crooked mount: yaw about the robot's vertical axis (the axis turns left
/// for positive yaw), then the tilt down about the yawed x axis, then the
/// roll about the optical axis (the camera's right side dips for positive
/// roll). With roll = yaw = 0 it is the seed's equation (1).
fn mount_rotation(mount: &Mount) -> [[f64; 3]; 3] {
    let (sin_y, cos_y) = (sin(mount.yaw_deg.to_radians()), cos(mount.yaw_deg.to_radians()));
    let (sin_t, cos_t) = (sin(mount.tilt_deg.to_radians()), cos(mount.tilt_deg.to_radians()));
    let (sin_r, cos_r) = (sin(mount.roll_deg.to_radians()), cos(mount.roll_deg.to_radians()));
    let yaw = [[cos_y, 0.0, sin_y], [0.0, 1.0, 0.0], [-sin_y, 0.0, cos_y]];
    let tilt = [[1.0, 0.0, 0.0], [0.0, cos_t, sin_t], [0.0, -sin_t, cos_t]];
    let roll = [[cos_r, -sin_r, 0.0], [sin_r, cos_r, 0.0], [0.0, 0.0, 1.0]];
    let product = |a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]| -> [[f64; 3]; 3] {
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, value) in row.iter_mut().enumerate() {
                *value = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
            }
        }
        m
    };
    product(&roll, &product(&tilt, &yaw))
}

/// Finds the normalised radius² up to which radial distortion stays monotonic,
/// and checks that it reaches past the image corners (so every image pixel
/// has exactly one undistorted ray).
fn monotonic_radius_sq(camera: &Intrinsics, d: &Distortion) -> Result<f64, RigError> {
    // Farthest image corner in normalised distorted coordinates.
    let (w, h) = (f64::from(camera.width), f64::from(camera.height));
    let corners = [(-0.5, -0.5), (w - 0.5, -0.5), (-0.5, h - 0.5), (w - 0.5, h - 0.5)];
    let mut corner_rd: f64 = 0.0;
    for (u, v) in corners {
        let x = (u - camera.cx) / camera.fx;
        let y = (v - camera.cy) / camera.fy;
        corner_rd = corner_rd.max(sqrt(x * x + y * y));
    }
    // Walk out along the radius until the distorted radius passes the corner
    // by a pixel (what interpolation at the image's edge reads), requiring a
    // positive derivative on the way. A wide lens folds back not far past
    // its corners: a wider margin refused lenses whose whole image inverts.
    let target = corner_rd + 1.0 / camera.fx.min(camera.fy);
    let radial_distorted = |r: f64| r * (1.0 + r * r * (d.k1 + r * r * (d.k2 + r * r * d.k3)));
    const STEPS: usize = 4000;
    let step = target / 400.0;
    let mut r = 0.0;
    let mut previous = 0.0;
    // Past the target, the walk goes on to the corners' own undistorted
    // radius (tangential terms move it off the radial one).
    let mut needed: Option<f64> = None;
    for _ in 0..STEPS {
        r += step;
        let rd = radial_distorted(r);
        if !(rd > previous) {
            return Err(RigError::Distortion);
        }
        previous = rd;
        if rd >= target && needed.is_none() {
            // Tangential terms: make sure the corners invert and round-trip.
            let mut farthest: f64 = 0.0;
            for (u, v) in corners {
                let xd = (u - camera.cx) / camera.fx;
                let yd = (v - camera.cy) / camera.fy;
                let (xu, yu) = d.invert(xd, yd).ok_or(RigError::Distortion)?;
                let (xr, yr) = d.apply(xu, yu);
                let err_px = (xr - xd).abs() * camera.fx + (yr - yd).abs() * camera.fy;
                if !(err_px < UNDISTORT_TOLERANCE_PX) {
                    return Err(RigError::Distortion);
                }
                farthest = farthest.max(sqrt(xu * xu + yu * yu));
            }
            needed = Some(farthest);
        }
        if needed.is_some_and(|needed| r >= needed) {
            return Ok(r * r);
        }
    }
    Err(RigError::Distortion)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use libm::tan;

    pub(crate) fn sample_rig() -> Rig {
        Rig::new_checked(
            Intrinsics { width: 256, height: 256, fx: 240.0, fy: 240.0, cx: 127.5, cy: 127.5, distortion: None, readout_ms: 0.0 },
            Mount::level(400.0, 32.0),
            Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 },
        )
        .unwrap()
    }

    #[test]
    fn ground_pixel_round_trip() {
        let rig = sample_rig();
        for (x, z) in [(0.0, 450.0), (-250.0, 1400.0), (120.0, 800.0)] {
            let p = rig.ground_to_pixel(x, z).unwrap();
            let (xb, zb) = rig.pixel_to_ground(p).unwrap();
            assert!((xb - x).abs() < 1e-6 && (zb - z).abs() < 1e-6, "{x},{z} -> {xb},{zb}");
        }
    }

    #[test]
    fn optical_axis_hits_principal_point() {
        let rig = sample_rig();
        let z = 400.0 / tan(32f64.to_radians());
        let p = rig.ground_to_pixel(0.0, z).unwrap();
        assert!((p.u - 127.5).abs() < 1e-9 && (p.v - 127.5).abs() < 1e-9);
    }

    #[test]
    fn kg_is_ground_over_height() {
        let rig = sample_rig();
        let p = rig.point_at_height_to_pixel(100.0, 900.0, 150.0).unwrap();
        let kg = rig.pixel_to_kg(p).unwrap();
        assert!((kg.k - 100.0 / 250.0).abs() < 1e-9 && (kg.g - 900.0 / 250.0).abs() < 1e-9);
        let back = rig.kg_to_point(kg, 150.0);
        assert!((back.x - 100.0).abs() < 1e-9 && (back.z - 900.0).abs() < 1e-9);
        let again = rig.kg_to_pixel(kg).unwrap();
        assert!((again.u - p.u).abs() < 1e-9 && (again.v - p.v).abs() < 1e-9);
    }

    fn crooked_rig(roll_deg: f64, yaw_deg: f64) -> Rig {
        let level = sample_rig();
        Rig::new_checked(*level.camera(), Mount { roll_deg, yaw_deg, ..*level.mount() }, *level.aoi()).unwrap()
    }

    #[test]
    fn crooked_mount_round_trips() {
        for (roll, yaw) in [(1.5, 0.0), (0.0, 2.0), (-3.0, 4.0), (6.0, -5.0)] {
            let rig = crooked_rig(roll, yaw);
            for (x, z) in [(0.0, 450.0), (-250.0, 1400.0), (120.0, 800.0)] {
                let p = rig.ground_to_pixel(x, z).unwrap();
                let (xb, zb) = rig.pixel_to_ground(p).unwrap();
                assert!((xb - x).abs() < 1e-6 && (zb - z).abs() < 1e-6, "{roll},{yaw}: {x},{z} -> {xb},{zb}");
            }
            let p = rig.point_at_height_to_pixel(100.0, 900.0, 150.0).unwrap();
            let kg = rig.pixel_to_kg(p).unwrap();
            assert!((kg.k - 100.0 / 250.0).abs() < 1e-9 && (kg.g - 900.0 / 250.0).abs() < 1e-9);
            let again = rig.kg_to_pixel(kg).unwrap();
            assert!((again.u - p.u).abs() < 1e-9 && (again.v - p.v).abs() < 1e-9);
        }
    }

    #[test]
    fn crooked_mount_conventions() {
        // Yaw turns the optical axis left: it meets the ground at negative x,
        // at the tilt's distance.
        let rig = crooked_rig(0.0, 5.0);
        let reach = 400.0 / tan(32f64.to_radians());
        let (s, c) = (5f64.to_radians().sin(), 5f64.to_radians().cos());
        let p = rig.ground_to_pixel(-reach * s, reach * c).unwrap();
        assert!((p.u - 127.5).abs() < 1e-9 && (p.v - 127.5).abs() < 1e-9, "{p:?}");
        // Roll with the right side dipping: ground points on the right appear
        // higher in the image (smaller v) than those on the left.
        let rig = crooked_rig(3.0, 0.0);
        let (left, right) = (rig.ground_to_pixel(-200.0, 700.0).unwrap(), rig.ground_to_pixel(200.0, 700.0).unwrap());
        assert!(right.v < left.v, "{left:?} {right:?}");
        // Roll alone keeps the principal ray.
        let p = rig.ground_to_pixel(0.0, reach).unwrap();
        assert!((p.u - 127.5).abs() < 1e-9 && (p.v - 127.5).abs() < 1e-9);
    }

    #[test]
    fn impossible_mounts_are_refused() {
        let level = sample_rig();
        let with = |roll_deg, yaw_deg| Rig::new_checked(*level.camera(), Mount { roll_deg, yaw_deg, ..*level.mount() }, *level.aoi());
        assert_eq!(with(31.0, 0.0).unwrap_err(), RigError::Roll);
        assert_eq!(with(0.0, -31.0).unwrap_err(), RigError::Yaw);
        assert_eq!(with(f64::NAN, 0.0).unwrap_err(), RigError::NotFinite);
        // Turned 25 degrees, the AOI's right edge leaves the 256 px view.
        assert_eq!(with(0.0, 25.0).unwrap_err(), RigError::AoiOutsideImage(AoiEdge::Right));
    }

    /// A wide lens whose whole image inverts is accepted however close to
    /// its corners it folds back (this one folds at 1.07 of the corner
    /// radius, which a 10 % margin refused), and every corner pixel
    /// round-trips through the ground; a lens that folds inside the image is
    /// refused.
    #[test]
    fn a_wide_lens_is_accepted_while_its_image_inverts() {
        let camera = |k1: f64| Intrinsics {
            width: 320,
            height: 240,
            fx: 197.664,
            fy: 197.664,
            cx: 159.5,
            cy: 119.5,
            distortion: Some(Distortion { k1, k2: 0.00415, p1: 0.00111, p2: -0.00021, k3: 0.0 }),
            readout_ms: 0.0,
        };
        let (mount, aoi) = (Mount::level(617.6, 46.06), Aoi { half_width_mm: 480.0, near_mm: 565.1, far_mm: 1686.7 });
        let rig = Rig::new_checked(camera(-0.1369), mount, aoi).expect("the whole image inverts");
        for (u, v) in [(0.0, 239.0), (319.0, 239.0), (0.0, 120.0), (319.0, 120.0)] {
            let (x, z) = rig.pixel_to_ground(Pixel { u, v }).expect("below the horizon");
            let p = rig.ground_to_pixel(x, z).expect("seen");
            assert!((p.u - u).abs() < 0.01 && (p.v - v).abs() < 0.01, "({u}, {v}) -> ({}, {})", p.u, p.v);
        }
        assert_eq!(Rig::new_checked(camera(-0.35), mount, aoi).err(), Some(RigError::Distortion));
    }

    #[test]
    fn distortion_inverts() {
        let d = Distortion { k1: -0.28, k2: 0.07, p1: 0.001, p2: -0.0005, k3: 0.0 };
        let (x, y) = (0.4, -0.3);
        let (xd, yd) = d.apply(x, y);
        let (xu, yu) = d.invert(xd, yd).unwrap();
        assert!((xu - x).abs() < 1e-12 && (yu - y).abs() < 1e-12);
    }
}

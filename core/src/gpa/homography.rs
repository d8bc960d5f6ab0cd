//! The motion estimate's model as one 3x3 homography in single precision:
//! current KG pixel -> keyframe KG pixel, the same map as
//! [`GroundMap::to_keyframe`](crate::motion::GroundMap) between the grid's
//! pixel and ground coordinates, but a few multiply-adds and one division
//! per point on the M4's FPU instead of software `f64`.
//!
//! The chain (each step linear in homogeneous coordinates): pixel -> the
//! ray to the ground point (x, -H, z) -> turned by the body's attitude now
//! -> met with the ground again from the turned camera centre -> moved back
//! by the planar motion -> seen by the body at the keyframe's attitude ->
//! keyframe pixel.

use crate::grid::KgGrid;
use core::cell::Cell;
use core::ops::{Add, Div, Mul, Neg, Sub};

/// Motion parameters: tx mm, tz mm, yaw deg, pitch deg, roll deg.
pub(super) type Params = [f32; 5];

/// The floating point a map is built and evaluated in: `f32` for the
/// motion estimate (the M4's FPU), `f64` for the warp's rows (their Q16
/// positions need its precision).
pub(super) trait Real: Copy + PartialOrd + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self> {
    const ZERO: Self;
    const ONE: Self;
    const HALF: Self;
    /// The least `w` a point maps with.
    const LEAST_W: Self;
    fn from_f64(value: f64) -> Self;
    fn from_usize(value: usize) -> Self;
    /// (sin, cos) of `self` degrees.
    fn sin_cos_deg(self) -> (Self, Self);
}

/// `Real` for a primitive float, its (sin, cos) from `libm` (for `f32`
/// through [`crate::kernels::sincosf`], the same bits).
macro_rules! real {
    ($float:ty, $sin_cos:path) => {
        impl Real for $float {
            const ZERO: $float = 0.0;
            const ONE: $float = 1.0;
            const HALF: $float = 0.5;
            const LEAST_W: $float = 1e-6;
            fn from_f64(value: f64) -> $float {
                value as $float
            }
            fn from_usize(value: usize) -> $float {
                value as $float
            }
            fn sin_cos_deg(self) -> ($float, $float) {
                $sin_cos(self.to_radians())
            }
        }
    };
}

real!(f32, crate::kernels::sincosf);
real!(f64, libm::sincos);

type Matrix<T> = [[T; 3]; 3];

fn product<T: Real>(a: &Matrix<T>, b: &Matrix<T>) -> Matrix<T> {
    core::array::from_fn(|r| core::array::from_fn(|c| a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c]))
}

/// Current KG pixel -> keyframe KG pixel under one motion.
#[derive(Clone, Copy, Debug)]
pub(super) struct PixelMap<T = f32> {
    /// Scaled so that the third coordinate is positive (and ~1) where the
    /// turned ray meets the ground.
    h: Matrix<T>,
}

/// The ground seen through the fixed remap by a body at `pitch`, `roll`
/// (degrees): the remap's point (x, z, 1) -> the level ground point,
/// homogeneous (as [`crate::motion::GroundMap`]'s tilt).
fn tilt<T: Real>(pitch: T, roll: T, height_mm: T, sin_cos: &dyn Fn(T) -> (T, T)) -> Matrix<T> {
    let (sp, cp) = sin_cos(pitch);
    let (sr, cr) = sin_cos(roll);
    let (zero, one) = (T::ZERO, T::ONE);
    // Rz(roll) Rx(pitch) of a body vector (x right, y up, z forward), as GroundMap.
    let turn = [[cr, sr * cp, -sr * sp], [-sr, cr * cp, -cr * sp], [zero, sp, cp]];
    let centre = [turn[0][1] * height_mm, turn[1][1] * height_mm, turn[2][1] * height_mm];
    // The point -> its vector from the camera (x, -H, z).
    let to_ray = [[one, zero, zero], [zero, zero, -height_mm], [zero, one, zero]];
    // Turned ray r -> the ground point where it meets the ground, times r_y.
    let meet = [[-centre[1], centre[0], zero], [zero, centre[2], -centre[1]], [zero, one, zero]];
    product(&meet, &product(&turn, &to_ray))
}

/// The inverse of a homography, up to scale (its adjugate).
fn adjugate<T: Real>(m: &Matrix<T>) -> Matrix<T> {
    let cofactor = |r: usize, c: usize| {
        let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
        let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
        m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]
    };
    core::array::from_fn(|r| core::array::from_fn(|c| cofactor(c, r)))
}

impl<T: Real> PixelMap<T> {
    /// The map of motion `p` (the attitude change in `p[3]`, `p[4]`) from a
    /// keyframe whose body stood at `keyframe` (pitch, roll, degrees).
    pub(super) fn new(p: &[T; 5], keyframe: [T; 2], height_mm: T, grid: &KgGrid) -> PixelMap<T> {
        Self::with_sin_cos(p, keyframe, height_mm, grid, &T::sin_cos_deg)
    }

    /// [`Self::new`] with the (sin, cos) of degrees from `sin_cos`.
    pub(super) fn with_sin_cos(p: &[T; 5], keyframe: [T; 2], height_mm: T, grid: &KgGrid, sin_cos: &dyn Fn(T) -> (T, T)) -> PixelMap<T> {
        let (zero, one) = (T::ZERO, T::ONE);
        let (m, left, far) = (T::from_f64(grid.mm_per_px), T::from_f64(grid.x_left_mm), T::from_f64(grid.z_far_mm));
        let to_ground_mm = [[m, zero, left], [zero, -m, far], [zero, zero, one]];
        let now = tilt(keyframe[0] + p[3], keyframe[1] + p[4], height_mm, sin_cos);
        // The planar motion: keyframe ground = tx,tz + yaw-turned point.
        let (sy, cy) = sin_cos(p[2]);
        let planar = [[cy, -sy, p[0]], [sy, cy, p[1]], [zero, zero, one]];
        let (ci, cj) = (T::HALF * T::from_usize(grid.width()), T::HALF * T::from_usize(grid.height()));
        let w_at_centre = |h: &Matrix<T>| h[2][0] * ci + h[2][1] * cj + h[2][2];
        let to_pixel = [[one / m, zero, -left / m], [zero, -one / m, far / m], [zero, zero, one]];
        let to_ground = product(&planar, &product(&now, &to_ground_mm));
        // w = r_y < 0 where the turned ray meets the ground.
        let meets = w_at_centre(&to_ground) < zero;
        let mut h = if keyframe == [zero, zero] {
            product(&to_pixel, &to_ground)
        } else {
            product(&to_pixel, &product(&adjugate(&tilt(keyframe[0], keyframe[1], height_mm, sin_cos)), &to_ground))
        };
        // Scaled so that w is 1 at the grid centre where the ray meets the
        // ground there, and negative (nothing maps) where it does not.
        let w = w_at_centre(&h);
        let scale = if meets { one / w } else { -one / w };
        for row in h.iter_mut() {
            for value in row.iter_mut() {
                *value = *value * scale;
            }
        }
        PixelMap { h }
    }

    /// Keyframe pixel of current pixel (i, j); None where the turned ray
    /// no longer meets the ground.
    #[inline]
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(w > LEAST_W)` also refuses NaN
    pub(super) fn at(&self, i: T, j: T) -> Option<(T, T)> {
        let h = &self.h;
        let w = h[2][0] * i + h[2][1] * j + h[2][2];
        if !(w > T::LEAST_W) {
            return None;
        }
        let inverse = T::ONE / w;
        Some(((h[0][0] * i + h[0][1] * j + h[0][2]) * inverse, (h[1][0] * i + h[1][1] * j + h[1][2]) * inverse))
    }
}

/// The (sin, cos) of the angles one motion estimate asks for, remembered:
/// its fits move one parameter at a time by finite differences, so most of
/// the maps they build share most of their five angles, and `sincosf`
/// (software `f64` inside, on the M4) was most of a map's cost. Looked up
/// by the angle's exact bits, so a remembered value is the one `libm` gives.
pub(super) struct SinCosMemo {
    slots: [Cell<Option<Remembered>>; MEMO_SLOTS],
}

/// An angle's bits and its (sin, cos).
type Remembered = (u32, (f32, f32));

/// Direct-mapped slots, by a multiplicative hash of the bits: a fit
/// iteration's maps use about 8 distinct angles, and the lower level's fits
/// all start from one motion, so angles recur across fits too. On
/// flat_marks 32 slots miss 3,244 of 18,665 look-ups; 16 slots with an
/// xor-shift hash missed 6,264 (a miss is ~2,400 M4 instructions).
const MEMO_SLOTS: usize = 32;

impl SinCosMemo {
    pub(super) fn new() -> SinCosMemo {
        SinCosMemo { slots: core::array::from_fn(|_| Cell::new(None)) }
    }

    /// (sin, cos) of `degrees`.
    pub(super) fn sin_cos_deg(&self, degrees: f32) -> (f32, f32) {
        let bits = degrees.to_bits();
        let slot = &self.slots[(bits.wrapping_mul(0x9E37_79B1) >> 20) as usize % MEMO_SLOTS];
        match slot.get() {
            Some((remembered, value)) if remembered == bits => value,
            _ => {
                let value = degrees.sin_cos_deg();
                slot.set(Some((bits, value)));
                value
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{Attitude, GroundMap, GroundMotion, Motion};

    #[test]
    fn agrees_with_the_ground_map() {
        let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 255 };
        let motion = GroundMotion {
            planar: Motion { tx_mm: 12.0, tz_mm: 90.0, dyaw_deg: 2.0 },
            attitude: Attitude { pitch_deg: 0.6, roll_deg: -0.4 },
        };
        let p = [12.0, 90.0, 2.0, 0.6, -0.4];
        let map = PixelMap::new(&p, [0.0, 0.0], 400.0, &grid);
        let exact = GroundMap::new(&motion, 400.0);
        for (i, j) in [(0.0, 0.0), (70.5, 127.0), (140.0, 254.0), (3.25, 200.5)] {
            let (x, z) = grid.pixel_to_ground(i, j);
            let (xk, zk) = exact.to_keyframe(x, z).unwrap();
            let (ie, je) = grid.ground_to_pixel(xk, zk);
            let (ia, ja) = map.at(i as f32, j as f32).unwrap();
            assert!((f64::from(ia) - ie).abs() < 1e-3 && (f64::from(ja) - je).abs() < 1e-3, "({i}, {j}): {ia},{ja} vs {ie},{je}");
        }
    }
}

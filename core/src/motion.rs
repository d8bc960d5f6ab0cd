//! Robot poses and the odometry between them (the seed's Tx, Tz, and yaw),
//! and the rotation by a heading that every change of frame goes through.
//!
//! World frame as in RECORDING.md: yaw is the heading, positive turning left
//! (counter-clockwise seen from above), 0 = world +z. The robot's forward
//! axis in world (x, z) is (-sin yaw, cos yaw) and its right axis (cos yaw, sin yaw).

use core::ops::{Add, Mul, Neg, Sub};
use libm::{cos, sin};

/// Where the robot was when a frame was captured (world frame, mm, degrees).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Pose {
    pub x_mm: f64,
    pub z_mm: f64,
    pub yaw_deg: f64,
}

/// Motion from one pose to a later one, in the robot frame of the earlier pose.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    pub tx_mm: f64,
    pub tz_mm: f64,
    /// Change of heading, positive turning left.
    pub dyaw_deg: f64,
}

impl Motion {
    /// The odometry (Tx, Tz, dyaw) from `from` to `to`, in `from`'s robot frame.
    pub fn between(from: &Pose, to: &Pose) -> Motion {
        let [tx_mm, tz_mm] = from.rotation().to_robot([to.x_mm - from.x_mm, to.z_mm - from.z_mm]);
        Motion { tx_mm, tz_mm, dyaw_deg: to.yaw_deg - from.yaw_deg }
    }

    /// This motion followed by `next` (given in the robot frame after this one).
    pub fn then(&self, next: &Motion) -> Motion {
        let (tx_mm, tz_mm) = self.to_earlier_frame(next.tx_mm, next.tz_mm);
        Motion { tx_mm, tz_mm, dyaw_deg: self.dyaw_deg + next.dyaw_deg }
    }

    /// Distance travelled (chord length), mm.
    pub fn distance_mm(&self) -> f64 {
        libm::hypot(self.tx_mm, self.tz_mm)
    }

    /// A ground point given in the robot frame *after* this motion, expressed
    /// in the robot frame *before* it.
    pub fn to_earlier_frame(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let [x, z] = self.turn().place([self.tx_mm, self.tz_mm], [x_mm, z_mm]);
        (x, z)
    }

    /// Inverse of [`Motion::to_earlier_frame`] (the tests' check of it).
    #[cfg(test)]
    fn to_later_frame(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let [x, z] = self.turn().to_robot([x_mm - self.tx_mm, z_mm - self.tz_mm]);
        (x, z)
    }

    /// The later frame's axes seen from the earlier one.
    fn turn(&self) -> Rotation<f64> {
        Rotation::from_degrees(self.dyaw_deg)
    }
}

impl Pose {
    /// A point in this pose's robot frame -> world frame.
    pub fn robot_to_world(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let [x, z] = self.rotation().place([self.x_mm, self.z_mm], [x_mm, z_mm]);
        (x, z)
    }

    /// A world point -> this pose's robot frame.
    pub fn world_to_robot(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let [x, z] = self.rotation().to_robot([x_mm - self.x_mm, z_mm - self.z_mm]);
        (x, z)
    }

    /// The rotation of this pose's robot axes in the world.
    pub fn rotation(&self) -> Rotation<f64> {
        Rotation::from_degrees(self.yaw_deg)
    }
}

/// The rotation by a heading (positive turning left): vectors in robot axes
/// to world axes and back, `[x, z]`. The robot's right axis in the world is
/// `(cos, sin)`, its forward axis `(-sin, cos)`. Poses, motions and GTI turn
/// through here; `f32` for callers that work in single precision (the sines
/// are computed in `f64` either way).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rotation<T> {
    sin: T,
    cos: T,
}

impl Rotation<f64> {
    pub fn from_radians(yaw_rad: f64) -> Rotation<f64> {
        Rotation { sin: sin(yaw_rad), cos: cos(yaw_rad) }
    }

    pub fn from_degrees(yaw_deg: f64) -> Rotation<f64> {
        Rotation::from_radians(yaw_deg.to_radians())
    }

    /// The same rotation in single precision.
    pub fn to_f32(self) -> Rotation<f32> {
        Rotation { sin: self.sin as f32, cos: self.cos as f32 }
    }
}

impl<T: Copy + Add<Output = T> + Sub<Output = T> + Mul<Output = T> + Neg<Output = T>> Rotation<T> {
    /// A vector in robot axes, in world axes.
    pub fn to_world(&self, [x, z]: [T; 2]) -> [T; 2] {
        [x * self.cos - z * self.sin, x * self.sin + z * self.cos]
    }

    /// A vector in world axes, in robot axes: the inverse of [`Rotation::to_world`].
    pub fn to_robot(&self, [x, z]: [T; 2]) -> [T; 2] {
        [x * self.cos + z * self.sin, -x * self.sin + z * self.cos]
    }

    /// The point at robot-axes offset `v` from `origin`: `origin + to_world(v)`,
    /// but summed term by term from the origin (`origin + x cos - z sin`), the
    /// rounding that poses and motions have always had.
    pub fn place(&self, origin: [T; 2], [x, z]: [T; 2]) -> [T; 2] {
        [origin[0] + x * self.cos - z * self.sin, origin[1] + x * self.sin + z * self.cos]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turning_chord_matches_recording_convention() {
        // From turn/poses.csv: an 80 mm chord at +3 deg per frame.
        let from = Pose { x_mm: 0.0, z_mm: 0.0, yaw_deg: 0.0 };
        let to = Pose { x_mm: -2.09, z_mm: 79.97, yaw_deg: 3.0 };
        let motion = Motion::between(&from, &to);
        assert!((motion.tx_mm + 2.09).abs() < 1e-9 && (motion.tz_mm - 79.97).abs() < 1e-9);
        // A world point seen from both poses agrees after the transform.
        let (wx, wz) = (150.0, 1150.0);
        let (bx, bz) = to.world_to_robot(wx, wz);
        let (ax, az) = motion.to_earlier_frame(bx, bz);
        let (ex, ez) = from.world_to_robot(wx, wz);
        assert!((ax - ex).abs() < 1e-9 && (az - ez).abs() < 1e-9);
        let (lx, lz) = motion.to_later_frame(ax, az);
        assert!((lx - bx).abs() < 1e-9 && (lz - bz).abs() < 1e-9);
        let (rx, rz) = to.robot_to_world(bx, bz);
        // Composition: from -> to -> later equals from -> later.
        let later = Pose { x_mm: -20.0, z_mm: 150.0, yaw_deg: 7.5 };
        let chained = motion.then(&Motion::between(&to, &later));
        let direct = Motion::between(&from, &later);
        assert!((chained.tx_mm - direct.tx_mm).abs() < 1e-9 && (chained.tz_mm - direct.tz_mm).abs() < 1e-9);
        assert!((chained.dyaw_deg - direct.dyaw_deg).abs() < 1e-12);
        assert!((rx - wx).abs() < 1e-9 && (rz - wz).abs() < 1e-9);
    }

    #[test]
    fn rotation_turns_left_and_back() {
        // 90 degrees left: the robot's right axis is world +z, forward is world -x.
        let turn = Rotation::from_degrees(90.0);
        let [x, z] = turn.to_world([1.0, 0.0]);
        assert!(x.abs() < 1e-12 && (z - 1.0).abs() < 1e-12);
        let [x, z] = turn.to_f32().to_world([0.0f32, 1.0]);
        assert!((x + 1.0).abs() < 1e-6 && z.abs() < 1e-6);
        let v = [30.0, -7.5];
        let yaw = Rotation::from_radians(0.7);
        let [bx, bz] = yaw.to_robot(yaw.to_world(v));
        assert!((bx - v[0]).abs() < 1e-12 && (bz - v[1]).abs() < 1e-12);
        let [px, pz] = yaw.place([100.0, 200.0], v);
        let [wx, wz] = yaw.to_world(v);
        assert!((px - 100.0 - wx).abs() < 1e-9 && (pz - 200.0 - wz).abs() < 1e-9);
    }
}

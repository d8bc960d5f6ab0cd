//! Robot poses and the odometry between them (the seed's Tx, Tz, and yaw).
//!
//! World frame as in RECORDING.md: yaw is the heading, positive turning left
//! (counter-clockwise seen from above), 0 = world +z. The robot's forward
//! axis in world (x, z) is (-sin yaw, cos yaw) and its right axis (cos yaw, sin yaw).

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
        let yaw = from.yaw_deg.to_radians();
        let (dx, dz) = (to.x_mm - from.x_mm, to.z_mm - from.z_mm);
        Motion {
            tx_mm: dx * cos(yaw) + dz * sin(yaw),
            tz_mm: -dx * sin(yaw) + dz * cos(yaw),
            dyaw_deg: to.yaw_deg - from.yaw_deg,
        }
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
        let yaw = self.dyaw_deg.to_radians();
        // The later frame's axes, seen from the earlier frame.
        let (right_x, right_z) = (cos(yaw), sin(yaw));
        let (forward_x, forward_z) = (-sin(yaw), cos(yaw));
        (self.tx_mm + x_mm * right_x + z_mm * forward_x, self.tz_mm + x_mm * right_z + z_mm * forward_z)
    }

    /// Inverse of [`Motion::to_earlier_frame`].
    pub fn to_later_frame(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let yaw = self.dyaw_deg.to_radians();
        let (dx, dz) = (x_mm - self.tx_mm, z_mm - self.tz_mm);
        (dx * cos(yaw) + dz * sin(yaw), -dx * sin(yaw) + dz * cos(yaw))
    }
}

impl Pose {
    /// A point in this pose's robot frame -> world frame.
    pub fn robot_to_world(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let yaw = self.yaw_deg.to_radians();
        (self.x_mm + x_mm * cos(yaw) - z_mm * sin(yaw), self.z_mm + x_mm * sin(yaw) + z_mm * cos(yaw))
    }

    /// A world point -> this pose's robot frame.
    pub fn world_to_robot(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
        let yaw = self.yaw_deg.to_radians();
        let (dx, dz) = (x_mm - self.x_mm, z_mm - self.z_mm);
        (dx * cos(yaw) + dz * sin(yaw), -dx * sin(yaw) + dz * cos(yaw))
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
}

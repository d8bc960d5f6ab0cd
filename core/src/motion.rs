//! Robot poses and the odometry between them (the seed's Tx, Tz, and yaw),
//! and the rotation by a heading that every change of frame goes through.
//!
//! World frame as in RECORDING.md: yaw is the heading, positive turning left
//! (counter-clockwise seen from above), 0 = world +z. The robot's forward
//! axis in world (x, z) is (-sin yaw, cos yaw) and its right axis (cos yaw, sin yaw).

use core::ops::{Add, Div, Mul, Neg, Sub};
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

/// The body's attitude (RECORDING.md): pitch > 0 dips the front (the
/// camera looks further down), roll > 0 dips the right side; degrees. As a
/// change between two frames it is the later minus the earlier.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Attitude {
    pub pitch_deg: f64,
    pub roll_deg: f64,
}

impl Attitude {
    /// This attitude changed by `change`.
    pub fn then(&self, change: &Attitude) -> Attitude {
        Attitude { pitch_deg: self.pitch_deg + change.pitch_deg, roll_deg: self.roll_deg + change.roll_deg }
    }

    /// The change from `earlier` to this attitude.
    pub fn since(&self, earlier: &Attitude) -> Attitude {
        Attitude { pitch_deg: self.pitch_deg - earlier.pitch_deg, roll_deg: self.roll_deg - earlier.roll_deg }
    }
}

/// The camera's motion over the ground from the keyframe to now: the
/// planar motion of the robot and the change of its body's attitude.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GroundMotion {
    pub planar: Motion,
    /// The body's attitude now, relative to the keyframe's.
    pub attitude: Attitude,
}

impl GroundMotion {
    /// Where the ground point that the fixed remap shows at (`x_mm`,
    /// `z_mm`) now (it assumes the rig's nominal attitude) shows in the
    /// keyframe, for a camera `height_mm` above the robot origin; see
    /// [`GroundMap`]. None when the turned ray no longer meets the ground.
    pub fn to_keyframe(&self, height_mm: f64, x_mm: f64, z_mm: f64) -> Option<(f64, f64)> {
        GroundMap::new(self, height_mm).to_keyframe(x_mm, z_mm)
    }
}

/// How a body at one attitude sees the ground through the fixed remap
/// (which assumes the nominal attitude): the body turned about the robot
/// origin on the ground, attitude = Rz(roll) Rx(pitch). `f64` for GPA's
/// maps, `f32` for GTI's points ([`Tilt::to_f32`]; a software f64 on the
/// M4 costs ~0.5 M instructions a frame there, and f32 is good to a
/// micrometre where GTI keeps quarter millimetres).
#[derive(Clone, Copy, Debug)]
pub struct Tilt<T> {
    /// The turned camera centre and the turn of a body vector (rows).
    /// `turn[2][0]` is zero: the maps below leave its products out.
    centre: [T; 3],
    turn: [[T; 3]; 3],
    height_mm: T,
    /// The products that do not depend on the point, worked out once:
    /// `turn[r][1] * -height_mm` of [`Tilt::to_ground`]'s rays and
    /// `turn[1][k] * -centre[1]` of [`Tilt::from_ground`]'s.
    ray_bias: [T; 3],
    back_bias: [T; 3],
}

/// What [`Tilt`]'s maps need of a float besides arithmetic; f64's are
/// done on its words, where a software routine would be called on the M4.
pub trait TiltFloat: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> + Neg<Output = Self> {
    /// `self >= -1e-9`, the test of a ray's height (NaN fails).
    fn not_below_horizon(self) -> bool;
    /// `self + 0.0 * v` (a product with [`Tilt`]'s zero entry), bit for bit.
    fn plus_zero_times(self, v: Self) -> Self;
}

impl TiltFloat for f64 {
    /// A positive sign passes up to infinity, a negative one up to a
    /// magnitude of 1e-9; NaN fails either.
    fn not_below_horizon(self) -> bool {
        let bits = self.to_bits();
        let magnitude = bits & !(1 << 63);
        magnitude <= if bits >> 63 == 0 { f64::INFINITY.to_bits() } else { 1e-9f64.to_bits() }
    }

    /// A zero product leaves a non-zero sum as it is, so only a zero sum
    /// (its sign) or a non-finite `v` (a NaN product) needs the arithmetic.
    fn plus_zero_times(self, v: f64) -> f64 {
        // Non-zero: a bit below the sign set (two instructions on the words).
        let bits = self.to_bits();
        if v.is_finite() && ((bits >> 32) as u32) << 1 | bits as u32 != 0 {
            self
        } else {
            self + 0.0 * v
        }
    }
}

impl TiltFloat for f32 {
    fn not_below_horizon(self) -> bool {
        self >= -1e-9
    }

    fn plus_zero_times(self, v: f32) -> f32 {
        self + 0.0 * v
    }
}

impl Tilt<f64> {
    pub fn new(attitude: &Attitude, height_mm: f64) -> Tilt<f64> {
        let (sp, cp) = (sin(attitude.pitch_deg.to_radians()), cos(attitude.pitch_deg.to_radians()));
        let (sr, cr) = (sin(attitude.roll_deg.to_radians()), cos(attitude.roll_deg.to_radians()));
        // Rz(roll) Rx(pitch) of a body vector (x right, y up, z forward).
        Tilt::turned([[cr, sr * cp, -sr * sp], [-sr, cr * cp, -cr * sp], [0.0, sp, cp]], height_mm)
    }

    /// The same tilt in single precision: its turn rounded, the rest worked out in f32.
    pub fn to_f32(&self) -> Tilt<f32> {
        Tilt::turned(self.turn.map(|row| row.map(|v| v as f32)), self.height_mm as f32)
    }
}

impl<T: TiltFloat> Tilt<T> {
    /// The tilt of a body vector's `turn`, for a camera `height_mm` up.
    fn turned(turn: [[T; 3]; 3], height_mm: T) -> Tilt<T> {
        let centre = [turn[0][1] * height_mm, turn[1][1] * height_mm, turn[2][1] * height_mm];
        let ray_bias = [turn[0][1] * -height_mm, turn[1][1] * -height_mm, turn[2][1] * -height_mm];
        let back_bias = [turn[1][0] * -centre[1], turn[1][1] * -centre[1], turn[1][2] * -centre[1]];
        Tilt { centre, turn, height_mm, ray_bias, back_bias }
    }

    /// The ground point (robot frame, level) that the remap shows at
    /// (`x_mm`, `z_mm`): the ray through it turned with the body and met
    /// with the ground. None when the turned ray misses the ground.
    pub fn to_ground(&self, x_mm: T, z_mm: T) -> Option<(T, T)> {
        // The ray turn . (x, -height, z), each row summed left to right.
        let turn = &self.turn;
        let rx = turn[0][0] * x_mm + self.ray_bias[0] + turn[0][2] * z_mm;
        let ry = turn[1][0] * x_mm + self.ray_bias[1] + turn[1][2] * z_mm;
        let rz = self.ray_bias[2].plus_zero_times(x_mm) + turn[2][2] * z_mm;
        if ry.not_below_horizon() {
            return None;
        }
        let t = -self.centre[1] / ry;
        Some((self.centre[0] + t * rx, self.centre[2] + t * rz))
    }

    /// The inverse of [`Tilt::to_ground`]: where the remap shows the ground
    /// point (`x_mm`, `z_mm`). None behind the turned camera's horizon.
    pub fn from_ground(&self, x_mm: T, z_mm: T) -> Option<(T, T)> {
        // The ray p = (x - cx, -cy, z - cz) from the turned centre to the
        // point, turned back to the body: turn^T . p, each column summed
        // left to right.
        let (p0, p2) = (x_mm - self.centre[0], z_mm - self.centre[2]);
        let turn = &self.turn;
        let bx = (turn[0][0] * p0 + self.back_bias[0]).plus_zero_times(p2);
        let by = turn[0][1] * p0 + self.back_bias[1] + turn[2][1] * p2;
        let bz = turn[0][2] * p0 + self.back_bias[2] + turn[2][2] * p2;
        if by.not_below_horizon() {
            return None;
        }
        let t = -self.height_mm / by;
        Some((t * bx, t * bz))
    }
}

/// [`GroundMotion::to_keyframe`] with its sines worked out once, for the
/// many points of one motion: the current frame's KG point to the ground
/// under the body's attitude now, moved back by the planar motion, and
/// into the keyframe's KG image under the body's attitude then.
///
/// Both attitudes matter, not only their change: a body that stays pitched
/// while it moves sees the same ground shifted by a projective map, not a
/// translation (by about a T z / H: 2 px at 1.4 m after 120 mm at 1.5
/// degrees).
#[derive(Clone, Copy, Debug)]
pub struct GroundMap {
    now: Tilt<f64>,
    /// None: the keyframe's body was at the nominal attitude.
    then: Option<Tilt<f64>>,
    planar: Motion,
    heading: Rotation<f64>,
}

impl GroundMap {
    /// The map of `motion` from a keyframe taken at the nominal attitude.
    pub fn new(motion: &GroundMotion, height_mm: f64) -> GroundMap {
        GroundMap::from_tilted_keyframe(motion, &Attitude::default(), height_mm)
    }

    /// The map of `motion` from a keyframe whose body stood at `keyframe`
    /// (relative to the nominal attitude); the body now stands at
    /// `keyframe` plus `motion.attitude`.
    pub fn from_tilted_keyframe(motion: &GroundMotion, keyframe: &Attitude, height_mm: f64) -> GroundMap {
        let now = keyframe.then(&motion.attitude);
        let level = *keyframe == Attitude::default();
        GroundMap {
            now: Tilt::new(&now, height_mm),
            then: (!level).then(|| Tilt::new(keyframe, height_mm)),
            planar: motion.planar,
            heading: motion.planar.turn(),
        }
    }

    pub fn to_keyframe(&self, x_mm: f64, z_mm: f64) -> Option<(f64, f64)> {
        let (x, z) = self.now.to_ground(x_mm, z_mm)?;
        let [x, z] = self.heading.place([self.planar.tx_mm, self.planar.tz_mm], [x, z]);
        match &self.then {
            Some(then) => then.from_ground(x, z),
            None => Some((x, z)),
        }
    }

    /// The inverse of [`GroundMap::to_keyframe`]: where the fixed remap
    /// shows now the keyframe's ground point (`x_mm`, `z_mm`). None when the
    /// point lies behind the turned camera's horizon.
    pub fn from_keyframe(&self, x_mm: f64, z_mm: f64) -> Option<(f64, f64)> {
        let (x_mm, z_mm) = match &self.then {
            Some(then) => then.to_ground(x_mm, z_mm)?,
            None => (x_mm, z_mm),
        };
        let [x, z] = self.heading.to_robot([x_mm - self.planar.tx_mm, z_mm - self.planar.tz_mm]);
        self.now.from_ground(x, z)
    }
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

    /// Inverse of [`Motion::to_earlier_frame`]: a ground point given in the
    /// robot frame *before* this motion, expressed in the frame *after* it.
    pub fn to_later_frame(&self, x_mm: f64, z_mm: f64) -> (f64, f64) {
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
    fn from_keyframe_undoes_to_keyframe() {
        let motion = GroundMotion {
            planar: Motion { tx_mm: 12.0, tz_mm: 80.0, dyaw_deg: 2.5 },
            attitude: Attitude { pitch_deg: 0.7, roll_deg: -0.4 },
        };
        let map = GroundMap::new(&motion, 400.0);
        for (x, z) in [(0.0, 500.0), (-300.0, 1400.0), (250.0, 900.0)] {
            let (xk, zk) = map.to_keyframe(x, z).unwrap();
            assert!(libm::hypot(xk - x, zk - z) > 10.0);
            let (xb, zb) = map.from_keyframe(xk, zk).unwrap();
            assert!(libm::hypot(xb - x, zb - z) < 1e-6, "({x}, {z}) -> ({xb}, {zb})");
        }
    }

    /// The matrix products as written out, every term and in order, of
    /// each precision's own stored tilt.
    trait Plain: TiltFloat + PartialOrd + core::fmt::Debug {
        const NEAR_ZERO: Self;
        fn word(self) -> u64;
    }
    impl Plain for f64 {
        const NEAR_ZERO: f64 = -1e-9;
        fn word(self) -> u64 {
            // Every NaN alike (which NaN an operation returns is the platform's).
            if self.is_nan() { f64::NAN.to_bits() } else { self.to_bits() }
        }
    }
    impl Plain for f32 {
        const NEAR_ZERO: f32 = -1e-9;
        fn word(self) -> u64 {
            u64::from(if self.is_nan() { f32::NAN.to_bits() } else { self.to_bits() })
        }
    }

    fn plain_products_bit_for_bit<T: Plain>(tilt: &Tilt<T>, coordinates: &[T], label: &str) {
        let to_ground = |x: T, z: T| {
            let v = [x, -tilt.height_mm, z];
            let ray = |row: &[T; 3]| row[0] * v[0] + row[1] * v[1] + row[2] * v[2];
            let (rx, ry, rz) = (ray(&tilt.turn[0]), ray(&tilt.turn[1]), ray(&tilt.turn[2]));
            if ry >= T::NEAR_ZERO {
                return None;
            }
            let t = -tilt.centre[1] / ry;
            Some((tilt.centre[0] + t * rx, tilt.centre[2] + t * rz))
        };
        let from_ground = |x: T, z: T| {
            let p = [x - tilt.centre[0], -tilt.centre[1], z - tilt.centre[2]];
            let back = |k: usize| tilt.turn[0][k] * p[0] + tilt.turn[1][k] * p[1] + tilt.turn[2][k] * p[2];
            let (bx, by, bz) = (back(0), back(1), back(2));
            if by >= T::NEAR_ZERO {
                return None;
            }
            let t = -tilt.height_mm / by;
            Some((t * bx, t * bz))
        };
        let words = |p: Option<(T, T)>| p.map(|(x, z)| (x.word(), z.word()));
        for &x in coordinates {
            for &z in coordinates {
                assert_eq!(words(tilt.to_ground(x, z)), words(to_ground(x, z)), "{label} {x:?} {z:?}");
                assert_eq!(words(tilt.from_ground(x, z)), words(from_ground(x, z)), "{label} {x:?} {z:?}");
            }
        }
    }

    #[test]
    fn tilt_maps_match_the_plain_products_bit_for_bit() {
        let attitudes = [(0.7, -0.4), (0.0, 0.3), (-0.0, -0.2), (1.5, 0.0), (-2.0, -0.0), (0.0, 0.0)];
        let coordinates = [0.0, -0.0, 1e-300, -250.0, 333.3, 1400.0, f64::INFINITY, f64::NEG_INFINITY, f64::NAN];
        let single = coordinates.map(|v| v as f32);
        for (pitch_deg, roll_deg) in attitudes {
            let tilt = Tilt::new(&Attitude { pitch_deg, roll_deg }, 300.0);
            let label = std::format!("{pitch_deg} {roll_deg}");
            plain_products_bit_for_bit(&tilt, &coordinates, &label);
            plain_products_bit_for_bit(&tilt.to_f32(), &single, &label);
        }
    }

    /// GTI's single-precision maps stay within a few f32 ulps of the f64
    /// ones: well under a micrometre where GTI keeps quarter millimetres.
    #[test]
    fn single_precision_tilt_maps_agree_to_a_micrometre() {
        let mut state = 0x1234_5678u32;
        let mut next = || crate::selftest::xorshift32(&mut state) as f64 / f64::from(u32::MAX);
        for _ in 0..500 {
            let attitude = Attitude { pitch_deg: next() * 4.0 - 2.0, roll_deg: next() * 4.0 - 2.0 };
            let (double, single) = (Tilt::new(&attitude, 400.0), Tilt::new(&attitude, 400.0).to_f32());
            for _ in 0..50 {
                let (x, z) = ((next() * 1200.0 - 600.0) as f32, (250.0 + next() * 1500.0) as f32);
                for (wide, narrow) in [
                    (double.to_ground(f64::from(x), f64::from(z)), single.to_ground(x, z)),
                    (double.from_ground(f64::from(x), f64::from(z)), single.from_ground(x, z)),
                ] {
                    let ((xw, zw), (xn, zn)) = (wide.unwrap(), narrow.unwrap());
                    assert!((xw - f64::from(xn)).abs() < 1e-3 && (zw - f64::from(zn)).abs() < 1e-3, "{attitude:?} ({x}, {z})");
                }
            }
        }
    }

    #[test]
    fn horizon_test_on_the_words_is_the_comparison() {
        let tiny = 1e-9f64;
        let values = [0.0, -0.0, tiny, -tiny, -tiny.next_down(), -tiny.next_up(), -1.0, 5.0, f64::INFINITY, f64::NEG_INFINITY, f64::NAN, -f64::NAN, -1e-300];
        for y in values {
            assert_eq!(y.not_below_horizon(), y >= -1e-9, "{y}");
        }
    }

    #[test]
    fn attitude_moves_far_ground_more_than_near() {
        let level = GroundMotion::default();
        assert_eq!(level.to_keyframe(400.0, 100.0, 800.0), Some((100.0, 800.0)));
        // The front dips 0.5 deg about the robot origin on the ground: the
        // camera looks further down, so a ground point the fixed remap
        // places at z truly lies nearer, by z^2/H per radian (ground ahead
        // stands z sin(pitch) above the body's ground plane).
        let pitched = GroundMotion { attitude: Attitude { pitch_deg: 0.5, roll_deg: 0.0 }, ..level };
        let (_, near) = pitched.to_keyframe(400.0, 0.0, 500.0).unwrap();
        let (_, far) = pitched.to_keyframe(400.0, 0.0, 1500.0).unwrap();
        assert!(near < 500.0 && 1500.0 - far > 3.0 * (500.0 - near), "{near} {far}");
        let expected = 1500.0f64.powi(2) / 400.0 * 0.5f64.to_radians();
        assert!((1500.0 - far - expected).abs() < 0.05 * expected, "{far} {expected}");
        // The right side dips, about the forward axis on the ground: ground on
        // that axis stays put; ground on the right stands x sin(roll) above
        // the body's ground plane, so the fixed remap shows it farther out by
        // H / (H - x sin(roll)); the left side the other way.
        let rolled = GroundMotion { attitude: Attitude { pitch_deg: 0.0, roll_deg: 0.5 }, ..level };
        let (x, z) = rolled.to_keyframe(400.0, 0.0, 1000.0).unwrap();
        assert!(x.abs() < 1e-9 && (z - 1000.0).abs() < 1e-9, "{x} {z}");
        let lift = 300.0 * 0.5f64.to_radians().sin();
        let (_, right) = rolled.to_keyframe(400.0, 300.0, 1000.0).unwrap();
        let (_, left) = rolled.to_keyframe(400.0, -300.0, 1000.0).unwrap();
        let expected = |lift: f64| 1000.0 * (400.0 - lift) / 400.0;
        assert!((right - expected(lift)).abs() < 0.5 && (left - expected(-lift)).abs() < 0.5, "{right} {left}");
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

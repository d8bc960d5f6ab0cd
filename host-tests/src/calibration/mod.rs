//! `flatland calibrate`: the mount (tilt, height, roll, yaw) from a drive
//! over flat ground.
//!
//! Between two frames, the ground seen in the later one maps into the
//! earlier one through the mount: back-project a pixel to the ground with
//! the mount, move the ground point by the robot's motion, project it with
//! the mount. The estimate minimises the photometric difference of the two
//! frames under that map, over many pairs at once, by Levenberg-Marquardt
//! on iteratively reweighted least squares:
//! - Tukey weights (Huber on the coarsest level) reject what is not flat
//!   ground (obstacles, a moving object), and pairs whose residual stays far
//!   above the others' (wheel slip: the odometry is wrong) are dropped;
//! - a gain and offset per pair absorb exposure changes and flicker;
//! - coarse to fine over a 2x pyramid (2x2 means, like camera binning).
//!
//! With odometry the metric motion fixes the height. Without it the height
//! is given (the rig's, or `--height-mm`) and each pair's motion (Tx, Tz,
//! dyaw) is estimated with the mount, started from a search over Tx, Tz on
//! the coarsest level. Straight driving determines all four: the tilt and
//! roll set the ground plane's normal in the camera, the yaw the direction
//! of travel in the image, the height the flow's metric scale.
//!
//! A real body rocks (RECORDING.md's body attitude): each frame's pitch and
//! roll are unknowns too, turning the ground map as GPA's estimate does
//! (`GroundMap`). Their mean over each connected set of pairs is held at
//! zero: a constant body attitude is indistinguishable from the mount, so
//! the mount is measured relative to the body's mean attitude over the drive
//! (Flatland's nominal attitude).
//!
//! A rolling shutter (the camera's `readout_ms`) captures each row at its
//! own time: each sample's map uses the motion between its two rows'
//! times, at the pair's velocity (`PairMap`).
//!
//! The user's AOI plays no part: the solve's rigs ([`ground_rig`]) check
//! only that the mount sees the ground.
//!
//! Beside the solve: [`camera_info`] reads a ROS camera_info file as the
//! camera, and [`rig_toml`] writes the values found into rig.toml.

pub mod camera_info;
pub mod rig_toml;

pub use camera_info::{camera_values, parse_camera_info, CameraInfo, CameraInfoError};
pub use rig_toml::{calibrated_rig_toml, mount_values, with_section_values};

use crate::recording::{Frame, Recording, RecordingError};
use flatland_core::geometry::{Aoi, Intrinsics, Mount, Pixel, Rig, RigError};
use flatland_core::motion::{Attitude, GroundMap, GroundMotion, Motion};
use std::fmt;

/// Least motion between two frames of a pair (mm of chord): less carries no
/// usable ground flow.
pub const MIN_PAIR_MOTION_MM: f64 = 20.0;
/// Motion a pair aims for when frames move less than this apart: the
/// earliest later frame at least this far is its partner.
const TARGET_PAIR_MOTION_MM: f64 = 50.0;
/// Most pairs used, spread evenly over the recording (bounds the run time).
const MAX_PAIRS: usize = 24;
/// Pyramid levels (0: full resolution).
const LEVELS: usize = 3;
/// LM iterations per level.
const ITERATIONS: usize = 12;
/// Ground samples reach at most this many times the AOI's far edge.
const REACH_FAR_EDGES: f64 = 2.5;
/// Tukey's constant (95 % efficiency for Gaussian residuals).
const TUKEY: f64 = 4.685;
/// Huber's constant, on the coarsest level.
const HUBER: f64 = 1.345;
/// A pair whose median residual exceeds this many times the median over
/// pairs is dropped (its motion is not what the odometry says).
const PAIR_OUTLIER_FACTOR: f64 = 2.5;
/// Pairs whose image-measured scale of the odometry lies within this
/// fraction of the median fix the height; the others slipped.
const SCALE_AGREEMENT: f64 = 0.1;

/// How a calibration runs.
#[derive(Clone, Copy, Debug, Default)]
pub struct CalibrationConfig {
    /// The known height (mm) when the recording has no odometry; None: the rig's.
    pub height_mm: Option<f64>,
    /// Ignore poses.csv's odometry even where present.
    pub ignore_odometry: bool,
}

/// The estimated mount and how well it is determined.
#[derive(Clone, Copy, Debug)]
pub struct MountEstimate {
    pub mount: Mount,
    /// One-sigma uncertainties (formal, from the Gauss-Newton normal
    /// matrix): tilt, height, roll, yaw; the height's is 0 when it was given.
    pub sigma: [f64; 4],
    /// RMS photometric residual (gray levels) at the rig as given and as estimated.
    pub residual_before: f64,
    pub residual_after: f64,
    /// Frame pairs used (after dropping outlier pairs) and ground samples at full resolution.
    pub pairs: usize,
    pub samples: usize,
    /// True when the height came from odometry, false when it was given.
    pub height_estimated: bool,
    /// The body model that explained the frames best.
    pub body: Body,
    /// RMS of the frames' estimated body pitch and roll (degrees; 0 for a rigid body).
    pub body_attitude_rms_deg: f64,
}

/// Why a recording could not be calibrated.
#[derive(Debug)]
pub enum CalibrationError {
    Recording(RecordingError),
    /// Fewer than two frames.
    TooFewFrames,
    /// No pair of frames moved [`MIN_PAIR_MOTION_MM`] apart.
    NoMotion { largest_mm: f64 },
    /// The ground flow does not determine the mount (the normal matrix is singular).
    Underdetermined,
    /// The estimate left the possible mounts (a tilt outside (0, 90) degrees,
    /// a roll or yaw beyond 30): the images fit no mount near the start.
    Diverged(RigError),
    /// Solves from starts near rig.toml's mount ([`OTHER_STARTS_DEG`]) came
    /// to different mounts, or failed: the images do not pin the mount
    /// down, and which answer came out would depend on rig.toml. Each
    /// start with what its solve came to.
    StartDependent { solves: Vec<(Mount, Result<Mount, String>)> },
}

impl fmt::Display for CalibrationError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CalibrationError::Recording(e) => write!(f, "{e}"),
            CalibrationError::TooFewFrames => f.write_str("calibration needs at least two frames"),
            CalibrationError::NoMotion { largest_mm } => write!(
                f,
                "the robot does not move (largest motion between frames {largest_mm:.1} mm): calibration needs a drive over flat ground of at least {MIN_PAIR_MOTION_MM} mm between frames"
            ),
            CalibrationError::Underdetermined => f.write_str("the ground's motion in the images does not determine the mount (too little texture or motion)"),
            CalibrationError::Diverged(e) => write!(
                f,
                "the estimate left the possible mounts ({e}): the images fit no mount near rig.toml's (is the drive over flat ground, is [camera] right?)"
            ),
            CalibrationError::StartDependent { solves } => {
                f.write_str("the mount depends on where the solve starts:")?;
                for (start, result) in solves {
                    write!(f, " from tilt {:.2} roll {:.2}: ", start.tilt_deg, start.roll_deg)?;
                    match result {
                        Ok(m) => write!(f, "tilt {:.2} roll {:.2} yaw {:.2} height {:.1};", m.tilt_deg, m.roll_deg, m.yaw_deg, m.height_mm)?,
                        Err(e) => write!(f, "{e};")?,
                    }
                }
                f.write_str(" the images do not determine it (a longer drive over flat, textured ground, with odometry, may)")
            }
        }
    }
}

impl std::error::Error for CalibrationError {}

impl From<RecordingError> for CalibrationError {
    fn from(e: RecordingError) -> Self {
        CalibrationError::Recording(e)
    }
}

/// A gray image in f32, for sampling between pixels.
#[derive(Clone, Debug)]
struct Image {
    width: usize,
    height: usize,
    pixels: Vec<f32>,
}

impl Image {
    fn from_frame(frame: &Frame) -> Image {
        Image { width: frame.width, height: frame.height, pixels: frame.pixels.iter().map(|&p| f32::from(p)).collect() }
    }

    /// 2x2 means (a last odd column or row is dropped), like camera binning.
    fn half(&self) -> Image {
        let (width, height) = (self.width / 2, self.height / 2);
        let at = |u: usize, v: usize| self.pixels[v * self.width + u];
        let pixels = (0..width * height)
            .map(|n| {
                let (u, v) = (2 * (n % width), 2 * (n / width));
                (at(u, v) + at(u + 1, v) + at(u, v + 1) + at(u + 1, v + 1)) / 4.0
            })
            .collect();
        Image { width, height, pixels }
    }

    /// Bilinear value and central-difference gradient at (u, v); None within
    /// two pixels of the border.
    fn sample(&self, u: f64, v: f64) -> Option<(f64, f64, f64)> {
        if !(u >= 1.0 && v >= 1.0 && u <= self.width as f64 - 3.0 && v <= self.height as f64 - 3.0) {
            return None;
        }
        let (u0, v0) = (u.floor() as usize, v.floor() as usize);
        let (fu, fv) = (u - u0 as f64, v - v0 as f64);
        let at = |c: usize, r: usize| f64::from(self.pixels[r * self.width + c]);
        let bilinear = |c: usize, r: usize| {
            let top = at(c, r) * (1.0 - fu) + at(c + 1, r) * fu;
            let bottom = at(c, r + 1) * (1.0 - fu) + at(c + 1, r + 1) * fu;
            top * (1.0 - fv) + bottom * fv
        };
        let value = bilinear(u0, v0);
        let gu = (bilinear(u0 + 1, v0) - bilinear(u0 - 1, v0)) / 2.0;
        let gv = (bilinear(u0, v0 + 1) - bilinear(u0, v0 - 1)) / 2.0;
        Some((value, gu, gv))
    }
}

/// The camera at pyramid level `level` (pixel centres keep their place).
fn level_camera(camera: &Intrinsics, level: usize) -> Intrinsics {
    let n = f64::from(1u32 << level);
    Intrinsics {
        width: camera.width >> level,
        height: camera.height >> level,
        fx: camera.fx / n,
        fy: camera.fy / n,
        cx: (camera.cx + 0.5) / n - 0.5,
        cy: (camera.cy + 0.5) / n - 0.5,
        ..*camera
    }
}

/// One pair of frames: the later frame's samples map into the earlier one.
struct Pair {
    earlier: usize,
    later: usize,
    /// Odometry from the earlier frame to the later, when the recording has it.
    odometry: Option<Motion>,
    /// Seconds from the earlier frame's time (its middle row's) to the
    /// later's, poses.csv's t_s; None when a frame has no time (then the
    /// rows are taken at their frame's time, as with a global shutter).
    interval_s: Option<f64>,
    /// Sample pixels of the later frame and their values, this level.
    samples: Vec<(Pixel, f64)>,
    gain: f64,
    offset: f64,
    used: bool,
}

/// The unknowns: the mount angles (the height stays at its nominal value
/// while solving: the ground flow fixes only motion over height), each
/// pair's step and each frame's body attitude.
#[derive(Clone)]
struct State {
    /// tilt, height, roll, yaw.
    mount: [f64; 4],
    /// Per pair: the scale of its odometry's translation (without odometry,
    /// its chord length in units of [`CHORD_UNIT_MM`]), and its turn, degrees.
    steps: Vec<[f64; 2]>,
    /// Per frame: the body's pitch and roll, degrees.
    attitudes: Vec<[f64; 2]>,
    /// Per frame: the frame whose attitude moves against it, so that the
    /// attitudes of a connected set of pairs keep summing to zero (the set's
    /// first frame, which has no unknowns of its own).
    anchors: Vec<usize>,
}

/// Chord length unit of a pair's step without odometry.
const CHORD_UNIT_MM: f64 = 100.0;

/// A pair's motion from its step: the odometry's direction scaled, or an
/// arc of a robot that drives along its heading (chord at half the turn).
fn pair_motion(odometry: Option<&Motion>, [a, dyaw_deg]: [f64; 2]) -> Motion {
    match odometry {
        Some(m) => Motion { tx_mm: a * m.tx_mm, tz_mm: a * m.tz_mm, dyaw_deg },
        None => {
            let (sin, cos) = (dyaw_deg / 2.0).to_radians().sin_cos();
            let chord = a * CHORD_UNIT_MM;
            Motion { tx_mm: -chord * sin, tz_mm: chord * cos, dyaw_deg }
        }
    }
}

/// Which unknowns are free, in the solve's order.
#[derive(Clone, Copy, PartialEq)]
enum Unknown {
    /// tilt 0, roll 2, yaw 3.
    Mount(usize),
    /// Pair index, component (scale or chord, turn).
    Step(usize, usize),
    /// Frame index, axis (pitch 0, roll 1).
    Attitude(usize, usize),
}

impl State {
    fn with(&self, unknown: Unknown, delta: f64) -> State {
        let mut s = self.clone();
        match unknown {
            Unknown::Mount(k) => s.mount[k] += delta,
            Unknown::Step(p, c) => s.steps[p][c] += delta,
            Unknown::Attitude(f, axis) => {
                s.attitudes[f][axis] += delta;
                s.attitudes[self.anchors[f]][axis] -= delta;
            }
        }
        s
    }

    fn motion(&self, pairs: &[Pair], n: usize) -> Motion {
        pair_motion(pairs[n].odometry.as_ref(), self.steps[n])
    }

    /// Pair `n`'s map from later to earlier pixels.
    fn pair_map(&self, pairs: &[Pair], n: usize) -> PairMap {
        let attitude = |f: usize| Attitude { pitch_deg: self.attitudes[f][0], roll_deg: self.attitudes[f][1] };
        let pair = &pairs[n];
        PairMap::new(self.motion(pairs, n), [attitude(pair.earlier), attitude(pair.later)], self.mount[1], pair.interval_s)
    }

    fn mount(&self) -> Mount {
        Mount { height_mm: self.mount[1], tilt_deg: self.mount[0], roll_deg: self.mount[2], yaw_deg: self.mount[3] }
    }
}

/// Finite-difference steps: degrees, mm, degrees, degrees; a pair's scale
/// (or chord unit) and turn (degrees); a frame's attitude (degrees).
const MOUNT_STEP: [f64; 4] = [1e-3, 0.05, 1e-3, 1e-3];
const PAIR_STEP: [f64; 2] = [1e-4, 1e-3];
const ATTITUDE_STEP: f64 = 1e-3;

fn step_of(unknown: Unknown) -> f64 {
    match unknown {
        Unknown::Mount(k) => MOUNT_STEP[k],
        Unknown::Step(_, c) => PAIR_STEP[c],
        Unknown::Attitude(..) => ATTITUDE_STEP,
    }
}

/// A pair's map from later-frame pixels to earlier-frame ones: back to the
/// ground with the rig, through the later frame's body attitude, the
/// motion, and the earlier frame's attitude undone.
///
/// With a rolling shutter (the rig's `readout_ms`) each row is captured at
/// its own time, and `motion` (between the frames' middle rows) is replaced
/// per sample by the motion between the two samples' rows at the pair's
/// velocity: [`Velocity::over`] the fraction of the pair's interval that
/// separates them. The earlier sample's row is where the warp lands, so it
/// is found by iterating from the middle rows' map.
#[derive(Clone, Copy)]
struct PairMap {
    motion: Motion,
    /// Earlier, later.
    attitudes: [Attitude; 2],
    /// The attitudes' ground maps; None for a level body (the identity).
    maps: [Option<GroundMap>; 2],
    /// `motion` as a constant velocity over the pair's interval, and the
    /// interval (s); None when the frames have no times.
    velocity: Option<(Velocity, f64)>,
}

/// Refinements of the earlier sample's row under a rolling shutter, from the
/// middle rows' map (about a row off on exposure_rolling): each multiplies
/// the row's error by the readout's share of the interval times the flow's
/// share of the height (0.3 x 0.14 there), so two leave ~0.002 row.
const ROW_TIME_ITERATIONS: usize = 2;

impl PairMap {
    fn new(motion: Motion, attitudes: [Attitude; 2], height_mm: f64, interval_s: Option<f64>) -> PairMap {
        let map = |attitude: Attitude| {
            (attitude != Attitude::default()).then(|| GroundMap::new(&GroundMotion { planar: Motion::default(), attitude }, height_mm))
        };
        let velocity = interval_s.filter(|&dt| dt > 0.0).map(|dt| (Velocity::of(&motion), dt));
        PairMap { motion, attitudes, maps: attitudes.map(map), velocity }
    }

    fn same_as(&self, other: &PairMap) -> bool {
        self.motion == other.motion && self.attitudes == other.attitudes
    }

    /// Where a later-frame pixel lands in the earlier frame.
    fn warp(&self, rig: &Rig, p: Pixel) -> Option<Pixel> {
        let (mut x, mut z) = rig.pixel_to_ground(p)?;
        if let Some(later) = &self.maps[1] {
            (x, z) = later.to_keyframe(x, z)?;
        }
        let middle_rows = self.earlier_pixel(rig, &self.motion, x, z)?;
        let camera = rig.camera();
        let Some((velocity, interval_s)) = self.velocity.filter(|_| camera.readout_ms != 0.0) else {
            return Some(middle_rows);
        };
        // A row's capture time after its frame's, as a fraction of the interval.
        let per_row = camera.readout_ms / 1000.0 / interval_s / f64::from(camera.height);
        let row_time = |v: f64| per_row * (v + 0.5 - f64::from(camera.height) / 2.0);
        let mut q = middle_rows;
        for _ in 0..ROW_TIME_ITERATIONS {
            q = self.earlier_pixel(rig, &velocity.over(1.0 + row_time(p.v) - row_time(q.v)), x, z)?;
        }
        Some(q)
    }

    /// A ground point of the later frame (level) through `motion` and the
    /// earlier frame's attitude into the earlier image.
    fn earlier_pixel(&self, rig: &Rig, motion: &Motion, x: f64, z: f64) -> Option<Pixel> {
        let (mut x, mut z) = motion.to_earlier_frame(x, z);
        if let Some(earlier) = &self.maps[0] {
            (x, z) = earlier.from_keyframe(x, z)?;
        }
        rig.ground_to_pixel(x, z)
    }
}

/// A planar motion as a constant velocity (a twist: the robot's velocity in
/// its own frame and its turn rate, per unit of the motion's duration), so
/// that a fraction of the motion's duration gives the motion then.
#[derive(Clone, Copy)]
struct Velocity {
    /// The robot-frame velocity and the turn rate, times the duration: mm
    /// along the robot's axes (the chord of a motion without turn), radians.
    x_mm: f64,
    z_mm: f64,
    turn_rad: f64,
}

/// An arc of turn `theta` (radians) carries a unit velocity in the robot's
/// frame to the chord `[[a, -b], [b, a]] v`: (a, b) = (sin t / t, (1 - cos t) / t).
fn arc_coefficients(theta: f64) -> (f64, f64) {
    if theta.abs() < 1e-6 {
        (1.0 - theta * theta / 6.0, theta / 2.0)
    } else {
        (theta.sin() / theta, (1.0 - theta.cos()) / theta)
    }
}

impl Velocity {
    fn of(motion: &Motion) -> Velocity {
        let turn_rad = motion.dyaw_deg.to_radians();
        let (a, b) = arc_coefficients(turn_rad);
        let norm = a * a + b * b;
        Velocity {
            x_mm: (a * motion.tx_mm + b * motion.tz_mm) / norm,
            z_mm: (-b * motion.tx_mm + a * motion.tz_mm) / norm,
            turn_rad,
        }
    }

    /// The motion over `fraction` of the duration.
    fn over(&self, fraction: f64) -> Motion {
        let turn_rad = fraction * self.turn_rad;
        let (a, b) = arc_coefficients(turn_rad);
        let (x, z) = (fraction * self.x_mm, fraction * self.z_mm);
        Motion { tx_mm: a * x - b * z, tz_mm: b * x + a * z, dyaw_deg: turn_rad.to_degrees() }
    }
}

/// Each frame's anchor (see [`State::anchors`]) and the attitude unknowns
/// of the frames that the used pairs connect.
fn attitude_unknowns(pairs: &[Pair], frames: usize) -> (Vec<usize>, Vec<Unknown>) {
    // Union-find over the used pairs; a set's root is its first frame.
    fn find(root: &mut [usize], mut f: usize) -> usize {
        while root[f] != f {
            root[f] = root[root[f]];
            f = root[f];
        }
        f
    }
    let mut root: Vec<usize> = (0..frames).collect();
    let mut in_pair = vec![false; frames];
    for pair in pairs.iter().filter(|p| p.used) {
        let (a, b) = (find(&mut root, pair.earlier), find(&mut root, pair.later));
        root[a.max(b)] = a.min(b);
        in_pair[pair.earlier] = true;
        in_pair[pair.later] = true;
    }
    let anchors: Vec<usize> = (0..frames).map(|f| find(&mut root, f)).collect();
    let unknowns = (0..frames)
        .filter(|&f| in_pair[f] && anchors[f] != f)
        .flat_map(|f| [Unknown::Attitude(f, 0), Unknown::Attitude(f, 1)])
        .collect();
    (anchors, unknowns)
}

/// The calibration problem at one pyramid level.
struct Level<'a> {
    camera: Intrinsics,
    images: &'a [Image],
}

impl Level<'_> {
    fn rig(&self, state: &State) -> Result<Rig, RigError> {
        ground_rig(self.camera, state.mount())
    }
}

/// A rig for `mount` that checks what calibration needs (the camera, a
/// mount that sees the ground) and not the user's AOI: on the way from a
/// wrong start, that AOI may leave the image while the ground stays in view.
/// Its AOI is a small patch straight ahead where the image sees the ground.
fn ground_rig(camera: Intrinsics, mount: Mount) -> Result<Rig, RigError> {
    // Where the optical axis meets the ground, then nearer and farther.
    let axis_mm = mount.height_mm / mount.tilt_deg.to_radians().tan();
    let mut first_error = None;
    for fraction in [1.0, 0.7, 1.4, 0.5, 2.0] {
        let near_mm = axis_mm * fraction;
        let aoi = Aoi { half_width_mm: 0.01 * near_mm, near_mm, far_mm: 1.01 * near_mm };
        match Rig::new_checked(camera, mount, aoi) {
            Ok(rig) => return Ok(rig),
            Err(e) => _ = first_error.get_or_insert(e),
        }
    }
    Err(first_error.unwrap_or(RigError::Tilt))
}

/// Residual of one sample, with its gradient image values: (r, value, gu, gv, warped).
fn residual(level: &Level, rig: &Rig, pair: &Pair, map: &PairMap, p: Pixel, target: f64) -> Option<(f64, f64, f64)> {
    let q = map.warp(rig, p)?;
    let (value, gu, gv) = level.images[pair.earlier].sample(q.u, q.v)?;
    Some((pair.gain * value + pair.offset - target, gu, gv))
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Robust weight of a residual over scale `sigma`.
fn weight(r: f64, sigma: f64, huber: bool) -> f64 {
    let x = (r / sigma).abs();
    if huber {
        if x <= HUBER { 1.0 } else { HUBER / x }
    } else if x < TUKEY {
        let t = 1.0 - (x / TUKEY).powi(2);
        t * t
    } else {
        0.0
    }
}

/// Robust cost of a residual (the weight's rho).
fn rho(r: f64, sigma: f64, huber: bool) -> f64 {
    let x = (r / sigma).abs();
    if huber {
        if x <= HUBER { x * x / 2.0 } else { HUBER * (x - HUBER / 2.0) }
    } else if x < TUKEY {
        let t = 1.0 - (x / TUKEY).powi(2);
        TUKEY * TUKEY / 6.0 * (1.0 - t * t * t)
    } else {
        TUKEY * TUKEY / 6.0
    }
}

/// Fits each used pair's gain and offset to the warped earlier frame, given
/// the weights of the last residuals (all 1 at first).
fn fit_photometry(level: &Level, rig: &Rig, pairs: &mut [Pair], state: &State, sigma: Option<f64>, huber: bool) {
    for n in 0..pairs.len() {
        let map = state.pair_map(pairs, n);
        let pair = &mut pairs[n];
        if !pair.used {
            continue;
        }
        let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(p, target) in &pair.samples {
            let Some(q) = map.warp(rig, p) else { continue };
            let Some((value, _, _)) = level.images[pair.earlier].sample(q.u, q.v) else { continue };
            let w = sigma.map_or(1.0, |s| weight(pair.gain * value + pair.offset - target, s, huber));
            sw += w;
            sx += w * value;
            sy += w * target;
            sxx += w * value * value;
            sxy += w * value * target;
        }
        let det = sw * sxx - sx * sx;
        if sw > 10.0 && det > 1e-9 * sw * sxx {
            pair.gain = (sw * sxy - sx * sy) / det;
            pair.offset = (sy - pair.gain * sx) / sw;
        }
    }
}

/// All residuals of the used pairs at `state` (None: the state is not a valid rig).
fn residuals(level: &Level, pairs: &[Pair], state: &State) -> Option<Vec<Vec<f64>>> {
    let rig = level.rig(state).ok()?;
    Some(
        pairs
            .iter()
            .enumerate()
            .map(|(n, pair)| {
                if !pair.used {
                    return Vec::new();
                }
                let map = state.pair_map(pairs, n);
                pair.samples.iter().filter_map(|&(p, target)| residual(level, &rig, pair, &map, p, target).map(|r| r.0)).collect()
            })
            .collect(),
    )
}

fn robust_scale(all: &[Vec<f64>]) -> f64 {
    let mut magnitudes: Vec<f64> = all.iter().flatten().map(|r| r.abs()).collect();
    (1.4826 * median(&mut magnitudes)).max(0.5)
}

fn cost(all: &[Vec<f64>], sigma: f64, huber: bool) -> f64 {
    all.iter().flatten().map(|&r| rho(r, sigma, huber)).sum()
}

/// Solves `a x = b` (symmetric positive definite) by Cholesky; None when singular.
// The textbook indexed loops; `!(a > b)` also refuses NaN.
#[allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]
fn solve(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let mut l = vec![vec![0.0; n]; n];
    for i in 0..n {
        for j in 0..=i {
            let sum: f64 = a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                if !(sum > 1e-12 * a[i][i].abs().max(1e-300)) {
                    return None;
                }
                l[i][i] = sum.sqrt();
            } else {
                l[i][j] = sum / l[j][j];
            }
        }
    }
    let mut y = vec![0.0; n];
    for i in 0..n {
        y[i] = (b[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        x[i] = (y[i] - (i + 1..n).map(|k| l[k][i] * x[k]).sum::<f64>()) / l[i][i];
    }
    Some(x)
}

/// The normal equations at `state`: (J^T W J, J^T W r, sum w r^2, sum w).
#[allow(clippy::type_complexity)]
fn normal_equations(
    level: &Level,
    pairs: &[Pair],
    state: &State,
    unknowns: &[Unknown],
    sigma: f64,
    huber: bool,
) -> Result<(Vec<Vec<f64>>, Vec<f64>, f64, f64), RigError> {
    let n = unknowns.len();
    let rig = level.rig(state)?;
    // The mount's perturbed rigs, shared by all pairs.
    let mount_rigs: Vec<Option<Rig>> = unknowns
        .iter()
        .map(|&u| match u {
            Unknown::Mount(_) => level.rig(&state.with(u, step_of(u))).ok(),
            Unknown::Step(..) | Unknown::Attitude(..) => None,
        })
        .collect();
    let mut jtj = vec![vec![0.0; n]; n];
    let mut jtr = vec![0.0; n];
    let (mut wrr, mut wsum) = (0.0, 0.0);
    let mut row = vec![0.0; n];
    let mut nonzero: Vec<usize> = Vec::with_capacity(n);
    for (pi, pair) in pairs.iter().enumerate() {
        if !pair.used {
            continue;
        }
        let map = state.pair_map(pairs, pi);
        // Per unknown: the rig and map it moves this pair's samples with
        // (None: it does not move them).
        let moved_by: Vec<Option<(&Rig, PairMap)>> = unknowns
            .iter()
            .enumerate()
            .map(|(k, &unknown)| match unknown {
                Unknown::Mount(_) => mount_rigs[k].as_ref().map(|moved| (moved, map)),
                _ => {
                    let moved = state.with(unknown, step_of(unknown)).pair_map(pairs, pi);
                    (!moved.same_as(&map)).then_some((&rig, moved))
                }
            })
            .collect();
        for &(p, target) in &pair.samples {
            let Some(q) = map.warp(&rig, p) else { continue };
            let Some((value, gu, gv)) = level.images[pair.earlier].sample(q.u, q.v) else { continue };
            let r = pair.gain * value + pair.offset - target;
            let w = weight(r, sigma, huber);
            if w == 0.0 {
                continue;
            }
            let mut touched = false;
            for (k, &unknown) in unknowns.iter().enumerate() {
                row[k] = 0.0;
                let Some((moved_rig, moved_map)) = &moved_by[k] else { continue };
                let Some(moved) = moved_map.warp(moved_rig, p) else { continue };
                let h = step_of(unknown);
                row[k] = pair.gain * (gu * (moved.u - q.u) + gv * (moved.v - q.v)) / h;
                touched = true;
            }
            if !touched {
                continue;
            }
            // A sample touches the mount, its own pair's motion and its
            // frames' attitudes (all of a set's through its anchor) only.
            nonzero.clear();
            nonzero.extend((0..n).filter(|&k| row[k] != 0.0));
            for &i in &nonzero {
                jtr[i] += w * row[i] * r;
                for &j in nonzero.iter().filter(|&&j| j <= i) {
                    jtj[i][j] += w * row[i] * row[j];
                }
            }
            wrr += w * r * r;
            wsum += w;
        }
    }
    // Only the lower triangle was summed: mirror it.
    for i in 0..n {
        let (upper, lower) = jtj.split_at_mut(i);
        for (j, row) in upper.iter_mut().enumerate() {
            row[i] = lower[0][j];
        }
    }
    Ok((jtj, jtr, wrr, wsum))
}

/// Whether each frame's body attitude is estimated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Body {
    /// The body does not rock: every frame at the mount's attitude.
    Rigid,
    /// Each frame's pitch and roll are unknowns (mean zero).
    Rocking,
}

/// The rocking body's model is taken when it explains the frames this much
/// better (RMS residual after, as a fraction of the rigid model's): more
/// unknowns always fit a little better, and on a body that does not rock
/// they fit noise and what is not flat ground (a drop's lower level).
pub const ROCKING_RESIDUAL_FRACTION: f64 = 0.9;

/// Calibrates the mount of `recording` (its rig is the starting point;
/// [`calibrate_checked`] also tries others):
/// with a rigid body, and with a rocking one, which is taken when it fits
/// clearly better ([`ROCKING_RESIDUAL_FRACTION`]).
pub fn calibrate(recording: &Recording, config: &CalibrationConfig) -> Result<MountEstimate, CalibrationError> {
    let rigid = calibrate_with(recording, config, Body::Rigid)?;
    match calibrate_with(recording, config, Body::Rocking) {
        Ok(rocking) if rocking.residual_after < ROCKING_RESIDUAL_FRACTION * rigid.residual_after => Ok(rocking),
        _ => Ok(rigid),
    }
}

/// Offsets (tilt, roll; degrees) from rig.toml's mount of the other starts
/// [`calibrate_checked`] solves from: a mount measured by hand is rarely
/// further off.
pub const OTHER_STARTS_DEG: [[f64; 2]; 2] = [[2.0, 2.0], [-2.0, -2.0]];
/// Solves that differ by no more than this in tilt, roll and yaw (degrees)
/// and [`START_AGREEMENT_HEIGHT`] in height are the same answer. Solves
/// that converge agree to a few thousandths of a degree; real_duckie_a's
/// spread over starts 1.6 degrees in tilt.
pub const START_AGREEMENT_DEG: f64 = 0.2;
/// Height agreement, as a fraction of the height.
pub const START_AGREEMENT_HEIGHT: f64 = 0.01;

/// Whether two solves are the same answer ([`START_AGREEMENT_DEG`]).
fn same_mount(a: &Mount, b: &Mount) -> bool {
    [a.tilt_deg - b.tilt_deg, a.roll_deg - b.roll_deg, a.yaw_deg - b.yaw_deg].iter().all(|d| d.abs() <= START_AGREEMENT_DEG)
        && (a.height_mm - b.height_mm).abs() <= START_AGREEMENT_HEIGHT * a.height_mm.abs()
}

/// [`calibrate`], then the same body model solved again from the starts
/// [`OTHER_STARTS_DEG`] away from rig.toml's mount: an estimate that only
/// one start reaches is refused ([`CalibrationError::StartDependent`])
/// rather than returned as if the images had determined it.
pub fn calibrate_checked(recording: &Recording, config: &CalibrationConfig) -> Result<MountEstimate, CalibrationError> {
    let estimate = calibrate(recording, config)?;
    let given = *recording.rig.mount();
    let mut solves = vec![(given, Ok(estimate.mount))];
    for [tilt, roll] in OTHER_STARTS_DEG {
        let start = Mount { tilt_deg: given.tilt_deg + tilt, roll_deg: given.roll_deg + roll, ..given };
        let solve = solve_from(recording, config, estimate.body, start).map(|other| other.mount).map_err(|e| e.to_string());
        solves.push((start, solve));
    }
    if solves.iter().all(|(_, solve)| solve.as_ref().is_ok_and(|mount| same_mount(mount, &estimate.mount))) {
        Ok(estimate)
    } else {
        Err(CalibrationError::StartDependent { solves })
    }
}

/// [`calibrate`] with the body model given.
pub fn calibrate_with(recording: &Recording, config: &CalibrationConfig, body: Body) -> Result<MountEstimate, CalibrationError> {
    solve_from(recording, config, body, *recording.rig.mount())
}

/// [`calibrate_with`] from the mount `start` instead of rig.toml's (the
/// residual before is the start's).
fn solve_from(recording: &Recording, config: &CalibrationConfig, body: Body, start_mount: Mount) -> Result<MountEstimate, CalibrationError> {
    let rig = recording.rig;
    let frames: Vec<u32> = recording.frames.clone();
    if frames.len() < 2 {
        return Err(CalibrationError::TooFewFrames);
    }
    let pose = |f: u32| if config.ignore_odometry { None } else { recording.pose(f).and_then(|row| row.pose) };
    let odometry = frames.iter().all(|&f| pose(f).is_some());
    let time = |f: u32| recording.pose(f).map(|row| row.t_s);
    let given_height = config.height_mm.unwrap_or(rig.mount().height_mm);

    // Pairs: with odometry, each frame with the first later one TARGET mm away.
    let mut candidates: Vec<(usize, usize, Motion)> = Vec::new();
    let mut largest: f64 = 0.0;
    if odometry {
        for i in 0..frames.len() {
            let from = pose(frames[i]).unwrap_or_default();
            let mut chosen = None;
            for j in i + 1..frames.len() {
                let motion = Motion::between(&from, &pose(frames[j]).unwrap_or_default());
                largest = largest.max(motion.distance_mm());
                if motion.distance_mm() >= TARGET_PAIR_MOTION_MM || j == frames.len() - 1 || j - i >= 8 {
                    chosen = Some((j, motion));
                    break;
                }
            }
            if let Some((j, motion)) = chosen.filter(|(_, m)| m.distance_mm() >= MIN_PAIR_MOTION_MM) {
                candidates.push((i, j, motion));
            }
        }
        if candidates.is_empty() {
            return Err(CalibrationError::NoMotion { largest_mm: largest });
        }
    } else {
        candidates = (0..frames.len() - 1).map(|i| (i, i + 1, Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 })).collect();
    }
    if candidates.len() > MAX_PAIRS {
        let n = candidates.len();
        candidates = (0..MAX_PAIRS).map(|k| candidates[k * (n - 1) / (MAX_PAIRS - 1)]).collect();
    }

    // Pyramids of the frames the pairs use.
    let mut pyramids: Vec<Vec<Image>> = vec![Vec::new(); frames.len()];
    for &(i, j, _) in &candidates {
        for f in [i, j] {
            if pyramids[f].is_empty() {
                let mut levels = vec![Image::from_frame(&recording.load_frame(frames[f])?)];
                for _ in 1..LEVELS {
                    let next = levels[levels.len() - 1].half();
                    levels.push(next);
                }
                pyramids[f] = levels;
            }
        }
    }
    let mut pairs: Vec<Pair> = candidates
        .iter()
        .map(|&(earlier, later, motion)| Pair {
            earlier,
            later,
            odometry: odometry.then_some(motion),
            interval_s: time(frames[later]).zip(time(frames[earlier])).map(|(later, earlier)| later - earlier),
            samples: Vec::new(),
            gain: 1.0,
            offset: 0.0,
            used: true,
        })
        .collect();
    let initial = start_mount;
    let mut state = State {
        mount: [initial.tilt_deg, if odometry { initial.height_mm } else { given_height }, initial.roll_deg, initial.yaw_deg],
        steps: pairs.iter().map(|p| [1.0, p.odometry.map_or(0.0, |m| m.dyaw_deg)]).collect(),
        attitudes: vec![[0.0; 2]; frames.len()],
        anchors: Vec::new(),
    };
    let start = state.clone();
    // The height stays nominal: each pair's scale takes up the flow's size.
    let mut unknowns: Vec<Unknown> = [0, 2, 3].map(Unknown::Mount).to_vec();
    // Each pair's turn is free, also with odometry: the odometry's turn
    // errors (0.05 deg a step on video_rate) otherwise go into the roll, which
    // moves the ground's flow much like a turn does (roll off by 0.75 deg).
    // The price: on sideways drives a free turn trades off against roll and
    // tilt (diagonal: 0.09 / 0.08 deg off instead of 0.006 / 0.001).
    unknowns.extend((0..pairs.len()).flat_map(|p| (0..2).map(move |c| Unknown::Step(p, c))));
    let rocking = body == Body::Rocking;
    let (anchors, attitude_unknowns_now) = attitude_unknowns(&pairs, frames.len());
    state.anchors = anchors;
    if rocking {
        unknowns.extend(attitude_unknowns_now);
    }
    let images_at = |level: usize| -> Vec<Image> {
        pyramids.iter().map(|levels| levels.get(level).cloned().unwrap_or(Image { width: 0, height: 0, pixels: Vec::new() })).collect()
    };

    let mut residual_before = 0.0;
    let mut last = None;
    for level_index in (0..LEVELS).rev() {
        let images = images_at(level_index);
        let level = Level { camera: level_camera(rig.camera(), level_index), images: &images };
        let level_rig = level.rig(&state).map_err(CalibrationError::Diverged)?;
        // Samples: later-frame pixels on the ground within reach, every
        // second pixel at full resolution.
        let stride = if level_index == 0 { 2 } else { 1 };
        let reach = REACH_FAR_EDGES * rig.aoi().far_mm;
        let camera = level.camera;
        for pair in pairs.iter_mut() {
            let image = &images[pair.later];
            pair.samples.clear();
            for v in (2..usize::from(camera.height) - 2).step_by(stride) {
                for u in (2..usize::from(camera.width) - 2).step_by(stride) {
                    let p = Pixel { u: u as f64, v: v as f64 };
                    if level_rig.pixel_to_ground(p).is_some_and(|(x, z)| x.hypot(z) <= reach) {
                        pair.samples.push((p, f64::from(image.pixels[v * image.width + u])));
                    }
                }
            }
        }
        let huber = level_index == LEVELS - 1;
        if !odometry && level_index == LEVELS - 1 {
            search_motions(&level, &mut pairs, &mut state);
        }
        if level_index == 0 {
            // At the rig as given, with the same samples.
            let mut given = state.clone();
            given.mount = start.mount;
            if odometry {
                given.steps = start.steps.clone();
            }
            if let Ok(given_rig) = level.rig(&given) {
                fit_photometry(&level, &given_rig, &mut pairs, &given, None, false);
                residual_before = residuals(&level, &pairs, &given).map_or(f64::NAN, |all| rms(&all));
            }
        }
        fit_photometry(&level, &level_rig, &mut pairs, &state, None, huber);
        let mut all = residuals(&level, &pairs, &state).ok_or(CalibrationError::Diverged(RigError::Tilt))?;
        let mut lambda = 1e-3;
        for _ in 0..ITERATIONS {
            let sigma = robust_scale(&all);
            let current_rig = level.rig(&state).map_err(CalibrationError::Diverged)?;
            fit_photometry(&level, &current_rig, &mut pairs, &state, Some(sigma), huber);
            all = residuals(&level, &pairs, &state).ok_or(CalibrationError::Diverged(RigError::Tilt))?;
            let before = cost(&all, sigma, huber);
            let (jtj, jtr, wrr, wsum) =
                normal_equations(&level, &pairs, &state, &unknowns, sigma, huber).map_err(CalibrationError::Diverged)?;
            last = Some((jtj.clone(), wrr, wsum));
            let mut improved = false;
            for _ in 0..6 {
                let damped: Vec<Vec<f64>> = (0..jtj.len())
                    .map(|i| (0..jtj.len()).map(|j| if i == j { jtj[i][j] * (1.0 + lambda) } else { jtj[i][j] }).collect())
                    .collect();
                let Some(step) = solve(&damped, &jtr.iter().map(|v| -v).collect::<Vec<_>>()) else {
                    return Err(CalibrationError::Underdetermined);
                };
                let mut trial = state.clone();
                for (k, &unknown) in unknowns.iter().enumerate() {
                    trial = trial.with(unknown, step[k]);
                }
                if let Some(trial_all) = residuals(&level, &pairs, &trial) {
                    if cost(&trial_all, sigma, huber) < before {
                        let small = unknowns.iter().enumerate().all(|(k, &u)| step[k].abs() < 0.05 * step_of(u));
                        state = trial;
                        all = trial_all;
                        lambda = (lambda / 10.0).max(1e-7);
                        improved = !small;
                        break;
                    }
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        // Pairs whose motion is not what the images show (slip) stand out.
        if level_index == LEVELS - 1 {
            let mut pair_medians: Vec<(usize, f64)> = all
                .iter()
                .enumerate()
                .filter(|(n, _)| pairs[*n].used)
                .map(|(n, r)| (n, median(&mut r.iter().map(|x| x.abs()).collect::<Vec<_>>())))
                .collect();
            let typical = median(&mut pair_medians.iter().map(|(_, m)| *m).collect::<Vec<_>>());
            for (n, m) in pair_medians.drain(..) {
                if m > PAIR_OUTLIER_FACTOR * typical && pairs.iter().filter(|p| p.used).count() > 1 {
                    pairs[n].used = false;
                }
            }
            // Dropped pairs may split a set of frames: new anchors, and no
            // attitude for a frame left without pairs.
            let (anchors, attitude_unknowns_now) = attitude_unknowns(&pairs, frames.len());
            unknowns.retain(|u| !matches!(u, Unknown::Attitude(..)));
            if rocking {
                unknowns.extend(attitude_unknowns_now);
            }
            state.anchors = anchors;
        }
    }

    let (jtj, wrr, wsum) = last.ok_or(CalibrationError::Underdetermined)?;
    let n = unknowns.len();
    let variance = wrr / (wsum - n as f64).max(1.0);
    let mut sigma = [0.0; 4];
    for (k, &unknown) in unknowns.iter().enumerate() {
        let Unknown::Mount(m) = unknown else { continue };
        let mut unit = vec![0.0; n];
        unit[k] = 1.0;
        let column = solve(&jtj, &unit).ok_or(CalibrationError::Underdetermined)?;
        sigma[m] = (variance * column[k]).sqrt();
    }
    let largest = (0..pairs.len()).filter(|&n| pairs[n].used).map(|n| state.motion(&pairs, n).distance_mm()).fold(0.0, f64::max);
    if largest < MIN_PAIR_MOTION_MM {
        return Err(CalibrationError::NoMotion { largest_mm: largest });
    }
    if odometry {
        // The images measure each pair's motion over the nominal height; the
        // odometry's distance over the pairs that agree (not slipping) fixes it.
        let scales: Vec<f64> = (0..pairs.len()).filter(|&n| pairs[n].used).map(|n| state.steps[n][0]).collect();
        let typical = median(&mut scales.clone());
        let agree: Vec<usize> = (0..pairs.len())
            .filter(|&n| pairs[n].used && (state.steps[n][0] - typical).abs() <= SCALE_AGREEMENT * typical.abs())
            .collect();
        let odometry_mm: f64 = agree.iter().map(|&n| pairs[n].odometry.map_or(0.0, |m| m.distance_mm())).sum();
        let seen_mm: f64 = agree.iter().map(|&n| state.steps[n][0] * pairs[n].odometry.map_or(0.0, |m| m.distance_mm())).sum();
        if !(typical > 0.0 && seen_mm > 0.0) {
            return Err(CalibrationError::Underdetermined);
        }
        let nominal = state.mount[1];
        state.mount[1] = nominal * odometry_mm / seen_mm;
        // The scatter of the pairs' scales, as the mean's uncertainty.
        let mean = agree.iter().map(|&n| state.steps[n][0]).sum::<f64>() / agree.len() as f64;
        let spread = agree.iter().map(|&n| (state.steps[n][0] - mean).powi(2)).sum::<f64>() / (agree.len().max(2) - 1) as f64;
        sigma[1] = state.mount[1] * spread.sqrt() / mean / (agree.len() as f64).sqrt();
        // The steps in the calibrated height's units.
        for step in state.steps.iter_mut() {
            step[0] *= odometry_mm / seen_mm;
        }
    }
    // The residual after, at full resolution with the same samples.
    let images = images_at(0);
    let level = Level { camera: *rig.camera(), images: &images };
    let final_rig = level.rig(&state).map_err(CalibrationError::Diverged)?;
    fit_photometry(&level, &final_rig, &mut pairs, &state, None, false);
    let residual_after = residuals(&level, &pairs, &state).map_or(f64::NAN, |all| rms(&all));
    let used: Vec<&Pair> = pairs.iter().filter(|p| p.used).collect();
    Ok(MountEstimate {
        mount: state.mount(),
        sigma,
        residual_before,
        residual_after,
        pairs: used.len(),
        samples: used.iter().map(|p| p.samples.len()).sum(),
        height_estimated: odometry,
        body,
        body_attitude_rms_deg: {
            let seen = |f: usize| used.iter().any(|p| p.earlier == f || p.later == f);
            let rocked: Vec<f64> = (0..frames.len()).filter(|&f| seen(f)).flat_map(|f| state.attitudes[f]).collect();
            (rocked.iter().map(|a| a * a).sum::<f64>() / rocked.len().max(1) as f64).sqrt()
        },
    })
}

fn rms(all: &[Vec<f64>]) -> f64 {
    let (sum, count) = all.iter().flatten().fold((0.0, 0usize), |(s, c), r| (s + r * r, c + 1));
    (sum / count.max(1) as f64).sqrt()
}

/// Without odometry: each pair's step from a search over chord lengths and
/// turns on the coarsest level, every fourth sample, at the starting mount.
fn search_motions(level: &Level, pairs: &mut [Pair], state: &mut State) {
    let Ok(rig) = level.rig(state) else { return };
    for (n, pair) in pairs.iter_mut().enumerate() {
        let mut best = (f64::INFINITY, state.steps[n]);
        for chord_cm in -30..=30 {
            for turn in -4..=4 {
                let step = [f64::from(chord_cm) * 10.0 / CHORD_UNIT_MM, f64::from(turn)];
                let map = PairMap::new(pair_motion(None, step), [Attitude::default(); 2], state.mount[1], pair.interval_s);
                let (mut sum, mut count) = (0.0, 0usize);
                for &(p, target) in pair.samples.iter().step_by(4) {
                    if let Some((r, _, _)) = residual(level, &rig, pair, &map, p, target) {
                        sum += r.abs();
                        count += 1;
                    }
                }
                if count * 2 >= pair.samples.len() / 4 {
                    let mean = sum / count as f64;
                    if mean < best.0 {
                        best = (mean, step);
                    }
                }
            }
        }
        state.steps[n] = best.1;
    }
}

/// `key: value` lines for stdout.
pub fn report(estimate: &MountEstimate) -> String {
    let m = &estimate.mount;
    let s = &estimate.sigma;
    format!(
        "tilt_deg: {:.3}\ntilt_deg_sigma: {:.3}\nheight_mm: {:.1}\nheight_mm_sigma: {:.1}\nroll_deg: {:.3}\nroll_deg_sigma: {:.3}\nyaw_deg: {:.3}\nyaw_deg_sigma: {:.3}\nheight_from: {}\nbody: {}\nbody_attitude_rms_deg: {:.3}\nresidual_before: {:.2}\nresidual_after: {:.2}\npairs: {}\nsamples: {}\n",
        m.tilt_deg,
        s[0],
        m.height_mm,
        s[1],
        m.roll_deg,
        s[2],
        m.yaw_deg,
        s[3],
        if estimate.height_estimated { "odometry" } else { "given" },
        match estimate.body {
            Body::Rigid => "rigid",
            Body::Rocking => "rocking",
        },
        estimate.body_attitude_rms_deg,
        estimate.residual_before,
        estimate.residual_after,
        estimate.pairs,
        estimate.samples,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Solves agree within 0.2 degrees and 1 % of the height; the refusal
    /// names every start and what it came to.
    #[test]
    fn solves_from_other_starts_must_agree() {
        let a = Mount { height_mm: 100.0, tilt_deg: 19.0, roll_deg: -2.5, yaw_deg: 0.0 };
        assert!(same_mount(&a, &Mount { tilt_deg: 19.19, height_mm: 100.9, ..a }));
        assert!(!same_mount(&a, &Mount { tilt_deg: 19.25, ..a }));
        assert!(!same_mount(&a, &Mount { roll_deg: -2.9, ..a }));
        assert!(!same_mount(&a, &Mount { height_mm: 101.5, ..a }));
        let error = CalibrationError::StartDependent {
            solves: vec![(a, Ok(a)), (Mount { tilt_deg: 21.0, ..a }, Ok(Mount { tilt_deg: 19.9, ..a })), (a, Err("no motion".into()))],
        };
        let text = error.to_string();
        assert!(text.starts_with("the mount depends on where the solve starts: from tilt 19.00 roll -2.50: tilt 19.00"), "{text}");
        assert!(text.contains("from tilt 21.00 roll -2.50: tilt 19.90") && text.contains("no motion;"), "{text}");
    }

    /// A constant velocity gives the motion back over its whole duration,
    /// and two halves make the whole (a turning arc with some sideways drift).
    #[test]
    fn velocity_splits_a_motion_into_equal_parts() {
        for motion in [
            Motion { tx_mm: -0.79, tz_mm: 59.99, dyaw_deg: 1.5 },
            Motion { tx_mm: 20.0, tz_mm: 40.0, dyaw_deg: -12.0 },
            Motion { tx_mm: 3.0, tz_mm: 50.0, dyaw_deg: 0.0 },
        ] {
            let velocity = Velocity::of(&motion);
            let whole = velocity.over(1.0);
            let half = velocity.over(0.5);
            let halves = half.then(&half);
            for m in [whole, halves] {
                assert!((m.tx_mm - motion.tx_mm).abs() < 1e-9 && (m.tz_mm - motion.tz_mm).abs() < 1e-9, "{m:?} {motion:?}");
                assert!((m.dyaw_deg - motion.dyaw_deg).abs() < 1e-9, "{m:?} {motion:?}");
            }
        }
    }

    #[test]
    fn section_values_keep_comments_and_layout() {
        let original = "# a rig\n\n[camera]\nfx = 240.0 # from the datasheet\n\n[mount]\nheight_mm=400.0\n\n[aoi]\nnear_mm = 450.0\n";
        let values = [("fx", "251.5".to_string()), ("fy", "251.5".to_string())];
        let text = with_section_values(original, "camera", &values).unwrap();
        assert_eq!(text, "# a rig\n\n[camera]\nfx = 251.5 # from the datasheet\nfy = 251.5\n\n[mount]\nheight_mm=400.0\n\n[aoi]\nnear_mm = 450.0\n");
        let text = with_section_values(original, "extra", &[("on", "true".to_string())]).unwrap();
        assert!(text.starts_with(original) && text.ends_with("[extra]\non = true\n"), "{text}");
        assert!(with_section_values("[mount\n", "mount", &values).is_err());
    }
}

//! Deterministic perturbations of a recording, for the robustness tests and
//! `flatland detect --perturb`: what real robots and cameras add to an ideal
//! recording. Sensor noise, gain flicker and odometry error; body pitch and
//! roll (the body turning about the robot origin on the ground: the frame is
//! warped by the ground's homography); exposure steps and vignetting (in
//! linear light); wheel slip (the images stand while poses.csv advances). Every random draw comes from the seed and the frame
//! number, so a run repeats exactly.
//!
//! [`Perturbation`] parses the `--perturb` grammar; [`Perturbation::apply`]
//! rewrites a recording's poses and truth and returns the [`FramePerturber`]
//! that alters its frames as they are loaded.

use crate::recording::{Frame, Recording, TruthPair};
use flatland_core::geometry::{Pixel, Rig};
use flatland_core::motion::{Attitude, Motion, Pose};
use std::collections::VecDeque;
use std::fmt::{self, Write};
use std::str::FromStr;

/// A small deterministic generator (SplitMix64): reproducible tests, no
/// dependency. The host side's one (perturbations, the fuzz targets'
/// textures); core's checks draw from `flatland_core::selftest::xorshift32`.
#[derive(Clone, Debug)]
pub struct SplitMix(u64);

impl SplitMix {
    pub fn new(seed: u64) -> SplitMix {
        SplitMix(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box-Muller).
    pub fn gaussian(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-12);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// Steps of one kind (`pitch`, `roll`, `exposure`) a perturbation holds: a
/// fixed capacity keeps [`Perturbation`] `Copy`.
pub const MAX_STEPS: usize = 8;

/// Largest body angle, degrees, as a jitter sigma or a step: a robot rocks
/// by a few degrees, and far beyond that the rotated view leaves the image.
pub const MAX_ANGLE_DEG: f64 = 10.0;

/// The "sRGB-ish" gamma that frames are encoded with: exposure and
/// vignetting act on linear light.
const GAMMA: f64 = 2.2;

/// A change from `frame` on.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Step {
    pub frame: u32,
    pub value: f64,
}

/// Changes from given frames on, at most [`MAX_STEPS`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Steps {
    steps: [Step; MAX_STEPS],
    len: usize,
}

impl Steps {
    /// Adds a step; gives it back when the steps are full.
    pub fn push(&mut self, step: Step) -> Result<(), Step> {
        let slot = self.steps.get_mut(self.len).ok_or(step)?;
        *slot = step;
        self.len += 1;
        Ok(())
    }

    pub fn as_slice(&self) -> &[Step] {
        &self.steps[..self.len]
    }

    /// The values of the steps taken by `frame`, added up.
    fn sum_at(&self, frame: u32) -> f64 {
        self.as_slice().iter().filter(|s| s.frame <= frame).map(|s| s.value).sum()
    }

    /// The values of the steps taken by `frame`, multiplied.
    fn product_at(&self, frame: u32) -> f64 {
        self.as_slice().iter().filter(|s| s.frame <= frame).map(|s| s.value).product()
    }
}

/// Wheel slip: in pairs `first_pair..=last_pair` (pair n compares frame n
/// with the frames before it) the robot stands still while its wheels turn.
/// The images hold frame `first_pair - 1` and every later image comes that
/// many frames late; poses.csv advances by the wheels' usual step, so from
/// `last_pair` on it runs ahead of the images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Slip {
    pub first_pair: u32,
    pub last_pair: u32,
}

impl Slip {
    /// The original frame whose image frame `frame` shows.
    pub fn source(&self, frame: u32) -> u32 {
        let held = self.first_pair.saturating_sub(1);
        if frame < self.first_pair {
            frame
        } else if frame <= self.last_pair {
            held
        } else {
            frame - (self.last_pair - held)
        }
    }

    /// Rewrites poses.csv (the wheels' steps over the images' motion) and the
    /// truth pairs (each frame's answer is its image's). The truth's world
    /// obstacles are left as they are.
    fn rewrite(&self, recording: &mut Recording) {
        let original = recording.poses.clone();
        let row_of = |frame: u32| original.iter().find(|row| row.frame == frame);
        for n in 1..original.len() {
            // A recording without odometry has no wheels to slip.
            let (Some(previous), Some(first), Some(second)) = (recording.poses[n - 1].pose, original[n - 1].pose, original[n].pose) else {
                continue;
            };
            let (before, after) = (original[n - 1].frame, original[n].frame);
            let (from, to) = (self.source(before), self.source(after));
            // Standing, the wheels make the step they would have made; else
            // they follow the images.
            let (from, to) = if from == to { (before, after) } else { (from, to) };
            let step = match (row_of(from).and_then(|row| row.pose), row_of(to).and_then(|row| row.pose)) {
                (Some(from), Some(to)) => Motion::between(&from, &to),
                _ => Motion::between(&first, &second),
            };
            recording.poses[n].pose = Some(moved(&previous, &step));
        }
        // The IMU is on the body, which stands where its images show.
        for row in recording.poses.iter_mut().filter(|row| row.attitude.is_some()) {
            row.attitude = row_of(self.source(row.frame)).and_then(|source| source.attitude);
        }
        if let Some(truth) = recording.truth.as_mut() {
            let pairs = std::mem::take(&mut truth.pair);
            truth.pair = recording
                .frames
                .iter()
                .filter_map(|&frame| {
                    let pair = pairs.iter().find(|pair| pair.frame == self.source(frame))?;
                    Some(TruthPair { frame, ..pair.clone() })
                })
                .collect();
        }
    }
}

/// What to do to a recording. `Default` does nothing; `"KEY=VALUE,..."`
/// parses into one (the `--perturb` grammar, docs/CLI.md).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Perturbation {
    pub seed: u64,
    /// Gaussian sensor noise, gray levels.
    pub noise_sigma: f64,
    /// Per-frame gain, uniformly within +-this fraction.
    pub gain_flicker: f64,
    /// Per-step odometry scale error, sigma as a fraction of the step.
    pub odometry_scale_sigma: f64,
    /// A constant odometry scale error (wheel diameter off), fraction.
    pub odometry_scale_bias: f64,
    /// Per-step yaw error, sigma in degrees.
    pub yaw_sigma_deg: f64,
    /// Body pitch and roll jitter, white per frame, sigma in degrees.
    pub pitch_sigma_deg: f64,
    pub roll_sigma_deg: f64,
    /// Sustained body pitch and roll (braking, a slope): each step adds its
    /// degrees from its frame on.
    pub pitch_steps: Steps,
    pub roll_steps: Steps,
    /// Exposure: each step multiplies the gain (linear light) from its frame on.
    pub exposure_steps: Steps,
    /// Vignetting: the linear-light brightness left at the corner farthest
    /// from the principal point, in (0, 1]; None: no vignetting.
    pub vignette_corner: Option<f64>,
    pub slip: Option<Slip>,
}

impl Perturbation {
    /// The body attitude applied to frame `index`: the sustained steps plus
    /// the jitter. On a level recording (every bundled one) it is the true
    /// attitude, what an exact IMU would report.
    pub fn attitude(&self, index: u32) -> Attitude {
        let mut rng = SplitMix::new(self.seed ^ (u64::from(index) << 32) ^ 0xA771);
        // Both draws always, so that one axis's jitter does not depend on the other's.
        let (pitch, roll) = (rng.gaussian(), rng.gaussian());
        Attitude {
            pitch_deg: self.pitch_steps.sum_at(index) + self.pitch_sigma_deg * pitch,
            roll_deg: self.roll_steps.sum_at(index) + self.roll_sigma_deg * roll,
        }
    }

    /// Applies noise and gain flicker to a frame (frame index mixes into the seed).
    pub fn frame(&self, index: u32, frame: &mut Frame) {
        let mut rng = SplitMix::new(self.seed ^ (u64::from(index) << 32) ^ 0x5EED);
        let gain = 1.0 + self.gain_flicker * (2.0 * rng.uniform() - 1.0);
        for pixel in frame.pixels.iter_mut() {
            let value = f64::from(*pixel) * gain + self.noise_sigma * rng.gaussian();
            *pixel = value.round().clamp(0.0, 255.0) as u8;
        }
    }

    /// Re-integrates the poses with odometry error: each step's length is
    /// scaled and its heading change disturbed, as wheel encoders would.
    pub fn poses(&self, recording: &mut Recording) {
        if self.odometry_scale_sigma == 0.0 && self.odometry_scale_bias == 0.0 && self.yaw_sigma_deg == 0.0 {
            return; // the poses as they are, bit for bit
        }
        let mut rng = SplitMix::new(self.seed ^ 0x0D0);
        let truth = recording.poses.clone();
        for n in 1..truth.len() {
            // Rows without odometry have none to disturb.
            let (Some(before), Some(after), Some(previous)) = (truth[n - 1].pose, truth[n].pose, recording.poses[n - 1].pose) else {
                continue;
            };
            let step = Motion::between(&before, &after);
            let scale = 1.0 + self.odometry_scale_bias + self.odometry_scale_sigma * rng.gaussian();
            let noisy = Motion {
                tx_mm: step.tx_mm * scale,
                tz_mm: step.tz_mm * scale,
                dyaw_deg: step.dyaw_deg + self.yaw_sigma_deg * rng.gaussian(),
            };
            recording.poses[n].pose = Some(moved(&previous, &noisy));
        }
    }

    /// Everything at once: rewrites the recording's poses (slip, then
    /// odometry error) and truth (slip), and returns what alters its frames.
    pub fn apply(&self, recording: &mut Recording) -> FramePerturber {
        if let Some(slip) = self.slip {
            slip.rewrite(recording);
        }
        self.poses(recording);
        // An IMU turns with the body: its columns read the applied attitude too.
        for row in recording.poses.iter_mut() {
            if let Some(imu) = row.attitude.as_mut() {
                *imu = imu.then(&self.attitude(row.frame));
            }
        }
        FramePerturber::new(*self, &recording.rig)
    }

    /// The recording's poses.csv with the applied attitude as its IMU
    /// columns (`pitch_deg,roll_deg`, RECORDING.md), exact: for a copy of
    /// the recording that tests an estimator with IMU priors.
    pub fn imu_poses_csv(&self, recording: &Recording) -> String {
        let mut text = String::from("frame,t_s,x_mm,z_mm,yaw_deg,pitch_deg,roll_deg\n");
        for row in &recording.poses {
            let attitude = self.attitude(row.frame);
            // A row without odometry keeps its motion fields empty.
            let motion = row.pose.map_or(String::from(",,"), |Pose { x_mm, z_mm, yaw_deg }| format!("{x_mm},{z_mm},{yaw_deg}"));
            let _ = writeln!(text, "{},{},{motion},{},{}", row.frame, row.t_s, attitude.pitch_deg, attitude.roll_deg);
        }
        text
    }

    /// The exposure gain of frame `index`.
    fn gain(&self, index: u32) -> f64 {
        self.exposure_steps.product_at(index)
    }
}

/// `pose` after `step` (given in its robot frame).
fn moved(pose: &Pose, step: &Motion) -> Pose {
    let (x_mm, z_mm) = pose.robot_to_world(step.tx_mm, step.tz_mm);
    Pose { x_mm, z_mm, yaw_deg: pose.yaw_deg + step.dyaw_deg }
}

/// Alters one recording's frames, in frame order (slip delays images):
/// slip, body attitude, exposure and vignetting, then noise and flicker.
pub struct FramePerturber {
    perturbation: Perturbation,
    rig: Rig,
    /// Original frames that slip shows later, oldest first.
    delayed: VecDeque<(u32, Frame)>,
    /// Each pixel's undistorted normalised ray (x right, y down), row-major.
    rays: Vec<(f64, f64)>,
    /// Each pixel's vignetting factor; empty without vignetting.
    shading: Vec<f64>,
    /// Gray level -> linear light in [0, 1].
    linear: [f64; 256],
}

impl FramePerturber {
    fn new(perturbation: Perturbation, rig: &Rig) -> FramePerturber {
        let camera = rig.camera();
        let (width, height) = (usize::from(camera.width), usize::from(camera.height));
        let pixels = || (0..height).flat_map(move |v| (0..width).map(move |u| Pixel { u: u as f64, v: v as f64 }));
        // A rig's every pixel undistorts (Rig::new_checked); the ray through
        // the distorted position would only stand in for an impossible one.
        let rays = pixels()
            .map(|p| rig.pixel_to_normalised(p).unwrap_or(((p.u - camera.cx) / camera.fx, (p.v - camera.cy) / camera.fy)))
            .collect();
        let shading = match perturbation.vignette_corner {
            None => Vec::new(),
            Some(corner) => {
                // cos^4 of the field angle, with the effective focal length that
                // leaves `corner` at the farthest corner.
                let radius_sq = |p: Pixel| ((p.u - camera.cx) / camera.fx).powi(2) + ((p.v - camera.cy) / camera.fy).powi(2);
                let (right, bottom) = (f64::from(camera.width) - 1.0, f64::from(camera.height) - 1.0);
                let farthest = [(0.0, 0.0), (right, 0.0), (0.0, bottom), (right, bottom)]
                    .map(|(u, v)| radius_sq(Pixel { u, v }))
                    .into_iter()
                    .fold(0.0, f64::max);
                let a = (corner.powf(-0.5) - 1.0) / farthest.max(f64::MIN_POSITIVE);
                pixels().map(|p| (1.0 + a * radius_sq(p)).powi(-2)).collect()
            }
        };
        let linear = std::array::from_fn(|level| (level as f64 / 255.0).powf(GAMMA));
        FramePerturber { perturbation, rig: *rig, delayed: VecDeque::new(), rays, shading, linear }
    }

    /// Alters frame `index` as loaded (of the rig's size, as
    /// [`Recording::load_frame`] gives it).
    pub fn alter(&mut self, index: u32, frame: &mut Frame) {
        self.slip(index, frame);
        let attitude = self.perturbation.attitude(index);
        if attitude != Attitude::default() {
            frame.pixels = self.rotate(frame, attitude);
        }
        self.photometry(index, frame);
        self.perturbation.frame(index, frame);
    }

    /// Shows the image slip wants for frame `index`. A source frame that was
    /// never loaded (a gap in the recording) leaves the frame as it is.
    fn slip(&mut self, index: u32, frame: &mut Frame) {
        let Some(slip) = self.perturbation.slip else { return };
        self.delayed.push_back((index, frame.clone()));
        let source = slip.source(index);
        while self.delayed.front().is_some_and(|(held, _)| *held < source) {
            self.delayed.pop_front();
        }
        if let Some((_, shown)) = self.delayed.front().filter(|(held, _)| *held == source) {
            frame.clone_from(shown);
        }
    }

    /// The frame as the camera sees it with the body at `attitude`: for each
    /// pixel, the level camera's ray through the same ground point (a
    /// homography between undistorted pixels, [`attitude_homography`]),
    /// bilinear, the nearest edge value outside the image.
    fn rotate(&self, frame: &Frame, attitude: Attitude) -> Vec<u8> {
        let m = attitude_homography(self.rig.mount().tilt_deg, attitude);
        let camera = self.rig.camera();
        self.rays
            .iter()
            .map(|&(x, y)| {
                let ray = [0, 1, 2].map(|i| m[i][0] * x + m[i][1] * y + m[i][2]);
                // Only a rotation far past MAX_ANGLE_DEG turns a ray behind the
                // camera; it keeps its sideways direction, to the nearest edge.
                let depth = ray[2].max(1e-9);
                let (xs, ys) = (ray[0] / depth, ray[1] / depth);
                // Past the lens's monotonic radius lies outside the image:
                // the pinhole position is as good an edge to clamp to.
                let source = self.rig.normalised_to_pixel(xs, ys).unwrap_or(Pixel { u: camera.fx * xs + camera.cx, v: camera.fy * ys + camera.cy });
                bilinear(frame, source)
            })
            .collect()
    }

    /// Exposure gain and vignetting, in linear light.
    fn photometry(&self, index: u32, frame: &mut Frame) {
        let gain = self.perturbation.gain(index);
        if gain == 1.0 && self.shading.is_empty() {
            return;
        }
        for (n, pixel) in frame.pixels.iter_mut().enumerate() {
            let light = self.linear[usize::from(*pixel)] * gain * self.shading.get(n).copied().unwrap_or(1.0);
            *pixel = (255.0 * light.clamp(0.0, 1.0).powf(1.0 / GAMMA)).round() as u8;
        }
    }
}

/// The map from a ray of the camera on the body at `attitude` to the level
/// camera's ray through the same ground point, both in camera axes (x right,
/// y down, z along the axis): T^T P R T. T holds the camera's axes in the
/// robot frame (x right, y up, z forward; tilted down by `tilt_deg`). R
/// turns the body about the robot origin on the ground (RECORDING.md):
/// pitch about its right axis, then roll about the level forward axis.
/// That also moves the optical centre C = (0, H, 0) to R C; P = I - w e_y^T,
/// w = (R C - C) / (R C)_y, takes the ground's view back to the level
/// centre (H cancels). A pure rotation about the optical centre (P = I)
/// would, under roll, shift the ground sideways by as much as it rotates
/// it. Exact on the ground; above it, the parallax of the few mm that the
/// centre moves is left out.
fn attitude_homography(tilt_deg: f64, attitude: Attitude) -> [[f64; 3]; 3] {
    let (sin_t, cos_t) = tilt_deg.to_radians().sin_cos();
    let (sin_p, cos_p) = attitude.pitch_deg.to_radians().sin_cos();
    let (sin_r, cos_r) = attitude.roll_deg.to_radians().sin_cos();
    // Columns: the camera's right, down and forward axes in the robot frame.
    let t = [[1.0, 0.0, 0.0], [0.0, -cos_t, -sin_t], [0.0, -sin_t, cos_t]];
    // Columns: where the body's right, up and forward axes go. Pitch takes
    // forward to (0, -sin, cos); roll takes right to (cos, -sin, 0).
    let pitch = [[1.0, 0.0, 0.0], [0.0, cos_p, -sin_p], [0.0, sin_p, cos_p]];
    let roll = [[cos_r, sin_r, 0.0], [-sin_r, cos_r, 0.0], [0.0, 0.0, 1.0]];
    let product = |a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]| -> [[f64; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
    };
    let r = product(&roll, &pitch);
    // (R C - C) / (R C)_y with C = H e_y: R's up column, less e_y, over its y.
    let w = [r[0][1], r[1][1] - 1.0, r[2][1]].map(|x| x / r[1][1]);
    let back: [[f64; 3]; 3] = std::array::from_fn(|i| {
        let mut row = [0.0; 3];
        row[i] = 1.0;
        row[1] -= w[i];
        row
    });
    let t_transposed = std::array::from_fn(|i| std::array::from_fn(|j| t[j][i]));
    product(&t_transposed, &product(&product(&back, &r), &t))
}

/// The frame at `p`, bilinear; outside the image, the nearest edge value.
fn bilinear(frame: &Frame, p: Pixel) -> u8 {
    let (Some(right), Some(bottom)) = (frame.width.checked_sub(1), frame.height.checked_sub(1)) else { return 0 };
    let u = p.u.clamp(0.0, right as f64);
    let v = p.v.clamp(0.0, bottom as f64);
    let (u0, v0) = (u.floor() as usize, v.floor() as usize);
    let (u1, v1) = ((u0 + 1).min(right), (v0 + 1).min(bottom));
    let (fu, fv) = (u - u0 as f64, v - v0 as f64);
    let at = |u: usize, v: usize| f64::from(frame.pixels.get(v * frame.width + u).copied().unwrap_or(0));
    let top = at(u0, v0) * (1.0 - fu) + at(u1, v0) * fu;
    let low = at(u0, v1) * (1.0 - fu) + at(u1, v1) * fu;
    (top * (1.0 - fv) + low * fv).round() as u8
}

/// Why a `--perturb` specification was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum PerturbError {
    /// An item is not `KEY=VALUE`.
    NotKeyValue(String),
    UnknownKey(String),
    /// A key that takes one value was given twice.
    Repeated(&'static str),
    /// A value does not parse or is out of range.
    BadValue { key: &'static str, value: String, expected: &'static str },
    /// More than [`MAX_STEPS`] steps of one kind.
    TooManySteps(&'static str),
}

/// The keys, in the order the help lists them.
const KEYS: [&str; 13] =
    ["noise", "flicker", "odometry", "bias", "yaw", "pitch-jitter", "roll-jitter", "pitch", "roll", "exposure", "vignette", "slip", "seed"];

impl fmt::Display for PerturbError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PerturbError::NotKeyValue(item) => write!(f, "perturbation {item:?} is not KEY=VALUE"),
            PerturbError::UnknownKey(key) => write!(f, "unknown perturbation {key:?} (keys: {})", KEYS.join(", ")),
            PerturbError::Repeated(key) => write!(f, "perturbation {key} given twice (only pitch, roll and exposure take several steps)"),
            PerturbError::BadValue { key, value, expected } => write!(f, "perturbation {key}={value}: expected {expected}"),
            PerturbError::TooManySteps(key) => write!(f, "more than {MAX_STEPS} {key} steps"),
        }
    }
}

impl std::error::Error for PerturbError {}

impl FromStr for Perturbation {
    type Err = PerturbError;

    /// `KEY=VALUE,...`; see [`KEYS`] and docs/CLI.md.
    fn from_str(text: &str) -> Result<Perturbation, PerturbError> {
        let mut p = Perturbation::default();
        let mut given: Vec<&'static str> = Vec::new();
        for item in text.split(',') {
            let (key, value) = item.split_once('=').ok_or_else(|| PerturbError::NotKeyValue(item.to_string()))?;
            let key = *KEYS.iter().find(|k| **k == key).ok_or_else(|| PerturbError::UnknownKey(key.to_string()))?;
            let bad = |expected: &'static str| PerturbError::BadValue { key, value: value.to_string(), expected };
            let number = |expected: &'static str, valid: fn(f64) -> bool| {
                value.parse::<f64>().ok().filter(|v| v.is_finite() && valid(*v)).ok_or_else(|| bad(expected))
            };
            let step = |expected: &'static str, valid: fn(f64) -> bool| -> Result<Step, PerturbError> {
                let (frame, amount) = value.split_once(':').ok_or_else(|| bad(expected))?;
                let frame = frame.parse().map_err(|_| bad(expected))?;
                let amount = amount.parse::<f64>().ok().filter(|v| v.is_finite() && valid(*v)).ok_or_else(|| bad(expected))?;
                Ok(Step { frame, value: amount })
            };
            let repeatable = matches!(key, "pitch" | "roll" | "exposure");
            if !repeatable && given.contains(&key) {
                return Err(PerturbError::Repeated(key));
            }
            given.push(key);
            let sigma: fn(f64) -> bool = |v| v >= 0.0;
            let angle: fn(f64) -> bool = |v| v.abs() <= MAX_ANGLE_DEG;
            let angle_sigma: fn(f64) -> bool = |v| (0.0..=MAX_ANGLE_DEG).contains(&v);
            match key {
                "noise" => p.noise_sigma = number("a sigma in gray levels, >= 0", sigma)?,
                "flicker" => p.gain_flicker = number("a fraction in [0, 1)", |v| (0.0..1.0).contains(&v))?,
                "odometry" => p.odometry_scale_sigma = number("a sigma as a fraction of the step, >= 0", sigma)?,
                "bias" => p.odometry_scale_bias = number("a scale error in (-1, 1)", |v| v.abs() < 1.0)?,
                "yaw" => p.yaw_sigma_deg = number("a sigma in degrees per step, >= 0", sigma)?,
                "pitch-jitter" => p.pitch_sigma_deg = number("a sigma in degrees, 0 to 10", angle_sigma)?,
                "roll-jitter" => p.roll_sigma_deg = number("a sigma in degrees, 0 to 10", angle_sigma)?,
                "pitch" | "roll" | "exposure" => {
                    let (steps, new) = match key {
                        "pitch" => (&mut p.pitch_steps, step("FRAME:DEGREES, -10 to 10", angle)?),
                        "roll" => (&mut p.roll_steps, step("FRAME:DEGREES, -10 to 10", angle)?),
                        _ => (&mut p.exposure_steps, step("FRAME:FACTOR, factor > 0", |v| v > 0.0)?),
                    };
                    steps.push(new).map_err(|_| PerturbError::TooManySteps(key))?;
                }
                "vignette" => p.vignette_corner = Some(number("the brightness left at the corners, in (0, 1]", |v| v > 0.0 && v <= 1.0)?),
                "slip" => {
                    let expected = "FIRST-LAST pair numbers, 1 <= FIRST <= LAST";
                    let (first, last) = value.split_once('-').ok_or_else(|| bad(expected))?;
                    let (first_pair, last_pair) = (first.parse().map_err(|_| bad(expected))?, last.parse().map_err(|_| bad(expected))?);
                    if !(1 <= first_pair && first_pair <= last_pair) {
                        return Err(bad(expected));
                    }
                    p.slip = Some(Slip { first_pair, last_pair });
                }
                "seed" => p.seed = value.parse().map_err(|_| bad("an unsigned integer"))?,
                other => return Err(PerturbError::UnknownKey(other.to_string())),
            }
        }
        Ok(p)
    }
}

//! Deterministic perturbations of recordings for the harder test cases:
//! sensor noise, gain flicker, odometry scale and yaw error.

use crate::recording::{Frame, Recording};

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

/// What to do to a recording.
#[derive(Clone, Copy, Debug, Default)]
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
}

impl Perturbation {
    /// Applies noise and gain to a frame (frame index mixes into the seed).
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
        let mut rng = SplitMix::new(self.seed ^ 0x0D0);
        let truth = recording.poses.clone();
        for n in 1..truth.len() {
            let (before, after) = (truth[n - 1].pose, truth[n].pose);
            let step = flatland_core::motion::Motion::between(&before, &after);
            let scale = 1.0 + self.odometry_scale_bias + self.odometry_scale_sigma * rng.gaussian();
            let noisy = flatland_core::motion::Motion {
                tx_mm: step.tx_mm * scale,
                tz_mm: step.tz_mm * scale,
                dyaw_deg: step.dyaw_deg + self.yaw_sigma_deg * rng.gaussian(),
            };
            let previous = recording.poses[n - 1].pose;
            let (x_mm, z_mm) = previous.robot_to_world(noisy.tx_mm, noisy.tz_mm);
            recording.poses[n].pose =
                flatland_core::motion::Pose { x_mm, z_mm, yaw_deg: previous.yaw_deg + noisy.dyaw_deg };
        }
    }
}

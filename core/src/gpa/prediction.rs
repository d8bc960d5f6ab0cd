//! The chained prediction: the motion keyframe -> frame n is predicted as
//! the *refined* motion keyframe -> n-1 followed by the odometry n-1 -> n,
//! so odometry error never accumulates over the keyframe baseline. Wheel
//! odometry with a constant scale error (a worn tyre) is corrected by the
//! scale the shift search has been measuring.

use crate::motion::Motion;

/// Interval ratios the constant-velocity step is scaled by; beyond them a
/// time stamp is more likely wrong than the robot's rate so uneven, and the
/// step is kept as measured (the prior's sigma still widens with the interval).
const INTERVAL_RATIOS: core::ops::RangeInclusive<f64> = 0.1..=10.0;

pub(super) struct Prediction {
    /// Refined motion keyframe -> last frame (-> this frame once settled).
    to_last: Motion,
    last_frame: u32,
    /// This frame's prediction, keyframe -> now.
    pub(super) predicted: Motion,
    /// Odometry since the previous frame, scale-corrected.
    pub(super) step: Motion,
    /// Measured ratio of true to odometry travel (1.0 until measured).
    odometry_scale: f64,
}

impl Prediction {
    pub(super) const START: Prediction = Prediction {
        to_last: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        last_frame: 0,
        predicted: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        step: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 },
        odometry_scale: 1.0,
    };

    /// Whether `frame` directly follows the last one.
    pub(super) fn follows(&self, frame: u32) -> bool {
        frame == self.last_frame.wrapping_add(1)
    }

    /// Predicts this frame from the last one moved by `odometry`, or
    /// without it by the step last measured (constant velocity: times
    /// `interval_ratio`, this frame's interval over the last one's, when known).
    pub(super) fn predict(&mut self, odometry: Option<&Motion>, interval_ratio: Option<f64>) {
        match odometry {
            Some(odometry) => {
                self.step = Motion {
                    tx_mm: odometry.tx_mm * self.odometry_scale,
                    tz_mm: odometry.tz_mm * self.odometry_scale,
                    dyaw_deg: odometry.dyaw_deg,
                };
            }
            None => {
                if let Some(ratio) = interval_ratio.filter(|r| INTERVAL_RATIOS.contains(r)) {
                    self.step = Motion { tx_mm: self.step.tx_mm * ratio, tz_mm: self.step.tz_mm * ratio, dyaw_deg: self.step.dyaw_deg * ratio };
                }
            }
        }
        self.predicted = self.to_last.then(&self.step);
    }

    /// No motion known: this frame starts a keyframe. The step is kept:
    /// without odometry it is the velocity the next frame predicts from,
    /// and a robot does not stop because an estimate failed.
    pub(super) fn start_keyframe(&mut self) {
        self.predicted = Motion::default();
    }

    /// The motion keyframe -> now: the shift search's `refined` one if it
    /// measured one (and then the odometry scale learns from it), else the
    /// prediction (on a grid of `mm_per_px`).
    pub(super) fn settle(&mut self, refined: Option<Motion>, mm_per_px: f64) {
        match refined {
            Some(refined) => {
                // The step as measured: refined keyframe->now, minus keyframe->before.
                let (dx, dz) = (refined.tx_mm - self.to_last.tx_mm, refined.tz_mm - self.to_last.tz_mm);
                self.to_last = refined;
                self.learn_odometry_scale(dx, dz, mm_per_px);
            }
            None => self.to_last = self.predicted,
        }
    }

    /// The motion keyframe -> last frame.
    pub(super) fn to_last(&self) -> Motion {
        self.to_last
    }

    /// Frame `frame` is over; if it became the keyframe, motion restarts from it.
    pub(super) fn finish(&mut self, frame: u32, new_keyframe: bool) {
        self.last_frame = frame;
        if new_keyframe {
            self.to_last = Motion::default();
        }
    }

    /// Updates the odometry scale from this frame's refined step (`dx`,
    /// `dz`): a slow average, so random per-step errors cancel and a
    /// constant one remains.
    fn learn_odometry_scale(&mut self, dx: f64, dz: f64, mm_per_px: f64) {
        let odometry = self.step.distance_mm() / self.odometry_scale;
        // Short steps measure the scale poorly.
        if odometry < 4.0 * mm_per_px {
            return;
        }
        let measured = libm::hypot(dx, dz) / odometry;
        if (0.8..=1.25).contains(&measured) {
            self.odometry_scale = (0.8 * self.odometry_scale + 0.2 * measured).clamp(0.8, 1.25);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without odometry the step last measured is the velocity: a frame
    /// twice as far apart in time is predicted twice as far; with
    /// odometry the interval does not matter.
    #[test]
    fn without_odometry_the_step_scales_with_the_interval() {
        let mut prediction = Prediction::START;
        prediction.predict(Some(&Motion { tx_mm: 2.0, tz_mm: 50.0, dyaw_deg: 1.0 }), None);
        prediction.predict(None, Some(2.0));
        assert_eq!(prediction.predicted, Motion { tx_mm: 4.0, tz_mm: 100.0, dyaw_deg: 2.0 });
        prediction.predict(None, None);
        assert_eq!(prediction.predicted, Motion { tx_mm: 4.0, tz_mm: 100.0, dyaw_deg: 2.0 });
        prediction.predict(Some(&Motion { tx_mm: 0.0, tz_mm: 30.0, dyaw_deg: 0.0 }), Some(3.0));
        assert_eq!(prediction.predicted, Motion { tx_mm: 0.0, tz_mm: 30.0, dyaw_deg: 0.0 });
    }
}

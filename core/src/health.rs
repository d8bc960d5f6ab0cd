//! Sensor health and the alarm it implies: the fail-safe rule in one place.
//!
//! The alarm output tells the robot whether its path is clear. It may be
//! released only by a frame that was judged clear; everything else (reset,
//! a keyframe restart, a frame not judged, a frame that could not be read,
//! a camera or an odometry stream that went quiet) asserts it. [`Monitor`] holds that rule:
//! the frame loop feeds it what happened and when, and reads back
//! [`Monitor::alarm`] and [`Monitor::health`].
//!
//! Time is the caller's: microseconds of the board's clock, wrapping at
//! 2^32 (71 minutes). Only differences are taken, and a timeout is latched
//! when first seen, so a wrap cannot make a stale stream look fresh as long
//! as [`Monitor::poll`] runs more often than every 35 minutes (the loop polls
//! continuously while it waits).
//!
//! [`Health`] is what a status output reports (the line protocol's `$FLERR`
//! codes, a MAVLink `HEARTBEAT.system_status` and `STATUSTEXT`).

use core::fmt;

/// A camera that delivers no frame this long after it was asked is lost.
pub const CAMERA_TIMEOUT_US: u32 = 500_000;
/// Odometry that does not come for this long while the loop waits for it
/// has stopped. The time the loop spends on a frame does not count: a robot
/// that keeps sending has its next `$FLODO` waiting when the frame ends.
pub const ODOMETRY_TIMEOUT_US: u32 = 500_000;

/// What is wrong with a sensor. Each raises the alarm until a frame is
/// judged clear again.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SensorFault {
    /// The camera delivered no frame within [`CAMERA_TIMEOUT_US`] of being asked.
    CameraTimeout,
    /// A frame came but could not be used: missing, not the rig's format,
    /// cut short, refused by the remap.
    FrameLost,
    /// No odometry for [`ODOMETRY_TIMEOUT_US`] while the loop waited for it.
    OdometryTimeout,
}

impl SensorFault {
    /// A short name for logs and status texts.
    pub const fn as_str(self) -> &'static str {
        match self {
            SensorFault::CameraTimeout => "camera_timeout",
            SensorFault::FrameLost => "frame_lost",
            SensorFault::OdometryTimeout => "odometry_lost",
        }
    }
}

impl fmt::Display for SensorFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SensorFault::CameraTimeout => "the camera delivered no frame in time",
            SensorFault::FrameLost => "a frame could not be used",
            SensorFault::OdometryTimeout => "odometry stopped",
        })
    }
}

impl core::error::Error for SensorFault {}

/// The sensor's state as a status output reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Health {
    /// No frame judged yet (since reset, or since the keyframe restarted):
    /// nothing is known, the alarm is asserted. MAVLink: `MAV_STATE_STANDBY`.
    Starting,
    /// The last frame was judged and no sensor is at fault. MAVLink: `MAV_STATE_ACTIVE`.
    Ok,
    /// A sensor is at fault: the alarm is asserted. MAVLink: `MAV_STATE_CRITICAL`.
    Fault(SensorFault),
}

/// What the last frame said about the path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Verdict {
    /// Not judged: reset, keyframe (re)start, a skipped or lost frame, a fault.
    Unknown,
    Clear,
    Obstacle,
}

/// The fail-safe state: the last verdict, the active fault and the odometry
/// timer. See the module documentation.
#[derive(Clone, Copy, Debug)]
pub struct Monitor {
    verdict: Verdict,
    fault: Option<SensorFault>,
    /// When the odometry timeout counts from: the last `$FLODO`, or the
    /// moment the loop began to wait if that is later. None before the first
    /// `$FLODO` (odometry that never started has not stopped; the alarm is
    /// asserted anyway).
    odometry_since: Option<u32>,
}

impl Default for Monitor {
    fn default() -> Self {
        Self::new()
    }
}

impl Monitor {
    /// The state at reset: nothing judged, alarm asserted.
    pub const fn new() -> Self {
        Monitor { verdict: Verdict::Unknown, fault: None, odometry_since: None }
    }

    /// The alarm output: asserted unless the last frame was judged clear
    /// and no sensor is at fault.
    pub fn alarm(&self) -> bool {
        !(self.verdict == Verdict::Clear && self.fault.is_none())
    }

    pub fn verdict(&self) -> Verdict {
        self.verdict
    }

    pub fn health(&self) -> Health {
        match (self.fault, self.verdict) {
            (Some(fault), _) => Health::Fault(fault),
            (None, Verdict::Unknown) => Health::Starting,
            (None, Verdict::Clear | Verdict::Obstacle) => Health::Ok,
        }
    }

    /// A `$FLODO` arrived at `now`: the odometry timer restarts, and an
    /// odometry timeout is over (the alarm stays until a frame is judged).
    pub fn odometry(&mut self, now: u32) {
        self.odometry_since = Some(now);
        if self.fault == Some(SensorFault::OdometryTimeout) {
            self.fault = None;
        }
    }

    /// The loop finished its work at `now` and waits for input: the
    /// odometry timer counts from here at the earliest.
    pub fn waiting(&mut self, now: u32) {
        if let Some(since) = self.odometry_since.as_mut() {
            // `now` is later than `since` (wrapping): only move forward.
            if now.wrapping_sub(*since) < u32::MAX / 2 {
                *since = now;
            }
        }
    }

    /// A frame was compared and judged: the verdict is its own, and a
    /// camera or frame fault is over. An odometry timeout cannot be: the
    /// frame needed a `$FLODO`, which ended it.
    pub fn judged(&mut self, obstacle: bool) {
        self.verdict = if obstacle { Verdict::Obstacle } else { Verdict::Clear };
        if matches!(self.fault, Some(SensorFault::CameraTimeout | SensorFault::FrameLost)) {
            self.fault = None;
        }
    }

    /// A frame ended without a verdict (it only (re)started the keyframe,
    /// it was not judged, or it was skipped): nothing is known about the path.
    pub fn unjudged(&mut self) {
        self.verdict = Verdict::Unknown;
    }

    /// A frame was lost to `fault`: nothing is known and the fault is active.
    pub fn frame_failed(&mut self, fault: SensorFault) {
        self.verdict = Verdict::Unknown;
        self.fault = Some(fault);
    }

    /// Checks the odometry timer at `now`; returns the fault when it is
    /// newly raised (to be reported once).
    pub fn poll(&mut self, now: u32) -> Option<SensorFault> {
        let since = self.odometry_since?;
        if self.fault == Some(SensorFault::OdometryTimeout) || now.wrapping_sub(since) <= ODOMETRY_TIMEOUT_US {
            return None;
        }
        self.verdict = Verdict::Unknown;
        self.fault = Some(SensorFault::OdometryTimeout);
        Some(SensorFault::OdometryTimeout)
    }
}

/// The rule's checks, listed in [`crate::selftest`].
#[cfg(any(test, feature = "selftest"))]
pub mod checks {
    use super::*;
    use crate::selftest::{ensure, Outcome as Check};

    pub fn alarm_is_asserted_until_a_frame_is_judged_clear() -> Check {
        let mut monitor = Monitor::new();
        ensure(monitor.alarm() && monitor.health() == Health::Starting, "alarm released at reset")?;
        monitor.odometry(0);
        monitor.unjudged(); // the first frame only takes the keyframe
        ensure(monitor.alarm(), "a keyframe released the alarm")?;
        monitor.judged(true);
        ensure(monitor.alarm() && monitor.health() == Health::Ok, "an obstacle did not assert the alarm")?;
        monitor.judged(false);
        ensure(!monitor.alarm() && monitor.health() == Health::Ok, "a clear frame did not release the alarm")?;
        monitor.unjudged();
        ensure(monitor.alarm(), "a keyframe restart kept a stale clear")
    }

    pub fn lost_frame_asserts_until_the_next_clear_frame() -> Check {
        let mut monitor = Monitor::new();
        monitor.judged(false);
        for fault in [SensorFault::FrameLost, SensorFault::CameraTimeout] {
            monitor.frame_failed(fault);
            ensure(monitor.alarm() && monitor.health() == Health::Fault(fault), "a lost frame kept a stale clear")?;
            monitor.unjudged(); // the next frame restarts the keyframe
            ensure(monitor.alarm(), "the keyframe after a lost frame released the alarm")?;
            monitor.judged(false);
            ensure(!monitor.alarm() && monitor.health() == Health::Ok, "a clear frame did not end the fault")?;
        }
        Ok(())
    }

    pub fn odometry_timeout_counts_only_while_waiting() -> Check {
        let mut monitor = Monitor::new();
        ensure(monitor.poll(10 * ODOMETRY_TIMEOUT_US).is_none(), "odometry that never started timed out")?;
        let start = u32::MAX - 100; // the clock wraps during the run
        monitor.odometry(start);
        monitor.judged(false);
        // A frame takes three timeouts' time; the loop then waits again.
        let done = start.wrapping_add(3 * ODOMETRY_TIMEOUT_US);
        monitor.waiting(done);
        ensure(monitor.poll(done.wrapping_add(ODOMETRY_TIMEOUT_US)).is_none(), "the frame's own time counted")?;
        ensure(!monitor.alarm(), "released alarm changed without a reason")?;
        let late = done.wrapping_add(ODOMETRY_TIMEOUT_US + 1);
        ensure(monitor.poll(late) == Some(SensorFault::OdometryTimeout), "stopped odometry was not seen")?;
        ensure(monitor.alarm(), "stopped odometry kept a stale clear")?;
        ensure(monitor.poll(late.wrapping_add(1)).is_none(), "a timeout was reported twice")?;
        monitor.odometry(late.wrapping_add(2));
        ensure(monitor.alarm() && monitor.health() == Health::Starting, "odometry alone released the alarm")?;
        monitor.judged(false);
        ensure(!monitor.alarm(), "a clear frame after the timeout did not release the alarm")
    }
}

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
//! [`FailSafe`] drives the alarm pin (an `embedded_hal` output) from the
//! monitor: the frame loop tells it what each frame came to and when it
//! waits, and the pin follows; host tests drive it with a mock pin.
//!
//! [`Health`] is what a status output reports (the line protocol's `$FLERR`
//! codes, a MAVLink `HEARTBEAT.system_status` and `STATUSTEXT`).

use core::fmt;

use embedded_hal::digital::OutputPin;

use crate::pipeline::Outcome;

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

/// The alarm pin (high = alarm) driven by a [`Monitor`]: asserted from
/// the start, released only right after a frame judged clear, asserted
/// again by anything else and at the end of input. The pin is written, and
/// the change logged (defmt builds), only when its level changes.
pub struct FailSafe<P> {
    pin: P,
    monitor: Monitor,
    asserted: bool,
    /// The last frame whose pose came (0 before any): what a timeout names.
    last_frame: u32,
}

/// A change of the alarm pin, for the log (read only by defmt builds).
#[derive(Clone, Copy)]
#[cfg_attr(not(feature = "defmt"), allow(dead_code))]
enum AlarmChange {
    Start,
    On { frame: u32, health: Health },
    Off { frame: u32 },
    End,
}

impl<P: OutputPin> FailSafe<P> {
    /// Asserts `pin` (the board should have already) with a monitor at reset.
    pub fn new(mut pin: P) -> Self {
        let _ = pin.set_high();
        log_change(AlarmChange::Start);
        FailSafe { pin, monitor: Monitor::new(), asserted: true, last_frame: 0 }
    }

    /// Whether the pin is asserted.
    pub fn alarm(&self) -> bool {
        self.asserted
    }

    pub fn health(&self) -> Health {
        self.monitor.health()
    }

    /// The last frame whose pose came (0 before any).
    pub fn last_frame(&self) -> u32 {
        self.last_frame
    }

    /// The pose that starts `frame` came at `now_us`.
    pub fn pose(&mut self, frame: u32, now_us: u32) {
        self.monitor.odometry(now_us);
        self.last_frame = frame;
    }

    /// `frame` ended: judged (its report's alarm), or without a verdict (it
    /// only (re)started the keyframe, or was not judged), or lost to `fault`.
    /// The pin first: it is what the robot acts on.
    pub fn frame_done(&mut self, frame: u32, result: Result<&Outcome, SensorFault>) {
        match result {
            Ok(Outcome::Compared(report)) => self.monitor.judged(report.alarm),
            Ok(Outcome::NotJudged(_) | Outcome::Keyframe { .. }) => self.monitor.unjudged(),
            Err(fault) => self.monitor.frame_failed(fault),
        }
        self.follow(frame);
    }

    /// `frame` was skipped before any of it was read (its pose was refused).
    pub fn frame_skipped(&mut self, frame: u32) {
        self.monitor.unjudged();
        self.follow(frame);
    }

    /// The loop finished its work at `now_us` and waits for input.
    pub fn waiting(&mut self, now_us: u32) {
        self.monitor.waiting(now_us);
    }

    /// While the loop waits: checks the odometry timer at `now_us`. Returns
    /// the fault when it is newly raised (to be reported once), the pin
    /// already asserted.
    pub fn poll(&mut self, now_us: u32) -> Option<SensorFault> {
        let fault = self.monitor.poll(now_us)?;
        self.follow(self.last_frame);
        Some(fault)
    }

    /// No more frames will be judged: asserted for good. The pin is handed
    /// back to be kept (dropping it could float it on a real board).
    pub fn end_of_input(mut self) -> P {
        if !self.asserted {
            self.asserted = true;
            let _ = self.pin.set_high();
            log_change(AlarmChange::End);
        }
        self.pin
    }

    /// The pin follows the monitor; `frame` is the frame that changed it.
    fn follow(&mut self, frame: u32) {
        let asserted = self.monitor.alarm();
        if asserted == self.asserted {
            return;
        }
        self.asserted = asserted;
        if asserted {
            let _ = self.pin.set_high();
            log_change(AlarmChange::On { frame, health: self.monitor.health() });
        } else {
            let _ = self.pin.set_low();
            log_change(AlarmChange::Off { frame });
        }
    }
}

/// The target's log of the pin (QEMU models no GPIO: the fail-safe tests
/// read these lines). Host builds log nothing; their tests read the pin.
#[cfg_attr(not(feature = "defmt"), allow(unused_variables))]
fn log_change(change: AlarmChange) {
    #[cfg(feature = "defmt")]
    match change {
        AlarmChange::Start => defmt::info!("alarm: on (start)"),
        AlarmChange::On { frame, health } => defmt::info!("alarm: on (frame {=u32}: {})", frame, health),
        AlarmChange::Off { frame } => defmt::info!("alarm: off (frame {=u32} clear)", frame),
        AlarmChange::End => defmt::info!("alarm: on (end of input)"),
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

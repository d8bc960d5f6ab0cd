//! The fail-safe (`health::FailSafe`) with a mock alarm pin: what the
//! firmware's frame loop tells it, and the level the pin is left at. The
//! QEMU test `firmware_failsafe` checks the same end to end.

use std::cell::RefCell;
use std::convert::Infallible;
use std::rc::Rc;

use flatland_core::health::{FailSafe, Health, SensorFault, ODOMETRY_TIMEOUT_US};
use flatland_core::pipeline::Outcome;
use flatland_core::report::{FrameReport, NotJudged};

/// An output pin that records every level written to it (true = high = alarm).
#[derive(Clone, Default)]
struct MockPin {
    writes: Rc<RefCell<Vec<bool>>>,
}

impl MockPin {
    fn level(&self) -> Option<bool> {
        self.writes.borrow().last().copied()
    }

    fn writes(&self) -> usize {
        self.writes.borrow().len()
    }
}

impl embedded_hal::digital::ErrorType for MockPin {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for MockPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.writes.borrow_mut().push(false);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.writes.borrow_mut().push(true);
        Ok(())
    }
}

fn compared(frame: u32, alarm: bool) -> Outcome {
    Outcome::Compared(FrameReport { frame, ref_frame: frame - 1, alarm, ..FrameReport::default() })
}

/// A fail-safe whose first two frames came: a keyframe, then a clear frame.
fn running() -> (FailSafe<MockPin>, MockPin) {
    let pin = MockPin::default();
    let mut fail_safe = FailSafe::new(pin.clone());
    fail_safe.pose(0, 0);
    fail_safe.frame_done(0, Ok(&Outcome::Keyframe { frame: 0 }));
    fail_safe.pose(1, 100_000);
    fail_safe.frame_done(1, Ok(&compared(1, false)));
    (fail_safe, pin)
}

#[test]
fn asserted_from_the_start_until_a_frame_is_judged_clear() {
    let pin = MockPin::default();
    let mut fail_safe = FailSafe::new(pin.clone());
    assert_eq!(pin.level(), Some(true), "asserted on start");
    assert_eq!(fail_safe.health(), Health::Starting);
    fail_safe.pose(0, 0);
    fail_safe.frame_done(0, Ok(&Outcome::Keyframe { frame: 0 }));
    assert_eq!(pin.level(), Some(true), "the keyframe knows nothing of the path");
    fail_safe.pose(1, 100_000);
    fail_safe.frame_done(1, Ok(&compared(1, true)));
    assert_eq!(pin.level(), Some(true), "an obstacle");
    fail_safe.pose(2, 200_000);
    fail_safe.frame_done(2, Ok(&compared(2, false)));
    assert_eq!(pin.level(), Some(false), "released by a clear frame");
    assert!(!fail_safe.alarm());
    assert_eq!(fail_safe.health(), Health::Ok);
    assert_eq!(pin.writes(), 2, "the pin is written only when its level changes");
}

#[test]
fn frames_without_a_verdict_assert_it() {
    let (mut fail_safe, pin) = running();
    fail_safe.frame_done(2, Ok(&Outcome::NotJudged(FrameReport::not_judged(2, 1, NotJudged::NoMotion))));
    assert_eq!(pin.level(), Some(true), "not judged");
    fail_safe.frame_done(3, Ok(&compared(3, false)));
    fail_safe.frame_skipped(4);
    assert_eq!(pin.level(), Some(true), "a frame whose pose was refused");
    fail_safe.frame_done(5, Ok(&Outcome::Keyframe { frame: 5 }));
    assert_eq!(pin.level(), Some(true), "a keyframe restart keeps no stale clear");
}

#[test]
fn a_lost_or_late_frame_asserts_it_until_the_next_clear_frame() {
    for fault in [SensorFault::FrameLost, SensorFault::CameraTimeout] {
        let (mut fail_safe, pin) = running();
        assert_eq!(pin.level(), Some(false));
        fail_safe.frame_done(2, Err(fault));
        assert_eq!(pin.level(), Some(true), "{fault:?}");
        assert_eq!(fail_safe.health(), Health::Fault(fault));
        fail_safe.frame_done(3, Ok(&Outcome::Keyframe { frame: 3 }));
        assert_eq!(pin.level(), Some(true), "the restart after {fault:?} released it");
        fail_safe.frame_done(4, Ok(&compared(4, false)));
        assert_eq!((pin.level(), fail_safe.health()), (Some(false), Health::Ok), "a clear frame ends {fault:?}");
    }
}

#[test]
fn stopped_odometry_asserts_it_once_while_waiting() {
    let (mut fail_safe, pin) = running();
    // The frame took longer than the timeout: its own time does not count.
    let done = 100_000 + 3 * ODOMETRY_TIMEOUT_US;
    fail_safe.waiting(done);
    assert_eq!(fail_safe.poll(done + ODOMETRY_TIMEOUT_US), None);
    assert_eq!(pin.level(), Some(false));
    let late = done + ODOMETRY_TIMEOUT_US + 1;
    assert_eq!(fail_safe.poll(late), Some(SensorFault::OdometryTimeout));
    assert_eq!(pin.level(), Some(true), "stale odometry");
    assert_eq!(fail_safe.last_frame(), 1, "the timeout names the last frame whose pose came");
    assert_eq!(fail_safe.poll(late + 1), None, "reported once");
    // Odometry resumes: the alarm stays until a frame is judged clear.
    fail_safe.pose(2, late + 2);
    assert_eq!(pin.level(), Some(true));
    fail_safe.frame_done(2, Ok(&compared(2, false)));
    assert_eq!(pin.level(), Some(false));
}

#[test]
fn odometry_that_never_started_has_not_stopped() {
    let pin = MockPin::default();
    let mut fail_safe = FailSafe::new(pin.clone());
    assert_eq!(fail_safe.poll(10 * ODOMETRY_TIMEOUT_US), None);
    assert_eq!((pin.level(), pin.writes()), (Some(true), 1));
}

#[test]
fn the_end_of_input_asserts_it_for_good() {
    let (fail_safe, pin) = running();
    assert_eq!(pin.level(), Some(false));
    let _kept = fail_safe.end_of_input();
    assert_eq!(pin.level(), Some(true));
}

//! Scoring detections against truth.toml: a confusion table with grace frames.

use crate::recording::{Hazard, Truth};
use flatland_core::report::FrameReport;

/// Counts of one recording's frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Confusion {
    pub true_alarm: u32,
    pub missed: u32,
    pub false_alarm: u32,
    pub true_clear: u32,
    /// Frames whose truth differs from a neighbour's: reported apart.
    pub grace_right: u32,
    pub grace_wrong: u32,
    /// Frames with truth but no report (skipped, or the first keyframe).
    pub unreported: u32,
    /// Frames with truth reported not judged (`status` not ok): no verdict
    /// to score (their alarm is the fail-safe's, not the detector's).
    pub not_judged: u32,
}

impl Confusion {
    pub fn errors(&self) -> u32 {
        self.missed + self.false_alarm
    }
}

/// A frame is a grace frame if its truth differs from the frame before or after.
pub fn is_grace(truth: &Truth, frame: u32) -> bool {
    let Some(this) = truth.pair(frame) else { return false };
    let differs = |other: Option<u32>| other.and_then(|f| truth.pair(f)).is_some_and(|p| p.alarm != this.alarm);
    differs(frame.checked_sub(1)) || differs(frame.checked_add(1))
}

/// What a report's alarm is about: a negative height is a drop's depth.
pub fn reported_hazard(report: &FrameReport) -> Option<Hazard> {
    report.alarm.then(|| if report.obstacle_h_mm.is_some_and(|h| h < 0) { Hazard::Drop } else { Hazard::Obstacle })
}

/// Scores reports (one per frame at most) against the truth. A report not
/// judged is counted apart ([`Confusion::not_judged`]) and has no row.
pub fn score(truth: &Truth, reports: &[FrameReport]) -> (Confusion, Vec<(u32, bool, bool)>) {
    score_hazard(truth, reports, None)
}

/// Scores one kind of hazard alone (None: both): a frame whose truth
/// alarm is of the other kind is left out, and an alarm of the other kind
/// on a clear frame counts as clear.
pub fn score_hazard(truth: &Truth, reports: &[FrameReport], kind: Option<Hazard>) -> (Confusion, Vec<(u32, bool, bool)>) {
    let mut confusion = Confusion::default();
    let mut rows = Vec::new();
    let of_kind = |hazard: Option<Hazard>| kind.is_none() || hazard.is_none() || hazard == kind;
    for pair in truth.pair.iter().filter(|pair| of_kind(pair.hazard())) {
        let Some(report) = reports.iter().find(|r| r.frame == pair.frame) else {
            confusion.unreported += 1;
            continue;
        };
        if !report.is_judged() {
            confusion.not_judged += 1;
            continue;
        }
        let alarm = report.alarm && (pair.alarm || of_kind(reported_hazard(report)));
        rows.push((pair.frame, pair.alarm, alarm));
        if is_grace(truth, pair.frame) {
            if alarm == pair.alarm {
                confusion.grace_right += 1;
            } else {
                confusion.grace_wrong += 1;
            }
            continue;
        }
        match (pair.alarm, alarm) {
            (true, true) => confusion.true_alarm += 1,
            (true, false) => confusion.missed += 1,
            (false, true) => confusion.false_alarm += 1,
            (false, false) => confusion.true_clear += 1,
        }
    }
    (confusion, rows)
}

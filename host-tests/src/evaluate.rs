//! Scoring detections against truth.toml: a confusion table with grace frames.

use crate::recording::Truth;
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

/// Scores reports (one per frame at most) against the truth.
pub fn score(truth: &Truth, reports: &[FrameReport]) -> (Confusion, Vec<(u32, bool, bool)>) {
    let mut confusion = Confusion::default();
    let mut rows = Vec::new();
    for pair in &truth.pair {
        let Some(report) = reports.iter().find(|r| r.frame == pair.frame) else {
            confusion.unreported += 1;
            continue;
        };
        rows.push((pair.frame, pair.alarm, report.alarm));
        if is_grace(truth, pair.frame) {
            if report.alarm == pair.alarm {
                confusion.grace_right += 1;
            } else {
                confusion.grace_wrong += 1;
            }
            continue;
        }
        match (pair.alarm, report.alarm) {
            (true, true) => confusion.true_alarm += 1,
            (true, false) => confusion.missed += 1,
            (false, true) => confusion.false_alarm += 1,
            (false, false) => confusion.true_clear += 1,
        }
    }
    (confusion, rows)
}

//! truth.toml reader, and the scoring that consumes it.
#![no_main]

use flatland_core::report::{FrameReport, NotJudged};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(truth) = flatland_host::recording::parse_truth(Path::new("truth.toml"), text) {
        for obstacle in &truth.obstacle {
            let _ = obstacle.centre_at(1.0);
        }
        // A report for every truth frame, so scoring visits each one; every
        // third not judged.
        let reports: Vec<FrameReport> = truth
            .pair
            .iter()
            .map(|p| match p.frame % 3 {
                0 => FrameReport::not_judged(p.frame, p.frame, NotJudged::AfterGap),
                _ => FrameReport { frame: p.frame, alarm: p.frame % 2 == 0, ..Default::default() },
            })
            .collect();
        let (confusion, _) = flatland_host::evaluate::score(&truth, &reports);
        let scored = confusion.true_alarm + confusion.missed + confusion.false_alarm + confusion.true_clear;
        let unscored = confusion.grace_right + confusion.grace_wrong + confusion.unreported + confusion.not_judged;
        assert_eq!(scored + unscored, truth.pair.len() as u32);
    }
});

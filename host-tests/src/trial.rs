//! One recording through `flatland detect` (the library call) under a
//! perturbation, scored against its truth: what the robustness tests share.

use crate::detect::{DetectConfig, Detector, FrameOutcome};
use crate::evaluate::{is_grace, score, Confusion};
use crate::perturb::Perturbation;
use crate::recording::Recording;
use flatland_core::report::FrameReport;
use std::path::Path;

/// What detection made of a perturbed recording.
pub struct Trial {
    /// The recording as perturbed: its poses and truth are what was run and scored.
    pub recording: Recording,
    pub reports: Vec<FrameReport>,
    pub confusion: Confusion,
    /// The frames outside grace frames whose alarm is wrong.
    pub wrong: Vec<u32>,
}

/// Runs the recording in `dir` under `perturbation` with the default
/// configuration, and scores it against its truth.toml.
pub fn run_trial(dir: &Path, perturbation: &Perturbation) -> Result<Trial, String> {
    let mut recording = Recording::open(dir).map_err(|e| e.to_string())?;
    let mut perturber = perturbation.apply(&mut recording);
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default())?;
    let mut reports = Vec::new();
    detector.run_with(&recording, |index, frame| perturber.alter(index, frame), |outcome, _| {
        if let FrameOutcome::Report { report, .. } = outcome {
            reports.push(report);
        }
    })?;
    let truth = recording.truth.as_ref().ok_or_else(|| format!("{}: no truth.toml", dir.display()))?;
    let (confusion, rows) = score(truth, &reports);
    let wrong = rows.iter().filter(|(frame, want, got)| want != got && !is_grace(truth, *frame)).map(|(frame, ..)| *frame).collect();
    Ok(Trial { recording, reports, confusion, wrong })
}

//! GPA detection on the bundled recordings and on perturbed copies of them.
//! One default configuration throughout; nothing is tuned per recording.

use flatland_core::report::FrameReport;
use flatland_host::detect::{DetectConfig, FrameOutcome, Pipeline};
use flatland_host::evaluate::{score, Confusion};
use flatland_host::perturb::Perturbation;
use flatland_host::recording::Recording;
use std::path::Path;

const RECORDINGS: [&str; 8] =
    ["flat_marks", "stool_bags", "approach_box", "diagonal", "turn", "qvga_curb", "noisy_marks", "noisy_approach"];

fn detect(name: &str, perturbation: Option<Perturbation>) -> (Confusion, Vec<FrameReport>) {
    let mut recording = Recording::open(Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(name)).unwrap();
    if let Some(p) = perturbation {
        p.poses(&mut recording);
    }
    let config = DetectConfig::default();
    let mut pipeline = Pipeline::new(&recording, &config).unwrap();
    let mut reports = Vec::new();
    pipeline
        .run_with(
            &recording,
            &config,
            |index, frame| {
                if let Some(p) = perturbation {
                    p.frame(index, frame)
                }
            },
            |outcome, _| {
                if let FrameOutcome::Report { report, .. } = outcome {
                    reports.push(report);
                }
            },
        )
        .unwrap();
    let truth = recording.truth.as_ref().unwrap();
    (score(truth, &reports).0, reports)
}

#[test]
fn every_bundled_recording_has_no_errors_outside_grace_frames() {
    for name in RECORDINGS {
        let (confusion, reports) = detect(name, None);
        println!("{name}: {confusion:?}");
        assert_eq!(confusion.errors(), 0, "{name}: {confusion:?}");
        // Every frame after the first gets a report (no keyframe restarts here).
        assert_eq!(reports.len() + 1, confusion.true_alarm as usize + confusion.missed as usize + confusion.false_alarm as usize + confusion.true_clear as usize + confusion.grace_right as usize + confusion.grace_wrong as usize + 1);
    }
}

#[test]
fn perturbed_recordings_sweep() {
    let cases = [
        ("noise 3, flicker 2%", Perturbation { seed: 1, noise_sigma: 3.0, gain_flicker: 0.02, ..Default::default() }),
        ("odometry 3% per step", Perturbation { seed: 2, odometry_scale_sigma: 0.03, yaw_sigma_deg: 0.1, ..Default::default() }),
        ("odometry +4% bias", Perturbation { seed: 3, odometry_scale_bias: 0.04, ..Default::default() }),
        ("all at once", Perturbation { seed: 4, noise_sigma: 2.5, gain_flicker: 0.015, odometry_scale_sigma: 0.025, yaw_sigma_deg: 0.05, ..Default::default() }),
    ];
    for (label, perturbation) in cases {
        for name in RECORDINGS {
            let (confusion, _) = detect(name, Some(perturbation));
            println!("{label:>22} {name:>15}: errors {} {confusion:?}", confusion.errors());
        }
    }
}

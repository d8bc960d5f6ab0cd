//! GPA detection on the bundled recordings and on perturbed copies of them.
//! One default configuration throughout; nothing is tuned per recording.

use flatland_core::report::FrameReport;
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::evaluate::{score, Confusion};
use flatland_host::perturb::Perturbation;
use flatland_host::recording::Recording;
mod common;
use common::{bundled, data};


/// The recordings rendered level, without noise or exposure effects of
/// their own: the perturbation sweeps below add theirs to these. (The
/// ledge is not among them: under sigma-3 noise and 2 % flicker it misses
/// two frames, beyond the bounds below.)
const RECORDINGS: [&str; 8] =
    ["flat_marks", "stool_bags", "approach_box", "diagonal", "turn", "qvga_curb", "noisy_marks", "noisy_approach"];

/// A bundled recording.
fn open(name: &str) -> Recording {
    Recording::open(data(name)).unwrap()
}

fn detect(name: &str, perturbation: Option<Perturbation>) -> (Confusion, Vec<FrameReport>) {
    let recording = open(name);
    detect_recording(recording, perturbation)
}

fn detect_recording(mut recording: Recording, perturbation: Option<Perturbation>) -> (Confusion, Vec<FrameReport>) {
    if let Some(p) = perturbation {
        p.poses(&mut recording);
    }
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
    let mut reports = Vec::new();
    detector
        .run_with(
            &recording,
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
    for name in bundled() {
        let (confusion, reports) = detect(&name, None);
        println!("{name}: {confusion:?}");
        assert_eq!(confusion.errors(), 0, "{name}: {confusion:?}");
        // Every frame after the first gets a report (no keyframe restarts here).
        assert_eq!(reports.len() + 1, confusion.true_alarm as usize + confusion.missed as usize + confusion.false_alarm as usize + confusion.true_clear as usize + confusion.grace_right as usize + confusion.grace_wrong as usize + 1);
    }
}

/// `--odometry none`: the motion from the images alone.
fn without_odometry(name: &str) {
    let mut recording = open(name);
    recording.ignore_odometry();
    let frames = recording.frames.len();
    let (confusion, reports) = detect_recording(recording, None);
    println!("{name} without odometry: {confusion:?}, {} reports", reports.len());
    assert_eq!(confusion.errors(), 0, "{name} without odometry: {confusion:?}");
    // A frame without a report, or one not judged (the estimate failed), is no answer either.
    assert_eq!(reports.len() + 1, frames, "{name}: every frame after the first gets a report");
    let not_judged: Vec<_> = reports.iter().filter(|report| !report.is_judged()).map(|report| (report.frame, report.status)).collect();
    assert!(not_judged.is_empty(), "{name}: frames not judged: {not_judged:?}");
    assert!(reports.iter().all(|report| report.odometry_fault.is_none()), "{name}: no odometry, no odometry fault");
}

/// One test per recording without odometry, so that each can be marked on its own.
macro_rules! without_odometry {
    ($($(#[$attribute:meta])* $recording:ident),* $(,)?) => {
        mod without_odometry {
            $(#[test] $(#[$attribute])* fn $recording() { super::without_odometry(stringify!($recording)) })*
        }
        const WITHOUT_ODOMETRY: &[&str] = &[$(stringify!($recording)),*];
    };
}

without_odometry! {
    flat_marks,
    stool_bags,
    approach_box,
    diagonal,
    turn,
    qvga_curb,
    noisy_marks,
    noisy_approach,
    bumpy_marks,
    bumpy_approach,
    exposure_rolling,
    slip,
    ledge,
}

#[test]
fn every_recording_is_tried_without_odometry() {
    let mut listed = WITHOUT_ODOMETRY.to_vec();
    listed.sort();
    assert_eq!(listed, bundled());
}

/// Errors outside grace frames per recording under one perturbation.
fn sweep(label: &str, perturbation: Perturbation) -> Vec<u32> {
    RECORDINGS
        .iter()
        .map(|name| {
            let (confusion, _) = detect(name, Some(perturbation));
            println!("{label:>28} {name:>15}: errors {} {confusion:?}", confusion.errors());
            confusion.errors()
        })
        .collect()
}

// The bounds below are what the detector achieves today (docs/RESULTS.md, "Detection
// under perturbation"); they guard against regressions. The misses left are
// first frames of an obstacle at the detection limit: the 40 mm curb under
// odometry noise and a bag entering from the side of a turn.

#[test]
fn added_sensor_noise_and_gain_flicker() {
    let errors = sweep("noise 3, flicker 2%", Perturbation { seed: 1, noise_sigma: 3.0, gain_flicker: 0.02, ..Default::default() });
    assert!(errors.iter().all(|&e| e <= 1), "{errors:?}");
    assert!(errors.iter().sum::<u32>() <= 2, "{errors:?}");
}

#[test]
fn per_step_odometry_error() {
    let p = Perturbation { seed: 2, odometry_scale_sigma: 0.03, yaw_sigma_deg: 0.1, ..Default::default() };
    let errors = sweep("odometry 3% + 0.1 deg/step", p);
    assert!(errors.iter().all(|&e| e <= 1), "{errors:?}");
    assert!(errors.iter().sum::<u32>() <= 3, "{errors:?}");
}

#[test]
fn constant_odometry_scale_error() {
    for bias in [0.04, -0.04] {
        let errors = sweep(&format!("odometry scale {bias:+}"), Perturbation { seed: 3, odometry_scale_bias: bias, ..Default::default() });
        assert!(errors.iter().sum::<u32>() <= 4, "{bias}: {errors:?}");
    }
}

#[test]
fn clean_recordings_made_noisy() {
    // What noisy_marks/noisy_approach carry, on the other recordings too.
    let p = Perturbation { seed: 5, noise_sigma: 2.0, gain_flicker: 0.012, odometry_scale_sigma: 0.025, yaw_sigma_deg: 0.05, ..Default::default() };
    let errors = sweep("sigma 2, 1.2%, 2.5%, 0.05 deg", p);
    assert!(errors.iter().sum::<u32>() <= 4, "{errors:?}");
}

/// Issue 14: ledge, a 150 mm step down across the path. Every pair is
/// right outside grace frames, the first alarm is the first alarm pair
/// outside grace frames (the edge has just entered the AOI), every alarm
/// is a drop (negative height), and nearest_mm is the edge within 5 %.
#[test]
fn ledge_is_a_drop_at_its_edge() {
    let recording = Recording::open(data("ledge")).unwrap();
    let truth = recording.truth.as_ref().unwrap();
    let (confusion, reports) = detect("ledge", None);
    println!("ledge: {confusion:?}");
    assert_eq!(confusion.errors(), 0, "{confusion:?}");
    let first_alarm = reports.iter().find(|r| r.alarm).map(|r| r.frame);
    let first_truth = truth.pair.iter().find(|p| p.alarm && !flatland_host::evaluate::is_grace(truth, p.frame)).map(|p| p.frame);
    assert_eq!(first_alarm, first_truth);
    for report in reports.iter().filter(|r| r.alarm) {
        let want = truth.pair(report.frame).and_then(|p| p.nearest_mm).unwrap();
        let got = f64::from(report.nearest_mm.unwrap());
        println!("ledge frame {}: nearest {got} mm (truth {want}), depth {:?}", report.frame, report.obstacle_h_mm);
        assert!((got - want).abs() <= 0.05 * want, "frame {}: {got} vs {want}", report.frame);
        assert!(report.obstacle_h_mm.is_some_and(|h| h <= -20), "frame {}: {:?}", report.frame, report.obstacle_h_mm);
    }
}

/// Where the obstacle is: nearest_mm against truth on alarm frames.
#[test]
fn obstacle_distance_follows_truth() {
    for name in ["stool_bags", "approach_box", "qvga_curb", "noisy_approach"] {
        let recording = open(name);
        let truth = recording.truth.as_ref().unwrap();
        let (_, reports) = detect(name, None);
        let mut errors: Vec<f64> = reports
            .iter()
            .filter_map(|r| {
                let want = truth.pair(r.frame)?.nearest_mm?;
                Some((f64::from(r.nearest_mm?) - want).abs())
            })
            .collect();
        errors.sort_by(f64::total_cmp);
        let median = errors[errors.len() / 2];
        println!("{name}: nearest_mm error median {median:.0} mm, max {:.0} mm over {} frames", errors[errors.len() - 1], errors.len());
        assert!(median <= 100.0, "{name}: median error {median}");
    }
}

/// GPA + GTI (issue 4): once GTI has tracked the obstacle's top, the height
/// in the alarm reports is GTI's, within the GTI accuracy bounds (GPA's own
/// parallax height is coarse: 74-200 mm on approach_box's 120 mm box).
#[test]
fn alarm_reports_carry_gti_heights() {
    for (name, truth_mm, tolerance_mm) in [("approach_box", 120, 6), ("noisy_approach", 120, 6), ("qvga_curb", 40, 5)] {
        let (_, reports) = detect(name, None);
        let last: Vec<Option<i32>> = reports.iter().rev().take(5).map(|r| r.alarm.then_some(r.obstacle_h_mm).flatten()).collect();
        println!("{name}: last five obstacle_h_mm {last:?}");
        // The last within the bound; the four before within 8 %
        // (the box's reading wanders by a few % from frame to frame).
        assert!(last[0].is_some_and(|h| (h - truth_mm).abs() <= tolerance_mm), "{name}: {last:?} vs {truth_mm}");
        let loose = tolerance_mm.max(truth_mm * 8 / 100);
        assert!(last.iter().all(|h| h.is_some_and(|h| (h - truth_mm).abs() <= loose)), "{name}: {last:?} vs {truth_mm}");
    }
    for name in ["flat_marks", "noisy_marks"] {
        let (_, reports) = detect(name, None);
        assert!(reports.iter().all(|r| !r.alarm && r.obstacle_h_mm.is_none()), "{name}");
    }
}

/// GTI's own alarm: with the wheels 4 % off, GPA alone misses 4 of
/// qvga_curb's alarm pairs (the 40 mm curb's parallax falls under its blob
/// thresholds); GTI, whose travel the floor corrects, confirms the curb.
#[test]
fn gti_alarm_covers_gpa_under_odometry_bias() {
    let (confusion, _) = detect("qvga_curb", Some(Perturbation { seed: 3, odometry_scale_bias: 0.04, ..Default::default() }));
    println!("{confusion:?}");
    assert!(confusion.errors() <= 1 && confusion.false_alarm == 0, "{confusion:?}");
}

/// Something moving on its own (a striped ball rolling across the path,
/// painted into flat_marks' frames) is no ground: it must raise the alarm,
/// and the reported extent must follow it across.
#[test]
fn moving_object_raises_the_alarm() {
    let recording = open("flat_marks");
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
    let mut reports = Vec::new();
    let paint_ball = |index: u32, frame: &mut flatland_host::recording::Frame| {
        let (cx, cy, r) = (60 + 22 * index as i64, 170i64, 14i64);
        for y in cy - r..=cy + r {
            for x in cx - r..=cx + r {
                if (x - cx).pow(2) + (y - cy).pow(2) <= r * r && x >= 0 && (x as usize) < frame.width {
                    // Stripes that turn as it rolls.
                    let stripe = (x - cx + 3 * index as i64).rem_euclid(8) < 4;
                    frame.pixels[y as usize * frame.width + x as usize] = if stripe { 200 } else { 60 };
                }
            }
        }
    };
    detector
        .run_with(&recording, paint_ball, |outcome, _| {
            if let FrameOutcome::Report { report, .. } = outcome {
                reports.push(report);
            }
        })
        .unwrap();
    assert!(reports.iter().all(|r| r.alarm), "{reports:?}");
    let centres: Vec<i32> = reports.iter().map(|r| (r.left_mm.unwrap() + r.right_mm.unwrap()) / 2).collect();
    println!("ball centre x per frame: {centres:?}");
    assert!(centres.windows(2).all(|w| w[1] > w[0]), "the extent follows the ball: {centres:?}");
}

/// Issue 13's attitude accuracy: on bumpy_marks with the IMU ignored
/// (`--imu none`), the estimated dpitch and droll track the IMU's own change
/// between the two frames within 0.15 deg RMS (its bias cancels in the
/// difference; its noise, sigma 0.05 deg per reading, does not).
#[test]
fn attitude_from_the_images_tracks_the_imu_on_bumpy_marks() {
    let original = open("bumpy_marks");
    let mut recording = original.clone();
    recording.ignore_imu();
    let (_, reports) = detect_recording(recording, None);
    let imu = |frame: u32| original.pose(frame).and_then(|row| row.attitude).expect("bumpy_marks has IMU columns");
    let scale = f64::from(flatland_core::report::ANGLE_SCALE);
    let (mut pitch, mut roll) = (0.0, 0.0);
    for report in &reports {
        let change = imu(report.frame).since(&imu(report.ref_frame));
        pitch += (f64::from(report.dpitch) / scale - change.pitch_deg).powi(2);
        roll += (f64::from(report.droll) / scale - change.roll_deg).powi(2);
    }
    let n = reports.len() as f64;
    let (pitch, roll) = ((pitch / n).sqrt(), (roll / n).sqrt());
    println!("bumpy_marks --imu none: dpitch RMS {pitch:.3} deg, droll RMS {roll:.3} deg over {n} pairs");
    assert!(reports.len() >= 14, "{} reports", reports.len());
    assert!(pitch <= 0.15 && roll <= 0.15, "RMS pitch {pitch:.3} roll {roll:.3} deg");
}

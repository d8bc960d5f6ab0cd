//! `flatland calibrate`: perturbed mounts come back, crooked mounts are
//! found, a recording without motion is refused.

mod common;

use common::{data, TempRecording};
use flatland_core::geometry::{Mount, Pixel, Rig};
use flatland_core::motion::Attitude;
use flatland_host::calibration::{
    calibrate, calibrated_rig_toml, parse_camera_info, Body, CalibrationConfig, CalibrationError, MountEstimate,
};
use flatland_host::detect::{DetectConfig, Detector};
use flatland_host::recording::{parse_poses, parse_rig, rig_with_aoi_in_view, Recording};
use std::path::Path;
use std::process::Command;

/// The bounds: tilt, height, roll, yaw.
const BOUNDS: [f64; 4] = [0.1, 5.0, 0.2, 0.3];

/// Bundled recordings with odometry over flat ground (some with a few
/// obstacles or a drop, which the robust weights must reject). The bumpy
/// ones have their own test. exposure_rolling has a rolling shutter (its
/// rig.toml's `readout_ms`), auto-exposure steps and motion blur.
/// qvga_low is the board's camera mounted low with a small AOI, which used
/// to leave the image on the way from a moderately wrong start; busy_floor
/// has many strong markings and hard shadows (its roll was 0.39 deg off when
/// the odometry's turns were trusted).
const FLAT: [&str; 13] = [
    "flat_marks",
    "noisy_marks",
    "diagonal",
    "turn",
    "qvga_curb",
    "qvga_low",
    "busy_floor",
    "approach_box",
    "noisy_approach",
    "stool_bags",
    "slip",
    "ledge",
    "exposure_rolling",
];

/// Recordings whose body rocks between frames (RECORDING.md's body attitude),
/// with the renderer's true attitudes in true_poses.csv.
const ROCKING: [&str; 2] = ["bumpy_marks", "bumpy_approach"];

/// The starting mounts: corners of the box (tilt +-2 deg, height
/// +-30 mm, roll +-2 deg, yaw +-2 deg). Four of its sixteen: tilt and height,
/// tilt and roll, roll and yaw each come with equal and with opposite signs
/// (tilt and yaw, height and roll only equal); `every_corner_on_every_recording`
/// runs all sixteen.
const STARTS: [[f64; 4]; 4] = [[2.0, 30.0, 2.0, 2.0], [-2.0, -30.0, -2.0, -2.0], [2.0, -30.0, -2.0, 2.0], [-2.0, 30.0, 2.0, -2.0]];

/// All sixteen corners of the box.
fn corners() -> Vec<[f64; 4]> {
    (0..16).map(|n| std::array::from_fn(|k| [2.0, 30.0, 2.0, 2.0][k] * if n >> k & 1 == 0 { 1.0 } else { -1.0 })).collect()
}

/// The rig with another mount, its AOI limited to the view as `flatland
/// calibrate` reads a rig.toml whose mount puts part of it out of view.
fn with_mount(rig: &Rig, mount: Mount) -> Rig {
    rig_with_aoi_in_view(*rig.camera(), mount, *rig.aoi()).expect("the image sees the ground")
}

fn offset(mount: &Mount, d: [f64; 4]) -> Mount {
    Mount {
        tilt_deg: mount.tilt_deg + d[0],
        height_mm: mount.height_mm + d[1],
        roll_deg: mount.roll_deg + d[2],
        yaw_deg: mount.yaw_deg + d[3],
    }
}

fn errors(estimate: &MountEstimate, truth: &Mount) -> [f64; 4] {
    let m = &estimate.mount;
    [m.tilt_deg - truth.tilt_deg, m.height_mm - truth.height_mm, m.roll_deg - truth.roll_deg, m.yaw_deg - truth.yaw_deg]
}

fn within(errors: &[f64; 4], check_height: bool) -> bool {
    errors.iter().zip(BOUNDS).enumerate().all(|(k, (e, b))| (k == 1 && !check_height) || e.abs() <= b)
}

/// The mount as the level ground sees it when the body holds `attitude`
/// (RECORDING.md: R = Rz(roll) Rx(pitch) turns the body, optical centre
/// included, about the robot origin on the ground): what calibration
/// measures when `attitude` is the body's mean over the drive.
fn mount_on_body(rig: &Rig, attitude: Attitude) -> Mount {
    let (sin_p, cos_p) = attitude.pitch_deg.to_radians().sin_cos();
    let (sin_r, cos_r) = attitude.roll_deg.to_radians().sin_cos();
    let pitch = [[1.0, 0.0, 0.0], [0.0, cos_p, -sin_p], [0.0, sin_p, cos_p]];
    let roll = [[cos_r, sin_r, 0.0], [-sin_r, cos_r, 0.0], [0.0, 0.0, 1.0]];
    let product = |a: &[[f64; 3]; 3], b: &[[f64; 3]; 3], transpose_b: bool| -> [[f64; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * if transpose_b { b[j][k] } else { b[k][j] }).sum()))
    };
    let body = product(&roll, &pitch, false);
    // Level robot frame -> camera: the mount's rotation after the body's undone.
    let c = product(&rig.camera_rotation(), &body, true);
    // rig.camera_rotation() is roll(r) tilt(t) yaw(y): its last row is
    // (-cos t sin y, -sin t, cos t cos y), its middle column (-sin r cos t, cos r cos t, -sin t).
    Mount {
        tilt_deg: (-c[2][1]).asin().to_degrees(),
        yaw_deg: (-c[2][0]).atan2(c[2][2]).to_degrees(),
        roll_deg: (-c[0][1]).atan2(c[1][1]).to_degrees(),
        height_mm: rig.mount().height_mm * body[1][1],
    }
}

/// The body's mean attitude over the drive, from the renderer's true poses.
fn mean_true_attitude(dir: &Path) -> Attitude {
    let path = dir.join("true_poses.csv");
    let rows = parse_poses(&path, &std::fs::read_to_string(&path).unwrap()).unwrap();
    let attitudes: Vec<Attitude> = rows.iter().map(|row| row.attitude.expect("true_poses.csv has the attitude")).collect();
    let n = attitudes.len() as f64;
    Attitude {
        pitch_deg: attitudes.iter().map(|a| a.pitch_deg).sum::<f64>() / n,
        roll_deg: attitudes.iter().map(|a| a.roll_deg).sum::<f64>() / n,
    }
}

/// What calibration should find on a recording: rig.toml's mount, on a
/// rocking body the mount on the body's mean attitude.
fn true_mount(recording: &Recording) -> Mount {
    if recording.dir.join("true_poses.csv").exists() {
        mount_on_body(&recording.rig, mean_true_attitude(&recording.dir))
    } else {
        *recording.rig.mount()
    }
}

/// Calibrates `recording` from each start offset from rig.toml's mount,
/// in parallel; the failures as text.
fn check(name: &str, recording: &Recording, starts: &[[f64; 4]], truth: &Mount, config: &CalibrationConfig) -> Vec<String> {
    let given = *recording.rig.mount();
    let outcomes: Vec<_> = std::thread::scope(|scope| {
        let runs: Vec<_> = starts
            .iter()
            .map(|&d| {
                scope.spawn(move || {
                    let mut perturbed = recording.clone();
                    perturbed.rig = with_mount(&recording.rig, offset(&given, d));
                    (d, calibrate(&perturbed, config))
                })
            })
            .collect();
        runs.into_iter().map(|run| run.join().unwrap()).collect()
    });
    let mut failures = Vec::new();
    for (d, outcome) in outcomes {
        match outcome {
            Ok(estimate) => {
                let e = errors(&estimate, truth);
                println!(
                    "{name} from {d:?}: errors tilt {:+.3} deg, height {:+.2} mm, roll {:+.3} deg, yaw {:+.3} deg; sigma {:.3?}; residual {:.2} -> {:.2}; {} pairs; {:?}",
                    e[0], e[1], e[2], e[3], estimate.sigma, estimate.residual_before, estimate.residual_after, estimate.pairs, estimate.body
                );
                if !within(&e, !config.ignore_odometry) {
                    failures.push(format!("{name} from {d:?}: errors {e:.3?}"));
                }
            }
            Err(e) => failures.push(format!("{name} from {d:?}: {e}")),
        }
    }
    failures
}

#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn perturbed_mounts_come_back_on_the_flat_recordings() {
    let mut failures = Vec::new();
    for name in FLAT {
        let recording = Recording::open(data(name)).unwrap();
        let truth = true_mount(&recording);
        failures.extend(check(name, &recording, &STARTS, &truth, &CalibrationConfig::default()));
    }
    assert!(failures.is_empty(), "outside the bounds {BOUNDS:?}:\n{}", failures.join("\n"));
}

/// The rocking body's frames are told apart from the mount, and the body
/// model says so.
#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn a_rocking_body_is_found_and_its_mean_taken_as_level() {
    for name in ROCKING {
        let mut recording = Recording::open(data(name)).unwrap();
        let truth = *recording.rig.mount();
        recording.rig = with_mount(&recording.rig, offset(&truth, STARTS[0]));
        let estimate = calibrate(&recording, &CalibrationConfig::default()).unwrap();
        assert_eq!(estimate.body, Body::Rocking, "{name}");
        assert!(estimate.body_attitude_rms_deg > 0.1, "{name}: {}", estimate.body_attitude_rms_deg);
    }
    for name in ["flat_marks", "ledge"] {
        let recording = Recording::open(data(name)).unwrap();
        assert_eq!(calibrate(&recording, &CalibrationConfig::default()).unwrap().body, Body::Rigid, "{name}");
    }
}

/// The bounds on the rocking recordings, against the mount on the
/// body's mean attitude over the drive (the renderer's true attitudes): a
/// constant body attitude cannot be told from the mount, so calibration
/// measures the mount relative to the body's mean.
#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn perturbed_mounts_come_back_on_the_rocking_recordings() {
    let mut failures = Vec::new();
    for name in ROCKING {
        let recording = Recording::open(data(name)).unwrap();
        let truth = true_mount(&recording);
        println!("{name}: mount on the mean body attitude {truth:?}");
        failures.extend(check(name, &recording, &STARTS, &truth, &CalibrationConfig::default()));
    }
    assert!(failures.is_empty(), "outside the bounds {BOUNDS:?}:\n{}", failures.join("\n"));
}

/// All sixteen corners of the box on every bundled recording and on
/// the directories in FLATLAND_CALIBRATE_DATA (comma-separated, e.g. the
/// shared recordings; a `real_` one has no true mount and only has to come
/// back without a panic). Ignored: roughly 15 minutes on 2 free cores
/// (estimated from single runs, not timed). Run with
/// `cargo test --release -p flatland-host --test calibrate -- --ignored --nocapture`.
#[test]
#[ignore = "sweep: 16 starts per recording, roughly 15 minutes"]
fn every_corner_on_every_recording() {
    let extra = std::env::var("FLATLAND_CALIBRATE_DATA").unwrap_or_default();
    // Every folder of data/ with a rig (qvga_low has no truth.toml), then the extra ones.
    let mut dirs: Vec<std::path::PathBuf> =
        std::fs::read_dir(data("")).unwrap().map(|entry| entry.unwrap().path()).filter(|dir| dir.join("rig.toml").exists()).collect();
    dirs.sort();
    dirs.extend(extra.split(',').filter(|d| !d.is_empty()).map(std::path::PathBuf::from));
    let mut failures = Vec::new();
    for dir in dirs {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let recording = Recording::open(&dir).unwrap();
        if name.starts_with("real_") {
            let outcome = calibrate(&recording, &CalibrationConfig::default());
            println!("{name}: {:?}", outcome.as_ref().map(|e| e.mount));
            continue;
        }
        let truth = true_mount(&recording);
        failures.extend(check(&name, &recording, &corners(), &truth, &CalibrationConfig::default()));
    }
    assert!(failures.is_empty(), "outside the bounds {BOUNDS:?}:\n{}", failures.join("\n"));
}

#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn without_odometry_a_known_height_gives_the_angles() {
    let mut failures = Vec::new();
    for name in ["flat_marks", "noisy_marks"] {
        let recording = Recording::open(data(name)).unwrap();
        let truth = *recording.rig.mount();
        let config = CalibrationConfig { height_mm: Some(truth.height_mm), ignore_odometry: true };
        failures.extend(check(name, &recording, &STARTS[..2], &truth, &config));
    }
    assert!(failures.is_empty(), "outside the bounds {BOUNDS:?}:\n{}", failures.join("\n"));
}

/// A copy of a bundled recording as a camera with mount roll and yaw sees
/// it: a pure rotation about the optical centre, so every frame is the
/// original warped by K R K^-1 (exact at any depth). The border the level
/// camera did not see repeats its edge.
fn crooked_copy(name: &str, roll_deg: f64, yaw_deg: f64) -> (TempRecording, Mount) {
    let copy = TempRecording::copy_of(name, "crooked");
    let recording = Recording::open(&copy.dir).unwrap();
    let level = recording.rig;
    let truth = Mount { roll_deg, yaw_deg, ..*level.mount() };
    let crooked = with_mount(&level, truth);
    let (a, b) = (level.camera_rotation(), crooked.camera_rotation());
    // Crooked camera axes -> level camera axes: A B^T (both Y up).
    let m: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[j][k]).sum()));
    let camera = level.camera();
    for &index in &recording.frames {
        let frame = recording.load_frame(index).unwrap();
        let mut pixels = vec![0u8; frame.pixels.len()];
        for v in 0..frame.height {
            for u in 0..frame.width {
                let (x, y) = crooked.pixel_to_normalised(Pixel { u: u as f64, v: v as f64 }).unwrap();
                let ray = [x, -y, 1.0];
                let level_ray: [f64; 3] = std::array::from_fn(|i| (0..3).map(|k| m[i][k] * ray[k]).sum());
                let source = level.normalised_to_pixel(level_ray[0] / level_ray[2], -level_ray[1] / level_ray[2]).unwrap();
                let (su, sv) = (source.u.clamp(0.0, camera.width as f64 - 1.0), source.v.clamp(0.0, camera.height as f64 - 1.0));
                let (u0, v0) = ((su.floor() as usize).min(frame.width - 2), (sv.floor() as usize).min(frame.height - 2));
                let (fu, fv) = (su - u0 as f64, sv - v0 as f64);
                let at = |c: usize, r: usize| f64::from(frame.pixels[r * frame.width + c]);
                let top = at(u0, v0) * (1.0 - fu) + at(u0 + 1, v0) * fu;
                let bottom = at(u0, v0 + 1) * (1.0 - fu) + at(u0 + 1, v0 + 1) * fu;
                pixels[v * frame.width + u] = (top * (1.0 - fv) + bottom * fv).round() as u8;
            }
        }
        let mut pgm = format!("P5\n{} {}\n255\n", frame.width, frame.height).into_bytes();
        pgm.extend_from_slice(&pixels);
        std::fs::write(copy.frame(index), pgm).unwrap();
    }
    let rig_path = copy.dir.join("rig.toml");
    let text = std::fs::read_to_string(&rig_path).unwrap();
    std::fs::write(&rig_path, calibrated_rig_toml(&text, &truth)).unwrap();
    (copy, truth)
}

#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn a_crooked_mount_is_found() {
    let mut failures = Vec::new();
    for (name, roll, yaw) in [("flat_marks", 1.5, -2.0), ("noisy_marks", -2.0, 2.5)] {
        let (copy, truth) = crooked_copy(name, roll, yaw);
        let recording = Recording::open(&copy.dir).unwrap();
        assert_eq!(*recording.rig.mount(), truth, "rig.toml carries the crooked mount");
        failures.extend(check(&format!("{name} rolled {roll} yawed {yaw}"), &recording, &STARTS[..2], &truth, &CalibrationConfig::default()));
        // From a level rig, as a user who does not know the mount is crooked starts.
        let mut level = recording.clone();
        level.rig = with_mount(&recording.rig, Mount { roll_deg: 0.0, yaw_deg: 0.0, ..offset(&truth, [1.0, -20.0, 0.0, 0.0]) });
        let estimate = calibrate(&level, &CalibrationConfig::default()).unwrap();
        let e = errors(&estimate, &truth);
        println!("{name} rolled {roll} yawed {yaw}, from a level rig: errors {e:.3?}");
        if !within(&e, true) {
            failures.push(format!("{name} from a level rig: errors {e:.3?}"));
        }
    }
    assert!(failures.is_empty(), "outside the bounds {BOUNDS:?}:\n{}", failures.join("\n"));
}

/// A recording whose robot stands: frame 0 over and over, poses unchanged.
fn standing_copy(dir: &Path) {
    let poses: String = (0..6).map(|n| format!("{n},{:.3},0.0,0.0,0.0\n", f64::from(n) * 0.1)).collect();
    std::fs::write(dir.join("poses.csv"), format!("frame,t_s,x_mm,z_mm,yaw_deg\n{poses}")).unwrap();
    let first = std::fs::read(dir.join("frames/000000.pgm")).unwrap();
    for entry in std::fs::read_dir(dir.join("frames")).unwrap() {
        std::fs::remove_file(entry.unwrap().path()).unwrap();
    }
    for n in 0..6 {
        std::fs::write(dir.join(format!("frames/{n:06}.pgm")), &first).unwrap();
    }
}

#[test]
fn a_recording_without_motion_is_refused() {
    let copy = TempRecording::copy_of("flat_marks", "standing");
    standing_copy(&copy.dir);
    let recording = Recording::open(&copy.dir).unwrap();
    let error = calibrate(&recording, &CalibrationConfig::default()).unwrap_err();
    assert!(matches!(error, CalibrationError::NoMotion { .. }), "{error}");
    // Without odometry the images show no motion either.
    let config = CalibrationConfig { ignore_odometry: true, ..CalibrationConfig::default() };
    let error = calibrate(&recording, &config).unwrap_err();
    assert!(matches!(error, CalibrationError::NoMotion { .. } | CalibrationError::Underdetermined), "{error}");
    // The CLI says so and exits nonzero, writing nothing.
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(["calibrate", "--write"]).arg(&copy.dir).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("does not move"), "{stderr}");
    assert!(!copy.dir.join("rig.calibrated.toml").exists());
}

#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn cli_prints_the_keys_and_writes_a_rig_that_parses() {
    let copy = TempRecording::copy_of("flat_marks", "calibrate-cli");
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(["calibrate", "--write"]).arg(&copy.dir).output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    for key in ["tilt_deg", "height_mm", "roll_deg", "yaw_deg"] {
        for name in [key.to_string(), format!("{key}_sigma")] {
            let line = stdout.lines().find(|l| l.split(':').next() == Some(name.as_str()));
            let value = line.and_then(|l| l.split(':').nth(1)).map(|v| v.trim().parse::<f64>());
            assert!(matches!(value, Some(Ok(v)) if v.is_finite()), "{name} missing in:\n{stdout}");
        }
    }
    assert!(stdout.contains("residual_before:") && stdout.contains("residual_after:"), "{stdout}");
    let written = copy.dir.join("rig.calibrated.toml");
    let text = std::fs::read_to_string(&written).unwrap();
    let (rig, _) = parse_rig(&written, &text).unwrap();
    let original = Recording::open(&copy.dir).unwrap().rig;
    assert_eq!(rig.camera(), original.camera());
    assert_eq!(rig.aoi(), original.aoi());
    assert!((rig.mount().tilt_deg - 32.0).abs() <= BOUNDS[0], "{text}");
}

/// What ROS camera_calibration writes (camera_info YAML), for flat_marks' camera.
const CAMERA_INFO: &str = "image_width: 256
image_height: 256
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [240.0, 0.0, 127.5,
         0.0, 240.0, 127.5,
         0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.01, 0.002, 0.0, 0.0, 0.0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
";

#[test]
fn camera_info_is_read() {
    let info = parse_camera_info(CAMERA_INFO).unwrap();
    assert_eq!((info.width, info.height, info.fx, info.fy, info.cx, info.cy), (256, 256, 240.0, 240.0, 127.5, 127.5));
    assert_eq!(info.distortion.map(|d| d.coefficients()), Some([-0.01, 0.002, 0.0, 0.0, 0.0]));
    assert!(parse_camera_info(&CAMERA_INFO.replace("plumb_bob", "equidistant")).is_err());
    assert!(parse_camera_info(&CAMERA_INFO.replace("127.5,\n         0.0, 0.0, 1.0", "127.5")).is_err());
}

/// `calibrate --camera-info` end to end (a calibration: the long tier).
#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn camera_info_is_written_into_the_calibrated_rig() {
    let info = parse_camera_info(CAMERA_INFO).unwrap();
    let copy = TempRecording::copy_of("flat_marks", "camera-info");
    let file = copy.dir.join("camera_info.yaml");
    std::fs::write(&file, CAMERA_INFO).unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_flatland"))
        .args(["calibrate", "--write", "--camera-info"])
        .arg(&file)
        .arg(&copy.dir)
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let written = copy.dir.join("rig.calibrated.toml");
    let (rig, _) = parse_rig(&written, &std::fs::read_to_string(&written).unwrap()).unwrap();
    assert_eq!(rig.camera().distortion, info.distortion);
    assert_eq!(rig.camera().fx, 240.0);
    // A camera_info of another size is refused.
    std::fs::write(&file, CAMERA_INFO.replace("image_width: 256", "image_width: 640")).unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(["calibrate", "--camera-info"]).arg(&file).arg(&copy.dir).output().unwrap();
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("640x256"), "{}", String::from_utf8_lossy(&output.stderr));
}

/// The crooked mount end to end: the rig message carries roll and yaw, the
/// firmware in QEMU builds the crooked table and gives exactly the host's
/// csv, and the warped flat floor raises no alarm. A roll that slants the
/// KG rows across more camera rows than the ring holds (`MAX_RING_BYTES`)
/// is refused with the same typed error on both: at start-up with
/// `camera_too_large` on the firmware, cleanly.
#[test]
#[cfg_attr(not(feature = "qemu-tests"), ignore = "QEMU tier: cargo test -p flatland-host --features qemu-tests")]
fn a_crooked_recording_detects_alike_on_host_and_firmware() {
    for (roll, yaw) in [(0.5, -1.0), (1.5, -2.0)] {
        let (copy, _) = crooked_copy("flat_marks", roll, yaw);
        let expected = common::detect_csv(&copy.dir);
        assert!(expected.lines().count() > 1, "no rows");
        for row in expected.lines().skip(1) {
            assert_eq!(row.split(',').nth(2), Some("0"), "alarm on the flat floor rolled {roll}: {row}");
        }
        let outcome = common::run(&copy.dir, common::script(&copy.dir));
        let (csv, summary) = common::decoded(&outcome);
        assert!(summary.frame_faults.is_empty(), "{:?}", summary.frame_faults);
        assert_eq!(csv, expected, "rolled {roll}, yawed {yaw}");
    }

    // Rolled 30 degrees (the rig alone: nothing is detected).
    let copy = TempRecording::copy_of("flat_marks", "rolled");
    let recording = Recording::open(&copy.dir).unwrap();
    let rolled = Mount { roll_deg: 30.0, ..*recording.rig.mount() };
    let rig_path = copy.dir.join("rig.toml");
    let text = std::fs::read_to_string(&rig_path).unwrap();
    std::fs::write(&rig_path, calibrated_rig_toml(&text, &rolled)).unwrap();
    let recording = Recording::open(&copy.dir).unwrap();
    let refused = Detector::new(&recording.rig, &DetectConfig::default()).and_then(|mut detector| detector.run(&recording, |_, _| {})).unwrap_err();
    assert!(refused.contains("row ring needs"), "{refused}");
    let outcome = common::run(&copy.dir, common::script(&copy.dir));
    assert!(outcome.log.contains("RingTooSmall"), "{}", outcome.log);
    let faults = common::faults(&outcome);
    assert!(faults.iter().any(|f| f.code == flatland_core::protocol::FaultCode::CameraTooLarge), "{faults:?}");
}

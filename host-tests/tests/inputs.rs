//! The host side of a recording's inputs (issue 13): poses.csv's columns
//! decided by its header, `--odometry none` / `--imu none`, frames larger
//! than the pipeline takes, AOI refusals that name the edge, a nearly level
//! car camera, and `flatland heights` on curved paths.

use flatland_core::geometry::{AoiEdge, RigError};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::motion::{Attitude, Pose};
use flatland_core::pipeline::PoseSample;
use flatland_core::remap::RemapTable;
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::heights::run_heights;
use flatland_host::recording::{parse_poses, parse_rig, Binning, Frame, PoseHeaderError, Recording, RecordingError};
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::data;

/// An empty scratch directory for this test.
fn scratch(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("inputs").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    dir
}

/// A copy of a bundled recording whose poses.csv keeps only `columns`.
fn with_pose_columns(name: &str, test: &str, columns: &[&str]) -> PathBuf {
    let source = data(name);
    let dir = scratch(test);
    for file in ["rig.toml", "truth.toml"] {
        std::fs::copy(source.join(file), dir.join(file)).unwrap();
    }
    for entry in std::fs::read_dir(source.join("frames")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), dir.join("frames").join(entry.file_name())).unwrap();
    }
    let text = std::fs::read_to_string(source.join("poses.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let keep: Vec<usize> = columns.iter().map(|c| header.iter().position(|h| h == c).unwrap()).collect();
    let mut out = columns.join(",") + "\n";
    for line in lines {
        let fields: Vec<&str> = line.split(',').collect();
        out += &(keep.iter().map(|&k| fields[k]).collect::<Vec<_>>().join(",") + "\n");
    }
    std::fs::write(dir.join("poses.csv"), out).unwrap();
    dir
}

/// `flatland ARGS DIR`: exit status, stdout, stderr.
fn flatland(args: &[&str], dir: &Path) -> (Option<i32>, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(args).arg(dir).output().unwrap();
    let text = |bytes: Vec<u8>| String::from_utf8(bytes).unwrap();
    (output.status.code(), text(output.stdout), text(output.stderr))
}

fn rows(text: &str) -> Vec<PoseSample> {
    parse_poses(Path::new("poses.csv"), text).unwrap().iter().map(PoseSample::from).collect()
}

#[test]
fn poses_header_decides_the_columns() {
    let pose = Some(Pose { x_mm: 1.0, z_mm: 2.0, yaw_deg: 3.0 });
    let attitude = Some(Attitude { pitch_deg: 0.5, roll_deg: -0.25 });
    let sample = |t_s, pose, attitude| PoseSample { t_s, pose, attitude };
    assert_eq!(rows("frame,t_s,x_mm,z_mm,yaw_deg\n0,0.0,1,2,3\n"), [sample(0.0, pose, None)]);
    assert_eq!(rows("frame,t_s,x_mm,z_mm,yaw_deg,pitch_deg,roll_deg\n0,0.0,1,2,3,0.5,-0.25\n"), [sample(0.0, pose, attitude)]);
    assert_eq!(rows("frame,t_s\n0,0.0\n1,0.1\n"), [sample(0.0, None, None), sample(0.1, None, None)]);
    // After frame,t_s the columns go by name, in any order.
    assert_eq!(rows("frame,t_s,pitch_deg,roll_deg,yaw_deg,x_mm,z_mm\n0,0.0,0.5,-0.25,3,1,2\n"), [sample(0.0, pose, attitude)]);
    assert_eq!(rows("frame,t_s,pitch_deg,roll_deg\n0,0.0,0.5,-0.25\n"), [sample(0.0, None, attitude)]);
    // A group left empty in a row is absent in that row.
    assert_eq!(
        rows("frame,t_s,x_mm,z_mm,yaw_deg,pitch_deg,roll_deg\n0,0.0,,,,0.5,-0.25\n1,0.1,1,2,3,,\n"),
        [sample(0.0, None, attitude), sample(0.1, pose, None)]
    );
}

#[test]
fn bad_poses_headers_and_rows_name_their_line() {
    let header_error = |text: &str| match parse_poses(Path::new("poses.csv"), text) {
        Err(error @ RecordingError::PoseHeader { .. }) => {
            assert!(error.to_string().starts_with("poses.csv:1: "), "{error}");
            let RecordingError::PoseHeader { error, .. } = error else { unreachable!() };
            error
        }
        other => panic!("{text:?}: {other:?}"),
    };
    let unknown = |column: &str| PoseHeaderError::Unknown { column: column.into() };
    let duplicate = |column: &str| PoseHeaderError::Duplicate { column: column.into() };
    assert_eq!(header_error(""), PoseHeaderError::Empty);
    assert_eq!(header_error("t_s,frame,x_mm,z_mm,yaw_deg\n"), PoseHeaderError::FirstColumns { found: "t_s,frame,x_mm,z_mm,yaw_deg".into() });
    assert_eq!(header_error("frame\n0\n"), PoseHeaderError::FirstColumns { found: "frame".into() });
    assert_eq!(header_error("frame,t_s,x_mm,z_mm,yaw\n"), unknown("yaw"));
    assert_eq!(header_error("frame,t_s,x_mm,z_mm,yaw_deg,x_mm\n"), duplicate("x_mm"));
    assert_eq!(header_error("frame,t_s,t_s\n"), duplicate("t_s"));
    assert_eq!(header_error("frame,t_s,x_mm,z_mm\n"), PoseHeaderError::Incomplete { column: "x_mm", missing: "yaw_deg" });
    assert_eq!(header_error("frame,t_s,x_mm,z_mm,yaw_deg,roll_deg\n"), PoseHeaderError::Incomplete { column: "roll_deg", missing: "pitch_deg" });
    let row_error = |text: &str, line: usize, says: &str| {
        let message = parse_poses(Path::new("poses.csv"), text).unwrap_err().to_string();
        assert!(message.starts_with(&format!("poses.csv:{line}: ")) && message.contains(says), "{message}");
    };
    let full = "frame,t_s,x_mm,z_mm,yaw_deg,pitch_deg,roll_deg\n0,0.0,0,0,0,0,0\n";
    row_error(&format!("{full}1,0.1,5,,0,0,0\n"), 3, "z_mm is empty");
    row_error(&format!("{full}1,0.1,5,6,0,x,0\n"), 3, "bad pitch_deg");
    row_error(&format!("{full}1,0.1,5,6,0,nan,0\n"), 3, "bad pitch_deg");
    row_error(&format!("{full}1,0.1,5,6,0\n"), 3, "expected 7 fields, found 5");
    row_error("frame,t_s\n0,0.0\n1,\n", 3, "bad t_s");
}

/// `--odometry none` is a poses.csv without the motion columns, `--imu none`
/// one without the IMU columns: the same csv, byte for byte.
#[test]
fn ignoring_a_sensor_is_leaving_its_columns_out() {
    let cases: [(&[&str], &[&str]); 3] = [
        (&["--odometry", "none"], &["frame", "t_s", "pitch_deg", "roll_deg"]),
        (&["--imu", "none"], &["frame", "t_s", "x_mm", "z_mm", "yaw_deg"]),
        (&["--odometry", "none", "--imu", "none"], &["frame", "t_s"]),
    ];
    for (n, (flags, kept)) in cases.into_iter().enumerate() {
        let ignored = flatland(&[&["detect"], flags].concat(), &data("bumpy_marks"));
        let left_out = flatland(&["detect"], &with_pose_columns("bumpy_marks", &format!("columns_{n}"), kept));
        assert_eq!((ignored.0, left_out.0), (Some(0), Some(0)), "{}{}", ignored.2, left_out.2);
        assert_eq!(ignored.1, left_out.1, "{flags:?} vs a poses.csv with {kept:?}");
        assert_eq!(left_out.1.lines().count(), 16, "the header and frames 1..=15");
    }
}

/// Without odometry the frames' times still order them: a frame whose time
/// goes backwards is skipped and the next restarts the keyframe (its row
/// says so: not judged, `after_gap`).
#[test]
fn time_orders_frames_without_odometry() {
    let dir = with_pose_columns("flat_marks", "time_without_odometry", &["frame", "t_s"]);
    let text = std::fs::read_to_string(dir.join("poses.csv")).unwrap().replace("\n4,0.400\n", "\n4,0.250\n");
    std::fs::write(dir.join("poses.csv"), text).unwrap();
    let (_, stdout, stderr) = flatland(&["detect"], &dir);
    assert!(stderr.contains("skipping frame 4"), "stderr: {stderr}");
    let frames: Vec<&str> = stdout.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(frames, ["1", "2", "3", "5", "6", "7"], "{stdout}");
    let statuses: Vec<&str> = stdout.lines().skip(1).map(|l| l.rsplit(',').next().unwrap()).collect();
    assert_eq!(statuses, ["ok", "ok", "ok", "after_gap", "ok", "ok"], "{stdout}");
    assert!(stdout.contains("\n5,5,1,,,,0,0,0.00,0.00,0.0,0.0,,0.000,0.000,0.000,,after_gap\n"), "{stdout}");
}

#[test]
fn binning_factor_and_average() {
    let factor = |w, h| Binning::for_frames(w, h).factor;
    assert_eq!([factor(256, 256), factor(1024, 1024), factor(1025, 10), factor(2048, 1536), factor(2049, 10), factor(4096, 3072)], [1, 1, 2, 2, 3, 4]);
    assert_eq!(Binning::for_frames(1242, 375).size(), (621, 187));
    // 2x2 blocks, rounded means; the odd last column and row are dropped.
    #[rustfmt::skip]
    let pixels = vec![
        0, 1, 10, 20, 99,
        2, 3, 30, 41, 99,
        99, 99, 99, 99, 99,
    ];
    let binned = Binning { factor: 2, recorded: (5, 3) }.apply(Frame { width: 5, height: 3, pixels });
    assert_eq!(binned, Frame { width: 2, height: 1, pixels: vec![2, 25] });
}

/// A recording upsampled `k` times (pixel replication, intrinsics scaled so
/// every ground point lands on the same scene content), in `dir`.
fn upsampled(name: &str, k: usize, dir: &Path) {
    let recording = Recording::open(data(name)).unwrap();
    let (camera, mount, aoi) = (recording.rig.camera(), recording.rig.mount(), recording.rig.aoi());
    let n = k as f64;
    let rig = format!(
        "[camera]\nwidth = {}\nheight = {}\nfx = {}\nfy = {}\ncx = {}\ncy = {}\n\n[mount]\nheight_mm = {}\ntilt_deg = {}\n\n[aoi]\nhalf_width_mm = {}\nnear_mm = {}\nfar_mm = {}\n",
        usize::from(camera.width) * k,
        usize::from(camera.height) * k,
        camera.fx * n,
        camera.fy * n,
        (camera.cx + 0.5) * n - 0.5,
        (camera.cy + 0.5) * n - 0.5,
        mount.height_mm,
        mount.tilt_deg,
        aoi.half_width_mm,
        aoi.near_mm,
        aoi.far_mm
    );
    std::fs::write(dir.join("rig.toml"), rig).unwrap();
    for file in ["poses.csv", "truth.toml"] {
        std::fs::copy(data(name).join(file), dir.join(file)).unwrap();
    }
    for &index in &recording.frames {
        let frame = recording.load_frame(index).unwrap();
        let big = replicate(&frame, k);
        let mut bytes = format!("P5\n{} {}\n255\n", big.width, big.height).into_bytes();
        bytes.extend_from_slice(&big.pixels);
        std::fs::write(dir.join("frames").join(format!("{index:06}.pgm")), bytes).unwrap();
    }
}

fn replicate(frame: &Frame, k: usize) -> Frame {
    let width = frame.width * k;
    let pixels = (0..frame.height * k)
        .flat_map(|v| (0..width).map(move |u| (u, v)))
        .map(|(u, v)| frame.pixels[(v / k) * frame.width + u / k])
        .collect();
    Frame { width, height: frame.height * k, pixels }
}

fn alarms(recording: &Recording) -> Vec<(u32, bool)> {
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
    let mut alarms = Vec::new();
    detector
        .run(recording, |outcome, _| {
            if let FrameOutcome::Report { report, .. } = outcome {
                alarms.push((report.frame, report.alarm));
            }
        })
        .unwrap();
    alarms
}

/// 2048 x 2048 frames (a bundled recording upsampled 8x) are binned 2x2 to
/// exactly the 4x upsampled frames and rig, and detect raises the same
/// alarms as on the original.
#[test]
fn large_frames_are_binned_to_what_the_grid_needs() {
    for name in ["stool_bags", "flat_marks"] {
        let dir = scratch(&format!("large_{name}"));
        upsampled(name, 8, &dir);
        let large = Recording::open(&dir).unwrap();
        let original = Recording::open(data(name)).unwrap();
        assert_eq!(large.binning, Binning { factor: 2, recorded: (2048, 2048) });
        let four_times = scratch(&format!("four_times_{name}"));
        upsampled(name, 4, &four_times);
        let expected = Recording::open(&four_times).unwrap();
        assert_eq!(expected.binning.factor, 1);
        assert_eq!(large.rig, expected.rig, "intrinsics scaled by the rule");
        assert_eq!(large.load_frame(3).unwrap(), replicate(&original.load_frame(3).unwrap(), 4));
        let (got, want) = (alarms(&large), alarms(&original));
        println!("{name}: alarms binned {got:?}");
        assert_eq!(got, want, "{name}");
        assert!(want.len() == 7 && want.iter().all(|&(_, alarm)| alarm == (name == "stool_bags")), "{want:?}");
        let _ = std::fs::remove_dir_all(&dir);
        let _ = std::fs::remove_dir_all(&four_times);
    }
}

/// A car's camera (KITTI-like: fx 721, 1242 x 375, 1.65 m high, 0.5 deg
/// down): binned 2x, its rig, grid, table and detector build for an AOI
/// below the horizon; AOIs outside the view name the edge that fails.
#[test]
fn nearly_level_car_camera() {
    let rig_toml = |near: f64, far: f64, half: f64| {
        format!(
            "[camera]\nwidth = 1242\nheight = 375\nfx = 721.5377\nfy = 721.5377\ncx = 609.5593\ncy = 172.854\n\n\
             [mount]\nheight_mm = 1650.0\ntilt_deg = 0.5\n\n[aoi]\nhalf_width_mm = {half}\nnear_mm = {near}\nfar_mm = {far}\n"
        )
    };
    let (rig, binning) = parse_rig(Path::new("rig.toml"), &rig_toml(7000.0, 15000.0, 2000.0)).unwrap();
    assert_eq!((binning.factor, binning.size()), (2, (621, 187)));
    assert_eq!((rig.camera().width, rig.camera().height, rig.camera().fx), (621, 187, 721.5377 / 2.0));
    let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
    let table = RemapTable::new(&rig, &grid).unwrap();
    let aoi = grid.aoi_pixels(&rig);
    println!("car: grid {}x{} at {} mm/px, AOI {aoi:?}", grid.width, grid.height, grid.mm_per_px);
    assert!(aoi.area() > 0 && (aoi.top..aoi.bottom).all(|j| table.valid_columns(j).len() >= aoi.width()));
    Detector::new(&rig, &DetectConfig::default()).unwrap();
    // 4 m ahead is below the image (the nearest ground in view is ~5.8 m),
    // 40 m to the side is beyond it, 1000 km is at the horizon.
    let refused = [
        (rig_toml(4000.0, 15000.0, 2000.0), RigError::AoiOutsideImage(AoiEdge::Near), "near_mm", "near edge"),
        (rig_toml(7000.0, 15000.0, 40000.0), RigError::AoiOutsideImage(AoiEdge::Left), "half_width_mm", "left edge"),
        (rig_toml(7000.0, 1.0e9, 2000.0), RigError::AoiBeyondHorizon, "far_mm", "far edge"),
    ];
    for (text, expected, key, says) in refused {
        let error = parse_rig(Path::new("rig.toml"), &text).unwrap_err();
        let line = text.lines().position(|l| l.starts_with(key)).unwrap() + 1;
        assert!(matches!(error, RecordingError::Rig { error, line: Some(l), .. } if error == expected && l == line), "{error:?}");
        assert!(error.to_string().starts_with(&format!("rig.toml:{line}: ")) && error.to_string().contains(says), "{error}");
    }
}

/// `flatland heights` gives points on a diagonal path, also without
/// odometry; on the turning one it has none and says why.
#[test]
fn heights_on_curved_paths_give_points_or_say_why() {
    let mut csv = Vec::new();
    let why = run_heights(&Recording::open(data("diagonal")).unwrap(), None, &mut csv).unwrap();
    let points = String::from_utf8(csv).unwrap().lines().count() - 1;
    assert!(why.is_none() && points > 0, "diagonal: {points} points, {why:?}");
    let mut csv = Vec::new();
    let why = run_heights(&Recording::open(data("turn")).unwrap(), None, &mut csv).unwrap();
    assert_eq!(String::from_utf8(csv).unwrap().lines().count(), 1, "turn: only the header");
    let why = why.expect("turn: a reason");
    assert!(why.contains("turns 3.0 deg per frame"), "{why}");
    // Without odometry GTI follows the motion GPA measures on the ground.
    let (status, stdout, stderr) = flatland(&["heights", "--odometry", "none"], &data("diagonal"));
    assert!(status == Some(0) && stdout.lines().count() > 1, "{stderr}");
}

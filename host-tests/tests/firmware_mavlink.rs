//! The `mavlink` firmware in QEMU, its stream decoded by the `mavlink`
//! crate's own reader: every OBSTACLE_DISTANCE equals, field for field, what
//! `flatland scan` gives on the same recording; HEARTBEAT and STATUSTEXT say
//! the sensor's state; poses go in as ODOMETRY or as LOCAL_POSITION_NED +
//! ATTITUDE; garbage, damaged and foreign frames are counted and change
//! nothing. The same streams, saved as files, are decoded by pymavlink (the
//! Python reference implementation, host-tests/tools/mavlink_check.py) and by
//! `flatland serial decode --mavlink`: each QEMU run serves all three. Every
//! captured OBSTACLE_DISTANCE gives ArduPilot and both PX4 readers every
//! hazard of the host's scan (`flatland_host::link::autopilot`).

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, OnceLock};

use flatland_core::scan::{Scan, ScanLayout, Sector, SCAN_INCREMENT_MDEG};
use flatland_host::link::autopilot::Readers;
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::link::mavlink::{decode, frames_by_time, write_scan_csv, Decoded, RowKey};
use flatland_host::qemu::{self, PoseMessages, RunRequest};
use flatland_host::recording::Recording;
use mavlink::dialects::common::{MavFrame, MavMessage, MavSeverity, MavState, OBSTACLE_DISTANCE_DATA};


fn mavlink_elf() -> std::path::PathBuf {
    static ELF: OnceLock<Result<std::path::PathBuf, String>> = OnceLock::new();
    let built = ELF.get_or_init(|| {
        qemu::require_tools()?;
        qemu::build_mavlink_firmware()
    });
    built.clone().unwrap_or_else(|message| panic!("cannot run the firmware in QEMU: {message}"))
}

/// The firmware's raw serial output and its log.
fn run_raw(dir: &Path, script: Vec<u8>) -> (Vec<u8>, String) {
    let elf = mavlink_elf();
    let request =
        RunRequest { elf: &elf, dir, script, then: None, bench: false, bench_mm_per_px: None, bench_no_margins: false, echo_log: false, exec_log: None, timeout: common::TIMEOUT, mavlink: true };
    let outcome = qemu::run_firmware(request, &mut |_| {}).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    assert!(outcome.status.success(), "{}: firmware exit {}; log:\n{}", dir.display(), outcome.status, outcome.log);
    (outcome.serial.raw, outcome.log)
}

fn run(dir: &Path, script: Vec<u8>) -> (Decoded, String) {
    let (raw, log) = run_raw(dir, script);
    (decode(&raw), log)
}

/// One recording's stream with the poses as ODOMETRY, saved as a file.
struct Capture {
    raw: Vec<u8>,
    log: String,
    path: PathBuf,
}

/// A bundled recording's capture: one QEMU run per recording for every
/// test that reads it (a second test asking waits for the first's run).
fn capture(name: &str) -> &'static Capture {
    static CAPTURES: Mutex<BTreeMap<String, &'static OnceLock<Capture>>> = Mutex::new(BTreeMap::new());
    let cell: &'static OnceLock<Capture> = CAPTURES.lock().unwrap().entry(name.to_string()).or_insert_with(|| Box::leak(Box::default()));
    cell.get_or_init(|| {
        let dir = common::data(name);
        let recording = Recording::open(&dir).unwrap();
        let (raw, log) = run_raw(&dir, qemu::mavlink_script(&recording, PoseMessages::Odometry).unwrap());
        let captures = Path::new(env!("CARGO_TARGET_TMPDIR")).join("mavlink-captures");
        std::fs::create_dir_all(&captures).unwrap();
        let path = captures.join(format!("{name}.bin"));
        std::fs::write(&path, &raw).unwrap();
        Capture { raw, log, path }
    })
}

/// `flatland scan`'s scans (in-process), by frame time in microseconds, the
/// frames by time, and the scans' layout.
fn host_scans(recording: &Recording) -> (BTreeMap<u64, Scan>, BTreeMap<u64, u32>, ScanLayout) {
    let times: BTreeMap<u32, u64> = recording.poses.iter().map(|row| (row.frame, (row.t_s * 1e6).round() as u64)).collect();
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
    let mut scans = BTreeMap::new();
    let mut layout = None;
    detector
        .run(recording, |outcome, pipeline| {
            layout = Some(pipeline.gpa().scan().layout());
            // Frames judged have a scan; the others compared nothing.
            match outcome {
                FrameOutcome::Report { report, .. } if report.is_judged() => {
                    scans.insert(times[&report.frame], *pipeline.gpa().scan());
                }
                _ => {}
            }
        })
        .unwrap();
    (scans, times.into_iter().map(|(frame, t)| (t, frame)).collect(), layout.expect("a frame was read"))
}

/// The range fields as docs/MAVLINK.md documents them (cm): the scan's
/// nearest range (at least 1), one beyond its farthest.
fn limits(layout: &ScanLayout) -> (u16, u16) {
    ((layout.range_min_mm / 10).max(1), layout.range_max_mm / 10 + 1)
}

/// The scan's sectors each element holds: element j (centred on 5j - 180
/// degrees) the sectors centred within 5 degrees of it.
fn groups(scan: &Scan) -> BTreeMap<usize, Vec<Sector>> {
    let layout = scan.layout();
    let mut groups: BTreeMap<usize, Vec<Sector>> = BTreeMap::new();
    for (k, sector) in scan.sectors().enumerate() {
        let centre_mdeg = layout.angle_start_mdeg() + k as i32 * SCAN_INCREMENT_MDEG;
        for bin in 0..72i32 {
            let apart = (centre_mdeg - bin * 5000).rem_euclid(360_000) - 180_000;
            if apart.abs() < 5000 {
                groups.entry(bin as usize).or_default().push(sector);
            }
        }
    }
    groups
}

/// OBSTACLE_DISTANCE as docs/MAVLINK.md documents it, from a scan's sectors:
/// element j holds the sectors centred within 5 degrees of 5j - 180, all
/// four of them in the scan for free; hazards in cm rounded down.
fn expected(scan: &Scan) -> ([u16; 72], u16, u16) {
    let (min, max) = limits(&scan.layout());
    let mut distances = [u16::MAX; 72];
    for (bin, sectors) in groups(scan) {
        let nearest = sectors.iter().filter_map(|s| if let Sector::Hazard(mm) = s { Some(*mm) } else { None }).min();
        distances[bin] = match nearest {
            Some(mm) => (mm / 10).clamp(min, max - 1),
            None if sectors.len() == 4 && sectors.iter().all(|s| *s == Sector::Free) => max + 1,
            None => u16::MAX,
        };
    }
    (distances, min, max)
}

/// Doubt as docs/MAVLINK.md documents it: min_distance in every element
/// that holds a sector of the scan, unknown elsewhere.
fn expected_doubt(layout: ScanLayout) -> ([u16; 72], u16, u16) {
    let (min, max) = limits(&layout);
    let mut distances = [u16::MAX; 72];
    for bin in groups(&Scan::new(layout)).into_keys() {
        distances[bin] = min;
    }
    (distances, min, max)
}

fn obstacle_distances(decoded: &Decoded) -> Vec<&OBSTACLE_DISTANCE_DATA> {
    decoded.messages.iter().filter_map(|(_, m)| if let MavMessage::OBSTACLE_DISTANCE(o) = m { Some(o) } else { None }).collect()
}

/// Checks a run against the host: one OBSTACLE_DISTANCE per pose, equal to
/// the host's scan field for field (doubt where the host compared nothing),
/// and read by every autopilot without a hazard lost or, after doubt, the
/// vehicle released; returns how many carried a scan.
fn check_against_host(name: &str, dir: &Path, decoded: &Decoded) -> usize {
    check_against(name, &Recording::open(dir).unwrap(), decoded)
}

/// [`check_against_host`] on a recording as opened (sensors left out).
fn check_against(name: &str, recording: &Recording, decoded: &Decoded) -> usize {
    assert!(decoded.errors.is_empty(), "{name}: {:?}", decoded.errors);
    let (scans, frames, layout) = host_scans(recording);
    let messages = obstacle_distances(decoded);
    assert_eq!(messages.len(), frames.len(), "{name}: one OBSTACLE_DISTANCE per pose");
    let mut compared = 0;
    let mut readers = Readers::default();
    for message in messages {
        let frame = frames[&message.time_usec];
        assert_eq!((message.increment_f, message.increment, message.angle_offset), (5.0, 5, -180.0), "{name} frame {frame}");
        assert_eq!(message.frame, MavFrame::MAV_FRAME_BODY_FRD);
        readers.read(message);
        let (distances, min, max) = scans.get(&message.time_usec).map_or(expected_doubt(layout), expected);
        assert_eq!((message.min_distance, message.max_distance), (min, max), "{name} frame {frame}");
        assert_eq!(message.distances, distances, "{name} frame {frame}");
        match scans.get(&message.time_usec) {
            Some(scan) => {
                let lost = readers.lost_hazards(message, scan);
                assert!(lost.is_empty(), "{name} frame {frame}: an autopilot loses hazards: {lost:?}");
                compared += 1;
            }
            None => {
                let released = readers.released(&layout, min);
                assert!(released.is_empty(), "{name} frame {frame}: nothing compared, yet released: {released:?}");
            }
        }
    }
    compared
}

fn heartbeats(decoded: &Decoded) -> Vec<MavState> {
    decoded
        .messages
        .iter()
        .filter_map(|(header, m)| match m {
            MavMessage::HEARTBEAT(h) => {
                assert_eq!((header.system_id, header.component_id), (1, 196), "MAV_COMP_ID_OBSTACLE_AVOIDANCE of system 1");
                Some(h.system_status)
            }
            _ => None,
        })
        .collect()
}

fn end_text(decoded: &Decoded) -> String {
    decoded
        .messages
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::STATUSTEXT(t) if t.severity == MavSeverity::MAV_SEVERITY_INFO => t.text.to_str().ok().map(str::to_string),
            _ => None,
        })
        .next_back()
        .unwrap_or_default()
}

#[test]
fn obstacle_distance_matches_flatland_scan_on_every_recording() {
    let mut compared = 0;
    for name in &common::bundled() {
        let dir = common::data(name);
        let recording = Recording::open(&dir).unwrap();
        let capture = capture(name);
        let (decoded, log) = (decode(&capture.raw), &capture.log);
        compared += check_against_host(name, &dir, &decoded);
        let states = heartbeats(&decoded);
        assert_eq!(states.first(), Some(&MavState::MAV_STATE_STANDBY), "{name}");
        assert!(states.contains(&MavState::MAV_STATE_ACTIVE), "{name}: {states:?}");
        assert!(end_text(&decoded).starts_with(&format!("end f{} g0 c0 u0 b0", recording.poses.len())), "{name}: {}\n{log}", end_text(&decoded));
    }
    assert!(compared > 150, "{compared}");
}

/// The venv's python that has pymavlink: `$FLATLAND_PYTHON` (.ci/test sets
/// it), else `.venv/bin/python` at the workspace root. Missing: the test
/// fails and says how to make it.
fn pymavlink_python() -> PathBuf {
    let python = std::env::var_os("FLATLAND_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| qemu::workspace_root().join(".venv").join("bin").join("python"));
    assert!(
        python.exists(),
        "no Python for pymavlink at {}: run .ci/ensure-tools (it makes .venv at the repository root and installs \
         host-tests/tools/requirements.txt), or set FLATLAND_PYTHON to a python that has pymavlink",
        python.display()
    );
    python
}

/// One OBSTACLE_DISTANCE as mavlink_check.py prints it.
#[derive(Debug)]
struct PyObstacleDistance {
    time_usec: u64,
    sender: (u8, u8),
    frame: u8,
    limits: (u16, u16),
    increment: u8,
    increment_f: f32,
    angle_offset: f32,
    distances: Vec<u16>,
}

/// What pymavlink made of a capture: its OBSTACLE_DISTANCE rows and counts.
struct PymavlinkReport {
    obstacles: Vec<PyObstacleDistance>,
    counts: BTreeMap<String, u64>,
    success: bool,
}

fn pymavlink_check(path: &Path) -> PymavlinkReport {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools").join("mavlink_check.py");
    let output = Command::new(pymavlink_python()).arg(&script).arg(path).output().unwrap();
    let stdout = String::from_utf8(output.stdout).unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    let mut lines = stdout.lines();
    let header = lines.next().unwrap_or_else(|| {
        panic!("mavlink_check.py printed nothing ({}; is pymavlink installed? .ci/ensure-tools installs it):\n{stderr}", output.status)
    });
    assert!(header.starts_with("time_usec,sysid,compid,frame,") && header.ends_with(",d71"), "{header}");
    let mut report = PymavlinkReport { obstacles: Vec::new(), counts: BTreeMap::new(), success: output.status.success() };
    for line in lines {
        if let Some(counts) = line.strip_prefix("# ") {
            let words: Vec<&str> = counts.split(' ').collect();
            for pair in words.chunks(2) {
                report.counts.insert(pair[0].to_string(), pair[1].parse().unwrap());
            }
            continue;
        }
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), 9 + 72, "{line}");
        let int = |k: usize| cells[k].parse::<u64>().unwrap_or_else(|e| panic!("{line}: column {k}: {e}"));
        report.obstacles.push(PyObstacleDistance {
            time_usec: int(0),
            sender: (int(1) as u8, int(2) as u8),
            frame: int(3) as u8,
            limits: (int(4) as u16, int(5) as u16),
            increment: int(6) as u8,
            increment_f: cells[7].parse().unwrap(),
            angle_offset: cells[8].parse().unwrap(),
            distances: (9..cells.len()).map(|k| int(k) as u16).collect(),
        });
    }
    assert!(report.counts.contains_key("messages"), "mavlink_check.py printed no counts ({}):\n{stderr}", output.status);
    report
}

/// Messages of each type, as mavlink_check.py names them.
fn type_counts(decoded: &Decoded) -> BTreeMap<String, u64> {
    let mut counts = BTreeMap::new();
    for (_, message) in &decoded.messages {
        let name = format!("{message:?}");
        let name = name.split('(').next().unwrap().to_string();
        *counts.entry(name).or_default() += 1;
    }
    counts
}

/// pymavlink, the reference implementation, reads every byte of every
/// recording's stream as valid MAVLink 2 (no CRC or length error, no byte
/// outside a frame, no unknown message, no sequence gap), finds the messages
/// the `mavlink` crate finds, and its OBSTACLE_DISTANCE equals `flatland scan`
/// by docs/MAVLINK.md's rule. The recordings are taken last first, so that this
/// test and the one above run QEMU on different recordings at once.
#[test]
fn pymavlink_decodes_every_recording_and_agrees_with_flatland_scan() {
    let python = pymavlink_python();
    let mut compared = 0;
    for name in common::bundled().iter().rev() {
        let dir = common::data(name);
        let capture = capture(name);
        let report = pymavlink_check(&capture.path);
        for fault in ["receive_errors", "bad_data", "unknown", "mavlink1", "seq_gaps", "leftover_bytes"] {
            assert_eq!(report.counts[fault], 0, "{name}: pymavlink {fault} ({} with {})", capture.path.display(), python.display());
        }
        assert!(report.success, "{name}: mavlink_check.py failed");
        let decoded = decode(&capture.raw);
        assert_eq!(report.counts["messages"], decoded.messages.len() as u64, "{name}: messages");
        assert_eq!(report.counts["bytes"], capture.raw.len() as u64, "{name}");
        for (kind, count) in type_counts(&decoded) {
            assert_eq!(report.counts.get(&kind), Some(&count), "{name}: {kind}");
        }
        let (scans, frames, layout) = host_scans(&Recording::open(&dir).unwrap());
        assert_eq!(report.obstacles.len(), frames.len(), "{name}: one OBSTACLE_DISTANCE per pose");
        for message in &report.obstacles {
            let frame = frames[&message.time_usec];
            assert_eq!(message.sender, (1, 196), "{name} frame {frame}");
            assert_eq!(message.frame, MavFrame::MAV_FRAME_BODY_FRD as u8, "{name} frame {frame}");
            assert_eq!((message.increment, message.increment_f, message.angle_offset), (5, 5.0, -180.0), "{name} frame {frame}");
            let (distances, min, max) = scans.get(&message.time_usec).map_or(expected_doubt(layout), expected);
            assert_eq!(message.limits, (min, max), "{name} frame {frame}");
            assert_eq!(message.distances, distances, "{name} frame {frame}");
            compared += usize::from(scans.contains_key(&message.time_usec));
        }
    }
    assert!(compared > 150, "{compared}");
}

/// `flatland serial decode --mavlink --recording REC` on each capture prints,
/// per pose, the scan merged into OBSTACLE_DISTANCE's 5-degree bins by the
/// docs/MAVLINK.md's rule, from -180 degrees, in `flatland scan`'s csv form (mm, `inf`
/// free, empty unknown); frames that compared nothing show doubt (the
/// nearest range wherever the camera looks).
#[test]
fn serial_decode_mavlink_prints_the_merged_scan() {
    for name in &common::bundled() {
        let dir = common::data(name);
        let capture = capture(name);
        let (scans, frames, layout) = host_scans(&Recording::open(&dir).unwrap());
        let mut expected_csv = String::from("frame,angle_start_deg,increment_deg");
        for k in 0..72 {
            expected_csv += &format!(",d{k}_mm");
        }
        expected_csv.push('\n');
        for (time, frame) in &frames {
            expected_csv += &format!("{frame},-180.000,5.000");
            let (distances, _, max) = scans.get(time).map_or(expected_doubt(layout), expected);
            for distance in distances {
                expected_csv.push(',');
                match distance {
                    u16::MAX => {}
                    d if d == max + 1 => expected_csv += "inf",
                    d => expected_csv += &(u32::from(d) * 10).to_string(),
                }
            }
            expected_csv.push('\n');
        }
        let output = Command::new(env!("CARGO_BIN_EXE_flatland"))
            .args(["serial", "decode", "--mavlink", "--recording"])
            .arg(&dir)
            .arg(&capture.path)
            .output()
            .unwrap();
        assert!(output.status.success(), "{name}: {}", String::from_utf8_lossy(&output.stderr));
        assert_eq!(String::from_utf8(output.stdout).unwrap(), expected_csv, "{name}");
        // Without the recording the rows are keyed by time_usec.
        let mut by_time = Vec::new();
        let rows = write_scan_csv(&decode(&capture.raw), RowKey::TimeUsec, &mut by_time).unwrap();
        assert_eq!(rows, frames.len(), "{name}");
        let by_time = String::from_utf8(by_time).unwrap();
        let first_row = by_time.lines().nth(1).unwrap();
        assert_eq!(first_row.split(',').next(), frames.keys().next().map(u64::to_string).as_deref(), "{name}");
        let recording = Recording::open(&dir).unwrap();
        assert_eq!(frames_by_time(&recording), frames, "{name}");
    }
}

#[test]
fn local_position_and_attitude_feed_the_same_poses() {
    let dir = common::data("bumpy_marks");
    let recording = Recording::open(&dir).unwrap();
    let (decoded, _) = run(&dir, qemu::mavlink_script(&recording, PoseMessages::LocalPosition).unwrap());
    assert!(check_against_host("bumpy_marks", &dir, &decoded) > 10);
}

/// Garbage between frames, a damaged ODOMETRY copy, foreign messages and a
/// MAVLink 1 frame before each real pose: each is counted, none changes a
/// scan.
#[test]
fn damaged_and_foreign_frames_are_counted_and_ignored() {
    let dir = common::data("flat_marks");
    let recording = Recording::open(&dir).unwrap();
    let clean = qemu::mavlink_script(&recording, PoseMessages::Odometry).unwrap();
    // The script is the rig line, MAVLink frames, the end line.
    let rig_end = clean.iter().position(|&b| b == b'\n').unwrap() + 1;
    let end_start = clean.iter().rposition(|&b| b == b'$').unwrap();
    let mut script = clean[..rig_end].to_vec();
    let mut frames = &clean[rig_end..end_start];
    let poses = recording.poses.len();
    let mut foreign = mavlink::MAVLinkV2MessageRaw::new();
    let text = mavlink::dialects::common::STATUSTEXT_DATA { text: "x".into(), ..Default::default() };
    foreign.serialize_message_data(mavlink::MavHeader::default(), &text);
    while !frames.is_empty() {
        let length = 12 + usize::from(frames[1]);
        let (frame, rest) = frames.split_at(length);
        let mut damaged = frame.to_vec();
        damaged[20] ^= 0x55;
        script.extend_from_slice(b"noise\x00\xff");
        script.extend_from_slice(&damaged);
        script.extend_from_slice(foreign.raw_bytes());
        script.extend_from_slice(&[0xFE, 2, 0, 1, 1, 0, 7, 7, 0, 0]);
        script.extend_from_slice(frame);
        frames = rest;
    }
    script.extend_from_slice(&clean[end_start..]);
    let (decoded, log) = run(&dir, script);
    check_against_host("flat_marks", &dir, &decoded);
    // 7 garbage bytes per pose ('$'-free), one bad checksum, one foreign
    // and one MAVLink 1 frame (both counted as unknown).
    let expected = format!("end f{poses} g{} c{poses} u{} b0", 7 * poses, 2 * poses);
    assert!(end_text(&decoded).starts_with(&expected), "{} vs {expected}\n{log}", end_text(&decoded));
    assert!(!log.contains("panic"));
}

/// Issue 33: a floor without texture (frames 4-7 of flat_marks made uniform
/// gray) and no odometry (ODOMETRY with x, y NaN). Frames 1-3 are judged;
/// frames 4-7 cannot be: each sends what the fail-safe says, an
/// OBSTACLE_DISTANCE of doubt (not the last judged frame's scan: no stale
/// clear; not all unknown, which ArduPilot and PX4 read as free: issue
/// 52), which holds every autopilot's reader back, a STATUSTEXT warning
/// that says why, and the status falls back to standby.
#[test]
fn a_frame_not_judged_is_unknown_and_says_why() {
    let copy = common::TempRecording::copy_of("flat_marks", "mavlink-not-judged");
    for frame in 4..8 {
        let mut bytes = b"P5\n256 256\n255\n".to_vec();
        bytes.resize(bytes.len() + 256 * 256, 128);
        std::fs::write(copy.frame(frame), bytes).unwrap();
    }
    let mut recording = Recording::open(&copy.dir).unwrap();
    recording.ignore_odometry();
    let (decoded, log) = run(&copy.dir, qemu::mavlink_script(&recording, PoseMessages::Odometry).unwrap());
    assert_eq!(check_against("textureless", &recording, &decoded), 3, "frames 1-3 carry a scan:\n{log}");
    let warnings: Vec<String> = decoded
        .messages
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::STATUSTEXT(t) if t.severity == MavSeverity::MAV_SEVERITY_WARNING => t.text.to_str().ok().map(str::to_string),
            _ => None,
        })
        .collect();
    let expected: Vec<String> = (4..8).map(|frame| format!("frame {frame} not judged: no_motion")).collect();
    assert_eq!(warnings, expected, "{log}");
    let mut states = heartbeats(&decoded);
    states.dedup();
    assert_eq!(states, [MavState::MAV_STATE_STANDBY, MavState::MAV_STATE_ACTIVE, MavState::MAV_STATE_STANDBY], "{log}");
}

/// Issue 52: a frame given up (frame 4's file missing: `frame_missing`)
/// sends doubt under its pose's time, before the STATUSTEXT that says why,
/// and so does frame 5, which restarts the keyframe: every autopilot's
/// reader holds back through both (check_against), where before frame 4
/// sent no OBSTACLE_DISTANCE at all and frame 5 an all-unknown one.
#[test]
fn a_frame_given_up_sends_doubt() {
    let copy = common::TempRecording::copy_of("flat_marks", "mavlink-frame-missing");
    std::fs::remove_file(copy.frame(4)).unwrap();
    let recording = Recording::open(&copy.dir).unwrap();
    let (decoded, log) = run(&copy.dir, qemu::mavlink_script(&recording, PoseMessages::Odometry).unwrap());
    let compared = check_against("frame_missing", &recording, &decoded);
    assert_eq!(compared, recording.poses.len() - 3, "frames 0, 4 and 5 compare nothing:\n{log}");
    let frame_4 = flatland_core::mavlink::time_usec(recording.poses.iter().find(|row| row.frame == 4).unwrap().t_s);
    let order: Vec<String> = decoded
        .messages
        .iter()
        .filter_map(|(_, m)| match m {
            MavMessage::OBSTACLE_DISTANCE(o) if o.time_usec == frame_4 => Some("doubt".to_string()),
            MavMessage::STATUSTEXT(t) if t.severity == MavSeverity::MAV_SEVERITY_ERROR => t.text.to_str().ok().map(str::to_string),
            _ => None,
        })
        .collect();
    assert_eq!(order, ["doubt", "frame 4: frame_missing"], "{log}");
}

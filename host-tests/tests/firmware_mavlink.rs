//! The `mavlink` firmware in QEMU, its stream decoded by the `mavlink`
//! crate's own reader: every OBSTACLE_DISTANCE equals, field for field, what
//! `flatland scan` gives on the same recording; HEARTBEAT and STATUSTEXT say
//! the sensor's state; poses go in as ODOMETRY or as LOCAL_POSITION_NED +
//! ATTITUDE; garbage, damaged and foreign frames are counted and change
//! nothing.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;

use flatland_core::scan::{Scan, Sector, SCAN_INCREMENT_MDEG};
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::mavlink_decode::{decode, Decoded};
use flatland_host::qemu::{self, PoseMessages, RunRequest};
use flatland_host::recording::Recording;
use mavlink::dialects::common::{MavFrame, MavMessage, MavSeverity, MavState, OBSTACLE_DISTANCE_DATA};

const RECORDINGS: [&str; 13] = [
    "flat_marks",
    "stool_bags",
    "approach_box",
    "diagonal",
    "turn",
    "qvga_curb",
    "noisy_marks",
    "noisy_approach",
    "bumpy_marks",
    "bumpy_approach",
    "exposure_rolling",
    "slip",
    "ledge",
];

fn mavlink_elf() -> std::path::PathBuf {
    static ELF: OnceLock<Result<std::path::PathBuf, String>> = OnceLock::new();
    let built = ELF.get_or_init(|| {
        qemu::require_tools()?;
        qemu::build_mavlink_firmware()
    });
    built.clone().unwrap_or_else(|message| panic!("cannot run the firmware in QEMU: {message}"))
}

fn run(dir: &Path, script: Vec<u8>) -> (Decoded, String) {
    let elf = mavlink_elf();
    let request =
        RunRequest { elf: &elf, dir, script, then: None, bench: false, bench_mm_per_px: None, bench_no_margins: false, echo_log: false, timeout: common::TIMEOUT, mavlink: true };
    let outcome = qemu::run_firmware(request, &mut |_| {}).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    assert!(outcome.status.success(), "{}: firmware exit {}; log:\n{}", dir.display(), outcome.status, outcome.log);
    (decode(&outcome.serial.raw), outcome.log)
}

/// `flatland scan`'s scans (in-process), by frame time in microseconds.
fn host_scans(dir: &Path) -> (BTreeMap<u64, Scan>, BTreeMap<u64, u32>) {
    let recording = Recording::open(dir).unwrap();
    let times: BTreeMap<u32, u64> = recording.poses.iter().map(|row| (row.frame, (row.t_s * 1e6).round() as u64)).collect();
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
    let mut scans = BTreeMap::new();
    detector
        .run(&recording, |outcome, pipeline| {
            if let FrameOutcome::Report { report, .. } = outcome {
                scans.insert(times[&report.frame], *pipeline.gpa().scan());
            }
        })
        .unwrap();
    (scans, times.into_iter().map(|(frame, t)| (t, frame)).collect())
}

/// OBSTACLE_DISTANCE as the README documents it, from a scan's sectors:
/// element j holds the sectors centred in [5j - 2.5, 5j + 2.5) degrees.
fn expected(scan: &Scan) -> ([u16; 72], u16, u16) {
    let layout = scan.layout();
    let (min, max) = (layout.range_min_mm / 10, layout.range_max_mm.div_ceil(10));
    let mut groups: BTreeMap<usize, Vec<Sector>> = BTreeMap::new();
    for (k, sector) in scan.sectors().enumerate() {
        let centre_mdeg = layout.angle_start_mdeg() + k as i32 * SCAN_INCREMENT_MDEG;
        let bin = (centre_mdeg + 2500).div_euclid(5000).rem_euclid(72) as usize;
        groups.entry(bin).or_default().push(sector);
    }
    let mut distances = [u16::MAX; 72];
    for (bin, sectors) in groups {
        let nearest = sectors.iter().filter_map(|s| if let Sector::Hazard(mm) = s { Some(*mm) } else { None }).min();
        distances[bin] = match nearest {
            Some(mm) => ((f64::from(mm) / 10.0).round() as u16).clamp(min, max),
            None if sectors.iter().all(|s| *s == Sector::Free) => max + 1,
            None => u16::MAX,
        };
    }
    (distances, min, max)
}

fn obstacle_distances(decoded: &Decoded) -> Vec<&OBSTACLE_DISTANCE_DATA> {
    decoded.messages.iter().filter_map(|(_, m)| if let MavMessage::OBSTACLE_DISTANCE(o) = m { Some(o) } else { None }).collect()
}

/// Checks a run against the host: one OBSTACLE_DISTANCE per pose, equal to
/// the host's scan field for field (all unknown where the host compared
/// nothing); returns how many carried a scan.
fn check_against_host(name: &str, dir: &Path, decoded: &Decoded) -> usize {
    assert!(decoded.errors.is_empty(), "{name}: {:?}", decoded.errors);
    let (scans, frames) = host_scans(dir);
    let messages = obstacle_distances(decoded);
    assert_eq!(messages.len(), frames.len(), "{name}: one OBSTACLE_DISTANCE per pose");
    let mut compared = 0;
    for message in messages {
        let frame = frames[&message.time_usec];
        assert_eq!((message.increment_f, message.increment, message.angle_offset), (5.0, 5, 0.0), "{name} frame {frame}");
        assert_eq!(message.frame, MavFrame::MAV_FRAME_BODY_FRD);
        match scans.get(&message.time_usec) {
            Some(scan) => {
                let (distances, min, max) = expected(scan);
                assert_eq!((message.min_distance, message.max_distance), (min, max), "{name} frame {frame}");
                assert_eq!(message.distances, distances, "{name} frame {frame}");
                compared += 1;
            }
            None => assert!(message.distances.iter().all(|&d| d == u16::MAX), "{name} frame {frame}: nothing compared, all unknown"),
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
    for name in RECORDINGS {
        let dir = common::data(name);
        let recording = Recording::open(&dir).unwrap();
        let (decoded, log) = run(&dir, qemu::mavlink_script(&recording, PoseMessages::Odometry).unwrap());
        compared += check_against_host(name, &dir, &decoded);
        let states = heartbeats(&decoded);
        assert_eq!(states.first(), Some(&MavState::MAV_STATE_STANDBY), "{name}");
        assert!(states.contains(&MavState::MAV_STATE_ACTIVE), "{name}: {states:?}");
        assert!(end_text(&decoded).starts_with(&format!("end f{} g0 c0 u0 b0", recording.poses.len())), "{name}: {}\n{log}", end_text(&decoded));
    }
    assert!(compared > 150, "{compared}");
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

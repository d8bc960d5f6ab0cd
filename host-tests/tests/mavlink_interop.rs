//! core's MAVLink decoder reads what the reference implementation writes:
//! the fuzz seeds in host-tests/fuzz/seeds/mavlink were packed by pymavlink
//! (host-tests/tools/mavlink_seeds.py, which says what each holds), and
//! each message converts to the pose the script describes, at poses.csv's
//! resolution (0.01 mm, 0.0001 degree). The other direction, pymavlink
//! reading the firmware, is in firmware_mavlink.rs.

use std::path::Path;

use flatland_core::mavlink::{sample_from_local_position, sample_from_odometry, FrameDecoder, Inbound};
use flatland_core::pipeline::PoseSample;
use mavlink::dialects::common::ATTITUDE_DATA;

fn seed(name: &str) -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds/mavlink").join(name)).unwrap()
}

/// Every message of `bytes`, checking that nothing was refused.
fn read_all(bytes: &[u8]) -> Vec<Inbound> {
    let mut decoder = FrameDecoder::new();
    let messages = bytes.iter().filter_map(|&b| decoder.push(b)).map(|m| m.unwrap()).collect();
    let stats = decoder.stats();
    assert_eq!((stats.garbage_bytes, stats.checksum, stats.foreign), (0, 0, 0), "{stats:?}");
    messages
}

/// `got` is `want` rounded to `resolution` (f32 transport included).
fn assert_rounded(got: f64, want: f64, resolution: f64, what: &str) {
    assert!((got - want).abs() <= resolution / 2.0 + 1e-6 * resolution, "{what}: {got} vs {want}");
}

/// Step `i`: z (north) `100 i` mm, x (east) `east_mm i`, yaw `-heading_deg i`
/// (heading is clockwise, RECORDING.md's yaw positive left).
fn assert_pose(sample: &PoseSample, i: u32, east_mm: f64, heading_deg: f64) {
    let i = f64::from(i);
    assert_rounded(sample.t_s, 0.1 * i, 1e-6, "t_s");
    let pose = sample.pose.unwrap();
    assert_rounded(pose.z_mm, 100.0 * i, 0.01, "z_mm");
    assert_rounded(pose.x_mm, east_mm * i, 0.01, "x_mm");
    assert_rounded(pose.yaw_deg, -heading_deg * i, 1e-4, "yaw_deg");
}

#[test]
fn core_reads_pymavlinks_odometry() {
    let messages = read_all(&seed("odometry.bin"));
    assert_eq!(messages.len(), 3);
    for (i, message) in (0..).zip(&messages) {
        let Inbound::Odometry(odometry) = message else { panic!("{message:?}") };
        let sample = sample_from_odometry(odometry).unwrap();
        assert_pose(&sample, i, 2.0, 1.5);
        let attitude = sample.attitude.unwrap();
        assert_eq!((attitude.pitch_deg, attitude.roll_deg), (0.0, 0.0));
    }
}

#[test]
fn core_reads_pymavlinks_local_position_and_attitude() {
    let messages = read_all(&seed("local_position.bin"));
    assert_eq!(messages.len(), 7);
    assert!(matches!(messages[0], Inbound::Heartbeat { system_id: 1, component_id: 1 }), "{:?}", messages[0]);
    let mut attitude: Option<&ATTITUDE_DATA> = None;
    let mut samples = Vec::new();
    for message in &messages[1..] {
        match message {
            Inbound::Attitude(latest) => attitude = Some(latest),
            Inbound::LocalPosition(position) => samples.push(sample_from_local_position(position, attitude.unwrap()).unwrap()),
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(samples.len(), 3);
    // Rolled 0.01 rad right side down, pitched 0.02 rad nose down, level.
    let tilts = [(0.0, 0.01f32), (0.02f32, 0.0), (0.0, 0.0)];
    for ((i, sample), (pitch_rad, roll_rad)) in (0..).zip(&samples).zip(tilts) {
        assert_pose(sample, i, 3.0, 2.0);
        let attitude = sample.attitude.unwrap();
        assert_rounded(attitude.pitch_deg, f64::from(pitch_rad).to_degrees(), 1e-4, "pitch_deg");
        assert_rounded(attitude.roll_deg, f64::from(roll_rad).to_degrees(), 1e-4, "roll_deg");
    }
}

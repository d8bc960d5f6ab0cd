//! Parity: the firmware in QEMU gives exactly the csv of `flatland detect`
//! on the same recording, field for field (the same core, the same integers),
//! also without odometry (`cargo fw --odometry none` against `flatland
//! detect --odometry none`).
//! Needs qemu-system-arm and defmt-print (`.ci/ensure-tools`); fails, never
//! skips, without them.

mod common;

use common::*;
use flatland_core::report::CSV_HEADER;
use flatland_host::qemu::Sensors;

/// `$FLODO` with the time (and IMU attitude, if any) alone.
const WITHOUT_ODOMETRY: Sensors = Sensors { odometry: false, imu: true };

fn parity(name: &str) {
    parity_with(name, Sensors::ALL);
}

fn parity_with(name: &str, sensors: Sensors) {
    let dir = data(name);
    let expected = detect_csv_with(&dir, sensors);
    let outcome = run(&dir, script_with(&dir, sensors));
    let (csv, summary) = decoded(&outcome);
    assert!(summary.frame_faults.is_empty(), "{name}: firmware skipped frames: {:?}", summary.frame_faults);
    // A row-level diff names the first differing frame and field.
    for (n, (got, want)) in csv.lines().zip(expected.lines()).enumerate() {
        if got != want {
            let header: Vec<&str> = CSV_HEADER.split(',').collect();
            let fields = got.split(',').zip(want.split(',')).enumerate().find(|(_, (g, w))| g != w);
            let column = fields.map_or("?", |(i, _)| header.get(i).copied().unwrap_or("?"));
            panic!("{name}: line {} differs in {column}:\n firmware: {got}\n detect:   {want}", n + 1);
        }
    }
    assert_eq!(csv.lines().count(), expected.lines().count(), "{name}: row counts differ\n{csv}\nvs\n{expected}");
    assert!(expected.lines().count() > 1, "{name}: detect produced no rows; nothing was compared");
    let stats = summary.stats.expect("the firmware sends $FLSTA");
    let frames = std::fs::read_dir(dir.join("frames")).expect("frames").count() as u32;
    assert_eq!(stats.frame_loop.frames, frames, "{name}: every frame processed");
    assert_eq!((stats.frame_loop.frame_gaps, stats.frame_loop.aborted, stats.decoder.garbage_bytes, stats.decoder.bad_checksum), (0, 0, 0, 0), "{name}: {stats:?}");
}

#[test]
fn parity_flat_marks() {
    parity("flat_marks");
}

#[test]
fn parity_stool_bags() {
    parity("stool_bags");
}

#[test]
fn parity_turn() {
    parity("turn");
}

#[test]
fn parity_qvga_curb() {
    parity("qvga_curb");
}

#[test]
fn parity_diagonal() {
    parity("diagonal");
}

#[test]
fn parity_noisy_marks() {
    parity("noisy_marks");
}

#[test]
fn parity_approach_box() {
    parity("approach_box");
}

#[test]
fn parity_noisy_approach() {
    parity("noisy_approach");
}

#[test]
fn parity_flat_marks_without_odometry() {
    parity_with("flat_marks", WITHOUT_ODOMETRY);
}

#[test]
fn parity_approach_box_without_odometry() {
    parity_with("approach_box", WITHOUT_ODOMETRY);
}

#[test]
fn parity_bumpy_marks() {
    parity("bumpy_marks");
}

#[test]
fn parity_bumpy_marks_imu_only() {
    parity_with("bumpy_marks", WITHOUT_ODOMETRY);
}

#[test]
fn parity_bumpy_marks_without_imu() {
    parity_with("bumpy_marks", Sensors { odometry: true, imu: false });
}

#[test]
fn parity_bumpy_approach() {
    parity("bumpy_approach");
}

#[test]
fn parity_exposure_rolling() {
    parity("exposure_rolling");
}

#[test]
fn parity_slip() {
    parity("slip");
}

/// Issue 14: a drop's alarm, negative obstacle_h_mm through the protocol.
#[test]
fn parity_ledge() {
    parity("ledge");
}

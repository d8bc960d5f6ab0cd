//! The polar obstacle scan on the bundled recordings: it agrees with the
//! report, claims nothing outside the camera's view, and is clear where the
//! floor is. `flatland scan` and `flatland detect --format json` carry it.

use std::process::Command;

use flatland_core::grid::KgGrid;
use flatland_core::report::FrameReport;
use flatland_core::scan::{Scan, Sector, SCAN_INCREMENT_MDEG};
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::recording::Recording;

mod common;
use common::{bundled, data};


/// Every compared (judged) frame's report and scan, and the grid.
fn scans(name: &str) -> (Vec<(FrameReport, Scan)>, KgGrid) {
    let recording = Recording::open(data(name)).unwrap();
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
    let mut out = Vec::new();
    detector
        .run(&recording, |outcome, pipeline| match outcome {
            FrameOutcome::Report { report, .. } if report.is_judged() => {
                assert_eq!(pipeline.gpa().scan().frame(), report.frame);
                out.push((report, *pipeline.gpa().scan()));
            }
            _ => {}
        })
        .unwrap();
    (out, detector.grid())
}

/// Sector `k`'s edges, degrees.
fn edges(scan: &Scan, k: usize) -> (f64, f64) {
    let increment = f64::from(SCAN_INCREMENT_MDEG) / 1000.0;
    let first = (k as f64 - (scan.len() / 2) as f64) * increment;
    (first, first + increment)
}

/// The report's obstacle is in the scan: every sector its footprint line
/// crosses reads no farther than the line, and straight ahead of an
/// obstacle that spans x = 0 the scan's reading is the report's nearest_mm.
#[test]
fn scan_agrees_with_the_report() {
    let mut ahead = 0;
    for name in bundled() {
        let (frames, _) = scans(&name);
        for (report, scan) in &frames {
            let (Some(near), Some(left), Some(right)) = (report.nearest_mm, report.left_mm, report.right_mm) else {
                assert!(!report.alarm);
                continue;
            };
            let hazard = |k: usize| match scan.sector(k) {
                Sector::Hazard(range) => Some(i32::from(range)),
                _ => None,
            };
            for k in 0..scan.len() {
                let (a0, a1) = edges(scan, k);
                let (x0, x1) = (f64::from(near) * a0.to_radians().tan(), f64::from(near) * a1.to_radians().tan());
                if x1 <= f64::from(left) || x0 >= f64::from(right) {
                    continue;
                }
                let x = 0f64.clamp(x0.max(f64::from(left)), x1.min(f64::from(right)));
                let line = f64::from(near).hypot(x).round() as i32;
                let reading = hazard(k);
                assert!(reading.is_some_and(|r| r <= line), "{name} frame {}: sector {k} reads {reading:?}, the report's line {line}", report.frame);
            }
            if left <= 0 && right >= 0 {
                let forward = [hazard(scan.len() / 2 - 1), hazard(scan.len() / 2)];
                assert_eq!(forward.iter().flatten().min(), Some(&near), "{name} frame {}: {forward:?}", report.frame);
                ahead += 1;
            }
        }
    }
    assert!(ahead > 50, "only {ahead} frames with an obstacle ahead");
}

/// A sector is free only where the KG grid holds its ground out to the
/// scan's range; the outermost sectors, beyond the grid, never are (a
/// hazard near enough to be seen there is still reported).
#[test]
fn sectors_outside_the_view_are_unknown() {
    for name in bundled() {
        let (frames, grid) = scans(&name);
        let (x_left, _) = grid.pixel_to_ground(0.0, 0.0);
        let (x_right, _) = grid.pixel_to_ground(grid.width() as f64, 0.0);
        for (report, scan) in &frames {
            let range = f64::from(scan.layout().range_max_mm);
            for k in 0..scan.len() {
                let (a0, a1) = edges(scan, k);
                let inside = range * a0.to_radians().sin() >= x_left && range * a1.to_radians().sin() <= x_right;
                if !inside {
                    assert!(!matches!(scan.sector(k), Sector::Free), "{name} frame {}: sector {k} free outside the view", report.frame);
                }
            }
            for k in [0, scan.len() - 1] {
                assert_ne!(scan.sector(k), Sector::Free, "{name} frame {}", report.frame);
            }
        }
    }
}

/// On the floors without hazards (truth.toml lists no obstacle or drop) every sector is
/// free or unknown, the free ones one block straight ahead, at least 20
/// degrees wide.
#[test]
fn clear_frames_are_free_within_view() {
    let clear: Vec<String> = bundled()
        .into_iter()
        .filter(|name| Recording::open(data(name)).unwrap().truth.is_some_and(|truth| truth.obstacle.is_empty() && truth.drop.is_empty()))
        .collect();
    assert!(clear.len() >= 3, "{clear:?}");
    for name in clear {
        let (frames, _) = scans(&name);
        assert!(!frames.is_empty());
        for (report, scan) in &frames {
            assert!(!report.alarm, "{name} frame {}", report.frame);
            let free: Vec<usize> = (0..scan.len()).filter(|&k| scan.sector(k) == Sector::Free).collect();
            let hazards = scan.sectors().filter(|s| matches!(s, Sector::Hazard(_))).count();
            assert_eq!(hazards, 0, "{name} frame {}", report.frame);
            assert!(free.len() * SCAN_INCREMENT_MDEG as usize >= 20_000, "{name} frame {}: {free:?}", report.frame);
            assert_eq!(free.last().unwrap() - free.first().unwrap() + 1, free.len(), "{name} frame {}: {free:?}", report.frame);
            assert!(free.contains(&(scan.len() / 2 - 1)) && free.contains(&(scan.len() / 2)), "{name} frame {}: {free:?}", report.frame);
        }
    }
}

fn flatland(args: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(args).output().unwrap();
    assert!(output.status.success(), "{args:?}: {}", String::from_utf8_lossy(&output.stderr));
    String::from_utf8(output.stdout).unwrap()
}

/// `flatland scan` prints a row per compared frame in the documented form,
/// and `detect --format json` carries the same readings.
#[test]
fn cli_prints_the_scan() {
    let dir = data("approach_box");
    let dir = dir.to_str().unwrap();
    let (frames, _) = scans("approach_box");
    let csv = flatland(&["scan", dir]);
    let mut lines = csv.lines();
    let header = lines.next().unwrap();
    let sectors = frames[0].1.len();
    let names: Vec<String> = (0..sectors).map(|k| format!("d{k}_mm")).collect();
    assert_eq!(header, format!("frame,angle_start_deg,increment_deg,{}", names.join(",")));
    let json = flatland(&["detect", dir, "--format", "json"]);
    let json_rows: Vec<&str> = json.lines().collect();
    assert_eq!(json_rows.len(), frames.len());
    for ((line, (report, scan)), json) in lines.zip(&frames).zip(json_rows) {
        let fields: Vec<&str> = line.split(',').collect();
        assert_eq!(fields.len(), 3 + sectors, "{line}");
        assert_eq!(fields[0], report.frame.to_string());
        assert_eq!(fields[1], format!("{:.3}", f64::from(scan.layout().angle_start_mdeg()) / 1000.0));
        assert_eq!(fields[2], "2.500");
        let mut readings = Vec::new();
        for (field, sector) in fields[3..].iter().zip(scan.sectors()) {
            let (csv_field, json_field) = match sector {
                Sector::Unknown => (String::new(), "null".to_string()),
                Sector::Free => ("inf".to_string(), "\"inf\"".to_string()),
                Sector::Hazard(range) => (range.to_string(), range.to_string()),
            };
            assert_eq!(*field, csv_field, "{line}");
            readings.push(json_field);
        }
        assert!(json.contains(&format!("\"ranges_mm\":[{}]", readings.join(","))), "{json}");
    }
}

/// Each recording's stream as the MAVLink build sends it (the scan of every
/// judged frame, doubt for the others), read in order by ArduPilot and both
/// PX4 readers, which keep state between messages as their code does
/// (`flatland_host::link::autopilot`): after each judged frame every reader holds
/// every hazard at its distance or nearer and no element sits at
/// max_distance; after each other frame every reader holds an obstacle at
/// the nearest range wherever the camera looks. The firmware's stream is
/// these messages (firmware_mavlink.rs compares them field for field).
#[test]
fn every_autopilot_reads_every_hazard() {
    use flatland_core::mavlink::{obstacle_distance, obstacle_distance_in_doubt};
    use flatland_host::link::autopilot::{hazards, Readers};
    let (mut checked, mut doubts) = (0, 0);
    for name in bundled() {
        let recording = Recording::open(data(&name)).unwrap();
        let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap();
        let mut readers = Readers::default();
        detector
            .run(&recording, |outcome, pipeline| {
                let scan = pipeline.gpa().scan();
                match outcome {
                    FrameOutcome::Report { report, .. } if report.is_judged() => {
                        let message = obstacle_distance(scan, 0);
                        readers.read(&message);
                        let problems = readers.lost_hazards(&message, scan);
                        assert!(problems.is_empty(), "{name} frame {}: {problems:?}", report.frame);
                        checked += hazards(scan);
                    }
                    FrameOutcome::Report { .. } | FrameOutcome::Keyframe { .. } => {
                        let message = obstacle_distance_in_doubt(&scan.layout(), 0);
                        readers.read(&message);
                        let released = readers.released(&scan.layout(), message.min_distance);
                        assert!(released.is_empty(), "{name}: a frame not judged releases {released:?}");
                        doubts += 1;
                    }
                    FrameOutcome::Skipped { .. } => {}
                }
            })
            .unwrap();
    }
    println!("{checked} hazard sectors read whole by every autopilot; {doubts} frames of doubt held every reader back");
    assert!(checked > 100, "the recordings hold hazards: {checked}");
    assert!(doubts >= bundled().len(), "every run starts with a keyframe: {doubts}");
}

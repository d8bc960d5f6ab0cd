//! Firmware robustness in QEMU (issue 7, firmware part): damaged serial
//! input, a frame source that stops mid-frame, gaps in frames and poses,
//! rigs that do not fit. Each run must end with exit 0 and no panic (checked
//! by `common::run`), count what it refused, and still match `flatland detect`.

mod common;

use common::*;
use flatland_core::gpa::Gpa;
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::protocol::{checksum, encode_line, FaultCode, Message, Odometry, RigRecord};
use flatland_host::qemu::{self, Sensors};
use flatland_host::recording::Recording;

/// A line with a correct checksum around `body`.
fn line(body: &str) -> Vec<u8> {
    format!("${body}*{:02X}\r\n", checksum(body.as_bytes())).into_bytes()
}

/// The csv rows (frame, status) whose status is not `ok`.
fn not_judged(csv: &str) -> Vec<(u32, String)> {
    csv.lines()
        .skip(1)
        .filter_map(|l| {
            let status = l.rsplit(',').next()?;
            (status != "ok").then(|| (l.split(',').next().unwrap().parse().unwrap(), status.to_string()))
        })
        .collect()
}

/// `frame` restarted the keyframe after a gap: its row says so, alarm asserted.
fn after_gap_row(frame: u32) -> String {
    format!("{frame},{frame},1,,,,0,0,0.00,0.00,0.0,0.0,,0.000,0.000,0.000,,after_gap")
}

#[test]
fn garbage_truncated_and_oversized_serial_input_is_counted_not_fatal() {
    let dir = data("stool_bags");
    let mut script = b"\x00\xffnoise".to_vec(); // 7 garbage bytes before the rig
    for (n, message) in messages(&dir).iter().enumerate() {
        if n == 2 {
            script.extend_from_slice(b"$FLODO,2,0.2,0,"); // cut short by the next `$`
            script.extend_from_slice(&line(&format!("FL{}", "A".repeat(600)))); // over MAX_LINE
            script.extend_from_slice(b"$FLEND*00\r\n"); // wrong checksum
            script.extend_from_slice(&line("FLXYZ,1")); // unknown type
            script.extend_from_slice(&line("FLODO,3,0.3,x,0,0")); // bad field
            script.extend_from_slice(&line("FLODO,3,0.3,0,0,0,0")); // 6 fields: neither 5 nor 7
            script.extend_from_slice(&line("FLRDY,9")); // wrong version
            // A well-formed message out of place: the host sending a report.
            script.extend_from_slice(encode_line(&Message::Frame(Default::default())).unwrap().as_bytes());
            script.extend_from_slice(b"\r\n\r\nzz"); // blank lines are fine, `zz` is garbage
        }
        script.extend_from_slice(encode_line(message).unwrap().as_bytes());
    }
    let outcome = run(&dir, script);
    let (csv, summary) = decoded(&outcome);
    assert_eq!(csv, detect_csv(&dir), "damaged lines between good ones change nothing");
    let stats = summary.stats.expect("$FLSTA");
    assert_eq!(stats.decoder.garbage_bytes, 9, "{stats:?}");
    assert_eq!(stats.decoder.truncated, 1, "{stats:?}");
    assert_eq!(stats.decoder.too_long, 1, "{stats:?}");
    assert_eq!(stats.decoder.bad_checksum, 1, "{stats:?}");
    assert_eq!(stats.decoder.unknown_type, 1, "{stats:?}");
    assert_eq!(stats.decoder.bad_field, 3, "{stats:?}");
    assert_eq!(stats.frame_loop.out_of_order, 1, "{stats:?}");
    assert_eq!((stats.frame_loop.frame_gaps, stats.frame_loop.aborted), (0, 0), "{stats:?}");
}

#[test]
fn input_that_ends_early_or_is_all_garbage_ends_the_run_cleanly() {
    let dir = data("flat_marks");
    // No rig at all: random bytes (no `$`), then the end.
    let mut script: Vec<u8> = (0..5000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).filter(|&b| b != b'$').collect();
    let noise = script.iter().filter(|&&b| b != b'\r' && b != b'\n').count() as u32;
    script.extend_from_slice(encode_line(&Message::End).unwrap().as_bytes());
    let outcome = run(&dir, script);
    let stats = outcome.serial.stats.expect("$FLSTA");
    assert_eq!((stats.frame_loop.frames, stats.decoder.garbage_bytes), (0, noise), "{stats:?}");
}

#[test]
fn frame_source_that_stops_mid_frame_is_abandoned_and_reported() {
    let copy = TempRecording::copy_of("stool_bags", "midframe");
    // Frame 3 stops halfway through its rows; frame 5 inside its header.
    let bytes = std::fs::read(copy.frame(3)).unwrap();
    std::fs::write(copy.frame(3), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(copy.frame(5), &bytes[..7]).unwrap();
    let outcome = run(&copy.dir, script(&copy.dir));
    let (csv, summary) = decoded(&outcome);
    assert_eq!(csv, detect_csv(&copy.dir), "the firmware skips what detect skips");
    let codes: Vec<(FaultCode, u32)> = faults(&outcome).iter().map(|f| (f.code, f.frame)).collect();
    assert_eq!(codes, [(FaultCode::FrameRead, 3), (FaultCode::FrameRead, 5)]);
    let stats = summary.stats.expect("$FLSTA");
    assert_eq!(stats.frame_loop.aborted, 1, "only frame 3 stopped mid-frame: {stats:?}");
    assert_eq!(stats.frame_loop.frame_gaps, 2, "frames 4 and 6 restart the keyframe: {stats:?}");
    // Reports before the break stand; the frames after each break restart
    // the keyframe, and their rows say so.
    assert_eq!(row_frames(&csv), [1, 2, 4, 6, 7], "{csv}");
    for frame in [4, 6] {
        assert!(csv.lines().any(|l| l == after_gap_row(frame)), "frame {frame}: {csv}");
    }
    assert_eq!(not_judged(&csv).len(), 2, "{csv}");
}

#[test]
fn gaps_in_frames_poses_or_time_reset_the_keyframe() {
    let copy = TempRecording::copy_of("approach_box", "gaps");
    // Frame 10's file is missing, frame 20 has no pose, frame 30's time goes backwards.
    std::fs::remove_file(copy.frame(10)).unwrap();
    let poses = std::fs::read_to_string(copy.dir.join("poses.csv")).unwrap();
    let poses: String = poses
        .lines()
        .filter(|l| !l.starts_with("20,"))
        .map(|l| if l.starts_with("30,") { l.replacen(",3.000,", ",2.850,", 1) } else { l.to_string() })
        .map(|l| l + "\n")
        .collect();
    assert!(poses.contains("30,2.850,"), "poses.csv layout changed: {poses}");
    std::fs::write(copy.dir.join("poses.csv"), poses).unwrap();

    let outcome = run(&copy.dir, script(&copy.dir));
    let (csv, summary) = decoded(&outcome);
    assert_eq!(csv, detect_csv(&copy.dir), "the firmware resets where detect resets");
    let codes: Vec<(FaultCode, u32)> = faults(&outcome).iter().map(|f| (f.code, f.frame)).collect();
    assert_eq!(codes, [(FaultCode::FrameMissing, 10)]);
    let stats = summary.stats.expect("$FLSTA");
    assert_eq!(stats.frame_loop.frame_gaps, 3, "frames 11, 21 and 31 restart the keyframe (30 is skipped): {stats:?}");
    let rows = row_frames(&csv);
    for lost in [10, 20, 30] {
        assert!(!rows.contains(&lost), "frame {lost} was not processed: {csv}");
    }
    // The frames after them had no keyframe to compare with, and say so.
    for restarted in [11, 21, 31] {
        assert!(csv.lines().any(|l| l == after_gap_row(restarted)), "frame {restarted}: {csv}");
    }
    let expected: Vec<(u32, String)> = [11, 21, 31].map(|frame| (frame, "after_gap".to_string())).to_vec();
    assert_eq!(not_judged(&csv), expected, "{csv}");
    // After each restart the reference is never older than the gap.
    for line in csv.lines().skip(1) {
        let fields: Vec<u32> = line.split(',').take(2).map(|f| f.parse().unwrap()).collect();
        let (frame, reference) = (fields[0], fields[1]);
        for gap in [11, 21, 30] {
            assert!(!(frame > gap && reference < gap), "frame {frame} compared across the gap at {gap}");
        }
    }
}

#[test]
fn odometry_out_of_sequence_on_the_wire_resets_the_keyframe() {
    // The poses arrive with one frame's message lost on the link, and one
    // duplicated: no report may compare across the loss, with or without
    // the wheels' fields (a robot without odometry has gaps too).
    let dir = data("flat_marks");
    for odometry in [true, false] {
        let mut script = Vec::new();
        for message in messages_with(&dir, Sensors { odometry, imu: true }) {
            if let Message::Odometry(Odometry { frame: 4, .. }) = message {
                continue;
            }
            script.extend_from_slice(encode_line(&message).unwrap().as_bytes());
            if let Message::Odometry(Odometry { frame: 6, .. }) = message {
                script.extend_from_slice(encode_line(&message).unwrap().as_bytes());
            }
        }
        let outcome = run(&dir, script);
        let (csv, summary) = decoded(&outcome);
        // 5 follows 3 and the repeated 6 follows 6: both restart (and say
        // so: rows not judged); 7 follows 6 again.
        assert_eq!(row_frames(&csv), [1, 2, 3, 5, 6, 6, 7], "odometry {odometry}: {csv}");
        let restarted: Vec<&str> = csv.lines().filter(|l| l.ends_with(",after_gap")).collect();
        assert_eq!(restarted, [after_gap_row(5), after_gap_row(6)], "odometry {odometry}: {csv}");
        assert_eq!(not_judged(&csv).len(), 2, "odometry {odometry}: {csv}");
        if odometry {
            let judged = csv.lines().skip(1).filter(|l| l.ends_with(",ok"));
            assert!(judged.clone().count() == 5 && judged.clone().all(|l| l.split(',').nth(2) == Some("0")), "no false alarm: {csv}");
        }
        let stats = summary.stats.expect("$FLSTA");
        assert_eq!(stats.frame_loop.frame_gaps, 2, "odometry {odometry}: frame 5 and the repeated 6: {stats:?}");
    }
}

#[test]
fn rig_that_does_not_fit_the_target_is_refused_with_a_typed_fault() {
    // A default grid always fits the board's images (it coarsens until it
    // does), so the QVGA rig at a fixed resolution too fine for them, the
    // firmware's `mm_per_px=` option; a valid rig, so only the capacity
    // refuses it. Then a camera wider than the board's rows.
    const IMAGE_CAPACITY: usize = 40_000; // firmware/src/frame_loop.rs
    const TOO_FINE_MM: f64 = 3.5;
    let base = Recording::open(data("qvga_curb")).unwrap();
    let fine = GridConfig { mm_per_px: Some(TOO_FINE_MM), ..GridConfig::default() };
    let grid = KgGrid::for_rig(&base.rig, &fine).unwrap();
    assert!(Gpa::image_bytes(&grid) > IMAGE_CAPACITY, "{}x{} fits", grid.width, grid.height);
    assert!(Gpa::image_bytes(&KgGrid::for_rig(&base.rig, &GridConfig::default()).unwrap()) <= IMAGE_CAPACITY);
    let mut too_wide = RigRecord::from(&base.rig);
    too_wide.camera.width = 800;
    too_wide.camera.cx = 399.5;
    let script = qemu::encode_script(&[Message::Rig(RigRecord::from(&base.rig)), Message::Rig(too_wide), Message::End]).unwrap();
    let outcome = run_at_resolution(&data("qvga_curb"), script, TOO_FINE_MM);
    let codes: Vec<FaultCode> = faults(&outcome).iter().map(|f| f.code).collect();
    assert_eq!(codes, [FaultCode::GridTooLarge, FaultCode::CameraTooLarge], "{}", outcome.log);
    assert!(!outcome.serial.messages.iter().any(|m| matches!(m, Message::Hello(_))), "nothing was accepted");
}

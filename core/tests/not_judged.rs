//! Issue 33: every frame after the first is judged or says why not. A
//! floor without texture gives the motion estimate nothing to measure;
//! without odometry to fall back on, the frame cannot be judged: GPA
//! reports it not judged (`no_motion`), alarm asserted, against the
//! keyframe it tried, and restarts the keyframe from it.

mod common;

use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::motion::Motion;
use flatland_core::remap::RemapTable;
use flatland_core::report::{FrameReport, NotJudged, Status};

/// Uniform gray frames (the KG rows directly) with each frame's odometry;
/// each frame's report, and whether GPA then has a measured step.
fn run(odometry: &[Option<Motion>]) -> Vec<(Option<FrameReport>, bool)> {
    let rig = common::flat_marks_rig(256);
    let grid = KgGrid::for_rig(&rig, &GridConfig::default()).expect("grid");
    let table = RemapTable::new(&rig, &grid).expect("table");
    let mut images = vec![0u8; Gpa::keyframe_bytes(&grid)];
    let mut gpa = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut images).expect("gpa");
    let row = vec![128u8; grid.width()];
    odometry
        .iter()
        .enumerate()
        .map(|(frame, &motion)| {
            gpa.begin_frame(frame as u32, motion, None);
            for j in 0..grid.height() {
                gpa.on_kg_row(j, &row);
            }
            let report = gpa.end_frame();
            (report, gpa.measured_step().is_some())
        })
        .collect()
}

#[test]
fn a_floor_without_texture_and_no_odometry_is_not_judged() {
    let frames = run(&[None, None, None]);
    assert_eq!(frames[0], (None, false), "the first frame only starts the keyframe");
    for (frame, (report, measured)) in frames.iter().enumerate().skip(1) {
        let frame = frame as u32;
        let report = report.unwrap_or_else(|| panic!("frame {frame}: no report, the frame was silent"));
        assert_eq!(report.status, Status::NotJudged(NotJudged::NoMotion), "frame {frame}");
        assert!(report.alarm, "frame {frame}: not judged must assert the alarm");
        assert_eq!((report.nearest_mm, report.left_mm, report.right_mm), (None, None, None), "frame {frame}");
        // It tried the keyframe before it, and restarted the keyframe from itself.
        assert_eq!((report.frame, report.ref_frame), (frame, frame - 1));
        assert_eq!(report, FrameReport::not_judged(frame, frame - 1, NotJudged::NoMotion));
        assert!(!measured, "frame {frame}: no step was measured");
    }
}

/// The same floor with odometry: the odometry stands in for the failed
/// estimate, and the frame is judged.
#[test]
fn with_odometry_the_same_floor_is_judged() {
    let still = Some(Motion::default());
    let frames = run(&[None, still, still]);
    for (frame, (report, _)) in frames.iter().enumerate().skip(1) {
        let report = report.unwrap_or_else(|| panic!("frame {frame}: no report"));
        assert_eq!(report.status, Status::Ok, "frame {frame}");
        assert!(!report.alarm, "frame {frame}: a uniform floor is clear");
    }
}

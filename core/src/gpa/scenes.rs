//! Rendered scenes through the whole detector: a floor that falls away.

use super::row::tests::{rig, texture};
use super::{Gpa, GpaConfig};
use crate::grid::{GridConfig, KgGrid};
use crate::motion::{Motion, Pose};
use crate::remap::RemapTable;
use crate::report::FrameReport;

/// World z of the floor's last edge; the lower level lies past it.
const EDGE_Z_MM: f64 = 1600.0;

/// The KG image seen from `pose` (driving along z) of a floor that drops
/// by `drop_mm` past [`EDGE_Z_MM`]. A ray that passes the edge meets the
/// lower level at (H + d) / H of its apparent ground distance.
fn ledge_image(grid: &KgGrid, table: &RemapTable, pose: &Pose, camera_height_mm: f64, drop_mm: f64) -> std::vec::Vec<u8> {
    let mut image = std::vec![0u8; grid.len()];
    for j in 0..grid.height() {
        for i in table.valid_columns(j) {
            let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
            let value = if pose.z_mm + z < EDGE_Z_MM {
                texture(pose.x_mm + x, pose.z_mm + z)
            } else {
                let scale = (camera_height_mm + drop_mm) / camera_height_mm;
                texture(pose.x_mm + x * scale, pose.z_mm + z * scale)
            };
            image[j * grid.width() + i] = value;
        }
    }
    image
}

/// Frames driven towards the ledge: its edge goes from 1600 to 600 mm ahead.
const FRAMES: u32 = 21;

/// How far ahead the edge is at `frame`.
fn edge_ahead_mm(frame: u32) -> f64 {
    EDGE_Z_MM - 50.0 * f64::from(frame)
}

/// Drives 50 mm a frame towards a ledge `drop_mm` deep; the reports.
fn drive_to_ledge(drop_mm: f64) -> std::vec::Vec<FrameReport> {
    let rig = rig();
    let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
    let table = RemapTable::new(&rig, &grid).unwrap();
    let mut keyframe = std::vec![0u8; Gpa::keyframe_bytes(&grid)];
    let mut gpa = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut keyframe).unwrap();
    let mut reports = std::vec::Vec::new();
    let step = Motion { tx_mm: 0.0, tz_mm: 50.0, dyaw_deg: 0.0 };
    for n in 0..FRAMES {
        let pose = Pose { x_mm: 0.0, z_mm: 50.0 * f64::from(n), yaw_deg: 0.0 };
        let image = ledge_image(&grid, &table, &pose, rig.height_mm(), drop_mm);
        gpa.begin_frame(n, (n > 0).then_some(step), None);
        for (j, row) in image.chunks_exact(grid.width()).enumerate() {
            gpa.on_kg_row(j, row);
        }
        reports.extend(gpa.end_frame());
    }
    reports
}

/// A 25 mm drop, just past the 20 mm limit, raises the alarm on every
/// frame from 1200 mm on (the AOI reaches 1400), at its edge (within 5 %)
/// and with its depth as a negative height.
///
/// A knife-edge by design: at H = 400 mm it lags T*d/(H+d) = 5.9 mm after
/// a 100 mm baseline, about one pixel, of which the ground's tolerance
/// takes half (README, GPA: Limits).
#[test]
fn drop_of_25_mm_raises_the_alarm() {
    let reports = drive_to_ledge(25.0);
    for report in &reports {
        let edge = edge_ahead_mm(report.frame);
        assert!(report.alarm || edge > 1200.0, "frame {}: no alarm with the edge {edge} mm ahead: {reports:?}", report.frame);
        if !report.alarm {
            continue;
        }
        let near = f64::from(report.nearest_mm.unwrap());
        assert!((near - edge).abs() <= 0.05 * edge, "frame {}: {near} vs edge {edge}", report.frame);
        let depth = report.obstacle_h_mm.unwrap();
        assert!((-40..=-20).contains(&depth), "frame {}: height {depth}", report.frame);
    }
}

/// A 10 mm dip is ground: no alarm, no drop cells.
#[test]
fn dip_of_10_mm_is_ground() {
    let reports = drive_to_ledge(10.0);
    assert!(reports.iter().all(|r| !r.alarm), "{reports:?}");
}

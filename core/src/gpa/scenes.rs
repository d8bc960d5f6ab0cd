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

/// Drives 50 mm a frame towards a ledge `drop_mm` deep; the reports.
fn drive_to_ledge(drop_mm: f64) -> std::vec::Vec<FrameReport> {
    let rig = rig();
    let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
    let table = RemapTable::new(&rig, &grid).unwrap();
    let mut keyframe = std::vec![0u8; Gpa::keyframe_bytes(&grid)];
    let mut gpa = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut keyframe).unwrap();
    let mut reports = std::vec::Vec::new();
    let step = Motion { tx_mm: 0.0, tz_mm: 50.0, dyaw_deg: 0.0 };
    for n in 0..12u32 {
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

/// A 25 mm drop, just past the 20 mm limit, raises the alarm at its edge
/// with its depth as a negative height, once the edge is in the AOI.
#[test]
#[ignore = "issue 14: passes today only by an estimate bug, so it is no bound yet. After a frame that takes a lower level, step 6 is skipped and the keyframe attitude's sigma falls back to the prior's (1 deg without an IMU); the next frame's step 6 then puts the drop into the keyframe pitch (1.05 deg, growing to 1.41 along the chain; truth 0), and the biased schedule compares frame 10 over 143 mm instead of 100. Fed the true motion, frame 10 reports 1220 mm against the edge at 1100: at 5.75 mm/px a 25 mm drop lags 1.02 px over a 100 mm baseline, inside the tolerant residue's pixel, so the depth hypotheses are not tried in most cells past the edge. Fixing the sigma (step 6 with the depth as an 8th unknown) moves ledge's droll past the 0.5 deg drop gate under jitter (36 errors, jitter::ledge seed 7 frame 19)"]
fn drop_of_25_mm_raises_the_alarm() {
    let reports = drive_to_ledge(25.0);
    let alarms: std::vec::Vec<_> = reports.iter().filter(|r| r.alarm).collect();
    assert!(alarms.len() >= 5, "{reports:?}");
    for report in alarms {
        let edge = EDGE_Z_MM - 50.0 * f64::from(report.frame);
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


//! Rendered scenes through the whole detector: a floor that falls away
//! (a ledge, a pit with floor beyond it).

use super::row::tests::{rig, texture};
use super::{Gpa, GpaConfig};
use crate::grid::{GridConfig, KgGrid};
use crate::motion::{Motion, Pose};
use crate::remap::RemapTable;
use crate::report::FrameReport;

/// World z where the floor ends ahead: a drop's edge, a pit's near edge.
const EDGE_Z_MM: f64 = 1600.0;

/// The surface along the drive: from each world z on (in order), how far
/// below the floor it lies (mm); the floor before the first.
type Profile<'a> = &'a [(f64, f64)];

/// The brightness of the surface that the ray through apparent ground
/// point (`x`, `z`) meets, seen from `pose` at `camera_height_mm` (H).
/// At depth d the ray reaches the surface at (H + d) / H of its apparent
/// distance; a surface that rises again (a pit's far wall) stops it first.
fn surface(profile: Profile, pose: &Pose, camera_height_mm: f64, x: f64, z: f64) -> u8 {
    let levels = core::iter::once((f64::NEG_INFINITY, 0.0)).chain(profile.iter().copied());
    let ends = profile.iter().map(|&(start, _)| start).chain(core::iter::once(f64::INFINITY));
    for ((start, depth), end) in levels.zip(ends) {
        // The ray's stretch over this level, as multiples of (x, z).
        let (enters, leaves) = (((start - pose.z_mm) / z).max(1.0), (end - pose.z_mm) / z);
        if leaves <= enters {
            continue;
        }
        let meets = (camera_height_mm + depth) / camera_height_mm;
        if enters > meets {
            // Already below this level where it begins: its wall.
            let below_floor = camera_height_mm * (enters - 1.0);
            return texture(pose.x_mm + x * enters, start + 10.0 * below_floor);
        }
        if meets < leaves {
            return texture(pose.x_mm + x * meets, pose.z_mm + z * meets);
        }
    }
    unreachable!("the last level reaches on")
}

/// The KG image of `profile` seen from `pose` (driving along z).
fn scene_image(grid: &KgGrid, table: &RemapTable, pose: &Pose, camera_height_mm: f64, profile: Profile) -> std::vec::Vec<u8> {
    let mut image = std::vec![0u8; grid.len()];
    for j in 0..grid.height() {
        for i in table.valid_columns(j) {
            let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
            image[j * grid.width() + i] = surface(profile, pose, camera_height_mm, x, z);
        }
    }
    image
}

/// Frames driven towards the edge: it goes from 1600 to 600 mm ahead.
const FRAMES: u32 = 21;

/// How far ahead the edge is at `frame`.
fn edge_ahead_mm(frame: u32) -> f64 {
    EDGE_Z_MM - 50.0 * f64::from(frame)
}

/// Drives 50 mm a frame over `profile`; the reports.
fn drive(profile: Profile) -> std::vec::Vec<FrameReport> {
    let rig = rig();
    let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
    let table = RemapTable::new(&rig, &grid).unwrap();
    let mut keyframe = std::vec![0u8; Gpa::keyframe_bytes(&grid)];
    let mut gpa = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut keyframe).unwrap();
    let mut reports = std::vec::Vec::new();
    let step = Motion { tx_mm: 0.0, tz_mm: 50.0, dyaw_deg: 0.0 };
    for n in 0..FRAMES {
        let pose = Pose { x_mm: 0.0, z_mm: 50.0 * f64::from(n), yaw_deg: 0.0 };
        let image = scene_image(&grid, &table, &pose, rig.height_mm(), profile);
        gpa.begin_frame(n, (n > 0).then_some(step), None);
        for (j, row) in image.chunks_exact(grid.width()).enumerate() {
            gpa.on_kg_row(j, row);
        }
        reports.extend(gpa.end_frame());
    }
    reports
}

/// Drives towards a ledge `drop_mm` deep at [`EDGE_Z_MM`].
fn drive_to_ledge(drop_mm: f64) -> std::vec::Vec<FrameReport> {
    drive(&[(EDGE_Z_MM, drop_mm)])
}

/// Every frame from 1200 mm on (the AOI reaches 1400) reports a drop at
/// its edge (within 5 %) with a depth in `depths`.
fn drop_reported(reports: &[FrameReport], depths: core::ops::RangeInclusive<i32>) {
    for report in reports {
        let edge = edge_ahead_mm(report.frame);
        assert!(report.alarm || edge > 1200.0, "frame {}: no alarm with the edge {edge} mm ahead: {reports:?}", report.frame);
        if !report.alarm {
            continue;
        }
        let near = f64::from(report.nearest_mm.unwrap());
        assert!((near - edge).abs() <= 0.05 * edge, "frame {}: {near} vs edge {edge}", report.frame);
        let depth = report.obstacle_h_mm.unwrap();
        assert!(depths.contains(&depth), "frame {}: height {depth}", report.frame);
    }
}

/// A 25 mm drop, just past the 20 mm limit, raises the alarm on every
/// frame from 1200 mm on (the AOI reaches 1400), at its edge (within 5 %)
/// and with its depth as a negative height.
///
/// A knife-edge by design: at H = 400 mm it lags T*d/(H+d) = 5.9 mm after
/// a 100 mm baseline, about one pixel, of which the ground's tolerance
/// takes half (docs/ARCHITECTURE.md, the motion estimate).
#[test]
fn drop_of_25_mm_raises_the_alarm() {
    drop_reported(&drive_to_ledge(25.0), -40..=-20);
}

/// A 10 mm dip is ground: no alarm on any frame.
#[test]
fn dip_of_10_mm_is_ground() {
    let reports = drive_to_ledge(10.0);
    assert!(reports.iter().all(|r| !r.alarm), "{reports:?}");
}

/// A pit 100 mm deep and 300 mm long, floor beyond it: a drop at its near
/// edge, not an obstacle at its far wall. Only the depth's side of the
/// limit is asserted: it reads -34 to -91 mm (depths read low; see
/// docs/ARCHITECTURE.md).
#[test]
fn pit_raises_the_alarm_at_its_near_edge() {
    drop_reported(&drive(&[(EDGE_Z_MM, 100.0), (EDGE_Z_MM + 300.0, 0.0)]), -255..=-20);
}

/// A shallow pit, 40 mm deep and 200 mm long (measured: -31 to -34 mm,
/// one frame -76).
#[test]
fn shallow_pit_raises_the_alarm_at_its_near_edge() {
    drop_reported(&drive(&[(EDGE_Z_MM, 40.0), (EDGE_Z_MM + 200.0, 0.0)]), -255..=-20);
}

/// A kerb down, 100 mm: a drop at its edge all the way to 600 mm.
#[test]
#[ignore = "issue 14: as the lower level comes to fill the view the estimate puts it into the keyframe pitch (from 950 mm on, -0.58 to -0.78 deg, true 0); frames 17, 18 and 20 (750-600 mm) report an obstacle or residue at 453-539 mm instead (the alarm stays up). docs/ARCHITECTURE.md"]
fn kerb_of_100_mm_raises_the_alarm_at_its_edge() {
    drop_reported(&drive_to_ledge(100.0), -255..=-20);
}

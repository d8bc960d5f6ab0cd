//! GTI accuracy on the bundled recordings (issue 4): heights from motion.

use flatland_core::gti::{Gti, GtiConfig, HeightPoint, RegionMm};
use flatland_host::heights::run_gti;
use flatland_host::recording::{Recording, TruthObstacle};
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(name)
}

/// Footprint of an obstacle in the robot frame of `frame`, grown by `margin_mm`
/// (the axis-aligned bounds of the rotated rectangle).
fn footprint(recording: &Recording, obstacle: &TruthObstacle, frame: u32, margin_mm: f32) -> RegionMm {
    let row = recording.pose(frame).unwrap();
    let (cx, cz) = obstacle.centre_at(row.t_s);
    let (hw, hd) = (obstacle.width_mm / 2.0, obstacle.depth_mm / 2.0);
    let corners = [(-hw, -hd), (hw, -hd), (-hw, hd), (hw, hd)].map(|(dx, dz)| row.pose.world_to_robot(cx + dx, cz + dz));
    let xs = corners.map(|c| c.0 as f32);
    let zs = corners.map(|c| c.1 as f32);
    let min = |v: [f32; 4]| v.iter().copied().fold(f32::INFINITY, f32::min);
    let max = |v: [f32; 4]| v.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    RegionMm { x_min: min(xs) - margin_mm, x_max: max(xs) + margin_mm, z_min: min(zs) - margin_mm, z_max: max(zs) + margin_mm }
}

struct FrameHeights {
    frame: u32,
    obstacle_h: Option<i32>,
    good_points: Vec<HeightPoint>,
    aoi_h: Option<i32>,
}

fn run(name: &str) -> (Recording, Vec<FrameHeights>) {
    let recording = Recording::open(data(name)).unwrap();
    let truth = recording.truth.clone().unwrap_or_default();
    let aoi = recording.rig.aoi();
    let aoi_region = RegionMm { x_min: -aoi.half_width_mm as f32, x_max: aoi.half_width_mm as f32, z_min: aoi.near_mm as f32, z_max: aoi.far_mm as f32 };
    let mut frames = Vec::new();
    let config = GtiConfig::default();
    run_gti(&recording, config, |frame, gti: &Gti| {
        let obstacle_h = truth.obstacle.first().and_then(|o| gti.height_in_region(&footprint(&recording, o, frame, 30.0)));
        let good_points = gti.points().filter(|p| p.quality >= config.good_quality).collect();
        frames.push(FrameHeights { frame, obstacle_h, good_points, aoi_h: gti.height_in_region(&aoi_region) });
    })
    .unwrap();
    (recording, frames)
}

fn report(name: &str, frames: &[FrameHeights]) {
    for f in frames {
        let hs: Vec<i32> = f.good_points.iter().map(|p| p.h_mm.round() as i32).collect();
        println!("{name} frame {}: obstacle {:?} aoi {:?} good {} {:?}", f.frame, f.obstacle_h, f.aoi_h, hs.len(), hs);
    }
}

#[test]
fn approach_box_height() {
    let (_, frames) = run("approach_box");
    report("approach_box", &frames);
}

#[test]
fn noisy_approach_height() {
    let (_, frames) = run("noisy_approach");
    report("noisy_approach", &frames);
}

#[test]
fn qvga_curb_height() {
    let (_, frames) = run("qvga_curb");
    report("qvga_curb", &frames);
}

#[test]
fn flat_marks_flat() {
    let (_, frames) = run("flat_marks");
    report("flat_marks", &frames);
}

#[test]
fn noisy_marks_flat() {
    let (_, frames) = run("noisy_marks");
    report("noisy_marks", &frames);
}

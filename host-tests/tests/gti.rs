//! GTI accuracy on the bundled recordings (issue 4): heights from motion.
//!
//! One default configuration for every recording. The obstacle's height is
//! what the GPA integration will read: `Gti::height_in_region` over the
//! obstacle's footprint (truth.toml, robot frame of the frame, grown by a
//! margin for position error).

use flatland_core::gti::{Gti, HeightPoint, RegionMm};
use flatland_host::heights::{run_gti, run_gti_perturbed};
use flatland_host::perturb::Perturbation;
use flatland_host::recording::{Recording, TruthObstacle};

mod common;
use common::data;

/// Footprint of a rectangle (world frame) in the robot frame of `frame`,
/// grown by `margin_mm` (bounds of the rotated rectangle).
fn footprint(recording: &Recording, centre: (f64, f64), size: (f64, f64), frame: u32, margin_mm: f32) -> RegionMm {
    let pose = recording.pose(frame).unwrap().pose.unwrap();
    let (hw, hd) = (size.0 / 2.0, size.1 / 2.0);
    let corners = [(-hw, -hd), (hw, -hd), (-hw, hd), (hw, hd)].map(|(dx, dz)| pose.world_to_robot(centre.0 + dx, centre.1 + dz));
    let xs = corners.map(|c| c.0 as f32);
    let zs = corners.map(|c| c.1 as f32);
    let min = |v: [f32; 4]| v.iter().copied().fold(f32::INFINITY, f32::min);
    let max = |v: [f32; 4]| v.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    RegionMm { x_min: min(xs) - margin_mm, x_max: max(xs) + margin_mm, z_min: min(zs) - margin_mm, z_max: max(zs) + margin_mm }
}

fn obstacle_footprint(recording: &Recording, obstacle: &TruthObstacle, frame: u32) -> RegionMm {
    let t_s = recording.pose(frame).unwrap().t_s;
    footprint(recording, obstacle.centre_at(t_s), (obstacle.width_mm, obstacle.depth_mm), frame, 30.0)
}

fn aoi_region(recording: &Recording) -> RegionMm {
    let aoi = recording.rig.aoi();
    RegionMm { x_min: -aoi.half_width_mm as f32, x_max: aoi.half_width_mm as f32, z_min: aoi.near_mm as f32, z_max: aoi.far_mm as f32 }
}

/// Per frame: the obstacle's estimated height, the whole AOI's, and the good points.
struct FrameHeights {
    frame: u32,
    obstacle_h: Option<i32>,
    aoi_h: Option<i32>,
    good_points: Vec<HeightPoint>,
}

fn collect(recording: &Recording, frame: u32, gti: &Gti) -> FrameHeights {
    let truth = recording.truth.clone().unwrap_or_default();
    let good = gti.config().good_quality;
    FrameHeights {
        frame,
        obstacle_h: truth.obstacle.first().and_then(|o| gti.height_in_region(&obstacle_footprint(recording, o, frame))),
        aoi_h: gti.height_in_region(&aoi_region(recording)),
        good_points: gti.points().filter(|p| p.quality >= good).collect(),
    }
}

fn run(name: &str) -> (Recording, Vec<FrameHeights>) {
    let recording = Recording::open(data(name)).unwrap();
    let mut frames = Vec::new();
    run_gti(&recording, |frame, gti| frames.push(collect(&recording, frame, gti))).unwrap();
    (recording, frames)
}

fn print(name: &str, frames: &[FrameHeights]) {
    for f in frames {
        println!("{name} frame {:2}: obstacle {:?} aoi {:?} good points {}", f.frame, f.obstacle_h, f.aoi_h, f.good_points.len());
    }
}

fn assert_obstacle_height(name: &str, frames: &[FrameHeights], truth_mm: f64, tolerance_mm: f64) {
    print(name, frames);
    let last = frames.last().unwrap();
    let h = last.obstacle_h.unwrap_or_else(|| panic!("{name}: no height for the obstacle in the last frame"));
    println!("{name}: obstacle {h} mm, truth {truth_mm} mm");
    assert!((f64::from(h) - truth_mm).abs() <= tolerance_mm, "{name}: {h} mm vs {truth_mm} +- {tolerance_mm}");
}

/// Flat scenes: in every frame the AOI's height and every marking's are under
/// 10 mm, and at least 95 % of the good points are within 10 mm of the floor.
fn assert_flat(name: &str) {
    let (recording, frames) = run(name);
    print(name, &frames);
    let truth = recording.truth.clone().unwrap();
    let run_again = |frame: u32, gti: &Gti| {
        for marking in &truth.marking {
            let region = footprint(&recording, (marking.x_mm, marking.z_mm), (marking.width_mm, marking.depth_mm), frame, 30.0);
            if let Some(h) = gti.height_in_region(&region) {
                assert!(h.abs() < 10, "{name} frame {frame}: marking at ({}, {}) reads {h} mm", marking.x_mm, marking.z_mm);
            }
        }
    };
    run_gti(&recording, run_again).unwrap();
    let mut total = 0;
    let mut near_floor = 0;
    for f in &frames {
        if let Some(h) = f.aoi_h {
            assert!(h.abs() < 10, "{name} frame {}: AOI reads {h} mm", f.frame);
        }
        total += f.good_points.len();
        near_floor += f.good_points.iter().filter(|p| p.h_mm.abs() < 10.0).count();
    }
    println!("{name}: {near_floor}/{total} good points within 10 mm of the floor");
    assert!(total > 20, "{name}: only {total} good points");
    assert!(near_floor as f64 >= 0.95 * total as f64, "{name}: {near_floor}/{total} near the floor");
}

#[test]
fn approach_box_height_within_5_percent() {
    let (_, frames) = run("approach_box");
    assert_obstacle_height("approach_box", &frames, 120.0, 6.0);
}

#[test]
fn noisy_approach_height_within_5_percent() {
    let (_, frames) = run("noisy_approach");
    assert_obstacle_height("noisy_approach", &frames, 120.0, 6.0);
}

#[test]
fn qvga_curb_height_within_5_mm() {
    let (_, frames) = run("qvga_curb");
    assert_obstacle_height("qvga_curb", &frames, 40.0, 5.0);
    // And from the frame it is first measured on, it stays within 5 mm.
    let measured: Vec<i32> = frames.iter().filter_map(|f| f.obstacle_h).filter(|h| *h > 20).collect();
    assert!(measured.len() >= 3 && measured.iter().all(|h| (h - 40).abs() <= 5), "{measured:?}");
}

#[test]
fn flat_marks_read_flat() {
    assert_flat("flat_marks");
}

#[test]
fn noisy_marks_read_flat() {
    assert_flat("noisy_marks");
}

/// Runs a recording with a perturbation applied to its poses and frames.
fn run_perturbed(name: &str, perturbation: Perturbation) -> (Recording, Vec<FrameHeights>) {
    let mut recording = Recording::open(data(name)).unwrap();
    perturbation.poses(&mut recording);
    let mut frames = Vec::new();
    run_gti_perturbed(&recording, |i, frame| perturbation.frame(i, frame), |frame, gti| {
        frames.push(collect(&recording, frame, gti))
    })
    .unwrap();
    (recording, frames)
}

/// Extra Gaussian sensor noise (sigma 4 gray levels, twice noisy_*'s) on
/// qvga_curb; the curb must still read 40 +- 5 mm.
#[test]
fn qvga_curb_survives_extra_sensor_noise() {
    let (_, frames) = run_perturbed("qvga_curb", Perturbation { seed: 7, noise_sigma: 4.0, ..Default::default() });
    assert_obstacle_height("qvga_curb + noise", &frames, 40.0, 5.0);
}

/// A systematic odometry scale error (wheels 3 % off, either way) scales
/// every slope; the floor's own motion corrects the travel, so heights hold
/// to the same bounds as with exact odometry.
#[test]
fn odometry_scale_bias_is_corrected_by_the_floor() {
    for bias in [0.03, -0.03] {
        let odometry = Perturbation { seed: 11, odometry_scale_bias: bias, ..Default::default() };
        let (_, frames) = run_perturbed("approach_box", odometry);
        assert_obstacle_height(&format!("approach_box, odometry {bias:+}"), &frames, 120.0, 6.0);
        let (_, frames) = run_perturbed("noisy_approach", odometry);
        assert_obstacle_height(&format!("noisy_approach, odometry {bias:+}"), &frames, 120.0, 6.0);
        let (_, frames) = run_perturbed("qvga_curb", odometry);
        assert_obstacle_height(&format!("qvga_curb, odometry {bias:+}"), &frames, 40.0, 5.0);
        for name in ["flat_marks", "noisy_marks"] {
            let (_, frames) = run_perturbed(name, odometry);
            for f in &frames {
                assert!(f.aoi_h.is_none_or(|h| h.abs() < 10), "{name}, odometry {bias:+}, frame {}: AOI reads {:?}", f.frame, f.aoi_h);
            }
            let good: Vec<_> = frames.iter().flat_map(|f| &f.good_points).collect();
            let near_floor = good.iter().filter(|p| p.h_mm.abs() < 10.0).count();
            println!("{name}, odometry {bias:+}: {near_floor}/{} good points within 10 mm", good.len());
            assert!(good.len() > 20 && near_floor as f64 >= 0.95 * good.len() as f64);
        }
    }
}

/// The RAM the GTI stage needs at the default configuration (issue 4): it
/// must fit beside GPA in the board's 128 KB; the budget is 24 KB.
#[test]
fn gti_state_fits_its_ram_budget() {
    let bytes = std::mem::size_of::<Gti>();
    println!("GTI state: {bytes} bytes ({:.1} KB) on this host", bytes as f64 / 1024.0);
    assert!(bytes <= 24 * 1024, "{bytes} bytes");
}

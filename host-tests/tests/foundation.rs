//! Foundation checks on the bundled recordings (issue: foundation §8).

use flatland_core::geometry::{AoiEdge, Pixel, RigError};
use flatland_core::grid::GridConfig;
use flatland_core::motion::Motion;
use flatland_host::kg::KgFrontEnd;
use flatland_host::recording::{parse_rig, Recording, RecordingError};
use std::path::Path;

mod common;
use common::data;

/// Sub-pixel position where a profile crosses `level`, searching outward from `from`.
fn crossing(profile: &[f64], from: usize, step: isize, level: f64) -> f64 {
    let mut i = from as isize;
    loop {
        let next = i + step;
        let (a, b) = (profile[i as usize], profile[next as usize]);
        if (a - level) * (b - level) <= 0.0 {
            return i as f64 + step as f64 * (a - level) / (a - b);
        }
        i = next;
    }
}

/// (a) Horizontal shape invariance: a flat marking keeps its metric size in the KG image.
#[test]
fn marking_size_in_kg_matches_truth() {
    let recording = Recording::open(data("flat_marks")).unwrap();
    let truth = recording.truth.clone().unwrap();
    let mut front_end = KgFrontEnd::new(&recording.rig, &GridConfig::default()).unwrap();
    let grid = front_end.grid;
    let kg = front_end.remap(&recording.load_frame(0).unwrap()).unwrap();
    let pose = recording.pose(0).unwrap().pose.unwrap();
    // The A4 sheet: the biggest marking, fully in view in frame 0.
    let marking = truth.marking.iter().find(|m| m.width_mm == 210.0).unwrap();
    let (x, z) = pose.world_to_robot(marking.x_mm, marking.z_mm);
    let (ci, cj) = grid.ground_to_pixel(x, z);
    let (ci, cj) = (ci.round() as usize, cj.round() as usize);
    let at = |i: usize, j: usize| f64::from(kg[j * grid.width() + i]);
    // Average a few lines through the centre to beat the floor texture.
    let row_profile: Vec<f64> = (0..grid.width()).map(|i| (cj - 5..=cj + 5).map(|j| at(i, j)).sum::<f64>() / 11.0).collect();
    let column_profile: Vec<f64> = (0..grid.height()).map(|j| (ci - 5..=ci + 5).map(|i| at(i, j)).sum::<f64>() / 11.0).collect();
    let paper = row_profile[ci];
    let floor_level = |p: &[f64], c: usize, half: usize| (p[c - half] + p[c + half]) / 2.0;
    let half_w = (marking.width_mm / grid.mm_per_px) as usize / 2;
    let half_d = (marking.depth_mm / grid.mm_per_px) as usize / 2;
    let level_w = (paper + floor_level(&row_profile, ci, half_w + 8)) / 2.0;
    let level_d = (paper + floor_level(&column_profile, cj, half_d + 8)) / 2.0;
    let width_px = crossing(&row_profile, ci, 1, level_w) - crossing(&row_profile, ci, -1, level_w);
    let depth_px = crossing(&column_profile, cj, 1, level_d) - crossing(&column_profile, cj, -1, level_d);
    let (want_w, want_d) = (marking.width_mm / grid.mm_per_px, marking.depth_mm / grid.mm_per_px);
    println!("A4 sheet in KG: {width_px:.2} x {depth_px:.2} px, truth {want_w:.2} x {want_d:.2} px");
    assert!((width_px - want_w).abs() <= 1.0, "width {width_px} vs {want_w}");
    assert!((depth_px - want_d).abs() <= 1.0, "depth {depth_px} vs {want_d}");
}

/// (b) KG invariance: consecutive KG images of flat ground agree once shifted by the odometry.
#[test]
fn consecutive_kg_images_agree_after_odometry_shift() {
    let recording = Recording::open(data("flat_marks")).unwrap();
    let mut front_end = KgFrontEnd::new(&recording.rig, &GridConfig::default()).unwrap();
    let grid = front_end.grid;
    let aoi = grid.aoi_pixels(&recording.rig);
    for pair in recording.frames.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let first = front_end.remap(&recording.load_frame(a).unwrap()).unwrap();
        let second = front_end.remap(&recording.load_frame(b).unwrap()).unwrap();
        let motion = Motion::between(&recording.pose(a).unwrap().pose.unwrap(), &recording.pose(b).unwrap().pose.unwrap());
        let (mut shifted_sum, mut plain_sum, mut count) = (0.0, 0.0, 0.0);
        for j in aoi.top..aoi.bottom {
            for i in aoi.left..aoi.right {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let (xa, za) = motion.to_earlier_frame(x, z);
                let (fi, fj) = grid.ground_to_pixel(xa, za);
                let (i0, j0) = (fi.floor() as usize, fj.floor() as usize);
                let (wx, wy) = (fi - i0 as f64, fj - j0 as f64);
                let px = |i: usize, j: usize| f64::from(first[j * grid.width() + i]);
                let earlier = px(i0, j0) * (1.0 - wx) * (1.0 - wy)
                    + px(i0 + 1, j0) * wx * (1.0 - wy)
                    + px(i0, j0 + 1) * (1.0 - wx) * wy
                    + px(i0 + 1, j0 + 1) * wx * wy;
                let now = f64::from(second[j * grid.width() + i]);
                shifted_sum += (now - earlier).abs();
                plain_sum += (now - px(i, j)).abs();
                count += 1.0;
            }
        }
        let (shifted, plain) = (shifted_sum / count, plain_sum / count);
        println!("frames {a}->{b}: mean |diff| {shifted:.2} shifted by odometry, {plain:.2} unshifted");
        assert!(shifted < 4.0 && shifted < plain / 5.0, "frames {a}->{b}: {shifted} vs {plain}");
    }
}

/// (c) The integer remap agrees with an exact float reference (float projection, float bilinear).
#[test]
fn remap_agrees_with_float_reference() {
    for name in ["approach_box", "qvga_curb"] {
        let recording = Recording::open(data(name)).unwrap();
        let rig = recording.rig;
        let mut front_end = KgFrontEnd::new(&rig, &GridConfig::default()).unwrap();
        let grid = front_end.grid;
        let frame = recording.load_frame(0).unwrap();
        let kg = front_end.remap(&frame).unwrap();
        let sample = |p: Pixel| {
            let (u0, v0) = (p.u.floor() as usize, p.v.floor() as usize);
            let (u1, v1) = ((u0 + 1).min(frame.width - 1), (v0 + 1).min(frame.height - 1));
            let (wu, wv) = (p.u - u0 as f64, p.v - v0 as f64);
            let px = |u: usize, v: usize| f64::from(frame.pixels[v * frame.width + u]);
            (px(u0, v0) * (1.0 - wu) + px(u1, v0) * wu) * (1.0 - wv) + (px(u0, v1) * (1.0 - wu) + px(u1, v1) * wu) * wv
        };
        let (mut worst, mut total, mut count) = (0.0f64, 0.0, 0usize);
        for j in 0..grid.height() {
            for i in front_end.table.valid_columns(j) {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let exact = sample(rig.ground_to_pixel(x, z).unwrap());
                let diff = (f64::from(kg[j * grid.width() + i]) - exact).abs();
                worst = worst.max(diff);
                total += diff;
                count += 1;
            }
        }
        println!("{name}: integer remap vs float reference: max {worst:.3}, mean {:.4} gray levels", total / count as f64);
        assert!(worst <= 1.0, "{name}: {worst}");
    }
}

/// (d) Each rig error variant comes out of a bad rig.toml, with the file and line.
#[test]
fn bad_rig_toml_gives_each_error() {
    let good = std::fs::read_to_string(data("approach_box").join("rig.toml")).unwrap();
    let path = Path::new("rig.toml");
    let cases: &[(&str, &str, RigError)] = &[
        ("tilt_deg = 32.0", "tilt_deg = 90.0", RigError::Tilt),
        ("tilt_deg = 32.0", "tilt_deg = 0.0", RigError::Tilt),
        ("fx = 240.0", "fx = 0.0", RigError::FocalLength),
        ("fy = 240.0", "fy = -240.0", RigError::FocalLength),
        ("fx = 240.0", "fx = nan", RigError::NotFinite),
        ("width = 256", "width = 0", RigError::ImageSize),
        ("cx = 127.5", "cx = 400.0", RigError::PrincipalPoint),
        ("height_mm = 400.0", "height_mm = -1.0", RigError::MountHeight),
        ("cy = 127.5", "cy = 127.5\ndistortion = [0.9, -2.0, 0.0, 0.0, 0.0]", RigError::Distortion),
        ("near_mm = 450.0", "near_mm = 1500.0", RigError::AoiEmpty),
        ("near_mm = 450.0", "near_mm = -100.0", RigError::AoiBehindCamera),
        ("far_mm = 1400.0", "far_mm = 1.0e9", RigError::AoiBeyondHorizon),
        ("far_mm = 1400.0", "far_mm = 8000.0", RigError::AoiOutsideImage(AoiEdge::Far)),
        ("near_mm = 450.0", "near_mm = 150.0", RigError::AoiOutsideImage(AoiEdge::Near)),
        ("half_width_mm = 250.0", "half_width_mm = 900.0", RigError::AoiOutsideImage(AoiEdge::Left)),
    ];
    for (from, to, expected) in cases {
        assert!(good.contains(from), "{from}");
        let text = good.replacen(from, to, 1);
        match parse_rig(path, &text) {
            Err(RecordingError::Rig { error, line, .. }) => {
                assert_eq!(error, *expected, "{to}");
                // The line of the value at fault.
                let key = to.lines().last().and_then(|l| l.split('=').next()).unwrap().trim();
                let line = line.unwrap_or_else(|| panic!("{to}: no line"));
                assert!(text.lines().nth(line - 1).unwrap().starts_with(key), "{to}: line {line}");
                let message = parse_rig(path, &text).unwrap_err().to_string();
                assert!(message.starts_with("rig.toml:"), "{message}");
            }
            other => panic!("{to}: expected {expected:?}, got {other:?}"),
        }
    }
    // Syntax errors and missing keys name the line too.
    let err = parse_rig(path, &good.replace("fx = 240.0", "fx = ")).unwrap_err().to_string();
    assert!(err.starts_with("rig.toml:"), "{err}");
    let err = parse_rig(path, &good.replace("fx = 240.0\n", "")).unwrap_err().to_string();
    assert!(err.contains("fx"), "{err}");
}

/// Clear floors rendered for calibration (data/README.md): no truth.toml,
/// so the detection suites, which take every recording with one, skip them.
const CALIBRATION_ONLY: [&str; 2] = ["busy_floor", "qvga_low"];

#[test]
fn every_bundled_recording_opens_and_remaps() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let mut seen = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if !path.is_dir() {
            continue;
        }
        let recording = Recording::open(&path).unwrap();
        let mut front_end = KgFrontEnd::new(&recording.rig, &GridConfig::default()).unwrap();
        let kg = front_end.remap(&recording.load_frame(recording.frames[0]).unwrap()).unwrap();
        assert!(kg.iter().any(|&p| p != 0));
        let calibration_only = CALIBRATION_ONLY.iter().any(|name| path.ends_with(name));
        assert_eq!(recording.truth.is_some(), !calibration_only, "{}", path.display());
        seen += 1;
    }
    assert_eq!(seen, 15);
}

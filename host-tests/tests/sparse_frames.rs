//! A small robot that gives one frame a second, without odometry or IMU,
//! moves 180 to 240 mm, and turns up to 9 degrees, between frames: every
//! bundled recording with only every k-th frame kept and its odometry (and
//! IMU) columns dropped, so that the motion comes from the images alone,
//! has no wrong alarm outside grace frames.

use flatland_host::perturb::Perturbation;
use flatland_host::trial::run_trial;
use std::fmt::Write as _;
use std::fs;
use std::path::PathBuf;

mod common;
use common::data;

/// A copy of recording `name` in a directory of its own with frames 0, k,
/// 2k, ... as frames 0, 1, 2, ..., no odometry nor IMU, and the truth's
/// pairs of the frames kept.
fn sparse_copy(name: &str, every: u32) -> PathBuf {
    let source = data(name);
    let dir = std::env::temp_dir().join(format!("flatland-sparse-{}-{name}-{every}", std::process::id()));
    fs::create_dir_all(dir.join("frames")).unwrap();
    fs::copy(source.join("rig.toml"), dir.join("rig.toml")).unwrap();
    let kept = |frame: u32| frame.is_multiple_of(every).then_some(frame / every);

    let poses = fs::read_to_string(source.join("poses.csv")).unwrap();
    let mut rows = String::from("frame,t_s,x_mm,z_mm,yaw_deg\n");
    for line in poses.lines().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        let Some(frame) = kept(fields[0].parse().unwrap()) else { continue };
        // The odometry's fields empty (RECORDING.md), the IMU's left out.
        writeln!(rows, "{frame},{},,,", fields[1]).unwrap();
        let from = source.join("frames").join(format!("{:06}.pgm", frame * every));
        fs::copy(from, dir.join("frames").join(format!("{frame:06}.pgm"))).unwrap();
    }
    fs::write(dir.join("poses.csv"), rows).unwrap();

    // The truth's tables, one `[[...]]` header each; the pairs of the frames kept, renumbered.
    let truth = fs::read_to_string(source.join("truth.toml")).unwrap();
    let mut tables: Vec<String> = Vec::new();
    for line in truth.lines() {
        if line.starts_with("[[") || tables.is_empty() {
            tables.push(String::new());
        }
        let table = tables.last_mut().unwrap();
        table.push_str(line);
        table.push('\n');
    }
    let mut sparse_truth = String::new();
    for table in tables {
        if !table.starts_with("[[pair]]") {
            sparse_truth.push_str(&table);
            continue;
        }
        let frame_line = table.lines().find(|line| line.starts_with("frame")).unwrap();
        let frame: u32 = frame_line.split('=').nth(1).unwrap().trim().parse().unwrap();
        if let Some(kept_frame) = kept(frame) {
            sparse_truth.push_str(&table.replacen(frame_line, &format!("frame = {kept_frame}"), 1));
        }
    }
    fs::write(dir.join("truth.toml"), sparse_truth).unwrap();
    dir
}

/// Recording `name` with every `every`-th frame, no odometry: no wrong
/// alarm outside grace frames, and at least `compared` frames compared.
fn holds(name: &str, every: u32) {
    let dir = sparse_copy(name, every);
    let trial = run_trial(&dir, &Perturbation::default()).unwrap();
    fs::remove_dir_all(&dir).unwrap();
    println!("{name} every {every} frames, no odometry: {:?}, wrong frames {:?}", trial.confusion, trial.wrong);
    assert!(trial.recording.poses.iter().all(|row| row.pose.is_none() && row.attitude.is_none()), "{name}: sensors left in the copy");
    assert!(trial.reports.len() >= 2, "{name}: only {} frames compared", trial.reports.len());
    assert!(trial.wrong.is_empty(), "{name} every {every} frames: wrong frames {:?} ({:?})", trial.wrong, trial.confusion);
}

macro_rules! sparse {
    ($($recording:ident every $every:literal),* $(,)?) => {
        $(#[test] fn $recording() { holds(stringify!($recording), $every) })*
    };
}

// Steps of 180-240 mm: 20 mm recordings every 10th frame, 50 mm every 4th,
// 60 mm every 3rd, 100 mm every 2nd; turn every 3rd turns 9 degrees.
sparse! {
    approach_box every 10,
    bumpy_approach every 5,
    bumpy_marks every 3,
    diagonal every 3,
    exposure_rolling every 3,
    flat_marks every 2,
    ledge every 4,
    noisy_approach every 10,
    noisy_marks every 2,
    qvga_curb every 4,
    slip every 3,
    stool_bags every 2,
    turn every 3,
}

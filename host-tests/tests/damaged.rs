//! The `flatland` CLI on damaged copies of host-tests/data/flat_marks
//! (issue 7): fatal damage is one line naming the file (and line) with exit
//! status 2; damage to one frame skips that frame (a stderr line, no row),
//! restarts the keyframe after it (that frame's row says `after_gap`, alarm
//! asserted), and every other frame still gets its csv row.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const RECORDING: &str = "flat_marks";

/// A fresh copy of the recording under the test's own name.
fn copy(test: &str) -> PathBuf {
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(RECORDING);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("damaged").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    for name in ["rig.toml", "poses.csv", "truth.toml"] {
        std::fs::copy(source.join(name), dir.join(name)).unwrap();
    }
    for entry in std::fs::read_dir(source.join("frames")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), dir.join("frames").join(entry.file_name())).unwrap();
    }
    dir
}

struct Run {
    status: Option<i32>,
    stdout: String,
    stderr: String,
}

fn flatland(args: &[&str], dir: &Path) -> Run {
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(args).arg(dir).output().unwrap();
    Run {
        status: output.status.code(),
        stdout: String::from_utf8(output.stdout).unwrap(),
        stderr: String::from_utf8(output.stderr).unwrap(),
    }
}

fn detect(dir: &Path) -> Run {
    flatland(&["detect"], dir)
}

/// csv rows by frame number (header checked and dropped).
fn rows(run: &Run) -> BTreeMap<u32, String> {
    let mut lines = run.stdout.lines();
    assert_eq!(lines.next(), Some(flatland_core::report::CSV_HEADER), "stdout: {}", run.stdout);
    lines.map(|line| (line.split(',').next().unwrap().parse().unwrap(), line.to_string())).collect()
}

fn ref_frame(row: &str) -> u32 {
    row.split(',').nth(1).unwrap().parse().unwrap()
}

fn frame_path(dir: &Path, frame: u32) -> PathBuf {
    dir.join("frames").join(format!("{frame:06}.pgm"))
}

fn frame_count(dir: &Path) -> u32 {
    std::fs::read_dir(dir.join("frames")).unwrap().count() as u32
}

/// 1-based line of the first line of `file` that starts with `prefix`.
fn line_starting(dir: &Path, file: &str, prefix: &str) -> usize {
    let text = std::fs::read_to_string(dir.join(file)).unwrap();
    text.lines().position(|l| l.starts_with(prefix)).unwrap() + 1
}

fn replace_line(dir: &Path, file: &str, prefix: &str, with: &str) {
    let path = dir.join(file);
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.lines().any(|l| l.starts_with(prefix)), "{file} has no line {prefix:?}");
    let edited: Vec<&str> = text.lines().map(|l| if l.starts_with(prefix) { with } else { l }).collect();
    std::fs::write(&path, edited.join("\n") + "\n").unwrap();
}

/// Fatal damage: status 2, nothing on stdout, exactly one stderr line containing `expect`.
fn assert_fatal(run: &Run, expect: &str) {
    assert_eq!(run.status, Some(2), "stderr: {}", run.stderr);
    let lines: Vec<&str> = run.stderr.lines().collect();
    assert_eq!(lines.len(), 1, "expected one stderr line, got {lines:?}");
    assert!(lines[0].contains(expect), "{:?} does not name {expect:?}", lines[0]);
    assert!(run.stdout.is_empty(), "stdout: {}", run.stdout);
}

#[test]
fn missing_rig_is_fatal() {
    let dir = copy("missing_rig");
    std::fs::remove_file(dir.join("rig.toml")).unwrap();
    assert_fatal(&detect(&dir), "rig.toml");
}

#[test]
fn nan_in_rig_names_its_line() {
    for (n, (key, value)) in [("fy =", "fy = -nan"), ("height_mm =", "height_mm = -inf # not informative")].into_iter().enumerate() {
        let dir = copy(&format!("nan_rig_{n}"));
        replace_line(&dir, "rig.toml", key, value);
        let line = line_starting(&dir, "rig.toml", key);
        assert_fatal(&detect(&dir), &format!("rig.toml:{line}:"));
    }
}

#[test]
fn impossible_rig_values_name_their_line() {
    for (key, value) in [("tilt_deg =", "tilt_deg = 95.0"), ("height_mm =", "height_mm = -400.0"), ("fx =", "fx = 0.0")] {
        let dir = copy(&format!("impossible_{}", key.trim_end_matches(" =")));
        replace_line(&dir, "rig.toml", key, value);
        let line = line_starting(&dir, "rig.toml", key);
        assert_fatal(&detect(&dir), &format!("rig.toml:{line}:"));
    }
}

#[test]
fn rig_that_is_not_toml_names_its_line() {
    let dir = copy("rig_syntax");
    replace_line(&dir, "rig.toml", "cx =", "cx = 127.5.5");
    let line = line_starting(&dir, "rig.toml", "cx =");
    assert_fatal(&detect(&dir), &format!("rig.toml:{line}:"));
}

#[test]
fn unparseable_poses_name_their_line() {
    let dir = copy("bad_poses");
    replace_line(&dir, "poses.csv", "3,", "3,0.300,zero,300.00,0.0000");
    let line = line_starting(&dir, "poses.csv", "3,");
    assert_fatal(&detect(&dir), &format!("poses.csv:{line}:"));

    let dir = copy("binary_poses");
    std::fs::write(dir.join("poses.csv"), b"\x00\x01garbage\n").unwrap();
    assert_fatal(&detect(&dir), "poses.csv:1:");
}

#[test]
fn no_frames_is_fatal() {
    let dir = copy("no_frames");
    for frame in 0..frame_count(&dir) {
        std::fs::remove_file(frame_path(&dir, frame)).unwrap();
    }
    assert_fatal(&detect(&dir), "frames");
}

/// Runs `damage` on frame `bad` of a fresh copy and checks the outcome
/// against the undamaged run.
fn one_bad_frame(test: &str, bad: u32, damage: impl FnOnce(&Path)) {
    let baseline = rows(&detect(&copy(&format!("{test}_baseline"))));
    let dir = copy(test);
    let frames = frame_count(&dir);
    damage(&dir);
    let run = detect(&dir);
    assert_eq!(run.status, Some(0), "stderr: {}", run.stderr);
    let skip_lines: Vec<&str> = run.stderr.lines().filter(|l| l.contains("skipping frame")).collect();
    assert_eq!(skip_lines.len(), 1, "stderr: {}", run.stderr);
    assert!(skip_lines[0].contains(&format!("skipping frame {bad}:")), "{}", skip_lines[0]);
    let got = rows(&run);
    // Frame 0 starts the keyframe (no row); the bad frame is skipped (no
    // row: its stderr line says why); the next one restarts the keyframe
    // and its row says so: not judged, the alarm asserted, no obstacle.
    let expected: Vec<u32> = (1..frames).filter(|&f| f != bad).collect();
    assert_eq!(got.keys().copied().collect::<Vec<_>>(), expected, "stdout: {}", run.stdout);
    for (frame, row) in &got {
        if *frame < bad {
            // Before the damage, nothing changed.
            assert_eq!(row, &baseline[frame]);
        } else if *frame == bad + 1 {
            assert_eq!(row, &format!("{frame},{frame},1,,,,0,0,0.00,0.00,0.0,0.0,,0.000,0.000,0.000,,after_gap"));
        } else {
            // After it, no comparison reaches back across the gap.
            assert!(ref_frame(row) > bad, "frame {frame} compared across the gap: {row}");
            assert!(row.ends_with(",ok"), "frame {frame} not judged: {row}");
        }
    }
}

fn write_pgm(path: &Path, width: usize, height: usize) {
    let mut bytes = format!("P5\n{width} {height}\n255\n").into_bytes();
    bytes.extend((0..width * height).map(|n| (n * 37 % 251) as u8));
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn truncated_frame_is_skipped() {
    one_bad_frame("truncated", 3, |dir| {
        let path = frame_path(dir, 3);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    });
}

#[test]
fn frame_of_the_wrong_size_is_skipped() {
    one_bad_frame("wrong_size", 4, |dir| write_pgm(&frame_path(dir, 4), 128, 96));
}

#[test]
fn frame_with_a_broken_header_is_skipped() {
    one_bad_frame("broken_header", 2, |dir| {
        let path = frame_path(dir, 2);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[3..7].copy_from_slice(b"2x6 ");
        std::fs::write(&path, bytes).unwrap();
    });
}

#[test]
fn missing_frame_is_skipped() {
    one_bad_frame("missing", 5, |dir| std::fs::remove_file(frame_path(dir, 5)).unwrap());
}

#[test]
fn first_and_last_frames_may_be_damaged() {
    one_bad_frame("first", 0, |dir| std::fs::write(frame_path(dir, 0), b"P5\n").unwrap());
    one_bad_frame("last", 7, |dir| std::fs::write(frame_path(dir, 7), b"").unwrap());
}

#[test]
fn time_going_backwards_skips_the_frame() {
    one_bad_frame("time_backwards", 4, |dir| {
        let line = line_starting(dir, "poses.csv", "4,");
        let text = std::fs::read_to_string(dir.join("poses.csv")).unwrap();
        let row: Vec<&str> = text.lines().nth(line - 1).unwrap().split(',').collect();
        let earlier = format!("4,0.150,{},{},{}", row[2], row[3], row[4]);
        replace_line(dir, "poses.csv", "4,", &earlier);
    });
}

#[test]
fn kg_writes_every_good_frame() {
    let dir = copy("kg_truncated");
    let frames = frame_count(&dir);
    std::fs::write(frame_path(&dir, 2), b"P5\n256 256\n255\n\x01\x02").unwrap();
    let out = dir.join("kg_out");
    let run = flatland(&["kg", "--out", out.to_str().unwrap()], &dir);
    assert_eq!(run.status, Some(0), "stderr: {}", run.stderr);
    assert!(run.stderr.contains("skipping frame 2:"), "stderr: {}", run.stderr);
    let pngs = std::fs::read_dir(&out).unwrap().filter(|e| e.as_ref().unwrap().path().extension().is_some_and(|x| x == "png")).count();
    assert_eq!(pngs as u32, frames - 1);
    assert!(!out.join("000002.png").exists());
}

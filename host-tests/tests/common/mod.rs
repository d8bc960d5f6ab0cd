//! Shared by the QEMU tests: builds the firmware once, runs it on a
//! recording directory with a byte script, and runs the host pipeline
//! (`flatland detect --format csv`, in-process) for comparison.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;

use flatland_core::protocol::{Fault, Message};
use flatland_core::report::CSV_HEADER;
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::qemu::{self, RunOutcome, RunRequest, Sensors};
use flatland_host::recording::Recording;
use flatland_host::link::serial::{run_serial_decode, DecodeSummary};

/// Per QEMU run; a run that hangs fails the test instead of hanging it.
pub const TIMEOUT: Duration = Duration::from_secs(300);

pub fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(name)
}

/// Every bundled recording (a folder of `data/` with a truth.toml), by name.
pub fn bundled() -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(data(""))
        .unwrap()
        .filter_map(|entry| {
            let path = entry.ok()?.path();
            path.join("truth.toml").exists().then(|| path.file_name()?.to_str().map(String::from))?
        })
        .collect();
    names.sort();
    names
}

/// The firmware ELF, built once per test binary. Panics (fails the test)
/// with a clear message when QEMU or defmt-print is missing: never a skip.
pub fn firmware_elf() -> PathBuf {
    static ELF: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    let built = ELF.get_or_init(|| {
        qemu::require_tools()?;
        Ok(qemu::build_firmware()?.join("flatland-firmware"))
    });
    match built {
        Ok(elf) => elf.clone(),
        Err(message) => panic!("cannot run the firmware in QEMU: {message}"),
    }
}

/// Runs the firmware in QEMU with `dir` as its working directory.
pub fn run(dir: &Path, script: Vec<u8>) -> RunOutcome {
    run_then(dir, script, None)
}

/// As [`run`], with more bytes sent once a frame is answered.
pub fn run_then(dir: &Path, script: Vec<u8>, then: Option<qemu::Continuation>) -> RunOutcome {
    checked_run(dir, script, then, None)
}

/// As [`run`], the KG resolution fixed (the firmware's `mm_per_px=`
/// option, which its benchmark mode takes).
pub fn run_at_resolution(dir: &Path, script: Vec<u8>, mm_per_px: f64) -> RunOutcome {
    checked_run(dir, script, None, Some(mm_per_px))
}

/// One QEMU run that must end well: exit status 0, no panic logged.
fn checked_run(dir: &Path, script: Vec<u8>, then: Option<qemu::Continuation>, mm_per_px: Option<f64>) -> RunOutcome {
    let elf = firmware_elf();
    let request = RunRequest { elf: &elf, dir, script, then, bench: mm_per_px.is_some(), bench_mm_per_px: mm_per_px, bench_no_margins: false, echo_log: false, exec_log: None, timeout: TIMEOUT, mavlink: false };
    let outcome = qemu::run_firmware(request, &mut |_| {}).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    assert!(outcome.status.success(), "{}: firmware exit {}; log:\n{}", dir.display(), outcome.status, outcome.log);
    assert!(!outcome.log.contains("panic"), "{}: log mentions a panic:\n{}", dir.display(), outcome.log);
    outcome
}

/// The firmware's serial output as `flatland serial decode` prints it.
pub fn decoded(outcome: &RunOutcome) -> (String, DecodeSummary) {
    let mut csv = Vec::new();
    let summary = run_serial_decode(&mut outcome.serial.raw.as_slice(), &mut csv)
        .unwrap_or_else(|e| panic!("serial decode: {e}; log:\n{}", outcome.log));
    (String::from_utf8(csv).expect("csv is ASCII"), summary)
}

/// `flatland detect <dir> --format csv` (stdout), computed in-process.
pub fn detect_csv(dir: &Path) -> String {
    detect_csv_with(dir, Sensors::ALL)
}

/// As [`detect_csv`], with `--odometry none` / `--imu none` as `sensors` says.
pub fn detect_csv_with(dir: &Path, sensors: Sensors) -> String {
    let mut recording = Recording::open(dir).unwrap_or_else(|e| panic!("{e}"));
    sensors.apply(&mut recording);
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let mut csv = format!("{CSV_HEADER}\n");
    detector
        .run(&recording, |outcome, _| {
            if let FrameOutcome::Report { report, .. } = outcome {
                report.write_csv(&mut csv).expect("String write");
                csv.push('\n');
            }
        })
        .unwrap_or_else(|e| panic!("{e}"));
    csv
}

/// The normal host script for a recording (rig, poses, end).
pub fn script(dir: &Path) -> Vec<u8> {
    script_with(dir, Sensors::ALL)
}

/// The host script of a robot with only `sensors` (`cargo fw --odometry none` ...).
pub fn script_with(dir: &Path, sensors: Sensors) -> Vec<u8> {
    let mut recording = Recording::open(dir).unwrap_or_else(|e| panic!("{e}"));
    sensors.apply(&mut recording);
    qemu::host_script(&recording).unwrap_or_else(|e| panic!("{e}"))
}

pub fn messages(dir: &Path) -> Vec<Message> {
    messages_with(dir, Sensors::ALL)
}

/// The messages of a robot with only `sensors`.
pub fn messages_with(dir: &Path, sensors: Sensors) -> Vec<Message> {
    let mut recording = Recording::open(dir).unwrap_or_else(|e| panic!("{e}"));
    sensors.apply(&mut recording);
    qemu::host_messages(&recording)
}

pub fn faults(outcome: &RunOutcome) -> Vec<Fault> {
    outcome.serial.messages.iter().filter_map(|m| if let Message::Fault(f) = m { Some(*f) } else { None }).collect()
}

/// A scratch copy of a bundled recording, removed on drop.
pub struct TempRecording {
    pub dir: PathBuf,
}

impl TempRecording {
    pub fn copy_of(name: &str, tag: &str) -> TempRecording {
        // Tests of one binary run in parallel in one process: each copy
        // gets its own directory.
        static COPIES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let copy = COPIES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("flatland-{tag}-{}-{copy}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("frames")).expect("temp dir");
        let source = data(name);
        for file in ["rig.toml", "poses.csv", "truth.toml"] {
            if source.join(file).exists() {
                std::fs::copy(source.join(file), dir.join(file)).expect("copy");
            }
        }
        for entry in std::fs::read_dir(source.join("frames")).expect("frames") {
            let entry = entry.expect("entry");
            std::fs::copy(entry.path(), dir.join("frames").join(entry.file_name())).expect("copy frame");
        }
        TempRecording { dir }
    }

    pub fn frame(&self, index: u32) -> PathBuf {
        self.dir.join("frames").join(format!("{index:06}.pgm"))
    }
}

impl Drop for TempRecording {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Frame numbers of the csv rows.
pub fn row_frames(csv: &str) -> Vec<u32> {
    csv.lines().skip(1).map(|l| l.split(',').next().and_then(|f| f.parse().ok()).expect("frame field")).collect()
}

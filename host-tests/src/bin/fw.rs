//! `cargo fw [RECORDING] [--csv]`, `cargo fw-test`, `cargo fw-bench`: builds
//! the firmware and runs it in QEMU (netduinoplus2).
//!
//! - Main job: QEMU's working directory is the recording, so the firmware
//!   reads `frames/NNNNNN.pgm` through semihosting; USART1 is a TCP
//!   connection to this runner, which sends the rig (rig.toml) and the poses
//!   (poses.csv) and decodes the reports. Prints alarm lines and the defmt
//!   log (through defmt-print); `--csv` prints only the csv of `flatland detect`.
//! - `--selftest`: core's checks on the target, then the panic, HardFault and watchdog
//!   paths, which must end QEMU with a nonzero status and a message.
//! - `--bench`: the main job under `-icount shift=0`; prints `key: value`.
//!   With `--profile [FIRST]`: first the instructions per function on three
//!   frames (from FIRST, default 0; FIRST is then the keyframe), from
//!   QEMU's record of what it ran ([`m4_profile`]).
//!   With `--frames`: also each frame's figures, a line per frame (where
//!   the worst frames come from).
//!   With `--full-frame`: the worst case, a square AOI making the KG grid
//!   256x256 without margins (`bench::FullFrame`, as `flatland bench
//!   --full-frame`), on the `full-frame` firmware build (no GTI stage).
//!
//! - `--odometry none`, `--imu none`: the poses go without the wheels' pose
//!   / the IMU's attitude (`$FLODO`'s optional fields), as `flatland detect`
//!   ignores them with the same options; with `--bench`, the cost the
//!   firmware has without them.
//! - `--protocol mavlink`: the `mavlink` firmware build, the poses sent as
//!   MAVLink `ODOMETRY` (`--poses local-position`: `LOCAL_POSITION_NED` +
//!   `ATTITUDE`); prints the stream as the `mavlink` crate decodes it, or
//!   with `--csv` the csv of `flatland serial decode --mavlink --recording`.
//!   `--protocol lines` (the default) is the line protocol.
//! - `--capture FILE`: saves the firmware's raw serial output to FILE.
//! - `--elf PATH`: runs that firmware ELF instead of building one; the
//!   thumb target's cargo runner (`cargo run --target thumbv7em-none-eabihf`
//!   in .cargo/config.toml). An ELF named `selftest` gets `--selftest`'s
//!   run, any other the main job (or `--csv`, `--bench`).
//!
//! Every QEMU run has a deadline (`--timeout SECS`, default 300); missing
//! tools (rustup target, qemu-system-arm, defmt-print) are installed first.

use std::collections::BTreeMap;
use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;

use flatland_core::protocol::Message;
use flatland_host::bench::FullFrame;
use flatland_host::qemu::{self, RunRequest, Sensors, DEFAULT_RECORDING};
use flatland_host::recording::Recording;
use flatland_host::link::{mavlink as mavlink_decode, serial as serial_decode};
use flatland_host::qemu::profile as m4_profile;

type Result<T> = std::result::Result<T, String>;

/// What the firmware speaks on USART1 (`--protocol`).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Protocol {
    /// `$FL...` lines (the default build).
    Lines,
    /// MAVLink 2 (the `mavlink` build).
    Mavlink,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Run,
    Csv,
    SelfTest,
    Bench,
}

struct Args {
    mode: Mode,
    /// A firmware ELF to run (`--elf`); None: build it.
    elf: Option<PathBuf>,
    recording: PathBuf,
    timeout: Duration,
    mm_per_px: Option<f64>,
    full_frame: bool,
    /// What `$FLODO` carries (`--odometry none`, `--imu none`).
    sensors: Sensors,
    /// `--protocol mavlink`: the `mavlink` build, poses sent as MAVLink
    /// (`--poses local-position`: LOCAL_POSITION_NED + ATTITUDE instead of
    /// ODOMETRY). None: `--protocol lines`, the line protocol.
    mavlink: Option<qemu::PoseMessages>,
    /// `--capture FILE`: the firmware's raw serial output.
    capture: Option<PathBuf>,
    /// `--profile [FIRST]`: instructions per function on frames FIRST.. (`--bench` only).
    profile: Option<u32>,
    /// `--frames`: each frame's figures too (`--bench` only).
    frames: bool,
}

/// Frames `--profile` counts (QEMU's record, ~0.4 GB a frame, is read
/// through a pipe as it is written).
const PROFILE_FRAMES: u32 = 3;
/// The function a frame starts with: the profile counts from FIRST's entry.
const PROFILE_START: &str = "flatland_core::pipeline::Pipeline::begin";

/// `--odometry poses|none`, `--imu poses|none`, as on `flatland detect`:
/// whether the run uses that sensor's poses.csv columns.
fn parse_source(option: &str, value: Option<String>) -> Result<bool> {
    match value.as_deref() {
        Some("poses") => Ok(true),
        Some("none") => Ok(false),
        _ => Err(format!("{option} takes `poses` (the default) or `none` (leave those fields out)")),
    }
}

fn parse_args() -> Result<Args> {
    let mut mode = Mode::Run;
    let mut elf = None;
    let mut recording = None;
    let mut timeout = Duration::from_secs(300);
    let mut mm_per_px = None;
    let mut full_frame = false;
    let mut sensors = Sensors::ALL;
    let mut protocol = Protocol::Lines;
    let mut poses = None;
    let mut profile = None;
    let mut capture = None;
    let mut frames = false;
    let mut args = std::env::args().skip(1).peekable();
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--csv" => mode = Mode::Csv,
            "--selftest" => mode = Mode::SelfTest,
            "--bench" => mode = Mode::Bench,
            "--full-frame" => full_frame = true,
            "--frames" => frames = true,
            "--profile" => {
                // An optional first frame: a run from there (its first frame the keyframe).
                let first = args.peek().and_then(|next| next.parse::<u32>().ok());
                if first.is_some() {
                    args.next();
                }
                profile = Some(first.unwrap_or(0));
            }
            "--protocol" => {
                protocol = match args.next().as_deref() {
                    Some("lines") => Protocol::Lines,
                    Some("mavlink") => Protocol::Mavlink,
                    _ => return Err("--protocol takes `lines` (the default) or `mavlink`".into()),
                }
            }
            "--poses" => {
                poses = Some(match args.next().as_deref() {
                    Some("odometry") => qemu::PoseMessages::Odometry,
                    Some("local-position") => qemu::PoseMessages::LocalPosition,
                    _ => return Err("--poses takes `odometry` (ODOMETRY, the default) or `local-position` (LOCAL_POSITION_NED + ATTITUDE)".into()),
                })
            }
            "--capture" => capture = Some(PathBuf::from(args.next().ok_or("--capture needs a file")?)),
            "--odometry" => sensors.odometry = parse_source("--odometry", args.next())?,
            "--imu" => sensors.imu = parse_source("--imu", args.next())?,
            "--elf" => elf = Some(PathBuf::from(args.next().ok_or("--elf needs a path")?)),
            "--timeout" => {
                let secs = args.next().and_then(|s| s.parse().ok()).ok_or("--timeout needs seconds")?;
                timeout = Duration::from_secs(secs);
            }
            "--mm-per-px" => {
                mm_per_px = Some(args.next().and_then(|s| s.parse().ok()).ok_or("--mm-per-px needs a number")?);
            }
            "-h" | "--help" => {
                println!("usage: cargo fw [RECORDING] [--csv] [--odometry none] [--imu none] [--timeout SECS] | cargo fw-test | cargo fw-bench [RECORDING] [--odometry none] [--imu none] [--mm-per-px X] [--full-frame] [--profile [FIRST]] [--frames]");
                println!("       --profile [FIRST]: instructions per function on {PROFILE_FRAMES} frames from FIRST (default 0); --frames: each frame's figures too");
                println!("       --odometry none / --imu none: $FLODO leaves the wheels' pose / the IMU's attitude out");
                println!("       --protocol lines|mavlink: the serial protocol (default lines); mavlink runs the mavlink build, poses sent as MAVLink;");
                println!("         with --csv it prints OBSTACLE_DISTANCE as `flatland serial decode --mavlink --recording RECORDING` does");
                println!("       --poses odometry|local-position: with --protocol mavlink, poses as ODOMETRY (default) or LOCAL_POSITION_NED + ATTITUDE");
                println!("       --capture FILE: save the firmware's raw serial output");
                println!("       fw --elf PATH [same options]: run that firmware ELF (the thumb target's cargo runner)");
                std::process::exit(0);
            }
            other if other.starts_with('-') => return Err(format!("unknown option {other}")),
            other => recording = Some(PathBuf::from(other)),
        }
    }
    let recording = recording.unwrap_or_else(|| qemu::workspace_root().join(DEFAULT_RECORDING));
    let recording = recording.canonicalize().map_err(|e| format!("recording {}: {e}", recording.display()))?;
    if full_frame && mode != Mode::Bench {
        return Err("--full-frame is for cargo fw-bench".into());
    }
    if (profile.is_some() || frames) && mode != Mode::Bench {
        return Err("--profile and --frames are for cargo fw-bench".into());
    }
    // QEMU runs in the recording's directory: the ELF's path must not be relative.
    let elf = elf.map(|elf: PathBuf| elf.canonicalize().map_err(|e| format!("firmware {}: {e}", elf.display()))).transpose()?;
    if mode == Mode::Run && elf.as_deref().and_then(Path::file_name).is_some_and(|name| name == "selftest") {
        mode = Mode::SelfTest;
    }
    let mavlink = match (protocol, poses) {
        (Protocol::Mavlink, poses) => Some(poses.unwrap_or(qemu::PoseMessages::Odometry)),
        (Protocol::Lines, None) => None,
        (Protocol::Lines, Some(_)) => return Err("--poses is for --protocol mavlink".into()),
    };
    if mavlink.is_some() && !matches!(mode, Mode::Run | Mode::Csv) {
        return Err("--protocol mavlink runs the main job (no --bench or --selftest)".into());
    }
    Ok(Args { mode, elf, recording, timeout, mm_per_px, full_frame, sensors, mavlink, capture, profile, frames })
}

fn describe(message: &Message) -> Option<String> {
    match message {
        Message::Hello(rig) => Some(format!(
            "firmware ready: camera {}x{}, H {} mm, tilt {} deg",
            rig.camera.width, rig.camera.height, rig.mount.height_mm, rig.mount.tilt_deg
        )),
        Message::Frame(r) if r.alarm => {
            let mm = |v: Option<i32>| v.map_or("?".to_string(), |v| v.to_string());
            Some(format!(
                "ALARM frame {} (vs {}): obstacle at {} mm, x {}..{} mm",
                r.frame,
                r.ref_frame,
                mm(r.nearest_mm),
                mm(r.left_mm),
                mm(r.right_mm)
            ))
        }
        Message::Frame(r) => Some(format!("frame {} (vs {}): clear", r.frame, r.ref_frame)),
        Message::Fault(f) => Some(format!("FAULT {} at frame {}", f.code.as_str(), f.frame)),
        Message::Stats(s) => Some(format!(
            "stats: {} frames; serial garbage {} B, truncated {}, too long {}, bad checksum {}, unknown {}, bad field {}, out of order {}, frame gaps {}, aborted {}",
            s.frame_loop.frames,
            s.decoder.garbage_bytes,
            s.decoder.truncated,
            s.decoder.too_long,
            s.decoder.bad_checksum,
            s.decoder.unknown_type,
            s.decoder.bad_field,
            s.frame_loop.out_of_order,
            s.frame_loop.frame_gaps,
            s.frame_loop.aborted
        )),
        _ => None,
    }
}

/// The main job, `--csv` and `--bench`: runs the firmware `elf` on a recording.
/// Returns the decoded log.
fn run_recording(args: &Args, elf: &Path, exec_log: Option<&Path>) -> Result<String> {
    let mut recording = Recording::open(&args.recording).map_err(|e| e.to_string())?;
    args.sensors.apply(&mut recording);
    if let (Some(_), Some(first)) = (exec_log, args.profile) {
        recording.poses.retain(|row| row.frame < first + PROFILE_FRAMES);
    }
    let mut mm_per_px = args.mm_per_px;
    if args.full_frame {
        let full = FullFrame::for_rig(&recording.rig, mm_per_px)?;
        recording.rig = full.rig;
        mm_per_px = Some(full.mm_per_px);
    }
    let human = args.mode == Mode::Run;
    let script = match args.mavlink {
        Some(poses) => qemu::mavlink_script(&recording, poses)?,
        None => qemu::host_script(&recording)?,
    };
    let request = RunRequest {
        elf,
        dir: &args.recording,
        script,
        then: None,
        mavlink: args.mavlink.is_some(),
        bench: args.mode == Mode::Bench,
        bench_mm_per_px: mm_per_px,
        bench_no_margins: args.full_frame,
        echo_log: human,
        exec_log,
        timeout: args.timeout,
    };
    let outcome = qemu::run_firmware(request, &mut |message| {
        if human {
            if let Some(text) = describe(message) {
                println!("{text}");
            }
        }
    })?;
    if let Some(path) = &args.capture {
        std::fs::write(path, &outcome.serial.raw).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    if !outcome.status.success() {
        if !human {
            eprintln!("{}", outcome.log);
        }
        return Err(format!("firmware failed ({})", outcome.status));
    }
    if args.mavlink.is_some() {
        let decoded = mavlink_decode::decode(&outcome.serial.raw);
        if args.mode == Mode::Csv {
            let frames = mavlink_decode::frames_by_time(&recording);
            mavlink_decode::write_scan_csv(&decoded, mavlink_decode::RowKey::Frame(&frames), &mut io::stdout().lock())
                .map_err(|e| e.to_string())?;
        } else {
            for (_, message) in &decoded.messages {
                println!("{}", mavlink_decode::describe(message));
            }
        }
        if !decoded.errors.is_empty() {
            return Err(format!("{} MAVLink frames did not decode: {:?}", decoded.errors.len(), decoded.errors));
        }
        return Ok(outcome.log);
    }
    if args.mode == Mode::Csv {
        let stdout = io::stdout();
        let summary = serial_decode::run_serial_decode(&mut outcome.serial.raw.as_slice(), &mut stdout.lock())
            .map_err(|e| e.to_string())?;
        for fault in summary.frame_faults {
            eprintln!("fw: firmware skipped frame {}: {}", fault.frame, fault.code.as_str());
        }
        for fault in summary.sensor_faults {
            eprintln!("fw: {} after frame {} (alarm asserted)", fault.code.as_str(), fault.frame);
        }
    }
    if outcome.serial.stats.is_none() {
        return Err("the firmware ended without its statistics message".into());
    }
    Ok(outcome.log)
}

/// core's checks on the target (the `selftest` ELF), then the deliberate faults.
fn run_selftest(args: &Args, elf: &Path) -> Result<()> {
    let (status, log) = qemu::run_selftest(elf, "", true, args.timeout)?;
    let summary = log.lines().find(|l| l.contains(" passed, ")).ok_or("selftest printed no summary")?;
    if !status.success() || !summary.contains(" 0 failed") {
        return Err(format!("on-target tests failed ({status}): {summary}"));
    }
    // Each fault path asserts the alarm (its log line says so) and ends QEMU with status 1.
    for (request, expected) in [("panic", "panic:"), ("hardfault", "HardFault"), ("hang", "watchdog: not fed")] {
        let (status, log) = qemu::run_selftest(elf, request, false, args.timeout)?;
        // A panic's message may span lines: the alarm note ends the message.
        let message = log.split_once(expected).map(|(_, rest)| rest.split_once(" ERROR ").map_or(rest, |(m, _)| m));
        if status.success() || !message.is_some_and(|m| m.contains("alarm asserted")) {
            return Err(format!("a deliberate {request} did not end QEMU with a failure and an alarm message:\n{log}"));
        }
        println!("fault path {request}: exit {status}, message {:?}", log.lines().find(|l| l.contains(expected)).unwrap_or(""));
    }
    Ok(())
}

fn run_bench(args: &Args, elf: &Path) -> Result<()> {
    // QEMU's record goes through a pipe, read as it is written: the frames
    // before FIRST run (the keyframe and GTI's tracks are then what they
    // are in the whole run) without their ~0.4 GB a frame being kept.
    let exec_log = args.profile.is_some().then(|| std::env::temp_dir().join(format!("flatland-exec-{}.fifo", std::process::id())));
    let reader = match (&exec_log, args.profile) {
        (Some(path), Some(first)) => {
            let made = std::process::Command::new("mkfifo").arg(path).status().map_err(|e| format!("mkfifo: {e}"))?;
            if !made.success() {
                return Err(format!("mkfifo {} failed", path.display()));
            }
            let mut recording = Recording::open(&args.recording).map_err(|e| e.to_string())?;
            args.sensors.apply(&mut recording);
            let nth = recording.poses.iter().filter(|row| row.frame < first).count() + 1;
            let path = path.clone();
            Some(std::thread::spawn(move || {
                let record = std::fs::File::open(&path).map(|file| std::io::BufReader::with_capacity(1 << 20, file));
                record.and_then(|record| m4_profile::read(record, Some(m4_profile::Start { function: PROFILE_START, nth })))
            }))
        }
        _ => None,
    };
    let log = run_recording(args, elf, exec_log.as_deref());
    if let (Some(path), Some(reader)) = (&exec_log, reader) {
        // Had QEMU not opened the pipe, the reader would wait for a writer:
        // one that opens and closes without blocking ends its wait.
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::fs::OpenOptionsExt;
            const O_NONBLOCK: i32 = 0o4000;
            let _ = std::fs::OpenOptions::new().write(true).custom_flags(O_NONBLOCK).open(path);
        }
        let profile = reader.join().map_err(|_| "the profile's reader panicked".to_string())?;
        let _ = std::fs::remove_file(path);
        let profile = profile.map_err(|e| format!("QEMU's record {}: {e}", path.display()))?;
        print_profile(&profile, args.profile.unwrap_or(0));
    }
    let log = log?;
    let mut per_frame: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    let mut once: Vec<(String, String)> = Vec::new();
    for line in log.lines() {
        let Some((_, rest)) = line.split_once("bench: ") else { continue };
        let Some((key, value)) = rest.split_once(": ") else { continue };
        match key {
            "frame" => {}
            "table_build" | "stack_high_water_bytes" | "stack_region_bytes" | "grid" | "sad_instructions_per_4_differences_x100"
            | "shift_search_instructions_per_4_differences_x100"
            | "histogram_instructions_per_pixel_x100"
            | "bilinear_instructions_per_pixel_x100"
            | "residue_instructions_per_pixel_x100" => once.push((key.to_string(), value.to_string())),
            _ => per_frame.entry(key.to_string()).or_default().extend(value.parse::<u64>().ok()),
        }
    }
    if per_frame.is_empty() {
        return Err("the firmware printed no benchmark figures".into());
    }
    println!("recording: {}", args.recording.display());
    if args.full_frame {
        println!("full_frame: square AOI, 256x256 KG grid without margins; firmware feature full-frame (no GTI stage)");
    }
    println!("unit: instructions (TIM2 under -icount shift=0), mean over the frames compared with a keyframe; _max: worst frame");
    for (key, value) in &once {
        println!("{key}: {value}");
    }
    for (key, values) in &per_frame {
        let mean = values.iter().sum::<u64>() / values.len().max(1) as u64;
        let max = values.iter().copied().max().unwrap_or(0);
        println!("{key}: {mean}");
        println!("{key}_max: {max}");
    }
    println!("frames: {}", per_frame.values().next().map_or(0, Vec::len));
    if args.frames {
        print_frames(&per_frame);
    }
    // The |diff| histogram is accumulated inside the shift search and its
    // median taken in the decision; it has no instructions of its own.
    println!("histogram: in_shift_search_and_decision");
    let (flash, ram) = qemu::memory_use(elf)?;
    println!("flash_bytes: {flash}");
    println!("static_ram_bytes: {ram}");
    Ok(())
}

/// `--frames`: a line per frame compared, its cycle and the largest stages.
fn print_frames(per_frame: &BTreeMap<String, Vec<u64>>) {
    const STAGES: [&str; 9] =
        ["instructions_per_cycle", "remap", "gpa_estimate", "gpa_warp", "gpa_residue", "gpa_parallax", "gpa_seed_search", "gti", "decision"];
    println!("per_frame: n {}", STAGES.join(" "));
    let frames = per_frame.get(STAGES[0]).map_or(0, Vec::len);
    for n in 0..frames {
        let figures: Vec<String> = STAGES.iter().map(|key| per_frame.get(*key).and_then(|values| values.get(n)).map_or("-".to_string(), u64::to_string)).collect();
        println!("per_frame: {n} {}", figures.join(" "));
    }
}

/// The profile's biggest entries (`--profile`).
fn print_profile(profile: &m4_profile::Profile, first: u32) {
    let share = |count: u64| 100.0 * count as f64 / profile.total.max(1) as f64;
    println!("profile: every instruction the M4 ran on {PROFILE_FRAMES} frames from frame {first} (serial waits included; the set-up and the frames before ran uncounted); the figures after the profile are the same run's, over frames 0 to {}", first + PROFILE_FRAMES - 1);
    println!("profile_total: {}", profile.total);
    for (name, count) in profile.functions.iter().take(40) {
        println!("profile: {count:>11} {:5.1} %  {name}", share(*count));
    }
    println!("profile: library routines by caller (their instructions are in the list above too)");
    for ((routine, caller), count) in profile.routines.iter().take(20) {
        println!("profile: {count:>11} {:5.1} %  {routine} <- {caller}", share(*count));
    }
    println!("profile: the hottest blocks by start address (read them with llvm-objdump -d)");
    for ((address, function), count) in profile.blocks.iter().take(30) {
        println!("profile: {count:>11} {:5.1} %  {address:#010x} {function}", share(*count));
    }
}

fn main() {
    let result = parse_args().and_then(|args| {
        qemu::ensure_tools()?;
        let elf = match &args.elf {
            Some(elf) => elf.clone(),
            // parse_args allows --full-frame with --bench only.
            None if args.full_frame => qemu::build_full_frame_firmware()?,
            None if args.mavlink.is_some() => qemu::build_mavlink_firmware()?,
            None => {
                let release_dir = qemu::build_firmware()?;
                release_dir.join(if args.mode == Mode::SelfTest { "selftest" } else { "flatland-firmware" })
            }
        };
        match args.mode {
            Mode::Run | Mode::Csv => run_recording(&args, &elf, None).map(drop),
            Mode::SelfTest => run_selftest(&args, &elf),
            Mode::Bench => run_bench(&args, &elf),
        }
    });
    if let Err(message) = result {
        eprintln!("fw: {message}");
        std::process::exit(1);
    }
}

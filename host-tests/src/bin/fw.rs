//! `cargo fw [RECORDING] [--csv]`, `cargo fw-test`, `cargo fw-bench`: builds
//! the firmware and runs it in QEMU (netduinoplus2).
//!
//! - Main job: QEMU's working directory is the recording, so the firmware
//!   reads `frames/NNNNNN.pgm` through semihosting; USART1 is a TCP
//!   connection to this runner, which sends the rig (rig.toml) and the poses
//!   (poses.csv) and decodes the reports. Prints alarm lines and the defmt
//!   log (through defmt-print); `--csv` prints only the csv of `flatland detect`.
//! - `--selftest`: core's checks on the target, then the panic and HardFault
//!   paths, which must end QEMU with a nonzero status and a message.
//! - `--bench`: the main job under `-icount shift=0`; prints `key: value`.
//!
//! Every QEMU run has a deadline (`--timeout SECS`, default 300); missing
//! tools (rustup target, qemu-system-arm, defmt-print) are installed first.

#[path = "../serial_decode.rs"]
mod serial_decode;

use std::collections::BTreeMap;
use std::fs;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

use flatland_core::protocol::{encode_line, Decoder, LinkStats, Message, Odometry, RigRecord};

const TARGET: &str = "thumbv7em-none-eabihf";
const DEFAULT_RECORDING: &str = "host-tests/data/flat_marks";

type Result<T> = std::result::Result<T, String>;

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Run,
    Csv,
    SelfTest,
    Bench,
}

struct Args {
    mode: Mode,
    recording: PathBuf,
    timeout: Duration,
}

fn workspace_root() -> PathBuf {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    manifest.parent().map(Path::to_path_buf).unwrap_or(manifest)
}

fn parse_args() -> Result<Args> {
    let mut mode = Mode::Run;
    let mut recording = None;
    let mut timeout = Duration::from_secs(300);
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--csv" => mode = Mode::Csv,
            "--selftest" => mode = Mode::SelfTest,
            "--bench" => mode = Mode::Bench,
            "--timeout" => {
                let secs = args.next().and_then(|s| s.parse().ok()).ok_or("--timeout needs seconds")?;
                timeout = Duration::from_secs(secs);
            }
            "-h" | "--help" => {
                println!("usage: cargo fw [RECORDING] [--csv] [--timeout SECS] | cargo fw-test | cargo fw-bench [RECORDING]");
                std::process::exit(0);
            }
            other if other.starts_with('-') => return Err(format!("unknown option {other}")),
            other => recording = Some(PathBuf::from(other)),
        }
    }
    let recording = recording.unwrap_or_else(|| workspace_root().join(DEFAULT_RECORDING));
    let recording = recording.canonicalize().map_err(|e| format!("recording {}: {e}", recording.display()))?;
    Ok(Args { mode, recording, timeout })
}

// ------------------------------------------------------------------ tools

fn succeeds(command: &mut Command) -> bool {
    command.stdout(Stdio::null()).stderr(Stdio::null()).status().is_ok_and(|s| s.success())
}

fn run_checked(command: &mut Command) -> Result<()> {
    let status = command.status().map_err(|e| format!("{command:?}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{command:?} failed: {status}"))
    }
}

fn on_path(tool: &str) -> bool {
    succeeds(Command::new(tool).arg("--version"))
}

/// Installs what is missing, and only that.
fn ensure_tools() -> Result<()> {
    let installed = Command::new("rustup").args(["target", "list", "--installed"]).output();
    if !installed.is_ok_and(|o| String::from_utf8_lossy(&o.stdout).lines().any(|l| l.trim() == TARGET)) {
        eprintln!("fw: installing the {TARGET} target");
        run_checked(Command::new("rustup").args(["target", "add", TARGET]))?;
    }
    if !on_path("qemu-system-arm") {
        eprintln!("fw: installing qemu-system-arm");
        let install = || succeeds(Command::new("apt-get").args(["install", "-y", "qemu-system-arm"]));
        if !install() {
            run_checked(Command::new("apt-get").arg("update"))?;
            run_checked(Command::new("apt-get").args(["install", "-y", "qemu-system-arm"]))?;
        }
    }
    if !on_path("defmt-print") {
        eprintln!("fw: installing defmt-print");
        run_checked(Command::new("cargo").args(["install", "--locked", "defmt-print"]))?;
    }
    Ok(())
}

fn build_firmware() -> Result<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    run_checked(
        Command::new(cargo)
            .current_dir(workspace_root())
            .args(["build", "--quiet", "--release", "-p", "flatland-firmware", "--target", TARGET]),
    )?;
    let target_dir = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| workspace_root().join("target"));
    Ok(target_dir.join(TARGET).join("release"))
}

// ------------------------------------------------------------------ recording

/// rig.toml's values. A line-based reader for the flat layout of
/// RECORDING.md (sections, `key = number`, `distortion = [..]`).
fn read_rig(path: &Path) -> Result<RigRecord> {
    let text = fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut values: BTreeMap<String, String> = BTreeMap::new();
    let mut section = String::new();
    for line in text.lines() {
        let line = line.split('#').next().unwrap_or("").trim();
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = name.trim().to_string();
        } else if let Some((key, value)) = line.split_once('=') {
            values.insert(format!("{section}.{}", key.trim()), value.trim().to_string());
        }
    }
    let number = |key: &str| -> Result<f64> {
        let raw = values.get(key).ok_or_else(|| format!("{}: missing {key}", path.display()))?;
        raw.parse().map_err(|_| format!("{}: {key} = {raw} is not a number", path.display()))
    };
    let side = |key: &str| -> Result<u16> {
        let value = number(key)?;
        if value.fract() == 0.0 && (0.0..=f64::from(u16::MAX)).contains(&value) {
            Ok(value as u16)
        } else {
            Err(format!("{}: {key} is not an image size", path.display()))
        }
    };
    let distortion = match values.get("camera.distortion") {
        None => None,
        Some(raw) => {
            let inner = raw.trim().trim_start_matches('[').trim_end_matches(']');
            let coefficients: Vec<f64> = inner
                .split(',')
                .map(|s| s.trim().parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| format!("{}: camera.distortion is not a list of numbers", path.display()))?;
            let five: [f64; 5] = coefficients
                .try_into()
                .map_err(|_| format!("{}: camera.distortion needs 5 numbers", path.display()))?;
            Some(five)
        }
    };
    Ok(RigRecord {
        width: side("camera.width")?,
        height: side("camera.height")?,
        fx: number("camera.fx")?,
        fy: number("camera.fy")?,
        cx: number("camera.cx")?,
        cy: number("camera.cy")?,
        distortion,
        height_mm: number("mount.height_mm")?,
        tilt_deg: number("mount.tilt_deg")?,
        aoi_half_width_mm: number("aoi.half_width_mm")?,
        aoi_near_mm: number("aoi.near_mm")?,
        aoi_far_mm: number("aoi.far_mm")?,
    })
}

fn read_poses(path: &Path) -> Result<Vec<Odometry>> {
    let text = fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut poses = Vec::new();
    for (index, line) in text.lines().enumerate().skip(1) {
        if line.trim().is_empty() {
            continue;
        }
        let bad = || format!("{}:{}: expected frame,t_s,x_mm,z_mm,yaw_deg", path.display(), index + 1);
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let [frame, t_s, x_mm, z_mm, yaw_deg] = fields.as_slice() else { return Err(bad()) };
        let float = |s: &str| s.parse::<f64>().map_err(|_| bad());
        poses.push(Odometry {
            frame: frame.parse().map_err(|_| bad())?,
            t_s: float(t_s)?,
            x_mm: float(x_mm)?,
            z_mm: float(z_mm)?,
            yaw_deg: float(yaw_deg)?,
        });
    }
    Ok(poses)
}

// ------------------------------------------------------------------ QEMU

fn qemu_command(elf: &Path, serial: &str, append: &str, icount: bool) -> Command {
    let mut command = Command::new("qemu-system-arm");
    command.args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"]);
    command.args(["-semihosting-config", "enable=on,target=native"]);
    command.args(["-serial", serial]);
    if icount {
        command.args(["-icount", "shift=0"]);
    }
    if !append.is_empty() {
        command.args(["-append", append]);
    }
    command.arg("-kernel").arg(elf);
    command
}

/// QEMU with its semihosting output piped through defmt-print.
struct Emulator {
    qemu: Child,
    decoder: Child,
    log: thread::JoinHandle<String>,
}

impl Emulator {
    /// `echo_log`: print the decoded log live (else it is only collected).
    fn start(mut qemu: Command, elf: &Path, echo_log: bool) -> Result<Emulator> {
        let mut qemu = qemu.stdin(Stdio::null()).stdout(Stdio::piped()).spawn().map_err(|e| format!("qemu-system-arm: {e}"))?;
        let frames = qemu.stdout.take().ok_or("qemu stdout")?;
        let mut decoder = Command::new("defmt-print")
            .args(["--log-format", "{t} {L} {s}", "-e"])
            .arg(elf)
            .stdin(Stdio::from(frames))
            .stdout(Stdio::piped())
            .spawn()
            .map_err(|e| format!("defmt-print: {e}"))?;
        let output = decoder.stdout.take().ok_or("defmt-print stdout")?;
        let log = thread::spawn(move || {
            let mut collected = String::new();
            for line in BufReader::new(output).lines().map_while(io::Result::ok) {
                if echo_log {
                    println!("{line}");
                }
                collected.push_str(&line);
                collected.push('\n');
            }
            collected
        });
        Ok(Emulator { qemu, decoder, log })
    }

    /// Waits for QEMU's exit within `deadline`; kills it after.
    fn finish(mut self, deadline: Instant) -> Result<(ExitStatus, String)> {
        let status = loop {
            if let Some(status) = self.qemu.try_wait().map_err(|e| e.to_string())? {
                break status;
            }
            if Instant::now() >= deadline {
                let _ = self.qemu.kill();
                let _ = self.qemu.wait();
                let _ = self.decoder.wait();
                let log = self.log.join().unwrap_or_default();
                return Err(format!("QEMU timed out; the log so far:\n{log}"));
            }
            thread::sleep(Duration::from_millis(20));
        };
        let _ = self.decoder.wait();
        let log = self.log.join().unwrap_or_default();
        Ok((status, log))
    }
}

/// The serial side of a run: what was received, decoded and raw.
struct SerialOutcome {
    raw: Vec<u8>,
    stats: Option<LinkStats>,
}

/// Talks to the firmware over USART1: waits for `$FLRDY`, sends the rig,
/// the poses and `$FLEND`, and collects everything it sends back.
fn converse(
    listener: TcpListener,
    rig: RigRecord,
    poses: Vec<Odometry>,
    deadline: Instant,
    on_message: &mut dyn FnMut(&Message),
) -> Result<SerialOutcome> {
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    let stream = loop {
        match listener.accept() {
            Ok((stream, _)) => break stream,
            Err(e) if e.kind() == io::ErrorKind::WouldBlock && Instant::now() < deadline => {
                thread::sleep(Duration::from_millis(10))
            }
            Err(e) => return Err(format!("QEMU did not connect its serial port: {e}")),
        }
    };
    stream.set_nonblocking(false).map_err(|e| e.to_string())?;
    stream.set_read_timeout(Some(Duration::from_millis(200))).map_err(|e| e.to_string())?;
    let mut writer: Option<TcpStream> = Some(stream.try_clone().map_err(|e| e.to_string())?);
    let mut reader = stream;
    let (done_tx, done_rx) = mpsc::channel::<io::Result<()>>();
    let mut decoder = Decoder::new();
    let mut outcome = SerialOutcome { raw: Vec::new(), stats: None };
    let mut chunk = [0u8; 4096];
    loop {
        if Instant::now() >= deadline {
            return Err("timed out waiting for the firmware's serial output".into());
        }
        if let Ok(Err(e)) = done_rx.try_recv() {
            return Err(format!("sending to the firmware: {e}"));
        }
        let length = match reader.read(&mut chunk) {
            Ok(0) => break,
            Ok(length) => length,
            Err(e) if matches!(e.kind(), io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut) => continue,
            Err(e) => return Err(format!("serial: {e}")),
        };
        outcome.raw.extend_from_slice(&chunk[..length]);
        for &byte in &chunk[..length] {
            let Some(Ok(message)) = decoder.push(byte) else { continue };
            on_message(&message);
            match message {
                Message::Ready => {
                    // The firmware listens: send everything from a thread (QEMU
                    // reads the socket only as fast as the firmware drains USART1).
                    if let Some(mut out) = writer.take() {
                        let (rig, poses, done) = (rig, poses.clone(), done_tx.clone());
                        thread::spawn(move || {
                            let send = |out: &mut TcpStream, m: &Message| -> io::Result<()> {
                                let line = encode_line(m).map_err(|e| io::Error::other(format!("{e:?}")))?;
                                out.write_all(line.as_bytes())
                            };
                            let result = (|| {
                                send(&mut out, &Message::Rig(rig))?;
                                for pose in &poses {
                                    send(&mut out, &Message::Odometry(*pose))?;
                                }
                                send(&mut out, &Message::End)
                            })();
                            let _ = done.send(result);
                        });
                    }
                }
                Message::Stats(stats) => outcome.stats = Some(stats),
                _ => {}
            }
        }
        if outcome.stats.is_some() {
            break;
        }
    }
    Ok(outcome)
}

fn describe(message: &Message) -> Option<String> {
    match message {
        Message::Hello(rig) => Some(format!(
            "firmware ready: camera {}x{}, H {} mm, tilt {} deg",
            rig.width, rig.height, rig.height_mm, rig.tilt_deg
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
            "stats: {} frames; serial garbage {} B, truncated {}, too long {}, bad checksum {}, unknown {}, bad field {}, out of order {}, frame gaps {}",
            s.frames, s.garbage_bytes, s.truncated, s.too_long, s.bad_checksum, s.unknown_type, s.bad_field, s.out_of_order, s.frame_gaps
        )),
        _ => None,
    }
}

/// The main job, `--csv` and `--bench`: runs the firmware on a recording.
/// Returns the decoded log.
fn run_recording(args: &Args, release_dir: &Path) -> Result<String> {
    let rig = read_rig(&args.recording.join("rig.toml"))?;
    let poses = read_poses(&args.recording.join("poses.csv"))?;
    let elf = release_dir.join("flatland-firmware");
    let listener = TcpListener::bind("127.0.0.1:0").map_err(|e| format!("serial socket: {e}"))?;
    let port = listener.local_addr().map_err(|e| e.to_string())?.port();
    let bench = args.mode == Mode::Bench;
    let mut qemu = qemu_command(&elf, &format!("tcp:127.0.0.1:{port}"), if bench { "bench" } else { "" }, bench);
    qemu.current_dir(&args.recording);
    let deadline = Instant::now() + args.timeout;
    let emulator = Emulator::start(qemu, &elf, args.mode == Mode::Run)?;
    let human = args.mode == Mode::Run;
    let serial = converse(listener, rig, poses, deadline, &mut |message| {
        if human {
            if let Some(text) = describe(message) {
                println!("{text}");
            }
        }
    });
    let (status, log) = emulator.finish(deadline)?;
    let serial = serial?;
    if !status.success() {
        if !human {
            eprintln!("{log}");
        }
        return Err(format!("firmware failed ({status})"));
    }
    if args.mode == Mode::Csv {
        let stdout = io::stdout();
        serial_decode::run_serial_decode(&mut serial.raw.as_slice(), &mut stdout.lock()).map_err(|e| e.to_string())?;
    }
    if serial.stats.is_none() {
        return Err("the firmware ended without its statistics message".into());
    }
    Ok(log)
}

/// core's checks on the target, then the deliberate faults.
fn run_selftest(args: &Args, release_dir: &Path) -> Result<()> {
    let elf = release_dir.join("selftest");
    let deadline = Instant::now() + args.timeout;
    let (status, log) = Emulator::start(qemu_command(&elf, "null", "", false), &elf, true)?.finish(deadline)?;
    let summary = log.lines().find(|l| l.contains(" passed, ")).ok_or("selftest printed no summary")?;
    if !status.success() || !summary.contains(" 0 failed") {
        return Err(format!("on-target tests failed ({status}): {summary}"));
    }
    for (request, expected) in [("panic", "panic:"), ("hardfault", "HardFault")] {
        let deadline = Instant::now() + args.timeout;
        let (status, log) = Emulator::start(qemu_command(&elf, "null", request, false), &elf, false)?.finish(deadline)?;
        if status.success() || !log.contains(expected) {
            return Err(format!("a deliberate {request} did not end QEMU with a failure and a message:\n{log}"));
        }
        println!("fault path {request}: exit {status}, message {:?}", log.lines().find(|l| l.contains(expected)).unwrap_or(""));
    }
    Ok(())
}

/// Flash and RAM use of the firmware ELF, from its section headers.
fn memory_use(elf: &Path) -> Result<(u64, u64)> {
    let bytes = fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let u16_at = |o: usize| bytes.get(o..o + 2).map(|b| u16::from_le_bytes([b[0], b[1]]) as usize);
    let u32_at = |o: usize| bytes.get(o..o + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as u64);
    let bad = || format!("{}: not a 32-bit little-endian ELF", elf.display());
    if bytes.get(..6) != Some(&[0x7f, b'E', b'L', b'F', 1, 1][..]) {
        return Err(bad());
    }
    let section_table = u32_at(0x20).ok_or_else(bad)? as usize;
    let (entry_size, count) = (u16_at(0x2E).ok_or_else(bad)?, u16_at(0x30).ok_or_else(bad)?);
    let (mut flash, mut ram) = (0, 0);
    for i in 0..count {
        let header = section_table + i * entry_size;
        let (flags, address, size) = (
            u32_at(header + 8).ok_or_else(bad)?,
            u32_at(header + 12).ok_or_else(bad)?,
            u32_at(header + 20).ok_or_else(bad)?,
        );
        let kind = u32_at(header + 4).ok_or_else(bad)?;
        const ALLOC: u64 = 2;
        const NOBITS: u64 = 8;
        if flags & ALLOC == 0 {
            continue;
        }
        if (0x0800_0000..0x0810_0000).contains(&address) {
            flash += size;
        } else if (0x2000_0000..0x2002_0000).contains(&address) {
            ram += size;
            if kind != NOBITS {
                flash += size; // .data's initial values are stored in flash
            }
        }
    }
    Ok((flash, ram))
}

fn run_bench(args: &Args, release_dir: &Path) -> Result<()> {
    let log = run_recording(args, release_dir)?;
    let mut per_frame: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    let mut once: Vec<(String, String)> = Vec::new();
    for line in log.lines() {
        let Some((_, rest)) = line.split_once("bench: ") else { continue };
        let Some((key, value)) = rest.split_once(": ") else { continue };
        match key {
            "frame" => {}
            "table_build" | "stack_high_water_bytes" => once.push((key.to_string(), value.to_string())),
            _ => per_frame.entry(key.to_string()).or_default().extend(value.parse::<u64>().ok()),
        }
    }
    if per_frame.is_empty() {
        return Err("the firmware printed no benchmark figures".into());
    }
    println!("recording: {}", args.recording.display());
    println!("unit: instructions (TIM2 under -icount shift=0)");
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
    for stage in ["shift_search", "histogram", "decision", "gti"] {
        println!("{stage}: not_implemented");
    }
    let (flash, ram) = memory_use(&release_dir.join("flatland-firmware"))?;
    println!("flash_bytes: {flash}");
    println!("static_ram_bytes: {ram}");
    Ok(())
}

fn main() {
    let result = parse_args().and_then(|args| {
        ensure_tools()?;
        let release_dir = build_firmware()?;
        match args.mode {
            Mode::Run | Mode::Csv => run_recording(&args, &release_dir).map(drop),
            Mode::SelfTest => run_selftest(&args, &release_dir),
            Mode::Bench => run_bench(&args, &release_dir),
        }
    });
    if let Err(message) = result {
        eprintln!("fw: {message}");
        std::process::exit(1);
    }
}

//! Runs the firmware in QEMU (netduinoplus2): shared by `cargo fw*` (the
//! `fw` binary) and the QEMU tests (parity, robustness).
//!
//! QEMU's working directory is the recording, so the firmware reads
//! `frames/NNNNNN.pgm` through semihosting; USART1 is a TCP connection to
//! this runner, which sends a script of bytes once the firmware announces
//! `$FLRDY` (normally the rig, the poses and `$FLEND`, see [`host_script`])
//! and collects what the firmware sends back. The defmt log goes through
//! defmt-print. Every run has a deadline: QEMU is killed after it.
//! [`profile`]: where the firmware's instructions go, from QEMU's record.

pub mod profile;

use std::fs;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

use flatland_core::protocol::{encode_line, Decoder, LinkStats, Message, Odometry, RigRecord};

use crate::recording::Recording;

pub const TARGET: &str = "thumbv7em-none-eabihf";
pub const DEFAULT_RECORDING: &str = "host-tests/data/approach_box";

pub type Result<T> = std::result::Result<T, String>;

pub fn workspace_root() -> PathBuf {
    let manifest = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    manifest.parent().map(Path::to_path_buf).unwrap_or(manifest)
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

fn target_installed() -> bool {
    let installed = Command::new("rustup").args(["target", "list", "--installed"]).output();
    installed.is_ok_and(|o| String::from_utf8_lossy(&o.stdout).lines().any(|l| l.trim() == TARGET))
}

/// Installs what is missing, and only that (`cargo fw*`).
pub fn ensure_tools() -> Result<()> {
    if !target_installed() {
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

/// For tests: fails with a clear message when a tool is missing (tests do
/// not install; `.ci/test` runs `.ci/ensure-tools` first).
pub fn require_tools() -> Result<()> {
    let mut missing = Vec::new();
    if !target_installed() {
        missing.push(format!("the rustup target {TARGET}"));
    }
    for tool in ["qemu-system-arm", "defmt-print"] {
        if !on_path(tool) {
            missing.push(tool.to_string());
        }
    }
    if missing.is_empty() {
        Ok(())
    } else {
        Err(format!("QEMU tests need {}; run .ci/ensure-tools (or .ci/test, which runs it)", missing.join(", ")))
    }
}

/// Release build of the firmware with `features`; returns the directory of its ELF files.
fn cargo_build_firmware(features: &[&str]) -> Result<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut command = Command::new(cargo);
    command.current_dir(workspace_root()).args(["build", "--quiet", "--release", "-p", "flatland-firmware", "--target", TARGET]);
    if !features.is_empty() {
        command.arg("--features").arg(features.join(","));
    }
    run_checked(&mut command)?;
    let target_dir = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| workspace_root().join("target"));
    Ok(target_dir.join(TARGET).join("release"))
}

/// Release build of the firmware; returns the directory of its ELF files.
pub fn build_firmware() -> Result<PathBuf> {
    cargo_build_firmware(&[])
}

/// Release build of the `mavlink` firmware (MAVLink 2 on USART1); returns
/// its ELF, copied to `flatland-firmware-mavlink` beside the default one.
pub fn build_mavlink_firmware() -> Result<PathBuf> {
    let release = cargo_build_firmware(&["mavlink"])?;
    let elf = release.join("flatland-firmware-mavlink");
    fs::copy(release.join("flatland-firmware"), &elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    Ok(elf)
}

/// Release build of the `full-frame` firmware (256x256 keyframe, no GTI);
/// returns its ELF, copied to `flatland-firmware-full-frame` beside the
/// default one (cargo puts both builds at the same path).
pub fn build_full_frame_firmware() -> Result<PathBuf> {
    let release = cargo_build_firmware(&["full-frame"])?;
    let elf = release.join("flatland-firmware-full-frame");
    fs::copy(release.join("flatland-firmware"), &elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    Ok(elf)
}

// ------------------------------------------------------------------ what is sent

/// Which of a recording's sensors a run uses: `cargo fw REC --odometry
/// none` / `--imu none`, with the meaning they have on `flatland detect`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sensors {
    pub odometry: bool,
    pub imu: bool,
}

impl Sensors {
    /// Every sensor the recording has.
    pub const ALL: Sensors = Sensors { odometry: true, imu: true };

    /// Forgets the poses.csv columns of the sensors left out, as `flatland
    /// detect` does: their `$FLODO` fields are then absent.
    pub fn apply(self, recording: &mut Recording) {
        if !self.odometry {
            recording.ignore_odometry();
        }
        if !self.imu {
            recording.ignore_imu();
        }
    }
}

/// The messages a robot controller sends for a recording: the rig, one
/// `$FLODO` per poses.csv row (with the fields of the sensors it has), `$FLEND`.
pub fn host_messages(recording: &Recording) -> Vec<Message> {
    let mut messages = vec![Message::Rig(RigRecord::from(&recording.rig))];
    messages.extend(recording.poses.iter().map(|row| Message::Odometry(Odometry::from(row))));
    messages.push(Message::End);
    messages
}

/// Encodes messages into the byte script sent to the firmware.
pub fn encode_script(messages: &[Message]) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    for message in messages {
        let line = encode_line(message).map_err(|e| format!("cannot encode {}: {e:?}", message.tag()))?;
        bytes.extend_from_slice(line.as_bytes());
    }
    Ok(bytes)
}

/// The normal script for a recording.
pub fn host_script(recording: &Recording) -> Result<Vec<u8>> {
    encode_script(&host_messages(recording))
}

/// How an autopilot sends the poses to the `mavlink` firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PoseMessages {
    /// One `ODOMETRY` per frame.
    Odometry,
    /// `ATTITUDE` then `LOCAL_POSITION_NED` per frame.
    LocalPosition,
}

/// The `mavlink` firmware's script for a recording: the rig as `$FLRIG`,
/// one pose per poses.csv row as MAVLink 2 frames from the autopilot
/// (system 1, component 1), `$FLEND`.
pub fn mavlink_script(recording: &Recording, poses: PoseMessages) -> Result<Vec<u8>> {
    use flatland_core::mavlink::{local_position_for, odometry_for, MessageData};
    use flatland_core::pipeline::PoseSample;
    let mut bytes = encode_script(&[Message::Rig(RigRecord::from(&recording.rig))])?;
    let mut sequence = 0u8;
    let mut frame = |message: &dyn Fn(&mut mavlink::MAVLinkV2MessageRaw, mavlink::MavHeader), bytes: &mut Vec<u8>| {
        let header = mavlink::MavHeader { system_id: 1, component_id: 1, sequence };
        sequence = sequence.wrapping_add(1);
        let mut raw = mavlink::MAVLinkV2MessageRaw::new();
        message(&mut raw, header);
        bytes.extend_from_slice(raw.raw_bytes());
    };
    fn put<D: MessageData>(data: D) -> impl Fn(&mut mavlink::MAVLinkV2MessageRaw, mavlink::MavHeader) {
        move |raw, header| raw.serialize_message_data(header, &data)
    }
    for row in &recording.poses {
        let sample = PoseSample::from(row);
        match poses {
            PoseMessages::Odometry => frame(&put(odometry_for(&sample)), &mut bytes),
            PoseMessages::LocalPosition => {
                let (position, attitude) = local_position_for(&sample);
                frame(&put(attitude), &mut bytes);
                frame(&put(position), &mut bytes);
            }
        }
    }
    bytes.extend(encode_script(&[Message::End])?);
    Ok(bytes)
}

// ------------------------------------------------------------------ QEMU

fn qemu_command(elf: &Path, serial: &str, append: &str, icount: bool, exec_log: Option<&Path>) -> Command {
    let mut command = Command::new("qemu-system-arm");
    command.args(["-M", "netduinoplus2", "-nographic", "-monitor", "none"]);
    command.args(["-semihosting-config", "enable=on,target=native"]);
    command.args(["-serial", serial]);
    if icount {
        command.args(["-icount", "shift=0"]);
    }
    if let Some(path) = exec_log {
        command.args(crate::qemu::profile::qemu_args(path));
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
        let mut decoder = match Command::new("defmt-print")
            .args(["--log-format", "{t}s {L} {s}", "-e"])
            .arg(elf)
            .stdin(Stdio::from(frames))
            .stdout(Stdio::piped())
            .spawn()
        {
            Ok(decoder) => decoder,
            Err(e) => {
                let _ = qemu.kill();
                let _ = qemu.wait();
                return Err(format!("defmt-print: {e}"));
            }
        };
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

/// The serial side of a run.
#[derive(Debug, Default)]
pub struct SerialOutcome {
    /// Every byte the firmware sent.
    pub raw: Vec<u8>,
    /// Every message decoded from `raw`, in order.
    pub messages: Vec<Message>,
    /// The final `$FLSTA`, if it came.
    pub stats: Option<LinkStats>,
}

/// More bytes for the firmware once it has answered frame `after_frame`
/// (`$FLFRM` or `$FLERR` of that frame): each chunk after its pause. What a
/// robot does in time, as opposed to the script sent at once: stop sending
/// for a while, send noise for a while.
#[derive(Clone, Debug, Default)]
pub struct Continuation {
    pub after_frame: u32,
    pub chunks: Vec<(Duration, Vec<u8>)>,
}

/// The frame a firmware message answers, if it answers one.
fn answered_frame(message: &Message) -> Option<u32> {
    match message {
        Message::Frame(report) => Some(report.frame),
        Message::Fault(fault) if fault.frame != 0 => Some(fault.frame),
        _ => None,
    }
}

/// Talks to the firmware over USART1: waits for `$FLRDY`, sends `script`
/// (from a thread: QEMU reads the socket only as fast as the firmware
/// drains USART1), then `then` when its frame is answered, and collects
/// everything it sends back until `$FLSTA`.
fn converse(
    listener: TcpListener,
    script: Vec<u8>,
    then: Option<Continuation>,
    deadline: Instant,
    mavlink: bool,
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
    let mut later_writer: Option<TcpStream> = Some(stream.try_clone().map_err(|e| e.to_string())?);
    let mut script = Some(script);
    let mut then = then;
    let mut reader = stream;
    let (done_tx, done_rx) = mpsc::channel::<io::Result<()>>();
    let mut decoder = Decoder::new();
    let mut outcome = SerialOutcome::default();
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
        if mavlink {
            // No lines: the first bytes (the firmware's HEARTBEAT) say it
            // listens; the run ends when QEMU closes the port.
            if let (Some(mut out), Some(bytes)) = (writer.take(), script.take()) {
                let done = done_tx.clone();
                thread::spawn(move || {
                    let _ = done.send(out.write_all(&bytes));
                });
            }
            continue;
        }
        for &byte in &chunk[..length] {
            let Some(Ok(message)) = decoder.push(byte) else { continue };
            on_message(&message);
            match message {
                Message::Ready => {
                    if let (Some(mut out), Some(bytes)) = (writer.take(), script.take()) {
                        let done = done_tx.clone();
                        thread::spawn(move || {
                            let _ = done.send(out.write_all(&bytes));
                        });
                    }
                }
                Message::Stats(stats) => outcome.stats = Some(stats),
                _ => {}
            }
            if then.as_ref().is_some_and(|c| answered_frame(&message) == Some(c.after_frame)) {
                if let (Some(mut out), Some(continuation)) = (later_writer.take(), then.take()) {
                    let done = done_tx.clone();
                    thread::spawn(move || {
                        let sent = continuation.chunks.iter().try_for_each(|(pause, bytes)| {
                            thread::sleep(*pause);
                            out.write_all(bytes)
                        });
                        let _ = done.send(sent);
                    });
                }
            }
            outcome.messages.push(message);
        }
        if outcome.stats.is_some() {
            break;
        }
    }
    Ok(outcome)
}

/// One firmware run.
pub struct RunRequest<'a> {
    /// The firmware ELF.
    pub elf: &'a Path,
    /// QEMU's working directory (the recording).
    pub dir: &'a Path,
    /// Bytes sent on USART1 after `$FLRDY`.
    pub script: Vec<u8>,
    /// Bytes sent later, once a frame is answered.
    pub then: Option<Continuation>,
    /// `-icount shift=0` and the `bench` command line; `Some(x)` also fixes
    /// the KG resolution (`mm_per_px=x`), `bench_no_margins` makes the grid
    /// the AOI alone (`no_margins`, the full-frame benchmark).
    pub bench: bool,
    pub bench_mm_per_px: Option<f64>,
    pub bench_no_margins: bool,
    /// Print the defmt log live.
    pub echo_log: bool,
    /// QEMU's record of every block it runs, for [`crate::qemu::profile`].
    pub exec_log: Option<&'a Path>,
    pub timeout: Duration,
    /// The firmware speaks MAVLink (the `mavlink` build): the script goes
    /// at its first bytes and the run ends at QEMU's exit.
    pub mavlink: bool,
}

/// What a run produced.
pub struct RunOutcome {
    pub status: ExitStatus,
    /// The decoded defmt log.
    pub log: String,
    pub serial: SerialOutcome,
}

/// Runs the firmware once. `on_message` sees every decoded message as it comes.
/// Errors: QEMU could not start, the deadline passed, or the serial link failed.
pub fn run_firmware(request: RunRequest, on_message: &mut dyn FnMut(&Message)) -> Result<RunOutcome> {
    let listener = TcpListener::bind("127.0.0.1:0").map_err(|e| format!("serial socket: {e}"))?;
    let port = listener.local_addr().map_err(|e| e.to_string())?.port();
    let mut append = match (request.bench, request.bench_mm_per_px) {
        (false, _) => String::new(),
        (true, None) => "bench".to_string(),
        (true, Some(mm)) => format!("bench mm_per_px={mm}"),
    };
    if request.bench && request.bench_no_margins {
        append.push_str(" no_margins");
    }
    let mut qemu = qemu_command(request.elf, &format!("tcp:127.0.0.1:{port}"), &append, request.bench, request.exec_log);
    qemu.current_dir(request.dir);
    let deadline = Instant::now() + request.timeout;
    let emulator = Emulator::start(qemu, request.elf, request.echo_log)?;
    let serial = converse(listener, request.script, request.then, deadline, request.mavlink, on_message);
    let (status, log) = emulator.finish(deadline)?;
    let serial = serial.map_err(|e| format!("{e}; firmware exit {status}; log:\n{log}"))?;
    Ok(RunOutcome { status, log, serial })
}

/// core's checks on the target (`selftest` ELF), or a deliberate fault
/// (`request` = "panic" / "hardfault"). Returns the exit status and the log.
pub fn run_selftest(elf: &Path, request: &str, echo_log: bool, timeout: Duration) -> Result<(ExitStatus, String)> {
    Emulator::start(qemu_command(elf, "null", request, false, None), elf, echo_log)?.finish(Instant::now() + timeout)
}

/// Flash and RAM use of the firmware ELF, from its section headers: RAM
/// counts every static, the CCM's too (the budget is the chip's 192 KB).
pub fn memory_use(elf: &Path) -> Result<(u64, u64)> {
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
        } else if (0x2000_0000..0x2003_0000).contains(&address) || (0x1000_0000..0x1001_0000).contains(&address) {
            // SRAM, with the CCM's statics (the QEMU bins put them in the
            // upper 64K of SRAM, the board's at 0x10000000): all of it is RAM.
            ram += size;
            if kind != NOBITS {
                flash += size; // .data's initial values are stored in flash
            }
        }
    }
    Ok((flash, ram))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--odometry none` leaves x_mm,z_mm,yaw_deg out of `$FLODO`, `--imu
    /// none` pitch_deg,roll_deg.
    #[test]
    fn sensors_choose_the_odometry_fields() {
        let line = |odometry, imu| {
            let mut recording = Recording::open(workspace_root().join("host-tests/data/bumpy_marks")).unwrap();
            Sensors { odometry, imu }.apply(&mut recording);
            encode_line(&host_messages(&recording)[2]).unwrap()
        };
        let poses = std::fs::read_to_string(workspace_root().join("host-tests/data/bumpy_marks/poses.csv")).unwrap();
        assert!(poses.starts_with("frame,t_s,x_mm,z_mm,yaw_deg,pitch_deg,roll_deg\n"), "{poses}");
        let row: Vec<&str> = poses.lines().nth(2).unwrap().split(',').collect();
        let expected = |fields: &[usize]| {
            let body = format!("FLODO,{}", fields.iter().map(|&i| row[i].parse::<f64>().unwrap().to_string()).collect::<Vec<_>>().join(","));
            format!("${body}*{:02X}\r\n", flatland_core::protocol::checksum(body.as_bytes()))
        };
        assert_eq!(line(true, true).as_str(), expected(&[0, 1, 2, 3, 4, 5, 6]));
        assert_eq!(line(true, false).as_str(), expected(&[0, 1, 2, 3, 4]));
        assert_eq!(line(false, true).as_str(), expected(&[0, 1, 5, 6]));
        assert_eq!(line(false, false).as_str(), expected(&[0, 1]));
    }
}

//! The frame loop speaking MAVLink 2 (feature `mavlink`): the same stages
//! and pipeline as [`crate::frame_loop`], talking to an autopilot.
//!
//! - Out: `HEARTBEAT` (component `MAV_COMP_ID_OBSTACLE_AVOIDANCE`) at
//!   start, on every change of its status, and at most once a second
//!   between frames; `OBSTACLE_DISTANCE` per frame (the scan, `core::mavlink::obstacle_distance`; every element
//!   unknown for a frame that only (re)started the keyframe or was not
//!   judged, since nothing was compared); `STATUSTEXT` on the rig, on every
//!   fault and on every frame not judged (`frame N not judged: REASON`,
//!   a warning), and the counters at the end.
//! - In: `ODOMETRY`, or `LOCAL_POSITION_NED` with the latest `ATTITUDE`
//!   (when no `ODOMETRY` has come), each one starting the next camera frame
//!   with that pose sample; the rig as the line protocol's `$FLRIG` (once,
//!   from a PC or companion; MAVLink has no message for it) and `$FLEND`
//!   (the emulated runs' end). Lines are told apart from frames by their
//!   `$` between MAVLink frames. Garbage, damaged, foreign and MAVLink 1
//!   frames are counted (`core::mavlink::MavStats`) and skipped.
//! - Fail-safe as the line protocol's loop (`flatland_core::health`): the
//!   alarm pin is asserted until a frame is judged clear, and again on every
//!   frame without a verdict, a camera timeout and odometry that stops for
//!   0.5 s; the loop polls, feeds the watchdog and sends the heartbeats while
//!   it waits. `HEARTBEAT.system_status` is the monitor's health.
//!
//! Frames are numbered by arrival from 0: on the emulated board frame n is
//! `frames/NNNNNN.pgm`, so a run sends one pose per recorded frame.

use core::fmt::Write as _;

use embedded_hal::digital::OutputPin;
use embedded_io::{Read, ReadReady, Write};
use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::health::Monitor;
use flatland_core::mavlink::common::{MavSeverity, ATTITUDE_DATA};
use flatland_core::mavlink::{
    heartbeat, obstacle_distance, sample_from_local_position, sample_from_odometry, status_text, FrameDecoder, Inbound, MavStats,
    MessageData, Sender, Status,
};
use flatland_core::pipeline::{Outcome, Pipeline, PoseSample};
use flatland_core::protocol::{Decoder, LinkStats, Message};
use flatland_core::remap::RemapTable;
use flatland_core::scan::Scan;

use crate::board::{Clock, CycleCounter, RowSource, Watchdog};
use crate::frame_loop::{
    bump, ccm_image, gti_stage, log_report, set_up, stream_frame, AlarmOutput, Board, Camera, Guard, Inbox, Link, LoopCounters, Options,
    DETECTOR, IMAGE, RING, TABLE,
};

/// Microseconds between heartbeats (1 Hz).
const HEARTBEAT_PERIOD_US: u32 = 1_000_000;

/// The serial port's two kinds of input, told apart.
enum Input {
    Line(Message),
    Mav(Inbound),
}

struct Port<S> {
    link: Link<S>,
    mav: FrameDecoder,
    sender: Sender,
    /// A `$` line is being read (between MAVLink frames).
    in_line: bool,
    status: Status,
    /// When the last heartbeat went out (us, the board's clock).
    last_heartbeat_us: u32,
}

impl<S: Read + ReadReady + Write> Inbox for Port<S> {
    type Item = Input;

    /// The next message of either kind among the bytes waiting; what does
    /// not decode is counted.
    fn poll(&mut self) -> Option<Input> {
        while self.link.serial.read_ready().unwrap_or(true) {
            let mut byte = [0u8; 1];
            match self.link.serial.read(&mut byte) {
                Ok(1) => {}
                Ok(_) => continue,
                Err(_) => {
                    bump(&mut self.link.counters.serial_overruns);
                    continue;
                }
            }
            let byte = byte[0];
            if self.in_line || (self.mav.idle() && byte == b'$') {
                self.in_line = true;
                match self.link.decoder.push(byte) {
                    Some(Ok(message)) => {
                        self.in_line = false;
                        return Some(Input::Line(message));
                    }
                    Some(Err(error)) => {
                        self.in_line = false;
                        defmt::warn!("serial: dropped a line ({})", error);
                    }
                    None => {}
                }
                continue;
            }
            match self.mav.push(byte) {
                Some(Ok(message)) => return Some(Input::Mav(message)),
                Some(Err(error)) => defmt::warn!("mavlink: dropped a frame ({})", error),
                None => {}
            }
        }
        None
    }

    fn odometry_lost(&mut self, frame: u32) {
        self.text(MavSeverity::MAV_SEVERITY_ERROR, &short(format_args!("odometry_lost after frame {}", frame)));
    }

    fn idle(&mut self, monitor: &Monitor, now_us: u32) {
        self.follow(monitor, now_us);
        self.heartbeat_due(now_us);
    }
}

impl<S: Read + ReadReady + Write> Port<S> {
    fn send<D: MessageData>(&mut self, message: &D) {
        let frame = self.sender.encode(message);
        if self.link.serial.write_all(frame.as_bytes()).is_err() {
            defmt::warn!("serial: write failed");
        }
    }

    fn heartbeat(&mut self, now_us: u32) {
        self.last_heartbeat_us = now_us;
        self.send(&heartbeat(self.status));
    }

    /// A heartbeat if a second has passed since the last.
    fn heartbeat_due(&mut self, now_us: u32) {
        if now_us.wrapping_sub(self.last_heartbeat_us) >= HEARTBEAT_PERIOD_US {
            self.heartbeat(now_us);
        }
    }

    fn text(&mut self, severity: MavSeverity, text: &str) {
        self.send(&status_text(severity, text));
    }

    /// The status follows the monitor's health, and every change is
    /// announced at once (docs/MAVLINK.md: a heartbeat at start, on every change of
    /// `system_status`, and at most once a second between frames). A run
    /// shorter than a second still tells the autopilot it went active.
    fn follow(&mut self, monitor: &Monitor, now_us: u32) {
        let status = Status::from(monitor.health());
        if status != self.status {
            self.status = status;
            self.heartbeat(now_us);
        }
    }

    /// A fault that is not the monitor's (a refused rig or pose): `STATUSTEXT`.
    fn fault(&mut self, text: &str) {
        defmt::error!("fault: {=str}", text);
        self.text(MavSeverity::MAV_SEVERITY_ERROR, text);
    }

    /// The line counters with the MAVLink decoder's folded in.
    fn stats(&self) -> LinkStats {
        let mut stats = self.link.stats();
        let mav: MavStats = self.mav.stats();
        stats.garbage_bytes = stats.garbage_bytes.saturating_add(mav.garbage_bytes);
        stats.bad_checksum = stats.bad_checksum.saturating_add(mav.checksum);
        stats.unknown_type = stats.unknown_type.saturating_add(mav.foreign).saturating_add(mav.version1);
        stats.bad_field = stats.bad_field.saturating_add(mav.payload).saturating_add(mav.incompatible);
        stats
    }

    /// The end of a run: the counters as a `STATUSTEXT`.
    fn finish(&mut self) -> LinkStats {
        let stats = self.stats();
        let mut text: heapless::String<50> = heapless::String::new();
        let _ = write!(
            text,
            "end f{} g{} c{} u{} b{} o{} a{}",
            stats.frames, stats.garbage_bytes, stats.bad_checksum, stats.unknown_type, stats.bad_field, stats.out_of_order, stats.aborted
        );
        self.text(MavSeverity::MAV_SEVERITY_INFO, &text);
        stats
    }
}

/// A short text (fits a `STATUSTEXT`).
fn short(args: core::fmt::Arguments) -> heapless::String<50> {
    let mut text = heapless::String::new();
    let _ = text.write_fmt(args);
    text
}

/// Runs until `$FLEND`; returns the final counters. The alarm pin is left
/// asserted, and kept (not dropped, which on a real board would float it).
pub fn run<S, A, C, R, K, W>(board: Board<S, A, C, R, K, W>, options: &Options) -> LinkStats
where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    let Board { serial, alarm, counter, mut frames, clock, mut watchdog } = board;
    let link = Link { serial, decoder: Decoder::new(), counters: LoopCounters::default() };
    let mut port =
        Port { link, mav: FrameDecoder::new(), sender: Sender::default(), in_line: false, status: Status::Starting, last_heartbeat_us: 0 };
    let mut alarm = AlarmOutput::new(alarm);
    let mut monitor = Monitor::new();
    let guard = Guard { alarm: &mut alarm, monitor: &mut monitor, clock: &clock, watchdog: &mut watchdog, last_frame: 0 };
    let stats = serve(&mut port, guard, &counter, &mut frames, options);
    alarm.assert_at_end();
    core::mem::forget(alarm);
    stats
}

fn serve<S, A, C, R, K, W>(port: &mut Port<S>, mut guard: Guard<A, K, W>, counter: &C, frames: &mut R, options: &Options) -> LinkStats
where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    let table: &'static mut RemapTable = TABLE.take();
    let ring = RING.take();
    let image = IMAGE.take();
    let Some(ccm_image) = ccm_image() else { return port.finish() };
    let gpa: &'static mut Gpa<'static> = DETECTOR.take();
    port.heartbeat(guard.clock.now_us());

    // The rig, as a `$FLRIG` line.
    let (rig, grid) = loop {
        match guard.receive(port) {
            Input::Line(Message::Rig(record)) => {
                guard.watchdog.feed();
                match set_up(&record, table, options) {
                    Ok(built) => {
                        defmt::info!("rig accepted: camera {=u16}x{=u16}", record.width, record.height);
                        port.text(MavSeverity::MAV_SEVERITY_INFO, &short(format_args!("rig {}x{} accepted", record.width, record.height)));
                        break built;
                    }
                    Err(error) => {
                        defmt::error!("rig refused: {}", error);
                        port.fault(&short(format_args!("rig refused: {:?}", error)));
                    }
                }
            }
            Input::Line(Message::End) => return port.finish(),
            Input::Line(_) => bump(&mut port.link.counters.out_of_order),
            Input::Mav(_) => {}
        }
    };
    let table: &RemapTable = table;
    let camera = (table.camera_width(), table.camera_height());
    guard.watchdog.feed();
    if let Err(error) = gpa.init_split(&rig, &grid, table, GpaConfig::default(), &mut image[..], &mut ccm_image[..]) {
        port.fault(&short(format_args!("detector refused: {}", error)));
        return port.finish();
    }
    let Some(gti) = gti_stage(&mut port.link, &rig, &grid) else { return port.finish() };
    let mut pipeline = match Pipeline::new(table, &mut ring[..], gpa, gti) {
        Ok(pipeline) => pipeline,
        Err(error) => {
            port.fault(&short(format_args!("pipeline refused: {}", error)));
            return port.finish();
        }
    };

    let mut next_frame: u32 = 0;
    let mut attitude: Option<ATTITUDE_DATA> = None;
    let mut odometry_seen = false;
    loop {
        let sample = match guard.receive(port) {
            Input::Line(Message::End) => break,
            Input::Line(_) => {
                bump(&mut port.link.counters.out_of_order);
                continue;
            }
            Input::Mav(Inbound::Odometry(odometry)) => {
                odometry_seen = true;
                sample_from_odometry(&odometry)
            }
            Input::Mav(Inbound::Attitude(latest)) => {
                attitude = Some(latest);
                continue;
            }
            Input::Mav(Inbound::LocalPosition(position)) => match (&attitude, odometry_seen) {
                (Some(attitude), false) => sample_from_local_position(&position, attitude),
                _ => continue,
            },
            Input::Mav(Inbound::Heartbeat { .. }) => continue,
        };
        let frame = next_frame;
        next_frame = next_frame.wrapping_add(1);
        guard.monitor.odometry(guard.clock.now_us());
        guard.last_frame = frame;
        serve_frame(port, &mut guard, counter, frames, &mut pipeline, frame, sample, camera);
        // The odometry timer counts from here: the frame's own time is not the robot's silence.
        let now = guard.clock.now_us();
        guard.monitor.waiting(now);
        port.follow(guard.monitor, now);
        port.heartbeat_due(now);
    }
    port.finish()
}

/// One pose's frame, from the pose to `OBSTACLE_DISTANCE` and the alarm.
#[allow(clippy::too_many_arguments)]
fn serve_frame<S, A, C, R, K, W>(
    port: &mut Port<S>,
    guard: &mut Guard<A, K, W>,
    counter: &C,
    frames: &mut R,
    pipeline: &mut Pipeline,
    frame: u32,
    sample: Result<PoseSample, flatland_core::mavlink::PoseError>,
    camera: (usize, usize),
) where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    let sample = match sample {
        Ok(sample) => sample,
        Err(error) => {
            // No usable pose: the frame is not taken and the next restarts.
            port.fault(&short(format_args!("frame {}: pose: {}", frame, error)));
            pipeline.restart();
            guard.monitor.unjudged();
            guard.alarm.follow(guard.monitor, frame);
            return;
        }
    };
    let time_usec = libm::round(sample.t_s * 1e6).max(0.0) as u64;
    if let Err(error) = pipeline.begin(frame, sample) {
        defmt::warn!("frame {=u32} skipped: {}", frame, error);
        guard.monitor.unjudged();
        guard.alarm.follow(guard.monitor, frame);
        return;
    }
    let mut read = 0;
    let parts = Camera { frames: &mut *frames, counter, clock: guard.clock, watchdog: &mut *guard.watchdog };
    match stream_frame(parts, pipeline, frame, camera, &mut read) {
        Ok(Outcome::Compared(report)) => {
            // The pin first: it is what the robot acts on.
            guard.monitor.judged(report.alarm);
            guard.alarm.follow(guard.monitor, frame);
            port.send(&obstacle_distance(pipeline.gpa().scan(), time_usec));
            log_report(&report);
        }
        Ok(Outcome::NotJudged(report)) => {
            // As a keyframe restart: the alarm, every element unknown (the
            // detector's scan is the last judged frame's: a stale clear),
            // and the reason as text.
            guard.monitor.unjudged();
            guard.alarm.follow(guard.monitor, frame);
            port.send(&obstacle_distance(&Scan::new(pipeline.gpa().scan().layout()), time_usec));
            port.text(MavSeverity::MAV_SEVERITY_WARNING, &short(format_args!("frame {} not judged: {}", frame, report.status)));
            log_report(&report);
        }
        Ok(Outcome::Keyframe { .. }) => {
            guard.monitor.unjudged();
            guard.alarm.follow(guard.monitor, frame);
            // Nothing compared: every element unknown.
            port.send(&obstacle_distance(&Scan::new(pipeline.gpa().scan().layout()), time_usec));
        }
        Err(failure) => {
            frames.end_frame();
            pipeline.abort();
            if failure.mid_frame {
                bump(&mut port.link.counters.aborted);
            }
            guard.monitor.frame_failed(failure.sensor_fault());
            guard.alarm.follow(guard.monitor, frame);
            port.text(MavSeverity::MAV_SEVERITY_ERROR, &short(format_args!("frame {}: {}", frame, failure.code.as_str())));
            return;
        }
    }
    bump(&mut port.link.counters.frames);
}

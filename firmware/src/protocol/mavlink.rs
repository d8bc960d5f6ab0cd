//! MAVLink 2 (feature `mavlink`), talking to an autopilot.
//!
//! - Out: `HEARTBEAT` (component `MAV_COMP_ID_OBSTACLE_AVOIDANCE`) at
//!   start, on every change of its status (the fail-safe's health), and at
//!   most once a second between frames; `OBSTACLE_DISTANCE` per frame (the
//!   scan, `core::mavlink::obstacle_distance`), and for a frame that only
//!   (re)started the keyframe, was not judged or was given up (late camera,
//!   lost frame), and when odometry stops, doubt: a hazard at the nearest
//!   range wherever the camera looks (`obstacle_distance_in_doubt`), which
//!   holds ArduPilot and PX4 back where all-unknown would release them;
//!   `STATUSTEXT` on the rig, on every fault and on every frame not judged
//!   (`frame N not judged: REASON`, a warning), and the counters at the end.
//! - In: `ODOMETRY`, or `LOCAL_POSITION_NED` with the latest `ATTITUDE`
//!   (when no `ODOMETRY` has come), each one starting the next camera frame
//!   with that pose sample (poses before the rig are dropped: an autopilot
//!   streams them regardless); the rig as the line protocol's `$FLRIG` (once,
//!   from a PC or companion; MAVLink has no message for it) and `$FLEND`
//!   (the emulated runs' end). Lines are told apart from frames by their
//!   `$` between MAVLink frames. Garbage, damaged, foreign and MAVLink 1
//!   frames are counted (`core::mavlink::MavStats`) and skipped.
//!
//! Frames are numbered by arrival from 0: on the emulated board frame n is
//! `frames/NNNNNN.pgm`, so a run sends one pose per recorded frame.

use core::fmt::Write as _;

use embedded_io::{Read, ReadReady, Write};
use flatland_core::health::Health;
use flatland_core::mavlink::common::{MavSeverity, ATTITUDE_DATA};
use flatland_core::mavlink::{
    heartbeat, obstacle_distance, obstacle_distance_in_doubt, sample_from_local_position, sample_from_odometry, status_text, FrameDecoder, Inbound, MessageData,
    PoseError, Sender, Status,
};
use flatland_core::pipeline::Outcome;
use flatland_core::protocol::{Decoder, DecoderStats, FaultCode, LinkStats, RigRecord};
use flatland_core::scan::{Scan, ScanLayout};

use super::{line_input, Input, Protocol, SerialPort};
use crate::frame_loop::SetupError;

/// Microseconds between heartbeats (1 Hz).
const HEARTBEAT_PERIOD_US: u32 = 1_000_000;

pub struct Mavlink<S> {
    port: SerialPort<S>,
    lines: Decoder,
    /// A `$` line is being read (between MAVLink frames).
    in_line: bool,
    frames: FrameDecoder,
    sender: Sender,
    status: Status,
    /// When the last heartbeat went out (us, the board's clock).
    last_heartbeat_us: u32,
    /// The latest `ATTITUDE`, for a `LOCAL_POSITION_NED`.
    attitude: Option<ATTITUDE_DATA>,
    /// An `ODOMETRY` came: `LOCAL_POSITION_NED` is ignored from then on.
    odometry_seen: bool,
    /// The last frame's scan layout and time (us), for the doubt sent when
    /// odometry stops.
    last_frame: Option<(ScanLayout, u64)>,
}

/// The serial port's two kinds of input, told apart.
enum Received {
    Line(flatland_core::protocol::Message),
    Mav(Inbound),
}

impl<S: Read + ReadReady + Write> Mavlink<S> {
    /// The next line or MAVLink message among the bytes waiting.
    fn receive(&mut self) -> Option<Received> {
        while let Some(byte) = self.port.next_byte() {
            if self.in_line || (self.frames.idle() && byte == b'$') {
                self.in_line = true;
                match self.lines.push(byte) {
                    Some(Ok(message)) => {
                        self.in_line = false;
                        return Some(Received::Line(message));
                    }
                    Some(Err(error)) => {
                        self.in_line = false;
                        defmt::warn!("serial: dropped a line ({})", error);
                    }
                    None => {}
                }
                continue;
            }
            match self.frames.push(byte) {
                Some(Ok(message)) => return Some(Received::Mav(message)),
                Some(Err(error)) => defmt::warn!("mavlink: dropped a frame ({})", error),
                None => {}
            }
        }
        None
    }

    fn send<D: MessageData>(&mut self, message: &D) {
        let frame = self.sender.encode(message);
        self.port.write(frame.as_bytes());
    }

    fn heartbeat(&mut self, now_us: u32) {
        self.last_heartbeat_us = now_us;
        self.send(&heartbeat(self.status));
    }

    fn text(&mut self, severity: MavSeverity, text: &str) {
        self.send(&status_text(severity, text));
    }

    /// `OBSTACLE_DISTANCE` saying doubt wherever the camera looks (never
    /// a stale clear, never unknown, which the autopilots read as free).
    fn doubt(&mut self, layout: ScanLayout, time_usec: u64) {
        self.last_frame = Some((layout, time_usec));
        self.send(&obstacle_distance_in_doubt(&layout, time_usec));
    }
}

/// A pose's time `t_s` as `time_usec` (negative times as 0).
fn time_usec(t_s: f64) -> u64 {
    libm::round(t_s * 1e6).max(0.0) as u64
}

/// A short text (fits a `STATUSTEXT`).
fn short(args: core::fmt::Arguments) -> heapless::String<50> {
    let mut text = heapless::String::new();
    let _ = text.write_fmt(args);
    text
}

impl<S: Read + ReadReady + Write> Protocol for Mavlink<S> {
    type Serial = S;
    type PoseError = PoseError;
    const POSES_STREAM: bool = true;

    fn new(serial: S) -> Self {
        Mavlink {
            port: SerialPort::new(serial),
            lines: Decoder::new(),
            in_line: false,
            frames: FrameDecoder::new(),
            sender: Sender::default(),
            status: Status::Starting,
            last_heartbeat_us: 0,
            attitude: None,
            odometry_seen: false,
            last_frame: None,
        }
    }

    fn poll(&mut self) -> Option<Input<PoseError>> {
        loop {
            let sample = match self.receive()? {
                Received::Line(message) => return Some(line_input(message, false)),
                Received::Mav(Inbound::Odometry(odometry)) => {
                    self.odometry_seen = true;
                    sample_from_odometry(&odometry)
                }
                Received::Mav(Inbound::Attitude(latest)) => {
                    self.attitude = Some(latest);
                    continue;
                }
                Received::Mav(Inbound::LocalPosition(position)) => match (&self.attitude, self.odometry_seen) {
                    (Some(attitude), false) => sample_from_local_position(&position, attitude),
                    _ => continue,
                },
                Received::Mav(Inbound::Heartbeat { .. }) => continue,
            };
            return Some(Input::Pose { frame: None, sample });
        }
    }

    fn listening(&mut self, now_us: u32) {
        self.heartbeat(now_us);
    }

    fn rig_accepted(&mut self, record: &RigRecord) {
        self.text(MavSeverity::MAV_SEVERITY_INFO, &short(format_args!("rig {}x{} accepted", record.camera.width, record.camera.height)));
    }

    fn setup_failed(&mut self, error: &SetupError) {
        self.text(MavSeverity::MAV_SEVERITY_ERROR, &short(format_args!("{}", error)));
    }

    fn pose_refused(&mut self, frame: u32, error: &PoseError) {
        self.text(MavSeverity::MAV_SEVERITY_ERROR, &short(format_args!("frame {}: pose: {}", frame, error)));
    }

    fn frame_done(&mut self, frame: u32, t_s: f64, outcome: &Outcome, scan: &Scan) {
        let time_usec = time_usec(t_s);
        match outcome {
            Outcome::Compared(_) => {
                self.last_frame = Some((scan.layout(), time_usec));
                self.send(&obstacle_distance(scan, time_usec));
            }
            Outcome::NotJudged(report) => {
                self.doubt(scan.layout(), time_usec);
                self.text(MavSeverity::MAV_SEVERITY_WARNING, &short(format_args!("frame {} not judged: {}", frame, report.status)));
            }
            Outcome::Keyframe { .. } => self.doubt(scan.layout(), time_usec),
        }
    }

    /// Doubt first, so the autopilot holds back before it reads why.
    fn frame_failed(&mut self, frame: u32, t_s: f64, code: FaultCode, scan: &Scan) {
        self.doubt(scan.layout(), time_usec(t_s));
        self.text(MavSeverity::MAV_SEVERITY_ERROR, &short(format_args!("frame {}: {}", frame, code.as_str())));
    }

    /// Doubt again, under the last frame's time (no new pose has come):
    /// without a message for 500 ms ArduPilot marks the sensor as having
    /// no data, and its avoidance then ignores it.
    fn odometry_lost(&mut self, frame: u32) {
        if let Some((layout, time_usec)) = self.last_frame {
            self.doubt(layout, time_usec);
        }
        self.text(MavSeverity::MAV_SEVERITY_ERROR, &short(format_args!("odometry_lost after frame {}", frame)));
    }

    /// The status follows the fail-safe's health, and every change is
    /// announced at once (docs/MAVLINK.md: a heartbeat at start, on every
    /// change of `system_status`, and at most once a second between
    /// frames). A run shorter than a second still tells the autopilot it
    /// went active.
    fn idle(&mut self, health: Health, now_us: u32) {
        let status = Status::from(health);
        if status != self.status {
            self.status = status;
            self.heartbeat(now_us);
        }
        if now_us.wrapping_sub(self.last_heartbeat_us) >= HEARTBEAT_PERIOD_US {
            self.heartbeat(now_us);
        }
    }

    /// The line decoder's counters with the MAVLink decoder's folded in.
    fn input_stats(&self) -> DecoderStats {
        let lines = self.lines.stats();
        let mav = self.frames.stats();
        DecoderStats {
            garbage_bytes: lines.garbage_bytes.saturating_add(self.port.overruns()).saturating_add(mav.garbage_bytes),
            bad_checksum: lines.bad_checksum.saturating_add(mav.checksum),
            unknown_type: lines.unknown_type.saturating_add(mav.foreign).saturating_add(mav.version1),
            bad_field: lines.bad_field.saturating_add(mav.payload).saturating_add(mav.incompatible),
            ..lines
        }
    }

    /// The counters as a `STATUSTEXT`.
    fn finish(&mut self, stats: &LinkStats) {
        let LinkStats { decoder, frame_loop } = stats;
        let text = short(format_args!(
            "end f{} g{} c{} u{} b{} o{} a{}",
            frame_loop.frames,
            decoder.garbage_bytes,
            decoder.bad_checksum,
            decoder.unknown_type,
            decoder.bad_field,
            frame_loop.out_of_order,
            frame_loop.aborted
        ));
        self.text(MavSeverity::MAV_SEVERITY_INFO, &text);
    }
}

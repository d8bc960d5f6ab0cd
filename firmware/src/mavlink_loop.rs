//! The frame loop speaking MAVLink 2 (feature `mavlink`): the same stages
//! and pipeline as [`crate::frame_loop`], talking to an autopilot.
//!
//! - Out: `HEARTBEAT` (component `MAV_COMP_ID_OBSTACLE_AVOIDANCE`) at start
//!   and then at most once a second, between frames; `OBSTACLE_DISTANCE` per
//!   frame (the scan, `core::mavlink::obstacle_distance`; every element
//!   unknown for a frame that only (re)started the keyframe, since nothing
//!   was compared); `STATUSTEXT` on the rig and on every fault, and the
//!   counters at the end.
//! - In: `ODOMETRY`, or `LOCAL_POSITION_NED` with the latest `ATTITUDE`
//!   (when no `ODOMETRY` has come), each one starting the next camera frame
//!   with that pose sample; the rig as the line protocol's `$FLRIG` (once,
//!   from a PC or companion; MAVLink has no message for it) and `$FLEND`
//!   (the emulated runs' end). Lines are told apart from frames by their
//!   `$` between MAVLink frames. Garbage, damaged, foreign and MAVLink 1
//!   frames are counted (`core::mavlink::MavStats`) and skipped.
//! - The alarm pin is asserted until a frame is judged clear, and again on
//!   every frame without a verdict.
//!
//! Frames are numbered by arrival from 0: on the emulated board frame n is
//! `frames/NNNNNN.pgm`, so a run sends one pose per recorded frame.

use core::fmt::Write as _;

use embedded_hal::digital::OutputPin;
use embedded_io::{Read, Write};
use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::mavlink::common::{MavSeverity, ATTITUDE_DATA};
use flatland_core::mavlink::{
    heartbeat, obstacle_distance, sample_from_local_position, sample_from_odometry, status_text, FrameDecoder, Inbound, MavStats,
    MessageData, Sender, Status,
};
use flatland_core::pipeline::{Outcome, Pipeline, PoseSample};
use flatland_core::protocol::{Decoder, LinkStats, Message};
use flatland_core::remap::RemapTable;
use flatland_core::scan::Scan;

use crate::board::{CycleCounter, RowSource};
use crate::frame_loop::{
    bump, ccm_image, gti_stage, log_report, set_up, stream_frame, Board, Link, LoopCounters, Options, DETECTOR, IMAGE, RING, TABLE,
};

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
    last_heartbeat: u32,
}

impl<S: Read + Write> Port<S> {
    /// The next message of either kind; what does not decode is counted.
    fn receive(&mut self) -> Input {
        loop {
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
                        return Input::Line(message);
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
                Some(Ok(message)) => return Input::Mav(message),
                Some(Err(error)) => defmt::warn!("mavlink: dropped a frame ({})", error),
                None => {}
            }
        }
    }

    fn send<D: MessageData>(&mut self, message: &D) {
        let frame = self.sender.encode(message);
        if self.link.serial.write_all(frame.as_bytes()).is_err() {
            defmt::warn!("serial: write failed");
        }
    }

    fn heartbeat<C: CycleCounter>(&mut self, counter: &C) {
        self.last_heartbeat = counter.now();
        self.send(&heartbeat(self.status));
    }

    /// A heartbeat if a second has passed (the loop calls it between frames).
    fn heartbeat_due<C: CycleCounter>(&mut self, counter: &C) {
        if counter.now().wrapping_sub(self.last_heartbeat) >= C::TICKS_PER_SECOND {
            self.heartbeat(counter);
        }
    }

    fn text(&mut self, severity: MavSeverity, text: &str) {
        self.send(&status_text(severity, text));
    }

    /// A fault: `STATUSTEXT`, and the status the next heartbeat carries.
    fn fault<C: CycleCounter>(&mut self, counter: &C, text: &str) {
        defmt::error!("fault: {=str}", text);
        self.text(MavSeverity::MAV_SEVERITY_ERROR, text);
        let changed = self.status != Status::Fault;
        self.status = Status::Fault;
        if changed {
            self.heartbeat(counter);
        }
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

/// Runs until `$FLEND`; returns the final counters.
pub fn run<S, A, C, R>(board: Board<S, A, C, R>, options: &Options) -> LinkStats
where
    S: Read + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
{
    let Board { serial, mut alarm, counter, mut frames } = board;
    let link = Link { serial, decoder: Decoder::new(), counters: LoopCounters::default() };
    let mut port = Port { link, mav: FrameDecoder::new(), sender: Sender::default(), in_line: false, status: Status::Starting, last_heartbeat: 0 };
    let _ = alarm.set_high();
    let table: &'static mut RemapTable = TABLE.take();
    let ring = RING.take();
    let image = IMAGE.take();
    let Some(ccm_image) = ccm_image() else { return port.finish() };
    let gpa: &'static mut Gpa<'static> = DETECTOR.take();
    port.heartbeat(&counter);

    // The rig, as a `$FLRIG` line.
    let (rig, grid) = loop {
        match port.receive() {
            Input::Line(Message::Rig(record)) => match set_up(&record, table, options) {
                Ok(built) => {
                    defmt::info!("rig accepted: camera {=u16}x{=u16}", record.width, record.height);
                    port.text(MavSeverity::MAV_SEVERITY_INFO, &short(format_args!("rig {}x{} accepted", record.width, record.height)));
                    break built;
                }
                Err(error) => {
                    defmt::error!("rig refused: {}", error);
                    let text = short(format_args!("rig refused: {:?}", error));
                    port.fault(&counter, &text);
                }
            },
            Input::Line(Message::End) => return port.finish(),
            Input::Line(_) => bump(&mut port.link.counters.out_of_order),
            Input::Mav(_) => {}
        }
        port.heartbeat_due(&counter);
    };
    let table: &RemapTable = table;
    let camera = (table.camera_width(), table.camera_height());
    if let Err(error) = gpa.init_split(&rig, &grid, table, GpaConfig::default(), &mut image[..], &mut ccm_image[..]) {
        port.fault(&counter, &short(format_args!("detector refused: {}", error)));
        return port.finish();
    }
    let Some(gti) = gti_stage(&mut port.link, &rig, &grid) else { return port.finish() };
    let mut pipeline = match Pipeline::new(table, &mut ring[..], gpa, gti) {
        Ok(pipeline) => pipeline,
        Err(error) => {
            port.fault(&counter, &short(format_args!("pipeline refused: {}", error)));
            return port.finish();
        }
    };

    let mut next_frame: u32 = 0;
    let mut attitude: Option<ATTITUDE_DATA> = None;
    let mut odometry_seen = false;
    loop {
        let sample = match port.receive() {
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
        let sample: PoseSample = match sample {
            Ok(sample) => sample,
            Err(error) => {
                // No usable pose: the frame is not taken and the next restarts.
                port.fault(&counter, &short(format_args!("frame {}: pose: {}", frame, error)));
                pipeline.restart();
                let _ = alarm.set_high();
                continue;
            }
        };
        let time_usec = libm::round(sample.t_s * 1e6).max(0.0) as u64;
        if let Err(error) = pipeline.begin(frame, Some(sample)) {
            defmt::warn!("frame {=u32} skipped: {}", frame, error);
            let _ = alarm.set_high();
            continue;
        }
        let mut read = 0;
        match stream_frame(&mut frames, &counter, &mut pipeline, frame, camera, &mut read) {
            Ok(Outcome::Compared(report)) => {
                let _ = if report.alarm { alarm.set_high() } else { alarm.set_low() };
                port.send(&obstacle_distance(pipeline.gpa().scan(), time_usec));
                log_report(&report);
                if port.status != Status::Active {
                    port.status = Status::Active;
                    port.heartbeat(&counter);
                }
            }
            Ok(Outcome::Keyframe { .. }) => {
                let _ = alarm.set_high();
                // Nothing compared: every element unknown.
                port.send(&obstacle_distance(&Scan::new(pipeline.gpa().scan().layout()), time_usec));
            }
            Err(failure) => {
                frames.end_frame();
                pipeline.abort();
                if failure.mid_frame {
                    bump(&mut port.link.counters.aborted);
                }
                let _ = alarm.set_high();
                port.fault(&counter, &short(format_args!("frame {}: {}", frame, failure.code.as_str())));
                continue;
            }
        }
        bump(&mut port.link.counters.frames);
        port.heartbeat_due(&counter);
    }
    port.finish()
}

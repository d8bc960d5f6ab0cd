//! What the frame loop speaks on the serial port: the [`Protocol`] trait,
//! and its two implementations, the line protocol ([`lines`], PROTOCOL.md)
//! and MAVLink 2 ([`mavlink`], feature `mavlink`).
//!
//! The loop decides (what a frame came to, what the alarm says, what is
//! counted); a protocol only turns received bytes into [`Input`]s and tells
//! the robot what happened, in its own messages.

use embedded_io::{Read, ReadReady, Write};

use flatland_core::health::Health;
use flatland_core::pipeline::{Outcome, PoseSample};
use flatland_core::protocol::{DecoderStats, FaultCode, LinkStats, Message, RigRecord};
use flatland_core::scan::Scan;

use crate::frame_loop::SetupError;

pub mod lines;
#[cfg(feature = "mavlink")]
pub mod mavlink;

/// What arrived, as the loop sees it.
pub enum Input<E> {
    /// The rig to build the remap table for.
    Rig(RigRecord),
    /// The robot's sensors for the next camera frame: frame `frame`, or
    /// when the protocol does not number frames (None) the next by arrival.
    Pose { frame: Option<u32>, sample: Result<PoseSample, E> },
    /// No more frames.
    End,
    /// A well-formed message that makes no sense here (its name).
    Unexpected(&'static str),
}

impl<E> Input<E> {
    /// The input's name, for the log of an out-of-order one (the rig and
    /// the end are lines in both protocols).
    pub fn name(&self) -> &'static str {
        match self {
            Input::Rig(_) => "FLRIG",
            Input::Pose { .. } => "pose",
            Input::End => "FLEND",
            Input::Unexpected(name) => name,
        }
    }
}

/// The line protocol's messages as inputs. `$FLODO` is a pose only where
/// `poses_as_lines` (the MAVLink build takes its poses as MAVLink).
pub fn line_input<E>(message: Message, poses_as_lines: bool) -> Input<E> {
    match message {
        Message::Rig(record) => Input::Rig(record),
        Message::Odometry(odometry) if poses_as_lines => Input::Pose { frame: Some(odometry.frame), sample: Ok(odometry.into()) },
        Message::End => Input::End,
        other => Input::Unexpected(other.tag()),
    }
}

/// A serial protocol, as the frame loop uses it.
pub trait Protocol {
    type Serial: Read + ReadReady + Write;
    /// Why a pose message could not be used.
    type PoseError;
    /// The robot streams its poses whether or not a rig has come (an
    /// autopilot does): poses before the rig are dropped, not counted as
    /// out of order.
    const POSES_STREAM: bool;

    fn new(serial: Self::Serial) -> Self;
    /// The next input among the bytes waiting; None once no byte waits.
    /// What does not decode is counted ([`Protocol::input_stats`]) and skipped.
    fn poll(&mut self) -> Option<Input<Self::PoseError>>;
    /// The loop listens (bytes that came before were lost).
    fn listening(&mut self, now_us: u32);
    /// The rig was accepted and the stages built for it.
    fn rig_accepted(&mut self, record: &RigRecord);
    /// The rig or the stages for it were refused.
    fn setup_failed(&mut self, error: &SetupError);
    /// Frame `frame`'s pose was refused: the frame is not taken.
    fn pose_refused(&mut self, frame: u32, error: &Self::PoseError);
    /// Frame `frame` came to `outcome`. `scan` is the detector's (the last
    /// judged frame's), `t_s` the frame's time.
    fn frame_done(&mut self, frame: u32, t_s: f64, outcome: &Outcome, scan: &Scan);
    /// Frame `frame` (its pose's time `t_s`) was given up; `scan` as in
    /// [`Protocol::frame_done`].
    fn frame_failed(&mut self, frame: u32, t_s: f64, code: FaultCode, scan: &Scan);
    /// Odometry stopped after `frame` (the alarm is already asserted).
    fn odometry_lost(&mut self, frame: u32);
    /// Between inputs, with the sensor's health: status outputs.
    fn idle(&mut self, _health: Health, _now_us: u32) {}
    /// What the protocol's decoders refused so far, serial overruns as garbage.
    fn input_stats(&self) -> DecoderStats;
    /// The run ends with `stats`.
    fn finish(&mut self, stats: &LinkStats);
}

/// The serial port as a protocol uses it: bytes in without blocking (a
/// failed read counted as an overrun), messages out.
pub struct SerialPort<S> {
    serial: S,
    overruns: u32,
}

impl<S: Read + ReadReady + Write> SerialPort<S> {
    pub fn new(serial: S) -> Self {
        SerialPort { serial, overruns: 0 }
    }

    /// The next byte waiting; None once none waits.
    pub fn next_byte(&mut self) -> Option<u8> {
        while self.serial.read_ready().unwrap_or(true) {
            let mut byte = [0u8; 1];
            match self.serial.read(&mut byte) {
                Ok(1) => return Some(byte[0]),
                Ok(_) => {}
                Err(_) => self.overruns = self.overruns.saturating_add(1),
            }
        }
        None
    }

    pub fn write(&mut self, bytes: &[u8]) {
        if self.serial.write_all(bytes).is_err() {
            defmt::warn!("serial: write failed");
        }
    }

    /// Bytes lost to overruns.
    pub fn overruns(&self) -> u32 {
        self.overruns
    }
}

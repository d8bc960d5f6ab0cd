//! The line protocol (PROTOCOL.md): `$FLRIG` and `$FLODO` in, `$FLRDY`,
//! `$FLHEL`, a `$FLFRM` per frame after the first, `$FLERR` and `$FLSTA` out.

use embedded_io::{Read, ReadReady, Write};

use flatland_core::pipeline::Outcome;
use flatland_core::protocol::{encode_line, Decoder, DecoderStats, Fault, FaultCode, LinkStats, Message, RigRecord};
use flatland_core::scan::Scan;

use super::{line_input, Input, Protocol, SerialPort};
use crate::frame_loop::SetupError;

/// A `$FLODO` always carries a usable pose: there is no pose error.
pub enum NoPoseError {}

pub struct Lines<S> {
    port: SerialPort<S>,
    decoder: Decoder,
}

impl<S: Read + ReadReady + Write> Lines<S> {
    fn send(&mut self, message: &Message) {
        match encode_line(message) {
            Ok(line) => self.port.write(line.as_bytes()),
            Err(error) => defmt::error!("serial: cannot encode {=str}: {}", message.tag(), error),
        }
    }

    fn fault(&mut self, code: FaultCode, frame: u32) {
        self.send(&Message::Fault(Fault { code, frame }));
    }
}

impl<S: Read + ReadReady + Write> Protocol for Lines<S> {
    type Serial = S;
    type PoseError = NoPoseError;
    const POSES_STREAM: bool = false;

    fn new(serial: S) -> Self {
        Lines { port: SerialPort::new(serial), decoder: Decoder::new() }
    }

    fn poll(&mut self) -> Option<Input<NoPoseError>> {
        while let Some(byte) = self.port.next_byte() {
            match self.decoder.push(byte) {
                Some(Ok(message)) => return Some(line_input(message, true)),
                Some(Err(error)) => defmt::warn!("serial: dropped a line ({})", error),
                None => {}
            }
        }
        None
    }

    fn listening(&mut self, _now_us: u32) {
        self.send(&Message::Ready);
    }

    fn rig_accepted(&mut self, record: &RigRecord) {
        self.send(&Message::Hello(*record));
    }

    fn setup_failed(&mut self, error: &SetupError) {
        self.fault(error.fault_code(), 0);
    }

    fn pose_refused(&mut self, _frame: u32, error: &NoPoseError) {
        match *error {}
    }

    fn frame_done(&mut self, _frame: u32, _t_s: f64, outcome: &Outcome, _scan: &Scan) {
        match outcome {
            Outcome::Compared(report) | Outcome::NotJudged(report) => self.send(&Message::Frame(*report)),
            // The run's first frame: nothing compared, no report.
            Outcome::Keyframe { .. } => {}
        }
    }

    fn frame_failed(&mut self, frame: u32, _t_s: f64, code: FaultCode, _scan: &Scan) {
        self.fault(code, frame);
    }

    fn odometry_lost(&mut self, frame: u32) {
        self.fault(FaultCode::OdometryLost, frame);
    }

    fn input_stats(&self) -> DecoderStats {
        let stats = self.decoder.stats();
        DecoderStats { garbage_bytes: stats.garbage_bytes.saturating_add(self.port.overruns()), ..stats }
    }

    fn finish(&mut self, stats: &LinkStats) {
        self.send(&Message::Stats(*stats));
    }
}

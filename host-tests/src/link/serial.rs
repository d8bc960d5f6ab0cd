//! `flatland serial decode`: the firmware's serial byte stream to the csv of
//! `flatland detect`, through the same decoder the firmware uses.

use std::fmt;
use std::io::{self, Read, Write};

use flatland_core::protocol::{DecodeError, Decoder, Fault, FaultCode, LinkStats, Message};
use flatland_core::report::CSV_HEADER;

/// A clean decode: the csv is written; frames the firmware skipped are listed
/// (as `flatland detect` skips a damaged frame and carries on).
#[derive(Debug, Default)]
pub struct DecodeSummary {
    pub rows: usize,
    /// Faults about one frame (missing, broken, stopped mid-frame, the
    /// camera too late).
    pub frame_faults: Vec<Fault>,
    /// A sensor stream that stopped (`odometry_lost`, with the last frame
    /// whose odometry came): no frame was skipped, the alarm was asserted.
    pub sensor_faults: Vec<Fault>,
    /// The firmware's final counters, if the stream has them.
    pub stats: Option<LinkStats>,
}

/// Faults that end the run (the rig could not be used) rather than skip a frame.
fn is_run_fault(code: FaultCode) -> bool {
    matches!(
        code,
        FaultCode::RigRejected | FaultCode::TableRejected | FaultCode::GridTooLarge | FaultCode::CameraTooLarge
    )
}

/// Why the stream did not decode cleanly. The csv of every frame message is
/// written before this is returned.
#[derive(Debug)]
pub enum SerialDecodeError {
    Io(io::Error),
    /// Lines that were refused (bad checksum, truncated, unknown type, ...),
    /// and why the first was.
    MalformedLines { count: u32, first: DecodeError },
    /// The firmware refused the rig (the first such fault).
    FirmwareFault(Fault),
}

impl fmt::Display for SerialDecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SerialDecodeError::Io(error) => write!(f, "serial decode: {error}"),
            SerialDecodeError::MalformedLines { count, .. } => write!(f, "serial decode: {count} malformed line(s) skipped"),
            SerialDecodeError::FirmwareFault(fault) => {
                write!(f, "firmware fault {} at frame {}", fault.code.as_str(), fault.frame)
            }
        }
    }
}

impl std::error::Error for SerialDecodeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            SerialDecodeError::Io(error) => Some(error),
            SerialDecodeError::MalformedLines { first, .. } => Some(first),
            SerialDecodeError::FirmwareFault(_) => None,
        }
    }
}

impl From<io::Error> for SerialDecodeError {
    fn from(error: io::Error) -> Self {
        SerialDecodeError::Io(error)
    }
}

/// Reads the whole byte stream and writes [`CSV_HEADER`] plus one row per frame message.
/// Garbage between lines is ignored, as the firmware ignores it.
pub fn run_serial_decode(input: &mut dyn Read, out: &mut dyn Write) -> Result<DecodeSummary, SerialDecodeError> {
    writeln!(out, "{CSV_HEADER}")?;
    let mut decoder = Decoder::new();
    let mut malformed = 0u32;
    let mut first_malformed = None;
    let mut first_fault = None;
    let mut summary = DecodeSummary::default();
    let mut chunk = [0u8; 4096];
    let mut row = String::new();
    loop {
        let length = match input.read(&mut chunk) {
            Ok(0) => break,
            Ok(length) => length,
            Err(error) if error.kind() == io::ErrorKind::Interrupted => continue,
            Err(error) => return Err(error.into()),
        };
        for &byte in &chunk[..length] {
            match decoder.push(byte) {
                Some(Ok(Message::Frame(report))) => {
                    row.clear();
                    // Writing into a String cannot fail.
                    let _ = report.write_csv(&mut row);
                    writeln!(out, "{row}")?;
                    summary.rows += 1;
                }
                Some(Ok(Message::Fault(fault))) if is_run_fault(fault.code) => {
                    first_fault.get_or_insert(fault);
                }
                Some(Ok(Message::Fault(fault))) if fault.code == FaultCode::OdometryLost => {
                    summary.sensor_faults.push(fault)
                }
                Some(Ok(Message::Fault(fault))) => summary.frame_faults.push(fault),
                Some(Ok(Message::Stats(stats))) => summary.stats = Some(stats),
                Some(Ok(_)) => {}
                Some(Err(error)) => {
                    malformed += 1;
                    first_malformed.get_or_insert(error);
                }
                None => {}
            }
        }
    }
    out.flush()?;
    if let Some(fault) = first_fault {
        return Err(SerialDecodeError::FirmwareFault(fault));
    }
    if let Some(first) = first_malformed {
        return Err(SerialDecodeError::MalformedLines { count: malformed, first });
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use flatland_core::protocol::{encode_line, FaultCode};
    use flatland_core::report::{FrameReport, NotJudged};

    /// Frame 2 raises the alarm; frame 1 has odometry that agrees, frame 2 none.
    fn report(frame: u32) -> FrameReport {
        FrameReport {
            frame,
            ref_frame: frame.saturating_sub(1),
            alarm: frame == 2,
            nearest_mm: Some(900),
            tz: 1000,
            dyaw: -1500,
            dpitch: 85,
            droll: -7,
            odometry_fault: (frame == 1).then_some(false),
            ..FrameReport::default()
        }
    }

    #[test]
    fn frames_become_csv_rows_and_garbage_is_skipped() {
        let mut stream = b"boot noise\r\n".to_vec();
        stream.extend_from_slice(encode_line(&Message::Ready).unwrap().as_bytes());
        for frame in 1..=2 {
            stream.extend_from_slice(encode_line(&Message::Frame(report(frame))).unwrap().as_bytes());
        }
        let mut out = Vec::new();
        assert_eq!(run_serial_decode(&mut stream.as_slice(), &mut out).unwrap().rows, 2);
        let text = String::from_utf8(out).unwrap();
        let mut expected = format!("{CSV_HEADER}\n");
        for frame in 1..=2 {
            let mut row = String::new();
            report(frame).write_csv(&mut row).unwrap();
            expected += &format!("{row}\n");
        }
        assert_eq!(text, expected);
        assert!(text.contains("\n1,0,0,900,,,0,0,0.00,0.00,0.0,100.0,,-1.500,0.085,-0.007,0,ok\n"), "{text}");
        assert!(text.contains("\n2,1,1,900,,,0,0,0.00,0.00,0.0,100.0,,-1.500,0.085,-0.007,,ok\n"), "{text}");
    }

    /// A frame not judged is a row like any other, its reason last.
    #[test]
    fn a_frame_not_judged_is_a_row_that_says_why() {
        let mut stream = encode_line(&Message::Frame(report(1))).unwrap().as_bytes().to_vec();
        stream.extend_from_slice(encode_line(&Message::Frame(FrameReport::not_judged(2, 1, NotJudged::NoMotion))).unwrap().as_bytes());
        stream.extend_from_slice(encode_line(&Message::Frame(FrameReport::not_judged(4, 4, NotJudged::AfterGap))).unwrap().as_bytes());
        let mut out = Vec::new();
        assert_eq!(run_serial_decode(&mut stream.as_slice(), &mut out).unwrap().rows, 3);
        let text = String::from_utf8(out).unwrap();
        let rows: Vec<&str> = text.lines().skip(1).collect();
        assert_eq!(rows[1], "2,1,1,,,,0,0,0.00,0.00,0.0,0.0,,0.000,0.000,0.000,,no_motion");
        assert_eq!(rows[2], "4,4,1,,,,0,0,0.00,0.00,0.0,0.0,,0.000,0.000,0.000,,after_gap");
    }

    /// firmware/PROTOCOL.md's example session decodes to the csv it shows
    /// (its checksums and field counts are right).
    #[test]
    fn documented_example_decodes_to_the_documented_csv() {
        let doc = include_str!("../../../firmware/PROTOCOL.md");
        let examples = doc.split_once("## Examples").expect("PROTOCOL.md has examples").1;
        // Text, session, text, csv, ...: the code blocks are the odd pieces.
        let pieces: Vec<&str> = examples.split("```").collect();
        let (session, csv) = (pieces[1].trim_start(), pieces[3].trim_start());
        let mut out = Vec::new();
        let summary = run_serial_decode(&mut session.as_bytes(), &mut out).unwrap();
        assert_eq!((summary.rows, summary.stats.map(|s| s.frame_loop.frames)), (3, Some(4)));
        assert_eq!(String::from_utf8(out).unwrap(), csv);
    }

    #[test]
    fn faults_and_malformed_lines_are_errors_after_the_csv() {
        let mut stream = encode_line(&Message::Frame(report(1))).unwrap().as_bytes().to_vec();
        stream.extend_from_slice(b"$FLFRM,1*00\r\n");
        let mut out = Vec::new();
        let result = run_serial_decode(&mut stream.as_slice(), &mut out);
        assert!(matches!(result, Err(SerialDecodeError::MalformedLines { count: 1, first: DecodeError::BadChecksum })), "{result:?}");
        assert_eq!(String::from_utf8(out).unwrap().lines().count(), 2);

        let fault = Fault { code: FaultCode::RigRejected, frame: 0 };
        let stream = encode_line(&Message::Fault(fault)).unwrap();
        let result = run_serial_decode(&mut stream.as_bytes(), &mut Vec::new());
        assert!(matches!(result, Err(SerialDecodeError::FirmwareFault(f)) if f == fault), "{result:?}");

        // A skipped frame is not a failed decode: it is listed, like detect's stderr line.
        let skipped = Fault { code: FaultCode::FrameMissing, frame: 4 };
        let stream = encode_line(&Message::Fault(skipped)).unwrap();
        let summary = run_serial_decode(&mut stream.as_bytes(), &mut Vec::new()).unwrap();
        assert_eq!(summary.frame_faults, vec![skipped]);
    }

    #[test]
    fn fail_safe_faults_are_listed_not_errors() {
        let late = Fault { code: FaultCode::CameraTimeout, frame: 6 };
        let stopped = Fault { code: FaultCode::OdometryLost, frame: 7 };
        let mut stream = encode_line(&Message::Fault(late)).unwrap().as_bytes().to_vec();
        stream.extend_from_slice(encode_line(&Message::Frame(report(8))).unwrap().as_bytes());
        stream.extend_from_slice(encode_line(&Message::Fault(stopped)).unwrap().as_bytes());
        let mut out = Vec::new();
        let summary = run_serial_decode(&mut stream.as_slice(), &mut out).unwrap();
        assert_eq!(summary.frame_faults, vec![late], "the camera's late frame was skipped");
        assert_eq!(summary.sensor_faults, vec![stopped], "stopped odometry skipped no frame");
        assert_eq!(String::from_utf8(out).unwrap().lines().count(), 2, "header and frame 8");
    }
}

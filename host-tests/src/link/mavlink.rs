//! The `mavlink` firmware's byte stream decoded by the `mavlink` crate's
//! own reader (the reference implementation's Rust port, std), not by
//! core's decoder: what an autopilot or companion computer would read.

use std::collections::BTreeMap;
use std::fmt;
use std::io::Write;

use crate::recording::Recording;
use mavlink::dialects::common::{MavMessage, OBSTACLE_DISTANCE_DATA};
use mavlink::error::MessageReadError;
use mavlink::{MavHeader, MavlinkReader};

/// Every message of a captured stream, and the frames the reader refused.
#[derive(Debug, Default)]
pub struct Decoded {
    pub messages: Vec<(MavHeader, MavMessage)>,
    /// Frames with a bad checksum or a payload that does not parse.
    pub errors: Vec<String>,
}

/// Decodes `bytes` to the end.
pub fn decode(bytes: &[u8]) -> Decoded {
    let mut reader = MavlinkReader::new(bytes);
    let mut decoded = Decoded::default();
    loop {
        match reader.read_any_message::<MavMessage>() {
            Ok(message) => decoded.messages.push(message),
            Err(MessageReadError::Io(error)) if error.kind() == std::io::ErrorKind::UnexpectedEof => break,
            Err(MessageReadError::Io(error)) => {
                decoded.errors.push(error.to_string());
                break;
            }
            Err(error) => decoded.errors.push(format!("{error:?}")),
        }
    }
    decoded
}

/// One line per message, for people.
pub fn describe(message: &MavMessage) -> String {
    match message {
        MavMessage::HEARTBEAT(h) => format!("HEARTBEAT {:?}", h.system_status),
        MavMessage::STATUSTEXT(t) => format!("STATUSTEXT {:?}: {}", t.severity, t.text.to_str().unwrap_or("?")),
        MavMessage::OBSTACLE_DISTANCE(o) => {
            // MAVLink's encoding: UINT16_MAX unknown, above max_distance free.
            let reading = |d: u16| match d {
                u16::MAX => "unknown".to_string(),
                d if d > o.max_distance => "free".to_string(),
                d => format!("{d} cm"),
            };
            let ahead = [-5.0, 0.0, 5.0].map(|deg| element_at(o, deg).map_or("none".to_string(), reading)).join(", ");
            let nearest = o.distances.iter().filter(|&&d| d <= o.max_distance).min();
            format!(
                "OBSTACLE_DISTANCE t {} us: -5/0/+5 deg [{ahead}], nearest {} (min {} max {} cm)",
                o.time_usec,
                nearest.map_or("none".to_string(), |&d| format!("{d} cm")),
                o.min_distance,
                o.max_distance
            )
        }
        other => format!("{other:?}"),
    }
}

/// Elements of `OBSTACLE_DISTANCE`.
const ELEMENTS: usize = 72;

/// The element width: `increment_f`, else `increment`.
fn increment_deg(o: &OBSTACLE_DISTANCE_DATA) -> f64 {
    if o.increment_f > 0.0 {
        f64::from(o.increment_f)
    } else {
        f64::from(o.increment)
    }
}

/// The element centred on `deg` (clockwise from the front), if one is.
fn element_at(o: &OBSTACLE_DISTANCE_DATA, deg: f64) -> Option<u16> {
    let increment = increment_deg(o);
    let index = ((deg - f64::from(o.angle_offset)).rem_euclid(360.0) / increment).round() as usize;
    (increment > 0.0).then(|| o.distances.get(index).copied()).flatten()
}

/// How `flatland serial decode --mavlink` names a row: by the frame whose
/// poses.csv time is the message's `time_usec` (`--recording`), else by the
/// time itself.
pub enum RowKey<'a> {
    Frame(&'a BTreeMap<u64, u32>),
    TimeUsec,
}

/// Frames by their poses.csv time in microseconds, the `time_usec` the
/// runner sends them with (`qemu::mavlink_script`).
pub fn frames_by_time(recording: &Recording) -> BTreeMap<u64, u32> {
    recording.poses.iter().map(|row| (flatland_core::mavlink::time_usec(row.t_s), row.frame)).collect()
}

/// Why the csv could not be written in full.
#[derive(Debug)]
pub enum ScanCsvError {
    Io(std::io::Error),
    /// An `OBSTACLE_DISTANCE` whose `time_usec` is no frame's time.
    UnknownTime(u64),
}

impl fmt::Display for ScanCsvError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ScanCsvError::Io(error) => write!(f, "{error}"),
            ScanCsvError::UnknownTime(t) => write!(f, "OBSTACLE_DISTANCE at time_usec {t} matches no frame of poses.csv"),
        }
    }
}

impl std::error::Error for ScanCsvError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            ScanCsvError::Io(error) => Some(error),
            ScanCsvError::UnknownTime(_) => None,
        }
    }
}

impl From<std::io::Error> for ScanCsvError {
    fn from(error: std::io::Error) -> Self {
        ScanCsvError::Io(error)
    }
}

/// `flatland serial decode --mavlink`: every `OBSTACLE_DISTANCE` of a
/// stream as a row of `flatland scan`'s csv,
/// `frame,angle_start_deg,increment_deg,d0_mm,...` (`time_usec` first
/// instead of `frame` without a recording). The elements are in the
/// message's own bins (5 degrees for our firmware, where `flatland scan` has
/// 2.5), turned to start at -180 degrees when they go once round (ours
/// start there: `angle_offset` -180), so left comes first as in the scan.
/// An element in `min_distance..=max_distance` is a hazard in mm (the cm
/// times 10), `max_distance + 1` is `inf` (seen and clear), anything else
/// (`UINT16_MAX`) empty (unknown). Frames that only (re)started a keyframe
/// are rows too, all unknown (`flatland scan` has no row for them).
/// Returns the number of rows.
pub fn write_scan_csv(decoded: &Decoded, key: RowKey, out: &mut dyn Write) -> Result<usize, ScanCsvError> {
    write!(out, "{},angle_start_deg,increment_deg", if matches!(key, RowKey::Frame(_)) { "frame" } else { "time_usec" })?;
    for k in 0..ELEMENTS {
        write!(out, ",d{k}_mm")?;
    }
    writeln!(out)?;
    let mut rows = 0;
    for (_, message) in &decoded.messages {
        let MavMessage::OBSTACLE_DISTANCE(o) = message else { continue };
        match key {
            RowKey::Frame(frames) => write!(out, "{}", frames.get(&o.time_usec).ok_or(ScanCsvError::UnknownTime(o.time_usec))?)?,
            RowKey::TimeUsec => write!(out, "{}", o.time_usec)?,
        }
        let increment = increment_deg(o);
        let once_round = (increment * ELEMENTS as f64 - 360.0).abs() < 1e-3;
        // The element at -180 degrees first.
        let turn = if once_round { ((f64::from(o.angle_offset) + 180.0).rem_euclid(360.0) / increment).round() as usize % ELEMENTS } else { 0 };
        let start = f64::from(o.angle_offset) - turn as f64 * increment;
        write!(out, ",{start:.3},{increment:.3}")?;
        for k in 0..ELEMENTS {
            match o.distances[(k + turn) % ELEMENTS] {
                d if (o.min_distance..=o.max_distance).contains(&d) => write!(out, ",{}", u32::from(d) * 10)?,
                d if o.max_distance < u16::MAX && d == o.max_distance + 1 => write!(out, ",inf")?,
                _ => write!(out, ",")?,
            }
        }
        writeln!(out)?;
        rows += 1;
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::OBSTACLE_DISTANCE_DATA;

    #[test]
    fn a_reading_says_free_and_unknown_in_words() {
        let mut data = OBSTACLE_DISTANCE_DATA { time_usec: 5, min_distance: 10, max_distance: 142, increment_f: 5.0, ..OBSTACLE_DISTANCE_DATA::default() };
        data.distances = [143; 72];
        (data.distances[71], data.distances[1], data.distances[30]) = (u16::MAX, 57, 40);
        let line = describe(&MavMessage::OBSTACLE_DISTANCE(data));
        assert_eq!(line, "OBSTACLE_DISTANCE t 5 us: -5/0/+5 deg [unknown, free, 57 cm], nearest 40 cm (min 10 max 142 cm)");
    }
}

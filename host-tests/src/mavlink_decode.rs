//! The `mavlink` firmware's byte stream decoded by the `mavlink` crate's
//! own reader (the reference implementation's Rust port, std), not by
//! core's decoder: what an autopilot or companion computer would read.

use mavlink::dialects::common::MavMessage;
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
            let ahead = [o.distances[71], o.distances[0], o.distances[1]];
            let nearest = o.distances.iter().filter(|&&d| d <= o.max_distance).min();
            format!(
                "OBSTACLE_DISTANCE t {} us: -5/0/+5 deg {:?} cm, nearest {} (min {} max {} cm)",
                o.time_usec,
                ahead,
                nearest.map_or("none".to_string(), |d| format!("{d} cm")),
                o.min_distance,
                o.max_distance
            )
        }
        other => format!("{other:?}"),
    }
}

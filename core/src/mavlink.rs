//! MAVLink 2 for an autopilot (feature `mavlink`): the scan out as
//! `OBSTACLE_DISTANCE`, the sensor's health as `HEARTBEAT` and
//! `STATUSTEXT`, odometry and attitude in from `ODOMETRY` or
//! `LOCAL_POSITION_NED` + `ATTITUDE`. One module for the firmware and for
//! the host that talks to it in tests, so both convert the same way.
//!
//! Messages are the `mavlink` crate's generated `common` structs, each
//! (de)serialised alone (`MessageData`): the dialect's whole-message enum,
//! whose parser would link every message of the dialect, is not used.
//! Frames are read by [`FrameDecoder`], a byte-at-a-time MAVLink 2 frame
//! reader whose every failure is a typed [`MavError`].
//!
//! Frames (vehicle conventions, ArduPilot and PX4 alike):
//! - `OBSTACLE_DISTANCE` in `MAV_FRAME_BODY_FRD`: element j is centred
//!   5j - 180 degrees clockwise from the vehicle's front (`angle_offset`
//!   -180, `increment_f` 5), so the 72 elements go once round starting
//!   straight behind. Starting behind keeps the front face whole:
//!   ArduPilot walks the elements in order and writes a face each time the
//!   walk leaves it, so a face split across element 0 is written twice and
//!   its second half wins. Each element carries the nearest hazard within
//!   +-5 degrees of its centre ([`obstacle_distance`]): the windows overlap
//!   so that every reader gets every hazard, whichever elements it takes
//!   (PX4's 36 bins of 10 degrees read only the even elements; ArduPilot
//!   and PX4's 72 bins read each). A frame that says nothing about the
//!   ground sends a hazard at `min_distance` wherever the camera looks
//!   ([`obstacle_distance_in_doubt`]): both autopilots skip unknown
//!   elements, so doubt sent as unknown would read as free. docs/MAVLINK.md
//!   has the readers.
//! - Positions NED (x north, y east), attitude as aerospace angles or a
//!   body-FRD-to-NED quaternion; converted to RECORDING.md's frames
//!   (x east, z north, yaw positive left; pitch positive nose down, roll
//!   positive right side down, pitch first and then roll about the level
//!   forward axis) exactly, then rounded to the resolution poses.csv
//!   carries (0.01 mm, 0.0001 degree, 1 us): MAVLink's f32 would otherwise
//!   move a 100 mm step by a few hundred nm, and the keyframe rule compares
//!   steps with exact thresholds.

use crate::health::Health;
use crate::motion::{Attitude, Pose};
use crate::pipeline::PoseSample;
use crate::scan::{Scan, ScanLayout, Sector, SCAN_INCREMENT_MDEG};
use core::fmt;
use mavlink::dialects::common::{
    MavAutopilot, MavDistanceSensor, MavFrame, MavModeFlag, MavSeverity, MavState, MavType, ATTITUDE_DATA, HEARTBEAT_DATA,
    LOCAL_POSITION_NED_DATA, OBSTACLE_DISTANCE_DATA, ODOMETRY_DATA, STATUSTEXT_DATA,
};
pub use mavlink::dialects::common::{self, MavComponent};
use mavlink::{MavHeader, MavlinkVersion};
pub use mavlink::MessageData;

/// The vehicle's system id (autopilots default to 1): a component of it.
pub const SYSTEM_ID: u8 = 1;
/// `MAV_COMP_ID_OBSTACLE_AVOIDANCE`.
pub const COMPONENT_ID: u8 = MavComponent::MAV_COMP_ID_OBSTACLE_AVOIDANCE as u8;
/// Width of an `OBSTACLE_DISTANCE` element, degrees (72 of them go round once).
pub const BIN_DEG: f32 = 5.0;
/// [`BIN_DEG`] in thousandths of a degree, as the scan counts its sectors.
const BIN_MDEG: i32 = 5000;
/// Elements of `OBSTACLE_DISTANCE`.
pub const BINS: usize = 72;
/// Element 0's direction, degrees clockwise from the front: straight
/// behind, where the camera never looks (see the module docs).
pub const ANGLE_OFFSET_DEG: f32 = -180.0;
/// Longest MAVLink 2 frame: 10 header bytes, 255 payload, 2 CRC, 13 signature.
pub const MAX_FRAME: usize = 280;

/// The sensor's state, as `HEARTBEAT.system_status` carries it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// Nothing judged yet (no rig, no compared frame): `MAV_STATE_STANDBY`.
    Starting,
    /// Frames are judged: `MAV_STATE_ACTIVE`.
    Active,
    /// A fault (a frame lost, the rig refused): `MAV_STATE_CRITICAL`.
    Fault,
}

impl From<Health> for Status {
    fn from(health: Health) -> Status {
        match health {
            Health::Starting => Status::Starting,
            Health::Ok => Status::Active,
            Health::Fault(_) => Status::Fault,
        }
    }
}

impl Status {
    pub fn mav_state(self) -> MavState {
        match self {
            Status::Starting => MavState::MAV_STATE_STANDBY,
            Status::Active => MavState::MAV_STATE_ACTIVE,
            Status::Fault => MavState::MAV_STATE_CRITICAL,
        }
    }
}

/// One frame, encoded: its bytes.
#[derive(Clone, Copy)]
pub struct Encoded {
    bytes: [u8; MAX_FRAME],
    len: usize,
}

impl Encoded {
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Frames this component sends, numbered in sequence.
#[derive(Clone, Copy, Debug, Default)]
pub struct Sender {
    sequence: u8,
}

impl Sender {
    /// `message` as a MAVLink 2 frame from this component.
    pub fn encode<D: MessageData>(&mut self, message: &D) -> Encoded {
        let header = MavHeader { system_id: SYSTEM_ID.into(), component_id: COMPONENT_ID, sequence: self.sequence };
        self.sequence = self.sequence.wrapping_add(1);
        let mut raw = mavlink::MAVLinkV2MessageRaw::new();
        raw.serialize_message_data(header, message);
        let frame = raw.raw_bytes();
        let mut bytes = [0u8; MAX_FRAME];
        let len = frame.len().min(MAX_FRAME);
        bytes[..len].copy_from_slice(&frame[..len]);
        Encoded { bytes, len }
    }
}

/// `HEARTBEAT` of an onboard sensor with `status`.
pub fn heartbeat(status: Status) -> HEARTBEAT_DATA {
    HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_ONBOARD_CONTROLLER,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status: status.mav_state(),
        mavlink_version: 3,
    }
}

/// `STATUSTEXT` (one chunk, at most 50 bytes of `text`).
pub fn status_text(severity: MavSeverity, text: &str) -> STATUSTEXT_DATA {
    let mut bytes = [0u8; 50];
    let n = text.len().min(50);
    bytes[..n].copy_from_slice(&text.as_bytes()[..n]);
    STATUSTEXT_DATA { severity, text: bytes.into(), id: 0, chunk_seq: 0 }
}

/// The `OBSTACLE_DISTANCE` range fields for a scan (cm): `min_distance`
/// the scan's nearest range (at least 1: ArduPilot skips 0), `max_distance`
/// one cm beyond its farthest, so that every hazard (whole cm, rounded down)
/// lies below it: PX4 reads a value at `max_distance` as free, ArduPilot as
/// an obstacle.
pub fn distance_limits_cm(layout: &ScanLayout) -> (u16, u16) {
    ((layout.range_min_mm / 10).max(1), layout.range_max_mm / 10 + 1)
}

/// The scan sectors element `element` merges: the four centred within 5
/// degrees of its centre, `None` where the scan has no such sector.
fn element_sectors(layout: &ScanLayout, element: usize) -> [Option<usize>; 4] {
    let centre = (element as i32 - BINS as i32 / 2) * BIN_MDEG;
    [-3, -1, 1, 3].map(|quarter| {
        let offset = centre + quarter * SCAN_INCREMENT_MDEG / 2 - layout.angle_start_mdeg();
        usize::try_from(offset.div_euclid(SCAN_INCREMENT_MDEG)).ok().filter(|&k| k < usize::from(layout.sectors))
    })
}

/// `OBSTACLE_DISTANCE` with `distances` and the fields every message shares.
fn message(layout: &ScanLayout, time_usec: u64, distances: [u16; BINS]) -> OBSTACLE_DISTANCE_DATA {
    let (min_distance, max_distance) = distance_limits_cm(layout);
    OBSTACLE_DISTANCE_DATA {
        time_usec,
        distances,
        min_distance,
        max_distance,
        sensor_type: MavDistanceSensor::MAV_DISTANCE_SENSOR_UNKNOWN,
        increment: BIN_DEG as u8,
        increment_f: BIN_DEG,
        angle_offset: ANGLE_OFFSET_DEG,
        frame: MavFrame::MAV_FRAME_BODY_FRD,
    }
}

/// `OBSTACLE_DISTANCE` for `scan` at `time_usec`. Element j merges the
/// scan's sectors whose centres lie within 5 degrees of 5j - 180 (four of
/// them): the nearest hazard if any (cm, rounded down, so never read
/// farther than it is, and below `max_distance`), else `max_distance + 1`
/// (free) when all four are free, else `UINT16_MAX` (unknown). Each sector
/// thus sits in two neighbouring elements, and the even elements alone (or
/// the odd ones) hold every hazard.
pub fn obstacle_distance(scan: &Scan, time_usec: u64) -> OBSTACLE_DISTANCE_DATA {
    let layout = scan.layout();
    let (min_cm, max_cm) = distance_limits_cm(&layout);
    let distances = core::array::from_fn(|element| {
        let merge = element_sectors(&layout, element)
            .into_iter()
            .fold(Merge::Free, |merge, k| merge.with(k.map_or(Sector::Unknown, |k| scan.sector(k))));
        match merge {
            Merge::Unknown => u16::MAX,
            Merge::Free => max_cm + 1,
            Merge::Hazard(mm) => (mm / 10).clamp(min_cm, max_cm - 1),
        }
    });
    message(&layout, time_usec, distances)
}

/// `OBSTACLE_DISTANCE` for a frame that tells nothing about the ground
/// (only (re)started the keyframe, not judged, lost or late): a hazard at
/// `min_distance` in every element that holds any of the scan's sectors,
/// unknown elsewhere. This is the alarm pin's rule (doubt is an obstacle)
/// in the autopilots' terms: ArduPilot clears every face on each message
/// and skips unknown elements, PX4 keeps a bin's last value while its
/// element is unknown, so an all-unknown message would let both drive on.
pub fn obstacle_distance_in_doubt(layout: &ScanLayout, time_usec: u64) -> OBSTACLE_DISTANCE_DATA {
    let (min_cm, _) = distance_limits_cm(layout);
    let distances =
        core::array::from_fn(|element| if element_sectors(layout, element).iter().any(Option::is_some) { min_cm } else { u16::MAX });
    message(layout, time_usec, distances)
}

/// Sectors merged into one element.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Merge {
    Unknown,
    Free,
    Hazard(u16),
}

impl Merge {
    fn with(self, sector: Sector) -> Merge {
        match (self, sector) {
            (Merge::Hazard(a), Sector::Hazard(b)) => Merge::Hazard(a.min(b)),
            (Merge::Hazard(a), _) => Merge::Hazard(a),
            (_, Sector::Hazard(b)) => Merge::Hazard(b),
            (Merge::Unknown, _) | (_, Sector::Unknown) => Merge::Unknown,
            (Merge::Free, Sector::Free) => Merge::Free,
        }
    }
}

// ---------------------------------------------------------------- input

/// What [`FrameDecoder`] delivers. ODOMETRY makes it 250 B; without a heap
/// it cannot be boxed, and one is moved at a time.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Inbound {
    Odometry(ODOMETRY_DATA),
    LocalPosition(LOCAL_POSITION_NED_DATA),
    Attitude(ATTITUDE_DATA),
    /// A `HEARTBEAT` (the autopilot's, or anyone's).
    Heartbeat { system_id: u8, component_id: u8 },
}

/// Why a frame was dropped. Each is counted; none stops the decoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MavError {
    /// The checksum does not match (damaged, or cut short and run into the
    /// next frame).
    Checksum { message_id: u32 },
    /// A message this sensor does not read (its checksum cannot be checked
    /// without its definition): skipped.
    Foreign { message_id: u32 },
    /// The payload does not decode (e.g. an enum value out of range).
    Payload { message_id: u32 },
    /// A MAVLink 1 frame (0xFE): skipped.
    Version1,
    /// Incompatibility flags this reader does not know.
    Incompatible { flags: u8 },
}

impl fmt::Display for MavError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MavError::Checksum { message_id } => write!(f, "message {message_id}: bad checksum"),
            MavError::Foreign { message_id } => write!(f, "message {message_id}: not read here"),
            MavError::Payload { message_id } => write!(f, "message {message_id}: payload does not decode"),
            MavError::Version1 => f.write_str("MAVLink 1 frame"),
            MavError::Incompatible { flags } => write!(f, "unknown incompatibility flags {flags:#04x}"),
        }
    }
}

impl core::error::Error for MavError {}

/// The decoder's counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MavStats {
    pub frames: u32,
    /// Bytes outside any frame.
    pub garbage_bytes: u32,
    pub checksum: u32,
    pub foreign: u32,
    pub payload: u32,
    pub version1: u32,
    pub incompatible: u32,
}

const STX_V2: u8 = 0xFD;
const STX_V1: u8 = 0xFE;
const HEADER: usize = 10;
const SIGNED: u8 = 0x01;
const SIGNATURE: usize = 13;

/// Reads MAVLink 2 frames a byte at a time. Bytes before a start marker are
/// garbage; a frame's length comes from its header, so a damaged frame
/// costs at most that frame (its checksum fails) before the decoder looks
/// for the next start marker.
pub struct FrameDecoder {
    buffer: [u8; MAX_FRAME],
    len: usize,
    /// Bytes the frame in progress has in all (0: looking for a start).
    expected: usize,
    stats: MavStats,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    pub const fn new() -> Self {
        FrameDecoder { buffer: [0; MAX_FRAME], len: 0, expected: 0, stats: MavStats { frames: 0, garbage_bytes: 0, checksum: 0, foreign: 0, payload: 0, version1: 0, incompatible: 0 } }
    }

    pub fn stats(&self) -> MavStats {
        self.stats
    }

    /// Whether no frame is in progress (the byte stream is between frames).
    pub fn idle(&self) -> bool {
        self.len == 0
    }

    /// One byte; a finished frame gives its message or why it was dropped.
    pub fn push(&mut self, byte: u8) -> Option<Result<Inbound, MavError>> {
        if self.len == 0 {
            match byte {
                STX_V2 | STX_V1 => {}
                _ => {
                    self.stats.garbage_bytes = self.stats.garbage_bytes.saturating_add(1);
                    return None;
                }
            }
        }
        self.buffer[self.len] = byte;
        self.len += 1;
        if self.len == 3 {
            // Start marker and payload length known: the frame's size.
            let payload = usize::from(self.buffer[1]);
            self.expected = match self.buffer[0] {
                STX_V1 => 6 + payload + 2,
                _ if self.buffer[2] & SIGNED != 0 => HEADER + payload + 2 + SIGNATURE,
                _ => HEADER + payload + 2,
            };
        }
        if self.len < 3 || self.len < self.expected {
            return None;
        }
        let total = self.len;
        self.len = 0;
        self.expected = 0;
        let result = self.decode(total);
        if let Err(error) = result {
            let counter = match error {
                MavError::Checksum { .. } => &mut self.stats.checksum,
                MavError::Foreign { .. } => &mut self.stats.foreign,
                MavError::Payload { .. } => &mut self.stats.payload,
                MavError::Version1 => &mut self.stats.version1,
                MavError::Incompatible { .. } => &mut self.stats.incompatible,
            };
            *counter = counter.saturating_add(1);
        } else {
            self.stats.frames = self.stats.frames.saturating_add(1);
        }
        Some(result)
    }

    fn decode(&self, total: usize) -> Result<Inbound, MavError> {
        let frame = &self.buffer[..total];
        if frame[0] == STX_V1 {
            return Err(MavError::Version1);
        }
        let flags = frame[2];
        if flags & !SIGNED != 0 {
            return Err(MavError::Incompatible { flags });
        }
        let payload_len = usize::from(frame[1]);
        let message_id = u32::from_le_bytes([frame[7], frame[8], frame[9], 0]);
        let (system_id, component_id) = (frame[5], frame[6]);
        let body = &frame[1..HEADER + payload_len];
        let crc = u16::from_le_bytes([frame[HEADER + payload_len], frame[HEADER + payload_len + 1]]);
        let payload = &frame[HEADER..HEADER + payload_len];
        fn read<D: MessageData>(body: &[u8], crc: u16, payload: &[u8]) -> Result<D, MavError> {
            if mavlink::calculate_crc(body, D::EXTRA_CRC) != crc {
                return Err(MavError::Checksum { message_id: D::ID });
            }
            D::deser(MavlinkVersion::V2, payload).map_err(|_| MavError::Payload { message_id: D::ID })
        }
        match message_id {
            ODOMETRY_DATA::ID => read::<ODOMETRY_DATA>(body, crc, payload).map(Inbound::Odometry),
            LOCAL_POSITION_NED_DATA::ID => read::<LOCAL_POSITION_NED_DATA>(body, crc, payload).map(Inbound::LocalPosition),
            ATTITUDE_DATA::ID => read::<ATTITUDE_DATA>(body, crc, payload).map(Inbound::Attitude),
            HEARTBEAT_DATA::ID => read::<HEARTBEAT_DATA>(body, crc, payload).map(|_| Inbound::Heartbeat { system_id, component_id }),
            _ => Err(MavError::Foreign { message_id }),
        }
    }
}

// ---------------------------------------------------------------- frames

/// Why a pose message cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PoseError {
    /// `ODOMETRY.frame_id` is not a local NED or FRD frame.
    Frame,
    /// The attitude is not finite (and not marked unknown).
    Attitude,
}

impl fmt::Display for PoseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PoseError::Frame => "ODOMETRY is not in MAV_FRAME_LOCAL_NED or MAV_FRAME_LOCAL_FRD",
            PoseError::Attitude => "attitude not finite",
        })
    }
}

impl core::error::Error for PoseError {}

type Matrix = [[f64; 3]; 3];

fn multiply(a: &Matrix, b: &Matrix) -> Matrix {
    core::array::from_fn(|i| core::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

fn transpose(a: &Matrix) -> Matrix {
    core::array::from_fn(|i| core::array::from_fn(|j| a[j][i]))
}

/// NED/FRD coordinates (X, Y, Z) -> RECORDING.md's (x, y, z) = (Y, -Z, X).
const TO_ROBOT: Matrix = [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];

/// RECORDING.md's attitude and heading as a body-to-world rotation (robot axes):
/// heading about up (positive left), after roll about forward after pitch about right.
fn robot_rotation(yaw_deg: f64, attitude: Attitude) -> Matrix {
    let (sy, cy) = libm::sincos(yaw_deg.to_radians());
    let (sp, cp) = libm::sincos(attitude.pitch_deg.to_radians());
    let (sr, cr) = libm::sincos(attitude.roll_deg.to_radians());
    let heading = [[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]];
    let tilt = [[cr, sr * cp, -sr * sp], [-sr, cr * cp, -cr * sp], [0.0, sp, cp]];
    multiply(&heading, &tilt)
}

/// Inverse of [`robot_rotation`]: (yaw, attitude), degrees.
fn robot_angles(r: &Matrix) -> (f64, Attitude) {
    let roll = libm::asin((-r[1][0]).clamp(-1.0, 1.0));
    let pitch = libm::atan2(-r[1][2], r[1][1]);
    let (sp, cp) = libm::sincos(pitch);
    let (sr, cr) = libm::sincos(roll);
    let tilt_row0 = [cr, sr * cp, -sr * sp];
    let dot = |row: &[f64; 3]| row.iter().zip(tilt_row0).map(|(a, b)| a * b).sum::<f64>();
    let yaw = libm::atan2(dot(&r[2]), dot(&r[0]));
    (yaw.to_degrees(), Attitude { pitch_deg: pitch.to_degrees(), roll_deg: roll.to_degrees() })
}

fn ned_from_robot(r: &Matrix) -> Matrix {
    multiply(&transpose(&TO_ROBOT), &multiply(r, &TO_ROBOT))
}

fn robot_from_ned(r: &Matrix) -> Matrix {
    multiply(&TO_ROBOT, &multiply(r, &transpose(&TO_ROBOT)))
}

/// Quaternion (w, x, y, z) -> rotation matrix.
fn from_quaternion(q: [f64; 4]) -> Matrix {
    let n = libm::sqrt(q.iter().map(|v| v * v).sum::<f64>());
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// Rotation matrix -> quaternion (w, x, y, z), w >= 0.
fn to_quaternion(r: &Matrix) -> [f64; 4] {
    let trace = r[0][0] + r[1][1] + r[2][2];
    let q = if trace > 0.0 {
        let s = 2.0 * libm::sqrt(trace + 1.0);
        [0.25 * s, (r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = 2.0 * libm::sqrt(1.0 + r[0][0] - r[1][1] - r[2][2]);
        [(r[2][1] - r[1][2]) / s, 0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s]
    } else if r[1][1] > r[2][2] {
        let s = 2.0 * libm::sqrt(1.0 + r[1][1] - r[0][0] - r[2][2]);
        [(r[0][2] - r[2][0]) / s, (r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s]
    } else {
        let s = 2.0 * libm::sqrt(1.0 + r[2][2] - r[0][0] - r[1][1]);
        [(r[1][0] - r[0][1]) / s, (r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s]
    };
    if q[0] < 0.0 {
        q.map(|v| -v)
    } else {
        q
    }
}

/// Aerospace ZYX angles (roll, pitch, yaw; radians) -> body-FRD-to-NED rotation.
fn from_euler(roll: f64, pitch: f64, yaw: f64) -> Matrix {
    let (sr, cr) = libm::sincos(roll);
    let (sp, cp) = libm::sincos(pitch);
    let (sy, cy) = libm::sincos(yaw);
    [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
}

/// Body-FRD-to-NED rotation -> aerospace (roll, pitch, yaw), radians.
fn to_euler(r: &Matrix) -> (f64, f64, f64) {
    (libm::atan2(r[2][1], r[2][2]), libm::asin((-r[2][0]).clamp(-1.0, 1.0)), libm::atan2(r[1][0], r[0][0]))
}

/// poses.csv's resolution: mm to 0.01, degrees to 0.0001 (see the module docs).
fn mm(metres: f32) -> f64 {
    libm::round(f64::from(metres) * 100_000.0) / 100.0
}

fn degrees(value: f64) -> f64 {
    libm::round(value * 10_000.0) / 10_000.0
}

/// `ODOMETRY.pose_covariance` indices of the roll and pitch variances
/// (upper triangle of x, y, z, roll, pitch, yaw, row by row).
const ROLL_VARIANCE: usize = 15;
const PITCH_VARIANCE: usize = 18;

/// The sample an `ODOMETRY` message gives: time `time_usec`; position
/// x, y NaN = no odometry; roll and pitch variances NaN = no attitude
/// (heading only).
pub fn sample_from_odometry(odometry: &ODOMETRY_DATA) -> Result<PoseSample, PoseError> {
    if !matches!(odometry.frame_id, MavFrame::MAV_FRAME_LOCAL_NED | MavFrame::MAV_FRAME_LOCAL_FRD) {
        return Err(PoseError::Frame);
    }
    let q = odometry.q.map(f64::from);
    if !q.iter().all(|v| v.is_finite()) || q.iter().all(|v| *v == 0.0) {
        return Err(PoseError::Attitude);
    }
    let (yaw, attitude) = robot_angles(&robot_from_ned(&from_quaternion(q)));
    let tilted = !(odometry.pose_covariance[ROLL_VARIANCE].is_nan() || odometry.pose_covariance[PITCH_VARIANCE].is_nan());
    let pose = (odometry.x.is_finite() && odometry.y.is_finite()).then(|| Pose { x_mm: mm(odometry.y), z_mm: mm(odometry.x), yaw_deg: degrees(yaw) });
    Ok(PoseSample {
        t_s: odometry.time_usec as f64 / 1e6,
        pose,
        attitude: tilted.then(|| Attitude { pitch_deg: degrees(attitude.pitch_deg), roll_deg: degrees(attitude.roll_deg) }),
    })
}

/// The sample `LOCAL_POSITION_NED` and the latest `ATTITUDE` give
/// (time: the position's).
pub fn sample_from_local_position(position: &LOCAL_POSITION_NED_DATA, attitude: &ATTITUDE_DATA) -> Result<PoseSample, PoseError> {
    let angles = [attitude.roll, attitude.pitch, attitude.yaw].map(f64::from);
    if !angles.iter().all(|v| v.is_finite()) {
        return Err(PoseError::Attitude);
    }
    let (yaw, tilt) = robot_angles(&robot_from_ned(&from_euler(angles[0], angles[1], angles[2])));
    let pose = (position.x.is_finite() && position.y.is_finite()).then(|| Pose { x_mm: mm(position.y), z_mm: mm(position.x), yaw_deg: degrees(yaw) });
    Ok(PoseSample {
        t_s: f64::from(position.time_boot_ms) / 1e3,
        pose,
        attitude: Some(Attitude { pitch_deg: degrees(tilt.pitch_deg), roll_deg: degrees(tilt.roll_deg) }),
    })
}

/// A sample's time `t_s` as the `time_usec` of the `ODOMETRY` sent for it
/// (and echoed in the frame's `OBSTACLE_DISTANCE`).
pub fn time_usec(t_s: f64) -> u64 {
    libm::round(t_s * 1e6) as u64
}

/// What an autopilot would send for `sample`: `ODOMETRY` in
/// `MAV_FRAME_LOCAL_NED` (the inverse of [`sample_from_odometry`]). A
/// sample without odometry sends NaN x, y and heading 0; without attitude,
/// NaN roll and pitch variances.
pub fn odometry_for(sample: &PoseSample) -> ODOMETRY_DATA {
    let yaw = sample.pose.map_or(0.0, |pose| pose.yaw_deg);
    let q = to_quaternion(&ned_from_robot(&robot_rotation(yaw, sample.attitude.unwrap_or_default())));
    let mut pose_covariance = [0.0f32; 21];
    if sample.attitude.is_none() {
        pose_covariance[ROLL_VARIANCE] = f32::NAN;
        pose_covariance[PITCH_VARIANCE] = f32::NAN;
    }
    let (x, y) = sample.pose.map_or((f32::NAN, f32::NAN), |pose| ((pose.z_mm / 1000.0) as f32, (pose.x_mm / 1000.0) as f32));
    ODOMETRY_DATA {
        time_usec: time_usec(sample.t_s),
        x,
        y,
        z: 0.0,
        q: q.map(|v| v as f32),
        pose_covariance,
        velocity_covariance: [f32::NAN; 21],
        frame_id: MavFrame::MAV_FRAME_LOCAL_NED,
        child_frame_id: MavFrame::MAV_FRAME_BODY_FRD,
        ..ODOMETRY_DATA::DEFAULT
    }
}

/// The `LOCAL_POSITION_NED` + `ATTITUDE` pair for `sample` (inverse of
/// [`sample_from_local_position`]; time in whole milliseconds).
pub fn local_position_for(sample: &PoseSample) -> (LOCAL_POSITION_NED_DATA, ATTITUDE_DATA) {
    let yaw = sample.pose.map_or(0.0, |pose| pose.yaw_deg);
    let (roll, pitch, heading) = to_euler(&ned_from_robot(&robot_rotation(yaw, sample.attitude.unwrap_or_default())));
    let time_boot_ms = libm::round(sample.t_s * 1e3) as u32;
    let (x, y) = sample.pose.map_or((f32::NAN, f32::NAN), |pose| ((pose.z_mm / 1000.0) as f32, (pose.x_mm / 1000.0) as f32));
    (
        LOCAL_POSITION_NED_DATA { time_boot_ms, x, y, ..LOCAL_POSITION_NED_DATA::DEFAULT },
        ATTITUDE_DATA { time_boot_ms, roll: roll as f32, pitch: pitch as f32, yaw: heading as f32, ..ATTITUDE_DATA::DEFAULT },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::{ScanLayout, View};

    fn sample(yaw: f64, attitude: Option<Attitude>) -> PoseSample {
        PoseSample { t_s: 1.3, pose: Some(Pose { x_mm: -204.72, z_mm: 764.03, yaw_deg: yaw }), attitude }
    }

    #[test]
    fn odometry_round_trips_at_poses_csv_resolution() {
        for yaw in [0.0, 3.0, -27.0, 89.9999, 179.5, -0.0148] {
            for attitude in [None, Some(Attitude { pitch_deg: 0.3563, roll_deg: -0.599 }), Some(Attitude { pitch_deg: -4.0, roll_deg: 7.5 })] {
                let expected = sample(yaw, attitude);
                assert_eq!(sample_from_odometry(&odometry_for(&expected)), Ok(expected), "yaw {yaw} {attitude:?}");
                let (position, angles) = local_position_for(&expected);
                let with_attitude = PoseSample { attitude: Some(attitude.unwrap_or_default()), ..expected };
                assert_eq!(sample_from_local_position(&position, &angles), Ok(with_attitude), "yaw {yaw} {attitude:?}");
            }
        }
        let no_odometry = PoseSample { pose: None, ..sample(0.0, None) };
        assert_eq!(sample_from_odometry(&odometry_for(&no_odometry)), Ok(no_odometry));
    }

    #[test]
    fn ned_conventions() {
        // North 1 m, east 2 m, facing east (heading 90 deg clockwise): x
        // 2000, z 1000, yaw -90 (left positive).
        let position = LOCAL_POSITION_NED_DATA { x: 1.0, y: 2.0, ..LOCAL_POSITION_NED_DATA::DEFAULT };
        let attitude = ATTITUDE_DATA { yaw: 90f32.to_radians(), ..ATTITUDE_DATA::DEFAULT };
        let got = sample_from_local_position(&position, &attitude).unwrap();
        assert_eq!(got.pose, Some(Pose { x_mm: 2000.0, z_mm: 1000.0, yaw_deg: -90.0 }));
        // Nose up 5 deg is pitch -5, right side down 3 deg roll +3 (the
        // two orders of turning differ in the second order only).
        let attitude = ATTITUDE_DATA { roll: 3f32.to_radians(), pitch: 5f32.to_radians(), ..ATTITUDE_DATA::DEFAULT };
        let tilt = sample_from_local_position(&position, &attitude).unwrap().attitude.unwrap();
        assert!((tilt.pitch_deg + 5.0).abs() < 0.02 && (tilt.roll_deg - 3.0).abs() < 0.02, "{tilt:?}");
    }

    #[test]
    fn obstacle_distance_elements_overlap_by_half() {
        // Eight sectors centred on -8.75, -6.25, ..., 8.75 degrees.
        let mut scan = Scan::new(ScanLayout::new(10.0, 450.0, 1500.0));
        scan.begin(1);
        scan.mark_view(15.0, |x, _| if x > -150.0 { View::Seen } else { View::Unseen });
        scan.add_point(-1.0, 809.0); // sector [-2.5, 0)
        let message = obstacle_distance(&scan, 5);
        assert_eq!((message.min_distance, message.max_distance), (45, 151), "max one cm beyond 1500 mm");
        // Element j is centred on 5j - 180 degrees: straight ahead is 36.
        assert_eq!(message.distances[36], 80, "809 mm rounded down");
        assert_eq!(message.distances[35], 80, "-5 degrees holds -1.25 too");
        assert_eq!(message.distances[37], 152, "1.25..8.75 free: max + 1");
        assert_eq!(message.distances[38], u16::MAX, "half outside the scan: unknown");
        assert_eq!(message.distances[34], u16::MAX, "-8.75 unseen");
        assert_eq!(message.distances[0], u16::MAX);
        assert_eq!((message.increment_f, message.angle_offset, message.frame), (5.0, -180.0, MavFrame::MAV_FRAME_BODY_FRD));
    }

    #[test]
    fn doubt_is_a_hazard_at_min_distance_wherever_the_scan_reaches() {
        // Sectors centred on -8.75..8.75 degrees: the elements centred on
        // -10..10 degrees hold some of them, the ones on +-15 none.
        let layout = ScanLayout::new(10.0, 450.0, 1500.0);
        let message = obstacle_distance_in_doubt(&layout, 7);
        let expected: [u16; 72] = core::array::from_fn(|j| if (34..=38).contains(&j) { 45 } else { u16::MAX });
        assert_eq!(message.distances, expected);
        assert_eq!((message.min_distance, message.max_distance, message.time_usec), (45, 151, 7));
        // A nearest range under 10 mm still sends at least 1 cm: ArduPilot skips 0.
        assert_eq!(obstacle_distance_in_doubt(&ScanLayout::new(10.0, 5.0, 1500.0), 7).distances[36], 1);
    }

    #[test]
    fn a_hazard_at_the_far_edge_stays_below_max_distance() {
        let mut scan = Scan::new(ScanLayout::new(10.0, 450.0, 1500.0));
        scan.begin(1);
        scan.mark_view(15.0, |_, _| View::Seen);
        scan.add_point(0.5, 1500.0);
        let message = obstacle_distance(&scan, 5);
        assert_eq!((message.distances[36], message.max_distance), (150, 151));
    }

    #[test]
    fn frames_round_trip_and_damage_is_typed() {
        let mut sender = Sender::default();
        let odometry = odometry_for(&sample(3.0, None));
        let frame = sender.encode(&odometry);
        let mut decoder = FrameDecoder::new();
        let mut out = None;
        for &byte in b"garbage$".iter().chain(frame.as_bytes()) {
            if let Some(result) = decoder.push(byte) {
                out = Some(result);
            }
        }
        assert!(matches!(out, Some(Ok(Inbound::Odometry(o))) if o.x == odometry.x && o.q == odometry.q));
        assert_eq!(decoder.stats().garbage_bytes, 8);
        let mut bytes = frame.as_bytes().to_vec();
        let n = bytes.len();
        bytes[n - 3] ^= 0x40;
        let results: Vec<_> = bytes.iter().filter_map(|&b| decoder.push(b)).collect();
        assert_eq!(results, [Err(MavError::Checksum { message_id: 331 })]);
        let foreign = sender.encode(&status_text(MavSeverity::MAV_SEVERITY_INFO, "hello"));
        let results: Vec<_> = foreign.as_bytes().iter().filter_map(|&b| decoder.push(b)).collect();
        assert_eq!(results, [Err(MavError::Foreign { message_id: 253 })]);
    }
}

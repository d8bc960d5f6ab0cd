//! The serial protocol between the firmware and its host (robot or runner).
//!
//! Versioned, line-oriented and checksummed, NMEA style:
//!
//! ```text
//! $FL<TYPE>,<field>,<field>,...*HH\r\n
//! ```
//!
//! `HH` is the XOR of every byte between `$` and `*`, in upper-case hex.
//! Readable on a serial terminal, resynchronised at the next `$` after
//! garbage, and implementable in a few lines on any robot controller.
//! `firmware/PROTOCOL.md` documents every message and argues the choice.
//!
//! Both directions use one [`Message`] type, one [`encode`] and one
//! [`Decoder`]; the firmware and the host share them. Each message's
//! fields are listed once, in a table both directions follow (`layout!`,
//! below). No heap, no panics:
//! the decoder is a byte-at-a-time state machine over a fixed line buffer
//! and every malformed input is a typed [`DecodeError`], also counted in
//! [`DecoderStats`].

use core::fmt::{self, Write};

use crate::geometry::{Aoi, Distortion, Intrinsics, Mount, Rig, RigError};
use crate::limits::MAX_LINE;
use crate::motion::{Attitude, Pose};
use crate::pipeline::PoseSample;
use crate::report::{FrameReport, Status};

/// Bumped whenever a message's fields change meaning or count (3: `FLFRM`
/// ends with the frame's `status`, and a frame not judged is sent too).
pub const PROTOCOL_VERSION: u32 = 3;

/// One encoded line.
pub type Line = heapless::String<MAX_LINE>;

/// The rig as it travels on the wire and as rig.toml writes it: its
/// `[camera]`, `[mount]` and `[aoi]`, unvalidated (with the `serde`
/// feature the host deserialises rig.toml into it). `Rig::try_from(&record)`
/// validates it (`Rig::new_checked`); `RigRecord::from(&rig)` gives it back
/// with the same f64 values.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Deserialize), serde(deny_unknown_fields))]
pub struct RigRecord {
    pub camera: Intrinsics,
    /// Roll and yaw on the wire: two optional trailing fields, written only
    /// when either is nonzero, so a level rig's message is the version-2
    /// message it always was.
    pub mount: Mount,
    pub aoi: Aoi,
}

/// All zeros (no lens): the decoder fills it in wire order.
impl Default for RigRecord {
    fn default() -> RigRecord {
        RigRecord {
            camera: Intrinsics { width: 0, height: 0, fx: 0.0, fy: 0.0, cx: 0.0, cy: 0.0, distortion: None, readout_ms: 0.0 },
            mount: Mount { height_mm: 0.0, tilt_deg: 0.0, roll_deg: 0.0, yaw_deg: 0.0 },
            aoi: Aoi { half_width_mm: 0.0, near_mm: 0.0, far_mm: 0.0 },
        }
    }
}

impl From<&Rig> for RigRecord {
    fn from(rig: &Rig) -> RigRecord {
        RigRecord { camera: *rig.camera(), mount: *rig.mount(), aoi: *rig.aoi() }
    }
}

impl TryFrom<&RigRecord> for Rig {
    type Error = RigError;

    fn try_from(record: &RigRecord) -> Result<Rig, RigError> {
        Rig::new_checked(record.camera, record.mount, record.aoi)
    }
}

/// What the robot's sensors said when frame `frame` was captured (a
/// poses.csv row): the time, and the wheels' pose and the IMU's attitude
/// when the robot has them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Odometry {
    pub frame: u32,
    pub t_s: f64,
    /// The wheel odometry's world-frame pose; None: no motion fields.
    pub pose: Option<Pose>,
    /// The IMU's body attitude; None: no IMU fields.
    pub attitude: Option<Attitude>,
}

/// The pipeline's view of an odometry message: when, and what the sensors said.
impl From<Odometry> for PoseSample {
    fn from(odometry: Odometry) -> Self {
        let Odometry { frame: _, t_s, pose, attitude } = odometry;
        PoseSample { t_s, pose, attitude }
    }
}

/// What a line decoder refused ([`Decoder::stats`]). The MAVLink build folds
/// its frame decoder's refusals in, and every build its serial overruns
/// (as garbage).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Bytes outside any `$...\n` line.
    pub garbage_bytes: u32,
    /// Lines cut short by a new `$`.
    pub truncated: u32,
    /// Lines longer than [`MAX_LINE`].
    pub too_long: u32,
    /// Lines with a missing or wrong checksum.
    pub bad_checksum: u32,
    /// Lines whose type is not one of ours.
    pub unknown_type: u32,
    /// Lines with a wrong version, field count or field value.
    pub bad_field: u32,
}

impl DecoderStats {
    /// Nothing refused yet (`Default`, in a `const fn`).
    pub const ZERO: DecoderStats =
        DecoderStats { garbage_bytes: 0, truncated: 0, too_long: 0, bad_checksum: 0, unknown_type: 0, bad_field: 0 };
}

/// What the firmware's frame loop counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoopStats {
    /// Frames processed to the end (with a report, or (re)starting the keyframe).
    pub frames: u32,
    /// Well-formed messages that make no sense where they came (e.g. odometry before the rig).
    pub out_of_order: u32,
    /// Frames that restarted the keyframe because the frame before them is
    /// missing (no pose, no or broken frame, time not increasing).
    pub frame_gaps: u32,
    /// Frames whose source stopped mid-frame (abandoned; see `FaultCode::FrameRead`).
    pub aborted: u32,
}

/// The counters a run ends with (`$FLSTA`): its input's and its loop's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    pub decoder: DecoderStats,
    pub frame_loop: LoopStats,
}

/// A condition the firmware reports: it gives up on a frame or the rig, or
/// a sensor went quiet. Every one of them asserts the alarm.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultCode {
    /// `Rig::new_checked` refused the rig.
    RigRejected,
    /// The KG grid or the remap table could not be built for the rig.
    TableRejected,
    /// The frame file could not be opened.
    FrameMissing,
    /// The frame file is not a PGM of the rig's size.
    FrameFormat,
    /// The frame file ended early or could not be read.
    FrameRead,
    /// The streaming remap refused a row.
    RemapFailed,
    /// The KG grid needs more keyframe memory than the target has.
    GridTooLarge,
    /// The camera rows need more row memory than the target has.
    CameraTooLarge,
    /// The camera delivered no frame within `health::CAMERA_TIMEOUT_US` of
    /// being asked (the frame is abandoned).
    CameraTimeout,
    /// No `$FLODO` for `health::ODOMETRY_TIMEOUT_US` while the firmware
    /// waited for one; `frame` is the last frame whose `$FLODO` came.
    OdometryLost,
}

impl FaultCode {
    /// Every code, in wire order.
    pub const ALL: [FaultCode; 10] = [
        FaultCode::RigRejected,
        FaultCode::TableRejected,
        FaultCode::FrameMissing,
        FaultCode::FrameFormat,
        FaultCode::FrameRead,
        FaultCode::RemapFailed,
        FaultCode::GridTooLarge,
        FaultCode::CameraTooLarge,
        FaultCode::CameraTimeout,
        FaultCode::OdometryLost,
    ];

    /// The wire name (also used in logs).
    pub const fn as_str(self) -> &'static str {
        match self {
            FaultCode::RigRejected => "rig_rejected",
            FaultCode::TableRejected => "table_rejected",
            FaultCode::FrameMissing => "frame_missing",
            FaultCode::FrameFormat => "frame_format",
            FaultCode::FrameRead => "frame_read",
            FaultCode::RemapFailed => "remap_failed",
            FaultCode::GridTooLarge => "grid_too_large",
            FaultCode::CameraTooLarge => "camera_too_large",
            FaultCode::CameraTimeout => "camera_timeout",
            FaultCode::OdometryLost => "odometry_lost",
        }
    }

    fn from_wire(name: &str) -> Option<FaultCode> {
        FaultCode::ALL.into_iter().find(|code| code.as_str() == name)
    }
}

/// A fault and the frame it concerns (0 when it concerns the run).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fault {
    pub code: FaultCode,
    pub frame: u32,
}

/// Every message, in both directions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Message {
    /// Firmware → host, at boot once the serial port listens: the protocol
    /// version; the host sends the rig after it (bytes sent earlier may be lost). `$FLRDY`.
    Ready,
    /// Firmware → host, once the rig is accepted: version and the rig in use. `$FLHEL`.
    Hello(RigRecord),
    /// Host → firmware: the rig to build the remap table for. `$FLRIG`.
    Rig(RigRecord),
    /// Host → firmware: the pose of the next frame. `$FLODO`.
    Odometry(Odometry),
    /// Firmware → host: one frame's result, the fields of `flatland detect`,
    /// for every frame judged or not (its `status`; not the run's first). `$FLFRM`.
    Frame(FrameReport),
    /// Firmware → host: counters, sent at the end of the run. `$FLSTA`.
    Stats(LinkStats),
    /// Firmware → host: a fault. `$FLERR`.
    Fault(Fault),
    /// Host → firmware: no more frames. `$FLEND`.
    End,
}

impl Message {
    /// The type tag after `$`.
    pub const fn tag(&self) -> &'static str {
        match self {
            Message::Ready => "FLRDY",
            Message::Hello(_) => "FLHEL",
            Message::Rig(_) => "FLRIG",
            Message::Odometry(_) => "FLODO",
            Message::Frame(_) => "FLFRM",
            Message::Stats(_) => "FLSTA",
            Message::Fault(_) => "FLERR",
            Message::End => "FLEND",
        }
    }
}

/// Why a message could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// NaN or infinity: the decoder would refuse it, so the encoder does.
    NonFinite,
    /// The writer refused (e.g. a full buffer).
    Write,
}

impl From<fmt::Error> for EncodeError {
    fn from(_: fmt::Error) -> Self {
        EncodeError::Write
    }
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            EncodeError::NonFinite => "a value is NaN or infinite",
            EncodeError::Write => "the writer refused the line",
        })
    }
}

impl core::error::Error for EncodeError {}

/// Why a line was refused. Each is counted in [`DecoderStats`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// A `$` arrived before the previous line ended.
    Truncated,
    /// The line exceeded [`MAX_LINE`]; the rest of it is skipped.
    TooLong,
    /// No `*HH` before the line end.
    MissingChecksum,
    /// The checksum does not match.
    BadChecksum,
    /// The type tag is not one of [`Message`]'s.
    UnknownType,
    /// The version field is not [`PROTOCOL_VERSION`].
    UnsupportedVersion,
    /// Too few or too many fields for the type.
    FieldCount,
    /// Field `index` (1 = first after the tag) does not parse or is out of range.
    BadField { index: u8 },
}

impl DecodeError {
    /// A short name for logs.
    pub const fn as_str(self) -> &'static str {
        match self {
            DecodeError::Truncated => "truncated",
            DecodeError::TooLong => "too_long",
            DecodeError::MissingChecksum => "missing_checksum",
            DecodeError::BadChecksum => "bad_checksum",
            DecodeError::UnknownType => "unknown_type",
            DecodeError::UnsupportedVersion => "unsupported_version",
            DecodeError::FieldCount => "field_count",
            DecodeError::BadField { .. } => "bad_field",
        }
    }
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::Truncated => f.write_str("line cut short by a new `$`"),
            DecodeError::TooLong => write!(f, "line longer than {MAX_LINE} bytes"),
            DecodeError::MissingChecksum => f.write_str("no `*HH` checksum before the line end"),
            DecodeError::BadChecksum => f.write_str("checksum does not match"),
            DecodeError::UnknownType => f.write_str("unknown message type"),
            DecodeError::UnsupportedVersion => write!(f, "protocol version is not {PROTOCOL_VERSION}"),
            DecodeError::FieldCount => f.write_str("too few or too many fields for the message type"),
            DecodeError::BadField { index } => write!(f, "field {index} does not parse or is out of range"),
        }
    }
}

impl core::error::Error for DecodeError {}

// ---------------------------------------------------------------- encoding

/// Forwards to `inner` and folds every byte into the XOR checksum.
struct ChecksumWriter<'a, W: Write> {
    inner: &'a mut W,
    checksum: u8,
}

impl<W: Write> Write for ChecksumWriter<'_, W> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.checksum = s.bytes().fold(self.checksum, |acc, b| acc ^ b);
        self.inner.write_str(s)
    }
}

/// XOR of `body`'s bytes: the NMEA checksum.
pub fn checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |acc, b| acc ^ b)
}

fn write_body<W: Write>(out: &mut W, message: &Message) -> Result<(), EncodeError> {
    out.write_str(message.tag())?;
    match message {
        Message::Ready => Version.write(out),
        Message::Hello(rig) | Message::Rig(rig) => rig.write(out),
        Message::Odometry(odometry) => odometry.write_fields(out),
        Message::Frame(report) => report.write_fields(out),
        Message::Stats(stats) => stats.write_fields(out),
        Message::Fault(fault) => fault.write_fields(out),
        Message::End => Ok(()),
    }
}

/// Writes `message` as one line, `$` to `\r\n`.
pub fn encode<W: Write>(message: &Message, out: &mut W) -> Result<(), EncodeError> {
    out.write_char('$')?;
    let mut body = ChecksumWriter { inner: out, checksum: 0 };
    write_body(&mut body, message)?;
    let sum = body.checksum;
    write!(out, "*{sum:02X}\r\n")?;
    Ok(())
}

/// [`encode`] into a fixed-capacity [`Line`].
pub fn encode_line(message: &Message) -> Result<Line, EncodeError> {
    let mut line = Line::new();
    encode(message, &mut line)?;
    Ok(line)
}

// ---------------------------------------------------------------- field tables
//
// Each message body is a table of fields in wire order (`layout!`); the
// encoder writes and the decoder reads through the same table, and each
// field's type knows its own text (`Field`).

/// One value's text on the wire: how it is written (with its leading
/// comma) and read back.
trait Field: Sized {
    fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError>;
    fn read(fields: &mut Fields) -> Result<Self, DecodeError>;
}

/// Integers: decimal.
macro_rules! integer_field {
    ($($ty:ty),*) => {$(
        impl Field for $ty {
            fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
                Ok(write!(out, ",{self}")?)
            }
            fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
                let raw = fields.next_raw()?;
                raw.parse().map_err(|_| fields.bad())
            }
        }
    )*};
}
integer_field!(u16, u32, i32);

/// An optional value: its own text, or an empty field.
macro_rules! optional_field {
    ($($ty:ty),*) => {$(
        impl Field for Option<$ty> {
            fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
                match self {
                    Some(value) => value.write(out),
                    None => Ok(out.write_char(',')?),
                }
            }
            fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
                if fields.next_is_empty() {
                    fields.next_raw()?;
                    return Ok(None);
                }
                <$ty>::read(fields).map(Some)
            }
        }
    )*};
}
optional_field!(i32, bool);

/// A float, so that parsing it gives back the same bits: plain decimal in
/// the usual range (readable), exponent form outside it (bounded length).
/// NaN and infinity are refused both ways.
impl Field for f64 {
    fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
        let value = *self;
        if !value.is_finite() {
            return Err(EncodeError::NonFinite);
        }
        let magnitude = value.abs();
        if magnitude == 0.0 || (1e-6..1e9).contains(&magnitude) {
            write!(out, ",{value}")?;
        } else {
            write!(out, ",{value:e}")?;
        }
        Ok(())
    }
    fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
        let raw = fields.next_raw()?;
        parse_finite(raw).ok_or(fields.bad())
    }
}

fn parse_finite(raw: &str) -> Option<f64> {
    raw.parse::<f64>().ok().filter(|value| value.is_finite())
}

/// A flag: `0` or `1`.
impl Field for bool {
    fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
        Ok(write!(out, ",{}", u8::from(*self))?)
    }
    fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
        match fields.next_raw()? {
            "0" => Ok(false),
            "1" => Ok(true),
            _ => Err(fields.bad()),
        }
    }
}

/// Named values: their names (`report::Status`, [`FaultCode`]).
macro_rules! named_field {
    ($($ty:ty: $parse:path),*) => {$(
        impl Field for $ty {
            fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
                Ok(write!(out, ",{}", self.as_str())?)
            }
            fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
                let raw = fields.next_raw()?;
                $parse(raw).ok_or(fields.bad())
            }
        }
    )*};
}
named_field!(Status: Status::from_name, FaultCode: FaultCode::from_wire);

/// A lens: five coefficients, or five empty fields for none.
impl Field for Option<Distortion> {
    fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
        match self {
            Some(lens) => lens.coefficients().iter().try_for_each(|value| value.write(out)),
            None => Ok(out.write_str(",,,,,")?),
        }
    }
    fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
        let mut raw = [""; 5];
        let first = fields.index + 1;
        for slot in raw.iter_mut() {
            *slot = fields.next_raw()?;
        }
        if raw.iter().all(|text| text.is_empty()) {
            return Ok(None);
        }
        let mut coefficients = [0.0; 5];
        for (i, (slot, text)) in coefficients.iter_mut().zip(raw).enumerate() {
            *slot = parse_finite(text).ok_or(DecodeError::BadField { index: first + i as u8 })?;
        }
        Ok(Some(Distortion::from_coefficients(coefficients)))
    }
}

/// A group of fields in a fixed order, written and read whole.
trait Layout: Sized {
    fn write_fields<W: Write>(&self, out: &mut W) -> Result<(), EncodeError>;
    fn read_fields(fields: &mut Fields) -> Result<Self, DecodeError>;
}

/// A struct's [`Layout`]: its fields listed once, in wire order. The plain
/// form builds the struct from every one of its fields (a field added to
/// the struct and not to the table does not compile); the `default` form
/// takes field paths (`a.b`) and fills a `Default` value in wire order.
macro_rules! layout {
    ($ty:ident { $($field:ident),* $(,)? }) => {
        impl Layout for $ty {
            fn write_fields<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
                $( Field::write(&self.$field, out)?; )*
                Ok(())
            }
            fn read_fields(fields: &mut Fields) -> Result<Self, DecodeError> {
                Ok($ty { $( $field: Field::read(fields)?, )* })
            }
        }
    };
    ($ty:ident: default { $($($path:ident).+),* $(,)? }) => {
        impl Layout for $ty {
            fn write_fields<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
                $( Field::write(&self.$($path).+, out)?; )*
                Ok(())
            }
            fn read_fields(fields: &mut Fields) -> Result<Self, DecodeError> {
                let mut value = $ty::default();
                $( value.$($path).+ = Field::read(fields)?; )*
                Ok(value)
            }
        }
    };
}

// `$FLFRM`: `flatland detect`'s csv row, in its order.
layout!(FrameReport {
    frame, ref_frame, alarm, nearest_mm, left_mm, right_mm, sad, count50, shift_k, shift_g, tx, tz,
    obstacle_h_mm, dyaw, dpitch, droll, odometry_fault, status,
});
// `$FLSTA`: the loop's frames first, then the input's refusals, then the rest of the loop's.
layout!(LinkStats: default {
    frame_loop.frames, decoder.garbage_bytes, decoder.truncated, decoder.too_long, decoder.bad_checksum,
    decoder.unknown_type, decoder.bad_field, frame_loop.out_of_order, frame_loop.frame_gaps, frame_loop.aborted,
});
// `$FLERR`.
layout!(Fault { code, frame });
// `$FLRIG` and `$FLHEL` between the version and the mount's optional roll and yaw.
// Not `camera.readout_ms`: the firmware does not model a rolling shutter
// (only the host's calibration does), so a decoded rig has a global shutter.
layout!(RigRecord: default {
    camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, camera.distortion,
    mount.height_mm, mount.tilt_deg, aoi.half_width_mm, aoi.near_mm, aoi.far_mm,
});
// `$FLODO`'s optional groups.
layout!(Pose { x_mm, z_mm, yaw_deg });
layout!(Attitude { pitch_deg, roll_deg });

/// The protocol's version, the first field of `$FLRDY`, `$FLRIG` and `$FLHEL`.
struct Version;

impl Field for Version {
    fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
        PROTOCOL_VERSION.write(out)
    }
    fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
        match u32::read(fields)? {
            PROTOCOL_VERSION => Ok(Version),
            _ => Err(DecodeError::UnsupportedVersion),
        }
    }
}

/// `$FLRIG` and `$FLHEL`: the version, the table, then roll and yaw when
/// the mount is crooked (a level rig's message is the version-2 message it
/// always was).
impl Field for RigRecord {
    fn write<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
        Version.write(out)?;
        self.write_fields(out)?;
        // By bits: a -0.0 must come back as -0.0.
        if self.mount.roll_deg.to_bits() != 0 || self.mount.yaw_deg.to_bits() != 0 {
            self.mount.roll_deg.write(out)?;
            self.mount.yaw_deg.write(out)?;
        }
        Ok(())
    }
    fn read(fields: &mut Fields) -> Result<Self, DecodeError> {
        Version::read(fields)?;
        let mut rig = RigRecord::read_fields(fields)?;
        // A crooked mount adds roll and yaw; an older sender's message ends before them.
        if fields.remaining() == 2 {
            rig.mount.roll_deg = f64::read(fields)?;
            rig.mount.yaw_deg = f64::read(fields)?;
        }
        Ok(rig)
    }
}

/// `$FLODO`: `frame,t_s`, then the wheels' pose (3 fields) and the IMU's
/// attitude (2) when the robot has them: 2, 4, 5 or 7 fields, told apart by
/// their count.
impl Layout for Odometry {
    fn write_fields<W: Write>(&self, out: &mut W) -> Result<(), EncodeError> {
        self.frame.write(out)?;
        self.t_s.write(out)?;
        if let Some(pose) = &self.pose {
            pose.write_fields(out)?;
        }
        if let Some(attitude) = &self.attitude {
            attitude.write_fields(out)?;
        }
        Ok(())
    }
    fn read_fields(fields: &mut Fields) -> Result<Self, DecodeError> {
        let (has_pose, has_attitude) = match fields.remaining() {
            2 => (false, false),
            4 => (false, true),
            5 => (true, false),
            7 => (true, true),
            _ => return Err(DecodeError::FieldCount),
        };
        let frame = u32::read(fields)?;
        let t_s = f64::read(fields)?;
        let pose = if has_pose { Some(Pose::read_fields(fields)?) } else { None };
        let attitude = if has_attitude { Some(Attitude::read_fields(fields)?) } else { None };
        Ok(Odometry { frame, t_s, pose, attitude })
    }
}

// ---------------------------------------------------------------- decoding

/// The comma-separated fields after the tag, with their 1-based index for errors.
struct Fields<'a> {
    rest: core::str::Split<'a, char>,
    index: u8,
}

impl<'a> Fields<'a> {
    fn next_raw(&mut self) -> Result<&'a str, DecodeError> {
        self.index = self.index.saturating_add(1);
        self.rest.next().ok_or(DecodeError::FieldCount)
    }

    /// The field last read is bad.
    fn bad(&self) -> DecodeError {
        DecodeError::BadField { index: self.index }
    }

    /// Whether the next field is there and empty (an absent optional value).
    fn next_is_empty(&self) -> bool {
        self.rest.clone().next() == Some("")
    }

    /// How many fields are left.
    fn remaining(&self) -> usize {
        self.rest.clone().count()
    }

    fn finish(mut self) -> Result<(), DecodeError> {
        match self.rest.next() {
            None => Ok(()),
            Some(_) => Err(DecodeError::FieldCount),
        }
    }
}

fn decode_body(body: &str) -> Result<Message, DecodeError> {
    let mut split = body.split(',');
    let tag = split.next().unwrap_or("");
    let mut fields = Fields { rest: split, index: 0 };
    let message = match tag {
        "FLRDY" => Version::read(&mut fields).map(|Version| Message::Ready)?,
        "FLHEL" => Message::Hello(Field::read(&mut fields)?),
        "FLRIG" => Message::Rig(Field::read(&mut fields)?),
        "FLODO" => Message::Odometry(Layout::read_fields(&mut fields)?),
        "FLFRM" => Message::Frame(Layout::read_fields(&mut fields)?),
        "FLSTA" => Message::Stats(Layout::read_fields(&mut fields)?),
        "FLERR" => Message::Fault(Layout::read_fields(&mut fields)?),
        "FLEND" => Message::End,
        _ => return Err(DecodeError::UnknownType),
    };
    fields.finish()?;
    Ok(message)
}

fn hex_digit(byte: u8) -> Option<u8> {
    match byte {
        b'0'..=b'9' => Some(byte - b'0'),
        b'A'..=b'F' => Some(byte - b'A' + 10),
        b'a'..=b'f' => Some(byte - b'a' + 10),
        _ => None,
    }
}

/// Decodes one line without its `$` and line ending: `TAG,fields*HH`.
pub fn decode_line(line: &[u8]) -> Result<Message, DecodeError> {
    let star = line.iter().rposition(|&b| b == b'*').ok_or(DecodeError::MissingChecksum)?;
    let (body, sum) = (&line[..star], &line[star + 1..]);
    let expected = match sum {
        [high, low] => match (hex_digit(*high), hex_digit(*low)) {
            (Some(high), Some(low)) => (high << 4) | low,
            _ => return Err(DecodeError::MissingChecksum),
        },
        _ => return Err(DecodeError::MissingChecksum),
    };
    if checksum(body) != expected {
        return Err(DecodeError::BadChecksum);
    }
    let body = core::str::from_utf8(body).map_err(|_| DecodeError::UnknownType)?;
    decode_body(body)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// Between lines: waiting for `$`.
    Idle,
    /// Inside a line.
    Line,
    /// Skipping the rest of an overlong line.
    Discard,
}

/// Byte-at-a-time decoder with a fixed [`MAX_LINE`] buffer.
///
/// Feed it every received byte; it returns a result when a line ends (or is
/// cut short), and counts what it refused in [`Decoder::stats`].
#[derive(Debug)]
pub struct Decoder {
    line: heapless::Vec<u8, MAX_LINE>,
    state: State,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Decoder { line: heapless::Vec::new(), state: State::Idle, stats: DecoderStats::ZERO }
    }

    /// What was refused so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    fn count(&mut self, error: DecodeError) -> DecodeError {
        let counter = match error {
            DecodeError::Truncated => &mut self.stats.truncated,
            DecodeError::TooLong => &mut self.stats.too_long,
            DecodeError::MissingChecksum | DecodeError::BadChecksum => &mut self.stats.bad_checksum,
            DecodeError::UnknownType => &mut self.stats.unknown_type,
            DecodeError::UnsupportedVersion | DecodeError::FieldCount | DecodeError::BadField { .. } => {
                &mut self.stats.bad_field
            }
        };
        *counter = counter.saturating_add(1);
        error
    }

    /// Feeds one byte. `Some` when a line ended: the message or why it was refused.
    pub fn push(&mut self, byte: u8) -> Option<Result<Message, DecodeError>> {
        match (self.state, byte) {
            (State::Idle, b'$') | (State::Discard, b'$') => {
                self.line.clear();
                self.state = State::Line;
                None
            }
            (State::Idle, b'\r' | b'\n') => None,
            (State::Idle, _) => {
                self.stats.garbage_bytes = self.stats.garbage_bytes.saturating_add(1);
                None
            }
            (State::Discard, b'\n') => {
                self.state = State::Idle;
                None
            }
            (State::Discard, _) => None,
            (State::Line, b'$') => {
                self.line.clear();
                Some(Err(self.count(DecodeError::Truncated)))
            }
            (State::Line, b'\n') => {
                self.state = State::Idle;
                let line = match self.line.as_slice() {
                    [rest @ .., b'\r'] => rest,
                    all => all,
                };
                let result = decode_line(line);
                self.line.clear();
                Some(result.map_err(|error| self.count(error)))
            }
            (State::Line, _) => {
                if self.line.push(byte).is_err() {
                    self.line.clear();
                    self.state = State::Discard;
                    return Some(Err(self.count(DecodeError::TooLong)));
                }
                None
            }
        }
    }
}

/// The protocol's checks, listed in [`crate::selftest`] (host `#[test]`s
/// and the firmware's `selftest` binary on the target).
#[cfg(any(test, feature = "selftest"))]
pub mod checks;

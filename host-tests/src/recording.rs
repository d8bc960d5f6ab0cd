//! Reader for the recording layout of RECORDING.md: rig.toml, poses.csv,
//! frames/NNNNNN.pgm and the optional truth.toml.
//!
//! Every error names the file and, where there is one, the line.

use flatland_core::geometry::{Aoi, AoiEdge, Intrinsics, Mount, Rig, RigError};
use flatland_core::limits::MAX_IMAGE_SIDE;
use flatland_core::motion::{Attitude, Pose};
use flatland_core::pgm::{Pgm, PgmError};
use flatland_core::pipeline::PoseSample;
use flatland_core::protocol::{Odometry, RigRecord};
use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// What went wrong, and where.
#[derive(Debug)]
pub enum RecordingError {
    /// A file could not be read.
    Io { path: PathBuf, error: std::io::Error },
    /// A TOML file does not parse or lacks a key.
    Toml { path: PathBuf, line: Option<usize>, message: String },
    /// rig.toml parses but describes an impossible rig.
    Rig { path: PathBuf, line: Option<usize>, error: RigError },
    /// poses.csv's header names columns it cannot have (always line 1).
    PoseHeader { path: PathBuf, error: PoseHeaderError },
    /// A row of poses.csv is malformed.
    Csv { path: PathBuf, line: usize, message: String },
    /// poses.csv has no row for a frame that frames/ holds.
    NoPose { path: PathBuf, frame: u32 },
    /// A frame is not a valid 8-bit binary PGM.
    Pgm { path: PathBuf, error: PgmError },
    /// A frame's size differs from the rig's camera.
    FrameSize { path: PathBuf, expected: (usize, usize), got: (usize, usize) },
    /// frames/ holds no frame.
    NoFrames { path: PathBuf },
}

impl fmt::Display for RecordingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let at = |path: &PathBuf, line: &Option<usize>| match line {
            Some(line) => format!("{}:{line}", path.display()),
            None => path.display().to_string(),
        };
        match self {
            RecordingError::Io { path, error } => write!(f, "{}: {error}", path.display()),
            RecordingError::Toml { path, line, message } => write!(f, "{}: {message}", at(path, line)),
            RecordingError::Rig { path, line, error } => write!(f, "{}: impossible rig: {error}", at(path, line)),
            RecordingError::PoseHeader { path, error } => write!(f, "{}:1: {error}", path.display()),
            RecordingError::Csv { path, line, message } => write!(f, "{}:{line}: {message}", path.display()),
            RecordingError::NoPose { path, frame } => write!(f, "{}: no row for frame {frame}", path.display()),
            RecordingError::Pgm { path, error } => write!(f, "{}: {error}", path.display()),
            RecordingError::FrameSize { path, expected, got } => write!(
                f,
                "{}: frame is {}x{}, the rig's camera is {}x{}",
                path.display(),
                got.0,
                got.1,
                expected.0,
                expected.1
            ),
            RecordingError::NoFrames { path } => write!(f, "{}: no frames (expected NNNNNN.pgm files)", path.display()),
        }
    }
}

impl std::error::Error for RecordingError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            RecordingError::Io { error, .. } => Some(error),
            RecordingError::Rig { error, .. } => Some(error),
            RecordingError::Pgm { error, .. } => Some(error),
            _ => None,
        }
    }
}

/// `error` about `path`.
fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
    move |error| RecordingError::Io { path: path.into(), error }
}

fn read_text(path: &Path) -> Result<String, RecordingError> {
    std::fs::read_to_string(path).map_err(io_error(path))
}

/// 1-based line of a byte offset.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].bytes().filter(|&b| b == b'\n').count() + 1
}

/// 1-based line where `key` is assigned, for errors about its value.
fn line_of_key(text: &str, key: &str) -> Option<usize> {
    text.lines().position(|l| {
        let l = l.trim_start();
        l.starts_with(key) && l[key.len()..].trim_start().starts_with('=')
    })
    .map(|n| n + 1)
}

fn parse_toml<T: for<'de> Deserialize<'de>>(path: &Path, text: &str) -> Result<T, RecordingError> {
    toml::from_str(text).map_err(|e| RecordingError::Toml {
        path: path.into(),
        line: e.span().map(|span| line_of(text, span.start)),
        message: e.message().to_string(),
    })
}

/// The key whose value a rig error is about (in `record`, the rig as
/// binned), for the error's line number. Values are finite past `NotFinite`.
fn key_of(error: RigError, record: &RigRecord) -> &'static str {
    let either = |first_at_fault: bool, first, second| if first_at_fault { first } else { second };
    match error {
        RigError::NotFinite => "width",
        RigError::ImageSize => either(record.camera.width == 0 || record.camera.width > MAX_IMAGE_SIDE, "width", "height"),
        RigError::FocalLength => either(record.camera.fx <= 0.0, "fx", "fy"),
        RigError::PrincipalPoint => either(record.camera.cx < -0.5 || record.camera.cx > f64::from(record.camera.width) - 0.5, "cx", "cy"),
        RigError::MountHeight => "height_mm",
        RigError::Tilt => "tilt_deg",
        RigError::Roll => "roll_deg",
        RigError::Yaw => "yaw_deg",
        RigError::Distortion => "distortion",
        RigError::AoiEmpty => either(record.aoi.half_width_mm <= 0.0, "half_width_mm", "near_mm"),
        RigError::AoiBehindCamera | RigError::AoiOutsideImage(AoiEdge::Near) => "near_mm",
        RigError::AoiBeyondHorizon | RigError::AoiOutsideImage(AoiEdge::Far) => "far_mm",
        RigError::AoiOutsideImage(AoiEdge::Left | AoiEdge::Right) => "half_width_mm",
    }
}

/// How recorded frames are area-averaged down to the camera the pipeline
/// sees: frames larger than [`MAX_IMAGE_SIDE`] on a side (real cameras, up
/// to 4096 px wide) are binned by the smallest integer factor n that brings
/// both sides within it. Each n x n block becomes one pixel (its rounded
/// mean); a last partial column or row of blocks is dropped. Pixel centres
/// keep their place: block centre u = n u' + (n - 1)/2, so fx' = fx/n,
/// cx' = (cx + 0.5)/n - 0.5 (likewise fy, cy); distortion, in normalised
/// coordinates, is unchanged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Binning {
    /// n: camera pixels averaged per side (1: frames as recorded).
    pub factor: usize,
    /// The recorded frame size, rig.toml's `[camera]` width and height.
    pub recorded: (usize, usize),
}

impl Binning {
    /// The binning for frames of `width` x `height`.
    pub fn for_frames(width: usize, height: usize) -> Binning {
        let side = usize::from(MAX_IMAGE_SIDE);
        let factor = width.div_ceil(side).max(height.div_ceil(side)).max(1);
        Binning { factor, recorded: (width, height) }
    }

    /// The binned frame size.
    pub fn size(&self) -> (usize, usize) {
        (self.recorded.0 / self.factor, self.recorded.1 / self.factor)
    }

    /// The intrinsics of the binned camera (the rest of the record as is).
    fn scale(&self, record: &mut RigRecord) {
        let n = self.factor as f64;
        let (width, height) = self.size();
        // No larger than the u16 they came from.
        let camera = &mut record.camera;
        (camera.width, camera.height) = (width as u16, height as u16);
        camera.fx /= n;
        camera.fy /= n;
        camera.cx = (camera.cx + 0.5) / n - 0.5;
        camera.cy = (camera.cy + 0.5) / n - 0.5;
    }

    /// A recorded frame, binned (as it is when the factor is 1).
    pub fn apply(&self, frame: Frame) -> Frame {
        let n = self.factor;
        if n == 1 {
            return frame;
        }
        let (width, height) = (frame.width / n, frame.height / n);
        let area = (n * n) as u32;
        let mut sums = vec![0u32; width];
        let mut pixels = Vec::with_capacity(width * height);
        for block_row in frame.pixels.chunks_exact(n * frame.width).take(height) {
            sums.fill(0);
            for row in block_row.chunks_exact(frame.width) {
                for (sum, block) in sums.iter_mut().zip(row.chunks_exact(n)) {
                    *sum += block.iter().map(|&p| u32::from(p)).sum::<u32>();
                }
            }
            // A mean of bytes is a byte.
            pixels.extend(sums.iter().map(|&sum| ((sum + area / 2) / area) as u8));
        }
        Frame { width, height, pixels }
    }
}

/// Parses rig.toml text (the path is only for messages): the rig the
/// pipeline sees, its camera binned as [`Binning`] says, and that binning.
pub fn parse_rig(path: &Path, text: &str) -> Result<(Rig, Binning), RecordingError> {
    parse_rig_with(path, text, |record| Rig::try_from(record))
}

/// [`parse_rig`] for calibration: an AOI partly out of view at rig.toml's
/// mount, which may be wrong (calibration finds it), is limited to the view
/// ([`rig_with_aoi_in_view`]); the AOI does not matter to calibration.
pub fn parse_rig_for_calibration(path: &Path, text: &str) -> Result<(Rig, Binning), RecordingError> {
    parse_rig_with(path, text, |record| {
        let rig = Rig::try_from(record);
        if !matches!(rig, Err(RigError::AoiOutsideImage(_) | RigError::AoiBeyondHorizon)) {
            return rig;
        }
        rig_with_aoi_in_view(record.camera, record.mount, record.aoi)
    })
}

/// A rig with `aoi` limited to what the image sees at `mount`: a rig.toml
/// whose mount is wrong may put part of its AOI out of view, which does not
/// matter to calibration (it samples the ground it sees). The edge a refusal
/// names is pulled in until the AOI fits; the first refusal when it cannot.
pub fn rig_with_aoi_in_view(camera: Intrinsics, mount: Mount, aoi: Aoi) -> Result<Rig, RigError> {
    let mut fitted = aoi;
    let mut first_error = None;
    for _ in 0..200 {
        let error = match Rig::new_checked(camera, mount, fitted) {
            Ok(rig) => return Ok(rig),
            Err(e) => e,
        };
        let first = *first_error.get_or_insert(error);
        let depth = fitted.far_mm - fitted.near_mm;
        match error {
            RigError::AoiOutsideImage(AoiEdge::Near) => fitted.near_mm += 0.02 * depth,
            RigError::AoiOutsideImage(AoiEdge::Far) | RigError::AoiBeyondHorizon => fitted.far_mm -= 0.02 * depth,
            RigError::AoiOutsideImage(AoiEdge::Left | AoiEdge::Right) => fitted.half_width_mm *= 0.95,
            _ => return Err(first),
        }
    }
    Err(first_error.unwrap_or(RigError::AoiEmpty))
}

fn parse_rig_with(path: &Path, text: &str, build: impl Fn(&RigRecord) -> Result<Rig, RigError>) -> Result<(Rig, Binning), RecordingError> {
    // rig.toml's sections are the record's parts (core's `serde` feature).
    let mut record: RigRecord = parse_toml(path, text)?;
    let binning = Binning::for_frames(usize::from(record.camera.width), usize::from(record.camera.height));
    binning.scale(&mut record);
    let rig = build(&record).map_err(|error| {
        // For NaN/inf, point at the first offending key when we can find it.
        let line = if error == RigError::NotFinite {
            text.lines().position(|l| {
                // The value without its comment (rig.toml has no strings).
                let v = l.split('#').next().unwrap_or("").split('=').nth(1).unwrap_or("").to_ascii_lowercase();
                v.contains("nan") || v.contains("inf")
            })
            .map(|n| n + 1)
        } else {
            line_of_key(text, key_of(error, &record))
        };
        RecordingError::Rig { path: path.into(), line, error }
    })?;
    Ok((rig, binning))
}

/// One row of poses.csv.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseRow {
    pub frame: u32,
    /// 1-based line in poses.csv, for messages about this row.
    pub line: usize,
    pub t_s: f64,
    /// Wheel odometry's pose; None when poses.csv has no `x_mm,z_mm,yaw_deg`
    /// columns or this row leaves them empty.
    pub pose: Option<Pose>,
    /// The IMU's body attitude; None when poses.csv has no
    /// `pitch_deg,roll_deg` columns or this row leaves them empty.
    pub attitude: Option<Attitude>,
}

/// The pipeline's input for this row.
impl From<&PoseRow> for PoseSample {
    fn from(row: &PoseRow) -> Self {
        PoseSample { t_s: row.t_s, pose: row.pose, attitude: row.attitude }
    }
}

/// The `$FLODO` message a robot controller sends for this row.
impl From<&PoseRow> for Odometry {
    fn from(row: &PoseRow) -> Self {
        Odometry { frame: row.frame, t_s: row.t_s, pose: row.pose, attitude: row.attitude }
    }
}

/// The columns poses.csv may have: `frame,t_s` first, then the groups in
/// any order.
const FIRST_COLUMNS: [&str; 2] = ["frame", "t_s"];
const ODOMETRY_COLUMNS: [&str; 3] = ["x_mm", "z_mm", "yaw_deg"];
const IMU_COLUMNS: [&str; 2] = ["pitch_deg", "roll_deg"];

/// Why poses.csv's header was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PoseHeaderError {
    /// The file is empty.
    Empty,
    /// The first two columns are not `frame,t_s`.
    FirstColumns { found: String },
    /// A column that is not one of RECORDING.md's.
    Unknown { column: String },
    /// A column named twice.
    Duplicate { column: String },
    /// Part of a group of columns without the rest of it.
    Incomplete { column: &'static str, missing: &'static str },
}

impl fmt::Display for PoseHeaderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PoseHeaderError::Empty => f.write_str("empty file (expected a header such as frame,t_s,x_mm,z_mm,yaw_deg)"),
            PoseHeaderError::FirstColumns { found } => write!(f, "the header must start with frame,t_s, found {found:?}"),
            PoseHeaderError::Unknown { column } => write!(
                f,
                "unknown column {column:?} in the header (after frame,t_s: {}, {})",
                ODOMETRY_COLUMNS.join(","),
                IMU_COLUMNS.join(",")
            ),
            PoseHeaderError::Duplicate { column } => write!(f, "column {column:?} appears twice in the header"),
            PoseHeaderError::Incomplete { column, missing } => write!(f, "the header has {column} but not {missing}"),
        }
    }
}

impl std::error::Error for PoseHeaderError {}

/// Where each optional group's columns are in a row, from the header.
#[derive(Debug)]
struct PoseColumns {
    count: usize,
    odometry: Option<[usize; 3]>,
    imu: Option<[usize; 2]>,
}

impl PoseColumns {
    fn parse(header: &str) -> Result<PoseColumns, PoseHeaderError> {
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        if names.get(..2) != Some(&FIRST_COLUMNS[..]) {
            return Err(PoseHeaderError::FirstColumns { found: header.trim().into() });
        }
        let mut odometry = [None; 3];
        let mut imu = [None; 2];
        for (index, &name) in names.iter().enumerate().skip(2) {
            let slot = match (ODOMETRY_COLUMNS.iter().position(|&c| c == name), IMU_COLUMNS.iter().position(|&c| c == name)) {
                (Some(k), _) => &mut odometry[k],
                (_, Some(k)) => &mut imu[k],
                _ if FIRST_COLUMNS.contains(&name) => return Err(PoseHeaderError::Duplicate { column: name.into() }),
                _ => return Err(PoseHeaderError::Unknown { column: name.into() }),
            };
            if slot.replace(index).is_some() {
                return Err(PoseHeaderError::Duplicate { column: name.into() });
            }
        }
        Ok(PoseColumns { count: names.len(), odometry: whole_group(odometry, ODOMETRY_COLUMNS)?, imu: whole_group(imu, IMU_COLUMNS)? })
    }
}

/// A group's column indices when all of its columns are there, None when none is.
fn whole_group<const N: usize>(found: [Option<usize>; N], names: [&'static str; N]) -> Result<Option<[usize; N]>, PoseHeaderError> {
    match (found.iter().position(Option::is_some), found.iter().position(Option::is_none)) {
        (Some(have), Some(lack)) => Err(PoseHeaderError::Incomplete { column: names[have], missing: names[lack] }),
        (Some(_), None) => Ok(Some(found.map(Option::unwrap_or_default))),
        (None, _) => Ok(None),
    }
}

/// A group's values in a row: all empty is None, all numbers is Some.
fn group_values<const N: usize>(
    fields: &[&str],
    columns: Option<[usize; N]>,
    names: [&'static str; N],
) -> Result<Option<[f64; N]>, String> {
    let Some(columns) = columns else { return Ok(None) };
    if columns.iter().all(|&c| fields[c].is_empty()) {
        return Ok(None);
    }
    let mut values = [0.0; N];
    for ((value, &column), name) in values.iter_mut().zip(&columns).zip(names) {
        let field = fields[column];
        *value = match field.parse::<f64>() {
            Ok(v) if v.is_finite() => v,
            _ if field.is_empty() => return Err(format!("{name} is empty but not all of {} are", names.join(","))),
            _ => return Err(format!("bad {name} {field:?}")),
        };
    }
    Ok(Some(values))
}

/// Parses poses.csv: a header naming the columns (`frame,t_s`, then
/// optionally `x_mm,z_mm,yaw_deg` and `pitch_deg,roll_deg`), then one row per frame.
pub fn parse_poses(path: &Path, text: &str) -> Result<Vec<PoseRow>, RecordingError> {
    let csv_error = |line: usize, message: String| RecordingError::Csv { path: path.into(), line, message };
    let header_error = |error: PoseHeaderError| RecordingError::PoseHeader { path: path.into(), error };
    let mut lines = text.lines().enumerate();
    let columns = match lines.next() {
        Some((_, header)) => PoseColumns::parse(header).map_err(header_error)?,
        None => return Err(header_error(PoseHeaderError::Empty)),
    };
    let mut rows: Vec<PoseRow> = Vec::new();
    for (index, line) in lines {
        let line_number = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != columns.count {
            return Err(csv_error(line_number, format!("expected {} fields, found {}", columns.count, fields.len())));
        }
        let frame: u32 = fields[0].parse().map_err(|_| csv_error(line_number, format!("bad frame number {:?}", fields[0])))?;
        let t_s = fields[1]
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| csv_error(line_number, format!("bad t_s {:?}", fields[1])))?;
        let pose = group_values(&fields, columns.odometry, ODOMETRY_COLUMNS)
            .map_err(|message| csv_error(line_number, message))?
            .map(|[x_mm, z_mm, yaw_deg]| Pose { x_mm, z_mm, yaw_deg });
        let attitude = group_values(&fields, columns.imu, IMU_COLUMNS)
            .map_err(|message| csv_error(line_number, message))?
            .map(|[pitch_deg, roll_deg]| Attitude { pitch_deg, roll_deg });
        if let Some(previous) = rows.last() {
            if frame <= previous.frame {
                return Err(csv_error(line_number, format!("frame {frame} after frame {}", previous.frame)));
            }
        }
        rows.push(PoseRow { frame, line: line_number, t_s, pose, attitude });
    }
    if rows.is_empty() {
        return Err(csv_error(2, "no pose rows".into()));
    }
    Ok(rows)
}

/// An object standing on the ground (truth.toml), world frame at t = 0.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TruthObstacle {
    #[serde(default)]
    pub name: String,
    pub shape: Shape,
    pub x_mm: f64,
    pub z_mm: f64,
    pub width_mm: f64,
    pub depth_mm: f64,
    pub height_mm: f64,
    #[serde(default)]
    pub moving: bool,
    #[serde(default)]
    pub vx_mm_s: f64,
    #[serde(default)]
    pub vz_mm_s: f64,
}

impl TruthObstacle {
    /// Footprint centre in the world frame at time `t_s` (moving obstacles move).
    pub fn centre_at(&self, t_s: f64) -> (f64, f64) {
        if self.moving {
            (self.x_mm + self.vx_mm_s * t_s, self.z_mm + self.vz_mm_s * t_s)
        } else {
            (self.x_mm, self.z_mm)
        }
    }
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    Box,
    Cylinder,
}

/// A flat figure on the ground (truth.toml), world frame.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TruthMarking {
    pub x_mm: f64,
    pub z_mm: f64,
    pub width_mm: f64,
    pub depth_mm: f64,
}

/// Where the ground falls away (truth.toml): the hole in the upper floor,
/// world frame; a ledge, stairs down or a pit.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TruthDrop {
    pub x_mm: f64,
    pub z_mm: f64,
    pub width_mm: f64,
    pub depth_mm: f64,
    /// How far the lower level lies below the floor.
    pub drop_mm: f64,
}

/// What gives a pair's `nearest_mm`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Hazard {
    Obstacle,
    Drop,
}

/// The expected answer for one frame (compared with any earlier frame).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TruthPair {
    pub frame: u32,
    pub alarm: bool,
    pub nearest_mm: Option<f64>,
    /// Absent in older recordings (which have no drops): an obstacle.
    pub hazard: Option<Hazard>,
}

impl TruthPair {
    /// What raises this pair's alarm, if anything.
    pub fn hazard(&self) -> Option<Hazard> {
        self.alarm.then(|| self.hazard.unwrap_or(Hazard::Obstacle))
    }
}

#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Truth {
    #[serde(default)]
    pub obstacle: Vec<TruthObstacle>,
    #[serde(default)]
    pub marking: Vec<TruthMarking>,
    #[serde(default)]
    pub drop: Vec<TruthDrop>,
    #[serde(default)]
    pub pair: Vec<TruthPair>,
}

impl Truth {
    pub fn pair(&self, frame: u32) -> Option<&TruthPair> {
        self.pair.iter().find(|p| p.frame == frame)
    }
}

pub fn parse_truth(path: &Path, text: &str) -> Result<Truth, RecordingError> {
    parse_toml(path, text)
}

/// An 8-bit grayscale frame.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<u8>,
}

/// Parses a PGM file's bytes (the path is only for messages).
pub fn parse_frame(path: &Path, bytes: &[u8]) -> Result<Frame, RecordingError> {
    let pgm = Pgm::new_checked(bytes).map_err(|error| RecordingError::Pgm { path: path.into(), error })?;
    Ok(Frame { width: pgm.width(), height: pgm.height(), pixels: pgm.pixels().to_vec() })
}

/// A recording directory: rig, poses and truth are read up front, frames on demand.
#[derive(Clone, Debug)]
pub struct Recording {
    pub dir: PathBuf,
    /// The rig the pipeline sees: rig.toml's, its camera binned by `binning`.
    pub rig: Rig,
    /// How recorded frames are averaged down to `rig`'s camera.
    pub binning: Binning,
    pub poses: Vec<PoseRow>,
    pub truth: Option<Truth>,
    /// Frame indices present in frames/ (sorted).
    pub frames: Vec<u32>,
}

/// How rig.toml's text becomes the rig: [`parse_rig`] or [`parse_rig_for_calibration`].
type ReadRig = fn(&Path, &str) -> Result<(Rig, Binning), RecordingError>;

impl Recording {
    pub fn open(dir: impl AsRef<Path>) -> Result<Recording, RecordingError> {
        Recording::open_with(dir, parse_rig)
    }

    /// [`Recording::open`] with rig.toml read by [`parse_rig_for_calibration`].
    pub fn open_for_calibration(dir: impl AsRef<Path>) -> Result<Recording, RecordingError> {
        Recording::open_with(dir, parse_rig_for_calibration)
    }

    fn open_with(dir: impl AsRef<Path>, read_rig: ReadRig) -> Result<Recording, RecordingError> {
        let dir = dir.as_ref().to_path_buf();
        let rig_path = dir.join("rig.toml");
        let (rig, binning) = read_rig(&rig_path, &read_text(&rig_path)?)?;
        let poses_path = dir.join("poses.csv");
        let poses = parse_poses(&poses_path, &read_text(&poses_path)?)?;
        let truth_path = dir.join("truth.toml");
        let truth = if truth_path.exists() { Some(parse_truth(&truth_path, &read_text(&truth_path)?)?) } else { None };
        let frames_dir = dir.join("frames");
        let listing = std::fs::read_dir(&frames_dir).map_err(io_error(&frames_dir))?;
        let mut frames: Vec<u32> = listing
            .filter_map(|entry| entry.ok())
            .filter_map(|entry| {
                let name = entry.file_name().into_string().ok()?;
                let stem = name.strip_suffix(".pgm")?;
                (stem.len() == 6 && stem.bytes().all(|b| b.is_ascii_digit())).then(|| stem.parse().ok())?
            })
            .collect();
        frames.sort_unstable();
        if frames.is_empty() {
            return Err(RecordingError::NoFrames { path: frames_dir });
        }
        Ok(Recording { dir, rig, binning, poses, truth, frames })
    }

    pub fn frame_path(&self, index: u32) -> PathBuf {
        self.dir.join("frames").join(format!("{index:06}.pgm"))
    }

    /// Reads frame `index`, checks its size against rig.toml's camera and
    /// bins it to the rig's.
    pub fn load_frame(&self, index: u32) -> Result<Frame, RecordingError> {
        let path = self.frame_path(index);
        let bytes = std::fs::read(&path).map_err(io_error(&path))?;
        let frame = parse_frame(&path, &bytes)?;
        let expected = self.binning.recorded;
        if (frame.width, frame.height) != expected {
            return Err(RecordingError::FrameSize { path, expected, got: (frame.width, frame.height) });
        }
        Ok(self.binning.apply(frame))
    }

    /// The pose row of frame `index`, if poses.csv has one.
    pub fn pose(&self, index: u32) -> Option<&PoseRow> {
        self.poses.iter().find(|p| p.frame == index)
    }

    /// Forgets poses.csv's odometry (`--odometry none`): the motion must
    /// come from the images. Times stay: they order the frames.
    pub fn ignore_odometry(&mut self) {
        self.poses.iter_mut().for_each(|row| row.pose = None);
    }

    /// Forgets poses.csv's IMU attitude (`--imu none`).
    pub fn ignore_imu(&mut self) {
        self.poses.iter_mut().for_each(|row| row.attitude = None);
    }
}

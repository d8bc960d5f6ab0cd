//! Reader for the recording layout of RECORDING.md: rig.toml, poses.csv,
//! frames/NNNNNN.pgm and the optional truth.toml.
//!
//! Every error names the file and, where there is one, the line.

use flatland_core::geometry::{Rig, RigError};
use flatland_core::motion::Pose;
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
    /// poses.csv is malformed.
    Csv { path: PathBuf, line: usize, message: String },
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
            RecordingError::Csv { path, line, message } => write!(f, "{}:{line}: {message}", path.display()),
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

/// rig.toml as written: the wire's [`RigRecord`] in sections.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RigFile {
    camera: CameraSection,
    mount: MountSection,
    aoi: AoiSection,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSection {
    width: u16,
    height: u16,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    distortion: Option<[f64; 5]>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MountSection {
    height_mm: f64,
    tilt_deg: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AoiSection {
    half_width_mm: f64,
    near_mm: f64,
    far_mm: f64,
}

impl From<RigFile> for RigRecord {
    fn from(RigFile { camera, mount, aoi }: RigFile) -> RigRecord {
        RigRecord {
            width: camera.width,
            height: camera.height,
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            distortion: camera.distortion,
            height_mm: mount.height_mm,
            tilt_deg: mount.tilt_deg,
            aoi_half_width_mm: aoi.half_width_mm,
            aoi_near_mm: aoi.near_mm,
            aoi_far_mm: aoi.far_mm,
        }
    }
}

/// The key whose value a rig error is about, for the error's line number.
fn key_of(error: RigError) -> &'static str {
    match error {
        RigError::NotFinite | RigError::ImageSize => "width",
        RigError::FocalLength => "fx",
        RigError::PrincipalPoint => "cx",
        RigError::MountHeight => "height_mm",
        RigError::Tilt => "tilt_deg",
        RigError::Distortion => "distortion",
        RigError::AoiEmpty | RigError::AoiBehindCamera => "near_mm",
        RigError::AoiBeyondHorizon | RigError::AoiOutsideImage => "far_mm",
    }
}

/// Parses rig.toml text (the path is only for messages).
pub fn parse_rig(path: &Path, text: &str) -> Result<Rig, RecordingError> {
    let file: RigFile = parse_toml(path, text)?;
    Rig::try_from(&RigRecord::from(file)).map_err(|error| {
        // For NaN/inf, point at the first offending key when we can find it.
        let line = if error == RigError::NotFinite {
            text.lines().position(|l| {
                // The value without its comment (rig.toml has no strings).
                let v = l.split('#').next().unwrap_or("").split('=').nth(1).unwrap_or("").to_ascii_lowercase();
                v.contains("nan") || v.contains("inf")
            })
            .map(|n| n + 1)
        } else {
            line_of_key(text, key_of(error))
        };
        RecordingError::Rig { path: path.into(), line, error }
    })
}

/// One row of poses.csv.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseRow {
    pub frame: u32,
    /// 1-based line in poses.csv, for messages about this row.
    pub line: usize,
    pub t_s: f64,
    pub pose: Pose,
}

/// The pipeline's input for this row.
impl From<&PoseRow> for PoseSample {
    fn from(row: &PoseRow) -> Self {
        PoseSample { t_s: row.t_s, pose: row.pose }
    }
}

/// The `$FLODO` message a robot controller sends for this row.
impl From<&PoseRow> for Odometry {
    fn from(row: &PoseRow) -> Self {
        Odometry { frame: row.frame, t_s: row.t_s, x_mm: row.pose.x_mm, z_mm: row.pose.z_mm, yaw_deg: row.pose.yaw_deg }
    }
}

/// Parses poses.csv: `frame,t_s,x_mm,z_mm,yaw_deg` header, then one row per frame.
pub fn parse_poses(path: &Path, text: &str) -> Result<Vec<PoseRow>, RecordingError> {
    let csv_error = |line: usize, message: String| RecordingError::Csv { path: path.into(), line, message };
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, header)) if header.trim() == "frame,t_s,x_mm,z_mm,yaw_deg" => {}
        Some((_, header)) => return Err(csv_error(1, format!("expected header frame,t_s,x_mm,z_mm,yaw_deg, found {header:?}"))),
        None => return Err(csv_error(1, "empty file".into())),
    }
    let mut rows: Vec<PoseRow> = Vec::new();
    for (index, line) in lines {
        let line_number = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != 5 {
            return Err(csv_error(line_number, format!("expected 5 fields, found {}", fields.len())));
        }
        let frame: u32 = fields[0].parse().map_err(|_| csv_error(line_number, format!("bad frame number {:?}", fields[0])))?;
        let mut numbers = [0f64; 4];
        for (slot, (field, name)) in numbers.iter_mut().zip(fields[1..].iter().zip(["t_s", "x_mm", "z_mm", "yaw_deg"])) {
            *slot = field
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| csv_error(line_number, format!("bad {name} {field:?}")))?;
        }
        if let Some(previous) = rows.last() {
            if frame <= previous.frame {
                return Err(csv_error(line_number, format!("frame {frame} after frame {}", previous.frame)));
            }
        }
        rows.push(PoseRow {
            frame,
            line: line_number,
            t_s: numbers[0],
            pose: Pose { x_mm: numbers[1], z_mm: numbers[2], yaw_deg: numbers[3] },
        });
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
    pub rig: Rig,
    pub poses: Vec<PoseRow>,
    pub truth: Option<Truth>,
    /// Frame indices present in frames/ (sorted).
    pub frames: Vec<u32>,
}

impl Recording {
    pub fn open(dir: impl AsRef<Path>) -> Result<Recording, RecordingError> {
        let dir = dir.as_ref().to_path_buf();
        let rig_path = dir.join("rig.toml");
        let rig = parse_rig(&rig_path, &read_text(&rig_path)?)?;
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
        Ok(Recording { dir, rig, poses, truth, frames })
    }

    pub fn frame_path(&self, index: u32) -> PathBuf {
        self.dir.join("frames").join(format!("{index:06}.pgm"))
    }

    /// Reads frame `index` and checks its size against the rig.
    pub fn load_frame(&self, index: u32) -> Result<Frame, RecordingError> {
        let path = self.frame_path(index);
        let bytes = std::fs::read(&path).map_err(io_error(&path))?;
        let frame = parse_frame(&path, &bytes)?;
        let camera = self.rig.camera();
        let expected = (usize::from(camera.width), usize::from(camera.height));
        if (frame.width, frame.height) != expected {
            return Err(RecordingError::FrameSize { path, expected, got: (frame.width, frame.height) });
        }
        Ok(frame)
    }

    /// The pose row of frame `index`, if poses.csv has one.
    pub fn pose(&self, index: u32) -> Option<&PoseRow> {
        self.poses.iter().find(|p| p.frame == index)
    }
}

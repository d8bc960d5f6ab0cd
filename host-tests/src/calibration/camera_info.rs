//! A ROS camera_info YAML file (camera_calibration's output) read as
//! flatland's camera (`flatland calibrate --camera-info`).

use flatland_core::geometry::{Distortion, Intrinsics};
use std::fmt;

/// A ROS `sensor_msgs/CameraInfo` YAML file (camera_calibration's output)
/// as flatland uses it: the camera at the recorded size, its matrix and
/// plumb_bob distortion (None when all coefficients are zero or absent).
pub type CameraInfo = Intrinsics;

/// Why a camera_info file could not be used.
#[derive(Debug)]
pub enum CameraInfoError {
    /// Not YAML, a key missing or of the wrong type (the message names the
    /// key and, where it can, the line and column).
    Yaml(serde_norway::Error),
    /// A matrix's `data` with another count of numbers than its shape.
    MatrixSize { matrix: &'static str, numbers: usize, expected: usize },
    /// A distortion model flatland does not implement.
    DistortionModel(String),
}

impl fmt::Display for CameraInfoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CameraInfoError::Yaml(e) => write!(f, "{e}"),
            CameraInfoError::MatrixSize { matrix, numbers, expected } => {
                write!(f, "{matrix} has {numbers} numbers, expected {expected}")?;
                if *matrix == "distortion_coefficients" {
                    f.write_str(" (plumb_bob)")?;
                }
                Ok(())
            }
            CameraInfoError::DistortionModel(model) => write!(f, "distortion_model {model}: only plumb_bob is supported"),
        }
    }
}

impl std::error::Error for CameraInfoError {}

/// The keys of camera_info YAML that flatland reads; the others
/// (camera_name, rectification and projection matrices) are ignored.
#[derive(serde::Deserialize)]
struct CameraInfoYaml {
    image_width: u16,
    image_height: u16,
    camera_matrix: YamlMatrix,
    distortion_model: Option<String>,
    distortion_coefficients: Option<YamlMatrix>,
}

/// A camera_info matrix: `rows` and `cols` (not needed: each matrix's shape
/// is fixed) and the numbers, row by row.
#[derive(serde::Deserialize)]
struct YamlMatrix {
    data: Vec<f64>,
}

/// Reads the keys flatland needs from camera_info YAML: `image_width`,
/// `image_height`, `camera_matrix: data: [...]` (9 numbers),
/// `distortion_model` (plumb_bob, or absent) and
/// `distortion_coefficients: data: [...]` (5 numbers, or none).
pub fn parse_camera_info(text: &str) -> Result<CameraInfo, CameraInfoError> {
    let yaml: CameraInfoYaml = serde_norway::from_str(text).map_err(CameraInfoError::Yaml)?;
    let k = &yaml.camera_matrix.data;
    if k.len() != 9 {
        return Err(CameraInfoError::MatrixSize { matrix: "camera_matrix", numbers: k.len(), expected: 9 });
    }
    if let Some(model) = yaml.distortion_model.filter(|m| m != "plumb_bob") {
        return Err(CameraInfoError::DistortionModel(model));
    }
    let d = yaml.distortion_coefficients.map(|m| m.data).unwrap_or_default();
    let distortion = match d.len() {
        0 => None,
        5 => Some([d[0], d[1], d[2], d[3], d[4]]).filter(|c| c.iter().any(|v| *v != 0.0)).map(Distortion::from_coefficients),
        n => return Err(CameraInfoError::MatrixSize { matrix: "distortion_coefficients", numbers: n, expected: 5 }),
    };
    Ok(Intrinsics { width: yaml.image_width, height: yaml.image_height, fx: k[0], fy: k[4], cx: k[2], cy: k[5], distortion, readout_ms: 0.0 })
}

/// The `[camera]` values of a camera_info, for [`with_section_values`](super::with_section_values).
pub fn camera_values(info: &CameraInfo) -> Vec<(&'static str, String)> {
    let mut values = vec![
        ("width", info.width.to_string()),
        ("height", info.height.to_string()),
        ("fx", format!("{}", info.fx)),
        ("fy", format!("{}", info.fy)),
        ("cx", format!("{}", info.cx)),
        ("cy", format!("{}", info.cy)),
    ];
    if let Some(d) = info.distortion.map(|d| d.coefficients()) {
        values.push(("distortion", format!("[{}, {}, {}, {}, {}]", d[0], d[1], d[2], d[3], d[4])));
    }
    values
}

//! The per-frame detection result, in integers, and its csv form.
//!
//! One home for the csv of `flatland detect`: the CLI prints it from the
//! host pipeline and `flatland serial decode` prints it from the firmware's
//! serial messages, so parity is a byte-for-byte comparison.

use core::fmt::{self, Write};

/// Header of `flatland detect --format csv` (and of `flatland serial decode`).
pub const CSV_HEADER: &str = "frame,ref_frame,alarm,nearest_mm,left_mm,right_mm,sad,count50,shift_k,shift_g,tx_mm,tz_mm,obstacle_h_mm,dyaw_deg,dpitch_deg,droll_deg,odometry_fault";

/// Fixed-point scale of [`FrameReport::shift_k`] / [`FrameReport::shift_g`]:
/// hundredths of a KG pixel.
pub const SHIFT_SCALE: i32 = 100;
/// Fixed-point scale of [`FrameReport::tx`] / [`FrameReport::tz`]: tenths of a mm.
pub const MOTION_SCALE: i32 = 10;
/// Fixed-point scale of [`FrameReport::dyaw`], [`FrameReport::dpitch`] and
/// [`FrameReport::droll`]: thousandths of a degree.
pub const ANGLE_SCALE: i32 = 1000;

/// What the detector says about frame `frame`, compared with `ref_frame`.
///
/// Every field is an integer so that the host and the target agree exactly.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameReport {
    pub frame: u32,
    pub ref_frame: u32,
    pub alarm: bool,
    /// Distance ahead (robot frame z, mm) of the nearest obstacle point.
    pub nearest_mm: Option<i32>,
    /// Lateral extent (robot frame x, mm) of the nearest obstacle.
    pub left_mm: Option<i32>,
    pub right_mm: Option<i32>,
    /// Sum of |diff| above the paper's level (30) inside the AOI at the
    /// predicted shift (from the shift search's histogram).
    pub sad: u32,
    /// AOI pixels with |diff| > 50 at the predicted shift.
    pub count50: u32,
    /// Best shift beyond the odometry prediction, in 1/[`SHIFT_SCALE`] KG px.
    pub shift_k: i32,
    pub shift_g: i32,
    /// Refined motion since `ref_frame`, in 1/[`MOTION_SCALE`] mm, robot frame of `ref_frame`.
    pub tx: i32,
    pub tz: i32,
    /// Estimated height of the nearest hazard (GTI's, else GPA's parallax),
    /// mm; negative for a drop: its depth below the floor (issue 14).
    pub obstacle_h_mm: Option<i32>,
    /// Estimated turn (yaw, left positive), pitch and roll change since
    /// `ref_frame`, in 1/[`ANGLE_SCALE`] degrees.
    pub dyaw: i32,
    pub dpitch: i32,
    pub droll: i32,
    /// Whether the odometry disagrees with the motion seen on the ground
    /// beyond its noise (slip, scale); None without odometry.
    pub odometry_fault: Option<bool>,
}

/// Writes a fixed-point value with `decimals` digits after the point.
fn write_fixed<W: Write>(out: &mut W, value: i32, scale: i32, decimals: usize) -> fmt::Result {
    let sign = if value < 0 { "-" } else { "" };
    let magnitude = value.unsigned_abs();
    let scale = scale.unsigned_abs();
    write!(out, "{}{}.{:0width$}", sign, magnitude / scale, magnitude % scale, width = decimals)
}

fn write_optional<W: Write>(out: &mut W, value: Option<i32>) -> fmt::Result {
    match value {
        Some(v) => write!(out, "{v}"),
        None => Ok(()),
    }
}

impl FrameReport {
    /// Writes the csv row (no newline) matching [`CSV_HEADER`].
    pub fn write_csv<W: Write>(&self, out: &mut W) -> fmt::Result {
        write!(out, "{},{},{},", self.frame, self.ref_frame, u8::from(self.alarm))?;
        write_optional(out, self.nearest_mm)?;
        out.write_char(',')?;
        write_optional(out, self.left_mm)?;
        out.write_char(',')?;
        write_optional(out, self.right_mm)?;
        write!(out, ",{},{},", self.sad, self.count50)?;
        write_fixed(out, self.shift_k, SHIFT_SCALE, 2)?;
        out.write_char(',')?;
        write_fixed(out, self.shift_g, SHIFT_SCALE, 2)?;
        out.write_char(',')?;
        write_fixed(out, self.tx, MOTION_SCALE, 1)?;
        out.write_char(',')?;
        write_fixed(out, self.tz, MOTION_SCALE, 1)?;
        out.write_char(',')?;
        write_optional(out, self.obstacle_h_mm)?;
        for angle in [self.dyaw, self.dpitch, self.droll] {
            out.write_char(',')?;
            write_fixed(out, angle, ANGLE_SCALE, 3)?;
        }
        out.write_char(',')?;
        write_optional(out, self.odometry_fault.map(i32::from))
    }
}

/// A report with every kind of field, for the tests here and the protocol's
/// checks (which also run on the target, hence not only under cfg(test)).
#[cfg(any(test, feature = "selftest"))]
pub(crate) fn sample_report() -> FrameReport {
    FrameReport {
        frame: 7,
        ref_frame: 6,
        alarm: true,
        nearest_mm: Some(820),
        left_mm: Some(-120),
        right_mm: None,
        sad: 12345,
        count50: 67,
        shift_k: -5,
        shift_g: 125,
        tx: -3,
        tz: 1003,
        obstacle_h_mm: None,
        dyaw: -1500,
        dpitch: 120,
        droll: -7,
        odometry_fault: Some(true),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_row_has_one_field_per_header_column() {
        let report = FrameReport { frame: 3, ref_frame: 1, right_mm: Some(95), ..sample_report() };
        let mut line: heapless::String<200> = heapless::String::new();
        report.write_csv(&mut line).unwrap();
        assert_eq!(line.as_str(), "3,1,1,820,-120,95,12345,67,-0.05,1.25,-0.3,100.3,,-1.500,0.120,-0.007,1");
        assert_eq!(line.split(',').count(), CSV_HEADER.split(',').count());
    }
}

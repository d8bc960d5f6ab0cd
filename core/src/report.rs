//! The per-frame detection result, in integers, and its csv form.
//!
//! One home for the csv of `flatland detect`: the CLI prints it from the
//! host pipeline and `flatland serial decode` prints it from the firmware's
//! serial messages, so parity is a byte-for-byte comparison.

use core::fmt::{self, Write};

/// Header of `flatland detect --format csv` (and of `flatland serial decode`).
pub const CSV_HEADER: &str = "frame,ref_frame,alarm,nearest_mm,left_mm,right_mm,sad,count50,shift_k,shift_g,tx_mm,tz_mm,obstacle_h_mm,dyaw_deg,dpitch_deg,droll_deg,odometry_fault,status";

/// Fixed-point scale of [`FrameReport::shift_k`] / [`FrameReport::shift_g`]:
/// hundredths of a KG pixel.
pub const SHIFT_SCALE: i32 = 100;
/// Fixed-point scale of [`FrameReport::tx`] / [`FrameReport::tz`]: tenths of a mm.
pub const MOTION_SCALE: i32 = 10;
/// Fixed-point scale of [`FrameReport::dyaw`], [`FrameReport::dpitch`] and
/// [`FrameReport::droll`]: thousandths of a degree.
pub const ANGLE_SCALE: i32 = 1000;

/// Why a frame could not be judged: every frame after the first of a run
/// is either judged ([`Status::Ok`]) or says which of these kept it from
/// it. A frame not judged asserts the alarm (fail-safe: the robot must not
/// drive on it) and restarts the keyframe from itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NotJudged {
    /// The motion since the keyframe could not be measured on the images
    /// (a floor without texture, too little overlap) and there is no
    /// odometry to fall back on. `ref_frame` is the keyframe it was tried
    /// against.
    NoMotion,
    /// The frame before this one was not processed (missing, unreadable,
    /// cut short, without a pose sample, its time not after the one before
    /// it, a gap in the frame numbers), so the motion since the keyframe is
    /// unknown: nothing to compare with. `ref_frame` is the frame itself,
    /// which became the keyframe.
    AfterGap,
}

impl NotJudged {
    /// Every reason, in wire order.
    pub const ALL: [NotJudged; 2] = [NotJudged::NoMotion, NotJudged::AfterGap];

    /// The stable name of the csv's `status` column and the protocol's field.
    pub const fn as_str(self) -> &'static str {
        match self {
            NotJudged::NoMotion => "no_motion",
            NotJudged::AfterGap => "after_gap",
        }
    }
}

impl fmt::Display for NotJudged {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            NotJudged::NoMotion => "the motion could not be measured on the images and there is no odometry",
            NotJudged::AfterGap => "the frame before was not processed: nothing to compare with",
        })
    }
}

impl core::error::Error for NotJudged {}

/// Whether a frame was judged: the report's `status`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// Compared with the keyframe and judged: the alarm is the detector's.
    #[default]
    Ok,
    /// Not judged, and why: the alarm is asserted.
    NotJudged(NotJudged),
}

impl Status {
    /// The csv's and the protocol's name: `ok` or the reason's.
    pub const fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::NotJudged(reason) => reason.as_str(),
        }
    }

    /// The status named `name` ([`Status::as_str`]), if any.
    pub fn from_name(name: &str) -> Option<Status> {
        if name == "ok" {
            return Some(Status::Ok);
        }
        NotJudged::ALL.into_iter().find(|reason| reason.as_str() == name).map(Status::NotJudged)
    }

    /// The reason as a `Result`: `Ok(())` when judged.
    pub fn judged(self) -> Result<(), NotJudged> {
        match self {
            Status::Ok => Ok(()),
            Status::NotJudged(reason) => Err(reason),
        }
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What the detector says about frame `frame`, compared with `ref_frame`
/// (or why it could not say: `status`).
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
    /// Judged, or why not ([`FrameReport::not_judged`]).
    pub status: Status,
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
    /// The fail-safe report of frame `frame` that could not be judged for
    /// `reason`: the alarm asserted, no obstacle named (nearest, left,
    /// right and height empty), the statistics, shift, motion and angles 0,
    /// no odometry verdict. `ref_frame`: see [`NotJudged`]'s reasons.
    pub const fn not_judged(frame: u32, ref_frame: u32, reason: NotJudged) -> FrameReport {
        FrameReport {
            frame,
            ref_frame,
            alarm: true,
            nearest_mm: None,
            left_mm: None,
            right_mm: None,
            sad: 0,
            count50: 0,
            shift_k: 0,
            shift_g: 0,
            tx: 0,
            tz: 0,
            obstacle_h_mm: None,
            dyaw: 0,
            dpitch: 0,
            droll: 0,
            odometry_fault: None,
            status: Status::NotJudged(reason),
        }
    }

    /// Whether the frame was compared and judged (`status` ok).
    pub fn is_judged(&self) -> bool {
        self.status == Status::Ok
    }

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
        write_optional(out, self.odometry_fault.map(i32::from))?;
        write!(out, ",{}", self.status.as_str())
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
        status: Status::Ok,
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
        assert_eq!(line.as_str(), "3,1,1,820,-120,95,12345,67,-0.05,1.25,-0.3,100.3,,-1.500,0.120,-0.007,1,ok");
        assert_eq!(line.split(',').count(), CSV_HEADER.split(',').count());
    }

    /// A frame not judged: the alarm asserted, no obstacle, the reason last.
    #[test]
    fn a_frame_not_judged_is_an_alarm_that_says_why() {
        let report = FrameReport::not_judged(5, 3, NotJudged::NoMotion);
        assert!(report.alarm && !report.is_judged());
        let mut line: heapless::String<200> = heapless::String::new();
        report.write_csv(&mut line).unwrap();
        assert_eq!(line.as_str(), "5,3,1,,,,0,0,0.00,0.00,0.0,0.0,,0.000,0.000,0.000,,no_motion");
        assert_eq!(line.split(',').count(), CSV_HEADER.split(',').count());
        assert_eq!(CSV_HEADER.rsplit(',').next(), Some("status"));
    }

    #[test]
    fn status_names_are_stable_and_round_trip() {
        let names: [&str; 2] = NotJudged::ALL.map(NotJudged::as_str);
        assert_eq!(names, ["no_motion", "after_gap"]);
        assert_eq!(Status::from_name("ok"), Some(Status::Ok));
        for reason in NotJudged::ALL {
            let status = Status::NotJudged(reason);
            assert_eq!(Status::from_name(status.as_str()), Some(status));
            assert_eq!(status.judged(), Err(reason));
        }
        assert_eq!(Status::from_name(""), None);
        assert_eq!(Status::from_name("OK"), None);
    }
}

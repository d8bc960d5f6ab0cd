//! The polar obstacle scan: per frame, the nearest hazard in each angular
//! sector of the ground the camera sees, like a 2-D laser scan.
//!
//! Robot frame (RECORDING.md): origin on the ground under the optical
//! centre, x right, z forward. A sector's angle is measured from straight
//! ahead (+z) towards the right (+x), so positive angles are clockwise seen
//! from above, as in MAVLink's `OBSTACLE_DISTANCE` (and the opposite of ROS
//! REP 103). Sectors are [`SCAN_INCREMENT_MDEG`] wide with a boundary
//! straight ahead, symmetric about it; sector `k` spans
//! `[(k - n/2) * inc, (k - n/2 + 1) * inc)` and its reading belongs to its
//! centre.
//!
//! Each sector is one of (ROS REP 117's three cases):
//! - [`Sector::Hazard`]: the range (mm, from the robot origin) of the
//!   nearest hazard footprint in the sector: an obstacle's base, a drop's
//!   edge, anything the detector found on the ground. Ranges below
//!   [`ScanLayout::range_min_mm`] are raised to it (the nearest ground the
//!   detector judges); hazards beyond [`ScanLayout::range_max_mm`] are out of
//!   range and left out.
//! - [`Sector::Free`]: the camera saw the whole sector's ground, from where
//!   the view starts out to `range_max_mm`, and no hazard was found on it.
//! - [`Sector::Unknown`]: no hazard, and part of the sector's ground was
//!   not seen (outside the view, or not comparable this frame). Never free.
//!
//! The input is hazard footprints, whatever found them ([`Scan::add_span`],
//! [`Scan::add_point`]); the view is a per-point question the detector
//! answers ([`Scan::mark_view`]). No heap: the sectors are a fixed array.

use crate::limits::MAX_SCAN_SECTORS;
use crate::motion::Motion;
use core::fmt::{self, Write};

/// Sector width, thousandths of a degree (2.5 degrees: two sectors make one
/// 5-degree bin of MAVLink's `OBSTACLE_DISTANCE` as PX4 reads it).
pub const SCAN_INCREMENT_MDEG: i32 = 2500;
/// The farthest range a scan carries, mm (the `u16` readings keep two
/// values above it for their own use).
pub const MAX_SCAN_RANGE_MM: u16 = 60_000;

/// One sector's reading.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sector {
    /// Not all of the sector's ground was seen, and no hazard was found.
    Unknown,
    /// Seen out to the range and clear.
    Free,
    /// The nearest hazard's range, mm.
    Hazard(u16),
}

/// The sectors and the range of one rig's scans.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScanLayout {
    /// Number of sectors (even, at most [`MAX_SCAN_SECTORS`]).
    pub sectors: u8,
    /// Nearest range a reading can have, mm: the nearest ground judged.
    pub range_min_mm: u16,
    /// Farthest range, mm: beyond it nothing is claimed.
    pub range_max_mm: u16,
}

impl ScanLayout {
    pub const EMPTY: ScanLayout = ScanLayout { sectors: 0, range_min_mm: 0, range_max_mm: 0 };

    /// The sectors that cover `half_angle_deg` either side of straight
    /// ahead (capped at [`MAX_SCAN_SECTORS`]), from `range_min_mm` to
    /// `range_max_mm` (capped at [`MAX_SCAN_RANGE_MM`]).
    pub fn new(half_angle_deg: f64, range_min_mm: f64, range_max_mm: f64) -> ScanLayout {
        let increment = f64::from(SCAN_INCREMENT_MDEG) / 1000.0;
        let half = libm::ceil(half_angle_deg.clamp(0.0, 90.0) / increment).max(1.0) as usize;
        let sectors = (2 * half).min(MAX_SCAN_SECTORS);
        let cap = f64::from(MAX_SCAN_RANGE_MM);
        let range_max = libm::ceil(range_max_mm.clamp(1.0, cap));
        let range_min = libm::floor(range_min_mm.clamp(0.0, range_max));
        ScanLayout { sectors: sectors as u8, range_min_mm: range_min as u16, range_max_mm: range_max as u16 }
    }

    /// Centre angle of sector 0, thousandths of a degree (ROS's `angle_min`).
    pub fn angle_start_mdeg(&self) -> i32 {
        -(i32::from(self.sectors) / 2) * SCAN_INCREMENT_MDEG + SCAN_INCREMENT_MDEG / 2
    }

    /// The sector holding `angle_deg` (clockwise from ahead), if any.
    fn sector_of(&self, angle_deg: f64) -> Option<usize> {
        let increment = f64::from(SCAN_INCREMENT_MDEG) / 1000.0;
        let k = libm::floor(angle_deg / increment) + f64::from(self.sectors / 2);
        (k >= 0.0 && k < f64::from(self.sectors)).then_some(k as usize)
    }

    /// Sector `k`'s edges, degrees.
    fn edges_deg(&self, k: usize) -> (f64, f64) {
        let increment = f64::from(SCAN_INCREMENT_MDEG) / 1000.0;
        let first = (k as f64 - f64::from(self.sectors / 2)) * increment;
        (first, first + increment)
    }
}

/// What the detector saw of one ground point this frame (see [`Scan::mark_view`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum View {
    /// Nearer than the ground the detector judges (under and just ahead of
    /// the robot, which no camera frame shows): neither seen nor missed.
    Blind,
    Seen,
    /// Outside the view, or not comparable this frame.
    Unseen,
}

/// Sentinel of [`Scan`]'s readings: no hazard in the sector.
const NO_HAZARD: u16 = u16::MAX;

/// One frame's scan. See the module documentation.
#[derive(Clone, Copy, Debug)]
pub struct Scan {
    frame: u32,
    layout: ScanLayout,
    /// Nearest hazard range per sector, mm; [`NO_HAZARD`] for none.
    range: [u16; MAX_SCAN_SECTORS],
    /// Where that hazard is (x, z mm), to carry it to the next frame.
    point: [[i16; 2]; MAX_SCAN_SECTORS],
    /// Sectors seen whole (bit k).
    seen: u128,
    /// The last frame's hazard points, held through short baselines.
    previous: [[i16; 2]; MAX_SCAN_SECTORS],
    previous_count: u8,
}

impl Scan {
    pub const EMPTY: Scan = Scan {
        frame: 0,
        layout: ScanLayout::EMPTY,
        range: [NO_HAZARD; MAX_SCAN_SECTORS],
        point: [[0; 2]; MAX_SCAN_SECTORS],
        seen: 0,
        previous: [[0; 2]; MAX_SCAN_SECTORS],
        previous_count: 0,
    };

    /// A scan with this layout, nothing held.
    pub fn new(layout: ScanLayout) -> Scan {
        Scan { layout, ..Scan::EMPTY }
    }

    /// Starts frame `frame`: every sector unknown and without hazard.
    pub fn begin(&mut self, frame: u32) {
        self.frame = frame;
        self.range = [NO_HAZARD; MAX_SCAN_SECTORS];
        self.seen = 0;
    }

    pub fn frame(&self) -> u32 {
        self.frame
    }

    pub fn layout(&self) -> ScanLayout {
        self.layout
    }

    /// Number of sectors.
    pub fn len(&self) -> usize {
        usize::from(self.layout.sectors)
    }

    pub fn is_empty(&self) -> bool {
        self.layout.sectors == 0
    }

    /// Sector `k`'s reading (Unknown beyond the last sector).
    pub fn sector(&self, k: usize) -> Sector {
        if k >= self.len() {
            return Sector::Unknown;
        }
        match self.range[k] {
            NO_HAZARD if self.seen & (1 << k) != 0 => Sector::Free,
            NO_HAZARD => Sector::Unknown,
            range => Sector::Hazard(range),
        }
    }

    /// The readings, sector 0 first.
    pub fn sectors(&self) -> impl Iterator<Item = Sector> + '_ {
        (0..self.len()).map(|k| self.sector(k))
    }

    /// A hazard footprint across the view: the segment at `z_mm` ahead from
    /// `x_left_mm` to `x_right_mm` (robot frame). Each sector it crosses
    /// gets the range of its nearest point inside the sector.
    pub fn add_span(&mut self, z_mm: f64, x_left_mm: f64, x_right_mm: f64) {
        if !(z_mm > 0.0 && x_left_mm <= x_right_mm) {
            return;
        }
        let angle = |x: f64| libm::atan2(x, z_mm).to_degrees();
        let first = self.layout.sector_of(angle(x_left_mm)).unwrap_or(0);
        let last = match self.layout.sector_of(angle(x_right_mm)) {
            Some(k) => k,
            None if angle(x_right_mm) > 0.0 => self.len().saturating_sub(1),
            None => return,
        };
        // A sector's far edge is the next one's near edge (the same angle,
        // exactly): each tangent is taken once (software f64 on the M4).
        let tan = |angle_deg: f64| libm::tan(angle_deg.to_radians());
        let mut near_edge_tan = tan(self.layout.edges_deg(first).0);
        for k in first..=last {
            let far_edge_tan = tan(self.layout.edges_deg(k).1);
            let lo = x_left_mm.max(z_mm * near_edge_tan);
            let hi = x_right_mm.min(z_mm * far_edge_tan);
            near_edge_tan = far_edge_tan;
            // The sector's part of the segment (a point where it only
            // touches an edge); its point nearest the origin.
            let x = 0.0f64.clamp(lo.min(hi), hi.max(lo));
            let range = if x == 0.0 { z_mm } else { libm::hypot(x, z_mm) };
            self.record(k, range, x, z_mm);
        }
    }

    /// A hazard at one point (x, z mm, robot frame).
    pub fn add_point(&mut self, x_mm: f64, z_mm: f64) {
        if let Some(k) = self.layout.sector_of(libm::atan2(x_mm, z_mm).to_degrees()) {
            self.record(k, libm::hypot(x_mm, z_mm), x_mm, z_mm);
        }
    }

    fn record(&mut self, k: usize, range_mm: f64, x_mm: f64, z_mm: f64) {
        let range = libm::round(range_mm);
        // NaN falls through with the out-of-range.
        if range.is_nan() || range > f64::from(self.layout.range_max_mm) {
            return;
        }
        let range = range.max(f64::from(self.layout.range_min_mm)) as u16;
        if range < self.range[k] {
            self.range[k] = range;
            let clamp = |v: f64| libm::round(v).clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
            self.point[k] = [clamp(x_mm), clamp(z_mm)];
        }
    }

    /// Adds the last frame's hazards, moved into this frame's robot frame
    /// by `step` (the motion from the last frame to this one): a baseline
    /// too short to see them again must not clear them.
    pub fn hold(&mut self, step: &Motion) {
        let previous = self.previous;
        for [x, z] in previous.iter().take(usize::from(self.previous_count)) {
            let (x, z) = step.to_later_frame(f64::from(*x), f64::from(*z));
            self.add_point(x, z);
        }
    }

    /// Keeps this frame's hazards for [`Scan::hold`] on the next frame.
    pub fn keep(&mut self) {
        let mut count = 0;
        for k in 0..self.len() {
            if self.range[k] != NO_HAZARD {
                self.previous[count] = self.point[k];
                count += 1;
            }
        }
        self.previous_count = count as u8;
    }

    /// Forgets the held hazards (the motion since them is lost).
    pub fn forget(&mut self) {
        self.previous_count = 0;
    }

    /// Marks the sectors the detector saw whole. `view` answers for ground
    /// points (x, z mm); each sector is sampled along two rays just inside
    /// its edges every `step_mm` from the range's start to its end (a
    /// sector is at most a few cells wide, and what the camera misses lies
    /// at the view's edges, which the rays cross). A sector is seen when some point is [`View::Seen`]
    /// and none [`View::Unseen`]. f32: the M4's FPU does it in hardware.
    pub fn mark_view(&mut self, step_mm: f32, mut view: impl FnMut(f32, f32) -> View) {
        let (near, far) = (f32::from(self.layout.range_min_mm), f32::from(self.layout.range_max_mm));
        let step = step_mm.max(1.0);
        let samples = libm::ceilf((far - near) / step) as u32;
        self.seen = 0;
        for k in 0..self.len() {
            let (a0, a1) = self.layout.edges_deg(k);
            let inset = 0.05 * (a1 - a0);
            let (mut any_seen, mut all_seen) = (false, true);
            for angle in [a0 + inset, a1 - inset] {
                if !all_seen {
                    break;
                }
                let (sin, cos) = crate::kernels::sincosf((angle as f32).to_radians());
                for n in 0..=samples {
                    let r = (near + n as f32 * step).min(far);
                    match view(r * sin, r * cos) {
                        View::Blind => {}
                        View::Seen => any_seen = true,
                        View::Unseen => all_seen = false,
                    }
                    if !all_seen {
                        break;
                    }
                }
            }
            if any_seen && all_seen {
                self.seen |= 1 << k;
            }
        }
    }

    /// The nearest hazard's distance ahead (z, mm) among the sectors, from
    /// the points the readings came from.
    pub fn nearest_ahead_mm(&self) -> Option<i32> {
        (0..self.len()).filter(|&k| self.range[k] != NO_HAZARD).map(|k| i32::from(self.point[k][1])).min()
    }
}

/// Header of `flatland scan`'s csv for `layout`:
/// `frame,angle_start_deg,increment_deg,d0_mm,...`.
pub fn write_csv_header<W: Write>(layout: &ScanLayout, out: &mut W) -> fmt::Result {
    out.write_str("frame,angle_start_deg,increment_deg")?;
    for k in 0..layout.sectors {
        write!(out, ",d{k}_mm")?;
    }
    Ok(())
}

/// Thousandths as a decimal with three places.
fn write_milli<W: Write>(out: &mut W, value: i32) -> fmt::Result {
    let sign = if value < 0 { "-" } else { "" };
    let magnitude = value.unsigned_abs();
    write!(out, "{sign}{}.{:03}", magnitude / 1000, magnitude % 1000)
}

impl Scan {
    /// The csv row (no newline) under [`write_csv_header`]: mm for a hazard,
    /// `inf` for free, empty for unknown (ROS REP 117).
    pub fn write_csv<W: Write>(&self, out: &mut W) -> fmt::Result {
        write!(out, "{},", self.frame)?;
        write_milli(out, self.layout.angle_start_mdeg())?;
        out.write_char(',')?;
        write_milli(out, SCAN_INCREMENT_MDEG)?;
        for sector in self.sectors() {
            out.write_char(',')?;
            match sector {
                Sector::Unknown => {}
                Sector::Free => out.write_str("inf")?,
                Sector::Hazard(range) => write!(out, "{range}")?,
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> ScanLayout {
        ScanLayout::new(40.0, 450.0, 1500.0)
    }

    #[test]
    fn layout_is_symmetric_with_a_boundary_ahead() {
        let layout = layout();
        assert_eq!(layout.sectors, 32);
        assert_eq!(layout.angle_start_mdeg(), -38_750);
        assert_eq!(layout.sector_of(0.0), Some(16));
        assert_eq!(layout.sector_of(-0.1), Some(15));
        assert_eq!(layout.sector_of(-40.0), Some(0));
        assert_eq!(layout.sector_of(40.0), None);
        assert_eq!(layout.edges_deg(16), (0.0, 2.5));
    }

    #[test]
    fn span_ahead_gives_its_distance_straight_ahead() {
        let mut scan = Scan::new(layout());
        scan.begin(3);
        scan.add_span(820.0, -120.0, 95.0);
        assert_eq!(scan.sector(15), Sector::Hazard(820));
        assert_eq!(scan.sector(16), Sector::Hazard(820));
        // Sector [5, 7.5) degrees: nearest point at 820 tan 5deg, inside the span.
        let x = 820.0 * libm::tan(5f64.to_radians());
        assert_eq!(scan.sector(18), Sector::Hazard(libm::round(libm::hypot(x, 820.0)) as u16));
        // Beyond the span's right end (atan(95/820) = 6.6 deg) nothing.
        assert_eq!(scan.sector(19), Sector::Unknown);
        assert_eq!(scan.nearest_ahead_mm(), Some(820));
    }

    #[test]
    fn nearest_hazard_wins_and_ranges_are_clamped() {
        let mut scan = Scan::new(layout());
        scan.begin(0);
        scan.add_point(0.0, 1000.0);
        scan.add_point(1.0, 700.0);
        scan.add_point(2.0, 300.0); // nearer than the range: raised to it
        assert_eq!(scan.sector(16), Sector::Hazard(450));
        scan.begin(1);
        scan.add_point(0.0, 1600.0); // beyond the range: left out
        assert_eq!(scan.sector(16), Sector::Unknown);
    }

    #[test]
    fn seen_sectors_are_free_and_partly_seen_ones_unknown() {
        let mut scan = Scan::new(layout());
        scan.begin(0);
        // The camera sees |x| <= 300 beyond z = 450; nearer is blind.
        scan.mark_view(15.0, |x, z| match (z < 450.0, x.abs() <= 300.0) {
            (true, _) => View::Blind,
            (false, true) => View::Seen,
            (false, false) => View::Unseen,
        });
        scan.add_point(-20.0, 900.0);
        let free: Vec<usize> = (0..scan.len()).filter(|&k| scan.sector(k) == Sector::Free).collect();
        // Whole out to 1500 mm: |angle| <= asin(300 / 1500) = 11.5 deg.
        assert_eq!(free, [12, 13, 14, 16, 17, 18, 19]);
        assert_eq!(scan.sector(15), Sector::Hazard(900));
        assert_eq!(scan.sector(11), Sector::Unknown);
        assert_eq!(scan.sector(0), Sector::Unknown);
    }

    #[test]
    fn held_hazards_follow_the_motion() {
        let mut scan = Scan::new(layout());
        scan.begin(0);
        scan.add_point(0.0, 1000.0);
        scan.keep();
        scan.begin(1);
        scan.hold(&Motion { tx_mm: 0.0, tz_mm: 100.0, dyaw_deg: 0.0 });
        assert_eq!(scan.sector(16), Sector::Hazard(900));
        scan.forget();
        scan.keep();
        scan.begin(2);
        scan.hold(&Motion { tx_mm: 0.0, tz_mm: 100.0, dyaw_deg: 0.0 });
        assert_eq!(scan.sector(16), Sector::Hazard(800), "kept again from frame 1");
    }

    #[test]
    fn csv_follows_rep_117() {
        let mut scan = Scan::new(ScanLayout::new(5.0, 450.0, 1500.0));
        scan.begin(7);
        scan.mark_view(15.0, |x, _| if x < 0.0 { View::Seen } else { View::Unseen });
        scan.add_point(10.0, 800.0);
        let mut header = String::new();
        write_csv_header(&scan.layout(), &mut header).unwrap();
        assert_eq!(header, "frame,angle_start_deg,increment_deg,d0_mm,d1_mm,d2_mm,d3_mm");
        let mut row = String::new();
        scan.write_csv(&mut row).unwrap();
        assert_eq!(row, "7,-3.750,2.500,inf,inf,800,");
    }
}

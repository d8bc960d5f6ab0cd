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

/// tan of the sector edges from -90 to 90 degrees, a sector apart: edge m
/// at `m * 2.5` degrees is entry `m + MAX_SCAN_SECTORS / 2`, exactly
/// `libm::tan` of it in radians (`edge_tangents_are_libm_tan`). A scan reads
/// them here, not from software `f64` on the M4 (~1,500 instructions each).
const EDGE_TANGENTS: [f64; MAX_SCAN_SECTORS + 1] = [
    -1.633123935319537e16,
    -22.903765548431192,
    -11.430052302761348,
    -7.5957541127251424,
    -5.671281819617707,
    -4.510708503662056,
    -3.7320508075688776,
    -3.1715948023632135,
    -2.7474774194546216,
    -2.414213562373095,
    -2.1445069205095586,
    -1.920982126971166,
    -1.7320508075688767,
    -1.5696855771174902,
    -1.4281480067421144,
    -1.3032253728412058,
    -1.19175359259421,
    -1.0913085010692716,
    -0.9999999999999999,
    -0.9163311740174234,
    -0.8390996311772799,
    -0.7673269879789604,
    -0.7002075382097097,
    -0.6370702608074932,
    -0.5773502691896257,
    -0.5205670505517462,
    -0.4663076581549986,
    -0.41421356237309503,
    -0.36397023426620234,
    -0.3152987888789835,
    -0.2679491924311227,
    -0.22169466264293988,
    -0.17632698070846498,
    -0.13165249758739583,
    -0.08748866352592401,
    -0.04366094290851206,
    0.0,
    0.04366094290851206,
    0.08748866352592401,
    0.13165249758739583,
    0.17632698070846498,
    0.22169466264293988,
    0.2679491924311227,
    0.3152987888789835,
    0.36397023426620234,
    0.41421356237309503,
    0.4663076581549986,
    0.5205670505517462,
    0.5773502691896257,
    0.6370702608074932,
    0.7002075382097097,
    0.7673269879789604,
    0.8390996311772799,
    0.9163311740174234,
    0.9999999999999999,
    1.0913085010692716,
    1.19175359259421,
    1.3032253728412058,
    1.4281480067421144,
    1.5696855771174902,
    1.7320508075688767,
    1.920982126971166,
    2.1445069205095586,
    2.414213562373095,
    2.7474774194546216,
    3.1715948023632135,
    3.7320508075688776,
    4.510708503662056,
    5.671281819617707,
    7.5957541127251424,
    11.430052302761348,
    22.903765548431192,
    1.633123935319537e16,
];

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

    /// tan of sector `k`'s near edge (its lower angle; `k = sectors`: the
    /// last sector's far edge).
    fn edge_tan(&self, k: usize) -> f64 {
        EDGE_TANGENTS[k + MAX_SCAN_SECTORS / 2 - usize::from(self.sectors / 2)]
    }

    /// [`Self::sector_of`] the direction of (`x_mm`, `z_mm`), `z_mm > 0`:
    /// the sector whose edges' tangents hold x/z. Within 1e-9 of an edge,
    /// where the rounding of the angle could fall either side, the angle
    /// decides, so the sector is always `sector_of`'s (and atan2 in
    /// software `f64`, ~2,000 M4 instructions, runs only there).
    fn sector_of_point(&self, x_mm: f64, z_mm: f64) -> Option<usize> {
        let t = x_mm / z_mm;
        let near = |edge: f64| libm::fabs(t - edge) <= 1e-9 * libm::fabs(edge).max(1.0);
        // Steep or not a number (x infinite, or NaN): by the angle.
        if t.is_nan() || libm::fabs(t) >= 1e6 {
            return self.sector_of(libm::atan2(x_mm, z_mm).to_degrees());
        }
        // The last edge at or below t (edges rise with their index).
        let m = EDGE_TANGENTS.partition_point(|&edge| edge <= t).saturating_sub(1);
        if near(EDGE_TANGENTS[m]) || EDGE_TANGENTS.get(m + 1).is_some_and(|&edge| near(edge)) {
            return self.sector_of(libm::atan2(x_mm, z_mm).to_degrees());
        }
        let k = (m + usize::from(self.sectors / 2)).checked_sub(MAX_SCAN_SECTORS / 2)?;
        (k < self.len()).then_some(k)
    }

    fn len(&self) -> usize {
        usize::from(self.sectors)
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
        self.layout.len()
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
        // Every point of the segment is at least z_mm away, so a sector
        // whose recorded range is within that keeps it (the common case in
        // a group of cells: most lie behind its nearest), and a segment
        // beyond the scan's reach records nothing. `record` rounds alike.
        let least = libm::round(z_mm);
        if least > f64::from(self.layout.range_max_mm) {
            return;
        }
        let least = least.max(f64::from(self.layout.range_min_mm)) as u16;
        let first = self.layout.sector_of_point(x_left_mm, z_mm).unwrap_or(0);
        let last = match self.layout.sector_of_point(x_right_mm, z_mm) {
            Some(k) => k,
            None if libm::atan2(x_right_mm, z_mm).to_degrees() > 0.0 => self.len().saturating_sub(1),
            None => return,
        };
        for k in first..=last {
            if self.range[k] <= least {
                continue;
            }
            let lo = x_left_mm.max(z_mm * self.layout.edge_tan(k));
            let hi = x_right_mm.min(z_mm * self.layout.edge_tan(k + 1));
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
    fn edge_tangents_are_libm_tan() {
        let layout = ScanLayout::new(90.0, 0.0, 1000.0);
        assert_eq!(usize::from(layout.sectors), MAX_SCAN_SECTORS);
        for k in 0..=MAX_SCAN_SECTORS {
            let edge_deg = if k < MAX_SCAN_SECTORS { layout.edges_deg(k).0 } else { layout.edges_deg(k - 1).1 };
            assert_eq!(layout.edge_tan(k).to_bits(), libm::tan(edge_deg.to_radians()).to_bits(), "edge {k}");
        }
    }

    /// The sector of a point from the tangents is the one its angle gives,
    /// for every layout, on points spread over the view and points on and
    /// a hair either side of every edge.
    #[test]
    fn sectors_of_points_are_those_of_their_angles() {
        let mut state = 0x5EC7_0125u32;
        for half_angle in [1.0, 12.0, 40.0, 61.0, 90.0] {
            let layout = ScanLayout::new(half_angle, 0.0, 1000.0);
            let mut points = std::vec::Vec::new();
            for k in 0..=usize::from(layout.sectors) {
                for z in [1.0, 37.0, 450.0, 1234.5, 60_000.0] {
                    let on_edge = z * layout.edge_tan(k);
                    for x in [on_edge, on_edge.next_up(), on_edge.next_down(), on_edge + 1e-7, on_edge - 1e-7, on_edge.round()] {
                        points.push((x, z));
                    }
                }
            }
            for _ in 0..20_000 {
                crate::selftest::xorshift32(&mut state);
                let z = f64::from(state % 3000) + 0.5;
                crate::selftest::xorshift32(&mut state);
                let x = f64::from(state % 12_000) - 6000.0;
                points.push((x, z));
            }
            for (x, z) in points {
                assert_eq!(layout.sector_of_point(x, z), layout.sector_of(libm::atan2(x, z).to_degrees()), "({x}, {z}) at half angle {half_angle}");
            }
        }
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

//! How autopilots read `OBSTACLE_DISTANCE`, step by step as their code
//! does, so that tests can check that no reader loses a hazard the scan
//! holds or reads it farther than it is ([`lost_hazards`]), and that doubt
//! holds every reader back ([`Readers::released`]).
//!
//! - **ArduPilot** (`AP_Proximity_MAV::handle_obstacle_distance_msg`,
//!   master): every message first clears all eight 45-degree faces
//!   (`boundary.reset()`), then walks the elements in order. Element j lies
//!   at `wrap_360(j * increment + angle_offset)`; 0, `UINT16_MAX` and values
//!   outside `min_distance..=max_distance` are skipped. The walk keeps the
//!   nearest valid element of the face it is in, and writes that face only
//!   when a valid element of another face comes (and once at the end), so
//!   a face whose elements are not contiguous in the walk is written more
//!   than once and the last write wins. The first face it enters is
//!   preceded by an invalid one, whose write does nothing. `PRX_FILT`'s
//!   low-pass filter on each face is not modelled (docs/MAVLINK.md sets it
//!   to 0, which passes each write through).
//! - **PX4 with 36 bins** of 10 degrees (`CollisionPrevention`, the
//!   versions with `INTERNAL_MAP_INCREMENT_DEG = 10`): bin i, centred on
//!   10 i degrees, reads element `ceil(wrap_360(10 i - angle_offset) /
//!   increment)` alone.
//! - **PX4 with 72 bins** of 5 degrees by overlap (later versions, with
//!   `ObstacleMath`): every element whose extent overlaps the bin's (strict
//!   comparisons, as the source) is entered in turn.
//!
//! Both PX4s keep their bins between messages: an element that is
//! `UINT16_MAX` leaves its bin as it was (until 0.5 s old, not modelled: a
//! message comes every frame), and a value goes in only if `_enterData`
//! accepts it (always, with one sensor of one range). A value below
//! `max_distance` is an obstacle, one at or beyond it free, in f32 as the
//! source computes; the arithmetic of bin and element angles is the
//! source's, in f32.

use flatland_core::scan::{Scan, ScanLayout, Sector, SCAN_INCREMENT_MDEG};
use mavlink::dialects::common::OBSTACLE_DISTANCE_DATA;

/// What a reader holds for one direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reading {
    /// Nothing (no element, or all unknown; ArduPilot: the face not valid).
    Unknown,
    /// Seen and clear to the sensor's range (PX4 only).
    Free,
    /// An obstacle this far, cm.
    Obstacle(u16),
}

/// The three readers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Autopilot {
    ArduPilot,
    Px4Bins36,
    Px4Bins72,
}

impl Autopilot {
    pub const ALL: [Autopilot; 3] = [Autopilot::ArduPilot, Autopilot::Px4Bins36, Autopilot::Px4Bins72];

    /// The bin (ArduPilot: the face) that holds the direction `angle_deg`
    /// (degrees clockwise from the front).
    fn bin(self, angle_deg: f64) -> usize {
        let angle = angle_deg.rem_euclid(360.0);
        match self {
            Autopilot::ArduPilot => (((angle + 22.5) / 45.0) as usize) % 8,
            Autopilot::Px4Bins36 => (angle / 10.0).round() as usize % 36,
            Autopilot::Px4Bins72 => (angle / 5.0).round() as usize % 72,
        }
    }

    fn bins(self) -> usize {
        match self {
            Autopilot::ArduPilot => 8,
            Autopilot::Px4Bins36 => 36,
            Autopilot::Px4Bins72 => 72,
        }
    }
}

/// One autopilot's obstacle state, kept between messages as its code
/// keeps it.
#[derive(Clone, Debug)]
pub struct Reader {
    autopilot: Autopilot,
    /// ArduPilot: each face's distance (cm), `UINT16_MAX` not valid. PX4:
    /// `_obstacle_map_body_frame.distances`.
    held: Vec<u16>,
    /// PX4's `_data_maxranges` (cm): the range of the sensor that wrote each bin.
    max_ranges: Vec<u16>,
}

impl Reader {
    pub fn new(autopilot: Autopilot) -> Reader {
        Reader { autopilot, held: vec![u16::MAX; autopilot.bins()], max_ranges: vec![0; autopilot.bins()] }
    }

    pub fn autopilot(&self) -> Autopilot {
        self.autopilot
    }

    /// Takes one message in.
    pub fn read(&mut self, message: &OBSTACLE_DISTANCE_DATA) {
        match self.autopilot {
            Autopilot::ArduPilot => self.held = ardupilot_faces(message).to_vec(),
            Autopilot::Px4Bins36 => self.px4_bins_36(message),
            Autopilot::Px4Bins72 => self.px4_bins_72(message),
        }
    }

    /// What it holds in the direction `angle_deg` (clockwise from the front).
    pub fn holds(&self, angle_deg: f64) -> Reading {
        let bin = self.autopilot.bin(angle_deg);
        match (self.autopilot, self.held[bin]) {
            (_, u16::MAX) => Reading::Unknown,
            (Autopilot::ArduPilot, cm) => Reading::Obstacle(cm),
            (_, cm) if f32::from(cm) * 0.01 < f32::from(self.max_ranges[bin]) * 0.01 => Reading::Obstacle(cm),
            _ => Reading::Free,
        }
    }

    /// PX4's `_enterData` for one sensor reading (metres, as the source).
    fn enter_data(&self, bin: usize, sensor_range: f32, reading: f32) -> bool {
        let range_cm = (100.0 * sensor_range + 0.5) as u16;
        let (held, max_range) = (self.held[bin], self.max_ranges[bin]);
        if reading < sensor_range {
            // The source's `(held < max && range <= max) || held >= max`, reduced.
            range_cm <= max_range || held >= max_range
        } else {
            (held >= max_range && range_cm >= max_range) || (held < max_range && range_cm == max_range)
        }
    }

    /// Bin `bin` takes element value `cm` when PX4 would.
    fn px4_enter(&mut self, bin: usize, message: &OBSTACLE_DISTANCE_DATA, cm: u16) {
        if cm != u16::MAX && self.enter_data(bin, f32::from(message.max_distance) * 0.01, f32::from(cm) * 0.01) {
            self.held[bin] = cm;
            self.max_ranges[bin] = message.max_distance;
        }
    }

    /// PX4 with 36 bins: bin i takes element `ceil(wrap_360(10 i - angle_offset) / increment)`.
    fn px4_bins_36(&mut self, message: &OBSTACLE_DISTANCE_DATA) {
        let factor = 1.0 / increment(message);
        for bin in 0..36 {
            let index = (wrap_360(bin as f32 * 10.0 - message.angle_offset) * factor).ceil() as usize;
            // Past the array the source reads out of bounds; nothing here.
            if let Some(&cm) = message.distances.get(index) {
                self.px4_enter(bin, message, cm);
            }
        }
    }

    /// PX4 with 72 bins of 5 degrees: every element overlapping each bin, in order.
    fn px4_bins_72(&mut self, message: &OBSTACLE_DISTANCE_DATA) {
        const BIN: f32 = 5.0;
        let increment = increment(message);
        let extent = |centre: f32, width: f32| {
            let (mut lower, upper) = (wrap_360(centre - width / 2.0), wrap_360(centre + width / 2.0));
            if lower > upper {
                lower -= 360.0;
            }
            (lower, upper)
        };
        for bin in 0..72 {
            let (bin_lower, bin_upper) = extent(bin as f32 * BIN, BIN);
            for j in (0..message.distances.len()).take_while(|&j| (j as f32) < 360.0 / increment) {
                let (lower, upper) = extent(j as f32 * increment + message.angle_offset, increment);
                let overlaps = (lower > bin_lower && lower < bin_upper)
                    || (upper > bin_lower && upper < bin_upper)
                    || (lower <= bin_lower && upper >= bin_upper)
                    || (lower >= bin_lower && upper <= bin_upper);
                if overlaps {
                    self.px4_enter(bin, message, message.distances[j]);
                }
            }
        }
    }
}

/// The element width a reader takes: `increment_f`, else `increment`.
fn increment(message: &OBSTACLE_DISTANCE_DATA) -> f32 {
    if message.increment_f != 0.0 {
        message.increment_f
    } else {
        f32::from(message.increment)
    }
}

/// ArduPilot's `wrap_360` (fmodf, then one turn added to a negative rest).
fn ardupilot_wrap_360(angle: f32) -> f32 {
    let rest = angle % 360.0;
    if rest < 0.0 {
        rest + 360.0
    } else {
        rest
    }
}

/// ArduPilot's faces after one message: the element walk (module docs),
/// with `PRX1_ORIENT` and `PRX1_YAW_CORR` 0. `UINT16_MAX`: not valid.
fn ardupilot_faces(message: &OBSTACLE_DISTANCE_DATA) -> [u16; 8] {
    // `boundary.reset()`: every face invalid before the walk.
    let mut faces = [u16::MAX; 8];
    let increment = increment(message);
    if increment == 0.0 {
        // The source returns before the reset; no message of ours has 0.
        return faces;
    }
    let total = ((360.0 / increment.abs() + 0.5) as u8).min(72);
    let yaw_correction = ardupilot_wrap_360(message.angle_offset);
    // `Face face;` starts invalid: its first write does nothing.
    let mut face: Option<usize> = None;
    let mut nearest: Option<u16> = None;
    // set_face_attributes / reset_face; an invalid face (sector 8, from a
    // wrap that rounds to 360) is ignored as the source's `face.valid()` does.
    let write = |faces: &mut [u16; 8], face: Option<usize>, nearest: Option<u16>| {
        if let Some(slot) = face.and_then(|f| faces.get_mut(f)) {
            *slot = nearest.unwrap_or(u16::MAX);
        }
    };
    for (j, &cm) in message.distances.iter().enumerate().take(usize::from(total)) {
        if cm == 0 || cm == u16::MAX || cm < message.min_distance || cm > message.max_distance {
            continue;
        }
        let mid_angle = ardupilot_wrap_360(j as f32 * increment + yaw_correction);
        let latest = (ardupilot_wrap_360(mid_angle + 22.5) / 45.0) as u8 as usize;
        if Some(latest) != face {
            write(&mut faces, face, nearest);
            face = Some(latest);
            nearest = None;
        }
        // `packet_distance_m < face_distance`: cm * 0.01 in f32 keeps the order of cm.
        if nearest.is_none_or(|n| cm < n) {
            nearest = Some(cm);
        }
    }
    write(&mut faces, face, nearest);
    faces
}

/// `wrap(x, 0, 360)` as PX4's matrix library computes it.
fn wrap_360(x: f32) -> f32 {
    if (0.0..360.0).contains(&x) {
        return x;
    }
    x - 360.0 * (x / 360.0).floor()
}

/// The three readers side by side, fed the same stream.
#[derive(Clone, Debug)]
pub struct Readers(pub [Reader; 3]);

impl Default for Readers {
    fn default() -> Self {
        Readers(Autopilot::ALL.map(Reader::new))
    }
}

impl Readers {
    pub fn read(&mut self, message: &OBSTACLE_DISTANCE_DATA) {
        self.0.iter_mut().for_each(|reader| reader.read(message));
    }

    /// Every way the readers, having read `message`, fail `scan`: a hazard
    /// some reader does not hold as an obstacle at its distance or nearer
    /// (in the direction of the hazard's sector centre), and an element at
    /// exactly `max_distance` (ArduPilot reads it as an obstacle, PX4 as
    /// free).
    pub fn lost_hazards(&self, message: &OBSTACLE_DISTANCE_DATA, scan: &Scan) -> Vec<String> {
        let mut problems = Vec::new();
        if let Some(j) = message.distances.iter().position(|&cm| cm == message.max_distance) {
            problems.push(format!("element {j} at max_distance {} cm", message.max_distance));
        }
        let start = scan.layout().angle_start_mdeg();
        for (k, sector) in scan.sectors().enumerate() {
            let Sector::Hazard(mm) = sector else { continue };
            let angle_deg = f64::from(start + k as i32 * SCAN_INCREMENT_MDEG) / 1000.0;
            for reader in &self.0 {
                match reader.holds(angle_deg) {
                    Reading::Obstacle(cm) if u32::from(cm) * 10 <= u32::from(mm) => {}
                    reading => problems.push(format!("{:?} at {angle_deg} deg: {reading:?} for a hazard at {mm} mm", reader.autopilot)),
                }
            }
        }
        problems
    }

    /// Every direction the camera looks (each sector centre of `layout`)
    /// where a reader holds anything but an obstacle at `min_distance_cm`
    /// or nearer: where it would let the vehicle drive on.
    pub fn released(&self, layout: &ScanLayout, min_distance_cm: u16) -> Vec<String> {
        let mut problems = Vec::new();
        for k in 0..usize::from(layout.sectors) {
            let angle_deg = f64::from(layout.angle_start_mdeg() + k as i32 * SCAN_INCREMENT_MDEG) / 1000.0;
            for reader in &self.0 {
                match reader.holds(angle_deg) {
                    Reading::Obstacle(cm) if cm <= min_distance_cm => {}
                    reading => problems.push(format!("{:?} at {angle_deg} deg: {reading:?}", reader.autopilot)),
                }
            }
        }
        problems
    }

    /// What each reader holds straight ahead.
    pub fn ahead(&self) -> [(Autopilot, Reading); 3] {
        [0, 1, 2].map(|i| (self.0[i].autopilot, self.0[i].holds(0.0)))
    }
}

/// [`Readers::lost_hazards`] for readers that read `message` alone.
pub fn lost_hazards(message: &OBSTACLE_DISTANCE_DATA, scan: &Scan) -> Vec<String> {
    let mut readers = Readers::default();
    readers.read(message);
    readers.lost_hazards(message, scan)
}

/// Hazard sectors in `scan`.
pub fn hazards(scan: &Scan) -> usize {
    scan.sectors().filter(|s| matches!(s, Sector::Hazard(_))).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use flatland_core::mavlink::{obstacle_distance, obstacle_distance_in_doubt};
    use flatland_core::scan::View;

    /// A scan `half_deg` either side, all seen, with hazards at `points`
    /// (x, z mm).
    fn scan_with(half_deg: f64, points: &[(f64, f64)]) -> Scan {
        let mut scan = Scan::new(ScanLayout::new(half_deg, 400.0, 1418.0));
        scan.begin(1);
        scan.mark_view(10.0, |_, _| View::Seen);
        for &(x, z) in points {
            scan.add_point(x, z);
        }
        scan
    }

    /// A point `range` mm away at `angle` degrees clockwise from ahead.
    fn polar(angle: f64, range: f64) -> (f64, f64) {
        let (sin, cos) = angle.to_radians().sin_cos();
        (range * sin, range * cos)
    }

    /// The stream before issue 52: element j centred on 5j degrees
    /// (`angle_offset` 0), and doubt sent as all unknown.
    fn before_issue_52(message: &OBSTACLE_DISTANCE_DATA) -> OBSTACLE_DISTANCE_DATA {
        let mut old = message.clone();
        old.angle_offset = 0.0;
        old.distances = core::array::from_fn(|j| message.distances[(j + 36) % 72]);
        old
    }

    fn all_unknown(message: &OBSTACLE_DISTANCE_DATA) -> OBSTACLE_DISTANCE_DATA {
        OBSTACLE_DISTANCE_DATA { distances: [u16::MAX; 72], ..message.clone() }
    }

    #[test]
    fn every_reader_gets_every_hazard_of_the_stream() {
        // Right of ahead at 1.25, 3.75 and 6.25 degrees (3.75 and 6.25 fall
        // in odd elements only under half-open 5-degree elements), and one
        // at the scan's far edge.
        for angle in [1.25f64, 3.75, 6.25, -6.25, 13.75, -18.75] {
            for range in [400.0, 817.0, 1418.0] {
                let scan = scan_with(20.0, &[polar(angle, range)]);
                assert_eq!(hazards(&scan), 1);
                let problems = lost_hazards(&obstacle_distance(&scan, 0), &scan);
                assert!(problems.is_empty(), "{angle} deg {range} mm: {problems:?}");
            }
        }
    }

    /// Issue 52's SITL case: a hazard at 60 cm 5-15 degrees right, a box at
    /// 90 cm from -40 to -10 degrees. Before, the walk left the front face
    /// at element 4 (20 degrees), wrote 60 cm, crossed face 7 (-45..-22.5)
    /// and came back into the front face at element 68 (-20): that second
    /// write, 90 cm, won.
    #[test]
    fn a_split_front_face_with_a_hazard_between_loses_nothing() {
        let mut points: Vec<(f64, f64)> = (0..=40).map(|i| polar(5.0 + 0.25 * f64::from(i), 600.0)).collect();
        points.extend((0..=120).map(|i| polar(-40.0 + 0.25 * f64::from(i), 900.0)));
        let scan = scan_with(45.0, &points);
        let message = obstacle_distance(&scan, 0);
        assert_eq!(lost_hazards(&message, &scan), Vec::<String>::new());
        let mut readers = Readers::default();
        readers.read(&message);
        assert_eq!(readers.0[0].holds(10.0), Reading::Obstacle(60));
        let old = before_issue_52(&message);
        let problems = lost_hazards(&old, &scan);
        assert!(problems.iter().any(|p| p.starts_with("ArduPilot at 6.25 deg: Obstacle(90)")), "{problems:?}");
        assert!(problems.iter().all(|p| p.starts_with("ArduPilot")), "PX4 read the old stream right: {problems:?}");
    }

    /// A wall ahead running away to the left, z = 600 - x / 2 mm: nearest
    /// on the right of the front face (53 cm at 23.75 degrees, in element
    /// 20 degrees), reaching 45 degrees left. Before, the front face was
    /// written last from its left half: 60 cm.
    #[test]
    fn an_oblique_wall_reads_at_its_nearest() {
        let points: Vec<(f64, f64)> = (0..=320)
            .map(|i| {
                let angle = (-45.0 + 0.25 * f64::from(i)).to_radians();
                polar(angle.to_degrees(), 600.0 / (angle.cos() + 0.5 * angle.sin()))
            })
            .collect();
        let scan = scan_with(45.0, &points);
        let message = obstacle_distance(&scan, 0);
        assert_eq!(lost_hazards(&message, &scan), Vec::<String>::new());
        let mut readers = Readers::default();
        readers.read(&message);
        assert_eq!(readers.0[0].holds(0.0), Reading::Obstacle(53));
        let mut old = Readers::default();
        old.read(&before_issue_52(&message));
        assert_eq!(old.0[0].holds(0.0), Reading::Obstacle(60));
    }

    /// What each reader holds after a frame that was not judged, following
    /// a judged frame that found the floor clear: doubt holds all three
    /// back at the nearest range. Before, all unknown: ArduPilot cleared
    /// every face (nothing to avoid), and PX4 kept the clear frame's
    /// "free" in every bin.
    #[test]
    fn a_frame_not_judged_holds_every_reader_back() {
        let clear = scan_with(30.0, &[]);
        let judged = obstacle_distance(&clear, 1);
        let doubt = obstacle_distance_in_doubt(&clear.layout(), 2);
        let mut readers = Readers::default();
        readers.read(&judged);
        assert!(readers.ahead().iter().all(|(autopilot, reading)| match autopilot {
            Autopilot::ArduPilot => *reading == Reading::Unknown,
            _ => *reading == Reading::Free,
        }));
        let mut old = readers.clone();
        readers.read(&doubt);
        println!("after a frame not judged: {:?}", readers.ahead());
        assert_eq!(readers.ahead().map(|(_, reading)| reading), [Reading::Obstacle(40); 3]);
        assert_eq!(readers.released(&clear.layout(), doubt.min_distance), Vec::<String>::new());
        old.read(&all_unknown(&doubt));
        println!("the same, sent all unknown: {:?}", old.ahead());
        assert_eq!(old.ahead().map(|(_, reading)| reading), [Reading::Unknown, Reading::Free, Reading::Free]);
        assert_eq!(old.released(&clear.layout(), doubt.min_distance).len(), 3 * 24);
    }

    #[test]
    fn half_open_elements_lose_hazards_on_px4_36() {
        // The stream before the overlap: element j held only the sectors in
        // [5j - 2.5, 5j + 2.5), rounded to the nearest cm and capped at
        // max_distance. A hazard at 3.75 degrees sits in element 1 alone,
        // which PX4's 36 bins never read; one at 1417 mm reads 142 cm, at
        // max_distance, so PX4 takes it as free.
        let scan = scan_with(20.0, &[polar(3.75, 1417.0)]);
        let mut message = obstacle_distance(&scan, 0);
        message.angle_offset = 0.0;
        message.max_distance = 142;
        message.distances = [u16::MAX; 72];
        message.distances[0] = 143;
        message.distances[1] = 142;
        let problems = lost_hazards(&message, &scan);
        assert!(problems.iter().any(|p| p.starts_with("Px4Bins36 at 3.75 deg: Free")), "{problems:?}");
        assert!(problems.iter().any(|p| p.starts_with("Px4Bins72 at 3.75 deg: Free")), "{problems:?}");
        assert!(problems.iter().any(|p| p.starts_with("element 1 at max_distance")), "{problems:?}");
    }

    #[test]
    fn readers_follow_their_sources() {
        let mut message = OBSTACLE_DISTANCE_DATA { increment_f: 5.0, min_distance: 20, max_distance: 150, ..Default::default() };
        message.distances = [u16::MAX; 72];
        message.distances[1] = 100; // 5 degrees
        message.distances[2] = 151; // 10 degrees, free
        message.distances[71] = 90; // -5 degrees
        let read = |message: &OBSTACLE_DISTANCE_DATA| {
            let mut readers = Readers::default();
            readers.read(message);
            readers
        };
        let readers = read(&message);
        let [ardupilot, px4_36, px4_72] = &readers.0;
        // PX4 36: bin 0 reads element 0 only, bin 1 element 2.
        assert_eq!(px4_36.holds(4.0), Reading::Unknown);
        assert_eq!(px4_36.holds(9.0), Reading::Free);
        // PX4 72: one element a bin.
        assert_eq!(px4_72.holds(5.0), Reading::Obstacle(100));
        assert_eq!(px4_72.holds(-5.0), Reading::Obstacle(90));
        // ArduPilot: face 0 (-22.5..22.5) keeps the nearest; free skipped.
        assert_eq!(ardupilot.holds(20.0), Reading::Obstacle(90));
        assert_eq!(ardupilot.holds(45.0), Reading::Unknown);
        // ArduPilot's walk: with the left half (-5 degrees) farther than
        // the right, the face keeps the nearest while the walk stays in
        // it; a valid element of face 1 (25 degrees) between the halves
        // makes the left half's write the last.
        message.distances[71] = 120;
        assert_eq!(read(&message).0[0].holds(0.0), Reading::Obstacle(100));
        message.distances[5] = 140;
        assert_eq!(read(&message).0[0].holds(0.0), Reading::Obstacle(120));
        // ... and every message clears all faces first.
        let mut later = Readers::default();
        later.read(&message);
        later.read(&all_unknown(&message));
        assert_eq!(later.0[0].holds(0.0), Reading::Unknown);
        // PX4 keeps a bin while its element is unknown.
        assert_eq!(later.0[2].holds(5.0), Reading::Obstacle(100));
        // A finer stream on PX4 72: the last overlapping element stays,
        // not the nearest.
        let mut fine = OBSTACLE_DISTANCE_DATA { increment_f: 2.5, min_distance: 20, max_distance: 150, ..Default::default() };
        fine.distances = [u16::MAX; 72];
        fine.distances[2] = 60; // 5 degrees
        fine.distances[3] = 120; // 7.5 degrees, overlaps bin 1 (2.5..7.5) too
        assert_eq!(read(&fine).0[2].holds(5.0), Reading::Obstacle(120));
    }
}

//! How autopilots read `OBSTACLE_DISTANCE`, modelled from their sources,
//! so that tests can check that no reader loses a hazard the scan holds or
//! reads it farther than it is ([`lost_hazards`]).
//!
//! - **ArduPilot** (`AP_Proximity_MAV::handle_obstacle_distance_msg`):
//!   element j lies at `j * increment_f` degrees; 0, `UINT16_MAX` and
//!   values outside `min_distance..=max_distance` are skipped; each of
//!   eight 45-degree faces, centred on 0, 45, ... degrees, keeps its
//!   nearest reading.
//! - **PX4 with 36 bins** of 10 degrees (`CollisionPrevention`, the
//!   versions with `BIN_COUNT = 36`): bin i, centred on 10 i degrees, reads
//!   element `ceil(10 i / increment)` alone.
//! - **PX4 with 72 bins** of 5 degrees by overlap (later versions): every
//!   element whose extent overlaps the bin's (strict comparisons, as the
//!   source) is entered in turn, and the last one not `UINT16_MAX` stays.
//!   With one sensor PX4's `_enterData` accepts every reading, so it is not
//!   modelled.
//!
//! Both PX4s read a value below `max_distance` as an obstacle and one at or
//! beyond it as free, in f32 as the source does; the arithmetic of bin and
//! element angles is the source's, in f32.

use flatland_core::scan::{Scan, Sector, SCAN_INCREMENT_MDEG};
use mavlink::dialects::common::OBSTACLE_DISTANCE_DATA;

/// What a reader holds for one direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reading {
    /// Nothing (no element, or all unknown).
    Unknown,
    /// Seen and clear to the sensor's range.
    Free,
    /// An obstacle this far, cm.
    Obstacle(u16),
}

/// The three readers, each mapping a direction (degrees clockwise from the
/// front) to what it took from one message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Autopilot {
    ArduPilot,
    Px4Bins36,
    Px4Bins72,
}

impl Autopilot {
    pub const ALL: [Autopilot; 3] = [Autopilot::ArduPilot, Autopilot::Px4Bins36, Autopilot::Px4Bins72];

    /// What this reader makes of `message` in the direction `angle_deg`.
    pub fn reading(self, message: &OBSTACLE_DISTANCE_DATA, angle_deg: f64) -> Reading {
        self.readings(message)[self.bin(angle_deg)]
    }

    /// Everything this reader takes from `message`, by its own bins.
    fn readings(self, message: &OBSTACLE_DISTANCE_DATA) -> Vec<Reading> {
        match self {
            Autopilot::ArduPilot => ardupilot_faces(message).to_vec(),
            Autopilot::Px4Bins36 => px4_bins_36(message).to_vec(),
            Autopilot::Px4Bins72 => px4_bins_72(message).to_vec(),
        }
    }

    /// The bin (ArduPilot: the face) that holds the direction `angle_deg`.
    fn bin(self, angle_deg: f64) -> usize {
        let angle = angle_deg.rem_euclid(360.0);
        match self {
            Autopilot::ArduPilot => (((angle + 22.5) / 45.0) as usize) % 8,
            Autopilot::Px4Bins36 => (angle / 10.0).round() as usize % 36,
            Autopilot::Px4Bins72 => (angle / 5.0).round() as usize % 72,
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

/// ArduPilot's eight faces: the nearest valid reading in each.
fn ardupilot_faces(message: &OBSTACLE_DISTANCE_DATA) -> [Reading; 8] {
    let mut faces = [Reading::Unknown; 8];
    let increment = increment(message);
    if increment == 0.0 {
        return faces;
    }
    let total = ((360.0 / increment.abs() + 0.5) as usize).min(message.distances.len());
    let yaw_correction = wrap_360(message.angle_offset);
    for (j, &cm) in message.distances.iter().enumerate().take(total) {
        if cm == 0 || cm == u16::MAX || cm < message.min_distance || cm > message.max_distance {
            continue;
        }
        let mid_angle = wrap_360(j as f32 * increment + yaw_correction);
        let face = (wrap_360(mid_angle + 22.5) / 45.0) as usize;
        faces[face] = match faces[face] {
            Reading::Obstacle(nearest) if nearest <= cm => Reading::Obstacle(nearest),
            _ => Reading::Obstacle(cm),
        };
    }
    faces
}

/// PX4's reading of one element value.
fn px4_reading(message: &OBSTACLE_DISTANCE_DATA, cm: u16) -> Reading {
    match cm {
        u16::MAX => Reading::Unknown,
        cm if f32::from(cm) * 0.01 < f32::from(message.max_distance) * 0.01 => Reading::Obstacle(cm),
        _ => Reading::Free,
    }
}

/// PX4 with 36 bins: bin i takes element `ceil(10 i / increment)`.
fn px4_bins_36(message: &OBSTACLE_DISTANCE_DATA) -> [Reading; 36] {
    let factor = 1.0 / increment(message);
    core::array::from_fn(|i| {
        let index = (wrap_360(i as f32 * 10.0 - message.angle_offset) * factor).ceil() as usize;
        message.distances.get(index).map_or(Reading::Unknown, |&cm| px4_reading(message, cm))
    })
}

/// PX4 with 72 bins of 5 degrees: the last element overlapping each bin.
fn px4_bins_72(message: &OBSTACLE_DISTANCE_DATA) -> [Reading; 72] {
    const BIN: f32 = 5.0;
    let increment = increment(message);
    let elements = (0..message.distances.len()).take_while(|&j| (j as f32) < 360.0 / increment);
    let extent = |centre: f32, width: f32| {
        let (mut lower, upper) = (wrap_360(centre - width / 2.0), wrap_360(centre + width / 2.0));
        if lower > upper {
            lower -= 360.0;
        }
        (lower, upper)
    };
    core::array::from_fn(|i| {
        let (bin_lower, bin_upper) = extent(i as f32 * BIN, BIN);
        elements
            .clone()
            .filter(|&j| {
                let (lower, upper) = extent(j as f32 * increment + message.angle_offset, increment);
                (lower > bin_lower && lower < bin_upper)
                    || (upper > bin_lower && upper < bin_upper)
                    || (lower <= bin_lower && upper >= bin_upper)
                    || (lower >= bin_lower && upper <= bin_upper)
            })
            .map(|j| message.distances[j])
            .filter(|&cm| cm != u16::MAX)
            .last()
            .map_or(Reading::Unknown, |cm| px4_reading(message, cm))
    })
}

/// `wrap(x, 0, 360)` as PX4's matrix library and ArduPilot compute it.
fn wrap_360(x: f32) -> f32 {
    if (0.0..360.0).contains(&x) {
        return x;
    }
    x - 360.0 * (x / 360.0).floor()
}

/// Every way `message` fails `scan`: a hazard some reader does not get as
/// an obstacle at its distance or nearer (in the direction of the hazard's
/// sector centre), and an element at exactly `max_distance` (ArduPilot
/// reads it as an obstacle, PX4 as free).
pub fn lost_hazards(message: &OBSTACLE_DISTANCE_DATA, scan: &Scan) -> Vec<String> {
    let mut problems = Vec::new();
    if let Some(j) = message.distances.iter().position(|&cm| cm == message.max_distance) {
        problems.push(format!("element {j} at max_distance {} cm", message.max_distance));
    }
    // Each reader's bins once per message, then every hazard looked up.
    let readers = Autopilot::ALL.map(|autopilot| (autopilot, autopilot.readings(message)));
    let start = scan.layout().angle_start_mdeg();
    for (k, sector) in scan.sectors().enumerate() {
        let Sector::Hazard(mm) = sector else { continue };
        let angle_deg = f64::from(start + k as i32 * SCAN_INCREMENT_MDEG) / 1000.0;
        for (autopilot, readings) in &readers {
            match readings[autopilot.bin(angle_deg)] {
                Reading::Obstacle(cm) if u32::from(cm) * 10 <= u32::from(mm) => {}
                reading => problems.push(format!("{autopilot:?} at {angle_deg} deg: {reading:?} for a hazard at {mm} mm")),
            }
        }
    }
    problems
}

/// Hazard sectors in `scan`.
pub fn hazards(scan: &Scan) -> usize {
    scan.sectors().filter(|s| matches!(s, Sector::Hazard(_))).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use flatland_core::mavlink::obstacle_distance;
    use flatland_core::scan::{ScanLayout, View};

    /// A scan 20 degrees either side, all seen, with hazards at `points`
    /// (x, z mm).
    fn scan_with(points: &[(f64, f64)]) -> Scan {
        let mut scan = Scan::new(ScanLayout::new(20.0, 400.0, 1418.0));
        scan.begin(1);
        scan.mark_view(10.0, |_, _| View::Seen);
        for &(x, z) in points {
            scan.add_point(x, z);
        }
        scan
    }

    #[test]
    fn every_reader_gets_every_hazard_of_the_stream() {
        // Right of ahead at 1.25, 3.75 and 6.25 degrees (3.75 and 6.25 fall
        // in odd element 1 only under half-open 5-degree elements), and one
        // at the scan's far edge.
        for angle in [1.25f64, 3.75, 6.25, -6.25, 13.75, -18.75] {
            for range in [400.0, 817.0, 1418.0] {
                let (sin, cos) = angle.to_radians().sin_cos();
                let scan = scan_with(&[(range * sin, range * cos)]);
                assert_eq!(hazards(&scan), 1);
                let problems = lost_hazards(&obstacle_distance(&scan, 0), &scan);
                assert!(problems.is_empty(), "{angle} deg {range} mm: {problems:?}");
            }
        }
    }

    #[test]
    fn half_open_elements_lose_hazards_on_px4_36() {
        // The stream before the overlap: element j held only the sectors in
        // [5j - 2.5, 5j + 2.5), rounded to the nearest cm and capped at
        // max_distance. A hazard at 3.75 degrees sits in element 1 alone,
        // which PX4's 36 bins never read; one at 1417 mm reads 142 cm, at
        // max_distance, so PX4 takes it as free.
        let (sin, cos) = 3.75f64.to_radians().sin_cos();
        let scan = scan_with(&[(1417.0 * sin, 1417.0 * cos)]);
        let mut message = obstacle_distance(&scan, 0);
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
        // PX4 36: bin 0 reads element 0 only, bin 1 element 2.
        assert_eq!(Autopilot::Px4Bins36.reading(&message, 4.0), Reading::Unknown);
        assert_eq!(Autopilot::Px4Bins36.reading(&message, 9.0), Reading::Free);
        // PX4 72: one element a bin.
        assert_eq!(Autopilot::Px4Bins72.reading(&message, 5.0), Reading::Obstacle(100));
        assert_eq!(Autopilot::Px4Bins72.reading(&message, -5.0), Reading::Obstacle(90));
        // ArduPilot: face 0 (-22.5..22.5) keeps the nearest; free skipped.
        assert_eq!(Autopilot::ArduPilot.reading(&message, 20.0), Reading::Obstacle(90));
        assert_eq!(Autopilot::ArduPilot.reading(&message, 45.0), Reading::Unknown);
        // A finer stream on PX4 72: the last overlapping element stays,
        // not the nearest.
        let mut fine = OBSTACLE_DISTANCE_DATA { increment_f: 2.5, min_distance: 20, max_distance: 150, ..Default::default() };
        fine.distances = [u16::MAX; 72];
        fine.distances[2] = 60; // 5 degrees
        fine.distances[3] = 120; // 7.5 degrees, overlaps bin 1 (2.5..7.5) too
        assert_eq!(Autopilot::Px4Bins72.reading(&fine, 5.0), Reading::Obstacle(120));
    }
}

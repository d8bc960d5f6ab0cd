//! Where the robot is: the odometry pose in the odometry world, each step
//! corrected by the floor's measurement of it, and odometry's scale as the
//! floor measured it so far. Tracks measure their travel from this pose.

use super::edges::{Edge, LineEdges};
use super::fits::{key_value, median, order_key};
use super::lines::{off_line, GtLine};
use super::tracks::{zncc, Track};
use super::Gti;
use crate::limits::MAX_TRACKS;
use crate::motion::{Motion, Rotation};
use crate::kernels::sqrtf;
use libm::fabsf;

/// `v` along a unit `axis` and across it (towards `(u_z, -u_x)`): the frame
/// a track's locus is measured in.
pub(super) fn along_across(v: [f32; 2], axis: [f32; 2]) -> (f32, f32) {
    (v[0] * axis[0] + v[1] * axis[1], v[0] * axis[1] - v[1] * axis[0])
}

/// Travel (mm) measured by the floor before its scale is applied to odometry.
const SCALE_MIN_TRAVEL_MM: f64 = 100.0;
/// Largest odometry scale error corrected (a factor): beyond it, the floor
/// measurement is more likely wrong than the wheels.
const MAX_SCALE_ERROR: f32 = 1.2;
/// Floor tracks the travel correction needs in a frame.
const MIN_FLOOR_TRACKS: usize = 6;
/// Fitted slopes within this of 1 count as floor for the travel correction
/// (wide enough for a few % of odometry scale error before correction).
const FLOOR_SLOPE_BAND: f32 = 0.08;

/// The level points of the strong edges floor tracks found in the travel
/// correction, by track slot: the association searches the same strong
/// edges (in the same order) and mostly matches a floor track to the same
/// edge, whose point then needs no second tilt (software f64 on the M4).
/// Valid for one frame: a frame starts from [`FloorPoints::NONE`].
pub(super) struct FloorPoints {
    /// The strong edge's index plus one (0: none).
    edge: [u8; MAX_TRACKS],
    point: [[f32; 2]; MAX_TRACKS],
}

impl FloorPoints {
    pub(super) const NONE: FloorPoints = FloorPoints { edge: [0; MAX_TRACKS], point: [[0.0; 2]; MAX_TRACKS] };

    /// The level point of strong edge `e` if track slot `index` found it.
    pub(super) fn get(&self, index: usize, e: usize) -> Option<[f32; 2]> {
        let found = self.edge.get(index).is_some_and(|&k| usize::from(k) == e + 1);
        found.then(|| self.point.get(index).copied()).flatten()
    }

    fn set(&mut self, index: usize, e: usize, point: [f32; 2]) {
        if let (Some(k), Some(p), Ok(e)) = (self.edge.get_mut(index), self.point.get_mut(index), u8::try_from(e + 1)) {
            *k = e;
            *p = point;
        }
    }
}

/// The odometry world pose of the current frame and the steps measured.
pub(super) struct Travel {
    position: [f64; 2],
    yaw_rad: f64,
    /// `Rotation::from_radians(yaw_rad)` and its f32 copy, worked out once
    /// per step: f64 sines are software on the M4, and every track turns
    /// through them several times a frame. None: not yet (the start's yaw).
    turn: Option<(Rotation<f64>, Rotation<f32>)>,
    /// Step lengths the floor measured, and odometry's for the same steps.
    step_sums: [f64; 2],
}

impl Travel {
    pub(super) const START: Travel = Travel { position: [0.0; 2], yaw_rad: 0.0, turn: None, step_sums: [0.0; 2] };

    pub(super) fn position(&self) -> [f64; 2] {
        self.position
    }

    /// The robot's axes in the odometry world.
    pub(super) fn rotation(&self) -> Rotation<f64> {
        self.turn.map_or_else(|| Rotation::from_radians(self.yaw_rad), |(turn, _)| turn)
    }

    /// [`Travel::rotation`] in single precision.
    pub(super) fn rotation_f32(&self) -> Rotation<f32> {
        self.turn.map_or_else(|| Rotation::from_radians(self.yaw_rad).to_f32(), |(_, turn)| turn)
    }

    /// Distance travelled along and across `axis` (world, unit) since the
    /// robot was at `origin`.
    pub(super) fn since(&self, origin: [f32; 2], axis: [f32; 2]) -> (f32, f32) {
        let d = [(self.position[0] - f64::from(origin[0])) as f32, (self.position[1] - f64::from(origin[1])) as f32];
        along_across(d, axis)
    }

    /// Moves the pose by `motion`; returns the step in the world.
    fn advance(&mut self, motion: &Motion) -> [f64; 2] {
        let before = self.position;
        let step = self.rotation().to_world([motion.tx_mm, motion.tz_mm]);
        self.position[0] += step[0];
        self.position[1] += step[1];
        self.yaw_rad += motion.dyaw_deg.to_radians();
        let turn = Rotation::from_radians(self.yaw_rad);
        self.turn = Some((turn, turn.to_f32()));
        [self.position[0] - before[0], self.position[1] - before[1]]
    }
}

/// For a floor track (matched last frame, fitted slope near 1, its axis
/// along the step's direction `d`): how far its axis runs along `d`.
fn floor_track_along(track: &Track, d: [f32; 2]) -> Option<f32> {
    // Three observations give a slope to tell floor from obstacle; waiting
    // for more would leave the first steps' error in every track.
    if track.misses != 0 || track.observations.len() < 3 {
        return None;
    }
    let (along, _) = along_across(d, track.axis);
    if along < 0.7 {
        return None; // the track's axis is not the travel's: its y says little
    }
    let fit = track.fit()?;
    if fabsf(-fit.slope - 1.0) > FLOOR_SLOPE_BAND {
        return None;
    }
    Some(along)
}

impl Gti {
    /// Moves the pose by the odometry since the previous frame (`motion`),
    /// scaled by odometry's learned scale, and corrects the step with the
    /// floor (`edges`: room for one line's edges; `found`: the floor tracks'
    /// edges' points).
    pub(super) fn advance_pose(&mut self, motion: &Motion, edges: &mut LineEdges, found: &mut FloorPoints) {
        let scale = f64::from(self.odometry_scale());
        let scaled = Motion { tx_mm: motion.tx_mm * scale, tz_mm: motion.tz_mm * scale, dyaw_deg: motion.dyaw_deg };
        let step = self.travel.advance(&scaled);
        if let Some(measured) = self.correct_travel(step, edges, found) {
            self.travel.step_sums[0] += f64::from(measured);
            self.travel.step_sums[1] += motion.distance_mm();
        }
    }

    /// Odometry's scale as the floor measured it so far (1 until it has):
    /// a constant error (wheel diameter) is then gone from the steps before
    /// the floor corrects them, and from steps where it cannot.
    fn odometry_scale(&self) -> f32 {
        let [measured, odometry] = self.travel.step_sums;
        if !(odometry > SCALE_MIN_TRAVEL_MM) {
            return 1.0;
        }
        ((measured / odometry) as f32).clamp(1.0 / MAX_SCALE_ERROR, MAX_SCALE_ERROR)
    }

    /// Corrects this frame's odometry step (`step`, world, mm) along its
    /// direction with the floor: a floor feature's apparent position moves by
    /// exactly the travel (slope 1), so the floor tracks' displacements
    /// measure the true step. Odometry scale errors (wheel wear, slip) would
    /// otherwise scale every slope: +2 % of travel reads the floor at
    /// -H/50 = -8 mm on a 400 mm mount. The visual step is the median over
    /// floor tracks matched in the previous frame, blended with odometry by
    /// their variances (`odometry_sigma` against the tracks' spread), so a
    /// bare floor or a scene filled by one obstacle falls back on odometry.
    /// Returns the corrected step length when the floor measured it.
    // Not inlined: the frame that holds the edges must stay small, as the
    // firmware's deepest stack runs through edge finding.
    #[inline(never)]
    fn correct_travel(&mut self, step: [f64; 2], edges: &mut LineEdges, found: &mut FloorPoints) -> Option<f32> {
        let length = libm::hypot(step[0], step[1]) as f32;
        if !(length > 1.0) {
            return None;
        }
        let d = [step[0] as f32 / length, step[1] as f32 / length];
        let mm_per_px = self.grid.mm_per_px;
        // The floor tracks' displacements, as order keys for their medians.
        let mut deltas: heapless::Vec<i32, MAX_TRACKS> = heapless::Vec::new();
        for l in 0..self.config.lines {
            let Some(line) = self.lines.line(l) else { continue };
            // A line without a floor track needs no edges (finding them is
            // most of this pass), and the others only the strong ones.
            if !self.tracks.iter().flatten().any(|t| usize::from(t.line) == l && floor_track_along(t, d).is_some()) {
                continue;
            }
            edges.find_strong(l, self.lines.samples(l), &self.config);
            for (index, track) in self.tracks.iter().enumerate() {
                let Some(track) = track.as_ref().filter(|t| usize::from(t.line) == l) else { continue };
                if let Some((delta, e, point)) = self.floor_displacement(track, line, &edges.strong, d, length, mm_per_px) {
                    let _ = deltas.push(order_key(delta));
                    found.set(index, e, point);
                }
            }
        }
        if deltas.len() < MIN_FLOOR_TRACKS {
            return None;
        }
        let visual = median(&mut deltas)?;
        // The deviations from the median replace the deltas.
        for delta in deltas.iter_mut() {
            *delta = order_key(fabsf(key_value(*delta) - visual));
        }
        let per_track = (1.4826 * median(&mut deltas).unwrap_or(0.0)).max(0.1 * mm_per_px);
        // Median of n: ~1.25 sigma / sqrt(n).
        let visual_var = {
            let s = 1.25 * per_track / sqrtf(deltas.len() as f32);
            s * s
        };
        let odometry_var = {
            let s = self.config.odometry_sigma * length;
            s * s
        };
        let correction = visual * odometry_var / (odometry_var + visual_var);
        self.travel.position[0] += f64::from(correction * d[0]);
        self.travel.position[1] += f64::from(correction * d[1]);
        Some(length + correction)
    }

    /// For a floor track (matched last frame, slope near 1): the
    /// travel (mm, along `d`) beyond the odometry step that its edge in this
    /// frame implies, if it finds one; and that edge's index and level point.
    fn floor_displacement(
        &self,
        track: &Track,
        line: &GtLine,
        edges: &[Edge],
        d: [f32; 2],
        length: f32,
        mm_per_px: f32,
    ) -> Option<(f32, usize, [f32; 2])> {
        let along = floor_track_along(track, d)?;
        // Where it is with slope 1 and the odometry step.
        let predicted = track.predict_apparent(&self.travel, 1.0, None)?;
        let (row, lateral) = self.row_of_level(line, predicted);
        if off_line(lateral, mm_per_px) {
            return None;
        }
        let window = self.config.gate_px + 3.0 * self.config.odometry_sigma * length / mm_per_px;
        let mut best: Option<(usize, f32, f32)> = None;
        for (e, edge) in edges.iter().enumerate().filter(|(_, e)| e.rising == track.rising && fabsf(e.row - row) <= window) {
            if zncc(&track.patch, &edge.patch) < self.config.min_patch_correlation {
                continue;
            }
            let distance = fabsf(edge.row - row);
            if best.is_none_or(|(_, _, b)| distance < b) {
                best = Some((e, edge.row, distance));
            }
        }
        let (e, observed_row, _) = best?;
        let rotation = self.travel.rotation_f32();
        let y_of = |p: [f32; 2]| along_across(rotation.to_world(p), track.axis).0;
        let y_predicted = y_of(self.level_point(line, row));
        let observed = self.level_point(line, observed_row);
        Some(((y_predicted - y_of(observed)) / along, e, observed))
    }
}

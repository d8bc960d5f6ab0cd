//! Tracks: one per feature on a GT line, its locus as observations `(c, y)`
//! (module docs of [`super`]). Each frame a line's edges are associated with
//! its tracks (prediction from the fitted locus, a gate around it, polarity
//! and a patch correlation), unmatched strong edges start tracks, and tracks
//! missed too often end; good ones leave their point in a small map.

use super::edges::{Edge, LineEdges, PATCH};
use super::fits::{robust_line_fit, slope_plausible, FittedHeight, LineFit};
use super::lines::{off_line, GtLine};
use super::travel::{along_across, FloorPoints, Travel};
use super::{Gti, HeightPoint};
use crate::limits::{MAX_EDGES_PER_LINE, MAX_OBSERVATIONS, MAX_TRACKS, MAX_WEAK_EDGES_PER_LINE};
use heapless::Vec;
use crate::kernels::sqrtf;
use libm::{fabsf, roundf};

/// Observation storage unit: 1/4 mm in i16 (tracks span at most +-8 m).
const OBS_UNITS_PER_MM: f32 = 4.0;
const OBS_LIMIT_MM: f32 = (i16::MAX as f32 - 1.0) / OBS_UNITS_PER_MM;
/// Most tracks refitted in a frame: what bounds GTI's work on the M4,
/// whatever the frame shows (each Theil-Sen refit of 16 observations is
/// ~7 k instructions there, so ~0.3 M; a fit refitted every frame for up
/// to [`MAX_TRACKS`] tracks was up to ~1 M). A frame matches up to ~110
/// tracks, so a fit can be a frame or two behind its track; a fit of up
/// to 16 observations moves little with one more. 48, not fewer: at 40,
/// noisy_approach's GTI height dropped to GPA's on one frame.
pub(super) const REFITS_PER_FRAME: usize = 48;
/// Matched KG row storage unit: 1/64 row in u16.
pub(super) const ROW_UNITS: f32 = 64.0;

/// One feature's locus: observations `(c, y)` in 1/4 mm, relative to its
/// first, where c is the distance travelled along `axis` and y the apparent
/// position along it (module docs of [`super`]).
#[derive(Clone, Debug)]
pub(super) struct Track {
    pub id: u32,
    pub line: u8,
    pub rising: bool,
    pub misses: u8,
    pub patch: [u8; PATCH],
    /// Gradient magnitude of the latest edge, 1/16 gray level per sample:
    /// weak tracks give way to strong new edges when a line is full.
    strength: u16,
    /// World direction u (unit) of the locus, and its normal.
    pub axis: [f32; 2],
    /// Robot position (odometry world) at the first observation. f32 is
    /// enough: its rounding shifts all of a track's c equally (slope unchanged).
    origin: [f32; 2],
    /// Apparent position along u at the first observation, mm.
    y0: f32,
    /// Latest apparent position across u (mm) and travel across u then.
    w_last: f32,
    across_last: f32,
    pub observations: Observations,
    /// KG row (1/[`ROW_UNITS`]) of the observation matched this frame (for drawing).
    pub matched_row: Option<u16>,
}

impl Track {
    /// A track for `edge` on line `l`, found at ground point `point` (robot frame).
    fn start(id: u32, l: usize, line: &GtLine, point: [f32; 2], edge: &Edge, travel: &Travel) -> Track {
        let rotation = travel.rotation_f32();
        let q = rotation.to_world(point);
        let axis = rotation.to_world(line.direction);
        let position = travel.position();
        let mut observations = Observations::EMPTY;
        observations.push([0i16, 0i16]);
        Track {
            id,
            line: l as u8,
            rising: edge.rising,
            misses: 0,
            patch: edge.patch,
            strength: encode_strength(edge.strength),
            axis,
            origin: [position[0] as f32, position[1] as f32],
            y0: q[0] * axis[0] + q[1] * axis[1],
            w_last: q[0] * axis[1] - q[1] * axis[0],
            across_last: 0.0,
            observations,
            matched_row: encode_row(edge.row),
        }
    }

    /// Robust line fit of the observations, in mm.
    pub(super) fn fit(&self) -> Option<LineFit> {
        self.observations.fit()
    }

    /// Apparent position (robot frame, mm) of the feature in the current
    /// frame, for slope `slope`, from its latest observation (or on `fit`).
    pub(super) fn predict_apparent(&self, travel: &Travel, slope: f32, fit: Option<&LineFit>) -> Option<[f32; 2]> {
        self.apparent_after(travel, self.travelled(travel), slope, fit)
    }

    /// Distance travelled along and across the track's axis since its first
    /// observation: worked out once a frame where it is needed more than
    /// once (f64 software on the M4).
    fn travelled(&self, travel: &Travel) -> (f32, f32) {
        travel.since(self.origin, self.axis)
    }

    /// [`Track::predict_apparent`] with [`Track::travelled`] given.
    fn apparent_after(&self, travel: &Travel, (c_now, across_now): (f32, f32), slope: f32, fit: Option<&LineFit>) -> Option<[f32; 2]> {
        let [c_last, y_last] = self.observations.last()?;
        let (c_last, y_last) = (f32::from(c_last) / OBS_UNITS_PER_MM, f32::from(y_last) / OBS_UNITS_PER_MM);
        let y = match fit {
            Some(fit) => fit.intercept + fit.slope * c_now,
            None => y_last - slope * (c_now - c_last),
        } + self.y0;
        let w = self.w_last - slope * (across_now - self.across_last);
        let u = self.axis;
        // q = y u + w u_perp, with u_perp = (u_z, -u_x) as in `Travel::since`.
        Some(travel.rotation_f32().to_robot([y * u[0] + w * u[1], y * u[1] - w * u[0]]))
    }

    /// Records a matched edge at ground point `point` (robot frame), `travelled` ([`Track::travelled`]) this frame.
    fn observe(&mut self, travel: &Travel, (c, across): (f32, f32), point: [f32; 2], edge: &Edge) {
        let q = travel.rotation_f32().to_world(point);
        let (along, w) = along_across(q, self.axis);
        let y = along - self.y0;
        if fabsf(c) > OBS_LIMIT_MM || fabsf(y) > OBS_LIMIT_MM {
            self.misses = u8::MAX; // outgrew its storage: end it
            return;
        }
        self.observations.push([roundf(c * OBS_UNITS_PER_MM) as i16, roundf(y * OBS_UNITS_PER_MM) as i16]);
        self.w_last = w;
        self.across_last = across;
        self.misses = 0;
        self.patch = edge.patch;
        self.strength = encode_strength(edge.strength);
        self.matched_row = encode_row(edge.row);
    }
}

/// A track's latest [`MAX_OBSERVATIONS`] observations `(c, y)` (1/4 mm,
/// oldest first) and their robust fit. The fit is kept, not computed on
/// demand: a track is asked for it several times a frame (its gate, the
/// travel correction, the end test, every query of the points), and the
/// Theil-Sen medians are most of GTI's work on the M4. It is refitted at
/// the frame's end within [`REFITS_PER_FRAME`], so until then it may miss
/// the newest observations (`unfitted`).
#[derive(Clone, Debug)]
pub(super) struct Observations {
    values: [[i16; 2]; MAX_OBSERVATIONS],
    len: u8,
    /// The fit's slope, intercept, residual and sxx ([`LineFit`]), in mm;
    /// `fit_inliers` is 0 when there is no fit. Kept apart rather than as an
    /// `Option<LineFit>` (its `usize` and tag) to stay in GTI's RAM budget.
    fit: [f32; 4],
    fit_inliers: u8,
    /// Observations that arrived since the fit was made.
    unfitted: u8,
}

impl Observations {
    const EMPTY: Observations = Observations { values: [[0; 2]; MAX_OBSERVATIONS], len: 0, fit: [0.0; 4], fit_inliers: 0, unfitted: 0 };

    pub(super) fn len(&self) -> usize {
        usize::from(self.len)
    }

    fn as_slice(&self) -> &[[i16; 2]] {
        self.values.get(..self.len()).unwrap_or(&[])
    }

    fn last(&self) -> Option<[i16; 2]> {
        self.as_slice().last().copied()
    }

    /// Appends an observation (dropping the oldest when full); the fit
    /// waits for [`Self::refit`].
    fn push(&mut self, observation: [i16; 2]) {
        let len = self.len();
        if len == MAX_OBSERVATIONS {
            self.values.copy_within(1.., 0);
            if let Some(slot) = self.values.last_mut() {
                *slot = observation;
            }
        } else if let Some(slot) = self.values.get_mut(len) {
            *slot = observation;
            self.len += 1;
        }
        self.unfitted = self.unfitted.saturating_add(1);
    }

    /// How far the fit is behind: [`NEW_TRACK`] when it has none though
    /// two observations could make one (a new track: its gate is widest
    /// without it), else the observations it lacks (all of them at most);
    /// 0 when nothing can be refitted.
    fn staleness(&self) -> usize {
        match (self.unfitted, self.fit_inliers) {
            (0, _) => 0,
            _ if self.len < 2 => 0,
            (_, 0) => NEW_TRACK,
            (unfitted, _) => usize::from(unfitted).min(MAX_OBSERVATIONS),
        }
    }

    /// Fits the observations again.
    fn refit(&mut self) {
        let fit = self.fitted();
        self.fit = fit.map_or([0.0; 4], |f| [f.slope, f.intercept, f.residual, f.sxx]);
        // A fit has at least 2 inliers (and at most MAX_OBSERVATIONS).
        self.fit_inliers = fit.map_or(0, |f| f.inliers as u8);
        self.unfitted = 0;
    }

    fn fit(&self) -> Option<LineFit> {
        let [slope, intercept, residual, sxx] = self.fit;
        (self.fit_inliers > 0).then_some(LineFit { slope, intercept, residual, inliers: usize::from(self.fit_inliers), sxx })
    }

    /// Robust line fit of the observations, in mm.
    fn fitted(&self) -> Option<LineFit> {
        let mut c: Vec<f32, MAX_OBSERVATIONS> = Vec::new();
        let mut y: Vec<f32, MAX_OBSERVATIONS> = Vec::new();
        for &[ci, yi] in self.as_slice() {
            let _ = c.push(f32::from(ci) / OBS_UNITS_PER_MM);
            let _ = y.push(f32::from(yi) / OBS_UNITS_PER_MM);
        }
        robust_line_fit(&c, &y)
    }
}

/// [`Observations::staleness`] of a track without a fit yet: the highest.
const NEW_TRACK: usize = MAX_OBSERVATIONS + 1;
/// [`Observations::staleness`]'s values: 0..=NEW_TRACK.
const STALENESS_LEVELS: usize = NEW_TRACK + 1;

/// Given how many tracks are at each staleness (`behind`), the least
/// staleness a budget of `budget` refits reaches, and how many tracks of
/// that staleness it refits (all of every staleness above it).
fn refit_floor(behind: &[usize; STALENESS_LEVELS], budget: usize) -> (usize, usize) {
    let (mut floor, mut at_floor, mut taken) = (1, 0, 0);
    for staleness in (1..STALENESS_LEVELS).rev() {
        if taken + behind[staleness] >= budget {
            return (staleness, budget - taken);
        }
        taken += behind[staleness];
        (floor, at_floor) = (staleness, behind[staleness]);
    }
    (floor, at_floor)
}

fn encode_row(row: f32) -> Option<u16> {
    (row >= 0.0 && row * ROW_UNITS < f32::from(u16::MAX)).then(|| roundf(row * ROW_UNITS) as u16)
}

fn encode_strength(strength: f32) -> u16 {
    roundf((strength * 16.0).clamp(0.0, f32::from(u16::MAX))) as u16
}

/// Zero-mean normalised cross-correlation of two patches; 0 if either is flat.
pub(super) fn zncc(a: &[u8; PATCH], b: &[u8; PATCH]) -> f32 {
    let mean = |p: &[u8; PATCH]| p.iter().map(|&v| f32::from(v)).sum::<f32>() / PATCH as f32;
    let (ma, mb) = (mean(a), mean(b));
    let (mut sab, mut saa, mut sbb) = (0f32, 0f32, 0f32);
    for (&va, &vb) in a.iter().zip(b) {
        let (da, db) = (f32::from(va) - ma, f32::from(vb) - mb);
        sab += da * db;
        saa += da * da;
        sbb += db * db;
    }
    if saa < 1e-3 || sbb < 1e-3 {
        return 0.0;
    }
    sab / sqrtf(saa * sbb)
}

/// A point of an ended track, in the odometry world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct MapPoint {
    pub world: [f32; 2],
    pub h_mm: f32,
    pub quality: u8,
    pub h_sigma_mm: f32,
}

/// Where a track's feature may be on its line this frame.
struct Gate {
    /// KG rows, fractional.
    low: f32,
    high: f32,
    /// The row an established track's fitted locus predicts.
    predicted: Option<f32>,
    /// The track's [`Track::travelled`] this frame.
    travelled: (f32, f32),
}

impl Gate {
    /// Which of the unused `edges` of the track's polarity inside the gate
    /// matches the track's `patch` best (nearest the prediction, if any,
    /// among equals); None when none correlates well enough.
    fn best(&self, edges: &[Edge], used: &[bool], rising: bool, patch: &[u8; PATCH], min_correlation: f32) -> Option<usize> {
        let mut best: Option<(usize, f32)> = None;
        for (e, edge) in edges.iter().enumerate() {
            if used.get(e).copied().unwrap_or(true) || edge.rising != rising {
                continue;
            }
            if edge.row < self.low || edge.row > self.high {
                continue;
            }
            let correlation = zncc(patch, &edge.patch);
            if correlation < min_correlation {
                continue;
            }
            let half_width = 0.5 * (self.high - self.low);
            let distance_penalty = self.predicted.map_or(0.0, |row| 0.2 * fabsf(edge.row - row) / half_width);
            let score = correlation - distance_penalty;
            if best.is_none_or(|(_, s)| score > s) {
                best = Some((e, score));
            }
        }
        best.map(|(e, _)| e)
    }
}

/// Marks every edge of `edges` at `row` used (the strong and weak sets share edges).
fn claim(edges: &[Edge], used: &mut [bool], row: f32) {
    for (e, other) in edges.iter().enumerate() {
        if fabsf(other.row - row) < 1e-3 {
            if let Some(flag) = used.get_mut(e) {
                *flag = true;
            }
        }
    }
}

impl Gti {
    /// Associates line `l`'s edges with its tracks, oldest tracks first
    /// (their predictions are the tightest); unmatched strong edges start
    /// tracks.
    // Not inlined: the frame that holds the edges must stay small, as the
    // firmware's deepest stack runs through edge finding.
    #[inline(never)]
    pub(super) fn associate_line(&mut self, l: usize, edges: &LineEdges, found: &FloorPoints) {
        let Some(line) = self.lines.line(l).copied() else { return };
        let mut taken = [false; MAX_EDGES_PER_LINE];
        let mut weak_taken = [false; MAX_WEAK_EDGES_PER_LINE];
        let mut order: Vec<(usize, usize), MAX_TRACKS> = Vec::new();
        for (index, track) in self.tracks.iter().enumerate() {
            if let Some(track) = track.as_ref().filter(|t| usize::from(t.line) == l) {
                let _ = order.push((track.observations.len(), index));
            }
        }
        order.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let min_correlation = self.config.min_patch_correlation;
        for &(_, index) in order.iter() {
            let Some(track) = self.tracks.get(index).and_then(|t| t.as_ref()) else { continue };
            let Some(gate) = self.gate(track, &line) else { continue };
            let (rising, patch) = (track.rising, track.patch);
            let (matched, point) = match gate.best(&edges.strong, &taken, rising, &patch, min_correlation) {
                Some(e) => {
                    let edge = edges.strong.get(e).copied();
                    (edge, found.get(index, e).or_else(|| edge.map(|edge| self.level_point(&line, edge.row))))
                }
                // An established track may continue on a weaker edge that no strong edge claimed.
                None if gate.predicted.is_some() => {
                    let edge = gate.best(&edges.weak, &weak_taken, rising, &patch, min_correlation).and_then(|e| edges.weak.get(e)).copied();
                    (edge, edge.map(|edge| self.level_point(&line, edge.row)))
                }
                None => (None, None),
            };
            let Some(track) = self.tracks.get_mut(index).and_then(|t| t.as_mut()) else { continue };
            match matched.zip(point) {
                Some((edge, point)) => {
                    claim(&edges.strong, &mut taken, edge.row);
                    claim(&edges.weak, &mut weak_taken, edge.row);
                    track.observe(&self.travel, gate.travelled, point, &edge);
                }
                None => track.misses = track.misses.saturating_add(1),
            }
        }
        self.start_tracks(l, &line, &edges.strong, &taken);
    }

    /// The gate of a track on its line this frame; None when its locus leaves
    /// the line (the track is then neither matched nor missed).
    fn gate(&self, track: &Track, line: &GtLine) -> Option<Gate> {
        let mm_per_px = self.grid.mm_per_px;
        let fit = if track.observations.len() >= 2 { track.fit() } else { None };
        let widen = self.config.gate_px * (1.0 + 0.5 * f32::from(track.misses));
        let travelled = track.travelled(&self.travel);
        match fit {
            Some(fit) if track.observations.len() >= 3 => {
                let p = track.apparent_after(&self.travel, travelled, -fit.slope, Some(&fit))?;
                let (row, lateral) = self.row_of_level(line, p);
                if off_line(lateral, mm_per_px) {
                    return None;
                }
                let gate = widen + 3.0 * fit.residual / mm_per_px;
                Some(Gate { low: row - gate, high: row + gate, predicted: Some(row), travelled })
            }
            _ => {
                // One or two observations: any slope in the initial range.
                let slope_hint = fit.map(|f| -f.slope).filter(|s| slope_plausible(*s));
                let (low, high) = match slope_hint {
                    Some(s) => (s * 0.85, s * 1.15),
                    None => (0.85, self.config.max_initial_slope),
                };
                let a = track.apparent_after(&self.travel, travelled, low, None)?;
                let b = track.apparent_after(&self.travel, travelled, high, None)?;
                let ((ra, la), (rb, lb)) = (self.row_of_level(line, a), self.row_of_level(line, b));
                if off_line(fabsf(la).min(fabsf(lb)), mm_per_px) {
                    return None;
                }
                Some(Gate { low: ra.min(rb) - widen, high: ra.max(rb) + widen, predicted: None, travelled })
            }
        }
    }

    /// Unmatched `edges` of line `l` start tracks, strongest first, within
    /// the line's share; when it is full, a much stronger edge replaces the
    /// weakest track (floor texture must not crowd out an obstacle's edges).
    fn start_tracks(&mut self, l: usize, line: &GtLine, edges: &[Edge], taken: &[bool]) {
        let share = MAX_TRACKS / self.config.lines;
        // Counted once (a new track in a free slot adds one; a replacement none).
        let mut on_line = self.tracks.iter().flatten().filter(|t| usize::from(t.line) == l).count();
        for (e, edge) in edges.iter().enumerate() {
            if taken.get(e).copied().unwrap_or(true) {
                continue;
            }
            let strength = encode_strength(edge.strength);
            let slot = if on_line < share {
                let free = self.tracks.iter().position(|t| t.is_none());
                on_line += usize::from(free.is_some());
                free
            } else {
                let weakest = self
                    .tracks
                    .iter()
                    .enumerate()
                    .filter_map(|(i, t)| t.as_ref().filter(|t| usize::from(t.line) == l).map(|t| (i, t.strength)))
                    .min_by_key(|&(_, s)| s);
                match weakest {
                    Some((i, s)) if u32::from(strength) * 2 > u32::from(s) * 3 => {
                        self.end_track(i);
                        Some(i)
                    }
                    _ => None,
                }
            };
            // The edges come strongest first and a slot is never freed here
            // but to be refilled: an edge that finds none leaves none for the rest.
            let Some(slot) = slot else { break };
            let point = self.level_point(line, edge.row);
            let track = Track::start(self.next_id, l, line, point, edge, &self.travel);
            self.next_id = self.next_id.wrapping_add(1);
            if let Some(s) = self.tracks.get_mut(slot) {
                *s = Some(track);
            }
        }
    }

    /// Refits the tracks whose fit is furthest behind, at most
    /// [`REFITS_PER_FRAME`]: new tracks first, then by the observations
    /// their fit lacks (a track passed over falls further behind and comes
    /// first next frame), ties in slot order. Two passes: the staleness the
    /// budget reaches down to, then the refits.
    pub(super) fn refit_stalest(&mut self) {
        let mut behind = [0usize; STALENESS_LEVELS];
        for track in self.tracks.iter().flatten() {
            behind[track.observations.staleness()] += 1;
        }
        let (floor, mut at_floor) = refit_floor(&behind, REFITS_PER_FRAME);
        for track in self.tracks.iter_mut().flatten() {
            let staleness = track.observations.staleness();
            if staleness > floor || (staleness == floor && at_floor > 0) {
                if staleness == floor {
                    at_floor -= 1;
                }
                track.observations.refit();
            }
        }
    }

    /// Ends tracks missed too often or with an implausible locus; good ones
    /// become map points.
    pub(super) fn end_lost_tracks(&mut self) {
        for index in 0..MAX_TRACKS {
            let Some(track) = self.tracks.get(index).and_then(|t| t.as_ref()) else { continue };
            let fit = if track.observations.len() >= 3 { track.fit() } else { None };
            let implausible = fit.is_some_and(|f| !slope_plausible(-f.slope));
            if track.misses <= self.config.max_misses && !implausible {
                continue;
            }
            self.end_track(index);
        }
    }

    /// Ends a track; a good one becomes a map point.
    fn end_track(&mut self, index: usize) {
        let Some(slot) = self.tracks.get(index) else { return };
        if let Some(point) = slot.as_ref().and_then(|track| self.estimate(track)) {
            if point.quality >= self.config.good_quality {
                let [x, z] = self.travel.rotation().place(self.travel.position(), [f64::from(point.x_mm), f64::from(point.z_mm)]);
                if self.map.is_full() {
                    self.map.pop_front();
                }
                let _ = self.map.push_back(MapPoint {
                    world: [x as f32, z as f32],
                    h_mm: point.h_mm,
                    quality: point.quality,
                    h_sigma_mm: point.h_sigma_mm,
                });
            }
        }
        if let Some(slot) = self.tracks.get_mut(index) {
            *slot = None;
        }
    }

    /// A track's point in the current robot frame, once it has enough
    /// observations and a plausible slope.
    pub(super) fn estimate(&self, track: &Track) -> Option<HeightPoint> {
        if track.observations.len() < self.config.min_observations {
            return None;
        }
        let fit = track.fit()?;
        let slope = -fit.slope;
        if !slope_plausible(slope) {
            return None;
        }
        let apparent = track.predict_apparent(&self.travel, slope, Some(&fit))?;
        let height = FittedHeight::new(&fit, slope, self.mount_height_mm, self.grid.mm_per_px);
        Some(HeightPoint {
            x_mm: apparent[0] / slope,
            z_mm: apparent[1] / slope,
            h_mm: height.h_mm,
            quality: height.quality,
            h_sigma_mm: height.h_sigma_mm,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_refit_budget_takes_the_stalest_first() {
        let mut behind = [0usize; STALENESS_LEVELS];
        behind[NEW_TRACK] = 3; // no fit yet
        behind[4] = 10;
        behind[2] = 50;
        behind[1] = 20;
        // All of the new tracks and staleness 4, then 7 of the 50 at 2.
        assert_eq!(refit_floor(&behind, 20), (2, 7));
        // The budget ends exactly with a staleness: all of it, none below.
        assert_eq!(refit_floor(&behind, 13), (4, 10));
        // Fewer stale tracks than the budget: every one of them.
        assert_eq!(refit_floor(&behind, 1000), (1, 20));
        assert_eq!(refit_floor(&[0; STALENESS_LEVELS], 48), (1, 0));
    }

    #[test]
    fn a_fit_waits_for_its_refit_and_a_new_track_comes_first() {
        let mut observations = Observations::EMPTY;
        observations.push([0, 0]);
        // One observation: nothing to fit.
        assert_eq!(observations.staleness(), 0);
        observations.push([40, 44]);
        assert!(observations.fit().is_none());
        assert_eq!(observations.staleness(), NEW_TRACK);
        observations.refit();
        let slope = observations.fit().map(|fit| fit.slope);
        assert!(slope.is_some_and(|slope| (slope - 1.1).abs() < 1e-3), "{slope:?}");
        assert_eq!(observations.staleness(), 0);
        observations.push([80, 96]);
        observations.push([120, 150]);
        // The fit is the old one until refitted, two observations behind.
        assert_eq!(observations.staleness(), 2);
        assert_eq!(observations.fit().map(|fit| fit.slope), slope);
    }
}

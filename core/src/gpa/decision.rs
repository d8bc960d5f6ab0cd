//! What a frame's evidence decides beyond itself: the noise level that sets
//! the next frame's thresholds (normalised decision: the pixel threshold
//! follows the measured noise), and the alarm, held through frames whose
//! baseline is too short to see the obstacle again.

use super::config::GpaConfig;
use super::keyframe;
use super::layout::AoiMm;
use super::obstacles::Footprint;
use crate::motion::Motion;

/// Which evidence raised (or held) the last frame's alarm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AlarmSource {
    #[default]
    None,
    /// Cells whose parallax says they stand above the ground.
    Parallax,
    /// Residue that no height explains (moving or deforming things).
    Residue,
    /// Cells that move with the robot (a car ahead): placed where they
    /// meet the ground, nearer than any parallax or residue placed it.
    MovingAlong,
    /// Too short a baseline to decide: the last obstacle, held.
    Held,
}

/// The noise level measured on earlier frames.
pub(super) struct Noise {
    /// Noise sigma (gray levels, x16).
    x16: u32,
    /// Median plain |diff| per pixel (gray levels) on the last frame: the
    /// floor noise puts under every plain SAD.
    floor: u8,
    /// A wide residue above this is residue.
    residue_threshold: u8,
}

impl Noise {
    pub(super) const NONE: Noise = Noise { x16: 0, floor: 0, residue_threshold: 0 };

    /// Before any measurement: the threshold is the configured floor.
    pub(super) fn new(config: &GpaConfig) -> Noise {
        Noise { residue_threshold: config.residue_floor, ..Noise::NONE }
    }

    /// Noise sigma, gray levels.
    pub(super) fn level(&self) -> f64 {
        f64::from(self.x16) / 16.0
    }

    pub(super) fn floor(&self) -> u8 {
        self.floor
    }

    pub(super) fn residue_threshold(&self) -> u8 {
        self.residue_threshold
    }

    /// Noise level from this frame's |diff| at the predicted shift, for the
    /// next frame's residue threshold. The median is robust while obstacles
    /// cover less than half the AOI; for Gaussian noise on both images it is
    /// 0.674 * sqrt(2) * sigma.
    pub(super) fn update(&mut self, histogram: &[u32; 256], config: &GpaConfig) {
        let total: u32 = histogram.iter().sum();
        if total == 0 {
            return;
        }
        let mut seen = 0;
        let mut median = 0u32;
        for (level, &count) in histogram.iter().enumerate() {
            seen += count;
            if seen * 2 >= total {
                median = level as u32;
                break;
            }
        }
        self.floor = median.min(255) as u8;
        // sigma = median / (0.674 * 1.414) ~= median * 1.05
        let sigma = f64::from(median) * 1.05;
        self.x16 = libm::round(sigma * 16.0) as u32;
        let threshold = libm::round(config.noise_factor * sigma) as u32;
        self.residue_threshold = threshold.clamp(u32::from(config.residue_floor), 120) as u8;
    }
}

/// A decided hazard: where it is, and its parallax height (mm, negative
/// for a drop; None for residue, which measures none).
pub(super) type Hazard = (Footprint, Option<i32>);

/// The alarm, with the hazard it holds.
pub(super) struct Alarm {
    source: AlarmSource,
    /// The last decided hazard, held through frames whose baseline is too
    /// short to see it, and the baseline it was found at (mm).
    previous: Option<(Hazard, f64)>,
    /// The shallowest drop (mm) the frame being decided tells from the
    /// ground ([`Self::sees_drops_from`]).
    shallowest_drop_mm: f64,
    /// An obstacle the frame being decided sees just beyond the AOI
    /// ([`Self::sees_beyond_the_aoi`]).
    beyond: Option<Footprint>,
    /// The AOI, where one is given ([`Self::within`]): a held hazard that
    /// the robot's motion (a turn in place) took out of it is not held.
    aoi: Option<AoiMm>,
}

impl Alarm {
    pub(super) const NONE: Alarm = Alarm { source: AlarmSource::None, previous: None, shallowest_drop_mm: 0.0, beyond: None, aoi: None };

    /// No alarm yet, for a detector whose AOI is `aoi`.
    pub(super) const fn within(aoi: AoiMm) -> Alarm {
        Alarm { aoi: Some(aoi), ..Alarm::NONE }
    }

    /// The next frame to decide tells drops from `shallowest_mm` deep on
    /// from the ground (its baseline, against its ground tolerance): a held
    /// drop shallower than that is beyond what it can clear.
    pub(super) fn sees_drops_from(&mut self, shallowest_mm: f64) {
        self.shallowest_drop_mm = shallowest_mm;
    }

    /// The next frame to decide sees an obstacle whose footprint lies just
    /// beyond the AOI's far edge: where it overlaps a held obstacle
    /// sideways, that one is seen again, its footprint a cell or so off
    /// (heights are measured to their hypotheses' spacing), and is not
    /// cleared.
    pub(super) fn sees_beyond_the_aoi(&mut self, beyond: Option<Footprint>) {
        self.beyond = beyond;
    }

    pub(super) fn source(&self) -> AlarmSource {
        self.source
    }

    /// The hazard found this frame was placed by cells that move with the
    /// robot ([`super::obstacles::moving_obstacle`]), not where parallax
    /// or residue put it: so says the source (a held hazard stays held).
    pub(super) fn placed_by_a_thing_moving_along(&mut self) {
        if matches!(self.source, AlarmSource::Parallax | AlarmSource::Residue) {
            self.source = AlarmSource::MovingAlong;
        }
    }

    /// Motion is lost: an obstacle seen before cannot be carried on.
    pub(super) fn forget(&mut self) {
        self.previous = None;
    }

    /// The hazard of this frame from its evidence: parallax first (it
    /// measures height and footprint directly), then residue. A frame at
    /// `baseline_mm` from its keyframe shows too little parallax to clear
    /// an alarm when the baseline is short (under 0.6 of the keyframe
    /// travel: a frame at half of it, the keyframe's own step, must not
    /// clear or hold by a millimetre of estimate noise), nor, for a
    /// height, when it is shorter than the baseline the hazard was found at
    /// (up to the keyframe travel): parallax grows with the baseline, so a
    /// shorter one may show too little of what a longer one just saw (a box
    /// at the AOI's far edge). Residue measures no height: past the short
    /// baselines a frame that does not see it again clears it. A drop's
    /// parallax is smaller still (T*d/(H+d), under T however deep), so a
    /// drop is held through baselines under three
    /// quarters of the travel, and through frames that could not look for
    /// drops at all (`drops_looked_for` false: the attitude change is
    /// unmeasured), else a drop seen on the last frame would
    /// turn into a stale clear, and through frames whose baseline shows its
    /// depth no more than the ground's tolerance does (a drop just past
    /// the limit lags the floor by about that much after a full baseline).
    /// A held hazard is moved by the odometry `step`.
    /// Residue from a held drop's edge on is that drop (its lower level
    /// lags the floor), so it does not replace it.
    ///
    /// A drop's lower level shows its depth only where its texture changes
    /// along the drive, so a frame finds its edge at the first such row past
    /// it, never nearer: a drop found again where the last frame's drop was
    /// (overlapping it sideways) keeps the nearer of the two edges, the last
    /// one moved by the step.
    pub(super) fn decide(
        &mut self,
        parallax: Option<(Footprint, i32)>,
        residue: Option<Footprint>,
        baseline_mm: f64,
        drops_looked_for: bool,
        config: &GpaConfig,
        step: &Motion,
    ) -> Option<Hazard> {
        self.source = match (parallax, residue) {
            (Some(_), _) => AlarmSource::Parallax,
            (None, Some(_)) => AlarmSource::Residue,
            (None, None) => AlarmSource::None,
        };
        let found = parallax.map(|(footprint, height)| (footprint, Some(height))).or(residue.map(|footprint| (footprint, None)));
        // What the motion brought nearer than the AOI's near edge is at that
        // edge, as far as the AOI goes (and the scan, which starts there):
        // held, or kept as a drop's nearer edge.
        let within_aoi = |((footprint, height), found_at): (Hazard, f64)| {
            let near_mm = self.aoi.as_ref().map_or(footprint.near_mm, |aoi| footprint.near_mm.max(libm::round(aoi.near) as i32));
            ((Footprint { near_mm, ..footprint }, height), found_at)
        };
        let moved_previous = self.previous.map(|((footprint, height), found_at)| ((footprint.moved(step), height), found_at)).map(within_aoi);
        let still_in_view = |moved: &(Hazard, f64)| self.aoi.as_ref().is_none_or(|aoi| moved.0 .0.in_aoi(aoi));
        let held = moved_previous
            .filter(still_in_view)
            .filter(|_| self.previous.is_some_and(|previous| self.cannot_clear(&previous, baseline_mm, drops_looked_for, config)));
        let found = found.map(|found| match moved_previous {
            Some((last, _)) => nearer_drop_edge(found, &last),
            None => found,
        });
        // A drop's lower level lags the floor, so it leaves residue from
        // its edge on: residue that starts there (within a cell, what a
        // footprint is good to) is the held drop seen without its depth,
        // not a new hazard.
        let explained_by_held_drop = |found: &Hazard| {
            found.1.is_none() && held.is_some_and(|(drop, _)| is_drop(&drop) && f64::from(found.0.near_mm) >= f64::from(drop.0.near_mm) - config.cell_mm)
        };
        // A baseline too short to clear a hazard is too short to move it
        // away too: what it finds farther, overlapping it sideways, is the
        // held one seen less well (a car ahead's lag shows only over a
        // long baseline).
        let farther_than_held = |found: &Hazard| {
            held.is_some_and(|(held, _)| {
                !is_drop(found) && !is_drop(&held) && found.0.overlaps_sideways(&held.0) && held.0.near_mm < found.0.near_mm
            })
        };
        let (hazard, found_at) = match (found, held) {
            (Some(found), Some((held, _))) if farther_than_held(&found) => {
                self.source = AlarmSource::Held;
                (Some(held), baseline_mm)
            }
            (Some(found), _) if !explained_by_held_drop(&found) => (Some(found), baseline_mm),
            (_, Some((held, found_at))) => {
                self.source = AlarmSource::Held;
                (Some(held), found_at)
            }
            (found, None) => (found, baseline_mm),
        };
        self.previous = hazard.map(|hazard| (hazard, found_at));
        hazard
    }

    /// Whether a frame at `baseline_mm` cannot clear `held`, found at a
    /// baseline of `found_at` (see [`Self::decide`]).
    fn cannot_clear(&self, (held, found_at): &(Hazard, f64), baseline_mm: f64, drops_looked_for: bool, config: &GpaConfig) -> bool {
        let drop = is_drop(held);
        // Parallax grows with the baseline; residue measures no height, and
        // a baseline past the short ones sees it again or not, whatever the
        // one it was found at (a thing that moved away leaves the
        // keyframe's view of it as residue until the keyframe renews: held
        // up to that baseline, it outlasts it by a keyframe).
        let found_at = if held.1.is_some() { found_at.min(keyframe::full_baseline_mm(config)) } else { 0.0 };
        let needed = (if drop { 0.75 } else { 0.6 } * config.keyframe_travel_mm).max(found_at);
        let unseen_depth = held.1.is_some_and(|h| f64::from(-h) < self.shallowest_drop_mm);
        let seen_again = held.1.is_some_and(|h| h > 0) && self.beyond.is_some_and(|beyond| beyond.overlaps_sideways(&held.0));
        baseline_mm < needed || (drop && (!drops_looked_for || unseen_depth)) || seen_again
    }
}

fn is_drop(hazard: &Hazard) -> bool {
    hazard.1.is_some_and(|h| h < 0)
}

/// `found` with the nearer of its edge and the `last` drop's (moved by the
/// step) when both are drops overlapping sideways: a frame finds a drop's
/// edge at the first textured row past it, never nearer.
fn nearer_drop_edge(found: Hazard, last: &Hazard) -> Hazard {
    let (footprint, height) = found;
    if is_drop(&found) && is_drop(last) && footprint.overlaps_sideways(&last.0) {
        (Footprint { near_mm: footprint.near_mm.min(last.0.near_mm), ..footprint }, height)
    } else {
        found
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STEP: Motion = Motion { tx_mm: 0.0, tz_mm: 50.0, dyaw_deg: 0.0 };

    fn at(near_mm: i32) -> Footprint {
        Footprint { near_mm, left_mm: -100, right_mm: 100 }
    }

    /// A hazard that cells moving along placed says so; a held one stays
    /// held, and the next frame's source is its own again.
    #[test]
    fn a_hazard_placed_by_a_thing_moving_along_says_so() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(1000), 300)), None, 100.0, true, &config, &STEP);
        alarm.placed_by_a_thing_moving_along();
        assert_eq!(alarm.source(), AlarmSource::MovingAlong);
        alarm.decide(None, Some(at(900)), 100.0, true, &config, &STEP);
        assert_eq!(alarm.source(), AlarmSource::Residue);
        alarm.placed_by_a_thing_moving_along();
        assert_eq!(alarm.source(), AlarmSource::MovingAlong);
        // Too short a baseline to clear it: held, whatever placed it.
        alarm.decide(None, None, 10.0, true, &config, &STEP);
        assert_eq!(alarm.source(), AlarmSource::Held);
        alarm.placed_by_a_thing_moving_along();
        assert_eq!(alarm.source(), AlarmSource::Held);
    }

    /// A drop seen, then a full baseline that could not look for drops:
    /// held (moved by the step), not a stale clear; a frame that looked and
    /// saw nothing clears it.
    #[test]
    fn a_drop_is_held_through_a_frame_blind_to_drops() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        let seen = alarm.decide(Some((at(1000), -150)), None, 100.0, true, &config, &STEP);
        assert_eq!(seen, Some((at(1000), Some(-150))));
        let blind = alarm.decide(None, None, 100.0, false, &config, &STEP);
        assert_eq!(blind, Some((at(950), Some(-150))));
        assert_eq!(alarm.source(), AlarmSource::Held);
        assert_eq!(alarm.decide(None, None, 100.0, true, &config, &STEP), None);
    }

    /// A drop held through a frame blind to drops explains the residue its
    /// lower level leaves from its edge on: the drop, with its depth, is
    /// reported; residue nearer than its edge is a hazard of its own.
    #[test]
    fn residue_beyond_a_held_drop_is_the_drop() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(1000), -80)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(None, Some(at(960)), 150.0, false, &config, &STEP), Some((at(950), Some(-80))));
        assert_eq!(alarm.source(), AlarmSource::Held);
        assert_eq!(alarm.decide(None, Some(at(700)), 150.0, false, &config, &STEP), Some((at(700), None)));
        assert_eq!(alarm.source(), AlarmSource::Residue);
    }

    /// A shallow drop is held through a full baseline whose ground
    /// tolerance swallows its lag (the frame sees drops from 36 mm on),
    /// and cleared by a longer one that shows it (from 23 mm on).
    #[test]
    fn a_shallow_drop_is_held_through_a_baseline_too_short_for_its_depth() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(1000), -27)), None, 150.0, true, &config, &STEP);
        alarm.sees_drops_from(36.0);
        assert_eq!(alarm.decide(None, None, 100.0, true, &config, &STEP), Some((at(950), Some(-27))));
        assert_eq!(alarm.source(), AlarmSource::Held);
        alarm.sees_drops_from(23.0);
        assert_eq!(alarm.decide(None, None, 150.0, true, &config, &STEP), None);
        // A deeper one is cleared at the full baseline.
        alarm.decide(Some((at(1000), -80)), None, 150.0, true, &config, &STEP);
        alarm.sees_drops_from(36.0);
        assert_eq!(alarm.decide(None, None, 100.0, true, &config, &STEP), None);
    }

    /// A drop found again beyond the last frame's edge (moved by the step)
    /// keeps that edge; one beside it, or nearer, keeps its own.
    #[test]
    fn a_drop_found_again_keeps_the_nearer_edge() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(1000), -30)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(Some((at(1010), -32)), None, 100.0, true, &config, &STEP), Some((at(950), Some(-32))));
        assert_eq!(alarm.decide(Some((at(880), -32)), None, 100.0, true, &config, &STEP), Some((at(880), Some(-32))));
        let beside = Footprint { near_mm: 900, left_mm: 200, right_mm: 300 };
        assert_eq!(alarm.decide(Some((beside, -32)), None, 100.0, true, &config, &STEP), Some((beside, Some(-32))));
        // An obstacle standing up is where it is found.
        alarm.decide(Some((at(1000), -30)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(Some((at(1000), 80)), None, 100.0, true, &config, &STEP), Some((at(1000), Some(80))));
    }

    /// A drop found again after the motion brought the last one's edge
    /// nearer than the AOI's near edge keeps that edge at the near edge,
    /// as a held one does: a footprint is never reported outside the AOI.
    #[test]
    fn a_drop_edge_kept_from_the_last_frame_stays_within_the_aoi() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::within(AoiMm { near: 300.0, far: 1000.0, half_width: 200.0 });
        alarm.decide(Some((at(320), -60)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(Some((at(400), -60)), None, 100.0, true, &config, &STEP), Some((at(300), Some(-60))));
    }

    /// A robot turning in place (no baseline: nothing can be cleared) holds
    /// what it found where it now is: turned with it, and let go once the
    /// turn has taken it out of the AOI.
    #[test]
    fn a_turn_in_place_carries_the_held_obstacle_out_of_the_aoi() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::within(AoiMm { near: 300.0, far: 1000.0, half_width: 200.0 });
        let ahead = Footprint { near_mm: 800, left_mm: 100, right_mm: 180 };
        alarm.decide(Some((ahead, 80)), None, 100.0, true, &config, &STEP);
        let turn = Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 5.0 };
        let (turned, _) = alarm.decide(None, None, 0.0, true, &config, &turn).expect("held through the turn's first step");
        assert_eq!(alarm.source(), AlarmSource::Held);
        assert!(turned.near_mm < 800 && turned.left_mm != 100, "turned with the robot: {turned:?}");
        for _ in 0..4 {
            alarm.decide(None, None, 0.0, true, &config, &turn);
        }
        assert_eq!(alarm.decide(None, None, 0.0, true, &config, &turn), None, "20 degrees on, it is out of the AOI");
    }

    /// A baseline too short to clear an obstacle does not move it away: a
    /// farther one it finds across it leaves the held one (moved by the
    /// step); one beside it, or nearer, is what it found.
    #[test]
    fn a_short_baseline_does_not_move_an_obstacle_away() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(800), 120)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(Some((at(1100), 90)), None, 40.0, true, &config, &STEP), Some((at(750), Some(120))));
        assert_eq!(alarm.source(), AlarmSource::Held);
        let beside = Footprint { near_mm: 1100, left_mm: 200, right_mm: 300 };
        assert_eq!(alarm.decide(Some((beside, 90)), None, 40.0, true, &config, &STEP), Some((beside, Some(90))));
        alarm.decide(Some((at(800), 120)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(Some((at(700), 90)), None, 40.0, true, &config, &STEP), Some((at(700), Some(90))));
        // A full baseline measures it again, wherever it finds it.
        alarm.decide(Some((at(800), 120)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(Some((at(1100), 90)), None, 100.0, true, &config, &STEP), Some((at(1100), Some(90))));
    }

    /// An obstacle standing up is seen whatever the attitude: blindness to
    /// drops does not hold it past a full baseline; a short one does.
    #[test]
    fn an_obstacle_is_held_only_through_short_baselines() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(800), 120)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(None, None, 40.0, false, &config, &STEP), Some((at(750), Some(120))));
        assert_eq!(alarm.decide(None, None, 100.0, false, &config, &STEP), None);
    }

    /// An obstacle found at a full baseline is held through a longer-than-
    /// short one that shows less of its parallax, and cleared by a full one;
    /// one found at a short baseline is cleared from 0.6 of the travel.
    #[test]
    fn an_obstacle_is_cleared_only_by_a_baseline_as_long_as_it_was_found_at() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(1300), 80)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(None, None, 80.0, true, &config, &STEP), Some((at(1250), Some(80))));
        assert_eq!(alarm.decide(None, None, 100.0, true, &config, &STEP), None);
        alarm.decide(Some((at(1300), 80)), None, 40.0, true, &config, &STEP);
        assert_eq!(alarm.decide(None, None, 60.0, true, &config, &STEP), None);
    }

    /// Residue measures no height: found at a full baseline, it is held
    /// through a short one and cleared from 0.6 of the travel, where a
    /// height found at that baseline is held until a full one (a thing
    /// that rolled away leaves the keyframe's view of it as residue: held
    /// to a full baseline, that ghost outlasted the keyframe).
    #[test]
    fn residue_is_held_only_through_short_baselines() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(None, Some(at(900)), 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(None, None, 40.0, true, &config, &STEP), Some((at(850), None)));
        assert_eq!(alarm.source(), AlarmSource::Held);
        assert_eq!(alarm.decide(None, None, 80.0, true, &config, &STEP), None);
        alarm.decide(Some((at(900), 80)), None, 100.0, true, &config, &STEP);
        assert_eq!(alarm.decide(None, None, 80.0, true, &config, &STEP), Some((at(850), Some(80))));
    }

    /// An obstacle found at a full baseline, then seen again only a little
    /// beyond the AOI's far edge by a full baseline's footprint, is held;
    /// one that nothing beyond the AOI overlaps sideways is cleared.
    #[test]
    fn an_obstacle_seen_again_just_beyond_the_aoi_is_held() {
        let config = GpaConfig::default();
        let mut alarm = Alarm::NONE;
        alarm.decide(Some((at(1390), 80)), None, 100.0, true, &config, &STEP);
        alarm.sees_beyond_the_aoi(Some(Footprint { near_mm: 1440, left_mm: 50, right_mm: 150 }));
        assert_eq!(alarm.decide(None, None, 100.0, true, &config, &STEP), Some((at(1340), Some(80))));
        assert_eq!(alarm.source(), AlarmSource::Held);
        alarm.sees_beyond_the_aoi(Some(Footprint { near_mm: 1440, left_mm: 150, right_mm: 250 }));
        assert_eq!(alarm.decide(None, None, 100.0, true, &config, &STEP), None);
    }
}

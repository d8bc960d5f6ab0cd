//! Motion estimation: the camera's whole motion over the ground from the
//! keyframe to now (Tx, Tz, yaw, and the body's pitch and roll change),
//! and the keyframe body's attitude relative to the ground in view,
//! measured between the two KG images. Odometry, the IMU and the nominal
//! attitude are priors.
//!
//! 1. [`coarse`](super::coarse): the planar motion on both images
//!    box-averaged to cells (the current one levelled by the prior's
//!    attitude change), every yaw and translation within the prior's
//!    reach scored. Skipped when the prior's 3 sigma lies within the
//!    alignment's own reach ([`within_alignment_reach`]): with odometry.
//! 2. [`direct`](super::direct): Gauss-Newton on the gray levels, coarse
//!    to fine, robust to what is not ground; on its coarse levels only
//!    the nearest rows take part, so the surface under the robot decides
//!    before a curb top or a lower level far ahead can. After step 1, also
//!    from starts either side of its own along the robot's axis, the best
//!    basin kept ([`best_of_ladder`]).
//! 3. Trust ([`trusted`]): enough of the pixels agree, the translation is
//!    pinned, and the residuals are not several times this camera's
//!    typical ones ([`TypicalMisregistration`]). Else the nearest rows
//!    alone, then the prior's own start, then the best translation on the
//!    top level between standing still and the prior with no planar prior
//!    (wheels that slip).
//! 4. The nearest surface: the nearest rows' own fit replaces the whole
//!    view's when it explains them clearly better.
//! 5. A far level ([`Direct::lower_level`]): every block-row edge tried
//!    with the far view on a plane of its own, below the ground (a drop)
//!    or above it (a box or a curb beyond the AOI), which would otherwise
//!    tilt the ground's fit.
//!
//! The keyframe's attitude is two of the unknowns. Its prior when the
//! keyframe is taken is [`GroundAttitude`]: the last keyframe's attitude
//! plus the change measured since, corrected by every alignment's own
//! measurement of it against the ground.
//!
//! All of it in `f32` (the M4 has a single-precision FPU).

use super::coarse::{cell_mm_on, fine_cell_mm, yaw_step, CoarseSearch, Widen};
use super::hazard_mask::MovedMask;
use super::direct::{self, Alignment, Direct, Geometry, Images, Schedule};
use super::homography::{Params, SinCosMemo};
use super::pyramid::LEVELS;
use super::warp::Coverage;
use super::profile::Profiler;
use crate::grid::KgGrid;
use crate::kernels;
use crate::motion::{Attitude, GroundMotion, Motion};

/// A trusted measurement: the fewest pixels its Tukey weights keep, as a
/// share of those that sampled the keyframe (obstacles and shadows that
/// moved may take the rest)...
const MIN_INLIER_SHARE: f32 = 0.3;
/// ...how far off the typical pixel may still lie (the residuals' scale
/// over the texture's gradient, grid pixels): an alignment into a wrong
/// minimum leaves the texture unmatched, about a pixel or more...
const MAX_MISREGISTRATION_PX: f32 = 1.0;
/// Once the camera's typical misregistration is known, at most this many
/// times it (never below [`MIN_MISREGISTRATION_PX`])...
const TYPICAL_MISREGISTRATION_FACTOR: f32 = 2.5;
const MIN_MISREGISTRATION_PX: f32 = 0.2;
/// How fast the typical misregistration follows the trusted alignments.
const TYPICAL_MISREGISTRATION_RATE: f32 = 0.2;
/// ...and the largest sigma of its translation, grid pixels.
const MAX_TRANSLATION_SIGMA_PX: f32 = 1.0;
/// The nearest rows' own fit replaces the whole view's when it lowers
/// their misfit (Tukey's loss, a full miss 1) by this much, and by this
/// share of their pixels: a fit of seven unknowns lowers it by a few by
/// chance; a far surface that bent the whole view's fit, by tens.
const NEAR_SURFACE_MISFIT: f32 = 6.0;
const NEAR_SURFACE_SHARE: f32 = 0.03;
/// How far the alignment reaches from its start: top-level pixels.
const ALIGNMENT_REACH_TOP_PX: f32 = 1.5;
/// Starts either side of the coarse search's, along the robot's axis, two
/// alignment reaches apart (see [`best_of_ladder`]).
const LADDER_RUNGS: i32 = 3;
/// A lower level replaces the ground alone when it lowers the chi-square
/// by this much (in the pixels' residual variance): its depth and its edge
/// buy a few by chance; a drop the ground alone bent to, tens.
const LOWER_LEVEL_CHI2: f32 = 3.0;
/// An attitude prior whose 3 sigma is within this needs no search (degrees).
const ATTITUDE_WITHIN_REACH_DEG: f32 = 0.3;
/// The planar motion's sigmas from the standing-still start: no prior (mm, mm, deg).
const UNMOORED_SIGMA: [f32; 3] = [10_000.0, 10_000.0, 90.0];
/// The coarsest level the nearest rows' own fit starts from.
const NEAREST_SURFACE_TOP_LEVEL: usize = 1;
/// The coarse levels that see only the nearest rows: the top two.
const NEAR_FROM_LEVEL: usize = LEVELS - 2;

fn params(motion: &GroundMotion) -> Params {
    [motion.planar.tx_mm as f32, motion.planar.tz_mm as f32, motion.planar.dyaw_deg as f32, motion.attitude.pitch_deg as f32, motion.attitude.roll_deg as f32]
}

fn motion(p: &[f32]) -> GroundMotion {
    GroundMotion {
        planar: Motion { tx_mm: f64::from(p[0]), tz_mm: f64::from(p[1]), dyaw_deg: f64::from(p[2]) },
        attitude: Attitude { pitch_deg: f64::from(p[3]), roll_deg: f64::from(p[4]) },
    }
}

/// The estimate: the motion keyframe -> now, and what is known of the
/// keyframe body's attitude after it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Estimate {
    pub(super) motion: GroundMotion,
    pub(super) keyframe_attitude: KeyframeAttitude,
    /// One sigma of the motion's attitude change (pitch, roll, degrees).
    pub(super) change_sigma: [f32; 2],
    /// The brightness of the current frame over the keyframe's (auto exposure).
    pub(super) gain: f32,
}

/// The keyframe body's attitude relative to the ground in view (pitch,
/// roll, degrees; see [`crate::motion::GroundMap`]) and how well it is
/// known (one sigma each). Each comparison with the keyframe adds to what
/// is known of it; a new keyframe starts from nominal again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct KeyframeAttitude {
    pub(super) deg: [f32; 2],
    pub(super) sigma_deg: [f32; 2],
}

impl KeyframeAttitude {
    /// A keyframe's attitude before any comparison: the nominal one, with
    /// room for a mount a degree off and a body that sits off it.
    pub(super) const NOMINAL: KeyframeAttitude = KeyframeAttitude { deg: [0.0, 0.0], sigma_deg: [0.3, 0.3] };

    pub(super) fn attitude(&self) -> Attitude {
        Attitude { pitch_deg: f64::from(self.deg[0]), roll_deg: f64::from(self.deg[1]) }
    }
}

/// How far the ground in view may turn under the body between two
/// keyframes beyond what the measured change says (degrees, one sigma):
/// a road's grade or camber changing, the change's own model error.
const GROUND_ATTITUDE_WANDER_DEG: f32 = 0.1;

/// The body's attitude relative to the ground in view, frame by frame: the
/// keyframe's attitude as the last alignment measured it (its prior
/// included) plus the change since, which the alignment pins far better
/// (a few hundredths of a degree) than a single pair pins the absolute
/// attitude (a few tenths). Each keyframe starts from it, so a body that
/// rocks from frame to frame is followed; every alignment also measures
/// the keyframe's attitude against the ground itself, so errors of the
/// changes do not add up without limit, and the prior's sigma never
/// exceeds [`KeyframeAttitude::NOMINAL`]'s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct GroundAttitude {
    now: KeyframeAttitude,
}

impl GroundAttitude {
    pub(super) const NOMINAL: GroundAttitude = GroundAttitude { now: KeyframeAttitude::NOMINAL };

    /// A frame whose attitude was measured: the keyframe's and the change
    /// since, within `bound_deg` of nominal (the body's largest attitude).
    pub(super) fn measured(&mut self, estimate: &Estimate, bound_deg: f32) {
        let change = [estimate.motion.attitude.pitch_deg as f32, estimate.motion.attitude.roll_deg as f32];
        let nominal = KeyframeAttitude::NOMINAL.sigma_deg;
        for k in 0..2 {
            let deg = estimate.keyframe_attitude.deg[k] + change[k];
            self.now.deg[k] = deg.clamp(-bound_deg, bound_deg);
            self.now.sigma_deg[k] = crate::kernels::hypotf(estimate.keyframe_attitude.sigma_deg[k], estimate.change_sigma[k]).min(nominal[k]);
        }
    }

    /// A frame whose attitude was not measured: nothing is known of it,
    /// and the next keyframe starts from nominal (never from a stale value).
    pub(super) fn unmeasured(&mut self) {
        self.now = KeyframeAttitude::NOMINAL;
    }

    /// What a keyframe taken now starts from.
    pub(super) fn keyframe(&self) -> KeyframeAttitude {
        let wander = |sigma: f32| crate::kernels::hypotf(sigma, GROUND_ATTITUDE_WANDER_DEG).min(KeyframeAttitude::NOMINAL.sigma_deg[0]);
        KeyframeAttitude { deg: self.now.deg, sigma_deg: self.now.sigma_deg.map(wander) }
    }
}

/// What the estimate starts from: a motion and how far off it may be
/// (one sigma per parameter: mm, mm, deg, deg, deg).
#[derive(Clone, Copy, Debug)]
pub(super) struct Prior {
    pub(super) motion: GroundMotion,
    pub(super) sigma: [f64; 5],
}

impl Prior {
    /// Whether its 3 sigma lies within the alignment's own reach.
    pub(super) fn within_alignment_reach(&self, grid: &KgGrid) -> bool {
        within_alignment_reach(grid, &Start::of(self).sigma)
    }
}

/// The prior in the estimate's units.
struct Start {
    p: Params,
    sigma: Params,
}

impl Start {
    fn of(prior: &Prior) -> Start {
        Start { p: params(&prior.motion), sigma: prior.sigma.map(|s| s as f32) }
    }
}

/// The two images and their geometry, for one frame's estimate.
pub(super) struct Scene<'a> {
    pub(super) keyframe: &'a [u8],
    pub(super) current: &'a [u8],
    pub(super) grid: &'a KgGrid,
    pub(super) coverage: &'a Coverage,
    pub(super) height_mm: f64,
    /// What is known of the keyframe body's attitude so far.
    pub(super) keyframe_attitude: KeyframeAttitude,
    /// This camera's typical misregistration so far.
    pub(super) typical: TypicalMisregistration,
    /// Where the last frame saw hazards, if it was the one before.
    pub(super) hazards: Option<MovedMask<'a>>,
    pub(super) sin_cos: SinCosMemo,
}

impl Scene<'_> {
    pub(super) fn images(&self) -> Images<'_> {
        Images {
            keyframe: self.keyframe,
            current: self.current,
            grid: self.grid,
            seen: self.coverage.current_rows(self.grid.height()),
            height_mm: self.height_mm as f32,
            hazards: self.hazards,
            sin_cos: &self.sin_cos,
        }
    }
}

/// One frame's alignments (step 2), each kept only if trusted (step 3):
/// the whole view, or the nearest rows alone, from a start under a prior.
struct Attempts<'a> {
    images: &'a Images<'a>,
    grid: &'a KgGrid,
    typical: Option<f32>,
    /// The keyframe attitude every start begins from.
    keyframe: [f32; 2],
    whole: Schedule,
    near: Schedule,
    /// A start the whole view was aligned from already this frame and
    /// not trusted (see [`first_trusted`]).
    untrusted: Option<Params>,
}

// `whole` and `near` are inlined: a frame of theirs would stand between
// the estimate and the alignment's deep calls, the stack's high-water mark.
impl Attempts<'_> {
    fn start(&self, p: &Params) -> Geometry {
        [p[0], p[1], p[2], p[3], p[4], self.keyframe[0], self.keyframe[1]]
    }

    /// The whole view from `p`; the flag says it was the whole view.
    #[inline(always)]
    fn whole(&self, direct: &mut Direct, p: &Params, prior: &direct::Prior) -> Option<(Alignment, bool)> {
        direct.align(self.images, prior, self.start(p), self.whole).filter(|a| trusted(a, self.grid, self.typical)).map(|a| (a, true))
    }

    /// The nearest rows alone from `p`: the ground is the surface under
    /// the robot (a curb top or a lower level may fill the far view).
    #[inline(always)]
    fn near(&self, direct: &mut Direct, p: &Params, prior: &direct::Prior) -> Option<(Alignment, bool)> {
        direct.align(self.images, prior, self.start(p), self.near).filter(|a| trusted(a, self.grid, self.typical)).map(|a| (a, false))
    }
}

/// The whole view from step 1's start and from starts either side of it
/// along the robot's axis, two alignment reaches apart (so that their
/// basins tile [`LADDER_RUNGS`] reaches either side): the trusted one
/// whose typical pixel lies least far off. The coarse cells rank a
/// texture that repeats about a step (lane dashes) or blurs between
/// frames no better than its period: on a Duckiebot's lane at 1 frame/s
/// they started 1 -> 2 at tz 8 mm (the whole view 1.19 px off there, 1.0
/// allowed, and the nearest rows alone then trusted at tz 7.5, 0.96 px),
/// where the whole view from the step (tz 75) leaves 0.78 px. The finest
/// level's misregistration tells the basins apart where the cells cannot.
/// A start whose alignment is already within [`MIN_MISREGISTRATION_PX`]
/// ends the ladder (a rendering's floor, 0.05 px). A rung on the start
/// `attempts.untrusted` is not aligned again (see [`first_trusted`]).
fn best_of_ladder(direct: &mut Direct, attempts: &Attempts, start: &Params, prior: &direct::Prior) -> Option<(Alignment, bool)> {
    let step_mm = 2.0 * ALIGNMENT_REACH_TOP_PX * super::pyramid::SCALES[LEVELS - 1] as f32 * attempts.grid.mm_per_px as f32;
    let off = |a: &Alignment| a.scale / a.texture;
    let mut best: Option<(Alignment, bool)> = None;
    for k in 0..=2 * LADDER_RUNGS {
        // 0, 1, -1, 2, -2, ...: the nearest to the coarse start first, which a tie keeps.
        let rung = if k % 2 == 1 { (k + 1) / 2 } else { -(k / 2) };
        let mut p = *start;
        p[1] += rung as f32 * step_mm;
        if attempts.untrusted == Some(p) {
            continue;
        }
        if let Some(found) = attempts.whole(direct, &p, prior) {
            if best.as_ref().is_none_or(|(b, _)| off(&found.0) < off(b)) {
                best = Some(found);
            }
        }
        // As close as the trust test tells apart: no other basin can do better.
        if best.as_ref().is_some_and(|(b, _)| off(b) <= MIN_MISREGISTRATION_PX) {
            break;
        }
    }
    best
}

/// The first trusted alignment, in this order: the whole view from step
/// 1's start (the best of its ladder when step 1 searched, `ladder`), from
/// the prior's, and from the best attitude change on the top level (a body
/// that pitched beyond the alignment's reach); the nearest rows alone from
/// the first two; the whole view and the nearest
/// rows again without the pixels where the last frame found hazards (an
/// obstacle that holds most of the contrast); last, the best translation
/// between standing still and the prior, with no prior on the planar
/// motion (standing still is the hypothesis that the odometry is wrong:
/// wheels that slip). None when none can be trusted.
///
/// `attempts.untrusted`: a start the whole view was aligned from already
/// this frame and not trusted (the prediction's,
/// [`Unmeasured::Untrusted`]). Before the hazards are left out, the whole
/// view is aligned from no start twice: on the same pixels an alignment
/// ends the same (it depends on nothing else), and a fallback frame would
/// pay for it twice.
fn first_trusted(direct: &mut Direct, attempts: &Attempts, start: &Params, prior_start: &Start, prior: &direct::Prior, ladder: bool) -> Option<(Alignment, bool)> {
    let untrusted = attempts.untrusted;
    let five = |g: Geometry| -> Params { [g[0], g[1], g[2], g[3], g[4]] };
    let other_start = (prior_start.p != *start).then_some(prior_start.p);
    let attitude_reach = 3.0 * prior_start.sigma[3].max(prior_start.sigma[4]);
    let mut aligned = match ladder {
        true => best_of_ladder(direct, attempts, start, prior),
        false => (untrusted != Some(*start)).then(|| attempts.whole(direct, start, prior)).flatten(),
    };
    if aligned.is_none() {
        if let Some(p) = other_start.filter(|&p| untrusted != Some(p)) {
            aligned = attempts.whole(direct, &p, prior);
        }
    }
    if aligned.is_none() && attitude_reach > ATTITUDE_WITHIN_REACH_DEG {
        // A search that finds no better attitude hands back a start the
        // whole view was aligned from already.
        let searched = five(direct.search_attitude(attempts.images, &attempts.start(start), attitude_reach));
        if searched != *start && Some(searched) != other_start && Some(searched) != untrusted {
            aligned = attempts.whole(direct, &searched, prior);
        }
    }
    if aligned.is_none() {
        aligned = attempts.near(direct, start, prior);
    }
    if aligned.is_none() {
        if let Some(p) = other_start {
            aligned = attempts.near(direct, &p, prior);
        }
    }
    if aligned.is_none() && direct.leave_out_hazards(attempts.images) {
        aligned = attempts.whole(direct, start, prior).or_else(|| attempts.near(direct, start, prior));
    }
    if aligned.is_none() {
        let mut unmoored = *prior;
        unmoored.sigma[..3].copy_from_slice(&UNMOORED_SIGMA);
        let searched = five(direct.search_translation(attempts.images, &attempts.start(&[0.0; 5]), &attempts.start(&prior_start.p)));
        aligned = attempts.whole(direct, &searched, &unmoored).or_else(|| attempts.near(direct, &searched, &unmoored));
    }
    aligned
}

/// Where an estimate's alignment starts ([`Estimator::estimate_from`]).
enum StartFrom {
    /// The prediction alone ([`Estimator::estimate_from_prediction`]).
    Prediction,
    /// Step 1's start ([`Estimator::estimate`]).
    Searched { start: Params, prediction_untrusted: bool },
}

/// Why an estimate measured nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Unmeasured {
    /// No alignment was trusted.
    Untrusted,
    /// The prediction's alignment was trusted, but it walked beyond the
    /// alignment's reach of the prediction, into another basin.
    WalkedAway,
}

/// Steps 2 and 3 and their memory (step 1 has its own, [`CoarseSearch`]:
/// the two are never live at once).
pub(super) struct Estimator {
    direct: Direct,
    /// The typical misregistration after this estimate (for the next frame's [`Scene`]).
    pub(super) typical: TypicalMisregistration,
    /// Its parts' ticks (the `estimate_*` fields).
    pub(super) profiler: Profiler,
}

impl Estimator {
    pub(super) const EMPTY: Estimator = Estimator { direct: Direct::EMPTY, typical: TypicalMisregistration(None), profiler: Profiler::OFF };

    /// The motion keyframe -> now from `start`, step 1's (see
    /// [`Self::coarse_start`]), or None when no start leads to a
    /// measurement that can be trusted. `prediction_untrusted`: this
    /// frame's [`Self::estimate_from_prediction`] ended
    /// [`Unmeasured::Untrusted`], so its start is not aligned from again.
    pub(super) fn estimate(&mut self, scene: &Scene, prior: &Prior, start: Params, prediction_untrusted: bool) -> Option<Estimate> {
        self.estimate_from(scene, prior, StartFrom::Searched { start, prediction_untrusted }).ok()
    }

    /// The motion keyframe -> now from the prior's prediction alone,
    /// without step 1: the whole view aligned from it, kept only when it
    /// is trusted and ends within the alignment's reach of its start (so
    /// that it settled in the basin the prediction lies in, not one it
    /// walked to). None otherwise: step 1 then searches the prior's reach.
    /// A prior reaching beyond the alignment is wide for the frames where
    /// the motion jumps (a turn begins, the robot stops); on the others
    /// the prediction is within a few millimetres, and this costs one
    /// alignment instead of the search.
    pub(super) fn estimate_from_prediction(&mut self, scene: &Scene, prior: &Prior) -> Result<Estimate, Unmeasured> {
        self.estimate_from(scene, prior, StartFrom::Prediction)
    }

    /// [`Self::estimate`] from step 1's start, or from the prediction alone.
    fn estimate_from(&mut self, scene: &Scene, prior: &Prior, from: StartFrom) -> Result<Estimate, Unmeasured> {
        self.typical = scene.typical;
        let since = self.profiler.now();
        let images = scene.images();
        self.direct.prepare(&images);
        self.profiler.charge(since, |p| &mut p.estimate_pyramids);
        let prior_start = Start::of(prior);
        let keyframe = scene.keyframe_attitude;
        let seven = |p: &Params, keyframe: [f32; 2]| -> Geometry { [p[0], p[1], p[2], p[3], p[4], keyframe[0], keyframe[1]] };
        let prior7 = direct::Prior { mean: seven(&prior_start.p, keyframe.deg), sigma: seven(&prior_start.sigma, keyframe.sigma_deg) };
        let schedule = Schedule { near_row: near_row(scene), near_from_level: NEAR_FROM_LEVEL, top_level: LEVELS - 1 };
        let since = self.profiler.now();
        let attempts = Attempts {
            images: &images,
            grid: scene.grid,
            typical: scene.typical.0,
            keyframe: keyframe.deg,
            whole: schedule,
            near: Schedule { near_from_level: 0, ..schedule },
            untrusted: match from {
                StartFrom::Searched { prediction_untrusted: true, .. } => Some(prior_start.p),
                _ => None,
            },
        };
        let aligned = match from {
            StartFrom::Searched { start, .. } => {
                // Step 1 searched when the prior reaches beyond the alignment.
                let ladder = !within_alignment_reach(scene.grid, &prior_start.sigma);
                first_trusted(&mut self.direct, &attempts, &start, &prior_start, &prior7, ladder).ok_or(Unmeasured::Untrusted)
            }
            StartFrom::Prediction => match attempts.whole(&mut self.direct, &prior_start.p, &prior7) {
                Some((a, whole)) if within_reach_of(scene.grid, &prior_start.p, &a.p) => Ok((a, whole)),
                Some(_) => Err(Unmeasured::WalkedAway),
                None => Err(Unmeasured::Untrusted),
            },
        };
        self.profiler.charge(since, |p| &mut p.estimate_align);
        let aligned = match aligned? {
            (whole, true) => self.nearest_surface(&images, &prior7, whole, schedule.near_row, scene.typical.0),
            (near, false) => near,
        };
        let since = self.profiler.now();
        let lower = self.direct.lower_level(&images, &prior7, &aligned, LOWER_LEVEL_CHI2);
        self.profiler.charge(since, |p| &mut p.estimate_lower_level);
        #[cfg(feature = "trace")]
        if let Some((two, chi2)) = &lower {
            std::eprintln!("trace: lower level chi2 {chi2:.1} {:?} p=[{:.1} {:.1} {:.2} {:.2} {:.2} {:.2} {:.2}]", two.lower, two.p[0], two.p[1], two.p[2], two.p[3], two.p[4], two.p[5], two.p[6]);
        }
        let aligned = match lower {
            Some((two, chi2)) if chi2 > LOWER_LEVEL_CHI2 => two,
            _ => aligned,
        };
        self.typical.learn(&aligned);
        let p = aligned.p;
        #[cfg(feature = "trace")]
        std::eprintln!("trace: estimate kf {:.3} {:.3} change {:.3} {:.3} sigma {:.3} {:.3}", p[5], p[6], p[3], p[4], aligned.sigma[5], aligned.sigma[6]);
        Ok(Estimate {
            motion: motion(&p[..5]),
            keyframe_attitude: KeyframeAttitude { deg: [p[5], p[6]], sigma_deg: [aligned.sigma[5], aligned.sigma[6]] },
            change_sigma: [aligned.sigma[3], aligned.sigma[4]],
            gain: aligned.gain,
        })
    }

    /// Step 3: the ground is the surface under the robot. A lower level
    /// (a drop) or a curb top that fills the far view bends the whole
    /// view's fit, its attitude change above all (0.07 degree of pitch
    /// moves ground at 1.3 m as far as a 25 mm drop's parallax after 100
    /// mm). The nearest third of the rows aligned on their own, from the
    /// whole view's fit, replaces it when it explains them clearly better.
    fn nearest_surface(&mut self, images: &Images, prior: &direct::Prior, whole: Alignment, near_row: usize, typical: Option<f32>) -> Alignment {
        let since = self.profiler.now();
        // From the whole view's fit, which is near: the finer levels.
        let schedule = Schedule { near_row, near_from_level: 0, top_level: NEAREST_SURFACE_TOP_LEVEL };
        let near = self.direct.align(images, prior, whole.p, schedule).filter(|near| trusted(near, images.grid, typical));
        let chosen = match near {
            Some(near) => {
                let scale = near.scale.min(whole.scale);
                // The near rows' own first: their alignment's last residuals.
                let (near_misfit, _) = self.direct.misfit(images, &near, near_row, scale);
                let (whole_misfit, count) = self.direct.misfit(images, &whole, near_row, scale);
                #[cfg(feature = "trace")]
                std::eprintln!("trace: nearest surface: misfit whole {whole_misfit:.1} near {near_misfit:.1} of {count}");
                if whole_misfit - near_misfit > NEAR_SURFACE_MISFIT.max(NEAR_SURFACE_SHARE * count as f32) { near } else { whole }
            }
            None => whole,
        };
        self.profiler.charge(since, |p| &mut p.estimate_nearest_surface);
        chosen
    }

    /// Step 1: where the alignment starts from. `prior.sigma` sets the coarse
    /// search's reach (3 sigma); a reach of more than a few cells is
    /// searched on cells twice as large first.
    /// `coarse` hands over the search's memory, asked for only when it
    /// searches: setting up its 33 KB costs thousands of instructions.
    pub(super) fn coarse_start<'c>(coarse: impl FnOnce() -> &'c mut CoarseSearch, scene: &Scene, prior: &Prior) -> Params {
        let prior = Start::of(prior);
        if within_alignment_reach(scene.grid, &prior.sigma) {
            return prior.p;
        }
        let coarse = coarse();
        coarse.new_scene();
        let fine_mm = fine_cell_mm(scene.grid);
        let reach = |sigma: f32, unit: f32| 3.0 * sigma / unit;
        let mut p = prior.p;
        let mut sigma = prior.sigma;
        if reach(sigma[0].max(sigma[1]), fine_mm) > 3.0 {
            let wide = coarse.search_with_runner_up(scene, &p, &sigma, 2.0 * fine_mm, Widen::OnLargerCells);
            // What is left: the large cells' answer is good to about half
            // a large cell, which the fine searches cover a whole one
            // either side (two fine cells, 3 sigma); and about a large
            // yaw step, which they cover three either side, the nearest
            // first (a turn can leave the large cells a minimum that far off).
            let large_cell_mm = cell_mm_on(scene.grid, 2.0 * fine_mm);
            sigma[0] = large_cell_mm / 3.0;
            sigma[1] = sigma[0];
            sigma[2] = sigma[2].min(yaw_step(scene.grid, large_cell_mm));
            // The large cells rank the candidates; the fine cells decide
            // between the two best (a near obstacle filling the view leaves
            // the large cells a near-tie a yaw step apart, which the
            // least rounding tips either way).
            let best = coarse.search(scene, &wide.p, &sigma, fine_mm, Widen::InPlace);
            p = match wide.runner_up {
                Some(runner_up) => {
                    // Toward where the best's own search ended, the
                    // runner-up's would walk ground that search covered.
                    let other = coarse.search(scene, &runner_up, &sigma, fine_mm, Widen::AwayFrom(best.p[2] - runner_up[2]));
                    if other.score < best.score { other.p } else { best.p }
                }
                None => best.p,
            };
        } else {
            p = coarse.search(scene, &p, &sigma, fine_mm, Widen::InPlace).p;
        }
        // The coarse search moves level images: its translation is the one
        // that best explains the attitude change too, so the alignment
        // starts from it level (the prior's attitude change, if any).
        p[3] = prior.p[3];
        p[4] = prior.p[4];
        p
    }
}

/// Whether the prior's 3 sigma lies within the alignment's own reach
/// (its top level's pixel), so the coarse search has nothing to add.
pub(super) fn within_alignment_reach(grid: &KgGrid, sigma: &Params) -> bool {
    let (reach_mm, reach_deg) = alignment_reach(grid);
    3.0 * sigma[0].max(sigma[1]) <= reach_mm && 3.0 * sigma[2] <= reach_deg
}

/// Whether the alignment that started at `start` ended at `end` within
/// its own reach ([`within_alignment_reach`]'s) in translation and yaw.
fn within_reach_of(grid: &KgGrid, start: &Params, end: &Geometry) -> bool {
    let (reach_mm, reach_deg) = alignment_reach(grid);
    kernels::hypotf(end[0] - start[0], end[1] - start[1]) <= reach_mm && libm::fabsf(end[2] - start[2]) <= reach_deg
}

/// How far the alignment reaches from its start: its top level's
/// [`ALIGNMENT_REACH_TOP_PX`], in mm and in degrees of yaw at the grid's
/// farthest corner.
fn alignment_reach(grid: &KgGrid) -> (f32, f32) {
    let reach_px = ALIGNMENT_REACH_TOP_PX * super::pyramid::SCALES[LEVELS - 1] as f32;
    let far_px = kernels::hypotf(grid.x_left_mm as f32, grid.z_far_mm as f32) / grid.mm_per_px as f32;
    (reach_px * grid.mm_per_px as f32, (reach_px / far_px.max(1.0)).to_degrees())
}

/// Whether an alignment is a measurement: most of the ground agrees with
/// it, and its translation is pinned to a fraction of a grid pixel. Both
/// in the grid's own units, so the same test holds on every camera.
fn trusted(aligned: &Alignment, grid: &KgGrid, typical: Option<f32>) -> bool {
    let per_px = 1.0 / grid.mm_per_px as f32;
    let inliers = aligned.inliers as f32 >= MIN_INLIER_SHARE * aligned.sampled as f32 && aligned.inliers >= direct::MIN_POINTS;
    let misregistration = aligned.scale / aligned.texture;
    let allowed = match typical {
        Some(typical) => (TYPICAL_MISREGISTRATION_FACTOR * typical).clamp(MIN_MISREGISTRATION_PX, MAX_MISREGISTRATION_PX),
        None => MAX_MISREGISTRATION_PX,
    };
    let pinned = aligned.sigma[0] * per_px <= MAX_TRANSLATION_SIGMA_PX && aligned.sigma[1] * per_px <= MAX_TRANSLATION_SIGMA_PX && misregistration <= allowed;
    #[cfg(feature = "trace")]
    std::eprintln!(
        "trace: mmpp {:.1} p=[{:.1} {:.1} {:.2} {:.2} {:.2} {:.2} {:.2}] sigma_px=[{:.2} {:.2}] sigma_deg=[{:.3} {:.2} {:.2} {:.2} {:.2}] scale={:.1} texture={:.1} off_px={:.2}/{:.2} sampled={} inliers={} gain={:.3} -> {}",
        grid.mm_per_px, aligned.p[0], aligned.p[1], aligned.p[2], aligned.p[3], aligned.p[4], aligned.p[5], aligned.p[6],
        aligned.sigma[0] * per_px, aligned.sigma[1] * per_px, aligned.sigma[2], aligned.sigma[3], aligned.sigma[4], aligned.sigma[5], aligned.sigma[6],
        aligned.scale, aligned.texture, misregistration, allowed, aligned.sampled, aligned.inliers, aligned.gain, inliers && pinned
    );
    inliers && pinned
}

/// The misregistration (residual scale over texture, grid pixels) this
/// camera's trusted alignments leave, smoothed over the frames: what a
/// right alignment looks like depends on the camera (0.05 px on a clean
/// rendering, 0.45 on a street at 10 frames/s), a wrong minimum leaves
/// several times its camera's typical value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct TypicalMisregistration(pub(super) Option<f32>);

impl TypicalMisregistration {
    fn learn(&mut self, aligned: &Alignment) {
        let value = aligned.scale / aligned.texture;
        self.0 = Some(match self.0 {
            Some(typical) => typical + TYPICAL_MISREGISTRATION_RATE * (value - typical),
            None => value,
        });
    }
}

/// The first row of the nearest third of the rows the camera sees.
fn near_row(scene: &Scene) -> usize {
    let rows = scene.grid.height();
    let first = (0..rows).find(|&j| scene.coverage.seen(j).is_some()).unwrap_or(0);
    let last = (0..rows).rev().find(|&j| scene.coverage.seen(j).is_some()).unwrap_or(0);
    last - (last - first) / 3
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpa::workspace::Workspace;
    use crate::motion::GroundMap;
    use std::vec::Vec;

    /// Value noise: a hashed lattice of `cell_mm`, bilinear between.
    fn noise(x: f64, z: f64, cell_mm: f64, seed: u32) -> f64 {
        let lattice = |i: i64, k: i64| {
            let mut h = (i as u32).wrapping_mul(0x9E37_79B1) ^ (k as u32).wrapping_mul(0x85EB_CA77) ^ seed;
            h ^= h >> 15;
            h = h.wrapping_mul(0x2C1B_3C6D);
            h ^= h >> 12;
            f64::from(h & 0xFFFF) / 65535.0 - 0.5
        };
        let (u, v) = (x / cell_mm, z / cell_mm);
        let (i, k) = (libm::floor(u), libm::floor(v));
        let (fu, fv) = (u - i, v - k);
        let (i, k) = (i as i64, k as i64);
        let top = lattice(i, k) * (1.0 - fu) + lattice(i + 1, k) * fu;
        let bottom = lattice(i, k + 1) * (1.0 - fu) + lattice(i + 1, k + 1) * fu;
        top * (1.0 - fv) + bottom * fv
    }

    /// A textured floor, no two places alike (as gravel): noise of three sizes.
    fn floor(x: f64, z: f64) -> f64 {
        128.0 + 90.0 * noise(x, z, 60.0, 1) + 70.0 * noise(x, z, 21.0, 2) + 50.0 * noise(x, z, 9.0, 3)
    }

    fn grid() -> KgGrid {
        KgGrid { mm_per_px: 5.0, x_left_mm: -350.0, z_far_mm: 1600.0, width: 141, height: 255 }
    }

    /// The KG image of the floor seen from a robot that moved by `motion`
    /// from the keyframe's pose; `raised` marks ground the box covers (it
    /// shows a texture of its own that does not move like the floor).
    fn render(motion: &GroundMotion, raised: impl Fn(f64, f64) -> bool) -> Vec<u8> {
        let grid = grid();
        let map = GroundMap::new(motion, 400.0);
        let mut image = Vec::new();
        for j in 0..grid.height() {
            for i in 0..grid.width() {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let (xk, zk) = map.to_keyframe(x, z).unwrap();
                let value = if raised(x, z) { floor(3.0 * x + 500.0, 2.0 * z) } else { floor(xk, zk) };
                image.push(value.clamp(0.0, 255.0) as u8);
            }
        }
        image
    }

    fn estimate_of(motion: &GroundMotion, prior: &Prior, raised: impl Fn(f64, f64) -> bool) -> GroundMotion {
        estimate_between(&render(&GroundMotion::default(), |_, _| false), &render(motion, raised), prior)
    }

    fn estimate_between(keyframe: &[u8], current: &[u8], prior: &Prior) -> GroundMotion {
        with_scene(keyframe, current, |scene| estimate(scene, prior)).expect("a textured floor is measured").motion
    }

    /// `f` on the scene of two of [`grid`]'s images, the whole grid seen.
    fn with_scene<R>(keyframe: &[u8], current: &[u8], f: impl FnOnce(&Scene) -> R) -> R {
        let grid = grid();
        let coverage = Coverage::full(&grid);
        f(&Scene { keyframe, current, grid: &grid, coverage: &coverage, height_mm: 400.0, hazards: None, keyframe_attitude: KeyframeAttitude::NOMINAL, typical: TypicalMisregistration::default(), sin_cos: SinCosMemo::new() })
    }

    /// Step 1, then the rest, as `Gpa::estimate` runs them when it does
    /// not try the prediction first (or the prediction fails).
    fn estimate(scene: &Scene, prior: &Prior) -> Option<Estimate> {
        let mut workspace = std::boxed::Box::new(Workspace::EMPTY);
        let start = Estimator::coarse_start(|| workspace.coarse(), scene, prior);
        workspace.estimator().estimate(scene, prior, start, false)
    }

    fn assert_close(found: &GroundMotion, truth: &GroundMotion) {
        let (f, t) = (params(found), params(truth));
        let tolerance = [1.0, 1.0, 0.05, 0.05, 0.05];
        for k in 0..5 {
            assert!(libm::fabsf(f[k] - t[k]) < tolerance[k], "parameter {k}: {} vs {} ({found:?})", f[k], t[k]);
        }
    }

    const TRUTH: GroundMotion = GroundMotion {
        planar: Motion { tx_mm: 12.0, tz_mm: 90.0, dyaw_deg: 2.0 },
        attitude: Attitude { pitch_deg: 0.6, roll_deg: -0.4 },
    };

    #[test]
    fn measures_pitch_roll_and_planar_motion_from_a_rough_prior() {
        // Odometry 20 % short and a degree off, no IMU.
        let prior = Prior {
            motion: GroundMotion { planar: Motion { tx_mm: 0.0, tz_mm: 72.0, dyaw_deg: 1.0 }, attitude: Attitude::default() },
            sigma: [12.0, 12.0, 1.0, 1.0, 1.0],
        };
        assert_close(&estimate_of(&TRUTH, &prior, |_, _| false), &TRUTH);
    }

    #[test]
    fn without_odometry_the_wide_search_finds_the_step() {
        let prior = Prior { motion: GroundMotion::default(), sigma: [83.0, 83.0, 8.0, 1.0, 1.0] };
        assert_close(&estimate_of(&TRUTH, &prior, |_, _| false), &TRUTH);
    }

    /// The prediction alone (`Gpa::estimate`'s first try under a wide
    /// prior), on the floor moved by `motion`.
    fn from_prediction(motion: &GroundMotion, prior: &Prior) -> Result<GroundMotion, Unmeasured> {
        let (keyframe, current) = (render(&GroundMotion::default(), |_, _| false), render(motion, |_, _| false));
        let mut workspace = std::boxed::Box::new(Workspace::EMPTY);
        with_scene(&keyframe, &current, |scene| workspace.estimator().estimate_from_prediction(scene, prior)).map(|e| e.motion)
    }

    /// Without odometry, a velocity measured: the prior is wide, but the
    /// motion is where the velocity predicts, and one alignment measures it.
    #[test]
    fn a_prediction_that_holds_is_measured_without_the_search() {
        let prior = Prior { motion: GroundMotion { planar: Motion { tx_mm: 10.0, tz_mm: 86.0, dyaw_deg: 1.8 }, attitude: Attitude::default() }, sigma: [83.0, 83.0, 8.0, 1.0, 1.0] };
        assert!(!prior.within_alignment_reach(&grid()), "a prior the search would cover");
        let found = from_prediction(&TRUTH, &prior).expect("the prediction holds");
        assert_close(&found, &TRUTH);
    }

    /// The prediction lies beyond the alignment's reach (12 top-level px,
    /// 60 mm here) of the motion: the robot sped up, or stopped. Its
    /// alignment is not kept, so the search runs: on this floor it walks
    /// to the motion from 75 mm, but a walk that long may as well end in
    /// a texture's alias. And from the stop it does not fit.
    #[test]
    fn a_prediction_that_does_not_hold_is_left_to_the_search() {
        let wide = [83.0, 83.0, 8.0, 1.0, 1.0];
        let short = Prior { motion: GroundMotion { planar: Motion { tz_mm: TRUTH.planar.tz_mm - 75.0, ..TRUTH.planar }, attitude: Attitude::default() }, sigma: wide };
        let found = from_prediction(&TRUTH, &short);
        assert_eq!(found.err(), Some(Unmeasured::WalkedAway), "kept {found:?}, walked 75 mm from the prediction");
        assert_close(&estimate_of(&TRUTH, &short, |_, _| false), &TRUTH);
        let stopped = GroundMotion { planar: Motion { tx_mm: 0.0, tz_mm: 0.0, dyaw_deg: 0.0 }, ..TRUTH };
        let moving = Prior { motion: GroundMotion { planar: TRUTH.planar, attitude: Attitude::default() }, sigma: wide };
        let found = from_prediction(&stopped, &moving);
        assert_eq!(found.err(), Some(Unmeasured::Untrusted), "kept {found:?} from a prediction 90 mm off");
        assert_close(&estimate_of(&stopped, &moving, |_, _| false), &stopped);
    }

    /// A fallback frame aligns the whole view from no start twice on the
    /// same pixels (it would pay twice for one result): not the
    /// prediction's again after it was not trusted, nor the start an
    /// attitude search that found nothing better hands back. On a view
    /// that matches no motion every fallback runs.
    #[test]
    fn no_alignment_runs_twice() {
        let prior = Prior { motion: GroundMotion { planar: TRUTH.planar, attitude: Attitude::default() }, sigma: [83.0, 83.0, 8.0, 1.0, 1.0] };
        // A floor, then a view of nothing: no alignment is trusted.
        let keyframe = render(&GroundMotion::default(), |_, _| false);
        let current = std::vec![128u8; keyframe.len()];
        let mut workspace = std::boxed::Box::new(Workspace::EMPTY);
        with_scene(&keyframe, &current, |scene| {
            assert_eq!(workspace.estimator().estimate_from_prediction(scene, &prior).err(), Some(Unmeasured::Untrusted));
            let mut aligned = core::mem::take(&mut workspace.estimator().direct.aligned);
            let start = Estimator::coarse_start(|| workspace.coarse(), scene, &prior);
            assert!(workspace.estimator().estimate(scene, &prior, start, true).is_none(), "a blank view aligned");
            aligned.append(&mut workspace.estimator().direct.aligned);
            let mut once = aligned.clone();
            once.sort();
            once.dedup();
            assert_eq!(once.len(), aligned.len(), "{aligned:#?}");
        });
    }

    /// What lets a start aligned once not be aligned again: an alignment
    /// ends the same from the same start, whatever ran before it.
    #[test]
    fn an_alignment_depends_on_its_start_alone() {
        let prior = Prior { motion: GroundMotion { planar: TRUTH.planar, attitude: Attitude::default() }, sigma: [83.0, 83.0, 8.0, 1.0, 1.0] };
        let (keyframe, current) = (render(&GroundMotion::default(), |_, _| false), render(&TRUTH, |_, _| false));
        with_scene(&keyframe, &current, |scene| {
            let images = scene.images();
            let mut direct = std::boxed::Box::new(Direct::EMPTY);
            direct.prepare(&images);
            let start = Start::of(&prior);
            let seven = |p: &Params| -> Geometry { [p[0], p[1], p[2], p[3], p[4], 0.0, 0.0] };
            let prior7 = direct::Prior { mean: seven(&start.p), sigma: [start.sigma[0], start.sigma[1], start.sigma[2], start.sigma[3], start.sigma[4], 1.0, 1.0] };
            let schedule = Schedule { near_row: near_row(scene), near_from_level: NEAR_FROM_LEVEL, top_level: LEVELS - 1 };
            let mut elsewhere = start.p;
            elsewhere[1] += 60.0;
            let first = direct.align(&images, &prior7, seven(&start.p), schedule).expect("aligned");
            direct.align(&images, &prior7, seven(&elsewhere), schedule);
            let again = direct.align(&images, &prior7, seven(&start.p), schedule).expect("aligned");
            assert_eq!((first.p, first.sigma, first.scale, first.gain, first.texture), (again.p, again.sigma, again.scale, again.gain, again.texture));
            assert_eq!((first.sampled, first.inliers), (again.sampled, again.inliers));
        });
    }

    /// Without odometry but with an IMU: the body pitched by 0.8 degree
    /// while the robot moved 20 mm. Unlevelled, the pitch moves the ground
    /// 1 m ahead by about 40 mm, and the search's rigid motions take that
    /// for travel; the current image levelled by the IMU's change first,
    /// its start lies within half a fine cell of the motion.
    #[test]
    fn the_search_levels_the_view_by_the_attitude_prior() {
        let pitched = GroundMotion { planar: Motion { tx_mm: 0.0, tz_mm: 20.0, dyaw_deg: 0.0 }, attitude: Attitude { pitch_deg: -0.8, roll_deg: 0.0 } };
        let imu = Prior { motion: GroundMotion { planar: Motion::default(), attitude: pitched.attitude }, sigma: [83.0, 83.0, 8.0, 0.1, 0.1] };
        let (keyframe, current) = (render(&GroundMotion::default(), |_, _| false), render(&pitched, |_, _| false));
        let mut workspace = std::boxed::Box::new(Workspace::EMPTY);
        let start = with_scene(&keyframe, &current, |scene| Estimator::coarse_start(|| workspace.coarse(), scene, &imu));
        let off = kernels::hypotf(start[0] - pitched.planar.tx_mm as f32, start[1] - pitched.planar.tz_mm as f32);
        assert!(off < 0.5 * super::super::coarse::COARSE_CELL_MM, "start {start:?}, {off:.1} mm from the motion");
    }

    /// A turn far past the wide search's first yaws: every yaw within the
    /// prior's reach is searched on cells twice as large, then refined.
    #[test]
    fn without_odometry_a_sharp_turn_is_found() {
        let turn = GroundMotion { planar: Motion { dyaw_deg: 12.0, ..TRUTH.planar }, ..TRUTH };
        let prior = Prior { motion: GroundMotion::default(), sigma: [83.0, 83.0, 8.0, 1.0, 1.0] };
        assert_close(&estimate_of(&turn, &prior, |_, _| false), &turn);
    }

    #[test]
    fn an_obstacle_in_view_does_not_bend_the_estimate() {
        let prior = Prior { motion: TRUTH, sigma: [12.0, 12.0, 1.0, 1.0, 1.0] };
        // A box a fifth as wide as the view, from 900 to 1200 mm.
        let found = estimate_of(&TRUTH, &prior, |x, z| (-60.0..80.0).contains(&x) && (900.0..1200.0).contains(&z));
        assert_close(&found, &TRUTH);
    }

    /// The KG image, seen from `pose` (a planar motion from the keyframe),
    /// of a floor whose part past `edge_z_mm` (keyframe frame) is a level
    /// `level_mm` above it (a plateau; negative, a drop's lower level),
    /// textured as the floor. A ray meets a level h above the floor at
    /// (H - h) / H of its apparent ground distance; it meets the level when
    /// that point lies past the edge, and (below) has passed the edge.
    fn render_level(pose: &Motion, edge_z_mm: f64, level_mm: f64) -> Vec<u8> {
        let grid = grid();
        let map = GroundMap::new(&GroundMotion { planar: *pose, attitude: Attitude::default() }, 400.0);
        let scale = (400.0 - level_mm) / 400.0;
        let mut image = Vec::new();
        for j in 0..grid.height() {
            for i in 0..grid.width() {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let (xk, zk) = map.to_keyframe(x, z).unwrap();
                let (xt, zt) = map.to_keyframe(x * scale, z * scale).unwrap();
                let value = if zk >= edge_z_mm && zt >= edge_z_mm { floor(xt, zt) } else { floor(xk, zk) };
                image.push(value.clamp(0.0, 255.0) as u8);
            }
        }
        image
    }

    #[test]
    fn the_ground_is_the_surface_under_the_robot() {
        // A 60 mm curb from 700 mm on (keyframe): its top fills most of the
        // view and moves 18 % faster than the floor the robot stands on.
        let step = Motion { tx_mm: 0.0, tz_mm: 80.0, dyaw_deg: 0.0 };
        let keyframe = render_level(&Motion::default(), 700.0, 60.0);
        let current = render_level(&step, 700.0, 60.0);
        // Odometry (or, without it, the last step) 10 % long.
        let predicted = GroundMotion { planar: Motion { tz_mm: 88.0, ..step }, attitude: Attitude::default() };
        let prior = Prior { motion: predicted, sigma: [12.0, 12.0, 1.0, 1.0, 1.0] };
        let found = estimate_between(&keyframe, &current, &prior);
        assert_close(&found, &GroundMotion { planar: step, attitude: Attitude::default() });
    }

    #[test]
    fn a_lower_level_is_not_taken_for_a_pitch_change() {
        // A 30 mm drop past 1200 mm: level, the lower level moves 7 % less
        // than the floor, which a small pitch change nearly mimics.
        let step = Motion { tx_mm: 0.0, tz_mm: 100.0, dyaw_deg: 0.0 };
        let keyframe = render_level(&Motion::default(), 1200.0, -30.0);
        let current = render_level(&step, 1200.0, -30.0);
        let predicted = GroundMotion { planar: step, attitude: Attitude::default() };
        let prior = Prior { motion: predicted, sigma: [15.0, 15.0, 0.5, 1.0, 1.0] };
        let found = estimate_between(&keyframe, &current, &prior);
        // Measured with the f64 estimate: 0.018 deg; its ground-only fit took 0.109 deg.
        assert!(libm::fabs(found.attitude.pitch_deg) < 0.03, "{found:?}");
        assert_close(&found, &GroundMotion { planar: step, attitude: Attitude::default() });
    }

    /// Wheels that slip: the odometry says 100 mm (sigma 15, as GpaConfig
    /// gives it), the images stand. The coarse search's reach (3 sigma)
    /// stops 55 mm short of standing still; the fit's last start is there.
    #[test]
    fn wheels_that_slip_do_not_move_the_ground() {
        let image = render(&GroundMotion::default(), |_, _| false);
        let odometry = GroundMotion { planar: Motion { tx_mm: 0.0, tz_mm: 100.0, dyaw_deg: 0.0 }, attitude: Attitude::default() };
        let prior = Prior { motion: odometry, sigma: [15.0, 15.0, 0.5, 1.0, 1.0] };
        assert_close(&estimate_between(&image, &image, &prior), &GroundMotion::default());
    }

    /// A body that sits pitched and rolled for a while: each comparison
    /// with its keyframe (the last one's result the next one's prior, as
    /// Gpa chains them) brings the keyframe's attitude closer, and surer.
    #[test]
    fn comparisons_with_a_tilted_keyframe_find_its_attitude() {
        let sitting = Attitude { pitch_deg: 0.8, roll_deg: -0.5 };
        let grid = grid();
        let coverage = Coverage::full(&grid);
        let keyframe = render(&GroundMotion { planar: Motion::default(), attitude: sitting }, |_, _| false);
        let mut known = KeyframeAttitude::NOMINAL;
        for tz_mm in [40.0, 80.0, 120.0, 160.0] {
            let change = Attitude { pitch_deg: 0.1, roll_deg: 0.05 };
            let current = render(&GroundMotion { planar: Motion { tx_mm: 5.0, tz_mm, dyaw_deg: 0.5 }, attitude: sitting.then(&change) }, |_, _| false);
            let scene = Scene { keyframe: &keyframe, current: &current, grid: &grid, coverage: &coverage, height_mm: 400.0, hazards: None, keyframe_attitude: known, typical: TypicalMisregistration::default(), sin_cos: SinCosMemo::new() };
            let prior = Prior { motion: GroundMotion { planar: Motion { tx_mm: 0.0, tz_mm, dyaw_deg: 0.0 }, attitude: Attitude::default() }, sigma: [12.0, 12.0, 1.0, 1.0, 1.0] };
            let estimate = estimate(&scene, &prior).expect("a textured floor is measured");
            let found = estimate.keyframe_attitude;
            assert!(found.sigma_deg[0] < known.sigma_deg[0] && found.sigma_deg[1] < known.sigma_deg[1], "{found:?} after {known:?}");
            known = found;
        }
        // Within two of its own sigmas, and most of the way from nominal
        // (measured: 0.70, -0.37 with sigmas 0.09, 0.14).
        let truth = [sitting.pitch_deg as f32, sitting.roll_deg as f32];
        for ((found, sigma), truth) in known.deg.iter().zip(known.sigma_deg).zip(truth) {
            let error = libm::fabsf(found - truth);
            assert!(error < 2.0 * sigma && error < libm::fabsf(truth) / 3.0, "{known:?}");
        }
    }
}

//! Motion estimation: the camera's whole motion over the ground from the
//! keyframe to now (Tx, Tz, yaw, and the body's pitch and roll change),
//! measured between the two KG images. Odometry and IMU are priors.
//!
//! Coarse to fine, as PX4FLOW does on a downward camera:
//! 1. [`coarse`](super::coarse): both images box-averaged to cells of
//!    ~[`COARSE_CELL_MM`]; every yaw and translation within the prior's
//!    reach is scored (SAD after a global gain match). Needed when there
//!    is no odometry or the wheels slipped; with good odometry the reach
//!    is small.
//! 2. `blocks`: blocks of the current image are matched in the keyframe
//!    around where the model puts them ([`block_match`](super::block_match)),
//!    to sub-pixel.
//! 3. `fit`: the five parameters from the block positions by robust least
//!    squares (Tukey weights: obstacles, whose blocks move by parallax, are
//!    outliers) with the priors as extra observations. Blocks are matched
//!    again around the fitted model, and the fit repeated.
//! 4. `nearest_surface`: the ground is the surface under the robot. When
//!    the whole view's fit leaves the nearest third of the blocks
//!    unexplained (a curb top or a lower level filling most of the view
//!    won the vote), their own fit replaces it if it explains more of them.
//! 5. `lower_level`: every row of blocks tried as a drop's edge, with the
//!    lower level's depth as a sixth unknown ([`super::fit`]); that fit's
//!    ground replaces one that bent its attitude to take the level in.
//!
//! All of it in `f32` and integers (the M4 has a single-precision FPU):
//! the model is a [`PixelMap`] homography, the block sums are integers.
//!
//! The remap table stays fixed: an attitude change moves the ground in the
//! KG plane non-uniformly (see [`GroundMotion::to_keyframe`]), which the
//! model carries into the warp of the comparison.

use super::block_match::{self, Images, BLOCK_PX};
use super::coarse::{yaw_step, CoarseSearch, COARSE_CELL_MM};
use super::fit::{capped_chi2, robust_fit, Problem, Surfaces};
use super::homography::{Params, PixelMap, SinCosMemo};
use super::warp::Coverage;
use crate::grid::KgGrid;
use crate::kernels;
use crate::limits::MAX_BLOCK_MATCHES;
use crate::motion::{Attitude, GroundMotion, Motion};
use super::Profiler;

/// Fewest inlier blocks that measure all five parameters.
const MIN_INLIERS: usize = 8;
/// Finite-difference steps per parameter (mm, mm, deg, deg, deg).
const STEP: Params = [0.5, 0.5, 0.02, 0.01, 0.01];
/// A lower level's depth: its finite-difference step and its prior's
/// sigma (mm; wide, the prior only keeps the system solvable).
const LOWER_LEVEL_DEPTH_STEP_MM: f32 = 1.0;
const LOWER_LEVEL_DEPTH_SIGMA_MM: f32 = 1000.0;
/// A lower level past some row replaces the ground alone when that model
/// explains the blocks better by this chi-square (capped residuals in the
/// two-level fit's scale): its depth and its edge row buy it about 5 by
/// chance, so this is a systematic misfit, not noise.
const LOWER_LEVEL_CHI2: f32 = 25.0;
/// Blocks each level needs before it counts as a level.
const LOWER_LEVEL_MIN_BLOCKS: usize = 6;

fn params(motion: &GroundMotion) -> Params {
    [motion.planar.tx_mm as f32, motion.planar.tz_mm as f32, motion.planar.dyaw_deg as f32, motion.attitude.pitch_deg as f32, motion.attitude.roll_deg as f32]
}

fn motion(p: &Params) -> GroundMotion {
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
    /// The brightness of the current frame over the keyframe's (auto
    /// exposure): the median over the last block matches.
    pub(super) gain: f32,
}

/// The keyframe body's attitude relative to the nominal one (pitch, roll,
/// degrees; see [`crate::motion::GroundMap`]) and how well it is known
/// (one sigma each). The keyframe's attitude does not change while it is
/// the keyframe, so each comparison with it adds to what is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct KeyframeAttitude {
    pub(super) deg: [f32; 2],
    pub(super) sigma_deg: [f32; 2],
}

impl KeyframeAttitude {
    /// A run's first keyframe: the nominal attitude, with room for a body
    /// that sits a little off it (the fit pulls it the rest of the way
    /// over the comparisons with the keyframe).
    pub(super) const NOMINAL: KeyframeAttitude = KeyframeAttitude { deg: [0.0, 0.0], sigma_deg: [0.3, 0.3] };

    pub(super) fn attitude(&self) -> Attitude {
        Attitude { pitch_deg: f64::from(self.deg[0]), roll_deg: f64::from(self.deg[1]) }
    }

    /// The next keyframe's: this one's and the change measured to it (its
    /// uncertainty added).
    pub(super) fn then(&self, change: &Attitude, change_sigma: [f32; 2]) -> KeyframeAttitude {
        let next = self.attitude().then(change);
        KeyframeAttitude {
            deg: [next.pitch_deg as f32, next.roll_deg as f32],
            sigma_deg: core::array::from_fn(|k| kernels::hypotf(self.sigma_deg[k], change_sigma[k])),
        }
    }
}

/// What the estimate starts from: a motion and how far off it may be
/// (one sigma per parameter: mm, mm, deg, deg, deg).
#[derive(Clone, Copy, Debug)]
pub(super) struct Prior {
    pub(super) motion: GroundMotion,
    pub(super) sigma: [f64; 5],
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

/// One block's match: where the current block's centre lies in the keyframe.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct BlockMatch {
    pub(super) current: (f32, f32),
    pub(super) keyframe: (f32, f32),
    /// Mean brightness of the current block over the keyframe's at the match.
    gain: f32,
}

/// The two images and their geometry, for one frame's estimate.
pub(super) struct Scene<'a> {
    pub(super) keyframe: &'a [u8],
    pub(super) current: &'a [u8],
    pub(super) grid: &'a KgGrid,
    pub(super) coverage: &'a Coverage,
    pub(super) height_mm: f64,
    /// The keyframe body's attitude: the motion's attitude is the change since.
    pub(super) keyframe_attitude: KeyframeAttitude,
    pub(super) sin_cos: SinCosMemo,
}

impl Scene<'_> {
    /// The map of the motion `p`.
    fn map(&self, p: &Params) -> PixelMap {
        self.map_from(p, self.keyframe_attitude.deg, self.height_mm as f32)
    }

    /// The map of the motion `p` from a keyframe body at `keyframe` (pitch,
    /// roll, degrees) of a ground `height_mm` below the camera.
    fn map_from(&self, p: &Params, keyframe: [f32; 2], height_mm: f32) -> PixelMap {
        PixelMap::with_sin_cos(p, keyframe, height_mm, self.grid, &|degrees| self.sin_cos.sin_cos_deg(degrees))
    }

    fn images(&self) -> Images<'_> {
        Images { keyframe: self.keyframe, current: self.current, grid: self.grid, coverage: self.coverage }
    }
}

/// Steps 2 to 6 and their memory, the block matches (step 1 has its own,
/// [`CoarseSearch`]: the two are never live at once).
pub(super) struct Estimator {
    matches: heapless::Vec<BlockMatch, MAX_BLOCK_MATCHES>,
    /// Its parts' ticks (the `estimate_*` fields).
    pub(super) profiler: Profiler,
}

impl Estimator {
    pub(super) const EMPTY: Estimator = Estimator {
        matches: heapless::Vec::new(),
        profiler: Profiler::OFF,
    };

    /// The brightness of the current frame over the keyframe's, the
    /// median over the block matches; 1 without matches.
    // Not inlined: its 1 KB of gains would sit in the estimate's frame,
    // under every block match.
    #[inline(never)]
    fn gain(&self) -> f32 {
        let mut gains = [0f32; MAX_BLOCK_MATCHES];
        let count = self.matches.len();
        if count == 0 {
            return 1.0;
        }
        for (gain, m) in gains.iter_mut().zip(&self.matches) {
            *gain = m.gain;
        }
        *gains[..count].select_nth_unstable_by(count / 2, |a, b| a.total_cmp(b)).1
    }

    /// The motion keyframe -> now from `start`, step 1's (see
    /// [`Self::coarse_start`]), or None when the ground does not show
    /// enough texture in both images to measure it.
    pub(super) fn estimate(&mut self, scene: &Scene, prior: &Prior, start: Params) -> Option<Estimate> {
        let prior = Start::of(prior);
        // A coarse start on an alias of the texture leaves too few blocks
        // agreeing; the prior's own motion is the other start, and standing
        // still the last (wheels that slip turn while the robot stands,
        // beyond the coarse search's reach around the odometry).
        let fitted = self
            .refine(scene, &prior, start, 0)
            .or_else(|| self.refine(scene, &prior, prior.p, 0))
            .or_else(|| self.refine(scene, &prior, [0.0; 5], 0))?;
        let (chosen, lower_level) = self.nearest_surface(scene, &prior, fitted);
        let chained = Estimate {
            motion: motion(&chosen),
            keyframe_attitude: scene.keyframe_attitude,
            change_sigma: [prior.sigma[3], prior.sigma[4]],
            gain: self.gain(),
        };
        // Step 6 (not over a lower level, which would bend it).
        if lower_level {
            return Some(chained);
        }
        Some(fit_keyframe_attitude(scene, &self.matches, &chained, &prior).unwrap_or(chained))
    }

    /// Step 1: where the blocks start from. `prior.sigma` sets the coarse
    /// search's reach (3 sigma); a reach of more than a few cells is
    /// searched on cells twice as large first.
    pub(super) fn coarse_start(coarse: &mut CoarseSearch, scene: &Scene, prior: &Prior) -> Params {
        let prior = Start::of(prior);
        let fine_mm = COARSE_CELL_MM.max(2.0 * scene.grid.mm_per_px as f32);
        let reach = |sigma: f32, unit: f32| 3.0 * sigma / unit;
        let mut p = prior.p;
        let mut sigma = prior.sigma;
        if reach(sigma[0].max(sigma[1]), fine_mm) > 3.0 {
            let wide = coarse.search_with_runner_up(scene, &p, &sigma, 2.0 * fine_mm);
            // What is left: about a large cell, and its yaw step.
            sigma[0] = 2.0 * fine_mm / 3.0;
            sigma[1] = sigma[0];
            sigma[2] = sigma[2].min(yaw_step(scene.grid, 2.0 * fine_mm));
            // The large cells rank the candidates; the fine cells decide
            // between the two best (a near obstacle filling the view leaves
            // the large cells a near-tie a yaw step apart, which the
            // least rounding tips either way).
            let best = coarse.search(scene, &wide.p, &sigma, fine_mm);
            p = match wide.runner_up {
                Some(runner_up) => {
                    let other = coarse.search(scene, &runner_up, &sigma, fine_mm);
                    if other.score < best.score { other.p } else { best.p }
                }
                None => best.p,
            };
        } else {
            p = coarse.search(scene, &p, &sigma, fine_mm).p;
        }
        // The coarse search moves level images: its translation is the one
        // that best explains the attitude change too, so the blocks start
        // from it level (the fit then splits the two, with the prior).
        p[3] = 0.0;
        p[4] = 0.0;
        p
    }

    /// Steps 2 and 3 from `start`, twice, on the blocks whose centres lie
    /// from `from_row` on.
    fn refine(&mut self, scene: &Scene, prior: &Start, start: Params, from_row: usize) -> Option<Fit> {
        let mut p = start;
        let mut fitted = None;
        for _ in 0..2 {
            self.match_blocks(scene, &p, from_row);
            let fit = fit(scene, &self.matches, &p, prior)?;
            p = fit.p;
            fitted = Some(fit);
        }
        fitted
    }

    /// Step 4: the ground is the surface the robot stands on. A curb top
    /// or a lower level that fills most of the view wins the vote of the
    /// whole view, or bends its fit. The blocks nearest the robot fitted
    /// on their own (from the prior, then from the whole view's fit)
    /// replace it when that fit explains clearly more of them.
    /// Also says whether a lower level was taken (step 5).
    fn nearest_surface(&mut self, scene: &Scene, prior: &Start, fitted: Fit) -> (Params, bool) {
        let near_row = near_row(scene);
        let near = self.refine(scene, prior, prior.p, near_row).or_else(|| self.refine(scene, prior, fitted.p, near_row));
        let chosen = match near {
            Some(near) => {
                // One yardstick for both: the tighter fit's.
                let within = 3.0 * near.scale.min(fitted.scale);
                let near_agreeing = agreeing(scene, &self.matches, &near.p, within);
                let fitted_agreeing = agreeing(scene, &self.matches, &fitted.p, within);
                let clearly_more = fitted_agreeing + (MIN_INLIERS / 2).max(fitted_agreeing / 4);
                if near_agreeing >= clearly_more { near.p } else { fitted.p }
            }
            None => fitted.p,
        };
        // Every block again, around the choice: the gain is their median.
        self.match_blocks(scene, &chosen, 0);
        let since = self.profiler.now();
        let lower_level = self.lower_level(scene, prior, &chosen);
        self.profiler.charge(since, |p| &mut p.estimate_lower_level);
        match lower_level {
            Some(ground) => {
                self.match_blocks(scene, &ground, 0);
                (ground, true)
            }
            None => (chosen, false),
        }
    }

    /// Step 5: whether the far part of the view is a level of its own
    /// below the ground (a drop's lower level), which the ground-only fit
    /// explains almost entirely by bending its attitude: at 1.3 m, 0.07
    /// deg of pitch moves the ground as far as a 25 mm drop's parallax
    /// after 100 mm. Each row of blocks is tried as the edge; the ground's
    /// motion of the best two-level fit replaces `chosen` when that fit is
    /// clearly the better explanation ([`LOWER_LEVEL_CHI2`]).
    #[inline(never)]
    fn lower_level(&self, scene: &Scene, prior: &Start, chosen: &Params) -> Option<Params> {
        let ground_only = Surfaces::ground(scene.map(chosen));
        let mut best: Option<(f32, Params)> = None;
        // Rows of block centres, far to near (the matches are in that order).
        let mut previous_row = None;
        for (k, m) in self.matches.iter().enumerate() {
            let row = m.current.1;
            if previous_row == Some(row) {
                continue;
            }
            previous_row = Some(row);
            if k < LOWER_LEVEL_MIN_BLOCKS || self.matches.len() - k < LOWER_LEVEL_MIN_BLOCKS {
                continue;
            }
            // The edge lies between this row of blocks and the one before it.
            let edge = row - 0.5 * BLOCK_PX as f32;
            let Some((two, depth)) = fit_two_levels(scene, &self.matches, chosen, prior, edge) else { continue };
            let gain = capped_chi2(&self.matches, &ground_only, two.scale) - capped_chi2(&self.matches, &two_levels(scene, &two.p, edge, depth), two.scale);
            if depth > 0.0 && gain > LOWER_LEVEL_CHI2 && best.is_none_or(|(g, _)| gain > g) {
                best = Some((gain, two.p));
            }
        }
        best.map(|(_, ground)| ground)
    }

    /// Step 2: every textured block of the current image whose centre
    /// lies from `from_row` on, matched in the keyframe around where `p`
    /// puts it.
    fn match_blocks(&mut self, scene: &Scene, p: &Params, from_row: usize) {
        let since = self.profiler.now();
        let map = scene.map(p);
        self.match_blocks_from(scene, &map, from_row);
        self.profiler.charge(since, |p| &mut p.estimate_blocks);
    }

    // Not inlined: its blocks' patches and sums (4 KB) would sit under the
    // map's sines and cosines, the estimate's deepest stack.
    #[inline(never)]
    fn match_blocks_from(&mut self, scene: &Scene, map: &PixelMap, from_row: usize) {
        self.matches.clear();
        let images = scene.images();
        let (w, h) = (scene.grid.width(), scene.grid.height());
        let half = (BLOCK_PX / 2) as f32;
        let mut scratch = block_match::Scratch::new();
        let mut bj = 0;
        while bj + BLOCK_PX <= h {
            let centre_row = bj as f32 + half - 0.5;
            let mut bi = 0;
            while centre_row >= from_row as f32 && bi + BLOCK_PX <= w {
                if let Some(found) = block_match::match_block(&images, map, bi, bj, &mut scratch) {
                    let centre = (bi as f32 + half - 0.5, centre_row);
                    if self.matches.push(BlockMatch { current: centre, keyframe: found.keyframe, gain: found.gain }).is_err() {
                        return;
                    }
                }
                bi += BLOCK_PX;
            }
            bj += BLOCK_PX;
        }
    }
}

/// A fitted motion and the robust scale of its block residuals (KG px).
#[derive(Clone, Copy, Debug)]
struct Fit {
    p: Params,
    scale: f32,
}

/// How far the model `map` puts a block from where it was found, KG px.
fn residual(map: &PixelMap, m: &BlockMatch) -> Option<f32> {
    Surfaces::ground(*map).residual(m)
}

/// How many of the `matches` the motion `p` puts within `within` KG px.
fn agreeing(scene: &Scene, matches: &[BlockMatch], p: &Params, within: f32) -> usize {
    let map = scene.map(p);
    matches.iter().filter(|m| residual(&map, m).is_some_and(|r| r < within)).count()
}

/// The first row of the nearest third of the rows the camera sees.
fn near_row(scene: &Scene) -> usize {
    let rows = scene.grid.height();
    let first = (0..rows).find(|&j| scene.coverage.seen(j).is_some()).unwrap_or(0);
    let last = (0..rows).rev().find(|&j| scene.coverage.seen(j).is_some()).unwrap_or(0);
    last - (last - first) / 3
}

/// Step 3: the parameters that put the blocks where they were found,
/// robustly (Tukey), with the prior as five more observations.
fn fit(scene: &Scene, matches: &[BlockMatch], start: &Params, prior: &Start) -> Option<Fit> {
    let surfaces = |p: &Params| Surfaces::ground(scene.map(p));
    let problem = Problem { surfaces: &surfaces, step: STEP, prior: prior.p, sigma: prior.sigma, min_inliers: MIN_INLIERS };
    let solution = robust_fit(matches, *start, &problem)?;
    Some(Fit { p: solution.p, scale: solution.scale })
}

/// The model of a lower level past `edge_row` `depth_mm` below the ground
/// moved by `p`.
fn two_levels(scene: &Scene, p: &Params, edge_row: f32, depth_mm: f32) -> Surfaces {
    let height_mm = scene.height_mm as f32;
    let lower = scene.map_from(p, scene.keyframe_attitude.deg, height_mm + depth_mm);
    Surfaces::two_levels(scene.map(p), lower, scene.grid, height_mm, edge_row, depth_mm)
}

/// Step 6: the keyframe body's attitude as two more unknowns, what was
/// known of it before as their prior. It shows only through how the motion
/// moves tilted ground (about a T z / H per radian: 1 px at 1.4 m for 0.2
/// degree after 100 mm), so a short baseline leaves it to the prior.
/// Starts from the `chained` estimate (the keyframe's attitude held) and
/// keeps its gain.
#[inline(never)]
fn fit_keyframe_attitude(scene: &Scene, matches: &[BlockMatch], chained: &Estimate, prior: &Start) -> Option<Estimate> {
    let five = |p: &[f32; 7]| -> Params { [p[0], p[1], p[2], p[3], p[4]] };
    let surfaces = |p: &[f32; 7]| Surfaces::ground(scene.map_from(&five(p), [p[5], p[6]], scene.height_mm as f32));
    let seven = |p: &Params, keyframe: [f32; 2]| -> [f32; 7] { [p[0], p[1], p[2], p[3], p[4], keyframe[0], keyframe[1]] };
    let keyframe = scene.keyframe_attitude;
    let problem = Problem {
        surfaces: &surfaces,
        step: seven(&STEP, [STEP[3], STEP[4]]),
        prior: seven(&prior.p, keyframe.deg),
        sigma: seven(&prior.sigma, keyframe.sigma_deg),
        min_inliers: MIN_INLIERS,
    };
    let fit = robust_fit(matches, seven(&params(&chained.motion), keyframe.deg), &problem)?;
    let (p, sigma) = (fit.p, fit.variance()?.map(kernels::sqrtf));
    Some(Estimate {
        motion: motion(&five(&p)),
        keyframe_attitude: KeyframeAttitude { deg: [p[5], p[6]], sigma_deg: [sigma[5], sigma[6]] },
        change_sigma: [sigma[3], sigma[4]],
        ..*chained
    })
}

/// A lower level past `edge_row` fitted with the ground: the ground's
/// motion and residual scale, and the level's depth below the ground (mm).
fn fit_two_levels(scene: &Scene, matches: &[BlockMatch], start: &Params, prior: &Start, edge_row: f32) -> Option<(Fit, f32)> {
    let ground = |p: &[f32; 6]| -> Params { [p[0], p[1], p[2], p[3], p[4]] };
    let surfaces = |p: &[f32; 6]| two_levels(scene, &ground(p), edge_row, p[5]);
    let six = |five: &Params, sixth: f32| -> [f32; 6] { [five[0], five[1], five[2], five[3], five[4], sixth] };
    let problem = Problem {
        surfaces: &surfaces,
        step: six(&STEP, LOWER_LEVEL_DEPTH_STEP_MM),
        prior: six(&prior.p, 0.0),
        sigma: six(&prior.sigma, LOWER_LEVEL_DEPTH_SIGMA_MM),
        min_inliers: MIN_INLIERS,
    };
    let fit = robust_fit(matches, six(start, 0.0), &problem)?;
    Some((Fit { p: ground(&fit.p), scale: fit.scale }, fit.p[5]))
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
        let grid = grid();
        let coverage = Coverage::full(&grid);
        let scene = Scene { keyframe, current, grid: &grid, coverage: &coverage, height_mm: 400.0, keyframe_attitude: KeyframeAttitude::NOMINAL, sin_cos: SinCosMemo::new() };
        estimate(&scene, prior).expect("a textured floor is measured").motion
    }

    /// Step 1, then the rest, as `Gpa::estimate` runs them.
    fn estimate(scene: &Scene, prior: &Prior) -> Option<Estimate> {
        let mut workspace = std::boxed::Box::new(Workspace::EMPTY);
        let start = Estimator::coarse_start(workspace.coarse(), scene, prior);
        workspace.estimator().estimate(scene, prior, start)
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
            let scene = Scene { keyframe: &keyframe, current: &current, grid: &grid, coverage: &coverage, height_mm: 400.0, keyframe_attitude: known, sin_cos: SinCosMemo::new() };
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

    #[test]
    fn a_new_keyframe_is_as_sure_as_the_last_and_the_change_to_it() {
        let last = KeyframeAttitude { deg: [0.5, -0.2], sigma_deg: [0.03, 0.04] };
        let next = last.then(&Attitude { pitch_deg: 0.25, roll_deg: 0.1 }, [0.04, 0.03]);
        assert!((next.deg[0] - 0.75).abs() < 1e-3 && (next.deg[1] + 0.1).abs() < 1e-3, "{next:?}");
        assert!((next.sigma_deg[0] - 0.05).abs() < 1e-6 && (next.sigma_deg[1] - 0.05).abs() < 1e-6, "{next:?}");
    }
}

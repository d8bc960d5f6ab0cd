//! Direct alignment: the motion under which the keyframe, warped, looks
//! like the current KG image, by Gauss-Newton on the gray levels
//! themselves. No features are matched, so no block's search window
//! limits the capture range and every textured pixel of the grid counts.
//!
//! The residual of a current pixel x is r = a K(W(x; p)) + b - C(x): K
//! the keyframe, W the ground's [`PixelMap`] under the seven geometric
//! unknowns `p` (tx, tz, yaw, the pitch and roll change, and the keyframe
//! body's pitch and roll relative to the ground), a and b the exposure.
//!
//! - Coarse to fine over a masked [`Pyramid`], [`LEVELS`] levels.
//! - On each level only the strongest-gradient pixel of each block is
//!   used, the blocks sized so that a level has at most [`MAX_POINTS`].
//! - The Jacobian is the inverse one (Hager and Belhumeur): the current
//!   image's gradient brought into the keyframe by the warp's own 2x2
//!   derivative, times the warp's derivative by each unknown. It is built
//!   once per level; each iteration warps, samples and re-weights.
//! - Robust: the first iteration a Huber loss, then Tukey's, both on the
//!   residuals' median absolute deviation. Obstacles and anything that
//!   moved are outliers.
//! - Each unknown has a prior (odometry, IMU, the nominal attitude): the
//!   solution is a maximum a posteriori one, and well defined when the
//!   ground shows little texture along some direction.

use super::homography::{PixelMap, SinCosMemo};
use super::hazard_mask::MovedMask;
use super::pyramid::{self, Level, Pyramid, Seen, LEVELS};
use crate::grid::KgGrid;
use crate::kernels;

mod choice;
mod solver;

use choice::{choose, leave_out, Chosen, ChosenLevel};
use solver::{cholesky, cholesky_solve, solve, solve_bordered, Border, GroundFactor};

/// Geometric unknowns: tx mm, tz mm, yaw, pitch change, roll change, then
/// the keyframe body's pitch and roll (degrees).
pub(super) const GEOMETRY: usize = 7;
pub(super) type Geometry = [f32; GEOMETRY];
/// And the exposure's gain and offset.
const UNKNOWNS: usize = GEOMETRY + 2;
const _: () = assert!(UNKNOWNS == kernels::NORMAL_UNKNOWNS);
/// The terms [`Points::accumulate`] hands the kernel at once.
const TERMS_A_BATCH: usize = 16;
/// Most pixels one level uses.
pub(super) const MAX_POINTS: usize = 512;
/// Fewest pixels that measure the unknowns at all.
pub(super) const MIN_POINTS: usize = 40;
/// Finite-difference steps of the warp's derivatives.
const STEP: Geometry = [0.5, 0.5, 0.02, 0.01, 0.01, 0.01, 0.01];
/// Iterations per level, finest first.
const ITERATIONS: [usize; LEVELS] = [5, 6, 8];
/// An iteration that moves no pixel by more than this (pixels of its
/// level) ends the level.
const CONVERGED_PX: f32 = 0.02;
/// The least |gx| + |gy| of a used pixel (twice the gray levels per pixel):
/// flatter pixels carry mostly noise.
const MIN_GRADIENT_SUM: u32 = 6;
/// The residuals' scale is their |r|'s 30th percentile over that of a
/// unit Gaussian's |r| (0.385).
const SCALE_QUANTILE_PERCENT: usize = 30;
const SCALE_QUANTILE_OF_SIGMA: f32 = 0.385;
/// The residuals' scale never falls below this (gray levels): noise-free
/// renderings would otherwise weigh their quantisation as information.
const SCALE_FLOOR: f32 = 1.0;
/// Neighbouring pixels' residuals are not independent (blur, the remap's
/// interpolation): the data count as this many times fewer pixels against
/// the priors and in the reported uncertainty.
const CORRELATION: f32 = 4.0;
/// Priors of the exposure: gain about 1, offset about mid-gray (wide).
const GAIN_SIGMA: f32 = 0.3;
const OFFSET_SIGMA: f32 = 40.0;
/// Tuning constants of the robust losses (95 % efficiency on Gaussian noise).
const HUBER: f32 = 1.345;
const TUKEY: f32 = 4.685;

/// The two images and their geometry.
pub(super) struct Images<'a> {
    pub(super) keyframe: &'a [u8],
    pub(super) current: &'a [u8],
    pub(super) grid: &'a KgGrid,
    /// Seen columns of each grid row (both images: one camera).
    pub(super) seen: &'a [Seen],
    pub(super) height_mm: f32,
    /// Pixels that may show a hazard the last frame saw: left out.
    pub(super) hazards: Option<MovedMask<'a>>,
    pub(super) sin_cos: &'a SinCosMemo,
}

impl Images<'_> {
    pub(super) fn map(&self, p: &Geometry) -> PixelMap {
        self.map_below(p, 0.0)
    }

    /// The map of a level `depth_mm` below the ground, for pixels already
    /// scaled to that level ([`Placement`]).
    fn map_below(&self, p: &Geometry, depth_mm: f32) -> PixelMap {
        PixelMap::with_sin_cos(&[p[0], p[1], p[2], p[3], p[4]], [p[5], p[6]], self.height_mm + depth_mm, self.grid, &|degrees| self.sin_cos.sin_cos_deg(degrees))
    }

    /// Pixels a unit of each unknown moves the far ground by, roughly
    /// (for the convergence test only).
    fn pixels_per_unit(&self) -> Geometry {
        let per_mm = 1.0 / self.grid.mm_per_px as f32;
        let per_deg = self.grid.z_far_mm as f32 * per_mm * core::f32::consts::PI / 180.0;
        [per_mm, per_mm, per_deg, per_deg, per_deg, per_deg, per_deg]
    }
}

/// What is known before: a mean and one sigma per geometric unknown.
#[derive(Clone, Copy, Debug)]
pub(super) struct Prior {
    pub(super) mean: Geometry,
    pub(super) sigma: Geometry,
}

/// Which of the current image's rows take part on the coarse levels.
#[derive(Clone, Copy, Debug)]
pub(super) struct Schedule {
    /// Grid rows from this one on, on the levels from `near_from_level` up
    /// (the ground under the robot decides before the far view joins in).
    pub(super) near_row: usize,
    pub(super) near_from_level: usize,
    /// The coarsest level it starts from.
    pub(super) top_level: usize,
}


/// A level below the ground from a grid row on to the far edge (a drop's
/// lower level; rows above the edge are farther).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Lower {
    pub(super) edge_row: f32,
    pub(super) depth_mm: f32,
}

/// Where the motion puts a grid pixel in the keyframe: on the ground, or
/// past the edge on the lower level. A point of a level d below the
/// ground appears H / (H + d) as far from the robot as it is; it is moved
/// by the motion's map for a plane H + d below the camera.
struct Placement {
    ground: PixelMap,
    lower: Option<(Lower, PixelMap)>,
    /// The grid's pixel -> ground offsets (px): x = left + i, z = far - j.
    left_px: f32,
    far_px: f32,
    height_mm: f32,
}

impl Placement {
    fn new(images: &Images, p: &Geometry, lower: Option<Lower>) -> Placement {
        let m = images.grid.mm_per_px as f32;
        Placement {
            ground: images.map(p),
            lower: lower.map(|lower| (lower, images.map_below(p, lower.depth_mm))),
            left_px: images.grid.x_left_mm as f32 / m,
            far_px: images.grid.z_far_mm as f32 / m,
            height_mm: images.height_mm,
        }
    }

    /// Pixel (i, j) of the point `factor` times as far from the robot.
    fn scaled(&self, (i, j): (f32, f32), factor: f32) -> (f32, f32) {
        ((i + self.left_px) * factor - self.left_px, (j - self.far_px) * factor + self.far_px)
    }

    #[inline]
    fn at(&self, x: f32, y: f32) -> Option<(f32, f32)> {
        match &self.lower {
            Some((lower, map)) if y < lower.edge_row => {
                let apparent = self.height_mm / (self.height_mm + lower.depth_mm);
                let (i, j) = self.scaled((x, y), 1.0 / apparent);
                map.at(i, j).map(|there| self.scaled(there, apparent))
            }
            _ => self.ground.at(x, y),
        }
    }
}

/// The result, and how good it is.
#[derive(Clone, Copy, Debug)]
pub(super) struct Alignment {
    pub(super) p: Geometry,
    /// Current brightness over the keyframe's.
    pub(super) gain: f32,
    /// One sigma of each geometric unknown.
    pub(super) sigma: Geometry,
    /// Robust scale of the final residuals, gray levels.
    pub(super) scale: f32,
    /// Pixels of the finest level that sampled the keyframe, and those
    /// the final Tukey weights kept.
    pub(super) sampled: usize,
    pub(super) inliers: usize,
    /// The median gradient length of the finest level's pixels (gray
    /// levels per pixel): `scale / texture` is how far off, in pixels,
    /// the typical pixel still lies.
    pub(super) texture: f32,
    /// The exposure as fitted (for [`Direct::misfit`]).
    exposure: (f32, f32),
    /// The lower level the motion was fitted with, if any.
    pub(super) lower: Option<Lower>,
}

/// One pixel in use: 32 bytes (512 of them are most of the alignment's memory).
#[derive(Clone, Copy)]
struct Point {
    /// Pixel of its level (levels are at most [`MAX_GRID_SIDE`] wide and high).
    ///
    /// [`MAX_GRID_SIDE`]: crate::grid::MAX_GRID_SIDE
    i: u8,
    j: u8,
    /// Its gray level in the current image.
    c: u8,
    /// Its gradient's length in half gray levels per pixel, truncated and
    /// capped at 255: the bin of [`Points::median_gradient`]'s histogram,
    /// its only use.
    gradient_bin: u8,
    /// d r / d p; while selecting, the gradient in the first two. With
    /// `depth` ([`Points::jacobians_with`]), the last (the keyframe body's
    /// roll, which [`Direct::lower_level`] holds at its prior, so its
    /// derivative is dead there) holds d r / d (depth of a lower level
    /// there) instead: [`DEPTH`].
    jacobian: Geometry,
}

/// The slot of [`Point::jacobian`] that holds the lower level's depth
/// derivative after [`Points::jacobians_with`] with `depth`: the keyframe
/// roll's, which [`hold_keyframe_attitude`] takes out of the normal
/// equations and [`Border::add`] leaves out when `held`.
const DEPTH: usize = 6;
/// The first of the unknowns [`Direct::lower_level`] holds: the keyframe's attitude.
const HELD_FROM: usize = 5;
const _: () = assert!(core::mem::size_of::<Point>() == 32);

#[derive(Clone, Copy)]
enum Loss {
    Huber,
    Tukey,
}

impl Loss {
    #[inline(always)]
    fn weight(self, residual: f32, scale: f32) -> f32 {
        let e = residual.abs() / scale;
        match self {
            Loss::Huber => {
                if e <= HUBER {
                    1.0
                } else {
                    HUBER / e
                }
            }
            Loss::Tukey => {
                if e < TUKEY {
                    let t = 1.0 - (e / TUKEY) * (e / TUKEY);
                    t * t
                } else {
                    0.0
                }
            }
        }
    }
}

/// The estimate as it goes.
#[derive(Clone, Copy, PartialEq)]
struct State {
    p: Geometry,
    gain: f32,
    /// Brightness at keyframe level 128.
    offset: f32,
    lower: Option<Lower>,
}

/// One iteration's normal equations (upper triangle, row by row).
struct Normal {
    h: [[f32; UNKNOWNS]; UNKNOWNS],
    g: [f32; UNKNOWNS],
}

/// The alignment's memory: both pyramids and one level's pixels.
pub(super) struct Direct {
    keyframe: Pyramid,
    current: Pyramid,
    /// Each level's chosen pixels.
    chosen: Chosen,
    points: Points,
    /// Tests: every alignment run so far, its start, prior and schedule.
    #[cfg(test)]
    pub(super) aligned: std::vec::Vec<std::string::String>,
}

/// One level's pixels in use, and their residuals.
struct Points {
    points: heapless::Vec<Point, MAX_POINTS>,
    /// The side of the blocks the points were chosen from (level pixels).
    side: usize,
    /// Each point's residual (NaN: it did not sample the keyframe) and keyframe sample.
    residuals: [f32; MAX_POINTS],
    samples: [f32; MAX_POINTS],
    /// The residuals stored are those at this state of the finest level's
    /// whole choice from this grid row on (none dropped): an alignment's
    /// last evaluation, reused by [`Direct::misfit`].
    evaluated: Option<(State, usize)>,
}

/// Level-0 coordinate of a level's pixel centre.
#[inline(always)]
fn to_grid(level: usize, index: u16) -> f32 {
    let s = pyramid::scale(level) as f32;
    s * f32::from(index) + 0.5 * (s - 1.0)
}

impl Direct {
    pub(super) const EMPTY: Direct = Direct {
        keyframe: Pyramid::EMPTY,
        current: Pyramid::EMPTY,
        chosen: Chosen::EMPTY,
        points: Points { points: heapless::Vec::new(), side: 1, residuals: [0.0; MAX_POINTS], samples: [0.0; MAX_POINTS], evaluated: None },
        #[cfg(test)]
        aligned: std::vec::Vec::new(),
    };

    /// Builds both pyramids; every [`Self::align`] until the next call uses them.
    pub(super) fn prepare(&mut self, images: &Images) {
        let (w, h) = (images.grid.width(), images.grid.height());
        self.keyframe.build(images.keyframe, w, h, images.seen);
        self.current.build(images.current, w, h, images.seen);
        let mut start = 0;
        for level in 0..LEVELS {
            let count = choose(&self.current.level(level, images.current, images.seen), &mut self.chosen.pixels[start..], &mut self.chosen.sides[level]);
            self.chosen.ranges[level] = (start, start + count);
            start += count;
        }
    }

    /// Leaves the pixels that may show a hazard the last frame saw out of
    /// every later alignment of this frame; whether any were.
    pub(super) fn leave_out_hazards(&mut self, images: &Images) -> bool {
        let Some(hazards) = &images.hazards else { return false };
        let mut any = false;
        let Chosen { pixels, ranges, .. } = &mut self.chosen;
        for (level, range) in ranges.iter_mut().enumerate() {
            any |= leave_out(level, pixels, range, hazards);
        }
        any
    }

    /// Aligns from `start` under `prior`; None when too few pixels sample
    /// both images or the equations are singular.
    pub(super) fn align(&mut self, images: &Images, prior: &Prior, start: Geometry, schedule: Schedule) -> Option<Alignment> {
        #[cfg(test)]
        self.aligned.push(std::format!("{start:?} {prior:?} {schedule:?}"));
        let mut state = State { p: start, gain: 1.0, offset: 128.0, lower: None };
        let mut first = true;
        // The finest level's first row, if none of its points was dropped.
        let mut finest = None;
        for level in (0..=schedule.top_level.min(LEVELS - 1)).rev() {
            let current = self.current.level(level, images.current, images.seen);
            let keyframe = self.keyframe.level(level, images.keyframe, images.seen);
            let near_row = if level >= schedule.near_from_level { schedule.near_row / pyramid::scale(level) } else { 0 };
            let points = &mut self.points;
            points.select(&current, self.chosen.level(level), near_row);
            if points.points.len() < MIN_POINTS {
                continue;
            }
            let chosen = points.points.len();
            points.jacobians(images, level, &state.p);
            let intact = points.points.len() == chosen;
            for _ in 0..ITERATIONS[level] {
                let loss = if first { Loss::Huber } else { Loss::Tukey };
                first = false;
                let before = state;
                let Some(moved) = points.iterate(images, &keyframe, level, &mut state, prior, loss) else {
                    // Too few pixels sampled, or a step off the sane range:
                    // a coarse level leaves the finer ones to it.
                    state = before;
                    if level == 0 {
                        #[cfg(feature = "trace")]
                        std::eprintln!("trace: level 0 failed from {:?} with {} points", start, points.points.len());
                        return None;
                    }
                    break;
                };
                if moved < CONVERGED_PX {
                    break;
                }
            }
            if level == 0 {
                finest = Some(intact.then_some(near_row));
            }
        }
        let finest_rows = finest?;
        let keyframe = self.keyframe.level(0, images.keyframe, images.seen);
        let aligned = self.points.evaluate(images, &keyframe, &state, prior);
        self.points.evaluated = finest_rows.map(|row| (state, row));
        aligned
    }
}

impl Points {
    /// The strongest-gradient pixel of each block of `level` from row
    /// `near_row` on, blocks sized so that at most [`MAX_POINTS`] are chosen.
    /// The chosen pixels of `level` (`chosen`, from [`choose`]) from row
    /// `near_row` on, with their gray level and gradient.
    fn select(&mut self, level: &Level, chosen: ChosenLevel, near_row: usize) {
        self.evaluated = None;
        self.points.clear();
        self.side = chosen.side;
        for &(i, j) in chosen.pixels {
            if usize::from(j) < near_row {
                continue;
            }
            let Some((gx, gy)) = level.gradient(usize::from(i), usize::from(j)) else { continue };
            let mut jacobian = [0.0; GEOMETRY];
            (jacobian[0], jacobian[1]) = (gx, gy);
            let c = level.at(usize::from(i), usize::from(j));
            // Twice the gradient is a whole number each way, so the bin,
            // floor(2 |g|), is the correctly rounded square root of an
            // exact sum of squares, truncated: the same as through hypotf.
            let (twice_x, twice_y) = (2.0 * gx, 2.0 * gy);
            let gradient_bin = (crate::kernels::sqrtf(twice_x * twice_x + twice_y * twice_y) as usize).min(255) as u8;
            // Capacity: `chosen` holds at most MAX_POINTS.
            let _ = self.points.push(Point { i, j, c, gradient_bin, jacobian });
        }
    }

    /// Each point's d r / d p at `p`; points whose warp is undefined there are dropped.
    fn jacobians(&mut self, images: &Images, level: usize, p: &Geometry) {
        self.jacobians_with(images, level, p, false);
    }

    /// [`Self::jacobians`], and with `depth` each point's derivative by
    /// the depth of a lower level under it.
    fn jacobians_with(&mut self, images: &Images, level: usize, p: &Geometry, depth: bool) {
        match depth {
            false => self.derivatives::<GEOMETRY>(images, level, p, None),
            // The keyframe's attitude is held at its prior (see
            // [`Direct::lower_level`]): its two derivatives are dead, the
            // roll's slot takes the depth's.
            true => {
                let below = Placement::new(images, p, Some(Lower { edge_row: f32::INFINITY, depth_mm: DEPTH_STEP_MM }));
                self.derivatives::<HELD_FROM>(images, level, p, Some(&below));
            }
        }
    }

    /// d r / d p of the first `N` geometric unknowns at `p` (the rest 0)
    /// and, with `below`, d r / d (depth) in the [`DEPTH`] slot.
    #[inline(always)]
    fn derivatives<const N: usize>(&mut self, images: &Images, level: usize, p: &Geometry, below: Option<&Placement>) {
        let base = images.map(p);
        let maps: [PixelMap; N] = core::array::from_fn(|k| {
            let mut q = *p;
            q[k] += STEP[k];
            images.map(&q)
        });
        let s = pyramid::scale(level) as f32;
        self.points.retain_mut(|point| {
            let (x, y) = (to_grid(level, u16::from(point.i)), to_grid(level, u16::from(point.j)));
            let (Some(w0), Some(wx), Some(wy)) = (base.at(x, y), base.at(x + 1.0, y), base.at(x, y + 1.0)) else { return false };
            // The warp's 2x2 derivative A; the gradient in the keyframe is g A^-1.
            let (a00, a01, a10, a11) = (wx.0 - w0.0, wy.0 - w0.0, wx.1 - w0.1, wy.1 - w0.1);
            let det = a00 * a11 - a01 * a10;
            if det.abs() < 1e-6 {
                return false;
            }
            let (gx, gy) = (point.jacobian[0], point.jacobian[1]);
            let (ku, kv) = ((gx * a11 - gy * a10) / det, (gy * a00 - gx * a01) / det);
            for (k, map) in maps.iter().enumerate() {
                let Some(moved) = map.at(x, y) else { return false };
                point.jacobian[k] = (ku * (moved.0 - w0.0) + kv * (moved.1 - w0.1)) / (STEP[k] * s);
            }
            point.jacobian[N..].fill(0.0);
            if let Some(below) = below {
                let Some(moved) = below.at(x, y) else { return false };
                point.jacobian[DEPTH] = (ku * (moved.0 - w0.0) + kv * (moved.1 - w0.1)) / (DEPTH_STEP_MM * s);
            }
            true
        });
    }

    /// Warps and samples every point at `state`: residuals and samples
    /// stored; returns how many sampled and their robust scale.
    fn residuals(&mut self, images: &Images, keyframe: &Level, level: usize, state: &State) -> (usize, f32) {
        let map = Placement::new(images, &state.p, state.lower);
        // The ground alone (most calls) in a loop of its own.
        match &map.lower {
            None => self.residuals_through(keyframe, level, state, |x, y| map.ground.at(x, y)),
            Some(_) => self.residuals_through(keyframe, level, state, |x, y| map.at(x, y)),
        }
    }

    /// [`Self::residuals`] with the placement `at`.
    #[inline(always)]
    fn residuals_through(&mut self, keyframe: &Level, level: usize, state: &State, at: impl Fn(f32, f32) -> Option<(f32, f32)>) -> (usize, f32) {
        let s = pyramid::scale(level) as f32;
        let (offset, inverse) = (0.5 * (s - 1.0), 1.0 / s);
        // |r| in quarter gray levels, for the median.
        let mut histogram = [0u16; 256];
        let mut sampled = 0usize;
        for (k, point) in self.points.iter().enumerate() {
            let sample = at(to_grid(level, u16::from(point.i)), to_grid(level, u16::from(point.j)))
                .and_then(|(u, v)| keyframe.sample((u - offset) * inverse, (v - offset) * inverse));
            match sample {
                Some(value) => {
                    let r = state.gain * (value - 128.0) + state.offset - f32::from(point.c);
                    self.residuals[k] = r;
                    self.samples[k] = value;
                    histogram[((r.abs() * 4.0) as usize).min(255)] += 1;
                    sampled += 1;
                }
                None => self.residuals[k] = f32::NAN,
            }
        }
        // The scale from a low quantile of |r|: the ground may be less than
        // half of the view (a stool's legs and two bags), and its pixels
        // are the ones with the smallest residuals.
        let (mut count, wanted) = (0usize, (sampled * SCALE_QUANTILE_PERCENT).div_ceil(100));
        let mut quantile = 64.0;
        for (bin, &n) in histogram.iter().enumerate() {
            count += usize::from(n);
            if count >= wanted {
                quantile = (bin as f32 + 0.5) * 0.25;
                break;
            }
        }
        (sampled, (quantile / SCALE_QUANTILE_OF_SIGMA).max(SCALE_FLOOR))
    }

    /// The normal equations of the stored residuals under `loss`, and
    /// how many points kept a weight.
    #[inline(never)] // its terms' buffer off the deepest stack path
    fn accumulate(&self, loss: Loss, scale: f32) -> (Normal, usize) {
        let mut normal = Normal { h: [[0.0; UNKNOWNS]; UNKNOWNS], g: [0.0; UNKNOWNS] };
        let mut terms = [kernels::NormalTerm::EMPTY; TERMS_A_BATCH];
        let (mut kept, mut batched) = (0, 0);
        for (k, point) in self.points.iter().enumerate() {
            let r = self.residuals[k];
            if r.is_nan() {
                continue;
            }
            let weight = loss.weight(r, scale);
            if weight == 0.0 {
                continue;
            }
            kept += 1;
            terms[batched] = kernels::NormalTerm { weight, residual: r, brightness: self.samples[k] - 128.0, jacobian: &point.jacobian };
            batched += 1;
            if batched == TERMS_A_BATCH {
                kernels::add_normal_terms(&terms, &mut normal.h, &mut normal.g);
                batched = 0;
            }
        }
        kernels::add_normal_terms(&terms[..batched], &mut normal.h, &mut normal.g);
        (normal, kept)
    }

    /// One Gauss-Newton step; returns how far it moved the far ground
    /// (pixels of the level), None when singular or too few points sampled.
    fn iterate(&mut self, images: &Images, keyframe: &Level, level: usize, state: &mut State, prior: &Prior, loss: Loss) -> Option<f32> {
        let (sampled, scale) = self.residuals(images, keyframe, level, state);
        if sampled < MIN_POINTS {
            return None;
        }
        let (mut normal, kept) = self.accumulate(loss, scale);
        if kept < MIN_POINTS {
            return None;
        }
        add_priors(&mut normal, state, prior, scale);
        let step = solve(&normal.h, &normal.g)?;
        let per_unit = images.pixels_per_unit();
        let s = pyramid::scale(level) as f32;
        let mut moved = 0.0f32;
        for k in 0..GEOMETRY {
            state.p[k] -= step[k];
            moved = moved.max((step[k] * per_unit[k]).abs() / s);
        }
        state.gain -= step[GEOMETRY];
        state.offset -= step[GEOMETRY + 1];
        if !state.p.iter().all(|v| v.is_finite()) || !(0.2..5.0).contains(&state.gain) {
            return None;
        }
        Some(moved)
    }

    /// The finest level's residuals at the solution, its inliers and
    /// each unknown's sigma.
    fn evaluate(&mut self, images: &Images, keyframe: &Level, state: &State, prior: &Prior) -> Option<Alignment> {
        let (sampled, scale) = self.residuals(images, keyframe, 0, state);
        let (mut normal, inliers) = self.accumulate(Loss::Tukey, scale);
        // The exposure's gain as the ratio of mean brightness over the
        // pixels that agree: the fitted gain also absorbs the contrast the
        // keyframe's interpolation smooths away (a few percent).
        let (mut current, mut warped) = (0.0f32, 0.0f32);
        for (k, point) in self.points.iter().enumerate() {
            let r = self.residuals[k];
            if !r.is_nan() && Loss::Tukey.weight(r, scale) > 0.0 {
                current += f32::from(point.c);
                warped += self.samples[k];
            }
        }
        let gain = if warped > 0.0 { current / warped } else { 1.0 };
        let texture = self.median_gradient();
        add_priors(&mut normal, state, prior, scale);
        let factor = cholesky(&normal.h)?;
        let variance = scale * scale * CORRELATION;
        let sigma = core::array::from_fn(|k| {
            let mut unit = [0.0; UNKNOWNS];
            unit[k] = 1.0;
            let column = cholesky_solve(&factor, &unit);
            crate::kernels::sqrtf((column[k] * variance).max(0.0))
        });
        Some(Alignment { p: state.p, gain, sigma, scale, sampled, inliers, texture, exposure: (state.gain, state.offset), lower: state.lower })
    }
}

/// The mean gray level of a level's seen pixels.
fn level_mean(level: &Level) -> f32 {
    let (mut sum, mut count) = (0u32, 0u32);
    for (j, &(lo, hi)) in level.seen.iter().enumerate().take(level.height) {
        for &value in &level.pixels[j * level.width..][usize::from(lo)..usize::from(hi)] {
            sum += u32::from(value);
            count += 1;
        }
    }
    if count == 0 { 0.0 } else { sum as f32 / count as f32 }
}

/// Most candidates of the top level's translation search, each way.
const SEARCH_STEPS: usize = 15;
/// Most steps of the top level's attitude search either side of its start.
const ATTITUDE_SEARCH_STEPS: usize = 4;

impl Direct {
    /// Of the `candidates` (the rest of the geometry as in `fallback`),
    /// the one that best explains the top level: the median absolute
    /// difference of its chosen pixels after a brightness match by the
    /// levels' means (an exposure step). `fallback` when none samples
    /// enough of the keyframe.
    fn best_on_top_level(&mut self, images: &Images, fallback: &Geometry, candidates: impl Iterator<Item = Geometry>) -> Geometry {
        let top = LEVELS - 1;
        let current = self.current.level(top, images.current, images.seen);
        let keyframe = self.keyframe.level(top, images.keyframe, images.seen);
        let points = &mut self.points;
        points.select(&current, self.chosen.level(top), 0);
        let gain = level_mean(&current) / level_mean(&keyframe).max(1.0);
        let mut best = (f32::INFINITY, *fallback);
        for p in candidates {
            let (sampled, scale) = points.residuals(images, &keyframe, top, &State { p, gain, offset: 128.0 * gain, lower: None });
            if sampled >= MIN_POINTS && scale < best.0 {
                best = (scale, p);
            }
        }
        best.1
    }

    /// The translation that best explains the top level, searched on a
    /// grid of its pixels over the box from `from` to `to` and a pixel
    /// beyond (yaw, attitude and the keyframe's attitude as in `to`).
    /// Wheels that slip leave the truth anywhere between standing still
    /// and the odometry, beyond the alignment's reach of both.
    pub(super) fn search_translation(&mut self, images: &Images, from: &Geometry, to: &Geometry) -> Geometry {
        let step_mm = pyramid::scale(LEVELS - 1) as f32 * images.grid.mm_per_px as f32;
        let axis = |k: usize| {
            let (lo, hi) = (from[k].min(to[k]) - step_mm, from[k].max(to[k]) + step_mm);
            // Saturating: a degenerate box (infinite, from a wild prior) is
            // as many steps as allowed, not an overflow.
            let steps = (((hi - lo) / step_mm) as usize).saturating_add(1).min(SEARCH_STEPS);
            (lo, (hi - lo) / (steps.max(2) - 1) as f32, steps)
        };
        let (x0, dx, nx) = axis(0);
        let (z0, dz, nz) = axis(1);
        let candidates = (0..nx).flat_map(|a| (0..nz).map(move |b| (a, b))).map(|(a, b)| {
            let mut p = *to;
            (p[0], p[1]) = (x0 + a as f32 * dx, z0 + b as f32 * dz);
            p
        });
        self.best_on_top_level(images, to, candidates)
    }

    /// The attitude change that best explains the top level, searched on
    /// a grid around `start`'s within `reach_deg` each way (pitch and roll,
    /// the rest as in `start`). A body that pitched a degree or more moves
    /// the far ground by several top-level pixels: beyond the alignment's
    /// own reach.
    pub(super) fn search_attitude(&mut self, images: &Images, start: &Geometry, reach_deg: f32) -> Geometry {
        // The step that moves the farthest ground by about a top-level
        // pixel: dz/dpitch = (z^2 + h^2) / h.
        let grid = images.grid;
        let (h, far) = (images.height_mm, grid.z_far_mm as f32);
        let pixel_deg = (pyramid::scale(LEVELS - 1) as f32 * grid.mm_per_px as f32 * h / (far * far + h * h)).to_degrees();
        let steps = (libm::ceilf(reach_deg / pixel_deg) as usize).clamp(1, ATTITUDE_SEARCH_STEPS);
        let step = reach_deg / steps as f32;
        let offset = move |k: usize| (k as f32 - steps as f32) * step;
        let span = 2 * steps + 1;
        let candidates = (0..span).flat_map(|a| (0..span).map(move |b| (a, b))).map(|(a, b)| {
            let mut p = *start;
            p[3] += offset(a);
            p[4] += offset(b);
            p
        });
        self.best_on_top_level(images, start, candidates)
    }

    /// How badly `aligned` explains the finest level's pixels from grid
    /// row `near_row` on: the sum of their capped squared residuals over
    /// `scale` (Tukey's loss, in units of one pixel's full miss), and how
    /// many took part.
    pub(super) fn misfit(&mut self, images: &Images, aligned: &Alignment, near_row: usize, scale: f32) -> (f32, usize) {
        let current = self.current.level(0, images.current, images.seen);
        let keyframe = self.keyframe.level(0, images.keyframe, images.seen);
        let points = &mut self.points;
        let state = State { p: aligned.p, gain: aligned.exposure.0, offset: aligned.exposure.1, lower: aligned.lower };
        if points.evaluated != Some((state, near_row)) {
            points.select(&current, self.chosen.level(0), near_row);
            points.residuals(images, &keyframe, 0, &state);
        }
        let (mut sum, mut count) = (0.0, 0);
        for &r in &points.residuals[..points.points.len()] {
            if r.is_nan() {
                continue;
            }
            count += 1;
            let t = crate::kernels::sqrtf(Loss::Tukey.weight(r, scale));
            sum += 1.0 - t * t * t;
        }
        (sum, count)
    }
}

impl Points {
    /// The median of the points' gradient lengths (in half gray levels).
    fn median_gradient(&self) -> f32 {
        let mut histogram = [0u16; 256];
        for point in self.points.iter() {
            histogram[usize::from(point.gradient_bin)] += 1;
        }
        let half = self.points.len().div_ceil(2);
        let mut count = 0usize;
        for (bin, &n) in histogram.iter().enumerate() {
            count += usize::from(n);
            if count >= half {
                return (bin as f32 + 0.5) * 0.5;
            }
        }
        128.0
    }
}

/// A lower level's depth: its finite-difference step and its prior's
/// sigma (mm; wide, the prior only keeps the system solvable).
const DEPTH_STEP_MM: f32 = 1.0;
const DEPTH_SIGMA_MM: f32 = 1000.0;
/// Whether the far level may also lie above the ground (a curb top, the
/// ground around a box that stands beyond the AOI): its own plane keeps
/// it from tilting the ground's.
const FAR_LEVEL_RAISED: bool = true;
/// Pixels each level needs before it counts as one.
const LEVEL_MIN_POINTS: usize = 30;
/// Gauss-Newton steps of the two-level model after the edge is chosen.
const LOWER_LEVEL_ITERATIONS: usize = 2;

impl Direct {
    /// Whether the far view is a level of its own below the ground (a
    /// drop's lower level), which `aligned`, the ground alone, explained
    /// by bending its motion (at 1.3 m, 0.07 degree of pitch moves the
    /// ground as far as a 25 mm drop's parallax after 100 mm). Every
    /// boundary between the finest level's block rows is tried as the
    /// edge, the level's depth a tenth unknown: one Gauss-Newton step of
    /// the bordered system from `aligned`, whose decrease of chi-square is
    /// exact for the linearised model (prefix sums over the rows make each
    /// edge a 10 x 10 solve). The best edge with a level below the ground
    /// is then refined if its decrease of chi-square (in pixels' residual
    /// variance, [`CORRELATION`] included) exceeds `adopted_from_chi2`.
    /// Returns it and that decrease, or None.
    #[inline(never)]
    pub(super) fn lower_level(&mut self, images: &Images, prior: &Prior, aligned: &Alignment, adopted_from_chi2: f32) -> Option<(Alignment, f32)> {
        let current = self.current.level(0, images.current, images.seen);
        let keyframe = self.keyframe.level(0, images.keyframe, images.seen);
        let points = &mut self.points;
        points.select(&current, self.chosen.level(0), 0);
        points.jacobians_with(images, 0, &aligned.p, true);
        // The keyframe's attitude held at its prior: with it free, a single
        // plane bends far enough to mimic most of a lower level.
        let mut state = State { p: aligned.p, gain: aligned.exposure.0, offset: aligned.exposure.1, lower: None };
        state.p[5] = prior.mean[5];
        state.p[6] = prior.mean[6];
        let (sampled, scale) = points.residuals(images, &keyframe, 0, &state);
        if sampled < 2 * LEVEL_MIN_POINTS {
            return None;
        }
        let variance = scale * scale * CORRELATION;
        let (mut normal, _) = points.accumulate(Loss::Tukey, scale);
        add_priors(&mut normal, &state, prior, scale);
        hold_keyframe_attitude(&mut normal);
        let ground = GroundFactor::of(&normal)?;
        let base = ground.reduction()?;
        let mut border = Border::default();
        let mut best: Option<(f32, f32, [f32; UNKNOWNS + 1])> = None;
        let mut far = 0;
        let side = points.side;
        for (k, point) in points.points.iter().enumerate() {
            let starts_block_row = k > 0 && usize::from(point.j) / side != usize::from(points.points[k - 1].j) / side;
            if starts_block_row && far >= LEVEL_MIN_POINTS && sampled - far >= LEVEL_MIN_POINTS {
                if let Some((decrease, step)) = ground.bordered(&border, variance, base) {
                    let chi2 = decrease / variance;
                    // The level's depth is minus the step's last entry.
                    if (FAR_LEVEL_RAISED || step[UNKNOWNS] < 0.0) && best.is_none_or(|(b, _, _)| chi2 > b) {
                        best = Some((chi2, (usize::from(point.j) / side * side) as f32 - 0.5, step));
                    }
                }
            }
            if points.residuals[k].is_nan() {
                continue;
            }
            far += 1;
            border.add(point, points.residuals[k], points.samples[k], scale);
        }
        let (chi2, edge_row, mut step) = best?;
        // Refined only when it could be adopted: the refinement is most of the cost.
        if chi2 <= adopted_from_chi2 {
            return None;
        }
        let mut depth_mm = 0.0;
        for _ in 0..LOWER_LEVEL_ITERATIONS {
            for (p, s) in state.p.iter_mut().zip(&step[..GEOMETRY]) {
                *p -= s;
            }
            state.gain -= step[GEOMETRY];
            state.offset -= step[GEOMETRY + 1];
            depth_mm -= step[UNKNOWNS];
            if !(depth_mm > -0.8 * images.height_mm && depth_mm < 4.0 * images.height_mm && state.p.iter().all(|v| v.is_finite())) {
                return None;
            }
            state.lower = Some(Lower { edge_row, depth_mm });
            let (_, scale) = points.residuals(images, &keyframe, 0, &state);
            let (mut normal, _) = points.accumulate(Loss::Tukey, scale);
            add_priors(&mut normal, &state, prior, scale);
            hold_keyframe_attitude(&mut normal);
            let mut border = Border::default();
            for (k, point) in points.points.iter().enumerate() {
                if to_grid(0, u16::from(point.j)) < edge_row && !points.residuals[k].is_nan() {
                    border.add(point, points.residuals[k], points.samples[k], scale);
                }
            }
            border.dd += scale * scale * CORRELATION / (DEPTH_SIGMA_MM * DEPTH_SIGMA_MM);
            step = solve_bordered(&normal, &border)?;
        }
        Some((Alignment { p: state.p, exposure: (state.gain, state.offset), lower: state.lower, ..*aligned }, chi2))
    }
}

/// Takes the keyframe's attitude out of the normal equations: its step is 0.
fn hold_keyframe_attitude(normal: &mut Normal) {
    for k in HELD_FROM..GEOMETRY {
        for other in 0..UNKNOWNS {
            normal.h[k][other] = 0.0;
            normal.h[other][k] = 0.0;
        }
        normal.h[k][k] = 1.0;
        normal.g[k] = 0.0;
    }
}

/// Adds each unknown's prior to the normal equations, weighed against
/// pixels of residual `scale`.
fn add_priors(normal: &mut Normal, state: &State, prior: &Prior, scale: f32) {
    let variance = scale * scale * CORRELATION;
    let mut add = |k: usize, value: f32, mean: f32, sigma: f32| {
        let weight = variance / (sigma * sigma);
        normal.h[k][k] += weight;
        normal.g[k] += weight * (value - mean);
    };
    for k in 0..GEOMETRY {
        add(k, state.p[k], prior.mean[k], prior.sigma[k]);
    }
    add(GEOMETRY, state.gain, 1.0, GAIN_SIGMA);
    add(GEOMETRY + 1, state.offset, 128.0, OFFSET_SIGMA);
}

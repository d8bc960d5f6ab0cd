//! The motion estimate's robust least squares: the parameters that put
//! the matched blocks where they were found in the keyframe, with Tukey
//! weights (obstacles, whose blocks move by parallax, are outliers) and a
//! prior on every parameter.
//!
//! Two models: the ground alone (five parameters: tx, tz, yaw, pitch,
//! roll), and the ground with the view past one row of blocks on a level
//! of its own (a sixth: that level's depth below the ground). The second
//! tells a drop's lower level from a pitch change: a lower level moves
//! less than the floor by the same amount at every distance, a pitch
//! change moves the ground more the farther it is.

use super::estimate::BlockMatch;
use super::homography::PixelMap;
use crate::grid::KgGrid;
use crate::kernels;
use crate::limits::MAX_BLOCK_MATCHES;

/// Where a model puts the blocks: the ground's map, and past `edge_row`
/// (rows above it are farther) a lower level.
#[derive(Clone, Copy, Debug)]
pub(super) struct Surfaces {
    ground: PixelMap,
    lower: Option<Lower>,
}

#[derive(Clone, Copy, Debug)]
struct Lower {
    edge_row: f32,
    /// The motion's map for a plane as far below the camera as the level.
    map: PixelMap,
    /// How much nearer a point of the level appears than it is: H / (H + d).
    apparent: f32,
    /// The grid's pixel -> ground offsets (mm): x = left + m i, z = far - m j.
    left_px: f32,
    far_px: f32,
}

impl Lower {
    /// Pixel (i, j) of the point at `factor` times pixel (i, j)'s ground
    /// position (the scaling is about the robot origin on the ground).
    fn scaled(&self, (i, j): (f32, f32), factor: f32) -> (f32, f32) {
        ((i + self.left_px) * factor - self.left_px, (j - self.far_px) * factor + self.far_px)
    }
}

impl Surfaces {
    /// The ground alone.
    pub(super) fn ground(ground: PixelMap) -> Surfaces {
        Surfaces { ground, lower: None }
    }

    /// The ground, and past `edge_row` a level `depth_mm` below it (`lower`:
    /// the motion's map of a ground `height_mm + depth_mm` below the camera),
    /// the ground seen from `height_mm`.
    pub(super) fn two_levels(ground: PixelMap, lower: PixelMap, grid: &KgGrid, height_mm: f32, edge_row: f32, depth_mm: f32) -> Surfaces {
        let m = grid.mm_per_px as f32;
        let lower = Lower {
            edge_row,
            map: lower,
            apparent: height_mm / (height_mm + depth_mm),
            left_px: grid.x_left_mm as f32 / m,
            far_px: grid.z_far_mm as f32 / m,
        };
        Surfaces { ground, lower: Some(lower) }
    }

    /// Keyframe pixel of the current block `m`'s centre.
    pub(super) fn place(&self, m: &BlockMatch) -> Option<(f32, f32)> {
        match self.lower {
            Some(lower) if m.current.1 < lower.edge_row => {
                let (i, j) = lower.scaled(m.current, 1.0 / lower.apparent);
                let there = lower.map.at(i, j)?;
                Some(lower.scaled(there, lower.apparent))
            }
            _ => self.ground.at(m.current.0, m.current.1),
        }
    }

    /// How far from where it was found the model puts block `m`, KG px.
    pub(super) fn residual(&self, m: &BlockMatch) -> Option<f32> {
        self.place(m).map(|at| kernels::hypotf(at.0 - m.keyframe.0, at.1 - m.keyframe.1))
    }
}

/// What a fit moves: `N` parameters, how each is turned into the model,
/// its finite-difference step, and the prior (mean, one sigma).
pub(super) struct Problem<'a, const N: usize> {
    pub(super) surfaces: &'a dyn Fn(&[f32; N]) -> Surfaces,
    pub(super) step: [f32; N],
    pub(super) prior: [f32; N],
    pub(super) sigma: [f32; N],
    /// Fewest blocks that must agree with the result.
    pub(super) min_inliers: usize,
}

/// A fit's result.
#[derive(Clone, Copy, Debug)]
pub(super) struct Solution<const N: usize> {
    pub(super) p: [f32; N],
    /// The robust scale of the residuals (KG px).
    pub(super) scale: f32,
    /// The last step's normal matrix (prior included), for the variances.
    normal: [[f32; N]; N],
}

impl<const N: usize> Solution<N> {
    /// Each parameter's variance after the fit (prior and blocks, the
    /// blocks' errors taken as independent at `scale`): the diagonal of
    /// the normal matrix's inverse, one column at a time. Asked for only
    /// where it is used: most fits are not.
    // Not inlined: its copies of the matrix would sit under the fit's frame.
    #[inline(never)]
    pub(super) fn variance(&self) -> Option<[f32; N]> {
        let factor = cholesky(self.normal)?;
        let mut variance = [0f32; N];
        for (k, v) in variance.iter_mut().enumerate() {
            let unit: [f32; N] = core::array::from_fn(|i| if i == k { 1.0 } else { 0.0 });
            *v = substitute(&factor, unit)[k];
        }
        Some(variance)
    }
}

// `robust_fit` indexes the matches with u8.
const _: () = assert!(MAX_BLOCK_MATCHES <= 256);

/// The parameters from `start` and the robust scale of the residuals
/// (MAD, floored: sub-pixel matches are not better than ~0.1 px); None
/// when too few blocks agree with the result.
#[inline(never)] // Its arrays (1.3 KB) would otherwise sit in every caller's frame, under the block matcher's.
pub(super) fn robust_fit<const N: usize>(matches: &[BlockMatch], start: [f32; N], problem: &Problem<N>) -> Option<Solution<N>> {
    if matches.len() < problem.min_inliers {
        return None;
    }
    let step = problem.step;
    let mut p = start;
    let mut scale = 1.0f32;
    let mut residuals = [0f32; MAX_BLOCK_MATCHES];
    // The median is selected through the residuals' indices: 256 B of
    // stack, not a 1 KB copy of them.
    let mut order = [0u8; MAX_BLOCK_MATCHES];
    for (n, index) in order.iter_mut().enumerate() {
        *index = n as u8;
    }
    let mut normal = [[0f32; N]; N];
    for iteration in 0..8 {
        let surfaces = (problem.surfaces)(&p);
        // Filled in place: `array::from_fn` builds a second array to move.
        let mut moved = [surfaces; N];
        for (k, stepped) in moved.iter_mut().enumerate() {
            let mut q = p;
            q[k] += step[k];
            *stepped = (problem.surfaces)(&q);
        }
        let count = matches.len();
        for (m, r) in matches.iter().zip(residuals.iter_mut()) {
            *r = surfaces.residual(m).unwrap_or(f32::MAX);
        }
        // The median: the element a full sort would put in the middle.
        let by_residual = |a: &u8, b: &u8| residuals[usize::from(*a)].total_cmp(&residuals[usize::from(*b)]);
        let (_, &mut middle, _) = order[..count].select_nth_unstable_by(count / 2, by_residual);
        let median = residuals[usize::from(middle)];
        scale = (1.4826 * median).max(0.15);
        // Huber first (wide basin), Tukey after (rejects obstacles).
        let weight = |r: f32| -> f32 {
            if iteration < 3 {
                let k = 2.0 * scale;
                if r <= k { 1.0 } else { k / r }
            } else {
                let c = 4.685 * scale;
                if r >= c {
                    0.0
                } else {
                    let u = 1.0 - (r / c) * (r / c);
                    u * u
                }
            }
        };
        normal = [[0f32; N]; N];
        let mut gradient = [0f32; N];
        for (m, &r) in matches.iter().zip(residuals.iter()) {
            let w = weight(r) / (scale * scale);
            if w == 0.0 {
                continue;
            }
            let Some(at) = surfaces.place(m) else { continue };
            let error = [at.0 - m.keyframe.0, at.1 - m.keyframe.1];
            let mut jacobian = [[0f32; N]; 2];
            for k in 0..N {
                let Some(there) = moved[k].place(m) else { continue };
                jacobian[0][k] = (there.0 - at.0) / step[k];
                jacobian[1][k] = (there.1 - at.1) / step[k];
            }
            // The lower triangle only: the normal matrix is symmetric, and
            // the Cholesky factorisation reads no other half.
            for axis in 0..2 {
                for a in 0..N {
                    gradient[a] += w * jacobian[axis][a] * error[axis];
                    for b in 0..=a {
                        normal[a][b] += w * jacobian[axis][a] * jacobian[axis][b];
                    }
                }
            }
        }
        mirror_lower_triangle(&mut normal);
        for k in 0..N {
            let precision = 1.0 / (problem.sigma[k] * problem.sigma[k]);
            normal[k][k] += precision;
            gradient[k] += precision * (p[k] - problem.prior[k]);
        }
        let delta = solve(normal, gradient)?;
        for k in 0..N {
            p[k] -= delta[k];
        }
        if delta.iter().zip(step).all(|(d, s)| libm::fabsf(*d) < 0.05 * s) {
            break;
        }
    }
    // Inliers: within 3 scales of the final model.
    let surfaces = (problem.surfaces)(&p);
    let inliers = matches.iter().filter_map(|m| surfaces.residual(m)).filter(|&r| r < 3.0 * scale).count();
    // A model most blocks disagree with is a wrong one (or the view is mostly obstacle).
    if inliers < problem.min_inliers || 3 * inliers < matches.len() {
        return None;
    }
    Some(Solution { p, scale, normal })
}

/// How much worse `surfaces` explains `matches` than a model whose
/// residual scale is `scale`: the sum of squared residuals in that scale,
/// each capped at 3 (an outlier counts once, not by its size).
pub(super) fn capped_chi2(matches: &[BlockMatch], surfaces: &Surfaces, scale: f32) -> f32 {
    const CAP: f32 = 3.0;
    matches.iter().map(|m| surfaces.residual(m).map_or(CAP, |r| (r / scale).min(CAP))).map(|r| r * r).sum()
}

/// Copies the lower triangle of `a` onto its upper one.
#[allow(clippy::needless_range_loop)]
fn mirror_lower_triangle<const N: usize>(a: &mut [[f32; N]; N]) {
    for row in 0..N {
        for column in row + 1..N {
            a[row][column] = a[column][row];
        }
    }
}

/// Solves the NxN symmetric positive definite system (Cholesky); None if singular.
fn solve<const N: usize>(a: [[f32; N]; N], b: [f32; N]) -> Option<[f32; N]> {
    Some(substitute(&cholesky(a)?, b))
}

/// The lower triangle L of a = L L^T; None if `a` is not positive definite.
// Indexed loops on purpose: the factorisation is written as in the textbook.
#[allow(clippy::needless_range_loop)]
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(sum > 0.0)` also refuses NaN
fn cholesky<const N: usize>(a: [[f32; N]; N]) -> Option<[[f32; N]; N]> {
    let mut l = [[0f32; N]; N];
    for i in 0..N {
        for j in 0..=i {
            let mut sum = a[i][j];
            for k in 0..j {
                sum -= l[i][k] * l[j][k];
            }
            if i == j {
                if !(sum > 0.0) {
                    return None;
                }
                l[i][i] = kernels::sqrtf(sum);
            } else {
                l[i][j] = sum / l[j][j];
            }
        }
    }
    Some(l)
}

/// x with L L^T x = b, L from [`cholesky`].
#[allow(clippy::needless_range_loop)]
fn substitute<const N: usize>(l: &[[f32; N]; N], b: [f32; N]) -> [f32; N] {
    let mut y = [0f32; N];
    for i in 0..N {
        let mut sum = b[i];
        for k in 0..i {
            sum -= l[i][k] * y[k];
        }
        y[i] = sum / l[i][i];
    }
    let mut x = [0f32; N];
    for i in (0..N).rev() {
        let mut sum = y[i];
        for k in i + 1..N {
            sum -= l[k][i] * x[k];
        }
        x[i] = sum / l[i][i];
    }
    x
}

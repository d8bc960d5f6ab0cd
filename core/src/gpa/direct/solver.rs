//! The normal equations' solutions: Cholesky after Jacobi scaling, and the
//! ground's factor bordered by a lower level's depth.

use super::*;

/// The lower level's row and column of the bordered normal equations.
#[derive(Default)]
pub(super) struct Border {
    pub(super) h: [f32; UNKNOWNS],
    pub(super) dd: f32,
    pub(super) g: f32,
}

impl Border {
    /// Adds a point of the level, not to the keyframe's attitude, which
    /// [`Direct::lower_level`] holds (the point's [`DEPTH`] slot holds the
    /// depth derivative).
    pub(super) fn add(&mut self, point: &Point, r: f32, sample: f32, scale: f32) {
        let weight = Loss::Tukey.weight(r, scale);
        if weight == 0.0 {
            return;
        }
        let depth = point.jacobian[DEPTH];
        let wd = weight * depth;
        for k in 0..HELD_FROM {
            self.h[k] += wd * point.jacobian[k];
        }
        self.h[GEOMETRY] += wd * (sample - 128.0);
        self.h[GEOMETRY + 1] += wd;
        self.dd += wd * depth;
        self.g += wd * r;
    }
}

/// The ground's normal equations factored once for every candidate edge
/// of a lower level: the bordered system's factor and forward pass share
/// their first [`UNKNOWNS`] rows with them (Cholesky goes row by row), so
/// each edge adds only its own row: the same arithmetic, a third of it.
pub(super) struct GroundFactor {
    factor: Factor,
    /// The forward pass of the ground's gradient, `L^-1 g` (scaled).
    forward: [f32; UNKNOWNS],
    g: [f32; UNKNOWNS],
}

impl GroundFactor {
    #[inline(never)]
    pub(super) fn of(normal: &Normal) -> Option<GroundFactor> {
        let factor = cholesky(&normal.h)?;
        Some(GroundFactor { forward: forward(&factor, &normal.g), factor, g: normal.g })
    }

    /// g^T H^-1 g: how much one Gauss-Newton step lowers the chi-square.
    pub(super) fn reduction(&self) -> Option<f32> {
        let x = back(&self.factor, &self.forward, None);
        x.iter().all(|v| v.is_finite()).then_some(x.iter().zip(&self.g).map(|(x, g)| x * g).sum())
    }

    /// The step of the normal equations bordered by a lower level's depth
    /// (what [`cholesky`] and [`cholesky_solve`] of the bordered system
    /// compute, its last row alone computed here).
    #[inline(never)]
    fn bordered_step(&self, border: &Border) -> Option<[f32; UNKNOWNS + 1]> {
        let (l, scales) = &self.factor;
        // Not positive, or NaN.
        if border.dd.is_nan() || border.dd <= 0.0 {
            return None;
        }
        let last_scale = 1.0 / crate::kernels::sqrtf(border.dd);
        let mut last = [0.0f32; UNKNOWNS];
        for c in 0..UNKNOWNS {
            let mut sum = border.h[c] * last_scale * scales[c];
            for (a, b) in last[..c].iter().zip(&l[c][..c]) {
                sum -= a * b;
            }
            last[c] = sum / l[c][c];
        }
        let mut sum = border.dd * last_scale * last_scale;
        for a in &last {
            sum -= a * a;
        }
        // Not positive, or NaN.
        if sum.is_nan() || sum <= 1e-9 {
            return None;
        }
        let diagonal = crate::kernels::sqrtf(sum);
        let mut sum = border.g * last_scale;
        for (a, y) in last.iter().zip(&self.forward) {
            sum -= a * y;
        }
        let x_last = sum / diagonal / diagonal;
        let x = back(&self.factor, &self.forward, Some((&last, x_last)));
        let step: [f32; UNKNOWNS + 1] = core::array::from_fn(|k| if k < UNKNOWNS { x[k] } else { x_last * last_scale });
        step.iter().all(|v| v.is_finite()).then_some(step)
    }

    /// [`Self::bordered_step`] at a candidate edge, and its decrease of
    /// chi-square beyond the ground alone's (`base`).
    pub(super) fn bordered(&self, border: &Border, variance: f32, base: f32) -> Option<(f32, [f32; UNKNOWNS + 1])> {
        let border = Border { h: border.h, dd: border.dd + variance / (DEPTH_SIGMA_MM * DEPTH_SIGMA_MM), g: border.g };
        let step = self.bordered_step(&border)?;
        let mut decrease: f32 = step[..UNKNOWNS].iter().zip(&self.g).map(|(x, g)| x * g).sum();
        decrease += step[UNKNOWNS] * border.g;
        Some((decrease - base, step))
    }
}

/// The step of the normal equations bordered by a lower level's depth.
pub(super) fn solve_bordered(normal: &Normal, border: &Border) -> Option<[f32; UNKNOWNS + 1]> {
    GroundFactor::of(normal)?.bordered_step(border)
}

/// A Cholesky factor after Jacobi scaling: (L, the scales).
pub(super) type Factor = ([[f32; UNKNOWNS]; UNKNOWNS], [f32; UNKNOWNS]);

/// The Cholesky factor of the symmetric `h` (upper triangle given) after
/// Jacobi scaling; None unless positive definite.
pub(super) fn cholesky(h: &[[f32; UNKNOWNS]; UNKNOWNS]) -> Option<Factor> {
    let mut scales = [0.0; UNKNOWNS];
    for k in 0..UNKNOWNS {
        // Not positive, or NaN.
        if h[k][k].is_nan() || h[k][k] <= 0.0 {
            return None;
        }
        scales[k] = 1.0 / crate::kernels::sqrtf(h[k][k]);
    }
    let mut l = [[0.0f32; UNKNOWNS]; UNKNOWNS];
    for r in 0..UNKNOWNS {
        for c in 0..=r {
            let mut sum = h[c][r] * scales[r] * scales[c];
            for (a, b) in l[r][..c].iter().zip(&l[c][..c]) {
                sum -= a * b;
            }
            if r == c {
                // Not positive, or NaN.
                if sum.is_nan() || sum <= 1e-9 {
                    return None;
                }
                l[r][r] = crate::kernels::sqrtf(sum);
            } else {
                l[r][c] = sum / l[c][c];
            }
        }
    }
    Some((l, scales))
}

/// Solves H x = b with H's factor.
pub(super) fn cholesky_solve(factor: &Factor, b: &[f32; UNKNOWNS]) -> [f32; UNKNOWNS] {
    back(factor, &forward(factor, b), None)
}

/// The forward pass: y = L^-1 (scaled b).
fn forward((l, scales): &Factor, b: &[f32; UNKNOWNS]) -> [f32; UNKNOWNS] {
    let mut y = [0.0f32; UNKNOWNS];
    for r in 0..UNKNOWNS {
        let mut sum = b[r] * scales[r];
        for k in 0..r {
            sum -= l[r][k] * y[k];
        }
        y[r] = sum / l[r][r];
    }
    y
}

/// The back pass: x = L^-T y, scaled back. With `border` (a bordering
/// row of L, and its unknown's x), that row's term is subtracted last, as
/// the bordered system's own back pass would.
fn back((l, scales): &Factor, y: &[f32; UNKNOWNS], border: Option<(&[f32; UNKNOWNS], f32)>) -> [f32; UNKNOWNS] {
    let mut x = [0.0f32; UNKNOWNS];
    for r in (0..UNKNOWNS).rev() {
        let mut sum = y[r];
        for k in r + 1..UNKNOWNS {
            sum -= l[k][r] * x[k];
        }
        if let Some((row, x_border)) = border {
            sum -= row[r] * x_border;
        }
        x[r] = sum / l[r][r];
    }
    core::array::from_fn(|k| x[k] * scales[k])
}

/// The step x of H x = g; None when H is not positive definite.
pub(super) fn solve(h: &[[f32; UNKNOWNS]; UNKNOWNS], g: &[f32; UNKNOWNS]) -> Option<[f32; UNKNOWNS]> {
    let factor = cholesky(h)?;
    let x = cholesky_solve(&factor, g);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_solver_inverts_a_symmetric_system() {
        // The upper triangle, as `accumulate` fills it.
        let h: [[f32; UNKNOWNS]; UNKNOWNS] = core::array::from_fn(|r| {
            core::array::from_fn(|c| match c.cmp(&r) {
                core::cmp::Ordering::Equal => 10.0 + r as f32 * 100.0,
                core::cmp::Ordering::Greater => 1.0 + (r + c) as f32 * 0.1,
                core::cmp::Ordering::Less => 0.0,
            })
        });
        let truth: [f32; UNKNOWNS] = core::array::from_fn(|k| k as f32 - 3.0);
        let g: [f32; UNKNOWNS] = core::array::from_fn(|r| (0..UNKNOWNS).map(|c| if c >= r { h[r][c] } else { h[c][r] } * truth[c]).sum());
        let x = solve(&h, &g).unwrap();
        for k in 0..UNKNOWNS {
            assert!((x[k] - truth[k]).abs() < 1e-3, "{x:?}");
        }
    }
}

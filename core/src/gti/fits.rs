//! From a locus to a height: the robust line fit of a track's observations
//! (Theil-Sen, then least squares over its inliers), slope <-> height
//! (eq. 12), a point's height error and quality, and the height that several
//! points support together.

use crate::limits::MAX_OBSERVATIONS;
use crate::kernels::sqrtf;
use heapless::Vec;
use libm::{fabsf, roundf};

/// Observations at which the quality stops growing with their count.
const FULL_QUALITY_OBSERVATIONS: usize = 10;
/// Height error (mm) at which quality is halved.
const QUALITY_SIGMA_MM: f32 = 3.0;
/// Good points [`super::Gti::height_in_region`] needs at one height.
pub(super) const MIN_SUPPORT: usize = 3;
/// Points within this height (or this fraction of it) support each other in
/// [`super::Gti::height_in_region`].
const SUPPORT_TOLERANCE_MM: f32 = 6.0;
const SUPPORT_TOLERANCE_FRACTION: f32 = 0.06;

/// Height (mm) of a point whose apparent ground position moves `slope` times
/// the distance travelled: eq. (12), h = H (1 - 1/s).
fn height_from_slope(mount_height_mm: f32, slope: f32) -> f32 {
    mount_height_mm * (1.0 - 1.0 / slope)
}

/// Inverse of [`height_from_slope`]: s = H / (H - h) (the tests' way to a slope).
#[cfg(test)]
fn slope_from_height(mount_height_mm: f32, height_mm: f32) -> f32 {
    mount_height_mm / (mount_height_mm - height_mm)
}

/// Slope range a locus may have: h from a drop as deep as the camera is
/// high (a lower level past an edge, s = 1/2) to near the camera.
pub(super) fn slope_plausible(slope: f32) -> bool {
    (0.5..=20.0).contains(&slope)
}

/// A straight-line fit `y = intercept + slope * x`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct LineFit {
    pub slope: f32,
    pub intercept: f32,
    /// Robust residual scale of the inliers (RMS), in y units.
    pub residual: f32,
    /// Points the final fit used.
    pub inliers: usize,
    /// Sum of squared x deviations of the inliers (for the slope's error).
    pub sxx: f32,
}

/// An f32 as an i32 that orders as [`f32::total_cmp`] orders the f32s (its
/// transform of the bits, which is its own inverse): [`median`] selects on
/// these, one integer comparison each on the M4 where `total_cmp` would
/// transform both sides of every comparison again.
pub(super) fn order_key(value: f32) -> i32 {
    flip_magnitude(value.to_bits() as i32)
}

/// The f32 of an [`order_key`].
pub(super) fn key_value(key: i32) -> f32 {
    f32::from_bits(flip_magnitude(key) as u32)
}

/// Negative values' magnitude bits inverted (the sign bit kept).
fn flip_magnitude(bits: i32) -> i32 {
    bits ^ (((bits >> 31) as u32) >> 1) as i32
}

/// Median of values given as [`order_key`]s, reordering them; None when
/// empty. Selected, not sorted (the same value; sorting the lines' noise
/// blocks was ~0.4 M M4 instructions a frame).
pub(super) fn median(keys: &mut [i32]) -> Option<f32> {
    median_of_parts(keys, &mut [])
}

/// [`median`] of the keys of `low` and `high` together, every key of `low`
/// below every key of `high`: only the part that holds the middle is selected.
// Inlined: [`median`]'s empty `high` then costs the small medians nothing.
#[inline(always)]
fn median_of_parts(low: &mut [i32], high: &mut [i32]) -> Option<f32> {
    let n = low.len() + high.len();
    if n == 0 {
        return None;
    }
    // The middle key and the keys before it in its part (`earlier`: those
    // of the low part when it is in the high one).
    let (before, upper, earlier): (&[i32], i32, &[i32]) = match n / 2 {
        k if k < low.len() => {
            let (before, &mut upper, _) = low.select_nth_unstable(k);
            (before, upper, &[])
        }
        k => {
            let (before, &mut upper, _) = high.select_nth_unstable(k - low.len());
            (before, upper, low)
        }
    };
    if n % 2 == 1 {
        Some(key_value(upper))
    } else {
        // The largest of the lower half: the element a sort puts just before.
        let lower = before.iter().copied().max().or_else(|| earlier.iter().copied().max())?;
        Some(0.5 * (key_value(lower) + key_value(upper)))
    }
}

/// Robust line fit of up to [`MAX_OBSERVATIONS`] points: Theil-Sen (median
/// of pairwise slopes, median intercept), then least squares over the points
/// within 3 robust sigmas of it. None with fewer than 2 points, unequal
/// lengths, or all x equal.
pub(super) fn robust_line_fit(x: &[f32], y: &[f32]) -> Option<LineFit> {
    let n = x.len();
    if n < 2 || n != y.len() || n > MAX_OBSERVATIONS {
        return None;
    }
    // The pairs' slopes as order keys, those below a pivot kept ahead of the
    // others: the median is then selected in one part only. Any pivot gives
    // the same median; the slope across the whole run, near it, halves the
    // part. A Vec, not an array: the M4 would clear all 480 bytes on every refit.
    let mut slopes: Vec<i32, { MAX_OBSERVATIONS * (MAX_OBSERVATIONS - 1) / 2 }> = Vec::new();
    let pivot = order_key((y[n - 1] - y[0]) / (x[n - 1] - x[0]));
    let mut below = 0;
    for a in 0..n {
        let (xa, ya) = (x[a], y[a]);
        for b in a + 1..n {
            let dx = x[b] - xa;
            if fabsf(dx) > 1e-6 {
                let key = order_key((y[b] - ya) / dx);
                if slopes.push(key).is_ok() && key < pivot {
                    let last = slopes.len() - 1;
                    slopes.swap(below, last);
                    below += 1;
                }
            }
        }
    }
    let (low, high) = slopes.split_at_mut(below);
    let slope = median_of_parts(low, high)?;
    let mut scratch = [0i32; MAX_OBSERVATIONS];
    for (slot, (xi, yi)) in scratch.iter_mut().zip(x.iter().zip(y)) {
        *slot = order_key(yi - slope * xi);
    }
    let intercept = median(scratch.get_mut(..n)?)?;
    for (slot, (xi, yi)) in scratch.iter_mut().zip(x.iter().zip(y)) {
        *slot = order_key(fabsf(yi - intercept - slope * xi));
    }
    let mad = median(scratch.get_mut(..n)?)?;
    // Floor on the gate: exact data has MAD 0 and every point is an inlier.
    let gate = 3.0 * 1.4826 * mad + 1e-3 * (1.0 + fabsf(intercept));
    let inlier = |i: usize| fabsf(y[i] - intercept - slope * x[i]) <= gate;
    let (mut sx, mut sy, mut m) = (0f32, 0f32, 0usize);
    for i in (0..n).filter(|&i| inlier(i)) {
        sx += x[i];
        sy += y[i];
        m += 1;
    }
    if m < 2 {
        return None;
    }
    let (mx, my) = (sx / m as f32, sy / m as f32);
    let (mut sxx, mut sxy) = (0f32, 0f32);
    for i in (0..n).filter(|&i| inlier(i)) {
        sxx += (x[i] - mx) * (x[i] - mx);
        sxy += (x[i] - mx) * (y[i] - my);
    }
    if !(sxx > 1e-6) {
        return None;
    }
    let slope = sxy / sxx;
    let intercept = my - slope * mx;
    let mut sum_sq = 0f32;
    for i in (0..n).filter(|&i| inlier(i)) {
        let r = y[i] - intercept - slope * x[i];
        sum_sq += r * r;
    }
    // Unbiased with two fitted parameters; a 2-point fit has no residual.
    let residual = if m > 2 { sqrtf(sum_sq / (m - 2) as f32) } else { 0.0 };
    Some(LineFit { slope, intercept, residual, inliers: m, sxx })
}

/// The height a locus fit gives and how sure it is.
pub(super) struct FittedHeight {
    pub h_mm: f32,
    /// Standard error of the height, mm.
    pub h_sigma_mm: f32,
    /// `100 * min(1, n / FULL_QUALITY_OBSERVATIONS) * QUALITY_SIGMA_MM / (QUALITY_SIGMA_MM + h_sigma_mm)`
    /// with n the fit's inliers.
    pub quality: u8,
}

impl FittedHeight {
    /// For a fit of slope `slope` (the locus falls by it: `slope = -fit.slope`);
    /// `mm_per_px` floors the residual (a perfect fit is not infinitely sure).
    pub(super) fn new(fit: &LineFit, slope: f32, mount_height_mm: f32, mm_per_px: f32) -> FittedHeight {
        let position_sigma = fit.residual.max(0.05 * mm_per_px);
        let slope_sigma = position_sigma / sqrtf(fit.sxx.max(1e-6));
        let h_sigma = mount_height_mm / (slope * slope) * slope_sigma;
        let count_factor = (fit.inliers as f32 / FULL_QUALITY_OBSERVATIONS as f32).min(1.0);
        let quality = 100.0 * count_factor * QUALITY_SIGMA_MM / (QUALITY_SIGMA_MM + h_sigma);
        FittedHeight {
            h_mm: height_from_slope(mount_height_mm, slope),
            h_sigma_mm: h_sigma,
            quality: roundf(quality).clamp(0.0, 100.0) as u8,
        }
    }
}

/// Heights within this of `h_mm` support it.
pub(super) fn support_tolerance(h_mm: f32) -> f32 {
    SUPPORT_TOLERANCE_MM.max(SUPPORT_TOLERANCE_FRACTION * fabsf(h_mm))
}

/// The height that at least [`MIN_SUPPORT`] heights reach together: the
/// highest run of [`MIN_SUPPORT`] consecutive heights (sorted) spanning at
/// most the support tolerance, and its median. A lone stray point cannot set
/// it, and lower points on an obstacle's side do not drag it down.
/// Reorders `heights`.
pub(super) fn top_supported_height(heights: &mut [f32]) -> Option<f32> {
    heights.sort_unstable_by(|a, b| b.total_cmp(a));
    heights
        .windows(MIN_SUPPORT)
        .find(|run| match (run.first(), run.last()) {
            (Some(&top), Some(&bottom)) => top - bottom <= support_tolerance(top),
            _ => false,
        })
        .and_then(|run| run.get(MIN_SUPPORT / 2).copied())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may panic
mod tests {
    use super::*;

    #[test]
    fn slope_and_height_invert() {
        assert!((height_from_slope(400.0, 1.0)).abs() < 1e-6);
        let s = slope_from_height(400.0, 120.0);
        assert!((s - 400.0 / 280.0).abs() < 1e-6);
        assert!((height_from_slope(400.0, s) - 120.0).abs() < 1e-3);
    }

    #[test]
    fn order_keys_order_as_total_cmp() {
        let values = [f32::NEG_INFINITY, -3.5, -1e-40, -0.0, 0.0, 1e-40, 0.25, 7.0, f32::MAX, f32::INFINITY, f32::NAN, -f32::NAN];
        for a in values {
            assert_eq!(key_value(order_key(a)).to_bits(), a.to_bits());
            for b in values {
                assert_eq!(order_key(a).cmp(&order_key(b)), a.total_cmp(&b), "{a} {b}");
            }
        }
    }

    #[test]
    fn median_of_parts_is_the_median() {
        let mut state = 0x5EED_F175u32;
        let mut next = || crate::selftest::xorshift32(&mut state);
        for _ in 0..5_000 {
            let n = 1 + next() as usize % 120;
            // Ties included: keys of a few values, or of many.
            let spread = [3, 50, 1 << 20][next() as usize % 3];
            let mut keys: Vec<i32, 120> = (0..n).map(|_| (next() % spread) as i32 - (spread / 2) as i32).collect();
            let pivot = keys[next() as usize % n] + (next() % 3) as i32 - 1;
            let mut parts: Vec<i32, 120> = keys.iter().copied().filter(|&k| k < pivot).collect();
            let below = parts.len();
            parts.extend(keys.iter().copied().filter(|&k| k >= pivot));
            let (low, high) = parts.split_at_mut(below);
            assert_eq!(median_of_parts(low, high).map(f32::to_bits), median(&mut keys).map(f32::to_bits));
        }
    }

    #[test]
    fn robust_fit_ignores_outliers() {
        let x: [f32; 12] = core::array::from_fn(|i| i as f32 * 20.0);
        let mut y: [f32; 12] = core::array::from_fn(|i| 50.0 - 1.4286 * x[i] + if i % 2 == 0 { 0.3 } else { -0.3 });
        y[3] += 40.0;
        y[8] -= 25.0;
        let fit = robust_line_fit(&x, &y).unwrap();
        assert!((fit.slope + 1.4286).abs() < 0.005, "slope {}", fit.slope);
        assert!((fit.intercept - 50.0).abs() < 1.0);
        assert_eq!(fit.inliers, 10);
        assert!(fit.residual < 0.5);
        assert_eq!(robust_line_fit(&[1.0, 1.0], &[0.0, 3.0]), None);
        assert_eq!(robust_line_fit(&[1.0], &[0.0]), None);
    }

    #[test]
    fn top_supported_height_needs_agreement() {
        let mut heights = [3.0, 118.0, 250.0, 121.0, 60.0, 119.5, 104.0, 2.0];
        assert_eq!(top_supported_height(&mut heights), Some(119.5));
        let mut pair = [250.0, 251.0, 2.0];
        assert_eq!(top_supported_height(&mut pair), None);
    }
}

//! Sub-pixel position of an extremum: the vertex of the parabola through
//! three equally spaced samples at -1, 0 and +1.
//!
//! Generic over the float type so each caller keeps its precision (GPA's
//! SAD minima in `f64`, GTI's gradient maxima in `f32`): the arithmetic is
//! the same, operation for operation, in either.

use core::ops::{Add, Div, Mul, Sub};

/// Offset in [-0.5, 0.5] of the minimum of the parabola through
/// (-1, `before`), (0, `centre`), (1, `after`); 0 when the parabola does not
/// open upwards (the centre is no strict minimum of its curve).
#[inline]
pub fn minimum_offset<T: Sample>(before: T, centre: T, after: T) -> T {
    vertex_offset(before, centre, after, |curvature| curvature > T::from(0.0))
}

/// Offset in [-0.5, 0.5] of the maximum of the parabola through
/// (-1, `before`), (0, `peak`), (1, `after`); 0 when the parabola does not
/// open downwards (or a sample is NaN).
#[inline]
pub fn maximum_offset<T: Sample>(before: T, peak: T, after: T) -> T {
    vertex_offset(before, peak, after, |curvature| curvature < T::from(0.0))
}

/// The float types the vertex is computed in (`f32`, `f64`).
pub trait Sample: Copy + PartialOrd + From<f32> + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self> {}
impl Sample for f32 {}
impl Sample for f64 {}

#[inline(always)]
fn vertex_offset<T: Sample>(before: T, centre: T, after: T, opens_right_way: impl Fn(T) -> bool) -> T {
    let curvature = before - T::from(2.0) * centre + after;
    if !opens_right_way(curvature) {
        return T::from(0.0);
    }
    let offset = T::from(0.5) * (before - after) / curvature;
    // As `clamp`, without its min <= max assertion.
    let (low, high) = (T::from(-0.5), T::from(0.5));
    if offset < low {
        low
    } else if offset > high {
        high
    } else {
        offset
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_vertex_of_either_kind() {
        // Samples of (x - 0.3)^2 and its negation at x = -1, 0, 1.
        let f = |x: f64| (x - 0.3) * (x - 0.3);
        assert!((minimum_offset(f(-1.0), f(0.0), f(1.0)) - 0.3).abs() < 1e-12);
        let g = |x: f32| -(x - 0.3) * (x - 0.3);
        assert!((maximum_offset(g(-1.0), g(0.0), g(1.0)) - 0.3).abs() < 1e-5);
    }

    #[test]
    fn flat_or_wrong_way_is_zero_and_far_is_clamped() {
        assert_eq!(minimum_offset(1.0f64, 1.0, 1.0), 0.0);
        assert_eq!(minimum_offset(0.0f64, 1.0, 0.0), 0.0);
        assert_eq!(maximum_offset(1.0f32, 0.0, 1.0), 0.0);
        assert_eq!(maximum_offset(f32::NAN, 1.0, 0.0), 0.0);
        // A vertex beyond the samples: 0.5 * (5 - 0) / (5 - 2 + 0) = 0.83 -> 0.5.
        assert_eq!(minimum_offset(5.0f64, 1.0, 0.0), 0.5);
        assert_eq!(minimum_offset(0.0f64, 1.0, 5.0), -0.5);
    }

    /// Operation for operation the forms the callers had inline.
    #[test]
    fn bit_identical_to_the_inline_forms() {
        let plain_min = |a: f64, b: f64, c: f64| {
            let curvature = a - 2.0 * b + c;
            if curvature > 0.0 { (0.5 * (a - c) / curvature).clamp(-0.5, 0.5) } else { 0.0 }
        };
        let plain_max = |a: f32, b: f32, c: f32| {
            let curvature = a - 2.0 * b + c;
            if curvature < 0.0 { (0.5 * (a - c) / curvature).clamp(-0.5, 0.5) } else { 0.0 }
        };
        // Every triple on a small lattice: minima, maxima, flat, clamped.
        for a in 0..24 {
            for b in 0..24 {
                for c in 0..24 {
                    let (a, b, c) = (f64::from(a * 1000), f64::from(b * 997), f64::from(c * 1013));
                    assert_eq!(minimum_offset(a, b, c).to_bits(), plain_min(a, b, c).to_bits());
                    let (a, b, c) = (a as f32 * 0.01, b as f32 * 0.03, c as f32 * -0.02);
                    assert_eq!(maximum_offset(a, b, c).to_bits(), plain_max(a, b, c).to_bits());
                }
            }
        }
    }
}

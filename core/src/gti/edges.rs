//! Edges on a GT line: extrema of the smoothed gradient above the line's own
//! noise, with sub-pixel positions and a patch of samples to match them by.
//! One pass over a line gives both sets: the strong edges that start and
//! continue tracks, and the weak ones (half the threshold) that only
//! established tracks may continue on.

use super::fits::median;
use super::lines::LineSamples;
use super::GtiConfig;
use crate::limits::{MAX_EDGES_PER_LINE, MAX_LINE_SAMPLES, MAX_WEAK_EDGES_PER_LINE};
use crate::subpixel::maximum_offset;
use heapless::Vec;
use libm::fabsf;

/// Samples either side of an edge in its matching patch.
pub(super) const PATCH_RADIUS: usize = 3;
pub(super) const PATCH: usize = 2 * PATCH_RADIUS + 1;
/// Threshold of the weak edges relative to the detection threshold.
const WEAK_EDGE_SCALE: f32 = 0.5;
/// Samples per block in which a line's noise is measured.
const NOISE_BLOCK: usize = 32;

/// An edge on a line in the current frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Edge {
    /// Sub-pixel KG row.
    pub row: f32,
    /// Gradient magnitude over the local threshold (> 1).
    pub strength: f32,
    pub rising: bool,
    pub patch: [u8; PATCH],
}

/// One line's edges in the current frame, each set strongest (relative to
/// its threshold) first.
pub(super) struct LineEdges {
    /// Above the threshold, at most [`MAX_EDGES_PER_LINE`].
    pub strong: Vec<Edge, MAX_EDGES_PER_LINE>,
    /// Above [`WEAK_EDGE_SCALE`] times the threshold (the strong ones too,
    /// with their strength over that), at most [`MAX_WEAK_EDGES_PER_LINE`].
    pub weak: Vec<Edge, MAX_WEAK_EDGES_PER_LINE>,
}

impl LineEdges {
    pub(super) const NONE: LineEdges = LineEdges { strong: Vec::new(), weak: Vec::new() };

    /// The edges of one line's samples: extrema of the smoothed gradient
    /// above `edge_threshold_sigma` robust sigmas of the gradient around them
    /// (floor texture and sensor noise), or above the contrast floor.
    pub(super) fn find(&mut self, samples: &LineSamples, config: &GtiConfig) {
        self.strong.clear();
        self.weak.clear();
        let valid = samples.valid();
        let values = &samples.values;
        let n = valid.len();
        // Smoothing [1 2 1], then the difference across +-2 samples: responds to
        // the contrast of a step spread over a few samples (far ground is
        // magnified in the KG image, so its edges are soft) more than to
        // single-sample floor texture. Gradient at row r uses r-3..=r+3.
        const REACH: usize = 3;
        if n < 2 * (PATCH_RADIUS + REACH) + 3 {
            return;
        }
        let value = |r: usize| values.get(r).map_or(0.0, |&v| f32::from(v));
        let smooth = |r: usize| 0.25 * (value(r - 1) + 2.0 * value(r) + value(r + 1));
        let mut gradient = [0f32; MAX_LINE_SAMPLES];
        let (first, last) = (valid.start + REACH, valid.end - REACH); // gradient defined on [first, last)
        for r in first..last {
            if let Some(g) = gradient.get_mut(r) {
                *g = 0.25 * (smooth(r + 2) - smooth(r - 2));
            }
        }
        // The line's noise (sensor noise plus floor texture) is measured locally,
        // per block of NOISE_BLOCK samples: the near floor's sharp texture must
        // not hide the soft edges of far, magnified ground.
        let mut block_sigma = [0f32; MAX_LINE_SAMPLES / NOISE_BLOCK + 1];
        for (b, sigma) in block_sigma.iter_mut().enumerate() {
            let start = first + b * NOISE_BLOCK;
            if start >= last {
                break;
            }
            // A short last block borrows samples from its predecessor.
            let end = (start + NOISE_BLOCK).min(last);
            let start = end.saturating_sub(NOISE_BLOCK).max(first);
            let mut magnitudes = [0f32; NOISE_BLOCK];
            for (slot, g) in magnitudes.iter_mut().zip(gradient.get(start..end).unwrap_or(&[])) {
                *slot = fabsf(*g);
            }
            // Median |g| of a zero-mean Gaussian is 0.6745 sigma.
            *sigma = magnitudes.get_mut(..end - start).and_then(median).unwrap_or(0.0) / 0.6745;
        }
        let floor = config.min_edge_contrast * 0.5;
        let threshold_at = |r: usize| {
            let sigma = block_sigma.get((r - first) / NOISE_BLOCK).copied().unwrap_or(0.0);
            (config.edge_threshold_sigma * sigma).max(floor)
        };
        let magnitude = |r: usize| gradient.get(r).map_or(0.0, |g| fabsf(*g));
        // Patches must lie inside the valid run.
        for r in (first + 1).max(valid.start + PATCH_RADIUS)..(last - 1).min(valid.end - PATCH_RADIUS) {
            let (before, here, after) = (magnitude(r - 1), magnitude(r), magnitude(r + 1));
            let threshold = threshold_at(r);
            // The weak threshold is the lower (the threshold is never negative).
            let weak_threshold = WEAK_EDGE_SCALE * threshold;
            if !(here > weak_threshold && here >= before && here > after) {
                continue;
            }
            let mut patch = [0u8; PATCH];
            for (k, slot) in patch.iter_mut().enumerate() {
                *slot = values.get(r + k - PATCH_RADIUS).copied().unwrap_or(0);
            }
            let edge = Edge {
                row: r as f32 + maximum_offset(before, here, after),
                strength: here / weak_threshold,
                rising: gradient.get(r).is_some_and(|g| *g > 0.0),
                patch,
            };
            keep_strongest(&mut self.weak, edge);
            if here > threshold {
                keep_strongest(&mut self.strong, Edge { strength: here / threshold, ..edge });
            }
        }
        self.strong.sort_unstable_by(|a, b| b.strength.total_cmp(&a.strength));
        self.weak.sort_unstable_by(|a, b| b.strength.total_cmp(&a.strength));
    }
}

/// Adds `edge` to `edges`; when full, it replaces the weakest if stronger.
fn keep_strongest<const N: usize>(edges: &mut Vec<Edge, N>, edge: Edge) {
    if edges.is_full() {
        let weakest = edges.iter().enumerate().min_by(|a, b| a.1.strength.total_cmp(&b.1.strength)).map(|(i, e)| (i, e.strength));
        if let Some((i, strength)) = weakest {
            if edge.strength > strength {
                if let Some(slot) = edges.get_mut(i) {
                    *slot = edge;
                }
            }
        }
    } else {
        let _ = edges.push(edge);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may panic
mod tests {
    use super::*;

    #[test]
    fn edge_peaks_use_the_parabola_vertex() {
        // Samples of -(x - 0.3)^2 at x = -1, 0, 1; collinear samples give 0.
        let f = |x: f32| -(x - 0.3) * (x - 0.3);
        assert!((maximum_offset(f(-1.0), f(0.0), f(1.0)) - 0.3).abs() < 1e-5);
        assert_eq!(maximum_offset(1.0f32, 1.0, 1.0), 0.0);
    }

    #[test]
    fn edges_are_found_with_subpixel_position() {
        // A blurred step at row 100.3 over a mildly textured line.
        let mut samples = LineSamples::EMPTY;
        for r in 40..200 {
            let x = (r as f32 - 100.3) / 1.5;
            let step = 60.0 + 100.0 / (1.0 + libm::expf(-x));
            let texture = if r % 3 == 0 { 2.0 } else { -1.0 };
            samples.take(r, Some((step + texture) as u8));
        }
        let mut edges = LineEdges::NONE;
        edges.find(&samples, &GtiConfig::DEFAULT);
        assert_eq!(edges.strong.len(), 1, "{:?}", edges.strong);
        assert!(edges.strong[0].rising);
        assert!((edges.strong[0].row - 100.3).abs() < 0.3, "row {}", edges.strong[0].row);
        // The strong edge is a weak one too, at twice its strength.
        let weak = edges.weak.iter().find(|e| e.row == edges.strong[0].row).unwrap();
        assert_eq!(weak.strength, 2.0 * edges.strong[0].strength);
    }
}

//! Edges on a GT line: extrema of the smoothed gradient above the line's own
//! noise, with sub-pixel positions and a patch of samples to match them by.
//! One pass over a line gives both sets: the strong edges that start and
//! continue tracks, and the weak ones (half the threshold) that only
//! established tracks may continue on.

use super::lines::LineSamples;
use super::GtiConfig;
use crate::limits::{MAX_EDGES_PER_LINE, MAX_LINES, MAX_LINE_SAMPLES, MAX_WEAK_EDGES_PER_LINE};
use crate::subpixel::maximum_offset;
use core::ops::Range;
use heapless::Vec;

/// Samples either side of an edge in its matching patch.
pub(super) const PATCH_RADIUS: usize = 3;
pub(super) const PATCH: usize = 2 * PATCH_RADIUS + 1;
/// Threshold of the weak edges relative to the detection threshold.
const WEAK_EDGE_SCALE: f32 = 0.5;
/// Samples per block in which a line's noise is measured.
const NOISE_BLOCK: usize = 32;
/// Noise blocks a line can have.
const NOISE_BLOCKS: usize = MAX_LINE_SAMPLES / NOISE_BLOCK + 1;
/// Smoothing [1 2 1], then the difference across +-2 samples: responds to
/// the contrast of a step spread over a few samples (far ground is
/// magnified in the KG image, so its edges are soft) more than to
/// single-sample floor texture. Gradient at row r uses r-REACH..=r+REACH.
const REACH: usize = 3;

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
    /// Each line's scan, once a search has made it: a frame searches a line
    /// twice (travel correction, association), and the gradient, its noise
    /// medians and the pass over its peaks are most of a search. Valid for
    /// one frame's samples: a new frame starts from [`LineEdges::NONE`].
    scans: [Option<LineScan>; MAX_LINES],
}

/// What a search keeps of a line's gradient for the line's next search.
#[derive(Clone, Copy)]
struct LineScan {
    /// The edge threshold per noise block.
    thresholds: [f32; NOISE_BLOCKS],
    /// Rows that are peaks of the gradient above the weak threshold (bit r
    /// of word r / 32): every edge either set can have, in row order.
    peaks: [u32; PEAK_WORDS],
}

/// Words of a line's peak bits.
const PEAK_WORDS: usize = MAX_LINE_SAMPLES.div_ceil(32);

impl LineEdges {
    pub(super) const NONE: LineEdges = LineEdges { strong: Vec::new(), weak: Vec::new(), scans: [None; MAX_LINES] };

    /// The edges of one line's samples: extrema of the smoothed gradient
    /// above `edge_threshold_sigma` robust sigmas of the gradient around them
    /// (floor texture and sensor noise), or above the contrast floor.
    /// `l` is the line's index, `samples` its samples in this frame.
    pub(super) fn find(&mut self, l: usize, samples: &LineSamples, config: &GtiConfig) {
        self.find_sets(l, samples, config, true);
    }

    /// [`LineEdges::find`]'s strong edges only (the weak set left empty):
    /// the same strong set without the weak one's upkeep, most of the work
    /// on a textured floor.
    pub(super) fn find_strong(&mut self, l: usize, samples: &LineSamples, config: &GtiConfig) {
        self.find_sets(l, samples, config, false);
    }

    fn find_sets(&mut self, l: usize, samples: &LineSamples, config: &GtiConfig, with_weak: bool) {
        self.strong.clear();
        self.weak.clear();
        let valid = samples.valid();
        let values = &samples.values;
        let n = valid.len();
        if n < 2 * (PATCH_RADIUS + REACH) + 3 {
            return;
        }
        let (first, last) = (valid.start + REACH, valid.end - REACH); // gradient defined on [first, last)
        // Patches must lie inside the valid run: edges at rows in [start, end).
        let (start, end) = ((first + 1).max(valid.start + PATCH_RADIUS), (last - 1).min(valid.end - PATCH_RADIUS));
        let known = self.scans.get(l).copied().flatten();
        let LineScan { thresholds, peaks } = known.unwrap_or_else(|| scan(values, &valid, first..last, start..end, config));
        if let Some(slot) = self.scans.get_mut(l) {
            *slot = Some(LineScan { thresholds, peaks });
        }
        let floor = config.min_edge_contrast * 0.5;
        // A peak's gradient and its neighbours' again from the samples: a few
        // rows, where keeping the line's gradient for the second search would
        // cost its 512 bytes per line.
        let gradient_at = |r: usize| values.get(r - REACH..=r + REACH).map_or(0, gradient);
        for (w, &word) in peaks.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                let r = 32 * w + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let threshold = thresholds.get((r - first) / NOISE_BLOCK).copied().unwrap_or(floor);
                // The weak threshold is the lower (the threshold is never negative).
                let weak_threshold = WEAK_EDGE_SCALE * threshold;
                let signed = gradient_at(r);
                let here = sixteenths(signed.unsigned_abs());
                if !(with_weak || here > threshold) {
                    continue;
                }
                let [before, after] = [gradient_at(r - 1), gradient_at(r + 1)].map(|g| sixteenths(g.unsigned_abs()));
                let mut patch = [0u8; PATCH];
                for (k, slot) in patch.iter_mut().enumerate() {
                    *slot = values.get(r + k - PATCH_RADIUS).copied().unwrap_or(0);
                }
                let edge = Edge { row: r as f32 + maximum_offset(before, here, after), strength: here / weak_threshold, rising: signed > 0, patch };
                if with_weak {
                    keep_strongest(&mut self.weak, edge);
                }
                if here > threshold {
                    keep_strongest(&mut self.strong, Edge { strength: here / threshold, ..edge });
                }
            }
        }
        self.strong.sort_unstable_by(|a, b| b.strength.total_cmp(&a.strength));
        self.weak.sort_unstable_by(|a, b| b.strength.total_cmp(&a.strength));
    }
}

/// A line's scan ([`LineScan`]): its gradient magnitudes on `gradient_rows`
/// (`values` valid on `valid`), their thresholds per noise block, and the
/// peaks among `edge_rows` above the weak threshold.
fn scan(values: &[u8; MAX_LINE_SAMPLES], valid: &Range<usize>, gradient_rows: Range<usize>, edge_rows: Range<usize>, config: &GtiConfig) -> LineScan {
    // The gradient is exact in sixteenths of a gray level: with integer
    // samples, 0.25 * (s(r+2) - s(r-2)) of the smoothing s = 0.25 * (a + 2b + c)
    // is (S(r+2) - S(r-2)) / 16 of the integer sums S, within +-1020. So it
    // is computed, compared and its noise medians selected in integers, and
    // converted to f32 (exactly) only where a value leaves: the same
    // thresholds and edges as f32 arithmetic, for a fraction of the M4's work.
    // Only magnitudes are kept (the search and the noise need no more):
    // an edge's sign is worked out again from its samples.
    let mut magnitudes = [0u16; MAX_LINE_SAMPLES];
    let (first, last) = (gradient_rows.start, gradient_rows.end);
    let windows = values.get(valid.clone()).unwrap_or(&[]).windows(2 * REACH + 1);
    for (m, window) in magnitudes.get_mut(first..last).unwrap_or(&mut []).iter_mut().zip(windows) {
        *m = gradient(window).unsigned_abs();
    }
    // The line's noise (sensor noise plus floor texture) is measured locally,
    // per block of NOISE_BLOCK samples: the near floor's sharp texture must
    // not hide the soft edges of far, magnified ground.
    let thresholds = block_thresholds(&magnitudes, first, last, config);
    let floor = config.min_edge_contrast * 0.5;
    let mut peaks = [0u32; PEAK_WORDS];
    // Each row with its neighbours' gradient (a window: one bounds check a row).
    let neighbourhoods = magnitudes.get(edge_rows.start - 1..edge_rows.end + 1).unwrap_or(&[]).windows(3);
    for (r, window) in edge_rows.zip(neighbourhoods) {
        let &[before, here, after] = window else { continue };
        if !(here >= before && here > after) {
            continue;
        }
        let threshold = thresholds.get((r - first) / NOISE_BLOCK).copied().unwrap_or(floor);
        if sixteenths(here) > WEAK_EDGE_SCALE * threshold {
            if let Some(word) = peaks.get_mut(r / 32) {
                *word |= 1 << (r % 32);
            }
        }
    }
    LineScan { thresholds, peaks }
}

/// The gradient at the middle of a window of 7 samples in sixteenths of a
/// gray level (see [`LineEdges::find`]): S(r+2) - S(r-2) of the sums
/// S = a + 2b + c; 0 for another length.
fn gradient(window: &[u8]) -> i16 {
    let &[a, b, c, _, e, f, h] = window else { return 0 };
    let sum = |x: u8, y: u8, z: u8| i16::from(x) + 2 * i16::from(y) + i16::from(z);
    sum(e, f, h) - sum(a, b, c)
}

/// A line's edge threshold per noise block from its gradient `magnitudes`
/// (defined on `first..last`): `edge_threshold_sigma` robust sigmas of the
/// block's gradient, at least the contrast floor.
fn block_thresholds(magnitudes: &[u16; MAX_LINE_SAMPLES], first: usize, last: usize, config: &GtiConfig) -> [f32; NOISE_BLOCKS] {
    let floor = config.min_edge_contrast * 0.5;
    let mut block_threshold = [floor; NOISE_BLOCKS];
    for (b, threshold) in block_threshold.iter_mut().enumerate() {
        let start = first + b * NOISE_BLOCK;
        if start >= last {
            break;
        }
        // A short last block borrows samples from its predecessor.
        let end = (start + NOISE_BLOCK).min(last);
        let start = end.saturating_sub(NOISE_BLOCK).max(first);
        // Median |g| of a zero-mean Gaussian is 0.6745 sigma.
        let sigma = magnitudes.get(start..end).and_then(median_sixteenths).unwrap_or(0.0) / 0.6745;
        *threshold = (config.edge_threshold_sigma * sigma).max(floor);
    }
    block_threshold
}

/// A gradient magnitude in sixteenths of a gray level, in gray levels (exact).
fn sixteenths(magnitude: u16) -> f32 {
    f32::from(magnitude) / 16.0
}

/// The median of gradient magnitudes in sixteenths, in gray levels: the
/// middle or the mean of the middle two (each exact in f32), as
/// [`super::fits::median`] of their values gives. None when empty.
fn median_sixteenths(magnitudes: &[u16]) -> Option<f32> {
    let n = magnitudes.len();
    let (lower, upper) = middle_pair(magnitudes, n.checked_sub(1)? / 2)?;
    if n % 2 == 1 {
        Some(sixteenths(lower))
    } else {
        Some(0.5 * (sixteenths(lower) + sixteenths(upper)))
    }
}

/// The `k`-th smallest of `magnitudes` (from 0) and the next in order,
/// found by counting (a selection took ~1,000 M4 instructions for a noise
/// block, this about half): by the high five of the ten bits a magnitude
/// has (at most 1020), then by the low five among those that share the
/// `k`-th's. None past the end (the next is the `k`-th itself at the end)
/// or for a magnitude of 1024 or more.
fn middle_pair(magnitudes: &[u16], k: usize) -> Option<(u16, u16)> {
    let mut high = [0u16; 32];
    for &m in magnitudes {
        *high.get_mut(usize::from(m >> 5))? += 1;
    }
    let (bucket, rank) = nth_counted(&high, k)?;
    let mut low = [0u16; 32];
    for &m in magnitudes.iter().filter(|&&m| usize::from(m >> 5) == bucket) {
        if let Some(count) = low.get_mut(usize::from(m & 31)) {
            *count += 1;
        }
    }
    let value = |digit: usize| (bucket << 5 | digit) as u16;
    let kth = value(nth_counted(&low, rank)?.0);
    let next = match nth_counted(&low, rank + 1) {
        Some((digit, _)) => value(digit),
        // The smallest of the higher buckets, or the k-th itself at the end.
        None => magnitudes.iter().copied().filter(|&m| usize::from(m >> 5) > bucket).min().unwrap_or(kth),
    };
    Some((kth, next))
}

/// The bucket of `counts` that holds the `k`-th counted value (from 0),
/// and its rank there.
fn nth_counted(counts: &[u16; 32], mut k: usize) -> Option<(usize, usize)> {
    for (bucket, &count) in counts.iter().enumerate() {
        let count = usize::from(count);
        if k < count {
            return Some((bucket, k));
        }
        k -= count;
    }
    None
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
    fn median_by_counting_is_the_median() {
        let mut state = 0x4D65_6469u32;
        let mut next = || crate::selftest::xorshift32(&mut state);
        for _ in 0..20_000 {
            let n = 1 + next() as usize % NOISE_BLOCK;
            // Every range of magnitudes, ties included, up to the largest (1020).
            let spread = [4, 40, 300, 1021][next() as usize % 4];
            let magnitudes: Vec<u16, NOISE_BLOCK> = (0..n).map(|_| (next() % spread) as u16).collect();
            let mut values: Vec<i32, NOISE_BLOCK> = magnitudes.iter().map(|&m| crate::gti::fits::order_key(sixteenths(m))).collect();
            let reference = crate::gti::fits::median(&mut values);
            assert_eq!(median_sixteenths(&magnitudes).map(f32::to_bits), reference.map(f32::to_bits), "{magnitudes:?}");
        }
        assert_eq!(median_sixteenths(&[]), None);
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
        edges.find(0, &samples, &GtiConfig::DEFAULT);
        assert_eq!(edges.strong.len(), 1, "{:?}", edges.strong);
        assert!(edges.strong[0].rising);
        assert!((edges.strong[0].row - 100.3).abs() < 0.3, "row {}", edges.strong[0].row);
        // The strong edge is a weak one too, at twice its strength.
        let weak = edges.weak.iter().find(|e| e.row == edges.strong[0].row).unwrap();
        assert_eq!(weak.strength, 2.0 * edges.strong[0].strength);
    }
}

//! The shift search (the seed's): the SAD of every shift in the `(2S+1)^2`
//! window around the predicted one over the AOI, plus the |diff| histogram
//! at the prediction (the seed's statistics, sum of |diff| > 30 and count
//! of |diff| > 50, and the noise estimate). At the frame's end: the best
//! shift to sub-pixel precision, and from it the refined motion, its yaw
//! from how the far and the near half of the AOI disagree.

use super::band::{BandRows, MAX_WINDOW};
use super::kernels;
use super::layout::Layout;
use super::warp::clip;
use crate::grid::PixelRect;
use crate::limits::MAX_SEARCH_RADIUS;
use crate::motion::Motion;
use crate::subpixel;

/// The seed's levels: |diff| above 30 is summed, above 50 counted.
pub const SEED_SUM_LEVEL: u8 = kernels::SUM_LEVEL;
pub const SEED_COUNT_LEVEL: u8 = kernels::COUNT_LEVEL;

/// The search's sums over the current frame.
pub(super) struct ShiftSearch {
    /// SAD per shift [dg][dk] over the near half of the AOI rows; the far
    /// half apart: a yaw error shifts far rows sideways more than near ones,
    /// which is how it is measured.
    pub(super) sad_near: [[u32; MAX_WINDOW]; MAX_WINDOW],
    /// The same over the far half.
    pub(super) sad_far: [[u32; MAX_WINDOW]; MAX_WINDOW],
    pub(super) compared_pixels: u32,
    /// Histogram of the plain |diff| at the predicted shift over the AOI...
    pub(super) diff_hist: kernels::DiffHistogram,
    /// ...or, for a search whose histogram nothing reads (the seed's own,
    /// apart from the measured motion's), only the seed's statistics of it
    /// ([`kernels::seed_sums`]).
    pub(super) seed_sums: (u32, u32),
}

/// What the search measured in a frame.
pub(super) struct ShiftFit {
    /// The best shift along K and G (KG px, sub-pixel).
    pub(super) shift_k: f64,
    pub(super) shift_g: f64,
    /// The motion keyframe -> now it gives; None when the minimum lies on
    /// the window's edge, which is no measurement.
    pub(super) refined: Option<Motion>,
}

impl ShiftSearch {
    pub(super) const EMPTY: ShiftSearch = ShiftSearch {
        sad_near: [[0; MAX_WINDOW]; MAX_WINDOW],
        sad_far: [[0; MAX_WINDOW]; MAX_WINDOW],
        compared_pixels: 0,
        diff_hist: kernels::DiffHistogram::EMPTY,
        seed_sums: (0, 0),
    };

    pub(super) fn clear(&mut self) {
        self.sad_near = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.sad_far = [[0; MAX_WINDOW]; MAX_WINDOW];
        self.compared_pixels = 0;
        self.diff_hist.clear();
        self.seed_sums = (0, 0);
    }

    /// Adds current row `row` against the `band` (search radius `s`) over
    /// the usable `runs` within the AOI's columns, to the far half's sums
    /// if `far_half`; the shifts' sums only if `shifts` (the histogram
    /// reads band row S alone), the histogram only if `histogram` (else
    /// the seed's statistics alone).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_row(&mut self, row: &[u8], band: &BandRows, s: usize, runs: &[(u16, u16)], aoi: &PixelRect, far_half: bool, shifts: bool, histogram: bool) {
        let r = MAX_SEARCH_RADIUS;
        let window = 2 * s + 1;
        for &run in runs {
            let columns = clip(run, aoi.left, aoi.right);
            if columns.is_empty() {
                continue;
            }
            let current = &row[columns.clone()];
            let predicted = &band[s][columns.start + r..columns.end + r];
            if histogram {
                self.diff_hist.add(current, predicted);
            } else {
                let (sum, count) = kernels::seed_sums(current, predicted);
                self.seed_sums = (self.seed_sums.0.wrapping_add(sum), self.seed_sums.1.wrapping_add(count));
            }
            self.compared_pixels += columns.len() as u32;
            if !shifts {
                continue;
            }
            // Shift dk of band row dg compares current[c] with band[dg][c + dk - s].
            let reference = columns.start + r - s..columns.end + r + s;
            let sums = if far_half { &mut self.sad_far } else { &mut self.sad_near };
            for (sums, band) in sums.iter_mut().zip(band).take(window) {
                kernels::sad_shifts(current, &band[reference.clone()], &mut sums[..window]);
            }
        }
    }

    /// The |diff| histogram at the predicted shift.
    pub(super) fn histogram(&self) -> [u32; 256] {
        self.diff_hist.counts()
    }

    /// The best shift (search radius `s`) and the motion it measures, from
    /// the `predicted` one.
    pub(super) fn fit(&self, s: usize, predicted: &Motion, layout: &Layout) -> ShiftFit {
        let sad = self.whole_aoi();
        // Best integer shift, then a parabola per axis for the sub-pixel part.
        let (best_g, best_k) = best_shift(&sad, s);
        let interior_k = best_k > 0 && best_k < 2 * s;
        let interior_g = best_g > 0 && best_g < 2 * s;
        let sub_k = if interior_k { minimum_offset(sad[best_g][best_k - 1], sad[best_g][best_k], sad[best_g][best_k + 1]) } else { 0.0 };
        let sub_g = if interior_g { minimum_offset(sad[best_g - 1][best_k], sad[best_g][best_k], sad[best_g + 1][best_k]) } else { 0.0 };
        let shift_k = best_k as f64 - s as f64 + sub_k;
        let shift_g = best_g as f64 - s as f64 + sub_g;
        // A minimum on the window's edge is not a measurement.
        let refined = (interior_k && interior_g).then(|| {
            // The keyframe matched at +shift: the current pixel lies that much
            // farther along K (x) and back along G (-z) in the keyframe.
            let mm = layout.grid.mm_per_px;
            let mut refined = Motion {
                tx_mm: predicted.tx_mm + shift_k * mm,
                tz_mm: predicted.tz_mm - shift_g * mm,
                dyaw_deg: predicted.dyaw_deg,
            };
            if let Some((yaw_deg, tx_mm)) = self.yaw_refinement(best_g, s, predicted, layout) {
                refined.dyaw_deg += yaw_deg;
                refined.tx_mm = tx_mm;
            }
            refined
        });
        ShiftFit { shift_k, shift_g, refined }
    }

    /// SAD per shift [dg][dk] over the whole AOI: near half plus far half.
    fn whole_aoi(&self) -> [[u32; MAX_WINDOW]; MAX_WINDOW] {
        let mut sad = self.sad_near;
        for (row, far) in sad.iter_mut().zip(&self.sad_far) {
            for (sum, &far) in row.iter_mut().zip(far) {
                *sum += far;
            }
        }
        sad
    }

    /// Yaw error from the K shift of the far and the near half of the AOI
    /// (on band row `best_g`): an extra turn e moves the keyframe match by
    /// -e*z sideways, so the two halves disagree by -e*(z_far - z_near).
    /// Returns (extra yaw in degrees, corrected tx) or None when either half
    /// has no clear minimum.
    fn yaw_refinement(&self, best_g: usize, s: usize, predicted: &Motion, layout: &Layout) -> Option<(f64, f64)> {
        let shift = |sums: &[u32; MAX_WINDOW]| -> Option<f64> {
            let best = (0..=2 * s).min_by_key(|&k| sums[k])?;
            if best == 0 || best == 2 * s {
                return None;
            }
            Some(best as f64 - s as f64 + minimum_offset(sums[best - 1], sums[best], sums[best + 1]))
        };
        let far = shift(&self.sad_far[best_g])?;
        let near = shift(&self.sad_near[best_g])?;
        let (aoi, grid) = (&layout.aoi, &layout.grid);
        let middle = (aoi.top + aoi.bottom) / 2;
        let (_, z_far) = grid.pixel_to_ground(0.0, (aoi.top + middle) as f64 / 2.0);
        let (_, z_near) = grid.pixel_to_ground(0.0, (middle + aoi.bottom) as f64 / 2.0);
        let mm = grid.mm_per_px;
        let extra_yaw = -(far - near) * mm / (z_far - z_near);
        // Beyond a couple of degrees this is not an odometry error but a bad match.
        if libm::fabs(extra_yaw) > 2f64.to_radians() {
            return None;
        }
        let tx_mm = predicted.tx_mm + near * mm + extra_yaw * z_near;
        Some((extra_yaw.to_degrees(), tx_mm))
    }
}

/// The (dg, dk) of the smallest SAD in the window of radius `s`; on ties
/// the centre, else the first in scan order.
fn best_shift(sad: &[[u32; MAX_WINDOW]; MAX_WINDOW], s: usize) -> (usize, usize) {
    let (mut best_g, mut best_k) = (s, s);
    for dg in 0..=2 * s {
        for dk in 0..=2 * s {
            if sad[dg][dk] < sad[best_g][best_k] {
                best_g = dg;
                best_k = dk;
            }
        }
    }
    (best_g, best_k)
}

/// Sub-pixel offset of a SAD minimum from its neighbours.
fn minimum_offset(minus: u32, centre: u32, plus: u32) -> f64 {
    subpixel::minimum_offset(f64::from(minus), f64::from(centre), f64::from(plus))
}

//! One block of the current KG image found in the keyframe around where a
//! motion model puts it: zero-mean normalised correlation (exposure steps
//! and shading do not bias it) over a window of whole-pixel shifts, then a
//! parabola to sub-pixel.
//!
//! Integer throughout: the keyframe patch is sampled bilinearly along the
//! model's local affine map in Q16 steps into Q4 gray levels, and every shift's
//! sums (keyframe, its squares, the product with the block) are exact
//! integers; only the 49 scores are divided in `f32`. The products run
//! two at a time ([`kernels::dot_shifts`], `smlad` on the M4).

use super::homography::PixelMap;
use super::warp::Coverage;
use crate::kernels;
use crate::grid::KgGrid;

/// Block side, KG pixels, and its search reach around the model.
pub(super) const BLOCK_PX: usize = 16;
const REACH: usize = 3;
const WINDOW: usize = 2 * REACH + 1;
/// A block's patch: the block and the reach on each side.
const PATCH: usize = BLOCK_PX + 2 * REACH;
const PIXELS: i64 = (BLOCK_PX * BLOCK_PX) as i64;
/// Q16 fixed point of the patch sampling.
const FRAC: u32 = 16;
const ONE: f32 = (1u32 << FRAC) as f32;
/// Fractional bits of the patch's gray levels (Q4). Rounded to whole gray
/// levels, a low-contrast patch turns into steps that pull sub-pixel peaks
/// toward whole pixels, and the fit's pitch and roll with them. Q4 keeps
/// every sum exact in `u32` (a row's squares: 16 x 4080^2 < 2^32).
const PATCH_FRAC: u32 = 4;
/// The keyframe patch, gray levels in Q4.
type Patch = [[u16; PATCH]; PATCH];

/// The images one block is matched between.
pub(super) struct Images<'a> {
    pub(super) keyframe: &'a [u8],
    pub(super) current: &'a [u8],
    pub(super) grid: &'a KgGrid,
    pub(super) coverage: &'a Coverage,
}

impl Images<'_> {
    fn seen(&self, i: usize, j: usize) -> bool {
        j < self.grid.height() && self.coverage.seen(j).is_some_and(|columns| columns.contains(&i))
    }
}

/// One block's working arrays, every element written before it is read:
/// made once per pass over the blocks, not zeroed (and the patch not
/// copied out of its sampler) for every block.
pub(super) struct Scratch {
    block: [[u8; BLOCK_PX]; BLOCK_PX],
    patch: Patch,
    /// Per patch row and horizontal shift: the sums of the block-wide run.
    run_sums: [[u32; WINDOW]; PATCH],
    run_squares: [[u32; WINDOW]; PATCH],
    /// The block's rows two pixels to a word, for the kernel's paired products.
    pairs: [[u32; BLOCK_PX / 2]; BLOCK_PX],
}

impl Scratch {
    pub(super) const fn new() -> Scratch {
        Scratch {
            block: [[0; BLOCK_PX]; BLOCK_PX],
            patch: [[0; PATCH]; PATCH],
            run_sums: [[0; WINDOW]; PATCH],
            run_squares: [[0; WINDOW]; PATCH],
            pairs: [[0; BLOCK_PX / 2]; BLOCK_PX],
        }
    }
}

/// A block found: its centre's keyframe position and the brightness of the
/// current block over the keyframe's there.
pub(super) struct Found {
    pub(super) keyframe: (f32, f32),
    pub(super) gain: f32,
}

/// The keyframe position of the centre of the block at (`bi`, `bj`) under
/// `map`, or None when it is off the view, flat, or ambiguous.
pub(super) fn match_block(images: &Images, map: &PixelMap, bi: usize, bj: usize, scratch: &mut Scratch) -> Option<Found> {
    let w = images.grid.width();
    if !(bj..bj + BLOCK_PX).all(|j| images.seen(bi, j) && images.seen(bi + BLOCK_PX - 1, j)) {
        return None;
    }
    // The current block; flat blocks (below ~3 gray levels RMS: sensor
    // noise, not texture) measure nothing.
    let (mut sum, mut squares) = (0u32, 0u32);
    for (v, row) in scratch.block.iter_mut().enumerate() {
        row.copy_from_slice(&images.current[(bj + v) * w + bi..][..BLOCK_PX]);
        for &value in row.iter() {
            sum += u32::from(value);
            squares += u32::from(value) * u32::from(value);
        }
    }
    let (sum, squares) = (i64::from(sum), i64::from(squares));
    // n^2 times the block's variance.
    let energy = PIXELS * squares - sum * sum;
    if energy < 9 * PIXELS * PIXELS {
        return None;
    }
    // The keyframe patch around the model's footprint: the model as an
    // affine map about the block's centre.
    let half = (BLOCK_PX / 2) as f32;
    let (ci, cj) = (bi as f32 + half - 0.5, bj as f32 + half - 0.5);
    let origin = map.at(ci, cj)?;
    let along = map.at(ci + 1.0, cj)?;
    let down = map.at(ci, cj + 1.0)?;
    let (du, dv) = ((along.0 - origin.0, along.1 - origin.1), (down.0 - origin.0, down.1 - origin.1));
    sample_patch(images, origin, du, dv, &mut scratch.patch)?;
    let scores = correlate(sum, energy, scratch);
    let patch = &scratch.patch;
    let (mut best_u, mut best_v) = (REACH, REACH);
    for (sv, row) in scores.iter().enumerate() {
        for (su, &score) in row.iter().enumerate() {
            if score > scores[best_v][best_u] {
                best_u = su;
                best_v = sv;
            }
        }
    }
    let best = scores[best_v][best_u];
    // On the reach's edge, weakly correlated, or as good a step away: no measurement.
    if best_u == 0 || best_v == 0 || best_u == WINDOW - 1 || best_v == WINDOW - 1 || best < 0.6 {
        return None;
    }
    for (sv, row) in scores.iter().enumerate() {
        for (su, &score) in row.iter().enumerate() {
            let apart = sv.abs_diff(best_v).max(su.abs_diff(best_u)) >= 2;
            if apart && score > best - 0.02 {
                return None;
            }
        }
    }
    let peak = |minus: f32, centre: f32, plus: f32| crate::subpixel::maximum_offset(minus, centre, plus);
    let su = best_u as f32 - REACH as f32 + peak(scores[best_v][best_u - 1], best, scores[best_v][best_u + 1]);
    let sv = best_v as f32 - REACH as f32 + peak(scores[best_v - 1][best_u], best, scores[best_v + 1][best_u]);
    let keyframe_sum: u32 = patch[best_v..best_v + BLOCK_PX].iter().map(|row| row[best_u..best_u + BLOCK_PX].iter().map(|&k| u32::from(k)).sum::<u32>()).sum();
    let n = PIXELS as f32;
    let keyframe_mean = keyframe_sum as f32 / (n * (1u32 << PATCH_FRAC) as f32);
    let gain = (sum as f32 / n + 1.0) / (keyframe_mean + 1.0);
    Some(Found { keyframe: (origin.0 + su * du.0 + sv * dv.0, origin.1 + su * du.1 + sv * dv.1), gain })
}

/// The keyframe sampled bilinearly at `origin + a du + b dv` for a, b from
/// -(half - 0.5) - reach in whole steps, in Q4 gray levels; None
/// unless every sample's four neighbours are in the camera's view (then
/// `patch` is left as it was).
fn sample_patch(images: &Images, origin: (f32, f32), du: (f32, f32), dv: (f32, f32), patch: &mut Patch) -> Option<()> {
    let first = -((BLOCK_PX / 2) as f32 - 0.5) - REACH as f32;
    // Steps rounded, and every position offset by half the bilinear
    // weights' 1/256 px so that truncating to it rounds: truncated, the
    // patch lies ~1/512 px off in both axes, in every block alike, and the
    // fit turns that into a pitch and roll of its own.
    let step_i = libm::roundf(du.0 * ONE) as i32;
    let step_j = libm::roundf(du.1 * ONE) as i32;
    const HALF_WEIGHT_STEP: i32 = 1 << (FRAC - 9);
    let last = (PATCH - 1) as i32;
    // Each row's start in Q16, and the bounding box of all samples (a
    // row's samples lie on a line, so its ends bound it).
    let mut starts = [(0i32, 0i32); PATCH];
    let (mut i_min, mut i_max, mut j_min, mut j_max) = (i64::MAX, i64::MIN, i64::MAX, i64::MIN);
    for (v, start) in starts.iter_mut().enumerate() {
        let b = first + v as f32;
        let (i, j) = (origin.0 + first * du.0 + b * dv.0, origin.1 + first * du.1 + b * dv.1);
        // Also refuses NaN and what the fixed point cannot hold.
        if !(i >= 0.0 && j >= 0.0 && i < 30000.0 && j < 30000.0) {
            return None;
        }
        *start = ((i * ONE) as i32 + HALF_WEIGHT_STEP, (j * ONE) as i32 + HALF_WEIGHT_STEP);
        // The ends in i64: a step no map of a sane motion gives cannot
        // wrap the box (the samples between stay between the ends).
        let end = |start: i32, step: i32| i64::from(start) + i64::from(last) * i64::from(step);
        for (ie, je) in [(i64::from(start.0), i64::from(start.1)), (end(start.0, step_i), end(start.1, step_j))] {
            i_min = i_min.min(ie >> FRAC);
            i_max = i_max.max(ie >> FRAC);
            j_min = j_min.min(je >> FRAC);
            j_max = j_max.max(je >> FRAC);
        }
    }
    let (w, h) = (images.grid.width() as i64, images.grid.height() as i64);
    if i_min < 0 || j_min < 0 || i_max + 1 >= w || j_max + 1 >= h || images.keyframe.len() < (w * h) as usize {
        return None;
    }
    let (i_min, i_max) = (i_min as usize, i_max as usize + 1);
    for j in j_min as usize..=j_max as usize + 1 {
        let columns = images.coverage.seen(j)?;
        if !(columns.start <= i_min && i_max < columns.end) {
            return None;
        }
    }
    let (w, keyframe) = (w as usize, images.keyframe);
    for (row, &(mut i, mut j)) in patch.iter_mut().zip(&starts) {
        for value in row.iter_mut() {
            let at = (j >> FRAC) as usize * w + (i >> FRAC) as usize;
            let (fx, fy) = ((i >> 8) & 0xFF, (j >> 8) & 0xFF);
            // SAFETY: every sample's (i >> 16, j >> 16) lies in the box
            // checked above, 0..w - 1 by 0..h - 1, so at + w + 1 <= h w - 1
            // and the keyframe holds h w bytes.
            let (p00, p01, p10, p11) = unsafe {
                (
                    i32::from(*keyframe.get_unchecked(at)),
                    i32::from(*keyframe.get_unchecked(at + 1)),
                    i32::from(*keyframe.get_unchecked(at + w)),
                    i32::from(*keyframe.get_unchecked(at + w + 1)),
                )
            };
            // a (256 - f) + b f = 256 a + (b - a) f, exactly: a multiply less.
            let top = (p00 << 8) + (p01 - p00) * fx;
            let bottom = (p10 << 8) + (p11 - p10) * fx;
            *value = (((top << 8) + (bottom - top) * fy + (1 << (15 - PATCH_FRAC))) >> (16 - PATCH_FRAC)) as u16;
            i += step_i;
            j += step_j;
        }
    }
    Some(())
}

/// The zero-mean normalised correlation of the scratch's block (sum `sum`,
/// n^2 times its variance `energy`) with its patch at every shift.
fn correlate(sum: i64, energy: i64, scratch: &mut Scratch) -> [[f32; WINDOW]; WINDOW] {
    let Scratch { block, patch, run_sums, run_squares, pairs } = scratch;
    for ((row, sums), squares) in patch.iter().zip(run_sums.iter_mut()).zip(run_squares.iter_mut()) {
        let (mut s, mut q) = (0u32, 0u32);
        for &k in &row[..BLOCK_PX] {
            s += u32::from(k);
            q += u32::from(k) * u32::from(k);
        }
        sums[0] = s;
        squares[0] = q;
        for su in 1..WINDOW {
            let (out, into) = (u32::from(row[su - 1]), u32::from(row[su + BLOCK_PX - 1]));
            s = s + into - out;
            q = q + into * into - out * out;
            sums[su] = s;
            squares[su] = q;
        }
    }
    for (row, packed) in block.iter().zip(pairs.iter_mut()) {
        kernels::pack_pairs(row, packed);
    }
    // Per horizontal shift, the keyframe's sums over the block's rows at
    // the vertical shift, slid down a row at a time.
    let mut window_sums = [0i64; WINDOW];
    let mut window_squares = [0i64; WINDOW];
    for v in 0..BLOCK_PX {
        for su in 0..WINDOW {
            window_sums[su] += i64::from(run_sums[v][su]);
            window_squares[su] += i64::from(run_squares[v][su]);
        }
    }
    let energy_f32 = kernels::i64_to_f32(energy);
    let mut scores = [[0f32; WINDOW]; WINDOW];
    for (sv, score_row) in scores.iter_mut().enumerate() {
        let mut cross = [0u32; WINDOW];
        for (v, packed) in pairs.iter().enumerate() {
            kernels::dot_shifts(packed, &patch[v + sv], &mut cross);
        }
        if sv > 0 {
            // The rows sv..sv + BLOCK_PX: one row in, one out.
            let (into, out) = (sv + BLOCK_PX - 1, sv - 1);
            for su in 0..WINDOW {
                window_sums[su] += i64::from(run_sums[into][su]) - i64::from(run_sums[out][su]);
                window_squares[su] += i64::from(run_squares[into][su]) - i64::from(run_squares[out][su]);
            }
        }
        for (su, score) in score_row.iter_mut().enumerate() {
            let (s, q) = (window_sums[su], window_squares[su]);
            // n^2 times the keyframe's variance and the covariance.
            let variance = PIXELS * q - s * s;
            let covariance = PIXELS * i64::from(cross[su]) - sum * s;
            *score = if variance > PIXELS << (2 * PATCH_FRAC) { kernels::i64_to_f32(covariance) / kernels::sqrtf(energy_f32 * kernels::i64_to_f32(variance)) } else { -1.0 };
        }
    }
    scores
}

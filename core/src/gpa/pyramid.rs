//! A KG image as a masked pyramid for the motion estimate: level 0 is the
//! image itself, each level above it averages square blocks of the
//! image's pixels ([`SCALES`]). A level's row keeps the columns whose every
//! pixel below was seen, so a sample never mixes in ground the camera did
//! not see.

use crate::grid::MAX_GRID_SIDE;
use crate::kernels;

/// Levels, the image included.
pub(super) const LEVELS: usize = 3;
/// Grid pixels per level pixel, each way. The level of 2 is left out:
/// the alignment reaches the image from a quarter pixel of level 4, well
/// within its reach, and the RAM it would take (a quarter of the grid
/// for each image) is the board's.
pub(super) const SCALES: [usize; LEVELS] = [1, 4, 8];
// Each level from the one below: 4x4 blocks, then 2x2 ([`Pyramid::build`]).
const _: () = assert!(SCALES[1] / SCALES[0] == 4 && SCALES[2] / SCALES[1] == 2);

/// Grid pixels per level pixel, each way.
#[inline(always)]
pub(super) fn scale(level: usize) -> usize {
    SCALES[level]
}

/// Pixels of levels 1.. together, for the largest grid.
const STORE: usize = (MAX_GRID_SIDE / 4) * (MAX_GRID_SIDE / 4) + (MAX_GRID_SIDE / 8) * (MAX_GRID_SIDE / 8);

/// Rows of levels 1.. together, for the largest grid.
const SEEN_ROWS: usize = MAX_GRID_SIDE / 4 + MAX_GRID_SIDE / 8;

/// Seen columns of a row, `(first, end)`; `(0, 0)` for none.
pub(super) type Seen = (u16, u16);

/// One level: its pixels row by row and each row's seen columns.
#[derive(Clone, Copy)]
pub(super) struct Level<'a> {
    pub(super) pixels: &'a [u8],
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) seen: &'a [Seen],
}

impl Level<'_> {
    /// The level's gray level at (u, v), bilinear between pixel centres
    /// (pixel (i, j) at u = i, v = j); None unless all four taps were seen.
    #[inline(always)]
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(u >= 0)` also refuses NaN
    pub(super) fn sample(&self, u: f32, v: f32) -> Option<f32> {
        // Beyond 65536 px (a wild hypothesis) is past any grid: refused
        // here, so the whole-pixel sums below cannot overflow.
        if !(u >= 0.0 && v >= 0.0 && u < 65536.0 && v < 65536.0) {
            return None;
        }
        let (i, j) = (u as usize, v as usize);
        if j + 1 >= self.height {
            return None;
        }
        let &[upper, lower] = self.seen.get(j..j + 2)? else { return None };
        if i < usize::from(upper.0.max(lower.0)) || i + 1 >= usize::from(upper.1.min(lower.1)) {
            return None;
        }
        let (fu, fv) = (u - i as f32, v - j as f32);
        let w = self.width;
        // The four taps in one bounds check.
        let taps = self.pixels.get(j * w + i..j * w + i + w + 2)?;
        let p = |k: usize| f32::from(taps[k]);
        let top = p(0) + fu * (p(1) - p(0));
        let bottom = p(w) + fu * (p(w + 1) - p(w));
        Some(top + fv * (bottom - top))
    }

    /// The central-difference gradient at pixel (i, j), gray levels per
    /// pixel; None unless its four neighbours were seen.
    #[inline]
    pub(super) fn gradient(&self, i: usize, j: usize) -> Option<(f32, f32)> {
        if i == 0 || j == 0 || i + 1 >= self.width || j + 1 >= self.height {
            return None;
        }
        let inside = |row: usize, first: usize, last: usize| {
            let (lo, hi) = self.seen[row];
            first >= usize::from(lo) && last < usize::from(hi)
        };
        if !(inside(j, i - 1, i + 1) && inside(j - 1, i, i) && inside(j + 1, i, i)) {
            return None;
        }
        let p = |i: usize, j: usize| f32::from(self.pixels[j * self.width + i]);
        Some((0.5 * (p(i + 1, j) - p(i - 1, j)), 0.5 * (p(i, j + 1) - p(i, j - 1))))
    }

    /// The gray level of pixel (i, j).
    #[inline]
    pub(super) fn at(&self, i: usize, j: usize) -> u8 {
        self.pixels[j * self.width + i]
    }
}

/// Levels 1.. of one image (level 0 is borrowed when asked for).
pub(super) struct Pyramid {
    store: [u8; STORE],
    /// The seen columns of levels 1.. row by row, one level after the other.
    seen: [Seen; SEEN_ROWS],
    /// Width and height of each level, the image's first.
    sizes: [(usize, usize); LEVELS],
    /// Where each level from 1 on starts in `store`, and its rows in `seen`.
    starts: [(usize, usize); LEVELS],
}

impl Pyramid {
    pub(super) const EMPTY: Pyramid = Pyramid { store: [0; STORE], seen: [(0, 0); SEEN_ROWS], sizes: [(0, 0); LEVELS], starts: [(0, 0); LEVELS] };

    /// Builds levels 1.. of `image` (`width` x `height`, row `j` seen at
    /// the columns `seen[j]`), each from the one below.
    pub(super) fn build(&mut self, image: &[u8], width: usize, height: usize, seen: &[Seen]) {
        self.sizes[0] = (width, height);
        let (mut start, mut seen_start) = (0, 0);
        for level in 1..LEVELS {
            let factor = scale(level) / scale(level - 1);
            let (below_width, below_height) = self.sizes[level - 1];
            let (w, h) = (below_width / factor, below_height / factor);
            self.sizes[level] = (w, h);
            self.starts[level] = (start, seen_start);
            let (below, above) = self.store.split_at_mut(start);
            let (done, level_seen) = self.seen.split_at_mut(seen_start);
            let (below_pixels, below_seen): (&[u8], &[Seen]) = if level == 1 { (image, seen) } else { (&below[self.starts[level - 1].0..], &done[self.starts[level - 1].1..]) };
            for j in 0..h {
                let rows = j * factor..(j + 1) * factor;
                let (lo, hi) = rows.fold((0u16, u16::MAX), |(lo, hi), r| (lo.max(below_seen[r].0), hi.min(below_seen[r].1)));
                let (lo, hi) = (lo.div_ceil(factor as u16), hi / factor as u16);
                level_seen[j] = if hi > lo { (lo, hi) } else { (0, 0) };
                let out = &mut above[j * w..][..w];
                let row = |r: usize| &below_pixels[(j * factor + r) * below_width..][..w * factor];
                match factor {
                    4 => kernels::mean_4x4([row(0), row(1), row(2), row(3)], out),
                    _ => {
                        for ((out, top), bottom) in out.iter_mut().zip(row(0).chunks_exact(2)).zip(row(1).chunks_exact(2)) {
                            let sum = u16::from(top[0]) + u16::from(top[1]) + u16::from(bottom[0]) + u16::from(bottom[1]);
                            *out = ((sum + 2) / 4) as u8;
                        }
                    }
                }
            }
            start += w * h;
            seen_start += h;
        }
    }

    /// Level `level` (0: `image`, which must be the one built from, with its `seen`).
    pub(super) fn level<'a>(&'a self, level: usize, image: &'a [u8], seen: &'a [Seen]) -> Level<'a> {
        let (width, height) = self.sizes[level];
        if level == 0 {
            return Level { pixels: image, width, height, seen };
        }
        let (start, seen_start) = self.starts[level];
        Level { pixels: &self.store[start..][..width * height], width, height, seen: &self.seen[seen_start..][..height] }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    #[test]
    fn a_level_averages_and_keeps_only_fully_seen_pixels() {
        let (w, h) = (16, 8);
        let image: Vec<u8> = (0..w * h).map(|k| (k % 251) as u8).collect();
        let mut seen = [(0u16, 0u16); MAX_GRID_SIDE];
        seen[..h].fill((0, 16));
        seen[2] = (1, 16);
        let mut pyramid = std::boxed::Box::new(Pyramid::EMPTY);
        pyramid.build(&image, w, h, &seen[..h]);
        let one = pyramid.level(1, &image, &seen[..h]);
        assert_eq!((one.width, one.height), (4, 2));
        // Pixel (0, 0) of level 1 averages rows 0-3, columns 0-3: 16 j + i.
        let mean = (0..4).flat_map(|j| (0..4).map(move |i| 16 * j + i)).sum::<usize>() as f32 / 16.0;
        assert_eq!(one.at(0, 0), libm::roundf(mean) as u8);
        // Row 2 of the image lacks column 0: level 1's row 0 starts at 1.
        assert_eq!(one.seen[0], (1, 4));
        assert_eq!(one.seen[1], (0, 4));
        let two = pyramid.level(2, &image, &seen[..h]);
        assert_eq!((two.width, two.height), (2, 1));
        assert_eq!(two.seen[0], (1, 2));
        let zero = pyramid.level(0, &image, &seen[..h]);
        assert_eq!(zero.sample(1.5, 3.25), Some(0.75 * 49.5 + 0.25 * 65.5));
        assert_eq!(zero.sample(0.5, 2.5), None);
    }
}

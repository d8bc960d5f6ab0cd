//! Each level's pixels in use: the strongest gradient of each block, made
//! once a frame from the current image, and those that may show a hazard
//! left out.

use super::*;

/// Each level's chosen pixels: the strongest gradient of each block, far
/// rows first. The choice depends on the current image alone, so it is
/// made once a frame.
pub(super) struct Chosen {
    /// The levels' pixels one after the other, finest first.
    pub(super) pixels: [(u8, u8); CHOSEN_CAPACITY],
    /// Where each level's are in `pixels`: start and end.
    pub(super) ranges: [(usize, usize); LEVELS],
    /// Each level's blocks' side, level pixels.
    pub(super) sides: [usize; LEVELS],
}

/// One level's chosen pixels.
#[derive(Clone, Copy)]
pub(super) struct ChosenLevel<'a> {
    pub(super) pixels: &'a [(u8, u8)],
    /// The blocks' side, level pixels.
    pub(super) side: usize,
}

impl Chosen {
    pub(super) const EMPTY: Chosen = Chosen { pixels: [(0, 0); CHOSEN_CAPACITY], ranges: [(0, 0); LEVELS], sides: [1; LEVELS] };

    pub(super) fn level(&self, level: usize) -> ChosenLevel<'_> {
        let (start, end) = self.ranges[level];
        ChosenLevel { pixels: &self.pixels[start..end], side: self.sides[level] }
    }
}

/// The side of [`choose`]'s blocks on a level `w` x `h` pixels: the
/// smallest that makes at most [`MAX_POINTS`] of them; None for a level
/// too small for any (or too large for a `u8` pixel).
const fn block_side(w: usize, h: usize) -> Option<usize> {
    if w < 3 || h < 3 || w > 256 || h > 256 {
        return None;
    }
    let mut side = 1;
    while w.div_ceil(side) * h.div_ceil(side) > MAX_POINTS {
        side += 1;
    }
    Some(side)
}

/// Most pixels [`choose`] keeps of a level `w` x `h` pixels: one per block
/// of its interior (columns and rows 1 to the last but one), blocks from
/// row 1 and column 0 on, and [`MAX_POINTS`] at most.
const fn most_chosen(w: usize, h: usize) -> usize {
    let Some(side) = block_side(w, h) else { return 0 };
    let block_rows = (h - 2).div_ceil(side);
    let block_columns = (w - 2) / side - 1 / side + 1;
    let most = block_rows * block_columns;
    if most < MAX_POINTS { most } else { MAX_POINTS }
}

/// Room for every level's chosen pixels, on any grid: [`MAX_POINTS`] for
/// the image, the most [`most_chosen`] gives on each coarser level (a
/// level of 4 or 8 grid pixels has fewer pixels than MAX_POINTS blocks or
/// not many more: 496 and 420 of a 256 x 256 grid's, not 512).
const CHOSEN_CAPACITY: usize = {
    let mut total = MAX_POINTS;
    let mut level = 1;
    while level < LEVELS {
        let largest = crate::grid::MAX_GRID_SIDE / pyramid::SCALES[level];
        let mut most = 0;
        let mut w = 0;
        while w <= largest {
            let mut h = 0;
            while h <= largest {
                let n = most_chosen(w, h);
                if n > most {
                    most = n;
                }
                h += 1;
            }
            w += 1;
        }
        total += most;
        level += 1;
    }
    total
};

/// Chooses the strongest-gradient pixel of each block of `level` (at least
/// [`MIN_GRADIENT_SUM`]), blocks sized so that at most [`MAX_POINTS`] are chosen.
/// Writes them to `out` (at most its length) and returns how many; the
/// blocks' side to `chosen_side` (unless the level is too small for any).
/// A frame of its own: inlined into the estimate, its blocks (1 KB) would
/// lie under the alignment's deepest calls.
#[inline(never)]
pub(super) fn choose(level: &Level, out: &mut [(u8, u8)], chosen_side: &mut usize) -> usize {
    // Blocks of many pixels are scanned on every second row and column:
    // one strong pixel of a block is all it gives, and a quarter of the
    // finest level's scan is most of the choice's cost.
    let stride = if level.width * level.height > 4 * MAX_POINTS { 2 } else { 1 };
    let mut count = 0;
    let (w, h) = (level.width, level.height);
    let Some(side) = block_side(w, h) else { return count };
    *chosen_side = side;
    let mut strongest = [kernels::Strongest::default(); crate::grid::MAX_GRID_SIDE];
    let strongest = &mut strongest[..w.div_ceil(side)];
    let mut block_row_start = 1;
    while block_row_start < h - 1 {
        let block_row_end = (block_row_start + side).min(h - 1);
        strongest.fill(kernels::Strongest::default());
        for j in (block_row_start..block_row_end).step_by(stride) {
            let (above, here, below) = (level.seen[j - 1], level.seen[j], level.seen[j + 1]);
            let lo = usize::from(above.0.max(below.0)).max(usize::from(here.0) + 1).max(1);
            let hi = usize::from(above.1.min(below.1)).min(usize::from(here.1).saturating_sub(1)).min(w - 1);
            let line = |j: usize| &level.pixels[j * w..][..w];
            let rows = kernels::GradientRows { up: line(j - 1), row: line(j), down: line(j + 1) };
            kernels::strongest_gradients(rows, j as u8, lo..hi, side, stride, strongest);
        }
        for block in strongest.iter() {
            if u32::from(block.strength) >= MIN_GRADIENT_SUM {
                // Capacity: at most MAX_POINTS blocks by construction, and
                // `out` holds `most_chosen` of the level.
                if count < out.len().min(MAX_POINTS) {
                    out[count] = (block.column, block.row);
                    count += 1;
                }
            }
        }
        block_row_start = block_row_end;
    }
    count
}

/// Leaves out the chosen pixels that may show a hazard, unless that would
/// leave fewer than [`MIN_GROUND_SHARE_PERCENT`] of them: a view that is mostly
/// hazard (or mistaken for it) is aligned as a whole, as before.
/// `range`: the level's in `pixels`, its end moved back by those left out.
pub(super) fn leave_out(level: usize, pixels: &mut [(u8, u8)], range: &mut (usize, usize), hazards: &MovedMask) -> bool {
    let ground = |&(i, j): &(u8, u8)| !hazards.covers(to_grid(level, u16::from(i)), to_grid(level, u16::from(j)));
    let chosen = &mut pixels[range.0..range.1];
    let kept = chosen.iter().filter(|p| ground(p)).count();
    let leave = kept < chosen.len() && kept * 100 >= MIN_GROUND_SHARE_PERCENT * chosen.len();
    if leave {
        // In order, as Vec::retain.
        let mut end = 0;
        for k in 0..chosen.len() {
            if ground(&chosen[k]) {
                chosen[end] = chosen[k];
                end += 1;
            }
        }
        range.1 = range.0 + end;
    }
    leave
}

/// The share of a level's chosen pixels the hazard mask must leave (percent).
const MIN_GROUND_SHARE_PERCENT: usize = 25;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chosen_pixels_fit_on_the_largest_grid() {
        // The image's 512, level 1 at most 496 (a 32 x 63 level), level 2 420.
        assert_eq!(CHOSEN_CAPACITY, MAX_POINTS + 496 + 420);
        assert_eq!(most_chosen(32, 63), 496);
        assert_eq!(most_chosen(32, 16), 420);
        assert_eq!(most_chosen(256, 256), 484);
        assert_eq!(most_chosen(128, 256), MAX_POINTS);
    }
}

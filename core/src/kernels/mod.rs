//! Instruction-set kernels: the byte loops of the GPA (SAD, shift search,
//! |diff| histogram, bilinear lines) and of the remap (pinhole rows, ring
//! row copy), with one selection of the instruction set.
//!
//! Four backends hold the same functions:
//! - `portable`: plain Rust, the reference, and the SIMD backends' tails;
//! - `sse2`: x86_64 (SSE2 is baseline there);
//! - `neon`: aarch64, e.g. a Raspberry Pi host (NEON is baseline there;
//!   checked under `qemu-aarch64`, `.ci/test`);
//! - `dsp`: Cortex-M4/M7, `asm!` with the DSP extension (cfg `flatland_dsp`,
//!   set by build.rs for `thumbv7em`).
//!
//! `selected` below is the backend the entry points of this module call.
//! Apart from it, two keyframe sampling loops have their own: the
//! parallax hypotheses' (`gpa::keyframe::lines::offsets`), `asm!` on the
//! M4, and the search band's stacks and spans of lines
//! (`gpa::keyframe::lines::stack`); each has an AVX2 version on an x86_64
//! that has it (`avx2()`, found at run time). All give identical results;
//! `checks` compares them with the portable ones and with per-pixel loops,
//! on the host and on the emulated M4 (`cargo fw-test`), and the AVX2
//! loops' own tests with their plain versions.

// Where a SIMD backend is selected, only its tails and the checks call the
// portable one, each a part of it.
#[cfg_attr(any(flatland_dsp, target_arch = "x86_64", target_arch = "aarch64"), allow(dead_code))]
mod portable;

#[cfg(flatland_dsp)]
mod dsp;
#[cfg(flatland_dsp)]
use dsp as selected;

#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
mod sse2;
#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
use sse2 as selected;

#[cfg(all(target_arch = "aarch64", not(flatland_dsp)))]
mod neon;
#[cfg(all(target_arch = "aarch64", not(flatland_dsp)))]
use neon as selected;

#[cfg(not(any(flatland_dsp, target_arch = "x86_64", target_arch = "aarch64")))]
use portable as selected;

pub(crate) mod pinhole;

// Whether this x86_64 CPU has AVX2, found once at run time by `cpufeatures`
// (`cpuid` and the OS's saved vector state, without std).
#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
cpufeatures::new!(cpu_avx2, "avx2");

/// Whether the AVX2 kernels run: the parallax hypotheses' gathered samples
/// (`gpa::keyframe::lines::offsets`) and the band's lines
/// (`gpa::keyframe::lines::stack`), beside the baseline SSE2 ones. Their
/// tests compare them with the plain versions where the CPU has AVX2.
#[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
#[inline(always)]
pub(crate) fn avx2() -> bool {
    cpu_avx2::get()
}

use crate::grid::MAX_GRID_SIDE;

#[cfg(any(test, feature = "selftest"))]
pub mod checks;

// ------------------------------------------------------------------ GPA

/// The seed's levels: |diff| above `SUM_LEVEL` is summed, above `COUNT_LEVEL` counted.
pub const SUM_LEVEL: u8 = 30;
pub const COUNT_LEVEL: u8 = 50;

/// Sum of |a - b| over the common length.
#[inline]
pub fn sad(a: &[u8], b: &[u8]) -> u32 {
    selected::sad(a, b)
}

/// A cell row's residues summed per grid column as its rows come
/// ([`add_to_columns`]), and per cell when it ends
/// ([`ColumnTotals::take_pieces`]): each pixel is added once, where it is
/// made, rather than per cell segment of every row.
#[repr(C, align(4))]
pub struct ColumnTotals {
    /// Per column: 16 for each pixel counted, plus its hot flag (0 or 1).
    /// Over a cell row's at most 15 rows both parts stay below 16.
    tallies: [u8; MAX_GRID_SIDE],
    /// Per column: the ground residues' sum.
    ground: [u16; MAX_GRID_SIDE],
}

/// Rows a cell row may have: below 16, a column's pixels and hot flags
/// each fit a nibble of its tally.
pub const MAX_TALLIED_ROWS: usize = 15;

impl ColumnTotals {
    pub const EMPTY: ColumnTotals = ColumnTotals { tallies: [0; MAX_GRID_SIDE], ground: [0; MAX_GRID_SIDE] };

    /// Adds one pixel at column `c` (below [`MAX_GRID_SIDE`]): its hot flag
    /// (0 or 1) and its ground residue.
    #[inline(always)]
    fn add(&mut self, c: usize, hot: u8, ground: u8) {
        self.tallies[c] = self.tallies[c].wrapping_add(16 | hot);
        self.ground[c] = self.ground[c].wrapping_add(u16::from(ground));
    }

    /// Writes the sums since the last call over each piece k of the first
    /// `width` columns cut `px` wide (as many as `pieces` holds) to
    /// `pieces[k]`, and starts every column again at 0; returns the
    /// pieces written.
    pub fn take_pieces(&mut self, px: usize, width: usize, pieces: &mut [PieceSums]) -> usize {
        let (px, width) = (px.max(1), width.min(MAX_GRID_SIDE));
        let count = width.div_ceil(px).min(pieces.len());
        if count > 0 {
            selected::take_pieces(self, px, 0..(count * px).min(width), &mut pieces[..count]);
        }
        // Whole, aligned arrays clear in word stores (a byte range would not).
        self.tallies = [0; MAX_GRID_SIDE];
        self.ground = [0; MAX_GRID_SIDE];
        count
    }
}

/// One piece's sums from [`ColumnTotals::take_pieces`], in a word: hot
/// pixels and pixels (at most 15 * 15 each) in its two low bytes, the
/// ground residues (at most 225 * 255) in its high halfword.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(transparent)]
pub struct PieceSums(u32);

impl PieceSums {
    pub const ZERO: PieceSums = PieceSums(0);

    /// Packs a tally's sum (hot pixels plus 16 per pixel), the sum of its
    /// high nibbles (the pixels) and the ground residues' sum.
    #[inline(always)]
    fn pack(tally: u32, pixels: u32, ground: u32) -> PieceSums {
        PieceSums((tally - 16 * pixels) | pixels << 8 | ground << 16)
    }

    pub fn hot(self) -> u32 {
        self.0 & 0xFF
    }

    pub fn pixels(self) -> u32 {
        (self.0 >> 8) & 0xFF
    }

    pub fn ground(self) -> u32 {
        self.0 >> 16
    }
}

/// Adds `hot[c]` (0 or 1) and `ground[c]` to `totals` at every column c of
/// `columns` (within both slices and the grid); returns the hot pixels.
#[inline]
pub fn add_to_columns(hot: &[u8], ground: &[u8], columns: core::ops::Range<usize>, totals: &mut ColumnTotals) -> u32 {
    let end = columns.end.min(hot.len()).min(ground.len()).min(MAX_GRID_SIDE);
    if columns.start >= end {
        return 0;
    }
    selected::add_to_columns(hot, ground, columns.start..end, totals)
}

/// The shift search's kernel: `sums[k] += SAD(current, reference[k..k + n])`
/// for every shift `k` in `0..sums.len()`, n = `current.len()`.
/// `reference` holds at least `n + sums.len() - 1` bytes (shorter: no-op).
/// One call does a whole row of shifts so each current word is loaded once.
#[inline]
pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
    if sums.is_empty() || reference.len() + 1 < current.len() + sums.len() {
        return;
    }
    selected::sad_shifts(current, reference, sums)
}

/// A histogram of |diff|, counted into the backend's number of interleaved
/// lanes (four on x86_64 and aarch64, one on the M4: see `HISTOGRAM_LANES` there).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DiffHistogram {
    lanes: [[u32; 256]; selected::HISTOGRAM_LANES],
}

impl DiffHistogram {
    pub const EMPTY: DiffHistogram = DiffHistogram { lanes: [[0; 256]; selected::HISTOGRAM_LANES] };

    pub fn clear(&mut self) {
        *self = Self::EMPTY;
    }

    /// Counts `|a[n] - b[n]|` over the common length.
    #[inline]
    pub fn add(&mut self, a: &[u8], b: &[u8]) {
        selected::diff_histogram(a, b, &mut self.lanes)
    }

    /// Adds one |diff| (the per-pixel reference path).
    pub fn add_one(&mut self, diff: u8) {
        self.lanes[0][usize::from(diff)] += 1;
    }

    /// The counts per |diff| level.
    pub fn counts(&self) -> [u32; 256] {
        let mut counts = self.lanes[0];
        for lane in &self.lanes[1..] {
            for (count, &more) in counts.iter_mut().zip(lane) {
                *count += more;
            }
        }
        counts
    }
}

/// The seed's statistics of `|a[n] - b[n]|` over the common length, as
/// [`seed_statistics`] of their histogram gives them (the sums wrap),
/// without the histogram: a search whose histogram nothing else reads.
#[inline]
pub fn seed_sums(a: &[u8], b: &[u8]) -> (u32, u32) {
    let n = a.len().min(b.len());
    selected::seed_sums(&a[..n], &b[..n])
}

/// The seed's statistics from a |diff| histogram: the sum of |diff| above
/// [`SUM_LEVEL`] and the count above [`COUNT_LEVEL`].
pub fn seed_statistics(histogram: &[u32; 256]) -> (u32, u32) {
    let mut sum_above = 0u32;
    let mut count_above = 0u32;
    for (level, &count) in histogram.iter().enumerate() {
        if level > usize::from(SUM_LEVEL) {
            sum_above = sum_above.wrapping_add(count.wrapping_mul(level as u32));
        }
        if level > usize::from(COUNT_LEVEL) {
            count_above = count_above.wrapping_add(count);
        }
    }
    (sum_above, count_above)
}

/// One line of bilinear samples with constant weights (`wx`, `wy` in 0..=255,
/// 1/256 units): `out[n]` from `upper[n..=n + 1]` and `lower[n..=n + 1]`,
/// `((top * (256 - wy) + bottom * wy + 2^15) >> 16)` with
/// `top = upper[n] * (256 - wx) + upper[n + 1] * wx` (likewise `bottom`).
/// `upper` and `lower` hold at least `out.len() + 1` bytes.
#[inline]
pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
    debug_assert!(wx <= 255 && wy <= 255);
    selected::bilinear_line(upper, lower, wx, wy, out)
}

/// Bilinear samples along a straight line between one pair of rows (a
/// stretch of a yawed line): `out[n]` blends `upper[x..=x + 1]` and
/// `lower[x..=x + 1]` as [`bilinear_line`] does, at `x` the whole pixels
/// (top 8 bits) and `wx` the next 8 bits of the Q8.24 column position
/// `i + n i_step`, and `wy` bits 16..24 of the row position `j + n j_step`
/// (wrapping sums, steps two's complement). Every `x + 1` must index
/// `upper` and `lower`: checked at both ends, the last one exactly (in
/// i64, so none between wraps), and the positions are linear.
#[inline]
pub fn bilinear_stretch(upper: &[u8], lower: &[u8], (i, i_step): (u32, u32), (j, j_step): (u32, u32), out: &mut [u8]) {
    let Some(last) = out.len().checked_sub(1) else { return };
    let last_position = i64::from(i) + last as i64 * i64::from(i_step as i32);
    let inside = |position: i64| (0..1 << 32).contains(&position) && ((position >> 24) as usize) + 1 < upper.len().min(lower.len());
    assert!(inside(i64::from(i)) && inside(last_position), "bilinear_stretch beyond its rows");
    selected::bilinear_stretch(upper, lower, (i, i_step), (j, j_step), out)
}

// ------------------------------------------------------ tolerant residue

/// A current row and, aligned by column, the warped keyframe around it:
/// `centre[c + 1]` under pixel `row[c]` (`centre` starts a column early, so
/// that the sideways neighbours are `centre[c]` and `centre[c + 2]`), and
/// `up[c]`, `down[c]` along. `centre` holds two bytes more than `row`, `up`
/// and `down` as many.
#[derive(Clone, Copy)]
pub struct ResidueLines<'a> {
    pub row: &'a [u8],
    pub centre: &'a [u8],
    pub up: &'a [u8],
    pub down: &'a [u8],
}

impl<'a> ResidueLines<'a> {
    /// The lines of `columns` (of `row`).
    pub fn columns(&self, columns: core::ops::Range<usize>) -> ResidueLines<'a> {
        let (a, b) = (columns.start, columns.end);
        ResidueLines { row: &self.row[a..b], centre: &self.centre[a..b + 2], up: &self.up[a..b], down: &self.down[a..b] }
    }

    /// Columns every line covers.
    fn len(&self) -> usize {
        self.row.len().min(self.centre.len().saturating_sub(2)).min(self.up.len()).min(self.down.len())
    }
}

/// The two tolerant residues of every pixel of `lines.row` against the
/// warped keyframe (see `gpa::residue`): the range that the keyframe under
/// it spans with its neighbours sideways and along. Writes `hot[c]`, 1
/// where the wide residue (the range reaching every neighbour) is above
/// `threshold` and 0 elsewhere, and `ground[c]`, the ground residue, whose
/// range reaches halfway to each neighbour, or all the way sideways with
/// `full.0`, along with `full.1`.
#[inline]
pub fn residues(lines: ResidueLines, full: (bool, bool), threshold: u8, hot: &mut [u8], ground: &mut [u8]) {
    let n = lines.len().min(hot.len()).min(ground.len());
    let (lines, hot, ground) = (lines.columns(0..n), &mut hot[..n], &mut ground[..n]);
    match full {
        (false, false) => selected::residues::<false, false>(lines, threshold, hot, ground),
        (true, false) => selected::residues::<true, false>(lines, threshold, hot, ground),
        (false, true) => selected::residues::<false, true>(lines, threshold, hot, ground),
        (true, true) => selected::residues::<true, true>(lines, threshold, hot, ground),
    }
}

/// One pixel's two residues (wide, ground) as [`residues`] defines them,
/// `FULL_K` / `FULL_G` for `full`: the definition every backend reproduces.
/// The halfway point is monotone in the neighbour, so the range's ends are
/// those of the nearest and farthest neighbour per axis.
#[inline(always)]
pub(crate) fn residue_pair<const FULL_K: bool, const FULL_G: bool>(value: u8, here: u8, sideways: [u8; 2], along: [u8; 2]) -> (u8, u8) {
    let half = |other: u8| ((u16::from(here) + u16::from(other) + 1) >> 1) as u8;
    let reach = |other: u8, full: bool| if full { other } else { half(other) };
    let (k_low, k_high) = (sideways[0].min(sideways[1]), sideways[0].max(sideways[1]));
    let (g_low, g_high) = (along[0].min(along[1]), along[0].max(along[1]));
    let beyond = |low: u8, high: u8| value.saturating_sub(high).max(low.saturating_sub(value));
    let wide = beyond(here.min(k_low).min(g_low), here.max(k_high).max(g_high));
    let ground = beyond(
        here.min(reach(k_low, FULL_K)).min(reach(g_low, FULL_G)),
        here.max(reach(k_high, FULL_K)).max(reach(g_high, FULL_G)),
    );
    (wide, ground)
}

// ------------------------------------------------------- block matching

/// A row of bytes as 16-bit lanes, two to a word (`row[2i]` low,
/// `row[2i + 1]` high): the block side of [`dot_shifts`]. Fills
/// `row.len() / 2` words.
pub fn pack_pairs(row: &[u8], pairs: &mut [u32]) {
    for (pair, two) in pairs.iter_mut().zip(row.chunks_exact(2)) {
        *pair = u32::from(two[0]) | (u32::from(two[1]) << 16);
    }
}

/// The block matcher's correlation: `sums[k] += sum over x of row[x] *
/// patch[k + x]` for every shift `k` in `0..sums.len()`, the row packed by
/// [`pack_pairs`] into `pairs`. `patch` values stay below 2^15 (the M4
/// multiplies signed lanes) and it holds at least `2 * pairs.len() +
/// sums.len() - 1` of them (fewer: no-op). Sums wrap, as the M4's do.
#[inline]
pub fn dot_shifts(pairs: &[u32], patch: &[u16], sums: &mut [u32]) {
    if sums.is_empty() || patch.len() + 1 < 2 * pairs.len() + sums.len() {
        return;
    }
    selected::dot_shifts(pairs, patch, sums)
}

// ---------------------------------------------------------------- float

/// The square root, correctly rounded as IEEE 754 asks: bit for bit what
/// `libm::sqrtf` gives, from the M4F's `vsqrt.f32` (five instructions with
/// its moves) instead of libm's software loop (~40 a call, ~1 M a frame in
/// the block matcher's scores).
#[inline]
pub fn sqrtf(x: f32) -> f32 {
    #[cfg(all(flatland_dsp, target_abi = "eabihf"))]
    {
        let mut bits = x.to_bits();
        // SAFETY: the hard-float ABI implies the FPU. Rust's target does not
        // name it as its (unstable) `vfp2` feature, without which `asm!`
        // takes no FPU register, so the value goes through s0, saved and
        // restored around it.
        unsafe {
            core::arch::asm!(
                "vpush {{s0}}",
                "vmov s0, {bits}",
                "vsqrt.f32 s0, s0",
                "vmov {bits}, s0",
                "vpop {{s0}}",
                bits = inout(reg) bits,
                options(pure, nomem),
            )
        };
        f32::from_bits(bits)
    }
    #[cfg(not(all(flatland_dsp, target_abi = "eabihf")))]
    libm::sqrtf(x)
}

/// Bit patterns of the `f32`s in [+0, 2^23): there truncation is the
/// FPU's one conversion, and a remainder below one is exact.
const SMALL_POSITIVE_END: u32 = 0x4B00_0000;

/// `libm::floorf`, bit for bit: below 2^23 (GTI's sample positions) the
/// FPU's conversions (libm works the bits in software, ~24 M4
/// instructions); elsewhere libm itself.
#[inline]
pub fn floorf(x: f32) -> f32 {
    if x.to_bits() < SMALL_POSITIVE_END {
        x as u32 as f32
    } else {
        libm::floorf(x)
    }
}

/// `libm::roundf` (halves away from zero), bit for bit: below 2^23 the
/// truncation, one more if the remainder is a half or more (libm: ~43 M4
/// instructions); elsewhere libm itself.
#[inline]
pub fn roundf(x: f32) -> f32 {
    if x.to_bits() < SMALL_POSITIVE_END {
        let whole = x as u32;
        (whole + u32::from(x - whole as f32 >= 0.5)) as f32
    } else {
        libm::roundf(x)
    }
}

/// `value as f32` (round to nearest, ties to even), for |value| < 2^62:
/// the M4 has no 64-bit conversion, and the library's takes ~25
/// instructions; here the value is cut to 31 bits with the bits cut off
/// kept as a sticky bit, so the FPU's one 32-bit conversion rounds it as
/// the whole would be, then scaled back by a power of two (exact).
#[inline]
pub fn i64_to_f32(value: i64) -> f32 {
    const LIMIT: i64 = 1 << 62;
    if value == value as i32 as i64 {
        return value as i32 as f32;
    }
    if !(-LIMIT..LIMIT).contains(&value) {
        return value as f32;
    }
    let magnitude = value.unsigned_abs();
    // Bits above the 31 a positive i32 holds.
    let cut = 33 - magnitude.leading_zeros();
    let kept = (magnitude >> cut) as u32 | u32::from(magnitude & ((1 << cut) - 1) != 0);
    let scaled = kept as i32 as f32 * f32::from_bits((127 + cut) << 23);
    if value < 0 { -scaled } else { scaled }
}

/// `libm::sincosf(x)`, bit for bit, without its software `f64` where
/// the motion estimate's angles lie (|x| in [2^-12, pi/4], ~400 M4
/// instructions against ~2,400 a miss of its memo). There libm rounds to
/// `f32` the `f64` value of two fixed polynomials; here they are summed
/// in 62-bit fixed point, within 2^-56 of that value, and rounded the same
/// way, unless that close to halfway between two `f32`s: then, and
/// everywhere else, libm itself.
pub fn sincosf(x: f32) -> (f32, f32) {
    let magnitude = x.to_bits() & 0x7FFF_FFFF;
    if !SINCOSF_OWN.contains(&magnitude) {
        return libm::sincosf(x);
    }
    let exponent = (magnitude >> 23) as i32 - 127;
    let q62 = u64::from(magnitude & 0x7F_FFFF | 0x80_0000) << (exponent + 39);
    let (sin, cos) = sin_cos_q62(q62);
    match (round_q62(sin), round_q62(cos)) {
        (Some(sin), Some(cos)) => (if x < 0.0 { -sin } else { sin }, cos),
        _ => libm::sincosf(x),
    }
}

/// The |x| (bits) [`sincosf`] computes itself: libm's polynomials, from
/// 2^-12 (below, libm gives x itself and 1) to ~pi/4.
const SINCOSF_OWN: core::ops::RangeInclusive<u32> = 0x3980_0000..=0x3F49_0FDA;

/// libm's (FreeBSD's) k_sinf and k_cosf polynomials at `x` (Q62, 0 < x <
/// 1), exactly but for the truncation of each product (~2^-58 in all).
/// Written with the coefficients' magnitudes, so every product is of two
/// non-negative numbers (each bracket is: its first term dominates).
fn sin_cos_q62(x: u64) -> (i64, i64) {
    const ONE: u64 = 1 << 62;
    // |coefficients| of k_sinf.rs and k_cosf.rs in Q62 (S3, S4 and C3
    // lose bits below 2^-62); S1, S3, C0 and C2 are negative.
    const S1: u64 = 0x15_5555_54CB_AC77 << 7;
    const S2: u64 = 0x11_1110_896E_FBB2 << 3;
    const S3: u64 = 0x1A_00F9_E2CA_E774 >> 3;
    const S4: u64 = 0x16_CD87_8C3B_46A7 >> 9;
    const C0: u64 = 0x1F_FFFF_FD0C_5E81 << 8;
    const C1: u64 = 0x15_5553_E105_3A42 << 5;
    const C2: u64 = 0x16_C087_E80F_1E27;
    const C3: u64 = 0x19_9342_E0EE_5069 >> 6;
    let z = mul_q62(x, x);
    let w = mul_q62(z, z);
    let s = mul_q62(z, x);
    // x + s (S1 + z S2) + s w (S3 + z S4)
    let sin = x as i64 - mul_q62(s, S1 - mul_q62(z, S2)) as i64 - mul_q62(mul_q62(s, w), S3 - mul_q62(z, S4)) as i64;
    // 1 + z C0 + w C1 + w z (C2 + z C3)
    let cos = ONE as i64 - mul_q62(z, C0) as i64 + mul_q62(w, C1) as i64 - mul_q62(mul_q62(w, z), C2 - mul_q62(z, C3)) as i64;
    (sin, cos)
}

/// a b in Q62, truncated (a, b < 2: four 32-bit products).
fn mul_q62(a: u64, b: u64) -> u64 {
    let (a1, a0, b1, b0) = (a >> 32, a & 0xFFFF_FFFF, b >> 32, b & 0xFFFF_FFFF);
    let low = a0 * b0;
    let (cross_a, cross_b) = (a1 * b0, a0 * b1);
    let middle = (low >> 32) + (cross_a & 0xFFFF_FFFF) + (cross_b & 0xFFFF_FFFF);
    let high = a1 * b1 + (cross_a >> 32) + (cross_b >> 32) + (middle >> 32);
    (high << 2) | ((middle & 0xFFFF_FFFF) >> 30)
}

/// A Q62 value in [2^-13, 2) to the nearest `f32`, or None within 2^-45
/// of its own size (plus 2^-56) of halfway: libm's `f64` could round there
/// either way.
fn round_q62(value: i64) -> Option<f32> {
    let v = u64::try_from(value).ok()?;
    if v < 1 << 49 {
        return None;
    }
    let top = 63 - v.leading_zeros();
    let shift = top - 23;
    let (mut mantissa, rest, half) = (v >> shift, v & ((1 << shift) - 1), 1u64 << (shift - 1));
    if rest.abs_diff(half) <= (v >> 45) + (1 << 6) {
        return None;
    }
    let mut exponent = top as i32 - 62 + 127;
    if rest > half {
        mantissa += 1;
        if mantissa == 1 << 24 {
            (mantissa, exponent) = (1 << 23, exponent + 1);
        }
    }
    Some(f32::from_bits((exponent as u32) << 23 | (mantissa as u32 & 0x7F_FFFF)))
}

/// `libm::hypotf(x, y)`, bit for bit, without its software `f64`: libm
/// rounds the exact x^2 + y^2 to `f64`, that to `f32`, and takes the
/// `f32` root; here x^2 + y^2 is summed exactly in integers and rounded
/// the same two ways (~80 M4 instructions against ~400). Zeros, infinities,
/// NaN, operands 2^25 apart and magnitudes beyond 2^+-60 (libm's scaled
/// paths) go to libm itself.
#[inline]
pub fn hypotf(x: f32, y: f32) -> f32 {
    let (ux, uy) = (x.to_bits() & 0x7FFF_FFFF, y.to_bits() & 0x7FFF_FFFF);
    let (high, low) = if ux < uy { (uy, ux) } else { (ux, uy) };
    if low < (0x7F - 60) << 23 || high >= (0x7F + 60) << 23 || high - low >= 25 << 23 {
        return libm::hypotf(x, y);
    }
    // Both normal: value = m 2^(e - 150), m with its implicit bit.
    let parts = |bits: u32| (bits >> 23, u64::from(bits & 0x7F_FFFF | 0x80_0000));
    let ((e_high, m_high), (e_low, m_low)) = (parts(high), parts(low));
    // x^2 + y^2 = sum 2^(2 (e_low - 150)), exactly: in 64 bits while the
    // two are within 7 binades (most residuals), else in 128 (under 2^98).
    let apart = 2 * (e_high - e_low);
    let (rounded, shift) = if apart <= 15 {
        let sum = ((m_high * m_high) << apart) + m_low * m_low;
        let (rounded, shift) = round_u64(sum, 53);
        let (rounded, more) = round_u64(rounded, 24);
        (rounded, shift + more)
    } else {
        let sum = (u128::from(m_high * m_high) << apart) + u128::from(m_low * m_low);
        let (rounded, shift) = round_u128(sum, 53);
        let (rounded, more) = round_u128(rounded, 24);
        (rounded as u64, shift + more)
    };
    // rounded in [2^23, 2^24] times 2^(shift + 2 (e_low - 150)).
    let (mantissa, exponent) = if rounded == 1 << 24 { (1u64 << 23, shift + 1) } else { (rounded, shift) };
    let biased = exponent as i32 + 2 * (e_low as i32 - 150) + 23 + 127;
    sqrtf(f32::from_bits(((biased as u32) << 23) | (mantissa as u32 & 0x7F_FFFF)))
}

/// `value` rounded to `bits` significant bits, to nearest with ties to
/// even: the significand and the power of two it is scaled by. For each
/// width the M4 handles (`u64` in registers, `u128` in library calls).
macro_rules! round_to_bits {
    ($name:ident, $int:ty) => {
        #[inline]
        fn $name(value: $int, bits: u32) -> ($int, u32) {
            let width = <$int>::BITS - value.leading_zeros();
            if width <= bits {
                return (value, 0);
            }
            let cut = width - bits;
            let (kept, rest, half) = (value >> cut, value & ((1 << cut) - 1), (1 as $int) << (cut - 1));
            let up = rest > half || (rest == half && kept & 1 == 1);
            (kept + <$int>::from(up), cut)
        }
    };
}
round_to_bits!(round_u64, u64);
round_to_bits!(round_u128, u128);

// ------------------------------------------------------- normal equations

/// Unknowns of the motion estimate's normal equations: 7 geometric ones,
/// then the exposure's gain and offset.
pub const NORMAL_UNKNOWNS: usize = 9;

/// One pixel's part in the normal equations: its derivatives are
/// `(jacobian, brightness, 1)` (the gain's is the keyframe's gray level
/// minus 128, the offset's 1).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct NormalTerm<'a> {
    pub weight: f32,
    pub residual: f32,
    pub brightness: f32,
    pub jacobian: &'a [f32; 7],
}

impl NormalTerm<'_> {
    pub const EMPTY: NormalTerm<'static> = NormalTerm { weight: 0.0, residual: 0.0, brightness: 0.0, jacobian: &[0.0; 7] };
}

/// Adds each term's `w j j^T` to the upper triangle of `h` and `w r j` to
/// `g`, term by term in order (each sum as a plain loop would make it,
/// bit for bit).
#[inline]
pub fn add_normal_terms(terms: &[NormalTerm], h: &mut [[f32; NORMAL_UNKNOWNS]; NORMAL_UNKNOWNS], g: &mut [f32; NORMAL_UNKNOWNS]) {
    selected::add_normal_terms(terms, h, g)
}

// ------------------------------------------------------------ pyramid

/// `out[k]` = the rounded mean of the 4x4 block of `rows` at columns
/// `4k..4k + 4`, for every `k` of `out` (each row holds at least
/// `4 * out.len()` bytes): the motion estimate's pyramid level 1.
#[inline]
pub fn mean_4x4(rows: [&[u8]; 4], out: &mut [u8]) {
    let n = out.len();
    if rows.iter().any(|row| row.len() < 4 * n) {
        return;
    }
    selected::mean_4x4(rows, out)
}

/// A pixel row with the rows above and below it, of one width: where
/// [`strongest_gradients`] measures.
#[derive(Clone, Copy)]
pub struct GradientRows<'a> {
    pub up: &'a [u8],
    pub row: &'a [u8],
    pub down: &'a [u8],
}

/// The gradient strength of column `i` (inside the rows, not at their
/// ends): `|row[i + 1] - row[i - 1]| + |down[i] - up[i]|`, the definition
/// every backend reproduces.
#[inline(always)]
pub(crate) fn gradient_strength(rows: GradientRows, i: usize) -> u32 {
    u32::from(rows.row[i + 1].abs_diff(rows.row[i - 1])) + u32::from(rows.down[i].abs_diff(rows.up[i]))
}

/// A block's strongest pixel so far (strength 0: none yet), a word on the M4.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C, align(4))]
pub struct Strongest {
    pub strength: u16,
    pub column: u8,
    pub row: u8,
}

/// The motion estimate's point choice along row `row` (its index, kept in
/// the pixels chosen): in each block of `side` columns, block b at columns
/// `b * side..(b + 1) * side`, the columns from `columns.start` (at least 1)
/// or the block's first, by `stride`, below `columns.end` (those without a
/// right neighbour, past `strongest`'s blocks or from 256, beyond a `u8`,
/// left out) replace `strongest[b]` when stronger by [`gradient_strength`],
/// so the first of equal ones stays.
#[inline]
pub fn strongest_gradients(rows: GradientRows, row: u8, columns: core::ops::Range<usize>, side: usize, stride: usize, strongest: &mut [Strongest]) {
    let width = rows.row.len().min(rows.up.len()).min(rows.down.len());
    let end = columns.end.min(width.saturating_sub(1)).min(strongest.len() * side).min(usize::from(u8::MAX) + 1);
    let columns = columns.start.max(1)..end;
    if columns.is_empty() || side == 0 {
        return;
    }
    selected::strongest_gradients(rows, row, columns, side, stride.max(1), strongest)
}

// ---------------------------------------------------------------- remap

/// Fractional bits of the fixed-point source coordinates (Q16.16 pixels).
pub const FRAC_BITS: u32 = 16;
/// Bits of the bilinear weights (1/256 px: far below the remap's 1/32 px error bound).
const WEIGHT_BITS: u32 = 8;

/// Bilinear sample at (u, v) Q16.16 from two camera rows, in integers: the
/// definition every remap path reproduces.
#[inline(always)]
pub(crate) fn bilinear(upper: &[u8], lower: &[u8], u: i32, v: i32) -> u8 {
    let x0 = (u >> FRAC_BITS) as usize;
    let x1 = (x0 + 1).min(upper.len() - 1);
    let wx = ((u >> (FRAC_BITS - WEIGHT_BITS)) & 0xFF) as u32;
    let wy = ((v >> (FRAC_BITS - WEIGHT_BITS)) & 0xFF) as u32;
    let top = u32::from(upper[x0]) * (256 - wx) + u32::from(upper[x1]) * wx;
    let bottom = u32::from(lower[x0]) * (256 - wx) + u32::from(lower[x1]) * wx;
    ((top * (256 - wy) + bottom * wy + (1 << (2 * WEIGHT_BITS - 1))) >> (2 * WEIGHT_BITS)) as u8
}

/// `dst.copy_from_slice(src)` (same length): a camera row into the remap's
/// ring, a KG row into its image.
#[inline]
pub fn copy_row(dst: &mut [u8], src: &[u8]) {
    selected::copy_row(dst, src)
}

#[cfg(test)]
mod tests {
    /// Every 61st `f32` of the range `floorf` and `roundf` compute themselves.
    #[test]
    fn floor_round_equal_libm_across_their_range() {
        for x in (0..super::SMALL_POSITIVE_END).step_by(61).map(f32::from_bits) {
            assert_eq!(super::floorf(x).to_bits(), libm::floorf(x).to_bits(), "floorf {x:e}");
            assert_eq!(super::roundf(x).to_bits(), libm::roundf(x).to_bits(), "roundf {x:e}");
        }
    }

    /// Every 61st `f32` of the range `sincosf` computes itself, both signs.
    #[test]
    fn sincosf_equals_libm_across_its_range() {
        for bits in super::SINCOSF_OWN.step_by(61) {
            for x in [f32::from_bits(bits), -f32::from_bits(bits)] {
                let ((s, c), (ls, lc)) = (super::sincosf(x), libm::sincosf(x));
                assert!(s.to_bits() == ls.to_bits() && c.to_bits() == lc.to_bits(), "{x:e}: {s:e} {c:e} vs libm {ls:e} {lc:e}");
            }
        }
    }
}

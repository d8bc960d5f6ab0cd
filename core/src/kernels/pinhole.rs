//! The pinhole row in two passes, bit-identical to [`bilinear`] per pixel.
//!
//! A pinhole KG row samples one pair of camera rows (`upper`, `lower`) at a
//! constant `v`, so `wy` is constant along it. All of [`bilinear`] is exact
//! integer arithmetic up to the final shift, so it may be summed in the
//! other order: vertical first,
//! `V[x] = upper[x] * (256 - wy) + lower[x] * wy` (<= 65,280: a u16), once per
//! source column the row touches, then per KG pixel
//! `(V[x0] * (256 - wx) + V[x1] * wx + 2^15) >> 16`, the same integer as
//! `(top * (256 - wy) + bottom * wy + 2^15) >> 16`. The `x1 = min(x0 + 1,
//! width - 1)` clamp becomes one duplicated entry after the last column.
//!
//! The vertical pass is contiguous and vectorises (SSE2 or NEON on the
//! host, packed halfwords on the M4); the horizontal one is one pair load
//! and one multiply-add per pixel. On x86_64 (`sse2`) and on the M4 (`dsp`,
//! `asm!`) the line holds `V ^ FLIP`, which read as i16 is `V - 2^15`, so
//! that a signed 16x16 dual multiply-add (`pmaddwd`, `smlad`) blends the
//! pair `[V[x0] | V[x0 + 1]]` (one 32-bit load) with `[256 - wx | wx]` at
//! once. On aarch64 (`neon`) it holds `V`, as `portable`'s does: NEON's
//! multiplies are unsigned and widen, so the flip would gain nothing.
//! This module holds the line and the span checks; the passes are the
//! backends' `pinhole_vertical` and `pinhole_horizontal`.

use super::{bilinear, selected, FRAC_BITS, WEIGHT_BITS};
use crate::limits::MAX_IMAGE_SIDE;

/// Entries of the line: the widest camera row, the duplicated last
/// column, and one spare to keep the size a whole number of words.
pub const LINE_CAPACITY: usize = MAX_IMAGE_SIDE as usize + 2;

/// The vertical pass of one KG row, word aligned (the M4 stores it with `strd`).
#[derive(Clone)]
#[repr(C, align(4))]
pub struct Line(pub [u16; LINE_CAPACITY]);

impl Line {
    pub const ZERO: Line = Line([0; LINE_CAPACITY]);
}

/// Source columns `first..=last` a row reads (`last` includes the `x0 + 1`
/// neighbour, clamped), and its start relative to `first` (Q16.16).
struct Span {
    first: usize,
    columns: usize,
    u: i32,
}

/// The span of `n` pixels from `u` by `step`, if every pixel's source
/// lies in `[0, width - 1]` (as a valid row of a built table does) and
/// the span fits the line. Then `u + c * step` never overflows i32 and
/// the kernels' reads are in bounds.
fn span(width: usize, u: i32, step: i32, n: usize) -> Option<Span> {
    let last_u = i64::from(u) + i64::from(step) * (n as i64 - 1);
    let (low, high) = (i64::from(u).min(last_u), i64::from(u).max(last_u));
    let max_u = (width as i64 - 1) << FRAC_BITS;
    if n == 0 || low < 0 || high > max_u || high > i64::from(i32::MAX) {
        return None;
    }
    let first = (low >> FRAC_BITS) as usize;
    let last = ((high >> FRAC_BITS) as usize + 1).min(width - 1);
    let columns = last + 1 - first;
    if columns + 1 > LINE_CAPACITY {
        return None;
    }
    // u >= low >= first << 16, and u <= high <= i32::MAX.
    Some(Span { first, columns, u: (i64::from(u) - ((first as i64) << FRAC_BITS)) as i32 })
}

/// `out[c]` = [`bilinear`]`(upper, lower, u + c * step, v)` (wrapping
/// u), with the kernels in use. Rows whose sources all lie in the image
/// take the two passes; anything else (no built table gives it) is
/// sampled per pixel.
#[inline]
pub fn sample_row(upper: &[u8], lower: &[u8], u: i32, step: i32, v: i32, line: &mut Line, out: &mut [u8]) {
    let kernels = (selected::pinhole_vertical as Vertical, selected::pinhole_horizontal as Horizontal);
    sample_row_with(kernels, upper, lower, u, step, v, line, out);
}

/// `line[..upper.len()]` from `upper` and `lower` (same length) at `wy`.
pub(super) type Vertical = fn(&[u8], &[u8], u32, &mut [u16]);
/// # Safety
/// For every `c < out.len()`, `x = (u + c * step) >> 16` (no overflow,
/// `u + c * step >= 0`) has `x + 1 < line.len()`.
pub(super) type Horizontal = unsafe fn(&[u16], i32, i32, &mut [u8]);

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn sample_row_with(
    (vertical, horizontal): (Vertical, Horizontal),
    upper: &[u8],
    lower: &[u8],
    u: i32,
    step: i32,
    v: i32,
    line: &mut Line,
    out: &mut [u8],
) -> bool {
    let width = upper.len();
    let Some(span) = span(width, u, step, out.len()).filter(|_| lower.len() == width) else {
        let mut u = u;
        for pixel in out {
            *pixel = bilinear(upper, lower, u, v);
            u = u.wrapping_add(step);
        }
        return false;
    };
    let wy = ((v >> (FRAC_BITS - WEIGHT_BITS)) & 0xFF) as u32;
    let columns = span.columns;
    let range = span.first..span.first + columns;
    vertical(&upper[range.clone()], &lower[range], wy, &mut line.0[..columns]);
    // x1 = min(x0 + 1, width - 1): past the last column, itself again.
    line.0[columns] = line.0[columns - 1];
    // SAFETY: `span` checked that every source u lies in
    // [first << 16, (first + columns - 1) << 16] without overflow, so
    // relative to `first` each x0 has x0 + 1 <= columns < line length.
    unsafe { horizontal(&line.0[..columns + 1], span.u, step, out) };
    true
}

/// What the x86_64 and M4 backends' line holds is `V ^ FLIP`: `V - 2^15`
/// as an i16 (portable and `neon` hold `V`, so there it goes unused).
#[cfg_attr(not(any(flatland_dsp, target_arch = "x86_64")), allow(dead_code))]
pub(super) const FLIP: u16 = 0x8000;


/// [`sample_row`] with the portable kernels; false if it sampled per pixel.
#[cfg(any(test, feature = "selftest"))]
pub fn sample_row_portable(upper: &[u8], lower: &[u8], u: i32, step: i32, v: i32, line: &mut Line, out: &mut [u8]) -> bool {
    sample_row_with((super::portable::pinhole_vertical, super::portable::pinhole_horizontal), upper, lower, u, step, v, line, out)
}

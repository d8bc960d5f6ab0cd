//! The tolerant residue, every operation per byte (`usub8` + `sel`).

use crate::kernels::{self, portable};

/// Per byte: (max(a, b), min(a, b)): `usub8` sets a GE flag per byte where
/// a >= b, and `sel` picks by them.
#[inline(always)]
fn max_min(a: u32, b: u32) -> (u32, u32) {
    let (max, min);
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!(
            "usub8 {t}, {a}, {b}",
            "sel {max}, {a}, {b}",
            "sel {min}, {b}, {a}",
            a = in(reg) a, b = in(reg) b, t = out(reg) _, max = out(reg) max, min = out(reg) min,
            options(pure, nomem, nostack)
        );
    }
    (max, min)
}

/// Per byte: max(a, b), or with `MIN` min(a, b) (`usub8` + one `sel`).
#[inline(always)]
fn extreme<const MIN: bool>(a: u32, b: u32) -> u32 {
    let (first, second) = if MIN { (b, a) } else { (a, b) };
    let picked;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!(
            "usub8 {t}, {a}, {b}",
            "sel {picked}, {first}, {second}",
            a = in(reg) a, b = in(reg) b, first = in(reg) first, second = in(reg) second, t = out(reg) _, picked = lateout(reg) picked,
            options(pure, nomem, nostack)
        );
    }
    picked
}

/// Per byte: a - b, or 0 below.
#[inline(always)]
fn saturating_sub(a: u32, b: u32) -> u32 {
    let difference;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!("uqsub8 {d}, {a}, {b}", a = in(reg) a, b = in(reg) b, d = out(reg) difference, options(pure, nomem, nostack));
    }
    difference
}

/// Per byte: (a + b + 1) >> 1, as a - ((a - b) >> 1): `uhsub8` halves the
/// 9-bit difference rounding down, so the result is exact (and a byte).
#[inline(always)]
fn rounded_half(a: u32, b: u32) -> u32 {
    let half: u32;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!("uhsub8 {h}, {a}, {b}", "usub8 {h}, {a}, {h}", a = in(reg) a, b = in(reg) b, h = out(reg) half, options(pure, nomem, nostack));
    }
    half
}

/// Per byte of `x`: 1 above `threshold` (replicated in each byte), 0
/// elsewhere: `usub8` from 0 flags the bytes that are 0 after the
/// subtraction, `sel` makes the others 1.
#[inline(always)]
fn above(x: u32, threshold: u32) -> u32 {
    let flags;
    // SAFETY: register arithmetic only.
    unsafe {
        core::arch::asm!(
            "uqsub8 {x}, {x}, {threshold}",
            "usub8 {x}, {zero}, {x}",
            "sel {flags}, {zero}, {ones}",
            x = inout(reg) x => _, threshold = in(reg) threshold, zero = in(reg) 0u32, ones = in(reg) 0x0101_0101u32,
            flags = lateout(reg) flags,
            options(pure, nomem, nostack)
        );
    }
    flags
}

/// Four pixels a step, every operation per byte: min and max by `usub8` +
/// `sel`, the halfway reach by `uhadd8`, the residues by `uqsub8`; a word
/// of each output stored at once.
#[inline(always)]
pub fn residues<const FULL_K: bool, const FULL_G: bool>(lines: kernels::ResidueLines, threshold: u8, hot: &mut [u8], ground: &mut [u8]) {
    let kernels::ResidueLines { row, centre, up, down } = lines;
    let n = lines.len().min(hot.len()).min(ground.len());
    let words = n / 4;
    let threshold4 = u32::from(threshold) * 0x0101_0101;
    for w in 0..words {
        let c = 4 * w;
        // SAFETY: c + 4 <= n, so the words at row, up, down, hot, ground + c
        // and at centre + c, c + 1, c + 2 lie within their slices (centre
        // has n + 2 bytes); unaligned word accesses are fine on the M4.
        let (value, left, here, right, along_up, along_down) = unsafe {
            let word = |slice: &[u8], at: usize| core::ptr::read_unaligned(slice.as_ptr().add(at).cast::<u32>());
            (word(row, c), word(centre, c), word(centre, c + 1), word(centre, c + 2), word(up, c), word(down, c))
        };
        let (k_high, k_low) = max_min(left, right);
        let (g_high, g_low) = max_min(along_up, along_down);
        let (min, max) = (extreme::<true>, extreme::<false>);
        // The halfway reach is monotone and leaves `here` where it is, so
        // min(here, half(a), half(b)) = half(min(here, a, b)) (max alike):
        // the ground range's ends are the reaches of the ranges of `here`
        // and the neighbours along the axes that take the half.
        let half = |ends: u32| rounded_half(here, ends);
        let (wide_low, wide_high, low, high) = match (FULL_K, FULL_G) {
            (false, false) => {
                let (low, high) = (min(here, min(k_low, g_low)), max(here, max(k_high, g_high)));
                (low, high, half(low), half(high))
            }
            (true, false) => {
                let (low, high) = (min(here, g_low), max(here, g_high));
                (min(k_low, low), max(k_high, high), min(k_low, half(low)), max(k_high, half(high)))
            }
            (false, true) => {
                let (low, high) = (min(here, k_low), max(here, k_high));
                (min(g_low, low), max(g_high, high), min(g_low, half(low)), max(g_high, half(high)))
            }
            (true, true) => {
                let (low, high) = (min(here, min(k_low, g_low)), max(here, max(k_high, g_high)));
                (low, high, low, high)
            }
        };
        let wide = saturating_sub(value, wide_high) | saturating_sub(wide_low, value);
        let residue = saturating_sub(value, high) | saturating_sub(low, value);
        // SAFETY: as above.
        unsafe {
            core::ptr::write_unaligned(hot.as_mut_ptr().add(c).cast::<u32>(), above(wide, threshold4));
            core::ptr::write_unaligned(ground.as_mut_ptr().add(c).cast::<u32>(), residue);
        }
    }
    let c = 4 * words;
    portable::residues::<FULL_K, FULL_G>(lines.columns(c..n), threshold, &mut hot[c..n], &mut ground[c..n]);
}

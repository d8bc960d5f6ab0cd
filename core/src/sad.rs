//! Byte-block difference kernels for the GPA's hot loops.
//!
//! On Cortex-M4/M7 (`thumbv7em`, cfg `flatland_dsp` from build.rs) they use
//! the DSP extension through `asm!` (LLVM never emits these): `usada8` adds
//! four absolute differences in one instruction, `usub8` + `sel` compare and
//! select four bytes, `smlad` does the bilinear blends two products at a
//! time. On x86_64 they use SSE2 (baseline there, so no runtime
//! detection, which `no_std` could not do anyway): `psadbw` for sums of 16
//! absolute differences, saturating subtractions for |diff| and the levels.
//! Elsewhere the portable versions run. All give identical results; the
//! `checks` below (also on the emulated M4, `cargo fw-test`) compare them.

/// The seed's levels: |diff| above `SUM_LEVEL` is summed, above `COUNT_LEVEL` counted.
pub const SUM_LEVEL: u8 = 30;
pub const COUNT_LEVEL: u8 = 50;

/// Sums over a block: SAD and the seed's statistics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SeedSums {
    pub sad: u32,
    /// Sum of |diff| where |diff| > [`SUM_LEVEL`].
    pub sum_above: u32,
    /// Count of |diff| > [`COUNT_LEVEL`].
    pub count_above: u32,
}

/// Sum of |a - b| over the common length.
#[inline]
pub fn sad(a: &[u8], b: &[u8]) -> u32 {
    #[cfg(flatland_dsp)]
    {
        dsp::sad(a, b)
    }
    #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
    {
        sse2::sad(a, b)
    }
    #[cfg(not(any(flatland_dsp, target_arch = "x86_64")))]
    {
        portable::sad(a, b)
    }
}

/// SAD plus the seed's statistics over the common length.
#[inline]
pub fn seed_sums(a: &[u8], b: &[u8]) -> SeedSums {
    #[cfg(flatland_dsp)]
    {
        dsp::seed_sums(a, b)
    }
    #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
    {
        sse2::seed_sums(a, b)
    }
    #[cfg(not(any(flatland_dsp, target_arch = "x86_64")))]
    {
        portable::seed_sums(a, b)
    }
}

/// One line of bilinear samples with constant weights (`wx`, `wy` in 0..=255,
/// 1/256 units): `out[n]` from `upper[n..=n + 1]` and `lower[n..=n + 1]`,
/// `((top * (256 - wy) + bottom * wy + 2^15) >> 16)` with
/// `top = upper[n] * (256 - wx) + upper[n + 1] * wx` (likewise `bottom`).
/// `upper` and `lower` hold at least `out.len() + 1` bytes.
#[inline]
pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
    debug_assert!(wx <= 255 && wy <= 255);
    #[cfg(flatland_dsp)]
    {
        dsp::bilinear_line(upper, lower, wx, wy, out)
    }
    #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
    {
        sse2::bilinear_line(upper, lower, wx, wy, out)
    }
    #[cfg(not(any(flatland_dsp, target_arch = "x86_64")))]
    {
        portable::bilinear_line(upper, lower, wx, wy, out)
    }
}

/// Plain Rust; the reference for the DSP versions.
pub mod portable {
    use super::{SeedSums, COUNT_LEVEL, SUM_LEVEL};

    #[inline]
    pub fn sad(a: &[u8], b: &[u8]) -> u32 {
        // u16 lanes over blocks of 256 cannot overflow and vectorise well.
        let mut total = 0u32;
        for (a, b) in a.chunks(256).zip(b.chunks(256)) {
            let block: u16 = a.iter().zip(b).map(|(&x, &y)| u16::from(x.abs_diff(y))).fold(0u16, u16::wrapping_add);
            total += u32::from(block);
        }
        total
    }

    #[inline]
    pub fn seed_sums(a: &[u8], b: &[u8]) -> SeedSums {
        let mut sums = SeedSums::default();
        for (a, b) in a.chunks(256).zip(b.chunks(256)) {
            let (mut sad, mut above, mut count) = (0u16, 0u16, 0u16);
            for (&x, &y) in a.iter().zip(b) {
                let d = x.abs_diff(y);
                sad = sad.wrapping_add(u16::from(d));
                above = above.wrapping_add(if d > SUM_LEVEL { u16::from(d) } else { 0 });
                count = count.wrapping_add(u16::from(d > COUNT_LEVEL));
            }
            sums.sad += u32::from(sad);
            sums.sum_above += u32::from(above);
            sums.count_above += u32::from(count);
        }
        sums
    }

    #[inline]
    pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
        let (ax, ay) = (256 - wx, 256 - wy);
        for ((pixel, u), l) in out.iter_mut().zip(upper.windows(2)).zip(lower.windows(2)) {
            let top = u32::from(u[0]) * ax + u32::from(u[1]) * wx;
            let bottom = u32::from(l[0]) * ax + u32::from(l[1]) * wx;
            *pixel = ((top * ay + bottom * wy + (1 << 15)) >> 16) as u8;
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub mod sse2 {
    use super::{portable, SeedSums, COUNT_LEVEL, SUM_LEVEL};
    use core::arch::x86_64::*;

    /// Low and high 64-bit lanes of a `psadbw` accumulator, added.
    #[inline(always)]
    fn total(v: __m128i) -> u32 {
        // SAFETY: SSE2 is part of the x86_64 baseline.
        unsafe { (_mm_cvtsi128_si64(v) + _mm_cvtsi128_si64(_mm_unpackhi_epi64(v, v))) as u32 }
    }

    #[inline]
    pub fn sad(a: &[u8], b: &[u8]) -> u32 {
        let n = a.len().min(b.len());
        let (a, b) = (&a[..n], &b[..n]);
        let mut done = 0;
        // SAFETY: SSE2 is baseline on x86_64; every load reads 16 (or 8)
        // bytes inside `a[..n]` and `b[..n]` (unaligned loads).
        let acc = unsafe {
            let mut acc = _mm_setzero_si128();
            while done + 16 <= n {
                let x = _mm_loadu_si128(a.as_ptr().add(done).cast());
                let y = _mm_loadu_si128(b.as_ptr().add(done).cast());
                acc = _mm_add_epi64(acc, _mm_sad_epu8(x, y));
                done += 16;
            }
            if done + 8 <= n {
                let x = _mm_loadl_epi64(a.as_ptr().add(done).cast());
                let y = _mm_loadl_epi64(b.as_ptr().add(done).cast());
                acc = _mm_add_epi64(acc, _mm_sad_epu8(x, y));
                done += 8;
            }
            acc
        };
        total(acc) + portable::sad(&a[done..], &b[done..])
    }

    #[inline]
    pub fn seed_sums(a: &[u8], b: &[u8]) -> SeedSums {
        let n = a.len().min(b.len());
        let (a, b) = (&a[..n], &b[..n]);
        let mut done = 0;
        // |d| > level  <=>  saturating (|d| - level) != 0; the selected bytes
        // (|d| itself, or 1 to count) are summed by `psadbw` against zero.
        #[inline(always)]
        unsafe fn step(x: __m128i, y: __m128i, acc: &mut [__m128i; 3]) {
            let zero = _mm_setzero_si128();
            let d = _mm_or_si128(_mm_subs_epu8(x, y), _mm_subs_epu8(y, x));
            let low = _mm_cmpeq_epi8(_mm_subs_epu8(d, _mm_set1_epi8(SUM_LEVEL as i8)), zero);
            let quiet = _mm_cmpeq_epi8(_mm_subs_epu8(d, _mm_set1_epi8(COUNT_LEVEL as i8)), zero);
            acc[0] = _mm_add_epi64(acc[0], _mm_sad_epu8(d, zero));
            acc[1] = _mm_add_epi64(acc[1], _mm_sad_epu8(_mm_andnot_si128(low, d), zero));
            acc[2] = _mm_add_epi64(acc[2], _mm_sad_epu8(_mm_andnot_si128(quiet, _mm_set1_epi8(1)), zero));
        }
        // SAFETY: SSE2 is baseline on x86_64; loads stay inside `a[..n]`, `b[..n]`.
        let acc = unsafe {
            let mut acc = [_mm_setzero_si128(); 3];
            while done + 16 <= n {
                let x = _mm_loadu_si128(a.as_ptr().add(done).cast());
                let y = _mm_loadu_si128(b.as_ptr().add(done).cast());
                step(x, y, &mut acc);
                done += 16;
            }
            if done + 8 <= n {
                // The upper 8 bytes are zero in both: |d| = 0 adds nothing.
                let x = _mm_loadl_epi64(a.as_ptr().add(done).cast());
                let y = _mm_loadl_epi64(b.as_ptr().add(done).cast());
                step(x, y, &mut acc);
                done += 8;
            }
            acc
        };
        let tail = portable::seed_sums(&a[done..], &b[done..]);
        SeedSums {
            sad: total(acc[0]) + tail.sad,
            sum_above: total(acc[1]) + tail.sum_above,
            count_above: total(acc[2]) + tail.count_above,
        }
    }

    /// 16 samples per step. `top` (<= 65,280) fits u16 lanes; the vertical
    /// blend uses `pmaddwd` on (top - 2^15, bottom - 2^15) pairs, which are
    /// i16, and adds back 2^15 * 256: the same integer as the portable sum.
    #[inline]
    pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
        let n = out.len().min(upper.len().saturating_sub(1)).min(lower.len().saturating_sub(1));
        let mut done = 0;
        // SAFETY: SSE2 is baseline on x86_64; loads read upper/lower[done..done + 17]
        // (< n + 1 <= len) and stores write out[done..done + 16] (<= n).
        unsafe {
            let zero = _mm_setzero_si128();
            let ax = _mm_set1_epi16((256 - wx) as i16);
            let wxv = _mm_set1_epi16(wx as i16);
            let weights = _mm_set1_epi32(((wy as i32) << 16) | (256 - wy) as i32);
            let bias = _mm_set1_epi32((1 << 23) + (1 << 15));
            let flip = _mm_set1_epi16(i16::MIN);
            let (pu, pl, po) = (upper.as_ptr(), lower.as_ptr(), out.as_mut_ptr());
            while done + 16 <= n {
                let u0 = _mm_loadu_si128(pu.add(done).cast());
                let u1 = _mm_loadu_si128(pu.add(done + 1).cast());
                let l0 = _mm_loadu_si128(pl.add(done).cast());
                let l1 = _mm_loadu_si128(pl.add(done + 1).cast());
                let horizontal = |p0: __m128i, p1: __m128i, high: bool| {
                    let (a, b) = if high {
                        (_mm_unpackhi_epi8(p0, zero), _mm_unpackhi_epi8(p1, zero))
                    } else {
                        (_mm_unpacklo_epi8(p0, zero), _mm_unpacklo_epi8(p1, zero))
                    };
                    _mm_xor_si128(_mm_add_epi16(_mm_mullo_epi16(a, ax), _mm_mullo_epi16(b, wxv)), flip)
                };
                let vertical = |top: __m128i, bottom: __m128i| {
                    let lo = _mm_madd_epi16(_mm_unpacklo_epi16(top, bottom), weights);
                    let hi = _mm_madd_epi16(_mm_unpackhi_epi16(top, bottom), weights);
                    let lo = _mm_srli_epi32(_mm_add_epi32(lo, bias), 16);
                    let hi = _mm_srli_epi32(_mm_add_epi32(hi, bias), 16);
                    _mm_packs_epi32(lo, hi)
                };
                let first = vertical(horizontal(u0, u1, false), horizontal(l0, l1, false));
                let second = vertical(horizontal(u0, u1, true), horizontal(l0, l1, true));
                _mm_storeu_si128(po.add(done).cast(), _mm_packus_epi16(first, second));
                done += 16;
            }
        }
        portable::bilinear_line(&upper[done..], &lower[done..], wx, wy, &mut out[done..n]);
    }
}

#[cfg(flatland_dsp)]
mod dsp {
    use super::{portable, SeedSums, COUNT_LEVEL, SUM_LEVEL};

    #[inline]
    pub fn sad(a: &[u8], b: &[u8]) -> u32 {
        let n = a.len().min(b.len());
        let words = n / 4;
        let mut acc = 0u32;
        if words > 0 {
            // SAFETY: reads `words` words (unaligned ldr is fine on M4) from
            // `a` and `b`, which hold at least 4 * words bytes each.
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldr {x}, [{pa}], #4",
                    "ldr {y}, [{pb}], #4",
                    "usada8 {acc}, {x}, {y}, {acc}",
                    "subs {n}, {n}, #1",
                    "bne 2b",
                    pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                    n = inout(reg) words => _, acc = inout(reg) acc,
                    x = out(reg) _, y = out(reg) _,
                    options(readonly, nostack)
                );
            }
        }
        acc + portable::sad(&a[4 * words..n], &b[4 * words..n])
    }

    /// The word loop is one `asm!` block: the GE flags must survive from
    /// `usub8` to `sel`, and inlined into the GPA's row code LLVM spilled
    /// every accumulator (30 instructions per word instead of 12).
    #[inline]
    pub fn seed_sums(a: &[u8], b: &[u8]) -> SeedSums {
        let n = a.len().min(b.len());
        let words = n / 4;
        let (mut sad, mut above, mut count31) = (0u32, 0u32, 0u32);
        if words > 0 {
            let sum_level = u32::from_ne_bytes([SUM_LEVEL + 1; 4]);
            let count_level = u32::from_ne_bytes([COUNT_LEVEL + 1; 4]);
            // SAFETY: reads `words` words from `a` and `b` (at least
            // 4 * words bytes each); register arithmetic and APSR.GE only.
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldr {x}, [{pa}], #4",
                    "ldr {y}, [{pb}], #4",
                    "usada8 {sad}, {x}, {y}, {sad}",
                    "usub8 {t}, {x}, {y}",            // GE[i] = x >= y
                    "usub8 {y}, {y}, {x}",            // GE[i] = y >= x
                    "sel {x}, {y}, {t}",              // x = |x - y| per byte
                    "usub8 {t}, {x}, {sl}",           // GE[i] = d > SUM_LEVEL
                    "sel {t}, {x}, {zero}",
                    "usada8 {above}, {t}, {zero}, {above}",
                    "usub8 {t}, {x}, {cl}",           // GE[i] = d > COUNT_LEVEL
                    // Out of registers for a 0x01 constant: count in units of
                    // SUM_LEVEL + 1 (31) and divide at the end.
                    "sel {t}, {sl}, {zero}",
                    "usada8 {count}, {t}, {zero}, {count}",
                    "subs {n}, {n}, #1",
                    "bne 2b",
                    pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                    n = inout(reg) words => _,
                    x = out(reg) _, y = out(reg) _, t = out(reg) _,
                    sad = inout(reg) sad, above = inout(reg) above, count = inout(reg) count31,
                    zero = in(reg) 0u32, sl = in(reg) sum_level, cl = in(reg) count_level,
                    options(readonly, nostack)
                );
            }
        }
        let tail = portable::seed_sums(&a[4 * words..n], &b[4 * words..n]);
        SeedSums {
            sad: sad + tail.sad,
            sum_above: above + tail.sum_above,
            count_above: count31 / u32::from(SUM_LEVEL + 1) + tail.count_above,
        }
    }

    /// Vertical blend first (exact integers, so the same value as the
    /// portable horizontal-first order): `V[x] = upper[x] * (256 - wy) +
    /// lower[x] * wy` (<= 65,280), then `out[n] = (V[n] * (256 - wx) +
    /// V[n + 1] * wx + 2^15) >> 16`. Both steps are `smlad`s with one
    /// accumulator constant `K = 2^23 + 2^15`:
    /// - vertical: `smlad((u, l), (256 - wy, wy), K)` = `V + K`, whose low
    ///   halfword is `V + 2^15 mod 2^16`, i.e. `V - 2^15` as an i16 (V < 2^16);
    /// - horizontal: `smlad((V[n] - 2^15, V[n + 1] - 2^15), (256 - wx, wx), K)`
    ///   = `V[n] * (256 - wx) + V[n + 1] * wx - 2^15 * 256 + 2^23 + 2^15`,
    ///   the portable sum before the shift (< 2^24, so bits 24..31 are zero).
    ///
    /// 4 samples per iteration, 26 instructions; `V` of the last column is
    /// carried to the next iteration. The tail (< 4 samples) is portable.
    #[inline]
    pub fn bilinear_line(upper: &[u8], lower: &[u8], wx: u32, wy: u32, out: &mut [u8]) {
        const K: u32 = (1 << 23) + (1 << 15);
        let n = out.len().min(upper.len().saturating_sub(1)).min(lower.len().saturating_sub(1));
        let words = n / 4;
        if words > 0 {
            let wxs = (256 - wx) | (wx << 16);
            let wys = (256 - wy) | (wy << 16);
            let v0 = u32::from(upper[0]) * (256 - wy) + u32::from(lower[0]) * wy + K;
            // SAFETY: iteration i reads the words upper/lower[4i + 1..4i + 5]
            // (the last ends at 4 * words + 1 <= n + 1 <= len) and writes the
            // word out[4i..4i + 4] (<= n <= out.len()); unaligned ldr/str are
            // fine on the M4. Register arithmetic only otherwise.
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldr {u}, [{pu}], #4",            // bytes u1 u2 u3 u4
                    "ldr {l}, [{pl}], #4",
                    "pkhbt {a}, {u}, {l}, lsl #16",   // bytes u1 u2 l1 l2
                    "pkhtb {b}, {l}, {u}, asr #16",   // bytes u3 u4 l3 l4
                    "uxtb16 {u}, {a}",                // (u1, l1)
                    "smlad {u}, {u}, {wy}, {k}",      // V1 + K
                    "uxtb16 {a}, {a}, ror #8",        // (u2, l2)
                    "smlad {a}, {a}, {wy}, {k}",      // V2 + K
                    "pkhbt {v}, {v}, {u}, lsl #16",   // (V0, V1) - 2^15
                    "smlad {v}, {v}, {wx}, {k}",      // out0 << 16
                    "pkhbt {u}, {u}, {a}, lsl #16",   // (V1, V2) - 2^15
                    "smlad {u}, {u}, {wx}, {k}",      // out1 << 16
                    "uxtb16 {l}, {b}",                // (u3, l3)
                    "smlad {l}, {l}, {wy}, {k}",      // V3 + K
                    "pkhbt {a}, {a}, {l}, lsl #16",   // (V2, V3) - 2^15
                    "smlad {a}, {a}, {wx}, {k}",      // out2 << 16
                    "pkhtb {a}, {a}, {v}, asr #16",   // out0 | out2 << 16
                    "uxtb16 {b}, {b}, ror #8",        // (u4, l4)
                    "smlad {v}, {b}, {wy}, {k}",      // V4 + K: V0 of the next iteration
                    "pkhbt {l}, {l}, {v}, lsl #16",   // (V3, V4) - 2^15
                    "smlad {l}, {l}, {wx}, {k}",      // out3 << 16
                    "pkhtb {l}, {l}, {u}, asr #16",   // out1 | out3 << 16
                    "orr {a}, {a}, {l}, lsl #8",
                    "str {a}, [{po}], #4",
                    "subs {n}, {n}, #1",
                    "bne 2b",
                    pu = inout(reg) upper[1..].as_ptr() => _, pl = inout(reg) lower[1..].as_ptr() => _,
                    po = inout(reg) out.as_mut_ptr() => _, n = inout(reg) words => _,
                    v = inout(reg) v0 => _,
                    u = out(reg) _, l = out(reg) _, a = out(reg) _, b = out(reg) _,
                    wx = in(reg) wxs, wy = in(reg) wys, k = in(reg) K,
                    options(nostack)
                );
            }
        }
        let done = 4 * words;
        portable::bilinear_line(&upper[done..], &lower[done..], wx, wy, &mut out[done..n]);
    }
}

#[cfg(any(test, feature = "selftest"))]
/// Checks (host `#[test]`s and `cargo fw-test` on the emulated M4): the
/// kernels in use equal the portable ones and a plain per-pixel loop.
pub mod checks {
    use super::{portable, SeedSums, COUNT_LEVEL, SUM_LEVEL};

    fn plain(a: &[u8], b: &[u8]) -> SeedSums {
        let mut s = SeedSums::default();
        for (&x, &y) in a.iter().zip(b) {
            let d = u32::from(x.abs_diff(y));
            s.sad += d;
            if d > u32::from(SUM_LEVEL) {
                s.sum_above += d;
            }
            if d > u32::from(COUNT_LEVEL) {
                s.count_above += 1;
            }
        }
        s
    }

    /// xorshift32: deterministic bytes without a dependency.
    fn fill(buffer: &mut [u8], mut state: u32, spread: u32) {
        for byte in buffer.iter_mut() {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            *byte = if spread >= 256 { state as u8 } else { 128u32.wrapping_add(state % (2 * spread + 1)).wrapping_sub(spread) as u8 };
        }
    }

    /// Every length 0..=300, unaligned starts, random and edge values
    /// (0, 255, the levels and their neighbours).
    pub fn dsp_kernels_equal_portable() -> Result<(), &'static str> {
        let mut a = [0u8; 307];
        let mut b = [0u8; 307];
        for (round, spread) in [(1u32, 256u32), (2, 60), (3, 30), (4, 3)].into_iter() {
            fill(&mut a, 0x9E37_79B9 ^ round, spread);
            fill(&mut b, 0x85EB_CA6B ^ (round * 7), spread);
            if round == 1 {
                // Exact edges: |diff| of 30, 31, 50, 51, 255.
                let edges = [(0u8, 30u8), (31, 0), (100, 50), (49, 100), (0, 255), (255, 0), (200, 149), (7, 7)];
                for (n, (x, y)) in edges.iter().enumerate() {
                    a[n] = *x;
                    b[n] = *y;
                }
            }
            for start in 0..4 {
                for length in 0..=300 {
                    let (x, y) = (&a[start..start + length], &b[3 - start..3 - start + length]);
                    let expected = plain(x, y);
                    if super::seed_sums(x, y) != expected || portable::seed_sums(x, y) != expected {
                        return Err("seed_sums differs from the per-pixel loop");
                    }
                    if super::sad(x, y) != expected.sad || portable::sad(x, y) != expected.sad {
                        return Err("sad differs from the per-pixel loop");
                    }
                }
            }
        }
        Ok(())
    }

    /// The bilinear kernel in use and the portable one equal a per-pixel loop:
    /// every length 0..=300, unaligned starts of `upper`, `lower` and `out`
    /// (independently), edge weights (0, 1, 128, 255) and random ones, random
    /// pixels, pixels near the middle, and all-0 / all-255 / alternating 0-255
    /// lines (the extremes of the intermediate sums).
    pub fn bilinear_line_equals_plain() -> Result<(), &'static str> {
        let mut upper = [0u8; 310];
        let mut lower = [0u8; 310];
        let mut out = [0u8; 310];
        let mut state = 0x1234_5678u32;
        let mut random = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state
        };
        for round in 0..6u32 {
            match round {
                0 | 1 => {
                    fill(&mut upper, 0x2545_F491 ^ round, if round == 0 { 256 } else { 3 });
                    fill(&mut lower, 0x6C07_8965 ^ (round * 3), if round == 0 { 256 } else { 3 });
                    upper[..4].copy_from_slice(&[255, 0, 255, 255]);
                    lower[..4].copy_from_slice(&[255, 255, 0, 255]);
                }
                2 => {
                    upper.fill(255);
                    lower.fill(255);
                }
                3 => {
                    upper.fill(0);
                    lower.fill(0);
                }
                4 => {
                    for (n, (u, l)) in upper.iter_mut().zip(lower.iter_mut()).enumerate() {
                        *u = if n % 2 == 0 { 255 } else { 0 };
                        *l = if n % 3 == 0 { 0 } else { 255 };
                    }
                }
                _ => {
                    for (n, (u, l)) in upper.iter_mut().zip(lower.iter_mut()).enumerate() {
                        *u = if n % 2 == 0 { 0 } else { 255 };
                        *l = if n % 2 == 0 { 255 } else { 0 };
                    }
                }
            }
            let mut weights = [(0u32, 0u32), (255, 255), (0, 255), (255, 0), (128, 1), (1, 128), (128, 128), (1, 1), (77, 201), (0, 0), (0, 0), (0, 0)];
            for pair in weights[9..].iter_mut() {
                let r = random();
                *pair = (r & 0xFF, (r >> 8) & 0xFF);
            }
            for (n, &(wx, wy)) in weights.iter().enumerate() {
                for (length, kernel) in (0..=600).map(|k| (k / 2, k % 2)) {
                    let r = random() as usize;
                    let (su, sl, so) = ((n + length) % 4, (r >> 4) % 4, (r >> 8) % 4);
                    let (u, l) = (&upper[su..su + length + 1], &lower[sl..sl + length + 1]);
                    out.fill(0xA5);
                    let target = &mut out[so..so + length];
                    if kernel == 0 {
                        super::bilinear_line(u, l, wx, wy, target);
                    } else {
                        portable::bilinear_line(u, l, wx, wy, target);
                    }
                    for (c, &got) in target.iter().enumerate() {
                        let top = u32::from(u[c]) * (256 - wx) + u32::from(u[c + 1]) * wx;
                        let bottom = u32::from(l[c]) * (256 - wx) + u32::from(l[c + 1]) * wx;
                        if u32::from(got) != (top * (256 - wy) + bottom * wy + (1 << 15)) >> 16 {
                            return Err("bilinear_line differs from the per-pixel formula");
                        }
                    }
                    if out[..so].iter().chain(&out[so + length..]).any(|&b| b != 0xA5) {
                        return Err("bilinear_line wrote outside its output");
                    }
                }
            }
        }
        Ok(())
    }

    #[cfg(test)]
    #[test]
    fn bilinear_line_equals_plain_host() {
        assert_eq!(bilinear_line_equals_plain(), Ok(()));
    }

    #[cfg(test)]
    #[test]
    fn dsp_kernels_equal_portable_host() {
        assert_eq!(dsp_kernels_equal_portable(), Ok(()));
    }
}

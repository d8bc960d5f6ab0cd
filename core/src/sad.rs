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

/// The shift search's kernel: `sums[k] += SAD(current, reference[k..k + n])`
/// for every shift `k` in `0..sums.len()`, n = `current.len()`.
/// `reference` holds at least `n + sums.len() - 1` bytes (shorter: no-op).
/// One call does a whole row of shifts so each current word is loaded once.
#[inline]
pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
    if sums.is_empty() || reference.len() + 1 < current.len() + sums.len() {
        return;
    }
    #[cfg(flatland_dsp)]
    {
        dsp::sad_shifts(current, reference, sums)
    }
    #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
    {
        sse2::sad_shifts(current, reference, sums)
    }
    #[cfg(not(any(flatland_dsp, target_arch = "x86_64")))]
    {
        portable::sad_shifts(current, reference, sums)
    }
}

/// A histogram of |diff|. On x86_64 it counts into four interleaved lanes:
/// neighbouring pixels of flat ground have equal |diff|, and one lane would
/// make every increment wait for the previous one's store. The M4 has no
/// such stall and keeps one lane (1 KB).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DiffHistogram {
    lanes: [[u32; 256]; HISTOGRAM_LANES],
}

#[cfg(target_arch = "x86_64")]
const HISTOGRAM_LANES: usize = 4;
#[cfg(not(target_arch = "x86_64"))]
const HISTOGRAM_LANES: usize = 1;

impl DiffHistogram {
    pub const EMPTY: DiffHistogram = DiffHistogram { lanes: [[0; 256]; HISTOGRAM_LANES] };

    pub fn clear(&mut self) {
        *self = Self::EMPTY;
    }

    /// Counts |a[n] - b[n]| over the common length.
    #[inline]
    pub fn add(&mut self, a: &[u8], b: &[u8]) {
        #[cfg(flatland_dsp)]
        {
            dsp::diff_histogram(a, b, &mut self.lanes[0])
        }
        #[cfg(all(target_arch = "x86_64", not(flatland_dsp)))]
        {
            sse2::diff_histogram(a, b, &mut self.lanes)
        }
        #[cfg(not(any(flatland_dsp, target_arch = "x86_64")))]
        {
            portable::diff_histogram(a, b, &mut self.lanes[0])
        }
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
    pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
        for (k, sum) in sums.iter_mut().enumerate() {
            *sum += sad(current, &reference[k..]);
        }
    }

    #[inline]
    pub fn diff_histogram(a: &[u8], b: &[u8], histogram: &mut [u32; 256]) {
        for (&x, &y) in a.iter().zip(b) {
            histogram[usize::from(x.abs_diff(y))] += 1;
        }
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
    use super::portable;
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
    pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
        match sums.len() {
            3 => shifts::<3>(current, reference, sums),
            5 => shifts::<5>(current, reference, sums),
            7 => shifts::<7>(current, reference, sums),
            _ => portable::sad_shifts(current, reference, sums),
        }
    }

    /// Each 16-byte block of `current` is loaded once for all N shifts.
    #[inline(always)]
    fn shifts<const N: usize>(current: &[u8], reference: &[u8], sums: &mut [u32]) {
        let n = current.len();
        let mut done = 0;
        // SAFETY: SSE2 is baseline on x86_64; loads read current[done..done + 16]
        // (<= n) and reference[done + k..done + k + 16] (<= n + N - 1 <= len,
        // checked by the caller `super::sad_shifts`).
        let acc = unsafe {
            let mut acc = [_mm_setzero_si128(); N];
            while done + 16 <= n {
                let x = _mm_loadu_si128(current.as_ptr().add(done).cast());
                for (k, acc) in acc.iter_mut().enumerate() {
                    let y = _mm_loadu_si128(reference.as_ptr().add(done + k).cast());
                    *acc = _mm_add_epi64(*acc, _mm_sad_epu8(x, y));
                }
                done += 16;
            }
            acc
        };
        for (k, (sum, acc)) in sums.iter_mut().zip(acc).enumerate() {
            *sum += total(acc) + portable::sad(&current[done..], &reference[done + k..]);
        }
    }

    /// |diff| of 16 pixels at a time, counted into the four lanes in turn.
    #[inline]
    pub fn diff_histogram(a: &[u8], b: &[u8], lanes: &mut [[u32; 256]; 4]) {
        let n = a.len().min(b.len());
        let mut done = 0;
        let mut diffs = [0u8; 16];
        while done + 16 <= n {
            // SAFETY: SSE2 is baseline on x86_64; loads read a/b[done..done + 16] (<= n).
            unsafe {
                let x = _mm_loadu_si128(a.as_ptr().add(done).cast());
                let y = _mm_loadu_si128(b.as_ptr().add(done).cast());
                let d = _mm_or_si128(_mm_subs_epu8(x, y), _mm_subs_epu8(y, x));
                _mm_storeu_si128(diffs.as_mut_ptr().cast(), d);
            }
            for quad in diffs.chunks_exact(4) {
                lanes[0][usize::from(quad[0])] += 1;
                lanes[1][usize::from(quad[1])] += 1;
                lanes[2][usize::from(quad[2])] += 1;
                lanes[3][usize::from(quad[3])] += 1;
            }
            done += 16;
        }
        portable::diff_histogram(&a[done..n], &b[done..n], &mut lanes[0]);
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
    use super::portable;

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

    /// Five shifts (the default ±2 window) per current word: the reference
    /// word of shift 4 is the next word's shift 0, so 1 + 4 loads feed
    /// 5 `usada8` (12 instructions per 4 pixels and 5 shifts). Other window
    /// widths run `sad` per shift.
    #[inline]
    pub fn sad_shifts(current: &[u8], reference: &[u8], sums: &mut [u32]) {
        let n = current.len();
        let words = n / 4;
        if sums.len() != 5 || words == 0 {
            for (k, sum) in sums.iter_mut().enumerate() {
                *sum += sad(current, &reference[k..]);
            }
            return;
        }
        let mut acc = [0u32; 5];
        // SAFETY: reads `words` words of `current` (4 * words <= n bytes) and
        // reference bytes below 4 * words + 4 <= n + 4 <= reference.len()
        // (checked by `super::sad_shifts`); unaligned ldr is fine on the M4.
        unsafe {
            core::arch::asm!(
                "ldr {r0}, [{pr}]",
                "2:",
                "ldr {c}, [{pc}], #4",
                "usada8 {a0}, {c}, {r0}, {a0}",
                "ldr {t}, [{pr}, #1]",
                "usada8 {a1}, {c}, {t}, {a1}",
                "ldr {t}, [{pr}, #2]",
                "usada8 {a2}, {c}, {t}, {a2}",
                "ldr {t}, [{pr}, #3]",
                "usada8 {a3}, {c}, {t}, {a3}",
                "ldr {r0}, [{pr}, #4]!",          // shift 4 now, shift 0 next word
                "usada8 {a4}, {c}, {r0}, {a4}",
                "subs {n}, {n}, #1",
                "bne 2b",
                pc = inout(reg) current.as_ptr() => _, pr = inout(reg) reference.as_ptr() => _,
                n = inout(reg) words => _,
                c = out(reg) _, t = out(reg) _, r0 = out(reg) _,
                a0 = inout(reg) acc[0], a1 = inout(reg) acc[1], a2 = inout(reg) acc[2],
                a3 = inout(reg) acc[3], a4 = inout(reg) acc[4],
                options(readonly, nostack)
            );
        }
        // At most 3 pixels left: a plain loop (the portable `sad`'s block
        // set-up would cost more than the pixels).
        let done = 4 * words;
        for (n, &value) in current[done..].iter().enumerate() {
            for (k, acc) in acc.iter_mut().enumerate() {
                *acc += u32::from(value.abs_diff(reference[done + n + k]));
            }
        }
        for (sum, acc) in sums.iter_mut().zip(acc) {
            *sum += acc;
        }
    }

    /// |diff| of four pixels with `usub8`/`sel` (the GE flags must survive
    /// from `usub8` to `sel`, hence one `asm!` block), then four increments.
    #[inline]
    pub fn diff_histogram(a: &[u8], b: &[u8], histogram: &mut [u32; 256]) {
        let n = a.len().min(b.len());
        let words = n / 4;
        if words > 0 {
            // SAFETY: reads `words` words of `a` and `b` (at least 4 * words
            // bytes each); every index is a byte (< 256) into `histogram`.
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldr {x}, [{pa}], #4",
                    "ldr {y}, [{pb}], #4",
                    "usub8 {t}, {x}, {y}",            // GE[i] = x >= y
                    "usub8 {y}, {y}, {x}",            // GE[i] = y >= x
                    "sel {x}, {y}, {t}",              // x = |x - y| per byte
                    "uxtb {t}, {x}",
                    "ldr {y}, [{h}, {t}, lsl #2]",
                    "add {y}, {y}, #1",
                    "str {y}, [{h}, {t}, lsl #2]",
                    "uxtb {t}, {x}, ror #8",
                    "ldr {y}, [{h}, {t}, lsl #2]",
                    "add {y}, {y}, #1",
                    "str {y}, [{h}, {t}, lsl #2]",
                    "uxtb {t}, {x}, ror #16",
                    "ldr {y}, [{h}, {t}, lsl #2]",
                    "add {y}, {y}, #1",
                    "str {y}, [{h}, {t}, lsl #2]",
                    "lsr {t}, {x}, #24",
                    "ldr {y}, [{h}, {t}, lsl #2]",
                    "add {y}, {y}, #1",
                    "str {y}, [{h}, {t}, lsl #2]",
                    "subs {n}, {n}, #1",
                    "bne 2b",
                    pa = inout(reg) a.as_ptr() => _, pb = inout(reg) b.as_ptr() => _,
                    n = inout(reg) words => _, h = in(reg) histogram.as_mut_ptr(),
                    x = out(reg) _, y = out(reg) _, t = out(reg) _,
                    options(nostack)
                );
            }
        }
        portable::diff_histogram(&a[4 * words..n], &b[4 * words..n], histogram);
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
    use super::portable;

    /// xorshift32: deterministic bytes without a dependency.
    fn fill(buffer: &mut [u8], mut state: u32, spread: u32) {
        for byte in buffer.iter_mut() {
            let random = xorshift32(&mut state);
            *byte = if spread >= 256 { random as u8 } else { 128u32.wrapping_add(random % (2 * spread + 1)).wrapping_sub(spread) as u8 };
        }
    }

    /// The next xorshift32 state: core's checks' random numbers.
    pub(crate) fn xorshift32(state: &mut u32) -> u32 {
        *state ^= *state << 13;
        *state ^= *state >> 17;
        *state ^= *state << 5;
        *state
    }

    /// Every length 0..=300, unaligned starts, random and edge values
    /// (0, 255, the seed levels and their neighbours), every window width.
    pub fn dsp_kernels_equal_portable() -> Result<(), &'static str> {
        let mut a = [0u8; 307];
        let mut b = [0u8; 314];
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
                    let plain_sad = |y: &[u8]| x.iter().zip(y).map(|(&p, &q)| u32::from(p.abs_diff(q))).sum::<u32>();
                    if super::sad(x, y) != plain_sad(y) || portable::sad(x, y) != plain_sad(y) {
                        return Err("sad differs from the per-pixel loop");
                    }
                    let mut expected = [0u32; 256];
                    for (&p, &q) in x.iter().zip(y) {
                        expected[usize::from(p.abs_diff(q))] += 1;
                    }
                    let mut histogram = super::DiffHistogram::EMPTY;
                    histogram.add(x, y);
                    let mut portable_histogram = [0u32; 256];
                    portable::diff_histogram(x, y, &mut portable_histogram);
                    if histogram.counts() != expected || portable_histogram != expected {
                        return Err("diff_histogram differs from the per-pixel loop");
                    }
                    for shifts in 1..=7 {
                        let reference = &b[3 - start..3 - start + length + shifts - 1];
                        let mut sums = [7u32; 7];
                        super::sad_shifts(x, reference, &mut sums[..shifts]);
                        for (k, &sum) in sums[..shifts].iter().enumerate() {
                            if sum != 7 + plain_sad(&reference[k..]) {
                                return Err("sad_shifts differs from the per-pixel loop");
                            }
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// The seed's statistics from a histogram equal a per-pixel loop.
    pub fn seed_statistics_equal_plain() -> Result<(), &'static str> {
        let mut a = [0u8; 1000];
        let mut b = [0u8; 1000];
        fill(&mut a, 0x1234_5678, 256);
        fill(&mut b, 0x0BAD_F00D, 256);
        let mut histogram = super::DiffHistogram::EMPTY;
        histogram.add(&a, &b);
        let (mut sum_above, mut count_above) = (0u32, 0u32);
        for (&x, &y) in a.iter().zip(&b) {
            let d = x.abs_diff(y);
            if d > super::SUM_LEVEL {
                sum_above += u32::from(d);
            }
            if d > super::COUNT_LEVEL {
                count_above += 1;
            }
        }
        if super::seed_statistics(&histogram.counts()) != (sum_above, count_above) {
            return Err("seed_statistics differs from the per-pixel loop");
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
    fn seed_statistics_equal_plain_host() {
        assert_eq!(seed_statistics_equal_plain(), Ok(()));
    }

    #[cfg(test)]
    #[test]
    fn dsp_kernels_equal_portable_host() {
        assert_eq!(dsp_kernels_equal_portable(), Ok(()));
    }
}

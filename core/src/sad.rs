//! Byte-block difference kernels for the GPA's hot loops.
//!
//! On Cortex-M4/M7 (`thumbv7em`, cfg `flatland_dsp` from build.rs) they use
//! the DSP extension through `asm!` (LLVM never emits these): `usada8` adds
//! four absolute differences in one instruction, `usub8` + `sel` compare and
//! select four bytes. Elsewhere the portable versions run, written so the
//! host compiler vectorises them. Both give identical results; the
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
    #[cfg(not(flatland_dsp))]
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
    #[cfg(not(flatland_dsp))]
    {
        portable::seed_sums(a, b)
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

    #[cfg(test)]
    #[test]
    fn dsp_kernels_equal_portable_host() {
        assert_eq!(dsp_kernels_equal_portable(), Ok(()));
    }
}

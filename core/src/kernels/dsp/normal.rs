//! The direct alignment's normal equations: the terms' sums in FPU
//! registers (`vmla`).

use crate::kernels;

/// The 54 sums do not fit the FPU's 32 registers (the compiler's loop
/// spills them every term, ~200 instructions a term): three passes over
/// the terms, rows 0-2, 3-5 and 6-8 of `h` with their `g`, each with its
/// sums in registers (~95 instructions a term in all). `vmla` rounds its
/// product as `*h += wa * jb` does, so the sums are the plain loop's.
/// `asm!` takes no FPU register on this target, so each pass saves and
/// restores the ones it uses.
#[inline]
pub fn add_normal_terms(terms: &[kernels::NormalTerm], h: &mut [[f32; kernels::NORMAL_UNKNOWNS]; kernels::NORMAL_UNKNOWNS], g: &mut [f32; kernels::NORMAL_UNKNOWNS]) {
    let n = terms.len();
    if n == 0 {
        return;
    }
    // A term: weight +0, residual +4, brightness +8, jacobian pointer +12.
    const _: () = assert!(core::mem::size_of::<kernels::NormalTerm>() == 16);
    let (h, g) = (h.as_mut_ptr().cast::<f32>(), g.as_mut_ptr());
    // SAFETY (all three): reads `n` 16-byte terms and the 7 floats each
    // points to; reads and writes the upper triangle of `h` (81 floats,
    // row-major) and `g` (9) at the offsets named; s0-s31 saved and restored.
    unsafe {
        // Rows 0-2: h[0][0..9] s0-s8, h[1][1..9] s9-s16, h[2][2..9] s17-s23,
        // g[0..3] s24-s26; w j0, w j1, w j2 in s27-s29.
        core::arch::asm!(
            "vpush {{d0-d15}}",
            "vldmia {h}, {{s0-s8}}",
            "add {t}, {h}, #40",
            "vldmia {t}, {{s9-s16}}",
            "add {t}, {h}, #80",
            "vldmia {t}, {{s17-s23}}",
            "vldmia {g}, {{s24-s26}}",
            "2:",
            "vldr s31, [{term}]",
            "ldr {t}, [{term}, #12]",
            "vldr s30, [{t}]",
            "vmul.f32 s27, s31, s30",
            "vmla.f32 s0, s27, s30",
            "vldr s30, [{t}, #4]",
            "vmul.f32 s28, s31, s30",
            "vmla.f32 s1, s27, s30",
            "vmla.f32 s9, s28, s30",
            "vldr s30, [{t}, #8]",
            "vmul.f32 s29, s31, s30",
            "vmla.f32 s2, s27, s30",
            "vmla.f32 s10, s28, s30",
            "vmla.f32 s17, s29, s30",
            "vldr s30, [{t}, #12]",
            "vmla.f32 s3, s27, s30",
            "vmla.f32 s11, s28, s30",
            "vmla.f32 s18, s29, s30",
            "vldr s30, [{t}, #16]",
            "vmla.f32 s4, s27, s30",
            "vmla.f32 s12, s28, s30",
            "vmla.f32 s19, s29, s30",
            "vldr s30, [{t}, #20]",
            "vmla.f32 s5, s27, s30",
            "vmla.f32 s13, s28, s30",
            "vmla.f32 s20, s29, s30",
            "vldr s30, [{t}, #24]",
            "vmla.f32 s6, s27, s30",
            "vmla.f32 s14, s28, s30",
            "vmla.f32 s21, s29, s30",
            "vldr s30, [{term}, #8]",
            "vmla.f32 s7, s27, s30",
            "vmla.f32 s15, s28, s30",
            "vmla.f32 s22, s29, s30",
            "vadd.f32 s8, s8, s27",
            "vadd.f32 s16, s16, s28",
            "vadd.f32 s23, s23, s29",
            "vldr s31, [{term}, #4]",
            "vmla.f32 s24, s27, s31",
            "vmla.f32 s25, s28, s31",
            "vmla.f32 s26, s29, s31",
            "adds {term}, #16",
            "subs {n}, #1",
            "bne 2b",
            "vstmia {g}, {{s24-s26}}",
            "add {t}, {h}, #80",
            "vstmia {t}, {{s17-s23}}",
            "add {t}, {h}, #40",
            "vstmia {t}, {{s9-s16}}",
            "vstmia {h}, {{s0-s8}}",
            "vpop {{d0-d15}}",
            h = in(reg) h, g = in(reg) g,
            term = inout(reg) terms.as_ptr() => _, n = inout(reg) n => _,
            t = out(reg) _,
            options(nostack)
        );
        // Rows 3-5: h[3][3..9] s0-s5, h[4][4..9] s6-s10, h[5][5..9] s11-s14,
        // g[3..6] s15-s17; w j3, w j4, w j5 in s18-s20.
        core::arch::asm!(
            "vpush {{d0-d15}}",
            "add {t}, {h}, #120",
            "vldmia {t}, {{s0-s5}}",
            "add {t}, {h}, #160",
            "vldmia {t}, {{s6-s10}}",
            "add {t}, {h}, #200",
            "vldmia {t}, {{s11-s14}}",
            "add {t}, {g}, #12",
            "vldmia {t}, {{s15-s17}}",
            "2:",
            "vldr s31, [{term}]",
            "ldr {t}, [{term}, #12]",
            "vldr s30, [{t}, #12]",
            "vmul.f32 s18, s31, s30",
            "vmla.f32 s0, s18, s30",
            "vldr s30, [{t}, #16]",
            "vmul.f32 s19, s31, s30",
            "vmla.f32 s1, s18, s30",
            "vmla.f32 s6, s19, s30",
            "vldr s30, [{t}, #20]",
            "vmul.f32 s20, s31, s30",
            "vmla.f32 s2, s18, s30",
            "vmla.f32 s7, s19, s30",
            "vmla.f32 s11, s20, s30",
            "vldr s30, [{t}, #24]",
            "vmla.f32 s3, s18, s30",
            "vmla.f32 s8, s19, s30",
            "vmla.f32 s12, s20, s30",
            "vldr s30, [{term}, #8]",
            "vmla.f32 s4, s18, s30",
            "vmla.f32 s9, s19, s30",
            "vmla.f32 s13, s20, s30",
            "vadd.f32 s5, s5, s18",
            "vadd.f32 s10, s10, s19",
            "vadd.f32 s14, s14, s20",
            "vldr s31, [{term}, #4]",
            "vmla.f32 s15, s18, s31",
            "vmla.f32 s16, s19, s31",
            "vmla.f32 s17, s20, s31",
            "adds {term}, #16",
            "subs {n}, #1",
            "bne 2b",
            "add {t}, {g}, #12",
            "vstmia {t}, {{s15-s17}}",
            "add {t}, {h}, #200",
            "vstmia {t}, {{s11-s14}}",
            "add {t}, {h}, #160",
            "vstmia {t}, {{s6-s10}}",
            "add {t}, {h}, #120",
            "vstmia {t}, {{s0-s5}}",
            "vpop {{d0-d15}}",
            h = in(reg) h, g = in(reg) g,
            term = inout(reg) terms.as_ptr() => _, n = inout(reg) n => _,
            t = out(reg) _,
            options(nostack)
        );
        // Rows 6-8: h[6][6..9] s0-s2, h[7][7..9] s3-s4, h[8][8] s5, g[6..9]
        // s6-s8; w j6, w j7 in s9-s10 (w j8 is w).
        core::arch::asm!(
            "vpush {{d0-d15}}",
            "add {t}, {h}, #240",
            "vldmia {t}, {{s0-s2}}",
            "add {t}, {h}, #280",
            "vldmia {t}, {{s3-s4}}",
            "add {t}, {h}, #320",
            "vldr s5, [{t}]",
            "add {t}, {g}, #24",
            "vldmia {t}, {{s6-s8}}",
            "2:",
            "vldr s31, [{term}]",
            "ldr {t}, [{term}, #12]",
            "vldr s30, [{t}, #24]",
            "vmul.f32 s9, s31, s30",
            "vmla.f32 s0, s9, s30",
            "vldr s30, [{term}, #8]",
            "vmul.f32 s10, s31, s30",
            "vmla.f32 s1, s9, s30",
            "vmla.f32 s3, s10, s30",
            "vadd.f32 s2, s2, s9",
            "vadd.f32 s4, s4, s10",
            "vadd.f32 s5, s5, s31",
            "vldr s30, [{term}, #4]",
            "vmla.f32 s6, s9, s30",
            "vmla.f32 s7, s10, s30",
            "vmla.f32 s8, s31, s30",
            "adds {term}, #16",
            "subs {n}, #1",
            "bne 2b",
            "add {t}, {g}, #24",
            "vstmia {t}, {{s6-s8}}",
            "add {t}, {h}, #320",
            "vstr s5, [{t}]",
            "add {t}, {h}, #280",
            "vstmia {t}, {{s3-s4}}",
            "add {t}, {h}, #240",
            "vstmia {t}, {{s0-s2}}",
            "vpop {{d0-d15}}",
            h = in(reg) h, g = in(reg) g,
            term = inout(reg) terms.as_ptr() => _, n = inout(reg) n => _,
            t = out(reg) _,
            options(nostack)
        );
    }
}

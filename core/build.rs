//! Enables the Cortex-M4/M7 DSP kernels (`usada8` & co. in `kernels/dsp/`) on
//! targets that have the DSP extension; rustc does not expose it as a
//! `target_feature` cfg for thumbv7em.
fn main() {
    println!("cargo::rustc-check-cfg=cfg(flatland_dsp)");
    println!("cargo::rerun-if-changed=build.rs");
    let target = std::env::var("TARGET").unwrap_or_default();
    if target.starts_with("thumbv7em") {
        println!("cargo::rustc-cfg=flatland_dsp");
    }
}

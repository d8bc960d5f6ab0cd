//! Puts the workspace root (where `memory.x` lives) on the linker search
//! path, and per bin the `ccm.x` that says where the CCM lies: the chip's
//! for the board bin, QEMU's stand-in for the emulated ones.
use std::{env, path::PathBuf};

fn main() {
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into()));
    let root = manifest_dir.parent().map(PathBuf::from).unwrap_or_else(|| manifest_dir.clone());
    println!("cargo:rustc-link-search={}", root.display());
    let link = manifest_dir.join("link");
    for (bin, place) in [("flatland-firmware", "qemu"), ("selftest", "qemu"), ("discovery", "board")] {
        println!("cargo:rustc-link-arg-bin={bin}=-L{}", link.join(place).display());
    }
    println!("cargo:rerun-if-changed={}", root.join("memory.x").display());
    println!("cargo:rerun-if-changed={}", link.display());
    println!("cargo:rerun-if-changed=build.rs");
}

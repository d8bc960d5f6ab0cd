//! Puts the workspace root (where `memory.x` lives) on the linker search path,
//! so one memory map serves the emulated and the real board.
use std::{env, path::PathBuf};

fn main() {
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| ".".into()));
    let root = manifest_dir.parent().map(PathBuf::from).unwrap_or(manifest_dir);
    println!("cargo:rustc-link-search={}", root.display());
    println!("cargo:rerun-if-changed={}", root.join("memory.x").display());
    println!("cargo:rerun-if-changed=build.rs");
}

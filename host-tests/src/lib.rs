//! Flatland on the host: the recording reader, picture output, and the
//! glue the `flatland` CLI and the tests share. All detection work is done
//! by `flatland_core`, the same code the firmware runs.
//!
//! The modules by layer, each using only those above it:
//! - `recording`: the recording layout (rig.toml, poses.csv, frames,
//!   truth.toml);
//! - `kg`, `detect`, `evaluate`, `perturb`, `trial`: detection on the host,
//!   scored against truth, under perturbations; `cells`: what a frame
//!   measured per cell;
//! - `calibration`: the mount from a drive over flat ground, camera_info,
//!   rig.toml's rewrite;
//! - `pictures`: what a person looks at (frame pictures, the run's
//!   summary and animation);
//! - `link`: the firmware's output streams read on the host (serial
//!   protocol, MAVLink) and the autopilots' readers of it;
//! - `qemu`: the firmware run in QEMU, and its instruction profile;
//! - `bench`, `heights`: `flatland bench` and `flatland heights`.
//!
//! The binaries: `src/cli/` (`flatland`) and `src/bin/fw.rs` (`cargo fw*`).

pub mod bench;
pub mod calibration;
pub mod cells;
pub mod detect;
pub mod evaluate;
pub mod heights;
pub mod kg;
pub mod link;
pub mod perturb;
pub mod pictures;
pub mod qemu;
pub mod recording;
pub mod trial;

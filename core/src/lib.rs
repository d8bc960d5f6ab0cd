//! Flatland core: obstacle detection from a tilted camera on a ground robot,
//! after "Real time algorithms for obstacle avoidance by using reprojection
//! transformation" (the seed paper).
//!
//! `no_std`, no heap: every capacity is a constant and every buffer is owned
//! by the caller or by a fixed-size struct. The same code runs on the host
//! (`host-tests`) and on the Cortex-M4F (`firmware`).
//!
//! Layers, one per module:
//! - [`geometry`]: the rig (camera, mount, AOI), the seed's equations (1)-(7)
//!   and their inverses, validation.
//! - [`gpa`]: the streaming ground-plane detector (shift search, residue, alarm).
//! - [`grid`]: the KG grid (top view) that covers the AOI plus search margin.
//! - [`remap`]: the compact fixed-point remap table and the streaming,
//!   row-by-row remap (the PIPE-like front end).
//! - [`kernels`]: the byte loops of the GPA and the remap, portable, SSE2
//!   and Cortex-M4 DSP, selected in one place.
//! - [`motion`]: poses and odometry (Tx, Tz, yaw) between frames.
//! - [`gti`]: heights from motion on GT-images (the seed's §3.2), row-fed.
//! - [`fusion`]: GPA's alarm with GTI's heights (the seed's §3.3).
//! - [`pipeline`]: one frame through remap, GPA, GTI and fusion, behind the
//!   odometry gate; what the firmware and the host both drive.
//! - [`pgm`]: checked view of binary PGM (P5) headers.
//! - [`health`]: sensor health and the fail-safe alarm rule.
//! - [`report`]: the per-frame result, shared by the CLI and the serial protocol.
//! - [`scan`]: the polar obstacle scan (nearest hazard per angular sector).
//! - [`protocol`]: the serial protocol between the firmware and its host.
//! - [`limits`]: every capacity (buffer sizes, input sizes, search bounds) in one place.
//! - [`subpixel`]: the parabola vertex that refines a sampled extremum.
//!
//! Every error type implements `Display` and [`core::error::Error`], and
//! `defmt::Format` with the `defmt` feature.
#![cfg_attr(not(test), no_std)]
#![deny(clippy::unwrap_used, clippy::expect_used)]
#[cfg(all(feature = "trace", not(test)))]
extern crate std;

pub mod fusion;
pub mod geometry;
pub mod gpa;
pub mod grid;
pub mod health;
pub mod gti;
pub mod kernels;
pub mod limits;
#[cfg(feature = "mavlink")]
pub mod mavlink;
pub mod motion;
pub mod pgm;
pub mod pipeline;
pub mod remap;
pub mod protocol;
pub mod report;
pub mod scan;
pub mod subpixel;
/// core's checks as one list: the on-target runner's (`cargo fw-test`) and the host `#[test]`s.
#[cfg(any(test, feature = "selftest"))]
pub mod selftest;

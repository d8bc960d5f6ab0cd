//! Flatland firmware: the board layer, the runtime (logging, panic and fault
//! handling, exit status) and the frame loop, shared by the `flatland-firmware`
//! and `selftest` binaries.
#![no_std]
#![deny(clippy::unwrap_used, clippy::expect_used)]

pub mod board;
pub mod frame_loop;
pub mod rt;

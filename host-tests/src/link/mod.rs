//! The firmware's output streams read on the host: its serial protocol
//! (`flatland serial decode`), its MAVLink stream through the `mavlink`
//! crate's own reader, and how autopilots read that stream's
//! `OBSTACLE_DISTANCE`.

pub mod autopilot;
pub mod mavlink;
pub mod serial;

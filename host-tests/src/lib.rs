//! Flatland on the host: the recording reader, picture output, and the
//! glue the `flatland` CLI and the tests share. All detection work is done
//! by `flatland_core`, the same code the firmware runs.

pub mod animation;
pub mod autopilot;
pub mod bench;
pub mod calibrate;
pub mod detect;
pub mod evaluate;
pub mod frame_picture;
pub mod heights;
pub mod images;
pub mod serial_decode;
pub mod summary;
pub mod kg;
pub mod m4_profile;
pub mod mavlink_decode;
pub mod perturb;
pub mod qemu;
pub mod recording;
pub mod trial;

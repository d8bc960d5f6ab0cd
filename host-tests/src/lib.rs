//! Flatland on the host: the recording reader, picture output, and the
//! glue the `flatland` CLI and the tests share. All detection work is done
//! by `flatland_core`, the same code the firmware runs.

pub mod heights;
pub mod images;
pub mod kg;
pub mod recording;

#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used)]

use cortex_m_rt::entry;
use flatland_firmware::rt::{exit, Exit};

#[entry]
fn main() -> ! {
    defmt::println!("flatland firmware {}", env!("CARGO_PKG_VERSION"));
    exit(Exit::Success)
}

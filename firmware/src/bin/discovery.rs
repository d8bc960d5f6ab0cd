//! Flatland on the STM32F4DISCOVERY with an OV7670 camera (README "Real
//! board"): the same frame loop as the emulated board, fed by DCMI, talking
//! the protocol of PROTOCOL.md on USART2 (PA2 TX, PA3 RX, 115200 8N1), logging
//! defmt over RTT. Build and flash: `cargo board-run`.
#![no_std]
#![no_main]
#![deny(clippy::unwrap_used, clippy::expect_used)]

use cortex_m_rt::entry;
use flatland_firmware::board::discovery::DiscoveryBoard;
use flatland_firmware::frame_loop::{self, Board, Options};
use flatland_firmware::rt::{paint_stack, stack_high_water};

#[entry]
fn main() -> ! {
    paint_stack();
    defmt::info!("flatland firmware {=str} (STM32F4DISCOVERY + OV7670)", env!("CARGO_PKG_VERSION"));
    let parts = DiscoveryBoard::take();
    let board = Board { serial: parts.serial, alarm: parts.alarm, counter: parts.counter, frames: parts.frames };
    // A robot has no end of input: after `$FLEND` the loop returns with its
    // counters (already sent as `$FLSTA`) and the board waits for a reset.
    let stats = frame_loop::run(board, &Options { bench: false, mm_per_px: None, no_margins: false, clock: None });
    defmt::info!("end of input after {=u32} frames", stats.frames);
    let (used, size) = stack_high_water();
    defmt::info!("stack high-water mark: {=usize} of {=usize} bytes", used, size);
    loop {
        cortex_m::asm::wfi();
    }
}

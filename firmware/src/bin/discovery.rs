//! Flatland on the STM32F4DISCOVERY with an OV7670 camera (docs/BOARD.md "Real
//! board"): the same frame loop as the emulated board, fed by DCMI, talking
//! the protocol of PROTOCOL.md on USART2 (PA2 TX, PA3 RX, 115200 8N1), logging
//! defmt over RTT. Build and flash: `cargo board-run`.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use flatland_firmware::board::discovery::DiscoveryBoard;
use flatland_firmware::frame_loop::Board;

#[entry]
fn main() -> ! {
    let take = || {
        let parts = DiscoveryBoard::take();
        Board {
            serial: parts.serial,
            alarm: parts.alarm,
            counter: parts.counter,
            frames: parts.frames,
            clock: parts.clock,
            watchdog: parts.watchdog,
        }
    };
    // A robot has no end of input: after `$FLEND` the loop returns with its
    // counters (already sent as `$FLSTA`) and the alarm asserted; nothing
    // feeds the watchdog any more, which resets the board within seconds
    // (it then announces `$FLRDY` again).
    let options = flatland_firmware::command_line_options(None);
    flatland_firmware::serve("STM32F4DISCOVERY + OV7670", take, &options);
    loop {
        cortex_m::asm::wfi();
    }
}

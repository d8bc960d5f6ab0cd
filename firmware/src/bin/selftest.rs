//! core's checks on the emulated Cortex-M4: runs `flatland_core::selftest::TESTS`
//! and prints `N passed, N failed`; the exit status is nonzero on any failure.
//!
//! The semihosting command line can also ask for a deliberate fault, so the
//! fault paths are tested too: `panic` or `hardfault`, and `hang`: the
//! emulated watchdog started with a short timeout and never fed.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use flatland_core::selftest::TESTS;
use flatland_firmware::rt::{command_line, exit, words, Exit, COMMAND_LINE_CAPACITY};

#[entry]
fn main() -> ! {
    let mut buf = [0u8; COMMAND_LINE_CAPACITY];
    // QEMU prefixes the kernel's file name; the request is the last word.
    let request = words(command_line(&mut buf)).last().unwrap_or(b"");
    match request {
        b"panic" => deliberate_panic(),
        b"hardfault" => cortex_m::asm::udf(),
        b"hang" => hang(),
        _ => {}
    }

    let (mut passed, mut failed) = (0u32, 0u32);
    for (name, check) in TESTS {
        match check() {
            Ok(()) => {
                passed += 1;
                defmt::println!("test {=str} ... ok", name);
            }
            Err(reason) => {
                failed += 1;
                defmt::println!("test {=str} ... FAILED: {=str}", name, reason);
            }
        }
    }
    defmt::println!("{=u32} passed, {=u32} failed", passed, failed);
    exit(if failed == 0 { Exit::Success } else { Exit::Failure })
}

/// The emulated watchdog's timeout for `hang`.
const HANG_WATCHDOG_TIMEOUT_MS: u32 = 200;

/// A loop that never feeds the watchdog: its exception must end the run.
fn hang() -> ! {
    let _watchdog = flatland_firmware::board::emulated::SysTickWatchdog::start(HANG_WATCHDOG_TIMEOUT_MS);
    defmt::println!("hanging with a {=u32} ms watchdog", HANG_WATCHDOG_TIMEOUT_MS);
    loop {
        cortex_m::asm::nop();
    }
}

#[inline(never)]
fn deliberate_panic() -> ! {
    // A value the optimiser cannot see through, so this is a real panic path.
    let divisor = core::hint::black_box(0u32);
    defmt::println!("{=u32}", 1 / divisor);
    exit(Exit::Success)
}

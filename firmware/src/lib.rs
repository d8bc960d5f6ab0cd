//! Flatland firmware: the board layer, the runtime (logging, panic and fault
//! handling, exit status, stack use) and the frame loop, and what every
//! board binary does around that loop ([`command_line_options`], [`serve`]).
//!
//! Binaries: `flatland-firmware` (src/main.rs, QEMU's netduinoplus2),
//! `discovery` (src/bin/discovery.rs, the STM32F4DISCOVERY + OV7670, feature
//! `discovery`) and `selftest` (src/bin/selftest.rs, core's checks).
//! Each is a `#![no_std]`, `#![no_main]` crate with a cortex-m-rt `#[entry]`;
//! the lints they share are in Cargo.toml's `[lints]`.
#![no_std]

pub mod board;
pub mod frame_loop;
pub mod protocol;
pub mod rt;

use embedded_hal::digital::OutputPin;
use embedded_io::{Read, ReadReady, Write};

use board::{Clock, CycleCounter, RowSource, Watchdog};
use frame_loop::{Board, Options};

/// The protocol the serial port speaks: the line protocol, or MAVLink 2 in
/// the `mavlink` build.
#[cfg(not(feature = "mavlink"))]
type Speaking<S> = protocol::lines::Lines<S>;
#[cfg(feature = "mavlink")]
type Speaking<S> = protocol::mavlink::Mavlink<S>;

/// The frame loop's options, from the semihosting command line (QEMU's
/// `-append`): `bench` adds instruction counts to the log (`profile_clock`
/// times the detector's stages), `mm_per_px=X` fixes the KG resolution,
/// `no_margins` makes the grid the AOI alone (`cargo fw-bench
/// --full-frame`). A real board has no command line: it runs as `flatland
/// detect` does.
pub fn command_line_options(profile_clock: Option<fn() -> u32>) -> Options {
    let mut buf = [0u8; rt::COMMAND_LINE_CAPACITY];
    let line = rt::command_line(&mut buf);
    let has = |flag: &[u8]| rt::words(line).any(|word| word == flag);
    let mm_per_px = rt::words(line)
        .find_map(|word| word.strip_prefix(b"mm_per_px="))
        .and_then(|value| core::str::from_utf8(value).ok())
        .and_then(|value| value.parse::<f64>().ok());
    Options { bench: has(b"bench"), mm_per_px, no_margins: has(b"no_margins"), clock: profile_clock }
}

/// Announces the firmware on `board_name`, sets the board up (`take`), runs
/// the frame loop until the host's `$FLEND` and logs its counters and the
/// stack's high-water mark, which it returns.
pub fn serve<S, A, C, R, K, W>(
    board_name: &str,
    take: impl FnOnce() -> Board<S, A, C, R, K, W>,
    options: &Options,
) -> rt::StackUse
where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    defmt::info!("flatland firmware {=str} ({=str})", env!("CARGO_PKG_VERSION"), board_name);
    let stats = frame_loop::FrameLoop::<Speaking<S>, _, _, _, _, _>::run(take(), options);
    let (input, frames) = (stats.decoder, stats.frame_loop);
    defmt::info!(
        "done: {=u32} frames; serial garbage {=u32} B, truncated {=u32}, too long {=u32}, bad checksum {=u32}, unknown {=u32}, bad field {=u32}, out of order {=u32}, frame gaps {=u32}, aborted {=u32}",
        frames.frames,
        input.garbage_bytes,
        input.truncated,
        input.too_long,
        input.bad_checksum,
        input.unknown_type,
        input.bad_field,
        frames.out_of_order,
        frames.frame_gaps,
        frames.aborted
    );
    let stack = rt::stack_use();
    defmt::info!("stack high-water mark: {=usize} of {=usize} bytes", stack.high_water, stack.size);
    if stack.reached_statics() {
        defmt::error!("stack overflow: the stack reached the statics");
    }
    stack
}

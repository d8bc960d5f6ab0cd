//! The board layer: what the frame loop sees of the hardware.
//!
//! - a [`RowSource`]: camera rows, one at a time, in order;
//! - a serial port: `embedded_io::Read + Write`;
//! - an alarm pin: `embedded_hal::digital::OutputPin`, high = alarm, set
//!   high by the board before the loop runs;
//! - a [`CycleCounter`] (benchmarks) and a [`Clock`] (timeouts, pauses);
//! - a [`Watchdog`] the loop feeds.
//!
//! [`assert_alarm_after_fault`] is for the panic and fault handlers, which
//! own nothing.
//!
//! [`emulated`] implements them for QEMU's netduinoplus2 (frames through
//! semihosting); [`discovery`] (feature `discovery`) for the STM32F4DISCOVERY
//! with an OV7670 camera on DCMI.

#[cfg(feature = "discovery")]
pub mod discovery;
pub mod emulated;
pub mod ov7670;

/// Microseconds on the board's free-running clock (the [`Clock`] the loop
/// gets; 0 until the board is taken; wraps after 71 minutes): the log's
/// timestamps, which the handlers need without owning the clock.
pub fn uptime_us() -> u32 {
    #[cfg(feature = "discovery")]
    return discovery::uptime_us();
    #[cfg(not(feature = "discovery"))]
    return emulated::uptime_us();
}

/// The size of the frame a [`RowSource`] is about to deliver.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct FrameSize {
    pub width: u16,
    pub height: u16,
}

/// Why a frame could not be delivered.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum RowSourceError {
    /// No frame with that index.
    Missing,
    /// The frame is not an 8-bit image the source can deliver.
    Format,
    /// The frame ended early or the read failed.
    Read,
    /// The caller's row buffer is not one row wide.
    RowLength,
    /// The camera sent nothing for its timeout (the board's own limit on a
    /// blocking read; the loop also times the whole frame).
    Timeout,
}

/// Camera rows, top to bottom, as a camera delivers them.
pub trait RowSource {
    /// Starts frame `index`; rows follow through [`RowSource::read_row`].
    /// A camera delivers its next whole frame (the index is the host's).
    fn begin_frame(&mut self, index: u32) -> Result<FrameSize, RowSourceError>;
    /// Fills `row` (exactly one row wide) with the next row of the frame.
    fn read_row(&mut self, row: &mut [u8]) -> Result<(), RowSourceError>;
    /// Ends the current frame (releases the file; a streaming camera goes on).
    fn end_frame(&mut self);
}

/// A free-running counter for timing and benchmarks.
pub trait CycleCounter {
    /// Ticks since start (wraps).
    fn now(&self) -> u32;
}

/// Monotonic time for the fail-safe timeouts (`flatland_core::health`),
/// and short pauses.
pub trait Clock {
    /// Microseconds since some start; wraps at 2^32 (71 minutes).
    fn now_us(&self) -> u32;
    /// Busy-waits about `us` microseconds (the loop's pause between two
    /// polls of an idle serial port).
    fn delay_us(&self, us: u32);
}

/// A watchdog that resets the board (or, emulated, ends the run) when the
/// loop stops feeding it. Started by the board; the loop only feeds it.
pub trait Watchdog {
    fn feed(&mut self);
}

/// GPIOD, where both boards have the alarm: PD14 (red LED) and PD11 (the
/// robot's alarm input on the real board; unused on the emulated one).
const GPIOD: usize = 0x4002_0C00;
const GPIO_MODER: usize = 0x00;
const GPIO_BSRR: usize = 0x18;
const RCC_AHB1ENR: usize = 0x4002_3830;
const RCC_AHB1ENR_GPIODEN: u32 = 1 << 3;
pub(crate) const ALARM_PINS: [u32; 2] = [14, 11];

/// Drives the alarm pins high straight through the registers: for the
/// panic and HardFault handlers, which cannot rely on the board's objects
/// (the fault may have come before they existed, or inside them). Clocks
/// GPIOD and makes the pins push-pull outputs, level first. QEMU models
/// neither RCC nor GPIO: the writes are ignored there, and the handler's
/// log line is what shows it ran.
pub fn assert_alarm_after_fault() {
    let set: u32 = ALARM_PINS.iter().map(|pin| 1 << pin).sum();
    // SAFETY: RCC_AHB1ENR and GPIOD's MODER and BSRR exist on every
    // STM32F4; BSRR writes are atomic set requests, and the read-modify-write
    // of AHB1ENR and MODER only adds bits. Nothing else runs after a fault.
    unsafe {
        let ahb1enr = RCC_AHB1ENR as *mut u32;
        ahb1enr.write_volatile(ahb1enr.read_volatile() | RCC_AHB1ENR_GPIODEN);
        ((GPIOD + GPIO_BSRR) as *mut u32).write_volatile(set);
        let moder = (GPIOD + GPIO_MODER) as *mut u32;
        let mut value = moder.read_volatile();
        for pin in ALARM_PINS {
            value = (value & !(0b11 << (2 * pin))) | (0b01 << (2 * pin));
        }
        moder.write_volatile(value);
        ((GPIOD + GPIO_BSRR) as *mut u32).write_volatile(set);
    }
}

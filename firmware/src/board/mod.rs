//! The board layer: what the frame loop sees of the hardware.
//!
//! - a [`RowSource`]: camera rows, one at a time, in order;
//! - a serial port: `embedded_io::Read + Write`;
//! - an alarm pin: `embedded_hal::digital::OutputPin`;
//! - a [`CycleCounter`].
//!
//! [`emulated`] implements them for QEMU's netduinoplus2 (frames through
//! semihosting); [`discovery`] (feature `discovery`) for the STM32F4DISCOVERY
//! with an OV7670 camera on DCMI.

#[cfg(feature = "discovery")]
pub mod discovery;
pub mod emulated;
pub mod ov7670;

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
}

/// Camera rows, top to bottom, as a camera delivers them.
pub trait RowSource {
    /// Starts frame `index`; rows follow through [`RowSource::read_row`].
    fn begin_frame(&mut self, index: u32) -> Result<FrameSize, RowSourceError>;
    /// Fills `row` (exactly one row wide) with the next row of the frame.
    fn read_row(&mut self, row: &mut [u8]) -> Result<(), RowSourceError>;
    /// Ends the current frame (releases the file, re-arms the camera).
    fn end_frame(&mut self);
}

/// A free-running counter for timing and benchmarks.
pub trait CycleCounter {
    /// Ticks per second (the MAVLink loop's 1 Hz heartbeat).
    const TICKS_PER_SECOND: u32;
    /// Ticks since start (wraps).
    fn now(&self) -> u32;
}

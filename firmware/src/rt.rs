//! Runtime: the defmt transport, the panic handler, the HardFault handler,
//! the exit status, the semihosting command line and the stack's use.
//!
//! Under QEMU every way out ends the emulator through semihosting
//! (`SYS_EXIT_EXTENDED`), so a fault is a nonzero exit status with a message,
//! never a hang.
//!
//! A panic, a HardFault or an unexpected interrupt first asserts the alarm
//! pins through the registers ([`crate::board::assert_alarm_after_fault`]),
//! then logs. On a real board the core then parks with the pins high until
//! the independent watchdog resets it, and the firmware starts again with
//! the alarm asserted.

use cortex_m_rt::{exception, ExceptionFrame, STACK_PAINT_VALUE};

#[cfg(feature = "rtt")]
use defmt_rtt as _;
#[cfg(not(feature = "rtt"))]
use defmt_semihosting as _;

/// Exit status reported to the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Exit {
    Success,
    Failure,
}

/// Ends the program. Under QEMU, the emulator exits with 0 or 1.
/// On a real board without a debugger attached, semihosting would trap, so
/// there we park the core instead (the `rtt` build).
pub fn exit(status: Exit) -> ! {
    #[cfg(not(feature = "rtt"))]
    {
        let code = match status {
            Exit::Success => cortex_m_semihosting::debug::EXIT_SUCCESS,
            Exit::Failure => cortex_m_semihosting::debug::EXIT_FAILURE,
        };
        cortex_m_semihosting::debug::exit(code);
    }
    #[cfg(feature = "rtt")]
    let _ = status;
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    crate::board::assert_alarm_after_fault();
    defmt::error!("panic: {}; alarm asserted", defmt::Display2Format(info));
    exit(Exit::Failure)
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    crate::board::assert_alarm_after_fault();
    defmt::error!("HardFault at pc={=u32:#010x} lr={=u32:#010x}; alarm asserted", frame.pc(), frame.lr());
    exit(Exit::Failure)
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    crate::board::assert_alarm_after_fault();
    defmt::error!("unexpected interrupt {=i16}; alarm asserted", irqn);
    exit(Exit::Failure)
}

// Seconds since the board's microsecond clock started (0 before it does),
// printed by defmt-print as `s.uuuuuu`.
defmt::timestamp!("{=u32:us}", crate::board::uptime_us());

/// Room for the semihosting command line: QEMU's kernel path, then the
/// options (a few words).
pub const COMMAND_LINE_CAPACITY: usize = 512;

/// The semihosting command line (QEMU's `-append`), copied into `buf`.
/// Empty when the host gives none or it does not fit (QEMU prefixes the
/// kernel's path, so leave room).
pub fn command_line(buf: &mut [u8]) -> &[u8] {
    #[cfg(not(feature = "rtt"))]
    {
        // SYS_GET_CMDLINE's parameter block: buffer address and size; the
        // host writes the length back into the second word.
        let mut block = [buf.as_mut_ptr() as usize, buf.len()];
        // SAFETY: the host writes at most `buf.len()` bytes into `buf` and
        // one word into `block`, both live for the call.
        let status = unsafe {
            cortex_m_semihosting::syscall1(cortex_m_semihosting::nr::GET_CMDLINE, block.as_mut_ptr() as usize)
        };
        if status == 0 {
            let length = block[1].min(buf.len());
            return &buf[..length];
        }
    }
    &buf[..0]
}

/// The space-separated words of a command line; QEMU puts the kernel's path
/// first.
pub fn words(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|&b| b == b' ').filter(|word| !word.is_empty())
}

// ------------------------------------------------------------------ stack use

extern "C" {
    /// The lowest address the stack may grow down to: the end of the
    /// statics (cortex-m-rt's link.x).
    static _stack_end: u32;
    /// The initial stack pointer: the top of RAM (cortex-m-rt's link.x).
    static _stack_start: u32;
}

/// How deep the stack has been since reset.
#[derive(Clone, Copy, Debug)]
pub struct StackUse {
    /// Bytes between the top of the stack and the deepest word written.
    pub high_water: usize,
    /// Bytes between the top of the stack and the statics.
    pub size: usize,
}

impl StackUse {
    /// The stack reached the statics. There is no guard page, so they may be
    /// corrupted: the run is not to be trusted.
    pub fn reached_statics(&self) -> bool {
        self.high_water >= self.size
    }
}

/// The stack's high-water mark, read from cortex-m-rt's paint.
///
/// The painting is cortex-m-rt's (feature `paint-stack`): its reset handler
/// fills the whole stack region with [`STACK_PAINT_VALUE`] in assembly,
/// before `main` runs, while nothing lives on the stack. Painting from Rust
/// would write, through pointers to no object, into the memory the compiler
/// allocates its frames in, trusting a guessed margin below the stack
/// pointer.
///
/// Here we only read, and only below the current stack pointer: RAM that
/// holds no live object, with volatile loads the compiler neither elides nor
/// reasons about, and with interrupts masked so that no handler pushes a
/// frame there meanwhile.
pub fn stack_use() -> StackUse {
    let bottom = core::ptr::addr_of!(_stack_end) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let deepest = cortex_m::interrupt::free(|_| {
        let limit = cortex_m::register::msp::read() as usize;
        let mut address = bottom;
        // SAFETY: [bottom, limit) is RAM below the live stack pointer, word
        // aligned (link.x asserts `_stack_end % 4 == 0`).
        while address < limit && unsafe { core::ptr::read_volatile(address as *const u32) } == STACK_PAINT_VALUE {
            address += 4;
        }
        address
    });
    StackUse { high_water: top - deepest, size: top - bottom }
}

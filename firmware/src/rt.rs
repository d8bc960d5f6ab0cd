//! Runtime: the defmt transport, the panic handler, the HardFault handler and
//! the exit status.
//!
//! Under QEMU every way out ends the emulator through semihosting
//! (`SYS_EXIT_EXTENDED`), so a fault is a nonzero exit status with a message,
//! never a hang.

use cortex_m_rt::{exception, ExceptionFrame};

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
    defmt::error!("panic: {}", defmt::Display2Format(info));
    exit(Exit::Failure)
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    defmt::error!("HardFault at pc={=u32:#010x} lr={=u32:#010x}", frame.pc(), frame.lr());
    exit(Exit::Failure)
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    defmt::error!("unexpected interrupt {=i16}", irqn);
    exit(Exit::Failure)
}

defmt::timestamp!("{=u32}", crate::board::emulated::instructions_now());

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

/// Fill pattern for the stack high-water mark.
const STACK_PAINT: u32 = 0xCCCC_CCCC;

extern "C" {
    /// End of .bss/.uninit: the lowest address the stack can grow down to (cortex-m-rt).
    static mut __sheap: u32;
    /// Initial stack pointer: the top of RAM (cortex-m-rt).
    static _stack_start: u32;
}

/// Paints the unused stack so [`stack_high_water`] can measure it. Call
/// first thing in `main`; it leaves 256 bytes below the live stack pointer.
pub fn paint_stack() {
    let bottom = core::ptr::addr_of_mut!(__sheap) as usize;
    let limit = cortex_m::register::msp::read() as usize - 256;
    let mut address = bottom;
    while address < limit {
        // SAFETY: [bottom, limit) is RAM between the statics and the live
        // stack, used by nothing else yet.
        unsafe { core::ptr::write_volatile(address as *mut u32, STACK_PAINT) };
        address += 4;
    }
}

/// Deepest stack use since [`paint_stack`], in bytes, and the stack's size.
pub fn stack_high_water() -> (usize, usize) {
    let bottom = core::ptr::addr_of_mut!(__sheap) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut address = bottom;
    // SAFETY: reads RAM between the statics and the top of the stack.
    while address < top && unsafe { core::ptr::read_volatile(address as *const u32) } == STACK_PAINT {
        address += 4;
    }
    (top - address, top - bottom)
}

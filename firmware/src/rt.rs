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
/// Empty when the host gives none.
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

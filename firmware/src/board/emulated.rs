//! The emulated board: QEMU's `netduinoplus2` (STM32F405, same core and map
//! as the STM32F407 target).
//!
//! What QEMU models and what it does not, as measured:
//! - USART1 at 0x4001_1000 works and is wired to QEMU's first `-serial`;
//! - there is no clock controller (RCC) model, so clock set-up is skipped;
//! - TIM2 counts; under `-icount shift=0` with prescaler 0 it advances one
//!   tick per instruction, which makes it the benchmark's instruction counter
//!   (the DWT cycle counter reads 0);
//! - there is no CCM RAM;
//! - GPIO ports are unimplemented devices: writes are accepted and ignored,
//!   so the alarm pin also keeps its level in RAM for the loop and the logs;
//! - the independent watchdog (IWDG) is an unimplemented device too (`-d
//!   unimp` lists the writes): the emulated board's watchdog is SysTick
//!   (which QEMU models, 168 MHz) counting down in its exception, which
//!   logs and ends the run where a real board would reset;
//! - QEMU's timers count virtual nanoseconds (1 GHz): TIM5, prescaled to
//!   1 MHz, is the fail-safe clock. Without `-icount` virtual time is the
//!   host's time.
//!
//! Frames come from the host through ARM semihosting (SYS_OPEN / SYS_READ of
//! `frames/NNNNNN.pgm`, relative to QEMU's working directory, which the
//! runner sets to the recording).

use core::convert::Infallible;
use core::ptr::{read_volatile, write_volatile};
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;

use cortex_m_semihosting::{nr, syscall};

use flatland_core::pgm::{PgmError, PgmHeader};

use super::{Clock, CycleCounter, FrameSize, RowSource, RowSourceError, Watchdog};

const USART1: usize = 0x4001_1000;
const USART_SR: usize = 0x00;
const USART_DR: usize = 0x04;
const USART_BRR: usize = 0x08;
const USART_CR1: usize = 0x0C;
const SR_ORE: u32 = 1 << 3;
const SR_RXNE: u32 = 1 << 5;
const SR_TXE: u32 = 1 << 7;
const CR1_RE: u32 = 1 << 2;
const CR1_TE: u32 = 1 << 3;
const CR1_UE: u32 = 1 << 13;

const TIM2: usize = 0x4000_0000;
const TIM_CR1: usize = 0x00;
const TIM_EGR: usize = 0x14;
const TIM_CNT: usize = 0x24;
const TIM_PSC: usize = 0x28;
const TIM_ARR: usize = 0x2C;

/// TIM5 (32-bit), prescaled to microseconds: the [`Clock`].
const TIM5: usize = 0x4000_0C00;
/// QEMU's STM32 timers count at 1 GHz (virtual nanoseconds).
const QEMU_TIMER_HZ: u32 = 1_000_000_000;

const GPIOD: usize = 0x4002_0C00;
const GPIO_MODER: usize = 0x00;
const GPIO_BSRR: usize = 0x18;
/// PD14: the red LED on STM32F4-Discovery-style boards.
const ALARM_PIN: u32 = 14;

/// The core clock QEMU gives the netduinoplus2 (SysTick's processor clock).
const CORE_HZ: u32 = 168_000_000;
/// SysTick period of the emulated watchdog.
const WATCHDOG_TICK_MS: u32 = 10;

fn write_register(address: usize, value: u32) {
    // SAFETY: `address` is one of the memory-mapped registers above, which
    // exist on the STM32F4 and are modelled (or ignored) by QEMU.
    unsafe { write_volatile(address as *mut u32, value) }
}

fn read_register(address: usize) -> u32 {
    // SAFETY: as for `write_register`.
    unsafe { read_volatile(address as *const u32) }
}

/// TIM2's counter: instructions under `-icount shift=0`, 0 before [`EmulatedBoard::take`].
pub fn instructions_now() -> u32 {
    read_register(TIM2 + TIM_CNT)
}

/// TIM5's counter: microseconds of virtual time, 0 before [`EmulatedBoard::take`]
/// starts it (QEMU's counter runs on virtual time even while disabled).
pub fn uptime_us() -> u32 {
    if read_register(TIM5 + TIM_CR1) & 1 == 0 {
        return 0;
    }
    read_register(TIM5 + TIM_CNT)
}

/// The emulated board's parts, handed to the frame loop.
pub struct EmulatedBoard {
    pub serial: Usart1,
    pub alarm: AlarmPin,
    pub counter: Tim2Counter,
    pub clock: Tim5Clock,
    pub watchdog: SysTickWatchdog,
    pub frames: SemihostingFrames,
}

impl EmulatedBoard {
    /// Configures the peripherals, the alarm asserted first, and starts the
    /// watchdog with `watchdog_timeout_ms`. Call once.
    pub fn take(watchdog_timeout_ms: u32) -> EmulatedBoard {
        // PD14 high, then a push-pull output: asserted from the first moment it drives.
        write_register(GPIOD + GPIO_BSRR, 1 << ALARM_PIN);
        let moder = read_register(GPIOD + GPIO_MODER) & !(0b11 << (2 * ALARM_PIN));
        write_register(GPIOD + GPIO_MODER, moder | (0b01 << (2 * ALARM_PIN)));
        // No RCC in QEMU: the peripheral clocks and the PLL are not set up.
        // USART1: 8N1, transmitter and receiver on. BRR is ignored by QEMU;
        // 115200 baud at 84 MHz APB2 on a real board.
        write_register(USART1 + USART_BRR, 0x02D9);
        write_register(USART1 + USART_CR1, CR1_UE | CR1_TE | CR1_RE);
        // TIM2: 32-bit, prescaler 0, free-running over the full range.
        write_register(TIM2 + TIM_PSC, 0);
        write_register(TIM2 + TIM_ARR, u32::MAX);
        write_register(TIM2 + TIM_EGR, 1);
        write_register(TIM2 + TIM_CR1, 1);
        // TIM5: 32-bit, 1 MHz, free-running.
        write_register(TIM5 + TIM_PSC, QEMU_TIMER_HZ / 1_000_000 - 1);
        write_register(TIM5 + TIM_ARR, u32::MAX);
        write_register(TIM5 + TIM_EGR, 1);
        write_register(TIM5 + TIM_CR1, 1);
        EmulatedBoard {
            serial: Usart1 { _private: () },
            alarm: AlarmPin { high: true },
            counter: Tim2Counter { _private: () },
            clock: Tim5Clock { _private: () },
            watchdog: SysTickWatchdog::start(watchdog_timeout_ms),
            frames: SemihostingFrames::new(),
        }
    }
}

/// TIM5 in microseconds.
pub struct Tim5Clock {
    _private: (),
}

impl Clock for Tim5Clock {
    fn now_us(&self) -> u32 {
        uptime_us()
    }

    /// Counted in instructions, as the real board's 168 MHz core would run
    /// them (QEMU's virtual time is the host's).
    fn delay_us(&self, us: u32) {
        cortex_m::asm::delay(us.saturating_mul(MODELLED_CPU_MHZ));
    }
}

/// The modelled core's clock (the STM32F4's 168 MHz), for [`Tim5Clock::delay_us`].
const MODELLED_CPU_MHZ: u32 = 168;

/// SysTick periods left before the emulated watchdog fires; u32::MAX: not started.
static WATCHDOG_TICKS_LEFT: AtomicU32 = AtomicU32::new(u32::MAX);
/// The timeout in SysTick periods, what a feed restores.
static WATCHDOG_TIMEOUT_TICKS: AtomicU32 = AtomicU32::new(u32::MAX);

/// The emulated board's watchdog: SysTick every [`WATCHDOG_TICK_MS`]
/// counts down; at zero its exception logs and ends the run with status 1,
/// where the real board's IWDG resets the chip.
pub struct SysTickWatchdog {
    _private: (),
}

impl SysTickWatchdog {
    /// Starts the watchdog (once: SysTick is taken from the core peripherals).
    pub fn start(timeout_ms: u32) -> SysTickWatchdog {
        let ticks = timeout_ms.div_ceil(WATCHDOG_TICK_MS).max(1);
        WATCHDOG_TIMEOUT_TICKS.store(ticks, Ordering::Relaxed);
        WATCHDOG_TICKS_LEFT.store(ticks, Ordering::Relaxed);
        match cortex_m::Peripherals::take() {
            Some(mut core) => {
                core.SYST.set_clock_source(SystClkSource::Core);
                core.SYST.set_reload(CORE_HZ / 1000 * WATCHDOG_TICK_MS - 1);
                core.SYST.clear_current();
                core.SYST.enable_interrupt();
                core.SYST.enable_counter();
            }
            None => defmt::error!("watchdog: SysTick already taken; running without a watchdog"),
        }
        SysTickWatchdog { _private: () }
    }
}

impl Watchdog for SysTickWatchdog {
    fn feed(&mut self) {
        WATCHDOG_TICKS_LEFT.store(WATCHDOG_TIMEOUT_TICKS.load(Ordering::Relaxed), Ordering::Relaxed);
    }
}

#[exception]
fn SysTick() {
    let left = WATCHDOG_TICKS_LEFT.load(Ordering::Relaxed);
    if left == u32::MAX {
        return;
    }
    if left > 1 {
        WATCHDOG_TICKS_LEFT.store(left - 1, Ordering::Relaxed);
        return;
    }
    super::assert_alarm_after_fault();
    let timeout_ms = WATCHDOG_TIMEOUT_TICKS.load(Ordering::Relaxed).saturating_mul(WATCHDOG_TICK_MS);
    defmt::error!("watchdog: not fed for {=u32} ms; alarm asserted, a real board resets here", timeout_ms);
    crate::rt::exit(crate::rt::Exit::Failure)
}

/// USART1, polled.
pub struct Usart1 {
    _private: (),
}

/// A receive overrun: bytes were lost (the loop counts it as garbage).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct Overrun;

impl embedded_io::Error for Overrun {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::Other
    }
}

impl embedded_io::ErrorType for Usart1 {
    type Error = Overrun;
}

impl embedded_io::Read for Usart1 {
    /// Blocks until at least one byte arrived, then returns what is there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Overrun> {
        let mut count = 0;
        while count < buf.len() {
            let status = read_register(USART1 + USART_SR);
            if status & SR_ORE != 0 {
                // Reading DR after SR clears ORE.
                let _ = read_register(USART1 + USART_DR);
                return Err(Overrun);
            }
            if status & SR_RXNE != 0 {
                buf[count] = read_register(USART1 + USART_DR) as u8;
                count += 1;
            } else if count > 0 {
                break;
            }
        }
        Ok(count)
    }
}

impl embedded_io::ReadReady for Usart1 {
    /// A byte waits (or an overrun, which `read` reports).
    fn read_ready(&mut self) -> Result<bool, Overrun> {
        Ok(read_register(USART1 + USART_SR) & (SR_RXNE | SR_ORE) != 0)
    }
}

impl embedded_io::Write for Usart1 {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Overrun> {
        for &byte in buf {
            while read_register(USART1 + USART_SR) & SR_TXE == 0 {}
            write_register(USART1 + USART_DR, u32::from(byte));
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Overrun> {
        while read_register(USART1 + USART_SR) & SR_TXE == 0 {}
        Ok(())
    }
}

/// The alarm output (PD14).
pub struct AlarmPin {
    high: bool,
}

impl AlarmPin {
    /// The level last set (GPIO is not modelled by QEMU, so not read back).
    pub fn is_set_high(&self) -> bool {
        self.high
    }
}

impl embedded_hal::digital::ErrorType for AlarmPin {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for AlarmPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        write_register(GPIOD + GPIO_BSRR, 1 << (ALARM_PIN + 16));
        self.high = false;
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        write_register(GPIOD + GPIO_BSRR, 1 << ALARM_PIN);
        self.high = true;
        Ok(())
    }
}

/// TIM2 as the cycle counter.
pub struct Tim2Counter {
    _private: (),
}

impl CycleCounter for Tim2Counter {
    fn now(&self) -> u32 {
        instructions_now()
    }
}

/// Bytes read to find the end of a PGM header (comments included); a longer
/// header is refused as a format error.
const HEADER_PREFIX: usize = 256;

/// Frames of a recording read through semihosting, one row per SYS_READ.
pub struct SemihostingFrames {
    handle: Option<usize>,
    width: u16,
    rows_left: u16,
}

impl SemihostingFrames {
    const fn new() -> Self {
        SemihostingFrames { handle: None, width: 0, rows_left: 0 }
    }

    /// `frames/NNNNNN.pgm\0` for `index` (six digits, as the recording layout has them).
    fn frame_path(index: u32) -> Option<[u8; 18]> {
        if index > 999_999 {
            return None;
        }
        let mut path = *b"frames/000000.pgm\0";
        let mut rest = index;
        for digit in path[7..13].iter_mut().rev() {
            *digit = b'0' + (rest % 10) as u8;
            rest /= 10;
        }
        Some(path)
    }

    /// SYS_READ of up to `buf.len()` bytes; returns how many were read.
    fn read_into(handle: usize, buf: &mut [u8]) -> usize {
        // SAFETY: SYS_READ writes at most `buf.len()` bytes into `buf`, and
        // returns the number of bytes it did *not* read.
        let not_read = unsafe { syscall!(READ, handle, buf.as_mut_ptr(), buf.len()) };
        buf.len().saturating_sub(not_read)
    }
}

impl RowSource for SemihostingFrames {
    fn begin_frame(&mut self, index: u32) -> Result<FrameSize, RowSourceError> {
        self.end_frame();
        let path = Self::frame_path(index).ok_or(RowSourceError::Missing)?;
        // SAFETY: `path` is NUL-terminated; the length excludes the NUL.
        let handle = unsafe { syscall!(OPEN, path.as_ptr(), nr::open::R_BINARY, path.len() - 1) };
        if handle == usize::MAX {
            return Err(RowSourceError::Missing);
        }
        self.handle = Some(handle);
        let mut prefix = [0u8; HEADER_PREFIX];
        let length = Self::read_into(handle, &mut prefix);
        let header = PgmHeader::parse(&prefix[..length]).map_err(|error| match error {
            // The file ended inside its header: the source stopped.
            PgmError::TruncatedHeader if length < HEADER_PREFIX => RowSourceError::Read,
            _ => RowSourceError::Format,
        })?;
        // maxval < 255 is used as is, as the host reader does.
        // SAFETY: SYS_SEEK to an absolute offset inside the file.
        let sought = unsafe { syscall!(SEEK, handle, header.data_offset) };
        if sought != 0 {
            return Err(RowSourceError::Read);
        }
        self.width = header.width;
        self.rows_left = header.height;
        Ok(FrameSize { width: header.width, height: header.height })
    }

    fn read_row(&mut self, row: &mut [u8]) -> Result<(), RowSourceError> {
        let handle = self.handle.ok_or(RowSourceError::Read)?;
        if row.len() != usize::from(self.width) {
            return Err(RowSourceError::RowLength);
        }
        if self.rows_left == 0 || Self::read_into(handle, row) != row.len() {
            return Err(RowSourceError::Read);
        }
        self.rows_left -= 1;
        Ok(())
    }

    fn end_frame(&mut self) {
        if let Some(handle) = self.handle.take() {
            // SAFETY: closes a handle SYS_OPEN returned; it is not used again.
            unsafe {
                syscall!(CLOSE, handle);
            }
        }
    }
}

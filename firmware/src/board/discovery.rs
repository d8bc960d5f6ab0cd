//! The real board: STM32F4DISCOVERY (STM32F407VG) with an OV7670 on DCMI.
//!
//! - Clocks: 168 MHz SYSCLK from the 8 MHz HSE crystal (PLL M=4 N=168 P=2
//!   Q=7), APB1 42 MHz, APB2 84 MHz.
//! - Camera: XCLK 16 MHz (HSI on MCO1, PA8), set up over SCCB on I2C1
//!   (PB8 SIOC, PB9 SIOD) with [`ov7670::SETUP`]: QVGA YUV422 at 30 frames/s
//!   (the VGA array downsampled 2x2 in the sensor, PCLK 12 MHz).
//! - Capture: DCMI in continuous mode from start-up on, for good, into a
//!   ring of [`CAMERA_RING_LINES`] YUV lines (DMA2 stream 1, circular),
//!   DCMI's crop fixing each frame at 240 lines of 640 bytes.
//!   [`RowSource::begin_frame`] waits for the next frame end (VSYNC; the
//!   DCMI interrupt counts them) and empties the ring: the frame that
//!   starts after it is the one read. [`RowSource::read_row`] takes a line
//!   out as the pipeline asks and keeps its Y bytes: 320x240 rows with the
//!   sensor's whole field of view. Frames that come while the loop is busy
//!   (its frame-end work, the serial link) run through the ring unread and
//!   are counted as dropped. Why not embassy's `Dcmi::capture`: it DMAs a
//!   whole frame into one buffer (QVGA YUV422 is 150 KB; RAM is 128 KB), and
//!   the F407's DCMI cannot drop the chroma bytes itself (no byte-select mode).
//! - Pairing with odometry: one frame per `$FLODO`, as on the emulated
//!   board: the frame loop is unchanged, and the frame is the camera's next
//!   whole frame after the `$FLODO` is handled, not a snapshot triggered
//!   by it. A free-running loop (frame when ready, newest odometry) was
//!   not taken: `$FLODO`'s frame number is the robot's and a frame compares
//!   only with the frame before (`Pipeline::follows`), so skipping
//!   odometry would restart the keyframe every frame, and renumbering or
//!   interpolating poses to the capture time is a protocol change the
//!   emulated board's golden output would see. A robot that sends its next
//!   `$FLODO` when the answer to the last one arrives gets every frame the
//!   board can process; one that sends faster queues them (the 1 KB
//!   receive buffer), and each is paired with a later frame.
//! - Serial: USART2 (PA2 TX, PA3 RX), 115200 8N1, interrupt-driven with RAM
//!   buffers, so odometry lines that arrive while a frame is processed wait.
//! - Alarm: red LED PD14 and PD11 (for the robot's controller) together,
//!   driven high (alarm) from the moment they become outputs;
//!   green LED PD12 toggles once per frame; orange LED PD13 = a camera fault
//!   since reset (set-up failed, DCMI error, ring overrun, a frame of the
//!   wrong length or no data).
//! - Cycle counter: DWT CYCCNT (168 MHz). TIM2 runs at 1 MHz for the defmt
//!   timestamps (rt.rs reads TIM2, as on the emulated board) and is the
//!   fail-safe [`Clock`]: microseconds.
//! - Watchdog: the independent watchdog (IWDG, on the 32 kHz LSI), started
//!   at the end of [`DiscoveryBoard::take`] with [`WATCHDOG_TIMEOUT_US`];
//!   once started nothing stops it. It is frozen while a debugger halts the
//!   core (DBGMCU), so stepping does not reset the board.
//!
//! Pins are checked by the type system (embassy's `dcmi::D0Pin` etc.), so a
//! pin that cannot carry the signal does not compile.

use core::convert::Infallible;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::peripheral::DWT;
use embassy_stm32::dcmi::{self, FrameDma};
use embassy_stm32::dma::{self, ReadableRingBuffer, TransferOptions};
use embassy_stm32::gpio::{AfType, Flex, Level, Output, Pin, Pull, Speed};
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::interrupt::typelevel::{Handler, Interrupt};
use embassy_stm32::mode::Blocking;
use embassy_stm32::rcc::{self, Mco, Mco1Source, McoConfig, McoPrescaler};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, interrupt, pac, peripherals, Peri};
use static_cell::ConstStaticCell;

use super::ov7670;
use super::{Clock, CycleCounter, FrameSize, RowSource, RowSourceError, Watchdog};

/// SYSCLK, for the millisecond busy-waits.
pub const SYSCLK_HZ: u32 = 168_000_000;
/// The camera's XCLK: HSI on MCO1.
pub const XCLK_HZ: u32 = 16_000_000;
/// The frame the pipeline sees: the sensor's QVGA, Y only.
pub const FRAME: FrameSize = FrameSize { width: ov7670::QVGA_WIDTH, height: ov7670::QVGA_HEIGHT };
/// The camera's frame rate (x1000), from its clocks: 30.0 frames/s.
const FRAME_RATE_MILLIHERTZ: u32 = ov7670::frame_rate_millihertz(XCLK_HZ);
/// Bytes per camera line as DCMI delivers it (YUV422: 2 per pixel).
const LINE_BYTES: usize = FRAME.width as usize * 2;
/// One 32-bit DMA word per pixel pair (Y0 U Y1 V).
const LINE_WORDS: usize = LINE_BYTES / 4;
/// YUV lines the DMA ring holds: how far the pipeline may fall behind the
/// camera within a frame (32 lines = 20 KB, 4.2 ms at a line per 130.7 us).
pub const CAMERA_RING_LINES: usize = 32;
const RING_WORDS: usize = CAMERA_RING_LINES * LINE_WORDS;
/// DMA words in one frame, as DCMI's crop cuts it.
const FRAME_WORDS: usize = FRAME.height as usize * LINE_WORDS;
/// No camera data, or no frame end, for this long is a dead camera (15
/// frame periods).
const CAMERA_TIMEOUT_CYCLES: u32 = SYSCLK_HZ / 2;
/// Frames taken between two log lines of the stream's counters.
const STATS_EVERY: u32 = 100;
/// The IWDG's timeout, nominal (LSI 32 kHz). The LSI may run anywhere
/// from 17 to 47 kHz, which makes it 3.4 to 9.4 s: above the longest stretch
/// the loop goes without feeding it, a frame's end (~1.6 s, docs/PERFORMANCE.md),
/// with a margin of two.
pub const WATCHDOG_TIMEOUT_US: u32 = 5_000_000;
/// USART2 buffers: a $FLRIG line is < 200 B, a $FLODO < 60 B.
const SERIAL_RX_BYTES: usize = 1024;
const SERIAL_TX_BYTES: usize = 256;

static CAMERA_RING: ConstStaticCell<[u32; RING_WORDS]> = ConstStaticCell::new([0; RING_WORDS]);
static SERIAL_RX: ConstStaticCell<[u8; SERIAL_RX_BYTES]> = ConstStaticCell::new([0; SERIAL_RX_BYTES]);
static SERIAL_TX: ConstStaticCell<[u8; SERIAL_TX_BYTES]> = ConstStaticCell::new([0; SERIAL_TX_BYTES]);

/// Frame ends (VSYNC turning to its blanking level) since reset, counted
/// by [`FrameEnds`].
static FRAME_ENDS: AtomicU32 = AtomicU32::new(0);
/// Where the DMA stood in the ring at the last frame end (low 16 bits, in
/// words), tagged with the low 16 bits of its count (high 16 bits), so a
/// reader can tell it belongs to the count it read.
static LAST_END: AtomicU32 = AtomicU32::new(0);

bind_interrupts!(struct Irqs {
    USART2 => usart::BufferedInterruptHandler<peripherals::USART2>;
    DMA2_STREAM1 => dma::InterruptHandler<peripherals::DMA2_CH1>;
    DCMI => FrameEnds;
});

/// The DCMI interrupt, on VSYNC only: counts frame ends and notes the
/// ring position of each, which is where the next frame's first word will
/// land (a frame ends 10 blank lines after its last line and the next
/// starts 20 lines later, so no word is in flight).
pub struct FrameEnds;

impl Handler<interrupt::typelevel::DCMI> for FrameEnds {
    unsafe fn on_interrupt() {
        let dcmi = pac::DCMI;
        if dcmi.mis().read().vsync_mis() {
            dcmi.icr().write(|w| w.set_vsync_isc(true));
            let count = FRAME_ENDS.load(Ordering::Relaxed).wrapping_add(1);
            LAST_END.store((count << 16) | ring_position() as u32, Ordering::Release);
            FRAME_ENDS.store(count, Ordering::Release);
        }
    }
}

/// Where the DMA writes next in the camera ring, in words. Read-only
/// access to stream 1's counter, which embassy's ring buffer reads too.
fn ring_position() -> usize {
    (RING_WORDS - usize::from(pac::DMA2.st(1).ndtr().read().ndt())) % RING_WORDS
}

/// The last frame end: its count and the ring position at it.
fn last_frame_end() -> (u32, usize) {
    loop {
        let count = FRAME_ENDS.load(Ordering::Acquire);
        let end = LAST_END.load(Ordering::Acquire);
        // Stored before the count: a mismatch means another frame ended in between.
        if end >> 16 == count & 0xFFFF {
            return (count, (end & 0xFFFF) as usize);
        }
    }
}

/// Waits for a frame end after the `seen`-th, up to [`CAMERA_TIMEOUT_CYCLES`]
/// from `since` (DWT cycles).
fn wait_frame_end(seen: u32, since: u32) -> Option<(u32, usize)> {
    loop {
        let end = last_frame_end();
        if end.0 != seen {
            return Some(end);
        }
        if DWT::cycle_count().wrapping_sub(since) > CAMERA_TIMEOUT_CYCLES {
            return None;
        }
    }
}

/// Busy-waits `ms` milliseconds at [`SYSCLK_HZ`] (no time driver is linked).
fn delay_ms(ms: u32) {
    cortex_m::asm::delay(ms * (SYSCLK_HZ / 1000));
}

/// The board's parts, handed to the frame loop.
pub struct DiscoveryBoard {
    pub serial: Usart2,
    pub alarm: AlarmOutputs,
    pub counter: DwtCounter,
    pub frames: CameraRows,
    pub clock: Tim2Clock,
    pub watchdog: Iwdg,
}

impl DiscoveryBoard {
    /// Clocks, pins, serial, camera. Call once. A camera that does not answer
    /// is logged and lights the orange LED; the serial link still comes up and
    /// every frame is then answered with `$FLERR,frame_missing`.
    pub fn take() -> DiscoveryBoard {
        let p = embassy_stm32::init(clock_config());
        // The alarm first: asserted from the moment the pins drive (before
        // this they float; docs/BOARD.md asks for a pull-up on PD11).
        let alarm = AlarmOutputs {
            led: Output::new(p.PD14, Level::High, Speed::Low),
            line: Output::new(p.PD11, Level::High, Speed::Low),
        };
        let mut core = cortex_m::Peripherals::take();
        if let Some(core) = core.as_mut() {
            core.DCB.enable_trace();
            core.DWT.enable_cycle_counter();
        }
        start_timestamp_timer();

        // On-board parts that share the camera's pins: CS43L22 audio DAC held
        // in reset (PD4 low) so it stays off PB6/PB9/PA4/PC7; LIS3DSH
        // accelerometer deselected (PE3 high) so it never drives PA6 (SPI1 MISO).
        let codec_reset = Output::new(p.PD4, Level::Low, Speed::Low);
        let accel_cs = Output::new(p.PE3, Level::High, Speed::Low);
        // Held for good: dropping an Output or Flex releases its pin.
        core::mem::forget((codec_reset, accel_cs));

        let mut uart_config = usart::Config::default();
        uart_config.baudrate = 115_200;
        let serial = BufferedUart::new(p.USART2, p.PA3, p.PA2, SERIAL_TX.take(), SERIAL_RX.take(), Irqs, uart_config)
            .map(|inner| Usart2 { inner: Some(inner) })
            .unwrap_or_else(|_| {
                defmt::error!("USART2 configuration refused");
                Usart2 { inner: None }
            });

        let heartbeat = Output::new(p.PD12, Level::Low, Speed::Low);
        let mut fault_led = Output::new(p.PD13, Level::Low, Speed::Low);

        // XCLK ([`XCLK_HZ`]) first: the OV7670 answers SCCB only with a running clock.
        let mut mco_config = McoConfig::default();
        mco_config.prescaler = McoPrescaler::DIV1;
        mco_config.speed = Speed::VeryHigh;
        let _xclk = Mco::new(p.MCO1, p.PA8, Mco1Source::HSI, mco_config);

        // PWDN low = on; RESET pulsed low.
        let power_down = Output::new(p.PD1, Level::Low, Speed::Low);
        let mut reset = Output::new(p.PD0, Level::Low, Speed::Low);
        delay_ms(10);
        reset.set_high();
        delay_ms(10);
        core::mem::forget((power_down, reset));

        let mut i2c_config = i2c::Config::default();
        i2c_config.frequency = Hertz::khz(100);
        // PB9 has the board's pull-up (audio I2C); PB8 needs an external one,
        // the internal ~40 kOhm is a fallback for short wires only.
        i2c_config.scl_pullup = true;
        i2c_config.sda_pullup = true;
        let mut sccb = I2c::new_blocking(p.I2C1, p.PB8, p.PB9, i2c_config);
        let camera_ok = match configure_camera(&mut sccb) {
            Ok(()) => true,
            Err(error) => {
                defmt::error!("camera set-up failed: {}", error);
                fault_led.set_high();
                false
            }
        };
        drop(sccb);

        let pins = [
            dcmi_pin(p.PC6, dcmi::D0Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PC7, dcmi::D1Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PC8, dcmi::D2Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PC9, dcmi::D3Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PE4, dcmi::D4Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PB6, dcmi::D5Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PE5, dcmi::D6Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PE6, dcmi::D7Pin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PA4, dcmi::HSyncPin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PB7, dcmi::VSyncPin::<peripherals::DCMI>::af_num),
            dcmi_pin(p.PA6, dcmi::PixClkPin::<peripherals::DCMI>::af_num),
        ];
        core::mem::forget(pins);

        let request = p.DMA2_CH1.request();
        let channel = dma::Channel::new(p.DMA2_CH1, Irqs);
        let options = TransferOptions::default();
        // SAFETY: DCMI's data register is a valid peripheral source for words;
        // the ring is 'static and owned by the ring buffer from here on.
        let mut ring = unsafe {
            ReadableRingBuffer::new(channel, request, pac::DCMI.dr().as_ptr() as *mut u32, CAMERA_RING.take(), options)
        };
        // Runs for good; DCMI gates the data, so the DMA only moves camera lines.
        ring.start();

        let mut frames = CameraRows {
            ring,
            camera_ok,
            streaming: false,
            line: [0; LINE_WORDS],
            rows_left: 0,
            frame_start: 0,
            start_position: 0,
            last_taken: None,
            stats: StreamStats::default(),
            heartbeat,
            fault_led,
        };
        interrupt::typelevel::DCMI::unpend();
        // SAFETY: FrameEnds, bound above, only touches DCMI's flags and two atomics.
        unsafe { interrupt::typelevel::DCMI::enable() };
        if camera_ok {
            frames.start_capture();
            frames.log_frame_rate();
        }

        // Last: set-up above takes ~0.4 s of delays; from here the loop feeds it.
        pac::DBGMCU.apb1fzr().modify(|w| w.set_iwdg(true));
        let mut iwdg = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
        iwdg.unleash();

        DiscoveryBoard {
            serial,
            alarm,
            counter: DwtCounter { _private: () },
            clock: Tim2Clock { _private: () },
            watchdog: Iwdg { inner: iwdg },
            frames,
        }
    }
}

/// 168 MHz from the 8 MHz crystal: 8 / 4 * 168 / 2; 48 MHz on Q (USB/SDIO).
fn clock_config() -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(rcc::Hse { freq: Hertz::mhz(8), mode: rcc::HseMode::Oscillator });
    // HSI stays on: it is the camera's XCLK.
    config.rcc.hsi = true;
    config.rcc.pll_src = rcc::PllSource::HSE;
    config.rcc.pll = Some(rcc::Pll {
        prediv: rcc::PllPreDiv::DIV4,
        mul: rcc::PllMul::MUL168,
        divp: Some(rcc::PllPDiv::DIV2),
        divq: Some(rcc::PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.sys = rcc::Sysclk::PLL1_P;
    config.rcc.ahb_pre = rcc::AHBPrescaler::DIV1;
    config.rcc.apb1_pre = rcc::APBPrescaler::DIV4;
    config.rcc.apb2_pre = rcc::APBPrescaler::DIV2;
    config
}

/// TIM2 free-running at 1 MHz (84 MHz timer clock / 84): the defmt timestamp.
fn start_timestamp_timer() {
    pac::RCC.apb1enr().modify(|w| w.set_tim2en(true));
    let tim2 = pac::TIM2;
    tim2.psc().write_value(83);
    tim2.arr().write_value(u32::MAX);
    tim2.egr().write(|w| w.set_ug(true));
    tim2.cr1().modify(|w| w.set_cen(true));
}

/// A DCMI input (AF13, no pull). `af` comes from the pin's DCMI signal trait,
/// so only pins that carry that signal compile.
fn dcmi_pin<P: Pin>(pin: Peri<'static, P>, af: impl FnOnce(&P) -> u8) -> Flex<'static> {
    let af_num = af(&pin);
    let mut flex = Flex::new(pin);
    flex.set_as_af_unchecked(af_num, AfType::input(Pull::None));
    flex
}

/// Why the camera could not be set up.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum CameraError {
    /// No SCCB answer (not wired, no XCLK, no power, no pull-ups).
    Sccb(u8),
    /// Something answered with the wrong product ID.
    WrongId { pid: u8, ver: u8 },
}

/// One SCCB register write.
fn sccb_write(sccb: &mut I2c<'static, Blocking, i2c::Master>, register: u8, value: u8) -> Result<(), CameraError> {
    sccb.blocking_write(ov7670::SCCB_ADDRESS, &[register, value]).map_err(|_| CameraError::Sccb(register))
}

/// One SCCB register read: SCCB wants a stop between the address write and
/// the read (no repeated start), hence two transactions.
fn sccb_read(sccb: &mut I2c<'static, Blocking, i2c::Master>, register: u8) -> Result<u8, CameraError> {
    let mut value = [0u8];
    sccb.blocking_write(ov7670::SCCB_ADDRESS, &[register]).map_err(|_| CameraError::Sccb(register))?;
    sccb.blocking_read(ov7670::SCCB_ADDRESS, &mut value).map_err(|_| CameraError::Sccb(register))?;
    Ok(value[0])
}

fn configure_camera(sccb: &mut I2c<'static, Blocking, i2c::Master>) -> Result<(), CameraError> {
    let (pid, ver) = (sccb_read(sccb, ov7670::PID)?, sccb_read(sccb, ov7670::VER)?);
    if (pid, ver) != ov7670::PRODUCT_ID {
        return Err(CameraError::WrongId { pid, ver });
    }
    sccb_write(sccb, ov7670::COM7, ov7670::COM7_RESET)?;
    delay_ms(10);
    for &(register, value) in ov7670::SETUP {
        sccb_write(sccb, register, value)?;
    }
    for (register, value) in ov7670::window_registers(ov7670::WINDOW_QVGA) {
        sccb_write(sccb, register, value)?;
    }
    // Settle: the PLL, and AEC/AGC need a few frames before the image is usable.
    delay_ms(300);
    defmt::info!(
        "OV7670 {=u8:#x}{=u8:x}: YUV422 {=u16}x{=u16} (DCW 2x2), XCLK {=u32} MHz x{=u32} /{=u8}, PCLK {=u32} kHz, {=u32}.{=u32} frames/s",
        pid,
        ver,
        FRAME.width,
        FRAME.height,
        XCLK_HZ / 1_000_000,
        ov7670::PLL_MULTIPLIER,
        ov7670::CLKRC_DIVIDER + 1,
        ov7670::pclk_hz(XCLK_HZ) / 1000,
        FRAME_RATE_MILLIHERTZ / 1000,
        FRAME_RATE_MILLIHERTZ / 100 % 10
    );
    Ok(())
}

/// What the camera stream did since reset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct StreamStats {
    /// Frames handed to the pipeline (begun).
    pub taken: u32,
    /// Whole frames the camera sent between two taken ones: the loop was busy.
    pub dropped: u32,
    /// Frame ends the sync came too late for (the next frame had begun);
    /// the sync then waits for the frame end after. Counted in `dropped` too.
    pub late_syncs: u32,
}

/// Camera rows from DCMI's continuous stream through the DMA ring.
pub struct CameraRows {
    ring: ReadableRingBuffer<'static, u32>,
    camera_ok: bool,
    /// DCMI is capturing; cleared by a DCMI error or a dead camera, after
    /// which the next frame restarts it.
    streaming: bool,
    /// The YUV line last taken from the ring.
    line: [u32; LINE_WORDS],
    /// Rows still to come in this frame.
    rows_left: u16,
    /// The frame end the current frame started after, and the ring
    /// position there (its first word).
    frame_start: u32,
    start_position: usize,
    /// The frame end the previous taken frame started after.
    last_taken: Option<u32>,
    stats: StreamStats,
    heartbeat: Output<'static>,
    fault_led: Output<'static>,
}

impl CameraRows {
    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// (Re)starts DCMI in continuous mode; the DMA ring keeps running.
    /// From the next VSYNC on, every frame flows into the ring.
    fn start_capture(&mut self) {
        // Reset DCMI so no word of an aborted frame is left in its FIFO.
        rcc::enable_and_reset::<peripherals::DCMI>();
        let dcmi = pac::DCMI;
        dcmi.icr().write(|w| {
            w.set_ovr_isc(true);
            w.set_err_isc(true);
            w.set_frame_isc(true);
            w.set_vsync_isc(true);
            w.set_line_isc(true);
        });
        // Crop to exactly 240 lines of 640 bytes from each frame's first:
        // a sensor window a few pixels or lines too large cannot shift the
        // ring's line boundaries (one too short is caught at the frame's end).
        dcmi.cwstrt().write(|w| {
            w.set_hoffcnt(0);
            w.set_vst(0);
        });
        dcmi.cwsize().write(|w| {
            w.set_capcnt(LINE_BYTES as u16 - 1); // pixel clocks (bytes) per line, minus one
            w.set_vline(FRAME.height - 1);
        });
        dcmi.cr().write(|w| {
            w.set_cm(false); // continuous: every frame, until CAPTURE is cleared
            w.set_crop(true);
            w.set_ess(false); // hardware HREF/VSYNC
            w.set_pckpol(true); // sample on the rising PCLK edge (OV7670 changes data on falling)
            w.set_vspol(true); // VSYNC high = blanking
            w.set_hspol(false); // HREF low = blanking
            w.set_fcrc(0); // every frame
            w.set_edm(0); // 8 data bits
        });
        dcmi.ier().write(|w| w.set_vsync_ie(true));
        dcmi.cr().modify(|w| w.set_enable(true));
        dcmi.cr().modify(|w| w.set_capture(true));
        self.streaming = true;
    }

    /// Stops DCMI (a fault); the DMA stays armed and idles without requests.
    fn stop_capture(&mut self) {
        pac::DCMI.cr().modify(|w| {
            w.set_capture(false);
            w.set_enable(false);
        });
        self.streaming = false;
    }

    /// Logs the frame period the camera really runs at (start-up: the
    /// only place it is measured), or that it sends no frames.
    fn log_frame_rate(&mut self) {
        let since = DWT::cycle_count();
        let Some((first, _)) = wait_frame_end(last_frame_end().0, since) else {
            defmt::error!("camera: no VSYNC for 0.5 s (XCLK, VSYNC or PCLK wiring?)");
            self.fault_led.set_high();
            return;
        };
        let first_at = DWT::cycle_count();
        match wait_frame_end(first, first_at) {
            Some(_) => {
                let period_us = DWT::cycle_count().wrapping_sub(first_at) / (SYSCLK_HZ / 1_000_000);
                defmt::info!("camera streaming: a frame every {=u32} us", period_us);
            }
            None => defmt::error!("camera: one VSYNC, then none for 0.5 s"),
        }
    }

    /// Syncs on the next frame: waits for a frame end, then empties the
    /// ring, which then starts at the next frame's first word. Returns the
    /// frame end synced on.
    fn sync(&mut self) -> Result<u32, RowSourceError> {
        let since = DWT::cycle_count();
        let mut seen = last_frame_end().0;
        loop {
            let Some((end, position)) = wait_frame_end(seen, since) else {
                defmt::error!("camera: no frame end for 0.5 s");
                return Err(self.fail(RowSourceError::Timeout, true));
            };
            self.ring.clear();
            // The ring's read position is the DMA's at the clear; if the DMA
            // has not moved since the frame end (and no other frame ended),
            // that is exactly where the next frame's first word will land.
            if ring_position() == position && FRAME_ENDS.load(Ordering::Acquire) == end {
                self.start_position = position;
                return Ok(end);
            }
            bump(&mut self.stats.late_syncs);
            seen = end;
        }
    }

    /// Fills `line` with the next YUV line from the DMA ring.
    fn read_line(&mut self) -> Result<(), RowSourceError> {
        let mut filled = 0;
        let mut last_progress = DWT::cycle_count();
        while filled < LINE_WORDS {
            // Read before the ring: a frame end seen here comes after every
            // word of the frame, so an empty ring then means the frame is over.
            let ended = FRAME_ENDS.load(Ordering::Acquire) != self.frame_start;
            match self.ring.read(&mut self.line[filled..]) {
                Ok((0, _)) => {
                    let status = pac::DCMI.ris().read();
                    if status.ovr_ris() || status.err_ris() {
                        defmt::error!("DCMI {=str}", if status.ovr_ris() { "overrun" } else { "sync error" });
                        return Err(self.fail(RowSourceError::Read, true));
                    }
                    if ended {
                        defmt::error!(
                            "camera: the frame ended {=u16} lines short of {=u16}",
                            self.rows_left,
                            FRAME.height
                        );
                        return Err(self.fail(RowSourceError::Read, false));
                    }
                    if DWT::cycle_count().wrapping_sub(last_progress) > CAMERA_TIMEOUT_CYCLES {
                        defmt::error!("camera: no line for 0.5 s ({=u16} rows left)", self.rows_left);
                        return Err(self.fail(RowSourceError::Timeout, true));
                    }
                }
                Ok((count, _)) => {
                    filled += count;
                    last_progress = DWT::cycle_count();
                }
                Err(_) => {
                    defmt::error!("camera ring overrun: the pipeline fell {=usize} lines behind", CAMERA_RING_LINES);
                    return Err(self.fail(RowSourceError::Read, false));
                }
            }
        }
        Ok(())
    }

    /// After the last row: waits for the frame's end and checks the words
    /// the DMA moved in it, start to end (modulo the ring: a frame short by
    /// a multiple of 32 lines passes here, but then its end came while the
    /// ring was empty, which [`CameraRows::read_line`] catches).
    fn check_frame_length(&mut self) -> Result<(), RowSourceError> {
        let Some((end, position)) = wait_frame_end(self.frame_start, DWT::cycle_count()) else {
            defmt::error!("camera: no frame end for 0.5 s after the last line");
            return Err(self.fail(RowSourceError::Timeout, true));
        };
        let words = (position + RING_WORDS - self.start_position) % RING_WORDS;
        if end != self.frame_start.wrapping_add(1) || words != FRAME_WORDS % RING_WORDS {
            defmt::error!(
                "camera: frame of {=usize} words modulo the ring, {=usize} expected ({=u32} frame ends)",
                words,
                FRAME_WORDS % RING_WORDS,
                end.wrapping_sub(self.frame_start)
            );
            return Err(self.fail(RowSourceError::Read, false));
        }
        Ok(())
    }

    /// Gives the frame up; `restart` when DCMI itself is in doubt.
    fn fail(&mut self, error: RowSourceError, restart: bool) -> RowSourceError {
        if restart {
            self.stop_capture();
        }
        self.rows_left = 0;
        self.fault_led.set_high();
        error
    }
}

fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

impl RowSource for CameraRows {
    /// Takes the camera's next whole frame: the one that starts after the
    /// next frame end. `index` is the host's frame number; the camera has none.
    fn begin_frame(&mut self, _index: u32) -> Result<FrameSize, RowSourceError> {
        if !self.camera_ok {
            return Err(RowSourceError::Missing);
        }
        self.rows_left = 0;
        // A DCMI overrun, even between frames, may have cost a word: restart.
        if !self.streaming || pac::DCMI.ris().read().ovr_ris() {
            self.start_capture();
        }
        let asked = DWT::cycle_count();
        let start = self.sync()?;
        if let Some(previous) = self.last_taken {
            let skipped = start.wrapping_sub(previous).saturating_sub(1);
            self.stats.dropped = self.stats.dropped.saturating_add(skipped);
        }
        self.last_taken = Some(start);
        self.frame_start = start;
        bump(&mut self.stats.taken);
        defmt::debug!("camera: frame start awaited {=u32} cycles", DWT::cycle_count().wrapping_sub(asked));
        if self.stats.taken.is_multiple_of(STATS_EVERY) {
            defmt::info!("camera: {}", self.stats);
        }
        self.rows_left = FRAME.height;
        Ok(FRAME)
    }

    /// One camera line, Y only.
    fn read_row(&mut self, row: &mut [u8]) -> Result<(), RowSourceError> {
        if row.len() != usize::from(FRAME.width) {
            return Err(RowSourceError::RowLength);
        }
        if self.rows_left == 0 {
            return Err(RowSourceError::Read);
        }
        self.read_line()?;
        let shift = 8 * ov7670::Y_OFFSET as u32;
        for (pixels, &word) in row.chunks_exact_mut(2).zip(self.line.iter()) {
            pixels[0] = (word >> shift) as u8;
            pixels[1] = (word >> (16 + shift)) as u8;
        }
        if self.rows_left == 1 {
            self.check_frame_length()?;
            self.heartbeat.toggle();
        }
        self.rows_left -= 1;
        Ok(())
    }

    /// The stream goes on: what comes until the next frame is asked for
    /// runs through the ring unread.
    fn end_frame(&mut self) {
        self.rows_left = 0;
    }
}

/// USART2 through embassy's interrupt-driven buffered driver (embedded-io
/// 0.7 inside; the frame loop speaks embedded-io 0.6, hence this wrapper).
pub struct Usart2 {
    /// None if embassy refused the configuration (logged; cannot happen for 115200 8N1).
    inner: Option<BufferedUart<'static>>,
}

/// A receive error (overrun, framing, noise, parity): bytes were lost.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct SerialError;

impl embedded_io::Error for SerialError {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::Other
    }
}

impl embedded_io::ErrorType for Usart2 {
    type Error = SerialError;
}

impl embedded_io::Read for Usart2 {
    /// Blocks until at least one byte arrived, then returns what is there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, SerialError> {
        let Some(inner) = self.inner.as_mut() else {
            // No serial port: nothing will ever arrive.
            loop {
                cortex_m::asm::wfi();
            }
        };
        if buf.is_empty() {
            return Ok(0);
        }
        loop {
            match embedded_io_07::Read::read(inner, buf) {
                Ok(0) => {}
                Ok(count) => return Ok(count),
                Err(_) => return Err(SerialError),
            }
        }
    }
}

impl embedded_io::ReadReady for Usart2 {
    fn read_ready(&mut self) -> Result<bool, SerialError> {
        match self.inner.as_mut() {
            Some(inner) => embedded_io_async_07::ReadReady::read_ready(inner).map_err(|_| SerialError),
            // No serial port: nothing will ever arrive.
            None => Ok(false),
        }
    }
}

impl embedded_io::Write for Usart2 {
    fn write(&mut self, buf: &[u8]) -> Result<usize, SerialError> {
        match self.inner.as_mut() {
            Some(inner) => embedded_io_07::Write::write(inner, buf).map_err(|_| SerialError),
            None => Ok(buf.len()),
        }
    }

    fn flush(&mut self) -> Result<(), SerialError> {
        match self.inner.as_mut() {
            Some(inner) => embedded_io_07::Write::flush(inner).map_err(|_| SerialError),
            None => Ok(()),
        }
    }
}

/// The alarm: red LED PD14 and the PD11 line, always at the same level.
pub struct AlarmOutputs {
    led: Output<'static>,
    line: Output<'static>,
}

impl embedded_hal::digital::ErrorType for AlarmOutputs {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for AlarmOutputs {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.line.set_low();
        self.led.set_low();
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.line.set_high();
        self.led.set_high();
        Ok(())
    }
}

/// DWT's cycle counter: CPU cycles at 168 MHz (wraps every 25.6 s).
pub struct DwtCounter {
    _private: (),
}

impl CycleCounter for DwtCounter {
    fn now(&self) -> u32 {
        DWT::cycle_count()
    }
}

/// TIM2 at 1 MHz (set up in [`DiscoveryBoard::take`]): the fail-safe clock.
pub struct Tim2Clock {
    _private: (),
}

/// TIM2's counter: microseconds, 0 before [`DiscoveryBoard::take`] enables it.
pub fn uptime_us() -> u32 {
    pac::TIM2.cnt().read()
}

impl Clock for Tim2Clock {
    fn now_us(&self) -> u32 {
        uptime_us()
    }

    /// On the timer itself: the same length at any flash wait states.
    fn delay_us(&self, us: u32) {
        let start = uptime_us();
        while uptime_us().wrapping_sub(start) < us {}
    }
}

/// The independent watchdog, started: it resets the chip unless fed within
/// [`WATCHDOG_TIMEOUT_US`].
pub struct Iwdg {
    inner: IndependentWatchdog<'static, peripherals::IWDG>,
}

impl Watchdog for Iwdg {
    fn feed(&mut self) {
        self.inner.pet();
    }
}

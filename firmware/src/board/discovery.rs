//! The real board: STM32F4DISCOVERY (STM32F407VG) with an OV7670 on DCMI.
//!
//! - Clocks: 168 MHz SYSCLK from the 8 MHz HSE crystal (PLL M=4 N=168 P=2
//!   Q=7), APB1 42 MHz, APB2 84 MHz.
//! - Camera: XCLK 16 MHz (HSI on MCO1, PA8), set up over SCCB on I2C1
//!   (PB8 SIOC, PB9 SIOD) with [`ov7670::SETUP`]: YUV422, full VGA window.
//! - Capture: DCMI in snapshot mode, one frame per [`RowSource::begin_frame`],
//!   DMA2 stream 1 in circular mode into a ring of [`CAMERA_RING_LINES`]
//!   YUV lines; [`RowSource::read_row`] takes two lines out, keeps the Y
//!   bytes and averages 2x2 blocks: 320x240 rows with the sensor's whole field
//!   of view. Why not embassy's `Dcmi::capture`: it DMAs a whole frame into
//!   one buffer (VGA YUV422 is 600 KB, QVGA 150 KB; RAM is 128 KB), and the
//!   F407's DCMI cannot drop the chroma bytes itself (no byte-select mode).
//! - Serial: USART2 (PA2 TX, PA3 RX), 115200 8N1, interrupt-driven with RAM
//!   buffers, so odometry lines that arrive while a frame is processed wait.
//! - Alarm: red LED PD14 and PD11 (for the robot's controller) together;
//!   green LED PD12 toggles once per frame; orange LED PD13 = a camera fault
//!   since reset (set-up failed, DCMI error, ring overrun or no data).
//! - Cycle counter: DWT CYCCNT (168 MHz). TIM2 runs at 1 MHz for the defmt
//!   timestamps (rt.rs reads TIM2, as on the emulated board): microseconds.
//!
//! Pins are checked by the type system (embassy's `dcmi::D0Pin` etc.), so a
//! pin that cannot carry the signal does not compile.

use core::convert::Infallible;

use cortex_m::peripheral::DWT;
use embassy_stm32::dcmi::{self, FrameDma};
use embassy_stm32::dma::{self, ReadableRingBuffer, TransferOptions};
use embassy_stm32::gpio::{AfType, Flex, Level, Output, Pin, Pull, Speed};
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::mode::Blocking;
use embassy_stm32::rcc::{self, Mco, Mco1Source, McoConfig, McoPrescaler};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::{bind_interrupts, pac, peripherals, Peri};
use static_cell::ConstStaticCell;

use super::ov7670::{self, Window};
use super::{CycleCounter, FrameSize, RowSource, RowSourceError};

/// SYSCLK, for the millisecond busy-waits.
pub const SYSCLK_HZ: u32 = 168_000_000;
/// The sensor window read out.
pub const WINDOW: Window = ov7670::WINDOW_VGA;
/// The frame the pipeline sees: the window binned 2x2.
pub const FRAME: FrameSize = FrameSize { width: WINDOW.width / 2, height: WINDOW.height / 2 };
/// Bytes per camera line as DCMI delivers it (YUV422: 2 per pixel).
const LINE_BYTES: usize = WINDOW.width as usize * 2;
/// One 32-bit DMA word per pixel pair (Y0 U Y1 V).
const LINE_WORDS: usize = LINE_BYTES / 4;
/// YUV lines the DMA ring holds: how far the pipeline may fall behind the
/// camera within a frame (16 lines = 20 KB = 8 output rows, 4.7 ms).
pub const CAMERA_RING_LINES: usize = 16;
const RING_WORDS: usize = CAMERA_RING_LINES * LINE_WORDS;
/// No camera data for this long is a dead camera (> 3 frames at 6.7 fps).
const LINE_TIMEOUT_CYCLES: u32 = SYSCLK_HZ / 2;
/// USART2 buffers: a $FLRIG line is < 200 B, a $FLODO < 60 B.
const SERIAL_RX_BYTES: usize = 1024;
const SERIAL_TX_BYTES: usize = 256;

static CAMERA_RING: ConstStaticCell<[u32; RING_WORDS]> = ConstStaticCell::new([0; RING_WORDS]);
static SERIAL_RX: ConstStaticCell<[u8; SERIAL_RX_BYTES]> = ConstStaticCell::new([0; SERIAL_RX_BYTES]);
static SERIAL_TX: ConstStaticCell<[u8; SERIAL_TX_BYTES]> = ConstStaticCell::new([0; SERIAL_TX_BYTES]);

bind_interrupts!(struct Irqs {
    USART2 => usart::BufferedInterruptHandler<peripherals::USART2>;
    DMA2_STREAM1 => dma::InterruptHandler<peripherals::DMA2_CH1>;
});

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
}

impl DiscoveryBoard {
    /// Clocks, pins, serial, camera. Call once. A camera that does not answer
    /// is logged and lights the orange LED; the serial link still comes up and
    /// every frame is then answered with `$FLERR,frame_missing`.
    pub fn take() -> DiscoveryBoard {
        let p = embassy_stm32::init(clock_config());
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

        let alarm = AlarmOutputs {
            led: Output::new(p.PD14, Level::Low, Speed::Low),
            line: Output::new(p.PD11, Level::Low, Speed::Low),
        };
        let heartbeat = Output::new(p.PD12, Level::Low, Speed::Low);
        let mut fault_led = Output::new(p.PD13, Level::Low, Speed::Low);

        // XCLK first: the OV7670 answers SCCB only with a running clock.
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

        DiscoveryBoard {
            serial,
            alarm,
            counter: DwtCounter { _private: () },
            frames: CameraRows {
                ring,
                camera_ok,
                line: [0; LINE_WORDS],
                pair_sums: [0; LINE_WORDS],
                rows_left: 0,
                heartbeat,
                fault_led,
            },
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
    for (register, value) in ov7670::window_registers(WINDOW) {
        sccb_write(sccb, register, value)?;
    }
    // Settle: AEC/AGC need a few frames before the image is usable.
    delay_ms(300);
    defmt::info!(
        "OV7670 {=u8:#x}{=u8:x}: YUV422 {=u16}x{=u16}, CLKRC /{=u8}; frames {=u16}x{=u16} (Y, 2x2 binned)",
        pid,
        ver,
        WINDOW.width,
        WINDOW.height,
        ov7670::CLKRC_DIVIDER + 1,
        FRAME.width,
        FRAME.height
    );
    Ok(())
}

/// Camera rows from DCMI: one snapshot per frame through the DMA ring.
pub struct CameraRows {
    ring: ReadableRingBuffer<'static, u32>,
    camera_ok: bool,
    /// The YUV line last taken from the ring.
    line: [u32; LINE_WORDS],
    /// Y0 + Y1 of each pixel pair of the first line of a row pair.
    pair_sums: [u16; LINE_WORDS],
    /// Output rows still to come in this frame.
    rows_left: u16,
    heartbeat: Output<'static>,
    fault_led: Output<'static>,
}

impl CameraRows {
    /// Fills `line` with the next YUV line from the DMA ring.
    fn read_line(&mut self) -> Result<(), RowSourceError> {
        let mut filled = 0;
        let mut last_progress = DWT::cycle_count();
        while filled < LINE_WORDS {
            match self.ring.read(&mut self.line[filled..]) {
                Ok((0, _)) => {
                    let status = pac::DCMI.ris().read();
                    if status.ovr_ris() || status.err_ris() {
                        defmt::error!("DCMI {=str}", if status.ovr_ris() { "overrun" } else { "sync error" });
                        return Err(self.fail(RowSourceError::Read));
                    }
                    if DWT::cycle_count().wrapping_sub(last_progress) > LINE_TIMEOUT_CYCLES {
                        defmt::error!("camera: no line for 0.5 s ({=u16} rows left)", self.rows_left);
                        return Err(self.fail(RowSourceError::Read));
                    }
                }
                Ok((count, _)) => {
                    filled += count;
                    last_progress = DWT::cycle_count();
                }
                Err(_) => {
                    defmt::error!("camera ring overrun: the pipeline fell {=usize} lines behind", CAMERA_RING_LINES);
                    return Err(self.fail(RowSourceError::Read));
                }
            }
        }
        Ok(())
    }

    /// Stops DCMI; the DMA stays armed and idles without requests.
    fn stop_capture(&mut self) {
        pac::DCMI.cr().modify(|w| {
            w.set_capture(false);
            w.set_enable(false);
        });
    }

    fn fail(&mut self, error: RowSourceError) -> RowSourceError {
        self.stop_capture();
        self.rows_left = 0;
        self.fault_led.set_high();
        error
    }
}

impl RowSource for CameraRows {
    /// Arms a snapshot of the next camera frame (DCMI waits for VSYNC).
    /// `index` is the host's frame number; the camera has none.
    fn begin_frame(&mut self, _index: u32) -> Result<FrameSize, RowSourceError> {
        if !self.camera_ok {
            return Err(RowSourceError::Missing);
        }
        self.stop_capture();
        // Reset DCMI so no word of an aborted frame is left in its FIFO,
        // then drop whatever the ring still holds.
        rcc::enable_and_reset::<peripherals::DCMI>();
        self.ring.clear();
        let dcmi = pac::DCMI;
        dcmi.icr().write(|w| {
            w.set_ovr_isc(true);
            w.set_err_isc(true);
            w.set_frame_isc(true);
        });
        dcmi.cr().write(|w| {
            w.set_cm(true); // snapshot: one frame, then CAPTURE clears itself
            w.set_ess(false); // hardware HREF/VSYNC
            w.set_pckpol(true); // sample on the rising PCLK edge (OV7670 changes data on falling)
            w.set_vspol(true); // VSYNC high = blanking
            w.set_hspol(false); // HREF low = blanking
            w.set_fcrc(0);
            w.set_edm(0); // 8 data bits
        });
        dcmi.cr().modify(|w| w.set_enable(true));
        dcmi.cr().modify(|w| w.set_capture(true));
        self.rows_left = FRAME.height;
        Ok(FRAME)
    }

    /// Two camera lines, Y only, 2x2 block means (rounded).
    fn read_row(&mut self, row: &mut [u8]) -> Result<(), RowSourceError> {
        if row.len() != usize::from(FRAME.width) {
            return Err(RowSourceError::RowLength);
        }
        if self.rows_left == 0 {
            return Err(RowSourceError::Read);
        }
        self.read_line()?;
        for (sum, &word) in self.pair_sums.iter_mut().zip(self.line.iter()) {
            *sum = luma_pair(word);
        }
        self.read_line()?;
        for ((out, &sum), &word) in row.iter_mut().zip(self.pair_sums.iter()).zip(self.line.iter()) {
            *out = ((sum + luma_pair(word) + 2) / 4) as u8;
        }
        self.rows_left -= 1;
        if self.rows_left == 0 {
            self.heartbeat.toggle();
        }
        Ok(())
    }

    fn end_frame(&mut self) {
        self.stop_capture();
        self.rows_left = 0;
    }
}

/// Y0 + Y1 of a DMA word: bytes Y0 U Y1 V, first byte lowest (DCMI packs
/// the first byte into bits 7:0).
fn luma_pair(word: u32) -> u16 {
    let shift = 8 * ov7670::Y_OFFSET as u32;
    ((word >> shift) & 0xFF) as u16 + ((word >> (16 + shift)) & 0xFF) as u16
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
    /// The core clock.
    const TICKS_PER_SECOND: u32 = 168_000_000;
    fn now(&self) -> u32 {
        DWT::cycle_count()
    }
}

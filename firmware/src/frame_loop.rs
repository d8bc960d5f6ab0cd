//! The frame loop: the board side of the pipeline. Rig in, remap table and
//! stages built (in statics), then per frame: the sensors' sample in from the
//! serial link (time, and the wheels' pose and IMU attitude when present),
//! camera rows from the row source fed to `flatland_core::pipeline`, one
//! report or fault out, the alarm pin set.
//!
//! It sees the board only through the board layer's traits, so the same loop
//! runs on the emulated and on a real board. The frame's work, odometry gate
//! included, is the pipeline's, which the host's `flatland detect` drives
//! too: the reports are equal field for field. Here:
//! - a frame that cannot be opened or read is skipped with a `$FLERR`, and
//!   one that stops mid-frame is abandoned (counted as aborted); the reports
//!   already sent stand and the loop goes on with the next pose;
//! - a frame whose time goes backwards is skipped without a fault;
//! - with `bench`, each compared frame's stage timing is logged.
//!
//! Fail-safe (`flatland_core::health`): the alarm pin is asserted from the
//! start and released only right after a frame judged clear. A keyframe
//! restart, a frame not judged (sent as `$FLFRM` with its reason in
//! `status`), a skipped or lost frame, a camera that does not deliver a frame
//! within 0.5 s, odometry that stops for 0.5 s while the loop waits, and the
//! end of input all assert it. The loop never blocks on the serial port: it
//! polls, feeds the watchdog and checks the odometry timer while it waits.

use embedded_hal::digital::OutputPin;
use embedded_io::{Read, ReadReady, Write};

use flatland_core::geometry::Rig;
use flatland_core::fusion::GtiStage;
use flatland_core::gpa::{Gpa, GpaConfig, GpaProfile};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::health::{Monitor, SensorFault, CAMERA_TIMEOUT_US};
#[cfg(feature = "full-frame")]
use flatland_core::limits::MAX_GRID_SIDE;
use flatland_core::pipeline::{FrameError, FrameTiming, Outcome, Pipeline, PoseSample};
use flatland_core::protocol::{encode_line, Decoder, Fault, FaultCode, LinkStats, Message, RigRecord};
use flatland_core::remap::{Line, RemapError, RemapTable};
use flatland_core::report::FrameReport;
use static_cell::ConstStaticCell;

use crate::board::{Clock, CycleCounter, RowSource, RowSourceError, Watchdog};

/// Widest camera row supported (VGA); wider rigs are refused at start-up.
pub const MAX_CAMERA_WIDTH: usize = 640;
/// Camera rows the streaming remap may keep: 4 rows of the widest camera
/// (8 of a QVGA one). The bundled rigs need 2; steep tilts and strong
/// distortion need more, and are refused at start-up if they need too many.
pub const RING_CAPACITY: usize = 4 * MAX_CAMERA_WIDTH;
/// Memory of each of GPA's two KG images (`Gpa::image_bytes`: one grid).
/// 40,000 B holds a grid at the default 40,000 px cap: every bundled rig's
/// default grid (256x256 camera: 141x255, 35,955 B; QVGA: 179x220, 39,380 B).
/// One image sits in RAM, the other in the CCM (memory.x).
#[cfg(not(feature = "full-frame"))]
pub const IMAGE_CAPACITY: usize = 40_000;
/// With the `full-frame` feature (the worst-case benchmark, `cargo fw-bench
/// --full-frame`): the 256x256 grid, 65,536 B. It fits only without the GTI
/// stage, which that build leaves out, and takes all of the CCM.
#[cfg(feature = "full-frame")]
pub const IMAGE_CAPACITY: usize = MAX_GRID_SIDE * MAX_GRID_SIDE;

pub(crate) static TABLE: ConstStaticCell<RemapTable> = ConstStaticCell::new(RemapTable::EMPTY);
pub(crate) static RING: ConstStaticCell<[u8; RING_CAPACITY]> = ConstStaticCell::new([0; RING_CAPACITY]);
pub(crate) static DETECTOR: ConstStaticCell<Gpa<'static>> = ConstStaticCell::new(Gpa::EMPTY);
/// The GTI stage (`size_of::<GtiStage>()`, 19.6 KB), configured in place,
/// in the CCM beside the second image (the CPU alone reads it; RAM holds
/// the detector). Not zeroed at reset: see [`ccm_gti`].
#[cfg(not(feature = "full-frame"))]
#[link_section = ".ccm"]
static mut CCM_GTI: core::mem::MaybeUninit<GtiStage> = core::mem::MaybeUninit::uninit();
#[cfg(not(feature = "full-frame"))]
static CCM_GTI_TAKEN: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
pub(crate) static IMAGE: ConstStaticCell<[u8; IMAGE_CAPACITY]> = ConstStaticCell::new([0; IMAGE_CAPACITY]);
/// The second image, in the CCM (not zeroed at reset; see [`ccm_image`]).
#[link_section = ".ccm"]
static mut CCM_IMAGE: core::mem::MaybeUninit<[u8; IMAGE_CAPACITY]> = core::mem::MaybeUninit::uninit();
static CCM_IMAGE_TAKEN: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// The CCM statics are not zeroed at reset (the `.ccm` section is not
/// loaded): each is handed out once, its `taken` flag (in RAM) set, after
/// `init` has written all of it; None on a second call.
///
/// SAFETY: the caller passes its own static's slot and flag, used nowhere else.
unsafe fn take_ccm<T>(slot: *mut core::mem::MaybeUninit<T>, taken: &core::sync::atomic::AtomicBool, init: impl FnOnce(*mut core::mem::MaybeUninit<T>)) -> Option<&'static mut T> {
    if taken.swap(true, core::sync::atomic::Ordering::AcqRel) {
        return None;
    }
    // SAFETY: the flag hands the slot out once, so this is its only
    // reference; `init` writes it whole before it is read.
    unsafe {
        init(slot);
        Some((*slot).assume_init_mut())
    }
}

/// The CCM image, zeroed, once; None on a second call.
pub(crate) fn ccm_image() -> Option<&'static mut [u8; IMAGE_CAPACITY]> {
    // SAFETY: CCM_IMAGE and its flag are used only here; zeroing writes
    // every byte.
    unsafe { take_ccm(&raw mut CCM_IMAGE, &CCM_IMAGE_TAKEN, |image| core::ptr::write_bytes(image, 0, 1)) }
}

/// The CCM's GTI stage, unconfigured, once; None on a second call.
#[cfg(not(feature = "full-frame"))]
fn ccm_gti() -> Option<&'static mut GtiStage> {
    // SAFETY: CCM_GTI and its flag are used only here.
    unsafe { take_ccm(&raw mut CCM_GTI, &CCM_GTI_TAKEN, |gti| _ = (*gti).write(GtiStage::UNCONFIGURED)) }
}

/// Why a rig was refused at start-up. Each is logged and sent as `$FLERR`.
#[derive(Clone, Copy, Debug, PartialEq, defmt::Format)]
pub enum SetupError {
    Rig(flatland_core::geometry::RigError),
    Grid(flatland_core::grid::GridError),
    Table(flatland_core::remap::TableError),
    /// Camera rows wider than [`MAX_CAMERA_WIDTH`].
    CameraTooWide { width: usize },
    /// The remap needs more than [`RING_CAPACITY`] bytes of camera rows.
    RingTooSmall { needed: usize },
    /// A KG image of the grid needs more than [`IMAGE_CAPACITY`] bytes.
    KeyframeTooLarge { needed: usize },
    Detector(flatland_core::gpa::GpaError),
    Gti(flatland_core::gti::GtiError),
}

impl SetupError {
    fn fault_code(self) -> FaultCode {
        match self {
            SetupError::Rig(_) => FaultCode::RigRejected,
            SetupError::Grid(_) | SetupError::Table(_) | SetupError::Detector(_) | SetupError::Gti(_) => {
                FaultCode::TableRejected
            }
            SetupError::CameraTooWide { .. } | SetupError::RingTooSmall { .. } => FaultCode::CameraTooLarge,
            SetupError::KeyframeTooLarge { .. } => FaultCode::GridTooLarge,
        }
    }
}

/// What the loop counts beyond the decoder's own counters.
#[derive(Default)]
pub(crate) struct LoopCounters {
    pub(crate) frames: u32,
    pub(crate) serial_overruns: u32,
    pub(crate) out_of_order: u32,
    pub(crate) frame_gaps: u32,
    pub(crate) aborted: u32,
}

pub(crate) fn bump(counter: &mut u32) {
    *counter = counter.saturating_add(1);
}

/// The board parts the loop needs.
pub struct Board<S, A, C, R, K, W> {
    pub serial: S,
    /// High = alarm; the board hands it over asserted.
    pub alarm: A,
    pub counter: C,
    pub frames: R,
    pub clock: K,
    pub watchdog: W,
}

/// The alarm pin driven from the [`Monitor`]: the pin is written, and the
/// change logged, only when the level changes.
pub(crate) struct AlarmOutput<A> {
    pin: A,
    asserted: bool,
}

impl<A: OutputPin> AlarmOutput<A> {
    /// Asserts the pin (the board should have already).
    pub(crate) fn new(mut pin: A) -> Self {
        let _ = pin.set_high();
        defmt::info!("alarm: on (start)");
        AlarmOutput { pin, asserted: true }
    }

    /// No more frames will be judged.
    pub(crate) fn assert_at_end(&mut self) {
        if !self.asserted {
            self.asserted = true;
            let _ = self.pin.set_high();
            defmt::info!("alarm: on (end of input)");
        }
    }

    /// Follows the monitor; `frame` is the frame that changed it.
    pub(crate) fn follow(&mut self, monitor: &Monitor, frame: u32) {
        let asserted = monitor.alarm();
        if asserted == self.asserted {
            return;
        }
        self.asserted = asserted;
        if asserted {
            let _ = self.pin.set_high();
            defmt::info!("alarm: on (frame {=u32}: {})", frame, monitor.health());
        } else {
            let _ = self.pin.set_low();
            defmt::info!("alarm: off (frame {=u32} clear)", frame);
        }
    }
}

pub struct Options {
    /// Emits benchmark figures as `bench: key: value` log lines.
    pub bench: bool,
    /// Fixed KG resolution (benchmarks); None: chosen from the rig, as the host does.
    pub mm_per_px: Option<f64>,
    /// A grid without margins, the AOI all of it (`GridConfig::without_margins`;
    /// the full-frame benchmark, which sends a square AOI).
    pub no_margins: bool,
    /// Per-stage profile of the detector (`Pipeline::set_clock`), with `bench`.
    pub clock: Option<fn() -> u32>,
}

pub(crate) struct Link<S> {
    pub(crate) serial: S,
    pub(crate) decoder: Decoder,
    pub(crate) counters: LoopCounters,
}

impl<S: Read + ReadReady + Write> Link<S> {
    /// The next well-formed message among the bytes waiting; None once no
    /// byte waits. Malformed input is counted and skipped.
    fn poll(&mut self) -> Option<Message> {
        while self.serial.read_ready().unwrap_or(true) {
            let mut byte = [0u8; 1];
            match self.serial.read(&mut byte) {
                Ok(1) => {}
                Ok(_) => continue,
                Err(_) => {
                    bump(&mut self.counters.serial_overruns);
                    continue;
                }
            }
            match self.decoder.push(byte[0]) {
                Some(Ok(message)) => return Some(message),
                Some(Err(error)) => defmt::warn!("serial: dropped a line ({})", error),
                None => {}
            }
        }
        None
    }

    fn send(&mut self, message: &Message) {
        match encode_line(message) {
            Ok(line) => {
                if self.serial.write_all(line.as_bytes()).is_err() {
                    defmt::warn!("serial: write failed");
                }
            }
            Err(error) => defmt::error!("serial: cannot encode {=str}: {}", message.tag(), error),
        }
    }

    fn fault(&mut self, code: FaultCode, frame: u32) {
        defmt::error!("fault {=str} (frame {=u32})", code.as_str(), frame);
        self.send(&Message::Fault(Fault { code, frame }));
    }

    pub(crate) fn stats(&self) -> LinkStats {
        let mut stats = self.decoder.stats();
        stats.frames = self.counters.frames;
        stats.garbage_bytes = stats.garbage_bytes.saturating_add(self.counters.serial_overruns);
        stats.out_of_order = self.counters.out_of_order;
        stats.frame_gaps = self.counters.frame_gaps;
        stats.aborted = self.counters.aborted;
        stats
    }

    fn out_of_order(&mut self, message: &Message) {
        defmt::warn!("serial: unexpected {=str}", message.tag());
        bump(&mut self.counters.out_of_order);
    }

    /// Sends the counters and returns them: the end of a run.
    fn finish(&mut self) -> LinkStats {
        let stats = self.stats();
        self.send(&Message::Stats(stats));
        stats
    }
}

/// Validates the rig, checks it fits the target's memory, builds the table.
#[inline(never)] // start-up only: its locals stay out of the frame loop's stack
pub(crate) fn set_up(record: &RigRecord, table: &mut RemapTable, options: &Options) -> Result<(Rig, KgGrid), SetupError> {
    let rig = Rig::try_from(record).map_err(SetupError::Rig)?;
    if usize::from(record.width) > MAX_CAMERA_WIDTH {
        return Err(SetupError::CameraTooWide { width: usize::from(record.width) });
    }
    let grid_config = if options.no_margins {
        GridConfig::without_margins(options.mm_per_px)
    } else {
        GridConfig { mm_per_px: options.mm_per_px, ..GridConfig::default() }
    };
    let grid = KgGrid::for_rig(&rig, &grid_config).map_err(SetupError::Grid)?;
    let needed = Gpa::image_bytes(&grid);
    if needed > IMAGE_CAPACITY {
        return Err(SetupError::KeyframeTooLarge { needed });
    }
    table.build(&rig, &grid).map_err(SetupError::Table)?;
    if table.ring_bytes() > RING_CAPACITY {
        return Err(SetupError::RingTooSmall { needed: table.ring_bytes() });
    }
    Ok((rig, grid))
}

/// Cycles between two polls of an idle serial port: 100 us at 168 MHz.
const IDLE_POLL_CYCLES: u32 = 16_800;

/// A serial protocol as the waiting loop sees it: what has arrived, and
/// what to tell the robot while nothing does.
pub(crate) trait Inbox {
    type Item;
    /// The next complete input among the bytes waiting; None once no byte waits.
    fn poll(&mut self) -> Option<Self::Item>;
    /// Odometry stopped after `frame`: report it (the alarm is already asserted).
    fn odometry_lost(&mut self, frame: u32);
    /// Called on every idle poll with the monitor's state (status outputs).
    fn idle(&mut self, _monitor: &Monitor, _now_us: u32) {}
}

impl<S: Read + ReadReady + Write> Inbox for Link<S> {
    type Item = Message;

    fn poll(&mut self) -> Option<Message> {
        Link::poll(self)
    }

    fn odometry_lost(&mut self, frame: u32) {
        self.fault(FaultCode::OdometryLost, frame);
    }
}

/// What the loop does while it waits: feeds the watchdog, watches the
/// odometry's timer and drives the alarm.
pub(crate) struct Guard<'a, A, K, W> {
    pub(crate) alarm: &'a mut AlarmOutput<A>,
    pub(crate) monitor: &'a mut Monitor,
    pub(crate) clock: &'a K,
    pub(crate) watchdog: &'a mut W,
    /// The last frame whose odometry came (0 before any).
    pub(crate) last_frame: u32,
}

impl<A: OutputPin, K: Clock, W: Watchdog> Guard<'_, A, K, W> {
    /// Waits for the next input. A newly stopped odometry stream asserts
    /// the alarm and is reported (line protocol: `$FLERR,odometry_lost`).
    pub(crate) fn receive<I: Inbox>(&mut self, inbox: &mut I) -> I::Item {
        loop {
            self.watchdog.feed();
            if let Some(item) = inbox.poll() {
                return item;
            }
            // Nothing waits: pause before polling again. Under QEMU a tight
            // loop of register reads (each takes the emulator's global lock)
            // held back the thread that feeds USART1 from the socket: three
            // parity runs saw `$FLODO` lines already sent come > 0.5 s late
            // (a false `odometry_lost`); with the pause they pass. On the
            // board received bytes wait in RAM (interrupt-driven).
            cortex_m::asm::delay(IDLE_POLL_CYCLES);
            let now = self.clock.now_us();
            if let Some(fault) = self.monitor.poll(now) {
                self.alarm.follow(self.monitor, self.last_frame);
                defmt::warn!("{=str}: no odometry after frame {=u32} for 0.5 s", fault.as_str(), self.last_frame);
                inbox.odometry_lost(self.last_frame);
            }
            inbox.idle(self.monitor, now);
        }
    }
}

/// Waits for a rig that fits, builds the remap table, and announces it.
/// None when the input ends first.
#[inline(never)] // start-up only: its locals stay out of the frame loop's stack
fn configure<S: Read + ReadReady + Write, C: CycleCounter, A: OutputPin, K: Clock, W: Watchdog>(
    link: &mut Link<S>,
    guard: &mut Guard<A, K, W>,
    counter: &C,
    table: &mut RemapTable,
    options: &Options,
) -> Option<(Rig, KgGrid)> {
    loop {
        let record = match guard.receive(link) {
            Message::Rig(record) => record,
            Message::End => return None,
            other => {
                link.out_of_order(&other);
                continue;
            }
        };
        let started = counter.now();
        guard.watchdog.feed();
        let (rig, grid) = match set_up(&record, table, options) {
            Ok(built) => built,
            Err(error) => {
                defmt::error!("rig refused: {}", error);
                link.fault(error.fault_code(), 0);
                continue;
            }
        };
        let build_instructions = counter.now().wrapping_sub(started);
        defmt::info!(
            "rig accepted: camera {=u16}x{=u16}, KG grid {=usize}x{=usize}, table {=usize} B, ring {=usize} of {=usize} B, keyframe {=usize} of {=usize} B",
            record.width,
            record.height,
            grid.width(),
            grid.height(),
            RemapTable::size_bytes(),
            table.ring_bytes(),
            RING_CAPACITY,
            Gpa::keyframe_bytes(&grid),
            2 * IMAGE_CAPACITY
        );
        if options.bench {
            defmt::println!("bench: table_build: {=u32}", build_instructions);
            defmt::println!("bench: grid: {=usize}x{=usize}", grid.width(), grid.height());
        }
        link.send(&Message::Hello(record));
        return Some((rig, grid));
    }
}

/// Why a frame was given up.
pub(crate) struct FrameFailure {
    pub(crate) code: FaultCode,
    /// The frame was open and sized: it is abandoned mid-way.
    pub(crate) mid_frame: bool,
}

impl FrameFailure {
    pub(crate) fn sensor_fault(&self) -> SensorFault {
        match self.code {
            FaultCode::CameraTimeout => SensorFault::CameraTimeout,
            _ => SensorFault::FrameLost,
        }
    }
}

/// The parts of the board [`stream_frame`] uses.
pub(crate) struct Camera<'a, R, C, K, W> {
    pub(crate) frames: &'a mut R,
    pub(crate) counter: &'a C,
    pub(crate) clock: &'a K,
    pub(crate) watchdog: &'a mut W,
}

/// The fault a pipeline error is sent as.
fn fault_code(error: FrameError) -> FaultCode {
    match error {
        FrameError::Remap(RemapError::RowLength { .. }) => FaultCode::FrameFormat,
        _ => FaultCode::RemapFailed,
    }
}

fn row_fault(error: RowSourceError) -> FaultCode {
    match error {
        RowSourceError::Missing => FaultCode::FrameMissing,
        RowSourceError::Format | RowSourceError::RowLength => FaultCode::FrameFormat,
        RowSourceError::Read => FaultCode::FrameRead,
        RowSourceError::Timeout => FaultCode::CameraTimeout,
    }
}

/// Streams frame `index` from the row source through the pipeline and
/// finishes it; `read` accumulates the ticks spent reading rows (the
/// pipeline times its own stages). A frame whose last row has not come
/// [`CAMERA_TIMEOUT_US`] after it was asked for is given up as
/// `camera_timeout`. On failure the caller gives the frame up.
pub(crate) fn stream_frame<R: RowSource, C: CycleCounter, K: Clock, W: Watchdog>(
    camera_parts: Camera<R, C, K, W>,
    pipeline: &mut Pipeline,
    index: u32,
    camera: (usize, usize),
    read: &mut u32,
) -> Result<Outcome, FrameFailure> {
    let Camera { frames, counter, clock, watchdog } = camera_parts;
    let asked = clock.now_us();
    let early = |code| FrameFailure { code, mid_frame: false };
    let size = frames.begin_frame(index).map_err(|error| early(row_fault(error)))?;
    let (width, height) = (usize::from(size.width), usize::from(size.height));
    // The host skips a frame whose size is not the rig's; so do we, before the detector sees it.
    if (width, height) != camera {
        return Err(early(FaultCode::FrameFormat));
    }
    stream_rows(Camera { frames: &mut *frames, counter, clock, watchdog: &mut *watchdog }, pipeline, camera, asked, read)?;
    frames.end_frame();
    watchdog.feed();
    let outcome = pipeline.finish().map_err(|error| FrameFailure { code: fault_code(error), mid_frame: true });
    watchdog.feed();
    outcome
}

/// [`stream_frame`]'s rows, `camera` = (width, height), asked for at `asked` (µs).
// Not inlined: the row and the remap's line (2.7 KB) would sit in the frame
// loop's frame, under the detector's deepest stack.
#[inline(never)]
fn stream_rows<R: RowSource, C: CycleCounter, K: Clock, W: Watchdog>(
    camera_parts: Camera<R, C, K, W>,
    pipeline: &mut Pipeline,
    (width, height): (usize, usize),
    asked: u32,
    read: &mut u32,
) -> Result<(), FrameFailure> {
    let Camera { frames, counter, clock, watchdog } = camera_parts;
    let mut row_buffer = [0u8; MAX_CAMERA_WIDTH];
    let mut line = Line::ZERO;
    let row = row_buffer.get_mut(..width).ok_or(FrameFailure { code: FaultCode::FrameFormat, mid_frame: false })?;
    let mid = |code| FrameFailure { code, mid_frame: true };
    for _ in 0..height {
        watchdog.feed();
        let start = counter.now();
        frames.read_row(row).map_err(|error| {
            mid(if error == RowSourceError::Timeout { FaultCode::CameraTimeout } else { FaultCode::FrameRead })
        })?;
        *read = read.wrapping_add(counter.now().wrapping_sub(start));
        if clock.now_us().wrapping_sub(asked) > CAMERA_TIMEOUT_US {
            return Err(mid(FaultCode::CameraTimeout));
        }
        pipeline.push_row(row, &mut line).map_err(|error| mid(fault_code(error)))?;
    }
    Ok(())
}

/// `cycle`: odometry received to report sent, the board's whole cycle
/// (the pipeline's own `timing.cycle` leaves out the serial side).
fn log_bench(frame: u32, read: u32, cycle: u32, timing: &FrameTiming, profile: &GpaProfile) {
    defmt::println!("bench: frame: {=u32}", frame);
    defmt::println!("bench: read_rows: {=u32}", read);
    defmt::println!("bench: remap: {=u32}", timing.remap);
    defmt::println!("bench: detector_rows: {=u32}", timing.detector_rows);
    defmt::println!("bench: gpa_warp: {=u32}", profile.warp);
    defmt::println!("bench: gpa_residue: {=u32}", profile.residue);
    defmt::println!("bench: gpa_parallax: {=u32}", profile.parallax);
    defmt::println!("bench: gpa_shift_search: {=u32}", profile.shift_search);
    defmt::println!("bench: gpa_keyframe_update: {=u32}", profile.keyframe_update);
    defmt::println!("bench: gpa_estimate: {=u32}", profile.estimate);
    defmt::println!("bench: gpa_estimate_coarse: {=u32}", profile.estimate_coarse);
    defmt::println!("bench: gpa_estimate_align: {=u32}", profile.estimate_align);
    defmt::println!("bench: gpa_estimate_pyramids: {=u32}", profile.estimate_pyramids);
    defmt::println!("bench: gpa_estimate_nearest_surface: {=u32}", profile.estimate_nearest_surface);
    defmt::println!("bench: gpa_estimate_lower_level: {=u32}", profile.estimate_lower_level);
    defmt::println!("bench: gpa_seed_search: {=u32}", profile.seed_search);
    defmt::println!("bench: decision: {=u32}", timing.decision);
    // The full-frame build has no GTI stage to measure.
    #[cfg(not(feature = "full-frame"))]
    {
        defmt::println!("bench: gti_rows: {=u32}", timing.gti_rows);
        defmt::println!("bench: gti_frame: {=u32}", timing.gti_frame);
        defmt::println!("bench: gti: {=u32}", timing.gti_rows.wrapping_add(timing.gti_frame));
    }
    defmt::println!("bench: instructions_per_cycle: {=u32}", cycle);
}

pub(crate) fn log_report(report: &FrameReport) {
    if let Err(reason) = report.status.judged() {
        defmt::warn!("frame {=u32} not judged ({=str}): alarm; new keyframe", report.frame, reason.as_str());
    } else if report.alarm {
        // Human-readable alarm line; absent distances print as -1, and a
        // drop's height is negative (its depth, -20 mm or lower).
        defmt::warn!(
            "ALARM frame {=u32} (vs {=u32}): obstacle at {=i32} mm, x {=i32}..{=i32} mm, height {=i32} mm",
            report.frame,
            report.ref_frame,
            report.nearest_mm.unwrap_or(-1),
            report.left_mm.unwrap_or(-1),
            report.right_mm.unwrap_or(-1),
            report.obstacle_h_mm.unwrap_or(-1)
        );
    } else {
        defmt::info!(
            "frame {=u32} (vs {=u32}): clear, shift {=i32},{=i32} /100 px",
            report.frame,
            report.ref_frame,
            report.shift_k,
            report.shift_g
        );
    }
}

/// Runs until the host sends `$FLEND`; returns the final counters. The
/// alarm pin is left asserted, and kept (not dropped, which on a real board
/// would float it): nothing is judged any more.
pub fn run<S, A, C, R, K, W>(board: Board<S, A, C, R, K, W>, options: &Options) -> LinkStats
where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    let Board { serial, alarm, counter, mut frames, clock, mut watchdog } = board;
    let mut link = Link { serial, decoder: Decoder::new(), counters: LoopCounters::default() };
    let mut alarm = AlarmOutput::new(alarm);
    let mut monitor = Monitor::new();
    let guard = Guard { alarm: &mut alarm, monitor: &mut monitor, clock: &clock, watchdog: &mut watchdog, last_frame: 0 };
    let stats = serve_frames(&mut link, guard, &counter, &mut frames, options);
    alarm.assert_at_end();
    core::mem::forget(alarm);
    stats
}

fn serve_frames<S, A, C, R, K, W>(
    link: &mut Link<S>,
    mut guard: Guard<A, K, W>,
    counter: &C,
    frames: &mut R,
    options: &Options,
) -> LinkStats
where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    let table: &'static mut RemapTable = TABLE.take();
    let ring: &'static mut [u8; RING_CAPACITY] = RING.take();
    let image: &'static mut [u8; IMAGE_CAPACITY] = IMAGE.take();
    let Some(ccm_image) = ccm_image() else { return link.finish() };
    let gpa: &'static mut Gpa<'static> = DETECTOR.take();

    // Bytes that arrive before the USART is enabled are lost: say when we listen.
    link.send(&Message::Ready);
    let Some((rig, grid)) = configure(link, &mut guard, counter, table, options) else {
        defmt::warn!("no rig before the end of input");
        return link.finish();
    };
    let table: &RemapTable = table;
    let camera = (table.camera_width(), table.camera_height());
    guard.watchdog.feed();
    // The detector lives in a static, initialised in place: by value LLVM
    // keeps stack temporaries of it, and it is kilobytes.
    if let Err(error) = gpa.init_split(&rig, &grid, table, GpaConfig::default(), &mut image[..], &mut ccm_image[..]) {
        defmt::error!("detector refused: {}", error);
        link.fault(SetupError::Detector(error).fault_code(), 0);
        return link.finish();
    }
    let Some(gti) = gti_stage(link, &rig, &grid) else { return link.finish() };
    // `set_up` checked the ring size, so this only fails on a core change;
    // still a typed fault, not a panic.
    let mut pipeline = match Pipeline::new(table, &mut ring[..], gpa, gti) {
        Ok(pipeline) => pipeline,
        Err(error) => {
            defmt::error!("pipeline refused: {}", error);
            link.fault(FaultCode::CameraTooLarge, 0);
            return link.finish();
        }
    };
    pipeline.set_clock(if options.bench { options.clock } else { None });

    let mut started = false;
    loop {
        let odometry = match guard.receive(link) {
            Message::Odometry(odometry) => odometry,
            Message::End => break,
            other => {
                link.out_of_order(&other);
                continue;
            }
        };
        let cycle_start = counter.now();
        let frame = odometry.frame;
        guard.monitor.odometry(guard.clock.now_us());
        guard.last_frame = frame;
        serve_frame(link, &mut guard, counter, frames, &mut pipeline, odometry, camera, &mut started, options, cycle_start);
        // The odometry timer counts from here: the frame's own time is not the robot's silence.
        guard.monitor.waiting(guard.clock.now_us());
    }
    link.finish()
}

/// One `$FLODO`'s frame, from the pose gate to the report and the alarm.
#[allow(clippy::too_many_arguments)]
fn serve_frame<S, A, C, R, K, W>(
    link: &mut Link<S>,
    guard: &mut Guard<A, K, W>,
    counter: &C,
    frames: &mut R,
    pipeline: &mut Pipeline,
    odometry: flatland_core::protocol::Odometry,
    camera: (usize, usize),
    started: &mut bool,
    options: &Options,
    cycle_start: u32,
) where
    S: Read + ReadReady + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    let frame = odometry.frame;
    let follows = pipeline.follows(frame);
    if let Err(error) = pipeline.begin(frame, PoseSample::from(odometry)) {
        // The pose cannot be trusted: the frame is skipped and the next one restarts.
        defmt::warn!("frame {=u32} skipped: {}", frame, error);
        guard.monitor.unjudged();
        guard.alarm.follow(guard.monitor, frame);
        return;
    }
    if !follows && *started {
        defmt::warn!("frame {=u32}: the frame before was not processed; keyframe restarts", frame);
        bump(&mut link.counters.frame_gaps);
    }
    *started = true;

    let mut read = 0;
    let parts = Camera { frames: &mut *frames, counter, clock: guard.clock, watchdog: &mut *guard.watchdog };
    match stream_frame(parts, pipeline, frame, camera, &mut read) {
        Ok(Outcome::Compared(report)) => {
            // The pin first: it is what the robot acts on.
            guard.monitor.judged(report.alarm);
            guard.alarm.follow(guard.monitor, frame);
            link.send(&Message::Frame(report));
            log_report(&report);
            let cycle = counter.now().wrapping_sub(cycle_start);
            // Benchmark figures are for detection cycles (frames compared with a keyframe).
            if options.bench {
                log_bench(frame, read, cycle, &pipeline.timing(), &pipeline.gpa().profile());
            }
        }
        Ok(Outcome::NotJudged(report)) => {
            // Not judged: nothing is known about the path; the pin first,
            // then the report that says why.
            guard.monitor.unjudged();
            guard.alarm.follow(guard.monitor, frame);
            link.send(&Message::Frame(report));
            log_report(&report);
        }
        Ok(Outcome::Keyframe { .. }) => {
            // The run's first frame: nothing to compare, nothing is known about the path.
            guard.monitor.unjudged();
            guard.alarm.follow(guard.monitor, frame);
            defmt::info!("frame {=u32}: new keyframe, nothing to compare", frame);
        }
        Err(failure) => {
            frames.end_frame();
            pipeline.abort();
            if failure.mid_frame {
                bump(&mut link.counters.aborted);
            }
            guard.monitor.frame_failed(failure.sensor_fault());
            guard.alarm.follow(guard.monitor, frame);
            link.fault(failure.code, frame);
            return;
        }
    }
    bump(&mut link.counters.frames);
}

/// GTI (19.6 KB) is configured in place in its static, as the detector.
/// None on a refused rig (the fault is sent), or when called twice.
#[cfg(not(feature = "full-frame"))]
pub(crate) fn gti_stage<S: Read + ReadReady + Write>(link: &mut Link<S>, rig: &Rig, grid: &KgGrid) -> Option<Option<&'static mut GtiStage>> {
    let gti: &'static mut GtiStage = ccm_gti()?;
    match gti.configure(rig, grid) {
        Ok(()) => Some(Some(gti)),
        Err(error) => {
            defmt::error!("GTI refused: {}", error);
            link.fault(SetupError::Gti(error).fault_code(), 0);
            None
        }
    }
}

/// The `full-frame` build has no GTI stage: its keyframe needs the RAM.
#[cfg(feature = "full-frame")]
pub(crate) fn gti_stage<S>(_: &mut Link<S>, _: &Rig, _: &KgGrid) -> Option<Option<&'static mut GtiStage>> {
    Some(None)
}

//! The frame loop: the board side of the pipeline. Rig in, remap table and
//! stages built (in statics), then per frame: the sensors' sample in from the
//! serial link (time, and the wheels' pose and IMU attitude when present),
//! camera rows from the row source fed to `flatland_core::pipeline`, one
//! report or fault out, the alarm pin set.
//!
//! It sees the board only through the board layer's traits and the serial
//! link only through a [`Protocol`] (the line protocol, or MAVLink in the
//! `mavlink` build): one loop runs on the emulated and on a real board, and
//! counts gaps, faults and benchmarks the same way for both protocols. The
//! frame's work, odometry gate included, is the pipeline's, which the
//! host's `flatland detect` drives too: the reports are equal field for
//! field. Here:
//! - a frame that cannot be opened or read is skipped with a fault, and
//!   one that stops mid-frame is abandoned (counted as aborted); the reports
//!   already sent stand and the loop goes on with the next pose;
//! - a frame whose time goes backwards is skipped without a fault;
//! - with `bench`, each compared frame's stage timing is logged.
//!
//! Fail-safe (`flatland_core::health::FailSafe`, tested on the host with a
//! mock pin): the alarm pin is asserted from the start and released only
//! right after a frame judged clear. A keyframe restart, a frame not judged
//! (reported with its reason), a skipped or lost frame, a camera that does
//! not deliver a frame within 0.5 s, odometry that stops for 0.5 s while
//! the loop waits, and the end of input all assert it. The loop never
//! blocks on the serial port: it polls, feeds the watchdog and checks the
//! odometry timer while it waits.

use embedded_hal::digital::OutputPin;

use flatland_core::fusion::GtiStage;
use flatland_core::geometry::Rig;
use flatland_core::gpa::{Gpa, GpaConfig, GpaProfile};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::health::{FailSafe, SensorFault, CAMERA_TIMEOUT_US};
#[cfg(feature = "full-frame")]
use flatland_core::limits::MAX_GRID_SIDE;
use flatland_core::limits::MAX_RING_BYTES;
use flatland_core::pipeline::{FrameError, FrameTiming, Outcome, Pipeline, PoseSample};
use flatland_core::protocol::{FaultCode, LinkStats, LoopStats, RigRecord};
use flatland_core::remap::{Line, RemapError, RemapTable};
use static_cell::ConstStaticCell;

use crate::board::{Clock, CycleCounter, RowSource, RowSourceError, Watchdog};
use crate::protocol::{Input, Protocol};

/// Widest camera row supported (VGA); wider rigs are refused at start-up.
pub const MAX_CAMERA_WIDTH: usize = 640;
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

static TABLE: ConstStaticCell<RemapTable> = ConstStaticCell::new(RemapTable::EMPTY);
static DETECTOR: ConstStaticCell<Gpa<'static>> = ConstStaticCell::new(Gpa::EMPTY);
/// The GTI stage (`size_of::<GtiStage>()`, 20.6 KB), configured in place,
/// in the CCM beside the second image (the CPU alone reads it; RAM holds
/// the detector). Not zeroed at reset: see [`ccm_gti`].
#[cfg(not(feature = "full-frame"))]
#[link_section = ".ccm"]
static mut CCM_GTI: core::mem::MaybeUninit<GtiStage> = core::mem::MaybeUninit::uninit();
#[cfg(not(feature = "full-frame"))]
static CCM_GTI_TAKEN: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);
static IMAGE: ConstStaticCell<[u8; IMAGE_CAPACITY]> = ConstStaticCell::new([0; IMAGE_CAPACITY]);
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
fn ccm_image() -> Option<&'static mut [u8; IMAGE_CAPACITY]> {
    // SAFETY: CCM_IMAGE and its flag are used only here; zeroing writes
    // every byte.
    unsafe { take_ccm(&raw mut CCM_IMAGE, &CCM_IMAGE_TAKEN, |image| core::ptr::write_bytes(image, 0, 1)) }
}

/// The build's GTI stage: the CCM's, unconfigured, once; None on a
/// second call.
#[cfg(not(feature = "full-frame"))]
fn ccm_gti() -> Option<Option<&'static mut GtiStage>> {
    // SAFETY: CCM_GTI and its flag are used only here.
    unsafe { take_ccm(&raw mut CCM_GTI, &CCM_GTI_TAKEN, |gti| _ = (*gti).write(GtiStage::UNCONFIGURED)) }.map(Some)
}

/// The `full-frame` build has no GTI stage (`Some(None)`): its keyframe
/// needs the RAM.
#[cfg(feature = "full-frame")]
fn ccm_gti() -> Option<Option<&'static mut GtiStage>> {
    Some(None)
}

/// The stages' memory, all statics, handed out once.
struct Memory {
    table: &'static mut RemapTable,
    image: &'static mut [u8; IMAGE_CAPACITY],
    ccm_image: &'static mut [u8; IMAGE_CAPACITY],
    gpa: &'static mut Gpa<'static>,
    /// None in the `full-frame` build.
    gti: Option<&'static mut GtiStage>,
}

impl Memory {
    /// None on a second call.
    fn take() -> Option<Memory> {
        Some(Memory {
            table: TABLE.try_take()?,
            image: IMAGE.try_take()?,
            ccm_image: ccm_image()?,
            gpa: DETECTOR.try_take()?,
            gti: ccm_gti()?,
        })
    }

    /// The detector (initialised in place in its static: by value LLVM
    /// keeps stack temporaries of it, and it is kilobytes), GTI (20.6 KB,
    /// configured in place too) and the pipeline over them, for the rig the
    /// table was built for.
    fn into_pipeline(self, rig: &Rig, grid: &KgGrid) -> Result<Pipeline<'static, 'static, 'static>, SetupError> {
        let Memory { table, image, ccm_image, gpa, gti } = self;
        gpa.init_split(rig, grid, table, GpaConfig::default(), &mut image[..], &mut ccm_image[..]).map_err(SetupError::Detector)?;
        let gti = match gti {
            Some(gti) => {
                gti.configure(rig, grid).map_err(SetupError::Gti)?;
                Some(gti)
            }
            None => None,
        };
        // `set_up` checked the ring size, so this only fails on a core
        // change; still a typed error, not a panic.
        Pipeline::new(table, gpa, gti).map_err(SetupError::Pipeline)
    }
}

/// Why a rig, or the stages for it, were refused at start-up. Each is
/// logged and reported (`$FLERR`, or a MAVLink `STATUSTEXT`).
#[derive(Clone, Copy, Debug, PartialEq, defmt::Format)]
pub enum SetupError {
    Rig(flatland_core::geometry::RigError),
    Grid(flatland_core::grid::GridError),
    Table(flatland_core::remap::TableError),
    /// Camera rows wider than [`MAX_CAMERA_WIDTH`].
    CameraTooWide { width: usize },
    /// The remap needs more than [`MAX_RING_BYTES`] of camera rows.
    RingTooSmall { needed: usize },
    /// A KG image of the grid needs more than [`IMAGE_CAPACITY`] bytes.
    KeyframeTooLarge { needed: usize },
    Detector(flatland_core::gpa::GpaError),
    Gti(flatland_core::gti::GtiError),
    /// The streaming remap refused its ring.
    Pipeline(RemapError),
}

impl SetupError {
    /// The line protocol's code for it.
    pub fn fault_code(self) -> FaultCode {
        match self {
            SetupError::Rig(_) => FaultCode::RigRejected,
            SetupError::Grid(_) | SetupError::Table(_) | SetupError::Detector(_) | SetupError::Gti(_) => {
                FaultCode::TableRejected
            }
            SetupError::CameraTooWide { .. } | SetupError::RingTooSmall { .. } | SetupError::Pipeline(_) => {
                FaultCode::CameraTooLarge
            }
            SetupError::KeyframeTooLarge { .. } => FaultCode::GridTooLarge,
        }
    }
}

impl core::fmt::Display for SetupError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SetupError::Rig(error) => write!(f, "rig refused: {error}"),
            SetupError::Grid(error) => write!(f, "KG grid refused: {error}"),
            SetupError::Table(error) => write!(f, "remap table refused: {error}"),
            SetupError::CameraTooWide { width } => write!(f, "camera {width} px wide, at most {MAX_CAMERA_WIDTH}"),
            SetupError::RingTooSmall { needed } => write!(f, "camera rows need {needed} B, at most {MAX_RING_BYTES}"),
            SetupError::KeyframeTooLarge { needed } => write!(f, "KG image needs {needed} B, at most {IMAGE_CAPACITY}"),
            SetupError::Detector(error) => write!(f, "detector refused: {error}"),
            SetupError::Gti(error) => write!(f, "GTI refused: {error}"),
            SetupError::Pipeline(error) => write!(f, "pipeline refused: {error}"),
        }
    }
}

impl core::error::Error for SetupError {}

fn bump(counter: &mut u32) {
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

/// Validates the rig, checks it fits the target's memory, builds the table.
#[inline(never)] // start-up only: its locals stay out of the frame loop's stack
fn set_up(record: &RigRecord, table: &mut RemapTable, options: &Options) -> Result<(Rig, KgGrid), SetupError> {
    let rig = Rig::try_from(record).map_err(SetupError::Rig)?;
    if usize::from(record.camera.width) > MAX_CAMERA_WIDTH {
        return Err(SetupError::CameraTooWide { width: usize::from(record.camera.width) });
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
    if table.ring_bytes() > MAX_RING_BYTES {
        return Err(SetupError::RingTooSmall { needed: table.ring_bytes() });
    }
    Ok((rig, grid))
}

/// Why a frame was given up.
struct FrameFailure {
    code: FaultCode,
    /// The frame was open and sized: it is abandoned mid-way.
    mid_frame: bool,
}

impl FrameFailure {
    fn sensor_fault(&self) -> SensorFault {
        match self.code {
            FaultCode::CameraTimeout => SensorFault::CameraTimeout,
            _ => SensorFault::FrameLost,
        }
    }
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

/// Microseconds between two polls of an idle serial port.
const IDLE_POLL_US: u32 = 100;

/// The loop's context: the protocol, the fail-safe and the board's parts,
/// and what the loop counts. [`FrameLoop::run`] runs it.
pub struct FrameLoop<'o, P, A, C, R, K, W> {
    protocol: P,
    fail_safe: FailSafe<A>,
    counter: C,
    frames: R,
    clock: K,
    watchdog: W,
    stats: LoopStats,
    options: &'o Options,
}

/// What the loop keeps from frame to frame once the stages are built.
struct Session {
    pipeline: Pipeline<'static, 'static, 'static>,
    /// The rig's camera, (width, height).
    camera: (usize, usize),
    /// A frame was begun: a later one that does not follow it is a gap.
    started: bool,
    /// Poses taken: the next frame's number when the protocol does not number frames.
    poses: u32,
}

impl<'o, P, A, C, R, K, W> FrameLoop<'o, P, A, C, R, K, W>
where
    P: Protocol,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
    K: Clock,
    W: Watchdog,
{
    /// Runs until the host sends its end of input, speaking protocol `P`;
    /// returns the final counters (also sent). The alarm pin is left
    /// asserted, and kept (not dropped, which on a real board would float
    /// it): nothing is judged any more.
    pub fn run(board: Board<P::Serial, A, C, R, K, W>, options: &'o Options) -> LinkStats {
        let Board { serial, alarm, counter, frames, clock, watchdog } = board;
        let fail_safe = FailSafe::new(alarm);
        let mut frame_loop =
            FrameLoop { protocol: P::new(serial), fail_safe, counter, frames, clock, watchdog, stats: LoopStats::default(), options };
        frame_loop.serve();
        let stats = LinkStats { decoder: frame_loop.protocol.input_stats(), frame_loop: frame_loop.stats };
        frame_loop.protocol.finish(&stats);
        core::mem::forget(frame_loop.fail_safe.end_of_input());
        stats
    }

    /// The rig, the stages, then frames until the end of input.
    fn serve(&mut self) {
        let Some(memory) = Memory::take() else { return };
        // Bytes that arrive before the USART is enabled are lost: say when we listen.
        self.protocol.listening(self.clock.now_us());
        let Some((rig, grid)) = self.configure(&mut *memory.table) else {
            defmt::warn!("no rig before the end of input");
            return;
        };
        let camera = (memory.table.camera_width(), memory.table.camera_height());
        self.watchdog.feed();
        let mut pipeline = match memory.into_pipeline(&rig, &grid) {
            Ok(pipeline) => pipeline,
            Err(error) => return self.setup_failed(&error),
        };
        pipeline.set_clock(if self.options.bench { self.options.clock } else { None });
        let mut session = Session { pipeline, camera, started: false, poses: 0 };
        loop {
            let (frame, sample) = match self.receive() {
                Input::Pose { frame, sample } => (frame.unwrap_or(session.poses), sample),
                Input::End => break,
                other => {
                    self.out_of_order(&other);
                    continue;
                }
            };
            session.poses = session.poses.wrapping_add(1);
            let cycle_start = self.counter.now();
            self.fail_safe.pose(frame, self.clock.now_us());
            match sample {
                Ok(sample) => self.serve_frame(&mut session, frame, sample, cycle_start),
                Err(error) => {
                    // No usable pose: the frame is not taken and the next restarts.
                    defmt::warn!("frame {=u32} skipped: its pose was refused", frame);
                    self.protocol.pose_refused(frame, &error);
                    session.pipeline.restart();
                    self.fail_safe.frame_skipped(frame);
                }
            }
            // The odometry timer counts from here: the frame's own time is not the robot's silence.
            let now = self.clock.now_us();
            self.fail_safe.waiting(now);
            self.protocol.idle(self.fail_safe.health(), now);
        }
    }

    /// Waits for the next input: feeds the watchdog, and a newly stopped
    /// odometry stream asserts the alarm and is reported.
    fn receive(&mut self) -> Input<P::PoseError> {
        loop {
            self.watchdog.feed();
            if let Some(input) = self.protocol.poll() {
                return input;
            }
            // Nothing waits: pause before polling again. Under QEMU a tight
            // loop of register reads (each takes the emulator's global lock)
            // held back the thread that feeds USART1 from the socket: three
            // parity runs saw `$FLODO` lines already sent come > 0.5 s late
            // (a false `odometry_lost`); with the pause they pass. On the
            // board received bytes wait in RAM (interrupt-driven).
            self.clock.delay_us(IDLE_POLL_US);
            let now = self.clock.now_us();
            if let Some(fault) = self.fail_safe.poll(now) {
                let frame = self.fail_safe.last_frame();
                defmt::warn!("{=str}: no odometry after frame {=u32} for 0.5 s", fault.as_str(), frame);
                self.protocol.odometry_lost(frame);
            }
            self.protocol.idle(self.fail_safe.health(), now);
        }
    }

    fn out_of_order(&mut self, input: &Input<P::PoseError>) {
        defmt::warn!("serial: unexpected {=str}", input.name());
        bump(&mut self.stats.out_of_order);
    }

    fn setup_failed(&mut self, error: &SetupError) {
        defmt::error!("set-up refused: {}", error);
        self.protocol.setup_failed(error);
    }

    /// Waits for a rig that fits, builds the remap table, and announces it.
    /// None when the input ends first.
    #[inline(never)] // start-up only: its locals stay out of the frame loop's stack
    fn configure(&mut self, table: &mut RemapTable) -> Option<(Rig, KgGrid)> {
        loop {
            let record = match self.receive() {
                Input::Rig(record) => record,
                Input::End => return None,
                Input::Pose { .. } if P::POSES_STREAM => continue,
                other => {
                    self.out_of_order(&other);
                    continue;
                }
            };
            let started = self.counter.now();
            self.watchdog.feed();
            let (rig, grid) = match set_up(&record, table, self.options) {
                Ok(built) => built,
                Err(error) => {
                    self.setup_failed(&error);
                    continue;
                }
            };
            let build_instructions = self.counter.now().wrapping_sub(started);
            defmt::info!(
                "rig accepted: camera {=u16}x{=u16}, KG grid {=usize}x{=usize}, table {=usize} B, ring {=usize} of {=usize} B, keyframe {=usize} of {=usize} B",
                record.camera.width,
                record.camera.height,
                grid.width(),
                grid.height(),
                RemapTable::size_bytes(),
                table.ring_bytes(),
                MAX_RING_BYTES,
                Gpa::keyframe_bytes(&grid),
                2 * IMAGE_CAPACITY
            );
            if self.options.bench {
                defmt::println!("bench: table_build: {=u32}", build_instructions);
                defmt::println!("bench: grid: {=usize}x{=usize}", grid.width(), grid.height());
            }
            self.protocol.rig_accepted(&record);
            return Some((rig, grid));
        }
    }

    /// Frame `frame` with its pose `sample`, from the pose gate to the
    /// report and the alarm; `cycle_start` is when its pose came.
    fn serve_frame(&mut self, session: &mut Session, frame: u32, sample: PoseSample, cycle_start: u32) {
        let follows = session.pipeline.follows(frame);
        if let Err(error) = session.pipeline.begin(frame, sample) {
            // The pose cannot be trusted: the frame is skipped and the next one restarts.
            defmt::warn!("frame {=u32} skipped: {}", frame, error);
            self.fail_safe.frame_skipped(frame);
            return;
        }
        if !follows && session.started {
            defmt::warn!("frame {=u32}: the frame before was not processed; keyframe restarts", frame);
            bump(&mut self.stats.frame_gaps);
        }
        session.started = true;

        let mut read = 0;
        match self.stream_frame(&mut session.pipeline, frame, session.camera, &mut read) {
            Ok(outcome) => {
                // The pin first: it is what the robot acts on.
                self.fail_safe.frame_done(frame, Ok(&outcome));
                self.protocol.frame_done(frame, sample.t_s, &outcome, session.pipeline.gpa().scan());
                log_outcome(&outcome);
                // Benchmark figures are for detection cycles (frames compared with a keyframe).
                if self.options.bench && matches!(outcome, Outcome::Compared(_)) {
                    let cycle = self.counter.now().wrapping_sub(cycle_start);
                    log_bench(frame, read, cycle, &session.pipeline.timing(), &session.pipeline.gpa().profile());
                }
                bump(&mut self.stats.frames);
            }
            Err(failure) => {
                self.frames.end_frame();
                session.pipeline.abort();
                if failure.mid_frame {
                    bump(&mut self.stats.aborted);
                }
                self.fail_safe.frame_done(frame, Err(failure.sensor_fault()));
                defmt::error!("fault {=str} (frame {=u32})", failure.code.as_str(), frame);
                self.protocol.frame_failed(frame, sample.t_s, failure.code, session.pipeline.gpa().scan());
            }
        }
    }

    /// Streams frame `index` from the row source through the pipeline and
    /// finishes it; `read` accumulates the ticks spent reading rows (the
    /// pipeline times its own stages). A frame whose last row has not come
    /// [`CAMERA_TIMEOUT_US`] after it was asked for is given up as
    /// `camera_timeout`. On failure the caller gives the frame up.
    fn stream_frame(&mut self, pipeline: &mut Pipeline, index: u32, camera: (usize, usize), read: &mut u32) -> Result<Outcome, FrameFailure> {
        let asked = self.clock.now_us();
        let early = |code| FrameFailure { code, mid_frame: false };
        let size = self.frames.begin_frame(index).map_err(|error| early(row_fault(error)))?;
        let (width, height) = (usize::from(size.width), usize::from(size.height));
        // The host skips a frame whose size is not the rig's; so do we, before the detector sees it.
        if (width, height) != camera {
            return Err(early(FaultCode::FrameFormat));
        }
        self.stream_rows(pipeline, camera, asked, read)?;
        self.frames.end_frame();
        self.watchdog.feed();
        let outcome = pipeline.finish().map_err(|error| FrameFailure { code: fault_code(error), mid_frame: true });
        self.watchdog.feed();
        outcome
    }

    /// [`Self::stream_frame`]'s rows, `camera` = (width, height), asked for at `asked` (µs).
    // Not inlined: the row and the remap's line (2.7 KB) would sit in the frame
    // loop's frame, under the detector's deepest stack.
    #[inline(never)]
    fn stream_rows(&mut self, pipeline: &mut Pipeline, (width, height): (usize, usize), asked: u32, read: &mut u32) -> Result<(), FrameFailure> {
        let mut row_buffer = [0u8; MAX_CAMERA_WIDTH];
        let mut line = Line::ZERO;
        let row = row_buffer.get_mut(..width).ok_or(FrameFailure { code: FaultCode::FrameFormat, mid_frame: false })?;
        let mid = |code| FrameFailure { code, mid_frame: true };
        for _ in 0..height {
            self.watchdog.feed();
            let start = self.counter.now();
            self.frames.read_row(row).map_err(|error| {
                mid(if error == RowSourceError::Timeout { FaultCode::CameraTimeout } else { FaultCode::FrameRead })
            })?;
            *read = read.wrapping_add(self.counter.now().wrapping_sub(start));
            if self.clock.now_us().wrapping_sub(asked) > CAMERA_TIMEOUT_US {
                return Err(mid(FaultCode::CameraTimeout));
            }
            pipeline.push_row(row, &mut line).map_err(|error| mid(fault_code(error)))?;
        }
        Ok(())
    }
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

fn log_outcome(outcome: &Outcome) {
    let report = match outcome {
        Outcome::Compared(report) | Outcome::NotJudged(report) => report,
        Outcome::Keyframe { frame } => {
            defmt::info!("frame {=u32}: new keyframe, nothing to compare", frame);
            return;
        }
    };
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

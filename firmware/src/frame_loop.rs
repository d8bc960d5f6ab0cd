//! The frame loop: rig in, table built, then per frame: pose in, rows
//! streamed through the KG remap, one report out.
//!
//! It sees the board only through the board layer's traits, so the same loop
//! runs on the emulated and on a real board.
//!
//! Stand-in until the detector lands: the per-frame report carries the frame
//! indices and the odometry's motion prediction since the reference frame;
//! the detection fields (alarm, nearest, SAD, shifts, height) stay at their
//! "nothing found" defaults and the log says so. The KG rows are counted and
//! their mean logged, which proves the remap runs on every frame.

use embedded_hal::digital::OutputPin;
use embedded_io::{Read, Write};
use libm::{cos, round, sin};

use flatland_core::geometry::{Aoi, Distortion, Intrinsics, Mount, Rig};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::protocol::{
    encode_line, Decoder, Fault, FaultCode, LinkStats, Message, Odometry, RigRecord,
};
use flatland_core::remap::{RemapTable, StreamingRemap};
use flatland_core::report::{FrameReport, MOTION_SCALE};
use static_cell::ConstStaticCell;

use crate::board::{CycleCounter, RowSource, RowSourceError};

/// Largest camera row we accept (the geometry caps the image side at 1024).
pub const MAX_CAMERA_WIDTH: usize = flatland_core::geometry::MAX_IMAGE_SIDE as usize;
/// Camera rows the streaming remap may keep, in bytes.
pub const RING_CAPACITY: usize = 16 * 1024;

static TABLE: ConstStaticCell<RemapTable> = ConstStaticCell::new(RemapTable::EMPTY);
static RING: ConstStaticCell<[u8; RING_CAPACITY]> = ConstStaticCell::new([0; RING_CAPACITY]);

/// Instruction counts of the last frame, for the benchmark log.
#[derive(Clone, Copy, Debug, Default)]
pub struct FrameTiming {
    /// Reading the rows from the row source.
    pub read: u32,
    /// The streaming remap (all `push_row` calls).
    pub remap: u32,
    /// The whole cycle, odometry received to report sent.
    pub cycle: u32,
}

/// What the loop counts beyond the decoder's own counters.
#[derive(Default)]
struct LoopCounters {
    frames: u32,
    serial_overruns: u32,
    out_of_order: u32,
    frame_gaps: u32,
}

/// The board parts the loop needs.
pub struct Board<S, A, C, R> {
    pub serial: S,
    pub alarm: A,
    pub counter: C,
    pub frames: R,
}

/// Emits benchmark figures as `bench: key: value` log lines when true.
pub struct Options {
    pub bench: bool,
}

struct Link<S> {
    serial: S,
    decoder: Decoder,
    counters: LoopCounters,
}

impl<S: Read + Write> Link<S> {
    /// Next well-formed message; malformed input is counted and skipped.
    fn receive(&mut self) -> Message {
        loop {
            let mut byte = [0u8; 1];
            match self.serial.read(&mut byte) {
                Ok(1) => {}
                Ok(_) => continue,
                Err(_) => {
                    self.counters.serial_overruns = self.counters.serial_overruns.saturating_add(1);
                    continue;
                }
            }
            match self.decoder.push(byte[0]) {
                Some(Ok(message)) => return message,
                Some(Err(error)) => defmt::warn!("serial: dropped a line ({=str})", error.as_str()),
                None => {}
            }
        }
    }

    fn send(&mut self, message: &Message) {
        match encode_line(message) {
            Ok(line) => {
                if self.serial.write_all(line.as_bytes()).is_err() {
                    defmt::warn!("serial: write failed");
                }
            }
            Err(_) => defmt::error!("serial: cannot encode {=str}", message.tag()),
        }
    }

    fn fault(&mut self, code: FaultCode, frame: u32) {
        defmt::error!("fault {=str} (frame {=u32})", code.as_str(), frame);
        self.send(&Message::Fault(Fault { code, frame }));
    }

    fn stats(&self) -> LinkStats {
        let mut stats = self.decoder.stats();
        stats.frames = self.counters.frames;
        stats.garbage_bytes = stats.garbage_bytes.saturating_add(self.counters.serial_overruns);
        stats.out_of_order = self.counters.out_of_order;
        stats.frame_gaps = self.counters.frame_gaps;
        stats
    }

    fn out_of_order(&mut self, message: &Message) {
        defmt::warn!("serial: unexpected {=str}", message.tag());
        self.counters.out_of_order = self.counters.out_of_order.saturating_add(1);
    }
}

/// The geometry's rig from the wire's record.
fn rig_from_record(record: &RigRecord) -> Result<Rig, flatland_core::geometry::RigError> {
    let camera = Intrinsics {
        width: record.width,
        height: record.height,
        fx: record.fx,
        fy: record.fy,
        cx: record.cx,
        cy: record.cy,
        distortion: record.distortion.map(|[k1, k2, p1, p2, k3]| Distortion { k1, k2, p1, p2, k3 }),
    };
    let mount = Mount { height_mm: record.height_mm, tilt_deg: record.tilt_deg };
    let aoi = Aoi {
        half_width_mm: record.aoi_half_width_mm,
        near_mm: record.aoi_near_mm,
        far_mm: record.aoi_far_mm,
    };
    Rig::new_checked(camera, mount, aoi)
}

/// Motion from pose `from` to pose `to`, in the robot frame of `from`, in
/// 1/[`MOTION_SCALE`] mm. Yaw turns left (counter-clockwise from above);
/// yaw 0 faces world +z, so the robot's right is (cos, sin) and its forward
/// is (-sin, cos) in world (x, z).
fn odometry_motion(from: &Odometry, to: &Odometry) -> (i32, i32) {
    let yaw = from.yaw_deg.to_radians();
    let (dx, dz) = (to.x_mm - from.x_mm, to.z_mm - from.z_mm);
    let tx = dx * cos(yaw) + dz * sin(yaw);
    let tz = -dx * sin(yaw) + dz * cos(yaw);
    let scale = f64::from(MOTION_SCALE);
    (round(tx * scale) as i32, round(tz * scale) as i32)
}

/// Waits for a rig that validates, builds the remap table, and announces it.
fn configure<S: Read + Write, C: CycleCounter>(
    link: &mut Link<S>,
    counter: &C,
    table: &mut RemapTable,
    options: &Options,
) -> Option<RigRecord> {
    loop {
        let record = match link.receive() {
            Message::Rig(record) => record,
            Message::End => return None,
            other => {
                link.out_of_order(&other);
                continue;
            }
        };
        let rig = match rig_from_record(&record) {
            Ok(rig) => rig,
            Err(error) => {
                defmt::error!("rig refused: {}", defmt::Debug2Format(&error));
                link.fault(FaultCode::RigRejected, 0);
                continue;
            }
        };
        let started = counter.now();
        let built = KgGrid::for_rig(&rig, &GridConfig::default())
            .map_err(|error| defmt::error!("grid refused: {}", defmt::Display2Format(&error)))
            .and_then(|grid| {
                table.build(&rig, &grid).map_err(|error| defmt::error!("table refused: {}", defmt::Debug2Format(&error)))
            });
        if built.is_err() {
            link.fault(FaultCode::TableRejected, 0);
            continue;
        }
        if table.ring_bytes() > RING_CAPACITY {
            defmt::error!("remap ring needs {=usize} bytes, have {=usize}", table.ring_bytes(), RING_CAPACITY);
            link.fault(FaultCode::TableRejected, 0);
            continue;
        }
        let build_instructions = counter.now().wrapping_sub(started);
        defmt::info!(
            "rig accepted: camera {=u16}x{=u16}, KG grid {=usize}x{=usize}, table {=usize} B, ring {=usize} rows",
            record.width,
            record.height,
            table.grid_width(),
            table.grid_height(),
            RemapTable::size_bytes(),
            table.ring_rows()
        );
        if options.bench {
            defmt::println!("bench: table_build: {=u32}", build_instructions);
        }
        link.send(&Message::Hello(record));
        return Some(record);
    }
}

/// Streams frame `index` through the remap. Returns the KG rows emitted and their pixel sum.
fn remap_frame<R: RowSource, C: CycleCounter>(
    frames: &mut R,
    counter: &C,
    remap: &mut StreamingRemap,
    index: u32,
    timing: &mut FrameTiming,
) -> Result<(u32, u64), FaultCode> {
    let size = frames.begin_frame(index).map_err(|error| match error {
        RowSourceError::Missing => FaultCode::FrameMissing,
        RowSourceError::Format | RowSourceError::RowLength => FaultCode::FrameFormat,
        RowSourceError::Read => FaultCode::FrameRead,
    })?;
    let width = usize::from(size.width);
    let mut row_buffer = [0u8; MAX_CAMERA_WIDTH];
    let row = row_buffer.get_mut(..width).ok_or(FaultCode::FrameFormat)?;
    remap.reset();
    let (mut kg_rows, mut kg_sum) = (0u32, 0u64);
    for _ in 0..size.height {
        let read_start = counter.now();
        frames.read_row(row).map_err(|_| FaultCode::FrameRead)?;
        let remap_start = counter.now();
        remap
            .push_row(row, |_, kg_row| {
                kg_rows += 1;
                kg_sum += kg_row.iter().map(|&p| u64::from(p)).sum::<u64>();
            })
            .map_err(|error| match error {
                flatland_core::remap::RemapError::RowLength { .. } => FaultCode::FrameFormat,
                _ => FaultCode::RemapFailed,
            })?;
        let end = counter.now();
        timing.read = timing.read.wrapping_add(remap_start.wrapping_sub(read_start));
        timing.remap = timing.remap.wrapping_add(end.wrapping_sub(remap_start));
    }
    frames.end_frame();
    Ok((kg_rows, kg_sum))
}

/// Runs until the host sends `$FLEND`; returns the final counters.
pub fn run<S, A, C, R>(board: Board<S, A, C, R>, options: &Options) -> LinkStats
where
    S: Read + Write,
    A: OutputPin,
    C: CycleCounter,
    R: RowSource,
{
    let Board { serial, mut alarm, counter, mut frames } = board;
    let mut link = Link { serial, decoder: Decoder::new(), counters: LoopCounters::default() };
    let table: &'static mut RemapTable = TABLE.take();
    let ring: &'static mut [u8; RING_CAPACITY] = RING.take();

    // Bytes that arrive before the USART is enabled are lost: say when we listen.
    link.send(&Message::Ready);
    if configure(&mut link, &counter, table, options).is_none() {
        defmt::warn!("no rig before the end of input");
        let stats = link.stats();
        link.send(&Message::Stats(stats));
        return stats;
    }
    let table: &RemapTable = table;
    let mut remap = match StreamingRemap::new(table, &mut ring[..]) {
        Ok(remap) => remap,
        Err(_) => {
            // `configure` checked the ring size, so this is not reachable from input.
            link.fault(FaultCode::TableRejected, 0);
            let stats = link.stats();
            link.send(&Message::Stats(stats));
            return stats;
        }
    };
    defmt::warn!("detector not integrated yet: reports carry odometry motion only, alarm stays 0");

    // The reference (key) frame's pose; None after start-up, a gap or a broken frame.
    let mut reference: Option<Odometry> = None;
    loop {
        let pose = match link.receive() {
            Message::Odometry(pose) => pose,
            Message::End => break,
            other => {
                link.out_of_order(&other);
                continue;
            }
        };
        let cycle_start = counter.now();
        if let Some(previous) = reference {
            if pose.frame != previous.frame.wrapping_add(1) {
                defmt::warn!("frame gap: {=u32} after {=u32}; keyframe reset", pose.frame, previous.frame);
                link.counters.frame_gaps = link.counters.frame_gaps.saturating_add(1);
                reference = None;
            }
        }
        let mut timing = FrameTiming::default();
        let (kg_rows, kg_sum) = match remap_frame(&mut frames, &counter, &mut remap, pose.frame, &mut timing) {
            Ok(result) => result,
            Err(code) => {
                frames.end_frame();
                link.fault(code, pose.frame);
                reference = None;
                continue;
            }
        };
        let reference_pose = reference.unwrap_or(pose);
        let (tx, tz) = odometry_motion(&reference_pose, &pose);
        let report = FrameReport { frame: pose.frame, ref_frame: reference_pose.frame, tx, tz, ..FrameReport::default() };
        let _ = if report.alarm { alarm.set_high() } else { alarm.set_low() };
        link.send(&Message::Frame(report));
        link.counters.frames = link.counters.frames.saturating_add(1);
        reference = Some(pose);
        timing.cycle = counter.now().wrapping_sub(cycle_start);

        let pixels = u64::from(kg_rows) * table.grid_width() as u64;
        let mean = kg_sum.checked_div(pixels).unwrap_or(0);
        defmt::info!("frame {=u32}: {=u32} KG rows, mean level {=u64}", pose.frame, kg_rows, mean);
        if options.bench {
            defmt::println!("bench: frame: {=u32}", pose.frame);
            defmt::println!("bench: read_rows: {=u32}", timing.read);
            defmt::println!("bench: remap: {=u32}", timing.remap);
            defmt::println!("bench: instructions_per_cycle: {=u32}", timing.cycle);
        }
    }
    let stats = link.stats();
    link.send(&Message::Stats(stats));
    stats
}

//! One frame's way through the stages: camera rows -> streaming remap ->
//! GPA (and GTI) per KG row -> GPA's decision, GTI's heights -> one
//! [`FrameReport`] (`fusion`). The firmware's frame loop and the host's
//! `flatland detect`, `heights` and `bench` all drive frames through a
//! [`Pipeline`], so the host and the target agree by construction.
//!
//! This room holds:
//! - the odometry gate ([`Pipeline::begin`]): a frame is compared with the
//!   keyframe only with the motion from the frame just before and forward
//!   in time; a frame given up ([`Pipeline::abort`]) or never begun (no
//!   pose sample, unreadable), a gap in frame numbers or time running
//!   backwards restart the keyframe;
//! - every frame after the run's first is judged or says why not
//!   ([`Outcome::NotJudged`], `report::NotJudged`): a frame that restarts
//!   the keyframe after a gap, or whose motion could not be measured, gets
//!   a fail-safe report (alarm asserted) with the reason;
//! - the frame's rows ([`Pipeline::push_row`]) and its end
//!   ([`Pipeline::finish`]), with typed outcomes and errors;
//! - per-stage timing ([`FrameTiming`]) from an injected clock, for the
//!   benchmarks of both sides (reading the camera is the caller's to time).
//!
//! No heap: the stages are borrowed (the firmware keeps them in statics).
//! GTI is optional: the firmware's `full-frame` benchmark build leaves it
//! out for the RAM its keyframe needs.

use crate::fusion::GtiStage;
use crate::gpa::Gpa;
use crate::limits::MAX_RING_BYTES;
use crate::motion::{Attitude, Motion, Pose};
use crate::remap::{Line, RemapError, RemapTable, StreamingRemap};
use crate::report::{FrameReport, NotJudged};
use core::fmt;

/// When a frame was captured, and what the robot's sensors said then.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseSample {
    /// Capture time, s.
    pub t_s: f64,
    /// Wheel odometry's pose; None: no odometry (the motion comes from the
    /// images alone).
    pub pose: Option<Pose>,
    /// The IMU's body attitude; None: no IMU.
    pub attitude: Option<Attitude>,
}

/// What became of a finished frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// Compared with the keyframe and judged (`status` ok): GPA's decision
    /// with GTI's heights.
    Compared(FrameReport),
    /// Not judged: the report's `status` says why (`report::NotJudged`),
    /// its alarm is asserted and it names no obstacle. The frame restarted
    /// the keyframe from itself.
    NotJudged(FrameReport),
    /// The run's first frame: it became the keyframe. Nothing to compare
    /// with and nothing before it, so no report (and no alarm can be claimed).
    Keyframe { frame: u32 },
}

/// Why a frame was skipped. Every error leaves the frame given up and the
/// keyframe forgotten: the next frame restarts it rather than raise a
/// false alarm.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The frame's time is not after the last frame's: its pose cannot be
    /// trusted, nor the motion to or from it.
    TimeBackwards { frame: u32, t_s: f64, previous_frame: u32, previous_t_s: f64 },
    /// A row or the end of a frame that was not begun.
    NotBegun,
    /// The remap refused a camera row.
    Remap(RemapError),
    /// The camera rows did not make every KG row.
    MissingRows { expected: usize, got: usize },
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::TimeBackwards { frame, t_s, previous_frame, previous_t_s } => {
                write!(f, "frame {frame} at t = {t_s} s is not after frame {previous_frame} at t = {previous_t_s} s")
            }
            FrameError::NotBegun => f.write_str("no frame was begun"),
            FrameError::Remap(error) => write!(f, "remap: {error}"),
            FrameError::MissingRows { expected, got } => write!(f, "the remap made {got} of {expected} KG rows"),
        }
    }
}

impl core::error::Error for FrameError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            FrameError::Remap(error) => Some(error),
            _ => None,
        }
    }
}

/// Clock ticks spent per stage on the last frame (all 0 without a clock).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameTiming {
    /// The streaming remap (`push_row` less the stages' share).
    pub remap: u32,
    /// GPA's per-row work (`Gpa::on_kg_row`: shift search, residue, keyframe update).
    pub detector_rows: u32,
    /// `Gpa::end_frame`: best shift, noise, blobs, decision.
    pub decision: u32,
    /// GTI's per-row sampling (`GtiStage::on_kg_row`).
    pub gti_rows: u32,
    /// GTI's per-frame work: edges, tracking, fits, and the combination
    /// with GPA's report (`GtiStage::end_frame`, `GtiStage::enrich`).
    pub gti_frame: u32,
    /// The whole frame, [`Pipeline::begin`] to the end of [`Pipeline::finish`]
    /// (the caller's reading of the rows included).
    pub cycle: u32,
}

/// The last frame that was finished: the next frame's motion starts from it.
#[derive(Clone, Copy)]
struct Previous {
    frame: u32,
    sample: PoseSample,
}

/// The frame between [`Pipeline::begin`] and its end.
#[derive(Clone, Copy)]
struct Current {
    frame: u32,
    pose: PoseSample,
    motion: Option<Motion>,
    /// The run's first frame (none begun, given up or refused before it):
    /// if it has nothing to compare with, it is not reported.
    first: bool,
    kg_rows: usize,
    begun_at: u32,
}

/// The stages of one rig and the frame bookkeeping between them.
pub struct Pipeline<'s, 'k, 't> {
    table: &'t RemapTable,
    remap: StreamingRemap<'t>,
    gpa: &'s mut Gpa<'k>,
    gti: Option<&'s mut GtiStage>,
    previous: Option<Previous>,
    current: Option<Current>,
    /// A frame was begun, given up or refused: the next one is not the
    /// run's first (a keyframe restart is then reported, not silent).
    started: bool,
    clock: Option<fn() -> u32>,
    timing: FrameTiming,
}

impl<'s, 'k, 't> Pipeline<'s, 'k, 't> {
    /// The stages, set up for the rig `table` was built for. The remap's
    /// camera rows ([`RemapTable::ring_bytes`]) live in memory GPA lends
    /// while rows stream ([`Gpa::lend_ring`]): a rig needing more than
    /// [`MAX_RING_BYTES`] is refused. Without `gti`, reports carry GPA's
    /// decision alone.
    pub fn new(table: &'t RemapTable, gpa: &'s mut Gpa<'k>, gti: Option<&'s mut GtiStage>) -> Result<Self, RemapError> {
        if table.ring_bytes() > MAX_RING_BYTES {
            return Err(RemapError::RingTooSmall { needed: table.ring_bytes() });
        }
        let remap = StreamingRemap::new(table);
        Ok(Pipeline { table, remap, gpa, gti, previous: None, current: None, started: false, clock: None, timing: FrameTiming::default() })
    }

    /// Times the stages with `clock` (any wrapping tick counter), GPA's
    /// inner stages too (`Gpa::set_clock`). None, the default, turns it off.
    pub fn set_clock(&mut self, clock: Option<fn() -> u32>) {
        self.clock = clock;
        self.gpa.set_clock(clock);
    }

    #[inline(always)]
    fn now(&self) -> u32 {
        self.clock.map_or(0, |clock| clock())
    }

    /// Starts frame `frame` captured at `pose`. Returns the odometry from
    /// the frame just before, or None when there is none: the keyframe
    /// restarts with the first frame and with one after a gap or a frame
    /// given up (each but the run's first is then reported not judged,
    /// `NotJudged::AfterGap`); a sample without odometry continues on the
    /// motion seen in the images. A frame without a pose sample cannot be
    /// placed in time: the caller does not begin it (it is a gap, as a
    /// missing frame). A frame whose time is not after the last frame's is
    /// skipped (error); a frame still in progress is given up first.
    pub fn begin(&mut self, frame: u32, pose: PoseSample) -> Result<Option<Motion>, FrameError> {
        let begun_at = self.now();
        if self.current.is_some() {
            self.abort();
        }
        if let Some(previous) = self.previous {
            if previous.frame != frame && pose.t_s <= previous.sample.t_s {
                self.restart();
                return Err(FrameError::TimeBackwards {
                    frame,
                    t_s: pose.t_s,
                    previous_frame: previous.frame,
                    previous_t_s: previous.sample.t_s,
                });
            }
        }
        let first = !core::mem::replace(&mut self.started, true);
        let follows = self.follows(frame);
        // What the frame just before tells: the odometry and the interval.
        let (motion, elapsed_s) = match self.previous {
            Some(previous) if follows => {
                let odometry = previous.sample.pose.zip(pose.pose).map(|(from, to)| Motion::between(&from, &to));
                (odometry, Some(pose.t_s - previous.sample.t_s))
            }
            _ => (None, None),
        };
        if !follows {
            self.gpa.reset_keyframe();
        }
        self.gpa.begin_frame_at(frame, elapsed_s, motion, pose.attitude);
        self.remap.reset();
        self.timing = FrameTiming::default();
        self.current = Some(Current { frame, pose, motion, first, kg_rows: 0, begun_at });
        Ok(motion)
    }

    /// Whether `frame` is the one after the last frame finished: it
    /// continues on the keyframe instead of restarting it.
    pub fn follows(&self, frame: u32) -> bool {
        self.previous.is_some_and(|previous| previous.frame.checked_add(1) == Some(frame))
    }

    /// Pushes the frame's next camera row through the remap into the stages;
    /// `line` is the remap's scratch ([`Line`], any contents). On error the
    /// frame is given up ([`Pipeline::abort`]).
    pub fn push_row(&mut self, camera_row: &[u8], line: &mut Line) -> Result<(), FrameError> {
        self.push_row_tapped(camera_row, line, |_, _| {})
    }

    /// As [`Pipeline::push_row`], and hands each KG row made to `tap`
    /// (the host's KG images).
    pub fn push_row_tapped(&mut self, camera_row: &[u8], line: &mut Line, mut tap: impl FnMut(usize, &[u8])) -> Result<(), FrameError> {
        let entered_at = self.now();
        let Pipeline { table, remap, gpa, gti, current, clock, timing, .. } = self;
        let Some(current) = current.as_mut() else { return Err(FrameError::NotBegun) };
        let (table, clock) = (*table, *clock);
        let now = || clock.map_or(0, |clock| clock());
        let (mut detector_rows, mut gti_rows) = (0u32, 0u32);
        // The ring is GPA's to lend between its calls (`Gpa::lend_ring`).
        let mut pushed = remap.store_row(gpa.lend_ring(), camera_row);
        while pushed.is_ok() {
            let (j, kg_row) = match remap.next_kg_row(gpa.lend_ring(), line) {
                Ok(Some(row)) => row,
                Ok(None) => break,
                Err(error) => {
                    pushed = Err(error);
                    break;
                }
            };
            let start = now();
            current.kg_rows += 1;
            gpa.on_kg_row(j, kg_row);
            let gti_start = now();
            if let Some(gti) = gti.as_deref_mut() {
                gti.on_kg_row(j, kg_row, table.valid_columns(j));
            }
            let end = now();
            detector_rows = detector_rows.wrapping_add(gti_start.wrapping_sub(start));
            gti_rows = gti_rows.wrapping_add(end.wrapping_sub(gti_start));
            tap(j, kg_row);
        }
        let stages = detector_rows.wrapping_add(gti_rows);
        timing.remap = timing.remap.wrapping_add(now().wrapping_sub(entered_at).wrapping_sub(stages));
        timing.detector_rows = timing.detector_rows.wrapping_add(detector_rows);
        timing.gti_rows = timing.gti_rows.wrapping_add(gti_rows);
        pushed.map_err(|error| {
            self.abort();
            FrameError::Remap(error)
        })
    }

    /// Ends the frame: GPA decides, GTI ends its frame and adds its heights
    /// to a frame judged. A frame that could not be judged is
    /// [`Outcome::NotJudged`], the run's first frame [`Outcome::Keyframe`].
    /// On error (rows missing) the frame is given up.
    // Inlined into the caller: a frame of its own would sit under
    // `Gpa::end_frame`, the deepest stack of the firmware's loop.
    #[inline]
    pub fn finish(&mut self) -> Result<Outcome, FrameError> {
        let Some(current) = self.current.take() else { return Err(FrameError::NotBegun) };
        // The remap re-arms itself after the last camera row; every KG row must have come out.
        let expected = self.table.grid_height();
        if current.kg_rows != expected {
            self.abort();
            return Err(FrameError::MissingRows { expected, got: current.kg_rows });
        }
        let start = self.now();
        let mut report = self.gpa.end_frame();
        let gti_start = self.now();
        // Only a frame judged is GTI's to add to, or the scan's to show.
        if let Some(gti) = self.gti.as_deref_mut() {
            // Without odometry GTI follows the ground's motion as GPA measured it.
            gti.end_frame(current.motion.or_else(|| self.gpa.measured_step()), self.gpa.body_attitude());
            if let Some(report) = report.as_mut().filter(|report| report.is_judged()) {
                gti.enrich(report);
            }
        }
        if let Some(report) = report.as_ref().filter(|report| report.is_judged()) {
            self.gpa.scan_report(report);
        }
        let end = self.now();
        self.previous = Some(Previous { frame: current.frame, sample: current.pose });
        self.timing.decision = gti_start.wrapping_sub(start);
        self.timing.gti_frame = end.wrapping_sub(gti_start);
        self.timing.cycle = end.wrapping_sub(current.begun_at);
        Ok(match report {
            Some(report) if report.is_judged() => Outcome::Compared(report),
            Some(report) => Outcome::NotJudged(report),
            // Nothing to compare with: the run's first frame is the
            // keyframe; any later one says why it restarted it.
            // (GPA has a keyframe whenever the frame follows the last one.)
            None if current.first => Outcome::Keyframe { frame: current.frame },
            None => Outcome::NotJudged(FrameReport::not_judged(current.frame, current.frame, NotJudged::AfterGap)),
        })
    }

    /// Gives the frame up: the caller could not deliver it (missing,
    /// unreadable, not the rig's size) or its rows broke off. The stages
    /// drop its rows and the next frame restarts the keyframe. Harmless
    /// when no frame is in progress.
    pub fn abort(&mut self) {
        self.gpa.abort_frame();
        if let Some(gti) = self.gti.as_deref_mut() {
            gti.abort_frame();
        }
        self.restart();
    }

    /// Forgets the keyframe and the last frame: the next frame starts afresh
    /// (and, not being the run's first, is reported not judged).
    pub fn restart(&mut self) {
        self.started = true;
        self.gpa.reset_keyframe();
        self.previous = None;
        self.current = None;
    }

    /// Per-stage ticks of the last frame (see [`Pipeline::set_clock`]).
    pub fn timing(&self) -> FrameTiming {
        self.timing
    }

    pub fn gpa(&self) -> &Gpa<'k> {
        self.gpa
    }

    pub fn gti(&self) -> Option<&GtiStage> {
        self.gti.as_deref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::tests::sample_rig;
    use crate::gpa::GpaConfig;
    use crate::grid::{GridConfig, KgGrid};
    use std::boxed::Box;
    use std::vec;
    use std::vec::Vec;

    /// Runs `test` on a pipeline for the sample rig (with GTI if `with_gti`).
    fn with_pipeline(with_gti: bool, test: impl FnOnce(&mut Pipeline, &RemapTable)) {
        let rig = sample_rig();
        let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
        let table = Box::new(RemapTable::new(&rig, &grid).unwrap());
        let mut keyframe = vec![0u8; Gpa::keyframe_bytes(&grid)];
        let mut gpa = Box::new(Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut keyframe).unwrap());
        let mut gti = with_gti.then(|| Box::new(GtiStage::new(&rig, &grid).unwrap()));
        let mut pipeline = Pipeline::new(&table, &mut gpa, gti.as_deref_mut()).unwrap();
        test(&mut pipeline, &table);
    }

    /// Runs `frames` (index, pose) of a flat grey scene through a pipeline,
    /// giving up those in `give_up` after one row, and those without a pose
    /// sample before they begin (as `flatland detect` skips them); the
    /// outcome of each other, or the error.
    fn run(frames: &[(u32, Option<PoseSample>)], give_up: &[u32]) -> Vec<Result<(Option<Motion>, Outcome), FrameError>> {
        let mut outcomes = Vec::new();
        with_pipeline(true, |pipeline, table| {
            let row = vec![128u8; table.camera_width()];
            let mut line = Line::ZERO;
            for &(frame, pose) in frames {
                let Some(pose) = pose else {
                    pipeline.abort();
                    continue;
                };
                let motion = match pipeline.begin(frame, pose) {
                    Ok(motion) => motion,
                    Err(error) => {
                        outcomes.push(Err(error));
                        continue;
                    }
                };
                if give_up.contains(&frame) {
                    pipeline.push_row(&row, &mut line).unwrap();
                    pipeline.abort();
                    continue;
                }
                for _ in 0..table.camera_height() {
                    pipeline.push_row(&row, &mut line).unwrap();
                }
                outcomes.push(pipeline.finish().map(|outcome| (motion, outcome)));
            }
        });
        outcomes
    }

    fn at(t_s: f64, z_mm: f64) -> Option<PoseSample> {
        Some(PoseSample { t_s, pose: Some(Pose { x_mm: 0.0, z_mm, yaw_deg: 0.0 }), attitude: None })
    }

    fn motion(tz_mm: f64) -> Option<Motion> {
        Some(Motion { tx_mm: 0.0, tz_mm, dyaw_deg: 0.0 })
    }

    #[test]
    fn motion_only_from_the_frame_just_before() {
        let outcomes = run(&[(0, at(0.0, 0.0)), (1, at(0.1, 20.0)), (3, at(0.3, 60.0)), (4, at(0.4, 80.0))], &[]);
        let motions: Vec<_> = outcomes.iter().map(|o| o.as_ref().unwrap().0).collect();
        assert_eq!(motions, [None, motion(20.0), None, motion(20.0)]);
        assert_eq!(outcomes[0].unwrap().1, Outcome::Keyframe { frame: 0 });
        assert!(matches!(outcomes[1].unwrap().1, Outcome::Compared(report) if report.frame == 1 && report.ref_frame == 0));
        assert_eq!(outcomes[2].unwrap().1, after_gap(3), "a gap restarts the keyframe, and says so");
        assert!(matches!(outcomes[3].unwrap().1, Outcome::Compared(report) if report.ref_frame == 3));
    }

    /// Frame `frame` restarted the keyframe after a gap: not judged, alarm asserted.
    fn after_gap(frame: u32) -> Outcome {
        Outcome::NotJudged(FrameReport::not_judged(frame, frame, NotJudged::AfterGap))
    }

    #[test]
    fn time_backwards_skips_and_restarts() {
        let outcomes = run(&[(0, at(0.0, 0.0)), (1, at(0.1, 20.0)), (2, at(0.1, 40.0)), (3, at(0.3, 60.0))], &[]);
        assert_eq!(
            outcomes[2],
            Err(FrameError::TimeBackwards { frame: 2, t_s: 0.1, previous_frame: 1, previous_t_s: 0.1 })
        );
        assert_eq!(outcomes[3], Ok((None, after_gap(3))));
    }

    #[test]
    fn a_missing_pose_or_a_frame_given_up_restarts() {
        let outcomes = run(&[(0, at(0.0, 0.0)), (1, None), (2, at(0.2, 40.0)), (3, at(0.3, 60.0))], &[]);
        let motions: Vec<_> = outcomes.iter().map(|o| o.as_ref().unwrap().0).collect();
        assert_eq!(motions, [None, None, motion(20.0)], "frames 0, 2 and 3");
        assert_eq!(outcomes[1].unwrap().1, after_gap(2));
        let outcomes = run(&[(0, at(0.0, 0.0)), (1, at(0.1, 20.0)), (2, at(0.2, 40.0)), (3, at(0.3, 60.0))], &[1]);
        assert_eq!(outcomes[1], Ok((None, after_gap(2))));
        assert_eq!(outcomes[2].unwrap().0, motion(20.0));
        // A run whose first frame is given up: the next is not the run's first.
        let outcomes = run(&[(0, at(0.0, 0.0)), (1, at(0.1, 20.0)), (2, at(0.2, 40.0))], &[0]);
        assert_eq!(outcomes[0], Ok((None, after_gap(1))));
    }

    /// A texture-less floor without odometry: the motion cannot be measured,
    /// so each frame after the first is reported not judged (alarm asserted,
    /// no obstacle), against the keyframe it tried, and restarts it.
    #[test]
    fn a_frame_whose_motion_cannot_be_measured_is_not_judged() {
        let blind = |t_s: f64| Some(PoseSample { t_s, pose: None, attitude: None });
        let outcomes = run(&[(0, blind(0.0)), (1, blind(0.1)), (2, blind(0.2))], &[]);
        assert_eq!(outcomes[0], Ok((None, Outcome::Keyframe { frame: 0 })));
        for (n, outcome) in outcomes.iter().enumerate().skip(1) {
            let frame = n as u32;
            let expected = FrameReport::not_judged(frame, frame - 1, NotJudged::NoMotion);
            assert!(expected.alarm && expected.nearest_mm.is_none() && expected.left_mm.is_none() && expected.right_mm.is_none());
            assert_eq!(outcome, &Ok((None, Outcome::NotJudged(expected))), "frame {frame}");
        }
    }

    #[test]
    fn rows_need_a_frame_and_a_frame_needs_its_rows() {
        with_pipeline(false, |pipeline, table| {
            let row = vec![0u8; table.camera_width()];
            let mut line = Line::ZERO;
            assert_eq!(pipeline.push_row(&row, &mut line), Err(FrameError::NotBegun));
            assert_eq!(pipeline.finish(), Err(FrameError::NotBegun));
            pipeline.begin(0, at(0.0, 0.0).unwrap()).unwrap();
            assert!(matches!(pipeline.push_row(&row[1..], &mut line), Err(FrameError::Remap(RemapError::RowLength { .. }))));
            assert_eq!(pipeline.push_row(&row, &mut line), Err(FrameError::NotBegun), "the frame was given up");
            pipeline.begin(1, at(0.1, 20.0).unwrap()).unwrap();
            pipeline.push_row(&row, &mut line).unwrap();
            let expected = table.grid_height();
            assert!(matches!(pipeline.finish(), Err(FrameError::MissingRows { got, .. }) if got < expected));
        });
    }
}

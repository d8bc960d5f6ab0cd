//! `flatland detect`: a recording's frames through `flatland_core::pipeline`
//! (remap -> GPA and GTI, combined by `flatland_core::fusion`), fed row by
//! row exactly as the firmware feeds them. `flatland heights` and `flatland
//! bench` drive the same pipeline from here.

use crate::kg::KgFrontEnd;
use crate::recording::{Frame, Recording, RecordingError};
use flatland_core::fusion::GtiStage;
use flatland_core::geometry::Rig;
use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::pipeline::{FrameError, Outcome, Pipeline, PoseSample};
use flatland_core::remap::{Line, RemapTable};
use flatland_core::report::FrameReport;

/// What happened to one frame.
#[derive(Debug)]
pub enum FrameOutcome {
    /// Reported: compared with the keyframe and judged, or not judged and
    /// why (`report.status`; then the alarm is asserted and the frame
    /// restarted the keyframe). Every frame after the run's first that was
    /// not skipped.
    Report { report: FrameReport, kg: Vec<u8> },
    /// Became the run's first keyframe: nothing to compare with.
    Keyframe { frame: u32, kg: Vec<u8> },
    /// Could not be used (no row: the stderr line says why); the next frame
    /// restarts the keyframe and is reported not judged (`after_gap`).
    Skipped { frame: u32, error: RecordingError },
}

/// Detector settings.
#[derive(Clone, Copy, Debug, Default)]
pub struct DetectConfig {
    pub grid: GridConfig,
    pub gpa: GpaConfig,
}

/// Whether a pipeline runs the GTI stage.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Heights {
    /// GPA's decision with GTI's heights: what the firmware runs.
    WithGti,
    /// GPA alone (`flatland bench`'s detection cycle).
    GpaOnly,
}

/// Everything built once per rig: the KG front end and the keyframe memory.
pub struct Detector {
    pub front_end: KgFrontEnd,
    keyframe: Vec<u8>,
    rig: Rig,
    config: DetectConfig,
}

impl Detector {
    pub fn new(rig: &Rig, config: &DetectConfig) -> Result<Detector, String> {
        let front_end = KgFrontEnd::new(rig, &config.grid).map_err(|e| e.to_string())?;
        let keyframe = vec![0; Gpa::keyframe_bytes(&front_end.grid)];
        Ok(Detector { front_end, keyframe, rig: *rig, config: *config })
    }

    pub fn grid(&self) -> KgGrid {
        self.front_end.grid
    }

    /// Runs `drive` on a fresh pipeline over these buffers.
    pub fn with_pipeline<T>(&mut self, heights: Heights, drive: impl FnOnce(&mut Pipeline) -> Result<T, String>) -> Result<T, String> {
        let KgFrontEnd { grid, table, .. } = &mut self.front_end;
        let table: &RemapTable = table;
        let mut gpa = Gpa::new(&self.rig, grid, table, self.config.gpa, &mut self.keyframe).map_err(|e| format!("detector: {e}"))?;
        let mut gti = match heights {
            Heights::WithGti => Some(Box::new(GtiStage::new(&self.rig, grid).map_err(|e| format!("GTI: {e}"))?)),
            Heights::GpaOnly => None,
        };
        let mut pipeline = Pipeline::new(table, &mut gpa, gti.as_deref_mut()).map_err(|e| e.to_string())?;
        drive(&mut pipeline)
    }

    /// Runs every frame of the recording through the pipeline, in order.
    pub fn run(&mut self, recording: &Recording, on_frame: impl FnMut(FrameOutcome, &Pipeline)) -> Result<(), String> {
        self.run_with(recording, |_, _| {}, on_frame)
    }

    /// As [`Detector::run`], with `alter` applied to each frame after loading
    /// (the tests' perturbations: noise, gain changes).
    pub fn run_with(
        &mut self,
        recording: &Recording,
        mut alter: impl FnMut(u32, &mut Frame),
        mut on_frame: impl FnMut(FrameOutcome, &Pipeline),
    ) -> Result<(), String> {
        let grid = self.grid();
        let first = recording.frames.first().copied().unwrap_or(0);
        let last = recording.frames.last().copied().unwrap_or(0);
        self.with_pipeline(Heights::WithGti, |pipeline| {
            for index in first..=last {
                let frame = match recording.load_frame(index) {
                    Ok(mut frame) => {
                        alter(index, &mut frame);
                        frame
                    }
                    Err(error) => {
                        // A missing or broken frame is a gap: the next good frame
                        // restarts the keyframe rather than raise a false alarm.
                        pipeline.abort();
                        on_frame(FrameOutcome::Skipped { frame: index, error }, pipeline);
                        continue;
                    }
                };
                let Some(pose) = recording.pose(index) else {
                    // No time, no pose: the frame cannot be placed. Skipped as a
                    // missing frame is (the firmware never sees it: no `$FLODO`).
                    pipeline.abort();
                    let error = RecordingError::NoPose { path: recording.dir.join("poses.csv"), frame: index };
                    on_frame(FrameOutcome::Skipped { frame: index, error }, pipeline);
                    continue;
                };
                if let Err(error) = pipeline.begin(index, PoseSample::from(pose)) {
                    let error = RecordingError::Csv { path: recording.dir.join("poses.csv"), line: pose.line, message: error.to_string() };
                    on_frame(FrameOutcome::Skipped { frame: index, error }, pipeline);
                    continue;
                }
                let mut kg = vec![0u8; grid.len()];
                let width = grid.width();
                push_frame(pipeline, &frame, |j, kg_row| kg[j * width..][..width].copy_from_slice(kg_row))
                    .map_err(|e| format!("frame {index}: {e}"))?;
                let outcome = match pipeline.finish().map_err(|e| format!("frame {index}: {e}"))? {
                    Outcome::Compared(report) | Outcome::NotJudged(report) => FrameOutcome::Report { report, kg },
                    Outcome::Keyframe { frame } => FrameOutcome::Keyframe { frame, kg },
                };
                on_frame(outcome, pipeline);
            }
            Ok(())
        })
    }
}

/// Pushes a frame's camera rows into the pipeline begun on it; `tap` sees each KG row.
pub fn push_frame(pipeline: &mut Pipeline, frame: &Frame, mut tap: impl FnMut(usize, &[u8])) -> Result<(), FrameError> {
    let mut line = Line::ZERO;
    frame.pixels.chunks_exact(frame.width).try_for_each(|row| pipeline.push_row_tapped(row, &mut line, &mut tap))
}

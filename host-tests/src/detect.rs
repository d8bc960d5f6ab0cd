//! `flatland detect`: the streaming pipeline (remap -> GPA and GTI, combined
//! by `flatland_core::fusion`) over a recording, fed row by row exactly as
//! the firmware feeds it.

use crate::recording::{Recording, RecordingError};
use flatland_core::fusion::GtiStage;
use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::motion::Motion;
use flatland_core::remap::{RemapTable, StreamingRemap};
use flatland_core::report::FrameReport;

/// What happened to one frame.
#[derive(Debug)]
pub enum FrameOutcome {
    /// Compared with the keyframe.
    Report { report: FrameReport, kg: Vec<u8> },
    /// Became the (first) keyframe: nothing to compare with.
    Keyframe { frame: u32, kg: Vec<u8> },
    /// Could not be used; the keyframe was reset if the gap demands it.
    Skipped { frame: u32, error: RecordingError },
}

/// Detector settings.
#[derive(Clone, Copy, Debug, Default)]
pub struct DetectConfig {
    pub grid: GridConfig,
    pub gpa: GpaConfig,
}

/// Everything built once per rig.
pub struct Pipeline {
    pub grid: KgGrid,
    pub table: Box<RemapTable>,
    ring: Vec<u8>,
    keyframe: Vec<u8>,
}

impl Pipeline {
    pub fn new(recording: &Recording, config: &DetectConfig) -> Result<Pipeline, String> {
        let grid = KgGrid::for_rig(&recording.rig, &config.grid).map_err(|e| format!("KG grid: {e}"))?;
        let mut table = Box::new(RemapTable::EMPTY);
        table.build(&recording.rig, &grid).map_err(|e| format!("remap table: {e:?}"))?;
        let ring = vec![0; table.ring_bytes()];
        let keyframe = vec![0; Gpa::keyframe_bytes(&grid)];
        Ok(Pipeline { grid, table, ring, keyframe })
    }

    /// Runs every frame of the recording through remap + GPA, in order.
    pub fn run(
        &mut self,
        recording: &Recording,
        config: &DetectConfig,
        on_frame: impl FnMut(FrameOutcome, &Gpa),
    ) -> Result<(), String> {
        self.run_with(recording, config, |_, _| {}, on_frame)
    }

    /// As [`Pipeline::run`], with `alter` applied to each frame after loading
    /// (the tests' perturbations: noise, gain changes).
    pub fn run_with(
        &mut self,
        recording: &Recording,
        config: &DetectConfig,
        mut alter: impl FnMut(u32, &mut crate::recording::Frame),
        mut on_frame: impl FnMut(FrameOutcome, &Gpa),
    ) -> Result<(), String> {
        let mut gpa = Gpa::new(&recording.rig, &self.grid, &self.table, config.gpa, &mut self.keyframe)
            .map_err(|e| format!("detector: {e:?}"))?;
        let mut gti = Box::new(GtiStage::new(&recording.rig, &self.grid).map_err(|e| format!("GTI: {e}"))?);
        let mut stream = StreamingRemap::new(&self.table, &mut self.ring).map_err(|e| e.to_string())?;
        let grid_width = self.grid.width();
        let first = recording.frames.first().copied().unwrap_or(0);
        let last = recording.frames.last().copied().unwrap_or(0);
        let mut previous: Option<(u32, f64, flatland_core::motion::Pose)> = None;
        for index in first..=last {
            let frame = match recording.load_frame(index) {
                Ok(mut frame) => {
                    alter(index, &mut frame);
                    frame
                }
                Err(error) => {
                    // A missing or broken frame is a gap: the next good frame
                    // restarts the keyframe rather than raise a false alarm.
                    gpa.reset_keyframe();
                    previous = None;
                    on_frame(FrameOutcome::Skipped { frame: index, error }, &gpa);
                    continue;
                }
            };
            let pose = recording.pose(index).copied();
            if let (Some((before, t_before, _)), Some(row)) = (previous, pose) {
                if row.t_s <= t_before {
                    // Time went backwards: this row's pose cannot be trusted,
                    // so neither can the motion to or from it.
                    gpa.reset_keyframe();
                    previous = None;
                    let error = RecordingError::Csv {
                        path: recording.dir.join("poses.csv"),
                        line: row.line,
                        message: format!("frame {index} at t = {} s is not after frame {before} at t = {t_before} s", row.t_s),
                    };
                    on_frame(FrameOutcome::Skipped { frame: index, error }, &gpa);
                    continue;
                }
            }
            let odometry = match (previous, pose) {
                (Some((before, _, from)), Some(row)) if before + 1 == index => Some(Motion::between(&from, &row.pose)),
                _ => None,
            };
            if pose.is_none() {
                eprintln!("flatland: frame {index}: no row in poses.csv; restarting the keyframe");
                gpa.reset_keyframe();
            }
            gpa.begin_frame(index, odometry);
            let mut kg = vec![0u8; self.grid.len()];
            let table = &self.table;
            for camera_row in frame.pixels.chunks_exact(frame.width) {
                stream
                    .push_row(camera_row, |j, kg_row| {
                        gpa.on_kg_row(j, kg_row);
                        gti.on_kg_row(j, kg_row, table.valid_columns(j));
                        kg[j * grid_width..][..grid_width].copy_from_slice(kg_row);
                    })
                    .map_err(|e| format!("frame {index}: {e}"))?;
            }
            let report = gpa.end_frame();
            gti.end_frame(odometry);
            let outcome = match report {
                Some(mut report) => {
                    gti.enrich(&mut report);
                    FrameOutcome::Report { report, kg }
                }
                None => FrameOutcome::Keyframe { frame: index, kg },
            };
            on_frame(outcome, &gpa);
            previous = pose.map(|row| (index, row.t_s, row.pose));
        }
        Ok(())
    }
}

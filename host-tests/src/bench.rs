//! `flatland bench`: wall-clock figures of one detection cycle per stage,
//! single-threaded, with warm-up and medians (a small harness in the spirit
//! of criterion: the stages take tens to hundreds of microseconds, so each
//! sample is a whole cycle and the median drops scheduler noise).
//!
//! A detection cycle is what the firmware does per frame, GTI aside: the
//! previous frame is the keyframe; the frame's camera rows stream through
//! the remap into the GPA, then the decision. Each sample re-makes the
//! keyframe from the previous frame so every sample does the same work.
//! The figures are the pipeline's own stage timing (`FrameTiming`, as
//! `cargo fw-bench` prints) and GPA's profile, from the x86 time-stamp
//! counter; its reads add a little.

use crate::detect::{push_frame, DetectConfig, Detector, Heights};
use crate::recording::Recording;
use flatland_core::geometry::{Aoi, Pixel, Rig};
use flatland_core::gpa::{GpaConfig, GpaProfile};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::limits::MAX_GRID_SIDE;
use flatland_core::pipeline::{FrameTiming, PoseSample};
use std::fmt::Write as _;
use std::hint::black_box;
#[cfg(not(target_arch = "x86_64"))]
use std::sync::OnceLock;
use std::time::Instant;

/// Samples per figure after the warm-up.
const SAMPLES: usize = 300;
const WARM_UP: usize = 30;

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// The pipeline's and GPA's profile clock, read ~9 times per KG row: the x86 time-stamp
/// counter (a few ns per read; `Instant::now` costs ~20 ns, which would show
/// in the stages), elsewhere nanoseconds since first use. Wrapping.
fn ticks() -> u32 {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: rdtsc is available on every x86_64 CPU.
    unsafe {
        core::arch::x86_64::_rdtsc() as u32
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        static START: OnceLock<Instant> = OnceLock::new();
        START.get_or_init(Instant::now).elapsed().as_nanos() as u32
    }
}

/// Profile clock ticks per microsecond, measured against `Instant` over 20 ms.
fn ticks_per_us() -> f64 {
    let (start, first) = (Instant::now(), ticks());
    while start.elapsed().as_millis() < 20 {
        std::hint::spin_loop();
    }
    f64::from(ticks().wrapping_sub(first)) / (start.elapsed().as_secs_f64() * 1e6)
}

/// The full-frame worst case (`--full-frame` of `flatland bench` and
/// `cargo fw-bench`): the rig with its AOI replaced by a square of 255 x 255
/// steps of `mm_per_px`, and a grid without margins, so the KG grid is
/// exactly 256x256 and the AOI is all of it.
#[derive(Clone, Copy, Debug)]
pub struct FullFrame {
    pub rig: Rig,
    pub mm_per_px: f64,
}

/// Resolution steps when choosing: a multiple of this (mm), as `KgGrid::for_rig` rounds.
const FULL_FRAME_QUANTUM_MM: f64 = 1.0 / 16.0;

impl FullFrame {
    /// `mm_per_px`: the given one, else the rig's own KG resolution
    /// (`KgGrid::for_rig` with the default config), or the largest multiple
    /// of 1/16 mm below it at which the square fits in the camera's view
    /// (a smaller square fits wherever a larger one does). The square's near
    /// edge is the rig's AOI near edge, moved the least needed to be in view.
    /// Errors when no square at that resolution is in view.
    pub fn for_rig(rig: &Rig, mm_per_px: Option<f64>) -> Result<FullFrame, String> {
        let mm_per_px = match mm_per_px {
            Some(mm) if mm.is_finite() && mm > 0.0 => mm,
            Some(mm) => return Err(format!("--mm-per-px {mm}: must be > 0")),
            None => {
                let own = KgGrid::for_rig(rig, &GridConfig::default()).map_err(|e| format!("KG grid: {e}"))?.mm_per_px;
                let quanta = (own / FULL_FRAME_QUANTUM_MM).floor() as u32;
                if near_edges(rig, own).is_some() {
                    own
                } else {
                    // Largest k in 1..quanta whose square fits (fitting is monotonic in k).
                    let (mut fits, mut fails) = (0u32, quanta);
                    while fails - fits > 1 {
                        let k = (fits + fails) / 2;
                        if near_edges(rig, f64::from(k) * FULL_FRAME_QUANTUM_MM).is_some() {
                            fits = k;
                        } else {
                            fails = k;
                        }
                    }
                    if fits == 0 {
                        return Err("no 256x256 square AOI is in the camera's view".into());
                    }
                    f64::from(fits) * FULL_FRAME_QUANTUM_MM
                }
            }
        };
        let (first, last) = near_edges(rig, mm_per_px).ok_or_else(|| {
            format!("a 256x256 square AOI at {mm_per_px} mm/px ({:.0} mm) does not fit in the camera's view", side_mm(mm_per_px))
        })?;
        let near_mm = rig.aoi().near_mm.clamp(first, last);
        let rig = square_rig(rig, mm_per_px, near_mm).map_err(|e| format!("full-frame rig: {e}"))?;
        let full = FullFrame { rig, mm_per_px };
        // Rounding of an inexact resolution can add a row or lose an AOI column.
        let grid = KgGrid::for_rig(&rig, &full.grid_config()).map_err(|e| format!("full-frame grid at {mm_per_px} mm/px: {e}"))?;
        let side = MAX_GRID_SIDE;
        if (grid.width(), grid.height(), grid.aoi_pixels(&rig).area()) != (side, side, side * side) {
            return Err(format!(
                "at {mm_per_px} mm/px the full-frame grid is {}x{}, not {side}x{side} all AOI (use a multiple of 1/16 mm)",
                grid.width(),
                grid.height()
            ));
        }
        Ok(full)
    }

    /// The grid configuration: no margins, the fixed resolution.
    pub fn grid_config(&self) -> GridConfig {
        GridConfig::without_margins(Some(self.mm_per_px))
    }
}

/// The square's side: 255 pixel steps, so 256 pixel centres.
fn side_mm(mm_per_px: f64) -> f64 {
    (MAX_GRID_SIDE - 1) as f64 * mm_per_px
}

/// `rig` with the square AOI at `mm_per_px` whose near edge is `near_mm`;
/// `Rig::new_checked` refuses an AOI that is not in view.
fn square_rig(rig: &Rig, mm_per_px: f64, near_mm: f64) -> Result<Rig, flatland_core::geometry::RigError> {
    let side = side_mm(mm_per_px);
    Rig::new_checked(*rig.camera(), *rig.mount(), Aoi { half_width_mm: side / 2.0, near_mm, far_mm: near_mm + side })
}

/// The nearest and farthest near edges (mm, on a quarter-pixel step) at
/// which the square at `mm_per_px` is in view; None if nowhere. Scans from
/// the ground seen by the bottom image row to the top row's (or 50 camera
/// heights when the top row is above the horizon).
fn near_edges(rig: &Rig, mm_per_px: f64) -> Option<(f64, f64)> {
    let camera = rig.camera();
    let ground_z = |v: f64| rig.pixel_to_ground(Pixel { u: camera.cx, v }).map(|(_, z)| z);
    // Near edges on multiples of 1/16 mm, so the AOI's extents stay exact
    // in binary floating point and the grid comes out exactly 256 wide and high.
    let quantum = FULL_FRAME_QUANTUM_MM;
    let start = (ground_z(f64::from(camera.height) - 1.0)?.max(quantum) / quantum).ceil() * quantum;
    let end = ground_z(0.0).unwrap_or(start + 50.0 * rig.height_mm()) - side_mm(mm_per_px);
    let step = (mm_per_px / 4.0 / quantum).ceil() * quantum;
    let mut found: Option<(f64, f64)> = None;
    let mut near = start;
    while near <= end {
        match (square_rig(rig, mm_per_px, near).is_ok(), found) {
            (true, None) => found = Some((near, near)),
            (true, Some((first, _))) => found = Some((first, near)),
            (false, Some(_)) => break,
            (false, None) => {}
        }
        near += step;
    }
    found
}

/// Runs the benchmark; returns the `key: value` lines. `full_frame`: the
/// worst case of [`FullFrame`] instead of the rig's AOI and margins.
/// The benchmark's set-up: recording, grid, search window, pairs, samples.
fn header(recording: &Recording, rig: &Rig, detector: &Detector, search: usize, full_frame: bool, pairs: usize) -> String {
    let mut out = String::new();
    let (grid, table) = (&detector.front_end.grid, &detector.front_end.table);
    let aoi = grid.aoi_pixels(rig);
    let valid: usize = (0..grid.height()).map(|j| table.valid_columns(j).len()).sum();
    let _ = writeln!(out, "recording: {}", recording.dir.display());
    if full_frame {
        let a = rig.aoi();
        let _ = writeln!(
            out,
            "full_frame: AOI x +-{} mm, z {}..{} mm, no margins",
            a.half_width_mm, a.near_mm, a.far_mm
        );
    }
    let _ = writeln!(out, "grid: {}x{}", grid.width(), grid.height());
    let _ = writeln!(out, "mm_per_px: {}", grid.mm_per_px);
    let _ = writeln!(out, "search: {search} ({} shifts)", (2 * search + 1).pow(2));
    let _ = writeln!(out, "aoi_pixels: {}", aoi.area());
    let _ = writeln!(out, "valid_kg_pixels: {valid} of {} ({:.1} %, seen by the camera)", grid.len(), 100.0 * valid as f64 / grid.len() as f64);
    let _ = writeln!(out, "pairs: {pairs}");
    let _ = writeln!(out, "samples: {SAMPLES} after {WARM_UP} warm-up, median, one thread");
    out
}

/// What [`run_bench`] measured: its `key: value` text, and the two cycles
/// the OpenCV anchor is set beside (medians, us).
pub struct BenchRun {
    pub text: String,
    pub seed_cycle_us: f64,
    pub cycle_us: f64,
}

pub fn run_bench(recording: &Recording, mm_per_px: Option<f64>, search: usize, full_frame: bool) -> Result<BenchRun, String> {
    let (rig, grid_config) = if full_frame {
        let full = FullFrame::for_rig(&recording.rig, mm_per_px)?;
        (full.rig, full.grid_config())
    } else {
        (recording.rig, GridConfig { mm_per_px, ..GridConfig::default() })
    };
    let config = DetectConfig { grid: grid_config, gpa: GpaConfig { search_radius: search, ..GpaConfig::default() } };
    let mut detector = Detector::new(&rig, &config)?;
    // Frames and poses of every consecutive pair.
    let mut pairs = Vec::new();
    for window in recording.frames.windows(2) {
        let (a, b) = (window[0], window[1]);
        let (Some(pa), Some(pb)) = (recording.pose(a), recording.pose(b)) else { continue };
        if b != a + 1 {
            continue;
        }
        let frames = (recording.load_frame(a).map_err(|e| e.to_string())?, recording.load_frame(b).map_err(|e| e.to_string())?);
        pairs.push(((a, PoseSample::from(pa), frames.0), (b, PoseSample::from(pb), frames.1)));
    }
    if pairs.is_empty() {
        return Err("no consecutive frames with poses".into());
    }

    let mut out = header(recording, &rig, &detector, search, full_frame, pairs.len());

    // Each sample: frame a becomes the keyframe, then b is the detection
    // cycle, timed per stage by the pipeline with the profile clock.
    let tick_rate = ticks_per_us();
    let (timings, profiles) = detector.with_pipeline(Heights::GpaOnly, |pipeline| {
        pipeline.set_clock(Some(ticks));
        let mut samples: Vec<(FrameTiming, GpaProfile)> = Vec::with_capacity(SAMPLES);
        for n in 0..WARM_UP + SAMPLES {
            let (keyframe, current) = &pairs[n % pairs.len()];
            pipeline.restart();
            for (index, pose, frame) in [keyframe, current] {
                pipeline.begin(*index, *pose).map_err(|e| e.to_string())?;
                push_frame(pipeline, frame, |_, _| {}).map_err(|e| e.to_string())?;
                black_box(pipeline.finish().map_err(|e| e.to_string())?);
            }
            if n >= WARM_UP {
                samples.push((pipeline.timing(), pipeline.gpa().profile()));
            }
        }
        Ok(samples.into_iter().unzip::<_, _, Vec<_>, Vec<_>>())
    })?;
    let us = |ticks: u32| f64::from(ticks) / tick_rate;
    let stage = |f: fn(&FrameTiming) -> u32| median(timings.iter().map(|t| us(f(t))).collect());
    let gpa_stage = |f: fn(&GpaProfile) -> u32| median(profiles.iter().map(|p| us(f(p))).collect());

    // The OpenCV anchor's cycle (remap, |diff| over the (2S+1)^2 shifts,
    // histogram) within the GPA: the remap, the keyframe warped by the
    // motion (the anchor shifts by whole pixels instead), the shift
    // searches with their histograms (the (2S+1)^2 shifts run in the
    // seed's search when there is a motion estimate, else in the one
    // around the measured motion), and the decision's own part. The warp
    // is the residue's band too: a little more than the anchor's work.
    // All of GPA runs inside `decision` (at the frame's end, once the
    // motion is measured), so its own part is what the GPA stages leave of it.
    let shifts = 2 * search + 1;
    let (remap_us, decision_us) = (stage(|t| t.remap), stage(|t| t.decision));
    let (warp_us, shift_search_us) = (gpa_stage(|p| p.warp), gpa_stage(|p| p.shift_search));
    let seed_us = median(
        timings
            .iter()
            .zip(&profiles)
            .map(|(t, p)| {
                let stages = [p.warp, p.residue, p.parallax, p.shift_search, p.estimate, p.seed_search];
                let decision_own = stages.iter().fold(t.decision, |left, &stage| left.saturating_sub(stage));
                us(t.remap) + us(p.warp) + us(p.shift_search) + us(p.seed_search) + us(decision_own)
            })
            .collect(),
    );
    let cycle_us = stage(|t| t.cycle);

    let _ = writeln!(out, "remap_us_median: {remap_us:.1}");
    let _ = writeln!(out, "gpa_rows_us_median: {:.1}", stage(|t| t.detector_rows));
    let _ = writeln!(out, "gpa_warp_us_median: {warp_us:.1}");
    let _ = writeln!(out, "gpa_residue_us_median: {:.1}", gpa_stage(|p| p.residue));
    let _ = writeln!(out, "gpa_parallax_us_median: {:.1}", gpa_stage(|p| p.parallax));
    let _ = writeln!(out, "gpa_shift_search_us_median: {shift_search_us:.1} (with the histogram)");
    let _ = writeln!(out, "gpa_keyframe_update_us_median: {:.1}", gpa_stage(|p| p.keyframe_update));
    let _ = writeln!(out, "gpa_estimate_us_median: {:.1}", gpa_stage(|p| p.estimate));
    let _ = writeln!(out, "gpa_estimate_coarse_us_median: {:.1}", gpa_stage(|p| p.estimate_coarse));
    let _ = writeln!(out, "gpa_estimate_align_us_median: {:.1}", gpa_stage(|p| p.estimate_align));
    let _ = writeln!(out, "gpa_estimate_pyramids_us_median: {:.1}", gpa_stage(|p| p.estimate_pyramids));
    let _ = writeln!(out, "gpa_estimate_nearest_surface_us_median: {:.1}", gpa_stage(|p| p.estimate_nearest_surface));
    let _ = writeln!(out, "gpa_estimate_lower_level_us_median: {:.1}", gpa_stage(|p| p.estimate_lower_level));
    let _ = writeln!(out, "gpa_seed_search_us_median: {:.1}", gpa_stage(|p| p.seed_search));
    let _ = writeln!(out, "decision_us_median: {decision_us:.1}");
    let _ = writeln!(
        out,
        "seed_cycle_us_median: {seed_us:.1} (remap + warp + the shift searches, {} shifts, with their histograms + the decision's own part: the OpenCV anchor's work)",
        shifts * shifts
    );
    let _ = writeln!(out, "cycle_us_median: {cycle_us:.1}");
    Ok(BenchRun { text: out, seed_cycle_us: seed_us, cycle_us })
}

/// Runs the OpenCV reference cycle (`opencv_cycle REC [--mm-per-px X]
/// --search S`, ../shared/reference) on the same recording, right after
/// [`run_bench`] in the same sitting, and sets it beside: `key: value`
/// lines with its median and both ratios (its cycle over ours: above 1,
/// ours is faster).
pub fn against_opencv(opencv_cycle: &std::path::Path, recording: &std::path::Path, mm_per_px: Option<f64>, search: usize, ours: &BenchRun) -> Result<String, String> {
    let mut command = std::process::Command::new(opencv_cycle);
    command.arg(recording).args(["--search", &search.to_string()]);
    if let Some(mm) = mm_per_px {
        command.args(["--mm-per-px", &mm.to_string()]);
    }
    let output = command.output().map_err(|e| format!("{}: {e}", opencv_cycle.display()))?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let median = stdout
        .lines()
        .find_map(|line| line.strip_prefix("cycle_us_median:"))
        .and_then(|value| value.trim().parse::<f64>().ok())
        .filter(|&us| output.status.success() && us > 0.0)
        .ok_or_else(|| format!("{}: no cycle_us_median (exit {}): {}", opencv_cycle.display(), output.status, String::from_utf8_lossy(&output.stderr).trim()))?;
    let mut out = String::new();
    let _ = writeln!(out, "opencv_cycle_us_median: {median:.1}");
    let _ = writeln!(out, "seed_cycle_speedup_over_opencv: {:.2} (goal: at least 5)", median / ours.seed_cycle_us);
    let _ = writeln!(out, "cycle_speedup_over_opencv: {:.2} (goal: at least 1, the whole cycle as fast as the anchor's seed cycle)", median / ours.cycle_us);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference's median becomes both speedups; a run that prints no
    /// median (or fails) is an error, not a ratio. A two-line script
    /// stands in for the reference, which lives outside the repository.
    #[test]
    fn opencv_medians_become_speedups() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("flatland-opencv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let script = |name: &str, body: &str| {
            let path = dir.join(name);
            std::fs::write(&path, format!("#!/bin/sh\n{body}\n")).unwrap();
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
            path
        };
        let ours = BenchRun { text: String::new(), seed_cycle_us: 40.0, cycle_us: 400.0 };
        let answers = script("answers", "echo \"remap_us_median: 9.0\"; echo \"cycle_us_median: 200.0\"");
        let out = against_opencv(&answers, std::path::Path::new("REC"), Some(5.0), 2, &ours).unwrap();
        assert!(out.contains("opencv_cycle_us_median: 200.0\n"), "{out}");
        assert!(out.contains("seed_cycle_speedup_over_opencv: 5.00 "), "{out}");
        assert!(out.contains("cycle_speedup_over_opencv: 0.50 "), "{out}");
        let fails = script("fails", "echo \"cycle_us_median: 200.0\"; exit 3");
        assert!(against_opencv(&fails, std::path::Path::new("REC"), None, 2, &ours).is_err());
        let silent = script("silent", "true");
        assert!(against_opencv(&silent, std::path::Path::new("REC"), None, 2, &ours).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
    use crate::qemu::workspace_root;
    use flatland_core::remap::RemapTable;

    fn rig(name: &str) -> Rig {
        Recording::open(workspace_root().join("host-tests/data").join(name)).expect("recording").rig
    }

    #[test]
    fn full_frame_is_256_square_all_aoi_in_view() {
        for (name, mm) in [("flat_marks", None), ("flat_marks", Some(5.0)), ("qvga_curb", None)] {
            let full = FullFrame::for_rig(&rig(name), mm).expect("full frame");
            let grid = KgGrid::for_rig(&full.rig, &full.grid_config()).expect("grid");
            assert_eq!((grid.width(), grid.height()), (MAX_GRID_SIDE, MAX_GRID_SIDE), "{name}");
            assert_eq!(grid.aoi_pixels(&full.rig).area(), MAX_GRID_SIDE * MAX_GRID_SIDE, "{name}");
            let table = RemapTable::new(&full.rig, &grid).expect("table");
            let valid: usize = (0..grid.height()).map(|j| table.valid_columns(j).len()).sum();
            assert_eq!(valid, grid.len(), "{name}: every KG pixel seen");
        }
    }

    #[test]
    fn full_frame_refuses_a_square_out_of_view() {
        assert!(FullFrame::for_rig(&rig("flat_marks"), Some(40.0)).is_err());
    }
}

//! `flatland detect`'s output: the csv or JSON rows, the pictures, and the
//! confusion table against truth.toml.

use super::{fatal, Format, Pictures, Sensors};
use flatland_core::report::{FrameReport, CSV_HEADER, MOTION_SCALE, SHIFT_SCALE};
use flatland_core::scan::{Scan, Sector, SCAN_INCREMENT_MDEG};
use flatland_host::cells::{cells_csv, CELLS_HEADER};
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::evaluate::{is_grace, score, score_hazard};
use flatland_host::perturb::Perturbation;
use flatland_host::pictures::animation::Animation;
use flatland_host::pictures::frame::{frame_picture, key_colours, FrameInputs, FrameLayout, GIF_SCALE, PNG_SCALE};
use flatland_host::pictures::summary::summary_picture;
use flatland_host::recording::{Frame, Hazard, Truth};
use std::cell::RefCell;
use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

/// One `detect --format json` row: the csv's fields (the attitude ones
/// left out) and the scan.
#[derive(serde::Serialize)]
struct JsonRow {
    frame: u32,
    ref_frame: u32,
    alarm: bool,
    nearest_mm: Option<i32>,
    left_mm: Option<i32>,
    right_mm: Option<i32>,
    sad: u32,
    count50: u32,
    shift_k: Decimal,
    shift_g: Decimal,
    tx_mm: Decimal,
    tz_mm: Decimal,
    obstacle_h_mm: Option<i32>,
    status: String,
    scan: JsonScan,
}

/// The scan as JSON: hazard ranges in mm, `"inf"` free, null unknown.
#[derive(serde::Serialize)]
struct JsonScan {
    angle_start_deg: Decimal,
    increment_deg: Decimal,
    range_min_mm: u16,
    range_max_mm: u16,
    ranges_mm: Vec<JsonRange>,
}

/// A fixed-point value written as the csv writes it: shortest decimal, no
/// `.0` on whole numbers.
struct Decimal(f64);

impl serde::Serialize for Decimal {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        if self.0.fract() == 0.0 {
            serializer.serialize_i64(self.0 as i64)
        } else {
            serializer.serialize_f64(self.0)
        }
    }
}

struct JsonRange(Sector);

impl serde::Serialize for JsonRange {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self.0 {
            Sector::Unknown => serializer.serialize_none(),
            Sector::Free => serializer.serialize_str("inf"),
            Sector::Hazard(range) => serializer.serialize_u16(range),
        }
    }
}

fn json_row(report: &FrameReport, scan: &Scan) -> String {
    let layout = scan.layout();
    let row = JsonRow {
        frame: report.frame,
        ref_frame: report.ref_frame,
        alarm: report.alarm,
        nearest_mm: report.nearest_mm,
        left_mm: report.left_mm,
        right_mm: report.right_mm,
        sad: report.sad,
        count50: report.count50,
        shift_k: Decimal(f64::from(report.shift_k) / f64::from(SHIFT_SCALE)),
        shift_g: Decimal(f64::from(report.shift_g) / f64::from(SHIFT_SCALE)),
        tx_mm: Decimal(f64::from(report.tx) / f64::from(MOTION_SCALE)),
        tz_mm: Decimal(f64::from(report.tz) / f64::from(MOTION_SCALE)),
        obstacle_h_mm: report.obstacle_h_mm,
        status: report.status.to_string(),
        scan: JsonScan {
            angle_start_deg: Decimal(f64::from(layout.angle_start_mdeg()) / 1000.0),
            increment_deg: Decimal(f64::from(SCAN_INCREMENT_MDEG) / 1000.0),
            range_min_mm: layout.range_min_mm,
            range_max_mm: layout.range_max_mm,
            ranges_mm: scan.sectors().map(JsonRange).collect(),
        },
    };
    serde_json::to_string(&row).expect("plain fields serialise")
}

/// The recording's name for the pictures: its directory's.
fn recording_name(path: &Path) -> String {
    let path = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

pub(crate) fn run_detect(
    path: &Path,
    format: Format,
    pictures: Pictures,
    truth: bool,
    perturbation: Option<Box<Perturbation>>,
    verbose: bool,
    sensors: &Sensors,
) -> ExitCode {
    let mut recording = match sensors.open(path) {
        Ok(r) => r,
        Err(e) => return fatal(e),
    };
    let mut perturber = perturbation.map(|p| p.apply(&mut recording));
    let mut detector = match Detector::new(&recording.rig, &DetectConfig::default()) {
        Ok(d) => d,
        Err(e) => return fatal(format!("{}: {e}", path.display())),
    };
    if let Some(dir) = pictures.dir {
        if let Err(e) = std::fs::create_dir_all(dir) {
            return fatal(format!("{}: {e}", dir.display()));
        }
    }
    let grid = detector.grid();
    let name = recording_name(path);
    let png_layout = FrameLayout::new(&recording.rig, &grid, PNG_SCALE);
    let gif_layout = FrameLayout::new(&recording.rig, &grid, GIF_SCALE);
    let mut animation = match pictures.gif.map(|file| Animation::create(file, gif_layout.width, gif_layout.height, &key_colours()).map_err(|e| format!("{}: {e}", file.display()))) {
        None => None,
        Some(Ok(animation)) => Some(animation),
        Some(Err(e)) => return fatal(e),
    };
    let mut reports = Vec::new();
    let mut previous_kg: Option<Vec<u8>> = None;
    // The camera frame as the pipeline saw it (binned, perturbed), for the pictures.
    let camera: RefCell<Option<Frame>> = RefCell::new(None);
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if format == Format::Csv {
        let _ = writeln!(out, "{CSV_HEADER}");
    }
    let mut picture_error = None;
    // The cells table and its path, for the errors.
    let mut cells = match pictures.cells.map(|path| (path, std::fs::File::create(path).map(std::io::BufWriter::new))) {
        None => None,
        Some((path, Ok(mut file))) => {
            let _ = writeln!(file, "{CELLS_HEADER}");
            Some((path, file))
        }
        Some((path, Err(e))) => return fatal(format!("{}: {e}", path.display())),
    };
    let camera_height_mm = recording.rig.height_mm();
    let alter = |index: u32, frame: &mut Frame| {
        if let Some(p) = perturber.as_mut() {
            p.alter(index, frame)
        }
        if pictures.per_frame() {
            *camera.borrow_mut() = Some(frame.clone());
        }
    };
    let result = detector.run_with(&recording, alter, |outcome, pipeline| match outcome {
        FrameOutcome::Report { report, kg } => {
            let gpa = pipeline.gpa();
            let judged = report.is_judged();
            let line = match format {
                Format::Csv => {
                    let mut line = String::new();
                    let _ = report.write_csv(&mut line);
                    line
                }
                Format::Json if judged => json_row(&report, gpa.scan()),
                // Nothing compared: every sector unknown (the detector's
                // scan is the last judged frame's).
                Format::Json => json_row(&report, &Scan::new(gpa.scan().layout())),
            };
            let _ = writeln!(out, "{line}");
            if verbose {
                match report.status.judged() {
                    Ok(()) => eprintln!("frame {}: {:?}", report.frame, gpa.alarm_source()),
                    Err(reason) => eprintln!("frame {}: not judged ({}): {reason}", report.frame, report.status),
                }
            }
            if let (true, Some((path, file))) = (judged, cells.as_mut()) {
                if let Err(e) = file.write_all(cells_csv(report.frame, gpa, &grid, camera_height_mm).as_bytes()) {
                    picture_error.get_or_insert(format!("{}: {e}", path.display()));
                }
            }
            // Pictures are of the frames compared.
            if let (true, true, Some(reference), Some(frame)) = (judged, pictures.per_frame(), previous_kg.as_ref(), camera.borrow().as_ref()) {
                let inputs = FrameInputs {
                    name: &name,
                    rig: &recording.rig,
                    grid: &grid,
                    camera: frame,
                    reference_kg: reference,
                    current_kg: &kg,
                    report: &report,
                    gpa,
                    truth: recording.truth.as_ref().map(|t| t.pair(report.frame)),
                    attitude: pictures.attitude,
                };
                if let Some(dir) = pictures.dir {
                    let path = dir.join(format!("{:06}.png", report.frame));
                    if let Err(e) = frame_picture(&inputs, &png_layout).save(&path) {
                        picture_error.get_or_insert(format!("{}: {e}", path.display()));
                    }
                }
                if let (Some(animation), Some(file)) = (animation.as_mut(), pictures.gif) {
                    if let Err(e) = animation.push(&frame_picture(&inputs, &gif_layout)) {
                        picture_error.get_or_insert(format!("{}: {e}", file.display()));
                    }
                }
            }
            if gpa.keyframe_frame() == Some(report.frame) {
                previous_kg = Some(kg);
            }
            reports.push(report);
        }
        FrameOutcome::Keyframe { kg, .. } => previous_kg = Some(kg),
        FrameOutcome::Skipped { frame, error } => {
            eprintln!("flatland: skipping frame {frame}: {error}");
        }
    });
    drop(out);
    if let Err(e) = result {
        return fatal(format!("{}: {e}", path.display()));
    }
    if let Some(e) = picture_error {
        return fatal(e);
    }
    if let Some((path, mut file)) = cells {
        if let Err(e) = file.flush() {
            return fatal(format!("{}: {e}", path.display()));
        }
    }
    if let (Some(animation), Some(file)) = (animation, pictures.gif) {
        if let Err(e) = animation.finish() {
            return fatal(format!("{}: {e}", file.display()));
        }
    }
    if let Some(file) = pictures.summary {
        let written = summary_picture(&name, &reports, recording.truth.as_ref(), recording.rig.aoi())
            .and_then(|picture| picture.save(file).map_err(Into::into));
        if let Err(e) = written {
            return fatal(format!("{}: {e}", file.display()));
        }
    }
    if truth {
        match &recording.truth {
            None => return fatal(format!("{}: no truth.toml", path.display())),
            Some(truth) => print_confusion(truth, &reports),
        }
    }
    ExitCode::SUCCESS
}

fn print_confusion(truth: &Truth, reports: &[FrameReport]) {
    let (c, rows) = score(truth, reports);
    let wrong: Vec<String> = rows
        .iter()
        .filter(|(frame, want, got)| want != got && !is_grace(truth, *frame))
        .map(|(frame, want, _)| format!("{frame}{}", if *want { "(missed)" } else { "(false)" }))
        .collect();
    eprintln!("                 detected alarm   detected clear");
    eprintln!("truth alarm      {:>14}   {:>14}", c.true_alarm, c.missed);
    eprintln!("truth clear      {:>14}   {:>14}", c.false_alarm, c.true_clear);
    let not_judged: Vec<String> = reports.iter().filter(|r| !r.is_judged() && truth.pair(r.frame).is_some()).map(|r| format!("{}({})", r.frame, r.status)).collect();
    eprintln!("grace frames: {} right, {} wrong; unreported: {}", c.grace_right, c.grace_wrong, c.unreported);
    eprintln!("not judged (alarm asserted): {}{}", c.not_judged, if not_judged.is_empty() { String::new() } else { format!(" [{}]", not_judged.join(", ")) });
    eprintln!("errors outside grace frames: {}{}", c.errors(), if wrong.is_empty() { String::new() } else { format!(" [{}]", wrong.join(", ")) });
    for (name, kind) in [("obstacles", Hazard::Obstacle), ("drops", Hazard::Drop)] {
        let (c, _) = score_hazard(truth, reports, Some(kind));
        eprintln!(
            "{name:>9} alone: {} alarms right, {} missed, {} false, {} clear; errors outside grace frames: {}",
            c.true_alarm,
            c.missed,
            c.false_alarm,
            c.true_clear,
            c.errors()
        );
    }
}

//! `flatland`: the host CLI. Runs the same core as the firmware on recordings.

use clap::{Parser, Subcommand};
use flatland_core::grid::GridConfig;
use flatland_core::report::{FrameReport, CSV_HEADER, MOTION_SCALE, SHIFT_SCALE};
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::evaluate::{is_grace, score, score_hazard};
use flatland_host::recording::Hazard;
use flatland_host::images::{detect_picture, save_gray};
use flatland_host::perturb::Perturbation;
use flatland_host::recording::Truth;
use std::io::Write;
use flatland_host::kg::KgFrontEnd;
use flatland_host::recording::Recording;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "flatland", version, about = "Obstacle detection from a tilted camera on a ground robot")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Remap frames into KG images (bird's-eye top views) and write them as PNG.
    Kg {
        /// Recording directory (rig.toml, poses.csv, frames/).
        recording: PathBuf,
        /// Frames to remap, Rust range syntax: A..B (B excluded), A.., ..B.
        #[arg(long, value_parser = parse_frame_range)]
        frames: Option<Range<u32>>,
        /// Output directory for NNNNNN.png and kg.toml.
        #[arg(long)]
        out: PathBuf,
        /// KG resolution in mm of ground per pixel (default: chosen from the rig).
        #[arg(long)]
        mm_per_px: Option<f64>,
    },
    /// Detect obstacles (GPA): one csv/json row per frame from frame 1 on.
    Detect {
        recording: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Csv)]
        format: Format,
        /// Write one picture per frame into this directory.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Compare with truth.toml and print a confusion table (stderr).
        #[arg(long)]
        truth: bool,
        /// Perturb the recording first (testing robustness), e.g.
        /// `noise=3,flicker=0.02,odometry=0.03,bias=0.04,yaw=0.1,seed=7`.
        #[arg(long, value_parser = parse_perturbation)]
        perturb: Option<Perturbation>,
        /// Say on stderr which evidence decided each frame.
        #[arg(long)]
        verbose: bool,
    },
    /// Heights from motion (GTI): points (x, z, h) per frame as CSV on stdout.
    Heights {
        /// Recording directory (rig.toml, poses.csv, frames/).
        recording: PathBuf,
        /// Output format (only csv).
        #[arg(long, value_enum, default_value = "csv")]
        format: HeightsFormat,
        /// Also write GT-images with fitted loci and a top-view height map here.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// Time one detection cycle per stage (remap, GPA rows, decision): medians in us.
    Bench {
        recording: PathBuf,
        /// KG resolution in mm of ground per pixel (default: chosen from the rig).
        #[arg(long)]
        mm_per_px: Option<f64>,
        /// Search radius S: (2S+1)^2 shifts.
        #[arg(long, default_value_t = 2)]
        search: usize,
        /// The worst case: the AOI replaced by a square that makes the KG
        /// grid exactly 256x256 without margins (resolution: `--mm-per-px`,
        /// else the rig's, made finer if the square would leave the view).
        #[arg(long)]
        full_frame: bool,
    },
    /// Serial tools for the firmware's USART1 byte stream.
    #[command(subcommand)]
    Serial(SerialCommand),
}

#[derive(Subcommand)]
enum SerialCommand {
    /// Decode the firmware's serial output (FILE, or stdin when absent or `-`)
    /// into the csv of `flatland detect`.
    Decode { file: Option<PathBuf> },
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Format {
    Csv,
    Json,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum HeightsFormat {
    Csv,
}

fn parse_frame_range(text: &str) -> Result<Range<u32>, String> {
    let (start, end) = text.split_once("..").ok_or_else(|| format!("{text:?} is not a range like 2..10"))?;
    let number = |s: &str, default: u32| -> Result<u32, String> {
        if s.is_empty() {
            Ok(default)
        } else {
            s.parse().map_err(|_| format!("{s:?} is not a frame number"))
        }
    };
    Ok(number(start, 0)?..number(end, u32::MAX)?)
}

/// A fatal error: one line on stderr, exit status 2.
fn fatal(message: impl std::fmt::Display) -> ExitCode {
    eprintln!("flatland: {message}");
    ExitCode::from(2)
}

fn run_kg(recording: &Path, frames: Option<Range<u32>>, out: &Path, mm_per_px: Option<f64>) -> ExitCode {
    let recording = match Recording::open(recording) {
        Ok(r) => r,
        Err(e) => return fatal(e),
    };
    let config = GridConfig { mm_per_px, ..GridConfig::default() };
    let mut front_end = match KgFrontEnd::new(&recording.rig, &config) {
        Ok(f) => f,
        Err(e) => return fatal(e),
    };
    if let Err(e) = std::fs::create_dir_all(out) {
        return fatal(format!("{}: {e}", out.display()));
    }
    if let Err(e) = std::fs::write(out.join("kg.toml"), front_end.grid_toml()) {
        return fatal(format!("{}: {e}", out.join("kg.toml").display()));
    }
    let range = frames.unwrap_or(0..u32::MAX);
    let selected: Vec<u32> = recording.frames.iter().copied().filter(|f| range.contains(f)).collect();
    let mut skipped = 0;
    for (n, &index) in selected.iter().enumerate() {
        let image = match recording.load_frame(index).map_err(|e| e.to_string()).and_then(|frame| front_end.remap(&frame).map_err(|e| e.to_string())) {
            Ok(image) => image,
            Err(e) => {
                eprintln!("flatland: skipping frame {index}: {e}");
                skipped += 1;
                continue;
            }
        };
        let path = out.join(format!("{index:06}.png"));
        if let Err(e) = save_gray(&path, front_end.grid.width(), front_end.grid.height(), &image) {
            return fatal(format!("{}: {e}", path.display()));
        }
        if selected.len() > 20 && (n + 1) % 10 == 0 {
            eprintln!("flatland kg: {}/{} frames", n + 1, selected.len());
        }
    }
    eprintln!(
        "flatland kg: wrote {} KG images ({}x{} at {} mm/px) to {}{}",
        selected.len() - skipped,
        front_end.grid.width,
        front_end.grid.height,
        front_end.grid.mm_per_px,
        out.display(),
        if skipped > 0 { format!(", skipped {skipped}") } else { String::new() }
    );
    ExitCode::SUCCESS
}

fn json_row(report: &FrameReport) -> String {
    let optional = |v: Option<i32>| v.map_or("null".to_string(), |v| v.to_string());
    format!(
        "{{\"frame\":{},\"ref_frame\":{},\"alarm\":{},\"nearest_mm\":{},\"left_mm\":{},\"right_mm\":{},\"sad\":{},\"count50\":{},\"shift_k\":{},\"shift_g\":{},\"tx_mm\":{},\"tz_mm\":{},\"obstacle_h_mm\":{}}}",
        report.frame,
        report.ref_frame,
        report.alarm,
        optional(report.nearest_mm),
        optional(report.left_mm),
        optional(report.right_mm),
        report.sad,
        report.count50,
        f64::from(report.shift_k) / f64::from(SHIFT_SCALE),
        f64::from(report.shift_g) / f64::from(SHIFT_SCALE),
        f64::from(report.tx) / f64::from(MOTION_SCALE),
        f64::from(report.tz) / f64::from(MOTION_SCALE),
        optional(report.obstacle_h_mm),
    )
}

fn parse_perturbation(text: &str) -> Result<Perturbation, String> {
    let mut p = Perturbation::default();
    for item in text.split(',') {
        let (key, value) = item.split_once('=').ok_or_else(|| format!("{item:?} is not key=value"))?;
        let number: f64 = value.parse().map_err(|_| format!("{value:?} is not a number"))?;
        match key {
            "noise" => p.noise_sigma = number,
            "flicker" => p.gain_flicker = number,
            "odometry" => p.odometry_scale_sigma = number,
            "bias" => p.odometry_scale_bias = number,
            "yaw" => p.yaw_sigma_deg = number,
            "seed" => p.seed = number as u64,
            _ => return Err(format!("unknown perturbation {key:?} (noise, flicker, odometry, bias, yaw, seed)")),
        }
    }
    Ok(p)
}

fn run_detect(
    path: &Path,
    format: Format,
    png: Option<&Path>,
    truth: bool,
    perturbation: Option<Perturbation>,
    verbose: bool,
) -> ExitCode {
    let mut recording = match Recording::open(path) {
        Ok(r) => r,
        Err(e) => return fatal(e),
    };
    if let Some(p) = perturbation {
        p.poses(&mut recording);
    }
    let mut detector = match Detector::new(&recording.rig, &DetectConfig::default()) {
        Ok(d) => d,
        Err(e) => return fatal(format!("{}: {e}", path.display())),
    };
    if let Some(dir) = png {
        if let Err(e) = std::fs::create_dir_all(dir) {
            return fatal(format!("{}: {e}", dir.display()));
        }
    }
    let grid = detector.grid();
    let mut reports = Vec::new();
    let mut previous_kg: Option<Vec<u8>> = None;
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    if format == Format::Csv {
        let _ = writeln!(out, "{CSV_HEADER}");
    }
    let mut picture_error = None;
    let result = detector.run_with(&recording, |index, frame| if let Some(p) = perturbation { p.frame(index, frame) }, |outcome, pipeline| match outcome {
        FrameOutcome::Report { report, kg } => {
            let gpa = pipeline.gpa();
            let line = match format {
                Format::Csv => {
                    let mut line = String::new();
                    let _ = report.write_csv(&mut line);
                    line
                }
                Format::Json => json_row(&report),
            };
            let _ = writeln!(out, "{line}");
            if verbose {
                eprintln!("frame {}: {:?}", report.frame, gpa.alarm_source());
            }
            if let (Some(dir), Some(reference)) = (png, previous_kg.as_ref()) {
                let path = dir.join(format!("{:06}.png", report.frame));
                if let Err(e) = detect_picture(&recording.rig, &grid, reference, &kg, &report, gpa).save(&path) {
                    picture_error.get_or_insert(format!("{}: {e}", path.display()));
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
    eprintln!("grace frames: {} right, {} wrong; unreported: {}", c.grace_right, c.grace_wrong, c.unreported);
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

fn run_serial_decode(file: Option<&Path>) -> ExitCode {
    let stdin = std::io::stdin();
    let mut input: Box<dyn std::io::Read> = match file {
        None => Box::new(stdin.lock()),
        Some(path) if path == Path::new("-") => Box::new(stdin.lock()),
        Some(path) => match std::fs::File::open(path) {
            Ok(f) => Box::new(f),
            Err(e) => return fatal(format!("{}: {e}", path.display())),
        },
    };
    match flatland_host::serial_decode::run_serial_decode(&mut input, &mut std::io::stdout().lock()) {
        Ok(summary) => {
            for fault in summary.frame_faults {
                eprintln!("flatland: firmware skipped frame {}: {}", fault.frame, fault.code.as_str());
            }
            ExitCode::SUCCESS
        }
        Err(e) => fatal(e),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Kg { recording, frames, out, mm_per_px } => run_kg(&recording, frames, &out, mm_per_px),
        Command::Detect { recording, format, png, truth, perturb, verbose } => {
            run_detect(&recording, format, png.as_deref(), truth, perturb, verbose)
        }
        Command::Bench { recording, mm_per_px, search, full_frame } => {
            let recording = match Recording::open(&recording) {
                Ok(r) => r,
                Err(e) => return fatal(e),
            };
            match flatland_host::bench::run_bench(&recording, mm_per_px, search, full_frame) {
                Ok(text) => {
                    print!("{text}");
                    ExitCode::SUCCESS
                }
                Err(e) => fatal(e),
            }
        }
        Command::Serial(SerialCommand::Decode { file }) => run_serial_decode(file.as_deref()),
        Command::Heights { recording, format: HeightsFormat::Csv, png } => {
            let recording = match Recording::open(&recording) {
                Ok(r) => r,
                Err(e) => return fatal(e),
            };
            let mut out = std::io::BufWriter::new(std::io::stdout().lock());
            match flatland_host::heights::run_heights(&recording, png.as_deref(), &mut out) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => fatal(e),
            }
        }
    }
}

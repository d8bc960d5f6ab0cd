//! `flatland`: the host CLI. Runs the same core as the firmware on recordings.

use clap::{Parser, Subcommand};
use flatland_core::grid::GridConfig;
use flatland_host::images::save_gray;
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Kg { recording, frames, out, mm_per_px } => run_kg(&recording, frames, &out, mm_per_px),
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

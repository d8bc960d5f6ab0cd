//! `flatland`: the host CLI. Runs the same core as the firmware on recordings.

use clap::{Args, Parser, Subcommand};
use flatland_core::grid::GridConfig;
use flatland_core::scan::write_csv_header;
use flatland_host::detect::{DetectConfig, Detector, FrameOutcome};
use flatland_host::pictures::raster::save_gray;
use flatland_host::perturb::Perturbation;
use std::io::Write;
use flatland_host::kg::KgFrontEnd;
use flatland_host::recording::Recording;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod detect;
use detect::run_detect;

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
    /// Detect obstacles (GPA): one csv/json row per frame after the first,
    /// judged or saying why not (`status`; a frame that cannot be read is
    /// said on stderr, and the one after it says `after_gap`).
    #[command(group(clap::ArgGroup::new("frame_pictures").args(["png", "gif"]).multiple(true)))]
    Detect {
        recording: PathBuf,
        #[arg(long, value_enum, default_value_t = Format::Csv)]
        format: Format,
        /// Write one picture per compared frame into this directory
        /// (NNNNNN.png): a header with the decision, the camera view with
        /// the AOI, the hazard's footprint and the ground marked every
        /// 250 mm, the top views, and a legend.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Write the frame pictures as one animated GIF (half their size).
        #[arg(long)]
        gif: Option<PathBuf>,
        /// Write one picture of the whole run: alarm and nearest distance
        /// against truth.toml, the seed's statistics, motion and attitude.
        #[arg(long)]
        summary: Option<PathBuf>,
        /// Write what every compared frame measured per cell (csv): each
        /// cell with a height, a lag or residue, where it is seen and where
        /// it stands, and the least height and drop the frame's baseline
        /// tells from the ground.
        #[arg(long)]
        cells: Option<PathBuf>,
        /// Align the frame pictures (--png, --gif) by the planar motion only,
        /// ignoring the measured pitch and roll change (shows what attitude
        /// compensation removes).
        #[arg(long, requires = "frame_pictures")]
        png_level: bool,
        /// Compare with truth.toml and print a confusion table (stderr).
        #[arg(long)]
        truth: bool,
        /// Perturb the recording first (testing robustness): KEY=VALUE,... e.g.
        /// `pitch-jitter=0.3,roll-jitter=0.2,seed=7`, `exposure=6:1.25,exposure=12:0.8`,
        /// `vignette=0.7`, `slip=6-9`.
        ///
        /// noise=SIGMA (gray levels), flicker=F (gain within +-F per frame);
        /// odometry=F (per-step scale error sigma), bias=F (constant scale
        /// error), yaw=DEG (per-step sigma); pitch-jitter=DEG, roll-jitter=DEG
        /// (body attitude sigma, white per frame), pitch=FRAME:DEG,
        /// roll=FRAME:DEG (sustained from FRAME on; repeatable, steps add up);
        /// exposure=FRAME:FACTOR (linear-light gain from FRAME on; repeatable,
        /// factors multiply), vignette=F (linear light left at the corners);
        /// slip=A-B (the images stand in pairs A..=B while poses.csv advances;
        /// later images come B-A+1 frames late and the truth follows them);
        /// seed=N. docs/CLI.md describes the models.
        // Boxed: a Perturbation is large beside the other commands' arguments.
        #[arg(long, value_parser = |text: &str| text.parse::<Perturbation>().map(Box::new))]
        perturb: Option<Box<Perturbation>>,
        /// Say on stderr which evidence decided each frame.
        #[arg(long)]
        verbose: bool,
        #[command(flatten)]
        sensors: Sensors,
    },
    /// The polar obstacle scan: one csv row per compared frame,
    /// `frame,angle_start_deg,increment_deg,d0_mm,...`: the nearest hazard
    /// per 2.5-degree sector (angles clockwise from straight ahead, robot
    /// frame), `inf` seen and clear, empty unknown (ROS REP 117).
    Scan {
        /// Recording directory (rig.toml, poses.csv, frames/).
        recording: PathBuf,
        #[command(flatten)]
        sensors: Sensors,
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
        #[command(flatten)]
        sensors: Sensors,
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
        /// The OpenCV reference cycle to set beside, run right after on
        /// the same recording (`../shared/reference/opencv_cycle`): prints
        /// its median and both speedups.
        #[arg(long, value_name = "OPENCV_CYCLE")]
        opencv: Option<PathBuf>,
    },
    /// Estimate the mount (tilt, height, roll, yaw) from a drive over flat
    /// ground: `key: value` lines on stdout.
    Calibrate {
        /// Recording directory (rig.toml is the starting point).
        recording: PathBuf,
        /// Write the corrected rig as RECORDING/rig.calibrated.toml.
        #[arg(long)]
        write: bool,
        /// The known camera height, mm, when the recording has no odometry
        /// (default: rig.toml's); with odometry the height is estimated.
        #[arg(long)]
        height_mm: Option<f64>,
        /// Wheel odometry: `poses` uses poses.csv's where present, `none`
        /// ignores it (the height is then given).
        #[arg(long, value_enum, default_value_t = Source::Poses)]
        odometry: Source,
        /// Intrinsics from a ROS camera_info YAML (camera_calibration's
        /// output) instead of rig.toml's `[camera]`; `--write` writes them too.
        #[arg(long)]
        camera_info: Option<PathBuf>,
    },
    /// Serial tools for the firmware's USART1 byte stream.
    #[command(subcommand)]
    Serial(SerialCommand),
}

#[derive(Subcommand)]
enum SerialCommand {
    /// Decode the firmware's serial output (FILE, or stdin when absent or `-`)
    /// into the csv of `flatland detect`; with `--mavlink`, the `mavlink`
    /// build's stream into the csv of `flatland scan`.
    Decode {
        file: Option<PathBuf>,
        /// The stream is MAVLink 2 (`cargo fw --protocol mavlink --capture`):
        /// one row per OBSTACLE_DISTANCE in `flatland scan`'s form, at its 5-degree
        /// bins from -180 degrees, mm (cm x 10), `inf` free, empty unknown.
        #[arg(long)]
        mavlink: bool,
        /// With `--mavlink`: the recording the stream came from; the first
        /// column is then the frame whose poses.csv time is the message's
        /// time_usec (without it, time_usec itself).
        #[arg(long, requires = "mavlink")]
        recording: Option<PathBuf>,
    },
}

/// Which of poses.csv's sensors a run uses; `t_s` always orders the frames.
#[derive(Args)]
struct Sensors {
    /// Wheel odometry, poses.csv's x_mm,z_mm,yaw_deg: `poses` uses them
    /// where the file has them; `none` ignores them (motion from the images alone).
    #[arg(long, value_enum, default_value_t = Source::Poses)]
    odometry: Source,
    /// IMU attitude, poses.csv's pitch_deg,roll_deg: `poses` uses them where
    /// the file has them; `none` ignores them.
    #[arg(long, value_enum, default_value_t = Source::Poses)]
    imu: Source,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Source {
    /// poses.csv's columns, where present.
    Poses,
    /// Ignored.
    None,
}

impl Sensors {
    /// Opens a recording without the sensors this run ignores.
    fn open(&self, path: &Path) -> Result<Recording, flatland_host::recording::RecordingError> {
        let mut recording = Recording::open(path)?;
        if self.odometry == Source::None {
            recording.ignore_odometry();
        }
        if self.imu == Source::None {
            recording.ignore_imu();
        }
        Ok(recording)
    }
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

/// Which pictures `detect` writes, and whether they compensate the attitude.
struct Pictures<'a> {
    /// One PNG per compared frame.
    dir: Option<&'a Path>,
    /// One animated GIF of the run.
    gif: Option<&'a Path>,
    /// One PNG of the whole run.
    summary: Option<&'a Path>,
    /// One csv row per cell with evidence, per compared frame.
    cells: Option<&'a Path>,
    attitude: bool,
}

impl Pictures<'_> {
    fn per_frame(&self) -> bool {
        self.dir.is_some() || self.gif.is_some()
    }
}

fn run_scan(path: &Path, sensors: &Sensors) -> ExitCode {
    let recording = match sensors.open(path) {
        Ok(r) => r,
        Err(e) => return fatal(e),
    };
    let mut detector = match Detector::new(&recording.rig, &DetectConfig::default()) {
        Ok(d) => d,
        Err(e) => return fatal(format!("{}: {e}", path.display())),
    };
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut header = false;
    let result = detector.run(&recording, |outcome, pipeline| {
        let scan = pipeline.gpa().scan();
        if !header {
            let mut line = String::new();
            let _ = write_csv_header(&scan.layout(), &mut line);
            let _ = writeln!(out, "{line}");
            header = true;
        }
        match outcome {
            FrameOutcome::Report { report, .. } if report.is_judged() => {
                let mut line = String::new();
                let _ = scan.write_csv(&mut line);
                let _ = writeln!(out, "{line}");
            }
            // A frame not judged compared nothing: no scan (the csv of
            // `flatland detect` says why).
            FrameOutcome::Report { .. } | FrameOutcome::Keyframe { .. } => {}
            FrameOutcome::Skipped { frame, error } => eprintln!("flatland: skipping frame {frame}: {error}"),
        }
    });
    drop(out);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fatal(format!("{}: {e}", path.display())),
    }
}

/// FILE, or stdin when absent or `-`.
fn open_input(file: Option<&Path>) -> Result<Box<dyn std::io::Read>, String> {
    Ok(match file {
        None => Box::new(std::io::stdin().lock()),
        Some(path) if path == Path::new("-") => Box::new(std::io::stdin().lock()),
        Some(path) => Box::new(std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?),
    })
}

/// `flatland serial decode --mavlink`: OBSTACLE_DISTANCE as scan csv rows.
fn run_mavlink_decode(file: Option<&Path>, recording: Option<&Path>) -> ExitCode {
    use flatland_host::link::mavlink::{decode, frames_by_time, write_scan_csv, RowKey, ScanCsvError};
    let mut bytes = Vec::new();
    if let Err(e) = open_input(file).and_then(|mut input| input.read_to_end(&mut bytes).map_err(|e| e.to_string())) {
        return fatal(e);
    }
    let frames = match recording.map(Recording::open).transpose() {
        Ok(recording) => recording.as_ref().map(frames_by_time),
        Err(e) => return fatal(e),
    };
    let key = frames.as_ref().map_or(RowKey::TimeUsec, RowKey::Frame);
    let decoded = decode(&bytes);
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    if let Err(e) = write_scan_csv(&decoded, key, &mut out).and_then(|_| out.flush().map_err(ScanCsvError::Io)) {
        return fatal(e);
    }
    if !decoded.errors.is_empty() {
        return fatal(format!("{} MAVLink frame(s) did not decode, the first: {}", decoded.errors.len(), decoded.errors[0]));
    }
    ExitCode::SUCCESS
}

fn run_serial_decode(file: Option<&Path>) -> ExitCode {
    let mut input = match open_input(file) {
        Ok(input) => input,
        Err(e) => return fatal(e),
    };
    match flatland_host::link::serial::run_serial_decode(&mut input, &mut std::io::stdout().lock()) {
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
        Command::Detect { recording, format, png, gif, summary, cells, png_level, truth, perturb, verbose, sensors } => {
            let pictures = Pictures { dir: png.as_deref(), gif: gif.as_deref(), summary: summary.as_deref(), cells: cells.as_deref(), attitude: !png_level };
            run_detect(&recording, format, pictures, truth, perturb, verbose, &sensors)
        }
        Command::Bench { recording: path, mm_per_px, search, full_frame, opencv } => {
            let recording = match Recording::open(&path) {
                Ok(r) => r,
                Err(e) => return fatal(e),
            };
            let ours = match flatland_host::bench::run_bench(&recording, mm_per_px, search, full_frame) {
                Ok(run) => run,
                Err(e) => return fatal(e),
            };
            print!("{}", ours.text);
            let Some(opencv) = opencv else { return ExitCode::SUCCESS };
            if full_frame {
                return fatal("--opencv sets the recording's own cycle beside OpenCV's, not --full-frame's");
            }
            match flatland_host::bench::against_opencv(&opencv, &path, mm_per_px, search, &ours) {
                Ok(text) => {
                    print!("{text}");
                    ExitCode::SUCCESS
                }
                Err(e) => fatal(e),
            }
        }
        Command::Serial(SerialCommand::Decode { file, mavlink: true, recording }) => {
            run_mavlink_decode(file.as_deref(), recording.as_deref())
        }
        Command::Serial(SerialCommand::Decode { file, mavlink: false, .. }) => run_serial_decode(file.as_deref()),
        Command::Calibrate { recording, write, height_mm, odometry, camera_info } => {
            run_calibrate(&recording, write, height_mm, odometry, camera_info.as_deref())
        }
        Command::Scan { recording, sensors } => run_scan(&recording, &sensors),
        Command::Heights { recording, format: HeightsFormat::Csv, png, sensors } => {
            let recording = match sensors.open(&recording) {
                Ok(r) => r,
                Err(e) => return fatal(e),
            };
            let mut out = std::io::BufWriter::new(std::io::stdout().lock());
            match flatland_host::heights::run_heights(&recording, png.as_deref(), &mut out) {
                Ok(no_points) => {
                    if let Some(why) = no_points {
                        eprintln!("flatland heights: no points: {why}");
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => fatal(e),
            }
        }
    }
}

fn run_calibrate(path: &Path, write: bool, height_mm: Option<f64>, odometry: Source, camera_info: Option<&Path>) -> ExitCode {
    use flatland_host::calibration::{
        calibrate_checked, camera_values, mount_values, parse_camera_info, report, with_section_values, CalibrationConfig,
    };
    let mut recording = match Recording::open_for_calibration(path) {
        Ok(r) => r,
        Err(e) => return fatal(e),
    };
    let info = match camera_info.map(|file| std::fs::read_to_string(file).map_err(|e| e.to_string()).and_then(|t| parse_camera_info(&t).map_err(|e| e.to_string()))) {
        None => None,
        Some(Ok(info)) => Some(info),
        Some(Err(e)) => return fatal(format!("{}: {e}", camera_info.unwrap_or(path).display())),
    };
    if let Some(info) = &info {
        let recorded = recording.binning.recorded;
        if (usize::from(info.width), usize::from(info.height)) != recorded {
            return fatal(format!("camera_info is {}x{}, the frames {}x{}: calibrate at the recorded size", info.width, info.height, recorded.0, recorded.1));
        }
        // Binned as the frames are (see recording::Binning).
        let n = recording.binning.factor as f64;
        let (width, height) = recording.binning.size();
        let camera = flatland_core::geometry::Intrinsics {
            width: width as u16,
            height: height as u16,
            fx: info.fx / n,
            fy: info.fy / n,
            cx: (info.cx + 0.5) / n - 0.5,
            cy: (info.cy + 0.5) / n - 0.5,
            distortion: info.distortion,
            // camera_info has no readout: rig.toml's stays.
            readout_ms: recording.rig.camera().readout_ms,
        };
        recording.rig = match flatland_host::recording::rig_with_aoi_in_view(camera, *recording.rig.mount(), *recording.rig.aoi()) {
            Ok(rig) => rig,
            Err(e) => return fatal(format!("rig with the camera_info intrinsics: {e}")),
        };
    }
    let config = CalibrationConfig { height_mm, ignore_odometry: odometry == Source::None };
    // Refused when solves from other starts near rig.toml's disagree.
    let estimate = match calibrate_checked(&recording, &config) {
        Ok(estimate) => estimate,
        Err(e) => return fatal(format!("calibrate {}: {e}", path.display())),
    };
    print!("{}", report(&estimate));
    if write {
        let original = path.join("rig.toml");
        let text = match std::fs::read_to_string(&original) {
            Ok(text) => text,
            Err(e) => return fatal(format!("{}: {e}", original.display())),
        };
        let target = path.join("rig.calibrated.toml");
        let mut edited = with_section_values(&text, "mount", &mount_values(&estimate.mount));
        if let Some(info) = &info {
            edited = edited.and_then(|text| with_section_values(&text, "camera", &camera_values(info)));
        }
        let text = match edited {
            Ok(text) => text,
            Err(e) => return fatal(format!("{}: {e}", original.display())),
        };
        if let Err(e) = std::fs::write(&target, text) {
            return fatal(format!("{}: {e}", target.display()));
        }
        eprintln!("flatland calibrate: wrote {}", target.display());
    }
    ExitCode::SUCCESS
}

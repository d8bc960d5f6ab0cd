//! `flatland heights`: GTI heights from motion over a recording, as CSV and
//! pictures (GT-images with the fitted loci, and a top-view height map).
//!
//! Frames go through the same pipeline as `flatland detect` and the firmware
//! (`detect::Detector`): rows streamed through the remap into GPA and GTI,
//! behind the same odometry gate.

use crate::detect::{DetectConfig, Detector, FrameOutcome};
use crate::pictures::raster::{Anchor, RgbImage};
use crate::recording::{Frame, Recording};
use flatland_core::grid::KgGrid;
use flatland_core::gti::{Gti, GtiConfig, HeightPoint, TrackView};
use flatland_core::motion::Motion;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// Runs the pipeline over every frame of a recording; `each_frame(frame, gti)`
/// is called after each frame it finished, when GTI's points and tracks are
/// current. A frame skipped (unreadable, time going backwards) is said on
/// stderr and restarts GTI's tracks, as it restarts `flatland detect`'s keyframe.
pub fn run_gti(recording: &Recording, each_frame: impl FnMut(u32, &Gti)) -> Result<KgGrid, String> {
    run_gti_perturbed(recording, |_, _| {}, each_frame)
}

/// [`run_gti`] with `perturb(frame, pixels)` applied to each frame as it is
/// loaded (robustness tests: extra sensor noise and the like).
pub fn run_gti_perturbed(
    recording: &Recording,
    perturb: impl FnMut(u32, &mut Frame),
    mut each_frame: impl FnMut(u32, &Gti),
) -> Result<KgGrid, String> {
    let mut detector = Detector::new(&recording.rig, &DetectConfig::default())?;
    detector.run_with(recording, perturb, |outcome, pipeline| {
        let frame = match outcome {
            FrameOutcome::Report { report, .. } => report.frame,
            FrameOutcome::Keyframe { frame, .. } => frame,
            FrameOutcome::Skipped { frame, error } => {
                eprintln!("flatland: skipping frame {frame}: {error}");
                return;
            }
        };
        if let Some(stage) = pipeline.gti() {
            each_frame(frame, stage.gti());
        }
    })?;
    Ok(detector.grid())
}

/// Heights in whole mm, positions in whole mm: what reaches the serial link.
fn csv_row(frame: u32, p: &HeightPoint) -> String {
    // Rounded to integers first: "{:.0}" would print -0 for small negatives.
    let whole = |v: f32| v.round() as i64;
    format!("{frame},{},{},{},{}", whole(p.x_mm), whole(p.z_mm), whole(p.h_mm), p.quality)
}

const CSV_HEADER: &str = "frame,x_mm,z_mm,h_mm,quality";

/// What the pictures need, collected frame by frame.
#[derive(Default)]
struct Drawing {
    /// Per line: one column of samples per frame (None where invalid).
    columns: Vec<Vec<Vec<Option<u8>>>>,
    /// Per track id: line, and per frame (column index) observed/fitted rows.
    loci: BTreeMap<u32, Locus>,
    last_points: Vec<HeightPoint>,
}

struct Locus {
    line: usize,
    observed: Vec<(usize, f32)>,
    fitted: Vec<(usize, f32)>,
    h_mm: Option<f32>,
}

impl Drawing {
    fn record(&mut self, gti: &Gti) {
        let column = self.columns.first().map_or(0, Vec::len);
        let lines = gti.lines().len();
        self.columns.resize_with(lines, Vec::new);
        for (l, columns) in self.columns.iter_mut().enumerate() {
            let column = gti.line_samples(l).map_or_else(Vec::new, |(values, valid)| {
                values.iter().enumerate().map(|(row, &v)| valid.contains(&row).then_some(v)).collect()
            });
            columns.push(column);
        }
        for view in gti.tracks() {
            self.record_track(column, &view);
        }
        self.last_points = gti.points().collect();
    }

    fn record_track(&mut self, column: usize, view: &TrackView) {
        let locus = self.loci.entry(view.id).or_insert(Locus { line: view.line, observed: vec![], fitted: vec![], h_mm: None });
        if let Some(row) = view.observed_row {
            locus.observed.push((column, row));
        }
        if let Some(row) = view.fitted_row {
            locus.fitted.push((column, row));
        }
        if let Some(p) = view.point {
            locus.h_mm = Some(p.h_mm);
        }
    }
}

/// Colour for a height: blue at the floor, green at `full_mm / 2`, red at
/// `full_mm` and above; below the floor (past a drop's edge, more than
/// [`BELOW_FLOOR_MM`] down) violet, darker with depth down to `full_mm`.
fn height_colour(h_mm: f32, full_mm: f32) -> [u8; 3] {
    if h_mm < -BELOW_FLOOR_MM {
        let k = (-h_mm / full_mm).clamp(0.0, 1.0);
        let level = (230.0 * (1.0 - 0.6 * k)) as u8;
        return [level, 0, level];
    }
    let t = (h_mm / full_mm).clamp(0.0, 1.0);
    if t < 0.5 {
        let k = t * 2.0;
        [0, (255.0 * k) as u8, (255.0 * (1.0 - k)) as u8]
    } else {
        let k = (t - 0.5) * 2.0;
        [(255.0 * k) as u8, (255.0 * (1.0 - k)) as u8, 0]
    }
}

/// What GTI saw over a run, to say why it found no point.
#[derive(Default)]
struct Coverage {
    frames: usize,
    /// Frames each track was matched in, by track id.
    matched: BTreeMap<u32, usize>,
    config: GtiConfig,
}

impl Coverage {
    fn record(&mut self, gti: &Gti) {
        self.frames += 1;
        self.config = *gti.config();
        for track in gti.tracks().filter(|t| t.observed_row.is_some()) {
            *self.matched.entry(track.id).or_default() += 1;
        }
    }

    /// Why a run over `recording` that gave no point gave none.
    fn why_no_points(&self, recording: &Recording, grid: &KgGrid) -> String {
        let config = &self.config;
        let steps: Vec<Motion> = recording
            .poses
            .windows(2)
            .filter(|w| w[1].frame == w[0].frame + 1)
            .filter_map(|w| Some(Motion::between(&w[0].pose?, &w[1].pose?)))
            .collect();
        let needed = config.min_observations;
        let longest = self.matched.values().copied().max().unwrap_or(0);
        let long_enough = self.matched.values().filter(|&&n| n >= needed).count();
        if steps.is_empty() {
            return "no odometry between consecutive frames (poses.csv has no x_mm,z_mm,yaw_deg, or --odometry none): \
                    GTI measures heights against the distance travelled"
                .into();
        }
        if self.frames < needed {
            return format!("{} frames were processed; a height needs a feature followed over {needed}", self.frames);
        }
        if long_enough > 0 {
            return format!(
                "{long_enough} features were followed over {needed} frames or more, but none fits a height well enough \
                 (quality >= {})",
                config.min_point_quality
            );
        }
        let mut why = format!("no feature stayed on a GT line for the {needed} frames a height needs (the longest: {longest})");
        // GT lines run along the straight direction of travel (the seed's
        // GTI); a turn sweeps the floor across them.
        let turn_deg = steps.iter().map(|m| m.dyaw_deg.abs()).sum::<f64>() / steps.len() as f64;
        let far_mm = recording.rig.aoi().far_mm;
        let drift_mm = far_mm * turn_deg.to_radians();
        if drift_mm > grid.mm_per_px {
            why += &format!(
                ": the path turns {turn_deg:.1} deg per frame, which moves a point {far_mm:.0} mm ahead {drift_mm:.0} mm \
                 sideways per frame (a KG pixel is {:.1} mm), off GTI's lines, which follow straight travel",
                grid.mm_per_px
            );
        }
        why
    }
}

/// Points lower than this below the floor are drawn apart (a fit's noise
/// scatters floor points a few mm either way).
const BELOW_FLOOR_MM: f32 = 10.0;

/// Runs GTI and writes the CSV to `out`; with `png_dir`, also writes
/// `gt_line_NN.png` (GT-images, time to the right, KG row down, observed
/// edges as dots and fitted loci as lines, coloured by height) and
/// `map.png` (top view of the final frame's points, coloured by height).
/// Returns, when no frame gave a point, why not.
pub fn run_heights(recording: &Recording, png_dir: Option<&Path>, out: &mut impl Write) -> Result<Option<String>, Box<dyn std::error::Error>> {
    let mut drawing = Drawing::default();
    let mut coverage = Coverage::default();
    let mut rows = Vec::new();
    let grid = run_gti(recording, |frame, gti| {
        for p in gti.points() {
            rows.push(csv_row(frame, &p));
        }
        coverage.record(gti);
        if png_dir.is_some() {
            drawing.record(gti);
        }
    })?;
    let no_points = rows.is_empty().then(|| coverage.why_no_points(recording, &grid));
    writeln!(out, "{CSV_HEADER}")?;
    for row in rows {
        writeln!(out, "{row}")?;
    }
    if let Some(dir) = png_dir {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        draw_gt_images(&drawing, &grid, recording.rig.height_mm() as f32, dir)?;
        draw_map(&drawing.last_points, recording, dir)?;
    }
    Ok(no_points)
}

/// Pixels per frame in the GT-images (frames are few, rows many).
const GT_COLUMN_PX: usize = 4;

fn draw_gt_images(drawing: &Drawing, grid: &KgGrid, mount_height_mm: f32, dir: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let full = 0.5 * mount_height_mm;
    for (l, columns) in drawing.columns.iter().enumerate() {
        let width = columns.len() * GT_COLUMN_PX;
        let height = grid.height();
        let mut image = RgbImage::new(width.max(1), height);
        for (c, column) in columns.iter().enumerate() {
            for (row, value) in column.iter().enumerate() {
                let v = value.unwrap_or(0);
                for dx in 0..GT_COLUMN_PX {
                    image.set(c * GT_COLUMN_PX + dx, row, [v / 2 + 40, v / 2 + 40, v / 2 + 40]);
                }
            }
        }
        let x_of = |c: usize| c * GT_COLUMN_PX + GT_COLUMN_PX / 2;
        for locus in drawing.loci.values().filter(|locus| locus.line == l) {
            let Some(h) = locus.h_mm else { continue };
            let colour = height_colour(h, full);
            for pair in locus.fitted.windows(2) {
                let ((c0, r0), (c1, r1)) = (pair[0], pair[1]);
                draw_segment(&mut image, x_of(c0) as f32, r0, x_of(c1) as f32, r1, colour);
            }
            for &(c, row) in &locus.observed {
                image.set(x_of(c), row.round().max(0.0) as usize, [255, 255, 255]);
            }
        }
        let path = dir.join(format!("gt_line_{l:02}.png"));
        image.save(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

fn draw_segment(image: &mut RgbImage, x0: f32, y0: f32, x1: f32, y1: f32, colour: [u8; 3]) {
    let steps = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as usize;
    for k in 0..=steps {
        let t = k as f32 / steps as f32;
        let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
        if x >= 0.0 && y >= 0.0 {
            image.set(x.round() as usize, y.round() as usize, colour);
        }
    }
}

/// Top view: 4 mm per pixel, robot at the bottom centre, AOI outlined,
/// each point a 5x5 square coloured by height; on the right, the colour
/// bar labelled in mm (0 at the bottom to H/2, the colours' top, above).
fn draw_map(points: &[HeightPoint], recording: &Recording, dir: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let path = dir.join("map.png");
    map_picture(points, recording).save(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
}

/// Width of the map's colour bar strip (bar, ticks and labels), px.
pub const COLOUR_BAR_STRIP: usize = 96;
/// The map's scale, mm of ground per px.
pub const MAP_MM_PER_PX: f32 = 4.0;
/// Height of the strip above the map for the colour bar's title, px.
const TITLE_STRIP: usize = 22;
/// The colour bar's left edge within its strip, and its width, px.
pub const BAR_LEFT: usize = 12;
pub const BAR_WIDTH: usize = 18;

/// The map `flatland heights --png` writes as map.png: the map of
/// [`draw_map`], then the colour bar strip.
pub fn map_picture(points: &[HeightPoint], recording: &Recording) -> RgbImage {
    let aoi = recording.rig.aoi();
    let half = aoi.half_width_mm as f32 + 200.0;
    let far = aoi.far_mm as f32 + 300.0;
    let (map_width, map_height) = ((2.0 * half / MAP_MM_PER_PX) as usize, (far / MAP_MM_PER_PX) as usize);
    let (width, height) = (map_width + COLOUR_BAR_STRIP, map_height + TITLE_STRIP);
    let mut image = RgbImage::new(width, height);
    let top = TITLE_STRIP as f32;
    let to_px = |x: f32, z: f32| ((x + half) / MAP_MM_PER_PX, top + (far - z) / MAP_MM_PER_PX);
    let (l, t) = to_px(-aoi.half_width_mm as f32, aoi.far_mm as f32);
    let (r, b) = to_px(aoi.half_width_mm as f32, aoi.near_mm as f32);
    image.rect(l as usize, t as usize, r as usize, b as usize, [90, 90, 90]);
    let full = 0.5 * recording.rig.height_mm() as f32;
    for p in points {
        let (x, y) = to_px(p.x_mm, p.z_mm);
        let colour = height_colour(p.h_mm, full);
        for dy in -2..=2 {
            for dx in -2..=2 {
                let (px, py) = (x + dx as f32, y + dy as f32);
                if px >= 0.0 && py >= top && px < map_width as f32 {
                    image.set(px as usize, py as usize, colour);
                }
            }
        }
    }
    draw_colour_bar(&mut image, map_width, full);
    image
}

/// The colour bar right of the map (`left`): 0 mm at the bottom, `full_mm`
/// (where the colours stop changing) at the top, ticks labelled in mm.
fn draw_colour_bar(image: &mut RgbImage, left: usize, full_mm: f32) {
    let (bar_top, bar_bottom) = (TITLE_STRIP + 8, image.height - 8);
    let span = (bar_bottom - bar_top) as f32;
    let bar_left = left + BAR_LEFT;
    for y in bar_top..=bar_bottom {
        let h = full_mm * (bar_bottom - y) as f32 / span;
        for x in bar_left..bar_left + BAR_WIDTH {
            image.set(x, y, height_colour(h, full_mm));
        }
    }
    let grey = [200, 200, 200];
    image.text(left as i32 + 4, 4, "height mm", 13, grey, Anchor::TopLeft);
    // Ticks at a round step, about five of them.
    let step = [5.0, 10.0, 20.0, 25.0, 50.0, 100.0, 200.0, 250.0, 500.0].into_iter().find(|&s| full_mm / s <= 6.0).unwrap_or(1000.0);
    let mut h = 0.0f32;
    while h <= full_mm + 0.01 {
        let y = (bar_bottom as f32 - h / full_mm * span).round() as i32;
        let x = (bar_left + BAR_WIDTH) as i32;
        image.polyline(&[(x, y), (x + 5, y)], grey, 1);
        let text = if (full_mm - h).abs() < 0.01 { format!(">={h:.0}") } else { format!("{h:.0}") };
        image.text(x + 8, y, &text, 12, grey, Anchor::CentreLeft);
        h += step;
    }
}

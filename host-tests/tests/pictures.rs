//! The pictures a person reads (issue 16): `flatland detect --png`,
//! `--summary`, `--gif` and `flatland heights --png` write pictures that
//! decode, at the size their layout says, with what they claim to show in
//! them; the hazard drawn in the camera view lands on the obstacle's
//! pixels; `--cells` tables what each frame measured per cell; and no
//! picture option changes the csv.

use flatland_core::geometry::Point3;
use flatland_host::detect::{DetectConfig, Detector};
use flatland_host::pictures::frame::{FrameLayout, Hazard, GIF_SCALE, PNG_SCALE};
use flatland_host::heights::{BAR_LEFT, BAR_WIDTH, COLOUR_BAR_STRIP};
use flatland_host::recording::{Recording, TruthObstacle};
use flatland_host::pictures::summary::SUMMARY_SIZE;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::data;

/// A fresh output directory for one test.
fn out_dir(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("pictures").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs `flatland ARGS`; returns stdout, failing on a non-zero exit.
fn flatland(args: &[&str]) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_flatland")).args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "flatland {args:?}: {}\n{stderr}", output.status);
    String::from_utf8(output.stdout).unwrap()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// An 8-bit RGB PNG: (width, height, pixels).
struct Picture {
    width: usize,
    height: usize,
    pixels: Vec<[u8; 3]>,
}

impl Picture {
    fn at(&self, x: usize, y: usize) -> [u8; 3] {
        self.pixels[y * self.width + x]
    }

    /// Pixels of exactly `colour` inside (left, top, width, height).
    fn find(&self, colour: [u8; 3], (left, top, width, height): (usize, usize, usize, usize)) -> Vec<(usize, usize)> {
        let mut found = Vec::new();
        for y in top..top + height {
            for x in left..left + width {
                if self.at(x, y) == colour {
                    found.push((x, y));
                }
            }
        }
        found
    }
}

fn read_png(file: &Path) -> Picture {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(file).unwrap()));
    let mut reader = decoder.read_info().unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let mut buffer = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buffer).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    assert_eq!((info.color_type, info.bit_depth), (png::ColorType::Rgb, png::BitDepth::Eight), "{}", file.display());
    let pixels = buffer[..info.buffer_size()].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Picture { width: info.width as usize, height: info.height as usize, pixels }
}

/// The layout every frame picture of this recording has at `scale`.
fn layout(recording: &Recording, scale: usize) -> FrameLayout {
    let grid = Detector::new(&recording.rig, &DetectConfig::default()).unwrap().grid();
    FrameLayout::new(&recording.rig, &grid, scale)
}

/// csv rows: (frame, alarm).
fn rows(csv: &str) -> Vec<(u32, bool)> {
    csv.lines().skip(1).map(|line| {
        let fields: Vec<&str> = line.split(',').collect();
        (fields[0].parse().unwrap(), fields[2] == "1")
    }).collect()
}

#[test]
fn picture_options_leave_the_csv_and_json_unchanged() {
    let dir = out_dir("unchanged");
    let recording = data("stool_bags");
    let (png, gif, summary) = (dir.join("png"), dir.join("run.gif"), dir.join("summary.png"));
    for format in ["csv", "json"] {
        let plain = flatland(&["detect", path(&recording), "--format", format]);
        let cells = dir.join("cells.csv");
        let with_pictures =
            flatland(&["detect", path(&recording), "--format", format, "--png", path(&png), "--gif", path(&gif), "--summary", path(&summary), "--cells", path(&cells)]);
        assert_eq!(plain, with_pictures, "{format}");
    }
}

/// The cells table explains a frame: on approach_box, a parallax alarm's
/// nearest distance is where a cell with a measured height stands (within
/// a 30 mm cell and its neighbour, as the detector places a group by its
/// cells) in at least 9 frames in 10 (the rest hold an obstacle found on an
/// earlier frame through a short baseline); every row of a frame carries
/// that frame's resolution.
#[test]
fn cells_table_shows_where_the_measured_cells_stand() {
    let dir = out_dir("cells");
    let recording = data("approach_box");
    let table = dir.join("cells.csv");
    let csv = flatland(&["detect", path(&recording), "--cells", path(&table)]);
    let text = std::fs::read_to_string(&table).unwrap();
    let mut lines = text.lines();
    let header = flatland_host::cells::CELLS_HEADER;
    assert_eq!(lines.next(), Some(header));
    let cells: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let column = |name: &str| header.split(',').position(|c| c == name).unwrap();
    let (frame, height, weak, stands, least) = (column("frame"), column("height_mm"), column("weak"), column("stands_at_mm"), column("least_height_mm"));
    let (mut placed, mut alarms) = (0, 0);
    for report in csv.lines().skip(1).map(|l| l.split(',').collect::<Vec<_>>()) {
        let (n, alarm, nearest) = (report[0], report[2], report[3]);
        let rows: Vec<&Vec<&str>> = cells.iter().filter(|c| c[frame] == n).collect();
        assert!(rows.windows(2).all(|w| w[0][least] == w[1][least]), "frame {n}: one resolution a frame");
        let standing: Vec<f64> = rows
            .iter()
            .filter(|c| c[weak] == "0" && c[height].parse::<i32>().unwrap() >= 20 && !c[stands].is_empty())
            .map(|c| c[stands].parse().unwrap())
            .collect();
        if alarm != "1" || nearest.is_empty() || standing.is_empty() {
            continue;
        }
        let nearest: f64 = nearest.parse().unwrap();
        alarms += 1;
        placed += usize::from(standing.iter().any(|z| (z - nearest).abs() <= 60.0));
    }
    assert!(alarms >= 20, "only {alarms} alarms with measured cells");
    assert!(placed * 10 >= alarms * 9, "{placed} of {alarms} alarms stand where a measured cell does");
}

#[test]
fn detect_png_writes_one_annotated_picture_per_compared_frame() {
    let dir = out_dir("png");
    for name in ["flat_marks", "qvga_curb"] {
        let out = dir.join(name);
        let csv = flatland(&["detect", path(&data(name)), "--png", path(&out)]);
        let recording = Recording::open(data(name)).unwrap();
        let layout = layout(&recording, PNG_SCALE);
        let rows = rows(&csv);
        let written = std::fs::read_dir(&out).unwrap().count();
        assert_eq!(written, rows.len(), "{name}: one picture per csv row");
        for &(frame, alarm) in &rows {
            let picture = read_png(&out.join(format!("{frame:06}.png")));
            assert_eq!((picture.width, picture.height), (layout.width, layout.height), "{name} frame {frame}");
            // The header says the decision: the alarm's badge in its hazard's
            // colour, else the green of a clear frame.
            let header = (0, 0, layout.width, layout.header.height);
            let alarm_badge = picture.find(Hazard::Obstacle.colour(), header).len();
            let clear_badge = picture.find([30, 150, 60], header).len();
            if alarm {
                assert!(alarm_badge > 100 && clear_badge == 0, "{name} frame {frame}: alarm badge {alarm_badge} px, clear {clear_badge} px");
            } else {
                assert!(clear_badge > 100 && alarm_badge == 0, "{name} frame {frame}: alarm badge {alarm_badge} px, clear {clear_badge} px");
            }
            // The camera view is the frame itself, scaled: its gray pixels
            // are the camera's.
            let camera = recording.load_frame(frame).unwrap();
            let s = layout.scale;
            let (u, v) = (camera.width / 3, camera.height - 4);
            let shown = picture.at(layout.camera.left + u * s, layout.camera.top + v * s);
            assert_eq!(shown, [camera.pixels[v * camera.width + u]; 3], "{name} frame {frame}: camera pixel ({u}, {v})");
        }
    }
}

/// How far the detector may place an obstacle from where it stands (mm),
/// as the GTI tests allow: the truth box grows by this much on every side.
const POSITION_MARGIN_MM: f64 = 30.0;

/// The truth obstacle's corners (ground and top), grown by
/// [`POSITION_MARGIN_MM`], in the camera at `frame`.
fn obstacle_corners(recording: &Recording, obstacle: &TruthObstacle, frame: u32) -> Vec<(f64, f64)> {
    let row = recording.pose(frame).unwrap();
    let pose = row.pose.unwrap();
    let (cx, cz) = obstacle.centre_at(row.t_s);
    let margin = POSITION_MARGIN_MM;
    let (hw, hd) = (obstacle.width_mm / 2.0 + margin, obstacle.depth_mm / 2.0 + margin);
    let mut corners = Vec::new();
    for (dx, dz) in [(-hw, -hd), (hw, -hd), (hw, hd), (-hw, hd)] {
        let (x, z) = pose.world_to_robot(cx + dx, cz + dz);
        for y in [0.0, obstacle.height_mm + margin] {
            let p = recording.rig.point_to_pixel(Point3 { x, y, z }).unwrap();
            corners.push((p.u, p.v));
        }
    }
    corners
}

/// Convex hull (counter-clockwise in image coordinates: v down).
fn hull(mut points: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    points.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0);
    let mut lower: Vec<(f64, f64)> = Vec::new();
    for &p in &points {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], p) <= 0.0 {
            lower.pop();
        }
        lower.push(p);
    }
    let mut upper: Vec<(f64, f64)> = Vec::new();
    for &p in points.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], p) <= 0.0 {
            upper.pop();
        }
        upper.push(p);
    }
    lower.pop();
    upper.pop();
    lower.extend(upper);
    lower
}

/// Distance from `p` to the convex polygon (0 inside).
fn distance_outside(polygon: &[(f64, f64)], p: (f64, f64)) -> f64 {
    let n = polygon.len();
    let mut outside = 0.0f64;
    let mut nearest_edge = f64::INFINITY;
    for k in 0..n {
        let (a, b) = (polygon[k], polygon[(k + 1) % n]);
        let (ex, ey) = (b.0 - a.0, b.1 - a.1);
        let length = ex.hypot(ey);
        // Signed distance to the edge's line, positive outside.
        let side = -((ex * (p.1 - a.1) - ey * (p.0 - a.0)) / length);
        outside = outside.max(side);
        let t = (((p.0 - a.0) * ex + (p.1 - a.1) * ey) / (length * length)).clamp(0.0, 1.0);
        nearest_edge = nearest_edge.min((p.0 - a.0 - t * ex).hypot(p.1 - a.1 - t * ey));
    }
    if outside <= 0.0 {
        0.0
    } else {
        nearest_edge
    }
}

/// In the written PNGs, the hazard's lines in the camera view (its
/// nearest edge across its width, and its front face up to its height)
/// fall on the pixels the truth obstacle occupies (grown by the position
/// error the detector is allowed; a pixel counts when its centre is within
/// one camera pixel of them: the lines are 2.5 camera pixels thick).
/// Checked on the frames of `frames` whose reported distance is within
/// that error of truth's (the picture draws what the detector says: where
/// it misplaces the obstacle, so does the drawing); at least `min_frames`.
fn footprint_lands_on_obstacle(name: &str, frames: std::ops::RangeInclusive<u32>, min_frames: usize, min_inside: f64) {
    let out = out_dir(&format!("footprint_{name}"));
    let csv = flatland(&["detect", path(&data(name)), "--png", path(&out)]);
    let recording = Recording::open(data(name)).unwrap();
    let truth = recording.truth.clone().unwrap();
    let layout = layout(&recording, PNG_SCALE);
    let s = layout.scale as f64;
    let camera = (layout.camera.left, layout.camera.top, layout.camera.width, layout.camera.height);
    let mut checked = 0;
    for line in csv.lines().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        let frame: u32 = fields[0].parse().unwrap();
        if !frames.contains(&frame) {
            continue;
        }
        let pair = truth.pair(frame).unwrap();
        assert!(fields[2] == "1" && pair.alarm, "{name} frame {frame}: the test wants an alarm (truth {}, detected {})", pair.alarm, fields[2]);
        let nearest: f64 = fields[3].parse().unwrap();
        let error = nearest - pair.nearest_mm.unwrap();
        if error.abs() > POSITION_MARGIN_MM {
            println!("{name} frame {frame}: not checked, reported {nearest} mm is {error:+.0} mm from truth's");
            continue;
        }
        let picture = read_png(&out.join(format!("{frame:06}.png")));
        let drawn = picture.find(Hazard::Obstacle.colour(), camera);
        assert!(drawn.len() >= 40, "{name} frame {frame}: {} hazard pixels in the camera view", drawn.len());
        // Picture pixel -> camera pixel (centres at integers).
        let in_camera = |(x, y): (usize, usize)| ((x - layout.camera.left) as f64 / s + 0.5 / s - 0.5, (y - layout.camera.top) as f64 / s + 0.5 / s - 0.5);
        // The obstacle nearest to the drawing is the one it is about.
        let hulls: Vec<Vec<(f64, f64)>> = truth.obstacle.iter().map(|o| hull(obstacle_corners(&recording, o, frame))).collect();
        let best = hulls
            .iter()
            .map(|h| drawn.iter().filter(|&&p| distance_outside(h, in_camera(p)) <= 1.0).count())
            .max()
            .unwrap();
        let inside = best as f64 / drawn.len() as f64;
        println!("{name} frame {frame}: {} hazard pixels, {:.0} % on the obstacle", drawn.len(), 100.0 * inside);
        assert!(inside >= min_inside, "{name} frame {frame}: only {:.0} % of the drawn footprint on the obstacle", 100.0 * inside);
        checked += 1;
    }
    assert!(checked >= min_frames, "{name}: {checked} frames checked");
}

#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn drawn_footprint_lands_on_the_box() {
    footprint_lands_on_obstacle("approach_box", 16..=39, 15, 0.95);
}

#[test]
#[cfg_attr(not(feature = "long-tests"), ignore = "long tier: cargo test -p flatland-host --features long-tests")]
fn drawn_footprint_lands_on_the_crate_and_the_curb() {
    footprint_lands_on_obstacle("diagonal", 7..=11, 4, 0.95);
    footprint_lands_on_obstacle("qvga_curb", 9..=15, 5, 0.95);
}

#[test]
fn summary_plots_the_run_against_truth() {
    let dir = out_dir("summary");
    for name in ["approach_box", "noisy_marks"] {
        let file = dir.join(format!("{name}.png"));
        flatland(&["detect", path(&data(name)), "--summary", path(&file)]);
        let picture = read_png(&file);
        assert_eq!((picture.width, picture.height), SUMMARY_SIZE, "{name}");
        let everywhere = (0, 0, picture.width, picture.height);
        // The alarm bars: approach_box raises alarms, noisy_marks none.
        let red = picture.find([220, 40, 40], everywhere).len();
        let green = picture.find([150, 205, 160], everywhere).len();
        assert!(green > 1000, "{name}: {green} px of clear bars");
        if name == "approach_box" {
            assert!(red > 1000, "{name}: {red} px of alarm bars");
        }
    }
    // Without truth.toml the plot is still drawn (the detector alone).
    let bare = dir.join("no_truth");
    std::fs::create_dir_all(bare.join("frames")).unwrap();
    let source = data("flat_marks");
    for name in ["rig.toml", "poses.csv"] {
        std::fs::copy(source.join(name), bare.join(name)).unwrap();
    }
    for entry in std::fs::read_dir(source.join("frames")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), bare.join("frames").join(entry.file_name())).unwrap();
    }
    let file = dir.join("no_truth.png");
    flatland(&["detect", path(&bare), "--summary", path(&file)]);
    assert_eq!((read_png(&file).width, read_png(&file).height), SUMMARY_SIZE);
}

#[test]
fn gif_has_one_picture_per_compared_frame() {
    let dir = out_dir("gif");
    let file = dir.join("run.gif");
    let name = "flat_marks";
    let csv = flatland(&["detect", path(&data(name)), "--gif", path(&file)]);
    let recording = Recording::open(data(name)).unwrap();
    let layout = layout(&recording, GIF_SCALE);
    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let mut decoder = options.read_info(std::fs::File::open(&file).unwrap()).unwrap();
    assert_eq!((decoder.width() as usize, decoder.height() as usize), (layout.width, layout.height));
    let mut frames = 0;
    while let Some(frame) = decoder.read_next_frame().unwrap() {
        assert_eq!((frame.width as usize, frame.height as usize), (layout.width, layout.height));
        assert!(frame.delay > 0);
        // The AOI's green survives the palette exactly.
        let green = frame.buffer.chunks_exact(4).filter(|p| p[..3] == [40, 220, 60]).count();
        assert!(green > 500, "frame {frames}: {green} px of AOI green");
        frames += 1;
    }
    assert_eq!(frames, rows(&csv).len());
}

#[test]
fn heights_map_has_a_colour_bar_in_mm() {
    let dir = out_dir("heights");
    flatland(&["heights", path(&data("approach_box")), "--png", path(&dir)]);
    let map = read_png(&dir.join("map.png"));
    let bar_x = map.width - COLOUR_BAR_STRIP + BAR_LEFT + BAR_WIDTH / 2;
    // The bar runs from red (H/2 and above) at the top to blue (0 mm) at the bottom.
    let column: Vec<[u8; 3]> = (0..map.height).map(|y| map.at(bar_x, y)).filter(|&[r, g, b]| !(r == g && g == b)).collect();
    assert!(column.len() > map.height / 2, "bar column: {} coloured px of {}", column.len(), map.height);
    assert_eq!(column.first(), Some(&[255, 0, 0]));
    assert_eq!(column.last(), Some(&[0, 0, 255]));
    // Labels beside it: light text right of the bar's ticks.
    let labels = (map.width - COLOUR_BAR_STRIP + BAR_LEFT + BAR_WIDTH + 8, 0, COLOUR_BAR_STRIP - BAR_LEFT - BAR_WIDTH - 8, map.height);
    let text = (labels.1..labels.3).flat_map(|y| (labels.0..labels.0 + labels.2).map(move |x| (x, y))).filter(|&(x, y)| map.at(x, y)[0] > 120).count();
    assert!(text > 100, "{text} px of label text beside the bar");
}

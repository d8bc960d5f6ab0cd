//! The picture of one compared frame (`flatland detect --png DIR`, and the
//! frames of `--gif`): a header that says what was decided, the camera
//! view with the AOI, the hazard's footprint projected back into
//! perspective and the ground marked every 250 mm, beside the three top
//! views (keyframe aligned by the measured motion, current KG image,
//! |difference|), and a legend.
//!
//! Every position comes from `flatland_core`'s geometry: the camera view's
//! overlays are ground points (or points at a height) through
//! [`Rig::ground_to_pixel`] / [`Rig::point_to_pixel`], lens distortion
//! included; the top views' are KG pixels of the grid.

use crate::cells::cells_with_evidence;
use crate::pictures::raster::{Anchor, RgbImage};
use crate::recording::{Frame, TruthPair};
use flatland_core::geometry::{Point3, Rig};
use flatland_core::gpa::{AlarmSource, Gpa};
use flatland_core::grid::KgGrid;
use flatland_core::motion::{Attitude, GroundMap, GroundMotion, Motion};
use flatland_core::report::{FrameReport, ANGLE_SCALE, MOTION_SCALE};

pub const AOI: [u8; 3] = [40, 220, 60];
pub const RESIDUE: [u8; 3] = [255, 160, 0];
pub const PARALLAX: [u8; 3] = [230, 60, 230];
/// Cells a lag hypothesis won: they move with the robot, height unknown.
pub const MOVING: [u8; 3] = [60, 210, 230];
pub const TICKS: [u8; 3] = [255, 235, 80];
// Text and background are grays, so antialiased text is gray too (the
// GIF's palette has every gray level and few colours).
const BACKGROUND: [u8; 3] = [24, 24, 24];
const TEXT: [u8; 3] = [235, 235, 235];
const DIM_TEXT: [u8; 3] = [170, 170, 170];
const CLEAR: [u8; 3] = [30, 150, 60];

/// Every colour the frame pictures draw with (the GIF keeps them exact).
pub fn key_colours() -> Vec<[u8; 3]> {
    let mut colours = vec![AOI, RESIDUE, PARALLAX, MOVING, TICKS, BACKGROUND, TEXT, DIM_TEXT, CLEAR, [0; 3], [255; 3]];
    colours.extend(Hazard::ALL.map(Hazard::colour));
    colours
}

/// Scale of the frame pictures: camera and KG pixels drawn 2x2 in the PNGs
/// (`--png`), 1x1 in the GIF (`--gif`), which then stays small enough to share.
pub const PNG_SCALE: usize = 2;
pub const GIF_SCALE: usize = 1;

/// Ground marks along the camera view and the top views' ruler, mm.
pub const TICK_SPACING_MM: i32 = 250;
/// Parallax cells this high or higher are drawn (the obstacle height).
const PARALLAX_MIN_MM: i16 = 20;

/// What kind of hazard an alarm is about; each has its own colour in every
/// picture and in the legend.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Hazard {
    /// Something standing on the ground.
    Obstacle,
    /// The ground falling away ahead (a negative obstacle: a step down, a
    /// hole, an edge).
    Drop,
}

impl Hazard {
    pub const ALL: [Hazard; 2] = [Hazard::Obstacle, Hazard::Drop];

    pub fn colour(self) -> [u8; 3] {
        match self {
            Hazard::Obstacle => [255, 40, 40],
            Hazard::Drop => [40, 150, 255],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Hazard::Obstacle => "obstacle",
            Hazard::Drop => "drop",
        }
    }

    /// The hazard a report raises, if any: a drop when its height is
    /// negative (its depth); everything drawn follows it.
    pub fn of(report: &FrameReport) -> Option<Hazard> {
        let below = report.obstacle_h_mm.is_some_and(|h| h < 0);
        report.alarm.then_some(if below { Hazard::Drop } else { Hazard::Obstacle })
    }
}

/// A rectangle of the picture, px.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Panel {
    pub left: usize,
    pub top: usize,
    pub width: usize,
    pub height: usize,
}

impl Panel {
    pub fn contains(&self, x: usize, y: usize) -> bool {
        x >= self.left && y >= self.top && x < self.left + self.width && y < self.top + self.height
    }
}

/// One legend entry: a swatch and what it means.
struct LegendItem {
    colour: [u8; 3],
    text: &'static str,
}

fn legend_items() -> Vec<LegendItem> {
    let mut items = vec![LegendItem { colour: AOI, text: "AOI" }];
    for hazard in Hazard::ALL {
        let text = match hazard {
            Hazard::Obstacle => "obstacle: nearest edge, width, height",
            Hazard::Drop => "drop: nearest edge, width",
        };
        items.push(LegendItem { colour: hazard.colour(), text });
    }
    items.push(LegendItem { colour: RESIDUE, text: "residue no motion explains" });
    items.push(LegendItem { colour: PARALLAX, text: "parallax height >= 20 mm (camera: where it stands)" });
    items.push(LegendItem { colour: MOVING, text: "moves with the robot (height unknown)" });
    items.push(LegendItem { colour: TICKS, text: "ground every 250 mm" });
    items
}

/// Where everything goes in a frame picture. Depends only on the rig, the
/// grid and the scale, so every frame of a run has the same size (the GIF
/// needs that) and the tests can find the camera view in a written PNG.
#[derive(Clone, Debug)]
pub struct FrameLayout {
    /// Camera and KG pixels are drawn as `scale` x `scale` squares.
    pub scale: usize,
    pub width: usize,
    pub height: usize,
    pub header: Panel,
    pub camera: Panel,
    /// The distance ruler of the top views, between them and the camera view.
    pub ruler: Panel,
    /// Aligned keyframe, current KG image, |difference|.
    pub top_views: [Panel; 3],
    legend: Vec<(usize, usize)>,
    title_size: u32,
    text_size: u32,
    small_size: u32,
}

const MARGIN: usize = 10;
const GAP: usize = 8;

impl FrameLayout {
    pub fn new(rig: &Rig, grid: &KgGrid, scale: usize) -> FrameLayout {
        let scale = scale.max(1);
        let camera = rig.camera();
        let (cw, ch) = (usize::from(camera.width) * scale, usize::from(camera.height) * scale);
        let (kw, kh) = (grid.width() * scale, grid.height() * scale);
        let title_size = 14 + 4 * scale as u32;
        let text_size = 11 + 2 * scale as u32;
        let small_size = 10 + scale as u32;
        let header_height = MARGIN + title_size as usize + 8 + text_size as usize + 6;
        let header = Panel { left: 0, top: 0, width: 0, height: header_height };
        let panels_top = header_height + small_size as usize + 8;
        let ruler_width = crate::pictures::raster::text_size("0000", small_size).0 as usize + 14;
        let camera_panel = Panel { left: MARGIN, top: panels_top, width: cw, height: ch };
        let ruler = Panel { left: camera_panel.left + cw + GAP, top: panels_top, width: ruler_width, height: kh };
        let mut left = ruler.left + ruler_width + 2;
        let top_views = [0, 1, 2].map(|_| {
            let panel = Panel { left, top: panels_top, width: kw, height: kh };
            left += kw + GAP;
            panel
        });
        let width = left - GAP + MARGIN;
        // The legend flows in rows under the panels.
        let legend_top = panels_top + ch.max(kh) + GAP;
        let swatch = 2 * small_size as usize;
        let row_height = small_size as usize + 10;
        let mut legend = Vec::new();
        let (mut x, mut y) = (MARGIN, legend_top);
        for item in legend_items() {
            let w = swatch + 6 + crate::pictures::raster::text_size(item.text, small_size).0 as usize + 18;
            if x > MARGIN && x + w > width - MARGIN {
                x = MARGIN;
                y += row_height;
            }
            legend.push((x, y));
            x += w;
        }
        let height = y + row_height + MARGIN / 2;
        FrameLayout {
            scale,
            width,
            height,
            header: Panel { width, ..header },
            camera: camera_panel,
            ruler,
            top_views,
            legend,
            title_size,
            text_size,
            small_size,
        }
    }
}

/// Everything one frame's picture shows.
pub struct FrameInputs<'a, 'g> {
    /// The recording's name, said in the header.
    pub name: &'a str,
    pub rig: &'a Rig,
    pub grid: &'a KgGrid,
    /// The camera frame as the pipeline saw it (binned, perturbed).
    pub camera: &'a Frame,
    /// The reference frame's KG image and the current one.
    pub reference_kg: &'a [u8],
    pub current_kg: &'a [u8],
    pub report: &'a FrameReport,
    pub gpa: &'a Gpa<'g>,
    /// truth.toml's answer for this frame, when the recording has one;
    /// `None` inside: truth.toml has no pair for the frame.
    pub truth: Option<Option<&'a TruthPair>>,
    /// Align the keyframe with the measured pitch and roll change too
    /// (false shows what the attitude compensation removes).
    pub attitude: bool,
}

/// The frame's picture, laid out by `layout`.
pub fn frame_picture(inputs: &FrameInputs, layout: &FrameLayout) -> RgbImage {
    let mut picture = RgbImage::new(layout.width, layout.height);
    picture.fill_rect(0, 0, layout.width, layout.height, BACKGROUND);
    draw_header(&mut picture, inputs, layout);
    let s = layout.scale;
    let titles_y = (layout.camera.top - layout.small_size as usize - 5) as i32;
    let report = inputs.report;
    let titles = [
        format!("camera, frame {}", report.frame),
        if inputs.attitude { format!("keyframe {}, aligned", report.ref_frame) } else { format!("keyframe {}, aligned by the planar motion", report.ref_frame) },
        format!("frame {}, top view", report.frame),
        "|difference| x3".to_string(),
    ];
    let panels = [layout.camera, layout.top_views[0], layout.top_views[1], layout.top_views[2]];
    for (title, panel) in titles.iter().zip(panels) {
        picture.text(panel.left as i32, titles_y, title, layout.small_size, DIM_TEXT, Anchor::TopLeft);
    }
    let camera = camera_view(inputs, s);
    picture.blit(&camera, layout.camera.left, layout.camera.top);
    let (aligned, diff) = aligned_and_difference(inputs);
    for (k, gray) in [&aligned[..], inputs.current_kg, &diff[..]].into_iter().enumerate() {
        let panel = top_view(inputs, gray, k == 2, s);
        picture.blit(&panel, layout.top_views[k].left, layout.top_views[k].top);
    }
    draw_ruler(&mut picture, inputs.grid, layout);
    draw_legend(&mut picture, layout);
    picture
}

fn millimetres(value: Option<i32>) -> String {
    value.map_or_else(|| "-".to_string(), |v| format!("{v} mm"))
}

/// The largest size up to `size` at which `text` is at most `width` px wide.
fn fitting_size(text: &str, size: u32, width: i32) -> u32 {
    let mut size = size;
    while size > 9 && crate::pictures::raster::text_size(text, size).0 > width {
        size -= 1;
    }
    size
}

fn draw_header(picture: &mut RgbImage, inputs: &FrameInputs, layout: &FrameLayout) {
    let report = inputs.report;
    let y = MARGIN as i32;
    let (badge, colour) = match Hazard::of(report) {
        Some(hazard) => (format!("ALARM: {}", hazard.name()), hazard.colour()),
        None => ("CLEAR".to_string(), CLEAR),
    };
    let source = match inputs.gpa.alarm_source() {
        AlarmSource::Parallax => "(parallax)   ",
        AlarmSource::Residue => "(residue)   ",
        AlarmSource::MovingAlong => "(moving along)   ",
        AlarmSource::Held => "(held)   ",
        AlarmSource::None => "",
    };
    let resolution = inputs.gpa.resolution();
    let least = |v: f64| if v.is_finite() { format!("{v:.0} mm") } else { "none".to_string() };
    let line = format!(
        "{source}frame {}  vs  reference {}   nearest {}   height {}   tells from ground: heights {}, drops {}",
        report.frame,
        report.ref_frame,
        millimetres(report.nearest_mm),
        millimetres(report.obstacle_h_mm),
        least(resolution.least_height_mm),
        least(resolution.shallowest_drop_mm),
    );
    let room = (layout.width - 2 * MARGIN) as i32 - 24;
    let size = fitting_size(&format!("{badge} {line}"), layout.title_size, room);
    let (_, _, right, _) = picture.label(MARGIN as i32 + 5, y + 2, &badge, size, [255; 3], colour, Anchor::TopLeft, 5);
    picture.text(right + 14, y + 2, &line, size, TEXT, Anchor::TopLeft);
    let truth = match inputs.truth {
        None => "no truth.toml".to_string(),
        Some(None) => "truth: no answer for this frame".to_string(),
        Some(Some(pair)) if pair.alarm => match pair.nearest_mm {
            Some(z) => format!("truth: alarm, nearest {z:.0} mm"),
            None => "truth: alarm".to_string(),
        },
        Some(Some(_)) => "truth: clear".to_string(),
    };
    let angle = |v: i32| f64::from(v) / f64::from(ANGLE_SCALE);
    let second = format!(
        "{}   {truth}   motion since {}: x {:.1} mm, z {:.1} mm, yaw {:.2}, pitch {:.2}, roll {:.2} deg",
        inputs.name,
        report.ref_frame,
        f64::from(report.tx) / f64::from(MOTION_SCALE),
        f64::from(report.tz) / f64::from(MOTION_SCALE),
        angle(report.dyaw),
        angle(report.dpitch),
        angle(report.droll),
    );
    let size = fitting_size(&second, layout.text_size, room + 24);
    picture.text(MARGIN as i32, y + layout.title_size as i32 + 10, &second, size, DIM_TEXT, Anchor::TopLeft);
}

/// A camera pixel (centre at integer u, v) in a view drawn at `scale`.
fn view_point(u: f64, v: f64, scale: usize) -> (i32, i32) {
    let s = scale as f64;
    (((u + 0.5) * s).round() as i32, ((v + 0.5) * s).round() as i32)
}

/// A ground polyline from (x0, z0) to (x1, z1) in `steps` pieces, in view
/// coordinates: straight on the ground, curved by the lens.
fn ground_line(rig: &Rig, (x0, z0): (f64, f64), (x1, z1): (f64, f64), steps: usize, scale: usize) -> Vec<(i32, i32)> {
    (0..=steps)
        .filter_map(|k| {
            let t = k as f64 / steps as f64;
            let p = rig.ground_to_pixel(x0 + (x1 - x0) * t, z0 + (z1 - z0) * t)?;
            Some(view_point(p.u, p.v, scale))
        })
        .collect()
}

/// The footprint of an alarm in the camera view, view coordinates: its
/// nearest edge on the ground (left to right), and, when its height is
/// known, the front face standing on that edge (a quad up to the height).
pub struct FootprintDrawing {
    pub edge: Vec<(i32, i32)>,
    pub face: Option<[(i32, i32); 4]>,
}

/// Where a report's hazard is drawn in the camera view at `scale`.
pub fn footprint_in_view(rig: &Rig, report: &FrameReport, scale: usize) -> Option<FootprintDrawing> {
    let (near, left, right) = (report.nearest_mm?, report.left_mm?, report.right_mm?);
    let (near, left, right) = (f64::from(near), f64::from(left), f64::from(right));
    let edge = ground_line(rig, (left, near), (right, near), 16, scale);
    let face = report.obstacle_h_mm.and_then(|h| {
        let h = f64::from(h).min(rig.height_mm() - 1.0);
        let corner = |x: f64, y: f64| rig.point_to_pixel(Point3 { x, y, z: near }).map(|p| view_point(p.u, p.v, scale));
        Some([corner(left, 0.0)?, corner(right, 0.0)?, corner(right, h)?, corner(left, h)?])
    });
    Some(FootprintDrawing { edge, face })
}

/// The camera frame at `scale` with the AOI, ground marks, residue,
/// parallax bases and the hazard's footprint.
fn camera_view(inputs: &FrameInputs, s: usize) -> RgbImage {
    let (rig, grid, frame) = (inputs.rig, inputs.grid, inputs.camera);
    let mut view = RgbImage::new(frame.width * s, frame.height * s);
    view.blit_gray_scaled(&frame.pixels, frame.width, 0, 0, s);
    let line = s as u32;
    // Ground marks every 250 mm: short ticks outside the AOI's sides, as
    // far as the camera sees them apart, labelled where there is room
    // (the labels go on later, over the evidence).
    let aoi = rig.aoi();
    let hw = aoi.half_width_mm;
    let tick = 0.3 * hw;
    let small = 10 + s as u32;
    let mut labels = Vec::new();
    let mut last_label_v = f64::INFINITY;
    for k in 1..=80 {
        let z = f64::from(k * TICK_SPACING_MM);
        let Some(centre) = rig.ground_to_pixel(0.0, z) else { continue };
        if centre.v > (frame.height as f64) + 0.5 {
            continue;
        }
        if centre.v < -0.5 {
            break;
        }
        for side in [-1.0, 1.0] {
            let points = ground_line(rig, (side * hw, z), (side * (hw + tick), z), 4, s);
            view.polyline(&points, TICKS, line);
        }
        if (last_label_v - centre.v) * s as f64 >= f64::from(small) + 4.0 {
            if let Some(p) = rig.ground_to_pixel(-(hw + tick), z) {
                labels.push((view_point(p.u, p.v, s), k * TICK_SPACING_MM));
                last_label_v = centre.v;
            }
        }
        // Ticks closer than 4 camera pixels are no longer told apart.
        let next_gap = rig.ground_to_pixel(0.0, z + f64::from(TICK_SPACING_MM)).map_or(0.0, |next| centre.v - next.v);
        if next_gap < 4.0 {
            break;
        }
    }
    // The AOI, edge by edge (lens distortion bends them).
    let corners = [(-hw, aoi.near_mm), (hw, aoi.near_mm), (hw, aoi.far_mm), (-hw, aoi.far_mm), (-hw, aoi.near_mm)];
    for pair in corners.windows(2) {
        view.polyline(&ground_line(rig, pair[0], pair[1], 24, s), AOI, line);
    }
    // Residue blobs: their KG rectangles are ground, so they map onto the
    // camera pixels that made them.
    let cell = inputs.gpa.cell_px() as f64;
    for blob in inputs.gpa.blobs() {
        let (l, r) = (f64::from(blob.cell_left) * cell - 0.5, (f64::from(blob.cell_right) + 1.0) * cell - 0.5);
        let (t, b) = (f64::from(blob.cell_top) * cell - 0.5, (f64::from(blob.cell_bottom) + 1.0) * cell - 0.5);
        let ground = |i: f64, j: f64| grid.pixel_to_ground(i, j);
        let quad = [ground(l, t), ground(r, t), ground(r, b), ground(l, b), ground(l, t)];
        for pair in quad.windows(2) {
            view.polyline(&ground_line(rig, pair[0], pair[1], 8, s), RESIDUE, line);
        }
    }
    // Parallax cells: each is drawn where it stands (what the detector uses).
    let dot = (s as i32 + 1).max(2);
    for found in cells_with_evidence(inputs.gpa, grid, rig.height_mm()) {
        let Some((x, z)) = found.stands_at.filter(|_| found.evidence.measured_height_mm() >= PARALLAX_MIN_MM) else { continue };
        if let Some(p) = rig.ground_to_pixel(x, z) {
            let (x, y) = view_point(p.u, p.v, s);
            view.fill_box((x - dot / 2, y - dot / 2, x + dot / 2, y + dot / 2), PARALLAX);
        }
    }
    // The distances go over the evidence, under the hazard.
    let half_height = small as i32 / 2 + 3;
    for ((x, y), z) in labels {
        let text = z.to_string();
        // Off the image's left edge: at the edge instead; never cut at the top or bottom.
        let (x, anchor) = if x - crate::pictures::raster::text_size(&text, small).0 < 3 { (3, Anchor::CentreLeft) } else { (x - 2, Anchor::CentreRight) };
        let y = y.clamp(half_height, view.height as i32 - half_height);
        view.label(x, y, &text, small, TICKS, [0; 3], anchor, 2);
    }
    if let (Some(hazard), Some(footprint)) = (Hazard::of(inputs.report), footprint_in_view(rig, inputs.report, s)) {
        let colour = hazard.colour();
        if let Some(face) = footprint.face {
            view.polygon(&face, colour, 0.25);
            let mut outline = face.to_vec();
            outline.push(face[0]);
            view.polyline(&outline, colour, line);
        }
        view.polyline(&footprint.edge, colour, 2 * line + 1);
    }
    view
}

/// The keyframe aligned by the report's motion, and |current - aligned| x3.
fn aligned_and_difference(inputs: &FrameInputs) -> (Vec<u8>, Vec<u8>) {
    let (grid, report) = (inputs.grid, inputs.report);
    let (reference, current) = (inputs.reference_kg, inputs.current_kg);
    let (w, h) = (grid.width(), grid.height());
    let angle = |scaled: i32| f64::from(scaled) / f64::from(ANGLE_SCALE);
    let motion = GroundMotion {
        planar: Motion {
            tx_mm: f64::from(report.tx) / f64::from(MOTION_SCALE),
            tz_mm: f64::from(report.tz) / f64::from(MOTION_SCALE),
            dyaw_deg: angle(report.dyaw),
        },
        attitude: if inputs.attitude { Attitude { pitch_deg: angle(report.dpitch), roll_deg: angle(report.droll) } } else { Attitude::default() },
    };
    let map = GroundMap::new(&motion, inputs.rig.height_mm());
    let mut aligned = vec![0u8; w * h];
    let mut diff = vec![0u8; w * h];
    for j in 0..h {
        for i in 0..w {
            let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
            let Some((xk, zk)) = map.to_keyframe(x, z) else { continue };
            let (fi, fj) = grid.ground_to_pixel(xk, zk);
            if fi < 0.0 || fj < 0.0 || fi >= (w - 1) as f64 || fj >= (h - 1) as f64 {
                continue;
            }
            let (i0, j0) = (fi as usize, fj as usize);
            let (wx, wy) = (fi - i0 as f64, fj - j0 as f64);
            let px = |i: usize, j: usize| f64::from(reference[j * w + i]);
            let value = (px(i0, j0) * (1.0 - wx) + px(i0 + 1, j0) * wx) * (1.0 - wy)
                + (px(i0, j0 + 1) * (1.0 - wx) + px(i0 + 1, j0 + 1) * wx) * wy;
            aligned[j * w + i] = value.round() as u8;
            if current[j * w + i] != 0 && reference[j0 * w + i0] != 0 {
                diff[j * w + i] = ((f64::from(current[j * w + i]) - value).abs() * 3.0).min(255.0) as u8;
            }
        }
    }
    (aligned, diff)
}

/// One top view at `scale`: AOI, residue blobs, the hazard's nearest edge
/// across its width, and (on the difference) the parallax cells.
fn top_view(inputs: &FrameInputs, gray: &[u8], parallax: bool, s: usize) -> RgbImage {
    let (grid, gpa) = (inputs.grid, inputs.gpa);
    let (w, h) = (grid.width(), grid.height());
    let mut view = RgbImage::new(w * s, h * s);
    view.blit_gray_scaled(gray, w, 0, 0, s);
    // KG pixel rectangle [l, r] x [t, b] (inclusive) in view coordinates.
    let rect = |l: usize, t: usize, r: usize, b: usize| ((l * s) as i32, (t * s) as i32, ((r + 1) * s) as i32 - 1, ((b + 1) * s) as i32 - 1);
    let line = s as u32;
    let aoi = grid.aoi_pixels(inputs.rig);
    view.frame_box(rect(aoi.left, aoi.top, aoi.right - 1, aoi.bottom - 1), AOI, line);
    let cell = gpa.cell_px();
    for blob in gpa.blobs() {
        let (l, r) = (usize::from(blob.cell_left) * cell, (usize::from(blob.cell_right) + 1) * cell - 1);
        let (t, b) = (usize::from(blob.cell_top) * cell, (usize::from(blob.cell_bottom) + 1) * cell - 1);
        view.frame_box(rect(l, t, r.min(w - 1), b.min(h - 1)), RESIDUE, line);
    }
    if parallax {
        for found in cells_with_evidence(gpa, grid, inputs.rig.height_mm()) {
            let (evidence, row, column) = (found.evidence, found.row, found.column);
            let h = evidence.measured_height_mm();
            // Standing up, or (a drop's lower level) below the floor, or moving with the robot.
            let colour = if h >= PARALLAX_MIN_MM {
                PARALLAX
            } else if h <= -PARALLAX_MIN_MM {
                Hazard::Drop.colour()
            } else if evidence.moves_with_robot() {
                MOVING
            } else {
                continue;
            };
            let (l, t, r, b) = rect(column * cell, row * cell, (column + 1) * cell - 1, (row + 1) * cell - 1);
            view.frame_box((l + 1, t + 1, r - 1, b - 1), colour, 1);
        }
    }
    let report = inputs.report;
    if let (Some(hazard), Some(near), Some(left), Some(right)) = (Hazard::of(report), report.nearest_mm, report.left_mm, report.right_mm) {
        let (li, row) = grid.ground_to_pixel(f64::from(left), f64::from(near));
        let (ri, _) = grid.ground_to_pixel(f64::from(right), f64::from(near));
        let y = ((row + 0.5) * s as f64).round() as i32;
        let (x0, x1) = (((li + 0.5) * s as f64).round() as i32, ((ri + 0.5) * s as f64).round() as i32);
        view.polyline(&[(x0, y), (x1, y)], hazard.colour(), 2 * line + 1);
    }
    view
}

/// Distances (mm ahead) beside the first top view, every 250 mm.
fn draw_ruler(picture: &mut RgbImage, grid: &KgGrid, layout: &FrameLayout) {
    let (ruler, s) = (layout.ruler, layout.scale as f64);
    let right = (ruler.left + ruler.width) as i32;
    let (_, far) = grid.pixel_to_ground(0.0, -0.5);
    let (_, near) = grid.pixel_to_ground(0.0, grid.height() as f64 - 0.5);
    let first = (near / f64::from(TICK_SPACING_MM)).ceil() as i32;
    let last = (far / f64::from(TICK_SPACING_MM)).floor() as i32;
    // "mm" heads the ruler; a tick too close under it goes unlabelled.
    picture.text(right - 8, ruler.top as i32, "mm", layout.small_size, DIM_TEXT, Anchor::TopRight);
    let free_below = ruler.top as i32 + 2 * layout.small_size as i32;
    for k in first.max(1)..=last {
        let z = k * TICK_SPACING_MM;
        let (_, row) = grid.ground_to_pixel(0.0, f64::from(z));
        let y = ruler.top as i32 + ((row + 0.5) * s).round() as i32;
        picture.polyline(&[(right - 6, y), (right, y)], TICKS, 1);
        if y >= free_below {
            picture.text(right - 8, y, &z.to_string(), layout.small_size, TICKS, Anchor::CentreRight);
        }
    }
}

fn draw_legend(picture: &mut RgbImage, layout: &FrameLayout) {
    let size = layout.small_size;
    let swatch = 2 * size as i32;
    for (item, &(x, y)) in legend_items().iter().zip(&layout.legend) {
        let (x, y) = (x as i32, y as i32);
        let half = size as i32 / 2;
        picture.fill_box((x, y + half - 3, x + swatch, y + half + 3), item.colour);
        picture.text(x + swatch + 6, y, item.text, size, TEXT, Anchor::TopLeft);
    }
}

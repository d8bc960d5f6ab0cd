//! PNG output for pictures a person looks at.

use std::path::Path;

/// An 8-bit RGB picture under construction.
#[derive(Clone, Debug)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[u8; 3]>,
}

impl RgbImage {
    pub fn new(width: usize, height: usize) -> RgbImage {
        RgbImage { width, height, pixels: vec![[0; 3]; width * height] }
    }

    /// Copies a grayscale raster into the picture at (left, top).
    pub fn blit_gray(&mut self, gray: &[u8], width: usize, left: usize, top: usize) {
        for (j, row) in gray.chunks_exact(width).enumerate() {
            for (i, &value) in row.iter().enumerate() {
                self.set(left + i, top + j, [value; 3]);
            }
        }
    }

    pub fn set(&mut self, x: usize, y: usize, color: [u8; 3]) {
        if x < self.width && y < self.height {
            self.pixels[y * self.width + x] = color;
        }
    }

    /// Outline of a rectangle, inclusive corners.
    pub fn rect(&mut self, left: usize, top: usize, right: usize, bottom: usize, color: [u8; 3]) {
        for x in left..=right {
            self.set(x, top, color);
            self.set(x, bottom, color);
        }
        for y in top..=bottom {
            self.set(left, y, color);
            self.set(right, y, color);
        }
    }

    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        let flat: Vec<u8> = self.pixels.iter().flatten().copied().collect();
        write_png(path, self.width, self.height, png::ColorType::Rgb, &flat)
    }
}

/// Writes an 8-bit grayscale PNG.
pub fn save_gray(path: &Path, width: usize, height: usize, pixels: &[u8]) -> std::io::Result<()> {
    write_png(path, width, height, png::ColorType::Grayscale, pixels)
}

fn write_png(path: &Path, width: usize, height: usize, color: png::ColorType, data: &[u8]) -> std::io::Result<()> {
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut encoder = png::Encoder::new(file, width as u32, height as u32);
    encoder.set_color(color);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
    writer.write_image_data(data).map_err(std::io::Error::other)?;
    writer.finish().map_err(std::io::Error::other)
}

use flatland_core::geometry::Rig;
use flatland_core::gpa::Gpa;
use flatland_core::grid::KgGrid;
use flatland_core::motion::{Attitude, GroundMap, GroundMotion, Motion};
use flatland_core::report::{FrameReport, ANGLE_SCALE, MOTION_SCALE};

const GREEN: [u8; 3] = [40, 220, 60];
const RED: [u8; 3] = [255, 40, 40];
const ORANGE: [u8; 3] = [255, 160, 0];
/// Drop cells: the lower level past an edge.
const CYAN: [u8; 3] = [0, 220, 255];
const MAGENTA: [u8; 3] = [230, 60, 230];

/// The detection picture: keyframe aligned by the refined motion, the current
/// KG image, and |diff| (x3) at that alignment. AOI in green, unexplained
/// residue blobs in orange, cells whose parallax puts them 20 mm or more
/// above the ground in magenta (on the difference), and the obstacle that
/// raised the alarm as a red line at its nearest point, across its width.
/// `attitude`: align with the measured pitch and roll change too (false
/// shows what the attitude compensation removes).
pub fn detect_picture(rig: &Rig, grid: &KgGrid, reference: &[u8], current: &[u8], report: &FrameReport, gpa: &Gpa, attitude: bool) -> RgbImage {
    let (w, h) = (grid.width(), grid.height());
    let angle = |scaled: i32| f64::from(scaled) / f64::from(ANGLE_SCALE);
    let motion = GroundMotion {
        planar: Motion {
            tx_mm: f64::from(report.tx) / f64::from(MOTION_SCALE),
            tz_mm: f64::from(report.tz) / f64::from(MOTION_SCALE),
            dyaw_deg: angle(report.dyaw),
        },
        attitude: if attitude { Attitude { pitch_deg: angle(report.dpitch), roll_deg: angle(report.droll) } } else { Attitude::default() },
    };
    let map = GroundMap::new(&motion, rig.height_mm());
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
    let gap = 4;
    let mut picture = RgbImage::new(3 * w + 2 * gap, h);
    picture.blit_gray(&aligned, w, 0, 0);
    picture.blit_gray(current, w, w + gap, 0);
    picture.blit_gray(&diff, w, 2 * (w + gap), 0);
    let aoi = grid.aoi_pixels(rig);
    let cell = gpa.cell_px();
    for panel in 0..3 {
        let left = panel * (w + gap);
        picture.rect(left + aoi.left, aoi.top, left + aoi.right - 1, aoi.bottom - 1, GREEN);
        for blob in gpa.blobs() {
            let (l, r) = (usize::from(blob.cell_left) * cell, (usize::from(blob.cell_right) + 1) * cell - 1);
            let (t, b) = (usize::from(blob.cell_top) * cell, (usize::from(blob.cell_bottom) + 1) * cell - 1);
            picture.rect(left + l, t, left + r.min(w - 1), b.min(h - 1), ORANGE);
        }
        if panel == 2 {
            let (rows, columns) = gpa.cells();
            for row in 0..rows {
                for column in 0..columns {
                    // Obstacle cells (standing 20 mm up) and drop cells (20 mm down).
                    let colour = match gpa.cell_height(row, column) {
                        h if h >= 20 => MAGENTA,
                        h if h <= -20 => CYAN,
                        _ => continue,
                    };
                    let (l, t) = (left + column * cell, row * cell);
                    picture.rect(l + 1, t + 1, l + cell - 2, t + cell - 2, colour);
                }
            }
        }
        if let (Some(near), Some(l), Some(r)) = (report.nearest_mm, report.left_mm, report.right_mm) {
            let (li, row) = grid.ground_to_pixel(f64::from(l), f64::from(near));
            let (ri, _) = grid.ground_to_pixel(f64::from(r), f64::from(near));
            let row = row.round().clamp(0.0, (h - 1) as f64) as usize;
            for i in li.round().max(0.0) as usize..=(ri.round() as usize).min(w - 1) {
                picture.set(left + i, row, RED);
                picture.set(left + i, row.saturating_sub(1), RED);
            }
        }
    }
    picture
}

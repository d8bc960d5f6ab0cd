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

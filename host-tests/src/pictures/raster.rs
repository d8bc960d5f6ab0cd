//! Pictures a person looks at: an RGB raster, PNG output, and drawing on
//! it (lines, polygons and text through `plotters`' bitmap backend, with a
//! font bundled in the binary: no system font is needed).

use plotters::backend::BitMapBackend;
use plotters::coord::Shift;
use plotters::drawing::{DrawingArea, IntoDrawingArea};
use plotters::element::{PathElement, Polygon, Rectangle};
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{Color, FontStyle, IntoFont, RGBColor, ShapeStyle, TextStyle};
use std::path::Path;
use std::sync::Once;

/// The font family every picture's text uses (see [`register_font`]).
pub const FONT: &str = "sans-serif";

/// Registers the bundled font (Hack, from `epaint_default_fonts`) with
/// plotters as [`FONT`], once. Every drawing entry point calls it.
pub fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if plotters::style::register_font(FONT, FontStyle::Normal, epaint_default_fonts::HACK_REGULAR).is_err() {
            panic!("the bundled font does not parse");
        }
    });
}

/// An RGB colour as plotters takes it.
pub fn rgb([r, g, b]: [u8; 3]) -> RGBColor {
    RGBColor(r, g, b)
}

/// Where a text's anchor point is on the text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Anchor {
    TopLeft,
    TopRight,
    TopCentre,
    CentreLeft,
    CentreRight,
    Centre,
}

impl Anchor {
    fn pos(self) -> Pos {
        match self {
            Anchor::TopLeft => Pos::new(HPos::Left, VPos::Top),
            Anchor::TopRight => Pos::new(HPos::Right, VPos::Top),
            Anchor::TopCentre => Pos::new(HPos::Center, VPos::Top),
            Anchor::CentreLeft => Pos::new(HPos::Left, VPos::Center),
            Anchor::CentreRight => Pos::new(HPos::Right, VPos::Center),
            Anchor::Centre => Pos::new(HPos::Center, VPos::Center),
        }
    }
}

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

    /// Copies a grayscale raster into the picture at (left, top), each
    /// pixel as a `scale` x `scale` square.
    pub fn blit_gray_scaled(&mut self, gray: &[u8], width: usize, left: usize, top: usize, scale: usize) {
        for (j, row) in gray.chunks_exact(width).enumerate() {
            for (i, &value) in row.iter().enumerate() {
                self.fill_rect(left + i * scale, top + j * scale, scale, scale, [value; 3]);
            }
        }
    }

    /// Copies another picture into this one at (left, top), clipped.
    pub fn blit(&mut self, other: &RgbImage, left: usize, top: usize) {
        for (j, row) in other.pixels.chunks_exact(other.width).enumerate() {
            let y = top + j;
            if y >= self.height || left >= self.width {
                break;
            }
            let n = other.width.min(self.width - left);
            self.pixels[y * self.width + left..][..n].copy_from_slice(&row[..n]);
        }
    }

    /// Fills `width` x `height` pixels from (left, top).
    pub fn fill_rect(&mut self, left: usize, top: usize, width: usize, height: usize, color: [u8; 3]) {
        for y in top..(top + height).min(self.height) {
            for x in left..(left + width).min(self.width) {
                self.pixels[y * self.width + x] = color;
            }
        }
    }

    /// The picture as a plotters drawing area, for lines, shapes and text
    /// (coordinates in pixels, clipped at the edges).
    pub fn canvas(&mut self) -> DrawingArea<BitMapBackend<'_>, Shift> {
        register_font();
        let size = (self.width as u32, self.height as u32);
        BitMapBackend::with_buffer(self.pixels.as_flattened_mut(), size).into_drawing_area()
    }

    /// Writes `text` with its `anchor` at (x, y), `size` px high.
    pub fn text(&mut self, x: i32, y: i32, text: &str, size: u32, color: [u8; 3], anchor: Anchor) {
        let style = text_style(size, color, anchor);
        self.canvas().draw_text(text, &style, (x, y)).expect("text into a memory buffer");
    }

    /// `text` on a filled box that pads it by `pad` px: readable over an image.
    /// Returns the box (left, top, right, bottom).
    #[allow(clippy::too_many_arguments)]
    pub fn label(&mut self, x: i32, y: i32, text: &str, size: u32, color: [u8; 3], background: [u8; 3], anchor: Anchor, pad: i32) -> (i32, i32, i32, i32) {
        let (w, h) = text_size(text, size);
        let left = match anchor {
            Anchor::TopLeft | Anchor::CentreLeft => x,
            Anchor::TopRight | Anchor::CentreRight => x - w,
            Anchor::TopCentre | Anchor::Centre => x - w / 2,
        };
        let top = match anchor {
            Anchor::TopLeft | Anchor::TopRight | Anchor::TopCentre => y,
            _ => y - h / 2,
        };
        let bounds = (left - pad, top - pad, left + w + pad, top + h + pad);
        self.fill_box(bounds, background);
        self.text(left, top, text, size, color, Anchor::TopLeft);
        bounds
    }

    /// Fills (left, top, right, bottom), inclusive, clipped.
    pub fn fill_box(&mut self, (left, top, right, bottom): (i32, i32, i32, i32), color: [u8; 3]) {
        let (l, t) = (left.max(0) as usize, top.max(0) as usize);
        let (r, b) = (right.max(-1) + 1, bottom.max(-1) + 1);
        self.fill_rect(l, t, (r as usize).saturating_sub(l), (b as usize).saturating_sub(t), color);
    }

    /// A polyline `width` px wide.
    pub fn polyline(&mut self, points: &[(i32, i32)], color: [u8; 3], width: u32) {
        if points.len() < 2 {
            return;
        }
        let style = ShapeStyle { color: rgb(color).to_rgba(), filled: false, stroke_width: width };
        self.canvas().draw(&PathElement::new(points.to_vec(), style)).expect("lines into a memory buffer");
    }

    /// A filled polygon blended over the picture with `opacity` (0..=1).
    pub fn polygon(&mut self, points: &[(i32, i32)], color: [u8; 3], opacity: f64) {
        if points.len() < 3 {
            return;
        }
        let style = rgb(color).mix(opacity).filled();
        self.canvas().draw(&Polygon::new(points.to_vec(), style)).expect("shapes into a memory buffer");
    }

    /// An outlined rectangle `width` px wide, (left, top, right, bottom) inclusive.
    pub fn frame_box(&mut self, (left, top, right, bottom): (i32, i32, i32, i32), color: [u8; 3], width: u32) {
        let style = ShapeStyle { color: rgb(color).to_rgba(), filled: false, stroke_width: width };
        self.canvas().draw(&Rectangle::new([(left, top), (right, bottom)], style)).expect("shapes into a memory buffer");
    }

    /// The flat RGB bytes, row by row.
    pub fn bytes(&self) -> &[u8] {
        self.pixels.as_flattened()
    }

    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        write_png(path, self.width, self.height, png::ColorType::Rgb, self.bytes())
    }
}

/// The style of a text `size` px high.
pub fn text_style(size: u32, color: [u8; 3], anchor: Anchor) -> TextStyle<'static> {
    register_font();
    (FONT, f64::from(size)).into_font().color(&rgb(color)).pos(anchor.pos())
}

/// Width and height in px of `text` at `size`.
pub fn text_size(text: &str, size: u32) -> (i32, i32) {
    let mut scratch = RgbImage::new(1, 1);
    let (w, h) = scratch.canvas().estimate_text_size(text, &text_style(size, [0; 3], Anchor::TopLeft)).expect("bundled font");
    (w as i32, h as i32)
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
    // Each row filtered the way that suits it (pictures mix photographs,
    // pixels drawn 2x2 and flat drawing), and deflate's default level
    // rather than the encoder's fast one: a fifth of the size.
    encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
    encoder.set_compression(png::Compression::Default);
    let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
    writer.write_image_data(data).map_err(std::io::Error::other)?;
    writer.finish().map_err(std::io::Error::other)
}


//! One animated GIF of a run (`flatland detect --gif FILE.gif`): the
//! frame pictures in order, looping, each shown long enough to read its
//! header, the last one longer.
//!
//! One palette for the whole animation: the pictures' own drawing colours
//! exactly, 176 gray levels for the camera and top views (and the
//! antialiased text, gray on gray), and a 4x4x4 colour cube for whatever
//! else (antialiased coloured labels). A fixed palette keeps colours from
//! shifting between frames, as per-frame quantisation would.

use crate::pictures::raster::RgbImage;
use std::collections::HashMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// How long each picture stays, in hundredths of a second.
pub const FRAME_DELAY_CS: u16 = 50;
/// How long the last picture stays before the loop starts again.
pub const LAST_DELAY_CS: u16 = 200;

const GRAYS: usize = 176;

/// The animation's 256 colours and a lookup from any colour into them.
struct Palette {
    colours: Vec<[u8; 3]>,
    /// Index of the first gray level.
    gray_start: usize,
    /// Colours already looked up (pictures repeat a few colours).
    cache: HashMap<[u8; 3], u8>,
}

impl Palette {
    fn new(key: &[[u8; 3]]) -> Palette {
        let mut colours: Vec<[u8; 3]> = key.iter().copied().take(256 - GRAYS - 64).collect();
        for r in 0..4u8 {
            for g in 0..4u8 {
                for b in 0..4u8 {
                    colours.push([r * 85, g * 85, b * 85]);
                }
            }
        }
        let gray_start = colours.len();
        colours.extend((0..GRAYS).map(|k| [((k * 255 + (GRAYS - 1) / 2) / (GRAYS - 1)) as u8; 3]));
        colours.resize(256, [0; 3]);
        Palette { colours, gray_start, cache: HashMap::new() }
    }

    fn index(&mut self, colour: [u8; 3]) -> u8 {
        let [r, g, b] = colour;
        if r == g && g == b {
            return (self.gray_start + (usize::from(r) * (GRAYS - 1) + 127) / 255) as u8;
        }
        if let Some(&index) = self.cache.get(&colour) {
            return index;
        }
        let distance = |c: &[u8; 3]| (0..3).map(|k| (i32::from(c[k]) - i32::from(colour[k])).pow(2)).sum::<i32>();
        let (index, _) = self.colours.iter().enumerate().min_by_key(|(_, c)| distance(c)).expect("256 colours");
        self.cache.insert(colour, index as u8);
        index as u8
    }

    fn flat(&self) -> Vec<u8> {
        self.colours.as_flattened().to_vec()
    }
}

/// An animation being written. Pictures must all have its size.
pub struct Animation {
    encoder: gif::Encoder<BufWriter<File>>,
    size: (usize, usize),
    palette: Palette,
    /// The latest picture: written when the next one comes (or at the
    /// end, with the last picture's delay).
    pending: Option<gif::Frame<'static>>,
    frames: usize,
}

fn error(e: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

impl Animation {
    /// A new animation of `width` x `height` pictures drawn with the
    /// `key` colours (kept exact; at most 16).
    pub fn create(path: &Path, width: usize, height: usize, key: &[[u8; 3]]) -> std::io::Result<Animation> {
        let (w, h) = (u16::try_from(width).map_err(error)?, u16::try_from(height).map_err(error)?);
        let palette = Palette::new(key);
        let file = BufWriter::new(File::create(path)?);
        let mut encoder = gif::Encoder::new(file, w, h, &palette.flat()).map_err(error)?;
        encoder.set_repeat(gif::Repeat::Infinite).map_err(error)?;
        Ok(Animation { encoder, size: (width, height), palette, pending: None, frames: 0 })
    }

    /// Adds a picture.
    pub fn push(&mut self, picture: &RgbImage) -> std::io::Result<()> {
        if (picture.width, picture.height) != self.size {
            return Err(error(format!("a {}x{} picture in a {}x{} animation", picture.width, picture.height, self.size.0, self.size.1)));
        }
        let indices: Vec<u8> = picture.pixels.iter().map(|&c| self.palette.index(c)).collect();
        let frame = gif::Frame {
            width: self.size.0 as u16,
            height: self.size.1 as u16,
            delay: FRAME_DELAY_CS,
            buffer: indices.into(),
            ..gif::Frame::default()
        };
        if let Some(previous) = self.pending.replace(frame) {
            self.encoder.write_frame(&previous).map_err(error)?;
        }
        self.frames += 1;
        Ok(())
    }

    /// Writes the last picture and closes the file; returns how many
    /// pictures the animation has.
    pub fn finish(mut self) -> std::io::Result<usize> {
        if let Some(mut last) = self.pending.take() {
            last.delay = LAST_DELAY_CS;
            self.encoder.write_frame(&last).map_err(error)?;
        }
        let frames = self.frames;
        self.encoder.into_inner().map_err(error)?.into_inner().map_err(|e| e.into_error())?;
        Ok(frames)
    }
}

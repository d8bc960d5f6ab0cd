//! The GT lines and their samples: [`GtiConfig::lines`] lines parallel to
//! the translation, spread evenly across the AOI, each sampled once per KG
//! row as the rows stream out of the remap (averaged over a few pixels across
//! the line). A frame's lines follow the previous frame's translation.

use super::{GtiConfig, GtiError};
use crate::geometry::Rig;
use crate::grid::KgGrid;
use crate::kernels::{floorf, roundf};
use crate::limits::{MAX_LINES, MAX_LINE_SAMPLES};
use core::ops::Range;
use libm::{cosf, fabsf, sinf};

/// The KG grid as the lines use it: its size, and its measures in f32 (the
/// lines' maths is f32; each conversion from the grid's f64 is a software
/// routine on the M4, so they are converted once).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct LineGrid {
    pub width: usize,
    pub height: usize,
    pub mm_per_px: f32,
    pub x_left_mm: f32,
    pub z_far_mm: f32,
}

impl LineGrid {
    pub(super) const UNCONFIGURED: LineGrid = LineGrid { width: 0, height: 0, mm_per_px: 1.0, x_left_mm: 0.0, z_far_mm: 0.0 };

    pub(super) fn new(grid: &KgGrid) -> LineGrid {
        LineGrid {
            width: grid.width(),
            height: grid.height(),
            mm_per_px: grid.mm_per_px as f32,
            x_left_mm: grid.x_left_mm as f32,
            z_far_mm: grid.z_far_mm as f32,
        }
    }
}

/// One GT line: fixed in the robot frame for a frame, parallel to the
/// translation. Points on it are `offset * normal + t * direction` (mm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtLine {
    /// Unit direction (x, z), forward.
    pub direction: [f32; 2],
    /// Unit normal (x, z), to the right of the direction.
    pub normal: [f32; 2],
    /// Signed distance of the line from the robot origin along the normal.
    pub offset_mm: f32,
}

impl GtLine {
    /// Ground point (robot frame) at KG row position `row` (fractional).
    pub(super) fn point_at_row(&self, grid: &LineGrid, row: f32) -> [f32; 2] {
        let z = grid.z_far_mm - row * grid.mm_per_px;
        let t = self.t_at_z(z);
        [self.offset_mm * self.normal[0] + t * self.direction[0], z]
    }
    fn t_at_z(&self, z: f32) -> f32 {
        (z - self.offset_mm * self.normal[1]) / self.direction[1]
    }
    /// KG row position (fractional) where the line passes the ground point's
    /// projection onto it, and the point's distance from the line (mm).
    pub(super) fn row_of(&self, grid: &LineGrid, point: [f32; 2]) -> (f32, f32) {
        let t = point[0] * self.direction[0] + point[1] * self.direction[1];
        let lateral = point[0] * self.normal[0] + point[1] * self.normal[1] - self.offset_mm;
        let z = self.offset_mm * self.normal[1] + t * self.direction[1];
        ((grid.z_far_mm - z) / grid.mm_per_px, lateral)
    }
}

/// A point `lateral` mm from a line ([`GtLine::row_of`]) is off it: more than
/// two KG pixels away, outside what the line's samples saw.
pub(super) fn off_line(lateral: f32, mm_per_px: f32) -> bool {
    fabsf(lateral) > 2.0 * mm_per_px
}

/// One line's samples for the current frame, indexed by KG row.
#[derive(Clone, Copy, Debug)]
pub(super) struct LineSamples {
    pub(super) values: [u8; MAX_LINE_SAMPLES],
    /// First contiguous run of valid samples, `[start, end)`.
    start: u16,
    end: u16,
    /// The run ended (a gap was seen): later samples are ignored.
    closed: bool,
}

impl LineSamples {
    pub(super) const EMPTY: LineSamples = LineSamples { values: [0; MAX_LINE_SAMPLES], start: 0, end: 0, closed: false };

    pub(super) fn valid(&self) -> Range<usize> {
        usize::from(self.start)..usize::from(self.end)
    }

    fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
        self.closed = false;
    }

    /// Takes KG row `row`'s sample (None: the line is not seen there) while
    /// the first contiguous run is open.
    pub(super) fn take(&mut self, row: usize, value: Option<u8>) {
        match value {
            Some(v) => {
                if self.start == self.end {
                    self.start = row as u16;
                } else if usize::from(self.end) != row {
                    self.closed = true;
                    return;
                }
                if let Some(slot) = self.values.get_mut(row) {
                    *slot = v;
                }
                self.end = row as u16 + 1;
            }
            None => {
                if self.start != self.end {
                    self.closed = true;
                }
            }
        }
    }
}

/// The lines of the current frame and their samples.
pub(super) struct Lines {
    lines: [GtLine; MAX_LINES],
    samples: [LineSamples; MAX_LINES],
    next_row: u16,
    /// A row of the current frame arrived (the samples are this frame's).
    frame_started: bool,
    /// Line angle for the next frame (from this frame's translation).
    next_angle: Option<f32>,
    /// Where the lines spread: the AOI's half width and middle depth, mm.
    aoi_half_width_mm: f32,
    aoi_mid_z_mm: f32,
}

impl Lines {
    pub(super) const UNCONFIGURED: Lines = {
        const LINE: GtLine = GtLine { direction: [0.0, 1.0], normal: [1.0, 0.0], offset_mm: 0.0 };
        Lines {
            lines: [LINE; MAX_LINES],
            samples: [LineSamples::EMPTY; MAX_LINES],
            next_row: 0,
            frame_started: false,
            next_angle: None,
            aoi_half_width_mm: 0.0,
            aoi_mid_z_mm: 0.0,
        }
    };

    /// Lines along the G axis for a rig; no samples yet.
    pub(super) fn configure(&mut self, rig: &Rig, config: &GtiConfig) {
        let aoi = rig.aoi();
        self.aoi_half_width_mm = aoi.half_width_mm as f32;
        self.aoi_mid_z_mm = (0.5 * (aoi.near_mm + aoi.far_mm)) as f32;
        self.clear_samples();
        self.frame_started = false;
        self.next_angle = None;
        self.place(0.0, config.lines);
    }

    /// The first `count` lines.
    pub(super) fn lines(&self, count: usize) -> &[GtLine] {
        self.lines.get(..count).unwrap_or(&[])
    }

    pub(super) fn line(&self, l: usize) -> Option<&GtLine> {
        self.lines.get(l)
    }

    /// Line `l`'s samples (none beyond [`MAX_LINES`]).
    pub(super) fn samples(&self, l: usize) -> &LineSamples {
        self.samples.get(l).unwrap_or(&LineSamples::EMPTY)
    }

    /// `count` lines parallel to `angle` (from the G axis, positive to the
    /// right), spread evenly across the AOI at its middle depth.
    fn place(&mut self, angle: f32, count: usize) {
        let (sin, cos) = (sinf(angle), cosf(angle));
        let spacing = 2.0 * self.aoi_half_width_mm / count as f32;
        for (l, line) in self.lines.iter_mut().take(count).enumerate() {
            let x = -self.aoi_half_width_mm + (l as f32 + 0.5) * spacing;
            let normal = [cos, -sin];
            *line = GtLine {
                direction: [sin, cos],
                normal,
                offset_mm: x * normal[0] + self.aoi_mid_z_mm * normal[1],
            };
        }
    }

    /// Samples the lines from KG row `row` of the current frame (see
    /// [`super::Gti::on_kg_row`]).
    pub(super) fn on_kg_row(
        &mut self,
        config: &GtiConfig,
        grid: &LineGrid,
        row: usize,
        kg_row: &[u8],
        valid_columns: Range<usize>,
    ) -> Result<(), GtiError> {
        if kg_row.len() != grid.width {
            return Err(GtiError::RowLength);
        }
        if !self.frame_started {
            self.start_frame(config.lines);
            self.frame_started = true;
        }
        if row >= grid.height || row < usize::from(self.next_row) {
            return Err(GtiError::RowIndex);
        }
        self.next_row = row as u16 + 1;
        let valid = valid_columns.start..valid_columns.end.min(kg_row.len());
        let half = (config.line_width_px / 2) as f32;
        for (line, samples) in self.lines.iter().zip(self.samples.iter_mut()).take(config.lines) {
            if samples.closed {
                continue;
            }
            let [x, _] = line.point_at_row(grid, row as f32);
            let centre = (x - grid.x_left_mm) / grid.mm_per_px;
            samples.take(row, sample_across(kg_row, &valid, centre, half));
        }
        Ok(())
    }

    /// Drops the current frame's rows: the next row starts a new frame.
    pub(super) fn abort_frame(&mut self) {
        self.frame_started = false;
    }

    /// Ends the frame's sampling (a frame without rows has no samples); the
    /// samples stay readable until the next frame's first row.
    pub(super) fn end_frame(&mut self, count: usize) {
        if !self.frame_started {
            self.start_frame(count);
        }
        self.frame_started = false;
    }

    /// The next frame's lines follow `angle` (see [`Lines::place`]).
    pub(super) fn turn_next_frame(&mut self, angle: f32) {
        self.next_angle = Some(angle);
    }

    /// Starts a frame: forget the last frame's samples, turn the lines.
    // Once a frame: kept out of the per-row sampling, which the firmware
    // inlines into the remap's row loop.
    #[cold]
    #[inline(never)]
    fn start_frame(&mut self, count: usize) {
        if let Some(angle) = self.next_angle.take() {
            self.place(angle, count);
        }
        self.clear_samples();
    }

    fn clear_samples(&mut self) {
        for samples in self.samples.iter_mut() {
            samples.clear();
        }
        self.next_row = 0;
    }
}

/// Average of `2 * half + 1` linearly interpolated pixels centred on
/// fractional column `centre`; None if any tap leaves the valid columns.
fn sample_across(row: &[u8], valid: &Range<usize>, centre: f32, half: f32) -> Option<u8> {
    let first = centre - half;
    let floor = floorf(first);
    if !(floor >= valid.start as f32) {
        return None;
    }
    let frac = first - floor;
    let base = floor as usize;
    let taps = 2 * half as usize + 1;
    if base + taps >= valid.end {
        return None;
    }
    let mut sum = 0f32;
    for pair in row.get(base..=base + taps)?.windows(2) {
        if let &[a, b] = pair {
            sum += f32::from(a) * (1.0 - frac) + f32::from(b) * frac;
        }
    }
    Some(roundf(sum / taps as f32).clamp(0.0, 255.0) as u8)
}

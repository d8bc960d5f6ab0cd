//! The KG remap: a compact fixed-point table and a streaming, row-by-row
//! remap (the PIPE-like front end of the pipeline).
//!
//! # Table layout (why it is small)
//! On flat ground a KG row (constant z) is one line of constant camera depth,
//! so an ideal pinhole maps it to one camera row `v`, with `u` affine in the
//! column. Each KG row therefore stores a start and a step in Q16.16, exact
//! up to rounding. Lens distortion bends those lines; its *residual* (distorted
//! minus pinhole source position) is smooth, so it is stored on a coarse mesh
//! (a node every [`MESH_STEP`] KG pixels) and interpolated with Catmull-Rom
//! cubics. Without
//! distortion the mesh is all zeros and the table is exact.
//!
//! 256 rows x 20 B + 35 x 35 nodes x 8 B = 14.9 KB for any 256x256 grid.
//!
//! # Streaming
//! [`StreamingRemap::push_row`] takes camera rows in order and emits each KG
//! row as soon as the last camera row it samples has arrived. Camera rows are
//! kept in a caller-provided ring of [`RemapTable::ring_rows`] rows; no whole
//! frame is ever held.

use crate::geometry::Rig;
use crate::grid::{KgGrid, MAX_GRID_SIDE};

/// Fractional bits of the fixed-point source coordinates.
pub const FRAC_BITS: u32 = 16;
const ONE: i32 = 1 << FRAC_BITS;
/// KG pixels between distortion mesh nodes (a power of two: divisions are shifts).
pub const MESH_STEP: usize = 8;
const MESH_SHIFT: u32 = MESH_STEP.trailing_zeros();
/// Mesh nodes per side for the largest grid: nodes -1 ..= n+1 around the
/// grid, for the cubic interpolation's outer taps.
pub const MAX_MESH_SIDE: usize = (MAX_GRID_SIDE - 1) / MESH_STEP + 4;
/// Catmull-Rom weights (sum 1024) for taps -1, 0, 1, 2 at t = k / MESH_STEP.
/// Cubic, not linear: the residual curves too much across a mesh cell near
/// the robot, where one KG row spans several camera rows.
const CUBIC_WEIGHTS: [[i64; 4]; MESH_STEP] = {
    let mut table = [[0i64; 4]; MESH_STEP];
    let mut k = 0;
    while k < MESH_STEP {
        // With t = k/8 and a 1024 denominator every weight is an integer.
        let (k1, k2, k3) = (k as i64, (k * k) as i64, (k * k * k) as i64);
        table[k] = [-k3 + 16 * k2 - 64 * k1, 3 * k3 - 40 * k2 + 1024, -3 * k3 + 32 * k2 + 64 * k1, k3 - 8 * k2];
        k += 1;
    }
    table
};
const CUBIC_SHIFT: u32 = 10;
/// Bits of the bilinear weights (1/256 px: far below the 1/32 px error bound).
const WEIGHT_BITS: u32 = 8;

/// Why a table could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TableError {
    /// The grid is larger than [`MAX_GRID_SIDE`] on a side.
    GridTooLarge,
    /// No KG pixel is seen by the camera.
    NothingInView,
}

/// Why a streamed row was refused. The remap's state is unchanged by a refused row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RemapError {
    /// The row's length is not the camera width.
    RowLength { expected: u16, got: usize },
    /// More rows than the camera height were pushed in one frame.
    TooManyRows,
    /// The ring buffer holds fewer than [`RemapTable::ring_rows`] camera rows.
    RingTooSmall { needed: usize },
    /// The frame ended before all camera rows arrived.
    Incomplete { rows_received: u16 },
    /// The output buffer is smaller than the grid.
    OutputTooSmall,
}

impl core::fmt::Display for RemapError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RemapError::RowLength { expected, got } => write!(f, "camera row has {got} pixels, expected {expected}"),
            RemapError::TooManyRows => f.write_str("more camera rows than the image height"),
            RemapError::RingTooSmall { needed } => write!(f, "row ring needs {needed} bytes"),
            RemapError::Incomplete { rows_received } => write!(f, "frame ended after {rows_received} rows"),
            RemapError::OutputTooSmall => f.write_str("output buffer smaller than the KG grid"),
        }
    }
}

/// One KG row: pinhole source line plus the camera rows and columns it uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct RowMap {
    /// Source u of column 0 and per-column step, Q16.16 (pinhole part).
    u_start: i32,
    u_step: i32,
    /// Source v of the row (pinhole part), Q16.16.
    v: i32,
    /// Camera rows sampled by this KG row (inclusive).
    first_source_row: u16,
    last_source_row: u16,
    /// Columns `[valid_start, valid_end)` that the camera sees.
    valid_start: u16,
    valid_end: u16,
}

/// The compact remap table for one rig and grid. About 14 KB: build it in a
/// static on the target, not on the stack.
#[derive(Clone, Debug)]
pub struct RemapTable {
    grid_width: u16,
    grid_height: u16,
    camera_width: u16,
    camera_height: u16,
    mesh_width: u16,
    has_distortion: bool,
    ring_rows: u16,
    rows: [RowMap; MAX_GRID_SIDE],
    /// Distortion residual (du, dv) at mesh nodes, Q16.16, row-major.
    mesh: [(i32, i32); MAX_MESH_SIDE * MAX_MESH_SIDE],
}

fn to_fixed(value: f64) -> i32 {
    // Saturate: coordinates this far out are outside the image anyway.
    let scaled = libm::round(value * f64::from(ONE));
    scaled.clamp(f64::from(i32::MIN / 2), f64::from(i32::MAX / 2)) as i32
}

/// Catmull-Rom interpolation of four mesh values at `k / MESH_STEP` past the second.
#[inline(always)]
fn mesh_cubic(taps: [i32; 4], k: usize) -> i32 {
    let w = &CUBIC_WEIGHTS[k];
    let sum = i64::from(taps[0]) * w[0] + i64::from(taps[1]) * w[1] + i64::from(taps[2]) * w[2] + i64::from(taps[3]) * w[3];
    (sum >> CUBIC_SHIFT) as i32
}

/// Distortion residual of one KG row at each mesh column, Q16.16.
type RowResidual = [(i32, i32); MAX_MESH_SIDE];

impl RemapTable {
    /// An empty table (all rows invalid); [`RemapTable::build`] fills it in place.
    pub const EMPTY: RemapTable = RemapTable {
        grid_width: 0,
        grid_height: 0,
        camera_width: 0,
        camera_height: 0,
        mesh_width: 0,
        has_distortion: false,
        ring_rows: 0,
        rows: [RowMap {
            u_start: 0,
            u_step: 0,
            v: 0,
            first_source_row: 0,
            last_source_row: 0,
            valid_start: 0,
            valid_end: 0,
        }; MAX_GRID_SIDE],
        mesh: [(0, 0); MAX_MESH_SIDE * MAX_MESH_SIDE],
    };

    /// Builds the table in place (so a target can fill a `static` without a
    /// 14 KB stack temporary).
    pub fn build(&mut self, rig: &Rig, grid: &KgGrid) -> Result<(), TableError> {
        let (width, height) = (grid.width(), grid.height());
        if width > MAX_GRID_SIDE || height > MAX_GRID_SIDE || width == 0 || height == 0 {
            return Err(TableError::GridTooLarge);
        }
        let camera = rig.camera();
        *self = RemapTable::EMPTY;
        self.grid_width = grid.width;
        self.grid_height = grid.height;
        self.camera_width = camera.width;
        self.camera_height = camera.height;
        self.has_distortion = camera.distortion.is_some();
        let mesh_width = (width - 1) / MESH_STEP + 4;
        let mesh_height = (height - 1) / MESH_STEP + 4;
        self.mesh_width = mesh_width as u16;

        // Pinhole part, exact per row.
        for (j, row) in self.rows.iter_mut().enumerate().take(height) {
            let (x0, z) = grid.pixel_to_ground(0.0, j as f64);
            let (x1, _) = grid.pixel_to_ground(1.0, j as f64);
            if let (Some(p0), Some(p1)) = (rig.ground_to_undistorted_pixel(x0, z), rig.ground_to_undistorted_pixel(x1, z)) {
                row.u_start = to_fixed(p0.u);
                row.u_step = to_fixed(p1.u - p0.u);
                row.v = to_fixed(p0.v);
                row.valid_end = width as u16; // narrowed below
            }
        }
        // Distortion residual on the mesh (zeros without distortion).
        if self.has_distortion {
            for mesh_row in 0..mesh_height {
                for mesh_column in 0..mesh_width {
                    // Storage index n holds node n - 1 (one node of padding).
                    let (x, z) = grid.pixel_to_ground(
                        (mesh_column as f64 - 1.0) * MESH_STEP as f64,
                        (mesh_row as f64 - 1.0) * MESH_STEP as f64,
                    );
                    let residual = match rig.ground_to_undistorted_pixel(x, z) {
                        Some(pinhole) => {
                            let distorted = rig.distort_pixel_extended(pinhole);
                            (to_fixed(distorted.u - pinhole.u), to_fixed(distorted.v - pinhole.v))
                        }
                        None => (0, 0), // behind the camera: the row is invalid anyway
                    };
                    self.mesh[mesh_row * MAX_MESH_SIDE + mesh_column] = residual;
                }
            }
        }
        // Validity and source rows, from the very coordinates the remap will use.
        let max_u = (i32::from(camera.width) - 1) << FRAC_BITS;
        let max_v = (i32::from(camera.height) - 1) << FRAC_BITS;
        let mut any_valid = false;
        let mut rows_needed_through = 0u16; // camera rows that must have arrived
        let mut ring_rows = 1u16;
        for j in 0..height {
            if self.rows[j].valid_end == 0 {
                continue;
            }
            let mut residual = [(0, 0); MAX_MESH_SIDE];
            self.row_residual(j, &mut residual);
            // Longest run of in-image columns: inside it every sample is safe.
            let (mut best, mut run_start) = ((0usize, 0usize), None);
            for i in 0..=width {
                let inside = i < width && {
                    let (u, v) = self.source(&self.rows[j], &residual, i);
                    (0..=max_u).contains(&u) && (0..=max_v).contains(&v)
                };
                match (inside, run_start) {
                    (true, None) => run_start = Some(i),
                    (false, Some(start)) => {
                        if i - start > best.1 - best.0 {
                            best = (start, i);
                        }
                        run_start = None;
                    }
                    _ => {}
                }
            }
            let row = &mut self.rows[j];
            row.valid_start = best.0 as u16;
            row.valid_end = best.1 as u16;
            if best.1 == best.0 {
                row.valid_start = 0;
                row.valid_end = 0;
                continue;
            }
            any_valid = true;
            let (mut first, mut last) = (u16::MAX, 0u16);
            for i in best.0..best.1 {
                let (_, v) = self.source(&self.rows[j], &residual, i);
                let top = (v >> FRAC_BITS) as u16;
                let bottom = (top + 1).min(camera.height - 1);
                first = first.min(top);
                last = last.max(bottom);
            }
            let row = &mut self.rows[j];
            row.first_source_row = first;
            row.last_source_row = last;
            rows_needed_through = rows_needed_through.max(last + 1);
            ring_rows = ring_rows.max(rows_needed_through - first);
        }
        if !any_valid {
            return Err(TableError::NothingInView);
        }
        self.ring_rows = ring_rows;
        Ok(())
    }

    /// Builds a table by value (host convenience; ~14 KB on the stack).
    pub fn new(rig: &Rig, grid: &KgGrid) -> Result<RemapTable, TableError> {
        let mut table = RemapTable::EMPTY;
        table.build(rig, grid)?;
        Ok(table)
    }

    /// Distortion residual of KG row `j` at each mesh column.
    #[inline]
    fn row_residual(&self, j: usize, out: &mut RowResidual) {
        if !self.has_distortion {
            return;
        }
        let mesh_row = j >> MESH_SHIFT; // storage rows mesh_row ..= mesh_row + 3
        let k = j & (MESH_STEP - 1);
        let width = usize::from(self.mesh_width);
        let row = |n: usize| &self.mesh[(mesh_row + n) * MAX_MESH_SIDE..][..width];
        let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
        for (c, slot) in out.iter_mut().enumerate().take(width) {
            *slot = (
                mesh_cubic([r0[c].0, r1[c].0, r2[c].0, r3[c].0], k),
                mesh_cubic([r0[c].1, r1[c].1, r2[c].1, r3[c].1], k),
            );
        }
    }

    /// Source position (Q16.16) of KG pixel `i` of a row.
    #[inline(always)]
    fn source(&self, row: &RowMap, residual: &RowResidual, i: usize) -> (i32, i32) {
        let pinhole_u = row.u_start.wrapping_add((i as i32).wrapping_mul(row.u_step));
        if !self.has_distortion {
            return (pinhole_u, row.v);
        }
        let node = i >> MESH_SHIFT; // storage columns node ..= node + 3
        let k = i & (MESH_STEP - 1);
        let r = &residual[node..node + 4];
        let du = mesh_cubic([r[0].0, r[1].0, r[2].0, r[3].0], k);
        let dv = mesh_cubic([r[0].1, r[1].1, r[2].1, r[3].1], k);
        (pinhole_u.wrapping_add(du), row.v.wrapping_add(dv))
    }

    /// Source position in pixels of KG pixel (column, row), or None where the
    /// camera does not see it. This is exactly what the remap samples.
    pub fn source_pixel(&self, column: usize, row: usize) -> Option<(f64, f64)> {
        let map = self.rows.get(row).filter(|_| row < self.grid_height())?;
        if column < usize::from(map.valid_start) || column >= usize::from(map.valid_end) {
            return None;
        }
        let mut residual = [(0, 0); MAX_MESH_SIDE];
        self.row_residual(row, &mut residual);
        let (u, v) = self.source(map, &residual, column);
        Some((f64::from(u) / f64::from(ONE), f64::from(v) / f64::from(ONE)))
    }

    pub fn grid_width(&self) -> usize {
        usize::from(self.grid_width)
    }
    pub fn grid_height(&self) -> usize {
        usize::from(self.grid_height)
    }
    pub fn camera_width(&self) -> usize {
        usize::from(self.camera_width)
    }
    pub fn camera_height(&self) -> usize {
        usize::from(self.camera_height)
    }
    /// Camera rows the streaming ring must hold.
    pub fn ring_rows(&self) -> usize {
        usize::from(self.ring_rows)
    }
    /// Bytes the streaming ring must hold.
    pub fn ring_bytes(&self) -> usize {
        self.ring_rows() * self.camera_width()
    }
    /// Columns of KG row `row` that the camera sees; the rest are invalid (0).
    pub fn valid_columns(&self, row: usize) -> core::ops::Range<usize> {
        match self.rows.get(row) {
            Some(map) if row < self.grid_height() => usize::from(map.valid_start)..usize::from(map.valid_end),
            _ => 0..0,
        }
    }
    /// Size of the table in bytes (what the target stores).
    pub const fn size_bytes() -> usize {
        core::mem::size_of::<RemapTable>()
    }
}

/// Bilinear sample at (u, v) Q16.16 from two camera rows, in integers.
#[inline(always)]
fn bilinear(upper: &[u8], lower: &[u8], u: i32, v: i32) -> u8 {
    let x0 = (u >> FRAC_BITS) as usize;
    let x1 = (x0 + 1).min(upper.len() - 1);
    let wx = ((u >> (FRAC_BITS - WEIGHT_BITS)) & 0xFF) as u32;
    let wy = ((v >> (FRAC_BITS - WEIGHT_BITS)) & 0xFF) as u32;
    let top = u32::from(upper[x0]) * (256 - wx) + u32::from(upper[x1]) * wx;
    let bottom = u32::from(lower[x0]) * (256 - wx) + u32::from(lower[x1]) * wx;
    ((top * (256 - wy) + bottom * wy + (1 << (2 * WEIGHT_BITS - 1))) >> (2 * WEIGHT_BITS)) as u8
}

/// Row-by-row remap of one frame at a time; see the module docs.
pub struct StreamingRemap<'t, 'r> {
    table: &'t RemapTable,
    ring: &'r mut [u8],
    rows_received: u16,
    next_kg_row: u16,
    kg_row: [u8; MAX_GRID_SIDE],
}

impl<'t, 'r> StreamingRemap<'t, 'r> {
    /// `ring` must hold at least [`RemapTable::ring_bytes`] bytes.
    pub fn new(table: &'t RemapTable, ring: &'r mut [u8]) -> Result<Self, RemapError> {
        if ring.len() < table.ring_bytes() {
            return Err(RemapError::RingTooSmall { needed: table.ring_bytes() });
        }
        Ok(StreamingRemap { table, ring, rows_received: 0, next_kg_row: 0, kg_row: [0; MAX_GRID_SIDE] })
    }

    /// Forgets the current frame (after a dropped or broken frame).
    pub fn reset(&mut self) {
        self.rows_received = 0;
        self.next_kg_row = 0;
    }

    /// Camera rows received in the current frame.
    pub fn rows_received(&self) -> usize {
        usize::from(self.rows_received)
    }

    /// True when every KG row of the frame has been emitted.
    pub fn frame_done(&self) -> bool {
        usize::from(self.next_kg_row) == self.table.grid_height()
    }

    /// Pushes the next camera row; calls `emit(kg_row_index, kg_row)` for every
    /// KG row that became ready. After the last camera row the frame is complete
    /// and the next push starts a new frame.
    pub fn push_row(&mut self, camera_row: &[u8], mut emit: impl FnMut(usize, &[u8])) -> Result<(), RemapError> {
        let table = self.table;
        if camera_row.len() != table.camera_width() {
            return Err(RemapError::RowLength { expected: table.camera_width, got: camera_row.len() });
        }
        if usize::from(self.rows_received) >= table.camera_height() {
            return Err(RemapError::TooManyRows);
        }
        let width = table.camera_width();
        let slot = usize::from(self.rows_received) % table.ring_rows();
        self.ring[slot * width..][..width].copy_from_slice(camera_row);
        self.rows_received += 1;

        while usize::from(self.next_kg_row) < table.grid_height() {
            let j = usize::from(self.next_kg_row);
            let map = &table.rows[j];
            let empty = map.valid_end == map.valid_start;
            if !empty && map.last_source_row >= self.rows_received {
                break;
            }
            self.render_row(j);
            emit(j, &self.kg_row[..table.grid_width()]);
            self.next_kg_row += 1;
        }
        if usize::from(self.rows_received) == table.camera_height() {
            // Every KG row needs only rows that exist, so all were emitted.
            self.reset();
        }
        Ok(())
    }

    /// Samples KG row `j` from the ring into `self.kg_row`.
    fn render_row(&mut self, j: usize) {
        let table = self.table;
        let map = &table.rows[j];
        let out = &mut self.kg_row[..table.grid_width()];
        out.fill(0);
        let valid = usize::from(map.valid_start)..usize::from(map.valid_end);
        if valid.is_empty() {
            return;
        }
        let width = table.camera_width();
        let ring_rows = table.ring_rows();
        let ring = &*self.ring;
        let row_at = |camera_row: usize| &ring[(camera_row % ring_rows) * width..][..width];
        let last_row = table.camera_height() - 1;
        if !table.has_distortion {
            // Fast path: the whole KG row samples one pair of camera rows.
            let top = (map.v >> FRAC_BITS) as usize;
            let (upper, lower) = (row_at(top), row_at((top + 1).min(last_row)));
            let mut u = map.u_start.wrapping_add((valid.start as i32).wrapping_mul(map.u_step));
            for pixel in &mut out[valid] {
                *pixel = bilinear(upper, lower, u, map.v);
                u = u.wrapping_add(map.u_step);
            }
            return;
        }
        let mut residual = [(0, 0); MAX_MESH_SIDE];
        table.row_residual(j, &mut residual);
        for i in valid {
            let (u, v) = table.source(map, &residual, i);
            let top = (v >> FRAC_BITS) as usize;
            out[i] = bilinear(row_at(top), row_at((top + 1).min(last_row)), u, v);
        }
    }
}

/// Whole-frame remap through the streaming path (bit-identical by construction).
/// `out` receives the grid row-major; invalid pixels are 0.
pub fn remap_frame(table: &RemapTable, frame: &[u8], ring: &mut [u8], out: &mut [u8]) -> Result<(), RemapError> {
    let (width, height) = (table.camera_width(), table.camera_height());
    if frame.len() != width * height {
        return Err(RemapError::RowLength { expected: table.camera_width, got: frame.len() / height.max(1) });
    }
    let grid_width = table.grid_width();
    if out.len() < grid_width * table.grid_height() {
        return Err(RemapError::OutputTooSmall);
    }
    let mut stream = StreamingRemap::new(table, ring)?;
    for camera_row in frame.chunks_exact(width) {
        stream.push_row(camera_row, |j, kg_row| out[j * grid_width..][..grid_width].copy_from_slice(kg_row))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Aoi, Distortion, Intrinsics, Mount, Rig};
    use crate::grid::GridConfig;

    /// Rigs unlike the samples: other focal lengths, fx != fy, an off-centre
    /// principal point, barrel and pincushion distortion with tangential terms.
    pub(crate) fn test_rigs() -> [Rig; 5] {
        let aoi = Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 };
        let mount = Mount { height_mm: 400.0, tilt_deg: 32.0 };
        let camera = Intrinsics { width: 256, height: 256, fx: 240.0, fy: 240.0, cx: 127.5, cy: 127.5, distortion: None };
        let barrel = Distortion { k1: -0.30, k2: 0.09, p1: 0.0012, p2: -0.0008, k3: -0.01 };
        let pincushion = Distortion { k1: 0.12, k2: 0.02, p1: -0.001, p2: 0.0005, k3: 0.0 };
        [
            Rig::new_checked(camera, mount, aoi).unwrap(),
            Rig::new_checked(
                Intrinsics { width: 320, height: 240, fx: 277.0, fy: 277.0, cx: 159.5, cy: 119.5, distortion: None },
                Mount { height_mm: 300.0, tilt_deg: 40.0 },
                Aoi { half_width_mm: 200.0, near_mm: 300.0, far_mm: 800.0 },
            )
            .unwrap(),
            Rig::new_checked(Intrinsics { fx: 215.0, fy: 200.0, cx: 140.2, cy: 110.7, ..camera }, mount, aoi).unwrap(),
            Rig::new_checked(
                Intrinsics { width: 320, height: 240, fx: 210.0, fy: 212.0, cx: 163.0, cy: 117.0, distortion: Some(barrel) },
                Mount { height_mm: 350.0, tilt_deg: 35.0 },
                Aoi { half_width_mm: 250.0, near_mm: 400.0, far_mm: 1200.0 },
            )
            .unwrap(),
            Rig::new_checked(Intrinsics { fx: 260.0, fy: 262.0, distortion: Some(pincushion), ..camera }, mount, aoi).unwrap(),
        ]
    }

    /// Largest distance (px) between the table's source coordinate and the
    /// exact float projection, over every valid KG pixel.
    fn max_source_error(rig: &Rig, grid: &KgGrid, table: &RemapTable) -> f64 {
        let mut worst: f64 = 0.0;
        for j in 0..grid.height() {
            for i in table.valid_columns(j) {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let exact = rig.ground_to_pixel(x, z).unwrap();
                let (u, v) = table.source_pixel(i, j).unwrap();
                worst = worst.max((u - exact.u).abs()).max((v - exact.v).abs());
            }
        }
        worst
    }

    #[test]
    fn table_is_compact() {
        assert!(RemapTable::size_bytes() <= 16 * 1024, "{} bytes", RemapTable::size_bytes());
    }

    #[test]
    fn source_coordinates_within_a_32nd_of_a_pixel() {
        for (n, rig) in test_rigs().iter().enumerate() {
            for mm_per_px in [None, Some(5.0)] {
                let grid = KgGrid::for_rig(rig, &GridConfig { mm_per_px, ..GridConfig::default() }).unwrap();
                let table = RemapTable::new(rig, &grid).unwrap();
                let error = max_source_error(rig, &grid, &table);
                std::println!("rig {n} grid {}x{}: max source error {error:.5} px", grid.width, grid.height);
                assert!(error <= 1.0 / 32.0, "rig {n}: {error} px");
            }
        }
    }

    #[test]
    fn invalid_pixels_are_the_unseen_ones() {
        for rig in test_rigs().iter() {
            let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
            let table = RemapTable::new(rig, &grid).unwrap();
            let (w, h) = (f64::from(rig.camera().width) - 1.0, f64::from(rig.camera().height) - 1.0);
            for j in 0..grid.height() {
                for i in 0..grid.width() {
                    let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                    let seen = rig
                        .ground_to_pixel(x, z)
                        .is_some_and(|p| p.u > 0.05 && p.v > 0.05 && p.u < w - 0.05 && p.v < h - 0.05);
                    if seen {
                        assert!(table.valid_columns(j).contains(&i), "seen pixel ({i},{j}) marked invalid");
                    }
                }
            }
            // The AOI itself is always entirely valid.
            let aoi = grid.aoi_pixels(rig);
            for j in aoi.top..aoi.bottom {
                let valid = table.valid_columns(j);
                assert!(valid.start <= aoi.left && valid.end >= aoi.right);
            }
        }
    }

    #[test]
    fn streaming_emits_rows_early_and_matches_whole_frame() {
        for rig in test_rigs().iter() {
            let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
            let table = RemapTable::new(rig, &grid).unwrap();
            let (cw, ch) = (table.camera_width(), table.camera_height());
            let frame: std::vec::Vec<u8> = (0..cw * ch).map(|n| ((n * 7919 + n / cw * 31) % 251) as u8).collect();
            let mut ring = std::vec![0u8; table.ring_bytes()];
            let mut whole = std::vec![0u8; grid.len()];
            remap_frame(&table, &frame, &mut ring, &mut whole).unwrap();

            let mut ring = std::vec![0u8; table.ring_bytes()];
            let mut stream = StreamingRemap::new(&table, &mut ring).unwrap();
            let mut emitted_after = std::vec![usize::MAX; grid.height()];
            let mut streamed = std::vec![0u8; grid.len()];
            for (n, row) in frame.chunks_exact(cw).enumerate() {
                stream
                    .push_row(row, |j, kg| {
                        emitted_after[j] = n + 1;
                        streamed[j * grid.width()..][..grid.width()].copy_from_slice(kg);
                    })
                    .unwrap();
            }
            assert_eq!(streamed, whole);
            for j in 0..grid.height() {
                let valid = table.valid_columns(j);
                if !valid.is_empty() {
                    // Emitted as soon as its last source row arrived, not later.
                    assert_eq!(emitted_after[j], usize::from(table.rows[j].last_source_row) + 1);
                }
                for i in 0..grid.width() {
                    if !valid.contains(&i) {
                        assert_eq!(whole[j * grid.width() + i], 0);
                    }
                }
            }
            assert!(table.ring_rows() < ch / 2, "ring of {} rows is not bounded", table.ring_rows());
        }
    }

    #[test]
    fn remap_matches_float_bilinear_reference() {
        let rig = &test_rigs()[3];
        let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
        let table = RemapTable::new(rig, &grid).unwrap();
        let (cw, ch) = (table.camera_width(), table.camera_height());
        // A smooth ramp: bilinear interpolation of it is exact, so the integer
        // remap must agree with the float projection to within rounding.
        let ramp = |u: f64, v: f64| 0.4 * u + 0.5 * v;
        let frame: std::vec::Vec<u8> =
            (0..cw * ch).map(|n| libm::round(ramp((n % cw) as f64, (n / cw) as f64)) as u8).collect();
        let mut ring = std::vec![0u8; table.ring_bytes()];
        let mut out = std::vec![0u8; grid.len()];
        remap_frame(&table, &frame, &mut ring, &mut out).unwrap();
        for j in 0..grid.height() {
            for i in table.valid_columns(j) {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let p = rig.ground_to_pixel(x, z).unwrap();
                let expected = ramp(p.u, p.v);
                let got = f64::from(out[j * grid.width() + i]);
                // Input rounding (0.5) plus output rounding (0.5), plus the tiny source error.
                assert!((got - expected).abs() <= 1.01, "({i},{j}): {got} vs {expected}");
            }
        }
    }

    #[test]
    fn refused_rows_leave_state_unchanged() {
        let rig = &test_rigs()[0];
        let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
        let table = RemapTable::new(rig, &grid).unwrap();
        let mut small = [0u8; 4];
        assert!(matches!(StreamingRemap::new(&table, &mut small), Err(RemapError::RingTooSmall { .. })));
        let mut ring = std::vec![0u8; table.ring_bytes()];
        let mut stream = StreamingRemap::new(&table, &mut ring).unwrap();
        let err = stream.push_row(&[0u8; 3], |_, _| {}).unwrap_err();
        assert_eq!(err, RemapError::RowLength { expected: 256, got: 3 });
        assert_eq!(stream.rows_received(), 0);
    }
}

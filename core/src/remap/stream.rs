//! The streaming remap: camera rows in, each KG row out as soon as the last
//! camera row it samples has arrived (see the module docs of [`super`]).

use super::*;

/// Row-by-row remap of one frame at a time; see the module docs. The ring
/// of camera rows is lent to each call, the same memory throughout a frame
/// (at least [`RemapTable::ring_bytes`] bytes; a smaller one is refused).
pub struct StreamingRemap<'t> {
    table: &'t RemapTable,
    rows_received: u16,
    next_kg_row: u16,
    kg_row: [u8; MAX_GRID_SIDE],
}

impl<'t> StreamingRemap<'t> {
    pub fn new(table: &'t RemapTable) -> Self {
        StreamingRemap { table, rows_received: 0, next_kg_row: 0, kg_row: [0; MAX_GRID_SIDE] }
    }

    /// The ring's first [`RemapTable::ring_bytes`] bytes, or the error.
    fn checked<'a>(&self, ring: &'a [u8]) -> Result<&'a [u8], RemapError> {
        let needed = self.table.ring_bytes();
        ring.get(..needed).ok_or(RemapError::RingTooSmall { needed })
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

    /// Pushes the next camera row into `ring`; calls `emit(kg_row_index,
    /// kg_row)` for every KG row that became ready, sampled through `line`
    /// (any contents). After the last camera row the frame is complete and
    /// the next push starts a new frame.
    pub fn push_row(&mut self, ring: &mut [u8], camera_row: &[u8], line: &mut Line, mut emit: impl FnMut(usize, &[u8])) -> Result<(), RemapError> {
        self.store_row(ring, camera_row)?;
        while let Some((j, kg_row)) = self.next_kg_row(ring, line)? {
            emit(j, kg_row);
        }
        Ok(())
    }

    /// [`Self::push_row`]'s first half: keeps the next camera row in
    /// `ring`. Then [`Self::next_kg_row`] until None gives the KG rows it
    /// completed; between the calls the ring's memory is the caller's.
    pub fn store_row(&mut self, ring: &mut [u8], camera_row: &[u8]) -> Result<(), RemapError> {
        let table = self.table;
        if camera_row.len() != table.camera_width() {
            return Err(RemapError::RowLength { expected: table.camera_width, got: camera_row.len() });
        }
        if usize::from(self.rows_received) >= table.camera_height() {
            return Err(RemapError::TooManyRows);
        }
        let needed = table.ring_bytes();
        let ring = ring.get_mut(..needed).ok_or(RemapError::RingTooSmall { needed })?;
        let width = table.camera_width();
        let slot = usize::from(self.rows_received) % table.ring_rows();
        copy_row(&mut ring[slot * width..][..width], camera_row);
        self.rows_received += 1;
        Ok(())
    }

    /// The next KG row the camera rows stored so far complete, sampled from
    /// `ring` through `line` (any contents), with its index; None when the
    /// next one needs rows still to come. After the frame's last KG row the
    /// next camera row starts a new frame.
    pub fn next_kg_row(&mut self, ring: &[u8], line: &mut Line) -> Result<Option<(usize, &[u8])>, RemapError> {
        let table = self.table;
        let j = usize::from(self.next_kg_row);
        let ready = j < table.grid_height()
            && table.rows.get(j).is_some_and(|map| map.valid_end == map.valid_start || map.last_source_row < self.rows_received);
        if !ready {
            if usize::from(self.rows_received) == table.camera_height() {
                // Every KG row needs only rows that exist, so all were emitted.
                self.reset();
            }
            return Ok(None);
        }
        let ring = self.checked(ring)?;
        self.render_row(ring, j, line);
        self.next_kg_row += 1;
        Ok(Some((j, &self.kg_row[..table.grid_width()])))
    }

    /// Samples KG row `j` from `ring` into `self.kg_row`.
    fn render_row(&mut self, ring: &[u8], j: usize, line: &mut Line) {
        let table = self.table;
        let map = &table.rows[j];
        let out = &mut self.kg_row[..table.grid_width()];
        let valid = usize::from(map.valid_start)..usize::from(map.valid_end);
        if valid.is_empty() {
            out.fill(0);
            return;
        }
        // Both paths below write every valid pixel: clear only the others.
        out[..valid.start].fill(0);
        out[valid.end..].fill(0);
        let width = table.camera_width();
        let ring_rows = table.ring_rows();
        let row_at = |camera_row: usize| &ring[(camera_row % ring_rows) * width..][..width];
        let last_row = table.camera_height() - 1;
        if table.crooked {
            // A slanted line (roll) or a projective one (yaw): per pixel.
            let lens = &table.lens;
            for (i, pixel) in valid.clone().zip(out[valid].iter_mut()) {
                // Valid pixels passed the same evaluation at build time.
                let (x, y) = crooked_point(map, i).unwrap_or((0, 0));
                let (u, v) = if table.has_distortion {
                    let (u, v) = lens_source(lens, x, y, mulq(y, y, lens.q)).unwrap_or((0, 0));
                    (u as i32, v as i32)
                } else {
                    (x, y)
                };
                let top = (v >> FRAC_BITS) as usize;
                *pixel = bilinear(row_at(top), row_at((top + 1).min(last_row)), u, v);
            }
            return;
        }
        if !table.has_distortion {
            // Fast path: the whole KG row samples one pair of camera rows at
            // one v, so it is a vertical pass then a horizontal one (see `kernels::pinhole`).
            let top = (map.v >> FRAC_BITS) as usize;
            let (upper, lower) = (row_at(top), row_at((top + 1).min(last_row)));
            let u = map.u_start.wrapping_add((valid.start as i32).wrapping_mul(map.u_step));
            pinhole::sample_row(upper, lower, u, map.u_step, map.v, line, &mut out[valid]);
            return;
        }
        // Lens path: normalised x steps along the row, y is the row's.
        let lens = &table.lens;
        let (y, step) = (map.v, map.u_step);
        let y2 = mulq(y, y, lens.q);
        let mut x = map.u_start.wrapping_add((valid.start as i32).wrapping_mul(step));
        for pixel in &mut out[valid] {
            // Valid pixels passed the same evaluation at build time.
            let (u, v) = lens_source(lens, x, y, y2).unwrap_or((0, 0));
            let (u, v) = (u as i32, v as i32);
            let top = (v >> FRAC_BITS) as usize;
            *pixel = bilinear(row_at(top), row_at((top + 1).min(last_row)), u, v);
            x = x.wrapping_add(step);
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
    let mut stream = StreamingRemap::new(table);
    let mut line = Line::ZERO;
    for camera_row in frame.chunks_exact(width) {
        stream.push_row(ring, camera_row, &mut line, |j, kg_row| out[j * grid_width..][..grid_width].copy_from_slice(kg_row))?;
    }
    Ok(())
}

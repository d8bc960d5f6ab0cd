//! The row step: one KG row of the current frame through every stage, and
//! its per-pixel reference (the tests' oracle for the whole-line passes).

use super::keyframe::Keyframe;
use super::warp::{KeptRuns, Runs};
use super::Gpa;

impl Gpa<'_> {
    /// One KG row against the warped keyframe: band, residue, hypotheses,
    /// shift search. Same results as the per-pixel reference below, organised
    /// as whole-line passes: keyframe rows looked up once per line, constant
    /// bilinear weights on translation rows, per-cell sums over column
    /// segments, and the shift search as block kernels.
    pub(super) fn compare_row(&mut self, keyframe: &Keyframe, j: usize, row: &[u8], exposure: Option<&[u8; 256]>) {
        let s = self.config.search_radius;
        let mut lap = self.profiler.now();
        let warp = self.row_line(j);
        let Some(seen) = self.coverage.seen(j) else {
            self.profiler.charge(lap, |p| &mut p.warp);
            self.finish_residue(j);
            self.end_row(keyframe, j, exposure);
            return;
        };
        let (grid, cells, aoi) = (&self.layout.grid, &self.layout.cells, &self.layout.aoi);
        let cell_row = j / cells.px;
        let mut runs = Runs::new();
        self.coverage.usable_runs(warp, seen.clone(), grid, &mut runs);
        self.cell_row_runs[j % cells.px] = KeptRuns::keep(&runs);
        let in_aoi = j >= aoi.top && j < aoi.bottom;
        let shifts = in_aoi && self.search_shifts;
        let rows = self.workspace.rows();
        // Every stage reads the band within the usable runs, widened by as
        // far as it looks beside them: that is all the band holds.
        let usable = runs.first().zip(runs.last()).map_or(0..0, |(first, last)| usize::from(first.0)..usize::from(last.1));
        rows.band.sample(keyframe, j, warp, usable, s, if shifts { s } else { 1 });
        let band = rows.band.rows(s);
        lap = self.profiler.charge(lap, |p| &mut p.warp);

        let in_cells = cell_row < cells.high;
        if in_cells {
            let full = self.parallax.hypotheses.ground_tolerance(j);
            let threshold = self.noise.residue_threshold();
            rows.residue.add_row(j, row, &band, s, &runs, full, threshold);
        }
        lap = self.profiler.charge(lap, |p| &mut p.residue);

        if in_aoi {
            rows.search.add_row(row, &band, s, &runs, aoi, self.layout.in_far_half(j), self.search_shifts, true);
        }
        lap = self.profiler.charge(lap, |p| &mut p.shift_search);
        self.finish_residue(j);
        lap = self.profiler.charge(lap, |p| &mut p.residue);
        self.end_row(keyframe, j, exposure);
        self.profiler.charge(lap, |p| &mut p.parallax);
    }

    /// After row `j`: if it was its cell row's last, the height hypotheses
    /// of that cell row, then its decision. The hypotheses run only in the
    /// cells whose ground residue leaves room for a height
    /// ([`super::parallax::Parallax::spans_to_try`]); the others get
    /// none whatever they would sum, so the heights are the same as when
    /// every cell is tried, at a fraction of the cost on open ground.
    fn end_row(&mut self, keyframe: &Keyframe, j: usize, exposure: Option<&[u8; 256]>) {
        let cells = self.layout.cells;
        let cell_row = j / cells.px;
        if self.ends_cell_row(j) && cell_row < cells.high {
            let min_gain = self.config.parallax_min_gain.max(self.noise.level());
            let mut spans = super::parallax::CellSpans::new();
            self.parallax.spans_to_try(&cells, min_gain, &mut spans);
            if !spans.is_empty() {
                // The rows' exposure-adjusted values, and any usable runs
                // too many to keep, are made again here (their warps were
                // kept): keeping a cell row's would cost ~8 KB of RAM, and
                // on open ground few cell rows get this far.
                let grid = &self.layout.grid;
                let mut runs = Runs::new();
                let super::workspace::RowStages { positions, samples, adjusted, .. } = self.workspace.rows();
                for row_j in cell_row * cells.px..=j {
                    let Some(seen) = self.coverage.seen(row_j) else { continue };
                    let warp = self.cell_row_warps[row_j % cells.px];
                    if !self.cell_row_runs[row_j % cells.px].restore(&mut runs) {
                        self.coverage.usable_runs(warp, seen.clone(), grid, &mut runs);
                    }
                    let row = super::exposed(keyframe.current_row(row_j), exposure, adjusted);
                    for span in &spans {
                        let columns = seen.start.max(span.start)..seen.end.min(span.end);
                        if !columns.is_empty() {
                            self.parallax.add_row(keyframe, warp, columns, &runs, row, &cells, positions, samples);
                        }
                    }
                }
            }
        }
        self.close_cell_row(j);
    }

    /// After row `j`: if it was its cell row's last, that cell row's
    /// residues counted into its cells (the ground's for the hypotheses).
    fn finish_residue(&mut self, j: usize) {
        let cells = self.layout.cells;
        if self.ends_cell_row(j) && j / cells.px < cells.high {
            self.workspace.rows().residue.finish_cell_row(&cells, j / cells.px, self.layout.grid.width(), &mut self.parallax.sums);
        }
    }

    /// Current row `j`'s line, kept for its cell row's hypotheses: row 0's
    /// own, then each continuing the row above's where it may
    /// ([`super::warp::Warp::row_after`]). Rows come in order, 0 first.
    fn row_line(&mut self, j: usize) -> super::warp::RowWarp {
        let px = self.layout.cells.px;
        let line = if j == 0 { self.warp.row(0) } else { self.warp.row_after(j, self.cell_row_warps[(j - 1) % px]) };
        self.cell_row_warps[j % px] = line;
        line
    }

    /// After row `j`: decides its cell row if `j` was that row's last.
    fn close_cell_row(&mut self, j: usize) {
        if self.ends_cell_row(j) {
            let cells = self.layout.cells;
            self.parallax.finish_cell_row(j / cells.px, &cells, self.layout.camera_height_mm, &self.noise, &self.config);
        }
    }

    /// Whether row `j` is its cell row's last one analysed.
    fn ends_cell_row(&self, j: usize) -> bool {
        (j + 1).is_multiple_of(self.layout.cells.px) || j + 1 == self.layout.analysis_rows
    }

    /// The plain per-pixel form of [`Self::compare_row`], kept as its
    /// reference: the tests check that both leave identical state.
    #[cfg(test)]
    // Indexed loops on purpose: the reference is written pixel by pixel.
    #[allow(clippy::needless_range_loop)]
    pub(super) fn compare_row_reference(&mut self, keyframe: &Keyframe, j: usize, row: &[u8]) {
        use super::parallax::HYPOTHESES;
        use super::warp::FRAC;
        use crate::grid::MAX_GRID_SIDE;
        use crate::limits::MAX_SEARCH_RADIUS;

        let s = self.config.search_radius;
        let grid = self.layout.grid;
        let width = grid.width();
        let warp = self.row_line(j);
        let Some(seen) = self.coverage.seen(j) else {
            self.close_cell_row(j);
            return;
        };
        let (cur_lo, cur_hi) = (seen.start, seen.end);
        let cells = self.layout.cells;
        let aoi = self.layout.aoi;
        let cell_row = j / cells.px;
        // Columns whose whole search neighbourhood lies in the keyframe's view.
        let mut usable = [false; MAX_GRID_SIDE];
        for c in cur_lo..cur_hi {
            usable[c] = self.coverage.usable(warp, c, &grid);
        }
        // The search band: band[dg][c + MAX_SEARCH_RADIUS] = keyframe at warp(c) + (0, dg - S).
        let rows = self.workspace.rows();
        let band = rows.band.unrolled();
        let first = cur_lo.saturating_sub(s);
        let last = (cur_hi + s).min(width);
        for dg in 0..=2 * s {
            for c in first..last {
                let (i_ref, j_ref) = warp.at(c);
                let (i, jr) = (i_ref, j_ref + ((dg as i32 - s as i32) << FRAC));
                let value = if keyframe.inside(i, jr) { keyframe.sample(i, jr) } else { 0 };
                band[dg][c + MAX_SEARCH_RADIUS] = value;
            }
        }
        // Height hypotheses (0 = the ground prediction itself, band[S]).
        // A sample off the keyframe is None: that hypothesis skips the pixel.
        let hypotheses = &self.parallax.hypotheses;
        let mut hypothesis_rows = [[None; MAX_GRID_SIDE]; HYPOTHESES];
        for k in hypotheses.active() {
            let (oi, oj) = hypotheses.offset[k];
            for c in cur_lo..cur_hi {
                let (i_ref, j_ref) = warp.at(c);
                let (i, jr) = (i_ref.wrapping_add(oi), j_ref.wrapping_add(oj));
                hypothesis_rows[k][c] = keyframe.inside(i, jr).then(|| keyframe.sample(i, jr));
            }
        }
        let in_aoi_row = j >= aoi.top && j < aoi.bottom;
        // A heading error moves far ground sideways by more than half a pixel.
        let (_, row_z) = grid.pixel_to_ground(0.0, j as f64);
        let yaw_blur = row_z * self.config.odometry_yaw_error_deg.to_radians() > 0.5 * grid.mm_per_px;
        let (full_k, full_g) = (hypotheses.full_tolerance.0 || yaw_blur, hypotheses.full_tolerance.1);
        // The far half of the AOI gets its own SADs: a yaw error shifts far
        // rows sideways more than near ones, which is how it is measured.
        let far_half = j < (aoi.top + aoi.bottom) / 2;
        let threshold = self.noise.residue_threshold();
        let (residue, sums, search) = (&mut rows.residue, &mut self.parallax.sums, &mut rows.search);
        for c in cur_lo..cur_hi {
            if !usable[c] {
                continue;
            }
            let value = row[c];
            let centre = c + MAX_SEARCH_RADIUS;
            // Two tolerant residues (Birchfield-Tomasi style): the current
            // value against the range the warped keyframe spans around the
            // prediction. For the parallax test's ground hypothesis the range
            // reaches half a pixel (a full pixel along an axis where the
            // odometry may be that far off); the residue that flags anything
            // unexplained always reaches the full neighbours, so a shift
            // search that lands a pixel away cannot light up ground edges.
            let here = band[s][centre];
            let sideways = [band[s][centre - 1], band[s][centre + 1]];
            let along = [band[s - 1][centre], band[s + 1][centre]];
            let half = |other: u8| ((u16::from(here) + u16::from(other) + 1) >> 1) as u8;
            let (mut low, mut high) = (here, here);
            let (mut wide_low, mut wide_high) = (here, here);
            for (v, full) in [(sideways[0], full_k), (sideways[1], full_k), (along[0], full_g), (along[1], full_g)] {
                let reached = if full { v } else { half(v) };
                low = low.min(reached);
                high = high.max(reached);
                wide_low = wide_low.min(v);
                wide_high = wide_high.max(v);
            }
            let ground_residue = value.saturating_sub(high).max(low.saturating_sub(value));
            let unexplained = value.saturating_sub(wide_high).max(wide_low.saturating_sub(value));
            let cell_column = c / cells.px;
            if cell_row < cells.high && cell_column < cells.wide {
                let cell = cell_row * cells.wide + cell_column;
                residue.cell_valid[cell] = residue.cell_valid[cell].saturating_add(1);
                if unexplained > threshold {
                    residue.cell_residue[cell] = residue.cell_residue[cell].saturating_add(1);
                    residue.row_residue[j] = residue.row_residue[j].saturating_add(1);
                }
                // The ground is the null hypothesis: it gets the half-pixel
                // tolerance, the heights must beat it outright.
                sums.pixels[0][cell_column] += 1;
                sums.sad[0][cell_column] += u16::from(ground_residue);
                for k in hypotheses.active() {
                    if let Some(sample) = hypothesis_rows[k][c] {
                        sums.tried = true;
                        sums.pixels[k][cell_column] += 1;
                        sums.sad[k][cell_column] += u16::from(value.abs_diff(sample));
                    }
                }
            }
            if in_aoi_row && c >= aoi.left && c < aoi.right {
                search.diff_hist.add_one(value.abs_diff(here));
                search.compared_pixels += 1;
                for dg in (0..=2 * s).filter(|_| self.search_shifts) {
                    for dk in 0..=2 * s {
                        let diff = u32::from(value.abs_diff(band[dg][centre + dk - s]));
                        if far_half {
                            search.sad_far[dg][dk] += diff;
                        } else {
                            search.sad_near[dg][dk] += diff;
                        }
                    }
                }
            }
        }
        self.close_cell_row(j);
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::super::{Gpa, GpaConfig};
    use crate::geometry::{Aoi, Intrinsics, Mount, Rig};
    use crate::grid::{GridConfig, KgGrid};
    use crate::limits::MAX_SEARCH_RADIUS;
    use crate::motion::{Motion, Pose};
    use crate::remap::RemapTable;
    use core::ops::Range;

    pub(in crate::gpa) fn rig() -> Rig {
        Rig::new_checked(
            Intrinsics { width: 256, height: 256, fx: 240.0, fy: 240.0, cx: 127.5, cy: 127.5, distortion: None, readout_ms: 0.0 },
            Mount::level(400.0, 32.0),
            Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 },
        )
        .unwrap()
    }

    /// Ground texture at world (x, z): smooth structure, edges and noise-like detail.
    pub(in crate::gpa) fn texture(x: f64, z: f64) -> u8 {
        let smooth = 90.0 * libm::sin(x * 0.031) * libm::cos(z * 0.027);
        let edges = if (libm::floor(x / 37.0) as i64 + libm::floor(z / 53.0) as i64) % 3 == 0 { 45.0 } else { 0.0 };
        let hash = ((libm::floor(x / 3.0) as i64).wrapping_mul(73_856_093) ^ (libm::floor(z / 3.0) as i64).wrapping_mul(19_349_663)) & 31;
        (120.0 + smooth + edges + hash as f64).clamp(0.0, 255.0) as u8
    }

    /// The KG image seen from `pose`, with a box-like patch that breaks the ground model.
    fn kg_image(grid: &KgGrid, table: &RemapTable, pose: &Pose, frame: u32) -> std::vec::Vec<u8> {
        let yaw = pose.yaw_deg.to_radians();
        let mut image = std::vec![0u8; grid.len()];
        for j in 0..grid.height() {
            for i in table.valid_columns(j) {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let (wx, wz) = (pose.x_mm + x * libm::cos(yaw) - z * libm::sin(yaw), pose.z_mm + x * libm::sin(yaw) + z * libm::cos(yaw));
                let mut value = texture(wx, wz);
                if (x - 40.0).abs() < 60.0 && (wz - 1700.0).abs() < 40.0 {
                    value = value.wrapping_add((frame as u8).wrapping_mul(37));
                }
                image[j * grid.width() + i] = value;
            }
        }
        image
    }

    /// Everything a row leaves behind; the band as its logical rows over
    /// `band_columns` (nothing reads the rest).
    fn state(gpa: &Gpa, band_columns: Range<usize>, fast_filled: Range<usize>) -> std::vec::Vec<u32> {
        let rows = gpa.workspace.rows_ref().expect("a compared frame leaves the row stages' sums");
        let mut v = std::vec::Vec::new();
        v.extend(rows.search.sad_near.iter().flatten());
        v.extend(rows.search.sad_far.iter().flatten());
        v.extend(rows.search.diff_hist.counts().iter());
        v.push(rows.search.compared_pixels);
        v.extend(rows.residue.cell_residue.iter().map(|&x| u32::from(x)));
        v.extend(rows.residue.cell_valid.iter().map(|&x| u32::from(x)));
        v.extend((0..crate::limits::MAX_CELLS).map(|cell| gpa.parallax.height.get(cell) as u32));
        v.extend(rows.residue.row_residue.iter().map(|&x| u32::from(x)));
        let s = gpa.config.search_radius;
        let span = band_columns.start + MAX_SEARCH_RADIUS..band_columns.end + MAX_SEARCH_RADIUS;
        // The rows the last row's stages read (the residue's outside the AOI).
        for row in rows.band.rows(s).iter().take(2 * s + 1).skip(fast_filled.start).take(fast_filled.len()) {
            v.extend(row[span.clone()].iter().map(|&x| u32::from(x)));
        }
        v
    }

    /// The fast row paths leave exactly the state of the per-pixel reference,
    /// on translation (integer and fractional), yaw, reverse, and keyframe swaps.
    #[test]
    fn fast_rows_equal_reference() {
        let rig = rig();
        for mm_per_px in [None, Some(5.0), Some(4.3)] {
            let grid = KgGrid::for_rig(&rig, &GridConfig { mm_per_px, ..GridConfig::default() }).unwrap();
            let table = RemapTable::new(&rig, &grid).unwrap();
            let (mut kf_fast, mut kf_ref) = (std::vec![0u8; Gpa::keyframe_bytes(&grid)], std::vec![0u8; Gpa::keyframe_bytes(&grid)]);
            let mut fast = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut kf_fast).unwrap();
            let mut reference = Gpa::new(&rig, &grid, &table, GpaConfig::default(), &mut kf_ref).unwrap();
            reference.reference = true;
            let steps = [(0.0, 100.0, 0.0), (0.0, 50.0, 0.0), (13.7, 61.3, 0.0), (-20.0, 40.0, 2.0), (5.0, 30.0, -1.5), (0.0, -35.0, 0.0), (30.0, 60.0, 0.0), (0.0, 45.5, 0.4)];
            let mut pose = Pose::default();
            let mut poses = std::vec![pose];
            for &(tx, tz, dyaw) in steps.iter().cycle().take(14) {
                let yaw = pose.yaw_deg.to_radians();
                pose = Pose {
                    x_mm: pose.x_mm + tx * libm::cos(yaw) - tz * libm::sin(yaw),
                    z_mm: pose.z_mm + tx * libm::sin(yaw) + tz * libm::cos(yaw),
                    yaw_deg: pose.yaw_deg + dyaw,
                };
                poses.push(pose);
            }
            let mut compared = 0;
            for (n, p) in poses.iter().enumerate() {
                let image = kg_image(&grid, &table, p, n as u32);
                let odometry = (n > 0).then(|| Motion::between(&poses[n - 1], p));
                for gpa in [&mut fast, &mut reference] {
                    gpa.begin_frame(n as u32, odometry, None);
                    for (j, row) in image.chunks_exact(grid.width()).enumerate() {
                        gpa.on_kg_row(j, row);
                    }
                }
                let (a, b) = (fast.end_frame(), reference.end_frame());
                assert_eq!(a, b, "frame {n}");
                let band = &fast.workspace.rows().band;
                let (band_columns, filled) = (band.columns(), band.filled());
                assert!(state(&fast, band_columns.clone(), filled.clone()) == state(&reference, band_columns, filled), "frame {n}: state differs");
                compared += usize::from(a.is_some());
            }
            assert!(compared >= 10 && fast.workspace.rows().search.compared_pixels > 1000, "too little compared: {compared}");
        }
    }
}

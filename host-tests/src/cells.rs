//! `flatland detect --cells`: what a compared frame measured in each cell,
//! for an engineer asking why a frame is wrong. A row per cell with any
//! evidence (a parallax height, weak or not, a lag, residue), where the
//! cell is seen on the ground and where a cell with a height stands (as
//! the detector reads it: seen at p with height h, it stands on p (H-h)/H),
//! and the frame's resolution: the least height and the shallowest drop
//! its baseline tells from the ground (below them a height is not known).

use flatland_core::gpa::{CellEvidence, Gpa};
use flatland_core::grid::KgGrid;
use std::fmt::Write;

pub const CELLS_HEADER: &str = "frame,row,column,x_mm,z_mm,height_mm,weak,moving,residue_percent,stands_at_mm,least_height_mm,shallowest_drop_mm";

/// One cell's row of the table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellRow {
    pub row: usize,
    pub column: usize,
    /// The cell's centre on the ground (mm across, mm ahead).
    pub x_mm: f64,
    pub z_mm: f64,
    pub evidence: CellEvidence,
    /// Where a cell with a measured height above the ground stands on the
    /// ground (mm across, mm ahead): seen at p with height h, on p (H-h)/H.
    pub stands_at: Option<(f64, f64)>,
}

/// The cells of the last frame `gpa` compared that hold any evidence, far
/// rows first.
pub fn cells_with_evidence(gpa: &Gpa, grid: &KgGrid, camera_height_mm: f64) -> Vec<CellRow> {
    let (rows, columns) = gpa.cells();
    let px = gpa.cell_px() as f64;
    let mut found = Vec::new();
    for row in 0..rows {
        for column in 0..columns {
            let evidence = gpa.cell_evidence(row, column);
            if evidence == CellEvidence::default() {
                continue;
            }
            let (x_mm, z_mm) = grid.pixel_to_ground((column as f64 + 0.5) * px - 0.5, (row as f64 + 0.5) * px - 0.5);
            let h = f64::from(evidence.measured_height_mm());
            let k = (camera_height_mm - h) / camera_height_mm;
            let stands_at = (h > 0.0).then_some((x_mm * k, z_mm * k));
            found.push(CellRow { row, column, x_mm, z_mm, evidence, stands_at });
        }
    }
    found
}

/// The table's rows for frame `frame` (no header), one line each.
pub fn cells_csv(frame: u32, gpa: &Gpa, grid: &KgGrid, camera_height_mm: f64) -> String {
    let resolution = gpa.resolution();
    let finite = |v: f64| if v.is_finite() { format!("{v:.1}") } else { "inf".to_string() };
    let (least, shallowest) = (finite(resolution.least_height_mm), finite(resolution.shallowest_drop_mm));
    let mut out = String::new();
    for cell in cells_with_evidence(gpa, grid, camera_height_mm) {
        let e = cell.evidence;
        let stands = cell.stands_at.map_or(String::new(), |(_, z)| format!("{z:.0}"));
        let _ = writeln!(
            out,
            "{frame},{},{},{:.0},{:.0},{},{},{},{},{stands},{least},{shallowest}",
            cell.row,
            cell.column,
            cell.x_mm,
            cell.z_mm,
            e.height_mm,
            u8::from(e.weak),
            u8::from(e.moving),
            e.residue_percent
        );
    }
    out
}

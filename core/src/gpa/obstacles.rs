//! Obstacles from a frame's evidence: connected groups of coherence cells
//! and where they stand. Parallax cells give heights and true footprints
//! (above the ground an obstacle, below it a drop: a ledge, stairs down, a pit);
//! residue blobs catch what has no consistent parallax. The whole grid
//! ahead of the AOI is analysed, and a blob counts when its base (nearest
//! point) lies in the AOI; blobs are measured in mm² of ground, so
//! thresholds carry across cameras.

use super::config::GpaConfig;
use super::hazard_mask::MovedMask;
use super::parallax::CellHeights;
use super::layout::{AoiMm, CellSet, Layout};
use super::residue::Residue;
use crate::limits::{MAX_BLOBS, MAX_BLOB_CELLS, MAX_CELLS_SIDE, MAX_FLOOD_CELLS};
use crate::motion::Motion;
use crate::scan::Scan;

/// A connected group of hot cells.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Blob {
    /// Cell bounds (inclusive).
    pub cell_left: u8,
    pub cell_right: u8,
    pub cell_top: u8,
    pub cell_bottom: u8,
    pub cells: u16,
    /// Residue pixels in the blob.
    pub pixels: u32,
    /// Highest residue percentage of any of its cells.
    pub peak_percent: u8,
}

/// Where an obstacle stands, robot frame mm: its nearest point ahead and
/// its lateral extent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Footprint {
    pub(super) near_mm: i32,
    pub(super) left_mm: i32,
    pub(super) right_mm: i32,
}

impl Footprint {
    /// Whether the two share some of their lateral extent.
    pub(super) fn overlaps_sideways(&self, other: &Footprint) -> bool {
        self.left_mm <= other.right_mm && self.right_mm >= other.left_mm
    }

    /// Where it stands after the robot moved by `step`, turn included: its
    /// near edge's two ends in the later frame, and the span between them
    /// (a robot turning in place sweeps what it found out of its AOI).
    pub(super) fn moved(&self, step: &Motion) -> Footprint {
        let (near, left, right) = (f64::from(self.near_mm), f64::from(self.left_mm), f64::from(self.right_mm));
        let (left_x, left_z) = step.to_later_frame(left, near);
        let (right_x, right_z) = step.to_later_frame(right, near);
        let mm = |v: f64| libm::round(v) as i32;
        Footprint { near_mm: mm(left_z.min(right_z)), left_mm: mm(left_x.min(right_x)), right_mm: mm(left_x.max(right_x)) }
    }

    /// Whether any of it lies in `aoi` (its near edge within the far edge,
    /// its span across the AOI's).
    pub(super) fn in_aoi(&self, aoi: &AoiMm) -> bool {
        f64::from(self.near_mm) <= aoi.far && f64::from(self.right_mm) >= -aoi.half_width && f64::from(self.left_mm) <= aoi.half_width
    }
}

/// Visits the cells connected to `start` (neighbours within `radius` cells,
/// in a grid of `size` = (columns, rows) cells stored row by row)
/// for which `member` holds, marking them in `seen`; `visit` gets (cell,
/// row, column). With `linked`, a member cell further along its columns
/// (any row, columns within `radius`) also joins when `linked(cell, it)`.
/// The work stack is bounded: a full one truncates the growth.
/// `linked` comes with [`member_rows`] of `member` less the cells already
/// in `seen`: the rows it looks along, which the flood keeps up to date
/// (a row whose members are all seen is not looked at again: a large
/// face would otherwise look along every row of its columns per cell).
fn flood_cells(
    size: (usize, usize),
    radius: i32,
    start: usize,
    seen: &mut CellSet,
    member: impl Fn(usize) -> bool,
    mut linked: Option<Linked>,
    mut visit: impl FnMut(usize, usize, usize),
) {
    let (w, h) = size;
    let mut stack: heapless::Vec<u16, MAX_FLOOD_CELLS> = heapless::Vec::new();
    let mark_seen = |seen: &mut CellSet, linked: &mut Option<Linked>, cell: usize| {
        seen.insert(cell);
        if let Some((_, unseen_rows)) = linked {
            unseen_rows[cell % w] &= !(1u64 << (cell / w));
        }
    };
    mark_seen(seen, &mut linked, start);
    let _ = stack.push(start as u16);
    while let Some(cell) = stack.pop() {
        let cell = usize::from(cell);
        let (r, c) = (cell / w, cell % w);
        visit(cell, r, c);
        // Linked: every row that has an unseen member within the columns,
        // in order (the others have none to add); else the rows within the radius.
        let mut rows = match &linked {
            Some((_, unseen_rows)) => {
                let columns = c.saturating_sub(radius as usize)..=(c + radius as usize).min(w - 1);
                unseen_rows[columns].iter().fold(0u64, |rows, &column| rows | column)
            }
            None => {
                let (first, last) = (r.saturating_sub(radius as usize), (r + radius as usize).min(h - 1));
                (u64::MAX >> (63 - last)) & (u64::MAX << first)
            }
        };
        while rows != 0 {
            let dr = rows.trailing_zeros() as i32 - r as i32;
            rows &= rows - 1;
            for dc in -radius..=radius {
                let (nr, nc) = (r as i32 + dr, c as i32 + dc);
                if nr < 0 || nc < 0 || nr as usize >= h || nc as usize >= w {
                    continue;
                }
                let neighbour = nr as usize * w + nc as usize;
                if seen.contains(neighbour) || !member(neighbour) {
                    continue;
                }
                if dr.abs() <= radius || linked.as_ref().is_some_and(|(linked, _)| linked(cell, neighbour)) {
                    mark_seen(seen, &mut linked, neighbour);
                    let _ = stack.push(neighbour as u16);
                }
            }
        }
    }
}

/// Per cell column, the cell rows (bit r) where a predicate holds.
type MemberRows = [u64; MAX_CELLS_SIDE];

/// A flood's link along the columns, and the rows of its members not yet seen.
type Linked<'a> = (&'a dyn Fn(usize, usize) -> bool, &'a mut MemberRows);
const _: () = assert!(MAX_CELLS_SIDE <= 64, "a cell column's rows fit a u64");

/// [`MemberRows`] of `member` over a grid of `size` = (columns, rows) cells.
fn member_rows((w, h): (usize, usize), member: impl Fn(usize) -> bool) -> MemberRows {
    let mut rows = [0u64; MAX_CELLS_SIDE];
    for r in 0..h {
        for (c, column) in rows.iter_mut().enumerate().take(w) {
            if member(r * w + c) {
                *column |= 1 << r;
            }
        }
    }
    rows
}

/// One hazard cell's footprint: a segment at `z` ahead from `left` to
/// `right` (mm, robot frame), what the scan takes.
#[derive(Clone, Copy)]
struct CellSpan {
    z: i16,
    left: i16,
    right: i16,
}

impl CellSpan {
    fn new(z: f32, left: f32, right: f32) -> CellSpan {
        let mm = |v: f32| libm::roundf(v).clamp(f32::from(i16::MIN), f32::from(i16::MAX)) as i16;
        CellSpan { z: mm(z), left: mm(left), right: mm(right) }
    }
}

/// Cells a group needs where heights are coarse (short baselines, drops).
const LARGE_GROUP_CELLS: usize = 8;
/// Cells a group of weak heights alone needs, at least half of them where
/// the last frame saw heights stand up, to count as measured.
const WEAK_GROUP_CELLS: usize = 5;
/// Cells a group of measured heights with residue needs, on a full
/// baseline, when every one of them stood up on the last frame too: a
/// fluke of texture does not recur at one place on the ground, a small
/// obstacle (a ball a cell or two across) does. Without residue a small
/// patch is the blur of a sharp ground edge, which recurs as well.
const SEEN_AGAIN_GROUP_CELLS: usize = 2;

/// Which side of the ground a group of parallax cells lies on.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Side {
    /// Standing up: an obstacle.
    Above,
    /// Below the floor: the lower level past a drop's edge.
    Below,
}

impl Side {
    /// How far apart (cells) two cells of one group may lie. Parallax is
    /// measured only where there is texture, so a face can leave a cell out
    /// here and there: one-cell gaps are bridged. Past a drop's edge every
    /// cell sees one lower level, which shows its depth only on rows where
    /// its texture changes along the drive; two rows without such texture
    /// must not cut the cells at the edge off from the hole behind them
    /// (too few alone to count, so the edge came out a texture period late).
    fn bridge(self) -> i32 {
        match self {
            Side::Above => 2,
            Side::Below => 3,
        }
    }
}

/// The groups [`parallax_group`] looks for.
#[derive(Clone, Copy)]
struct Wanted<'a> {
    side: Side,
    /// Cell rows above it are left out.
    first_row: usize,
    /// Heights are coarse: only a large group counts.
    short_baseline: bool,
    /// The last frame's cells that stood up, moved to this one (None: not
    /// the frame before, or below the ground): where weak heights seen
    /// again count.
    last_frame: Option<MovedMask<'a>>,
}

/// What the parallax cells show: the nearest hazard inside the AOI,
/// obstacle or drop, and its signed height (mm; a drop's is minus its
/// depth); and the nearest obstacle that stands just beyond the AOI's far
/// edge by its footprint (which the heights place to a cell or so: it may
/// be one seen inside before).
pub(super) struct ParallaxEvidence {
    pub(super) hazard: Option<(Footprint, i32)>,
    pub(super) beyond: Option<Footprint>,
    /// The hazard is an obstacle placed by its own lower part, which lags
    /// the ground ([`lower_part`]): a thing moving along with the robot.
    pub(super) moves_along: bool,
}

/// The frame's [`ParallaxEvidence`]; drops only when `drops`. See
/// [`parallax_group`], which also fills `scan`.
pub(super) fn parallax_obstacle(
    layout: &Layout,
    heights: &CellHeights,
    residue: &Residue,
    config: &GpaConfig,
    short_baseline: bool,
    drops: bool,
    last_frame: Option<MovedMask<'_>>,
    scan: &mut Scan,
) -> ParallaxEvidence {
    let drop = if drops { parallax_group(layout, (heights, residue), config, Wanted { side: Side::Below, first_row: 0, short_baseline, last_frame: None }, scan).0 } else { None };
    // Past a drop's edge the floor is gone: what stands there is reached
    // only after the drop, and cells that seem to stand up there are the
    // lower level's blur, which can fake an obstacle nearer than the edge.
    let cells = &layout.cells;
    let first_before_edge = drop.map_or(0, |(edge, _)| {
        (0..cells.high).find(|&r| layout.centre_mm(r) < f64::from(edge.near_mm)).unwrap_or(cells.high)
    });
    let (obstacle, beyond) = parallax_group(layout, (heights, residue), config, Wanted { side: Side::Above, first_row: first_before_edge, short_baseline, last_frame }, scan);
    let lowered = obstacle.and_then(|(face, height)| lower_part(layout, heights, &face, config.max_drop_mm).map(|nearer| (nearer, height)));
    let obstacle = lowered.or(obstacle);
    let (hazard, moves_along) = match (obstacle, drop) {
        (Some(o), Some(d)) if d.0.near_mm < o.0.near_mm => (Some(d), false),
        (o, d) => (o.or(d), lowered.is_some()),
    };
    ParallaxEvidence { hazard, beyond, moves_along }
}

/// Least cells of a face's [`lower_part`]: one alone is too easily a
/// fluke of texture.
const LOWER_PART_CELLS: usize = 2;

/// Where an obstacle placed at `face` reaches nearer, by its own part
/// below the ground's level; None when nothing shows one.
///
/// A face standing still at its footprint F has ground in front of it. A
/// face that moves along with the robot (a car ahead, braking) has no
/// footprint of its own in the heights: static parallax reads every cell
/// of it as standing on one F = z T / V (z its true distance, T the
/// robot's travel, V the face's approach), beyond the true one when it
/// approaches slower than the ground. Its cells above F's ground line
/// measure heights (the trunk), those below it depths or lags past the
/// deepest drop (the bumper): cells nearer than F whose depth points at F
/// (within a cell, as [`parallax_group`]'s faces agree), or that lag too
/// much to point nearer, in the face's columns (within a cell), are its
/// lower part; weak ones too (a bumper in shade), since they only move an
/// obstacle already found. From the nearest of them on is the thing, or a hole in
/// front of a face: a hazard either way. At least
/// [`LOWER_PART_CELLS`] must show it; the AOI's near edge is the nearest
/// it is placed.
// Not inlined: its locals stay out of `parallax_obstacle`'s frame, which
// the parallax groups' floods stand on.
#[inline(never)]
fn lower_part(layout: &Layout, heights: &CellHeights, face: &Footprint, deepest_drop_mm: f64) -> Option<Footprint> {
    let (grid, cells) = (&layout.grid, &layout.cells);
    let camera_height = layout.camera_height_mm;
    let cell_mm = layout.cell_mm();
    let (face_z, left, right) = (f64::from(face.near_mm), f64::from(face.left_mm) - cell_mm, f64::from(face.right_mm) + cell_mm);
    let (first_left, _) = grid.pixel_to_ground(0.0, 0.0);
    let mut columns = (0..cells.wide).filter(|&c| {
        let cell_left = first_left + c as f64 * cell_mm;
        cell_left + cell_mm > left && cell_left < right
    });
    let first_column = columns.next()?;
    let last_column = columns.next_back().unwrap_or(first_column);
    // Per cell in f32 (the M4's FPU), as `parallax_group`'s footprints.
    let (camera_f32, face_f32, cell_f32) = (camera_height as f32, face_z as f32, cell_mm as f32);
    let deepest_reach = (camera_height + deepest_drop_mm) as f32 / camera_f32;
    let (mut count, mut nearest_row) = (0usize, None);
    for r in 0..cells.high {
        if layout.near_side_mm(r) >= face_z {
            continue;
        }
        let z_centre = layout.centre_mm(r) as f32;
        let points_at_face = |cell: usize| {
            let depth = heights.any(cell);
            if heights.moving(cell) {
                z_centre * deepest_reach <= face_f32 + cell_f32
            } else {
                depth < 0 && libm::fabsf(z_centre * (camera_f32 - f32::from(depth)) / camera_f32 - face_f32) <= cell_f32
            }
        };
        let found = (first_column..=last_column).filter(|&c| points_at_face(r * cells.wide + c)).count();
        count += found;
        if found > 0 {
            nearest_row = Some(r);
        }
    }
    let near = layout.near_side_mm(nearest_row.filter(|_| count >= LOWER_PART_CELLS)?).max(layout.aoi_mm().near);
    Some(Footprint { near_mm: libm::round(near) as i32, ..*face }).filter(|nearer| nearer.near_mm < face.near_mm)
}

/// Groups cells whose parallax height (`heights`, mm) reaches the obstacle
/// height on `side` of the ground; returns the nearest footprint inside
/// the AOI and its height (mm), and the nearest beyond its far edge. A `short_baseline` measures heights
/// coarsely: only a large group counts. Cell rows above `first_row` are
/// left out. Every cell of a group that counts goes to `scan` at its
/// footprint, none nearer than the group's `nearest` (the odd cell whose
/// height is off would place it there).
///
/// Above: a cell at apparent ground position p with height h stands on
/// p*(H-h)/H, so every cell of a vertical face points at the face's own
/// footprint. Below: the nearest visible point of the lower level is seen
/// past the floor's edge, so its apparent position is the edge itself:
/// the hole starts at the nearest cells' near side.
fn parallax_group(
    layout: &Layout,
    (heights, residue): (&CellHeights, &Residue),
    config: &GpaConfig,
    wanted: Wanted,
    scan: &mut Scan,
) -> (Option<(Footprint, i32)>, Option<Footprint>) {
    let Wanted { side, first_row, short_baseline, last_frame } = wanted;
    let (grid, cells, camera_height_mm) = (&layout.grid, &layout.cells, layout.camera_height_mm);
    let (w, h) = (cells.wide, cells.high);
    // Heights are whole mm, so |h| >= min_height exactly when |h| >= ceil(min_height):
    // an integer compare per cell instead of a soft-float one on the M4.
    let min_height = libm::ceil(config.min_obstacle_height_mm) as i32;
    let on_side = |height: i16| match side {
        Side::Above => i32::from(height) >= min_height,
        Side::Below => i32::from(height) <= -min_height,
    };
    // Below, a cell that lags past the deepest drop looked for may be the
    // lower level of a deeper one: it counts, at that depth, in a group
    // where some cell measured a depth.
    let deeper = |cell: usize| side == Side::Below && heights.is_moving(cell);
    let member = |cell: usize| cell >= first_row * w && (on_side(heights.get(cell)) || deeper(cell));
    // Hysteresis, as for edges: a weak height does not count, but it joins
    // measured cells across it, a surface whose contrast is low in places.
    let reaches = |cell: usize| cell >= first_row * w && (on_side(heights.any(cell)) || deeper(cell));
    // A drop must show over an area: its parallax is at most T*d/(H+d),
    // so an odometry or heading error fakes a small shallow patch more
    // easily, and a hole a wheel can fall into shows its lower level over
    // many cells (though, far and seen at a grazing angle, in scattered
    // ones; the groups in front mark its edge). That lower level is
    // often of low contrast (farther, in the floor's shadow): its weak
    // depths count toward the area too, though they found no group.
    if side == Side::Below && (0..h * w).filter(|&cell| reaches(cell)).count() < LARGE_GROUP_CELLS {
        return (None, None);
    }
    // A cell's geometry is worked out per cell, so in f32 (the M4's FPU;
    // f64 is software there) from each cell row's centre (mm ahead) and
    // each cell column's sides (mm across) at the ground, once a call:
    // millimetres to well under a millimetre, what the report rounds to.
    let mut row_centre_z = [0.0f32; MAX_CELLS_SIDE];
    for (r, z) in row_centre_z.iter_mut().enumerate().take(h) {
        *z = layout.centre_mm(r) as f32;
    }
    // The columns' sides step by a cell from the first's (pixel_to_ground
    // is affine along a row): two software f64 calls, not two a column.
    let (first_left, _) = grid.pixel_to_ground(0.0, 0.0);
    let (first_right, _) = grid.pixel_to_ground(cells.px as f64 - 1.0, 0.0);
    let cell_mm = layout.cell_mm();
    let cell_mm_f32 = cell_mm as f32;
    let mut column_sides = [[0.0f32; 2]; MAX_CELLS_SIDE];
    for (c, sides) in column_sides.iter_mut().enumerate().take(w) {
        let offset = c as f32 * cell_mm_f32;
        *sides = [first_left as f32 + offset, first_right as f32 + offset];
    }
    let camera_height = camera_height_mm as f32;
    // Above: where a cell stands (mm ahead), from its height at its centre.
    let footprint = |cell: usize| row_centre_z[cell / w] * (camera_height - f32::from(heights.get(cell))) / camera_height;
    // Every cell of a vertical face points at the face's footprint, but a
    // plain face shows parallax only where it has texture (its top edge, a
    // feature or two), possibly many rows apart: above the ground, cells in
    // neighbouring columns whose footprints agree to a cell are one face.
    let measured = |cell: usize| !heights.is_weak(cell);
    // The flood asks of one cell's neighbours in turn: its footprint is kept.
    let last = core::cell::Cell::new((usize::MAX, 0.0));
    let footprint_of_a = |a: usize| {
        if last.get().0 != a {
            last.set((a, footprint(a)));
        }
        last.get().1
    };
    let same_face = |a: usize, b: usize| measured(a) && measured(b) && libm::fabsf(footprint_of_a(a) - footprint(b)) <= cell_mm_f32;
    // The reaching cells not yet in a group, by column.
    let mut unseen_rows = member_rows((w, h), reaches);
    let aoi = layout.aoi_mm();
    let mut seen = CellSet::EMPTY;
    let mut best: Option<(f64, f64, f64, f64)> = None;
    let mut beyond: Option<(f64, f64, f64)> = None;
    // Then, above the ground, groups of weak heights alone (each beat the
    // ground by less than the absolute gain: low contrast, or shading
    // that differs between the views). One frame's such group is too
    // easily shading; seen again where the last frame saw heights stand
    // up, it is a surface of low contrast (a printed box on a wooden
    // floor), measured over two frames. Every measured cell, and every
    // weak one joined to it, is seen by the first sweep.
    let weak_member = |cell: usize| cell >= first_row * w && heights.is_weak(cell) && on_side(heights.any(cell));
    let weak_sweep = if side == Side::Above && last_frame.is_some() { 0..h * w } else { 0..0 };
    for (weak_only, start) in (0..h * w).map(|cell| (false, cell)).chain(weak_sweep.map(|cell| (true, cell))) {
        if seen.contains(start) || !(if weak_only { weak_member(start) } else { member(start) }) {
            continue;
        }
        let mut with_residue = false;
        let mut stood_up_before = 0usize;
        let mut measured_depth = false;
        let mut footprints: heapless::Vec<f32, MAX_BLOB_CELLS> = heapless::Vec::new();
        // Below: per cell column, 1 + the nearest cell row (0: none).
        let mut nearest_rows = [0u8; MAX_CELLS_SIDE];
        // Above: the tallest cell; below: the cells' depths, for their median
        // (past an edge every cell sees the same lower level).
        let mut depths: heapless::Vec<i16, MAX_BLOB_CELLS> = heapless::Vec::new();
        let mut spans: heapless::Vec<CellSpan, MAX_BLOB_CELLS> = heapless::Vec::new();
        let (mut left, mut right, mut tallest) = (f32::MAX, f32::MIN, 0.0f32);
        let (mut group, mut nearest_row) = (0usize, 0usize);
        let linked: Option<Linked> = match side {
            Side::Above if !weak_only => Some((&same_face, &mut unseen_rows)),
            _ => None,
        };
        flood_cells((w, h), side.bridge(), start, &mut seen, reaches, linked, |cell, r, c| {
            if heights.is_weak(cell) && !weak_only {
                return;
            }
            stood_up_before += usize::from(last_frame.is_some_and(|last| last.stood_up(r, c)));
            group += 1;
            nearest_row = nearest_row.max(r);
            with_residue |= residue.percent(cell, cells.px) >= config.active_cell_percent;
            // (A weak cell reaches here only in the weak sweep.)
            let height = f32::from(heights.any(cell));
            // The cell's measured height belongs to its centre.
            let z_centre = row_centre_z[r];
            let scale = match side {
                Side::Above => {
                    let scale = (camera_height - height) / camera_height;
                    // At the top hypothesis the cell may stand taller, so
                    // nearer: its footprint is a bound, kept negative.
                    let z = z_centre * scale;
                    let _ = footprints.push(if heights.is_at_top(cell) { -z } else { z });
                    scale
                }
                Side::Below => {
                    nearest_rows[c] = nearest_rows[c].max(r as u8 + 1);
                    1.0
                }
            };
            let [x_left, x_right] = column_sides[c];
            let _ = spans.push(CellSpan::new(z_centre * scale, x_left * scale, x_right * scale));
            left = left.min(x_left * scale);
            right = right.max(x_right * scale);
            match side {
                Side::Above => tallest = tallest.max(height),
                Side::Below => {
                    measured_depth |= !deeper(cell);
                    let depth = if deeper(cell) { -(libm::round(config.max_drop_mm) as i16) } else { heights.get(cell) };
                    let _ = depths.push(depth);
                }
            }
        });
        // One cell alone is too easily a fluke of texture, and a small
        // patch of parallax without any residue is a blur difference on a
        // sharp ground edge (the camera resolves it differently from
        // another distance). Smooth obstacles leave little residue but
        // parallax over a wider patch. A small one with residue shows on
        // every frame at the same place, which a fluke does not.
        // A short baseline measures heights coarsely, so its footprints
        // wander: there a blob must be large to raise an alarm by itself.
        let large = group >= LARGE_GROUP_CELLS;
        let wide_enough = group >= 3 && (with_residue || group >= 4);
        let seen_again = side == Side::Above && !weak_only && with_residue && group >= SEEN_AGAIN_GROUP_CELLS && stood_up_before == group;
        // Where the group is seen to start on the ground.
        let nearest_seen = layout.near_side_mm(nearest_row);
        if !(wide_enough || seen_again) || (short_baseline && !large) {
            continue;
        }
        if weak_only && (group < WEAK_GROUP_CELLS || 2 * stood_up_before < group) {
            continue;
        }
        // A drop shows its depth somewhere: a group that only lags the
        // ground is a thing moving along with the robot (a car ahead, its
        // shadow), which `moving_obstacle` places, not a hole.
        if side == Side::Below && !measured_depth {
            continue;
        }

        let height = match side {
            Side::Above => f64::from(tallest),
            Side::Below => {
                let edges = nearest_rows.iter().filter(|&&rows| rows > 0).map(|&rows| layout.near_side_mm(usize::from(rows) - 1) as f32);
                footprints.extend(edges);
                let middle = depths.len() / 2;
                f64::from(*depths.select_nth_unstable(middle).1)
            }
        };
        // Above, every cell of a vertical face points at the same footprint:
        // the lower quartile is robust to the odd cell whose height is off,
        // and so that it is in the small groups too (3 and 4 cells, where
        // the quartile is the nearest cell), never the nearest one alone.
        // Below, a cell straddling the edge mostly sees the floor, so every
        // column's nearest drop cell starts up to a cell past the edge: the
        // nearest column is the edge.
        // Selected, not sorted: the same value, without a sort's recursion
        // on the deepest stack of the frame.
        // (Footprints at the top hypothesis are kept negative: bounds.)
        let quartile = |footprints: &mut [f32]| {
            let rank = match side {
                Side::Above => ((footprints.len() - 1) / 4).max(1).min(footprints.len() - 1),
                Side::Below => 0,
            };
            libm::fabsf(*footprints.select_nth_unstable_by(rank, |a, b| libm::fabsf(*a).total_cmp(&libm::fabsf(*b))).1)
        };
        // A face taller than the top hypothesis (a car from its own camera)
        // stands nearer than its cells there place it: its lower part, when
        // enough of it is measured, places it.
        let mut nearest = quartile(&mut footprints);
        if footprints.iter().any(|z| *z < 0.0) {
            footprints.retain(|z| *z >= 0.0);
            if footprints.len() >= 3 {
                nearest = nearest.min(quartile(&mut footprints));
            }
        }
        let nearest = f64::from(nearest);
        let (left, right) = (f64::from(left), f64::from(right));
        // Nor beyond where the group is seen to start: a thing standing on
        // the ground is seen from its footprint on (its base), so a group
        // whose heights place it farther (a car ahead moving away from the
        // camera's parallax, which the static heights misread) starts there.
        let nearest = match side {
            Side::Above => nearest.min(nearest_seen),
            Side::Below => nearest,
        };
        for span in &spans {
            scan.add_span(f64::from(span.z).max(nearest), f64::from(span.left), f64::from(span.right));
        }
        // A footprint is good to a fraction of a cell (the heights are):
        // one measured a little beyond the far edge may stand on it. A hole
        // reaches on from its edge, so it is in the AOI while the edge is
        // not beyond it.
        let near_enough = side == Side::Below || nearest >= aoi.near - cell_mm;
        let across = right >= -aoi.half_width && left <= aoi.half_width;
        let inside = nearest <= aoi.far + 0.5 * cell_mm && near_enough && across;
        if inside && best.is_none_or(|b| nearest < b.0) {
            best = Some((nearest, left.max(-aoi.half_width), right.min(aoi.half_width), height));
        } else if side == Side::Above && across && nearest > aoi.far && beyond.is_none_or(|b| nearest < b.0) {
            beyond = Some((nearest, left.max(-aoi.half_width), right.min(aoi.half_width)));
        }
    }
    let mm = |v: f64| libm::round(v) as i32;
    let hazard = best.map(|(z, left, right, height)| {
        let z = z.clamp(aoi.near, aoi.far);
        (Footprint { near_mm: mm(z), left_mm: mm(left), right_mm: mm(right) }, mm(height))
    });
    (hazard, beyond.map(|(z, left, right)| Footprint { near_mm: mm(z), left_mm: mm(left), right_mm: mm(right) }))
}

/// The nearest group of cells that move with the robot
/// ([`CellHeights::is_moving`]): at least three cells, neighbours within
/// three cells, as a drop's lower level (a thing moving along lags only
/// where it has texture, rows apart). Such a thing shows no height, so it
/// is placed where its nearest cell's near side is seen on the ground: its
/// own footprint where it meets the ground (a car's bumper and the shadow
/// under it), never nearer than it is; at the AOI's near edge when it
/// covers it.
// Not inlined: its flood's work stack stays out of `decide`'s frame, which
// the parallax groups' floods stand on.
#[inline(never)]
pub(super) fn moving_obstacle(layout: &Layout, heights: &CellHeights) -> Option<Footprint> {
    let (grid, cells) = (&layout.grid, &layout.cells);
    let (w, h) = (cells.wide, cells.high);
    let moving = |cell: usize| heights.is_moving(cell);
    let aoi = layout.aoi_mm();
    let mut seen = CellSet::EMPTY;
    let mut best: Option<Footprint> = None;
    for start in 0..h * w {
        if seen.contains(start) || !moving(start) {
            continue;
        }
        let (mut group, mut nearest_row, mut left_column, mut right_column) = (0usize, 0usize, usize::MAX, 0usize);
        flood_cells((w, h), Side::Below.bridge(), start, &mut seen, moving, None, |_, r, c| {
            group += 1;
            nearest_row = nearest_row.max(r);
            left_column = left_column.min(c);
            right_column = right_column.max(c);
        });
        if group < 3 {
            continue;
        }
        let near = layout.near_side_mm(nearest_row);
        let (left, _) = grid.pixel_to_ground((left_column * cells.px) as f64, 0.0);
        let (right, _) = grid.pixel_to_ground(((right_column + 1) * cells.px) as f64 - 1.0, 0.0);
        let mm = |v: f64| libm::round(v) as i32;
        let found = Footprint { near_mm: mm(near.max(aoi.near)), left_mm: mm(left.max(-aoi.half_width)), right_mm: mm(right.min(aoi.half_width)) };
        if found.in_aoi(&aoi) && best.is_none_or(|b| found.near_mm < b.near_mm) {
            best = Some(found);
        }
    }
    best
}

/// The frame's evidence once what moves with the robot (`moving`, from
/// [`moving_obstacle`]) is weighed: (parallax, residue, whether a thing
/// moving along placed the hazard). Such a thing shows no height of its
/// own: where it is nearer than what parallax placed, it is that thing's
/// footprint (a car ahead: its roof measured, its bumper lagging the
/// ground). A drop's lower level lags the floor too, but only past its
/// edge: a drop keeps its edge unless the moving thing starts more than a
/// cell (`cell_mm`) nearer, which no lower level of it can (a car's
/// shadow lagging ahead of a "drop" that is the car's body). Residue
/// nearer than a moving thing places the hazard itself.
pub(super) fn weigh_moving(
    parallax: Option<(Footprint, i32)>,
    residue: Option<Footprint>,
    moving: Option<Footprint>,
    moves_along: bool,
    cell_mm: f64,
) -> (Option<(Footprint, i32)>, Option<Footprint>, bool) {
    match (parallax, moving) {
        (Some((placed, height)), Some(moving)) if height > 0 && moving.near_mm < placed.near_mm => (Some((moving, height)), residue, true),
        (Some((edge, depth)), Some(moving)) if depth < 0 && f64::from(moving.near_mm) < f64::from(edge.near_mm) - cell_mm => moving_alone(residue, moving),
        (None, Some(moving)) => moving_alone(residue, moving),
        (parallax, _) => (parallax, residue, moves_along),
    }
}

/// A moving thing with no parallax hazard before it: it places the hazard
/// unless residue lies nearer.
fn moving_alone(residue: Option<Footprint>, moving: Footprint) -> (Option<(Footprint, i32)>, Option<Footprint>, bool) {
    match residue.filter(|r| r.near_mm < moving.near_mm) {
        Some(nearer) => (None, Some(nearer), false),
        None => (None, Some(moving), true),
    }
}

/// Labels the cells active with residue into blobs (at most [`MAX_BLOBS`]).
pub(super) fn residue_blobs(layout: &Layout, residue: &Residue, config: &GpaConfig) -> heapless::Vec<Blob, MAX_BLOBS> {
    let mut blobs: heapless::Vec<Blob, MAX_BLOBS> = heapless::Vec::new();
    let cells = &layout.cells;
    let (w, h) = (cells.wide, cells.high);
    let mut label = CellSet::EMPTY;
    let percent = |cell: usize| residue.percent(cell, cells.px);
    let active = |cell: usize| percent(cell) >= config.active_cell_percent;
    for start in 0..h * w {
        if label.contains(start) || !active(start) {
            continue;
        }
        let (sr, sc) = ((start / w) as u8, (start % w) as u8);
        let mut blob = Blob { cell_left: sc, cell_right: sc, cell_top: sr, cell_bottom: sr, cells: 0, pixels: 0, peak_percent: 0 };
        flood_cells((w, h), 1, start, &mut label, active, None, |cell, r, c| {
            blob.cells += 1;
            blob.pixels += u32::from(residue.cell_residue[cell]);
            blob.peak_percent = blob.peak_percent.max(percent(cell).min(100) as u8);
            blob.cell_left = blob.cell_left.min(c as u8);
            blob.cell_right = blob.cell_right.max(c as u8);
            blob.cell_top = blob.cell_top.min(r as u8);
            blob.cell_bottom = blob.cell_bottom.max(r as u8);
        });
        if blobs.push(blob).is_err() {
            break;
        }
    }
    blobs
}

/// The nearest of `blobs` that is an obstacle (peak and area) and whose
/// base lies in the AOI, located.
pub(super) fn nearest_residue_obstacle(blobs: &[Blob], layout: &Layout, residue: &Residue, config: &GpaConfig) -> Option<Footprint> {
    let (grid, aoi, cell_px) = (&layout.grid, &layout.aoi, layout.cells.px);
    let pixel_mm2 = grid.mm_per_px * grid.mm_per_px;
    let mut best: Option<Blob> = None;
    for blob in blobs {
        let obstacle = u32::from(blob.peak_percent) >= config.peak_cell_percent
            && f64::from(blob.pixels) * pixel_mm2 >= config.min_residue_mm2;
        if !obstacle {
            continue;
        }
        let left_px = usize::from(blob.cell_left) * cell_px;
        let right_px = (usize::from(blob.cell_right) + 1) * cell_px;
        let base_z = base_z(blob, layout, residue);
        let (_, aoi_far_z) = grid.pixel_to_ground(0.0, aoi.top as f64);
        let in_aoi = base_z <= aoi_far_z + 0.5 * grid.mm_per_px && right_px > aoi.left && left_px < aoi.right;
        if in_aoi && best.is_none_or(|b| blob.cell_bottom > b.cell_bottom) {
            best = Some(*blob);
        }
    }
    best.map(|blob| locate(&blob, layout, residue))
}

/// Apparent ground distance (mm) of a blob's nearest residue row.
/// Residue of anything standing up appears beyond its footprint, so this
/// never places a static obstacle nearer than it is: the residue path
/// cannot raise an early alarm, and parallax measures the true footprint.
fn base_z(blob: &Blob, layout: &Layout, residue: &Residue) -> f64 {
    let cell_px = layout.cells.px;
    let top = usize::from(blob.cell_top) * cell_px;
    let bottom = ((usize::from(blob.cell_bottom) + 1) * cell_px).min(layout.analysis_rows);
    let mut base = bottom.saturating_sub(1);
    while base > top && residue.row_residue[base] < 2 {
        base -= 1;
    }
    let (_, apparent_z) = layout.grid.pixel_to_ground(0.0, base as f64);
    apparent_z
}

/// Nearest point and lateral extent of a blob.
fn locate(blob: &Blob, layout: &Layout, residue: &Residue) -> Footprint {
    let (grid, aoi, cell_px) = (&layout.grid, &layout.aoi, layout.cells.px);
    let near_z = base_z(blob, layout, residue);
    let (_, aoi_near_z) = grid.pixel_to_ground(0.0, (aoi.bottom.saturating_sub(1)) as f64);
    let near_z = near_z.max(aoi_near_z);
    let left_px = usize::from(blob.cell_left) * cell_px;
    let right_px = ((usize::from(blob.cell_right) + 1) * cell_px).min(grid.width()) - 1;
    let (left, _) = grid.pixel_to_ground(left_px as f64, 0.0);
    let (right, _) = grid.pixel_to_ground(right_px as f64, 0.0);
    Footprint { near_mm: libm::round(near_z) as i32, left_mm: libm::round(left) as i32, right_mm: libm::round(right) as i32 }
}

#[cfg(test)]
mod tests {
    use super::super::parallax::HEIGHT_FRACTIONS;
    use super::*;
    use crate::geometry::tests::sample_rig;
    use crate::grid::{GridConfig, KgGrid};
    use crate::scan::{Scan, ScanLayout};

    /// The cell (row, column) at the middle of the sample rig's AOI, 800 mm
    /// ahead: the nearest cell of the test's patch.
    fn patch_corner(layout: &Layout) -> (usize, usize) {
        let (i, j) = layout.grid.ground_to_pixel(0.0, 800.0);
        (j as usize / layout.cells.px, i as usize / layout.cells.px)
    }

    /// A patch below the ground in the middle of the sample rig's AOI,
    /// every cell lagging the ground past the deepest drop; `depth_cell`
    /// (if any, outside it) measured a drop's depth.
    fn lagging_patch(layout: &Layout, depth_cell: Option<usize>) -> CellHeights {
        let cells = &layout.cells;
        let mut heights = CellHeights::for_camera(layout.camera_height_mm);
        let (row, column) = patch_corner(layout);
        for r in row - 5..=row {
            for c in column - 3..=column + 3 {
                heights.set_moving(r * cells.wide + c, false);
            }
        }
        if let Some(cell) = depth_cell {
            heights.set(cell, -80, false);
        }
        heights
    }

    /// The sample rig's layout at the default grid and configuration, no
    /// residue, and a scan to fill.
    fn sample_layout() -> (Layout, GpaConfig, Residue, Scan) {
        let rig = sample_rig();
        let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
        let config = GpaConfig::default();
        let layout = Layout::new(&rig, &grid, config.cell_mm);
        (layout, config, Residue::EMPTY, Scan::new(ScanLayout::new(40.0, 450.0, 1500.0)))
    }

    /// Cells that only lag the ground (a car ahead's shadow moving with it)
    /// are no drop, but a moving obstacle; the same lags beside a cell that
    /// measured a depth are a drop deeper than any looked for.
    #[test]
    fn lags_alone_are_a_moving_thing_not_a_drop() {
        let (layout, config, residue, mut scan) = sample_layout();
        let lags = lagging_patch(&layout, None);
        let evidence = parallax_obstacle(&layout, &lags, &residue, &config, false, true, None, &mut scan);
        assert!(evidence.hazard.is_none(), "{:?}", evidence.hazard);
        let moving = moving_obstacle(&layout, &lags).expect("a moving obstacle");
        assert!((750..=800).contains(&moving.near_mm), "{moving:?}");

        // Next to the patch, on its far side.
        let (row, column) = patch_corner(&layout);
        let measured = (row - 6) * layout.cells.wide + column;
        let with_depth = lagging_patch(&layout, Some(measured));
        let evidence = parallax_obstacle(&layout, &with_depth, &residue, &config, false, true, None, &mut scan);
        let (drop, depth) = evidence.hazard.expect("a drop");
        assert!(depth < 0 && (750..=850).contains(&drop.near_mm), "{drop:?} {depth}");
    }

    /// A lower level of low contrast: four cells measured a drop's depth,
    /// four beside them only weakly. Together they show the area a drop
    /// needs; the measured four alone do not, and the weak ones found no
    /// drop on their own.
    #[test]
    fn weak_depths_count_toward_a_drops_area() {
        let (layout, config, residue, mut scan) = sample_layout();
        let (row, column) = patch_corner(&layout);
        let wide = layout.cells.wide;
        let patch = |firm: bool, weak: bool| {
            let mut heights = CellHeights::for_camera(layout.camera_height_mm);
            for r in row - 1..=row {
                for c in column - 1..=column {
                    if firm {
                        heights.set(r * wide + c, -80, false);
                    }
                    if weak {
                        heights.set(r * wide + c + 2, -80, true);
                    }
                }
            }
            heights
        };
        let drop_of = |heights: &CellHeights, scan: &mut Scan| parallax_obstacle(&layout, heights, &residue, &config, false, true, None, scan).hazard;
        let (drop, depth) = drop_of(&patch(true, true), &mut scan).expect("a drop");
        assert!(depth <= -20 && (750..=850).contains(&drop.near_mm), "{drop:?} {depth}");
        assert!(drop_of(&patch(true, false), &mut scan).is_none(), "four measured depths are no area");
        assert!(drop_of(&patch(false, true), &mut scan).is_none(), "weak depths alone found no drop");
    }

    /// A face standing on `face_mm` ahead, 3 cells wide around the middle
    /// of the AOI: every cell of it from 1060 to 1250 mm seen measures the
    /// height that points at that footprint.
    fn face_on(layout: &Layout, face_mm: f64) -> CellHeights {
        let (grid, cells) = (&layout.grid, &layout.cells);
        let mut heights = CellHeights::for_camera(layout.camera_height_mm);
        let row_of = |z: f64| grid.ground_to_pixel(0.0, z).1 as usize / cells.px;
        let column = grid.ground_to_pixel(0.0, 800.0).0 as usize / cells.px;
        for r in row_of(1250.0)..=row_of(1060.0) {
            let height = layout.camera_height_mm * (1.0 - face_mm / layout.centre_mm(r));
            for c in column - 1..=column + 1 {
                heights.set(r * cells.wide + c, height as i16, false);
            }
        }
        heights
    }

    /// A face taller than the highest hypothesis (a car ahead from a car's
    /// camera): all but its nearest cells match that hypothesis best, which
    /// places them short of how tall they are, so beyond the face; the
    /// cells of its lower part that measured their heights place it.
    #[test]
    fn a_face_above_the_top_hypothesis_stands_where_its_lower_part_says() {
        let (layout, config, residue, mut scan) = sample_layout();
        let (grid, cells) = (&layout.grid, &layout.cells);
        let camera_height = layout.camera_height_mm;
        let row_of = |z: f64| grid.ground_to_pixel(0.0, z).1 as usize / cells.px;
        let column = grid.ground_to_pixel(0.0, 800.0).0 as usize / cells.px;
        let lower_row = row_of(900.0);
        let face_mm = 0.52 * layout.centre_mm(lower_row);
        let top = camera_height * HEIGHT_FRACTIONS[HEIGHT_FRACTIONS.len() - 1];
        let mut heights = CellHeights::for_camera(camera_height);
        for r in row_of(1400.0)..=lower_row {
            let height = camera_height * (1.0 - face_mm / layout.centre_mm(r));
            for c in column - 1..=column + 1 {
                heights.set(r * cells.wide + c, libm::round(height.min(top)) as i16, false);
            }
        }
        let (face, _) = parallax_obstacle(&layout, &heights, &residue, &config, false, true, None, &mut scan).hazard.expect("the face");
        assert!((f64::from(face.near_mm) - face_mm).abs() <= 3.0, "{face:?} for {face_mm}");
    }

    /// A face whose lower part, nearer than its footprint, lags the ground
    /// where that footprint says (a car ahead moving along: its bumper)
    /// reaches there, and moves along; one cell of it is not enough, nor
    /// cells that point elsewhere or stand beside the face.
    #[test]
    fn a_face_whose_lower_part_lags_reaches_there() {
        let (layout, config, residue, mut scan) = sample_layout();
        let (grid, cells) = (&layout.grid, &layout.cells);
        let camera_height = layout.camera_height_mm;
        let face_mm = 1000.0;
        let standing = face_on(&layout, face_mm);
        let found = |heights: &CellHeights, scan: &mut Scan| parallax_obstacle(&layout, heights, &residue, &config, false, true, None, scan);
        let alone = found(&standing, &mut scan);
        let (face, height) = alone.hazard.expect("the face");
        assert!(height > 0 && (face.near_mm - 1000).abs() <= 2 && !alone.moves_along, "{face:?}");

        let cell_at = |x: f64, z: f64| {
            let (i, j) = grid.ground_to_pixel(x, z);
            (j as usize / cells.px) * cells.wide + i as usize / cells.px
        };
        // The depth a cell below the ground measures when it points at the face.
        let pointing = |cell: usize| -((camera_height * (face_mm / layout.centre_mm(cell / cells.wide) - 1.0)) as i16);
        let with = |cells_set: &[(usize, i16)]| {
            let mut heights = face_on(&layout, face_mm);
            for &(cell, depth) in cells_set {
                heights.set(cell, depth, false);
            }
            heights
        };
        let (nearer, nearest) = (cell_at(0.0, 900.0), cell_at(0.0, 870.0));
        let evidence = found(&with(&[(nearer, pointing(nearer)), (nearest, pointing(nearest))]), &mut scan);
        let (lowered, lowered_height) = evidence.hazard.expect("the face, lowered");
        assert_eq!(lowered_height, height);
        assert_eq!(f64::from(lowered.near_mm), libm::round(layout.near_side_mm(nearest / cells.wide)));
        assert!(evidence.moves_along && lowered.near_mm < 870);

        // One cell alone; two whose depths point past the face; two a
        // column beyond the face's side and its cell of slack.
        let beside = |z: f64| cell_at(face.right_mm as f64 + 2.5 * cells.px as f64 * grid.mm_per_px, z);
        for lower in [
            [(nearer, pointing(nearer)), (nearer, pointing(nearer))],
            [(nearer, 3 * pointing(nearer)), (nearest, 3 * pointing(nearest))],
            [(beside(900.0), pointing(nearer)), (beside(870.0), pointing(nearest))],
        ] {
            let evidence = found(&with(&lower), &mut scan);
            assert_eq!(evidence.hazard, alone.hazard, "{lower:?}");
            assert!(!evidence.moves_along);
        }

        // Lags past the deepest drop: part of the face where that depth
        // would still put them nearer than it, not where it would put
        // them beyond.
        let lagging = |z: f64| {
            let mut heights = face_on(&layout, face_mm);
            for cell in [cell_at(0.0, z), cell_at(0.0, z - 30.0)] {
                heights.set_moving(cell, false);
            }
            heights
        };
        let reach = face_mm * camera_height / (camera_height + config.max_drop_mm);
        assert!(reach > layout.aoi_mm().near + 60.0, "the sample rig sees lags that point at the face");
        assert!(found(&lagging(reach - 20.0), &mut scan).moves_along);
        assert_eq!(found(&lagging(900.0), &mut scan).hazard, alone.hazard);
    }

    /// Heights that each beat the ground only weakly, a patch of
    /// `rows` x 3 cells 60 mm up from the middle of the AOI on.
    fn weak_patch(layout: &Layout, rows: usize) -> CellHeights {
        let mut heights = CellHeights::for_camera(layout.camera_height_mm);
        let (row, column) = patch_corner(layout);
        for r in row + 1 - rows..=row {
            for c in column - 1..=column + 1 {
                heights.set(r * layout.cells.wide + c, 60, true);
            }
        }
        heights
    }

    /// A group of weak heights alone is no obstacle on one frame; it is
    /// one where the last frame saw heights stand up, if it is large
    /// enough and at least half of it stood up then.
    #[test]
    fn weak_heights_count_where_the_last_frame_saw_them_stand_up() {
        let (layout, config, residue, mut scan) = sample_layout();
        let weak = weak_patch(&layout, 2);
        let found = |last: Option<MovedMask>, scan: &mut Scan| parallax_obstacle(&layout, &weak, &residue, &config, false, true, last, scan).hazard;
        assert_eq!(found(None, &mut scan), None);

        let mut last_frame = super::super::hazard_mask::HazardMask::EMPTY;
        // The last frame saw nothing stand up there.
        last_frame.record(7, layout.cells, &CellHeights::for_camera(layout.camera_height_mm), &residue, &config);
        assert_eq!(found(last_frame.moved(8, 0.0), &mut scan), None);
        // It saw the same weak heights: an obstacle, standing nearer than
        // where its cells are seen (60 mm up).
        last_frame.record(7, layout.cells, &weak, &residue, &config);
        let (obstacle, height) = found(last_frame.moved(8, 0.0), &mut scan).expect("an obstacle");
        assert_eq!(height, 60);
        let (row, _) = patch_corner(&layout);
        assert!(f64::from(obstacle.near_mm) < layout.near_side_mm(row), "{obstacle:?}");
        // Not the frame before: nothing to see it again in.
        assert_eq!(found(last_frame.moved(9, 0.0), &mut scan), None);
        // Within a cell of where heights stood up (the step's error) is
        // where they stood up: the patch's nearer row is enough for its two
        // rows; of five rows, the three farther ones stood up nowhere near,
        // more than half of the patch: it does not count.
        last_frame.record(7, layout.cells, &weak_patch(&layout, 1), &residue, &config);
        assert!(found(last_frame.moved(8, 0.0), &mut scan).is_some());
        let five_rows = weak_patch(&layout, 5);
        assert_eq!(parallax_obstacle(&layout, &five_rows, &residue, &config, false, true, last_frame.moved(8, 0.0), &mut scan).hazard, None);
        // Too small a group (four cells, enough for measured heights),
        // however often seen.
        let two_by_two = |weak: bool| {
            let mut heights = CellHeights::for_camera(layout.camera_height_mm);
            let (row, column) = patch_corner(&layout);
            for cell in [row - 1, row].into_iter().flat_map(|r| [r * layout.cells.wide + column, r * layout.cells.wide + column + 1]) {
                heights.set(cell, 60, weak);
            }
            heights
        };
        let four = two_by_two(true);
        last_frame.record(7, layout.cells, &four, &residue, &config);
        assert_eq!(parallax_obstacle(&layout, &four, &residue, &config, false, true, last_frame.moved(8, 0.0), &mut scan).hazard, None);
        let measured = two_by_two(false);
        assert!(parallax_obstacle(&layout, &measured, &residue, &config, false, true, None, &mut scan).hazard.is_some());
    }

    /// Two cells of measured heights with residue are too few on one
    /// frame; where every one of them stood up on the last frame too, they
    /// are a small obstacle, on a full baseline only. Without residue, or
    /// weak, they are not.
    #[test]
    fn a_small_group_seen_again_where_it_stood_counts() {
        let (layout, config, plain, mut scan) = sample_layout();
        let mut residue = Residue::EMPTY;
        let (row, column) = patch_corner(&layout);
        let px = layout.cells.px;
        for c in [column, column + 1] {
            let cell = row * layout.cells.wide + c;
            residue.cell_valid[cell] = (px * px) as u8;
            residue.cell_residue[cell] = (px * px / 2) as u8;
        }
        assert!(residue.percent(row * layout.cells.wide + column, px) >= config.active_cell_percent);
        let pair = |weak: bool| {
            let mut heights = CellHeights::for_camera(layout.camera_height_mm);
            for c in [column, column + 1] {
                heights.set(row * layout.cells.wide + c, 60, weak);
            }
            heights
        };
        let measured = pair(false);
        let found = |heights: &CellHeights, short: bool, last: Option<MovedMask>, scan: &mut Scan| parallax_obstacle(&layout, heights, &residue, &config, short, true, last, scan).hazard;
        assert_eq!(found(&measured, false, None, &mut scan), None);
        let mut last_frame = super::super::hazard_mask::HazardMask::EMPTY;
        last_frame.record(7, layout.cells, &CellHeights::for_camera(layout.camera_height_mm), &residue, &config);
        assert_eq!(found(&measured, false, last_frame.moved(8, 0.0), &mut scan), None);
        last_frame.record(7, layout.cells, &measured, &residue, &config);
        let (obstacle, height) = found(&measured, false, last_frame.moved(8, 0.0), &mut scan).expect("a small obstacle");
        assert_eq!(height, 60);
        assert!(f64::from(obstacle.near_mm) < layout.near_side_mm(row), "{obstacle:?}");
        // A short baseline's heights wander: a small group never counts there.
        assert_eq!(found(&measured, true, last_frame.moved(8, 0.0), &mut scan), None);
        // Only half of it stood up before.
        let mut half = CellHeights::for_camera(layout.camera_height_mm);
        half.set(row * layout.cells.wide + column + 2, 60, false);
        last_frame.record(7, layout.cells, &half, &residue, &config);
        assert_eq!(found(&measured, false, last_frame.moved(8, 0.0), &mut scan), None);
        let weak = pair(true);
        last_frame.record(7, layout.cells, &weak, &residue, &config);
        assert_eq!(found(&weak, false, last_frame.moved(8, 0.0), &mut scan), None);
        // Seen again, but without residue: a sharp ground edge's blur.
        last_frame.record(7, layout.cells, &measured, &plain, &config);
        assert_eq!(parallax_obstacle(&layout, &measured, &plain, &config, false, true, last_frame.moved(8, 0.0), &mut scan).hazard, None);
    }

    /// A moving thing nearer than a parallax obstacle places it, keeping its
    /// height; a drop keeps its edge against a moving thing within a cell
    /// of it (its lower level lags too), but not against one that starts
    /// farther than a cell nearer (a car's shadow ahead of its body
    /// misread as a drop), which places the hazard as a thing moving along,
    /// unless residue lies nearer still.
    #[test]
    fn a_thing_moving_along_places_what_it_starts_nearer_than() {
        let at = |near_mm: i32| Footprint { near_mm, left_mm: -100, right_mm: 100 };
        let cell_mm = 30.0;
        assert_eq!(weigh_moving(Some((at(1000), 400)), None, Some(at(800)), false, cell_mm), (Some((at(800), 400)), None, true));
        assert_eq!(weigh_moving(Some((at(1000), 400)), None, Some(at(1200)), false, cell_mm), (Some((at(1000), 400)), None, false));
        assert_eq!(weigh_moving(Some((at(1000), -60)), None, Some(at(980)), false, cell_mm), (Some((at(1000), -60)), None, false));
        assert_eq!(weigh_moving(Some((at(1000), -60)), None, Some(at(800)), false, cell_mm), (None, Some(at(800)), true));
        assert_eq!(weigh_moving(Some((at(1000), -60)), Some(at(700)), Some(at(800)), false, cell_mm), (None, Some(at(700)), false));
        assert_eq!(weigh_moving(None, Some(at(900)), Some(at(800)), false, cell_mm), (None, Some(at(800)), true));
        assert_eq!(weigh_moving(None, Some(at(900)), None, false, cell_mm), (None, Some(at(900)), false));
    }
}

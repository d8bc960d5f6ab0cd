//! Fixed-point limits (issue 7): the largest camera image, the largest KG
//! grid (256x256) and the widest search window, with all-255 frames against
//! all-0 frames, so every difference is the largest possible. Tests build
//! with overflow checks on, so an accumulator that overflowed would panic;
//! the worst-case bounds are also computed and checked against the types.

mod common;

use flatland_core::geometry::Rig;
use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::kernels::FRAC_BITS;
use flatland_core::limits::{MAX_GRID_SIDE, MAX_IMAGE_SIDE, MAX_SEARCH_RADIUS};
use flatland_core::motion::Motion;
use flatland_core::remap::{Line, RemapTable, StreamingRemap};
use flatland_core::report::FrameReport;

/// Margins that make both grid extents exactly 255 pixels of 5 mm:
/// 2 * (250 + 387.5) = 1275 and (1400 + 265) - (450 - 60) = 1275.
fn largest_grid(rig: &Rig) -> KgGrid {
    let config = GridConfig { margin_lateral_mm: 387.5, margin_far_mm: Some(265.0), margin_near_mm: 60.0, mm_per_px: Some(5.0), ..GridConfig::default() };
    KgGrid::for_rig(rig, &config).expect("256x256 grid")
}

/// Worst cases, from the algorithms' definitions:
/// - remap bilinear: `top * (256 - wy) + bottom * wy + 2^15` with
///   `top, bottom <= 255 * 256` (u32);
/// - the shift search: every SAD / seed sum adds at most 255 per compared
///   pixel, and at most every grid pixel is compared (u32);
/// - the |diff| histogram counts at most every grid pixel (u32);
/// - fixed-point source coordinates: the table clamps to i32::MAX / 2, and a
///   row adds at most 256 steps of at most that much (wrapping on purpose).
#[test]
fn worst_case_sums_fit_their_types() {
    let bilinear = 255u64 * 256 * 256 + (1 << 15);
    assert!(bilinear <= u64::from(u32::MAX), "bilinear intermediate {bilinear}");
    let pixels = (MAX_GRID_SIDE * MAX_GRID_SIDE) as u64;
    let sad = 255 * pixels;
    assert!(sad <= u64::from(u32::MAX), "SAD bound {sad}");
    assert!(pixels <= u64::from(u32::MAX), "histogram bound {pixels}");
    // Camera coordinates in Q16.16: the largest image side fits with room to spare.
    assert!(i64::from(MAX_IMAGE_SIDE) << FRAC_BITS <= i64::from(i32::MAX));
}

#[test]
fn largest_grid_is_256_square() {
    let rig = common::flat_marks_rig(MAX_IMAGE_SIDE);
    let grid = largest_grid(&rig);
    assert_eq!((grid.width(), grid.height()), (MAX_GRID_SIDE, MAX_GRID_SIDE));
}

/// Streams `value`-filled camera frames through remap and GPA; returns each
/// frame's report and checks every valid KG pixel equals `value`.
fn run(frames: &[(u8, Option<Motion>)]) -> Vec<Option<FrameReport>> {
    let rig = common::flat_marks_rig(MAX_IMAGE_SIDE);
    let grid = largest_grid(&rig);
    let table = RemapTable::new(&rig, &grid).expect("table");
    let config = GpaConfig { search_radius: MAX_SEARCH_RADIUS, ..GpaConfig::default() };
    let mut keyframe = vec![0u8; Gpa::keyframe_bytes(&grid)];
    let mut gpa = Gpa::new(&rig, &grid, &table, config, &mut keyframe).expect("gpa");
    let mut ring = vec![0u8; table.ring_bytes()];
    let mut stream = StreamingRemap::new(&table);
    let mut line = Line::ZERO;
    let (cw, ch) = (table.camera_width(), table.camera_height());
    let mut reports = Vec::new();
    for (n, &(value, odometry)) in frames.iter().enumerate() {
        let row = vec![value; cw];
        gpa.begin_frame(n as u32, odometry, None);
        for _ in 0..ch {
            stream
                .push_row(&mut ring, &row, &mut line, |j, kg| {
                    for i in table.valid_columns(j) {
                        assert_eq!(kg[i], value, "KG pixel ({i}, {j}) of a flat {value} frame");
                    }
                    gpa.on_kg_row(j, kg);
                })
                .expect("row");
        }
        reports.push(gpa.end_frame());
    }
    reports
}

#[test]
fn all_255_against_all_0_at_the_limits() {
    let still = Some(Motion::default());
    // Zero odometry keeps frame 0 (all 0) the keyframe throughout.
    let frames = [(0, None), (255, still), (0, still), (255, still)];
    let reports = run(&frames);
    assert!(reports[0].is_none(), "the first frame only starts the keyframe");
    let compared = reports[1].expect("a report against the keyframe").count50;
    assert!(compared > 0 && compared as usize <= MAX_GRID_SIDE * MAX_GRID_SIDE);
    for (&(value, _), report) in frames.iter().zip(&reports).skip(1) {
        let report = report.expect("a report against the all-0 keyframe");
        assert_eq!(report.ref_frame, 0);
        if value == 255 {
            // Every compared pixel differs by 255 at every shift: the seed
            // statistics are exact, not wrapped or saturated.
            assert_eq!(report.count50, compared);
            assert_eq!(u64::from(report.sad), 255 * u64::from(compared));
        } else {
            assert_eq!((report.sad, report.count50), (0, 0));
        }
    }
}

/// The largest odometry steps a recording can give (well beyond the search
/// window, and full turns) must not overflow the warp's fixed point either.
#[test]
fn extreme_motion_at_the_limits() {
    let huge = Motion { tx_mm: -1.0e12, tz_mm: 1.0e12, dyaw_deg: 720.0 };
    let tiny = Motion { tx_mm: 1e-300, tz_mm: -1e-300, dyaw_deg: -1e-300 };
    let reports = run(&[(255, None), (0, Some(huge)), (255, Some(tiny)), (0, Some(huge))]);
    assert!(reports[0].is_none());
}

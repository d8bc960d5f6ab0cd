//! Property tests (issue 7) over random valid rigs, frames and messages:
//! geometry round trips, the remap table's error bound, streaming remap
//! against an independent whole-frame reference, the GPA shift search
//! against a naive SAD, and the serial protocol's encode/decode round trip.

mod common;

use flatland_core::geometry::{Aoi, Distortion, Intrinsics, Mount, Pixel, Rig};
use flatland_core::gpa::{Gpa, GpaConfig, SEED_COUNT_LEVEL, SEED_SUM_LEVEL};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::limits::MAX_SEARCH_RADIUS;
use flatland_core::motion::{Attitude, Motion, Pose};
use flatland_core::protocol::{encode_line, Decoder, DecoderStats, Fault, FaultCode, LinkStats, LoopStats, Message, Odometry, RigRecord};
use flatland_core::remap::{remap_frame, Line, RemapTable, StreamingRemap};
use flatland_core::report::{FrameReport, NotJudged, Status, SHIFT_SCALE};
use flatland_core::selftest::xorshift32;
use proptest::prelude::*;

/// Parameters of a rig whose AOI is placed inside the camera's view.
#[derive(Clone, Debug)]
struct RigParams {
    width: u16,
    height: u16,
    /// fx as a multiple of the image width: horizontal field of view 23-118 degrees.
    fx: f64,
    aspect: f64,
    cx_frac: f64,
    cy_frac: f64,
    tilt_deg: f64,
    height_mm: f64,
    /// Where the AOI's near and far edges sit between the principal point
    /// and the bottom / top image rows (0 = principal point, 1 = image edge).
    near_frac: f64,
    far_frac: f64,
    half_width_frac: f64,
    distortion: Option<[f64; 5]>,
}

fn rig_params() -> impl Strategy<Value = RigParams> {
    let distortion = prop_oneof![
        Just(None),
        (-0.3..0.15f64, -0.05..0.1f64, -0.002..0.002f64, -0.002..0.002f64, -0.01..0.01f64)
            .prop_map(|(k1, k2, p1, p2, k3)| Some([k1, k2, p1, p2, k3])),
    ];
    (
        (64u16..=640, 64u16..=480, 0.3..2.5f64, 0.9..1.1f64, 0.4..0.6f64, 0.4..0.6f64),
        (15.0..60.0f64, 150.0..800.0f64, 0.2..0.85f64, 0.1..0.7f64, 0.2..0.8f64),
        distortion,
    )
        .prop_map(|((width, height, fx, aspect, cx_frac, cy_frac), (tilt_deg, height_mm, near_frac, far_frac, half_width_frac), distortion)| {
            RigParams { width, height, fx, aspect, cx_frac, cy_frac, tilt_deg, height_mm, near_frac, far_frac, half_width_frac, distortion }
        })
}

/// Builds the rig: the AOI's edges from viewing angles inside the image, so
/// most parameter sets are valid; the rest are refused by `Rig::new_checked`.
fn build_rig(p: &RigParams) -> Option<Rig> {
    let fx = p.fx * f64::from(p.width);
    let fy = fx * p.aspect;
    let cx = p.cx_frac * (f64::from(p.width) - 1.0);
    let cy = p.cy_frac * (f64::from(p.height) - 1.0);
    let tilt = p.tilt_deg.to_radians();
    let below = ((f64::from(p.height) - 1.0 - cy) / fy).atan() * p.near_frac;
    let above = (cy / fy).atan() * p.far_frac;
    if tilt - above <= 0.02 || tilt + below >= 1.55 {
        return None;
    }
    let near = p.height_mm / (tilt + below).tan();
    let far = p.height_mm / (tilt - above).tan();
    // Lateral extent seen at the near edge, along its line of sight.
    let near_range = (p.height_mm * p.height_mm + near * near).sqrt();
    let half_width = near_range * cx.min(f64::from(p.width) - 1.0 - cx) / fx * p.half_width_frac;
    let distortion = p.distortion.map(Distortion::from_coefficients);
    Rig::new_checked(
        Intrinsics { width: p.width, height: p.height, fx, fy, cx, cy, distortion, readout_ms: 0.0 },
        Mount::level(p.height_mm, p.tilt_deg),
        Aoi { half_width_mm: half_width, near_mm: near, far_mm: far },
    )
    .ok()
}

fn valid_rig() -> impl Strategy<Value = Rig> {
    rig_params().prop_filter_map("rig refused by Rig::new_checked", |p| build_rig(&p))
}

fn pinhole_rig() -> impl Strategy<Value = Rig> {
    rig_params().prop_filter_map("rig refused by Rig::new_checked", |p| build_rig(&RigParams { distortion: None, ..p }))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// Ground -> pixel -> ground, for points of the AOI (always in view).
    #[test]
    fn ground_pixel_ground(rig in valid_rig(), s in 0.0..1.0f64, t in 0.0..1.0f64) {
        let aoi = *rig.aoi();
        let (x, z) = (-aoi.half_width_mm + 2.0 * aoi.half_width_mm * s, aoi.near_mm + (aoi.far_mm - aoi.near_mm) * t);
        let pixel = rig.ground_to_pixel(x, z).expect("AOI point in view");
        prop_assert!(rig.pixel_in_image(pixel));
        let (xb, zb) = rig.pixel_to_ground(pixel).expect("pixel below the horizon");
        // 1e-6 px of image error is this much ground at this range.
        let tolerance = 1e-6 * z.max(1.0);
        prop_assert!((xb - x).abs() <= tolerance && (zb - z).abs() <= tolerance, "({x}, {z}) -> ({xb}, {zb})");
    }

    /// Pixel -> ground -> pixel, for pixels below the horizon.
    #[test]
    fn pixel_ground_pixel(rig in valid_rig(), s in 0.0..1.0f64, t in 0.0..1.0f64) {
        let camera = *rig.camera();
        let pixel = Pixel { u: s * (f64::from(camera.width) - 1.0), v: t * (f64::from(camera.height) - 1.0) };
        if let Some((x, z)) = rig.pixel_to_ground(pixel) {
            let back = rig.ground_to_pixel(x, z).expect("a ground point seen by a pixel projects back");
            prop_assert!((back.u - pixel.u).abs() < 1e-6 && (back.v - pixel.v).abs() < 1e-6, "{pixel:?} -> {back:?}");
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// The table's source coordinates stay within 1/32 px of the exact
    /// projection, at the resolution chosen from the rig or a finer one.
    #[test]
    fn remap_table_error_bound(rig in pinhole_rig(), finer in proptest::option::of(0.5..1.0f64)) {
        check_table_error(&rig, finer)?;
    }

    /// Streaming remap, row by row through the small ring (also after a frame
    /// abandoned half way), equals a bilinear sample of the whole frame at the
    /// table's source coordinates.
    #[test]
    fn streaming_remap_equals_whole_frame(rig in valid_rig(), seed in any::<u32>(), abandon_at in 0.0..1.0f64) {
        let grid = KgGrid::for_rig(&rig, &GridConfig::default()).expect("grid");
        let table = RemapTable::new(&rig, &grid).expect("table");
        let (cw, ch) = (table.camera_width(), table.camera_height());
        let mut state = seed | 1; // xorshift32's state must not be 0
        let frame: Vec<u8> = (0..cw * ch).map(|_| xorshift32(&mut state) as u8).collect();
        let mut ring = vec![0u8; table.ring_bytes()];
        let mut stream = StreamingRemap::new(&table);
        let stop = ((ch as f64) * abandon_at) as usize;
        let mut line = Line::ZERO;
        for row in frame.chunks_exact(cw).take(stop).rev() {
            // A frame of other content, abandoned part way (rows in reverse order).
            stream.push_row(&mut ring, row, &mut line, |_, _| {}).expect("row");
        }
        stream.reset();
        let mut streamed = vec![0u8; grid.len()];
        for row in frame.chunks_exact(cw) {
            stream.push_row(&mut ring, row, &mut line, |j, kg| streamed[j * grid.width()..][..grid.width()].copy_from_slice(kg)).expect("row");
        }
        for j in 0..grid.height() {
            let valid = table.valid_columns(j);
            for i in 0..grid.width() {
                let expected = match table.source_pixel(i, j) {
                    Some((u, v)) if valid.contains(&i) => bilinear_reference(&frame, cw, ch, u, v),
                    _ => 0,
                };
                prop_assert_eq!(streamed[j * grid.width() + i], expected, "KG pixel ({}, {})", i, j);
            }
        }
        let mut whole = vec![0u8; grid.len()];
        let mut ring = vec![0u8; table.ring_bytes()];
        remap_frame(&table, &frame, &mut ring, &mut whole).expect("whole frame");
        prop_assert!(whole == streamed);
    }
}

/// The same bound with lens distortion, on every valid rig (500 cases):
/// wide and narrow lenses, small images, coarse grids (KG pixels much larger
/// than camera pixels), barrel and pincushion with tangential terms. States
/// the measured maximum.
#[test]
fn remap_table_error_bound_with_distortion() {
    let config = ProptestConfig { cases: 500, failure_persistence: None, ..ProptestConfig::default() };
    let mut runner = proptest::test_runner::TestRunner::new(config);
    let worst = std::cell::Cell::new(0.0f64);
    let bound = std::cell::Cell::new(0.0f64);
    let result = runner.run(&(valid_rig(), proptest::option::of(0.5..1.0f64)), |(rig, finer)| {
        if let Some((error, table_bound)) = check_table_error(&rig, finer)? {
            worst.set(worst.get().max(error));
            bound.set(bound.get().max(table_bound));
        }
        Ok(())
    });
    if let Err(failure) = result {
        panic!("{failure}");
    }
    println!(
        "remap with distortion, 500 random rigs: max source error {:.5} px (largest build-time bound {:.5} px, limit 1/32)",
        worst.get(),
        bound.get()
    );
}

/// Measured max source error and the table's own bound, or None where the
/// finer grid exceeds the cap.
fn check_table_error(rig: &Rig, finer: Option<f64>) -> Result<Option<(f64, f64)>, TestCaseError> {
    let auto = KgGrid::for_rig(rig, &GridConfig::default()).expect("grid at the rig's own resolution");
    let config = GridConfig { mm_per_px: finer.map(|f| auto.mm_per_px * f), ..GridConfig::default() };
    let grid = match KgGrid::for_rig(rig, &config) {
        Ok(grid) => grid,
        Err(_) => return Ok(None), // finer than the 256x256 cap allows
    };
    let table = RemapTable::new(rig, &grid).expect("a valid rig's AOI is in view");
    prop_assert!(table.error_bound_px() <= 1.0 / 32.0);
    let mut worst: f64 = 0.0;
    let mut valid = 0usize;
    for j in 0..grid.height() {
        for i in table.valid_columns(j) {
            let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
            let exact = rig.ground_to_pixel(x, z).expect("valid KG pixel in view");
            let (u, v) = table.source_pixel(i, j).expect("valid column");
            worst = worst.max((u - exact.u).abs()).max((v - exact.v).abs());
            valid += 1;
        }
    }
    prop_assert!(valid > 0);
    prop_assert!(worst <= 1.0 / 32.0, "max source error {worst} px");
    prop_assert!(worst <= table.error_bound_px(), "max source error {worst} px above the table's bound {}", table.error_bound_px());
    Ok(Some((worst, table.error_bound_px())))
}

/// Bilinear sample with 8-bit weights, as the remap documents it, on the
/// whole frame (no ring): a reference written from the definition.
fn bilinear_reference(frame: &[u8], width: usize, height: usize, u: f64, v: f64) -> u8 {
    let (uf, vf) = ((u * 65536.0) as i64, (v * 65536.0) as i64);
    let (x0, y0) = ((uf >> 16) as usize, (vf >> 16) as usize);
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    let (wx, wy) = (((uf >> 8) & 0xFF) as u32, ((vf >> 8) & 0xFF) as u32);
    let at = |x: usize, y: usize| u32::from(frame[y * width + x]);
    let top = at(x0, y0) * (256 - wx) + at(x1, y0) * wx;
    let bottom = at(x0, y1) * (256 - wx) + at(x1, y1) * wx;
    ((top * (256 - wy) + bottom * wy + (1 << 15)) >> 16) as u8
}

/// A smooth texture defined on every integer position (so shifted copies
/// have no border): a sum of a few random sinusoids, in 40..=190.
fn texture(phases: &[(f64, f64, f64); 4], i: i64, j: i64) -> u8 {
    let (x, y) = (i as f64, j as f64);
    let sum: f64 = phases.iter().map(|&(fx, fy, phase)| (fx * x + fy * y + phase).sin()).sum();
    (115.0 + 75.0 * sum / 4.0).round() as u8
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// The GPA shift search on KG images fed directly: the current image is
    /// the keyframe moved by a known integer shift beyond the (zero)
    /// odometry, plus a bright patch. The reported best shift must be the
    /// naive SAD minimum over the window, and the seed statistics (sum of
    /// |diff| > 30, count of |diff| > 50) those of the naive |diff| at the
    /// predicted shift over the AOI.
    #[test]
    fn gpa_shift_search_matches_naive_sad(
        radius in 1usize..=MAX_SEARCH_RADIUS,
        shift in (-3i64..=3, -3i64..=3),
        phases in proptest::array::uniform4((0.15..0.6f64, 0.15..0.6f64, 0.0..6.3f64)),
        patch in (0.2..0.8f64, 0.2..0.8f64, 2usize..6, 55u8..=65),
    ) {
        let (sk, sg) = (shift.0.clamp(-(radius as i64), radius as i64), shift.1.clamp(-(radius as i64), radius as i64));
        let rig = common::flat_marks_rig(256);
        let grid = KgGrid::for_rig(&rig, &GridConfig::default()).expect("grid");
        let table = RemapTable::new(&rig, &grid).expect("table");
        let config = GpaConfig { search_radius: radius, ..GpaConfig::default() };
        let mut keyframe = vec![0u8; Gpa::keyframe_bytes(&grid)];
        let mut gpa = Gpa::new(&rig, &grid, &table, config, &mut keyframe).expect("gpa");
        let (w, h) = (grid.width(), grid.height());
        let aoi = grid.aoi_pixels(&rig);
        let key = |i: i64, j: i64| texture(&phases, i, j);
        // The patch: a square of +level inside the AOI.
        let (pi, pj) = (aoi.left + ((aoi.right - aoi.left) as f64 * patch.0) as usize, aoi.top + ((aoi.bottom - aoi.top) as f64 * patch.1) as usize);
        let in_patch = |i: usize, j: usize| i >= pi && i < pi + patch.2 && j >= pj && j < pj + patch.2;
        // current(i, j) = keyframe(i + sk, j + sg): GPA reports that as shift (sk, sg).
        let current = |i: usize, j: usize| {
            let base = key(i as i64 + sk, j as i64 + sg);
            if in_patch(i, j) { base + patch.3 } else { base }
        };
        gpa.begin_frame(0, None, None);
        for j in 0..h {
            let row: Vec<u8> = (0..w).map(|i| if table.valid_columns(j).contains(&i) { key(i as i64, j as i64) } else { 0 }).collect();
            gpa.on_kg_row(j, &row);
        }
        prop_assert!(gpa.end_frame().is_none(), "the first frame only starts the keyframe");
        gpa.begin_frame(1, Some(Motion::default()), None);
        for j in 0..h {
            let row: Vec<u8> = (0..w).map(|i| if table.valid_columns(j).contains(&i) { current(i, j) } else { 0 }).collect();
            gpa.on_kg_row(j, &row);
        }
        let report: FrameReport = gpa.end_frame().expect("a report against the keyframe");

        // Naive reference over the AOI's interior, where every shift's sample exists.
        let s = radius as i64;
        let margin = radius + 2;
        let mut best = (i64::MAX, 0i64, 0i64);
        for dg in -s..=s {
            for dk in -s..=s {
                let mut sad = 0i64;
                for j in aoi.top + margin..aoi.bottom - margin {
                    for i in aoi.left + margin..aoi.right - margin {
                        sad += (i64::from(current(i, j)) - i64::from(key(i as i64 + dk, j as i64 + dg))).abs();
                    }
                }
                if sad < best.0 {
                    best = (sad, dk, dg);
                }
            }
        }
        prop_assert_eq!((best.1, best.2), (sk, sg), "naive SAD minimum is the applied shift");
        let scale = i64::from(SHIFT_SCALE);
        // Sub-pixel refinement moves less than half a pixel from the best integer shift.
        prop_assert!((i64::from(report.shift_k) - sk * scale).abs() < scale / 2, "shift_k {} for {}", report.shift_k, sk);
        prop_assert!((i64::from(report.shift_g) - sg * scale).abs() < scale / 2, "shift_g {} for {}", report.shift_g, sg);
        // The seed statistics at the prediction (zero shift): with no shift
        // only the patch differs, by patch.3 (above both seed levels).
        prop_assert!(patch.3 > SEED_COUNT_LEVEL);
        let (mut sum_above, mut count_above) = (0u32, 0u32);
        for j in aoi.top..aoi.bottom {
            for i in aoi.left..aoi.right {
                let diff = current(i, j).abs_diff(key(i as i64, j as i64));
                if diff > SEED_SUM_LEVEL {
                    sum_above += u32::from(diff);
                }
                if diff > SEED_COUNT_LEVEL {
                    count_above += 1;
                }
            }
        }
        if (sk, sg) == (0, 0) {
            let area = (patch.2 * patch.2) as u32;
            prop_assert_eq!((count_above, sum_above), (area, area * u32::from(patch.3)));
        }
        prop_assert_eq!((report.count50, report.sad), (count_above, sum_above));
    }
}

// ------------------------------------------------------------ protocol

fn finite() -> impl Strategy<Value = f64> {
    prop_oneof![
        proptest::num::f64::NORMAL | proptest::num::f64::SUBNORMAL | proptest::num::f64::ZERO,
        -2000.0..2000.0f64,
    ]
}

fn rig_record() -> impl Strategy<Value = RigRecord> {
    // Level mounts (no roll/yaw fields on the wire) and crooked ones.
    let mount = prop_oneof![Just([0.0, 0.0]), [finite(), finite()]];
    (any::<u16>(), any::<u16>(), [finite(), finite(), finite(), finite()], proptest::option::of([finite(), finite(), finite(), finite(), finite()]), [finite(), finite(), finite(), finite(), finite()], mount)
        .prop_map(|(width, height, [fx, fy, cx, cy], distortion, [height_mm, tilt_deg, aoi_half_width_mm, aoi_near_mm, aoi_far_mm], [roll_deg, yaw_deg])| RigRecord {
            camera: Intrinsics { width, height, fx, fy, cx, cy, distortion: distortion.map(Distortion::from_coefficients), readout_ms: 0.0 },
            mount: Mount { height_mm, tilt_deg, roll_deg, yaw_deg },
            aoi: Aoi { half_width_mm: aoi_half_width_mm, near_mm: aoi_near_mm, far_mm: aoi_far_mm },
        })
}

fn frame_report() -> impl Strategy<Value = FrameReport> {
    // Judged, or not judged for each reason.
    let statuses = [Status::Ok, Status::NotJudged(NotJudged::NoMotion), Status::NotJudged(NotJudged::AfterGap)];
    (
        (any::<u32>(), any::<u32>(), any::<bool>(), any::<Option<i32>>(), any::<Option<i32>>(), any::<Option<i32>>()),
        (any::<u32>(), any::<u32>(), any::<i32>(), any::<i32>(), any::<i32>(), any::<i32>(), any::<Option<i32>>()),
        0..statuses.len(),
    )
        .prop_map(move |((frame, ref_frame, alarm, nearest_mm, left_mm, right_mm), (sad, count50, shift_k, shift_g, tx, tz, obstacle_h_mm), status)| FrameReport {
            frame, ref_frame, alarm, nearest_mm, left_mm, right_mm, sad, count50, shift_k, shift_g, tx, tz, obstacle_h_mm,
            dyaw: sad as i32, dpitch: count50 as i32, droll: shift_k.wrapping_neg(), odometry_fault: alarm.then_some(tx > 0),
            status: statuses[status],
        })
}

/// With and without each sensor's fields.
fn odometry() -> impl Strategy<Value = Odometry> {
    (any::<u32>(), finite(), proptest::option::of([finite(), finite(), finite()]), proptest::option::of([finite(), finite()]))
        .prop_map(|(frame, t_s, pose, attitude)| Odometry {
            frame,
            t_s,
            pose: pose.map(|[x_mm, z_mm, yaw_deg]| Pose { x_mm, z_mm, yaw_deg }),
            attitude: attitude.map(|[pitch_deg, roll_deg]| Attitude { pitch_deg, roll_deg }),
        })
}

fn message() -> impl Strategy<Value = Message> {
    let codes = FaultCode::ALL;
    prop_oneof![
        Just(Message::Ready),
        Just(Message::End),
        rig_record().prop_map(Message::Rig),
        rig_record().prop_map(Message::Hello),
        odometry().prop_map(Message::Odometry),
        frame_report().prop_map(Message::Frame),
        any::<[u32; 10]>().prop_map(|c| Message::Stats(LinkStats {
            decoder: DecoderStats { garbage_bytes: c[1], truncated: c[2], too_long: c[3], bad_checksum: c[4], unknown_type: c[5], bad_field: c[6] },
            frame_loop: LoopStats { frames: c[0], out_of_order: c[7], frame_gaps: c[8], aborted: c[9] },
        })),
        (0usize..codes.len(), any::<u32>()).prop_map(move |(c, frame)| Message::Fault(Fault { code: codes[c], frame })),
    ]
}

/// Floats compared bit for bit (so -0.0 must stay -0.0).
fn same_bits(a: &Message, b: &Message) -> bool {
    let bits = |m: &Message| -> Vec<u64> {
        match m {
            Message::Rig(r) | Message::Hello(r) => {
                let (c, m, a) = (&r.camera, &r.mount, &r.aoi);
                let mut v: Vec<u64> = [c.fx, c.fy, c.cx, c.cy, m.height_mm, m.tilt_deg, m.roll_deg, m.yaw_deg, a.half_width_mm, a.near_mm, a.far_mm].iter().map(|x| x.to_bits()).collect();
                v.extend(c.distortion.iter().flat_map(|d| d.coefficients()).map(|x| x.to_bits()));
                v
            }
            Message::Odometry(o) => {
                let mut v = vec![o.t_s.to_bits()];
                v.extend(o.pose.iter().flat_map(|p| [p.x_mm, p.z_mm, p.yaw_deg]).map(f64::to_bits));
                v.extend(o.attitude.iter().flat_map(|a| [a.pitch_deg, a.roll_deg]).map(f64::to_bits));
                v
            }
            _ => Vec::new(),
        }
    };
    a == b && bits(a) == bits(b)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// Every message encodes to one line that decodes to the same message,
    /// also when garbage precedes it.
    #[test]
    fn protocol_round_trips(message in message(), garbage in proptest::collection::vec(any::<u8>(), 0..40)) {
        let line = encode_line(&message).expect("finite messages encode");
        let mut decoder = Decoder::new();
        for &byte in &garbage {
            let _ = decoder.push(byte);
        }
        let _ = decoder.push(b'\n'); // ends whatever the garbage started
        let decoded: Vec<_> = line.bytes().filter_map(|b| decoder.push(b)).collect();
        prop_assert_eq!(decoded.len(), 1, "{:?}", decoded);
        let decoded = decoded[0].expect("decodes");
        prop_assert!(same_bits(&decoded, &message), "{:?} != {:?}", decoded, message);
    }
}

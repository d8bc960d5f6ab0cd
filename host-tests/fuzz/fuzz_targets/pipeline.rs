//! The core pipeline on arbitrary rigs and frames: Rig::new_checked, the KG
//! grid, the remap table, streaming remap (also cut off mid-frame) and the
//! GPA detector over a few frames with arbitrary odometry and gaps.
//!
//! Numbers come mostly from scaled integers, so that valid rigs are common,
//! and any one of them can be replaced by an arbitrary f64 (NaN, inf, huge).
#![no_main]

use arbitrary::Arbitrary;
use flatland_core::geometry::{Aoi, Distortion, Intrinsics, Mount, Rig};
use flatland_core::gpa::{Gpa, GpaConfig};
use flatland_core::grid::{GridConfig, KgGrid};
use flatland_core::motion::Motion;
use flatland_core::remap::{remap_frame, Line, RemapTable, StreamingRemap};
use flatland_host::perturb::SplitMix;
use libfuzzer_sys::fuzz_target;

#[derive(Arbitrary, Debug)]
struct Input {
    /// Offsets from the flat_marks rig (all zero: that rig), see [`numbers`].
    deltas: [i16; 17],
    fixed_resolution: bool,
    distortion: Option<[i16; 5]>,
    /// Replace `numbers()[index % 15]` by a raw float (NaN, inf, huge, negative).
    raw: Option<(u8, f64)>,
    search_radius: u8,
    frames: Vec<FrameInput>,
}

#[derive(Arbitrary, Debug)]
struct FrameInput {
    /// 0 repeats the frame number, 2+ leaves a gap.
    step: u8,
    /// Odometry since the previous frame as offsets from 100 mm straight ahead
    /// (0.1 mm, 0.1 mm, 0.01 deg); None: unknown; or a raw triple.
    odometry: Option<(i16, i16, i16)>,
    raw_odometry: Option<(f64, f64, f64)>,
    /// Camera rows delivered before the source stops (None: all).
    stop_after_rows: Option<u16>,
    texture: u8,
    seed: u32,
}

/// Image size, then fx, fy, cx, cy, height_mm, tilt, AOI half width, near,
/// far, three grid margins, mm_per_px and keyframe travel. Scales are
/// multiplicative (x1/16 .. x16) so every order of magnitude is reached.
fn numbers(d: &[i16; 17]) -> (u16, u16, [f64; 15]) {
    let side = |i: usize| (256 + i32::from(d[i]) / 32).clamp(0, 1100) as u16;
    let (width, height) = (side(0), side(1));
    let times = |i: usize, base: f64| base * f64::exp2(f64::from(d[i]) / 8192.0);
    let centre = |i: usize, size: u16| {
        (f64::from(size) - 1.0) / 2.0 + f64::from(d[i]) / 32768.0 * (f64::from(size) / 2.0 + 1.0)
    };
    let values = [
        times(2, 240.0),
        times(3, 240.0),
        centre(4, width),
        centre(5, height),
        times(6, 400.0),
        32.0 + f64::from(d[7]) / 32768.0 * 60.0,
        times(8, 250.0),
        times(9, 450.0),
        times(10, 1400.0),
        150.0 + f64::from(d[11]) / 64.0,
        250.0 + f64::from(d[12]) / 64.0,
        60.0 + f64::from(d[13]) / 64.0,
        times(14, 5.0),
        times(15, 100.0),
        f64::from(d[16]),
    ];
    (width, height, values)
}

/// Pixel (u, v) of a texture; `noise` (seeded per frame) draws texture 2.
fn pixel(texture: u8, seed: u32, u: usize, v: usize, noise: &mut SplitMix) -> u8 {
    match texture % 4 {
        0 => 0,
        1 => 255,
        2 => (noise.next_u64() >> 56) as u8,
        _ => {
            let scale = seed % 6;
            if ((u >> scale) ^ (v >> scale)) & 1 == 1 {
                255
            } else {
                0
            }
        }
    }
}

fuzz_target!(|input: Input| {
    let (width, height, mut v) = numbers(&input.deltas);
    if let Some((index, raw)) = input.raw {
        v[usize::from(index) % v.len()] = raw;
    }
    let distortion = input.distortion.map(|d| {
        let c = |i: usize, scale: f64| f64::from(d[i]) / 32768.0 * scale;
        Distortion { k1: c(0, 0.5), k2: c(1, 0.2), p1: c(2, 0.01), p2: c(3, 0.01), k3: c(4, 0.05) }
    });
    let camera = Intrinsics { width, height, fx: v[0], fy: v[1], cx: v[2], cy: v[3], distortion, readout_ms: 0.0 };
    let Ok(rig) = Rig::new_checked(
        camera,
        Mount::level(v[4], v[5]),
        Aoi { half_width_mm: v[6], near_mm: v[7], far_mm: v[8] },
    ) else {
        return;
    };
    let grid_config = GridConfig {
        margin_lateral_mm: v[9],
        // Both the rig-derived far margin and a fuzzed one.
        margin_far_mm: input.fixed_resolution.then_some(v[10]),
        margin_near_mm: v[11],
        mm_per_px: input.fixed_resolution.then_some(v[12]),
        ..GridConfig::default()
    };
    let Ok(grid) = KgGrid::for_rig(&rig, &grid_config) else { return };
    assert!(grid.width() >= 1 && grid.height() >= 1);
    let Ok(table) = RemapTable::new(&rig, &grid) else { return };
    assert!(table.ring_rows() >= 1 && table.ring_rows() <= usize::from(height));
    let config = GpaConfig {
        search_radius: usize::from(input.search_radius % 5),
        keyframe_travel_mm: v[13],
        ..GpaConfig::default()
    };
    let mut keyframe = vec![0u8; Gpa::keyframe_bytes(&grid)];
    let gpa = Gpa::new(&rig, &grid, &table, config, &mut keyframe);
    let mut gpa = match gpa {
        Ok(gpa) => Some(gpa),
        Err(_) => None,
    };
    let (cw, ch) = (usize::from(width), usize::from(height));
    let mut ring = vec![0u8; table.ring_bytes()];
    let mut whole_ring = vec![0u8; table.ring_bytes()];
    let mut stream = StreamingRemap::new(&table);
    let mut line = Line::ZERO;
    let mut frame_number = 0u32;
    for (n, f) in input.frames.iter().take(5).enumerate() {
        if n > 0 {
            frame_number = frame_number.wrapping_add(u32::from(f.step % 4));
        }
        let mut noise = SplitMix::new(u64::from(f.seed));
        let image: Vec<u8> = (0..cw * ch).map(|i| pixel(f.texture, f.seed, i % cw, i / cw, &mut noise)).collect();
        let odometry = match (f.raw_odometry, f.odometry) {
            (Some((tx, tz, yaw)), _) => Some(Motion { tx_mm: tx, tz_mm: tz, dyaw_deg: yaw }),
            (None, Some((tx, tz, yaw))) => Some(Motion {
                tx_mm: f64::from(tx) / 10.0,
                tz_mm: 100.0 + f64::from(tz) / 10.0,
                dyaw_deg: f64::from(yaw) / 100.0,
            }),
            (None, None) => None,
        };
        if let Some(gpa) = gpa.as_mut() {
            gpa.begin_frame(frame_number, odometry, None);
        }
        let rows = f.stop_after_rows.map_or(ch, |r| usize::from(r) % (ch + 1));
        let mut kg = vec![0u8; grid.len()];
        let gw = grid.width();
        for camera_row in image.chunks_exact(cw).take(rows) {
            stream
                .push_row(&mut ring, camera_row, &mut line, |j, kg_row| {
                    if let Some(gpa) = gpa.as_mut() {
                        gpa.on_kg_row(j, kg_row);
                    }
                    kg[j * gw..][..gw].copy_from_slice(kg_row);
                })
                .expect("a row of the camera's width is accepted");
        }
        if rows < ch {
            // The frame source stopped mid-frame.
            stream.reset();
            if let Some(gpa) = gpa.as_mut() {
                gpa.abort_frame();
            }
            continue;
        }
        assert_eq!(stream.rows_received(), 0, "a complete frame resets the stream");
        let mut whole = vec![0u8; grid.len()];
        remap_frame(&table, &image, &mut whole_ring, &mut whole).expect("whole-frame remap");
        assert_eq!(kg, whole, "streaming and whole-frame remap differ");
        if let Some(report) = gpa.as_mut().and_then(|gpa| gpa.end_frame()) {
            assert_eq!(report.frame, frame_number);
        }
    }
});

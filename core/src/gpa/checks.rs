//! gpa's checks (host `#[test]`s and `cargo fw-test` on the emulated M4,
//! listed in [`crate::selftest`]): its `asm!` loops equal the plain
//! definitions they reproduce.

use super::keyframe::{Keyframe, LinePositions};
use super::warp::RowWarp;
use crate::grid::{KgGrid, MAX_GRID_SIDE};
use crate::selftest::{ensure, xorshift32, Outcome};

/// A line's sums at several offsets (the M4's `asm!` loop there) equal
/// those of the line moved and sampled by `sample_line`, which samples
/// every column of an offset kept: yawed and bent lines, offsets of either
/// sign, cell-like pieces of the columns.
pub fn moved_sums_equal_sampled_lines() -> Outcome {
    const WIDTH: usize = 64;
    const HEIGHT: usize = 48;
    let mut state = 0x0FF5_E701u32;
    let mut next = move |n: u32| xorshift32(&mut state) % n;
    let (mut first, mut second) = ([0u8; WIDTH * HEIGHT], [0u8; WIDTH * HEIGHT]);
    for pixel in first.iter_mut() {
        *pixel = next(256) as u8;
    }
    let mut row = [0u8; WIDTH];
    for value in row.iter_mut() {
        *value = next(256) as u8;
    }
    let grid = KgGrid { mm_per_px: 5.0, x_left_mm: -160.0, z_far_mm: 1000.0, width: WIDTH as u16, height: HEIGHT as u16 };
    let keyframe = Keyframe::new(&mut first, &mut second, &grid);
    let mut positions = LinePositions::EMPTY;
    let mut samples = [0u8; MAX_GRID_SIDE];
    let (mut kept, mut compared) = (0, 0);
    for round in 0..600 {
        // Yaw up to ~6 degrees, bends up to ~1/2000 px per column squared.
        let yaw = (f64::from(next(2001)) - 1000.0) * 1e-4;
        let (sin, cos) = libm::sincos(yaw);
        let bent = round % 3 != 0;
        let mut bend = || if bent { next(1 << 13) as i32 - (1 << 12) } else { 0 };
        let (i_bend, j_bend) = (bend(), bend());
        let line = RowWarp {
            i_start: next(12 << 16) as i32 - (4 << 16),
            i_step: (cos * 65536.0) as i32,
            i_bend,
            j_start: next(46 << 16) as i32,
            j_step: (sin * 65536.0) as i32,
            j_bend,
        };
        let start = next(8) as usize;
        let columns = start..start + 1 + next(48) as usize;
        keyframe.step_positions(line, columns.clone(), &row, &mut positions);
        let mut lines = keyframe.moved_lines::<4>(&positions);
        let mut offsets = [(0, 0); 4];
        for (key, offset) in offsets.iter_mut().enumerate() {
            *offset = (next(8 << 16) as i32 - (4 << 16), next(20 << 16) as i32 - (10 << 16));
            kept += usize::from(lines.add(key, *offset));
        }
        let mut c = columns.start;
        let mut outcome = Ok(());
        while c < columns.end {
            let piece = c..(c + 1 + next(9) as usize).min(columns.end);
            lines.sads(piece.clone(), |key, sum| {
                let (di, dj) = offsets[key];
                let sampled = keyframe.sample_line(line.moved(di, dj), columns.clone(), &mut samples);
                let want: u32 = piece.clone().map(|c| u32::from(samples[c].abs_diff(row[c]))).sum();
                if sampled != columns || sum != want {
                    outcome = Err("a moved line's sum differs from its sampled line's");
                }
                compared += piece.len();
            });
            c = piece.end;
        }
        outcome?;
    }
    ensure(kept > 600 && compared > 15_000, "too few offsets kept inside the grid")
}

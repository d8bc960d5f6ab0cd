//! Flatland on the emulated board: receives the rig and the poses on USART1,
//! reads the frames through semihosting, streams them through the KG remap
//! and reports each frame on USART1 (see PROTOCOL.md). The semihosting
//! command line sets the options
//! ([`flatland_firmware::command_line_options`]); with `bench` the run also
//! prints the stack's high-water mark and the DSP kernels' instruction
//! counts. QEMU exits with 0, or 1 if the stack reached the
//! statics.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use flatland_firmware::board::emulated::{instructions_now, EmulatedBoard};
use flatland_firmware::frame_loop::Board;
use flatland_firmware::rt::{exit, Exit};

/// The emulated watchdog's timeout. QEMU's time is the host's (without
/// `-icount`), and a frame's ~275 M instructions take a few seconds of it on
/// a busy machine, so this is far above the real board's 5 s: it catches a
/// hung loop, not a slow host.
const WATCHDOG_TIMEOUT_MS: u32 = 60_000;

#[entry]
fn main() -> ! {
    let options = flatland_firmware::command_line_options(Some(instructions_now));
    let take = || {
        let parts = EmulatedBoard::take(WATCHDOG_TIMEOUT_MS);
        Board {
            serial: parts.serial,
            alarm: parts.alarm,
            counter: parts.counter,
            frames: parts.frames,
            clock: parts.clock,
            watchdog: parts.watchdog,
        }
    };
    let stack = flatland_firmware::serve("QEMU netduinoplus2", take, &options);
    if options.bench {
        defmt::println!("bench: stack_high_water_bytes: {=usize}", stack.high_water);
        defmt::println!("bench: stack_region_bytes: {=usize}", stack.size);
        // After the stack measurement: the kernels' buffers are not the pipeline's.
        let (sad, shifts, histogram) = kernel_bench();
        let bilinear = bilinear_bench();
        let residue = residue_bench();
        defmt::println!("bench: sad_instructions_per_4_differences_x100: {=u32}", sad);
        defmt::println!("bench: shift_search_instructions_per_4_differences_x100: {=u32}", shifts);
        defmt::println!("bench: histogram_instructions_per_pixel_x100: {=u32}", histogram);
        defmt::println!("bench: bilinear_instructions_per_pixel_x100: {=u32}", bilinear);
        defmt::println!("bench: residue_instructions_per_pixel_x100: {=u32}", residue);
    }
    exit(if stack.reached_statics() { Exit::Failure } else { Exit::Success })
}

/// Kernel figures on 1024-byte blocks (call overhead included), x100:
/// instructions per 4 pixel differences of `sad` and of `sad_shifts` over
/// five shifts (the shift search's kernel), and per pixel of the histogram.
#[inline(never)]
fn kernel_bench() -> (u32, u32, u32) {
    use core::hint::black_box;
    use flatland_core::kernels;
    const N: usize = 1024;
    let mut a = [0u8; N];
    let mut b = [0u8; N + 4];
    for (n, x) in a.iter_mut().enumerate() {
        *x = (n * 37 % 251) as u8;
    }
    for (n, y) in b.iter_mut().enumerate() {
        *y = (n * 91 % 241) as u8;
    }
    let start = instructions_now();
    black_box(kernels::sad(black_box(&a), black_box(&b)));
    let sad_count = instructions_now().wrapping_sub(start);
    let mut sums = [0u32; 5];
    let start = instructions_now();
    kernels::sad_shifts(black_box(&a), black_box(&b), black_box(&mut sums));
    let shifts_count = instructions_now().wrapping_sub(start);
    black_box(&sums);
    let mut histogram = kernels::DiffHistogram::EMPTY;
    let start = instructions_now();
    black_box(&mut histogram).add(black_box(&a), black_box(&b));
    let histogram_count = instructions_now().wrapping_sub(start);
    black_box(&histogram);
    let per_4 = |instructions: u32, blocks: u32| instructions * 100 * 4 / (blocks * N as u32);
    (per_4(sad_count, 1), per_4(shifts_count, 5), histogram_count * 100 / N as u32)
}

/// Instructions per output pixel (x100) of the GPA warp's bilinear line
/// (`kernels::bilinear_line`), 1023 samples from two 1024-byte rows (call
/// overhead included). Separate from `kernel_bench` so its figures keep
/// their code.
#[inline(never)]
fn bilinear_bench() -> u32 {
    const N: usize = 1024;
    let mut upper = [0u8; N];
    let mut lower = [0u8; N];
    for (n, (x, y)) in upper.iter_mut().zip(lower.iter_mut()).enumerate() {
        *x = (n * 37 % 251) as u8;
        *y = (n * 91 % 241) as u8;
    }
    let mut line = [0u8; N - 1];
    let start = instructions_now();
    flatland_core::kernels::bilinear_line(
        core::hint::black_box(&upper),
        core::hint::black_box(&lower),
        core::hint::black_box(77),
        core::hint::black_box(201),
        core::hint::black_box(&mut line),
    );
    let instructions = instructions_now().wrapping_sub(start);
    core::hint::black_box(&line);
    instructions * 100 / (N - 1) as u32
}

/// Instructions per pixel (x100) of the tolerant residue
/// (`kernels::residues`, both residues of 1024 pixels, the halfway reach on
/// both axes; call overhead included).
#[inline(never)]
fn residue_bench() -> u32 {
    use core::hint::black_box;
    use flatland_core::kernels::{self, ResidueLines};
    const N: usize = 1024;
    let mut lines = [[0u8; N + 2]; 4];
    for (k, line) in lines.iter_mut().enumerate() {
        for (n, x) in line.iter_mut().enumerate() {
            *x = ((n * (37 + 18 * k)) % 251) as u8;
        }
    }
    let (mut hot, mut ground) = ([0u8; N], [0u8; N]);
    let [row, centre, up, down] = &lines;
    let start = instructions_now();
    kernels::residues(
        black_box(ResidueLines { row: &row[..N], centre, up: &up[..N], down: &down[..N] }),
        black_box((false, false)),
        black_box(30),
        black_box(&mut hot),
        black_box(&mut ground),
    );
    let instructions = instructions_now().wrapping_sub(start);
    black_box((&hot, &ground));
    instructions * 100 / N as u32
}

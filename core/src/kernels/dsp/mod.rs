//! Cortex-M4/M7 kernels (`thumbv7em`, cfg `flatland_dsp` from build.rs)
//! with the DSP extension through `asm!` (LLVM never emits these):
//! `usada8` adds four absolute differences in one instruction, `usub8` +
//! `sel` compare and select four bytes, `smlad` does the bilinear blends two
//! products at a time, `ldm`/`stm` copy rows. Same functions as `portable`,
//! whose versions do the tails.
//!
//! One file per kernel family:
//! - `sad`: SAD, the shift search, the seed's sums and |diff| histogram;
//! - `columns`: a cell row's residues summed per column and per cell;
//! - `bilinear`: bilinear lines and stretches;
//! - `remap`: the pinhole rows and the ring's row copy;
//! - `pyramid`: the 4x4 mean and the strongest gradients;
//! - `normal`: the direct alignment's normal equations (FPU);
//! - `blocks`: block matching's dot products per shift;
//! - `residues`: the tolerant residue.

mod bilinear;
mod blocks;
mod columns;
mod normal;
mod pyramid;
mod remap;
mod residues;
mod sad;

pub use bilinear::{bilinear_line, bilinear_stretch};
pub use blocks::dot_shifts;
pub use columns::{add_to_columns, take_pieces};
pub use normal::add_normal_terms;
pub use pyramid::{mean_4x4, strongest_gradients};
pub use remap::{copy_row, pinhole_horizontal, pinhole_vertical};
pub use residues::residues;
pub use sad::{diff_histogram, sad, sad_shifts, seed_sums, HISTOGRAM_LANES};

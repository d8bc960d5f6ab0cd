//! The KG remap: a compact fixed-point table and a streaming, row-by-row
//! remap (the PIPE-like front end of the pipeline).
//!
//! # Table layout (why it is small)
//! On flat ground a KG row (constant z) is one line of constant camera depth,
//! so an ideal pinhole maps it to one camera row `v`, with `u` affine in the
//! column. Each KG row therefore stores a start and a step in Q16.16, exact
//! up to rounding.
//!
//! With lens distortion the same structure holds one step earlier: along a
//! KG row the *undistorted normalised* coordinates are `x` affine in the
//! column and `y` constant. Each row then stores `x` start and step and `y`
//! in fixed point (Q`q`, `q` chosen per table), and the remap applies the
//! plumb_bob polynomial to them per pixel in integer arithmetic (13
//! multiplies, no division), with the lens coefficients in Q`q` as well. No
//! interpolation mesh: the only error is fixed-point rounding, and the build
//! derives a rigorous bound on it from the ranges involved
//! ([`RemapTable::error_bound_px`]), refusing the table with
//! [`TableError::LensPrecision`] if it exceeds 1/32 px (it is ~1e-4 px on
//! real lenses). An earlier design interpolated the distortion residual on a
//! 35x35 Catmull-Rom mesh; it reached 0.05-0.2 px where KG pixels are large
//! against camera pixels.
//!
//! # Crooked mounts (roll, yaw)
//! With mount roll or yaw a KG row is no longer a line of constant camera
//! row. Its camera-frame points are still affine in the column, so with
//! `w(i)` the depth relative to column 0's, `u w` and `v w` (pinhole, in
//! Q16.16 pixels) or `x w` and `y w` (lens, in Q`q`) are affine too: each row
//! stores both starts and steps and the step of `w` (Q2.30). With roll alone
//! `w` is 1 and `u`, `v` are affine along a slanted line: no division. Yaw
//! makes the depth vary along the row and costs one i64 division per
//! coordinate and pixel. The row then samples a band of camera rows (the
//! ring grows with the roll; [`RemapTable::ring_rows`]). A level mount keeps
//! the paths above bit for bit.
//!
//! 256 rows x 28 B + the lens (~100 B) = 7.3 KB for any 256x256 grid.
//!
//! # Streaming
//! [`StreamingRemap::push_row`] takes camera rows in order and emits each KG
//! row as soon as the last camera row it samples has arrived. Camera rows are
//! kept in a ring of [`RemapTable::ring_rows`] rows that the caller lends
//! each call (the pipeline lends memory that is idle while rows stream); no
//! whole frame is ever held.

use crate::geometry::{Distortion, Rig};
use crate::grid::KgGrid;
use crate::kernels::{bilinear, copy_row, pinhole, FRAC_BITS};
use crate::limits::MAX_GRID_SIDE;

mod stream;
pub use stream::{remap_frame, StreamingRemap};

const ONE: i32 = 1 << FRAC_BITS;
/// The accuracy the table guarantees (px), per the issue.
pub const ERROR_BOUND_PX: f64 = 1.0 / 32.0;
/// Fewest fractional bits the lens arithmetic may use.
const MIN_LENS_BITS: u32 = 8;
/// Most fractional bits the lens arithmetic uses (keeps products in i64).
const MAX_LENS_BITS: u32 = 30;
/// Focal lengths (px) the Q16.16 lens output supports.
const MAX_FOCAL_PX: f64 = 16384.0;
/// Fractional bits of a crooked row's relative depth `w`.
const DEPTH_BITS: u32 = 30;
/// Smallest relative depth `w` (Q2.30) a crooked row evaluates: columns whose
/// depth falls below half of column 0's are left invalid, which bounds the
/// division's error growth (a real KG row varies by a few percent).
const MIN_DEPTH: i64 = 1 << (DEPTH_BITS - 1);

/// Source of column `i` of a crooked row: numerators summed wrapping (exact
/// on valid columns, which the build checked), divided by the relative depth.
#[inline(always)]
fn crooked_point(row: &RowMap, i: usize) -> Option<(i32, i32)> {
    let nu = row.u_start.wrapping_add((i as i32).wrapping_mul(row.u_step));
    let nv = row.v.wrapping_add((i as i32).wrapping_mul(row.v_step));
    if row.w_step == 0 {
        return Some((nu, nv));
    }
    let w = (1i64 << DEPTH_BITS) + i as i64 * i64::from(row.w_step);
    if w < MIN_DEPTH {
        return None;
    }
    let u = (i64::from(nu) << DEPTH_BITS) / w;
    let v = (i64::from(nv) << DEPTH_BITS) / w;
    Some((i32::try_from(u).ok()?, i32::try_from(v).ok()?))
}

/// Why a table could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TableError {
    /// The grid is larger than [`MAX_GRID_SIDE`] on a side.
    GridTooLarge,
    /// No KG pixel is seen by the camera.
    NothingInView,
    /// The lens model does not fit the integer arithmetic within the
    /// [`ERROR_BOUND_PX`] accuracy (absurd distortion coefficients or focal
    /// lengths above 16384 px). Real lenses are far inside.
    LensPrecision,
}

impl core::fmt::Display for TableError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            TableError::GridTooLarge => "KG grid larger than 256x256",
            TableError::NothingInView => "the camera sees no KG pixel",
            TableError::LensPrecision => "lens distortion/focal length too large for the 1/32 px fixed-point remap",
        })
    }
}

impl core::error::Error for TableError {}

/// Why a streamed row was refused. The remap's state is unchanged by a refused row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RemapError {
    /// The row's length is not the camera width.
    RowLength { expected: u16, got: usize },
    /// More rows than the camera height were pushed in one frame.
    TooManyRows,
    /// The ring buffer holds fewer than [`RemapTable::ring_rows`] camera rows.
    RingTooSmall { needed: usize },
    /// The output buffer is smaller than the grid.
    OutputTooSmall,
}

impl core::fmt::Display for RemapError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RemapError::RowLength { expected, got } => {
                write!(f, "camera row has {got} pixels, expected {expected}")
            }
            RemapError::TooManyRows => f.write_str("more camera rows than the image height"),
            RemapError::RingTooSmall { needed } => write!(f, "row ring needs {needed} bytes"),
            RemapError::OutputTooSmall => f.write_str("output buffer smaller than the KG grid"),
        }
    }
}

impl core::error::Error for RemapError {}

/// One KG row: its source line plus the camera rows and columns it uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct RowMap {
    /// Without distortion: source u of column 0 and per-column step, and the
    /// source v, Q16.16 pixels. With distortion: undistorted normalised x of
    /// column 0 (wrapping: only valid columns are evaluated, and there the
    /// wrapped sum is exact) and step, and normalised y, all Q`lens.q`.
    /// A crooked mount stores `u w` / `x w` and `v w` / `y w` (module docs).
    u_start: i32,
    u_step: i32,
    v: i32,
    /// Crooked mounts: the per-column step of `v` (or `y`) times `w`, and of
    /// `w` itself (Q2.30); 0 on a level mount.
    v_step: i32,
    w_step: i32,
    /// Camera rows sampled by this KG row (inclusive).
    first_source_row: u16,
    last_source_row: u16,
    /// Columns `[valid_start, valid_end)` that the camera sees.
    valid_start: u16,
    valid_end: u16,
}

/// The plumb_bob lens in fixed point: coefficients and normalised values in
/// Q`q`, intrinsics in Q16.16.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Lens {
    q: u32,
    k1: i32,
    k2: i32,
    k3: i32,
    p1: i32,
    p2: i32,
    p1x2: i32,
    p2x2: i32,
    /// Largest r² (Q`q`) evaluated: the lens folds back beyond it.
    r2_max: i64,
    fx: i64,
    fy: i64,
    cx: i64,
    cy: i64,
}

impl Lens {
    const NONE: Lens =
        Lens { q: 0, k1: 0, k2: 0, k3: 0, p1: 0, p2: 0, p1x2: 0, p2x2: 0, r2_max: 0, fx: 0, fy: 0, cx: 0, cy: 0 };
}

/// `a * b` in Q`q` (floor).
#[inline(always)]
fn mulq(a: i32, b: i32, q: u32) -> i32 {
    ((i64::from(a) * i64::from(b)) >> q) as i32
}

/// Distorted source position (Q16.16) of undistorted normalised (x, y), Q`q`,
/// with `y2 = mulq(y, y)`. None beyond the lens's monotonic radius (not seen).
/// The build's range analysis guarantees that no intermediate overflows i32
/// once r² passed the check.
#[inline(always)]
fn lens_source(lens: &Lens, x: i32, y: i32, y2: i32) -> Option<(i64, i64)> {
    let q = lens.q;
    let x2 = (i64::from(x) * i64::from(x)) >> q;
    let r2 = x2 + i64::from(y2);
    if r2 > lens.r2_max {
        return None;
    }
    let (x2, r2) = (x2 as i32, r2 as i32);
    let radial = mulq(mulq(mulq(lens.k3, r2, q) + lens.k2, r2, q) + lens.k1, r2, q);
    let xy = mulq(x, y, q);
    let xd = x + mulq(x, radial, q) + mulq(lens.p1x2, xy, q) + mulq(lens.p2, r2 + 2 * x2, q);
    let yd = y + mulq(y, radial, q) + mulq(lens.p1, r2 + 2 * y2, q) + mulq(lens.p2x2, xy, q);
    Some((((lens.fx * i64::from(xd)) >> q) + lens.cx, ((lens.fy * i64::from(yd)) >> q) + lens.cy))
}

/// A magnitude bound and an error bound of one fixed-point quantity.
#[derive(Clone, Copy)]
struct Bound {
    magnitude: f64,
    error: f64,
}

/// Range and rounding analysis of [`lens_source`] with `q` fractional bits,
/// for |x|, |y| <= R and r² <= R² = `r2_max`: the largest intermediate
/// magnitude and the bound on the output error (px, per coordinate).
fn lens_analysis(d: &Distortion, r2_max: f64, fx: f64, fy: f64, q: u32, width: usize, crooked: bool) -> (f64, f64) {
    let ulp = 1.0 / f64::from(1u32 << q);
    let largest = core::cell::Cell::new(0.0f64);
    let note = |b: Bound| {
        largest.set(largest.get().max(b.magnitude + b.error));
        b
    };
    let mul = |a: Bound, b: Bound| Bound {
        magnitude: a.magnitude * b.magnitude,
        error: a.magnitude * b.error + b.magnitude * a.error + a.error * b.error + ulp,
    };
    let add = |a: Bound, b: Bound| Bound { magnitude: a.magnitude + b.magnitude, error: a.error + b.error };
    let coef = |c: f64| Bound { magnitude: c.abs(), error: ulp / 2.0 };
    let radius = libm::sqrt(r2_max);
    // x: start and step rounded to half an ulp each; the step is added up to `width` times.
    let affine = ulp / 2.0 * (1.0 + width as f64);
    let (x_error, y_error) = if crooked {
        // Both are affine numerators over w >= 1/2: doubled, plus the
        // division's ulp and w's own rounding (relative, times |x| <= R).
        let divided = 2.0 * affine + ulp + 2.0 * radius * (1.0 + width as f64) / f64::from(1u32 << (DEPTH_BITS + 1));
        (divided, divided)
    } else {
        (affine, ulp / 2.0)
    };
    let x = note(Bound { magnitude: radius, error: x_error });
    let y = note(Bound { magnitude: radius, error: y_error });
    let x2 = note(Bound { magnitude: r2_max, ..mul(x, x) });
    let y2 = note(Bound { magnitude: r2_max, ..mul(y, y) });
    // r² is checked against r2_max, so that is its magnitude.
    let r2 = note(Bound { magnitude: r2_max, ..add(x2, y2) });
    let h = note(add(note(mul(coef(d.k3), r2)), coef(d.k2)));
    let h = note(add(note(mul(h, r2)), coef(d.k1)));
    let radial = note(mul(h, r2));
    let xy = note(mul(x, y));
    let tx = note(add(add(r2, x2), x2));
    let ty = note(add(add(r2, y2), y2));
    let xd = note(add(add(x, note(mul(x, radial))), add(note(mul(coef(2.0 * d.p1), xy)), note(mul(coef(d.p2), tx)))));
    let yd = note(add(add(y, note(mul(y, radial))), add(note(mul(coef(d.p1), ty)), note(mul(coef(2.0 * d.p2), xy)))));
    // Output: f (Q16.16, rounded) * xd, floored to Q16.16, plus c (rounded).
    let px = |f: f64, v: Bound| f * v.error + v.magnitude / 131072.0 + 1.0 / 65536.0 + 1.0 / 131072.0;
    (largest.get(), px(fx, xd).max(px(fy, yd)))
}

/// The compact remap table for one rig and grid. About 5 KB: build it in a
/// static on the target, not on the stack.
#[derive(Clone, Debug)]
pub struct RemapTable {
    grid_width: u16,
    grid_height: u16,
    camera_width: u16,
    camera_height: u16,
    has_distortion: bool,
    /// The mount has roll or yaw: rows use [`crooked_point`].
    crooked: bool,
    ring_rows: u16,
    /// Rigorous bound on the source-coordinate error, px.
    error_bound_px: f32,
    lens: Lens,
    rows: [RowMap; MAX_GRID_SIDE],
}

fn to_fixed(value: f64) -> i32 {
    // Saturate: coordinates this far out are outside the image anyway.
    let scaled = libm::round(value * f64::from(ONE));
    scaled.clamp(f64::from(i32::MIN / 2), f64::from(i32::MAX / 2)) as i32
}

/// `value` in Q`q`, as i64 (saturating; callers range-check).
fn to_q(value: f64, q: u32) -> i64 {
    libm::round(value * f64::from(1u32 << q)) as i64
}

impl RemapTable {
    /// An empty table (all rows invalid); [`RemapTable::build`] fills it in place.
    pub const EMPTY: RemapTable = RemapTable {
        grid_width: 0,
        grid_height: 0,
        camera_width: 0,
        camera_height: 0,
        has_distortion: false,
        crooked: false,
        ring_rows: 0,
        error_bound_px: 0.0,
        lens: Lens::NONE,
        rows: [RowMap {
            u_start: 0,
            u_step: 0,
            v: 0,
            v_step: 0,
            w_step: 0,
            first_source_row: 0,
            last_source_row: 0,
            valid_start: 0,
            valid_end: 0,
        }; MAX_GRID_SIDE],
    };

    /// Builds the table in place (so a target can fill a `static` without a
    /// stack temporary).
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(a <= b)` also refuses NaN
    pub fn build(&mut self, rig: &Rig, grid: &KgGrid) -> Result<(), TableError> {
        let (width, height) = (grid.width(), grid.height());
        if width > MAX_GRID_SIDE || height > MAX_GRID_SIDE || width == 0 || height == 0 {
            return Err(TableError::GridTooLarge);
        }
        let camera = rig.camera();
        *self = RemapTable::EMPTY;
        self.grid_width = grid.width;
        self.grid_height = grid.height;
        self.camera_width = camera.width;
        self.camera_height = camera.height;
        self.has_distortion = camera.distortion.is_some();
        self.crooked = rig.mount().is_crooked();
        // Pinhole: start and step rounded to half a Q16 ulp, the step added up to `width` times.
        let affine_px = (1.0 + width as f64) / f64::from(2 * ONE);
        self.error_bound_px = if self.crooked {
            // Over w >= 1/2, plus the division's ulp and w's rounding times the largest coordinate.
            let largest_px = f64::from(camera.width.max(camera.height));
            (2.0 * affine_px + 1.0 / f64::from(ONE) + 2.0 * largest_px * (1.0 + width as f64) / f64::from(1u32 << (DEPTH_BITS + 1))) as f32
        } else {
            affine_px as f32
        };

        if let Some(d) = &camera.distortion {
            if !(camera.fx <= MAX_FOCAL_PX && camera.fy <= MAX_FOCAL_PX) {
                return Err(TableError::LensPrecision);
            }
            // Just inside the lens's own limit, so the float projection
            // agrees about every pixel the table accepts.
            let r2_max = rig.max_undistorted_radius_sq() * 0.999;
            // The most fractional bits whose intermediates stay below 2^30.
            let mut chosen = None;
            let mut q = MAX_LENS_BITS;
            while q >= MIN_LENS_BITS {
                let (largest, error) = lens_analysis(d, r2_max, camera.fx, camera.fy, q, width, self.crooked);
                if largest * f64::from(1u32 << q) < f64::from(1u32 << 30) {
                    chosen = Some((q, error));
                    break;
                }
                q -= 1;
            }
            let (q, error) = chosen.ok_or(TableError::LensPrecision)?;
            if !(error <= ERROR_BOUND_PX) {
                return Err(TableError::LensPrecision);
            }
            self.error_bound_px = error as f32;
            let c = |v: f64| to_q(v, q) as i32;
            self.lens = Lens {
                q,
                k1: c(d.k1),
                k2: c(d.k2),
                k3: c(d.k3),
                p1: c(d.p1),
                p2: c(d.p2),
                p1x2: c(2.0 * d.p1),
                p2x2: c(2.0 * d.p2),
                r2_max: to_q(r2_max, q),
                fx: i64::from(to_fixed(camera.fx)),
                fy: i64::from(to_fixed(camera.fy)),
                cx: i64::from(to_fixed(camera.cx)),
                cy: i64::from(to_fixed(camera.cy)),
            };
        }

        // Validity and source rows, from the very coordinates the remap will use.
        let max_u = i64::from((i32::from(camera.width) - 1) << FRAC_BITS);
        let max_v = i64::from((i32::from(camera.height) - 1) << FRAC_BITS);
        let mut any_valid = false;
        let mut rows_needed_through = 0u16; // camera rows that must have arrived
        let mut ring_rows = 1u16;
        for j in 0..height {
            let (x0, z) = grid.pixel_to_ground(0.0, j as f64);
            let (x1, _) = grid.pixel_to_ground(1.0, j as f64);
            // Source of column i, exactly as the remap computes it, or None.
            let mut line = (0i64, 0i64, 0i64); // lens path: x start, x step, y (Q`q`)
            // Crooked path: u (or x) w start and step, v (or y) w start and step (Q16 or Q`q`).
            let mut crooked = [0i64; 4];
            let usable = if self.crooked {
                let ((xa, ya, za), (xb, yb, zb)) = (rig.ground_to_camera(x0, z), rig.ground_to_camera(x1, z));
                if !(za > 1e-9) {
                    false
                } else {
                    let (dx, dy, dz) = (xb - xa, yb - ya, zb - za);
                    let fixed = |v: f64| if self.has_distortion { to_q(v, self.lens.q) } else { i64::from(to_fixed(v)) };
                    crooked = if self.has_distortion {
                        [fixed(xa / za), fixed(dx / za), fixed(ya / za), fixed(dy / za)]
                    } else {
                        let (fx, fy, cx, cy) = (camera.fx, camera.fy, camera.cx, camera.cy);
                        [
                            fixed(cx + fx * xa / za),
                            fixed((cx * dz + fx * dx) / za),
                            fixed(cy + fy * ya / za),
                            fixed((cy * dz + fy * dy) / za),
                        ]
                    };
                    let w_step = to_q(dz / za, DEPTH_BITS);
                    let fits = |v: i64| i32::try_from(v).is_ok();
                    let row = &mut self.rows[j];
                    // Starts wrap (see RowMap); steps must fit.
                    (row.u_start, row.u_step, row.v, row.v_step) =
                        (crooked[0] as i32, crooked[1] as i32, crooked[2] as i32, crooked[3] as i32);
                    row.w_step = w_step as i32;
                    fits(crooked[1]) && fits(crooked[3]) && fits(w_step)
                }
            } else if self.has_distortion {
                let lens = &self.lens;
                match (rig.ground_to_normalised(x0, z), rig.ground_to_normalised(x1, z)) {
                    (Some((xa, y)), Some((xb, _))) => {
                        let (start, step, y) = (to_q(xa, lens.q), to_q(xb - xa, lens.q), to_q(y, lens.q));
                        let fits = |v: i64| v.unsigned_abs() < 1 << 30;
                        line = (start, step, y);
                        fits(step) && fits(y) && (y * y) >> lens.q <= lens.r2_max
                    }
                    _ => false,
                }
            } else {
                match (rig.ground_to_undistorted_pixel(x0, z), rig.ground_to_undistorted_pixel(x1, z)) {
                    (Some(p0), Some(p1)) => {
                        let row = &mut self.rows[j];
                        row.u_start = to_fixed(p0.u);
                        row.u_step = to_fixed(p1.u - p0.u);
                        row.v = to_fixed(p0.v);
                        true
                    }
                    _ => false,
                }
            };
            if !usable {
                continue;
            }
            let (start, step, y) = line;
            let lens = self.lens;
            let y32 = y as i32;
            let y2 = mulq(y32, y32, lens.q);
            let row = self.rows[j];
            let at = |i: usize| -> Option<(i64, i64)> {
                if self.crooked {
                    // The wrapping sums are exact only where the exact ones fit.
                    let exact = |start: i64, step: i64| i32::try_from(start + step * i as i64).is_ok();
                    if !(exact(crooked[0], crooked[1]) && exact(crooked[2], crooked[3])) {
                        return None;
                    }
                    let (x, y) = crooked_point(&row, i)?;
                    if !self.has_distortion {
                        return Some((i64::from(x), i64::from(y)));
                    }
                    return lens_source(&lens, x, y, mulq(y, y, lens.q));
                }
                if self.has_distortion {
                    // Exact in i64 here; the remap's wrapping i32 sum equals it wherever it fits.
                    let x = start.saturating_add(step.saturating_mul(i as i64));
                    if x.unsigned_abs() >= 1 << 31 {
                        return None;
                    }
                    lens_source(&lens, x as i32, y32, y2)
                } else {
                    let (u, v) = Self::pinhole_source(&row, i);
                    Some((i64::from(u), i64::from(v)))
                }
            };
            // Longest run of in-image columns: inside it every sample is safe.
            let (mut best, mut run_start) = ((0usize, 0usize), None);
            for i in 0..=width {
                let inside =
                    i < width && at(i).is_some_and(|(u, v)| (0..=max_u).contains(&u) && (0..=max_v).contains(&v));
                match (inside, run_start) {
                    (true, None) => run_start = Some(i),
                    (false, Some(first)) => {
                        if i - first > best.1 - best.0 {
                            best = (first, i);
                        }
                        run_start = None;
                    }
                    _ => {}
                }
            }
            if best.1 == best.0 {
                continue;
            }
            any_valid = true;
            let (mut first, mut last) = (u16::MAX, 0u16);
            for i in best.0..best.1 {
                let (_, v) = at(i).unwrap_or((0, 0));
                let top = (v >> FRAC_BITS) as u16;
                let bottom = (top + 1).min(camera.height - 1);
                first = first.min(top);
                last = last.max(bottom);
            }
            let row = &mut self.rows[j];
            if self.has_distortion && !self.crooked {
                // Truncation to i32 wraps; see RowMap.
                row.u_start = start as i32;
                row.u_step = step as i32;
                row.v = y32;
            }
            row.valid_start = best.0 as u16;
            row.valid_end = best.1 as u16;
            row.first_source_row = first;
            row.last_source_row = last;
            rows_needed_through = rows_needed_through.max(last + 1);
            ring_rows = ring_rows.max(rows_needed_through - first);
        }
        if !any_valid {
            return Err(TableError::NothingInView);
        }
        self.ring_rows = ring_rows;
        Ok(())
    }

    /// Builds a table by value (host convenience; ~5 KB on the stack).
    pub fn new(rig: &Rig, grid: &KgGrid) -> Result<RemapTable, TableError> {
        let mut table = RemapTable::EMPTY;
        table.build(rig, grid)?;
        Ok(table)
    }

    /// Pinhole source position (Q16.16) of KG pixel `i` of a row (no distortion).
    #[inline(always)]
    fn pinhole_source(row: &RowMap, i: usize) -> (i32, i32) {
        (row.u_start.wrapping_add((i as i32).wrapping_mul(row.u_step)), row.v)
    }

    /// Source position (Q16.16) of valid KG pixel `i` of a row.
    #[inline(always)]
    fn source(&self, row: &RowMap, i: usize) -> (i32, i32) {
        if self.crooked {
            let (x, y) = crooked_point(row, i).unwrap_or((-1, -1));
            if !self.has_distortion {
                return (x, y);
            }
            let (u, v) = lens_source(&self.lens, x, y, mulq(y, y, self.lens.q)).unwrap_or((-1, -1));
            return (u as i32, v as i32);
        }
        if !self.has_distortion {
            return Self::pinhole_source(row, i);
        }
        let q = self.lens.q;
        let x = row.u_start.wrapping_add((i as i32).wrapping_mul(row.u_step));
        let (u, v) = lens_source(&self.lens, x, row.v, mulq(row.v, row.v, q)).unwrap_or((-1, -1));
        (u as i32, v as i32)
    }

    /// Source position in pixels of KG pixel (column, row), or None where the
    /// camera does not see it. This is exactly what the remap samples.
    pub fn source_pixel(&self, column: usize, row: usize) -> Option<(f64, f64)> {
        let map = self.rows.get(row).filter(|_| row < self.grid_height())?;
        if column < usize::from(map.valid_start) || column >= usize::from(map.valid_end) {
            return None;
        }
        let (u, v) = self.source(map, column);
        Some((f64::from(u) / f64::from(ONE), f64::from(v) / f64::from(ONE)))
    }

    /// A rigorous bound (px) on how far any valid pixel's source coordinate
    /// lies from the exact float projection, derived at build time from the
    /// fixed-point ranges; the build refuses tables above [`ERROR_BOUND_PX`].
    pub fn error_bound_px(&self) -> f64 {
        f64::from(self.error_bound_px)
    }

    /// Fractional bits of the lens arithmetic (0 without distortion).
    #[cfg(test)]
    fn lens_bits(&self) -> u32 {
        self.lens.q
    }

    pub fn grid_width(&self) -> usize {
        usize::from(self.grid_width)
    }
    pub fn grid_height(&self) -> usize {
        usize::from(self.grid_height)
    }
    pub fn camera_width(&self) -> usize {
        usize::from(self.camera_width)
    }
    pub fn camera_height(&self) -> usize {
        usize::from(self.camera_height)
    }
    /// Camera rows the streaming ring must hold.
    pub fn ring_rows(&self) -> usize {
        usize::from(self.ring_rows)
    }
    /// Bytes the streaming ring must hold.
    pub fn ring_bytes(&self) -> usize {
        self.ring_rows() * self.camera_width()
    }
    /// Columns of KG row `row` that the camera sees; the rest are invalid (0).
    pub fn valid_columns(&self, row: usize) -> core::ops::Range<usize> {
        match self.rows.get(row) {
            Some(map) if row < self.grid_height() => usize::from(map.valid_start)..usize::from(map.valid_end),
            _ => 0..0,
        }
    }
    /// Size of the table in bytes (what the target stores).
    pub const fn size_bytes() -> usize {
        core::mem::size_of::<RemapTable>()
    }
}

/// The pinhole path's vertical pass (2,052 bytes), lent to
/// [`StreamingRemap::push_row`]: not kept in the remap, it need live only
/// while rows stream (the firmware's frame loop keeps it out of the
/// frame's end, its deepest stack).
pub use crate::kernels::pinhole::Line;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Aoi, Distortion, Intrinsics, Mount, Rig};
    use crate::grid::GridConfig;

    /// Rigs unlike the samples: other focal lengths, fx != fy, an off-centre
    /// principal point, barrel and pincushion distortion with tangential terms.
    pub(crate) fn test_rigs() -> std::vec::Vec<Rig> {
        let mut rigs = level_rigs().to_vec();
        // Crooked mounts: roll alone (affine slanted rows), yaw alone
        // (projective rows), both, with and without a lens.
        for (n, roll_deg, yaw_deg) in [(0, 1.5, 0.0), (0, 0.0, 2.0), (1, -2.0, 1.0), (3, 1.5, -2.0), (5, -3.0, 3.0)] {
            let rig = level_rigs()[n];
            let mount = Mount { roll_deg, yaw_deg, ..*rig.mount() };
            rigs.push(Rig::new_checked(*rig.camera(), mount, *rig.aoi()).unwrap());
        }
        rigs
    }

    fn level_rigs() -> [Rig; 6] {
        let aoi = Aoi { half_width_mm: 250.0, near_mm: 450.0, far_mm: 1400.0 };
        let mount = Mount::level(400.0, 32.0);
        let camera = Intrinsics { width: 256, height: 256, fx: 240.0, fy: 240.0, cx: 127.5, cy: 127.5, distortion: None, readout_ms: 0.0 };
        let barrel = Distortion { k1: -0.30, k2: 0.09, p1: 0.0012, p2: -0.0008, k3: -0.01 };
        let pincushion = Distortion { k1: 0.12, k2: 0.02, p1: -0.001, p2: 0.0005, k3: 0.0 };
        [
            Rig::new_checked(camera, mount, aoi).unwrap(),
            Rig::new_checked(
                Intrinsics { width: 320, height: 240, fx: 277.0, fy: 277.0, cx: 159.5, cy: 119.5, distortion: None, readout_ms: 0.0 },
                Mount::level(300.0, 40.0),
                Aoi { half_width_mm: 200.0, near_mm: 300.0, far_mm: 800.0 },
            )
            .unwrap(),
            Rig::new_checked(Intrinsics { fx: 215.0, fy: 200.0, cx: 140.2, cy: 110.7, ..camera }, mount, aoi).unwrap(),
            Rig::new_checked(
                Intrinsics { width: 320, height: 240, fx: 210.0, fy: 212.0, cx: 163.0, cy: 117.0, distortion: Some(barrel), readout_ms: 0.0 },
                Mount::level(350.0, 35.0),
                Aoi { half_width_mm: 250.0, near_mm: 400.0, far_mm: 1200.0 },
            )
            .unwrap(),
            Rig::new_checked(Intrinsics { fx: 260.0, fy: 262.0, distortion: Some(pincushion), ..camera }, mount, aoi).unwrap(),
            // Small image, strong barrel, KG pixels large against camera
            // pixels: the old residual mesh missed by ~0.05-0.2 px here.
            Rig::new_checked(
                Intrinsics {
                    width: 160,
                    height: 120,
                    fx: 104.0,
                    fy: 109.0,
                    cx: 84.0,
                    cy: 57.0,
                    distortion: Some(Distortion { k1: -0.25, k2: 0.06, p1: 0.0015, p2: -0.001, k3: 0.0023 }),
                    readout_ms: 0.0,
                },
                Mount::level(300.0, 35.0),
                Aoi { half_width_mm: 150.0, near_mm: 300.0, far_mm: 900.0 },
            )
            .unwrap(),
        ]
    }

    /// Largest distance (px) between the table's source coordinate and the
    /// exact float projection, over every valid KG pixel.
    fn max_source_error(rig: &Rig, grid: &KgGrid, table: &RemapTable) -> f64 {
        let mut worst: f64 = 0.0;
        for j in 0..grid.height() {
            for i in table.valid_columns(j) {
                let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                let exact = rig.ground_to_pixel(x, z).unwrap();
                let (u, v) = table.source_pixel(i, j).unwrap();
                worst = worst.max((u - exact.u).abs()).max((v - exact.v).abs());
            }
        }
        worst
    }

    #[test]
    fn table_is_compact() {
        std::println!("remap table: {} bytes for any grid up to 256x256, with or without distortion", RemapTable::size_bytes());
        assert!(RemapTable::size_bytes() <= 16 * 1024, "{} bytes", RemapTable::size_bytes());
    }

    #[test]
    fn source_coordinates_within_a_32nd_of_a_pixel() {
        for (n, rig) in test_rigs().iter().enumerate() {
            for mm_per_px in [None, Some(5.0), Some(9.4)] {
                let grid = KgGrid::for_rig(rig, &GridConfig { mm_per_px, ..GridConfig::default() }).unwrap();
                let table = RemapTable::new(rig, &grid).unwrap();
                let error = max_source_error(rig, &grid, &table);
                let bound = table.error_bound_px();
                std::println!(
                    "rig {n} grid {}x{}: max source error {error:.5} px (build-time bound {bound:.5} px, lens Q{})",
                    grid.width,
                    grid.height,
                    table.lens_bits()
                );
                assert!(error <= 1.0 / 32.0, "rig {n}: {error} px");
                assert!(error <= bound, "rig {n}: {error} px above its bound {bound} px");
            }
        }
    }

    #[test]
    fn lens_beyond_the_fixed_point_range_is_refused() {
        // A 20,000 px focal length: Q16.16 times the lens output would overflow.
        let rig = Rig::new_checked(
            Intrinsics {
                width: 1024,
                height: 1024,
                fx: 20000.0,
                fy: 20000.0,
                cx: 511.5,
                cy: 511.5,
                distortion: Some(Distortion { k1: -0.1, k2: 0.0, p1: 0.0, p2: 0.0, k3: 0.0 }),
                readout_ms: 0.0,
            },
            Mount::level(400.0, 10.0),
            Aoi { half_width_mm: 30.0, near_mm: 2100.0, far_mm: 2450.0 },
        )
        .unwrap();
        let grid = KgGrid::for_rig(&rig, &GridConfig::default()).unwrap();
        assert_eq!(RemapTable::new(&rig, &grid).unwrap_err(), TableError::LensPrecision);
    }

    #[test]
    fn invalid_pixels_are_the_unseen_ones() {
        for rig in test_rigs().iter() {
            let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
            let table = RemapTable::new(rig, &grid).unwrap();
            let (w, h) = (f64::from(rig.camera().width) - 1.0, f64::from(rig.camera().height) - 1.0);
            for j in 0..grid.height() {
                for i in 0..grid.width() {
                    let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                    let seen = rig
                        .ground_to_pixel(x, z)
                        .is_some_and(|p| p.u > 0.05 && p.v > 0.05 && p.u < w - 0.05 && p.v < h - 0.05);
                    if seen {
                        assert!(table.valid_columns(j).contains(&i), "seen pixel ({i},{j}) marked invalid");
                    }
                }
            }
            // The AOI itself is always entirely valid.
            let aoi = grid.aoi_pixels(rig);
            for j in aoi.top..aoi.bottom {
                let valid = table.valid_columns(j);
                assert!(valid.start <= aoi.left && valid.end >= aoi.right);
            }
        }
    }

    #[test]
    fn streaming_emits_rows_early_and_matches_whole_frame() {
        for rig in test_rigs().iter() {
            let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
            let table = RemapTable::new(rig, &grid).unwrap();
            let (cw, ch) = (table.camera_width(), table.camera_height());
            let frame: std::vec::Vec<u8> = (0..cw * ch).map(|n| ((n * 7919 + n / cw * 31) % 251) as u8).collect();
            let mut ring = std::vec![0u8; table.ring_bytes()];
            let mut whole = std::vec![0u8; grid.len()];
            remap_frame(&table, &frame, &mut ring, &mut whole).unwrap();

            let mut ring = std::vec![0u8; table.ring_bytes()];
            let mut stream = StreamingRemap::new(&table);
            let mut emitted_after = std::vec![usize::MAX; grid.height()];
            let mut streamed = std::vec![0u8; grid.len()];
            let mut line = Line::ZERO;
            for (n, row) in frame.chunks_exact(cw).enumerate() {
                stream
                    .push_row(&mut ring, row, &mut line, |j, kg| {
                        emitted_after[j] = n + 1;
                        streamed[j * grid.width()..][..grid.width()].copy_from_slice(kg);
                    })
                    .unwrap();
            }
            assert_eq!(streamed, whole);
            for j in 0..grid.height() {
                let valid = table.valid_columns(j);
                if !valid.is_empty() {
                    // Emitted as soon as its last source row arrived, not later.
                    assert_eq!(emitted_after[j], usize::from(table.rows[j].last_source_row) + 1);
                }
                for i in 0..grid.width() {
                    if !valid.contains(&i) {
                        assert_eq!(whole[j * grid.width() + i], 0);
                    }
                }
            }
            assert!(table.ring_rows() < ch / 2, "ring of {} rows is not bounded", table.ring_rows());
        }
    }

    #[test]
    fn remap_matches_float_bilinear_reference() {
        for rig in [test_rigs()[3], test_rigs()[9], test_rigs()[7]] {
            let rig = &rig;
            let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
            let table = RemapTable::new(rig, &grid).unwrap();
            let (cw, ch) = (table.camera_width(), table.camera_height());
            // A smooth ramp: bilinear interpolation of it is exact, so the integer
            // remap must agree with the float projection to within rounding.
            let ramp = |u: f64, v: f64| 0.4 * u + 0.5 * v;
            let frame: std::vec::Vec<u8> =
                (0..cw * ch).map(|n| libm::round(ramp((n % cw) as f64, (n / cw) as f64)) as u8).collect();
            let mut ring = std::vec![0u8; table.ring_bytes()];
            let mut out = std::vec![0u8; grid.len()];
            remap_frame(&table, &frame, &mut ring, &mut out).unwrap();
            for j in 0..grid.height() {
                for i in table.valid_columns(j) {
                    let (x, z) = grid.pixel_to_ground(i as f64, j as f64);
                    let p = rig.ground_to_pixel(x, z).unwrap();
                    let expected = ramp(p.u, p.v);
                    let got = f64::from(out[j * grid.width() + i]);
                    // Input rounding (0.5) plus output rounding (0.5), plus the tiny source error.
                    assert!((got - expected).abs() <= 1.01, "({i},{j}): {got} vs {expected}");
                }
            }
        }
    }

    #[test]
    fn roll_widens_the_ring_and_a_small_ring_is_refused() {
        let level = &test_rigs()[0];
        let rolled = &test_rigs()[6];
        let grid = KgGrid::for_rig(level, &GridConfig::default()).unwrap();
        let (level_table, rolled_table) = (RemapTable::new(level, &grid).unwrap(), RemapTable::new(rolled, &grid).unwrap());
        std::println!("ring rows: level {}, rolled 1.5 deg {}", level_table.ring_rows(), rolled_table.ring_rows());
        assert!(rolled_table.ring_rows() > level_table.ring_rows() + 2);
        let mut ring = std::vec![0u8; level_table.ring_bytes()];
        let (row, mut line) = (std::vec![0u8; rolled_table.camera_width()], Line::ZERO);
        assert_eq!(
            StreamingRemap::new(&rolled_table).push_row(&mut ring, &row, &mut line, |_, _| {}).err(),
            Some(RemapError::RingTooSmall { needed: rolled_table.ring_bytes() })
        );
    }

    #[test]
    fn refused_rows_leave_state_unchanged() {
        let rig = &test_rigs()[0];
        let grid = KgGrid::for_rig(rig, &GridConfig::default()).unwrap();
        let table = RemapTable::new(rig, &grid).unwrap();
        let mut stream = StreamingRemap::new(&table);
        let mut line = Line::ZERO;
        let mut small = [0u8; 4];
        let row = std::vec![0u8; table.camera_width()];
        let err = stream.push_row(&mut small, &row, &mut line, |_, _| {}).unwrap_err();
        assert!(matches!(err, RemapError::RingTooSmall { .. }));
        assert_eq!(stream.rows_received(), 0);
        let mut ring = std::vec![0u8; table.ring_bytes()];
        let err = stream.push_row(&mut ring, &[0u8; 3], &mut line, |_, _| {}).unwrap_err();
        assert_eq!(err, RemapError::RowLength { expected: 256, got: 3 });
        assert_eq!(stream.rows_received(), 0);
    }
}

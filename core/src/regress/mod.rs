//! Cross-regression (Choi et al. 2024, "Online Neural Denoising with
//! Cross-Regression for Interactive Rendering") and its spatiotemporal
//! cross-bilateral filter, in f32.
//!
//! **Variance** ([`variance_rows`]): per pixel, `sum_c (y_c - m_c)^2` with `m`
//! the mean of the pixel's 3x3 neighbours inside the image, the pixel itself
//! left out (0 when it has none).
//!
//! **Cross-regression** ([`regression_rows`]): two half-sample images; the
//! features come from one (`x`, with its variance) and the fitted values
//! from the other (`y`). A centre sits on every 4th pixel in x and y
//! (`(4i, 4j)`, 1/16 of the pixels). At a centre `c`, over the 17x17 window
//! (coordinates mirrored at the image border, `-1 -> 1`), each colour channel
//! `k` is fitted separately with the design row
//! `[1, (x_i,k - x_c,k) / (s_i + s_c + 0.01), a_i,k - a_c,k, n_i - n_c (3)]`
//! (`s = sqrt(variance)`, `a` albedo, `n` normal: six columns, as in the
//! authors' code), weight `w_ci = exp(-|x_i - x_c|^2 / (v_c + v_i + 1e-4)) +
//! 1e-7`, and the normal equations `(X^T W X + 1e-3 I) b = X^T W y_k` solved
//! in place by Cholesky. A pixel `p` then blends the predictions
//! `b_c . row(p - c)` of every centre within +-8 px (inside the image) with the
//! same weight `w_cp`, and the result is clamped to `>= 0`.
//! The centres' coefficients live in a ring of five centre rows in the
//! caller's scratch ([`regression_scratch_len`]): each is solved once per
//! band, and bands give bit-identical results whatever their split.
//!
//! **Filter** ([`filter_rows`], backward [`filter_grad_rows`]): per pixel
//! six raw network outputs `r`: five bandwidths used as `k_j = 1 / (r_j^2 +
//! 1e-4)` (pilot A colour, pilot B colour, albedo, normal, pixel distance) and
//! `alpha = sigmoid(r_5)`. Over the 11x11 window (mirrored), for pilot `X`:
//! `w_i = exp(-(k_X |f_i - f_c|^2 + k_2 |a_i - a_c|^2 + k_3 |n_i - n_c|^2 +
//! k_4 |p_i - p_c|^2 / 25))`, `S_X = sum w_i f_i`, `W_X = sum w_i` (>= 1: the
//! centre weighs 1), spatial `s_X = S_X / W_X`, both combined
//! `s = (S_A + S_B) / (W_A + W_B)`. With the warped previous output `q` and
//! its validity `v` in `[0, 1]`: `a = v alpha + 1 - v`, and the outputs are
//! `a s_X + (1 - a) q` (A, B) and `a s + (1 - a) q` (combined). The backward
//! pass maps gradients of the two per-pilot outputs (what the loss sees) to
//! the six raw outputs; a gradient that overflows f32 (pilots near the
//! sanitised range's 1e20) saturates, and an undefined one is written as 0.

use crate::error::{check_scratch, check_shape, Error, Result, Shape};
use crate::math::{EXP_C, EXP_HI, EXP_LO, LN2_HI, LN2_LO, LOG2E, ROUND_MAGIC};
use crate::unfold::{check_band, check_band_rows};
use crate::view::{View, ViewMut};
use crate::Isa;

/// Regression window side (17x17).
pub const REG_WINDOW: usize = 17;
/// Half of it.
pub const REG_RADIUS: usize = REG_WINDOW / 2;
/// A centre every this many pixels in x and y.
pub const SPARSITY: usize = 4;
/// Coefficients per colour channel (design columns).
pub const COEFFS: usize = 6;
/// Ridge added to the normal equations' diagonal.
pub const RIDGE: f32 = 1e-3;
/// Filter window side (11x11).
pub const FILTER_WINDOW: usize = 11;
/// Half of it.
pub const FILTER_RADIUS: usize = FILTER_WINDOW / 2;
/// Raw network outputs the filter reads per pixel.
pub const PARAMS: usize = 6;
/// Added to `r^2` before the reciprocal that makes a bandwidth.
pub const BAND_EPS: f32 = 1e-4;

/// `e^x` with the algorithm and the values of the core's `exp` (0 below
/// `EXP_LO`, clamped at `EXP_HI`), written with integer arithmetic on the
/// rounding constant's bits instead of a float-to-int conversion (whose
/// saturating semantics keep loops from vectorising).
#[inline(always)]
pub fn exp_vec(x: f32) -> f32 {
    let valid = x >= EXP_LO;
    let xc = if valid { x } else { 0.0 };
    let xc = if xc > EXP_HI { EXP_HI } else { xc };
    let y = xc * LOG2E + ROUND_MAGIC;
    let n = y - ROUND_MAGIC;
    let r = (xc - n * LN2_HI) - n * LN2_LO;
    let mut p = EXP_C[6];
    p = p * r + EXP_C[5];
    p = p * r + EXP_C[4];
    p = p * r + EXP_C[3];
    p = p * r + EXP_C[2];
    p = p * r + EXP_C[1];
    p = p * r + EXP_C[0];
    // The low bits of `y` hold `n` in two's complement.
    let ni = y.to_bits().wrapping_sub(ROUND_MAGIC.to_bits());
    let scale = f32::from_bits(ni.wrapping_add(127) << 23);
    if valid {
        p * scale
    } else {
        0.0
    }
}

/// Index `i` mirrored into `0..n` (`-1 -> 1`, `n -> n - 2`), periodically for
/// windows wider than the image.
#[inline]
pub fn mirror(i: isize, n: usize) -> usize {
    if n <= 1 {
        return 0;
    }
    let p = 2 * (n as isize - 1);
    let m = i.rem_euclid(p);
    if m >= n as isize {
        (p - m) as usize
    } else {
        m as usize
    }
}

/// Centres along a side of `n` pixels.
pub fn centres(n: usize) -> usize {
    n.div_ceil(SPARSITY)
}

/// `k = 1 / (r^2 + 1e-4)`.
#[inline(always)]
pub fn bandwidth(r: f32) -> f32 {
    1.0 / (r * r + BAND_EPS)
}

/// `1 / (1 + e^-r)`.
#[inline(always)]
pub fn sigmoid(r: f32) -> f32 {
    1.0 / (1.0 + exp_vec(-r))
}

// ---- variance ---------------------------------------------------------------

/// The per-pixel variance estimate of `src` (3 planes) for rows `y0 ..
/// y0 + out.height()` into `out` (1 plane). It saturates at `f32::MAX`:
/// finite values beyond about 1e19 square past f32's range.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn variance_rows(isa: Isa, src: &View<'_, f32>, out: &mut ViewMut<'_, f32>, y0: usize) -> Result<()> {
    let isa = isa.check()?;
    let s = src.shape();
    if s.channels != 3 {
        return Err(Error::BadParameter { what: "variance source", expected: "3 colour planes" });
    }
    check_band("variance", Shape::new(1, s.width, s.height), out.shape(), y0)?;
    let (w, h) = (s.width, s.height);
    versions!(isa, || {
        for yo in 0..out.height() {
            let y = y0 + yo;
            let (ya, yb) = (y.saturating_sub(1), (y + 1).min(h - 1));
            for x in 0..w {
                let (xa, xb) = (x.saturating_sub(1), (x + 1).min(w - 1));
                let count = ((yb - ya + 1) * (xb - xa + 1) - 1) as f32;
                let mut v = 0.0f32;
                if count > 0.0 {
                    for c in 0..3 {
                        let centre = src.row(c, y)[x];
                        let mut sum = 0.0f32;
                        for yy in ya..=yb {
                            let r = src.row(c, yy);
                            for xx in xa..=xb {
                                sum += r[xx];
                            }
                        }
                        let m = (sum - centre) / count;
                        v += (m - centre) * (m - centre);
                    }
                }
                out.row_mut(0, yo)[x] = v.min(f32::MAX);
            }
        }
    });
    Ok(())
}

// ---- cross-regression ----------------------------------------------------------

/// The buffers of one cross-regression.
#[derive(Clone, Copy, Debug)]
pub struct RegressionInputs<'a> {
    /// The image the features and weights come from (3 planes, log colour).
    pub x: View<'a, f32>,
    /// Its per-pixel variance ([`variance_rows`], 1 plane).
    pub var: View<'a, f32>,
    /// The image whose colours are fitted (3 planes).
    pub y: View<'a, f32>,
    /// Albedo (3 planes).
    pub albedo: View<'a, f32>,
    /// Normal (3 planes).
    pub normal: View<'a, f32>,
}

impl RegressionInputs<'_> {
    fn check(&self) -> Result<Shape> {
        let s = self.x.shape();
        let three = Shape::new(3, s.width, s.height);
        check_shape("regression features", three, s)?;
        check_shape("regression variance", Shape::new(1, s.width, s.height), self.var.shape())?;
        check_shape("regression target", three, self.y.shape())?;
        check_shape("regression albedo", three, self.albedo.shape())?;
        check_shape("regression normal", three, self.normal.shape())?;
        Ok(s)
    }
}

/// Coefficients stored per centre: `COEFFS` per colour channel.
const PER_CENTRE: usize = 3 * COEFFS;
/// Centre rows a pixel row can see (`+-8` px at a spacing of 4).
const RING: usize = 2 * REG_RADIUS / SPARSITY + 1;

/// Scratch words for [`regression_rows`] on an image `width` wide.
pub fn regression_scratch_len(width: usize) -> usize {
    RING * centres(width) * PER_CENTRE
        + RING * EXPANDED * expanded_width(width)
        + 11 * width.div_ceil(LANES) * LANES
        + PHASE_VALUES * SPARSITY * phase_len(width)
}

/// Values per centre in the expanded rows: x (3), albedo (3), normal (3),
/// variance, standard deviation, the 18 coefficients, and 1 inside the image
/// (0 in the padding).
const EXPANDED: usize = 30;

/// Width of an expanded row: every centre's values repeated over its 4
/// pixels, 8 entries of padding before, whole chunks plus 8 after.
fn expanded_width(width: usize) -> usize {
    width.div_ceil(16) * 16 + 16
}

/// Centre row `j`'s values expanded along the row: entry `x + 8` holds
/// centre `x / 4`, so that the centre `x / 4 + q` of pixel `x` is entry
/// `x + 4 q + 8`, contiguous over consecutive pixels.
#[inline(always)]
fn expand_row(inp: &RegressionInputs<'_>, j: usize, coeffs: &[f32], e: &mut [f32], ew: usize) {
    let ncx = centres(inp.x.width());
    e.fill(0.0);
    for i in 0..ncx {
        let c = px(inp, j * SPARSITY, i * SPARSITY);
        let mut vals = [0.0f32; EXPANDED];
        vals[..3].copy_from_slice(&c.x);
        vals[3..6].copy_from_slice(&c.a);
        vals[6..9].copy_from_slice(&c.n);
        vals[9] = c.var;
        vals[10] = c.sd;
        vals[11..11 + PER_CENTRE].copy_from_slice(&coeffs[i * PER_CENTRE..(i + 1) * PER_CENTRE]);
        vals[EXPANDED - 1] = 1.0;
        for (v, &val) in vals.iter().enumerate() {
            let at = v * ew + 8 + SPARSITY * i;
            e[at..at + SPARSITY].fill(val);
        }
    }
}

/// Centres solved together (one AVX-512 or two AVX2 vectors).
const LANES: usize = 16;
/// 1 on the lanes of a chunk that sit on a centre column (chunks start on one).
const ON_CENTRE: [f32; LANES] = {
    let mut m = [0.0f32; LANES];
    let mut l = 0;
    while l < LANES {
        m[l] = if l % SPARSITY == 0 { 1.0 } else { 0.0 };
        l += 1;
    }
    m
};
/// Values per pixel in the phase planes: x (3), y (3), albedo (3), normal
/// (3), variance, standard deviation.
const PHASE_VALUES: usize = 14;

/// Length of a phase plane: the centres rounded up to whole lane groups and
/// 2 more on each side (the window reaches 8 px = 2 centres).
fn phase_len(width: usize) -> usize {
    centres(width).div_ceil(LANES) * LANES + 4
}

/// The 14 values of image row `sy` de-interleaved by `x mod 4` (entries `m0 .. m1`):
/// `ph[(v * 4 + p) * len + m]` is value `v` at `x = mirror(4 (m - 2) + p)`,
/// so that the pixel `4 i + dx` of centre `i` (`dx = 4 q + p`) is
/// `ph[(v * 4 + p) * len + i + q + 2]`: contiguous over consecutive centres.
#[inline(always)]
fn fill_phases(inp: &RegressionInputs<'_>, sy: usize, ph: &mut [f32], len: usize, m0: usize, m1: usize) {
    let w = inp.x.width();
    let rows: [&[f32]; PHASE_VALUES - 1] = [
        inp.x.row(0, sy),
        inp.x.row(1, sy),
        inp.x.row(2, sy),
        inp.y.row(0, sy),
        inp.y.row(1, sy),
        inp.y.row(2, sy),
        inp.albedo.row(0, sy),
        inp.albedo.row(1, sy),
        inp.albedo.row(2, sy),
        inp.normal.row(0, sy),
        inp.normal.row(1, sy),
        inp.normal.row(2, sy),
        inp.var.row(0, sy),
    ];
    let mut idx = [0usize; LANES + 4];
    let n = m1 - m0;
    for p in 0..SPARSITY {
        for (t, ix) in idx[..n].iter_mut().enumerate() {
            let x = SPARSITY as isize * ((m0 + t) as isize - 2) + p as isize;
            // One reflection covers the window's reach on images wider than it.
            *ix = if x >= 0 && (x as usize) < w { x as usize } else { mirror(x, w) };
        }
        for (v, row) in rows.iter().enumerate() {
            let dst = &mut ph[(v * SPARSITY + p) * len + m0..(v * SPARSITY + p) * len + m1];
            for (d, &x) in dst.iter_mut().zip(&idx[..n]) {
                *d = row[x];
            }
        }
        let (vars, sds) = ph.split_at_mut((PHASE_VALUES - 1) * SPARSITY * len);
        let var = &vars[(12 * SPARSITY + p) * len + m0..(12 * SPARSITY + p) * len + m1];
        let sd = &mut sds[p * len + m0..p * len + m1];
        for (d, &v) in sd.iter_mut().zip(var) {
            *d = libm::sqrtf(v.max(0.0));
        }
    }
}

/// Solves centre row `j` (all its centres) into `dst` (`ncx * PER_CENTRE`
/// words), `LANES` centres at a time. The normal equations' entries that
/// involve only the intercept and the normal columns are the same for the
/// three channels and summed once.
#[inline(always)]
fn solve_row(inp: &RegressionInputs<'_>, j: usize, dst: &mut [f32], ph: &mut [f32]) {
    let (w, h) = (inp.x.width(), inp.x.height());
    let ncx = centres(w);
    let len = phase_len(w);
    let r = REG_RADIUS as isize;
    let cy = j * SPARSITY;
    // Shared pairs among columns {0, 3, 4, 5}; per channel the pairs with 1 or 2.
    const SHARED: [(usize, usize); 10] =
        [(0, 0), (0, 3), (0, 4), (0, 5), (3, 3), (3, 4), (3, 5), (4, 4), (4, 5), (5, 5)];
    const OWN: [(usize, usize); 11] =
        [(0, 1), (0, 2), (1, 1), (1, 2), (1, 3), (1, 4), (1, 5), (2, 2), (2, 3), (2, 4), (2, 5)];
    let mut i0 = 0;
    while i0 < ncx {
        let mut c = [[0.0f32; LANES]; PHASE_VALUES];
        for l in 0..LANES {
            let cx = (i0 + l).min(ncx - 1) * SPARSITY;
            let p = px(inp, cy, cx);
            for k in 0..3 {
                c[k][l] = p.x[k];
                c[6 + k][l] = p.a[k];
                c[9 + k][l] = p.n[k];
            }
            c[12][l] = p.var;
            c[13][l] = p.sd;
        }
        let mut shared = [[0.0f32; LANES]; 10];
        let mut own = [[[0.0f32; LANES]; 11]; 3];
        let mut rhs = [[[0.0f32; LANES]; COEFFS]; 3];
        for dy in -r..=r {
            let sy = mirror(cy as isize + dy, h);
            // The part of the phase planes this lane group reads.
            fill_phases(inp, sy, ph, len, i0, i0 + LANES + 4);
            for dx in -r..=r {
                let (q, p) = (dx.div_euclid(SPARSITY as isize), dx.rem_euclid(SPARSITY as isize) as usize);
                let at = (i0 as isize + q + 2) as usize;
                // Copied out of the phase planes: values the compiler knows
                // alias nothing, so that the lane loops below vectorise.
                let v = |k: usize| -> [f32; LANES] {
                    let b = (k * SPARSITY + p) * len + at;
                    ph[b..b + LANES].try_into().expect("inside the phase plane")
                };
                let (x0, x1, x2) = (v(0), v(1), v(2));
                let (y0, y1, y2) = (v(3), v(4), v(5));
                let (a0, a1, a2) = (v(6), v(7), v(8));
                let (n0, n1, n2) = (v(9), v(10), v(11));
                let (var, sd) = (v(12), v(13));
                // Per lane: the weight and the design columns (the loops over
                // lanes are innermost so that they vectorise).
                let mut wt = [0.0f32; LANES];
                let mut inv = [0.0f32; LANES];
                let mut e = [[0.0f32; LANES]; 3];
                for l in 0..LANES {
                    e[0][l] = x0[l] - c[0][l];
                    e[1][l] = x1[l] - c[1][l];
                    e[2][l] = x2[l] - c[2][l];
                    let d2 = e[0][l] * e[0][l] + e[1][l] * e[1][l] + e[2][l] * e[2][l];
                    wt[l] = exp_vec(-d2 / (c[12][l] + var[l] + 1e-4)) + 1e-7;
                    inv[l] = 1.0 / (c[13][l] + sd[l] + 0.01);
                }
                // Columns: 0 ones, 1-2 per channel, 3-5 the normal differences.
                let mut col = [[0.0f32; LANES]; 6];
                col[0] = [1.0; LANES];
                for l in 0..LANES {
                    col[3][l] = n0[l] - c[9][l];
                    col[4][l] = n1[l] - c[10][l];
                    col[5][l] = n2[l] - c[11][l];
                }
                let mut wc = [[0.0f32; LANES]; 6];
                for pp in [0, 3, 4, 5] {
                    for l in 0..LANES {
                        wc[pp][l] = wt[l] * col[pp][l];
                    }
                }
                for (t, &(a, b)) in SHARED.iter().enumerate() {
                    for l in 0..LANES {
                        shared[t][l] += wc[a][l] * col[b][l];
                    }
                }
                let ys = [&y0, &y1, &y2];
                let als = [&a0, &a1, &a2];
                for k in 0..3 {
                    for l in 0..LANES {
                        col[1][l] = e[k][l] * inv[l];
                        col[2][l] = als[k][l] - c[6 + k][l];
                        wc[1][l] = wt[l] * col[1][l];
                        wc[2][l] = wt[l] * col[2][l];
                    }
                    for (t, &(a, b)) in OWN.iter().enumerate() {
                        for l in 0..LANES {
                            own[k][t][l] += wc[a][l] * col[b][l];
                        }
                    }
                    let yk: [f32; LANES] = *ys[k];
                    for pp in 0..COEFFS {
                        for l in 0..LANES {
                            rhs[k][pp][l] += wc[pp][l] * yk[l];
                        }
                    }
                }
            }
        }
        for l in 0..LANES.min(ncx - i0) {
            let out = &mut dst[(i0 + l) * PER_CENTRE..(i0 + l + 1) * PER_CENTRE];
            for k in 0..3 {
                let mut a = [0.0f32; COEFFS * COEFFS];
                for (t, &(p, q)) in SHARED.iter().enumerate() {
                    a[p * COEFFS + q] = shared[t][l];
                }
                for (t, &(p, q)) in OWN.iter().enumerate() {
                    a[p * COEFFS + q] = own[k][t][l];
                }
                let rk: [f32; COEFFS] = core::array::from_fn(|pp| rhs[k][pp][l]);
                let b = solve(&mut a, &rk);
                out[k * COEFFS..(k + 1) * COEFFS].copy_from_slice(&b);
            }
        }
        i0 += LANES;
    }
}

/// One pixel's values the regression reads.
#[derive(Clone, Copy)]
struct Px {
    x: [f32; 3],
    a: [f32; 3],
    n: [f32; 3],
    var: f32,
    sd: f32,
}

#[inline(always)]
fn px(inp: &RegressionInputs<'_>, y: usize, x: usize) -> Px {
    let var = inp.var.row(0, y)[x];
    Px {
        x: [inp.x.row(0, y)[x], inp.x.row(1, y)[x], inp.x.row(2, y)[x]],
        a: [inp.albedo.row(0, y)[x], inp.albedo.row(1, y)[x], inp.albedo.row(2, y)[x]],
        n: [inp.normal.row(0, y)[x], inp.normal.row(1, y)[x], inp.normal.row(2, y)[x]],
        var,
        sd: libm::sqrtf(var.max(0.0)),
    }
}

/// Solves `(A + RIDGE I) b = r` for a symmetric positive `A` (upper triangle
/// given, row-major) by Cholesky in place.
#[inline(always)]
fn solve(a: &mut [f32; COEFFS * COEFFS], r: &[f32; COEFFS]) -> [f32; COEFFS] {
    const P: usize = COEFFS;
    for i in 0..P {
        a[i * P + i] += RIDGE;
        for j in 0..i {
            a[i * P + j] = a[j * P + i];
        }
    }
    // L in the lower triangle (a pivot that rounding made non-positive is
    // floored, as the authors' code does).
    for i in 0..P {
        for j in 0..=i {
            let mut s = a[i * P + j];
            for k in 0..j {
                s -= a[i * P + k] * a[j * P + k];
            }
            a[i * P + j] = if i == j { libm::sqrtf(s.max(1e-5)) } else { s / a[j * P + j] };
        }
    }
    let mut z = [0.0f32; P];
    for i in 0..P {
        let mut s = r[i];
        for k in 0..i {
            s -= a[i * P + k] * z[k];
        }
        z[i] = s / a[i * P + i];
    }
    let mut b = [0.0f32; P];
    for i in (0..P).rev() {
        let mut s = z[i];
        for k in i + 1..P {
            s -= a[k * P + i] * b[k];
        }
        b[i] = s / a[i * P + i];
    }
    if b.iter().all(|v| v.is_finite()) {
        b
    } else {
        [0.0; P]
    }
}

/// The cross-regression's pilot estimate for rows `y0 .. y0 + out.height()`
/// into `out` (3 planes): centres solved on demand into a ring in `scratch`
/// ([`regression_scratch_len`]), then every pixel blended from the centres
/// within +-8 px.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above; [`Error::ScratchTooSmall`] when `scratch` is shorter than this operator's
/// `*_scratch_len`.
pub fn regression_rows(
    isa: Isa,
    inp: &RegressionInputs<'_>,
    out: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let isa = isa.check()?;
    let s = inp.check()?;
    check_band("regression output", s, out.shape(), y0)?;
    let w = s.width;
    let ncx = centres(w);
    let row_len = ncx * PER_CENTRE;
    check_scratch(regression_scratch_len(w), scratch.len())?;
    if out.height() == 0 || w == 0 {
        return Ok(());
    }
    let ew = expanded_width(w);
    let pwid = w.div_ceil(LANES) * LANES;
    let (ring, rest) = scratch.split_at_mut(RING * row_len);
    let (exp_ring, rest) = rest.split_at_mut(RING * EXPANDED * ew);
    let (pix, ph) = rest.split_at_mut(11 * pwid);
    let bufs = RegressionScratch { ring, exp_ring, pix, ph };
    let args = (inp, out, y0, bufs, ew, pwid);
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a checked token: this CPU runs AVX-512.
        Isa::Avx512 => unsafe { regression_avx512(args) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above, AVX2 and FMA.
        Isa::Avx2 => unsafe { regression_avx2(args) },
        _ => regression_body(args),
    }
    Ok(())
}

/// The scratch areas of [`regression_rows`].
struct RegressionScratch<'s> {
    ring: &'s mut [f32],
    exp_ring: &'s mut [f32],
    pix: &'s mut [f32],
    ph: &'s mut [f32],
}

type RegressionArgs<'a, 'b, 'c, 's> =
    (&'a RegressionInputs<'b>, &'a mut ViewMut<'c, f32>, usize, RegressionScratch<'s>, usize, usize);

// The body is one large function: compiled once per instruction set through
// these wrappers (a closure this size would not be inlined into them).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn regression_avx512(args: RegressionArgs<'_, '_, '_, '_>) {
    regression_body(args)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn regression_avx2(args: RegressionArgs<'_, '_, '_, '_>) {
    regression_body(args)
}

#[inline(always)]
fn regression_body(args: RegressionArgs<'_, '_, '_, '_>) {
    let (inp, out, y0, bufs, ew, pwid) = args;
    let RegressionScratch { ring, exp_ring, pix, ph } = bufs;
    let (w, h) = (inp.x.width(), inp.x.height());
    let ncx = centres(w);
    let ncy = centres(h);
    let row_len = ncx * PER_CENTRE;
    let mut held = [usize::MAX; RING];
    let r = REG_RADIUS as isize;
    for yo in 0..out.height() {
        let y = y0 + yo;
        // Centre rows j with |4j - y| <= 8, inside the image.
        let jlo = (y as isize - r).max(0) as usize;
        let jlo = jlo.div_ceil(SPARSITY);
        let jhi = ((y + REG_RADIUS) / SPARSITY).min(ncy - 1);
        for j in jlo..=jhi {
            let slot = j % RING;
            if held[slot] != j {
                let coeffs = &mut ring[slot * row_len..(slot + 1) * row_len];
                solve_row(inp, j, coeffs, ph);
                expand_row(inp, j, coeffs, &mut exp_ring[slot * EXPANDED * ew..(slot + 1) * EXPANDED * ew], ew);
                held[slot] = j;
            }
        }
        // This row's pixel values, padded to whole chunks.
        for (v, plane) in [
            inp.x.row(0, y),
            inp.x.row(1, y),
            inp.x.row(2, y),
            inp.albedo.row(0, y),
            inp.albedo.row(1, y),
            inp.albedo.row(2, y),
            inp.normal.row(0, y),
            inp.normal.row(1, y),
            inp.normal.row(2, y),
            inp.var.row(0, y),
        ]
        .into_iter()
        .enumerate()
        {
            let dst = &mut pix[v * pwid..(v + 1) * pwid];
            dst[..w].copy_from_slice(plane);
            dst[w..].fill(0.0);
        }
        {
            let (vars, sds) = pix[9 * pwid..11 * pwid].split_at_mut(pwid);
            for (sd, &v) in sds.iter_mut().zip(vars.iter()) {
                *sd = libm::sqrtf(v.max(0.0));
            }
        }
        let mut x0 = 0;
        while x0 < w {
            let pv = |v: usize| -> &[f32; LANES] {
                pix[v * pwid + x0..v * pwid + x0 + LANES].try_into().expect("inside the padded row")
            };
            let mut acc = [[0.0f32; LANES]; 3];
            let mut wsum = [0.0f32; LANES];
            for j in jlo..=jhi {
                let e = &exp_ring[(j % RING) * EXPANDED * ew..];
                for q in -2isize..=2 {
                    let at = (x0 as isize + 4 * q + 8) as usize;
                    let ev = |v: usize| -> &[f32; LANES] {
                        e[v * ew + at..v * ew + at + LANES].try_into().expect("inside the expanded row")
                    };
                    let valid = ev(EXPANDED - 1);
                    // q = -2 reaches 8 px only from pixels on a centre column
                    // (x0 is a multiple of 4): a 0/1 factor per lane keeps
                    // the loop free of branches, so that it vectorises.
                    let near: &[f32; LANES] = if q == -2 { &ON_CENTRE } else { &[1.0; LANES] };
                    // Every row the lane loops read, bound before them (no
                    // bounds checks inside: the loops vectorise).
                    let (p0, p1, p2) = (pv(0), pv(1), pv(2));
                    let (e0, e1, e2) = (ev(0), ev(1), ev(2));
                    let (pvar, evar, psd, esd) = (pv(9), ev(9), pv(10), ev(10));
                    let mut wt = [0.0f32; LANES];
                    let mut inv = [0.0f32; LANES];
                    for l in 0..LANES {
                        let (t0, t1, t2) = (p0[l] - e0[l], p1[l] - e1[l], p2[l] - e2[l]);
                        let d = t0 * t0 + t1 * t1 + t2 * t2;
                        let wgt = exp_vec(-d / (evar[l] + pvar[l] + 1e-4)) + 1e-7;
                        wt[l] = near[l] * valid[l] * wgt;
                        inv[l] = 1.0 / (esd[l] + psd[l] + 0.01);
                    }
                    for l in 0..LANES {
                        wsum[l] += wt[l];
                    }
                    let (pn0, pn1, pn2) = (pv(6), pv(7), pv(8));
                    let (en0, en1, en2) = (ev(6), ev(7), ev(8));
                    for k in 0..3 {
                        let b: [&[f32; LANES]; COEFFS] = core::array::from_fn(|t| ev(11 + k * COEFFS + t));
                        let (pk, ek, pa, ea) = (pv(k), ev(k), pv(3 + k), ev(3 + k));
                        let ak = &mut acc[k];
                        for l in 0..LANES {
                            let mut pred = 0.0f32;
                            pred += b[0][l] * 1.0;
                            pred += b[1][l] * ((pk[l] - ek[l]) * inv[l]);
                            pred += b[2][l] * (pa[l] - ea[l]);
                            pred += b[3][l] * (pn0[l] - en0[l]);
                            pred += b[4][l] * (pn1[l] - en1[l]);
                            pred += b[5][l] * (pn2[l] - en2[l]);
                            ak[l] += wt[l] * pred;
                        }
                    }
                }
            }
            for l in 0..LANES.min(w - x0) {
                let inv = 1.0 / wsum[l].max(1e-7);
                for k in 0..3 {
                    out.row_mut(k, yo)[x0 + l] = (acc[k][l] * inv).max(0.0);
                }
            }
            x0 += LANES;
        }
    }
}

// ---- spatiotemporal filter ----------------------------------------------------------

/// The buffers of the spatiotemporal filter (all full-frame).
#[derive(Clone, Copy, Debug)]
pub struct FilterInputs<'a> {
    /// Pilot estimate A (3 planes).
    pub pilot_a: View<'a, f32>,
    /// Pilot estimate B (3 planes).
    pub pilot_b: View<'a, f32>,
    /// Albedo (3 planes).
    pub albedo: View<'a, f32>,
    /// Normal (3 planes).
    pub normal: View<'a, f32>,
    /// The warped previous output (3 planes).
    pub prev: View<'a, f32>,
    /// Its validity in `[0, 1]` (1 plane; 0: no history, the spatial result alone).
    pub valid: View<'a, f32>,
}

impl FilterInputs<'_> {
    fn check(&self) -> Result<Shape> {
        let s = self.pilot_a.shape();
        let three = Shape::new(3, s.width, s.height);
        check_shape("filter pilot A", three, s)?;
        check_shape("filter pilot B", three, self.pilot_b.shape())?;
        check_shape("filter albedo", three, self.albedo.shape())?;
        check_shape("filter normal", three, self.normal.shape())?;
        check_shape("filter previous output", three, self.prev.shape())?;
        check_shape("filter validity", Shape::new(1, s.width, s.height), self.valid.shape())?;
        Ok(s)
    }
}

/// Guide planes copied per window row: pilot A, pilot B, albedo, normal.
const GUIDES: usize = 12;
/// Pixels per chunk: every per-pixel quantity of a chunk is a fixed-size
/// array, so that the window loop runs at a constant trip count with no
/// bounds checks and vectorises across pixels (one AVX-512 or two AVX2
/// vectors; the accumulators can stay in registers).
const CHUNK: usize = 16;

/// Padded width of a guide row in the scratch: the image rounded up to whole
/// chunks, plus the window's halo on each side.
fn padded_width(width: usize) -> usize {
    width.div_ceil(CHUNK) * CHUNK + 2 * FILTER_RADIUS
}

/// Scratch words for [`filter_rows`] and [`filter_grad_rows`] on an image
/// `width` wide: the 11 window rows of the 12 guide planes, mirrored and
/// padded by 5 on each side.
pub fn filter_scratch_len(width: usize) -> usize {
    FILTER_WINDOW * GUIDES * padded_width(width)
}

/// Copies the mirrored window rows of output row `y` into `rows`.
fn fill_rows(inp: &FilterInputs<'_>, y: usize, rows: &mut [f32]) {
    let (w, h) = (inp.pilot_a.width(), inp.pilot_a.height());
    let pw = padded_width(w);
    let r = FILTER_RADIUS as isize;
    for (t, dy) in (-r..=r).enumerate() {
        let sy = mirror(y as isize + dy, h);
        for g in 0..GUIDES {
            let src = match g / 3 {
                0 => inp.pilot_a.row(g % 3, sy),
                1 => inp.pilot_b.row(g % 3, sy),
                2 => inp.albedo.row(g % 3, sy),
                _ => inp.normal.row(g % 3, sy),
            };
            let dst = &mut rows[(t * GUIDES + g) * pw..(t * GUIDES + g + 1) * pw];
            dst[FILTER_RADIUS..FILTER_RADIUS + w].copy_from_slice(src);
            for i in 0..FILTER_RADIUS {
                dst[i] = src[mirror(i as isize - r, w)];
                dst[FILTER_RADIUS + w + i] = src[mirror((w + i) as isize, w)];
            }
            // The last chunk's lanes past the image: finite, never written out.
            dst[2 * FILTER_RADIUS + w..].fill(0.0);
        }
    }
}

/// Window sums of one chunk: `S_A (3), W_A, S_B (3), W_B` (the backward
/// pass sums `w (f_i - f_c)` instead of `w f_i`) and, for the
/// backward pass, per pilot `T_j = sum w D_j (g . (f_i - f_c))` and `U_j = sum w D_j`
/// for the four terms `j` (own colour, albedo, normal, distance).
struct Sums {
    s: [[f32; CHUNK]; 8],
    t: [[f32; CHUNK]; 16],
}

/// Runs the window over one chunk of row `y` (pixels `x0 .. x0 + CHUNK`;
/// lanes past the image compute on padding and are ignored).
#[inline(always)]
fn window<const GRAD: bool>(
    rows: &[f32],
    pw: usize,
    x0: usize,
    k: &[[f32; CHUNK]; 5],
    g: &[[f32; CHUNK]; 6],
    sums: &mut Sums,
) {
    let r = FILTER_RADIUS as isize;
    let span = |base: usize, gd: usize, u: usize| -> &[f32; CHUNK] {
        let at = base + gd * pw + x0 + u;
        rows[at..at + CHUNK].try_into().expect("a chunk inside the padded row")
    };
    let mut c = [[0.0f32; CHUNK]; GUIDES];
    for (gd, cg) in c.iter_mut().enumerate() {
        *cg = *span(FILTER_RADIUS * GUIDES * pw, gd, FILTER_RADIUS);
    }
    let mut s = [[0.0f32; CHUNK]; 8];
    let mut t = [[0.0f32; CHUNK]; 16];
    for (ti, dy) in (-r..=r).enumerate() {
        let base = ti * GUIDES * pw;
        for (u, dx) in (-r..=r).enumerate() {
            let pd = ((dx * dx + dy * dy) as f32) / ((FILTER_RADIUS * FILTER_RADIUS) as f32);
            let (a0, a1, a2) = (span(base, 0, u), span(base, 1, u), span(base, 2, u));
            let (b0, b1, b2) = (span(base, 3, u), span(base, 4, u), span(base, 5, u));
            let (l0, l1, l2) = (span(base, 6, u), span(base, 7, u), span(base, 8, u));
            let (n0, n1, n2) = (span(base, 9, u), span(base, 10, u), span(base, 11, u));
            for i in 0..CHUNK {
                let sq = |v: f32| v * v;
                let (ea0, ea1, ea2) = (a0[i] - c[0][i], a1[i] - c[1][i], a2[i] - c[2][i]);
                let (eb0, eb1, eb2) = (b0[i] - c[3][i], b1[i] - c[4][i], b2[i] - c[5][i]);
                let da = sq(ea0) + sq(ea1) + sq(ea2);
                let db = sq(eb0) + sq(eb1) + sq(eb2);
                let dl = sq(l0[i] - c[6][i]) + sq(l1[i] - c[7][i]) + sq(l2[i] - c[8][i]);
                let dn = sq(n0[i] - c[9][i]) + sq(n1[i] - c[10][i]) + sq(n2[i] - c[11][i]);
                let common = k[2][i] * dl + k[3][i] * dn + k[4][i] * pd;
                let wa = exp_vec(-(k[0][i] * da + common));
                let wb = exp_vec(-(k[1][i] * db + common));
                if GRAD {
                    // Relative to the centre (the backward pass needs s - f_c).
                    s[0][i] += wa * ea0;
                    s[1][i] += wa * ea1;
                    s[2][i] += wa * ea2;
                    s[4][i] += wb * eb0;
                    s[5][i] += wb * eb1;
                    s[6][i] += wb * eb2;
                } else {
                    s[0][i] += wa * a0[i];
                    s[1][i] += wa * a1[i];
                    s[2][i] += wa * a2[i];
                    s[4][i] += wb * b0[i];
                    s[5][i] += wb * b1[i];
                    s[6][i] += wb * b2[i];
                }
                s[3][i] += wa;
                s[7][i] += wb;
                if GRAD {
                    // g . (f_i - f_c): relative to the centre, so that a flat
                    // window cancels exactly.
                    let gfa = g[0][i] * ea0 + g[1][i] * ea1 + g[2][i] * ea2;
                    let gfb = g[3][i] * eb0 + g[4][i] * eb1 + g[5][i] * eb2;
                    let (wda, wdb) = (wa * da, wb * db);
                    let (wla, wna, wpa) = (wa * dl, wa * dn, wa * pd);
                    let (wlb, wnb, wpb) = (wb * dl, wb * dn, wb * pd);
                    t[0][i] += wda * gfa;
                    t[1][i] += wla * gfa;
                    t[2][i] += wna * gfa;
                    t[3][i] += wpa * gfa;
                    t[4][i] += wda;
                    t[5][i] += wla;
                    t[6][i] += wna;
                    t[7][i] += wpa;
                    t[8][i] += wdb * gfb;
                    t[9][i] += wlb * gfb;
                    t[10][i] += wnb * gfb;
                    t[11][i] += wpb * gfb;
                    t[12][i] += wdb;
                    t[13][i] += wlb;
                    t[14][i] += wnb;
                    t[15][i] += wpb;
                }
            }
        }
    }
    sums.s = s;
    if GRAD {
        sums.t = t;
    }
}

/// A gradient as written: values past f32's range saturate to `±f32::MAX`,
/// and an undefined one (NaN: terms that overflowed to infinities of both
/// signs, or met a weight of 0) is 0. Its terms grow with the cube of colour
/// differences, so pilots within the host's sanitised range (up to 1e20)
/// overflow where a real render's never do; the contract is a finite
/// gradient, and a training step treats it like any other.
#[inline(always)]
fn saturate(v: f32) -> f32 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(-f32::MAX, f32::MAX)
    }
}

fn check_params(what: &'static str, s: Shape, v: Shape, y0: usize, c: usize) -> Result<()> {
    check_band(what, Shape::new(c, s.width, s.height), v, y0)
}

/// The filter for rows `y0 .. y0 + out.height()`: `params` holds the six raw
/// network outputs of those rows, `out` gets 9 planes (output A, output B,
/// combined output). `scratch`: [`filter_scratch_len`].
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above; [`Error::ScratchTooSmall`] when `scratch` is shorter than this operator's
/// `*_scratch_len`.
pub fn filter_rows(
    isa: Isa,
    inp: &FilterInputs<'_>,
    params: &View<'_, f32>,
    out: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let isa = isa.check()?;
    let s = inp.check()?;
    check_params("filter parameters", s, params.shape(), y0, PARAMS)?;
    check_band_rows("filter output", Shape::new(9, s.width, s.height), out.shape(), y0, params.height())?;
    check_scratch(filter_scratch_len(s.width), scratch.len())?;
    let w = s.width;
    if w == 0 {
        // Rows of no pixels: nothing to write (and no window rows to mirror).
        return Ok(());
    }
    let pw = padded_width(w);
    versions!(isa, || {
        let mut sums = Sums { s: [[0.0; CHUNK]; 8], t: [[0.0; CHUNK]; 16] };
        let g = [[0.0f32; CHUNK]; 6];
        for yo in 0..out.height() {
            let y = y0 + yo;
            fill_rows(inp, y, scratch);
            let mut x0 = 0;
            while x0 < w {
                let n = CHUNK.min(w - x0);
                let mut k = [[0.0f32; CHUNK]; 5];
                for (j, kj) in k.iter_mut().enumerate() {
                    let r = &params.row(j, yo)[x0..x0 + n];
                    for i in 0..n {
                        kj[i] = bandwidth(r[i]);
                    }
                }
                window::<false>(scratch, pw, x0, &k, &g, &mut sums);
                for i in 0..n {
                    let x = x0 + i;
                    let alpha = sigmoid(params.row(5, yo)[x]);
                    let v = inp.valid.row(0, y)[x];
                    let a = v * alpha + (1.0 - v);
                    let (wa, wb) = (sums.s[3][i], sums.s[7][i]);
                    let (ia, ib, iab) = (1.0 / wa, 1.0 / wb, 1.0 / (wa + wb));
                    for ch in 0..3 {
                        let q = inp.prev.row(ch, y)[x];
                        let (sa, sb) = (sums.s[ch][i], sums.s[4 + ch][i]);
                        out.row_mut(ch, yo)[x] = a * (sa * ia) + (1.0 - a) * q;
                        out.row_mut(3 + ch, yo)[x] = a * (sb * ib) + (1.0 - a) * q;
                        out.row_mut(6 + ch, yo)[x] = a * ((sa + sb) * iab) + (1.0 - a) * q;
                    }
                }
                x0 += n;
            }
        }
    });
    Ok(())
}

/// The filter's backward pass for rows `y0 .. y0 + dparams.height()`:
/// `grad` holds the loss's gradients of output A and output B (6 planes) of
/// those rows, `dparams` gets the gradients of the six raw outputs.
/// `scratch`: [`filter_scratch_len`].
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above; [`Error::ScratchTooSmall`] when `scratch` is shorter than this operator's
/// `*_scratch_len`.
pub fn filter_grad_rows(
    isa: Isa,
    inp: &FilterInputs<'_>,
    params: &View<'_, f32>,
    grad: &View<'_, f32>,
    dparams: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let isa = isa.check()?;
    let s = inp.check()?;
    check_params("filter parameters", s, params.shape(), y0, PARAMS)?;
    check_params("filter output gradient", s, grad.shape(), y0, 6)?;
    check_params("filter parameter gradient", s, dparams.shape(), y0, PARAMS)?;
    if params.height() != dparams.height() || grad.height() != dparams.height() {
        return Err(Error::BadParameter {
            what: "filter gradient bands",
            expected: "parameters, output gradient and parameter gradient of the same rows",
        });
    }
    check_scratch(filter_scratch_len(s.width), scratch.len())?;
    let w = s.width;
    if w == 0 {
        // Rows of no pixels: nothing to write (and no window rows to mirror).
        return Ok(());
    }
    let pw = padded_width(w);
    versions!(isa, || {
        let mut sums = Sums { s: [[0.0; CHUNK]; 8], t: [[0.0; CHUNK]; 16] };
        for yo in 0..dparams.height() {
            let y = y0 + yo;
            fill_rows(inp, y, scratch);
            let mut x0 = 0;
            while x0 < w {
                let n = CHUNK.min(w - x0);
                let mut k = [[0.0f32; CHUNK]; 5];
                for (j, kj) in k.iter_mut().enumerate() {
                    let r = &params.row(j, yo)[x0..x0 + n];
                    for i in 0..n {
                        kj[i] = bandwidth(r[i]);
                    }
                }
                let mut g = [[0.0f32; CHUNK]; 6];
                for (j, gj) in g.iter_mut().enumerate() {
                    gj[..n].copy_from_slice(&grad.row(j, yo)[x0..x0 + n]);
                }
                window::<true>(scratch, pw, x0, &k, &g, &mut sums);
                for i in 0..n {
                    let x = x0 + i;
                    let r5 = params.row(5, yo)[x];
                    let alpha = sigmoid(r5);
                    let v = inp.valid.row(0, y)[x];
                    let a = v * alpha + (1.0 - v);
                    let (wa, wb) = (sums.s[3][i], sums.s[7][i]);
                    let (ia, ib) = (1.0 / wa, 1.0 / wb);
                    // g . (s_X - f_c) and g . (s_X - q) per pilot.
                    let (mut gsa, mut gsb, mut da) = (0.0f32, 0.0f32, 0.0f32);
                    for ch in 0..3 {
                        let q = inp.prev.row(ch, y)[x];
                        // s_X - f_c from the centred sums.
                        let (ra, rb) = (sums.s[ch][i] * ia, sums.s[4 + ch][i] * ib);
                        gsa += g[ch][i] * ra;
                        gsb += g[3 + ch][i] * rb;
                        let (sa, sb) = (inp.pilot_a.row(ch, y)[x] + ra, inp.pilot_b.row(ch, y)[x] + rb);
                        da += g[ch][i] * (sa - q) + g[3 + ch][i] * (sb - q);
                    }
                    // dL/dk_j = -(a / W_X) (T_j - (g . (s_X - f_c)) U_j), summed over the pilots using k_j.
                    let ta = |j: usize| -(a * ia) * (sums.t[j][i] - gsa * sums.t[4 + j][i]);
                    let tb = |j: usize| -(a * ib) * (sums.t[8 + j][i] - gsb * sums.t[12 + j][i]);
                    let dk = [ta(0), tb(0), ta(1) + tb(1), ta(2) + tb(2), ta(3) + tb(3)];
                    for j in 0..5 {
                        let r = params.row(j, yo)[x];
                        let kj = k[j][i];
                        dparams.row_mut(j, yo)[x] = saturate(dk[j] * (-2.0 * r * kj * kj));
                    }
                    dparams.row_mut(5, yo)[x] = saturate(da * v * alpha * (1.0 - alpha));
                }
                x0 += n;
            }
        }
    });
    Ok(())
}

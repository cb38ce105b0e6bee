//! Backward passes of the pools, the upsamplers and the scale compositor
//! (f32), and the bilinear 2x upsample (forward and backward).
//!
//! Images are `W x H` (fine) and `ceil(W/2) x ceil(H/2)` (coarse); a 2x2
//! cell holds the in-image pixels of fine rows `2Y, 2Y + 1` and columns
//! `2X, 2X + 1` (one or two at an odd border). Every function writes a band
//! of its output rows (`y0 ..`) from whole inputs, each output from its
//! position alone, so bands compose and threads do not change the result.
//! Gathers only (no scatter), so there is nothing to accumulate across
//! bands.
//!
//! - [`avg_pool2x2_grad`]: `dx(p) = dy(cell) / n(cell)`;
//! - [`max_pool2x2_grad`]: `dy(cell)` to the cell's first largest pixel (row
//!   major, NaN never the largest), 0 to the others — the argmax recomputed
//!   from the pool's input;
//! - [`upsample_nearest2x_grad`]: `dx(cell) = sum of dy over the cell`;
//! - [`upsample_bilinear2x`] and its gradient [`upsample_bilinear2x_grad`]:
//!   PyTorch's `align_corners = False` convention, the fine pixel `x` at
//!   coarse coordinate `(x + 0.5) / 2 - 0.5`, clamped to the coarse image;
//! - [`composite_grad`]: for `o = f - a U(D(f)) + a U(c)`,
//!   `df(p) = g(p) - sum_{p' in cell} a(p') g(p') / n(cell)`,
//!   `dc(cell) = sum_{p in cell} a(p) g(p)` and `da(p) = g(p) (c(cell) - D(f)(cell))`
//!   (summed over the channels when `a` has one plane).
//!
//! The same loops are compiled for AVX2 and AVX-512 (the compiler
//! vectorises them; no FMA contraction, so every ISA gives the same bits).

use crate::error::{check_shape, Error, Result, Shape};
use crate::unfold::{check_band, check_band_rows};
use crate::view::{View, ViewMut};
use crate::Isa;

fn coarse_shape(fine: Shape) -> Shape {
    Shape::new(fine.channels, fine.width.div_ceil(2), fine.height.div_ceil(2))
}

/// The gradient of the 2x2 average pool: fine rows `y0 ..` of `dx` from the
/// coarse gradient `dy` (of a `dx`-sized image: `full_height` rows).
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn avg_pool2x2_grad(
    isa: Isa,
    dy: &View<'_, f32>,
    dx: &mut ViewMut<'_, f32>,
    y0: usize,
    full_height: usize,
) -> Result<()> {
    let isa = isa.check()?;
    let full = Shape::new(dx.channels(), dx.width(), full_height);
    check_shape("average pool gradient", coarse_shape(full), dy.shape())?;
    check_band("average pool input gradient", full, dx.shape(), y0)?;
    let (w, h) = (full.width, full_height);
    versions!(isa, || {
        for c in 0..dx.channels() {
            for r in 0..dx.height() {
                let y = y0 + r;
                let rows = if y / 2 * 2 + 1 < h { 2.0 } else { 1.0 };
                let g = dy.row(c, y / 2);
                let o = dx.row_mut(c, r);
                for (x, o) in o.iter_mut().enumerate() {
                    let cols = if x / 2 * 2 + 1 < w { 2.0 } else { 1.0 };
                    *o = g[x / 2] / (rows * cols);
                }
            }
        }
    });
    Ok(())
}

/// The gradient of the 2x2 max pool: fine rows `y0 ..` of `dx` from the pool's
/// whole input `x` and the coarse gradient `dy`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn max_pool2x2_grad(
    isa: Isa,
    x: &View<'_, f32>,
    dy: &View<'_, f32>,
    dx: &mut ViewMut<'_, f32>,
    y0: usize,
) -> Result<()> {
    let isa = isa.check()?;
    let full = x.shape();
    check_shape("max pool gradient", coarse_shape(full), dy.shape())?;
    check_band("max pool input gradient", full, dx.shape(), y0)?;
    let (w, h) = (full.width, full.height);
    versions!(isa, || {
        for c in 0..full.channels {
            for r in 0..dx.height() {
                let y = y0 + r;
                let (top, bot) = (y / 2 * 2, (y / 2 * 2 + 1).min(h - 1));
                let (xt, xb) = (x.row(c, top), x.row(c, bot));
                let g = dy.row(c, y / 2);
                let o = dx.row_mut(c, r);
                for (xo, o) in o.iter_mut().enumerate() {
                    let (l, rr) = (xo / 2 * 2, (xo / 2 * 2 + 1).min(w - 1));
                    // The cell's pixels in row-major order, each once.
                    let cand = [(top, l, xt[l]), (top, rr, xt[rr]), (bot, l, xb[l]), (bot, rr, xb[rr])];
                    let mut best = (usize::MAX, usize::MAX, f32::NEG_INFINITY);
                    for (i, &(cy, cx, v)) in cand.iter().enumerate() {
                        let dup = (i % 2 == 1 && rr == l) || (i >= 2 && bot == top);
                        if !dup && (v > best.2 || best.0 == usize::MAX && v == best.2) {
                            best = (cy, cx, v);
                        }
                    }
                    *o = if best.0 == y && best.1 == xo { g[xo / 2] } else { 0.0 };
                }
            }
        }
    });
    Ok(())
}

/// The gradient of the nearest 2x upsample: coarse rows `y0 ..` of `dx`, the
/// sum of the whole fine gradient `dy` over each cell.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn upsample_nearest2x_grad(isa: Isa, dy: &View<'_, f32>, dx: &mut ViewMut<'_, f32>, y0: usize) -> Result<()> {
    let isa = isa.check()?;
    let full = dy.shape();
    check_band("upsample input gradient", coarse_shape(full), dx.shape(), y0)?;
    let (w, h) = (full.width, full.height);
    versions!(isa, || {
        for c in 0..full.channels {
            for r in 0..dx.height() {
                let yc = y0 + r;
                let o = dx.row_mut(c, r);
                o.fill(0.0);
                for y in 2 * yc..(2 * yc + 2).min(h) {
                    let g = dy.row(c, y);
                    for (xc, o) in o.iter_mut().enumerate() {
                        *o += g[2 * xc];
                        if 2 * xc + 1 < w {
                            *o += g[2 * xc + 1];
                        }
                    }
                }
            }
        }
    });
    Ok(())
}

/// The two coarse taps of fine coordinate `i` (of `n` coarse samples) and
/// the weight of the second: `(i + 0.5) / 2 - 0.5` clamped to `[0, n - 1]`.
#[inline(always)]
fn taps(i: usize, n: usize) -> (usize, usize, f32) {
    if i == 0 || n == 1 {
        return (0, 0, 0.0);
    }
    // i odd: between (i-1)/2 and (i+1)/2 at 0.25; i even: between i/2 - 1 and i/2 at 0.75.
    let (a, t) = if i % 2 == 1 { ((i - 1) / 2, 0.25) } else { (i / 2 - 1, 0.75) };
    if a + 1 >= n {
        (n - 1, n - 1, 0.0)
    } else {
        (a, a + 1, t)
    }
}

/// Bilinear 2x upsample (`align_corners = False`) of the coarse `src` into
/// fine rows `y0 ..` of `dst`, a `dst.width() x full_height` image whose
/// coarse size is `src`'s.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn upsample_bilinear2x(
    isa: Isa,
    src: &View<'_, f32>,
    dst: &mut ViewMut<'_, f32>,
    y0: usize,
    full_height: usize,
) -> Result<()> {
    let isa = isa.check()?;
    let full = Shape::new(dst.channels(), dst.width(), full_height);
    check_shape("bilinear upsample input", coarse_shape(full), src.shape())?;
    check_band("bilinear upsample output", full, dst.shape(), y0)?;
    let (wc, hc) = (src.width(), src.height());
    versions!(isa, || {
        for c in 0..full.channels {
            for r in 0..dst.height() {
                let (ya, yb, ty) = taps(y0 + r, hc);
                let (ra, rb) = (src.row(c, ya), src.row(c, yb));
                let o = dst.row_mut(c, r);
                for (x, o) in o.iter_mut().enumerate() {
                    let (xa, xb, tx) = taps(x, wc);
                    let top = ra[xa] * (1.0 - tx) + ra[xb] * tx;
                    let bot = rb[xa] * (1.0 - tx) + rb[xb] * tx;
                    *o = top * (1.0 - ty) + bot * ty;
                }
            }
        }
    });
    Ok(())
}

/// The fine pixels whose bilinear taps reach coarse index `j` (of `n`), with
/// their weights on it: at most four, in ascending order.
#[inline(always)]
fn reach(j: usize, n: usize, fine: usize) -> ([(usize, f32); 4], usize) {
    let mut out = [(0usize, 0.0f32); 4];
    let mut m = 0;
    let lo = (2 * j).saturating_sub(2);
    for i in lo..(2 * j + 3).min(fine) {
        let (a, b, t) = taps(i, n);
        let mut wgt = 0.0;
        if a == j {
            wgt += 1.0 - t;
        }
        if b == j {
            wgt += t;
        }
        if wgt != 0.0 && m < 4 {
            out[m] = (i, wgt);
            m += 1;
        }
    }
    (out, m)
}

/// The gradient of [`upsample_bilinear2x`]: coarse rows `y0 ..` of `dx` from
/// the whole fine gradient `dy`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn upsample_bilinear2x_grad(isa: Isa, dy: &View<'_, f32>, dx: &mut ViewMut<'_, f32>, y0: usize) -> Result<()> {
    let isa = isa.check()?;
    let full = dy.shape();
    let cs = coarse_shape(full);
    check_band("bilinear upsample input gradient", cs, dx.shape(), y0)?;
    let (w, h) = (full.width, full.height);
    versions!(isa, || {
        for c in 0..full.channels {
            for r in 0..dx.height() {
                let (ys, ny) = reach(y0 + r, cs.height, h);
                let o = dx.row_mut(c, r);
                for (xc, o) in o.iter_mut().enumerate() {
                    let (xs, nx) = reach(xc, cs.width, w);
                    let mut s = 0.0f32;
                    for &(y, wy) in &ys[..ny] {
                        let g = dy.row(c, y);
                        let mut t = 0.0f32;
                        for &(x, wx) in &xs[..nx] {
                            t += wx * g[x];
                        }
                        s += wy * t;
                    }
                    *o = s;
                }
            }
        }
    });
    Ok(())
}

/// The gradients of the scale compositor (see the module) for fine rows
/// `y0 .. y0 + n` (`y0` even): `d_fine` and `d_alpha` hold those rows,
/// `d_coarse` the coarse rows `y0 / 2 .. (y0 + n + 1) / 2`. Inputs whole:
/// `fine` (C planes), `coarse` (C planes, half size), `alpha` (1 or C
/// planes), `g` the output's gradient (C planes). `d_alpha` has as many planes as `alpha`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
#[allow(clippy::too_many_arguments)]
pub fn composite_grad(
    isa: Isa,
    fine: &View<'_, f32>,
    coarse: &View<'_, f32>,
    alpha: &View<'_, f32>,
    g: &View<'_, f32>,
    d_fine: &mut ViewMut<'_, f32>,
    d_coarse: &mut ViewMut<'_, f32>,
    d_alpha: &mut ViewMut<'_, f32>,
    y0: usize,
) -> Result<()> {
    let isa = isa.check()?;
    let full = fine.shape();
    let cs = coarse_shape(full);
    check_shape("compositor coarse input", cs, coarse.shape())?;
    check_shape("compositor output gradient", full, g.shape())?;
    let na = alpha.channels();
    if na != 1 && na != full.channels {
        return Err(Error::BadParameter { what: "compositor alpha", expected: "one plane, or one per channel" });
    }
    check_shape("compositor alpha", Shape::new(na, full.width, full.height), alpha.shape())?;
    if !y0.is_multiple_of(2) {
        return Err(Error::BadParameter { what: "compositor gradient band", expected: "an even first row" });
    }
    let n = d_fine.height();
    check_band("compositor fine gradient", full, d_fine.shape(), y0)?;
    check_band_rows("compositor alpha gradient", Shape::new(na, full.width, full.height), d_alpha.shape(), y0, n)?;
    let coarse_rows = (y0 + n).div_ceil(2) - y0 / 2;
    check_band_rows(
        "compositor coarse gradient",
        Shape::new(full.channels, cs.width, coarse_rows),
        d_coarse.shape(),
        0,
        coarse_rows,
    )?;
    let (w, h) = (full.width, full.height);
    versions!(isa, || {
        // `na` may be 0 (no channels at all): then there is nothing to zero.
        for r in 0..d_alpha.height() {
            for a in 0..na {
                d_alpha.row_mut(a, r).fill(0.0);
            }
        }
        for c in 0..full.channels {
            let ac = if na == 1 { 0 } else { c };
            for rc in 0..d_coarse.height() {
                let yc = y0 / 2 + rc;
                let (top, bot) = (2 * yc, (2 * yc + 1).min(h - 1));
                let two_rows = bot != top;
                let (ft, fb) = (fine.row(c, top), fine.row(c, bot));
                let (gt, gb) = (g.row(c, top), g.row(c, bot));
                let (at, ab) = (alpha.row(ac, top), alpha.row(ac, bot));
                let cr = coarse.row(c, yc);
                for xc in 0..cs.width {
                    let (l, rr) = (2 * xc, (2 * xc + 1).min(w - 1));
                    let two_cols = rr != l;
                    // The cell's pixels (row, column, fine, g, alpha), each once.
                    let mut px = [(top, l, ft[l], gt[l], at[l]); 4];
                    let mut m = 1;
                    if two_cols {
                        px[m] = (top, rr, ft[rr], gt[rr], at[rr]);
                        m += 1;
                    }
                    if two_rows {
                        px[m] = (bot, l, fb[l], gb[l], ab[l]);
                        m += 1;
                        if two_cols {
                            px[m] = (bot, rr, fb[rr], gb[rr], ab[rr]);
                            m += 1;
                        }
                    }
                    let (mut mean, mut ag) = (0.0f32, 0.0f32);
                    for &(_, _, f, gv, a) in &px[..m] {
                        mean += f;
                        ag += a * gv;
                    }
                    let inv = 1.0 / m as f32;
                    mean *= inv;
                    d_coarse.row_mut(c, rc)[xc] = ag;
                    let diff = cr[xc] - mean;
                    for &(y, x, _, gv, _) in &px[..m] {
                        if y >= y0 && y < y0 + n {
                            d_fine.row_mut(c, y - y0)[x] = gv - ag * inv;
                            d_alpha.row_mut(ac, y - y0)[x] += gv * diff;
                        }
                    }
                }
            }
        }
    });
    Ok(())
}

//! Backward passes of the softmax operators (f32), and the sigmoid.
//!
//! - [`channel_softmax_grad`]: `dx_i = y_i (dy_i - sum_j y_j dy_j)`.
//! - [`sigmoid`] and [`sigmoid_grad`]: `y = 1 / (1 + e^-x)`, `dx = dy y (1 - y)`.
//! - [`fused_filter_grad`]: the gradients of the fused importance filter
//!   (WSKP eq. 5, [`super::fused_filter`]) for its importance logits, its
//!   fusion logits and its radiance, given the gradient `G` of its output.
//!
//! ## The fused filter's gradient
//! With `out_c(p) = a_c(p) sum_k alpha_k(p) R_kc(p)`,
//! `R_kc(p) = sum_{q in W_k(p)} w_kp(q) c_c(q)` and the window's softmax
//! weights `w_kp(q) = e_k(q) / D_k(p)`, `e_k = exp(I_k)`:
//! - `dI_k(q) = sum_{p: q in W_k(p)} sum_c g_kc(p) w_kp(q) (c_c(q) - R_kc(p))`,
//! - `dc_c(q) = sum_k sum_{p: q in W_k(p)} g_kc(p) w_kp(q)`,
//! - `dF_k(p) = alpha_k (d_k - sum_j alpha_j d_j)` with `d_k = sum_c G_c a_c R_kc`,
//!
//! where `g_kc = G_c a_c alpha_k`. Shifting every `e_k` of a region by the
//! region's largest logit changes no `w` (it cancels in the ratio), and then
//! `w_kp(q) = e'(q) / D'(p)` with `e' <= 1`, so the sums over `p` are box
//! sums: `dI_k(q) = e'(q) (sum_c c_c(q) U_kc(q) - V_k(q))` and
//! `dc_c(q) += e'(q) U_kc(q)`, with `U_kc` the window sum of `g_kc / D'` and
//! `V_k` that of `sum_c g_kc R_kc / D'`. Cost per pixel does not grow with
//! `k` beyond the `2k` adds of each separable window sum.
//!
//! The regions are the tiles of a fixed grid ([`GRAD_TILE_H`] x
//! [`GRAD_TILE_W`] output pixels; the shift is the largest logit of the tile
//! and its `2r` halo), so the result does not depend on how the rows are cut
//! into bands. A window whose shifted denominator falls below
//! [`GRAD_TINY`] (its logits lie more than ~41 nats under the region's
//! largest) is taken by one of [`GRAD_EXTRA_PASSES`] more passes of the same
//! box sums at shifts [`GRAD_SHIFT_STEP`] lower each, restricted to the
//! windows left (the sums over `p` split into the passes' disjoint sets);
//! only a window left after them is computed directly with its own maximum
//! as the shift, its terms added to the `q` of the band one by one: no
//! overflow, no `0 / 0`, for any logit (clamped to `±LOGIT_LIMIT`, NaN
//! weighing 0 as in the forward pass). A trained ImportanceNet's logits
//! spread by more than 41 nats between neighbours, and the window-by-window
//! path made a WSKP-6 training step 8x slower (480 against 60 ms,
//! `profile_train`); with the extra passes here and in the forward pass, 70 ms.
//!
//! Every path compiles the same loops for its ISA (the compiler vectorises
//! them), so the gradients are the same bits on every ISA.

use crate::error::{check_scratch, check_shape, Error, Result, Shape};
use crate::math::scalar::exp;
use crate::softmax::{FusedInputs, LOGIT_LIMIT, MAX_CHANNELS, MAX_FUSED, MAX_WINDOW};
use crate::unfold::{check_band, check_band_rows};
use crate::view::{View, ViewMut};
use crate::Isa;

/// `dx_i = y_i (dy_i - sum_j y_j dy_j)` per pixel over the channels: `y` the
/// softmax's output, `dy` its gradient, all three one shape.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn channel_softmax_grad(isa: Isa, y: &View<'_, f32>, dy: &View<'_, f32>, dx: &mut ViewMut<'_, f32>) -> Result<()> {
    let isa = isa.check()?;
    check_shape("softmax gradient", y.shape(), dy.shape())?;
    check_shape("softmax input gradient", y.shape(), dx.shape())?;
    let n = y.channels();
    versions!(isa, || {
        for r in 0..y.height() {
            for x in 0..y.width() {
                let mut dot = 0.0f32;
                for c in 0..n {
                    dot += y.row(c, r)[x] * dy.row(c, r)[x];
                }
                for c in 0..n {
                    let yv = y.row(c, r)[x];
                    dx.row_mut(c, r)[x] = yv * (dy.row(c, r)[x] - dot);
                }
            }
        }
    });
    Ok(())
}

/// `y = 1 / (1 + e^-x)` element by element (0 for NaN).
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn sigmoid(isa: Isa, x: &View<'_, f32>, y: &mut ViewMut<'_, f32>) -> Result<()> {
    let isa = isa.check()?;
    check_shape("sigmoid output", x.shape(), y.shape())?;
    versions!(isa, || {
        for c in 0..x.channels() {
            for r in 0..x.height() {
                for (o, &v) in y.row_mut(c, r).iter_mut().zip(x.row(c, r)) {
                    // Both halves through e^-|x| <= 1, so nothing overflows.
                    *o = if v >= 0.0 {
                        1.0 / (1.0 + exp(-v))
                    } else if v < 0.0 {
                        let e = exp(v);
                        e / (1.0 + e)
                    } else {
                        0.0
                    };
                }
            }
        }
    });
    Ok(())
}

/// `dx = dy y (1 - y)` from the sigmoid's output `y`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn sigmoid_grad(isa: Isa, y: &View<'_, f32>, dy: &View<'_, f32>, dx: &mut ViewMut<'_, f32>) -> Result<()> {
    let isa = isa.check()?;
    check_shape("sigmoid gradient", y.shape(), dy.shape())?;
    check_shape("sigmoid input gradient", y.shape(), dx.shape())?;
    versions!(isa, || {
        for c in 0..y.channels() {
            for r in 0..y.height() {
                let (yr, gr) = (y.row(c, r), dy.row(c, r));
                for ((o, &yv), &g) in dx.row_mut(c, r).iter_mut().zip(yr).zip(gr) {
                    *o = g * yv * (1.0 - yv);
                }
            }
        }
    });
    Ok(())
}

/// Rows of the fused gradient's tile grid.
pub const GRAD_TILE_H: usize = 32;
/// Columns of the fused gradient's tile grid.
pub const GRAD_TILE_W: usize = 256;
/// Passes of the gradient after the first, each at a shift
/// [`GRAD_SHIFT_STEP`] lower, for the windows whose denominator fell under
/// [`GRAD_TINY`] at the previous one; only what is left after them is
/// computed window by window.
pub const GRAD_EXTRA_PASSES: usize = 2;
/// How far each extra pass lowers the shift (nats): under the ~41.6 nats
/// below which every logit of a window left must lie, so the window's
/// weights stay under 1 at the new shift.
pub const GRAD_SHIFT_STEP: f32 = 40.0;
/// The largest exponent of a weight in a pass (e^80, finite in f32): the
/// pixels above it belong to no window that pass takes.
const GRAD_E_CAP: f32 = 80.0;

/// A shifted window denominator below this (2^-60) is recomputed with the
/// window's own shift.
pub const GRAD_TINY: f32 = 8.673_617e-19;

/// The gradients [`fused_filter_grad`] writes: rows `y0 ..` of each.
pub struct FusedGrads<'a, 'b> {
    /// `M` planes: the importance logits' gradient.
    pub importance: &'a mut ViewMut<'b, f32>,
    /// `M` planes: the fusion logits' gradient (`None` exactly when the
    /// inputs have no fusion logits).
    pub fusion: Option<&'a mut ViewMut<'b, f32>>,
    /// The radiance's gradient (its channels).
    pub radiance: &'a mut ViewMut<'b, f32>,
}

/// A rectangle of image pixels, stored row-major in a scratch region.
#[derive(Clone, Copy, Debug)]
struct Rect {
    y0: usize,
    y1: usize,
    x0: usize,
    x1: usize,
}

impl Rect {
    fn grow(self, r: usize, w: usize, h: usize) -> Rect {
        Rect {
            y0: self.y0.saturating_sub(r),
            y1: (self.y1 + r).min(h),
            x0: self.x0.saturating_sub(r),
            x1: (self.x1 + r).min(w),
        }
    }
    fn w(&self) -> usize {
        self.x1 - self.x0
    }
    #[inline(always)]
    fn at(&self, y: usize, x: usize) -> usize {
        (y - self.y0) * self.w() + (x - self.x0)
    }
}

/// The largest region a tile needs: its output rows and columns grown by
/// `2 r_max` on every side.
fn region_cap(width: usize) -> usize {
    let g = 2 * (MAX_WINDOW - 1);
    (GRAD_TILE_H + g) * (GRAD_TILE_W.min(width) + g)
}

/// Scratch words [`fused_filter_grad`] needs for images `width` wide with
/// `channels` radiance channels and `m` sizes.
pub fn fused_grad_scratch_len(m: usize, channels: usize, width: usize) -> usize {
    // e', the horizontal sums (1 + C), D' and N (1 + C), R (C), u and v
    // (C + 1), their horizontal and vertical sums (2 (C + 1)), alpha (M),
    // d_k (M) and a fallback mask.
    let planes = channels.saturating_mul(6).saturating_add(m.saturating_mul(2)).saturating_add(7); // 7 + 6 C + 2 M
    planes.saturating_mul(region_cap(width)).saturating_add(row_len(width))
}

/// A row of the widest region (the temporary row of [`tile_grad`]).
fn row_len(width: usize) -> usize {
    GRAD_TILE_W.min(width) + 4 * (MAX_WINDOW - 1)
}

#[inline(always)]
fn logit(v: f32) -> f32 {
    if v.is_nan() {
        -LOGIT_LIMIT
    } else {
        v.max(-LOGIT_LIMIT).min(LOGIT_LIMIT)
    }
}

/// The gradients of the fused importance filter (see the module) for output
/// rows `y0 .. y0 + n`: `g` is the output's gradient (the radiance's channels,
/// whole image), the inputs as [`super::fused_filter`] takes them (f32).
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above; [`Error::ScratchTooSmall`] when `scratch` is shorter than this operator's
/// `*_scratch_len`.
pub fn fused_filter_grad(
    isa: Isa,
    inp: &FusedInputs<'_, f32>,
    g: &View<'_, f32>,
    out: FusedGrads<'_, '_>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let isa = isa.check()?;
    let m = inp.sizes.len();
    let s = inp.radiance.shape();
    let (c, w, h) = (s.channels, s.width, s.height);
    if m == 0 || m > MAX_FUSED {
        return Err(Error::BadParameter { what: "fused filter sizes", expected: "1 to MAX_FUSED window sizes" });
    }
    for &k in inp.sizes {
        crate::check_kernel_size("fused filter window size", k, MAX_WINDOW)?;
    }
    if c == 0 || c > MAX_CHANNELS {
        return Err(Error::BadParameter { what: "fused filter radiance", expected: "1 to 4 channels" });
    }
    let plane = |n| Shape::new(n, w, h);
    check_shape("fused importance logits", plane(m), inp.importance.shape())?;
    match (&inp.fusion, m) {
        (Some(f), _) => check_shape("fused fusion logits", plane(m), f.shape())?,
        (None, 1) => {}
        (None, _) => {
            return Err(Error::BadParameter { what: "fused fusion logits", expected: "present when mixing sizes" })
        }
    }
    if let Some(a) = &inp.albedo {
        check_shape("fused albedo", s, a.shape())?;
    }
    check_shape("fused output gradient", s, g.shape())?;
    let n = out.importance.height();
    check_band("fused importance gradient", plane(m), out.importance.shape(), y0)?;
    check_band_rows("fused radiance gradient", s, out.radiance.shape(), y0, n)?;
    match (&out.fusion, &inp.fusion) {
        (Some(f), Some(_)) => check_band_rows("fused fusion gradient", plane(m), f.shape(), y0, n)?,
        (None, None) => {}
        _ => {
            return Err(Error::BadParameter {
                what: "fused fusion gradient",
                expected: "present exactly when the inputs have fusion logits",
            })
        }
    }
    check_scratch(fused_grad_scratch_len(m, c, w), scratch.len())?;
    if n == 0 || w == 0 {
        return Ok(());
    }
    let FusedGrads { importance, fusion, radiance } = out;
    let mut fusion = fusion;
    let mut ty = y0 / GRAD_TILE_H * GRAD_TILE_H;
    while ty < y0 + n {
        let mut tx = 0;
        while tx < w {
            let tile = Rect { y0: ty, y1: (ty + GRAD_TILE_H).min(h), x0: tx, x1: (tx + GRAD_TILE_W).min(w) };
            let q = Rect { y0: tile.y0.max(y0), y1: tile.y1.min(y0 + n), ..tile };
            let t = TileArgs { inp, g, tile, q, y0 };
            match isa.isa() {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
                Isa::Avx2 => unsafe { tile_avx2(&t, importance, fusion.as_deref_mut(), radiance, scratch) },
                #[cfg(target_arch = "x86_64")]
                // SAFETY: as above.
                Isa::Avx512 => unsafe { tile_avx512(&t, importance, fusion.as_deref_mut(), radiance, scratch) },
                _ => tile_grad(&t, importance, fusion.as_deref_mut(), radiance, scratch),
            }
            tx += GRAD_TILE_W;
        }
        ty += GRAD_TILE_H;
    }
    Ok(())
}

/// What a tile's gradient reads.
struct TileArgs<'a, 'b> {
    inp: &'a FusedInputs<'b, f32>,
    g: &'a View<'b, f32>,
    tile: Rect,
    q: Rect,
    y0: usize,
}

/// [`tile_grad`] compiled for AVX2 (the compiler vectorises its row loops).
///
/// # Safety
/// AVX2 and FMA must be supported.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn tile_avx2(
    t: &TileArgs<'_, '_>,
    d_imp: &mut ViewMut<'_, f32>,
    d_fus: Option<&mut ViewMut<'_, f32>>,
    d_rad: &mut ViewMut<'_, f32>,
    scratch: &mut [f32],
) {
    tile_grad(t, d_imp, d_fus, d_rad, scratch)
}

/// [`tile_grad`] compiled for AVX-512.
///
/// # Safety
/// AVX-512 F/BW/DQ/VL, AVX2 and FMA must be supported.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn tile_avx512(
    t: &TileArgs<'_, '_>,
    d_imp: &mut ViewMut<'_, f32>,
    d_fus: Option<&mut ViewMut<'_, f32>>,
    d_rad: &mut ViewMut<'_, f32>,
    scratch: &mut [f32],
) {
    tile_grad(t, d_imp, d_fus, d_rad, scratch)
}

/// `dst[x - bx0] = sum of src over the window of radius r around x` for
/// columns `bx0 .. bx0 + dst.len()`, clipped to `[0, w)`; `src` holds
/// columns `ax0 ..`. Added in ascending column order, one shifted row at a
/// time (contiguous, so it vectorises).
#[inline(always)]
fn box_row(src: &[f32], ax0: usize, dst: &mut [f32], bx0: usize, r: usize, w: usize) {
    dst.fill(0.0);
    let bx1 = bx0 + dst.len();
    for d in -(r as isize)..=(r as isize) {
        let lo = (bx0 as isize).max(-d).min(bx1 as isize) as usize;
        let hi = (bx1 as isize).min(w as isize - d).max(lo as isize) as usize;
        if hi == lo {
            continue;
        }
        let s0 = (lo as isize + d) as usize - ax0;
        for (o, &v) in dst[lo - bx0..hi - bx0].iter_mut().zip(&src[s0..s0 + (hi - lo)]) {
            *o += v;
        }
    }
}

/// The vertical half of [`box_row`]: for each of `planes` planes (`cap`
/// apart) and each row `y` of `ys`, `dst` row `y - ys.start` (`n` wide) is
/// the sum of `src` rows `yy - ay0` for `yy` within radius `r` of `y`,
/// clipped to `[0, h)`, added in ascending row order.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn box_col(
    src: &[f32],
    ay0: usize,
    dst: &mut [f32],
    ys: core::ops::Range<usize>,
    n: usize,
    planes: usize,
    cap: usize,
    r: usize,
    h: usize,
) {
    for y in ys.clone() {
        let (lo, hi) = (y.saturating_sub(r), (y + r + 1).min(h));
        let o = (y - ys.start) * n;
        for pl in 0..planes {
            let d = &mut dst[pl * cap + o..pl * cap + o + n];
            d.fill(0.0);
            for yy in lo..hi {
                let so = pl * cap + (yy - ay0) * n;
                for (d, &v) in d.iter_mut().zip(&src[so..so + n]) {
                    *d += v;
                }
            }
        }
    }
}

/// One tile's gradients for its rows `q` (inside the band starting at `y0`).
#[inline(always)]
fn tile_grad(
    t: &TileArgs<'_, '_>,
    d_imp: &mut ViewMut<'_, f32>,
    d_fus: Option<&mut ViewMut<'_, f32>>,
    d_rad: &mut ViewMut<'_, f32>,
    scratch: &mut [f32],
) {
    use crate::math::scalar::exp_select as ex;
    let TileArgs { inp, g, tile, q, y0 } = *t;
    let (c, w, h) = (inp.radiance.channels(), inp.radiance.width(), inp.radiance.height());
    let m = inp.sizes.len();
    let cap = region_cap(w);
    let (e, rest) = scratch.split_at_mut(cap);
    let (hsum, rest) = rest.split_at_mut((1 + c) * cap);
    let (dn, rest) = rest.split_at_mut((1 + c) * cap);
    let (rr, rest) = rest.split_at_mut(c * cap);
    let (uv, rest) = rest.split_at_mut((c + 1) * cap);
    let (uvh, rest) = rest.split_at_mut((c + 1) * cap);
    let (uvs, rest) = rest.split_at_mut((c + 1) * cap);
    let (alpha, rest) = rest.split_at_mut(m * cap);
    let (dk, rest) = rest.split_at_mut(m * cap);
    let (fallback, rest) = rest.split_at_mut(cap);
    let row_tmp = &mut rest[..row_len(w)];
    let alb_row = |ch: usize, y: usize| inp.albedo.as_ref().map(|a| a.row(ch, y));
    // The fusion weights over q grown by the largest radius.
    let rmax = inp.sizes.iter().max().copied().unwrap_or(1) / 2;
    let pa = q.grow(rmax, w, h);
    let paw = pa.w();
    for y in pa.y0..pa.y1 {
        let o = (y - pa.y0) * paw;
        match &inp.fusion {
            None => alpha[o..o + paw].fill(1.0),
            Some(f) => {
                let mx = &mut row_tmp[..paw];
                mx.fill(-LOGIT_LIMIT);
                for k in 0..m {
                    for (mv, &v) in mx.iter_mut().zip(&f.row(k, y)[pa.x0..pa.x1]) {
                        *mv = mv.max(logit(v));
                    }
                }
                for k in 0..m {
                    for ((a, &v), &mv) in
                        alpha[k * cap + o..k * cap + o + paw].iter_mut().zip(&f.row(k, y)[pa.x0..pa.x1]).zip(mx.iter())
                    {
                        *a = ex(logit(v) - mv);
                    }
                }
                for x in 0..paw {
                    let mut sum = 0.0f32;
                    for k in 0..m {
                        sum += alpha[k * cap + o + x];
                    }
                    mx[x] = 1.0 / sum;
                }
                for k in 0..m {
                    for (a, &inv) in alpha[k * cap + o..k * cap + o + paw].iter_mut().zip(mx.iter()) {
                        *a *= inv;
                    }
                }
            }
        }
    }
    // Zero the outputs of q before the sizes add into them.
    for y in q.y0..q.y1 {
        for ch in 0..c {
            d_rad.row_mut(ch, y - y0)[q.x0..q.x1].fill(0.0);
        }
    }
    let (qw, qh) = (q.w(), q.y1 - q.y0);
    for (kk, &k) in inp.sizes.iter().enumerate() {
        let r = k / 2;
        let p = q.grow(r, w, h);
        let er = p.grow(r, w, h);
        let (pw, ew) = (p.w(), er.w());
        // The shift: the largest logit of the whole tile and its 2r halo
        // (independent of the band).
        let sr = tile.grow(2 * r, w, h);
        let imp = &inp.importance;
        let mut mx = -LOGIT_LIMIT;
        for y in sr.y0..sr.y1 {
            for &v in &imp.row(kk, y)[sr.x0..sr.x1] {
                mx = mx.max(logit(v));
            }
        }
        // Passes at shifts `mx`, `mx - GRAD_SHIFT_STEP`, ...: pass 0 takes
        // every window whose shifted denominator reaches GRAD_TINY; each
        // later pass takes, of the windows left, those that reach it at the
        // lower shift (every logit of a window left lies more than ~41 nats
        // under the previous shift, so its weights stay below 1 and its sums
        // exact; the other pixels' weights are capped at e^GRAD_E_CAP, finite,
        // and enter no window of the pass). What is left after the last pass
        // is computed directly with each window's own shift.
        let mut any_fallback = false;
        for pass in 0..=GRAD_EXTRA_PASSES {
            if pass > 0 && !any_fallback {
                break;
            }
            let shift = mx - pass as f32 * GRAD_SHIFT_STEP;
            for y in er.y0..er.y1 {
                let o = (y - er.y0) * ew;
                for (ev, &v) in e[o..o + ew].iter_mut().zip(&imp.row(kk, y)[er.x0..er.x1]) {
                    *ev = ex((logit(v) - shift).min(GRAD_E_CAP));
                }
            }
            // D' and N over p: horizontal sums (rows of er, columns of p), then vertical.
            for y in er.y0..er.y1 {
                let (o, ho) = ((y - er.y0) * ew, (y - er.y0) * pw);
                let erow = &e[o..o + ew];
                box_row(erow, er.x0, &mut hsum[ho..ho + pw], p.x0, r, w);
                for ch in 0..c {
                    let prod = &mut row_tmp[..ew];
                    for ((t, &ev), &rv) in prod.iter_mut().zip(erow).zip(&inp.radiance.row(ch, y)[er.x0..er.x1]) {
                        *t = ev * rv;
                    }
                    box_row(prod, er.x0, &mut hsum[(1 + ch) * cap + ho..(1 + ch) * cap + ho + pw], p.x0, r, w);
                }
            }
            box_col(hsum, er.y0, dn, p.y0..p.y1, pw, c + 1, cap, r, h);
            // R, u = g / D', v = sum_c u_c R_c over p for the windows this
            // pass takes; the others get u = v = 0 (and keep their R).
            any_fallback = false;
            for y in p.y0..p.y1 {
                let o = (y - p.y0) * pw;
                let inv = &mut row_tmp[..pw];
                for ((iv, fb), &d) in inv.iter_mut().zip(&mut fallback[o..o + pw]).zip(&dn[o..o + pw]) {
                    // Pass 0: every window is open; later: those left open.
                    let open = pass == 0 || *fb != 0.0;
                    let small = !(d >= GRAD_TINY);
                    *fb = if open && small { 1.0 } else { 0.0 };
                    *iv = if open && !small { 1.0 / d } else { 0.0 };
                }
                any_fallback |= fallback[o..o + pw].iter().any(|&f| f != 0.0);
                let ao = (y - pa.y0) * paw + (p.x0 - pa.x0);
                let al = &alpha[kk * cap + ao..kk * cap + ao + pw];
                uv[c * cap + o..c * cap + o + pw].fill(0.0);
                for ch in 0..c {
                    let gr = &g.row(ch, y)[p.x0..p.x1];
                    let ar = alb_row(ch, y).map(|a| &a[p.x0..p.x1]);
                    let (nr, rrow) = (&dn[(1 + ch) * cap + o..(1 + ch) * cap + o + pw], ch * cap + o);
                    let (uvc, vrow) = uv.split_at_mut(c * cap);
                    let vrow = &mut vrow[o..o + pw];
                    for x in 0..pw {
                        let taken = inv[x] != 0.0;
                        let rv = if taken { nr[x] * inv[x] } else { rr[rrow + x] };
                        rr[rrow + x] = rv;
                        let gk = gr[x] * ar.map_or(1.0, |a| a[x]) * al[x];
                        let u = gk * inv[x];
                        uvc[ch * cap + o + x] = u;
                        vrow[x] += if taken { u * rv } else { 0.0 };
                    }
                }
            }
            // U, V over q: horizontal sums (rows of p, columns of q), then vertical.
            for y in p.y0..p.y1 {
                let (o, ho) = ((y - p.y0) * pw, (y - p.y0) * qw);
                for pl in 0..=c {
                    let (src, dst) =
                        (&uv[pl * cap + o..pl * cap + o + pw], &mut uvh[pl * cap + ho..pl * cap + ho + qw]);
                    box_row(src, p.x0, dst, q.x0, r, w);
                }
            }
            box_col(uvh, p.y0, uvs, q.y0..q.y1, qw, c + 1, cap, r, h);
            // dI and dc over q (pass 0 writes dI, later passes add to it).
            for y in q.y0..q.y1 {
                let o = (y - q.y0) * qw;
                let eo = (y - er.y0) * ew + (q.x0 - er.x0);
                let ev = &e[eo..eo + qw];
                let t = &mut row_tmp[..qw];
                for (tv, &v) in t.iter_mut().zip(&uvs[c * cap + o..c * cap + o + qw]) {
                    *tv = -v;
                }
                for ch in 0..c {
                    let u = &uvs[ch * cap + o..ch * cap + o + qw];
                    let rad = &inp.radiance.row(ch, y)[q.x0..q.x1];
                    let drow = &mut d_rad.row_mut(ch, y - y0)[q.x0..q.x1];
                    for x in 0..qw {
                        t[x] += rad[x] * u[x];
                        drow[x] += ev[x] * u[x];
                    }
                }
                let drow = &mut d_imp.row_mut(kk, y - y0)[q.x0..q.x1];
                if pass == 0 {
                    for ((d, &evx), &tv) in drow.iter_mut().zip(ev).zip(t.iter()) {
                        *d = evx * tv;
                    }
                } else {
                    for ((d, &evx), &tv) in drow.iter_mut().zip(ev).zip(t.iter()) {
                        *d += evx * tv;
                    }
                }
            }
        }
        // The windows left: R with their own shift, then their terms, one by one, into q.
        if any_fallback {
            for y in p.y0..p.y1 {
                for x in p.x0..p.x1 {
                    let i = p.at(y, x);
                    if fallback[i] != 0.0 {
                        let rv = direct_r(inp, kk, r, y, x);
                        for ch in 0..c {
                            rr[ch * cap + i] = rv[ch];
                        }
                    }
                }
            }
            for py in p.y0..p.y1 {
                for px in p.x0..p.x1 {
                    let i = p.at(py, px);
                    if fallback[i] == 0.0 {
                        continue;
                    }
                    let ai = pa.at(py, px);
                    let (wy0, wy1) = (py.saturating_sub(r).max(q.y0), (py + r + 1).min(q.y1));
                    let (wx0, wx1) = (px.saturating_sub(r).max(q.x0), (px + r + 1).min(q.x1));
                    if wy0 >= wy1 || wx0 >= wx1 {
                        continue;
                    }
                    let (mxw, den) = window_shift(inp, kk, r, py, px);
                    for yy in wy0..wy1 {
                        for xx in wx0..wx1 {
                            let wq = ex(logit(imp.row(kk, yy)[xx]) - mxw) / den;
                            let mut t = 0.0f32;
                            for ch in 0..c {
                                let gk =
                                    g.row(ch, py)[px] * alb_row(ch, py).map_or(1.0, |a| a[px]) * alpha[kk * cap + ai];
                                let cq = inp.radiance.row(ch, yy)[xx];
                                t += gk * (cq - rr[ch * cap + i]);
                                d_rad.row_mut(ch, yy - y0)[xx] += gk * wq;
                            }
                            d_imp.row_mut(kk, yy - y0)[xx] += wq * t;
                        }
                    }
                }
            }
        }
        // d_k over q, from every window's R.
        for y in q.y0..q.y1 {
            let o = (y - q.y0) * qw;
            let po = (y - p.y0) * pw + (q.x0 - p.x0);
            let dkr = &mut dk[kk * cap + o..kk * cap + o + qw];
            dkr.fill(0.0);
            for ch in 0..c {
                let gr = &g.row(ch, y)[q.x0..q.x1];
                let ar = alb_row(ch, y).map(|a| &a[q.x0..q.x1]);
                let rrow = &rr[ch * cap + po..ch * cap + po + qw];
                for x in 0..qw {
                    dkr[x] += gr[x] * ar.map_or(1.0, |a| a[x]) * rrow[x];
                }
            }
        }
    }
    let _ = qh;
    // The fusion logits: dF_k = alpha_k (d_k - sum_j alpha_j d_j).
    if let Some(df) = d_fus {
        for y in q.y0..q.y1 {
            let o = (y - q.y0) * qw;
            let ao = (y - pa.y0) * paw + (q.x0 - pa.x0);
            let dot = &mut row_tmp[..qw];
            dot.fill(0.0);
            for k in 0..m {
                for ((d, &a), &v) in
                    dot.iter_mut().zip(&alpha[k * cap + ao..k * cap + ao + qw]).zip(&dk[k * cap + o..k * cap + o + qw])
                {
                    *d += a * v;
                }
            }
            for k in 0..m {
                let out = &mut df.row_mut(k, y - y0)[q.x0..q.x1];
                for (((o2, &a), &v), &d) in out
                    .iter_mut()
                    .zip(&alpha[k * cap + ao..k * cap + ao + qw])
                    .zip(&dk[k * cap + o..k * cap + o + qw])
                    .zip(dot.iter())
                {
                    *o2 = a * (v - d);
                }
            }
        }
    }
}

/// The window of `(y, x)` for size index `kk`: its largest logit and the sum
/// of its weights under that shift (at least 1).
#[inline(always)]
fn window_shift(inp: &FusedInputs<'_, f32>, kk: usize, r: usize, y: usize, x: usize) -> (f32, f32) {
    let (w, h) = (inp.radiance.width(), inp.radiance.height());
    let (ya, yb, xa, xb) = (y.saturating_sub(r), (y + r + 1).min(h), x.saturating_sub(r), (x + r + 1).min(w));
    let mut mx = -LOGIT_LIMIT;
    for yy in ya..yb {
        for &v in &inp.importance.row(kk, yy)[xa..xb] {
            mx = mx.max(logit(v));
        }
    }
    let mut den = 0.0f32;
    for yy in ya..yb {
        for &v in &inp.importance.row(kk, yy)[xa..xb] {
            den += exp(logit(v) - mx);
        }
    }
    (mx, den)
}

/// `R_k(y, x)` with the window's own shift (the fallback).
#[inline(always)]
fn direct_r(inp: &FusedInputs<'_, f32>, kk: usize, r: usize, y: usize, x: usize) -> [f32; MAX_CHANNELS] {
    let (w, h) = (inp.radiance.width(), inp.radiance.height());
    let (mx, den) = window_shift(inp, kk, r, y, x);
    let mut out = [0.0f32; MAX_CHANNELS];
    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
            let wq = exp(logit(inp.importance.row(kk, yy)[xx]) - mx) / den;
            for (ch, o) in out.iter_mut().enumerate().take(inp.radiance.channels()) {
                *o += wq * inp.radiance.row(ch, yy)[xx];
            }
        }
    }
    out
}

//! Backward pass of the convolution layers (f32), for training.
//!
//! With `z = W * x + b` (before the activation) and `y = act(z)`:
//! - [`activation_grad`]: `dz = dy * act'(z)`, read from `y` (for ReLU and
//!   LeakyReLU with slope `s >= 0`, `y > 0` exactly when `z > 0`; at `z = 0`
//!   the derivative is taken as `s`);
//! - [`grad_input`]: `dx = W^T * dz`, the forward convolution of `dz` with the
//!   weights transposed and flipped ([`transpose_weights`]), so it runs the
//!   forward kernels (every ISA's);
//! - [`grad_weights`]: `dW[co][ci][ky][kx] += sum_p dz[co](p) x[ci](p + (ky - r, kx - r))`
//!   (out-of-image `x` is 0, the zero padding) and `db[co] += sum_p dz[co](p)`,
//!   over the rows `y0 .. y0 + rows` of `dz`: a caller that splits the rows
//!   into bands accumulates each band's partial sums in its own buffer and
//!   adds them in band order, so the result depends on the bands, not on the
//!   threads that ran them.
//!
//! The AVX2 and AVX-512 weight gradients keep a block of output channels
//! times every column tap in accumulators while a row of `x` and the block's
//! rows of `dz` stream past (each `x` load feeds the block's FMAs, each `dz`
//! load `k` of them); lanes are summed at the end of the call. Their sums
//! differ from the scalar loop's by rounding only.

use crate::conv::{conv2d, conv2d_scratch_len, Activation, Conv2d, KERNEL_SIZES};
use crate::error::{check_shape, Error, Result, Shape};
use crate::isa::Supported;
use crate::view::{View, ViewMut};
use crate::{Isa, F32};

/// `dz = dy * act'(z)` element by element, `act'` read from the layer's
/// output `y` (see the module). All three views have one shape.
///
/// # Errors
/// [`Error::ShapeMismatch`] or [`Error::BadParameter`] when an argument's shape, band of rows or
/// parameter is not as described above.
pub fn activation_grad(
    act: Activation,
    y: &View<'_, f32>,
    dy: &View<'_, f32>,
    dz: &mut ViewMut<'_, f32>,
) -> Result<()> {
    check_shape("activation gradient", y.shape(), dy.shape())?;
    check_shape("activation gradient output", y.shape(), dz.shape())?;
    let s = match act {
        Activation::Identity => 1.0,
        Activation::Relu => 0.0,
        Activation::LeakyRelu(s) => {
            if !(0.0..=1.0).contains(&s) {
                return Err(Error::BadParameter { what: "leaky relu slope", expected: "in [0, 1]" });
            }
            s
        }
    };
    for c in 0..y.channels() {
        for r in 0..y.height() {
            let (yr, dyr) = (y.row(c, r), dy.row(c, r));
            for ((d, &yv), &g) in dz.row_mut(c, r).iter_mut().zip(yr).zip(dyr) {
                *d = if yv > 0.0 { g } else { s * g };
            }
        }
    }
    Ok(())
}

fn check_weights(k: usize, cin: usize, cout: usize, len: usize, what: &'static str) -> Result<usize> {
    if !KERNEL_SIZES.contains(&k) {
        return Err(Error::BadParameter { what: "conv kernel size", expected: "1, 3 or 5" });
    }
    if cin == 0 || cout == 0 {
        return Err(Error::BadParameter { what: "conv channels", expected: "at least one in and one out" });
    }
    let n = cout.checked_mul(cin).and_then(|v| v.checked_mul(k * k)).ok_or(Error::SizeOverflow { what })?;
    if len != n {
        return Err(Error::BufferTooSmall { what, needed: n, got: len });
    }
    Ok(n)
}

/// `out[ci][co][k-1-ky][k-1-kx] = w[co][ci][ky][kx]`: the weights of the
/// convolution that maps `dz` (cout channels) to `dx` (cin channels).
///
/// # Errors
/// [`Error::ShapeMismatch`] or [`Error::BadParameter`] when an argument's shape, band of rows or
/// parameter is not as described above.
pub fn transpose_weights(k: usize, cin: usize, cout: usize, w: &[f32], out: &mut [f32]) -> Result<()> {
    check_weights(k, cin, cout, w.len(), "conv weights")?;
    check_weights(k, cout, cin, out.len(), "transposed conv weights")?;
    for co in 0..cout {
        for ci in 0..cin {
            for ky in 0..k {
                for kx in 0..k {
                    out[((ci * cout + co) * k + (k - 1 - ky)) * k + (k - 1 - kx)] =
                        w[((co * cin + ci) * k + ky) * k + kx];
                }
            }
        }
    }
    Ok(())
}

/// Scratch words [`grad_input`] needs.
pub fn grad_input_scratch_len(k: usize, cin: usize, cout: usize, width: usize) -> usize {
    conv2d_scratch_len::<F32>(k, cout, cin, width)
}

/// `dx = W^T * dz` into rows `y0 .. y0 + dx.height()` of `dx` (`cin`
/// planes), from the whole `dz` (`cout` planes) and the weights transposed by
/// [`transpose_weights`].
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above; [`Error::ScratchTooSmall`] when `scratch` is shorter than this operator's
/// `*_scratch_len`.
#[allow(clippy::too_many_arguments)]
pub fn grad_input(
    isa: Isa,
    k: usize,
    cin: usize,
    cout: usize,
    transposed: &[f32],
    dz: &View<'_, f32>,
    dx: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let layer =
        Conv2d { k, cin: cout, cout: cin, weights: transposed, bias: None, act: Activation::Identity, weight_frac: 0 };
    conv2d::<F32>(isa, &layer, dz, dx, y0, scratch)
}

/// Adds the weight and bias gradients of rows `y0 .. y0 + rows` of `dz` to
/// `dw` (`cout * cin * k * k`, `[co][ci][ky][kx]`) and `db` (`cout`, or
/// none). `x`: the layer's whole input (`cin` planes); `dz`: the gradient of
/// its pre-activation output (`cout` planes, same size).
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
#[allow(clippy::too_many_arguments)]
pub fn grad_weights(
    isa: Isa,
    k: usize,
    x: &View<'_, f32>,
    dz: &View<'_, f32>,
    y0: usize,
    rows: usize,
    dw: &mut [f32],
    db: Option<&mut [f32]>,
) -> Result<()> {
    let isa = isa.check()?;
    let (cin, cout) = (x.channels(), dz.channels());
    check_weights(k, cin, cout, dw.len(), "conv weight gradient")?;
    let s = x.shape();
    check_shape("conv output gradient", Shape::new(cout, s.width, s.height), dz.shape())?;
    if y0.checked_add(rows).is_none_or(|e| e > s.height) {
        return Err(Error::BadParameter {
            what: "conv gradient rows",
            expected: "a band of rows inside the image (y0 + rows <= height)",
        });
    }
    if let Some(db) = db {
        if db.len() != cout {
            return Err(Error::BufferTooSmall { what: "conv bias gradient", needed: cout, got: db.len() });
        }
        for (co, d) in db.iter_mut().enumerate() {
            let mut t = 0.0f32;
            for y in y0..y0 + rows {
                t += dz.row(co, y).iter().sum::<f32>();
            }
            *d += t;
        }
    }
    if rows == 0 || s.width == 0 {
        return Ok(());
    }
    dispatch(isa, k, x, dz, y0, rows, dw);
    Ok(())
}

fn dispatch(isa: Supported, k: usize, x: &View<'_, f32>, dz: &View<'_, f32>, y0: usize, rows: usize, dw: &mut [f32]) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 => unsafe { avx2::grad_weights(k, x, dz, y0, rows, dw) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Isa::Avx512 => unsafe { avx512::grad_weights(k, x, dz, y0, rows, dw) },
        _ => grad_weights_scalar(k, x, dz, y0, rows, dw),
    }
}

/// The reference loop: per weight, rows then columns in order.
fn grad_weights_scalar(k: usize, x: &View<'_, f32>, dz: &View<'_, f32>, y0: usize, rows: usize, dw: &mut [f32]) {
    let (cin, cout, w, h) = (x.channels(), dz.channels(), x.width(), x.height());
    let p = k / 2;
    for co in 0..cout {
        for ci in 0..cin {
            for ky in 0..k {
                for kx in 0..k {
                    let mut s = 0.0f32;
                    for y in y0..y0 + rows {
                        let yy = y + ky;
                        if yy < p || yy - p >= h {
                            continue;
                        }
                        let (g, xr) = (dz.row(co, y), x.row(ci, yy - p));
                        // Columns whose tap x + kx - p is inside the image.
                        let lo = p.saturating_sub(kx);
                        let hi = (w + p).saturating_sub(kx).min(w);
                        for xo in lo..hi {
                            s += g[xo] * xr[xo + kx - p];
                        }
                    }
                    dw[((co * cin + ci) * k + ky) * k + kx] += s;
                }
            }
        }
    }
}

/// Rows per tile of the SIMD weight gradients.
#[cfg(target_arch = "x86_64")]
const ROW_TILE: usize = 8;

/// The output-channel blocks: near-equal sizes of at most `max`.
#[cfg(target_arch = "x86_64")]
fn blocks(cout: usize, max: usize) -> impl Iterator<Item = (usize, usize)> {
    let n = cout.div_ceil(max);
    (0..n).scan(0, move |co0, b| {
        let ob = cout / n + usize::from(b < cout % n);
        let r = (*co0, ob);
        *co0 += ob;
        Some(r)
    })
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use core::arch::x86_64::*;

    use super::{blocks, ROW_TILE};
    use crate::simd::avx2::load8_range;
    use crate::view::View;

    /// Sum of the eight lanes.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn hsum(v: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps::<0b01>(s, s));
        _mm_cvtss_f32(s)
    }

    /// One 8-pixel chunk at column `xo` (`len` pixels) of one row.
    ///
    /// # Safety
    /// AVX2/FMA; without `EDGE`, columns `xo - K/2 .. xo + 8 + K/2` of the
    /// rows are readable; with it, `xo + len <= w`.
    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    unsafe fn chunk<const K: usize, const OB: usize, const EDGE: bool>(
        acc: &mut [[__m256; K]; OB],
        gp: &[*const f32; OB],
        xp: *const f32,
        xo: usize,
        len: usize,
        w: usize,
    ) {
        let p = K / 2;
        let mut gv = [_mm256_setzero_ps(); OB];
        for o in 0..OB {
            // SAFETY: lanes below len are inside the row.
            gv[o] = unsafe {
                if EDGE {
                    load8_range(gp[o].add(xo), 0, len)
                } else {
                    _mm256_loadu_ps(gp[o].add(xo))
                }
            };
        }
        for kx in 0..K {
            let c0 = xo as isize + kx as isize - p as isize;
            // SAFETY: as the function's contract.
            let xv = unsafe {
                if EDGE {
                    let lo = (-c0).clamp(0, 8) as usize;
                    let hi = ((w as isize - c0).clamp(0, len as isize) as usize).max(lo);
                    load8_range(xp.wrapping_offset(c0), lo, hi)
                } else {
                    _mm256_loadu_ps(xp.offset(c0))
                }
            };
            for o in 0..OB {
                acc[o][kx] = _mm256_fmadd_ps(gv[o], xv, acc[o][kx]);
            }
        }
    }

    /// # Safety
    /// AVX2 and FMA must be supported; shapes checked by the caller.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub(super) unsafe fn grad_weights(
        k: usize,
        x: &View<'_, f32>,
        dz: &View<'_, f32>,
        y0: usize,
        rows: usize,
        dw: &mut [f32],
    ) {
        let cout = dz.channels();
        macro_rules! go {
            ($k:literal, $max:literal, [$($ob:literal),*]) => {
                for (co0, ob) in blocks(cout, $max) {
                    match ob {
                        $($ob => block::<$k, $ob>(x, dz, y0, rows, co0, dw),)*
                        _ => unreachable!("blocks are at most the maximum"),
                    }
                }
            };
        }
        // Accumulators: OB x K of the 16 registers.
        match k {
            1 => go!(1, 7, [1, 2, 3, 4, 5, 6, 7]),
            3 => go!(3, 3, [1, 2, 3]),
            _ => go!(5, 2, [1, 2]),
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma,f16c")]
    fn block<const K: usize, const OB: usize>(
        x: &View<'_, f32>,
        dz: &View<'_, f32>,
        y0: usize,
        rows: usize,
        co0: usize,
        dw: &mut [f32],
    ) {
        let (cin, w, h) = (x.channels(), x.width(), x.height());
        let p = K / 2;
        // Rows in tiles small enough that the block's rows of dz and x stay
        // in L1 across the (ci, ky) passes; each tile's sums go into dw.
        let mut yt = y0;
        while yt < y0 + rows {
            let yt1 = (yt + ROW_TILE).min(y0 + rows);
            for ci in 0..cin {
                for ky in 0..K {
                    let mut acc = [[_mm256_setzero_ps(); K]; OB];
                    for y in yt..yt1 {
                        let yy = y + ky;
                        if yy < p || yy - p >= h {
                            continue;
                        }
                        let xr = x.row(ci, yy - p);
                        let mut gp = [core::ptr::null::<f32>(); OB];
                        for (o, g) in gp.iter_mut().enumerate() {
                            *g = dz.row(co0 + o, y).as_ptr();
                        }
                        let xp = xr.as_ptr();
                        // SAFETY (every chunk): interior chunks lie inside
                        // the row; the edge ones read only their in-image lanes.
                        // The edge chunks in loops of their own, so the
                        // interior loop keeps its accumulators in registers.
                        let mut xo = 0;
                        while xo < w && xo < p {
                            unsafe { chunk::<K, OB, true>(&mut acc, &gp, xp, xo, (w - xo).min(8), w) };
                            xo += 8;
                        }
                        while xo + 8 + p <= w {
                            unsafe { chunk::<K, OB, false>(&mut acc, &gp, xp, xo, 8, w) };
                            xo += 8;
                        }
                        while xo < w {
                            unsafe { chunk::<K, OB, true>(&mut acc, &gp, xp, xo, (w - xo).min(8), w) };
                            xo += 8;
                        }
                    }
                    let cin_k = cin * K * K;
                    for o in 0..OB {
                        for kx in 0..K {
                            dw[(co0 + o) * cin_k + (ci * K + ky) * K + kx] += hsum(acc[o][kx]);
                        }
                    }
                }
            }
            yt = yt1;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use core::arch::x86_64::*;

    use super::{blocks, ROW_TILE};
    use crate::view::View;

    /// Lanes `lo .. hi` set.
    #[inline]
    fn lanes(lo: usize, hi: usize) -> __mmask16 {
        if hi <= lo {
            0
        } else {
            (((1u32 << hi) - 1) & !((1u32 << lo) - 1)) as __mmask16
        }
    }

    /// One 16-pixel chunk at column `xo` (`len` pixels) of one row: every
    /// column tap of `x` against the block's rows of `dz`.
    ///
    /// # Safety
    /// AVX-512; without `EDGE`, columns `xo - K/2 .. xo + 16 + K/2` of the
    /// rows are readable; with it, `xo + len <= w`.
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
    unsafe fn chunk<const K: usize, const OB: usize, const EDGE: bool>(
        acc: &mut [[__m512; K]; OB],
        gp: &[*const f32; OB],
        xp: *const f32,
        xo: usize,
        len: usize,
        w: usize,
    ) {
        let p = K / 2;
        let m = if EDGE { lanes(0, len) } else { 0xffff };
        let mut gv = [_mm512_setzero_ps(); OB];
        for o in 0..OB {
            // SAFETY: lanes below len are inside the row.
            gv[o] = unsafe { _mm512_maskz_loadu_ps(m, gp[o].add(xo)) };
        }
        for kx in 0..K {
            let c0 = xo as isize + kx as isize - p as isize;
            // SAFETY: as the function's contract.
            let xv = unsafe {
                if EDGE {
                    let lo = (-c0).clamp(0, 16) as usize;
                    let hi = (w as isize - c0).clamp(0, len as isize) as usize;
                    _mm512_maskz_loadu_ps(lanes(lo, hi), xp.wrapping_offset(c0))
                } else {
                    _mm512_loadu_ps(xp.offset(c0))
                }
            };
            for o in 0..OB {
                acc[o][kx] = _mm512_fmadd_ps(gv[o], xv, acc[o][kx]);
            }
        }
    }

    /// # Safety
    /// AVX-512 F must be supported; shapes checked by the caller.
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
    pub(super) unsafe fn grad_weights(
        k: usize,
        x: &View<'_, f32>,
        dz: &View<'_, f32>,
        y0: usize,
        rows: usize,
        dw: &mut [f32],
    ) {
        let cout = dz.channels();
        macro_rules! go {
            ($k:literal, $max:literal, [$($ob:literal),*]) => {
                for (co0, ob) in blocks(cout, $max) {
                    match ob {
                        $($ob => block::<$k, $ob>(x, dz, y0, rows, co0, dw),)*
                        _ => unreachable!("blocks are at most the maximum"),
                    }
                }
            };
        }
        // Accumulators: OB x K of the 32 registers.
        match k {
            1 => go!(1, 14, [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14]),
            3 => go!(3, 7, [1, 2, 3, 4, 5, 6, 7]),
            _ => go!(5, 4, [1, 2, 3, 4]),
        }
    }

    #[inline]
    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
    fn block<const K: usize, const OB: usize>(
        x: &View<'_, f32>,
        dz: &View<'_, f32>,
        y0: usize,
        rows: usize,
        co0: usize,
        dw: &mut [f32],
    ) {
        let (cin, w, h) = (x.channels(), x.width(), x.height());
        let p = K / 2;
        // Rows in tiles (see the AVX2 block).
        let mut yt = y0;
        while yt < y0 + rows {
            let yt1 = (yt + ROW_TILE).min(y0 + rows);
            for ci in 0..cin {
                for ky in 0..K {
                    let mut acc = [[_mm512_setzero_ps(); K]; OB];
                    for y in yt..yt1 {
                        let yy = y + ky;
                        if yy < p || yy - p >= h {
                            continue;
                        }
                        let xr = x.row(ci, yy - p);
                        let mut gp = [core::ptr::null::<f32>(); OB];
                        for (o, g) in gp.iter_mut().enumerate() {
                            *g = dz.row(co0 + o, y).as_ptr();
                        }
                        let xp = xr.as_ptr();
                        // SAFETY (every chunk): interior chunks lie inside
                        // the row; the edge ones read only their in-image lanes.
                        // The edge chunks in loops of their own, so the
                        // interior loop keeps its accumulators in registers.
                        let mut xo = 0;
                        while xo < w && xo < p {
                            unsafe { chunk::<K, OB, true>(&mut acc, &gp, xp, xo, (w - xo).min(16), w) };
                            xo += 16;
                        }
                        while xo + 16 + p <= w {
                            unsafe { chunk::<K, OB, false>(&mut acc, &gp, xp, xo, 16, w) };
                            xo += 16;
                        }
                        while xo < w {
                            unsafe { chunk::<K, OB, true>(&mut acc, &gp, xp, xo, (w - xo).min(16), w) };
                            xo += 16;
                        }
                    }
                    let cin_k = cin * K * K;
                    for o in 0..OB {
                        for kx in 0..K {
                            dw[(co0 + o) * cin_k + (ci * K + ky) * K + kx] += _mm512_reduce_add_ps(acc[o][kx]);
                        }
                    }
                }
            }
            yt = yt1;
        }
    }
}

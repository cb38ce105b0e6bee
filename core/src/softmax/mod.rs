//! Softmax operators: importance-weighted window filters (WSKP eq. 3–5) and
//! the per-pixel softmax across channels.
//!
//! ## The importance filter
//! `R(p) = sum_{q in W_k(p)} e(q) r(q) / sum_{q in W_k(p)} e(q)`, `e(q) = exp(I(q))`:
//! the weight of a neighbour is its own importance, shared by every window that
//! contains it. Out-of-image neighbours have weight zero (they leave numerator
//! and denominator). The fused form (eq. 5) runs `M` sizes with `M` importance
//! maps and mixes them with `alpha = softmax_M(F)` per pixel, then multiplies by
//! albedo: `out = albedo * sum_i alpha_i R_i`, in one pass that never builds a
//! kernel map.
//!
//! ## Shift strategy (why no input overflows or empties a window)
//! Subtracting a constant from every logit of a window changes nothing in exact
//! arithmetic. Logits are first clamped to `±LOGIT_LIMIT` (NaN counts as
//! `-LOGIT_LIMIT`, i.e. weight zero unless the whole window is NaN).
//! - [`WindowPath::Direct`] shifts each window by its own maximum: the largest
//!   weight is exactly 1, so the denominator is in `[1, k^2]` — no overflow,
//!   no 0/0, whatever the logits. Cost `k^2` per pixel per size.
//! - [`WindowPath::BoxSum`] shifts every weight of a tile (48 x 256 output
//!   pixels plus the halo) by the tile's maximum, so every weight is in `(0, 1]`
//!   and no sum overflows; the window sums are then separable box filters whose
//!   cost does not grow with `k`: horizontally by power-of-two doubling
//!   (`s2 = v + v>>1`, `s4 = s2 + s2>>2`, `s8 = s4 + s4>>4`, then one add per
//!   set bit of `k`: at most 6 adds for any `k <= 15`), vertically by the van
//!   Herk/Gil-Werman prefix/suffix split (3 adds whatever `k`). Neither ever
//!   subtracts, so a firefly or a weight 90 nats above its neighbours leaves no
//!   cancellation residue behind. A window whose denominator falls below
//!   `2^-100` (its logits all lie ~69 nats or more under the tile maximum —
//!   real WSKP maps span 97 nats in a frame) is recomputed with the direct
//!   path's window-local shift; above that threshold every weight that matters
//!   (within 2^-24 of the window sum) is a normal float, so the box result is as
//!   accurate as the direct one.
//! - [`WindowPath::Separable`] uses the box-sum path's tile shift and
//!   fallback, but sums each window directly: down the `k` rows of a ring of
//!   weight rows (in the ring's slot order, which depends only on the image
//!   row), then along `k` columns. Also subtraction-free; cost `2k` per pixel.

use crate::error::{check_scratch, check_shape, Error, Result, Shape};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::unfold::check_band;
use crate::view::{View, ViewMut};
use crate::{check_kernel_size, Isa};

pub(crate) mod fixed;
pub(crate) mod float;
pub mod grad;

/// Largest window size.
pub const MAX_WINDOW: usize = 15;
/// Most sizes the fused filter mixes.
pub const MAX_FUSED: usize = 8;
/// Most radiance channels the importance filters take.
pub const MAX_CHANNELS: usize = 4;
/// Logits are clamped to `±LOGIT_LIMIT` before use; NaN counts as `-LOGIT_LIMIT`.
pub const LOGIT_LIMIT: f32 = 1.0e30;
/// A box-sum window whose denominator is below this (2^-100) is recomputed with a window-local shift.
pub const TINY_DENOMINATOR: f32 = 7.888_609e-31;

/// How the window sums of the importance filters are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WindowPath {
    /// Every window summed tap by tap with its own max shift (`k^2` per pixel).
    Direct,
    /// Separable box sums over tile-shifted weights (cost independent of `k`).
    BoxSum,
    /// The box-sum path's tile shift and fallback, with each window summed
    /// directly along its rows and then its columns (`2k` adds per pixel per
    /// plane). More adds than [`WindowPath::BoxSum`] for large `k`, but one
    /// pass per row with no intermediate levels or prefix/suffix rows, and a
    /// ring of `k` weight rows small enough for L1: the fastest path for the
    /// WSKP sizes (3..13) on AVX2. Fixed point sums exactly (integers), so
    /// there it runs the box-sum code, which gives the same result.
    Separable,
}

/// The inputs of the fused importance filter (WSKP eq. 5).
#[derive(Clone, Copy, Debug)]
pub struct FusedInputs<'a, T> {
    /// Window sizes, one per importance map (odd, `1..=15`).
    pub sizes: &'a [usize],
    /// `M` planes of importance logits, one per size.
    pub importance: View<'a, T>,
    /// `M` planes of fusion logits (softmax over the `M` planes per pixel);
    /// may be `None` only when `M == 1`.
    pub fusion: Option<View<'a, T>>,
    /// Albedo to remodulate with (same channels as `radiance`), or `None`.
    pub albedo: Option<View<'a, T>>,
    /// The (demodulated) radiance to filter: `1..=4` channels.
    pub radiance: View<'a, T>,
}

/// Precisions the softmax operators are implemented for.
pub trait SoftmaxPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn fused_impl(
        chk: Checked,
        path: WindowPath,
        inp: &FusedInputs<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
        scratch: &mut [f32],
    );
    #[doc(hidden)]
    fn kernels_impl(
        chk: Checked,
        k: usize,
        logits: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
    );
    #[doc(hidden)]
    fn channel_impl(chk: Checked, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>);
}

macro_rules! float_softmax {
    ($p:ty) => {
        impl SoftmaxPrecision for $p {
            fn fused_impl(
                chk: Checked,
                path: WindowPath,
                inp: &FusedInputs<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
                scratch: &mut [f32],
            ) {
                float::fused(chk.isa(), path, inp, dst, y0, scratch)
            }
            fn kernels_impl(
                chk: Checked,
                k: usize,
                logits: &View<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
            ) {
                float::kernels(chk.isa(), k, logits, dst, y0)
            }
            fn channel_impl(chk: Checked, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>) {
                float::channel(chk.isa(), src, dst)
            }
        }
    };
}
float_softmax!(F32);
float_softmax!(F16);

impl SoftmaxPrecision for Fixed {
    fn fused_impl(
        chk: Checked,
        path: WindowPath,
        inp: &FusedInputs<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
        scratch: &mut [f32],
    ) {
        fixed::fused(chk.isa(), path, inp, dst, y0, scratch)
    }
    fn kernels_impl(_chk: Checked, k: usize, logits: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
        fixed::kernels(k, logits, dst, y0)
    }
    fn channel_impl(chk: Checked, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
        fixed::channel(chk.isa(), src, dst)
    }
}

impl SoftmaxPrecision for F16Arith {
    fn fused_impl(
        _chk: Checked,
        path: WindowPath,
        inp: &FusedInputs<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
        scratch: &mut [f32],
    ) {
        float::fused_scalar::<_, crate::real::H>(path, inp, dst, y0, scratch)
    }
    fn kernels_impl(
        _chk: Checked,
        k: usize,
        logits: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
    ) {
        float::scalar::kernels::<_, crate::real::H>(k, logits, dst, y0)
    }
    fn channel_impl(_chk: Checked, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>) {
        float::scalar::channel::<_, crate::real::H>(src, dst)
    }
}

/// Scratch words [`fused_filter`] needs for these sizes, channels and width
/// (independent of the number of output rows).
pub fn fused_scratch_len<P: SoftmaxPrecision>(
    path: WindowPath,
    sizes: &[usize],
    channels: usize,
    width: usize,
) -> usize {
    match path {
        WindowPath::Direct => 0,
        WindowPath::BoxSum if P::NAME == "fixed" => fixed::boxsum_scratch_len(sizes, channels, width),
        WindowPath::BoxSum => float::boxsum_scratch_len(sizes, channels, width),
        WindowPath::Separable if P::NAME == "fixed" => fixed::boxsum_scratch_len(sizes, channels, width),
        WindowPath::Separable => float::separable_scratch_len(sizes, channels, width),
    }
}

/// Scratch words [`window_filter`] needs.
pub fn window_scratch_len<P: SoftmaxPrecision>(path: WindowPath, k: usize, channels: usize, width: usize) -> usize {
    fused_scratch_len::<P>(path, &[k], channels, width)
}

/// The importance filter for one window size (WSKP eq. 3–4):
/// `dst = sum_q exp(I(q)) r(q) / sum_q exp(I(q))` over the `k x k` window.
/// `logits`: one plane, `radiance`'s width and height; `dst`: `radiance`'s channels and width, rows
/// `y0 ..`. Scratch: [`window_scratch_len`] f32 words.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::BadParameter`] when `k` is even or
/// above [`MAX_WINDOW`] or the rows are not inside the image; [`Error::ShapeMismatch`] when
/// `logits` or `dst` do not fit `radiance`; [`Error::ScratchTooSmall`] when `scratch` is shorter
/// than [`window_scratch_len`].
#[allow(clippy::too_many_arguments)]
pub fn window_filter<P: SoftmaxPrecision>(
    isa: Isa,
    path: WindowPath,
    k: usize,
    logits: &View<'_, P::Store>,
    radiance: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let sizes = [k];
    let inp = FusedInputs { sizes: &sizes, importance: *logits, fusion: None, albedo: None, radiance: *radiance };
    fused_filter::<P>(isa, path, &inp, dst, y0, scratch)
}

/// The fused importance filter (WSKP eq. 5) for output rows `y0 .. y0 + dst.height()`.
/// Shapes: one importance plane per size and, when given, one fusion plane per size and the albedo,
/// all of `inp.radiance`'s width and height; `dst`: the radiance's channels and width, rows `y0
/// ..`. Scratch: [`fused_scratch_len`] f32 words.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::BadParameter`] when there are no
/// sizes or more than [`MAX_FUSED`], a size is even or above [`MAX_WINDOW`], or the rows are not
/// inside the image; [`Error::ShapeMismatch`] when a plane does not fit the radiance;
/// [`Error::ScratchTooSmall`] when `scratch` is shorter than [`fused_scratch_len`].
pub fn fused_filter<P: SoftmaxPrecision>(
    isa: Isa,
    path: WindowPath,
    inp: &FusedInputs<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    let s = inp.radiance.shape();
    let m = inp.sizes.len();
    if m == 0 || m > MAX_FUSED {
        return Err(Error::BadParameter { what: "fused sizes", expected: "1 to 8 window sizes" });
    }
    for &k in inp.sizes {
        check_kernel_size("importance window size", k, MAX_WINDOW)?;
    }
    if s.channels == 0 || s.channels > MAX_CHANNELS {
        return Err(Error::BadParameter { what: "radiance channels", expected: "1 to 4 channels" });
    }
    check_shape("importance maps", Shape::new(m, s.width, s.height), inp.importance.shape())?;
    match inp.fusion {
        Some(f) => check_shape("fusion logits", Shape::new(m, s.width, s.height), f.shape())?,
        None if m > 1 => {
            return Err(Error::BadParameter {
                what: "fusion logits",
                expected: "present when more than one size is fused",
            })
        }
        None => {}
    }
    if let Some(a) = inp.albedo {
        check_shape("albedo", s, a.shape())?;
    }
    check_band("filtered output", s, dst.shape(), y0)?;
    check_scratch(fused_scratch_len::<P>(path, inp.sizes, s.channels, s.width), scratch.len())?;
    if dst.height() == 0 || s.width == 0 {
        return Ok(());
    }
    P::fused_impl(chk, path, inp, dst, y0, scratch);
    Ok(())
}

/// Materialises the per-pixel kernels of one importance map (WSKP eq. 3):
/// plane `j` of `dst` is `w_p(p + o_j) = exp(I(p + o_j)) / sum_{q in W_k(p)} exp(I(q))`
/// for in-image taps, 0 for taps outside. Each pixel's weights sum to one.
/// `dst` holds `k*k` planes for rows `y0 ..`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::BadParameter`] when `k` is even or
/// above [`MAX_WINDOW`], `logits` is not one plane, or the rows are not inside the image;
/// [`Error::ShapeMismatch`] when `dst` is not `k*k` planes of `logits`' width.
pub fn importance_kernels<P: SoftmaxPrecision>(
    isa: Isa,
    k: usize,
    logits: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    check_kernel_size("importance window size", k, MAX_WINDOW)?;
    let s = logits.shape();
    if s.channels != 1 {
        return Err(Error::BadParameter { what: "importance logits", expected: "one plane" });
    }
    check_band("kernel map", Shape::new(k * k, s.width, s.height), dst.shape(), y0)?;
    if dst.height() == 0 || s.width == 0 {
        return Ok(());
    }
    P::kernels_impl(chk, k, logits, dst, y0);
    Ok(())
}

/// Softmax across the planes of `src` at every pixel (max-shifted: the
/// largest logit weighs exactly 1 before normalisation, so any finite or
/// infinite logits give weights in `[0, 1]` summing to one; NaN counts as
/// `-LOGIT_LIMIT`). `dst` has the shape of `src`.
/// No scratch.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] when `dst`'s shape
/// differs from `src`'s.
pub fn channel_softmax<P: SoftmaxPrecision>(
    isa: Isa,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    check_shape("channel softmax output", src.shape(), dst.shape())?;
    if src.channels() == 0 || src.width() == 0 || src.height() == 0 {
        return Ok(());
    }
    P::channel_impl(chk, src, dst);
    Ok(())
}

/// Clamps a logit to `±LOGIT_LIMIT`; NaN becomes `-LOGIT_LIMIT`.
#[inline(always)]
pub(crate) fn clamp_logit(x: f32) -> f32 {
    x.max(-LOGIT_LIMIT).min(LOGIT_LIMIT)
}

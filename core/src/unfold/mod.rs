//! Per-pixel kernel apply ("unfold"):
//! `out_c(p) = sum_j K_j(p) * r_c(p + o_j)` for an odd kernel size `k` in `1..=15`.
//!
//! The kernel map is planar: plane `j` holds tap `j` of every pixel, taps in
//! row-major order (`j = (dy + r) * k + (dx + r)`, `r = k / 2`). Taps that fall
//! outside the image contribute zero (the kernel is not renormalised; a
//! caller that wants renormalisation builds it into the kernel, as the
//! softmax operators do). Every path sums the taps of a pixel in ascending
//! `j`, so the paths differ only by FMA rounding.
//!
//! 7x7 (AFN) and every other odd size up to 15 have a register-blocked AVX2
//! path: eight pixels at a time, all taps, up to four channels held in
//! registers, so each kernel plane is streamed exactly once.

use crate::error::{check_scratch, check_shape, Result, Shape};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::view::{View, ViewMut};
use crate::{check_kernel_size, Isa};

pub(crate) mod fixed;
pub(crate) mod float;
pub mod grad;

/// Largest kernel size.
pub const MAX_KERNEL: usize = 15;

/// Precisions the unfold operator is implemented for.
pub trait UnfoldPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn scratch_len_impl(k: usize, channels: usize, width: usize) -> usize;
    #[doc(hidden)]
    fn apply_impl(
        chk: Checked,
        k: usize,
        kernel: &View<'_, Self::Store>,
        src: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
        scratch: &mut [f32],
    );
}

macro_rules! float_unfold {
    ($p:ty, $a:ty) => {
        impl UnfoldPrecision for $p {
            fn scratch_len_impl(k: usize, channels: usize, width: usize) -> usize {
                float::scratch_len::<<$p as Precision>::Store>(k, channels, width)
            }
            fn apply_impl(
                chk: Checked,
                k: usize,
                kernel: &View<'_, Self::Store>,
                src: &View<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
                scratch: &mut [f32],
            ) {
                float::run::<_, $a>(chk.isa(), k, kernel, src, dst, y0, scratch)
            }
        }
    };
}
float_unfold!(F32, f32);
float_unfold!(F16, f32);
float_unfold!(F16Arith, crate::real::H);

impl UnfoldPrecision for Fixed {
    fn scratch_len_impl(_k: usize, _channels: usize, _width: usize) -> usize {
        0
    }
    fn apply_impl(
        chk: Checked,
        k: usize,
        kernel: &View<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
        _scratch: &mut [f32],
    ) {
        fixed::run(chk.isa(), k, kernel, src, dst, y0)
    }
}

/// Scratch words [`apply`] and [`apply_rows`] need.
pub fn scratch_len<P: UnfoldPrecision>(k: usize, channels: usize, width: usize) -> usize {
    P::scratch_len_impl(k, channels, width)
}

/// Applies a `k x k` per-pixel kernel map to every channel of `src`.
///
/// `kernel`: `k*k` planes, same width and height as `src`; `dst`: same shape as `src`.
/// Scratch: [`scratch_len`]`::<P>(k, src.channels(), src.width())` f32 words.
///
/// # Errors
/// [`Error::IsaUnsupported`](crate::Error::IsaUnsupported) when this CPU lacks `isa`;
/// [`Error::BadParameter`](crate::Error::BadParameter) when `k` is even or above [`MAX_KERNEL`];
/// [`Error::ShapeMismatch`](crate::Error::ShapeMismatch) when `kernel` is not `k*k` planes of
/// `src`'s size or `dst` not `src`'s shape;
/// [`Error::ScratchTooSmall`](crate::Error::ScratchTooSmall) when `scratch` is shorter than
/// [`scratch_len`].
pub fn apply<P: UnfoldPrecision>(
    isa: Isa,
    k: usize,
    kernel: &View<'_, P::Store>,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    scratch: &mut [f32],
) -> Result<()> {
    check_shape("unfold output", src.shape(), dst.shape())?;
    apply_rows::<P>(isa, k, kernel, src, dst, 0, scratch)
}

/// Like [`apply`] for the output rows `y0 .. y0 + dst.height()` only; `dst`
/// holds just those rows.
/// Scratch: [`scratch_len`]`::<P>(k, src.channels(), src.width())` f32 words.
///
/// # Errors
/// As [`apply`], and [`Error::BadParameter`](crate::Error::BadParameter) when the rows `y0 .. y0 +
/// dst.height()` are not inside `src`.
pub fn apply_rows<P: UnfoldPrecision>(
    isa: Isa,
    k: usize,
    kernel: &View<'_, P::Store>,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    check_kernel_size("unfold kernel size", k, MAX_KERNEL)?;
    let s = src.shape();
    check_shape("unfold kernel map", Shape::new(k * k, s.width, s.height), kernel.shape())?;
    check_band("unfold output", s, dst.shape(), y0)?;
    check_scratch(scratch_len::<P>(k, s.channels, s.width), scratch.len())?;
    if dst.height() == 0 || s.width == 0 || s.channels == 0 {
        return Ok(());
    }
    P::apply_impl(chk, k, kernel, src, dst, y0, scratch);
    Ok(())
}

/// Checks that `band` is rows `y0 ..` of an image of shape `full`.
pub(crate) fn check_band(what: &'static str, full: Shape, band: Shape, y0: usize) -> Result<()> {
    let fits = y0.checked_add(band.height).is_some_and(|e| e <= full.height);
    let expected = Shape::new(full.channels, full.width, band.height);
    if !fits {
        return Err(crate::Error::BadParameter {
            what,
            expected: "a band of rows inside the image (y0 + rows <= height)",
        });
    }
    check_shape(what, expected, band)
}

/// [`check_band`] for a second output of the same call: it must also cover exactly `rows` rows,
/// the rows of the call's first band (the kernels index every band by the first one's rows).
pub(crate) fn check_band_rows(what: &'static str, full: Shape, band: Shape, y0: usize, rows: usize) -> Result<()> {
    check_band(what, full, band, y0)?;
    check_shape(what, Shape::new(full.channels, full.width, rows), band)
}

//! Two-scale operators: 2x2 average pool `D`, nearest-neighbour 2x upsample
//! `U`, the scale compositor `o = f - a U(D(f)) + a U(c)` (AFN eq. 3, WSKP
//! eq. 7), and 2x2 max pool for the U-Nets.
//!
//! ## Odd sizes
//! A `W x H` image pools to `ceil(W/2) x ceil(H/2)`. Coarse cell `(X, Y)`
//! covers the fine pixels `{2X, 2X+1} x {2Y, 2Y+1}` that lie inside the image
//! (4, 2 or 1 of them) and `D` averages exactly those; `U` repeats each coarse
//! pixel over its cell and crops at the border. So `D(U(c)) = c` holds at every
//! size, bit for bit (the mean of equal floats is exact below 8e37), and the
//! compositor with `a = 0` returns `f` exactly.
//!
//! Summation order (all paths): columns of a cell are summed first, then the
//! two column sums: `((f00 + f10) + (f01 + f11)) * 0.25`.

use crate::error::{check_shape, Error, Result, Shape};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::unfold::check_band;
use crate::view::{View, ViewMut};
use crate::Isa;

pub(crate) mod fixed;
pub(crate) mod float;
pub mod grad;

/// The coarse size of a fine size: `ceil(n / 2)`.
pub const fn coarse(n: usize) -> usize {
    n.div_ceil(2)
}

/// Which 2x2 reduction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reduce {
    /// Mean of the in-image pixels of the cell.
    Mean,
    /// Maximum of the in-image pixels (a NaN loses to any number).
    Max,
}

/// Precisions the pool operators are implemented for.
pub trait PoolPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn reduce_impl(
        chk: Checked,
        op: Reduce,
        src: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
    );
    #[doc(hidden)]
    fn upsample_impl(chk: Checked, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>, y0: usize);
    #[doc(hidden)]
    fn composite_impl(
        chk: Checked,
        fine: &View<'_, Self::Store>,
        coarse: &View<'_, Self::Store>,
        alpha: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
    );
}

macro_rules! float_pool {
    ($p:ty, $a:ty) => {
        impl PoolPrecision for $p {
            fn reduce_impl(
                chk: Checked,
                op: Reduce,
                src: &View<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
            ) {
                float::reduce::<_, $a>(chk.isa(), op, src, dst, y0)
            }
            fn upsample_impl(chk: Checked, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>, y0: usize) {
                float::upsample::<_, $a>(chk.isa(), src, dst, y0)
            }
            fn composite_impl(
                chk: Checked,
                fine: &View<'_, Self::Store>,
                coarse: &View<'_, Self::Store>,
                alpha: &View<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
            ) {
                float::composite::<_, $a>(chk.isa(), fine, coarse, alpha, dst, y0)
            }
        }
    };
}
float_pool!(F32, f32);
float_pool!(F16, f32);
float_pool!(F16Arith, crate::real::H);

impl PoolPrecision for Fixed {
    fn reduce_impl(chk: Checked, op: Reduce, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
        fixed::reduce(chk.isa(), op, src, dst, y0)
    }
    fn upsample_impl(chk: Checked, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
        fixed::upsample(chk.isa(), src, dst, y0)
    }
    fn composite_impl(
        chk: Checked,
        fine: &View<'_, i16>,
        coarse: &View<'_, i16>,
        alpha: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
    ) {
        fixed::composite(chk.isa(), fine, coarse, alpha, dst, y0)
    }
}

/// 2x2 reduction (mean or max) of `src` into coarse rows `y0 .. y0 + dst.height()`;
/// the full coarse image is `ceil(W/2) x ceil(H/2)`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn reduce2x2<P: PoolPrecision>(
    isa: Isa,
    op: Reduce,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    let s = src.shape();
    let full = Shape::new(s.channels, coarse(s.width), coarse(s.height));
    check_band("pooled output", full, dst.shape(), y0)?;
    if dst.height() == 0 || s.width == 0 || s.channels == 0 {
        return Ok(());
    }
    P::reduce_impl(chk, op, src, dst, y0);
    Ok(())
}

/// 2x2 average pool, whole image.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn avg_pool2x2<P: PoolPrecision>(
    isa: Isa,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
) -> Result<()> {
    check_whole(src.shape(), dst.shape())?;
    reduce2x2::<P>(isa, Reduce::Mean, src, dst, 0)
}

/// 2x2 max pool, whole image.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn max_pool2x2<P: PoolPrecision>(
    isa: Isa,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
) -> Result<()> {
    check_whole(src.shape(), dst.shape())?;
    reduce2x2::<P>(isa, Reduce::Max, src, dst, 0)
}

fn check_whole(s: Shape, d: Shape) -> Result<()> {
    check_shape("pooled output", Shape::new(s.channels, coarse(s.width), coarse(s.height)), d)
}

/// Nearest-neighbour 2x upsample of the coarse `src` into fine rows
/// `y0 .. y0 + dst.height()` of a `W x H` image with `ceil(W/2) = src.width()`
/// and `ceil(H/2) = src.height()`; `full_height` is `H`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn upsample_nearest2x<P: PoolPrecision>(
    isa: Isa,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
    full_height: usize,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    let s = src.shape();
    let d = dst.shape();
    if coarse(d.width) != s.width || coarse(full_height) != s.height {
        return Err(Error::ShapeMismatch {
            what: "upsample input (must be ceil(W/2) x ceil(H/2) of the output)",
            expected: Shape::new(d.channels, coarse(d.width), coarse(full_height)),
            got: s,
        });
    }
    check_band("upsampled output", Shape::new(s.channels, d.width, full_height), d, y0)?;
    if d.height == 0 || d.width == 0 || d.channels == 0 {
        return Ok(());
    }
    P::upsample_impl(chk, src, dst, y0);
    Ok(())
}

/// The scale compositor `o = f - a U(D(f)) + a U(c)` for fine rows `y0 ..`:
/// replaces the low band of the fine image `f` by the coarse image `c` with
/// per-pixel weight `a` (1 plane, or one per channel).
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn composite<P: PoolPrecision>(
    isa: Isa,
    fine: &View<'_, P::Store>,
    coarse_img: &View<'_, P::Store>,
    alpha: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    let f = fine.shape();
    check_shape("coarse image", Shape::new(f.channels, coarse(f.width), coarse(f.height)), coarse_img.shape())?;
    let a = alpha.shape();
    if (a.channels != 1 && a.channels != f.channels) || a.width != f.width || a.height != f.height {
        return Err(Error::ShapeMismatch {
            what: "compositing weights (1 plane or one per channel)",
            expected: Shape::new(1, f.width, f.height),
            got: a,
        });
    }
    check_band("composited output", f, dst.shape(), y0)?;
    if dst.height() == 0 || f.width == 0 || f.channels == 0 {
        return Ok(());
    }
    P::composite_impl(chk, fine, coarse_img, alpha, dst, y0);
    Ok(())
}

//! Per-pixel maps: albedo demodulation and remodulation, input sanitising,
//! gamma and filmic tone mapping, `log1p` / `expm1` range compression.
//!
//! - Demodulation divides by `albedo + eps` and remodulation multiplies by
//!   the same `albedo + eps`, so the round trip is the identity up to two
//!   roundings and a zero albedo (sky, emitters) never divides by zero; `eps`
//!   must be positive (WSKP and KPCN use about 1e-3 to 1e-2).
//! - [`Map::Sanitize`] is the input contract's first step: NaN becomes 0 and
//!   values are clamped to `[-limit, limit]` (so ±inf becomes ±limit).
//! - [`Map::Gamma`] is `clamp(x, 0, 1)^(1/g)` (or `max(x, 0)^(1/g)` unclamped),
//!   [`Map::Filmic`] the ACES fit of Narkowicz (2015) clamped to [0, 1],
//!   [`Map::Log1p`] is `ln(1 + max(x, 0))` and [`Map::Expm1`] `e^x - 1`.
//!   NaN maps to 0 in every tone map.

use crate::error::{check_shape, Error, Result};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::view::{View, ViewMut};
use crate::Isa;

pub(crate) mod fixed;
pub(crate) mod float;

/// An elementwise map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Map {
    /// NaN to 0, clamp to `[-limit, limit]`.
    Sanitize {
        /// The clamp bound (positive).
        limit: f32,
    },
    /// `x^(1/gamma)` of `clamp(x, 0, 1)` (or of `max(x, 0)` when not clamped).
    Gamma {
        /// The display gamma (e.g. 2.2).
        gamma: f32,
        /// Clamp to [0, 1] first.
        clamp: bool,
    },
    /// ACES filmic fit `x(2.51x + 0.03) / (x(2.43x + 0.59) + 0.14)` on `max(x, 0)`, clamped to [0, 1].
    Filmic,
    /// `ln(1 + max(x, 0))`.
    Log1p,
    /// `e^x - 1`.
    Expm1,
}

impl Map {
    /// The map applied to one value: the scalar reference of every path.
    #[inline]
    pub fn apply(self, x: f32) -> f32 {
        use crate::math::scalar as m;
        // NaN to 0 up front (fails every comparison below otherwise).
        let x = if x.is_nan() { 0.0 } else { x };
        match self {
            Map::Sanitize { limit } => x.max(-limit).min(limit),
            Map::Gamma { gamma, clamp } => {
                let v = if clamp { x.max(0.0).min(1.0) } else { x.max(0.0) };
                m::pow(v, 1.0 / gamma)
            }
            Map::Filmic => {
                let v = x.max(0.0).min(1.0e18);
                let r = (v * (2.51 * v + 0.03)) / (v * (2.43 * v + 0.59) + 0.14);
                r.max(0.0).min(1.0)
            }
            Map::Log1p => m::log1p(x.max(0.0)),
            Map::Expm1 => m::expm1(x),
        }
    }

    fn check(self) -> Result<()> {
        match self {
            Map::Sanitize { limit } if !(limit > 0.0) => {
                Err(Error::BadParameter { what: "sanitize limit", expected: "a positive number" })
            }
            Map::Gamma { gamma, .. } if !(gamma > 0.0 && gamma.is_finite()) => {
                Err(Error::BadParameter { what: "gamma", expected: "a positive finite number" })
            }
            _ => Ok(()),
        }
    }
}

/// Precisions the per-pixel maps are implemented for.
pub trait TonemapPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn map_impl(chk: Checked, op: Map, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>);
    #[doc(hidden)]
    fn modulate_impl(
        chk: Checked,
        divide: bool,
        src: &View<'_, Self::Store>,
        albedo: &View<'_, Self::Store>,
        eps: f32,
        dst: &mut ViewMut<'_, Self::Store>,
    );
}

macro_rules! float_tonemap {
    ($p:ty, $a:ty) => {
        impl TonemapPrecision for $p {
            fn map_impl(chk: Checked, op: Map, src: &View<'_, Self::Store>, dst: &mut ViewMut<'_, Self::Store>) {
                float::map::<_, $a>(chk.isa(), op, src, dst)
            }
            fn modulate_impl(
                chk: Checked,
                divide: bool,
                src: &View<'_, Self::Store>,
                albedo: &View<'_, Self::Store>,
                eps: f32,
                dst: &mut ViewMut<'_, Self::Store>,
            ) {
                float::modulate::<_, $a>(chk.isa(), divide, src, albedo, eps, dst)
            }
        }
    };
}
float_tonemap!(F32, f32);
float_tonemap!(F16, f32);
float_tonemap!(F16Arith, crate::real::H);

impl TonemapPrecision for Fixed {
    fn map_impl(_chk: Checked, op: Map, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
        fixed::map(op, src, dst)
    }
    fn modulate_impl(
        _chk: Checked,
        divide: bool,
        src: &View<'_, i16>,
        albedo: &View<'_, i16>,
        eps: f32,
        dst: &mut ViewMut<'_, i16>,
    ) {
        fixed::modulate(divide, src, albedo, eps, dst)
    }
}

/// Applies `op` to every element of `src` into `dst` (same shape; they may
/// not alias — run it in place through a copy).
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn map<P: TonemapPrecision>(
    isa: Isa,
    op: Map,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    op.check()?;
    check_shape("mapped output", src.shape(), dst.shape())?;
    P::map_impl(chk, op, src, dst);
    Ok(())
}

fn check_modulate(src_shape: crate::Shape, albedo: crate::Shape, dst: crate::Shape, eps: f32) -> Result<()> {
    if !(eps > 0.0 && eps.is_finite()) {
        return Err(Error::BadParameter { what: "albedo epsilon", expected: "a positive finite number" });
    }
    check_shape("albedo", src_shape, albedo)?;
    check_shape("modulated output", src_shape, dst)
}

/// `dst = src / (albedo + eps)`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn demodulate<P: TonemapPrecision>(
    isa: Isa,
    src: &View<'_, P::Store>,
    albedo: &View<'_, P::Store>,
    eps: f32,
    dst: &mut ViewMut<'_, P::Store>,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    check_modulate(src.shape(), albedo.shape(), dst.shape(), eps)?;
    P::modulate_impl(chk, true, src, albedo, eps, dst);
    Ok(())
}

/// `dst = src * (albedo + eps)`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn remodulate<P: TonemapPrecision>(
    isa: Isa,
    src: &View<'_, P::Store>,
    albedo: &View<'_, P::Store>,
    eps: f32,
    dst: &mut ViewMut<'_, P::Store>,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    check_modulate(src.shape(), albedo.shape(), dst.shape(), eps)?;
    P::modulate_impl(chk, false, src, albedo, eps, dst);
    Ok(())
}

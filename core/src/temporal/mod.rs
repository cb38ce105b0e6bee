//! Temporal accumulation (BMFR-style, reused by WSKP and AFN): reproject the
//! previous accumulated colour into the current frame and blend.
//!
//! For each pixel `p`:
//! 1. The previous position of `p` is `p + motion(p)` (pixels; pixel centres at
//!    `x + 0.5`). Without motion vectors it is found by world position: the
//!    previous frame's pixel within `search_radius` of `p` whose world position
//!    is closest to `position(p)` (the previous frame's position buffer is the
//!    lookup table); that pixel is taken whole (one tap, weight 1).
//! 2. With motion, the four pixels around the previous position are the
//!    bilinear taps. A tap counts only if it is inside the image and its
//!    geometry agrees: `|pos_prev - pos|^2 < pos_limit^2` and
//!    `|n_prev - n|^2 < normal_limit^2` and `|a_prev - a|^2 < albedo_limit^2`
//!    for the albedo `a` (each test only when both buffers are present).
//!    Accepted taps are renormalised by their bilinear weights. The albedo
//!    test keeps an emitter seen directly (albedo 0) and the lit surface
//!    it lies on apart: their positions and normals may agree, and a
//!    bilinear tap across the light's outline would otherwise smear it into
//!    the surface (and the surface into it) as the camera moves.
//! 3. No accepted tap: the pixel restarts, `out = colour`, history 0. Else with
//!    the reprojected history `n` (bilinear over the accepted taps) and
//!    colour `prev`: `alpha = max(1 / (n + 1), alpha_min)`,
//!    `out = alpha colour + (1 - alpha) prev`, history `min(n + 1, cap)`.
//! 4. With `clamp_sigma = k > 0`, before the blend `prev` is clamped per
//!    channel to `mu -+ k sqrt(sigma^2 + (clamp_floor prev)^2)`, with the
//!    mean and the variance (population) of the current colour over the
//!    `(2 clamp_radius + 1)^2` window around `p` (its in-image pixels): a
//!    history that the current frame's neighbourhood cannot explain (a
//!    light that moved or switched, a shadow that left) gives way to it
//!    instead of lagging for `1 / alpha_min` frames. The statistics come
//!    from sums of the values and their squares over the window, in f64 in
//!    the float precisions (f16 squares overflow), exactly in integers (an
//!    integer square root) in fixed point. A window with a
//!    non-finite value leaves `prev` unclamped.
//!
//! `pos_limit` is in world units; the host derives it from the scene scale
//! (a fraction of the frame's position bounding-box diagonal).

use crate::error::{check_shape, Error, Result, Shape};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::unfold::{check_band, check_band_rows};
use crate::view::{View, ViewMut};
use crate::Isa;

pub(crate) mod fixed;
pub(crate) mod float;

/// Tuning of the accumulation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TemporalParams {
    /// Largest accepted world-position distance between a pixel and a tap.
    pub pos_limit: f32,
    /// Largest accepted distance between unit normals (0.3 is about 17 degrees).
    pub normal_limit: f32,
    /// Smallest blend weight of the current frame (0.2 in BMFR).
    pub alpha_min: f32,
    /// Largest history count kept.
    pub history_cap: f32,
    /// Search radius (pixels) for reprojection by world position without motion vectors.
    pub search_radius: usize,
    /// Largest accepted distance between albedos (RGB).
    pub albedo_limit: f32,
    /// The history clamp's width in standard deviations of the current
    /// colour's neighbourhood (0: no clamp, as BMFR).
    pub clamp_sigma: f32,
    /// The history clamp's window radius (pixels; at most 8).
    pub clamp_radius: usize,
    /// The history clamp's floor: the window's variance is widened by
    /// `(clamp_floor prev)^2`, so that a window of zeros (a dim surface at
    /// 1 spp) cannot wipe a history out (at most `1 - k clamp_floor` of it
    /// goes in a frame).
    pub clamp_floor: f32,
}

impl Default for TemporalParams {
    fn default() -> Self {
        TemporalParams {
            pos_limit: 0.01,
            normal_limit: 0.3,
            alpha_min: 0.2,
            history_cap: 64.0,
            search_radius: 2,
            albedo_limit: 0.3,
            clamp_sigma: 0.0,
            clamp_radius: 2,
            clamp_floor: 0.5,
        }
    }
}

/// Current and previous buffers of one accumulation step.
#[derive(Clone, Copy, Debug)]
pub struct TemporalInputs<'a, T> {
    /// Current noisy colour (any number of channels, usually 3).
    pub color: View<'a, T>,
    /// Current world-space normal (3 planes), if known.
    pub normal: Option<View<'a, T>>,
    /// Current world position (3 planes), if known.
    pub position: Option<View<'a, T>>,
    /// Motion in pixels (2 planes: x, y) with `previous = current + motion`.
    pub motion: Option<View<'a, T>>,
    /// The previous accumulated colour.
    pub prev_color: View<'a, T>,
    /// The previous frame's normal, if known.
    pub prev_normal: Option<View<'a, T>>,
    /// The previous frame's position, if known.
    pub prev_position: Option<View<'a, T>>,
    /// Current albedo (3 planes), if known.
    pub albedo: Option<View<'a, T>>,
    /// The previous frame's albedo, if known.
    pub prev_albedo: Option<View<'a, T>>,
    /// The previous history counts (1 plane).
    pub prev_history: View<'a, T>,
}

/// Precisions temporal accumulation is implemented for.
pub trait TemporalPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn accumulate_impl(
        chk: Checked,
        inp: &TemporalInputs<'_, Self::Store>,
        params: &TemporalParams,
        color: &mut ViewMut<'_, Self::Store>,
        history: &mut ViewMut<'_, Self::Store>,
        y0: usize,
    );
}

macro_rules! float_temporal {
    ($p:ty, $a:ty) => {
        impl TemporalPrecision for $p {
            fn accumulate_impl(
                chk: Checked,
                inp: &TemporalInputs<'_, Self::Store>,
                params: &TemporalParams,
                color: &mut ViewMut<'_, Self::Store>,
                history: &mut ViewMut<'_, Self::Store>,
                y0: usize,
            ) {
                float::accumulate::<_, $a>(chk.isa(), inp, params, color, history, y0)
            }
        }
    };
}
float_temporal!(F32, f32);
float_temporal!(F16, f32);
float_temporal!(F16Arith, crate::real::H);

impl TemporalPrecision for Fixed {
    fn accumulate_impl(
        _chk: Checked,
        inp: &TemporalInputs<'_, i16>,
        params: &TemporalParams,
        color: &mut ViewMut<'_, i16>,
        history: &mut ViewMut<'_, i16>,
        y0: usize,
    ) {
        fixed::accumulate(inp, params, color, history, y0)
    }
}

/// One accumulation step for output rows `y0 .. y0 + color.height()`.
/// Needs either `motion` or both `position` and `prev_position`.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; [`Error::ShapeMismatch`] or
/// [`Error::BadParameter`] when an argument's shape, band of rows or parameter is not as described
/// above.
pub fn accumulate<P: TemporalPrecision>(
    isa: Isa,
    inp: &TemporalInputs<'_, P::Store>,
    params: &TemporalParams,
    color: &mut ViewMut<'_, P::Store>,
    history: &mut ViewMut<'_, P::Store>,
    y0: usize,
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    let s = inp.color.shape();
    let plane = |c| Shape::new(c, s.width, s.height);
    check_shape("previous colour", s, inp.prev_color.shape())?;
    check_shape("previous history", plane(1), inp.prev_history.shape())?;
    for (what, v, c) in [
        ("normal", inp.normal, 3),
        ("position", inp.position, 3),
        ("motion", inp.motion, 2),
        ("previous normal", inp.prev_normal, 3),
        ("previous position", inp.prev_position, 3),
        ("albedo", inp.albedo, 3),
        ("previous albedo", inp.prev_albedo, 3),
    ] {
        if let Some(v) = v {
            check_shape(what, plane(c), v.shape())?;
        }
    }
    if inp.motion.is_none() && (inp.position.is_none() || inp.prev_position.is_none()) {
        return Err(Error::BadParameter {
            what: "temporal reprojection",
            expected: "motion vectors, or current and previous world positions",
        });
    }
    if !(params.pos_limit >= 0.0 && params.normal_limit >= 0.0 && params.albedo_limit >= 0.0) {
        return Err(Error::BadParameter { what: "temporal limits", expected: "non-negative numbers" });
    }
    if !(params.alpha_min > 0.0 && params.alpha_min <= 1.0) {
        return Err(Error::BadParameter { what: "temporal alpha_min", expected: "in (0, 1]" });
    }
    if !(params.history_cap >= 0.0) || params.search_radius > 16 {
        return Err(Error::BadParameter {
            what: "temporal history cap / search radius",
            expected: "a non-negative cap and a radius up to 16",
        });
    }
    if !(params.clamp_sigma >= 0.0 && params.clamp_sigma <= 1e6)
        || params.clamp_radius > 8
        || !(params.clamp_floor >= 0.0 && params.clamp_floor <= 1e3)
    {
        return Err(Error::BadParameter {
            what: "temporal history clamp",
            expected: "a width of 0 (off) up to 1e6 standard deviations, a radius up to 8 and a floor from 0 to 1e3",
        });
    }
    check_band("accumulated colour", s, color.shape(), y0)?;
    check_band_rows("accumulated history", plane(1), history.shape(), y0, color.height())?;
    if color.height() == 0 || s.width == 0 {
        return Ok(());
    }
    P::accumulate_impl(chk, inp, params, color, history, y0);
    Ok(())
}

//! Edge-avoiding à-trous wavelet filtering (Dammertz et al. 2010) and the
//! SURE-based shrinkage of its detail coefficients (Kim, Moon, Yoon 2016).
//!
//! ## One step
//! `c_{i+1}(p) = sum_q w(p, q) c_i(q) / sum_q w(p, q)` over the 5x5 taps
//! `q = p + 2^i (dx, dy)`, `dx, dy in -2..=2`, with
//! `w = h(dx) h(dy) exp(-(t_colour + t_normal + t_geometry))`,
//! `h = (1/16, 1/4, 3/8, 1/4, 1/16)` (B3 spline), out-of-image taps left out:
//! - `t_colour = |g(p) - g(q)|^2 / (phi_color 2^-i min(v(p), v(q)) + eps)`:
//!   `g` is the colour guide (the first of the images filtered together), `v`
//!   the input's per-pixel noise variance (a negative one counts as 0), so
//!   colour stops edges relative to
//!   the local noise and the threshold shrinks by half each level. The
//!   smaller of the two variances is used so that a very noisy pixel (a
//!   partially covered light edge) does not open the gate to clean neighbours
//!   (on the Cornell box fixture this alone takes plain à-trous from 35.9 to
//!   39.3 dB);
//! - `t_normal = |n(p) - n(q)|^2 / sigma_normal^2`;
//! - `t_geometry`: with normal and position, the mean of the two pixels'
//!   squared tangent-plane distances,
//!   `((n(p) . d)^2 + (n(q) . d)^2) / (2 sigma_plane^2)` with `d = x(q) - x(p)`;
//!   plus, when `sigma_distance > 0`, `|d|^2 / sigma_distance^2`;
//!   with position only, `|x(q) - x(p)|^2 / (sigma_plane 2^i)^2`; with depth
//!   only, `(z(q) - z(p))^2 / (z(p) z(q)) / (sigma_depth 2^i)^2` (depths
//!   clamped to 1e-20).
//!
//! Every term is symmetric in `p` and `q` (the colour gate through the
//! smaller variance, the geometry terms through both normals or depths), so
//! `w(p, q) = w(q, p)`: the SIMD step computes each tap pair's weight once
//! and uses it for both pixels (`float/avx2.rs`). Dammertz et al. measure
//! the plane distance from `p`'s plane only; the symmetric mean costs
//! 0.06 dB on the bundled sample and nothing measurable on the Cornell box,
//! and halves the weights to compute.
//!
//! The centre tap always weighs `9/64`, so the normaliser never vanishes.
//!
//! Several images (`groups` of 3 channels) can be filtered with the same
//! weights, the first one guiding (for the paired SURE: the mean of two
//! estimates, and half their difference riding along); a variance plane can ride along (filtered with squared normalised
//! weights), with the normalised centre weight written beside it, for the
//! variance propagation of the single-estimate SURE.
//!
//! ## SURE shrinkage
//! With detail `D_i = c_i - c_{i+1}` the output is
//! `c_N + sum_i beta_i(p) D_i(p)`; `beta = 0` everywhere is plain à-trous,
//! `beta = 1` returns the input. For linear shrinkage of a detail with noise
//! variance `s`, Stein's unbiased risk estimate is
//! `(1 - beta)^2 D^2 + (2 beta - 1) s`; summed over a window around `p` (and
//! the channels) it is an unbiased estimate of the window's risk, and
//! [`sure_shrink`] takes the candidate `beta` minimising it. Any `beta` in
//! [0, 1] is valid for this estimator, so 0 and 1 join the paper's
//! {0.2, 0.4, 0.6, 0.8}: where the detail is pure noise the risk is lowest at
//! 0, where it is signal well above the noise at 1.

use crate::error::{check_scratch, check_shape, Error, Result, Shape};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::unfold::check_band;
use crate::view::{View, ViewMut};
use crate::Isa;

pub(crate) mod fixed;
pub(crate) mod float;
pub mod noise;
mod sure;

pub use sure::{sure_levels_scratch_len, sure_scratch_len, sure_shrink, sure_shrink_levels, MAX_SURE_LEVELS};

/// The B3-spline taps.
pub const B3: [f32; 5] = [1.0 / 16.0, 1.0 / 4.0, 3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0];
/// Deepest level (hole spacing 2^7 = 128).
pub const MAX_LEVEL: u32 = 7;
/// Most 3-channel images filtered together.
pub const MAX_GROUPS: usize = 2;

/// Edge-stopping parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AtrousParams {
    /// Colour: multiple of the noise variance a squared colour difference is
    /// compared with at level 0. The default, 64, is where plain à-trous
    /// has its lowest error on the bundled sample (a sweep is in docs/quality.md).
    pub phi_color: f32,
    /// Normal difference scale.
    pub sigma_normal: f32,
    /// Tangent-plane (or position) distance scale, world units.
    pub sigma_plane: f32,
    /// Relative depth difference scale (depth-only guides).
    pub sigma_depth: f32,
    /// With normal and position: a world-space distance scale, the same at
    /// every level, adding `|x(q) - x(p)|^2 / sigma_distance^2` to the
    /// plane term, so that the deep levels (taps 8 and 16 pixels apart)
    /// weigh far points less even on one plane (Dammertz et al.'s position
    /// term). 0 (the default) leaves it out.
    pub sigma_distance: f32,
    /// Added to the colour denominator (noise-free inputs).
    pub eps: f32,
}

impl Default for AtrousParams {
    fn default() -> Self {
        AtrousParams {
            phi_color: 64.0,
            sigma_normal: 0.3,
            sigma_plane: 0.01,
            sigma_depth: 0.05,
            sigma_distance: 0.0,
            eps: 1e-6,
        }
    }
}

/// The guides of a step.
#[derive(Clone, Copy, Debug)]
pub struct AtrousGuides<'a, T> {
    /// Per-pixel noise variance of the input (1 plane).
    pub noise: View<'a, T>,
    /// World-space normal (3 planes).
    pub normal: Option<View<'a, T>>,
    /// World position (3 planes).
    pub position: Option<View<'a, T>>,
    /// Depth (1 plane), used when there is no position.
    pub depth: Option<View<'a, T>>,
}

/// Precisions the à-trous operators are implemented for.
pub trait AtrousPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn scratch_len_impl(level: u32) -> usize;
    #[doc(hidden)]
    #[allow(clippy::too_many_arguments)]
    fn step_impl(
        chk: Checked,
        level: u32,
        groups: usize,
        with_variance: bool,
        params: &AtrousParams,
        guides: &AtrousGuides<'_, Self::Store>,
        src: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
        scratch: &mut [f32],
    );
}

macro_rules! float_atrous {
    ($p:ty, $a:ty) => {
        impl AtrousPrecision for $p {
            fn scratch_len_impl(level: u32) -> usize {
                if <$a as crate::real::Real>::IS_F32 {
                    float::scratch_len(level)
                } else {
                    0
                }
            }
            fn step_impl(
                chk: Checked,
                level: u32,
                groups: usize,
                with_variance: bool,
                params: &AtrousParams,
                guides: &AtrousGuides<'_, Self::Store>,
                src: &View<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
                scratch: &mut [f32],
            ) {
                float::step::<_, $a>(chk.isa(), level, groups, with_variance, params, guides, src, dst, y0, scratch)
            }
        }
    };
}
float_atrous!(F32, f32);
float_atrous!(F16, f32);
float_atrous!(F16Arith, crate::real::H);

impl AtrousPrecision for Fixed {
    fn scratch_len_impl(_level: u32) -> usize {
        0
    }
    fn step_impl(
        chk: Checked,
        level: u32,
        groups: usize,
        with_variance: bool,
        params: &AtrousParams,
        guides: &AtrousGuides<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
        _scratch: &mut [f32],
    ) {
        fixed::step(chk.isa(), level, groups, with_variance, params, guides, src, dst, y0)
    }
}

/// Scratch floats [`step`] needs at `level` (for any width, band and
/// instruction set; 0 for the precisions that run the scalar pixel). At
/// level 4 about 320 KB.
pub fn step_scratch_len<P: AtrousPrecision>(level: u32) -> usize {
    P::scratch_len_impl(level.min(MAX_LEVEL))
}

/// One à-trous step at `level` for output rows `y0 ..`.
///
/// `src` holds `3 * groups` colour planes, plus one variance plane when
/// `with_variance`; `dst` holds `3 * groups` planes, plus (with variance)
/// the filtered variance and the normalised centre weight. `scratch` holds
/// at least [`step_scratch_len`] floats (its contents are ignored). The
/// result does not depend on how the rows are split into bands.
///
/// # Errors
/// An instruction set this CPU lacks; `level` above [`MAX_LEVEL`]; `groups`
/// not 1 or 2; a sigma or `phi_color` that is not positive and finite, a
/// negative or non-finite `sigma_distance` or `eps`; guides or `src` of
/// another size than `src`, `dst` not a band of it starting at `y0`, or with
/// the wrong channel counts; `scratch` shorter than [`step_scratch_len`].
#[allow(clippy::too_many_arguments)]
pub fn step<P: AtrousPrecision>(
    isa: Isa,
    level: u32,
    groups: usize,
    with_variance: bool,
    params: &AtrousParams,
    guides: &AtrousGuides<'_, P::Store>,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    if level > MAX_LEVEL {
        return Err(Error::BadParameter { what: "a-trous level", expected: "0 to 7" });
    }
    if groups == 0 || groups > MAX_GROUPS {
        return Err(Error::BadParameter { what: "a-trous image groups", expected: "1 or 2 images of 3 channels" });
    }
    let p = params;
    let positive = |v: f32| v > 0.0 && v.is_finite();
    let sigmas_ok =
        positive(p.phi_color) && positive(p.sigma_normal) && positive(p.sigma_plane) && positive(p.sigma_depth);
    let distance_ok = p.sigma_distance >= 0.0 && p.sigma_distance.is_finite();
    if !(sigmas_ok && distance_ok && p.eps >= 0.0 && p.eps.is_finite()) {
        return Err(Error::BadParameter { what: "a-trous parameters", expected: "positive finite sigmas" });
    }
    let s = src.shape();
    let extra = usize::from(with_variance);
    check_shape("a-trous input", Shape::new(3 * groups + extra, s.width, s.height), s)?;
    let plane = |c| Shape::new(c, s.width, s.height);
    check_shape("a-trous noise variance", plane(1), guides.noise.shape())?;
    for (what, v, c) in [("normal", guides.normal, 3), ("position", guides.position, 3), ("depth", guides.depth, 1)] {
        if let Some(v) = v {
            check_shape(what, plane(c), v.shape())?;
        }
    }
    check_band("a-trous output", plane(3 * groups + 2 * extra), dst.shape(), y0)?;
    if dst.height() == 0 || s.width == 0 {
        return Ok(());
    }
    check_scratch(P::scratch_len_impl(level), scratch.len())?;
    P::step_impl(chk, level, groups, with_variance, params, guides, src, dst, y0, scratch);
    Ok(())
}

/// The SURE candidate weights: the paper's four plus 0 and 1.
pub const SURE_CANDIDATES: [f32; 6] = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0];

/// Radius of the window the SURE terms are summed over (5x5).
pub const SURE_RADIUS: usize = 2;

/// Where the noise of a level's detail comes from (see [`sure_shrink`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SureSource {
    /// Two independent estimates, filtered as their mean `M` and half
    /// difference `H`.
    Pair,
    /// One estimate with its variance propagated through the levels.
    Single,
}

fn check_candidates(candidates: &[f32]) -> Result<()> {
    if candidates.is_empty() || candidates.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(Error::BadParameter { what: "SURE candidates", expected: "values in [0, 1]" });
    }
    Ok(())
}

/// The candidate minimising the SURE `(1 - b)^2 e + (2 b - 1) s` (the first
/// on ties), as every shrinkage path picks it per pixel; an error when
/// `candidates` is empty or holds a value outside `[0, 1]`.
pub fn best_beta(e: f32, s: f32, candidates: &[f32]) -> Result<f32> {
    check_candidates(candidates)?;
    Ok(risk_argmin(e, s, candidates))
}

/// [`best_beta`] past its check (`candidates` not empty): the scalar
/// shrinkage calls it per pixel; the SIMD paths compute the same risks in
/// the same order, lane by lane.
#[inline(always)]
pub(crate) fn risk_argmin(e: f32, s: f32, candidates: &[f32]) -> f32 {
    let mut best = (f32::INFINITY, candidates[0]);
    for &b in candidates {
        let r = (1.0 - b) * (1.0 - b) * e + (2.0 * b - 1.0) * s;
        if r < best.0 {
            best = (r, b);
        }
    }
    best.1
}

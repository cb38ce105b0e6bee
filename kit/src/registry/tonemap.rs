//! Entries of the tone maps: albedo demodulation and remodulation, gamma.

use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{F16Arith, Fixed, Result as CoreResult, ViewMut, F16, F32};

use super::{base, full, image, no_scratch, per, tol, unit_frac, Args, Field, Op, Per, Prep, Run};
use mcdenoise::runtime::precision::{HostPrecision, Kind};

/// The albedo epsilon the (de)modulation entries use.
pub const DEMOD_EPS: f32 = 1e-3;

fn k_demodulate<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let n = b.height();
    tonemap::demodulate::<P>(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, DEMOD_EPS, b)
}
fn k_remodulate<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let n = b.height();
    tonemap::remodulate::<P>(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, DEMOD_EPS, b)
}
fn k_gamma<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    tonemap::map::<P>(a.isa, Map::Gamma { gamma: 2.2, clamp: true }, &a.ins[0].rows(y0, b.height())?, b)
}

/// The tone-mapping entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![
        Op {
            oracle: |i, _| {
                i.get(Radiance)
                    .iter()
                    .zip(i.get(Albedo))
                    .map(|(&r, &a)| r as f64 / (a as f64 + DEMOD_EPS as f64))
                    .collect()
            },
            ..base(
                "demodulate",
                "radiance / (albedo + eps)",
                vec![image(Radiance), full(Albedo, 3, Kind::Unit)],
                per!(One, k_demodulate, no_scratch),
            )
        },
        Op {
            oracle: |i, _| {
                i.get(Radiance)
                    .iter()
                    .zip(i.get(Albedo))
                    .map(|(&r, &a)| r as f64 * (a as f64 + DEMOD_EPS as f64))
                    .collect()
            },
            ..base(
                "remodulate",
                "irradiance * (albedo + eps)",
                vec![image(Radiance), full(Albedo, 3, Kind::Unit)],
                per!(One, k_remodulate, no_scratch),
            )
        },
        Op {
            oracle: |i, _| i.get(Radiance).iter().map(|&r| (r as f64).clamp(0.0, 1.0).powf(1.0 / 2.2)).collect(),
            tol: [tol(1e-7, 1e-6), tol(4e-4, 8e-4), tol(1e-3, 2e-3), tol(5e-4, 0.0)],
            out_frac: unit_frac,
            ..base("gamma", "clamp(x, 0, 1)^(1/2.2)", vec![image(Radiance)], per!(One, k_gamma, no_scratch))
        },
    ]
}

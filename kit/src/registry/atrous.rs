//! The entry of the edge-avoiding à-trous step.

use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
use mcdenoise_core::{F16Arith, Fixed, Result as CoreResult, ViewMut, F16, F32};

use super::{base, full, image, per, Args, Field, Inputs, Op, Per, Prep, Run};
use crate::oracle;
use mcdenoise::runtime::precision::{HostPrecision, Kind};

/// The à-trous entry's parameters (level 1: hole 2).
fn atrous_params() -> AtrousParams {
    AtrousParams { sigma_plane: 0.05, sigma_distance: 0.2, ..AtrousParams::default() }
}

fn k_atrous<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    let g = AtrousGuides { noise: a.ins[1], normal: Some(a.ins[2]), position: Some(a.ins[3]), depth: None };
    atrous::step::<P>(a.isa, 1, 1, false, &atrous_params(), &g, &a.ins[0], b, y0, s)
}
fn s_atrous<P: HostPrecision>(_w: usize) -> usize {
    atrous::step_scratch_len::<P>(1)
}

fn o_atrous(i: &Inputs) -> Vec<f64> {
    let p = atrous_params();
    let (noise, normal, pos) = (i.f64(Field::Noise), i.f64(Field::Normal), i.f64(Field::Position));
    let g = oracle::AtrousGuides { noise: &noise, normal: Some(&normal), position: Some(&pos), depth: None };
    oracle::atrous_step(
        1,
        1,
        false,
        p.phi_color as f64,
        p.sigma_normal as f64,
        p.sigma_plane as f64,
        p.sigma_depth as f64,
        p.sigma_distance as f64,
        p.eps as f64,
        &g,
        &i.f64(Field::Radiance),
        i.w,
        i.h,
    )
}

/// The à-trous entry of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![Op {
        oracle: |i, _| o_atrous(i),
        ..base(
            "atrous",
            "one edge-avoiding a-trous level (hole 2) with colour, normal and plane edge-stopping",
            vec![
                image(Radiance),
                full(Noise, 1, Kind::Plain),
                full(Normal, 3, Kind::Unit),
                full(Position, 3, Kind::Plain),
            ],
            per!(One, k_atrous, s_atrous),
        )
    }]
}

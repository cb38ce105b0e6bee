//! Entries of the pools: 2x2 average and max, nearest upsampling, the scale compositor.

use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::{F16Arith, Fixed, Result as CoreResult, ViewMut, F16, F32};

use super::{base, coarse, full, image, no_scratch, per, Args, Field, Op, Per, Prep, Run};
use crate::oracle;
use mcdenoise::runtime::precision::{HostPrecision, Kind};

fn k_avgpool<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::reduce2x2::<P>(a.isa, Reduce::Mean, &a.ins[0], b, y0)
}
fn k_maxpool<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::reduce2x2::<P>(a.isa, Reduce::Max, &a.ins[0], b, y0)
}
fn k_upsample<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::upsample_nearest2x::<P>(a.isa, &a.ins[0], b, y0, a.size.1)
}
fn k_composite<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::composite::<P>(a.isa, &a.ins[0], &a.ins[1], &a.ins[2], b, y0)
}

/// The pooling entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![
        Op {
            oracle: |i, _| oracle::reduce2x2(&i.f64(Radiance), 3, i.w, i.h, false),
            out: (3, true),
            ..base("avgpool", "2x2 average pool", vec![image(Radiance)], per!(One, k_avgpool, no_scratch))
        },
        Op {
            oracle: |i, _| oracle::reduce2x2(&i.f64(Radiance), 3, i.w, i.h, true),
            out: (3, true),
            ..base("maxpool", "2x2 max pool", vec![image(Radiance)], per!(One, k_maxpool, no_scratch))
        },
        Op {
            oracle: |i, _| oracle::upsample(&i.f64(Coarse), 3, i.w, i.h),
            align: 2,
            ..base("upsample", "nearest-neighbour 2x upsampling", vec![coarse()], per!(One, k_upsample, no_scratch))
        },
        Op {
            oracle: |i, _| oracle::composite(&i.f64(Radiance), &i.f64(Coarse), &i.f64(Alpha), 3, i.w, i.h),
            align: 2,
            ..base(
                "composite",
                "the scale compositor d - a U(D(d)) + a U(coarse) (AFN)",
                vec![image(Radiance), coarse(), full(Alpha, 1, Kind::Unit)],
                per!(One, k_composite, no_scratch),
            )
        },
    ]
}

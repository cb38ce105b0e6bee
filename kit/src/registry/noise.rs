//! Entries of the single-image noise estimators (f32).

use mcdenoise_core::atrous;
use mcdenoise_core::{Result as CoreResult, ViewMut};

use super::{base, full, image, per_f32, Args, Field, Op, Per, Prep, Run, F32_ONLY};
use crate::oracle;
use mcdenoise::runtime::precision::Kind;

fn k_local_noise(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    atrous::noise::local_noise_rows(&a.ins[0], b, y0)
}
fn k_median3(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    atrous::noise::median3_rows(&a.ins[0], b, y0)
}

/// The noise-estimator entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![
        Op {
            oracle: |i, _| oracle::local_noise(&i.f64(Radiance), i.w, i.h),
            out: (1, false),
            precisions: F32_ONLY,
            ..base(
                "noise-local",
                "single-image noise variance: 0.84 |y - median of 8 neighbours|^2, mean over channels",
                vec![image(Radiance)],
                per_f32!(One, k_local_noise),
            )
        },
        Op {
            oracle: |i, _| oracle::median3(&i.f64(Noise), i.w, i.h),
            out: (1, false),
            precisions: F32_ONLY,
            ..base(
                "noise-median3",
                "1.27 x the 3x3 median of a noise map",
                vec![full(Noise, 1, Kind::Plain)],
                per_f32!(One, k_median3),
            )
        },
    ]
}

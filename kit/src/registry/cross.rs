//! Entries of cross-regression (f32): variance, regression pilot, spatiotemporal filter and its gradient.

use mcdenoise_core::regress;
use mcdenoise_core::{Result as CoreResult, ViewMut};

use super::{base, full, image, logits, per_f32, tol, Args, Field, Inputs, Op, Per, Prep, Run, Tol, F32_ONLY};
use crate::oracle;
use mcdenoise::runtime::precision::Kind;

/// The regression solves 6x6 systems per centre: f32 loses a few digits to
/// their conditioning; the filter sums 121 exponentials.
const REGRESSION_TOL: [Tol; 4] = [tol(5e-4, 5e-4), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const FILTER_TOL: [Tol; 4] = [tol(1e-6, 1e-5), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const FILTER_GRAD_TOL: [Tol; 4] = [tol(1e-5, 1e-4), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];

fn k_cross_variance(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    regress::variance_rows(a.isa, &a.ins[0], b, y0)
}
fn regression_inputs<'a>(a: &Args<'a, f32>) -> regress::RegressionInputs<'a> {
    regress::RegressionInputs { x: a.ins[0], var: a.ins[1], y: a.ins[2], albedo: a.ins[3], normal: a.ins[4] }
}
fn k_cross_regression(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    regress::regression_rows(a.isa, &regression_inputs(a), b, y0, s)
}
fn s_cross_regression(w: usize) -> usize {
    regress::regression_scratch_len(w)
}
fn filter_inputs<'a>(a: &Args<'a, f32>) -> regress::FilterInputs<'a> {
    regress::FilterInputs {
        pilot_a: a.ins[0],
        pilot_b: a.ins[1],
        albedo: a.ins[2],
        normal: a.ins[3],
        prev: a.ins[4],
        valid: a.ins[5],
    }
}
fn k_cross_filter(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    regress::filter_rows(a.isa, &filter_inputs(a), &a.ins[6].rows(y0, n)?, b, y0, s)
}
fn k_cross_filter_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    let g = a.ins[7].channels_range(0, 6)?.rows(y0, n)?;
    regress::filter_grad_rows(a.isa, &filter_inputs(a), &a.ins[6].rows(y0, n)?, &g, b, y0, s)
}
fn s_cross_filter(w: usize) -> usize {
    regress::filter_scratch_len(w)
}
fn cross_filter_oracle(i: &Inputs) -> [Vec<f64>; 6] {
    [
        i.f64(Field::Radiance),
        i.f64(Field::Previous),
        i.f64(Field::Albedo),
        i.f64(Field::Normal),
        i.f64(Field::Position),
        i.f64(Field::Alpha),
    ]
}

/// The cross-regression entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![
        Op {
            oracle: |i, _| oracle::cross_variance(&i.f64(Radiance), i.w, i.h),
            out: (1, false),
            precisions: F32_ONLY,
            tol: FILTER_TOL,
            ..base(
                "cross-variance",
                "cross-regression: per-pixel variance, |y - mean of the 8 neighbours|^2 over the channels",
                vec![image(Radiance)],
                per_f32!(One, k_cross_variance),
            )
        },
        Op {
            oracle: |i, _| {
                oracle::cross_regression(
                    &i.f64(Radiance),
                    &i.f64(Noise),
                    &i.f64(Previous),
                    &i.f64(Albedo),
                    &i.f64(Normal),
                    i.w,
                    i.h,
                )
            },
            out: (3, false),
            precisions: F32_ONLY,
            tol: REGRESSION_TOL,
            ..base(
                "cross-regression",
                "cross-regression pilot: 17x17 weighted fits at every 4th pixel (Cholesky), blended within +-8 px",
                vec![
                    image(Radiance),
                    full(Noise, 1, Kind::Plain),
                    image(Previous),
                    full(Albedo, 3, Kind::Unit),
                    full(Normal, 3, Kind::Unit),
                ],
                per_f32!(One, k_cross_regression, s_cross_regression),
            )
        },
        Op {
            oracle: |i, _| {
                let [pa, pb, alb, nrm, prev, valid] = cross_filter_oracle(i);
                let f = oracle::CrossFilter {
                    pa: &pa,
                    pb: &pb,
                    alb: &alb,
                    nrm: &nrm,
                    prev: &prev,
                    valid: &valid,
                    w: i.w,
                    h: i.h,
                };
                f.forward(&i.f64(Logits))
            },
            out: (9, false),
            precisions: F32_ONLY,
            tol: FILTER_TOL,
            ..base(
                "cross-filter",
                "cross-regression: 11x11 spatiotemporal cross-bilateral filter of both pilots (outputs A, B, combined)",
                vec![
                    image(Radiance),
                    image(Previous),
                    full(Albedo, 3, Kind::Unit),
                    full(Normal, 3, Kind::Unit),
                    full(Position, 3, Kind::Plain),
                    full(Alpha, 1, Kind::Unit),
                    logits(6),
                ],
                per_f32!(One, k_cross_filter, s_cross_filter),
            )
        },
        Op {
            oracle: |i, _| {
                let [pa, pb, alb, nrm, prev, valid] = cross_filter_oracle(i);
                let f = oracle::CrossFilter {
                    pa: &pa,
                    pb: &pb,
                    alb: &alb,
                    nrm: &nrm,
                    prev: &prev,
                    valid: &valid,
                    w: i.w,
                    h: i.h,
                };
                f.backward(&i.f64(Logits), &i.f64(Grad)[..6 * i.w * i.h])
            },
            out: (6, false),
            precisions: F32_ONLY,
            tol: FILTER_GRAD_TOL,
            ..base(
                "cross-filter-grad",
                "backward: the spatiotemporal filter's gradient by the network's six raw outputs",
                vec![
                    image(Radiance),
                    image(Previous),
                    full(Albedo, 3, Kind::Unit),
                    full(Normal, 3, Kind::Unit),
                    full(Position, 3, Kind::Plain),
                    full(Alpha, 1, Kind::Unit),
                    logits(6),
                    full(Grad, 6, Kind::Image),
                ],
                per_f32!(One, k_cross_filter_grad, s_cross_filter),
            )
        },
    ]
}

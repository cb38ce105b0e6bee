//! Entries of the convolutions (1x1, 3x3, 5x5, 14 -> 14 with bias and LeakyReLU).

use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::{F16Arith, Fixed, Result as CoreResult, ViewMut, F16, F32};

use super::{base, full, per, tol, Args, Field, Inputs, Op, Per, Prep, Run, Tol};
use crate::oracle;
use mcdenoise::runtime::par::Pool;
use mcdenoise::runtime::precision::{HostPrecision, Kind};

/// Convolutions sum 14 x k^2 products: more rounding in f32 and f16
/// arithmetic, and fixed point carries the weights' quantisation too.
const CONV_TOL: [Tol; 4] = [tol(1e-6, 5e-6), tol(8e-4, 8e-4), tol(6e-3, 6e-3), tol(4e-3, 0.0)];

fn conv_layer<'a, T>(a: &Args<'a, T>, k: usize) -> Conv2d<'a, T> {
    Conv2d {
        k,
        cin: 14,
        cout: 14,
        weights: a.params[0],
        bias: Some(a.params[1]),
        act: Activation::LeakyRelu(0.1),
        weight_frac: a.weight_frac,
    }
}
fn k_conv1<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    conv::conv2d::<P>(a.isa, &conv_layer(a, 1), &a.ins[0], b, y0, s)
}
fn s_conv1<P: HostPrecision>(w: usize) -> usize {
    conv::conv2d_scratch_len::<P>(1, 14, 14, w)
}
fn k_conv3<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    conv::conv2d::<P>(a.isa, &conv_layer(a, 3), &a.ins[0], b, y0, s)
}
fn s_conv3<P: HostPrecision>(w: usize) -> usize {
    conv::conv2d_scratch_len::<P>(3, 14, 14, w)
}
fn k_conv5<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    conv::conv2d::<P>(a.isa, &conv_layer(a, 5), &a.ins[0], b, y0, s)
}
fn s_conv5<P: HostPrecision>(w: usize) -> usize {
    conv::conv2d_scratch_len::<P>(5, 14, 14, w)
}

fn o_conv(i: &Inputs, pool: &Pool, k: usize, wf: Field) -> Vec<f64> {
    let per = 14 * k * k;
    let (x, wts, b) = (i.f64(Field::Features), i.f64(wf), i.f64(Field::Bias));
    // One output channel per task: the oracle is the slow part of a report.
    let chans: Vec<Vec<f64>> = pool.map(14, |co| {
        oracle::conv2d(k, 14, 1, &wts[co * per..(co + 1) * per], Some(&b[co..co + 1]), Some(0.1), &x, i.w, i.h)
    });
    chans.concat()
}

/// The convolution entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![
        Op {
            oracle: |i, p| o_conv(i, p, 1, Weights1),
            params: vec![Weights1, Bias],
            out: (14, false),
            tol: CONV_TOL,
            ..base(
                "conv1x1",
                "1x1 convolution 14 -> 14, bias, LeakyReLU(0.1)",
                vec![full(Features, 14, Kind::Image)],
                per!(One, k_conv1, s_conv1),
            )
        },
        Op {
            oracle: |i, p| o_conv(i, p, 3, Weights3),
            params: vec![Weights3, Bias],
            out: (14, false),
            tol: CONV_TOL,
            ..base(
                "conv3x3",
                "3x3 convolution 14 -> 14, bias, LeakyReLU(0.1)",
                vec![full(Features, 14, Kind::Image)],
                per!(One, k_conv3, s_conv3),
            )
        },
        Op {
            oracle: |i, p| o_conv(i, p, 5, Weights5),
            params: vec![Weights5, Bias],
            out: (14, false),
            tol: CONV_TOL,
            ..base(
                "conv5x5",
                "5x5 convolution 14 -> 14, bias, LeakyReLU(0.1)",
                vec![full(Features, 14, Kind::Image)],
                per!(One, k_conv5, s_conv5),
            )
        },
    ]
}

//! Entries of the backward passes (f32), with sigmoid and bilinear upsampling (training-only forwards).

use mcdenoise_core::conv::{self, Activation};
use mcdenoise_core::pool;
use mcdenoise_core::softmax;
use mcdenoise_core::{unfold, Result as CoreResult, ViewMut};

use super::unfold::{fused_inputs, SIX};
use super::{
    base, coarse, full, fusion, image, logits, per_f32, tol, Args, Field, In, Inputs, Op, Per, Prep, Run, Store, Tol,
    F32_ONLY,
};
use crate::oracle;
use mcdenoise::runtime::precision::Kind;

/// Backward passes, f32: gathers to rounding of the inputs' range; the
/// fused filter's cancelling terms and the weight gradient's long sums (every
/// pixel of the image) need more.
const GRAD_TOL: [Tol; 4] = [tol(1e-6, 1e-5), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const FUSED_GRAD_TOL: [Tol; 4] = [tol(1e-6, 1e-5), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const WEIGHT_GRAD_TOL: [Tol; 4] = [tol(5e-6, 5e-6), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];

// Backward passes (f32): several gradients go out as one tensor, their
// planes one after the other.

fn k_conv3_grad_input(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let (tw, rest) = s.split_at_mut(14 * 14 * 9);
    conv::grad::transpose_weights(3, 14, 14, a.params[0], tw)?;
    conv::grad::grad_input(a.isa, 3, 14, 14, tw, &a.ins[0], b, y0, rest)
}
fn s_conv3_grad_input(w: usize) -> usize {
    14 * 14 * 9 + conv::grad::grad_input_scratch_len(3, 14, 14, w)
}
fn conv_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, k: usize) -> CoreResult<()> {
    // The weights' gradient as one row of cout * cin * k * k values, all image rows summed.
    let dw = b.row_mut(0, 0);
    dw.fill(0.0);
    let rows = a.ins[0].height();
    conv::grad::grad_weights(a.isa, k, &a.ins[0], &a.ins[1], 0, rows, dw, None)
}
fn k_conv3_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, _: usize, _: &mut [f32]) -> CoreResult<()> {
    conv_grad_weights(a, b, 3)
}
fn k_conv5_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, _: usize, _: &mut [f32]) -> CoreResult<()> {
    conv_grad_weights(a, b, 5)
}
fn k_fused6_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let (mut imp, rest) = b.reborrow().split_channels_at(6);
    let (mut fus, mut rad) = rest.split_channels_at(6);
    let out = softmax::grad::FusedGrads { importance: &mut imp, fusion: Some(&mut fus), radiance: &mut rad };
    let g = a.ins[4].channels_range(0, 3)?;
    softmax::grad::fused_filter_grad(a.isa, &fused_inputs(a, &SIX), &g, out, y0, s)
}
fn s_fused6_grad(w: usize) -> usize {
    softmax::grad::fused_grad_scratch_len(6, 3, w)
}
fn k_apply7_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let (mut dk, mut ds) = b.reborrow().split_channels_at(49);
    let g = a.ins[2].channels_range(0, 3)?;
    unfold::grad::apply_grad(a.isa, 7, &a.ins[0], &a.ins[1], &g, Some(&mut dk), Some(&mut ds), y0)
}
fn k_softmax6_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    softmax::grad::channel_softmax_grad(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, b)
}

fn k_conv1_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, _: usize, _: &mut [f32]) -> CoreResult<()> {
    conv_grad_weights(a, b, 1)
}
fn k_avgpool_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::avg_pool2x2_grad(a.isa, &a.ins[0], b, y0, a.size.1)
}
fn k_maxpool_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::max_pool2x2_grad(a.isa, &a.ins[0], &a.ins[1], b, y0)
}
fn k_upsample_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::upsample_nearest2x_grad(a.isa, &a.ins[0], b, y0)
}
fn k_bilinear(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::upsample_bilinear2x(a.isa, &a.ins[0], b, y0, a.size.1)
}
fn k_bilinear_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::upsample_bilinear2x_grad(a.isa, &a.ins[0], b, y0)
}

/// Which gradient of the compositor an entry checks.
#[derive(Clone, Copy, PartialEq)]
enum CompositeGrad {
    Fine,
    Coarse,
    Alpha,
}

/// The compositor's gradients for the band of the checked output (fine rows
/// for `Fine` and `Alpha`, coarse rows for `Coarse`); the other two go to
/// temporaries of the band's size. Inputs: fine, coarse, alpha, gradient.
fn composite_grad_band(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, which: CompositeGrad) -> CoreResult<()> {
    let (w, h) = a.size;
    let (cw, n) = (w.div_ceil(2), b.height());
    // Fine rows y0f .. y0f + nf and coarse rows y0f / 2 .. (y0f + nf + 1) / 2.
    let (y0f, nf) = if which == CompositeGrad::Coarse { (2 * y0, (2 * n).min(h - 2 * y0)) } else { (y0, n) };
    let nc = (y0f + nf).div_ceil(2) - y0f / 2;
    let (mut t1, mut t2) = (vec![0.0f32; 3 * w * nf], vec![0.0f32; 3 * cw * nc.max(nf)]);
    let g = a.ins[3].channels_range(0, 3)?;
    let run = |df: &mut ViewMut<'_, f32>, dc: &mut ViewMut<'_, f32>, da: &mut ViewMut<'_, f32>| {
        pool::grad::composite_grad(a.isa, &a.ins[0], &a.ins[1], &a.ins[2], &g, df, dc, da, y0f)
    };
    match which {
        CompositeGrad::Fine => {
            let mut dc = ViewMut::new(&mut t2[..3 * cw * nc], 3, cw, nc)?;
            let mut da = ViewMut::new(&mut t1[..w * nf], 1, w, nf)?;
            run(b, &mut dc, &mut da)
        }
        CompositeGrad::Coarse => {
            let mut df = ViewMut::new(&mut t1, 3, w, nf)?;
            let mut da = ViewMut::new(&mut t2[..w * nf], 1, w, nf)?;
            run(&mut df, b, &mut da)
        }
        CompositeGrad::Alpha => {
            let mut df = ViewMut::new(&mut t1, 3, w, nf)?;
            let mut dc = ViewMut::new(&mut t2[..3 * cw * nc], 3, cw, nc)?;
            run(&mut df, &mut dc, b)
        }
    }
}
fn k_composite_grad_fine(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    composite_grad_band(a, b, y0, CompositeGrad::Fine)
}
fn k_composite_grad_coarse(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    composite_grad_band(a, b, y0, CompositeGrad::Coarse)
}
fn k_composite_grad_alpha(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    composite_grad_band(a, b, y0, CompositeGrad::Alpha)
}
fn k_sigmoid(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    softmax::grad::sigmoid(a.isa, &a.ins[0].rows(y0, b.height())?, b)
}
fn k_sigmoid_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    softmax::grad::sigmoid_grad(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, b)
}
fn k_activation_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    conv::grad::activation_grad(Activation::LeakyRelu(0.1), &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, b)
}

/// The half-resolution gradient the pool-gradient entries read.
fn o_half_grad(i: &Inputs) -> Vec<f64> {
    i.f64(Field::Grad)[..3 * i.w.div_ceil(2) * i.h.div_ceil(2)].to_vec()
}

/// The compositor's three gradients on the registry's fields.
fn o_composite_grad(i: &Inputs) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let g = &i.f64(Field::Grad)[..3 * i.w * i.h];
    let (f, c, a) = (i.f64(Field::Radiance), i.f64(Field::Coarse), i.f64(Field::Alpha));
    oracle::composite_grad(&f, &c, &a, g, 3, i.w, i.h)
}

fn concat(parts: [Vec<f64>; 3]) -> Vec<f64> {
    parts.concat()
}

fn o_conv_grad(i: &Inputs, k: usize, wf: Field) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    oracle::conv2d_grad(k, 14, 14, &i.f64(wf), &i.f64(Field::Features), &i.f64(Field::Grad), i.w, i.h)
}

/// The backward entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    // A half-resolution gradient: the first planes' worth of the Grad field.
    let half_grad = In { field: Grad, c: 3, half: true, store: Store::As(Kind::Image) };
    let composite_grad_ins = vec![image(Radiance), coarse(), full(Alpha, 1, Kind::Unit), full(Grad, 14, Kind::Image)];
    vec![
        Op {
            oracle: |i, _| o_conv_grad(i, 3, Weights3).0,
            params: vec![Weights3],
            out: (14, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "conv3x3-grad-input",
                "backward: the input gradient of a 3x3 convolution 14 -> 14 (the forward kernel on transposed weights)",
                vec![full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv3_grad_input, s_conv3_grad_input),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 3, Weights3).1,
            out_fixed: Some((1, 14 * 14 * 9, 1)),
            precisions: F32_ONLY,
            tol: WEIGHT_GRAD_TOL,
            ..base(
                "conv3x3-grad-weights",
                "backward: the weight gradient of a 3x3 convolution 14 -> 14, summed over the image",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv3_grad_weights),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 5, Weights5).1,
            out_fixed: Some((1, 14 * 14 * 25, 1)),
            precisions: F32_ONLY,
            tol: WEIGHT_GRAD_TOL,
            ..base(
                "conv5x5-grad-weights",
                "backward: the weight gradient of a 5x5 convolution 14 -> 14, summed over the image",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv5_grad_weights),
            )
        },
        Op {
            oracle: |i, _| {
                let n = i.w * i.h;
                let (di, df, dc) = oracle::fused_grad(
                    &SIX,
                    &i.f64(Logits),
                    Some(&i.f64(Fusion)),
                    Some(&i.f64(Albedo)),
                    &i.f64(Radiance),
                    &i.f64(Grad)[..3 * n],
                    3,
                    i.w,
                    i.h,
                );
                concat([di, df, dc])
            },
            out: (15, false),
            align: 32,
            precisions: F32_ONLY,
            tol: FUSED_GRAD_TOL,
            ..base(
                "fused6-grad",
                "backward: the fused importance filter's gradients (importance, fusion, radiance)",
                vec![logits(6), fusion(6), full(Albedo, 3, Kind::Unit), image(Radiance), full(Grad, 3, Kind::Image)],
                per_f32!(One, k_fused6_grad, s_fused6_grad),
            )
        },
        Op {
            oracle: |i, _| {
                let n = i.w * i.h;
                let (dk, ds) =
                    oracle::unfold_grad(7, &i.f64(Kernel), &i.f64(Radiance), &i.f64(Grad)[..3 * n], 3, i.w, i.h);
                [dk, ds].concat()
            },
            out: (52, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "apply7x7-grad",
                "backward: the 7x7 apply's gradients (kernel map, image)",
                vec![full(Kernel, 49, Kind::Unit), image(Radiance), full(Grad, 3, Kind::Image)],
                per_f32!(One, k_apply7_grad),
            )
        },
        Op {
            oracle: |i, _| {
                let n = i.w * i.h;
                oracle::channel_softmax_grad(&i.f64(Fusion), &i.f64(Grad)[..6 * n], 6, i.w, i.h)
            },
            out: (6, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "softmax6-grad",
                "backward: the channel softmax's gradient y (dy - sum y dy)",
                vec![fusion(6), full(Grad, 6, Kind::Image)],
                per_f32!(One, k_softmax6_grad),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 1, Weights1).1,
            out_fixed: Some((1, 14 * 14, 1)),
            precisions: F32_ONLY,
            tol: WEIGHT_GRAD_TOL,
            ..base(
                "conv1x1-grad-weights",
                "backward: the weight gradient of a 1x1 convolution 14 -> 14, summed over the image",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv1_grad_weights),
            )
        },
        Op {
            oracle: |i, _| oracle::avg_pool_grad(&o_half_grad(i), 3, i.w, i.h),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "avgpool-grad",
                "backward: the 2x2 average pool's gradient (a quarter of the cell's to each pixel)",
                vec![half_grad],
                per_f32!(One, k_avgpool_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::max_pool_grad(&i.f64(Radiance), &o_half_grad(i), 3, i.w, i.h),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "maxpool-grad",
                "backward: the 2x2 max pool's gradient (the cell's to its maximum)",
                vec![image(Radiance), half_grad],
                per_f32!(One, k_maxpool_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::upsample_grad(&i.f64(Grad)[..3 * i.w * i.h], 3, i.w, i.h),
            out: (3, true),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "upsample-grad",
                "backward: the nearest 2x upsample's gradient (each cell's sum)",
                vec![full(Grad, 3, Kind::Image)],
                per_f32!(One, k_upsample_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::upsample_bilinear(&i.f64(Coarse), 3, i.w, i.h),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "upsample-bilinear",
                "bilinear 2x upsampling (align_corners = false), the forward of the next entry",
                vec![coarse()],
                per_f32!(One, k_bilinear),
            )
        },
        Op {
            oracle: |i, _| oracle::upsample_bilinear_grad(&i.f64(Grad)[..3 * i.w * i.h], 3, i.w, i.h),
            out: (3, true),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "upsample-bilinear-grad",
                "backward: the bilinear 2x upsample's gradient",
                vec![full(Grad, 3, Kind::Image)],
                per_f32!(One, k_bilinear_grad),
            )
        },
        Op {
            oracle: |i, _| o_composite_grad(i).0,
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "composite-grad-fine",
                "backward: the scale compositor's gradient with respect to the fine image",
                composite_grad_ins.clone(),
                per_f32!(One, k_composite_grad_fine),
            )
        },
        Op {
            oracle: |i, _| o_composite_grad(i).1,
            out: (3, true),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "composite-grad-coarse",
                "backward: the scale compositor's gradient with respect to the coarse image",
                composite_grad_ins.clone(),
                per_f32!(One, k_composite_grad_coarse),
            )
        },
        Op {
            oracle: |i, _| o_composite_grad(i).2,
            out: (1, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "composite-grad-alpha",
                "backward: the scale compositor's gradient with respect to its blend weight",
                composite_grad_ins,
                per_f32!(One, k_composite_grad_alpha),
            )
        },
        Op {
            oracle: |i, _| oracle::sigmoid(&i.f64(Features)),
            out: (14, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "sigmoid",
                "1 / (1 + e^-x) (AFN's fusion weight)",
                vec![full(Features, 14, Kind::Image)],
                per_f32!(One, k_sigmoid),
            )
        },
        Op {
            oracle: |i, _| oracle::sigmoid_grad(&i.f64(Alpha), &i.f64(Grad)[..i.w * i.h]),
            out: (1, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "sigmoid-grad",
                "backward: the sigmoid's gradient from its output, dy y (1 - y)",
                vec![full(Alpha, 1, Kind::Unit), full(Grad, 1, Kind::Image)],
                per_f32!(One, k_sigmoid_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::leaky_relu_grad(&i.f64(Features), &i.f64(Grad), 0.1),
            out: (14, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "activation-grad",
                "backward: LeakyReLU(0.1)'s gradient through its output",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_activation_grad),
            )
        },
    ]
}

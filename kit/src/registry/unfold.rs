//! Entries of the per-pixel kernels: the 7x7 apply, window and fused filters, importance kernels, softmax.

use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::{unfold, F16Arith, Fixed, Result as CoreResult, ViewMut, F16, F32};

use super::{
    base, full, fused_ins, fusion, image, logits, no_scratch, per, tol, unit_frac, Args, Field, In, Inputs, Op, Per,
    Prep, Run, Store, Tol,
};
use crate::oracle;
use mcdenoise::runtime::precision::{HostPrecision, Kind};

/// Softmax weights in [0, 1]: f16 rounds each to 2^-11 relative; fixed
/// point Q1.14 to 2^-15 absolute, plus its exp approximation.
const WEIGHT_TOL: [Tol; 4] = [tol(1e-7, 1e-6), tol(3e-4, 3e-3), tol(1e-3, 4e-3), tol(2e-3, 0.0)];

/// Softmax weights from logits in `[-50, 50)`. A logit error `e` moves a
/// weight `w` by at most `2 w (1 - w) e`. f16 stores a logit near 50 to
/// 2^-6 (`e = 2^-6`): at most 3.1 % of the weight, plus its own 2^-11.
/// f16 arithmetic also rounds `l - max` (up to 100: 2^-5) and the sums.
/// Fixed point stores logits in Q7.8 whatever their size (`e = 2^-9`, the
/// same as at +-8), so the +-8 bound holds; Q1.14 on the weight.
/// (Set from the analysis and checked against the measured worst case, see
/// [`IMAGE_TOL`](super::IMAGE_TOL).)
const WIDE_WEIGHT_TOL: [Tol; 4] = [tol(1e-7, 1e-6), tol(1e-4, 3.3e-2), tol(1e-3, 7e-2), tol(2e-3, 0.0)];

fn k_apply7<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    unfold::apply_rows::<P>(a.isa, 7, &a.ins[0], &a.ins[1], b, y0, s)
}
fn s_apply7<P: HostPrecision>(w: usize) -> usize {
    unfold::scratch_len::<P>(7, 3, w)
}

pub(super) fn fused_inputs<'a, T>(a: &Args<'a, T>, sizes: &'a [usize]) -> FusedInputs<'a, T> {
    let multi = sizes.len() > 1;
    FusedInputs {
        sizes,
        importance: a.ins[0],
        fusion: multi.then(|| a.ins[1]),
        albedo: multi.then(|| a.ins[2]),
        radiance: a.ins[3],
    }
}

pub(super) const SIX: [usize; 6] = [3, 5, 7, 9, 11, 13];

fn k_window7<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::BoxSum, &fused_inputs(a, &[7]), b, y0, s)
}
fn s_window7<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::BoxSum, &[7], 3, w)
}
fn k_fused6<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::BoxSum, &fused_inputs(a, &SIX), b, y0, s)
}
fn s_fused6<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::BoxSum, &SIX, 3, w)
}
fn k_fused6_sep<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::Separable, &fused_inputs(a, &SIX), b, y0, s)
}
fn s_fused6_sep<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::Separable, &SIX, 3, w)
}
fn k_fused6_direct<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::Direct, &fused_inputs(a, &SIX), b, y0, s)
}
fn s_fused6_direct<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::Direct, &SIX, 3, w)
}
fn k_kernels7<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    softmax::importance_kernels::<P>(a.isa, 7, &a.ins[0], b, y0)
}
fn k_softmax6<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    softmax::channel_softmax::<P>(a.isa, &a.ins[0].rows(y0, b.height())?, b)
}

fn o_fused(i: &Inputs, sizes: &[usize]) -> Vec<f64> {
    let m = sizes.len();
    let n = i.w * i.h;
    let imp = &i.f64(Field::Logits)[..m * n];
    if m == 1 {
        oracle::fused_pixelwise(sizes, imp, None, None, &i.f64(Field::Radiance), 3, i.w, i.h)
    } else {
        let fus = &i.f64(Field::Fusion)[..m * n];
        oracle::fused_pixelwise(
            sizes,
            imp,
            Some(fus),
            Some(&i.f64(Field::Albedo)),
            &i.f64(Field::Radiance),
            3,
            i.w,
            i.h,
        )
    }
}

/// The per-pixel kernel and softmax entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    vec![
        Op {
            oracle: |i, _| oracle::unfold(7, &i.f64(Kernel), &i.f64(Radiance), 3, i.w, i.h),
            ..base(
                "apply7x7",
                "a 7x7 per-pixel kernel map applied to 3 channels (AFN)",
                vec![full(Kernel, 49, Kind::Unit), image(Radiance)],
                per!(One, k_apply7, s_apply7),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &[7]),
            align: 48,
            ..base(
                "window7",
                "the importance-weighted 7x7 window filter (WSKP, one size), box-sum path",
                fused_ins(1),
                per!(One, k_window7, s_window7),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &SIX),
            align: 48,
            ..base(
                "fused6",
                "the fused importance filter, sizes 3..13 with fusion weights and albedo (WSKP), box-sum path",
                fused_ins(6),
                per!(One, k_fused6, s_fused6),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &SIX),
            align: 48,
            ..base(
                "fused6-sep",
                "the fused importance filter through the separable window sums",
                fused_ins(6),
                per!(One, k_fused6_sep, s_fused6_sep),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &SIX),
            ..base(
                "fused6-direct",
                "the fused importance filter, every window summed tap by tap with its own shift",
                fused_ins(6),
                per!(One, k_fused6_direct, s_fused6_direct),
            )
        },
        Op {
            oracle: |i, _| oracle::importance_kernels(7, &i.f64(Logits)[..i.w * i.h], i.w, i.h),
            out: (49, false),
            tol: WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "kernels7",
                "per-pixel 7x7 softmax kernels from an importance map (WSKP eq. 3)",
                vec![logits(1)],
                per!(One, k_kernels7, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::channel_softmax(&i.f64(Fusion), 6, i.w, i.h),
            out: (6, false),
            tol: WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "softmax6",
                "the softmax across 6 channels per pixel",
                vec![fusion(6)],
                per!(One, k_softmax6, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::importance_kernels(7, &i.f64(WideLogits)[..i.w * i.h], i.w, i.h),
            out: (49, false),
            tol: WIDE_WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "kernels7-wide",
                "per-pixel 7x7 softmax kernels from logits in [-50, 50) (a trained network's range)",
                vec![In { field: WideLogits, c: 1, half: false, store: Store::Logit }],
                per!(One, k_kernels7, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::channel_softmax(&i.f64(WideLogits), 6, i.w, i.h),
            out: (6, false),
            tol: WIDE_WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "softmax6-wide",
                "the softmax across 6 channels of logits in [-50, 50)",
                vec![In { field: WideLogits, c: 6, half: false, store: Store::Logit }],
                per!(One, k_softmax6, no_scratch),
            )
        },
    ]
}

//! Portable pool operators. Every function takes `x_from`: the SIMD paths
//! call them for the columns their vector loops left over.

use super::Reduce;
use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};

/// The reduction of coarse cell `X` between fine rows `r0` and optional `r1`.
#[inline(always)]
pub(crate) fn cell<S: FloatElement, A: Real>(op: Reduce, r0: &[S], r1: Option<&[S]>, xc: usize, w: usize) -> A {
    let x0 = 2 * xc;
    let has_right = x0 + 1 < w;
    // Column sums (or maxima) first, then across the two columns.
    let col = |x: usize| -> A {
        let a = A::of(r0[x].to_f32());
        match (op, r1) {
            (Reduce::Mean, Some(r1)) => a + A::of(r1[x].to_f32()),
            (Reduce::Max, Some(r1)) => A::of(r1[x].to_f32()).maxps(a),
            (_, None) => a,
        }
    };
    let n = (1 + r1.is_some() as usize) * (1 + has_right as usize);
    let v = if has_right {
        match op {
            Reduce::Mean => col(x0) + col(x0 + 1),
            Reduce::Max => col(x0 + 1).maxps(col(x0)),
        }
    } else {
        col(x0)
    };
    match (op, n) {
        (Reduce::Mean, 4) => v * A::of(0.25),
        (Reduce::Mean, 2) => v * A::of(0.5),
        _ => v,
    }
}

pub(crate) fn reduce<S: FloatElement, A: Real>(
    op: Reduce,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    x_from: usize,
) {
    let (w, h) = (src.width(), src.height());
    for yo in 0..dst.height() {
        let yc = y0 + yo;
        for c in 0..src.channels() {
            let r0 = src.row(c, 2 * yc);
            let r1 = (2 * yc + 1 < h).then(|| src.row(c, 2 * yc + 1));
            let out = dst.row_mut(c, yo);
            for (xc, o) in out.iter_mut().enumerate().skip(x_from) {
                *o = S::from_f32(cell::<S, A>(op, r0, r1, xc, w).f32());
            }
        }
    }
}

pub(crate) fn upsample<S: FloatElement>(src: &View<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize, x_from: usize) {
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for c in 0..src.channels() {
            let s = src.row(c, y / 2);
            for (x, o) in dst.row_mut(c, yo).iter_mut().enumerate().skip(x_from) {
                *o = s[x / 2];
            }
        }
    }
}

pub(crate) fn composite<S: FloatElement, A: Real>(
    fine: &View<'_, S>,
    coarse: &View<'_, S>,
    alpha: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    x_from: usize,
) {
    let (w, h) = (fine.width(), fine.height());
    let per_channel_alpha = alpha.channels() > 1;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let yc = y / 2;
        for c in 0..fine.channels() {
            let r0 = fine.row(c, 2 * yc);
            let r1 = (2 * yc + 1 < h).then(|| fine.row(c, 2 * yc + 1));
            let f = fine.row(c, y);
            let crow = coarse.row(c, yc);
            let a = alpha.row(if per_channel_alpha { c } else { 0 }, y);
            let out = dst.row_mut(c, yo);
            for x in x_from..w {
                let d = A::of(crow[x / 2].to_f32()) - cell::<S, A>(Reduce::Mean, r0, r1, x / 2, w);
                out[x] = S::from_f32((A::of(f[x].to_f32()) + A::of(a[x].to_f32()) * d).f32());
            }
        }
    }
}

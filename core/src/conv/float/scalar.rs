//! Portable convolution: per output row and channel, taps outermost over a
//! row accumulator (`width` words of scratch), x range clipped per tap.

use crate::conv::Conv2d;
use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};

pub(crate) fn forward<S: FloatElement, A: Real>(
    layer: &Conv2d<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    for yo in 0..dst.height() {
        for co in 0..layer.cout {
            row::<S, A>(layer, src, dst, y0, yo, co, scratch);
        }
    }
}

/// Output row `yo` (image row `y0 + yo`) of channel `co`.
pub(crate) fn row<S: FloatElement, A: Real>(
    layer: &Conv2d<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    yo: usize,
    co: usize,
    scratch: &mut [f32],
) {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let y = y0 + yo;
    let acc: &mut [A] = bytemuck::cast_slice_mut(&mut scratch[..w]);
    acc.fill(A::of(layer.bias.map_or(0.0, |b| b[co].to_f32())));
    for ci in 0..layer.cin {
        for ky in 0..k {
            let Some(sy) = (y + ky).checked_sub(p).filter(|&v| v < h) else { continue };
            let srow = src.row(ci, sy);
            for kx in 0..k {
                let wv = A::of(layer.weights[((co * layer.cin + ci) * k + ky) * k + kx].to_f32());
                let x_lo = p.saturating_sub(kx);
                let x_hi = (w + p).saturating_sub(kx).min(w);
                if x_lo >= x_hi {
                    continue;
                }
                for (a, &s) in acc[x_lo..x_hi].iter_mut().zip(&srow[x_lo + kx - p..x_hi + kx - p]) {
                    *a += wv * A::of(s.to_f32());
                }
            }
        }
    }
    let out = dst.row_mut(co, yo);
    for (o, &a) in out.iter_mut().zip(acc.iter()) {
        *o = S::from_f32(act::<A>(layer.act, a).f32());
    }
}

/// One output pixel (same order as [`row`]).
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) fn pixel<S: FloatElement>(layer: &Conv2d<'_, S>, src: &View<'_, S>, co: usize, y: usize, x: usize) -> f32 {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let mut acc = layer.bias.map_or(0.0, |b| b[co].to_f32());
    for ci in 0..layer.cin {
        for ky in 0..k {
            let Some(sy) = (y + ky).checked_sub(p).filter(|&v| v < h) else { continue };
            let srow = src.row(ci, sy);
            for kx in 0..k {
                let Some(sx) = (x + kx).checked_sub(p).filter(|&v| v < w) else { continue };
                acc += layer.weights[((co * layer.cin + ci) * k + ky) * k + kx].to_f32() * srow[sx].to_f32();
            }
        }
    }
    layer.act.apply(acc)
}

/// The activation in arithmetic `A` (same comparisons as [`crate::conv::Activation::apply`]).
#[inline(always)]
pub(crate) fn act<A: Real>(act: crate::conv::Activation, x: A) -> A {
    match act {
        crate::conv::Activation::Identity => x,
        crate::conv::Activation::Relu => {
            if x > A::ZERO {
                x
            } else {
                A::ZERO
            }
        }
        crate::conv::Activation::LeakyRelu(s) => {
            let sx = A::of(s) * x;
            if x > sx {
                x
            } else {
                sx
            }
        }
    }
}

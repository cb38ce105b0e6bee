//! Portable fixed-point convolution, pixel by pixel.

use super::{finish, shift};
use crate::conv::Conv2d;
use crate::fixed::ld;
use crate::view::{View, ViewMut};

pub(crate) fn forward(layer: &Conv2d<'_, i16>, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let s = shift(layer, src, dst);
    for yo in 0..dst.height() {
        for co in 0..layer.cout {
            for x in 0..dst.width() {
                let acc = pixel(layer, src, co, y0 + yo, x);
                dst.row_mut(co, yo)[x] = finish(layer, co, acc, s);
            }
        }
    }
}

/// The exact sum of one output value (out-of-image taps are 0).
pub(crate) fn pixel(layer: &Conv2d<'_, i16>, src: &View<'_, i16>, co: usize, y: usize, x: usize) -> i32 {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let mut acc = 0i32;
    for ci in 0..layer.cin {
        for ky in 0..k {
            let Some(sy) = (y + ky).checked_sub(p).filter(|&v| v < h) else { continue };
            let row = src.row(ci, sy);
            for kx in 0..k {
                let Some(sx) = (x + kx).checked_sub(p).filter(|&v| v < w) else { continue };
                acc += ld(layer.weights[((co * layer.cin + ci) * k + ky) * k + kx]) * ld(row[sx]);
            }
        }
    }
    acc
}

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

/// The exact sum of one output value (out-of-image taps are 0): the
/// in-image kernel rows and columns found once, then a dot product of a
/// kernel row with an image row segment per input channel and kernel row.
pub(crate) fn pixel(layer: &Conv2d<'_, i16>, src: &View<'_, i16>, co: usize, y: usize, x: usize) -> i32 {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let (ky_lo, ky_hi) = (p.saturating_sub(y), k.min((h + p).saturating_sub(y)));
    let (kx_lo, kx_hi) = (p.saturating_sub(x), k.min((w + p).saturating_sub(x)));
    if kx_lo >= kx_hi {
        return 0;
    }
    let n = kx_hi - kx_lo;
    let mut acc = 0i32;
    for ci in 0..layer.cin {
        for ky in ky_lo..ky_hi {
            let row = &src.row(ci, y + ky - p)[x + kx_lo - p..][..n];
            let base = ((co * layer.cin + ci) * k + ky) * k + kx_lo;
            let wr = &layer.weights[base..base + n];
            for (&a, &b) in wr.iter().zip(row) {
                acc += ld(a) * ld(b);
            }
        }
    }
    acc
}

//! Portable fixed-point unfold, pixel by pixel.

use crate::fixed::{ld, sat16, shr_round, PAIR_SHIFT};
use crate::view::{View, ViewMut};

pub(crate) fn run(k: usize, kernel: &View<'_, i16>, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let shift = super::out_shift(kernel, src, dst);
    for yo in 0..dst.height() {
        for c in 0..src.channels() {
            for x in 0..dst.width() {
                let v = pixel(k, kernel, src, c, y0 + yo, x);
                dst.row_mut(c, yo)[x] = sat16(shr_round(v as i64, shift));
            }
        }
    }
}

/// The accumulator of one output value: pair sums of taps `(2i, 2i + 1)`,
/// each shifted right by `PAIR_SHIFT`; out-of-image taps count as 0.
pub(crate) fn pixel(k: usize, kernel: &View<'_, i16>, src: &View<'_, i16>, c: usize, y: usize, x: usize) -> i32 {
    let (w, h) = (src.width(), src.height());
    let r = k / 2;
    let tap = |j: usize| -> i32 {
        if j >= k * k {
            return 0;
        }
        let (ky, kx) = (j / k, j % k);
        let sy = (y + ky).checked_sub(r).filter(|&v| v < h);
        let sx = (x + kx).checked_sub(r).filter(|&v| v < w);
        match sy.zip(sx) {
            Some((sy, sx)) => ld(kernel.at(j, y, x)) * ld(src.at(c, sy, sx)),
            None => 0,
        }
    };
    let mut acc = 0i32;
    let mut j = 0;
    while j < k * k {
        acc += (tap(j) + tap(j + 1)) >> PAIR_SHIFT;
        j += 2;
    }
    acc
}

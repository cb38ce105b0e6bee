//! Portable unfold: taps outermost over a row, accumulating whole rows in
//! scratch (`channels * width` words), which the compiler can vectorise for
//! f32. Generic over the arithmetic `A` (f32, or f16-rounded for the
//! f16-arithmetic precision). Out-of-image taps are skipped by clipping the x
//! range and the tap rows.

use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};

pub(crate) fn run<S: FloatElement, A: Real>(
    k: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    for yo in 0..dst.height() {
        row::<S, A>(k, kernel, src, dst, y0, yo, scratch);
    }
}

/// Output row `yo` of the band starting at image row `y0`.
pub(crate) fn row<S: FloatElement, A: Real>(
    k: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    yo: usize,
    scratch: &mut [f32],
) {
    let (w, h, ch) = (src.width(), src.height(), src.channels());
    let r = k / 2;
    let y = y0 + yo;
    let acc: &mut [A] = bytemuck::cast_slice_mut(&mut scratch[..ch * w]);
    acc.fill(A::ZERO);
    for ky in 0..k {
        let Some(sy) = (y + ky).checked_sub(r).filter(|&sy| sy < h) else { continue };
        for kx in 0..k {
            let krow = kernel.row(ky * k + kx, y);
            // Output x takes source x + kx - r; keep both inside [0, w).
            let x_lo = r.saturating_sub(kx);
            let x_hi = (w + r).saturating_sub(kx).min(w);
            if x_lo >= x_hi {
                continue;
            }
            for c in 0..ch {
                let srow = src.row(c, sy);
                let a = &mut acc[c * w + x_lo..c * w + x_hi];
                let kk = &krow[x_lo..x_hi];
                let ss = &srow[x_lo + kx - r..x_hi + kx - r];
                for ((a, &kv), &sv) in a.iter_mut().zip(kk).zip(ss) {
                    *a += A::of(kv.to_f32()) * A::of(sv.to_f32());
                }
            }
        }
    }
    for c in 0..ch {
        let out = dst.row_mut(c, yo);
        for (o, &a) in out.iter_mut().zip(&acc[c * w..(c + 1) * w]) {
            *o = S::from_f32(a.f32());
        }
    }
}

/// One output pixel, channel `c`, taps in ascending order, out-of-image taps skipped.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) fn pixel<S: FloatElement>(
    k: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    c: usize,
    y: usize,
    x: usize,
) -> f32 {
    let (w, h) = (src.width(), src.height());
    let r = k / 2;
    let mut acc = 0.0f32;
    for ky in 0..k {
        let Some(sy) = (y + ky).checked_sub(r).filter(|&sy| sy < h) else { continue };
        let srow = src.row(c, sy);
        for kx in 0..k {
            let Some(sx) = (x + kx).checked_sub(r).filter(|&sx| sx < w) else { continue };
            acc += kernel.at(ky * k + kx, y, x).to_f32() * srow[sx].to_f32();
        }
    }
    acc
}

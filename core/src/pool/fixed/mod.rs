//! Pool operators in fixed point (portable integer code on every ISA).
//! Means round half up (`(sum + n/2) >> log2 n`); every result is rescaled
//! to the output's format, rounded, and saturated.

use super::Reduce;
use crate::fixed::{ld, rescale, sat16, shr_round};
use crate::view::{View, ViewMut};

/// The 2x2 cell `xc` between rows `r0` and optional `r1`, in the input's format.
fn cell(op: Reduce, r0: &[i16], r1: Option<&[i16]>, xc: usize, w: usize) -> i64 {
    let x0 = 2 * xc;
    let xs = if x0 + 1 < w { 2 } else { 1 };
    let mut vals = [0i32; 4];
    let mut n = 0;
    for row in [Some(r0), r1].into_iter().flatten() {
        for x in x0..x0 + xs {
            vals[n] = ld(row[x]);
            n += 1;
        }
    }
    match op {
        Reduce::Max => vals[..n].iter().copied().max().unwrap_or(0) as i64,
        Reduce::Mean => {
            let sum: i64 = vals[..n].iter().map(|&v| v as i64).sum();
            shr_round(sum, n.trailing_zeros() as i32)
        }
    }
}

pub(crate) fn reduce(op: Reduce, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (w, h) = (src.width(), src.height());
    let (fi, fo) = (src.frac() as i32, dst.frac() as i32);
    for yo in 0..dst.height() {
        let yc = y0 + yo;
        for c in 0..src.channels() {
            let r0 = src.row(c, 2 * yc);
            let r1 = (2 * yc + 1 < h).then(|| src.row(c, 2 * yc + 1));
            for xc in 0..dst.width() {
                dst.row_mut(c, yo)[xc] = sat16(rescale(cell(op, r0, r1, xc, w), fi, fo));
            }
        }
    }
}

pub(crate) fn upsample(src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (fi, fo) = (src.frac() as i32, dst.frac() as i32);
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for c in 0..src.channels() {
            let s = src.row(c, y / 2);
            for x in 0..dst.width() {
                dst.row_mut(c, yo)[x] = sat16(rescale(ld(s[x / 2]) as i64, fi, fo));
            }
        }
    }
}

pub(crate) fn composite(
    fine: &View<'_, i16>,
    coarse: &View<'_, i16>,
    alpha: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    let (w, h) = (fine.width(), fine.height());
    let (ff, fc, fa, fo) = (fine.frac() as i32, coarse.frac() as i32, alpha.frac() as i32, dst.frac() as i32);
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
            for x in 0..w {
                let d = rescale(ld(crow[x / 2]) as i64, fc, ff) - cell(Reduce::Mean, r0, r1, x / 2, w);
                let o = ld(f[x]) as i64 + shr_round(ld(a[x]) as i64 * d, fa);
                dst.row_mut(c, yo)[x] = sat16(rescale(o, ff, fo));
            }
        }
    }
}

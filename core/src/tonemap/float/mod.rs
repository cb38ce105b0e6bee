//! Per-pixel maps in f32 arithmetic over f32 or f16 storage.

use super::Map;
use crate::precision::FloatElement;
use crate::view::{View, ViewMut};
use crate::Isa;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;

/// Scalar map of a row from `x_from` on.
pub(crate) fn map_row<S: FloatElement>(op: Map, src: &[S], dst: &mut [S], x_from: usize) {
    for (o, &v) in dst.iter_mut().zip(src).skip(x_from) {
        *o = S::from_f32(op.apply(v.to_f32()));
    }
}

/// Scalar (de)modulation of a row from `x_from` on.
pub(crate) fn modulate_row<S: FloatElement>(
    divide: bool,
    src: &[S],
    alb: &[S],
    eps: f32,
    dst: &mut [S],
    x_from: usize,
) {
    for ((o, &v), &a) in dst.iter_mut().zip(src).zip(alb).skip(x_from) {
        let d = a.to_f32() + eps;
        *o = S::from_f32(if divide { v.to_f32() / d } else { v.to_f32() * d });
    }
}

pub(crate) fn map<S: FloatElement>(isa: Isa, op: Map, src: &View<'_, S>, dst: &mut ViewMut<'_, S>) {
    for c in 0..src.channels() {
        for y in 0..src.height() {
            let (s, d) = (src.row(c, y), dst.row_mut(c, y));
            let done = match isa {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: the caller checked support.
                crate::Isa::Avx2 => unsafe { avx2::map_row(op, s, d) },
                _ => 0,
            };
            map_row(op, s, d, done);
        }
    }
}

pub(crate) fn modulate<S: FloatElement>(
    isa: Isa,
    divide: bool,
    src: &View<'_, S>,
    albedo: &View<'_, S>,
    eps: f32,
    dst: &mut ViewMut<'_, S>,
) {
    for c in 0..src.channels() {
        for y in 0..src.height() {
            let (s, a, d) = (src.row(c, y), albedo.row(c, y), dst.row_mut(c, y));
            let done = match isa {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: the caller checked support.
                crate::Isa::Avx2 => unsafe { avx2::modulate_row(divide, s, a, eps, d) },
                _ => 0,
            };
            modulate_row(divide, s, a, eps, d, done);
        }
    }
}

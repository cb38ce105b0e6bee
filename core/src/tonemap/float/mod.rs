//! Per-pixel maps in f32 arithmetic over f32 or f16 storage.

use super::Map;
use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;

/// Scalar map of a row from `x_from` on. A tone map is one operation of the
/// arithmetic `A` (evaluated in f32, rounded once), like a native instruction.
pub(crate) fn map_row<S: FloatElement, A: Real>(op: Map, src: &[S], dst: &mut [S], x_from: usize) {
    for (o, &v) in dst.iter_mut().zip(src).skip(x_from) {
        *o = S::from_f32(A::of(op.apply(v.to_f32())).f32());
    }
}

/// Scalar (de)modulation of a row from `x_from` on.
pub(crate) fn modulate_row<S: FloatElement, A: Real>(
    divide: bool,
    src: &[S],
    alb: &[S],
    eps: f32,
    dst: &mut [S],
    x_from: usize,
) {
    for ((o, &v), &a) in dst.iter_mut().zip(src).zip(alb).skip(x_from) {
        let d = A::of(a.to_f32()) + A::of(eps);
        let v = A::of(v.to_f32());
        *o = S::from_f32(if divide { v / d } else { v * d }.f32());
    }
}

pub(crate) fn map<S: FloatElement, A: Real>(
    isa: crate::isa::Supported,
    op: Map,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
) {
    for c in 0..src.channels() {
        for y in 0..src.height() {
            let (s, d) = (src.row(c, y), dst.row_mut(c, y));
            let done = match isa.isa() {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
                crate::Isa::Avx2 | crate::Isa::Avx512 if A::IS_F32 => unsafe { avx2::map_row(op, s, d) },
                _ => 0,
            };
            map_row::<S, A>(op, s, d, done);
        }
    }
}

pub(crate) fn modulate<S: FloatElement, A: Real>(
    isa: crate::isa::Supported,
    divide: bool,
    src: &View<'_, S>,
    albedo: &View<'_, S>,
    eps: f32,
    dst: &mut ViewMut<'_, S>,
) {
    for c in 0..src.channels() {
        for y in 0..src.height() {
            let (s, a, d) = (src.row(c, y), albedo.row(c, y), dst.row_mut(c, y));
            let done = match isa.isa() {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
                crate::Isa::Avx2 | crate::Isa::Avx512 if A::IS_F32 => unsafe {
                    avx2::modulate_row(divide, s, a, eps, d)
                },
                _ => 0,
            };
            modulate_row::<S, A>(divide, s, a, eps, d, done);
        }
    }
}

//! Pool operators for f32 arithmetic over f32 or f16 storage.

use super::Reduce;
use crate::precision::FloatElement;
use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;

pub(crate) fn reduce<S: FloatElement, A: crate::real::Real>(
    isa: crate::isa::Supported,
    op: Reduce,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 | Isa::Avx512 if A::IS_F32 => unsafe { avx2::reduce(op, src, dst, y0) },
        _ => scalar::reduce::<S, A>(op, src, dst, y0, 0),
    }
}

pub(crate) fn upsample<S: FloatElement, A: crate::real::Real>(
    isa: crate::isa::Supported,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 | Isa::Avx512 if A::IS_F32 => unsafe { avx2::upsample(src, dst, y0) },
        _ => scalar::upsample(src, dst, y0, 0),
    }
}

pub(crate) fn composite<S: FloatElement, A: crate::real::Real>(
    isa: crate::isa::Supported,
    fine: &View<'_, S>,
    coarse: &View<'_, S>,
    alpha: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 | Isa::Avx512 if A::IS_F32 => unsafe { avx2::composite(fine, coarse, alpha, dst, y0) },
        _ => scalar::composite::<S, A>(fine, coarse, alpha, dst, y0, 0),
    }
}

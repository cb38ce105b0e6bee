//! Convolution in f32 arithmetic over f32 or f16 storage.

use super::Conv2d;
use crate::precision::FloatElement;
use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;

pub(crate) fn forward<S: FloatElement, A: crate::real::Real>(
    isa: crate::isa::Supported,
    layer: &Conv2d<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 if A::IS_F32 => unsafe { avx2::forward(layer, src, dst, y0, scratch) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx512 if A::IS_F32 => unsafe { avx512::forward(layer, src, dst, y0, scratch) },
        _ => scalar::forward::<S, A>(layer, src, dst, y0, scratch),
    }
}

//! Unfold for f32 arithmetic over f32 or f16 storage.

use crate::precision::FloatElement;
use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;

/// Scratch words: the scalar row accumulator, or (AVX2) two row accumulators
/// and (f16) the ring of widened source rows; the larger so any ISA can run.
pub(crate) fn scratch_len<S: FloatElement>(k: usize, channels: usize, width: usize) -> usize {
    #[cfg(target_arch = "x86_64")]
    {
        avx2::scratch_len(k, channels, width, S::IS_F16)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = k;
        channels.saturating_mul(width)
    }
}

pub(crate) fn run<S: FloatElement, A: crate::real::Real>(
    isa: crate::isa::Supported,
    k: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 if A::IS_F32 => unsafe { avx2::run(k, kernel, src, dst, y0, scratch) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        Isa::Avx512 if A::IS_F32 => unsafe { avx512::run(k, kernel, src, dst, y0, scratch) },
        _ => scalar::run::<S, A>(k, kernel, src, dst, y0, scratch),
    }
}

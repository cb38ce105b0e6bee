//! AVX-512 loads and stores of sixteen f32 lanes from either float storage,
//! whole or under a lane mask (masked-off lanes read as 0 and touch no
//! memory). f16 converts with `vcvtph2ps` / `vcvtps2ph` (round to nearest
//! even), bit-equal to the scalar and AVX2 paths.

use core::arch::x86_64::*;

use crate::precision::FloatElement;

/// The lanes of `m` from `p` (unaligned); the others are 0.
///
/// # Safety
/// `p + i` must be readable for every lane `i` set in `m`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
pub unsafe fn load16_mask<S: FloatElement>(p: *const S, m: __mmask16) -> __m512 {
    if S::IS_F16 {
        // SAFETY: masked-off lanes are not accessed (fault suppression).
        unsafe { _mm512_cvtph_ps(_mm256_maskz_loadu_epi16(m, p as *const i16)) }
    } else {
        // SAFETY: as above.
        unsafe { _mm512_maskz_loadu_ps(m, p as *const f32) }
    }
}

/// Stores the lanes of `m` to `p` (unaligned), rounding to the storage type
/// (f16 saturating at ±65504, NaN passing through).
///
/// # Safety
/// `p + i` must be writable for every lane `i` set in `m`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
pub unsafe fn store16_mask<S: FloatElement>(p: *mut S, m: __mmask16, v: __m512) {
    if S::IS_F16 {
        // MAXPS/MINPS return the second operand for NaN: NaN passes through.
        let lim = crate::real::F16_MAX;
        let v = _mm512_min_ps(_mm512_set1_ps(lim), _mm512_max_ps(_mm512_set1_ps(-lim), v));
        let h = _mm512_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(v);
        // SAFETY: masked-off lanes are not written.
        unsafe { _mm256_mask_storeu_epi16(p as *mut i16, m, h) }
    } else {
        // SAFETY: as above.
        unsafe { _mm512_mask_storeu_ps(p as *mut f32, m, v) }
    }
}

/// The mask of the first `n` lanes (`n <= 16`).
#[inline(always)]
pub fn first_lanes(n: usize) -> __mmask16 {
    if n >= 16 {
        0xffff
    } else {
        ((1u32 << n) - 1) as u16
    }
}

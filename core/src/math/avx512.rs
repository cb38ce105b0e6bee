//! AVX-512 versions of the functions in [`crate::math`], sixteen lanes at a
//! time, same algorithm and constants as [`super::avx2`].

use core::arch::x86_64::*;

use super::*;

/// `e^x` per lane; 0 where `x < EXP_LO` or NaN (never a subnormal).
///
/// # Safety
/// Only callable (`unsafe`) where AVX-512F is available.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
pub fn exp(x: __m512) -> __m512 {
    let valid = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(x, _mm512_set1_ps(EXP_LO));
    let x = _mm512_min_ps(x, _mm512_set1_ps(EXP_HI));
    let magic = _mm512_set1_ps(ROUND_MAGIC);
    let n = _mm512_sub_ps(_mm512_fmadd_ps(x, _mm512_set1_ps(LOG2E), magic), magic);
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(LN2_HI), x);
    let r = _mm512_fnmadd_ps(n, _mm512_set1_ps(LN2_LO), r);
    let mut p = _mm512_set1_ps(EXP_C[6]);
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(EXP_C[5]));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(EXP_C[4]));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(EXP_C[3]));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(EXP_C[2]));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(EXP_C[1]));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(EXP_C[0]));
    // n is an integer in [-126, 127] here, so 2^n is a normal number: the
    // same result as the AVX2 exponent-bits construction.
    _mm512_maskz_scalef_ps(valid, p, n)
}

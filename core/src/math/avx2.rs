//! AVX2 + FMA versions of the functions in [`crate::math`], eight lanes at a
//! time, same algorithm as [`super::scalar`] (FMA in the reductions, so the
//! results differ from scalar by at most a few ulp).

use core::arch::x86_64::*;

use super::*;

/// `e^x` per lane; 0 where `x < EXP_LO` or NaN.
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 and FMA are available.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub fn exp(x: __m256) -> __m256 {
    let valid = _mm256_cmp_ps::<_CMP_GE_OQ>(x, _mm256_set1_ps(EXP_LO));
    let x = _mm256_min_ps(x, _mm256_set1_ps(EXP_HI));
    let magic = _mm256_set1_ps(ROUND_MAGIC);
    let n = _mm256_sub_ps(_mm256_fmadd_ps(x, _mm256_set1_ps(LOG2E), magic), magic);
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_HI), x);
    let r = _mm256_fnmadd_ps(n, _mm256_set1_ps(LN2_LO), r);
    let mut p = _mm256_set1_ps(EXP_C[6]);
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(EXP_C[5]));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(EXP_C[4]));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(EXP_C[3]));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(EXP_C[2]));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(EXP_C[1]));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(EXP_C[0]));
    let ni = _mm256_cvtps_epi32(n);
    let scale = _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_add_epi32(ni, _mm256_set1_epi32(127))));
    _mm256_and_ps(_mm256_mul_ps(p, scale), valid)
}

/// Natural log per lane for `x > 0`; `f32::MIN` where `x <= 0` or NaN.
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 and FMA are available.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub fn log(x: __m256) -> __m256 {
    let valid = _mm256_cmp_ps::<_CMP_GT_OQ>(x, _mm256_setzero_ps());
    let x = _mm256_min_ps(x, _mm256_set1_ps(f32::MAX));
    // Subnormals: scale by 2^25 and remember it.
    let sub = _mm256_cmp_ps::<_CMP_LT_OQ>(x, _mm256_set1_ps(f32::MIN_POSITIVE));
    let x = _mm256_blendv_ps(x, _mm256_mul_ps(x, _mm256_set1_ps(33_554_432.0)), sub);
    let bias = _mm256_and_ps(sub, _mm256_set1_ps(25.0));
    let bits = _mm256_castps_si256(x);
    let e = _mm256_sub_epi32(
        _mm256_and_si256(_mm256_srli_epi32::<23>(bits), _mm256_set1_epi32(0xff)),
        _mm256_set1_epi32(127),
    );
    let mut e = _mm256_sub_ps(_mm256_cvtepi32_ps(e), bias);
    let mut m = _mm256_castsi256_ps(_mm256_or_si256(
        _mm256_and_si256(bits, _mm256_set1_epi32(0x007f_ffff)),
        _mm256_set1_epi32(0x3f80_0000),
    ));
    let big = _mm256_cmp_ps::<_CMP_GT_OQ>(m, _mm256_set1_ps(2.0 * SQRT_HALF));
    m = _mm256_blendv_ps(m, _mm256_mul_ps(m, _mm256_set1_ps(0.5)), big);
    e = _mm256_add_ps(e, _mm256_and_ps(big, _mm256_set1_ps(1.0)));
    let one = _mm256_set1_ps(1.0);
    let z = _mm256_div_ps(_mm256_sub_ps(m, one), _mm256_add_ps(m, one));
    let z2 = _mm256_mul_ps(z, z);
    let mut s = _mm256_set1_ps(1.0 / 9.0);
    s = _mm256_fmadd_ps(s, z2, _mm256_set1_ps(1.0 / 7.0));
    s = _mm256_fmadd_ps(s, z2, _mm256_set1_ps(1.0 / 5.0));
    s = _mm256_fmadd_ps(s, z2, _mm256_set1_ps(1.0 / 3.0));
    s = _mm256_fmadd_ps(s, z2, one);
    let r = _mm256_fmadd_ps(e, _mm256_set1_ps(LN2), _mm256_mul_ps(_mm256_add_ps(z, z), s));
    _mm256_blendv_ps(_mm256_set1_ps(f32::MIN), r, valid)
}

/// `x^p` per lane for `x > 0`; 0 where `x <= 0` or NaN.
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 and FMA are available.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub fn pow(x: __m256, p: __m256) -> __m256 {
    let valid = _mm256_cmp_ps::<_CMP_GT_OQ>(x, _mm256_setzero_ps());
    _mm256_and_ps(exp(_mm256_mul_ps(p, log(x))), valid)
}

/// `ln(1 + x)` per lane, accurate near 0, for `x > -1`.
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 and FMA are available.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub fn log1p(x: __m256) -> __m256 {
    let one = _mm256_set1_ps(1.0);
    let u = _mm256_add_ps(one, x);
    let d = _mm256_sub_ps(u, one);
    let zero = _mm256_cmp_ps::<_CMP_EQ_OQ>(d, _mm256_setzero_ps());
    let r = _mm256_mul_ps(log(u), _mm256_div_ps(x, d));
    _mm256_blendv_ps(r, x, zero)
}

/// `e^x - 1` per lane, accurate near 0.
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 and FMA are available.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub fn expm1(x: __m256) -> __m256 {
    let one = _mm256_set1_ps(1.0);
    let x = _mm256_min_ps(x, _mm256_set1_ps(EXP_HI));
    let u = exp(x);
    let d = _mm256_sub_ps(u, one);
    let r = _mm256_mul_ps(d, _mm256_div_ps(x, log(u)));
    let r = _mm256_blendv_ps(r, x, _mm256_cmp_ps::<_CMP_EQ_OQ>(d, _mm256_setzero_ps()));
    _mm256_blendv_ps(r, _mm256_set1_ps(-1.0), _mm256_cmp_ps::<_CMP_EQ_OQ>(d, _mm256_set1_ps(-1.0)))
}

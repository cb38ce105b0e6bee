//! AVX2 loads and stores of eight f32 lanes from either float storage.
//! f16 goes through F16C (`vcvtph2ps` / `vcvtps2ph`, round to nearest even),
//! which rounds exactly like `half::f16::from_f32`, so scalar and SIMD stores agree bit for bit.

use core::arch::x86_64::*;

use crate::precision::FloatElement;

/// Eight elements from `p` (unaligned) as f32 lanes.
///
/// # Safety
/// `p .. p + 8` must be readable.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
pub unsafe fn load8<S: FloatElement>(p: *const S) -> __m256 {
    if S::IS_F16 {
        // SAFETY: caller guarantees 8 readable f16 = 16 bytes.
        unsafe { _mm256_cvtph_ps(_mm_loadu_si128(p as *const __m128i)) }
    } else {
        // SAFETY: caller guarantees 8 readable f32.
        unsafe { _mm256_loadu_ps(p as *const f32) }
    }
}

/// Stores eight f32 lanes to `p` (unaligned), rounding to the storage type
/// (f16 saturating at ±65504).
///
/// # Safety
/// `p .. p + 8` must be writable.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
pub unsafe fn store8<S: FloatElement>(p: *mut S, v: __m256) {
    if S::IS_F16 {
        // Saturate at ±65504 (MAXPS/MINPS return their second operand for NaN,
        // so NaN passes through as the scalar path lets it).
        let m = crate::real::F16_MAX;
        let v = _mm256_min_ps(_mm256_set1_ps(m), _mm256_max_ps(_mm256_set1_ps(-m), v));
        let h = _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(v);
        // SAFETY: caller guarantees 16 writable bytes.
        unsafe { _mm_storeu_si128(p as *mut __m128i, h) }
    } else {
        // SAFETY: caller guarantees 8 writable f32.
        unsafe { _mm256_storeu_ps(p as *mut f32, v) }
    }
}

/// Horizontal maximum of eight lanes.
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 and FMA are available.
#[inline]
#[target_feature(enable = "avx2,fma")]
pub fn hmax(v: __m256) -> f32 {
    let m = _mm_max_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let m = _mm_max_ps(m, _mm_movehl_ps(m, m));
    let m = _mm_max_ss(m, _mm_shuffle_ps::<0b01>(m, m));
    _mm_cvtss_f32(m)
}

/// Lanes `lo .. hi` of eight elements from `p` (unaligned) as f32, the other
/// lanes 0. Only the elements of those lanes are read.
///
/// # Safety
/// `lo <= hi <= 8`; `p + i` must be readable for `lo <= i < hi` (`p` itself
/// may point outside its allocation; it is only offset with wrapping
/// arithmetic).
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
pub unsafe fn load8_range<S: FloatElement>(p: *const S, lo: usize, hi: usize) -> __m256 {
    if S::IS_F16 {
        let mut tmp = [0u16; 8];
        for (i, t) in tmp.iter_mut().enumerate().take(hi).skip(lo) {
            // SAFETY: lane i is readable (caller).
            *t = unsafe { core::ptr::read_unaligned(p.wrapping_add(i) as *const u16) };
        }
        // SAFETY: tmp holds 16 bytes.
        unsafe { _mm256_cvtph_ps(_mm_loadu_si128(tmp.as_ptr() as *const __m128i)) }
    } else {
        // SAFETY: VMASKMOVPS touches only the lanes whose mask is set (no
        // fault on the others), and those are readable (caller).
        unsafe { _mm256_maskload_ps(p as *const f32, lane_range(lo, hi)) }
    }
}

/// The integer mask of lanes `lo .. hi` (all bits set in those lanes).
///
/// # Safety
/// Only callable (`unsafe`) where AVX2 is available.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
pub fn lane_range(lo: usize, hi: usize) -> __m256i {
    let idx = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let below_hi = _mm256_cmpgt_epi32(_mm256_set1_epi32(hi as i32), idx);
    let below_lo = _mm256_cmpgt_epi32(_mm256_set1_epi32(lo as i32), idx);
    _mm256_andnot_si256(below_lo, below_hi)
}

/// Stores the first `n` lanes (`n <= 8`) to `p`, rounding to the storage type
/// as [`store8`]; nothing past `p + n` is touched.
///
/// # Safety
/// `p .. p + n` must be writable.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
pub unsafe fn store8_first<S: FloatElement>(p: *mut S, n: usize, v: __m256) {
    if n >= 8 {
        // SAFETY: eight elements are writable (caller).
        unsafe { store8(p, v) };
    } else if S::IS_F16 {
        let mut tmp = [0u16; 8];
        // SAFETY: tmp holds eight f16.
        unsafe { store8(tmp.as_mut_ptr() as *mut S, v) };
        for (i, t) in tmp.iter().enumerate().take(n) {
            // SAFETY: p + i is writable for i < n (caller).
            unsafe { core::ptr::write_unaligned(p.add(i) as *mut u16, *t) };
        }
    } else {
        // SAFETY: only lanes below n are written, and those are writable.
        unsafe { _mm256_maskstore_ps(p as *mut f32, lane_range(0, n), v) }
    }
}

//! AVX2 per-pixel maps, eight lanes at a time; each returns how many
//! elements it wrote, the caller finishes the row with the scalar map.

use core::arch::x86_64::*;

use crate::math::avx2 as m;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, store8};
use crate::tonemap::Map;

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn map_row<S: FloatElement>(op: Map, src: &[S], dst: &mut [S]) -> usize {
    let n = src.len().min(dst.len());
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: x + 8 <= n.
        let v = unsafe { load8(src.as_ptr().add(x)) };
        // NaN to 0: keep lanes equal to themselves.
        let v = _mm256_and_ps(v, _mm256_cmp_ps::<_CMP_EQ_OQ>(v, v));
        let r = match op {
            Map::Sanitize { limit } => _mm256_min_ps(_mm256_max_ps(v, _mm256_set1_ps(-limit)), _mm256_set1_ps(limit)),
            Map::Gamma { gamma, clamp } => {
                let mut t = _mm256_max_ps(v, zero);
                if clamp {
                    t = _mm256_min_ps(t, one);
                }
                m::pow(t, _mm256_set1_ps(1.0 / gamma))
            }
            Map::Filmic => {
                let t = _mm256_min_ps(_mm256_max_ps(v, zero), _mm256_set1_ps(1.0e18));
                let num = _mm256_mul_ps(t, _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(2.51), t), _mm256_set1_ps(0.03)));
                let den = _mm256_add_ps(
                    _mm256_mul_ps(t, _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(2.43), t), _mm256_set1_ps(0.59))),
                    _mm256_set1_ps(0.14),
                );
                _mm256_min_ps(_mm256_max_ps(_mm256_div_ps(num, den), zero), one)
            }
            Map::Log1p => m::log1p(_mm256_max_ps(v, zero)),
            Map::Expm1 => m::expm1(v),
        };
        // SAFETY: x + 8 <= n.
        unsafe { store8(dst.as_mut_ptr().add(x), r) };
        x += 8;
    }
    x
}

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn modulate_row<S: FloatElement>(
    divide: bool,
    src: &[S],
    alb: &[S],
    eps: f32,
    dst: &mut [S],
) -> usize {
    let n = src.len().min(dst.len()).min(alb.len());
    let e = _mm256_set1_ps(eps);
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: x + 8 <= n for all three rows.
        unsafe {
            let d = _mm256_add_ps(load8(alb.as_ptr().add(x)), e);
            let v = load8(src.as_ptr().add(x));
            let r = if divide { _mm256_div_ps(v, d) } else { _mm256_mul_ps(v, d) };
            store8(dst.as_mut_ptr().add(x), r);
        }
        x += 8;
    }
    x
}

//! AVX2 pool operators: 16 fine columns (8 coarse) per step, the same IEEE
//! operations in the same order as [`super::scalar`] (bit-identical results);
//! the columns left over go to the scalar code.

use core::arch::x86_64::*;

use super::scalar;
use super::Reduce;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, store8};
use crate::view::{View, ViewMut};

/// Reduces 16 fine columns of one or two rows to 8 coarse values.
///
/// # Safety
/// `p0 .. p0 + 16` (and `p1` when given) readable.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn cell16<S: FloatElement>(op: Reduce, p0: *const S, p1: Option<*const S>) -> __m256 {
    // SAFETY: the caller guarantees 16 readable elements per row.
    let (mut a, mut b) = unsafe { (load8(p0), load8(p0.add(8))) };
    if let Some(p1) = p1 {
        // SAFETY: as above.
        let (c, d) = unsafe { (load8(p1), load8(p1.add(8))) };
        match op {
            Reduce::Mean => {
                a = _mm256_add_ps(a, c);
                b = _mm256_add_ps(b, d);
            }
            Reduce::Max => {
                a = _mm256_max_ps(c, a);
                b = _mm256_max_ps(d, b);
            }
        }
    }
    let v = match op {
        // hadd lane order: a0+a1 a2+a3 b0+b1 b2+b3 | a4+a5 a6+a7 b4+b5 b6+b7
        Reduce::Mean => _mm256_hadd_ps(a, b),
        Reduce::Max => {
            let even = _mm256_shuffle_ps::<0b10_00_10_00>(a, b);
            let odd = _mm256_shuffle_ps::<0b11_01_11_01>(a, b);
            _mm256_max_ps(odd, even)
        }
    };
    let v = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
    match (op, p1.is_some()) {
        (Reduce::Mean, true) => _mm256_mul_ps(v, _mm256_set1_ps(0.25)),
        (Reduce::Mean, false) => _mm256_mul_ps(v, _mm256_set1_ps(0.5)),
        (Reduce::Max, _) => v,
    }
}

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn reduce<S: FloatElement>(op: Reduce, src: &View<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let (w, h) = (src.width(), src.height());
    // Full cells only: 2 * (xc + 8) <= w.
    let vec_end = (w / 16) * 8;
    for yo in 0..dst.height() {
        let yc = y0 + yo;
        for c in 0..src.channels() {
            let p0 = src.ptr(c, 2 * yc);
            let p1 = (2 * yc + 1 < h).then(|| src.ptr(c, 2 * yc + 1));
            let out = dst.ptr_mut(c, yo);
            let mut xc = 0;
            while xc + 8 <= vec_end {
                // SAFETY: 2 * xc + 16 <= w fine columns; xc + 8 <= wc coarse columns.
                unsafe { store8(out.add(xc), cell16(op, p0.add(2 * xc), p1.map(|p| p.add(2 * xc)))) };
                xc += 8;
            }
        }
        scalar::reduce::<S, f32>(op, src, &mut dst.rows_mut_clamped(yo, 1), yc, vec_end);
    }
}

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn upsample<S: FloatElement>(src: &View<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let w = dst.width();
    let vec_end = (w / 16) * 16;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for c in 0..src.channels() {
            let s = src.ptr(c, y / 2);
            let out = dst.ptr_mut(c, yo);
            let mut x = 0;
            while x < vec_end {
                // SAFETY: x/2 + 8 <= ceil(w/2) coarse columns; x + 16 <= w.
                unsafe {
                    let v = load8(s.add(x / 2));
                    let lo = _mm256_unpacklo_ps(v, v); // v0 v0 v1 v1 | v4 v4 v5 v5
                    let hi = _mm256_unpackhi_ps(v, v); // v2 v2 v3 v3 | v6 v6 v7 v7
                    store8(out.add(x), _mm256_permute2f128_ps::<0x20>(lo, hi));
                    store8(out.add(x + 8), _mm256_permute2f128_ps::<0x31>(lo, hi));
                }
                x += 16;
            }
        }
        scalar::upsample(src, &mut dst.rows_mut_clamped(yo, 1), y, vec_end);
    }
}

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn composite<S: FloatElement>(
    fine: &View<'_, S>,
    coarse: &View<'_, S>,
    alpha: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
) {
    let (w, h) = (fine.width(), fine.height());
    let vec_end = (w / 16) * 16;
    let per_channel_alpha = alpha.channels() > 1;
    let mut yo = 0;
    while yo < dst.height() {
        let y = y0 + yo;
        let yc = y / 2;
        // Both rows of a coarse cell in this band: the cell's mean, its
        // difference from the coarse value and the upsampling are computed
        // once for the two, and the two fine rows loaded for the mean are the
        // `f` of the two outputs (for f16, a third fewer conversions).
        let pair = y.is_multiple_of(2) && yo + 1 < dst.height() && y + 1 < h;
        for c in 0..fine.channels() {
            let p0 = fine.ptr(c, 2 * yc);
            let p1 = (2 * yc + 1 < h).then(|| fine.ptr(c, 2 * yc + 1));
            let f = fine.ptr(c, y);
            let cr = coarse.ptr(c, yc);
            let ac = if per_channel_alpha { c } else { 0 };
            let a = alpha.ptr(ac, y);
            let mut x = 0;
            if pair {
                let (p1, a1) = (fine.ptr(c, y + 1), alpha.ptr(ac, y + 1));
                while x < vec_end {
                    // SAFETY: x + 16 <= w fine columns, x/2 + 8 <= ceil(w/2)
                    // coarse columns, rows y and y + 1 inside.
                    unsafe {
                        let (f00, f01, f10, f11) =
                            (load8(p0.add(x)), load8(p0.add(x + 8)), load8(p1.add(x)), load8(p1.add(x + 8)));
                        // The mean as cell16: the two rows summed, pairs added, a quarter.
                        let v = _mm256_hadd_ps(_mm256_add_ps(f00, f10), _mm256_add_ps(f01, f11));
                        let v = _mm256_castpd_ps(_mm256_permute4x64_pd::<0b11_01_10_00>(_mm256_castps_pd(v)));
                        let mean = _mm256_mul_ps(v, _mm256_set1_ps(0.25));
                        let d = _mm256_sub_ps(load8(cr.add(x / 2)), mean);
                        let lo = _mm256_unpacklo_ps(d, d);
                        let hi = _mm256_unpackhi_ps(d, d);
                        let d0 = _mm256_permute2f128_ps::<0x20>(lo, hi);
                        let d1 = _mm256_permute2f128_ps::<0x31>(lo, hi);
                        let (o0, o1) = (dst.ptr_mut(c, yo), dst.ptr_mut(c, yo + 1));
                        store8(o0.add(x), _mm256_add_ps(f00, _mm256_mul_ps(load8(a.add(x)), d0)));
                        store8(o0.add(x + 8), _mm256_add_ps(f01, _mm256_mul_ps(load8(a.add(x + 8)), d1)));
                        store8(o1.add(x), _mm256_add_ps(f10, _mm256_mul_ps(load8(a1.add(x)), d0)));
                        store8(o1.add(x + 8), _mm256_add_ps(f11, _mm256_mul_ps(load8(a1.add(x + 8)), d1)));
                    }
                    x += 16;
                }
                continue;
            }
            let out = dst.ptr_mut(c, yo);
            while x < vec_end {
                // SAFETY: x + 16 <= w fine columns, x/2 + 8 <= ceil(w/2) coarse columns.
                unsafe {
                    let d = _mm256_sub_ps(load8(cr.add(x / 2)), cell16(Reduce::Mean, p0.add(x), p1.map(|p| p.add(x))));
                    let lo = _mm256_unpacklo_ps(d, d);
                    let hi = _mm256_unpackhi_ps(d, d);
                    let d0 = _mm256_permute2f128_ps::<0x20>(lo, hi);
                    let d1 = _mm256_permute2f128_ps::<0x31>(lo, hi);
                    let o0 = _mm256_add_ps(load8(f.add(x)), _mm256_mul_ps(load8(a.add(x)), d0));
                    let o1 = _mm256_add_ps(load8(f.add(x + 8)), _mm256_mul_ps(load8(a.add(x + 8)), d1));
                    store8(out.add(x), o0);
                    store8(out.add(x + 8), o1);
                }
                x += 16;
            }
        }
        scalar::composite::<S, f32>(fine, coarse, alpha, &mut dst.rows_mut_clamped(yo, 1), y, vec_end);
        if pair {
            scalar::composite::<S, f32>(fine, coarse, alpha, &mut dst.rows_mut_clamped(yo + 1, 1), y + 1, vec_end);
            yo += 2;
        } else {
            yo += 1;
        }
    }
}

//! AVX2 fixed-point unfold: sixteen pixels a step, each pair of taps
//! interleaved (`vpunpck[lh]wd`) and multiplied-and-added (`vpmaddwd`) into
//! i32, shifted and accumulated; rows whose taps leave the image and the
//! border columns run the scalar pixel. Bit-identical to the scalar path.

use core::arch::x86_64::*;

use super::scalar;
use crate::fixed::{sat16, shr_round, PAIR_SHIFT, QMAX};
use crate::view::{View, ViewMut};

/// # Safety
/// AVX2 must be supported.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn run(k: usize, kernel: &View<'_, i16>, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (w, h, ch) = (src.width(), src.height(), src.channels());
    let r = k / 2;
    let shift = super::out_shift(kernel, src, dst);
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let interior_row = y >= r && y + r < h && shift > 0;
        for c in 0..ch {
            let mut x = 0;
            while x < w {
                let vec = interior_row && x >= r && w >= 16 + 2 * r;
                if vec && x + 16 + r <= w {
                    // SAFETY: all taps of pixels x .. x + 16 lie inside the image.
                    unsafe { interior16(k, kernel, src, dst, c, y, yo, x, shift) };
                    x += 16;
                } else if vec && x < w - r {
                    // The tail: one block ending at the last interior column,
                    // overlapping the previous one (same values written twice).
                    // SAFETY: as above.
                    unsafe { interior16(k, kernel, src, dst, c, y, yo, w - r - 16, shift) };
                    x = w - r;
                } else {
                    let v = scalar::pixel(k, kernel, src, c, y, x);
                    dst.row_mut(c, yo)[x] = sat16(shr_round(v as i64, shift));
                    x += 1;
                }
            }
        }
    }
}

#[inline(always)]
unsafe fn ld16(p: *const i16) -> __m256i {
    // SAFETY: the caller guarantees 16 readable values; -32768 reads as -32767.
    unsafe { _mm256_max_epi16(_mm256_loadu_si256(p as *const __m256i), _mm256_set1_epi16(-QMAX as i16)) }
}

/// # Safety
/// AVX2; every tap of pixels `x .. x + 16` on row `y` inside the image; `shift > 0`.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn interior16(
    k: usize,
    kernel: &View<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    c: usize,
    y: usize,
    yo: usize,
    x: usize,
    shift: i32,
) {
    let r = k / 2;
    let n = k * k;
    let zero = _mm256_setzero_si256();
    let tap = |j: usize| -> (__m256i, __m256i) {
        if j >= n {
            return (zero, zero);
        }
        let (ky, kx) = (j / k, j % k);
        // SAFETY: in range (caller).
        unsafe { (ld16(kernel.ptr(j, y).add(x)), ld16(src.ptr(c, y + ky - r).add(x + kx - r))) }
    };
    let sh = _mm_cvtsi32_si128(PAIR_SHIFT);
    let mut lo = zero;
    let mut hi = zero;
    let mut j = 0;
    while j < n {
        let (ka, ra) = tap(j);
        let (kb, rb) = tap(j + 1);
        let plo = _mm256_madd_epi16(_mm256_unpacklo_epi16(ka, kb), _mm256_unpacklo_epi16(ra, rb));
        let phi = _mm256_madd_epi16(_mm256_unpackhi_epi16(ka, kb), _mm256_unpackhi_epi16(ra, rb));
        lo = _mm256_add_epi32(lo, _mm256_sra_epi32(plo, sh));
        hi = _mm256_add_epi32(hi, _mm256_sra_epi32(phi, sh));
        j += 2;
    }
    // Round half up, shift, saturate symmetric; lo holds pixels 0-3 and 8-11,
    // hi 4-7 and 12-15, so the lane-wise pack restores pixel order.
    let half = _mm256_set1_epi32(1 << (shift - 1));
    let s = _mm_cvtsi32_si128(shift);
    let lo = _mm256_sra_epi32(_mm256_add_epi32(lo, half), s);
    let hi = _mm256_sra_epi32(_mm256_add_epi32(hi, half), s);
    let out = _mm256_max_epi16(_mm256_packs_epi32(lo, hi), _mm256_set1_epi16(-QMAX as i16));
    // SAFETY: x + 16 <= width.
    unsafe { _mm256_storeu_si256(dst.ptr_mut(c, yo).add(x) as *mut __m256i, out) };
}

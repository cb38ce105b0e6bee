//! AVX2 + FMA unfold. Rows whose taps all stay inside the image run a
//! register-blocked kernel: eight output pixels, every tap, up to four
//! channels accumulated in registers, so each kernel plane is read once and
//! nothing is stored until the pixel is finished. Border rows, border columns
//! and the tail of a row fall back to the scalar code (same tap order).

use core::arch::x86_64::*;

use super::scalar;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, store8};
use crate::view::{View, ViewMut};

/// # Safety
/// The CPU must support AVX2, FMA and F16C.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn run<S: FloatElement>(
    k: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    let (w, h, ch) = (src.width(), src.height(), src.channels());
    let r = k / 2;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        if y < r || y + r >= h || w < k + 8 {
            scalar::row::<S, f32>(k, kernel, src, dst, y0, yo, scratch);
            continue;
        }
        let mut c0 = 0;
        while c0 < ch {
            let n = (ch - c0).min(4);
            // SAFETY: y is an interior row and w >= k + 8 (checked above).
            let done = unsafe {
                match (k, n) {
                    (1, _) => interior_dyn::<S>(k, n, kernel, src, dst, y, yo, c0),
                    (3, 3) => interior::<S, 3, 3>(kernel, src, dst, y, yo, c0),
                    (5, 3) => interior::<S, 5, 3>(kernel, src, dst, y, yo, c0),
                    (7, 1) => interior::<S, 7, 1>(kernel, src, dst, y, yo, c0),
                    (7, 2) => interior::<S, 7, 2>(kernel, src, dst, y, yo, c0),
                    (7, 3) => interior::<S, 7, 3>(kernel, src, dst, y, yo, c0),
                    (7, 4) => interior::<S, 7, 4>(kernel, src, dst, y, yo, c0),
                    (9, 3) => interior::<S, 9, 3>(kernel, src, dst, y, yo, c0),
                    (11, 3) => interior::<S, 11, 3>(kernel, src, dst, y, yo, c0),
                    (13, 3) => interior::<S, 13, 3>(kernel, src, dst, y, yo, c0),
                    (15, 3) => interior::<S, 15, 3>(kernel, src, dst, y, yo, c0),
                    _ => interior_dyn::<S>(k, n, kernel, src, dst, y, yo, c0),
                }
            };
            // Left border, and right border plus the tail the vector loop left.
            for c in c0..c0 + n {
                for x in (0..r).chain(done..w) {
                    let v = scalar::pixel(k, kernel, src, c, y, x);
                    dst.row_mut(c, yo)[x] = S::from_f32(v);
                }
            }
            c0 += n;
        }
    }
}

/// How far ahead (in elements) the kernel planes are prefetched.
const PREFETCH: usize = 64;

/// Interior pixels `r ..` of row `y`, eight at a time, channels `c0 .. c0 + N`;
/// returns the first x not written.
///
/// # Safety
/// AVX2/FMA/F16C; `r <= y < h - r`; `w >= K + 8`.
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn interior<S: FloatElement, const K: usize, const N: usize>(
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y: usize,
    yo: usize,
    c0: usize,
) -> usize {
    let r = K / 2;
    let w = src.width();
    let kp = kernel.ptr(0, y);
    let kstride = kernel.plane_stride();
    let sstride = src.row_stride();
    let sp: [*const S; N] = core::array::from_fn(|c| src.ptr(c0 + c, y - r));
    let dp: [*mut S; N] = core::array::from_fn(|c| dst.ptr_mut(c0 + c, yo));
    let mut x = r;
    while x + 8 + r <= w {
        if x % 16 < 8 {
            // Every kernel plane is its own stream; 49 of them are more than the
            // hardware prefetchers follow. Fetch each plane's line PREFETCH floats ahead.
            for j in 0..K * K {
                let ahead = kp.wrapping_add(j * kstride + x + PREFETCH) as *const i8;
                _mm_prefetch::<_MM_HINT_T0>(ahead);
            }
        }
        let mut acc = [_mm256_setzero_ps(); N];
        for ky in 0..K {
            for kx in 0..K {
                // SAFETY: plane ky*K+kx exists and x + 8 <= w.
                let kv = unsafe { load8(kp.add((ky * K + kx) * kstride + x)) };
                for c in 0..N {
                    // SAFETY: row y - r + ky < h, columns x - r + kx .. + 8 <= w.
                    let sv = unsafe { load8(sp[c].add(ky * sstride + x + kx - r)) };
                    acc[c] = _mm256_fmadd_ps(kv, sv, acc[c]);
                }
            }
        }
        for c in 0..N {
            // SAFETY: x + 8 <= w.
            unsafe { store8(dp[c].add(x), acc[c]) };
        }
        x += 8;
    }
    x
}

/// Same as [`interior`] for any `k` and up to four channels, with run-time loop bounds.
///
/// # Safety
/// As for [`interior`].
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn interior_dyn<S: FloatElement>(
    k: usize,
    n: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y: usize,
    yo: usize,
    c0: usize,
) -> usize {
    let r = k / 2;
    let w = src.width();
    let kp = kernel.ptr(0, y);
    let kstride = kernel.plane_stride();
    let sstride = src.row_stride();
    let mut sp = [core::ptr::null::<S>(); 4];
    let mut dp = [core::ptr::null_mut::<S>(); 4];
    for c in 0..n {
        sp[c] = src.ptr(c0 + c, y - r);
        dp[c] = dst.ptr_mut(c0 + c, yo);
    }
    let mut x = r;
    while x + 8 + r <= w {
        let mut acc = [_mm256_setzero_ps(); 4];
        for ky in 0..k {
            for kx in 0..k {
                // SAFETY: as in `interior`.
                let kv = unsafe { load8(kp.add((ky * k + kx) * kstride + x)) };
                for c in 0..n {
                    // SAFETY: as in `interior`.
                    let sv = unsafe { load8(sp[c].add(ky * sstride + x + kx - r)) };
                    acc[c] = _mm256_fmadd_ps(kv, sv, acc[c]);
                }
            }
        }
        for c in 0..n {
            // SAFETY: x + 8 <= w.
            unsafe { store8(dp[c].add(x), acc[c]) };
        }
        x += 8;
    }
    x
}

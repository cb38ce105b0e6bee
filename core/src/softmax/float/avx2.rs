//! AVX2 + FMA row loops and 8-pixel paths of the softmax operators. Each loop
//! does the same IEEE operations in the same order as [`super::scalar`]; only
//! `exp` differs (FMA in its reduction and polynomial). Tails shorter than
//! eight lanes run the scalar code.

use core::arch::x86_64::*;

use super::scalar::{self, box_sum_scalar, ScalarOps};
use super::Ops;
use crate::math::avx2::exp;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, store8};
use crate::softmax::{FusedInputs, LOGIT_LIMIT, MAX_CHANNELS, MAX_FUSED, TINY_DENOMINATOR};
use crate::view::{View, ViewMut};

/// [`Ops`] for AVX2; only constructed once support is known.
pub(crate) struct Avx2Ops(());

impl Avx2Ops {
    /// # Safety
    /// The CPU must support AVX2, FMA and F16C.
    pub(crate) unsafe fn new() -> Self {
        Avx2Ops(())
    }
}

#[inline]
#[target_feature(enable = "avx2,fma")]
fn clamp8(v: __m256) -> __m256 {
    // max(v, -L) returns -L when v is NaN (MAXPS returns its second operand).
    _mm256_min_ps(_mm256_max_ps(v, _mm256_set1_ps(-LOGIT_LIMIT)), _mm256_set1_ps(LOGIT_LIMIT))
}

#[target_feature(enable = "avx2,fma,f16c")]
fn row_max<S: FloatElement>(row: &[S]) -> f32 {
    let n = row.len();
    let mut acc = _mm256_set1_ps(f32::NEG_INFINITY);
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: x + 8 <= n.
        let v = unsafe { load8(row.as_ptr().add(x)) };
        acc = _mm256_max_ps(v, acc); // NaN lanes of v keep acc
        x += 8;
    }
    let mut m = crate::simd::avx2::hmax(acc);
    for &v in &row[x..] {
        m = m.max(v.to_f32());
    }
    m
}

#[target_feature(enable = "avx2,fma,f16c")]
fn exp_shifted<S: FloatElement>(l: &[S], shift: f32, e: &mut [f32]) {
    let n = e.len().min(l.len());
    let sh = _mm256_set1_ps(shift);
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: x + 8 <= n for both slices.
        unsafe {
            let v = clamp8(load8(l.as_ptr().add(x)));
            _mm256_storeu_ps(e.as_mut_ptr().add(x), exp(_mm256_sub_ps(v, sh)));
        }
        x += 8;
    }
    ScalarOps.exp_shifted(&l[x..n], shift, &mut e[x..n]);
}

#[target_feature(enable = "avx2,fma,f16c")]
fn mul<S: FloatElement>(e: &[f32], r: &[S], out: &mut [f32]) {
    let n = out.len().min(e.len()).min(r.len());
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: x + 8 <= n for all three slices.
        unsafe {
            let v = _mm256_mul_ps(_mm256_loadu_ps(e.as_ptr().add(x)), load8(r.as_ptr().add(x)));
            _mm256_storeu_ps(out.as_mut_ptr().add(x), v);
        }
        x += 8;
    }
    ScalarOps.mul(&e[x..n], &r[x..n], &mut out[x..n]);
}

/// `out[x] = a[x + oa] + b[x + ob]` for `x < n`.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn add_off(a: &[f32], oa: usize, b: &[f32], ob: usize, out: &mut [f32], n: usize) {
    assert!(a.len() >= oa + n && b.len() >= ob + n && out.len() >= n);
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: bounds asserted above.
        unsafe {
            let v = _mm256_add_ps(_mm256_loadu_ps(a.as_ptr().add(oa + x)), _mm256_loadu_ps(b.as_ptr().add(ob + x)));
            _mm256_storeu_ps(out.as_mut_ptr().add(x), v);
        }
        x += 8;
    }
    for i in x..n {
        out[i] = a[oa + i] + b[ob + i];
    }
}

/// `out[x] += a[x + oa]` for `x < n`.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn acc_off(out: &mut [f32], a: &[f32], oa: usize, n: usize) {
    assert!(a.len() >= oa + n && out.len() >= n);
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: bounds asserted above.
        unsafe {
            let p = out.as_mut_ptr().add(x);
            _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), _mm256_loadu_ps(a.as_ptr().add(oa + x))));
        }
        x += 8;
    }
    for i in x..n {
        out[i] += a[oa + i];
    }
}

/// Same pieces, same order as [`box_sum_scalar`].
#[target_feature(enable = "avx2,fma")]
fn box_sum(v: &[f32], k: usize, out: &mut [f32], lv: &mut [f32]) {
    let n = out.len();
    if k == 1 || v.len() < 8 {
        return box_sum_scalar(v, k, out, lv);
    }
    let len = v.len();
    let (s2, rest) = lv.split_at_mut(len);
    let (s4, s8) = rest.split_at_mut(len);
    add_off(v, 0, v, 1, s2, len - 1);
    if k >= 4 {
        add_off(s2, 0, s2, 2, s4, len - 3);
    }
    if k >= 8 {
        add_off(s4, 0, s4, 4, s8, len - 7);
    }
    let mut off = 0;
    let mut first = true;
    for (bit, level) in [(8usize, &*s8), (4, &*s4), (2, &*s2), (1, v)] {
        if k & bit == 0 {
            continue;
        }
        if first {
            out.copy_from_slice(&level[off..off + n]);
            first = false;
        } else {
            acc_off(out, level, off, n);
        }
        off += bit;
    }
}

#[target_feature(enable = "avx2,fma,f16c")]
fn alphas8<S: FloatElement>(f: &View<'_, S>, y: usize, x: usize) -> [__m256; MAX_FUSED] {
    let m = f.channels();
    let mut l = [_mm256_setzero_ps(); MAX_FUSED];
    let mut mx = _mm256_set1_ps(f32::NEG_INFINITY);
    for i in 0..m {
        // SAFETY: the caller guarantees x + 8 <= width.
        l[i] = clamp8(unsafe { load8(f.ptr(i, y).add(x)) });
        mx = _mm256_max_ps(mx, l[i]);
    }
    let mut sum = _mm256_setzero_ps();
    for v in l.iter_mut().take(m) {
        *v = exp(_mm256_sub_ps(*v, mx));
        sum = _mm256_add_ps(sum, *v);
    }
    let inv = _mm256_div_ps(_mm256_set1_ps(1.0), sum);
    for v in l.iter_mut().take(m) {
        *v = _mm256_mul_ps(*v, inv);
    }
    l
}

#[target_feature(enable = "avx2,fma,f16c")]
fn alphas<S: FloatElement>(f: &View<'_, S>, y: usize, x0: usize, n: usize, out: &mut [f32], stride: usize) {
    let m = f.channels();
    assert!(x0 + n <= f.width() && n <= stride && (m == 0 || out.len() >= (m - 1) * stride + n));
    let mut x = 0;
    while x + 8 <= n {
        let a = alphas8(f, y, x0 + x);
        for (i, v) in a.iter().enumerate().take(m) {
            // SAFETY: (i * stride + x + 8) <= (m - 1) * stride + n <= out.len().
            unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(i * stride + x), *v) };
        }
        x += 8;
    }
    let mut a = [0.0f32; MAX_FUSED];
    for x in x..n {
        super::alpha_pixel(f, y, x0 + x, &mut a);
        for i in 0..m {
            out[i * stride + x] = a[i];
        }
    }
}

#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
fn accumulate(
    s: &[f32],
    p: Option<&[f32]>,
    plane: usize,
    channels: usize,
    alpha: &[f32],
    acc: &mut [f32],
    acc_plane: usize,
) -> bool {
    let n = alpha.len();
    assert!(s.len() >= channels * plane + n && acc.len() >= (channels - 1) * acc_plane + n);
    if let Some(p) = p {
        assert!(p.len() >= channels * plane + n);
    }
    let tiny = _mm256_set1_ps(TINY_DENOMINATOR);
    let mut all = 0xff;
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: bounds asserted above.
        unsafe {
            let ld = |buf: &[f32], at: usize| _mm256_loadu_ps(buf.as_ptr().add(at));
            let mut den = ld(s, x);
            if let Some(p) = p {
                den = _mm256_add_ps(den, ld(p, x));
            }
            let ok = _mm256_cmp_ps::<_CMP_GE_OQ>(den, tiny);
            all &= _mm256_movemask_ps(ok);
            let inv = _mm256_div_ps(ld(alpha, x), den);
            for c in 0..channels {
                let at = (1 + c) * plane + x;
                let mut num = ld(s, at);
                if let Some(p) = p {
                    num = _mm256_add_ps(num, ld(p, at));
                }
                let add = _mm256_and_ps(_mm256_mul_ps(num, inv), ok);
                let dp = acc.as_mut_ptr().add(c * acc_plane + x);
                _mm256_storeu_ps(dp, _mm256_add_ps(_mm256_loadu_ps(dp), add));
            }
        }
        x += 8;
    }
    let mut any_tiny = all != 0xff;
    for x in x..n {
        let den = match p {
            Some(p) => s[x] + p[x],
            None => s[x],
        };
        if den >= TINY_DENOMINATOR {
            let inv = alpha[x] / den;
            for c in 0..channels {
                let at = (1 + c) * plane + x;
                let num = match p {
                    Some(p) => s[at] + p[at],
                    None => s[at],
                };
                acc[c * acc_plane + x] += num * inv;
            }
        } else {
            any_tiny = true;
        }
    }
    any_tiny
}

#[target_feature(enable = "avx2,fma,f16c")]
fn finish<S: FloatElement>(acc: &[f32], albedo: Option<&[S]>, out: &mut [S]) {
    let n = out.len().min(acc.len());
    if let Some(al) = albedo {
        assert!(al.len() >= n);
    }
    let mut x = 0;
    while x + 8 <= n {
        // SAFETY: x + 8 <= n for every slice.
        unsafe {
            let mut v = _mm256_loadu_ps(acc.as_ptr().add(x));
            if let Some(al) = albedo {
                v = _mm256_mul_ps(v, load8(al.as_ptr().add(x)));
            }
            store8(out.as_mut_ptr().add(x), v);
        }
        x += 8;
    }
    ScalarOps.finish(&acc[x..n], albedo.map(|a| &a[x..n]), &mut out[x..n]);
}

impl Ops for Avx2Ops {
    fn row_max<S: FloatElement>(&self, row: &[S]) -> f32 {
        // SAFETY: Avx2Ops exists only when AVX2/FMA/F16C are supported.
        unsafe { row_max(row) }
    }
    fn exp_shifted<S: FloatElement>(&self, l: &[S], shift: f32, e: &mut [f32]) {
        // SAFETY: as above.
        unsafe { exp_shifted(l, shift, e) }
    }
    fn mul<S: FloatElement>(&self, e: &[f32], r: &[S], out: &mut [f32]) {
        // SAFETY: as above.
        unsafe { mul(e, r, out) }
    }
    fn box_sum(&self, v: &[f32], k: usize, out: &mut [f32], lv: &mut [f32]) {
        // SAFETY: as above.
        unsafe { box_sum(v, k, out, lv) }
    }
    fn add(&self, a: &[f32], b: &[f32], out: &mut [f32]) {
        let n = out.len();
        // SAFETY: as above.
        unsafe { add_off(a, 0, b, 0, out, n) }
    }
    fn add_assign(&self, a: &mut [f32], b: &[f32]) {
        let n = a.len().min(b.len());
        // SAFETY: as above.
        unsafe { acc_off(a, b, 0, n) }
    }
    fn alphas<S: FloatElement>(&self, f: &View<'_, S>, y: usize, x0: usize, n: usize, out: &mut [f32], stride: usize) {
        // SAFETY: as above.
        unsafe { alphas(f, y, x0, n, out, stride) }
    }
    fn accumulate(
        &self,
        s: &[f32],
        p: Option<&[f32]>,
        plane: usize,
        channels: usize,
        alpha: &[f32],
        acc: &mut [f32],
        acc_plane: usize,
    ) -> bool {
        // SAFETY: as above.
        unsafe { accumulate(s, p, plane, channels, alpha, acc, acc_plane) }
    }
    fn finish<S: FloatElement>(&self, acc: &[f32], albedo: Option<&[S]>, out: &mut [S]) {
        // SAFETY: as above.
        unsafe { finish(acc, albedo, out) }
    }
}

/// The direct fused path: eight pixels at a time where every window of every
/// size lies inside the image, the scalar pixel elsewhere.
///
/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn direct<S: FloatElement>(inp: &FusedInputs<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let rad = &inp.radiance;
    let (w, h, ch) = (rad.width(), rad.height(), rad.channels());
    let rmax = inp.sizes.iter().copied().max().unwrap_or(1) / 2;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let mut x = 0;
        while x < w {
            let interior = y >= rmax && y + rmax < h && x >= rmax && x + 8 + rmax <= w;
            if !interior {
                let v = scalar::fused_pixel(inp, y, x);
                for (c, &vc) in v.iter().enumerate().take(ch) {
                    dst.row_mut(c, yo)[x] = S::from_f32(vc);
                }
                x += 1;
                continue;
            }
            let alpha = match &inp.fusion {
                Some(f) => alphas8(f, y, x),
                None => [_mm256_set1_ps(1.0); MAX_FUSED],
            };
            let mut acc = [_mm256_setzero_ps(); MAX_CHANNELS];
            for (i, &k) in inp.sizes.iter().enumerate() {
                let r = k / 2;
                let mut m = _mm256_set1_ps(f32::NEG_INFINITY);
                for yy in y - r..=y + r {
                    for xx in x - r..=x + r {
                        // SAFETY: interior: the window lies inside the image.
                        let l = clamp8(unsafe { load8(inp.importance.ptr(i, yy).add(xx)) });
                        m = _mm256_max_ps(m, l);
                    }
                }
                let mut den = _mm256_setzero_ps();
                let mut num = [_mm256_setzero_ps(); MAX_CHANNELS];
                for yy in y - r..=y + r {
                    for xx in x - r..=x + r {
                        // SAFETY: as above.
                        let l = clamp8(unsafe { load8(inp.importance.ptr(i, yy).add(xx)) });
                        let e = exp(_mm256_sub_ps(l, m));
                        den = _mm256_add_ps(den, e);
                        for (c, n) in num.iter_mut().enumerate().take(ch) {
                            // SAFETY: as above.
                            let rv = unsafe { load8(rad.ptr(c, yy).add(xx)) };
                            *n = _mm256_add_ps(*n, _mm256_mul_ps(e, rv));
                        }
                    }
                }
                for c in 0..ch {
                    let rr = _mm256_div_ps(num[c], den);
                    acc[c] = _mm256_add_ps(acc[c], _mm256_mul_ps(rr, alpha[i]));
                }
            }
            for (c, a) in acc.iter_mut().enumerate().take(ch) {
                if let Some(al) = &inp.albedo {
                    // SAFETY: x + 8 <= w.
                    *a = _mm256_mul_ps(*a, unsafe { load8(al.ptr(c, y).add(x)) });
                }
                // SAFETY: x + 8 <= w.
                unsafe { store8(dst.ptr_mut(c, yo).add(x), *a) };
            }
            x += 8;
        }
    }
}

/// Materialised kernels: eight pixels at a time in the interior.
///
/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn kernels<S: FloatElement>(k: usize, logits: &View<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let (w, h) = (logits.width(), logits.height());
    let r = k / 2;
    let mut wbuf = [0.0f32; 15 * 15];
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let mut x = 0;
        while x < w {
            let interior = y >= r && y + r < h && x >= r && x + 8 + r <= w;
            if !interior {
                scalar::kernel_pixel(k, logits, y, x, &mut wbuf);
                for (j, &v) in wbuf[..k * k].iter().enumerate() {
                    dst.row_mut(j, yo)[x] = S::from_f32(v);
                }
                x += 1;
                continue;
            }
            // SAFETY (all loads below): the window lies inside the image.
            let tap = |ky: usize, kx: usize| clamp8(unsafe { load8(logits.ptr(0, y + ky - r).add(x + kx - r)) });
            let mut m = _mm256_set1_ps(f32::NEG_INFINITY);
            for ky in 0..k {
                for kx in 0..k {
                    m = _mm256_max_ps(m, tap(ky, kx));
                }
            }
            let mut den = _mm256_setzero_ps();
            for ky in 0..k {
                for kx in 0..k {
                    den = _mm256_add_ps(den, exp(_mm256_sub_ps(tap(ky, kx), m)));
                }
            }
            let inv = _mm256_div_ps(_mm256_set1_ps(1.0), den);
            for ky in 0..k {
                for kx in 0..k {
                    let v = _mm256_mul_ps(exp(_mm256_sub_ps(tap(ky, kx), m)), inv);
                    // SAFETY: x + 8 <= w.
                    unsafe { store8(dst.ptr_mut(ky * k + kx, yo).add(x), v) };
                }
            }
            x += 8;
        }
    }
}

/// Channel softmax, eight pixels at a time, scalar tail.
///
/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn channel<S: FloatElement>(src: &View<'_, S>, dst: &mut ViewMut<'_, S>) {
    let (n, w) = (src.channels(), src.width());
    for y in 0..src.height() {
        let mut x = 0;
        while x + 8 <= w {
            // SAFETY (loads and stores): x + 8 <= w.
            let ld = |c: usize| clamp8(unsafe { load8(src.ptr(c, y).add(x)) });
            let mut m = _mm256_set1_ps(f32::NEG_INFINITY);
            for c in 0..n {
                m = _mm256_max_ps(m, ld(c));
            }
            let mut sum = _mm256_setzero_ps();
            for c in 0..n {
                sum = _mm256_add_ps(sum, exp(_mm256_sub_ps(ld(c), m)));
            }
            let inv = _mm256_div_ps(_mm256_set1_ps(1.0), sum);
            for c in 0..n {
                let v = _mm256_mul_ps(exp(_mm256_sub_ps(ld(c), m)), inv);
                // SAFETY: as above.
                unsafe { store8(dst.ptr_mut(c, y).add(x), v) };
            }
            x += 8;
        }
        for xx in x..w {
            scalar::channel_at(src, dst, y, xx);
        }
    }
}

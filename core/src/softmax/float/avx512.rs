//! AVX-512 row loops of the box-sum softmax path: sixteen lanes, tails under a
//! lane mask instead of scalar code. Same IEEE operations in the same order as
//! [`super::scalar`] and [`super::avx2`]; `exp` is bit-equal to the AVX2 one,
//! so the full-width lanes agree with AVX2 exactly and the tails differ from
//! it only by the FMA rounding of `exp`.

use core::arch::x86_64::*;

use super::Ops;
use crate::math::avx512::exp;
use crate::precision::FloatElement;
use crate::simd::avx512::{first_lanes, load16_mask, store16_mask};
use crate::softmax::{LOGIT_LIMIT, MAX_CHANNELS, MAX_FUSED, TINY_DENOMINATOR};
use crate::view::View;

/// [`Ops`] for AVX-512; only constructed once support is known.
pub(crate) struct Avx512Ops(());

impl Avx512Ops {
    /// # Safety
    /// The CPU must support AVX-512 F/BW/DQ/VL, AVX2, FMA and F16C.
    pub(crate) unsafe fn new() -> Self {
        Avx512Ops(())
    }
}

#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
fn clamp16(v: __m512) -> __m512 {
    // max(v, -L) returns -L when v is NaN (MAXPS returns its second operand).
    _mm512_min_ps(_mm512_max_ps(v, _mm512_set1_ps(-LOGIT_LIMIT)), _mm512_set1_ps(LOGIT_LIMIT))
}

#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
fn row_max<S: FloatElement>(row: &[S]) -> f32 {
    let n = row.len();
    let mut acc = _mm512_set1_ps(f32::NEG_INFINITY);
    let mut x = 0;
    while x < n {
        let m = first_lanes(n - x);
        // SAFETY: the lanes of m are below n.
        let v = unsafe { load16_mask(row.as_ptr().add(x), m) };
        acc = _mm512_mask_max_ps(acc, m, v, acc); // NaN lanes of v keep acc
        x += 16;
    }
    _mm512_reduce_max_ps(acc)
}

/// `out[x] = a[x + oa] + b[x + ob]` for `x < n`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
fn add_off(a: &[f32], oa: usize, b: &[f32], ob: usize, out: &mut [f32], n: usize) {
    assert!(a.len() >= oa + n && b.len() >= ob + n && out.len() >= n);
    let mut x = 0;
    while x < n {
        let m = first_lanes(n - x);
        // SAFETY: the lanes of m are in bounds (asserted above).
        unsafe {
            let v = _mm512_add_ps(
                _mm512_maskz_loadu_ps(m, a.as_ptr().add(oa + x)),
                _mm512_maskz_loadu_ps(m, b.as_ptr().add(ob + x)),
            );
            _mm512_mask_storeu_ps(out.as_mut_ptr().add(x), m, v);
        }
        x += 16;
    }
}

#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
fn alphas<S: FloatElement>(f: &View<'_, S>, y: usize, x0: usize, n: usize, out: &mut [f32], stride: usize) {
    let m = f.channels();
    assert!(m <= MAX_FUSED && x0 + n <= f.width() && n <= stride && (m == 0 || out.len() >= (m - 1) * stride + n));
    let mut x = 0;
    while x < n {
        let mask = first_lanes(n - x);
        let mut l = [_mm512_setzero_ps(); MAX_FUSED];
        let mut mx = _mm512_set1_ps(f32::NEG_INFINITY);
        for (i, li) in l.iter_mut().enumerate().take(m) {
            // SAFETY: x0 + x + lane < x0 + n <= width for the lanes of mask.
            *li = clamp16(unsafe { load16_mask(f.ptr(i, y).add(x0 + x), mask) });
            mx = _mm512_max_ps(mx, *li);
        }
        let mut sum = _mm512_setzero_ps();
        for v in l.iter_mut().take(m) {
            *v = exp(_mm512_sub_ps(*v, mx));
            sum = _mm512_add_ps(sum, *v);
        }
        let inv = _mm512_div_ps(_mm512_set1_ps(1.0), sum);
        for (i, v) in l.iter().enumerate().take(m) {
            // SAFETY: i * stride + x + lane < (m - 1) * stride + n <= out.len().
            unsafe { _mm512_mask_storeu_ps(out.as_mut_ptr().add(i * stride + x), mask, _mm512_mul_ps(*v, inv)) };
        }
        x += 16;
    }
}

#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
fn finish<S: FloatElement>(acc: &[f32], albedo: Option<&[S]>, out: &mut [S]) {
    let n = out.len().min(acc.len());
    if let Some(al) = albedo {
        assert!(al.len() >= n);
    }
    let mut x = 0;
    while x < n {
        let m = first_lanes(n - x);
        // SAFETY: the lanes of m are below n for every slice.
        unsafe {
            let mut v = _mm512_maskz_loadu_ps(m, acc.as_ptr().add(x));
            if let Some(al) = albedo {
                v = _mm512_mul_ps(v, load16_mask(al.as_ptr().add(x), m));
            }
            store16_mask(out.as_mut_ptr().add(x), m, v);
        }
        x += 16;
    }
}

#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
fn forward_row<S: FloatElement>(
    l: Option<&[S]>,
    rad: &[&[S]],
    shift: f32,
    u0: usize,
    u1: usize,
    a: &mut [f32],
    p_prev: Option<&[f32]>,
    p: &mut [f32],
) {
    let np = 1 + rad.len();
    let len = a.len() / np;
    assert!(np <= 1 + MAX_CHANNELS && a.len() == np * len && p.len() >= np * len && u0 <= u1 && u1 <= len);
    if let Some(pp) = p_prev {
        assert!(pp.len() >= np * len);
    }
    let n = u1 - u0;
    if let Some(l) = l {
        assert!(l.len() >= n && rad.iter().all(|r| r.len() >= n));
    }
    // Columns outside the image (and whole rows outside it): weight 0.
    let zero_col = |a: &mut [f32], p: &mut [f32], u: usize| {
        for q in 0..np {
            let i = q * len + u;
            a[i] = 0.0;
            p[i] = match p_prev {
                Some(pp) => 0.0 + pp[i],
                None => 0.0,
            };
        }
    };
    let Some(l) = l else {
        for u in 0..len {
            zero_col(a, p, u);
        }
        return;
    };
    for u in (0..u0).chain(u1..len) {
        zero_col(a, p, u);
    }
    let sh = _mm512_set1_ps(shift);
    let ap = a.as_mut_ptr();
    let pq = p.as_mut_ptr();
    let mut u = u0;
    while u < u1 {
        let m = first_lanes(u1 - u);
        // SAFETY: for the lanes of m, u - u0 + lane < n for l and rad and
        // q * len + u + lane < np * len for a, p and p_prev (asserted above).
        unsafe {
            let e = exp(_mm512_sub_ps(clamp16(load16_mask(l.as_ptr().add(u - u0), m)), sh));
            let put = |q: usize, val: __m512| {
                let i = q * len + u;
                _mm512_mask_storeu_ps(ap.add(i), m, val);
                let pv = match p_prev {
                    Some(pp) => _mm512_add_ps(val, _mm512_maskz_loadu_ps(m, pp.as_ptr().add(i))),
                    None => val,
                };
                _mm512_mask_storeu_ps(pq.add(i), m, pv);
            };
            put(0, e);
            for (c, r) in rad.iter().enumerate() {
                put(1 + c, _mm512_mul_ps(e, load16_mask(r.as_ptr().add(u - u0), m)));
            }
        }
        u += 16;
    }
}

#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
fn backward_row(a: &mut [f32], a_next: Option<&[f32]>, p_win: Option<&[f32]>, mut v: Option<&mut [f32]>) {
    let n = a.len();
    assert!(a_next.is_none_or(|x| x.len() >= n) && p_win.is_none_or(|x| x.len() >= n));
    assert!(v.as_ref().is_none_or(|x| x.len() >= n));
    let mut i = 0;
    while i < n {
        let m = first_lanes(n - i);
        // SAFETY: the lanes of m are below n for every slice (asserted).
        unsafe {
            let mut s = _mm512_maskz_loadu_ps(m, a.as_ptr().add(i));
            if let Some(nx) = a_next {
                s = _mm512_add_ps(s, _mm512_maskz_loadu_ps(m, nx.as_ptr().add(i)));
            }
            _mm512_mask_storeu_ps(a.as_mut_ptr().add(i), m, s);
            if let Some(v) = v.as_deref_mut() {
                let w = match p_win {
                    Some(p) => _mm512_add_ps(s, _mm512_maskz_loadu_ps(m, p.as_ptr().add(i))),
                    None => s,
                };
                _mm512_mask_storeu_ps(v.as_mut_ptr().add(i), m, w);
            }
        }
        i += 16;
    }
}

/// Sixteen window sums at `x` (the lanes of `m`) from the levels, same pieces
/// and order as [`super::scalar::box_at`].
///
/// # Safety
/// For the lanes of `m`, `x + lane + k` values of `v` and the needed levels
/// must be readable.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn box16(v: *const f32, lv: *const f32, len: usize, k: usize, x: usize, m: __mmask16) -> __m512 {
    let mut acc: Option<__m512> = None;
    let mut off = 0;
    for (bit, base) in [(8usize, 2 * len), (4, len), (2, 0)] {
        if k & bit != 0 {
            // SAFETY: the level is defined at x + off + lane (caller).
            let t = unsafe { _mm512_maskz_loadu_ps(m, lv.add(base + x + off)) };
            acc = Some(acc.map_or(t, |a| _mm512_add_ps(a, t)));
            off += bit;
        }
    }
    // SAFETY: as above.
    let t = unsafe { _mm512_maskz_loadu_ps(m, v.add(x + off)) };
    acc.map_or(t, |a| _mm512_add_ps(a, t))
}

#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
#[allow(clippy::too_many_arguments)]
fn horizontal_accumulate(
    v: &[f32],
    np: usize,
    k: usize,
    alpha: &[f32],
    acc: &mut [f32],
    acc_plane: usize,
    den: &mut [f32],
    lv: &mut [f32],
) -> bool {
    let len = v.len() / np;
    let tw = alpha.len();
    assert!(k >= 1 && tw + k - 1 <= len && den.len() >= tw && lv.len() >= 3 * np * len);
    assert!(np >= 2 && acc.len() >= (np - 2) * acc_plane + tw);
    // The levels, plane by plane (same additions as box_levels).
    for q in 0..np {
        let vq = &v[q * len..(q + 1) * len];
        let (s2, rest) = lv[3 * q * len..3 * (q + 1) * len].split_at_mut(len);
        let (s4, s8) = rest.split_at_mut(len);
        if k >= 2 {
            add_off(vq, 0, vq, 1, s2, len - 1);
        }
        if k >= 4 {
            add_off(s2, 0, s2, 2, s4, len - 3);
        }
        if k >= 8 {
            add_off(s4, 0, s4, 4, s8, len - 7);
        }
    }
    let tiny = _mm512_set1_ps(TINY_DENOMINATOR);
    let mut any_tiny = false;
    let mut x = 0;
    while x < tw {
        let m = first_lanes(tw - x);
        // SAFETY: x + lane + k - 1 < len for the lanes of m, so every piece of
        // box16 is in its level's defined range; acc and den hold tw columns
        // per plane (asserted).
        unsafe {
            let d = box16(v.as_ptr(), lv.as_ptr(), len, k, x, m);
            _mm512_mask_storeu_ps(den.as_mut_ptr().add(x), m, d);
            let ok = _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(m, d, tiny);
            any_tiny |= ok != m;
            let inv = _mm512_div_ps(_mm512_maskz_loadu_ps(m, alpha.as_ptr().add(x)), d);
            for q in 1..np {
                let num = box16(v.as_ptr().add(q * len), lv.as_ptr().add(3 * q * len), len, k, x, m);
                let dp = acc.as_mut_ptr().add((q - 1) * acc_plane + x);
                // Lanes below TINY (and past the tail) keep their accumulator.
                let sum = _mm512_add_ps(_mm512_maskz_loadu_ps(m, dp), _mm512_mul_ps(num, inv));
                _mm512_mask_storeu_ps(dp, ok, sum);
            }
        }
        x += 16;
    }
    any_tiny
}

impl Ops<f32> for Avx512Ops {
    fn row_max<S: FloatElement>(&self, row: &[S]) -> f32 {
        // SAFETY: Avx512Ops exists only when its features are supported.
        unsafe { row_max(row) }
    }
    fn forward_row<S: FloatElement>(
        &self,
        l: Option<&[S]>,
        rad: &[&[S]],
        shift: f32,
        u0: usize,
        u1: usize,
        a: &mut [f32],
        p_prev: Option<&[f32]>,
        p: &mut [f32],
    ) {
        // SAFETY: as above.
        unsafe { forward_row(l, rad, shift, u0, u1, a, p_prev, p) }
    }
    fn backward_row(&self, a: &mut [f32], a_next: Option<&[f32]>, p_win: Option<&[f32]>, v: Option<&mut [f32]>) {
        // SAFETY: as above.
        unsafe { backward_row(a, a_next, p_win, v) }
    }
    fn horizontal_accumulate(
        &self,
        v: &[f32],
        np: usize,
        k: usize,
        alpha: &[f32],
        acc: &mut [f32],
        acc_plane: usize,
        den: &mut [f32],
        lv: &mut [f32],
    ) -> bool {
        // SAFETY: as above.
        unsafe { horizontal_accumulate(v, np, k, alpha, acc, acc_plane, den, lv) }
    }
    fn alphas<S: FloatElement>(&self, f: &View<'_, S>, y: usize, x0: usize, n: usize, out: &mut [f32], stride: usize) {
        // SAFETY: as above.
        unsafe { alphas(f, y, x0, n, out, stride) }
    }
    fn finish<S: FloatElement>(&self, acc: &[f32], albedo: Option<&[S]>, out: &mut [S]) {
        // SAFETY: as above.
        unsafe { finish(acc, albedo, out) }
    }
    fn prefetch<S: FloatElement>(&self, row: &[S]) {
        super::prefetch_row(row)
    }
}

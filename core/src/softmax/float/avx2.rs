//! AVX2 + FMA row loops and 8-pixel paths of the softmax operators. Each loop
//! does the same IEEE operations in the same order as [`super::scalar`]; only
//! `exp` differs (FMA in its reduction and polynomial). Tails shorter than
//! eight lanes run the scalar code, except in the box-sum path's carried
//! rows (a lane-masked chunk: that row's exp is the vector one throughout).

use core::arch::x86_64::*;

use super::scalar::{self, box_at, ScalarOps};
use super::{Ops, SepOps, SEP_LS, SEP_SS};
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

/// The fusion weights of eight pixels; `M` planes when not 0, else `f.channels()`.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
fn alphas8<S: FloatElement, const M: usize>(f: &View<'_, S>, y: usize, x: usize) -> [__m256; MAX_FUSED] {
    let m = if M > 0 { M } else { f.channels() };
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
    match f.channels() {
        // WSKP's six sizes: the plane loops unrolled.
        6 => alphas_m::<S, 6>(f, y, x0, n, out, stride),
        _ => alphas_m::<S, 0>(f, y, x0, n, out, stride),
    }
}

/// [`alphas`] with `M` planes (0: `f.channels()`).
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
fn alphas_m<S: FloatElement, const M: usize>(
    f: &View<'_, S>,
    y: usize,
    x0: usize,
    n: usize,
    out: &mut [f32],
    stride: usize,
) {
    let m = if M > 0 { M } else { f.channels() };
    assert!(m == f.channels() && x0 + n <= f.width() && n <= stride && (m == 0 || out.len() >= (m - 1) * stride + n));
    let mut x = 0;
    while x + 8 <= n {
        let a = alphas8::<S, M>(f, y, x0 + x);
        for (i, v) in a.iter().enumerate().take(m) {
            // SAFETY: (i * stride + x + 8) <= (m - 1) * stride + n <= out.len().
            unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(i * stride + x), *v) };
        }
        x += 8;
    }
    let mut a = [0.0f32; MAX_FUSED];
    for x in x..n {
        super::alpha_pixel::<S, f32>(f, y, x0 + x, &mut a);
        for i in 0..m {
            out[i * stride + x] = a[i];
        }
    }
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
    ScalarOps::<f32>::new().finish(&acc[x..n], albedo.map(|a| &a[x..n]), &mut out[x..n]);
}

#[target_feature(enable = "avx2,fma,f16c")]
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
    // The vector loop, with the channel count and the block start as
    // constants (no test or pointer reload per chunk).
    let u = match (rad.len(), p_prev) {
        (1, None) => forward_chunks::<S, 1, false, true>(l, rad, shift, u0, u1, a, None, p),
        (1, Some(pp)) => forward_chunks::<S, 1, true, true>(l, rad, shift, u0, u1, a, Some(pp), p),
        (3, None) => forward_chunks::<S, 3, false, true>(l, rad, shift, u0, u1, a, None, p),
        (3, Some(pp)) => forward_chunks::<S, 3, true, true>(l, rad, shift, u0, u1, a, Some(pp), p),
        (_, pp) => forward_chunks::<S, 0, false, true>(l, rad, shift, u0, u1, a, pp, p),
    };
    debug_assert_eq!(u, u1);
}

/// The columns `u0 .. u1` of [`forward_row`], eight at a time and the last
/// few under a lane mask; returns `u1`. `NC` radiance channels and `PREV` (a
/// previous prefix row) when `NC` is not 0, else `rad.len()` and `p_prev`.
/// Without `PFX` only `a` is written (the separable path's weight rows).
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
fn forward_chunks<S: FloatElement, const NC: usize, const PREV: bool, const PFX: bool>(
    l: &[S],
    rad: &[&[S]],
    shift: f32,
    u0: usize,
    u1: usize,
    a: &mut [f32],
    p_prev: Option<&[f32]>,
    p: &mut [f32],
) -> usize {
    let nc = if NC > 0 { NC } else { rad.len() };
    let np = 1 + nc;
    let len = a.len() / np;
    // (forward_row asserted every length.)
    let sh = _mm256_set1_ps(shift);
    let ap = a.as_mut_ptr();
    let pq = p.as_mut_ptr();
    let pp = p_prev.map_or(core::ptr::null(), |v| v.as_ptr());
    let has_prev = if NC > 0 { PREV } else { p_prev.is_some() };
    let mut rp = [core::ptr::null::<S>(); MAX_CHANNELS];
    for (r, src) in rp.iter_mut().zip(rad) {
        *r = src.as_ptr();
    }
    // Columns u .. u + n: whole chunks, then the last 1-7 columns with
    // their loads and stores under a lane mask (the vector exp, as the
    // chunks before them). One body, expanded for each so neither tests n.
    // SAFETY (the loads and stores): lanes below n lie inside l and rad
    // (u - u0 + n <= u1 - u0) and a, p, p_prev (q * len + u + n <= np * len).
    macro_rules! chunk {
        ($u:expr, $n:expr, $masked:literal) => {{
            let (u, n) = ($u, $n);
            unsafe {
                use crate::simd::avx2::{load8_range, store8_first};
                let ld = |p: *const S| if $masked { load8_range(p, 0, n) } else { load8(p) };
                let ldf = |p: *const f32| if $masked { load8_range(p, 0, n) } else { _mm256_loadu_ps(p) };
                let st = |p: *mut f32, v: __m256| {
                    if $masked {
                        store8_first::<f32>(p, n, v)
                    } else {
                        _mm256_storeu_ps(p, v)
                    }
                };
                let e = exp(_mm256_sub_ps(clamp8(ld(l.as_ptr().add(u - u0))), sh));
                let put = |q: usize, val: __m256| {
                    let i = q * len + u;
                    st(ap.add(i), val);
                    if PFX {
                        st(pq.add(i), if has_prev { _mm256_add_ps(val, ldf(pp.add(i))) } else { val });
                    }
                };
                put(0, e);
                for (c, r) in rp.iter().enumerate().take(nc) {
                    put(1 + c, _mm256_mul_ps(e, ld(r.add(u - u0))));
                }
            }
        }};
    }
    let mut u = u0;
    while u + 8 <= u1 {
        chunk!(u, 8, false);
        u += 8;
    }
    if u < u1 {
        chunk!(u, u1 - u, true);
    }
    u1
}

#[target_feature(enable = "avx2,fma")]
fn backward_row(a: &mut [f32], a_next: Option<&[f32]>, p_win: Option<&[f32]>, mut v: Option<&mut [f32]>) {
    let n = a.len();
    assert!(a_next.is_none_or(|x| x.len() >= n) && p_win.is_none_or(|x| x.len() >= n));
    assert!(v.as_ref().is_none_or(|x| x.len() >= n));
    let mut i = 0;
    while i + 8 <= n {
        // SAFETY: i + 8 <= n for every slice (asserted).
        unsafe {
            let mut s = _mm256_loadu_ps(a.as_ptr().add(i));
            if let Some(nx) = a_next {
                s = _mm256_add_ps(s, _mm256_loadu_ps(nx.as_ptr().add(i)));
            }
            _mm256_storeu_ps(a.as_mut_ptr().add(i), s);
            if let Some(v) = v.as_deref_mut() {
                let w = match p_win {
                    Some(p) => _mm256_add_ps(s, _mm256_loadu_ps(p.as_ptr().add(i))),
                    None => s,
                };
                _mm256_storeu_ps(v.as_mut_ptr().add(i), w);
            }
        }
        i += 8;
    }
    for i in i..n {
        let s = match a_next {
            Some(nx) => a[i] + nx[i],
            None => a[i],
        };
        a[i] = s;
        if let Some(v) = v.as_deref_mut() {
            v[i] = match p_win {
                Some(p) => s + p[i],
                None => s,
            };
        }
    }
}

/// Eight window sums at `x` from the levels, same pieces and order as [`box_at`].
///
/// # Safety
/// `x + k` values of `v` and the needed levels must be readable.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn box8(v: *const f32, lv: *const f32, len: usize, k: usize, x: usize) -> __m256 {
    let mut acc: Option<__m256> = None;
    let mut off = 0;
    for (bit, base) in [(8usize, 2 * len), (4, len), (2, 0)] {
        if k & bit != 0 {
            // SAFETY: the level is defined at x + off .. x + off + 8 (caller).
            let t = unsafe { _mm256_loadu_ps(lv.add(base + x + off)) };
            acc = Some(acc.map_or(t, |a| _mm256_add_ps(a, t)));
            off += bit;
        }
    }
    // SAFETY: as above.
    let t = unsafe { _mm256_loadu_ps(v.add(x + off)) };
    acc.map_or(t, |a| _mm256_add_ps(a, t))
}

/// [`horizontal_accumulate_k`] with the window size as a constant for the
/// odd sizes (the pieces of [`box8`] then need no test per chunk).
#[target_feature(enable = "avx2,fma")]
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
    macro_rules! go {
        ($k:literal) => {
            horizontal_accumulate_k::<$k>(v, np, $k, alpha, acc, acc_plane, den, lv)
        };
    }
    match k {
        1 => go!(1),
        3 => go!(3),
        5 => go!(5),
        7 => go!(7),
        9 => go!(9),
        11 => go!(11),
        13 => go!(13),
        15 => go!(15),
        _ => horizontal_accumulate_k::<0>(v, np, k, alpha, acc, acc_plane, den, lv),
    }
}

/// Window size `k` (`K` when not 0).
#[inline]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
fn horizontal_accumulate_k<const K: usize>(
    v: &[f32],
    np: usize,
    k: usize,
    alpha: &[f32],
    acc: &mut [f32],
    acc_plane: usize,
    den: &mut [f32],
    lv: &mut [f32],
) -> bool {
    let k = if K > 0 { K } else { k };
    let len = v.len() / np;
    let tw = alpha.len();
    assert!(tw + k - 1 <= len && den.len() >= tw && lv.len() >= 3 * np * len);
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
    let tiny = _mm256_set1_ps(TINY_DENOMINATOR);
    let mut all = 0xff;
    let mut x = 0;
    while x + 8 <= tw {
        // SAFETY: x + 8 + k - 1 <= len, so every piece of box8 is in its level's
        // defined range; acc and den hold tw columns per plane (asserted).
        unsafe {
            let d = box8(v.as_ptr(), lv.as_ptr(), len, k, x);
            _mm256_storeu_ps(den.as_mut_ptr().add(x), d);
            let ok = _mm256_cmp_ps::<_CMP_GE_OQ>(d, tiny);
            all &= _mm256_movemask_ps(ok);
            let inv = _mm256_div_ps(_mm256_loadu_ps(alpha.as_ptr().add(x)), d);
            for q in 1..np {
                let num = box8(v.as_ptr().add(q * len), lv.as_ptr().add(3 * q * len), len, k, x);
                let add = _mm256_and_ps(_mm256_mul_ps(num, inv), ok);
                let dp = acc.as_mut_ptr().add((q - 1) * acc_plane + x);
                _mm256_storeu_ps(dp, _mm256_add_ps(_mm256_loadu_ps(dp), add));
            }
        }
        x += 8;
    }
    let mut any_tiny = all != 0xff;
    for x in x..tw {
        let d = box_at(&v[..len], &lv[..3 * len], k, x);
        den[x] = d;
        if d >= TINY_DENOMINATOR {
            let inv = alpha[x] / d;
            for q in 1..np {
                let num = box_at(&v[q * len..(q + 1) * len], &lv[3 * q * len..3 * (q + 1) * len], k, x);
                acc[(q - 1) * acc_plane + x] += num * inv;
            }
        } else {
            any_tiny = true;
        }
    }
    any_tiny
}

/// [`SepOps::weights_row`].
#[target_feature(enable = "avx2,fma,f16c")]
fn weights_row<S: FloatElement>(l: Option<&[S]>, rad: &[&[S]], shift: f32, u0: usize, u1: usize, w: &mut [f32]) {
    let np = 1 + rad.len();
    assert!(np <= 1 + MAX_CHANNELS && w.len() >= np * SEP_LS && u0 <= u1 && u1 <= SEP_LS);
    let w = &mut w[..np * SEP_LS];
    let Some(l) = l else {
        w.fill(0.0);
        return;
    };
    assert!(l.len() >= u1 - u0 && rad.iter().all(|r| r.len() >= u1 - u0));
    for q in 0..np {
        w[q * SEP_LS..q * SEP_LS + u0].fill(0.0);
        w[q * SEP_LS + u1..(q + 1) * SEP_LS].fill(0.0);
    }
    let u = match rad.len() {
        1 => forward_chunks::<S, 1, false, false>(l, rad, shift, u0, u1, w, None, &mut []),
        3 => forward_chunks::<S, 3, false, false>(l, rad, shift, u0, u1, w, None, &mut []),
        _ => forward_chunks::<S, 0, false, false>(l, rad, shift, u0, u1, w, None, &mut []),
    };
    debug_assert_eq!(u, u1);
}

/// [`SepOps::vertical_sum`] with the window size `K` as a constant (0: `k`).
#[target_feature(enable = "avx2,fma")]
fn vertical_sum_k<const K: usize>(ring: &[f32], k: usize, v: &mut [f32]) {
    let k = if K > 0 { K } else { k };
    let n = v.len();
    assert!(k >= 1 && ring.len() >= (k - 1) * SEP_SS + n);
    let (rp, vp) = (ring.as_ptr(), v.as_mut_ptr());
    let mut i = 0;
    while i + 8 <= n {
        // SAFETY: slot * SEP_SS + i + 8 <= (k - 1) * SEP_SS + n <= ring.len() (asserted).
        unsafe {
            let mut s = _mm256_loadu_ps(rp.add(i));
            for slot in 1..k {
                s = _mm256_add_ps(s, _mm256_loadu_ps(rp.add(slot * SEP_SS + i)));
            }
            _mm256_storeu_ps(vp.add(i), s);
        }
        i += 8;
    }
    // The same additions in the same order as the chunks.
    ScalarOps::<f32>::new().vertical_sum(&ring[i..], k, &mut v[i..]);
}

/// Eight horizontal window sums `sum_{j < k} p[x + j]`, `j` ascending.
///
/// # Safety
/// `p[.. 8 + k - 1]` must be readable.
#[inline(always)]
unsafe fn window8(p: *const f32, k: usize) -> __m256 {
    // SAFETY: the caller's range.
    unsafe {
        let mut s = _mm256_loadu_ps(p);
        for j in 1..k {
            s = _mm256_add_ps(s, _mm256_loadu_ps(p.add(j)));
        }
        s
    }
}

/// [`SepOps::horizontal_direct`] with `K` as a constant (0: `k`).
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
fn horizontal_direct_k<const K: usize, const NP: usize>(
    v: &[f32],
    np: usize,
    k: usize,
    alpha: &[f32],
    acc: &mut [f32],
    acc_plane: usize,
    den: &mut [f32],
) -> bool {
    let k = if K > 0 { K } else { k };
    let np = if NP > 0 { NP } else { np };
    let tw = alpha.len();
    assert!(np >= 2 && tw + k - 1 <= SEP_LS && v.len() >= np * SEP_LS && den.len() >= tw);
    assert!(acc.len() >= (np - 2) * acc_plane + tw);
    let tiny = _mm256_set1_ps(TINY_DENOMINATOR);
    let mut all = 0xff;
    let mut x = 0;
    while x + 8 <= tw {
        // SAFETY: q * SEP_LS + x + 8 + k - 1 <= np * SEP_LS <= v.len(); acc and
        // den hold tw columns per plane (asserted).
        unsafe {
            let d = window8(v.as_ptr().add(x), k);
            _mm256_storeu_ps(den.as_mut_ptr().add(x), d);
            let ok = _mm256_cmp_ps::<_CMP_GE_OQ>(d, tiny);
            all &= _mm256_movemask_ps(ok);
            let inv = _mm256_div_ps(_mm256_loadu_ps(alpha.as_ptr().add(x)), d);
            for q in 1..np {
                let num = window8(v.as_ptr().add(q * SEP_LS + x), k);
                let add = _mm256_and_ps(_mm256_mul_ps(num, inv), ok);
                let dp = acc.as_mut_ptr().add((q - 1) * acc_plane + x);
                _mm256_storeu_ps(dp, _mm256_add_ps(_mm256_loadu_ps(dp), add));
            }
        }
        x += 8;
    }
    // The last 1-7 columns: the same operations in the same order.
    let tail = x < tw
        && ScalarOps::<f32>::new().horizontal_direct(
            &v[x..],
            np,
            k,
            &alpha[x..],
            &mut acc[x..],
            acc_plane,
            &mut den[x..],
        );
    all != 0xff || tail
}

impl SepOps<f32> for Avx2Ops {
    fn weights_row<S: FloatElement>(
        &self,
        l: Option<&[S]>,
        rad: &[&[S]],
        shift: f32,
        u0: usize,
        u1: usize,
        w: &mut [f32],
    ) {
        // SAFETY: Avx2Ops exists only when AVX2/FMA/F16C are supported.
        unsafe { weights_row(l, rad, shift, u0, u1, w) }
    }
    fn vertical_sum(&self, ring: &[f32], k: usize, v: &mut [f32]) {
        macro_rules! go {
            ($($k:literal)*) => {
                match k {
                    // SAFETY: as above.
                    $($k => unsafe { vertical_sum_k::<$k>(ring, k, v) },)*
                    // SAFETY: as above.
                    _ => unsafe { vertical_sum_k::<0>(ring, k, v) },
                }
            };
        }
        go!(1 3 5 7 9 11 13 15)
    }
    fn horizontal_direct(
        &self,
        v: &[f32],
        np: usize,
        k: usize,
        alpha: &[f32],
        acc: &mut [f32],
        acc_plane: usize,
        den: &mut [f32],
    ) -> bool {
        // The window size and, for one or three channels, the plane count as constants.
        macro_rules! go {
            ($($k:literal)*) => {
                match (k, np) {
                    // SAFETY: as above.
                    $(($k, 4) => unsafe { horizontal_direct_k::<$k, 4>(v, np, k, alpha, acc, acc_plane, den) },)*
                    // SAFETY: as above.
                    $(($k, 2) => unsafe { horizontal_direct_k::<$k, 2>(v, np, k, alpha, acc, acc_plane, den) },)*
                    // SAFETY: as above.
                    _ => unsafe { horizontal_direct_k::<0, 0>(v, np, k, alpha, acc, acc_plane, den) },
                }
            };
        }
        go!(1 3 5 7 9 11 13 15)
    }
}

impl Ops<f32> for Avx2Ops {
    fn row_max<S: FloatElement>(&self, row: &[S]) -> f32 {
        // SAFETY: Avx2Ops exists only when AVX2/FMA/F16C are supported.
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
                let v = scalar::fused_pixel::<S, f32>(inp, y, x);
                for (c, &vc) in v.iter().enumerate().take(ch) {
                    dst.row_mut(c, yo)[x] = S::from_f32(vc);
                }
                x += 1;
                continue;
            }
            let alpha = match &inp.fusion {
                Some(f) => alphas8::<S, 0>(f, y, x),
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
                scalar::kernel_pixel::<S, f32>(k, logits, y, x, &mut wbuf);
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
            scalar::channel_at::<S, f32>(src, dst, y, xx);
        }
    }
}

//! AVX2 à-trous step: eight pixels at a time where all 25 taps lie inside
//! the image (the same operations in the same order as the scalar pixel, FMA
//! aside), the scalar pixel near the border.

use core::arch::x86_64::*;

use super::scalar::{self, MAX_OUT};
use super::{h2, Ctx, Geometry};
use crate::math::avx2::exp;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, store8};
use crate::view::{View, ViewMut};

#[inline(always)]
unsafe fn ld<S: FloatElement>(v: &View<'_, S>, c: usize, y: usize, x: usize) -> __m256 {
    // SAFETY: the caller keeps (c, y, x .. x + 8) inside the view.
    unsafe { load8(v.ptr(c, y).add(x)) }
}

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn step<S: FloatElement>(c: &Ctx<'_, '_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let (w, h) = (c.src.width(), c.src.height());
    let m = 2 * c.hole;
    let nout = dst.channels();
    let mut out = [0.0f32; MAX_OUT];
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let mut x = 0;
        while x < w {
            if y >= m && y + m < h && x >= m && x + 8 + m <= w {
                // SAFETY: every tap of the eight pixels lies inside the image.
                unsafe { interior8(c, dst, y, yo, x) };
                x += 8;
            } else {
                scalar::pixel(c, y, x, &mut out);
                for (ch, &v) in out.iter().enumerate().take(nout) {
                    dst.row_mut(ch, yo)[x] = S::from_f32(v);
                }
                x += 1;
            }
        }
    }
}

/// # Safety
/// AVX2/FMA/F16C; all taps of pixels `x .. x + 8` on row `y` inside the image.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn interior8<S: FloatElement>(c: &Ctx<'_, '_, S>, dst: &mut ViewMut<'_, S>, y: usize, yo: usize, x: usize) {
    let src = c.src;
    let g = c.guides;
    let nc = 3 * c.groups;
    let inv_g = _mm256_set1_ps(1.0 / c.groups as f32);
    // SAFETY (all loads in this function): the caller guarantees every tap is inside.
    let guide = |yy: usize, xx: usize, ch: usize| unsafe {
        let mut s = ld(src, ch, yy, xx);
        for gi in 1..c.groups {
            s = _mm256_add_ps(s, ld(src, 3 * gi + ch, yy, xx));
        }
        _mm256_mul_ps(s, inv_g)
    };
    let gp = [guide(y, x, 0), guide(y, x, 1), guide(y, x, 2)];
    let vp = unsafe { ld(&g.noise, 0, y, x) };
    let cscale = _mm256_set1_ps(c.color_scale);
    let ceps = _mm256_set1_ps(c.eps);
    let v3 = |v: &View<'_, S>, yy: usize, xx: usize| unsafe { [ld(v, 0, yy, xx), ld(v, 1, yy, xx), ld(v, 2, yy, xx)] };
    let zero = _mm256_setzero_ps();
    let np = g.normal.as_ref().map(|n| v3(n, y, x)).unwrap_or([zero; 3]);
    let xp = g.position.as_ref().map(|p| v3(p, y, x)).unwrap_or([zero; 3]);
    let zp = g.depth.as_ref().map(|d| unsafe { ld(d, 0, y, x) }).unwrap_or(zero);
    let inv_zp = _mm256_div_ps(_mm256_set1_ps(1.0), _mm256_max_ps(zp, _mm256_set1_ps(1e-20)));
    let inv_n2 = _mm256_set1_ps(c.inv_normal2);
    let inv_geo = _mm256_set1_ps(c.inv_geom2);
    let mut wsum = zero;
    let mut acc = [zero; 6];
    let mut accv = zero;
    for dy in 0..5 {
        let qy = y + dy * c.hole - 2 * c.hole;
        for dx in 0..5 {
            let qx = x + dx * c.hole - 2 * c.hole;
            let mut dc = zero;
            for ch in 0..3 {
                let d = _mm256_sub_ps(gp[ch], guide(qy, qx, ch));
                dc = _mm256_fmadd_ps(d, d, dc);
            }
            // min(vq, vp) as the scalar `if vq < vp { vq } else { vp }`.
            let v = _mm256_min_ps(unsafe { ld(&g.noise, 0, qy, qx) }, vp);
            let mut t = _mm256_div_ps(dc, _mm256_fmadd_ps(cscale, v, ceps));
            if let Some(n) = &g.normal {
                let nq = v3(n, qy, qx);
                let mut dn = zero;
                for k in 0..3 {
                    let d = _mm256_sub_ps(np[k], nq[k]);
                    dn = _mm256_fmadd_ps(d, d, dn);
                }
                t = _mm256_fmadd_ps(dn, inv_n2, t);
            }
            match c.geometry {
                Geometry::Plane | Geometry::Position => {
                    let xq = v3(g.position.as_ref().expect("position"), qy, qx);
                    let d = [_mm256_sub_ps(xq[0], xp[0]), _mm256_sub_ps(xq[1], xp[1]), _mm256_sub_ps(xq[2], xp[2])];
                    let gd = if c.geometry == Geometry::Plane {
                        let pd = _mm256_fmadd_ps(np[2], d[2], _mm256_fmadd_ps(np[1], d[1], _mm256_mul_ps(np[0], d[0])));
                        _mm256_mul_ps(pd, pd)
                    } else {
                        _mm256_fmadd_ps(d[2], d[2], _mm256_fmadd_ps(d[1], d[1], _mm256_mul_ps(d[0], d[0])))
                    };
                    t = _mm256_fmadd_ps(gd, inv_geo, t);
                }
                Geometry::Depth => {
                    let zq = unsafe { ld(g.depth.as_ref().expect("depth"), 0, qy, qx) };
                    let r = _mm256_mul_ps(_mm256_sub_ps(zq, zp), inv_zp);
                    t = _mm256_fmadd_ps(_mm256_mul_ps(r, r), inv_geo, t);
                }
                Geometry::None => {}
            }
            let wt = _mm256_mul_ps(_mm256_set1_ps(h2(dy, dx)), exp(_mm256_sub_ps(zero, t)));
            wsum = _mm256_add_ps(wsum, wt);
            for (ch, a) in acc.iter_mut().enumerate().take(nc) {
                *a = _mm256_fmadd_ps(wt, unsafe { ld(src, ch, qy, qx) }, *a);
            }
            if c.with_variance {
                accv = _mm256_fmadd_ps(_mm256_mul_ps(wt, wt), unsafe { ld(src, nc, qy, qx) }, accv);
            }
        }
    }
    let inv = _mm256_div_ps(_mm256_set1_ps(1.0), wsum);
    for (ch, a) in acc.iter().enumerate().take(nc) {
        // SAFETY: x + 8 <= width.
        unsafe { store8(dst.ptr_mut(ch, yo).add(x), _mm256_mul_ps(*a, inv)) };
    }
    if c.with_variance {
        // SAFETY: as above.
        unsafe {
            store8(dst.ptr_mut(nc, yo).add(x), _mm256_mul_ps(_mm256_mul_ps(accv, inv), inv));
            store8(dst.ptr_mut(nc + 1, yo).add(x), _mm256_mul_ps(_mm256_set1_ps(h2(2, 2)), inv));
        }
    }
}

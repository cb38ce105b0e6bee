//! AVX2 à-trous step: eight pixels at a time wherever the 25 taps stay
//! inside the image horizontally (tap rows above or below the image are
//! skipped, as in the scalar pixel), the scalar pixel in the left and right
//! margins. Same operations in the same order as the scalar pixel, except
//! FMA contractions and the reciprocal (one Newton step, 2 ulp).

use core::arch::x86_64::*;

use super::scalar::{self, MAX_OUT};
use super::{h2, rows, Ctx, Geometry, RowPtrs};
use crate::math::avx2::exp;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, store8};
use crate::view::ViewMut;

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn step<S: FloatElement>(c: &Ctx<'_, '_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let w = c.src.width();
    let m = 2 * c.hole;
    let nout = dst.channels();
    let mut out = [0.0f32; MAX_OUT];
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let mut scalar_px = |x: usize, dst: &mut ViewMut<'_, S>| {
            scalar::pixel::<S, f32>(c, y, x, &mut out);
            for (ch, &v) in out.iter().enumerate().take(nout) {
                dst.row_mut(ch, yo)[x] = S::from_f32(v);
            }
        };
        let mut x = 0;
        while x < w.min(m) {
            scalar_px(x, dst);
            x += 1;
        }
        // The next output row's tap rows were last read 2^level rows ago and
        // have left L2 at the coarse levels: ask for them now (into L2).
        if y + 1 < c.src.height() {
            for dy in 0..5 {
                if let Some(qy) = (y + 1 + dy * c.hole).checked_sub(2 * c.hole).filter(|&v| v < c.src.height()) {
                    prefetch_row(c, qy);
                }
            }
        }
        // The rows every tap reads, once per output row: the centre row and
        // the five tap rows (None above or below the image).
        let centre = rows(c, y);
        let taps: [Option<RowPtrs<S>>; 5] = core::array::from_fn(|dy| {
            (y + dy * c.hole).checked_sub(2 * c.hole).filter(|&v| v < c.src.height()).map(|qy| rows(c, qy))
        });
        macro_rules! run {
            ($g:literal, $v:literal, $geo:literal) => {
                while x + 8 + m <= w {
                    // SAFETY: every tap column of the eight pixels lies inside the image.
                    unsafe { interior8::<S, $g, $v, $geo>(c, &centre, &taps, dst, yo, x) };
                    x += 8;
                }
            };
        }
        // Monomorphised so every loop bound is a constant and the
        // accumulators stay in registers.
        match (c.groups, c.with_variance, c.geometry) {
            (1, false, Geometry::Plane) => run!(1, false, 0),
            (1, false, Geometry::Position) => run!(1, false, 1),
            (1, false, Geometry::Depth) => run!(1, false, 2),
            (1, false, Geometry::None) => run!(1, false, 3),
            (1, true, Geometry::Plane) => run!(1, true, 0),
            (1, true, Geometry::Position) => run!(1, true, 1),
            (1, true, Geometry::Depth) => run!(1, true, 2),
            (1, true, Geometry::None) => run!(1, true, 3),
            (2, false, Geometry::Plane) => run!(2, false, 0),
            (2, false, Geometry::Position) => run!(2, false, 1),
            (2, false, Geometry::Depth) => run!(2, false, 2),
            (2, false, Geometry::None) => run!(2, false, 3),
            (2, true, Geometry::Plane) => run!(2, true, 0),
            (2, true, Geometry::Position) => run!(2, true, 1),
            (2, true, Geometry::Depth) => run!(2, true, 2),
            (2, true, Geometry::None) => run!(2, true, 3),
            _ => {} // groups is checked to be 1 or 2: unreachable
        }
        while x < w {
            scalar_px(x, dst);
            x += 1;
        }
    }
}

/// Prefetches row `yy` of every plane a tap reads into L2.
#[target_feature(enable = "avx2,fma,f16c")]
fn prefetch_row<S: FloatElement>(c: &Ctx<'_, '_, S>, yy: usize) {
    let r = rows(c, yy);
    let bytes = c.src.width() * core::mem::size_of::<S>();
    let one = |p: *const S| {
        if p.is_null() {
            return;
        }
        let mut off = 0;
        while off < bytes {
            _mm_prefetch::<_MM_HINT_T1>((p as *const i8).wrapping_add(off));
            off += 64;
        }
    };
    for p in r.src.iter().chain(r.normal.iter()).chain(r.position.iter()) {
        one(*p);
    }
    one(r.noise);
    one(r.depth);
}

/// # Safety
/// AVX2/FMA/F16C; columns `x - 2 hole .. x + 8 + 2 hole` inside the image;
/// `centre` and `taps` are the rows of output row `yo`.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn interior8<S: FloatElement, const G: usize, const VAR: bool, const GEO: u8>(
    c: &Ctx<'_, '_, S>,
    pr: &RowPtrs<S>,
    taps: &[Option<RowPtrs<S>>; 5],
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    x: usize,
) {
    let g = c.guides;
    let nc = 3 * G;
    let geo = match GEO {
        0 => Geometry::Plane,
        1 => Geometry::Position,
        2 => Geometry::Depth,
        _ => Geometry::None,
    };
    // SAFETY (every load below): pointers come from in-range rows and
    // columns x - 2 hole .. x + 8 + 2 hole are inside (caller).
    let ld = |p: *const S, xx: usize| unsafe { load8(p.add(xx)) };
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let two = _mm256_set1_ps(2.0);
    // The colour guide is the first image.
    let guide = |r: &RowPtrs<S>, xx: usize, ch: usize| ld(r.src[ch], xx);
    let gp = [guide(pr, x, 0), guide(pr, x, 1), guide(pr, x, 2)];
    let vp = ld(pr.noise, x);
    // Plane needs normals; the other geometries may have them too.
    let has_n = g.normal.is_some();
    let np: [__m256; 3] = core::array::from_fn(|k| if has_n { ld(pr.normal[k], x) } else { zero });
    let uses_pos = matches!(geo, Geometry::Plane | Geometry::Position);
    let xp: [__m256; 3] = core::array::from_fn(|k| if uses_pos { ld(pr.position[k], x) } else { zero });
    let zp = if geo == Geometry::Depth { ld(pr.depth, x) } else { zero };
    let inv_zp = _mm256_div_ps(one, _mm256_max_ps(zp, _mm256_set1_ps(1e-20)));
    let cscale = _mm256_set1_ps(c.color_scale);
    let ceps = _mm256_set1_ps(c.eps);
    let inv_n2 = _mm256_set1_ps(c.inv_normal2);
    let inv_geo = _mm256_set1_ps(c.inv_geom2);
    // n(p) . x(p), so the tangent-plane distance is n(p) . x(q) - n(p) . x(p).
    let npxp = _mm256_fmadd_ps(np[2], xp[2], _mm256_fmadd_ps(np[1], xp[1], _mm256_mul_ps(np[0], xp[0])));
    // Pass 1: the 25 weights (0 for tap rows outside the image), into a
    // small array, so that pass 2 keeps only the accumulators in registers.
    let mut wts = [zero; 25];
    for dy in 0..5 {
        let Some(qr) = &taps[dy] else { continue };
        for dx in 0..5 {
            let qx = x + dx * c.hole - 2 * c.hole;
            let mut dc = zero;
            for ch in 0..3 {
                let d = _mm256_sub_ps(gp[ch], guide(qr, qx, ch));
                dc = _mm256_fmadd_ps(d, d, dc);
            }
            // min(vq, vp) as the scalar `if vq < vp { vq } else { vp }`.
            let v = _mm256_min_ps(ld(qr.noise, qx), vp);
            let den = _mm256_fmadd_ps(cscale, v, ceps);
            let r0 = _mm256_rcp_ps(den);
            let rcp = _mm256_mul_ps(r0, _mm256_fnmadd_ps(den, r0, two));
            let mut t = _mm256_mul_ps(dc, rcp);
            if has_n {
                let mut dn = zero;
                for k in 0..3 {
                    let d = _mm256_sub_ps(np[k], ld(qr.normal[k], qx));
                    dn = _mm256_fmadd_ps(d, d, dn);
                }
                t = _mm256_fmadd_ps(dn, inv_n2, t);
            }
            match geo {
                Geometry::Plane => {
                    let q: [__m256; 3] = core::array::from_fn(|k| ld(qr.position[k], qx));
                    let pd = _mm256_sub_ps(
                        _mm256_fmadd_ps(np[2], q[2], _mm256_fmadd_ps(np[1], q[1], _mm256_mul_ps(np[0], q[0]))),
                        npxp,
                    );
                    t = _mm256_fmadd_ps(_mm256_mul_ps(pd, pd), inv_geo, t);
                }
                Geometry::Position => {
                    let d: [__m256; 3] = core::array::from_fn(|k| _mm256_sub_ps(ld(qr.position[k], qx), xp[k]));
                    let gd = _mm256_fmadd_ps(d[2], d[2], _mm256_fmadd_ps(d[1], d[1], _mm256_mul_ps(d[0], d[0])));
                    t = _mm256_fmadd_ps(gd, inv_geo, t);
                }
                Geometry::Depth => {
                    let r = _mm256_mul_ps(_mm256_sub_ps(ld(qr.depth, qx), zp), inv_zp);
                    t = _mm256_fmadd_ps(_mm256_mul_ps(r, r), inv_geo, t);
                }
                Geometry::None => {}
            }
            wts[dy * 5 + dx] = _mm256_mul_ps(_mm256_set1_ps(h2(dy, dx)), exp(_mm256_sub_ps(zero, t)));
        }
    }
    // Pass 2: accumulate, taps in the same order.
    let mut wsum = zero;
    let mut acc = [zero; 6]; // only the first 3 * G are used
    let mut accv = zero;
    for dy in 0..5 {
        let Some(qr) = &taps[dy] else { continue };
        for dx in 0..5 {
            let qx = x + dx * c.hole - 2 * c.hole;
            let wt = wts[dy * 5 + dx];
            wsum = _mm256_add_ps(wsum, wt);
            for ch in 0..nc {
                acc[ch] = _mm256_fmadd_ps(wt, ld(qr.src[ch], qx), acc[ch]);
            }
            if VAR {
                accv = _mm256_fmadd_ps(_mm256_mul_ps(wt, wt), ld(qr.src[nc], qx), accv);
            }
        }
    }
    let inv = _mm256_div_ps(one, wsum);
    for ch in 0..nc {
        // SAFETY: x + 8 <= width.
        unsafe { store8(dst.ptr_mut(ch, yo).add(x), _mm256_mul_ps(acc[ch], inv)) };
    }
    if VAR {
        // SAFETY: as above.
        unsafe {
            store8(dst.ptr_mut(nc, yo).add(x), _mm256_mul_ps(_mm256_mul_ps(accv, inv), inv));
            store8(dst.ptr_mut(nc + 1, yo).add(x), _mm256_mul_ps(_mm256_set1_ps(h2(2, 2)), inv));
        }
    }
}

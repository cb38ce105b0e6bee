//! AVX-512 à-trous step: sixteen pixels at a time over the whole row. Near
//! the left and right borders each tap loads under a lane mask (taps outside
//! the image read as 0 and get weight 0, which is how the scalar pixel leaves
//! them out), so no pixel falls back to the scalar path. Rows are walked in
//! column strips, so the 5 tap rows x 13 planes a coarse level keeps in
//! flight stay in L2. One pass per tap (32 registers hold the centre values,
//! the accumulators and the constants). Same operations in the same order as
//! the scalar pixel, except FMA contractions and the evaluation order of
//! the `exp` polynomial.

use core::arch::x86_64::*;

use super::{h2, rows, Ctx, Geometry, RowPtrs};
use crate::math::{EXP_C, EXP_HI, EXP_LO, LN2_HI, LN2_LO, LOG2E, ROUND_MAGIC};
use crate::precision::FloatElement;
use crate::simd::avx512::{first_lanes, load16, load16_mask, store16_mask};
use crate::view::ViewMut;

/// Output columns per strip: with 5 tap rows of up to 13 planes of f32 and
/// the halo of level 4, a strip's rows in flight take about 1 MB.
const STRIP: usize = 256;

/// # Safety
/// AVX-512 F/BW/DQ/VL, AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
pub(crate) unsafe fn step<S: FloatElement>(c: &Ctx<'_, '_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    macro_rules! go {
        ($g:literal, $v:literal, $geo:literal) => {
            // SAFETY: forwarded from the caller.
            unsafe { strips::<S, $g, $v, $geo>(c, dst, y0) }
        };
    }
    // Monomorphised so every loop bound is a constant and the accumulators
    // stay in registers.
    match (c.groups, c.with_variance, c.geometry) {
        (1, false, Geometry::Plane) => go!(1, false, 0),
        (1, false, Geometry::Position) => go!(1, false, 1),
        (1, false, Geometry::Depth) => go!(1, false, 2),
        (1, false, Geometry::None) => go!(1, false, 3),
        (1, true, Geometry::Plane) => go!(1, true, 0),
        (1, true, Geometry::Position) => go!(1, true, 1),
        (1, true, Geometry::Depth) => go!(1, true, 2),
        (1, true, Geometry::None) => go!(1, true, 3),
        (2, false, Geometry::Plane) => go!(2, false, 0),
        (2, false, Geometry::Position) => go!(2, false, 1),
        (2, false, Geometry::Depth) => go!(2, false, 2),
        (2, false, Geometry::None) => go!(2, false, 3),
        (2, true, Geometry::Plane) => go!(2, true, 0),
        (2, true, Geometry::Position) => go!(2, true, 1),
        (2, true, Geometry::Depth) => go!(2, true, 2),
        (2, true, Geometry::None) => go!(2, true, 3),
        _ => {} // groups is checked to be 1 or 2: unreachable
    }
}

/// The 25 B3 tap weights, row-major.
const H2: [f32; 25] = {
    let mut t = [0.0f32; 25];
    let mut i = 0;
    while i < 25 {
        t[i] = super::super::B3[i / 5] * super::super::B3[i % 5];
        i += 1;
    }
    t
};

/// `e^-t` per lane for five vectors side by side: the reduction and
/// polynomial of [`crate::math::exp`] (0 where `-t < EXP_LO` or NaN), the
/// polynomial evaluated by Estrin's scheme (depth 4 instead of 6).
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
fn exp_neg5(t: [__m512; 5]) -> [__m512; 5] {
    let valid: [__mmask16; 5] =
        core::array::from_fn(|i| _mm512_cmp_ps_mask::<_CMP_LE_OQ>(t[i], _mm512_set1_ps(-EXP_LO)));
    let t: [__m512; 5] = core::array::from_fn(|i| _mm512_max_ps(t[i], _mm512_set1_ps(-EXP_HI)));
    let magic = _mm512_set1_ps(ROUND_MAGIC);
    let n: [__m512; 5] =
        core::array::from_fn(|i| _mm512_sub_ps(_mm512_fmadd_ps(t[i], _mm512_set1_ps(-LOG2E), magic), magic));
    // r = -t - n ln2, in two parts.
    let r: [__m512; 5] = core::array::from_fn(|i| _mm512_fnmsub_ps(n[i], _mm512_set1_ps(LN2_HI), t[i]));
    let r: [__m512; 5] = core::array::from_fn(|i| _mm512_fnmadd_ps(n[i], _mm512_set1_ps(LN2_LO), r[i]));
    let c = |i: usize| _mm512_set1_ps(EXP_C[i]);
    let r2: [__m512; 5] = core::array::from_fn(|i| _mm512_mul_ps(r[i], r[i]));
    let p01: [__m512; 5] = core::array::from_fn(|i| _mm512_fmadd_ps(r[i], c(1), c(0)));
    let p23: [__m512; 5] = core::array::from_fn(|i| _mm512_fmadd_ps(r[i], c(3), c(2)));
    let p45: [__m512; 5] = core::array::from_fn(|i| _mm512_fmadd_ps(r[i], c(5), c(4)));
    let p46: [__m512; 5] = core::array::from_fn(|i| _mm512_fmadd_ps(r2[i], c(6), p45[i]));
    let r4: [__m512; 5] = core::array::from_fn(|i| _mm512_mul_ps(r2[i], r2[i]));
    let p03: [__m512; 5] = core::array::from_fn(|i| _mm512_fmadd_ps(r2[i], p23[i], p01[i]));
    core::array::from_fn(|i| _mm512_maskz_scalef_ps(valid[i], _mm512_fmadd_ps(r4[i], p46[i], p03[i]), n[i]))
}

/// Prefetches columns `x0 .. x1` of row `yy` of every plane a tap reads into L2.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
fn prefetch_strip<S: FloatElement>(c: &Ctx<'_, '_, S>, yy: usize, x0: usize, x1: usize) {
    let r = rows(c, yy);
    let sz = core::mem::size_of::<S>();
    let one = |p: *const S| {
        if p.is_null() {
            return;
        }
        let (a, b) = ((p as *const i8).wrapping_add(x0 * sz), (p as *const i8).wrapping_add(x1 * sz));
        let mut q = a;
        while q < b {
            _mm_prefetch::<_MM_HINT_T1>(q);
            q = q.wrapping_add(64);
        }
        // The last line when the range ends past a line start.
        _mm_prefetch::<_MM_HINT_T1>(b.wrapping_sub(1));
    };
    for p in r.src.iter().chain(r.normal.iter()).chain(r.position.iter()) {
        one(*p);
    }
    one(r.noise);
    one(r.depth);
}

/// # Safety
/// As [`step`].
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
unsafe fn strips<S: FloatElement, const G: usize, const VAR: bool, const GEO: u8>(
    c: &Ctx<'_, '_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
) {
    let (w, h) = (c.src.width(), c.src.height());
    let m = 2 * c.hole;
    let mut xs = 0;
    while xs < w {
        let xe = (xs + STRIP).min(w);
        for yo in 0..dst.height() {
            let y = y0 + yo;
            // The next output row brings one new tap row (2 hole below this
            // one's last): fetch its part of the strip into L2 now. Fifty-odd
            // row streams are more than the hardware prefetchers follow.
            if let Some(qy) = Some(y + 1 + m).filter(|&v| v < h) {
                prefetch_strip(c, qy, xs.saturating_sub(m), (xe + m).min(w));
            }
            let centre = rows(c, y);
            let taps: [Option<RowPtrs<S>>; 5] =
                core::array::from_fn(|dy| (y + dy * c.hole).checked_sub(m).filter(|&v| v < h).map(|qy| rows(c, qy)));
            let mut x = xs;
            while x < xe {
                let len = (xe - x).min(16);
                // SAFETY: rows are in range; columns are checked per tap
                // (edge) or lie inside (x - m >= 0, x + 16 + m <= w).
                unsafe {
                    if x < m || x + 16 + m > w {
                        chunk::<S, G, VAR, GEO, true>(c, &centre, &taps, dst, yo, x, len)
                    } else {
                        chunk::<S, G, VAR, GEO, false>(c, &centre, &taps, dst, yo, x, 16)
                    }
                }
                x += len;
            }
        }
        xs = xe;
    }
}

/// Output pixels `x .. x + len` of row `yo`.
///
/// # Safety
/// AVX-512 as [`step`]; `centre` and `taps` are the rows of output row `yo`;
/// `x + len <= width`; without `EDGE`, columns `x - 2 hole .. x + 16 + 2 hole`
/// lie inside the image and `len == 16`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
unsafe fn chunk<S: FloatElement, const G: usize, const VAR: bool, const GEO: u8, const EDGE: bool>(
    c: &Ctx<'_, '_, S>,
    pr: &RowPtrs<S>,
    taps: &[Option<RowPtrs<S>>; 5],
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    x: usize,
    len: usize,
) {
    let w = c.src.width() as isize;
    let g = c.guides;
    let nc = 3 * G;
    let geo = match GEO {
        0 => Geometry::Plane,
        1 => Geometry::Position,
        2 => Geometry::Depth,
        _ => Geometry::None,
    };
    let out_mask = first_lanes(len);
    // SAFETY (every load): the pointer is row + column of an in-range row;
    // under a mask only in-image lanes are read, else all 16 are inside.
    let ld = |p: *const S, xx: isize, mk: __mmask16| unsafe {
        if EDGE {
            load16_mask(p.wrapping_offset(xx), mk)
        } else {
            load16(p.offset(xx))
        }
    };
    let xi = x as isize;
    let zero = _mm512_setzero_ps();
    let one = _mm512_set1_ps(1.0);
    let gp = [ld(pr.src[0], xi, out_mask), ld(pr.src[1], xi, out_mask), ld(pr.src[2], xi, out_mask)];
    let vp = ld(pr.noise, xi, out_mask);
    let has_n = g.normal.is_some();
    let np: [__m512; 3] = core::array::from_fn(|k| if has_n { ld(pr.normal[k], xi, out_mask) } else { zero });
    let uses_pos = matches!(geo, Geometry::Plane | Geometry::Position);
    let xp: [__m512; 3] = core::array::from_fn(|k| if uses_pos { ld(pr.position[k], xi, out_mask) } else { zero });
    let zp = if geo == Geometry::Depth { ld(pr.depth, xi, out_mask) } else { zero };
    let inv_zp = _mm512_div_ps(one, _mm512_max_ps(zp, _mm512_set1_ps(1e-20)));
    let cscale = _mm512_set1_ps(c.color_scale);
    let ceps = _mm512_set1_ps(c.eps);
    let inv_n2 = _mm512_set1_ps(c.inv_normal2);
    let inv_geo = _mm512_set1_ps(c.inv_geom2);
    let npxp = _mm512_fmadd_ps(np[2], xp[2], _mm512_fmadd_ps(np[1], xp[1], _mm512_mul_ps(np[0], xp[0])));
    let mut wsum = zero;
    let mut acc = [zero; 6]; // only the first 3 * G are used
    let mut accv = zero;
    // The five taps of a tap row go through each stage together: a tap's
    // weight is a chain of ~40 dependent operations, and five independent
    // chains side by side keep the FP scheduler from filling up with
    // operations that wait on one chain.
    for (dy, tr) in taps.iter().enumerate() {
        let Some(qr) = tr else { continue };
        let qx: [isize; 5] = core::array::from_fn(|dx| xi + (dx as isize - 2) * c.hole as isize);
        // In-image lanes of each tap (all of them away from the borders).
        let mk: [__mmask16; 5] = core::array::from_fn(|dx| {
            if EDGE {
                let lo = (-qx[dx]).clamp(0, 16) as usize;
                let hi = (w - qx[dx]).clamp(0, len as isize) as usize;
                if hi <= lo {
                    0
                } else {
                    first_lanes(hi) & !first_lanes(lo)
                }
            } else {
                0xffff
            }
        });
        let mut dc = [zero; 5];
        for ch in 0..3 {
            for dx in 0..5 {
                let d = _mm512_sub_ps(gp[ch], ld(qr.src[ch], qx[dx], mk[dx]));
                dc[dx] = _mm512_fmadd_ps(d, d, dc[dx]);
            }
        }
        // min(vq, vp) as the scalar `if vq < vp { vq } else { vp }`.
        let den: [__m512; 5] =
            core::array::from_fn(|dx| _mm512_fmadd_ps(cscale, _mm512_min_ps(ld(qr.noise, qx[dx], mk[dx]), vp), ceps));
        // A true division, as the scalar pixel: the divider runs beside the
        // two FMA pipes, which are this kernel's bottleneck (a reciprocal
        // estimate with a Newton step measured a third slower).
        let mut t: [__m512; 5] = core::array::from_fn(|dx| _mm512_div_ps(dc[dx], den[dx]));
        if has_n {
            let mut dn = [zero; 5];
            for k in 0..3 {
                for dx in 0..5 {
                    let d = _mm512_sub_ps(np[k], ld(qr.normal[k], qx[dx], mk[dx]));
                    dn[dx] = _mm512_fmadd_ps(d, d, dn[dx]);
                }
            }
            for dx in 0..5 {
                t[dx] = _mm512_fmadd_ps(dn[dx], inv_n2, t[dx]);
            }
        }
        match geo {
            Geometry::Plane => {
                let mut pd = [zero; 5];
                for k in 0..3 {
                    for dx in 0..5 {
                        pd[dx] = _mm512_fmadd_ps(np[k], ld(qr.position[k], qx[dx], mk[dx]), pd[dx]);
                    }
                }
                for dx in 0..5 {
                    let d = _mm512_sub_ps(pd[dx], npxp);
                    t[dx] = _mm512_fmadd_ps(_mm512_mul_ps(d, d), inv_geo, t[dx]);
                }
            }
            Geometry::Position => {
                let mut gd = [zero; 5];
                for k in 0..3 {
                    for dx in 0..5 {
                        let d = _mm512_sub_ps(ld(qr.position[k], qx[dx], mk[dx]), xp[k]);
                        gd[dx] = _mm512_fmadd_ps(d, d, gd[dx]);
                    }
                }
                for dx in 0..5 {
                    t[dx] = _mm512_fmadd_ps(gd[dx], inv_geo, t[dx]);
                }
            }
            Geometry::Depth => {
                for dx in 0..5 {
                    let r = _mm512_mul_ps(_mm512_sub_ps(ld(qr.depth, qx[dx], mk[dx]), zp), inv_zp);
                    t[dx] = _mm512_fmadd_ps(_mm512_mul_ps(r, r), inv_geo, t[dx]);
                }
            }
            Geometry::None => {}
        }
        let e = exp_neg5(t);
        for dx in 0..5 {
            let hw = _mm512_set1_ps(H2[dy * 5 + dx]);
            let wt = if EDGE { _mm512_maskz_mul_ps(mk[dx], hw, e[dx]) } else { _mm512_mul_ps(hw, e[dx]) };
            wsum = _mm512_add_ps(wsum, wt);
            for (ch, a) in acc.iter_mut().enumerate().take(nc) {
                *a = _mm512_fmadd_ps(wt, ld(qr.src[ch], qx[dx], mk[dx]), *a);
            }
            if VAR {
                accv = _mm512_fmadd_ps(_mm512_mul_ps(wt, wt), ld(qr.src[nc], qx[dx], mk[dx]), accv);
            }
        }
    }
    // The centre tap always counts, so wsum >= 9/64 in the output lanes.
    let inv = _mm512_div_ps(one, wsum);
    for (ch, a) in acc.iter().enumerate().take(nc) {
        // SAFETY: x + len <= width; only the first len lanes are written.
        unsafe { store16_mask(dst.ptr_mut(ch, yo).add(x), out_mask, _mm512_mul_ps(*a, inv)) };
    }
    if VAR {
        // SAFETY: as above.
        unsafe {
            store16_mask(dst.ptr_mut(nc, yo).add(x), out_mask, _mm512_mul_ps(_mm512_mul_ps(accv, inv), inv));
            store16_mask(dst.ptr_mut(nc + 1, yo).add(x), out_mask, _mm512_mul_ps(_mm512_set1_ps(h2(2, 2)), inv));
        }
    }
}

//! AVX2 à-trous step: eight pixels at a time over the whole row. Near the
//! left and right borders each tap loads under a lane mask (taps outside the
//! image read as 0 and get weight 0, which is how the scalar pixel leaves
//! them out), so no pixel falls back to the scalar path; the last chunk of a
//! row stores only its in-image lanes. Rows are walked in column strips so
//! the tap rows a coarse level keeps in flight stay in L2.
//!
//! One pass per tap: its weight is computed and accumulated at once, so the
//! tap's colour is loaded once and no weight goes through memory. The five
//! taps of a tap row go through each stage side by side (`STAGE`): a tap's
//! weight is a chain of ~40 dependent operations, and independent chains
//! next to each other keep the FP scheduler busy. Same operations in the
//! same order as the scalar pixel, except FMA contractions and the
//! evaluation order of the `exp` polynomial (Estrin).

use core::arch::x86_64::*;

use super::{h2, rows, Ctx, Geometry, RowPtrs};
use crate::math::{EXP_C, EXP_HI, EXP_LO, LN2_HI, LN2_LO, LOG2E, ROUND_MAGIC};
use crate::precision::FloatElement;
use crate::simd::avx2::{lane_range, load8, load8_range, store8_first};
use crate::view::ViewMut;

/// Output columns per strip: 5 tap rows of up to 14 planes of f32 with the
/// halo of level 4 take about 110 KB, well inside this core's L2.
const STRIP: usize = 256;

/// # Safety
/// AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx2,fma,f16c")]
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

/// Taps of a tap row that go through each stage together.
const STAGE: usize = 5;

/// `e^-t` per lane for `N` vectors side by side: the reduction of
/// [`crate::math::exp`] (0 where `-t < EXP_LO` or NaN), its polynomial by
/// Estrin's scheme (depth 4 instead of 6).
#[inline(always)]
unsafe fn exp_neg<const N: usize>(t: [__m256; N]) -> [__m256; N] {
    // SAFETY (the whole body): AVX2 and FMA are enabled in every caller.
    unsafe {
        let valid: [__m256; N] = core::array::from_fn(|i| _mm256_cmp_ps::<_CMP_LE_OQ>(t[i], _mm256_set1_ps(-EXP_LO)));
        let t: [__m256; N] = core::array::from_fn(|i| _mm256_max_ps(t[i], _mm256_set1_ps(-EXP_HI)));
        let magic = _mm256_set1_ps(ROUND_MAGIC);
        let n: [__m256; N] =
            core::array::from_fn(|i| _mm256_sub_ps(_mm256_fmadd_ps(t[i], _mm256_set1_ps(-LOG2E), magic), magic));
        // r = -t - n ln2, in two parts.
        let r: [__m256; N] = core::array::from_fn(|i| _mm256_fnmsub_ps(n[i], _mm256_set1_ps(LN2_HI), t[i]));
        let r: [__m256; N] = core::array::from_fn(|i| _mm256_fnmadd_ps(n[i], _mm256_set1_ps(LN2_LO), r[i]));
        let c = |i: usize| _mm256_set1_ps(EXP_C[i]);
        let r2: [__m256; N] = core::array::from_fn(|i| _mm256_mul_ps(r[i], r[i]));
        let p01: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(r[i], c(1), c(0)));
        let p23: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(r[i], c(3), c(2)));
        let p45: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(r[i], c(5), c(4)));
        let p46: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(r2[i], c(6), p45[i]));
        let r4: [__m256; N] = core::array::from_fn(|i| _mm256_mul_ps(r2[i], r2[i]));
        let p03: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(r2[i], p23[i], p01[i]));
        core::array::from_fn(|i| {
            let p = _mm256_fmadd_ps(r4[i], p46[i], p03[i]);
            let bits = _mm256_slli_epi32::<23>(_mm256_add_epi32(_mm256_cvtps_epi32(n[i]), _mm256_set1_epi32(127)));
            _mm256_and_ps(_mm256_mul_ps(p, _mm256_castsi256_ps(bits)), valid[i])
        })
    }
}

/// Prefetches columns `x0 .. x1` of row `yy` of every plane a tap reads into L2.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
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
#[target_feature(enable = "avx2,fma,f16c")]
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
                let len = (xe - x).min(8);
                // SAFETY: rows are in range; columns are checked per tap
                // (edge) or lie inside (x - m >= 0, x + 8 + m <= w).
                unsafe {
                    if x < m || x + 8 + m > w {
                        chunk::<S, G, VAR, GEO, true>(c, &centre, &taps, dst, yo, x, len)
                    } else {
                        chunk::<S, G, VAR, GEO, false>(c, &centre, &taps, dst, yo, x, 8)
                    }
                }
                x += len;
            }
        }
        xs = xe;
    }
}

/// In-image lanes `lo .. hi` of a tap whose first lane is column `qx`, and
/// their integer mask (all lanes away from the borders).
#[derive(Clone, Copy)]
struct Lanes {
    lo: usize,
    hi: usize,
    mask: __m256,
}

/// Output pixels `x .. x + len` of row `yo`.
///
/// # Safety
/// AVX2/FMA/F16C; `centre` and `taps` are the rows of output row `yo`;
/// `x + len <= width`; without `EDGE`, columns `x - 2 hole .. x + 8 + 2 hole`
/// lie inside the image and `len == 8`.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
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
    // SAFETY (every load): the pointer is row + column of an in-range row;
    // at the edges only in-image lanes are read, else all 8 are inside.
    let ld = |p: *const S, xx: isize, l: &Lanes| unsafe {
        if EDGE {
            load8_range(p.wrapping_offset(xx), l.lo, l.hi)
        } else {
            load8(p.offset(xx))
        }
    };
    let xi = x as isize;
    let zero = _mm256_setzero_ps();
    let one = _mm256_set1_ps(1.0);
    let own = Lanes { lo: 0, hi: len, mask: zero };
    let gp = [ld(pr.src[0], xi, &own), ld(pr.src[1], xi, &own), ld(pr.src[2], xi, &own)];
    let vp = ld(pr.noise, xi, &own);
    let has_n = g.normal.is_some();
    let np: [__m256; 3] = core::array::from_fn(|k| if has_n { ld(pr.normal[k], xi, &own) } else { zero });
    let uses_pos = matches!(geo, Geometry::Plane | Geometry::Position);
    let xp: [__m256; 3] = core::array::from_fn(|k| if uses_pos { ld(pr.position[k], xi, &own) } else { zero });
    let zp = if geo == Geometry::Depth { ld(pr.depth, xi, &own) } else { zero };
    let inv_zp = _mm256_div_ps(one, _mm256_max_ps(zp, _mm256_set1_ps(1e-20)));
    let cscale = _mm256_set1_ps(c.color_scale);
    let ceps = _mm256_set1_ps(c.eps);
    let inv_n2 = _mm256_set1_ps(c.inv_normal2);
    let inv_geo = _mm256_set1_ps(c.inv_geom2);
    // n(p) . x(p), so the tangent-plane distance is n(p) . x(q) - n(p) . x(p).
    let npxp = _mm256_fmadd_ps(np[2], xp[2], _mm256_fmadd_ps(np[1], xp[1], _mm256_mul_ps(np[0], xp[0])));
    let mut wsum = zero;
    let mut acc = [zero; 6]; // only the first 3 * G are used
    let mut accv = zero;
    for (dy, tr) in taps.iter().enumerate() {
        let Some(qr) = tr else { continue };
        let mut dx0 = 0;
        while dx0 < 5 {
            let qx: [isize; STAGE] = core::array::from_fn(|i| xi + ((dx0 + i) as isize - 2) * c.hole as isize);
            let lanes: [Lanes; STAGE] = core::array::from_fn(|i| {
                if EDGE {
                    let lo = (-qx[i]).clamp(0, 8) as usize;
                    let hi = (w - qx[i]).clamp(0, len as isize) as usize;
                    let hi = hi.max(lo);
                    Lanes { lo, hi, mask: _mm256_castsi256_ps(lane_range(lo, hi)) }
                } else {
                    Lanes { lo: 0, hi: 8, mask: zero }
                }
            });
            let mut dc = [zero; STAGE];
            for ch in 0..3 {
                for i in 0..STAGE {
                    let d = _mm256_sub_ps(gp[ch], ld(qr.src[ch], qx[i], &lanes[i]));
                    dc[i] = _mm256_fmadd_ps(d, d, dc[i]);
                }
            }
            // min(vq, vp) as the scalar `if vq < vp { vq } else { vp }`.
            let den: [__m256; STAGE] = core::array::from_fn(|i| {
                _mm256_fmadd_ps(cscale, _mm256_min_ps(ld(qr.noise, qx[i], &lanes[i]), vp), ceps)
            });
            let mut t: [__m256; STAGE] = core::array::from_fn(|i| _mm256_div_ps(dc[i], den[i]));
            if has_n {
                let mut dn = [zero; STAGE];
                for k in 0..3 {
                    for i in 0..STAGE {
                        let d = _mm256_sub_ps(np[k], ld(qr.normal[k], qx[i], &lanes[i]));
                        dn[i] = _mm256_fmadd_ps(d, d, dn[i]);
                    }
                }
                for i in 0..STAGE {
                    t[i] = _mm256_fmadd_ps(dn[i], inv_n2, t[i]);
                }
            }
            match geo {
                Geometry::Plane => {
                    let mut pd = [zero; STAGE];
                    for k in 0..3 {
                        for i in 0..STAGE {
                            pd[i] = _mm256_fmadd_ps(np[k], ld(qr.position[k], qx[i], &lanes[i]), pd[i]);
                        }
                    }
                    for i in 0..STAGE {
                        let d = _mm256_sub_ps(pd[i], npxp);
                        t[i] = _mm256_fmadd_ps(_mm256_mul_ps(d, d), inv_geo, t[i]);
                    }
                }
                Geometry::Position => {
                    let mut gd = [zero; STAGE];
                    for k in 0..3 {
                        for i in 0..STAGE {
                            let d = _mm256_sub_ps(ld(qr.position[k], qx[i], &lanes[i]), xp[k]);
                            gd[i] = _mm256_fmadd_ps(d, d, gd[i]);
                        }
                    }
                    for i in 0..STAGE {
                        t[i] = _mm256_fmadd_ps(gd[i], inv_geo, t[i]);
                    }
                }
                Geometry::Depth => {
                    for i in 0..STAGE {
                        let r = _mm256_mul_ps(_mm256_sub_ps(ld(qr.depth, qx[i], &lanes[i]), zp), inv_zp);
                        t[i] = _mm256_fmadd_ps(_mm256_mul_ps(r, r), inv_geo, t[i]);
                    }
                }
                Geometry::None => {}
            }
            // SAFETY: AVX2 and FMA are enabled here.
            let e = unsafe { exp_neg(t) };
            for i in 0..STAGE {
                let hw = _mm256_set1_ps(h2(dy, dx0 + i));
                let mut wt = _mm256_mul_ps(hw, e[i]);
                if EDGE {
                    wt = _mm256_and_ps(wt, lanes[i].mask);
                }
                wsum = _mm256_add_ps(wsum, wt);
                for (ch, a) in acc.iter_mut().enumerate().take(nc) {
                    *a = _mm256_fmadd_ps(wt, ld(qr.src[ch], qx[i], &lanes[i]), *a);
                }
                if VAR {
                    accv = _mm256_fmadd_ps(_mm256_mul_ps(wt, wt), ld(qr.src[nc], qx[i], &lanes[i]), accv);
                }
            }
            dx0 += STAGE;
        }
    }
    // The centre tap always counts, so wsum >= 9/64 in the output lanes
    // (the lanes past `len` are not stored).
    let inv = _mm256_div_ps(one, wsum);
    for (ch, a) in acc.iter().enumerate().take(nc) {
        // SAFETY: x + len <= width; only the first len lanes are written.
        unsafe { store8_first(dst.ptr_mut(ch, yo).add(x), len, _mm256_mul_ps(*a, inv)) };
    }
    if VAR {
        // SAFETY: as above.
        unsafe {
            store8_first(dst.ptr_mut(nc, yo).add(x), len, _mm256_mul_ps(_mm256_mul_ps(accv, inv), inv));
            store8_first(dst.ptr_mut(nc + 1, yo).add(x), len, _mm256_mul_ps(_mm256_set1_ps(h2(2, 2)), inv));
        }
    }
}

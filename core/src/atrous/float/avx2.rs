//! AVX2 à-trous step by tap pairs.
//!
//! The edge-stopping weight is symmetric, `w(p, q) = w(q, p)` (see
//! [`crate::atrous`]), so of the 24 off-centre taps of a pixel only 12 need a
//! weight of their own: for the forward offsets `o` (`oy > 0`, or `oy = 0`
//! and `ox > 0`, in units of the hole) the weight `W_o(p) = w(p, p + o)` is
//! computed once and serves `p` (tap `p + o`) and `p + o` (tap `p`). The step
//! runs as two register-light streaming loops per output row:
//!
//! 1. weights: for each forward offset, `W_o` over the row (p's and q's
//!    guides loaded per chunk of eight pixels; 0 where `q` or `p` is outside
//!    the image) into a ring of rows in the scratch, deep enough to hold
//!    rows `y - oy hole ..= y`;
//! 2. accumulation: `out(p) = (9/64 c(p) + sum_o W_o(p) c(p + o) +
//!    W_o(p - o) c(p - o)) / (9/64 + sum of those weights)`.
//!
//! A band first fills the ring with the rows above it (`2 hole` of them), so
//! the result does not depend on the band split. Columns go in strips so the
//! rings and the tap rows stay in L2; a strip computes each offset's weights
//! only over the columns it reads. Near the borders loads go under a lane
//! mask (taps outside the image read as 0 and weigh 0, as the scalar pixel
//! leaves them out). The sums run in a different order from the scalar
//! pixel's, so results agree to rounding, not bit for bit.

use core::arch::x86_64::*;

use super::{rows, Ctx, Geometry, RowPtrs};
use crate::math::{EXP_HI, EXP_LO, LOG2E};
use crate::precision::FloatElement;
use crate::simd::avx2::{lane_range, load8, load8_range, store8_first};
use crate::view::ViewMut;

/// Output columns per strip (a multiple of 8).
const STRIP: usize = 256;

/// The forward offsets `(ox, oy)` in units of the hole.
const FORWARD: [(isize, usize); 12] =
    [(1, 0), (2, 0), (-2, 1), (-1, 1), (0, 1), (1, 1), (2, 1), (-2, 2), (-1, 2), (0, 2), (1, 2), (2, 2)];

/// The B3 tap weight of offset `(ox, oy)`.
fn h_of(ox: isize, oy: usize) -> f32 {
    let b3 = super::super::B3;
    b3[(ox + 2) as usize] * b3[oy + 2]
}

/// Floats per ring row: the strip, its `2 hole` halo each side, rounded up
/// to whole chunks, plus one chunk that unstored lanes may read.
fn ring_row(hole: usize) -> usize {
    (STRIP + 4 * hole).div_ceil(8) * 8 + 8
}

/// Rows the ring of offset row `oy` keeps: `oy hole + 1`.
fn depth(oy: usize, hole: usize) -> usize {
    oy * hole + 1
}

/// Scratch floats the pair step needs at `level` (any width).
pub(crate) fn scratch_len(level: u32) -> usize {
    let hole = 1usize << level;
    let rows: usize = FORWARD.iter().map(|&(_, oy)| depth(oy, hole)).sum();
    rows * ring_row(hole)
}

/// # Safety
/// AVX2, FMA and F16C must be supported; `scratch.len() >= scratch_len(level)`.
#[target_feature(enable = "avx2,fma,f16c")]
pub(crate) unsafe fn step<S: FloatElement>(
    c: &Ctx<'_, '_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    macro_rules! go {
        ($g:literal, $v:literal, $geo:literal) => {
            // SAFETY: forwarded from the caller.
            unsafe { strips::<S, $g, $v, $geo>(c, dst, y0, scratch) }
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

/// `2^f` on `[-1/2, 1/2]`: Taylor terms of `e^(f ln 2)` to degree 6
/// (relative error below 2e-7), Estrin's scheme.
const EXP2_C: [f32; 7] = [
    1.0,
    core::f32::consts::LN_2,
    0.240_226_5,
    0.055_504_11,
    0.009_618_129,
    0.001_333_355_8,
    0.000_154_035_3,
];

/// `e^-t` per lane for `N` vectors side by side: `2^y` with `y = -t log2(e)`
/// split into `round(y)` (the exponent) and a polynomial of the rest; 0
/// where `t > 87` or NaN (as [`crate::math::exp`] at `-t`). Its chain is
/// about 24 cycles against the 30 of the two-constant reduction; `y` is
/// rounded once, a relative error of `|y| 2^-24` (3.6e-7 at `t = 4`, and
/// only weights below 1e-30 see more than 4e-6).
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn exp_neg<const N: usize>(t: [__m256; N]) -> [__m256; N] {
    // SAFETY (the whole body): AVX2 and FMA are enabled in every caller.
    unsafe {
        let valid: [__m256; N] =
            core::array::from_fn(|i| _mm256_cmp_ps::<_CMP_LE_OQ>(t[i], _mm256_set1_ps(-EXP_LO)));
        // t >= 0 for any noise >= 0; the clamps keep the exponent in range
        // for anything else (beyond 87 the lane is masked to 0 anyway).
        let y: [__m256; N] = core::array::from_fn(|i| {
            let t = _mm256_max_ps(_mm256_min_ps(t[i], _mm256_set1_ps(-EXP_LO)), _mm256_set1_ps(-EXP_HI));
            _mm256_mul_ps(t, _mm256_set1_ps(-LOG2E))
        });
        let n: [__m256; N] =
            core::array::from_fn(|i| _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(y[i]));
        let f: [__m256; N] = core::array::from_fn(|i| _mm256_sub_ps(y[i], n[i]));
        let c = |i: usize| _mm256_set1_ps(EXP2_C[i]);
        let f2: [__m256; N] = core::array::from_fn(|i| _mm256_mul_ps(f[i], f[i]));
        let p01: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(f[i], c(1), c(0)));
        let p23: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(f[i], c(3), c(2)));
        let p45: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(f[i], c(5), c(4)));
        let p46: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(f2[i], c(6), p45[i]));
        let f4: [__m256; N] = core::array::from_fn(|i| _mm256_mul_ps(f2[i], f2[i]));
        let p03: [__m256; N] = core::array::from_fn(|i| _mm256_fmadd_ps(f2[i], p23[i], p01[i]));
        core::array::from_fn(|i| {
            let p = _mm256_fmadd_ps(f4[i], p46[i], p03[i]);
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

/// The rings of the forward offsets inside the scratch.
struct Rings {
    base: *mut f32,
    /// Start of each offset's ring, in floats.
    start: [usize; 12],
    row: usize,
    hole: usize,
}

impl Rings {
    fn new(scratch: &mut [f32], hole: usize) -> Self {
        let row = ring_row(hole);
        let mut start = [0; 12];
        let mut at = 0;
        for (k, &(_, oy)) in FORWARD.iter().enumerate() {
            start[k] = at;
            at += depth(oy, hole) * row;
        }
        debug_assert!(at <= scratch.len());
        Rings { base: scratch.as_mut_ptr(), start, row, hole }
    }

    /// Row `y` of offset `k`'s ring (ring index 0 is column `xs - 2 hole`).
    fn at(&self, k: usize, y: usize) -> *mut f32 {
        let d = depth(FORWARD[k].1, self.hole);
        self.base.wrapping_add(self.start[k] + (y % d) * self.row)
    }
}

/// # Safety
/// As [`step`].
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn strips<S: FloatElement, const G: usize, const VAR: bool, const GEO: u8>(
    c: &Ctx<'_, '_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    let (w, h) = (c.src.width(), c.src.height());
    let hole = c.hole;
    let m = 2 * hole;
    let rings = Rings::new(scratch, hole);
    let y1 = y0 + dst.height();
    let mut xs = 0;
    while xs < w {
        let xe = (xs + STRIP).min(w);
        // Rows above the band whose weights reach into it.
        for r in y0.saturating_sub(m)..y0 {
            for (k, &(ox, oy)) in FORWARD.iter().enumerate() {
                if oy > 0 && r + oy * hole >= y0 && r + oy * hole < h {
                    // SAFETY: forwarded; the ring row is inside the scratch.
                    unsafe { weights::<S, GEO>(c, &rings, k, ox, oy, r, xs, xe) };
                }
            }
        }
        for y in y0..y1 {
            if let Some(qy) = Some(y + 1 + m).filter(|&v| v < h) {
                prefetch_strip(c, qy, xs.saturating_sub(m), (xe + m).min(w));
            }
            for (k, &(ox, oy)) in FORWARD.iter().enumerate() {
                if y + oy * hole < h {
                    // SAFETY: as above.
                    unsafe { weights::<S, GEO>(c, &rings, k, ox, oy, y, xs, xe) };
                }
            }
            // SAFETY: as above.
            unsafe {
                if G == 1 && !VAR {
                    accumulate::<S, G, VAR, 3>(c, &rings, dst, y - y0, y, xs, xe)
                } else {
                    accumulate::<S, G, VAR, 2>(c, &rings, dst, y - y0, y, xs, xe)
                }
            };
        }
        xs = xe;
    }
}

/// Lanes `lo .. hi` of a chunk whose first lane is at column `x`, inside
/// `0 .. w` (empty when `hi <= lo`).
#[inline]
fn inside(x: isize, w: isize) -> (usize, usize) {
    let lo = (-x).clamp(0, 8) as usize;
    let hi = (w - x).clamp(0, 8) as usize;
    (lo, hi.max(lo))
}

/// `W_k` of row `y` over the columns strip `xs .. xe` reads, into its ring.
///
/// # Safety
/// As [`step`]; row `y + oy hole` is inside the image.
#[allow(clippy::too_many_arguments)]
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn weights<S: FloatElement, const GEO: u8>(
    c: &Ctx<'_, '_, S>,
    rings: &Rings,
    k: usize,
    ox: isize,
    oy: usize,
    y: usize,
    xs: usize,
    xe: usize,
) {
    let w = c.src.width() as isize;
    let hole = c.hole as isize;
    let s = ox * hole;
    let base = xs as isize - 2 * hole; // column of ring index 0
    // Columns read: forward at xs .. xe, backward at xs - s .. xe - s.
    let (c0, c1) = ((xs as isize).min(xs as isize - s), (xe as isize).max(xe as isize - s));
    let (i0, i1) = (((c0 - base) / 8 * 8) as usize, (c1 - base) as usize);
    let out = rings.at(k, y);
    let pr = rows(c, y);
    let qr = rows(c, y + oy * hole as usize);
    let hw = _mm256_set1_ps(h_of(ox, oy));
    // Chunks whose p and q lanes all lie inside: x >= 0, x + s >= 0,
    // x + 8 <= w, x + s + 8 <= w.
    let (xa, xb) = (0isize.max(-s), w.min(w - s) - 8);
    let mut i = i0;
    while i < i1 {
        let x = base + i as isize;
        // SAFETY: the ring row holds ring_row(hole) >= i1 rounded up to 8 floats.
        let o = out.wrapping_add(i);
        if x >= xa && x + 8 * (STAGE as isize - 1) <= xb && i + 8 * STAGE <= i1.next_multiple_of(8) {
            // SAFETY: all STAGE chunks lie inside (just checked).
            unsafe {
                let e = pair::<S, GEO, false, STAGE>(c, &pr, &qr, x, s, 0, 8);
                for (k, v) in e.iter().enumerate() {
                    _mm256_storeu_ps(o.add(8 * k), _mm256_mul_ps(hw, *v));
                }
            }
            i += 8 * STAGE;
            continue;
        }
        let (lo, hi) = {
            let (a, b) = inside(x, w);
            let (qa, qb) = inside(x + s, w);
            (a.max(qa), b.min(qb).max(a.max(qa)))
        };
        // SAFETY: the lanes lo .. hi of p and q are inside.
        unsafe {
            if lo == 0 && hi == 8 {
                _mm256_storeu_ps(o, _mm256_mul_ps(hw, pair::<S, GEO, false, 1>(c, &pr, &qr, x, s, 0, 8)[0]));
            } else if lo < hi {
                let wt = _mm256_mul_ps(hw, pair::<S, GEO, true, 1>(c, &pr, &qr, x, s, lo, hi)[0]);
                _mm256_storeu_ps(o, _mm256_and_ps(wt, _mm256_castsi256_ps(lane_range(lo, hi))));
            } else {
                _mm256_storeu_ps(o, _mm256_setzero_ps());
            }
        }
        i += 8;
    }
}

/// Interior chunks computed side by side (see [`pair`]).
const STAGE: usize = 3;

/// `e^-t(p, q)` for `N` chunks of eight pixels side by side: `p` at
/// columns `x + 8 k ..` of row `pr`, `q` at `x + 8 k + s ..` of row `qr`
/// (lanes `lo .. hi` only under `EDGE`, where `N` is 1). Each stage runs over
/// the `N` chunks before the next, so the FP scheduler sees `N` independent
/// chains; the colour quotient runs beside the geometry terms and joins them
/// at the end.
///
/// # Safety
/// AVX2/FMA/F16C; lanes `lo .. hi` of every chunk of both rows are inside
/// the image (all eight without `EDGE`).
#[allow(clippy::too_many_arguments)]
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn pair<S: FloatElement, const GEO: u8, const EDGE: bool, const N: usize>(
    c: &Ctx<'_, '_, S>,
    pr: &RowPtrs<S>,
    qr: &RowPtrs<S>,
    x: isize,
    s: isize,
    lo: usize,
    hi: usize,
) -> [__m256; N] {
    // SAFETY (every load): in-range rows; the lanes read are inside (caller).
    let ld = |p: *const S, xx: isize| unsafe {
        if EDGE {
            load8_range(p.wrapping_offset(xx), lo, hi)
        } else {
            load8(p.offset(xx))
        }
    };
    let xs: [isize; N] = core::array::from_fn(|k| x + 8 * k as isize);
    let lp = |p: *const S| -> [__m256; N] { core::array::from_fn(|k| ld(p, xs[k])) };
    let lq = |p: *const S| -> [__m256; N] { core::array::from_fn(|k| ld(p, xs[k] + s)) };
    // SAFETY (the body): AVX2 and FMA are enabled in every caller.
    unsafe {
        let zero = _mm256_setzero_ps();
        let mut dc = [zero; N];
        for ch in 0..3 {
            let (a, b) = (lp(pr.src[ch]), lq(qr.src[ch]));
            for k in 0..N {
                let d = _mm256_sub_ps(a[k], b[k]);
                dc[k] = _mm256_fmadd_ps(d, d, dc[k]);
            }
        }
        let (vp, vq) = (lp(pr.noise), lq(qr.noise));
        // min as the scalar `if vq < vp { vq } else { vp }`.
        let tc: [__m256; N] = core::array::from_fn(|k| {
            let den = _mm256_fmadd_ps(_mm256_set1_ps(c.color_scale), _mm256_min_ps(vq[k], vp[k]), _mm256_set1_ps(c.eps));
            _mm256_div_ps(dc[k], den)
        });
        // The other terms, beside the division.
        let mut tg = [zero; N];
        let has_n = !pr.normal[0].is_null();
        let mut np = [[zero; N]; 3];
        let mut nq = [[zero; N]; 3];
        if has_n {
            let mut dn = [zero; N];
            for j in 0..3 {
                np[j] = lp(pr.normal[j]);
                nq[j] = lq(qr.normal[j]);
                for k in 0..N {
                    let d = _mm256_sub_ps(np[j][k], nq[j][k]);
                    dn[k] = _mm256_fmadd_ps(d, d, dn[k]);
                }
            }
            for k in 0..N {
                tg[k] = _mm256_mul_ps(dn[k], _mm256_set1_ps(c.inv_normal2));
            }
        }
        match GEO {
            // Plane: the mean of both pixels' squared tangent-plane distances.
            0 | 1 => {
                let mut d = [[zero; N]; 3];
                for j in 0..3 {
                    let (a, b) = (lp(pr.position[j]), lq(qr.position[j]));
                    for k in 0..N {
                        d[j][k] = _mm256_sub_ps(b[k], a[k]);
                    }
                }
                for k in 0..N {
                    let g = if GEO == 0 {
                        let pd =
                            _mm256_fmadd_ps(np[2][k], d[2][k], _mm256_fmadd_ps(np[1][k], d[1][k], _mm256_mul_ps(np[0][k], d[0][k])));
                        let qd =
                            _mm256_fmadd_ps(nq[2][k], d[2][k], _mm256_fmadd_ps(nq[1][k], d[1][k], _mm256_mul_ps(nq[0][k], d[0][k])));
                        _mm256_mul_ps(_mm256_fmadd_ps(pd, pd, _mm256_mul_ps(qd, qd)), _mm256_set1_ps(0.5 * c.inv_geom2))
                    } else {
                        let g = _mm256_fmadd_ps(d[2][k], d[2][k], _mm256_fmadd_ps(d[1][k], d[1][k], _mm256_mul_ps(d[0][k], d[0][k])));
                        _mm256_mul_ps(g, _mm256_set1_ps(c.inv_geom2))
                    };
                    tg[k] = _mm256_add_ps(tg[k], g);
                }
            }
            2 => {
                let tiny = _mm256_set1_ps(1e-20);
                let (zp, zq) = (lp(pr.depth), lq(qr.depth));
                for k in 0..N {
                    let dz = _mm256_sub_ps(zq[k], zp[k]);
                    let zz = _mm256_mul_ps(_mm256_max_ps(zp[k], tiny), _mm256_max_ps(zq[k], tiny));
                    let r2 = _mm256_div_ps(_mm256_mul_ps(dz, dz), zz);
                    tg[k] = _mm256_fmadd_ps(r2, _mm256_set1_ps(c.inv_geom2), tg[k]);
                }
            }
            _ => {}
        }
        exp_neg(core::array::from_fn(|k| _mm256_add_ps(tc[k], tg[k])))
    }
}

/// One term of the accumulation: the rows of the taps `q = p + s` (columns)
/// and the weights, indexed like the output chunk (`w` already offset by
/// the ring's base and, for backward links, by `-s`).
#[derive(Clone, Copy)]
struct Link<S> {
    src: [*const S; 7],
    w: *const f32,
    s: isize,
}

/// Output row `yo` (image row `y`), columns `xs .. xe`, from the rings.
///
/// # Safety
/// As [`step`]; the rings hold the weights of rows `y - 2 hole ..= y` that exist.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn accumulate<S: FloatElement, const G: usize, const VAR: bool, const N: usize>(
    c: &Ctx<'_, '_, S>,
    rings: &Rings,
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    y: usize,
    xs: usize,
    xe: usize,
) {
    let (w, h) = (c.src.width() as isize, c.src.height());
    let hole = c.hole;
    let m = 2 * hole as isize;
    let base = xs as isize - m;
    let nc = 3 * G;
    let nin = nc + usize::from(VAR);
    // Forward links (q = p + o, weight row y) and backward ones (q = p - o,
    // weight row y - oy hole), those whose rows exist.
    let src_row = |yy: usize| -> [*const S; 7] {
        core::array::from_fn(|ch| if ch < nin { c.src.ptr(ch, yy) } else { core::ptr::null() })
    };
    let mut links = [Link { src: [core::ptr::null(); 7], w: core::ptr::null(), s: 0 }; 24];
    let mut nl = 0;
    for (k, &(ox, oy)) in FORWARD.iter().enumerate() {
        let s = ox * hole as isize;
        if y + oy * hole < h {
            let wr = (rings.at(k, y) as *const f32).wrapping_offset(-base);
            links[nl] = Link { src: src_row(y + oy * hole), w: wr, s };
            nl += 1;
        }
        if let Some(r) = y.checked_sub(oy * hole) {
            let wr = (rings.at(k, r) as *const f32).wrapping_offset(-s - base);
            links[nl] = Link { src: src_row(r), w: wr, s: -s };
            nl += 1;
        }
    }
    let links = &links[..nl];
    let centre = src_row(y);
    let mut x = xs;
    while x < xe {
        let xi = x as isize;
        if xi >= m && xi + 8 * N as isize + m <= w && x + 8 * N <= xe {
            // SAFETY: every tap column of the N chunks lies inside.
            unsafe { chunks::<S, G, VAR, N, false>(links, &centre, dst, yo, x, 8) };
            x += 8 * N;
        } else {
            let len = (xe - x).min(8);
            // SAFETY: columns are checked per tap.
            unsafe { chunks::<S, G, VAR, 1, true>(links, &centre, dst, yo, x, len) };
            x += len;
        }
    }
}

/// `N` chunks of eight output pixels from `x` (one chunk of `len` under `EDGE`).
///
/// # Safety
/// As [`accumulate`]; without `EDGE` every tap column is inside and `len == 8`.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn chunks<S: FloatElement, const G: usize, const VAR: bool, const N: usize, const EDGE: bool>(
    links: &[Link<S>],
    centre: &[*const S; 7],
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    x: usize,
    len: usize,
) {
    let w = dst.width() as isize;
    let nc = 3 * G;
    let nin = nc + usize::from(VAR);
    // SAFETY (every load): rows in range; columns inside or under a mask
    // (taps outside the image read as 0 and their weight is 0).
    let ld = |p: *const S, xx: isize| unsafe {
        if EDGE {
            let (lo, hi) = inside(xx, w);
            let hi = hi.min(len).max(lo);
            load8_range(p.wrapping_offset(xx), lo, hi)
        } else {
            load8(p.offset(xx))
        }
    };
    let xk: [isize; N] = core::array::from_fn(|k| (x + 8 * k) as isize);
    let hc = _mm256_set1_ps(super::h2(2, 2));
    let mut acc = [[_mm256_setzero_ps(); 7]; N];
    let mut wsum = [hc; N];
    for k in 0..N {
        for ch in 0..nin {
            let v = ld(centre[ch], xk[k]);
            acc[k][ch] = if VAR && ch == nc { _mm256_mul_ps(_mm256_mul_ps(hc, hc), v) } else { _mm256_mul_ps(hc, v) };
        }
    }
    for l in links {
        // SAFETY: the weight rows cover every chunk column (see Rings).
        let wt: [__m256; N] = core::array::from_fn(|k| unsafe { _mm256_loadu_ps(l.w.wrapping_offset(xk[k])) });
        for k in 0..N {
            wsum[k] = _mm256_add_ps(wsum[k], wt[k]);
        }
        for ch in 0..nc {
            for k in 0..N {
                acc[k][ch] = _mm256_fmadd_ps(wt[k], ld(l.src[ch], xk[k] + l.s), acc[k][ch]);
            }
        }
        if VAR {
            for k in 0..N {
                acc[k][nc] = _mm256_fmadd_ps(_mm256_mul_ps(wt[k], wt[k]), ld(l.src[nc], xk[k] + l.s), acc[k][nc]);
            }
        }
    }
    for k in 0..N {
        let xo = x + 8 * k;
        // wsum >= 9/64 in the stored lanes.
        let inv = _mm256_div_ps(_mm256_set1_ps(1.0), wsum[k]);
        for ch in 0..nc {
            // SAFETY: x + len <= width; only the first len lanes are written.
            unsafe { store8_first(dst.ptr_mut(ch, yo).add(xo), len, _mm256_mul_ps(acc[k][ch], inv)) };
        }
        if VAR {
            // SAFETY: as above.
            unsafe {
                store8_first(dst.ptr_mut(nc, yo).add(xo), len, _mm256_mul_ps(_mm256_mul_ps(acc[k][nc], inv), inv));
                store8_first(dst.ptr_mut(nc + 1, yo).add(xo), len, _mm256_mul_ps(hc, inv));
            }
        }
    }
}

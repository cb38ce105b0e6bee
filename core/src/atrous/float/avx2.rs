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
//! the result does not depend on the band split. Columns go in strips only
//! as wide as a packed sub-row allows (a whole 1280-pixel row up to level
//! 4); a strip computes each offset's weights only over the columns it
//! reads. Near the borders loads go under a lane mask (taps outside the
//! image read as 0 and weigh 0, as the scalar pixel leaves them out). The
//! sums run in a different order from the scalar pixel's, so results agree
//! to rounding, not bit for bit.

use core::arch::x86_64::*;

use super::{rows, Ctx, Geometry};
use crate::math::LOG2E;
use crate::precision::FloatElement;
use crate::simd::avx2::{lane_range, load8, load8_range, store8_first};
use crate::view::ViewMut;

/// Floats between the sub-rows (planes) of a packed guide row: a
/// compile-time constant, so every load of the weight kernel is one base
/// register plus a constant plus the column. 5568 bytes apart, the ten
/// sub-rows of a row start at least five cache lines apart in the L1's
/// 4 KiB set space whatever the caller's plane layout (planes of 1280x720
/// f32 are 900 pages each: read in place, the ten guide streams of a row
/// would all share one set). Wide enough for a whole 1280-pixel row and its
/// halo up to level 4 (see [`strip`]).
const PK: usize = 1392;

/// Guide planes in a packed row: colour 0..3, noise, normal 0..3, then
/// position 0..3 (or depth in the first of those).
const NPLANES: usize = 10;

/// The widest strip (a multiple of 8): what fits a packed sub-row with its
/// `2 hole` halo each side (1376 columns at level 0, 1320 at level 4, 872 at level 7).
/// Rows go in as few strips as that allows, of equal width (see [`strips`]):
/// measured on Zen 3 at 1280x720, one strip per row runs a level 15-25 %
/// faster than 256-column strips (whose halos are weighed and packed twice,
/// 25 % extra at level 4, and whose short row pieces the prefetchers never
/// get going on), although its rings and packed rows live in L3.
fn strip(hole: usize) -> usize {
    (PK - 8 - 4 * hole) / 8 * 8
}

/// The forward offsets `(ox, oy)` in units of the hole.
const FORWARD: [(isize, usize); 12] =
    [(1, 0), (2, 0), (-2, 1), (-1, 1), (0, 1), (1, 1), (2, 1), (-2, 2), (-1, 2), (0, 2), (1, 2), (2, 2)];

/// The B3 tap weights of the forward offsets.
const H_FORWARD: [f32; 12] = {
    let b3 = super::super::B3;
    let mut t = [0.0f32; 12];
    let mut k = 0;
    while k < 12 {
        t[k] = b3[(FORWARD[k].0 + 2) as usize] * b3[FORWARD[k].1 + 2];
        k += 1;
    }
    t
};

/// `log2` of [`H_FORWARD`] (exact: every tap weight is a power of two
/// times 1, 3 or 9, and these are computed in f64).
const LOG2_H_FORWARD: [f32; 12] = {
    // log2 of 1/256, 1/64, 3/128, 1/16, 3/32, 9/64 (and 3/8 unused here).
    let mut t = [0.0f32; 12];
    let mut k = 0;
    while k < 12 {
        let h = H_FORWARD[k];
        t[k] = if h == 1.0 / 256.0 {
            -8.0
        } else if h == 1.0 / 64.0 {
            -6.0
        } else if h == 3.0 / 128.0 {
            -5.415_037_5
        } else if h == 1.0 / 16.0 {
            -4.0
        } else if h == 3.0 / 32.0 {
            -3.415_037_5
        } else {
            -2.830_075 // 9/64
        };
        k += 1;
    }
    t
};

/// Floats per weight-ring row: the strip and its `2 hole` halo each side,
/// rounded up to whole chunks, plus one chunk that unstored lanes may read.
fn ring_row(hole: usize) -> usize {
    (strip(hole) + 4 * hole).div_ceil(8) * 8 + 8
}

/// Rows the ring of offset row `oy` keeps: `oy hole + 1`.
fn depth(oy: usize, hole: usize) -> usize {
    oy * hole + 1
}

/// Floats of the weight rings.
fn rings_len(hole: usize) -> usize {
    FORWARD.iter().map(|&(_, oy)| depth(oy, hole)).sum::<usize>() * ring_row(hole)
}

/// Scratch floats the pair step needs at `level` (any width): the weight
/// rings, `2 hole + 1` packed guide rows (level 4: about 3.2 MB in all,
/// level 7: 25 MB), and `2 hole + 8` floats of slack. Halo chunks whose
/// weights are never read load their `q` up to `2 hole` floats before a
/// packed sub-row (inside the rings) or past it (the next sub-row, or the
/// slack after the last).
pub(crate) fn scratch_len(level: u32) -> usize {
    let hole = 1usize << level;
    rings_len(hole) + (2 * hole + 1) * NPLANES * PK + 2 * hole + 8
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
const EXP2_C: [f32; 7] =
    [1.0, core::f32::consts::LN_2, 0.240_226_5, 0.055_504_11, 0.009_618_129, 0.001_333_355_8, 0.000_154_035_3];

/// `h e^-t = 2^y`, `y = log2(h) - t log2(e)`, per lane for `N` vectors:
/// `round(y)` goes into the exponent bits of a degree-6 polynomial of the
/// rest. `t >= 0` or NaN here (the packed guides make every term a square or
/// a non-negative product); lanes with `y < -125` (`h e^-t` below 2^-125,
/// `t` beyond about 82) or NaN give 0. `y` is rounded once: a relative error
/// of `|y| 2^-24` (below 5e-7 for `t <= 4`).
#[inline(always)]
unsafe fn exp_neg<const N: usize>(t: [__m256; N], log2h: [__m256; N]) -> [__m256; N] {
    // SAFETY (the whole body): inlined into AVX2/FMA code only.
    unsafe {
        let c = [
            _mm256_set1_ps(EXP2_C[0]),
            _mm256_set1_ps(EXP2_C[1]),
            _mm256_set1_ps(EXP2_C[2]),
            _mm256_set1_ps(EXP2_C[3]),
            _mm256_set1_ps(EXP2_C[4]),
            _mm256_set1_ps(EXP2_C[5]),
            _mm256_set1_ps(EXP2_C[6]),
        ];
        let mut out = t;
        for i in 0..N {
            let y = _mm256_fmadd_ps(t[i], _mm256_set1_ps(-LOG2E), log2h[i]);
            let valid = _mm256_cmp_ps::<_CMP_GE_OQ>(y, _mm256_set1_ps(-125.0));
            let n = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(y);
            let f = _mm256_sub_ps(y, n);
            let f2 = _mm256_mul_ps(f, f);
            let p01 = _mm256_fmadd_ps(f, c[1], c[0]);
            let p23 = _mm256_fmadd_ps(f, c[3], c[2]);
            let p45 = _mm256_fmadd_ps(f, c[5], c[4]);
            let p46 = _mm256_fmadd_ps(f2, c[6], p45);
            let f4 = _mm256_mul_ps(f2, f2);
            let p03 = _mm256_fmadd_ps(f2, p23, p01);
            let p = _mm256_fmadd_ps(f4, p46, p03);
            // p in [2^-1/2, 2^1/2]: adding n to its exponent field is p 2^n
            // for n >= -125.
            let e = _mm256_add_epi32(_mm256_castps_si256(p), _mm256_slli_epi32::<23>(_mm256_cvtps_epi32(n)));
            out[i] = _mm256_and_ps(_mm256_castsi256_ps(e), valid);
        }
        out
    }
}

/// Prefetches columns `x0 .. x1` of row `yy` of the colour planes (the
/// accumulation reads them in place) into L2.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
fn prefetch_colour<S: FloatElement>(c: &Ctx<'_, '_, S>, nin: usize, yy: usize, x0: usize, x1: usize) {
    let sz = core::mem::size_of::<S>();
    for ch in 0..nin {
        let p = c.src.ptr(ch, yy);
        let (a, b) = ((p as *const i8).wrapping_add(x0 * sz), (p as *const i8).wrapping_add(x1 * sz));
        let mut q = a;
        while q < b {
            _mm_prefetch::<_MM_HINT_T1>(q);
            q = q.wrapping_add(64);
        }
        _mm_prefetch::<_MM_HINT_T1>(b.wrapping_sub(1));
    }
}

/// Prefetches columns `x0 .. x1` of row `yy` of every guide plane into L2.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
fn prefetch_guides<S: FloatElement>(c: &Ctx<'_, '_, S>, yy: usize, x0: usize, x1: usize) {
    let r = rows(c, yy);
    let sz = core::mem::size_of::<S>();
    let planes = [r.src[0], r.src[1], r.src[2], r.noise, r.normal[0], r.normal[1], r.normal[2]];
    let geo = [r.position[0], r.position[1], r.position[2], r.depth];
    for p in planes.into_iter().chain(geo) {
        if p.is_null() {
            continue;
        }
        let (a, b) = ((p as *const i8).wrapping_add(x0 * sz), (p as *const i8).wrapping_add(x1 * sz));
        let mut q = a;
        while q < b {
            _mm_prefetch::<_MM_HINT_T1>(q);
            q = q.wrapping_add(64);
        }
        _mm_prefetch::<_MM_HINT_T1>(b.wrapping_sub(1));
    }
}

/// The weight rings of the forward offsets inside the scratch.
struct Rings {
    base: *mut f32,
    /// Start of each offset's ring, in floats.
    start: [usize; 12],
    row: usize,
    hole: usize,
}

impl Rings {
    fn new(base: *mut f32, hole: usize) -> Self {
        let row = ring_row(hole);
        let mut start = [0; 12];
        let mut at = 0;
        for (k, &(_, oy)) in FORWARD.iter().enumerate() {
            start[k] = at;
            at += depth(oy, hole) * row;
        }
        Rings { base, start, row, hole }
    }

    /// Row `y` of offset `k`'s ring (ring index 0 is column `xs - 2 hole`).
    fn at(&self, k: usize, y: usize) -> *mut f32 {
        let d = depth(FORWARD[k].1, self.hole);
        self.base.wrapping_add(self.start[k] + (y % d) * self.row)
    }
}

/// The packed guide rows: `2 hole + 1` slots of `NPLANES` sub-rows of `PK`
/// floats; slot element `i` of a sub-row is column `xs - 2 hole + i`.
struct Packed {
    base: *mut f32,
    slots: usize,
}

impl Packed {
    fn row(&self, y: usize) -> *mut f32 {
        self.base.wrapping_add((y % self.slots) * NPLANES * PK)
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
    let rings = Rings::new(scratch.as_mut_ptr(), hole);
    let packed = Packed { base: scratch.as_mut_ptr().wrapping_add(rings_len(hole)), slots: 2 * hole + 1 };
    let nin = 3 * G + usize::from(VAR);
    let y1 = y0 + dst.height();
    // As few strips as fit, of equal width (a multiple of 8, <= strip(hole)).
    let sw = w.div_ceil(w.div_ceil(strip(hole))).div_ceil(8) * 8;
    let mut xs = 0;
    while xs < w {
        let xe = (xs + sw).min(w);
        // Guide rows are packed once each, as they first come into reach
        // (as the lowest q row, 2 hole below the row being weighed).
        let first = y0.saturating_sub(m);
        let mut next_pack = first;
        let mut pack_upto = |r: usize| {
            while next_pack <= (r + m).min(h - 1) {
                // SAFETY: the slot lies inside the scratch.
                unsafe { pack_row::<S, GEO>(c, packed.row(next_pack), next_pack, xs, xe) };
                next_pack += 1;
                // The row packed next, into L2 while this one is weighed.
                if next_pack < h {
                    prefetch_guides(c, next_pack, xs.saturating_sub(m), (xe + m).min(w));
                }
            }
        };
        // Rows above the band whose weights reach into it.
        for r in first..y0 {
            pack_upto(r);
            // SAFETY: forwarded; the ring rows are inside the scratch.
            unsafe { weights_row::<GEO>(c, &rings, &packed, r, xs, xe) };
        }
        for y in y0..y1 {
            if let Some(qy) = Some(y + 1 + m).filter(|&v| v < h) {
                prefetch_colour(c, nin, qy, xs.saturating_sub(m), (xe + m).min(w));
            }
            pack_upto(y);
            // SAFETY: as above.
            unsafe { weights_row::<GEO>(c, &rings, &packed, y, xs, xe) };
            // Two groups go one after the other (the second with the
            // variance, when there is one), each through 15 input streams:
            // all six channels at once read 30 and ran the level ~1.5x the
            // time of one group at 9 % more instructions.
            // SAFETY: as above.
            unsafe {
                if G == 2 {
                    accumulate::<S, false, 3>(c, &rings, dst, y - y0, y, xs, xe, 0);
                }
                let c0 = 3 * (G - 1);
                if VAR {
                    accumulate::<S, true, 2>(c, &rings, dst, y - y0, y, xs, xe, c0)
                } else {
                    accumulate::<S, false, 3>(c, &rings, dst, y - y0, y, xs, xe, c0)
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

/// Packs the guides of image row `y` over columns `xs - 2 hole .. xe + 2
/// hole` into `out` as f32, zero outside the image. Planes a geometry does
/// not use are left alone (never read).
///
/// # Safety
/// As [`step`]; `out` holds `NPLANES * PK` floats.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn pack_row<S: FloatElement, const GEO: u8>(c: &Ctx<'_, '_, S>, out: *mut f32, y: usize, xs: usize, xe: usize) {
    let w = c.src.width();
    let m = 2 * c.hole;
    let r = rows(c, y);
    let pos = if GEO == 2 { [r.depth, core::ptr::null(), core::ptr::null()] } else { r.position };
    let planes: [*const S; NPLANES] =
        [r.src[0], r.src[1], r.src[2], r.noise, r.normal[0], r.normal[1], r.normal[2], pos[0], pos[1], pos[2]];
    // Image columns a .. b land at packed index a - (xs - 2 hole).
    let lo = xs.saturating_sub(m);
    let hi = (xe + m).min(w);
    let off = lo + m - xs; // packed index of column lo
                           // (The noise sub-row is zero outside the image too: those lanes weigh 0.)
    let len = (xe + m - xs + m).div_ceil(8) * 8; // packed indices touched by the chunks
                                                 // What the sub-rows hold, so the weight kernel multiplies by no
                                                 // constant: colour as is; the noise as the colour gate's reciprocal
                                                 // `1 / (scale v + eps)` (>= 0; `max` of two of them is the reciprocal of
                                                 // the scalar's `min`); normals over sigma_normal; positions times
                                                 // sigma_normal sqrt(1 / (2 sigma_plane^2)) for the plane term (so
                                                 // `(n'(p) . d')^2 = (n(p) . d)^2 / (2 sigma_plane^2)`), times
                                                 // sqrt(1 / sigma^2) for the position term; depth as is.
    let has_n = !r.normal[0].is_null();
    let sn = if has_n { libm::sqrtf(c.inv_normal2) } else { 0.0 };
    let sx = match GEO {
        0 => libm::sqrtf(0.5 * c.inv_geom2) / sn,
        1 => libm::sqrtf(c.inv_geom2),
        _ => 1.0,
    };
    let scale = [1.0, 1.0, 1.0, 0.0, sn, sn, sn, sx, sx, sx];
    let (cs, eps) = (_mm256_set1_ps(c.color_scale), _mm256_set1_ps(c.eps));
    let one = _mm256_set1_ps(1.0);
    for (k, &p) in planes.iter().enumerate() {
        if p.is_null() {
            continue;
        }
        let sk = _mm256_set1_ps(scale[k]);
        let tr = |v: __m256| -> __m256 {
            match k {
                0..=2 => v,
                3 => _mm256_max_ps(_mm256_div_ps(one, _mm256_fmadd_ps(cs, v, eps)), _mm256_setzero_ps()),
                7 if GEO == 2 => v,
                _ => _mm256_mul_ps(v, sk),
            }
        };
        let o = out.wrapping_add(k * PK);
        // SAFETY (the loops): packed indices stay below len <= PK - 8; image
        // columns lo .. hi are inside the row.
        unsafe {
            // Zero where the strip's halo leaves the image (first and last
            // strips); the last store may run past `off` into what the copy
            // writes next (off <= 2 hole, far inside the sub-row).
            let zero = _mm256_setzero_ps();
            let mut i = 0;
            while i < off {
                _mm256_storeu_ps(o.add(i), zero);
                i += 8;
            }
            let n = hi - lo;
            let mut j = 0;
            while j + 8 <= n {
                _mm256_storeu_ps(o.add(off + j), tr(load8(p.add(lo + j))));
                j += 8;
            }
            if j < n {
                let v = tr(load8_range(p.add(lo + j), 0, n - j));
                _mm256_storeu_ps(o.add(off + j), _mm256_and_ps(v, _mm256_castsi256_ps(lane_range(0, n - j))));
            }
            // Exactly up to len + 8: past it lies the next sub-row (or slot).
            let mut i = off + n;
            while i + 8 <= len + 8 {
                _mm256_storeu_ps(o.add(i), zero);
                i += 8;
            }
            while i < len + 8 {
                *o.add(i) = 0.0;
                i += 1;
            }
        }
    }
}

/// The weights of all twelve forward offsets for image row `y` over the
/// columns strip `xs .. xe` reads, into the rings, from the packed rows `y`,
/// `y + hole`, `y + 2 hole` (an offset whose `q` row is past the image gets
/// a weight that is never read: its ring slot held a row no longer needed).
///
/// # Safety
/// As [`step`]; the packed rows are current.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn weights_row<const GEO: u8>(
    c: &Ctx<'_, '_, impl FloatElement>,
    rings: &Rings,
    packed: &Packed,
    y: usize,
    xs: usize,
    xe: usize,
) {
    let (w, h) = (c.src.width() as isize, c.src.height());
    let hole = c.hole;
    let m = 2 * hole as isize;
    let base = xs as isize - m; // column of ring / packed index 0
    let qrow = |oy: usize| packed.row(if y + oy * hole < h { y + oy * hole } else { y }) as *const f32;
    let rows = [qrow(0), qrow(1), qrow(2)];
    let out: [*mut f32; 12] = core::array::from_fn(|k| rings.at(k, y));
    let n = (xe as isize + m - base) as usize; // packed indices the rings need
    let mut i = 0;
    while i < n {
        let x = base + i as isize;
        // SAFETY: packed and ring indices i .. i + 8 (+/- 2 hole for q) lie
        // inside their rows.
        unsafe {
            if x >= m && x + 8 + m <= w {
                chunk::<GEO, false>(c, &rows, &out, i, x);
            } else {
                chunk::<GEO, true>(c, &rows, &out, i, x);
            }
        }
        i += 8;
    }
}

/// The twelve weights of the chunk at packed index `i` (column `x`). Pass 1
/// (colour terms, `p`'s colour and noise in registers) and pass 2 (geometry
/// and weight, `p`'s normal and position) run over groups of offsets stage
/// by stage, so the FP scheduler holds several independent chains. Under
/// `EDGE`, lanes whose `p` or `q` lies outside the image get weight 0.
///
/// # Safety
/// As [`weights_row`].
#[inline(always)]
unsafe fn chunk<const GEO: u8, const EDGE: bool>(
    c: &Ctx<'_, '_, impl FloatElement>,
    rows: &[*const f32; 3],
    out: &[*mut f32; 12],
    i: usize,
    x: isize,
) {
    // SAFETY (the body): inlined into AVX2/FMA code only; loads and stores
    // inside the packed rows and the rings (caller).
    unsafe {
        let zero = _mm256_setzero_ps();
        let mut tc = [zero; 12];
        for k0 in [0, 4, 8] {
            let t = colour_terms::<4>(c, rows, i, k0);
            tc[k0..k0 + 4].copy_from_slice(&t);
        }
        for k0 in [0, 3, 6, 9] {
            let e = geometry_weights::<GEO, 3>(c, rows, &tc, i, k0);
            for (j, e) in e.iter().enumerate() {
                let k = k0 + j;
                let mut wt = *e;
                if EDGE {
                    let w = c.src.width() as isize;
                    let (a, b) = inside(x, w);
                    let (qa, qb) = inside(x + FORWARD[k].0 * c.hole as isize, w);
                    let lo = a.max(qa);
                    wt = _mm256_and_ps(wt, _mm256_castsi256_ps(lane_range(lo, b.min(qb).max(lo))));
                }
                _mm256_storeu_ps(out[k].add(i), wt);
            }
        }
    }
}

/// Eight floats of sub-row `plane` of a packed row at index `i`.
///
/// # Safety
/// Inside the packed row.
#[inline(always)]
unsafe fn lp(row: *const f32, plane: usize, i: isize) -> __m256 {
    // SAFETY: caller; AVX is enabled in every caller.
    unsafe { _mm256_loadu_ps(row.offset(i + (plane * PK) as isize)) }
}

/// Colour terms `|g(p) - g(q)|^2 / (scale min(v(p), v(q)) + eps)` of offsets
/// `k0 .. k0 + N`.
#[inline(always)]
unsafe fn colour_terms<const N: usize>(
    c: &Ctx<'_, '_, impl FloatElement>,
    rows: &[*const f32; 3],
    i: usize,
    k0: usize,
) -> [__m256; N] {
    let hole = c.hole as isize;
    let ip = i as isize;
    let p = rows[0];
    let mut q = [(p, 0isize); N];
    for (j, q) in q.iter_mut().enumerate() {
        let (ox, oy) = FORWARD[k0 + j];
        *q = (rows[oy], ip + ox * hole);
    }
    // SAFETY (the body): inlined into AVX2/FMA code only; loads inside the
    // packed rows (caller).
    unsafe {
        let mut dc = [_mm256_setzero_ps(); N];
        for ch in 0..3 {
            let gp = lp(p, ch, ip);
            for j in 0..N {
                let d = _mm256_sub_ps(gp, lp(q[j].0, ch, q[j].1));
                dc[j] = _mm256_fmadd_ps(d, d, dc[j]);
            }
        }
        // The packed noise is 1 / (scale v + eps): the larger reciprocal is
        // the scalar's smaller variance.
        let ivp = lp(p, 3, ip);
        for j in 0..N {
            dc[j] = _mm256_mul_ps(dc[j], _mm256_max_ps(lp(q[j].0, 3, q[j].1), ivp));
        }
        dc
    }
}

/// `e^-t` of offsets `k0 .. k0 + N`, their colour terms `tc` plus the
/// geometry terms.
#[inline(always)]
unsafe fn geometry_weights<const GEO: u8, const N: usize>(
    c: &Ctx<'_, '_, impl FloatElement>,
    rows: &[*const f32; 3],
    tc: &[__m256; 12],
    i: usize,
    k0: usize,
) -> [__m256; N] {
    let hole = c.hole as isize;
    let ip = i as isize;
    let p = rows[0];
    let mut q = [(p, 0isize); N];
    for (j, q) in q.iter_mut().enumerate() {
        let (ox, oy) = FORWARD[k0 + j];
        *q = (rows[oy], ip + ox * hole);
    }
    let has_n = c.guides.normal.is_some();
    // SAFETY (the body): inlined into AVX2/FMA code only; loads inside the
    // packed rows (caller).
    unsafe {
        let zero = _mm256_setzero_ps();
        let mut t = [zero; N];
        t.copy_from_slice(&tc[k0..k0 + N]);
        let mut nq = [[zero; N]; 3];
        if has_n {
            // Normals are packed over sigma_normal.
            for a in 0..3 {
                let np = lp(p, 4 + a, ip);
                for j in 0..N {
                    nq[a][j] = lp(q[j].0, 4 + a, q[j].1);
                    let d = _mm256_sub_ps(np, nq[a][j]);
                    t[j] = _mm256_fmadd_ps(d, d, t[j]);
                }
            }
        }
        match GEO {
            // Plane: the mean of both pixels' squared tangent-plane distances
            // (positions packed so that the squares come out scaled).
            0 => {
                let mut pd = [zero; N];
                let mut qd = [zero; N];
                let mut dd = [zero; N];
                for a in 0..3 {
                    let (xp, np) = (lp(p, 7 + a, ip), lp(p, 4 + a, ip));
                    for j in 0..N {
                        let d = _mm256_sub_ps(lp(q[j].0, 7 + a, q[j].1), xp);
                        pd[j] = _mm256_fmadd_ps(np, d, pd[j]);
                        qd[j] = _mm256_fmadd_ps(nq[a][j], d, qd[j]);
                        dd[j] = _mm256_fmadd_ps(d, d, dd[j]);
                    }
                }
                for j in 0..N {
                    t[j] = _mm256_fmadd_ps(qd[j], qd[j], _mm256_fmadd_ps(pd[j], pd[j], t[j]));
                }
                // The distance term: positions are packed times sx (see
                // `pack_row`), so |d'|^2 = |d|^2 sx^2. (Computed also when
                // it is off: its FMAs hide under the loads.)
                if c.inv_dist2 > 0.0 {
                    let sn2 = c.inv_normal2;
                    let k = _mm256_set1_ps(c.inv_dist2 * sn2 / (0.5 * c.inv_geom2));
                    for j in 0..N {
                        t[j] = _mm256_fmadd_ps(dd[j], k, t[j]);
                    }
                }
            }
            1 => {
                for a in 0..3 {
                    let xp = lp(p, 7 + a, ip);
                    for j in 0..N {
                        let d = _mm256_sub_ps(lp(q[j].0, 7 + a, q[j].1), xp);
                        t[j] = _mm256_fmadd_ps(d, d, t[j]);
                    }
                }
            }
            2 => {
                let tiny = _mm256_set1_ps(1e-20);
                let zp = lp(p, 7, ip);
                for j in 0..N {
                    let zq = lp(q[j].0, 7, q[j].1);
                    let dz = _mm256_sub_ps(zq, zp);
                    let zz = _mm256_mul_ps(_mm256_max_ps(zp, tiny), _mm256_max_ps(zq, tiny));
                    let r2 = _mm256_div_ps(_mm256_mul_ps(dz, dz), zz);
                    t[j] = _mm256_fmadd_ps(r2, _mm256_set1_ps(c.inv_geom2), t[j]);
                }
            }
            _ => {}
        }
        let mut lh = [zero; N];
        for j in 0..N {
            lh[j] = _mm256_set1_ps(LOG2_H_FORWARD[k0 + j]);
        }
        exp_neg(t, lh)
    }
}

/// One term of the accumulation: the tap rows `q = p + s` and the weights,
/// both indexed like the output chunk (`src` already offset by `s`; `w` by
/// the ring's base and, for backward links, by `-s`), so a load is one
/// pointer plus the output column.
#[derive(Clone, Copy)]
struct Link<S> {
    src: [*const S; 4],
    w: *const f32,
    s: isize,
}

/// Output row `yo` (image row `y`), columns `xs .. xe`, from the rings: the
/// three colour channels from `c0` (and after them, under `VAR`, the
/// variance in, the variance and the centre weight out).
///
/// # Safety
/// As [`step`]; the rings hold the weights of rows `y - 2 hole ..= y` that
/// exist; `c0 + 3 + VAR` channels in `c.src`, `c0 + 3 + 2 VAR` in `dst`.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn accumulate<S: FloatElement, const VAR: bool, const N: usize>(
    c: &Ctx<'_, '_, S>,
    rings: &Rings,
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    y: usize,
    xs: usize,
    xe: usize,
    c0: usize,
) {
    let (w, h) = (c.src.width() as isize, c.src.height());
    let hole = c.hole;
    let m = 2 * hole as isize;
    let base = xs as isize - m;
    let nin = 3 + usize::from(VAR);
    // Forward links (q = p + o, weight row y) and backward ones (q = p - o,
    // weight row y - oy hole), those whose rows exist.
    let src_row = |yy: usize, s: isize| -> [*const S; 4] {
        core::array::from_fn(|ch| if ch < nin { c.src.ptr(c0 + ch, yy).wrapping_offset(s) } else { core::ptr::null() })
    };
    let mut links = [Link { src: [core::ptr::null(); 4], w: core::ptr::null(), s: 0 }; 24];
    let mut nl = 0;
    for (k, &(ox, oy)) in FORWARD.iter().enumerate() {
        let s = ox * hole as isize;
        if y + oy * hole < h {
            let wr = (rings.at(k, y) as *const f32).wrapping_offset(-base);
            links[nl] = Link { src: src_row(y + oy * hole, s), w: wr, s };
            nl += 1;
        }
        if let Some(r) = y.checked_sub(oy * hole) {
            let wr = (rings.at(k, r) as *const f32).wrapping_offset(-s - base);
            links[nl] = Link { src: src_row(r, -s), w: wr, s: -s };
            nl += 1;
        }
    }
    let links = &links[..nl];
    let centre = src_row(y, 0);
    let mut x = xs;
    while x < xe {
        let xi = x as isize;
        if xi >= m && xi + 8 * N as isize + m <= w && x + 8 * N <= xe {
            // SAFETY: every tap column of the N chunks lies inside.
            unsafe { chunks::<S, VAR, N, false>(links, &centre, dst, yo, x, 8, c0) };
            x += 8 * N;
        } else {
            let len = (xe - x).min(8);
            // SAFETY: columns are checked per tap.
            unsafe { chunks::<S, VAR, 1, true>(links, &centre, dst, yo, x, len, c0) };
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
#[allow(clippy::too_many_arguments)]
unsafe fn chunks<S: FloatElement, const VAR: bool, const N: usize, const EDGE: bool>(
    links: &[Link<S>],
    centre: &[*const S; 4],
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    x: usize,
    len: usize,
    c0: usize,
) {
    let w = dst.width() as isize;
    let nc = 3;
    let nin = nc + usize::from(VAR);
    // SAFETY (every load): rows in range; columns inside or under a mask
    // (taps outside the image read as 0 and their weight is 0). `p` points
    // at the row shifted by `s`, `xx` is the output column.
    let ld = |p: *const S, xx: isize, s: isize| unsafe {
        if EDGE {
            let (lo, hi) = inside(xx + s, w);
            let hi = hi.min(len).max(lo);
            load8_range(p.wrapping_offset(xx), lo, hi)
        } else {
            load8(p.wrapping_offset(xx))
        }
    };
    let xk: [isize; N] = core::array::from_fn(|k| (x + 8 * k) as isize);
    let hc = _mm256_set1_ps(super::h2(2, 2));
    let mut acc = [[_mm256_setzero_ps(); 4]; N];
    let mut wsum = [hc; N];
    for k in 0..N {
        for ch in 0..nin {
            let v = ld(centre[ch], xk[k], 0);
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
                acc[k][ch] = _mm256_fmadd_ps(wt[k], ld(l.src[ch], xk[k], l.s), acc[k][ch]);
            }
        }
        if VAR {
            for k in 0..N {
                acc[k][nc] = _mm256_fmadd_ps(_mm256_mul_ps(wt[k], wt[k]), ld(l.src[nc], xk[k], l.s), acc[k][nc]);
            }
        }
    }
    for k in 0..N {
        let xo = x + 8 * k;
        // wsum >= 9/64 in the stored lanes.
        let inv = _mm256_div_ps(_mm256_set1_ps(1.0), wsum[k]);
        for ch in 0..nc {
            // SAFETY: x + len <= width; only the first len lanes are written.
            unsafe { store8_first(dst.ptr_mut(c0 + ch, yo).add(xo), len, _mm256_mul_ps(acc[k][ch], inv)) };
        }
        if VAR {
            // SAFETY: as above.
            unsafe {
                store8_first(dst.ptr_mut(c0 + nc, yo).add(xo), len, _mm256_mul_ps(_mm256_mul_ps(acc[k][nc], inv), inv));
                store8_first(dst.ptr_mut(c0 + nc + 1, yo).add(xo), len, _mm256_mul_ps(hc, inv));
            }
        }
    }
}

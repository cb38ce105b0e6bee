//! The à-trous step in fixed point (integer only). The edge-stopping
//! exponent is assembled in Q.8 from the colour, normal and geometry terms,
//! the weight is `h * exp_q8(-t)` in Q.16, sums are exact `i64`, ratios are
//! rounded integer divisions. See [`super`] for the definition.
//!
//! [`step`] computes in `i64`, each geometry term capped where the weight is
//! already 0; `step_wide` (products in `i128`, so no format combination
//! overflows) is the same arithmetic, and runs for the formats and
//! parameters the `i64` path cannot hold. Both give the same bits (tested).

use super::{AtrousGuides, AtrousParams, B3};
use crate::fixed::{div_round, exp_q8, ld, rescale, sat16};
use crate::view::{View, ViewMut};

fn at(v: &View<'_, i16>, c: usize, y: usize, x: usize) -> i64 {
    ld(v.at(c, y, x)) as i64
}

fn q16(v: f32) -> i128 {
    (v.clamp(0.0, 1.0e12) as f64 * 65536.0) as i128
}

/// `v / 2^s` for `s >= 0` in i128 (floor), `v * 2^-s` otherwise.
fn sh(v: i128, s: i32) -> i128 {
    if s >= 0 {
        v >> s.min(126)
    } else {
        v << (-s).min(60)
    }
}

#[allow(clippy::too_many_arguments)]
fn step_wide(
    level: u32,
    groups: usize,
    with_variance: bool,
    p: &AtrousParams,
    g: &AtrousGuides<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    let (w, h) = (src.width(), src.height());
    let hole = 1usize << level;
    let nc = 3 * groups;
    let fs = src.frac() as i32;
    let fo = dst.frac() as i32;
    let fv = g.noise.frac() as i32;
    // Real-valued parameters in Q.16.
    let scale_q = q16(p.phi_color / hole as f32);
    let eps_q = q16(p.eps);
    let inv_n2 = q16(1.0 / (p.sigma_normal * p.sigma_normal));
    let (geo_plane, geo_pos, geo_depth) = (
        g.normal.is_some() && g.position.is_some(),
        g.normal.is_none() && g.position.is_some(),
        g.position.is_none() && g.depth.is_some(),
    );
    let inv_geo = if geo_plane {
        q16(1.0 / (p.sigma_plane * p.sigma_plane))
    } else if geo_pos {
        q16(1.0 / ((p.sigma_plane * hole as f32) * (p.sigma_plane * hole as f32)))
    } else {
        q16(1.0 / ((p.sigma_depth * hole as f32) * (p.sigma_depth * hole as f32)))
    };
    // The plane geometry's distance term (0: off).
    let inv_dist =
        if geo_plane && p.sigma_distance > 0.0 { q16(1.0 / (p.sigma_distance * p.sigma_distance)) } else { 0 };
    // The colour guide is the first image.
    let guide = |y: usize, x: usize, c: usize| -> i128 { at(src, c, y, x) as i128 };
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for x in 0..w {
            let gp = [guide(y, x, 0), guide(y, x, 1), guide(y, x, 2)];
            let vp = at(&g.noise, 0, y, x);
            let mut wsum = 0i64;
            let mut acc = [0i64; 6];
            let mut accv = 0i128;
            for dy in 0..5 {
                let Some(qy) = (y + dy * hole).checked_sub(2 * hole).filter(|&v| v < h) else { continue };
                for dx in 0..5 {
                    let Some(qx) = (x + dx * hole).checked_sub(2 * hole).filter(|&v| v < w) else { continue };
                    // Colour: |g_p - g_q|^2 (Q.2fs) over scale * min(v) + eps (real), as Q.8.
                    let dc: i128 = (0..3).map(|c| (gp[c] - guide(qy, qx, c)).pow(2)).sum();
                    let v = vp.min(at(&g.noise, 0, qy, qx)).max(0) as i128; // negative variance counts as 0
                                                                            // Denominator in Q.(2fs + 16): scale (Q.16) * v (Q.fv) -> shift to Q.(2fs+16).
                    let den = sh(scale_q * v, fv - 2 * fs) + sh(eps_q, -2 * fs);
                    let mut t8: i128 = if den > 0 {
                        (dc << 24) / den
                    } else if dc > 0 {
                        1 << 40
                    } else {
                        0
                    };
                    if let Some(n) = &g.normal {
                        let fnm = n.frac() as i32;
                        let dn: i128 = (0..3).map(|c| ((at(n, c, y, x) - at(n, c, qy, qx)) as i128).pow(2)).sum();
                        t8 += sh(dn * inv_n2, 2 * fnm + 8);
                    }
                    if geo_plane || geo_pos {
                        let pos = g.position.as_ref().expect("position");
                        let fx = pos.frac() as i32;
                        let d: [i128; 3] = core::array::from_fn(|c| (at(pos, c, qy, qx) - at(pos, c, y, x)) as i128);
                        let gd = if geo_plane {
                            let n = g.normal.as_ref().expect("normal");
                            let fnm = n.frac() as i32;
                            // Both pixels' tangent-plane distances, Q.(fn + fx) -> 16
                            // fractional bits before squaring; their squares averaged.
                            let pd: i128 = (0..3).map(|c| at(n, c, y, x) as i128 * d[c]).sum();
                            let qd: i128 = (0..3).map(|c| at(n, c, qy, qx) as i128 * d[c]).sum();
                            let (pd16, qd16) = (sh(pd, fnm + fx - 16), sh(qd, fnm + fx - 16));
                            if inv_dist > 0 {
                                let d16: [i128; 3] = core::array::from_fn(|c| sh(d[c], fx - 16));
                                t8 += sh(sh(d16.iter().map(|v| v * v).sum::<i128>(), 16) * inv_dist, 24);
                            }
                            sh(pd16 * pd16 + qd16 * qd16, 17)
                        } else {
                            let d16: [i128; 3] = core::array::from_fn(|c| sh(d[c], fx - 16));
                            sh(d16.iter().map(|v| v * v).sum::<i128>(), 16)
                        };
                        t8 += sh(gd * inv_geo, 24);
                    } else if geo_depth {
                        let dz = g.depth.as_ref().expect("depth");
                        // (zq - zp)^2 / (zp zq) in Q.16 (depths clamped to one unit).
                        let zp = (at(dz, 0, y, x) as i128).max(1);
                        let zq = (at(dz, 0, qy, qx) as i128).max(1);
                        let r2 = ((zq - zp).pow(2) << 16) / (zp * zq);
                        t8 += sh(r2 * inv_geo, 24);
                    }
                    let t8 = t8.clamp(0, 1 << 28) as i32;
                    let h2 = (B3[dy] * B3[dx] * 65536.0) as i64; // exact: multiples of 1/256
                    let wt = (h2 * exp_q8(-t8) as i64) >> 16; // Q.16
                    wsum += wt;
                    for (c, a) in acc.iter_mut().enumerate().take(nc) {
                        *a += wt * at(src, c, qy, qx);
                    }
                    if with_variance {
                        accv += (wt as i128 * wt as i128) * at(src, nc, qy, qx) as i128;
                    }
                }
            }
            let wsum = wsum.max(1);
            for c in 0..nc {
                dst.row_mut(c, yo)[x] = sat16(rescale(div_round(acc[c], wsum), fs, fo));
            }
            if with_variance {
                // sum w^2 var / (sum w)^2: Q.32 * Q.fs over Q.32 -> Q.fs (the variance plane shares the input's format).
                let w2 = wsum as i128 * wsum as i128;
                let var = ((accv + w2 / 2) / w2) as i64;
                dst.row_mut(nc, yo)[x] = sat16(rescale(var, fs, fo));
                // The centre tap's normalised weight, 9/64 over the sum, in Q.16.
                let centre = div_round(9216i64 << 16, wsum);
                dst.row_mut(nc + 1, yo)[x] = sat16(rescale(centre, 16, fo));
            }
        }
    }
}

/// The B3 taps in Q.8 (`B3 * 256`, exact).
const B3_Q8: [i64; 5] = [16, 64, 96, 64, 16];

/// A term of the edge-stopping exponent at or above this (Q.8: 32 nats)
/// makes the tap's weight exactly 0 (`exp_q8` is 0 past about 11.8 nats), so
/// each term is capped here before it is summed: the sums stay in `i64` and
/// the weights do not change.
const TERM_CAP: i64 = 1 << 13;

/// The colour term is capped here (Q.8) before the others are added: the
/// exponent is clamped to `2^28` after the sum of non-negative terms, so
/// any colour term at or above `2^29` gives the same weight (0).
const COLOUR_CAP: i64 = 1 << 29;

/// The largest `x` worth multiplying by `inv` before a right shift by `s`:
/// from `x >= cap_for(inv, s)` on, `x * inv >> s >= TERM_CAP` (and the
/// product of the cap with `inv` stays below 2^62 for `s <= 48`).
fn cap_for(inv: i128, s: i32) -> i64 {
    if inv <= 0 {
        return i64::MAX;
    }
    ((((TERM_CAP as i128) << s.clamp(0, 48)) / inv) + 1).min(i64::MAX as i128) as i64
}

/// `v / 2^s` (floor) for `s >= 0`, `v * 2^-s` otherwise: [`sh`] in `i64`,
/// right shifts below 64 and left shifts of at most 60.
#[inline(always)]
fn shr(v: i64, s: i32) -> i64 {
    if s >= 0 {
        v >> s.min(63)
    } else {
        v << (-s).min(60)
    }
}

/// 2^52: integers below it are f64 values with this exponent (see [`to_f64`]).
const MAGIC: f64 = 4_503_599_627_370_496.0;

/// `v < 2^52` as f64, exactly: its bits under `MAGIC`'s exponent, less
/// `MAGIC`. Unlike `as`, integer and bit operations only, which vectorise
/// on AVX2 too.
#[inline(always)]
fn small_to_f64(v: u64) -> f64 {
    f64::from_bits(v | MAGIC.to_bits()) - MAGIC
}

/// `0 <= v < 2^63` as f64 with one rounding (two exact halves, one add).
#[inline(always)]
fn to_f64(v: i64) -> f64 {
    let v = v as u64;
    small_to_f64(v >> 32) * 4_294_967_296.0 + small_to_f64(v & 0xFFFF_FFFF)
}

/// `0 <= x < 2^51` rounded to the nearest integer (adding `MAGIC` rounds
/// at the units; the bits above it are the integer).
#[inline(always)]
fn round_to_i64(x: f64) -> i64 {
    ((x + MAGIC).to_bits() - MAGIC.to_bits()) as i64
}

/// `floor(num / den)` for `0 <= num < 2^62`, `0 < den < 2^62`, or `cap`
/// where that is larger (`0 <= cap <= 2^49`). With `FLOAT` (the SIMD
/// paths, where f64 division vectorises and integer division does not)
/// from the f64 quotient: its relative error is below `3 * 2^-53` (both
/// operands and the division rounded once), so below `cap + 1 <= 2^49` it
/// is within 0.19 of the exact quotient, its nearest integer is the floor
/// or one more, and the remainder's sign tells which; at or above `cap + 1`
/// the floor is at least `cap`. The same integer either way.
#[inline(always)]
fn div_floor_capped<const FLOAT: bool>(num: i64, den: i64, cap: i64) -> i64 {
    if FLOAT {
        let top = cap as f64 + 1.0;
        let qf = to_f64(num) / to_f64(den);
        let q = round_to_i64(qf.min(top));
        // Past the cap `q * den` may wrap; the result is then `cap` anyway.
        let r = num.wrapping_sub(q.wrapping_mul(den));
        let q = if r < 0 { q - 1 } else { q };
        if qf >= top {
            cap
        } else {
            q.min(cap)
        }
    } else {
        (num / den).min(cap)
    }
}

/// `num / den` truncated toward zero (`den > 0`, `|num| < 2^50`), as `i64`
/// division gives it.
#[inline(always)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))] // the SIMD rows only
fn div_trunc<const FLOAT: bool>(num: i64, den: i64) -> i64 {
    let q = div_floor_capped::<FLOAT>(num.abs(), den, i64::MAX >> 14);
    if num < 0 {
        -q
    } else {
        q
    }
}

/// [`div_round`] (half away from zero; `b > 0`, `|a| + b < 2^50`).
#[inline(always)]
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))] // the SIMD rows only
fn div_round_f<const FLOAT: bool>(a: i64, b: i64) -> i64 {
    let q = div_floor_capped::<FLOAT>(a.abs() + b / 2, b, i64::MAX >> 14);
    if a < 0 {
        -q
    } else {
        q
    }
}

/// Geometry of the `i64` step (const parameters of its tap weight).
const G_NONE: u8 = 0;
/// Normal and position: tangent-plane distances.
const G_PLANE: u8 = 1;
/// Position only.
const G_POS: u8 = 2;
/// Depth only.
const G_DEPTH: u8 = 3;

/// The `i64` step's constants, derived once per call.
struct Prep {
    hole: usize,
    nc: usize,
    fs: i32,
    fo: i32,
    /// The colour denominator: `shr(scale_q * v, den_shift) + eps_den`, Q.(2fs + 16).
    scale_q: i64,
    den_shift: i32,
    eps_den: i64,
    inv_n2: i64,
    cap_n: i64,
    /// The normal term's right shift, `2 fn + 8`.
    sn: i32,
    inv_geo: i64,
    cap_g: i64,
    inv_dist: i64,
    cap_d: i64,
    /// Shifts to 16 fractional bits: plane distances (`fn + fx - 16`) and
    /// position differences (`fx - 16`).
    s_pd: i32,
    s_d16: i32,
    normal: bool,
    geo: u8,
}

impl Prep {
    /// The constants, or `None` where the colour denominator's parameters or
    /// the formats do not fit the `i64` arithmetic ([`step_wide`] then).
    fn new(
        level: u32,
        groups: usize,
        p: &AtrousParams,
        g: &AtrousGuides<'_, i16>,
        src: &View<'_, i16>,
        dst: &ViewMut<'_, i16>,
    ) -> Option<Prep> {
        let hole = 1usize << level;
        let fs = src.frac() as i32;
        let fv = g.noise.frac() as i32;
        let scale_q = q16(p.phi_color / hole as f32);
        let eps_q = q16(p.eps);
        // The colour denominator at its largest (v = 32767), and the shifted
        // squared colour difference, must stay below 2^62.
        let den_max = sh(scale_q * 32767, fv - 2 * fs) + sh(eps_q, -2 * fs);
        let shifts_ok = (fv - 2 * fs) > -30 && 2 * fs < 30;
        if !(shifts_ok && den_max < (1i128 << 62) && scale_q < (1i128 << 46)) {
            return None;
        }
        let inv_n2 = q16(1.0 / (p.sigma_normal * p.sigma_normal));
        let geo = match (g.normal.is_some(), g.position.is_some(), g.depth.is_some()) {
            (true, true, _) => G_PLANE,
            (false, true, _) => G_POS,
            (_, false, true) => G_DEPTH,
            _ => G_NONE,
        };
        let inv_geo = match geo {
            G_PLANE => q16(1.0 / (p.sigma_plane * p.sigma_plane)),
            G_POS => q16(1.0 / ((p.sigma_plane * hole as f32) * (p.sigma_plane * hole as f32))),
            _ => q16(1.0 / ((p.sigma_depth * hole as f32) * (p.sigma_depth * hole as f32))),
        };
        let inv_dist =
            if geo == G_PLANE && p.sigma_distance > 0.0 { q16(1.0 / (p.sigma_distance * p.sigma_distance)) } else { 0 };
        let fnm = g.normal.as_ref().map_or(0, |n| n.frac() as i32);
        let fx = g.position.as_ref().map_or(0, |x| x.frac() as i32);
        // The geometry's left shifts must not overflow before their caps, and
        // the normal term's right shift must stay within `cap_for`'s range.
        if 2 * fnm + 8 > 48 || fnm + fx - 16 < -28 || fx - 16 < -40 {
            return None;
        }
        Some(Prep {
            hole,
            nc: 3 * groups,
            fs,
            fo: dst.frac() as i32,
            scale_q: scale_q as i64,
            den_shift: fv - 2 * fs,
            eps_den: sh(eps_q, -2 * fs) as i64,
            inv_n2: inv_n2.min(i64::MAX as i128) as i64,
            cap_n: cap_for(inv_n2, 2 * fnm + 8),
            sn: 2 * fnm + 8,
            inv_geo: inv_geo.min(i64::MAX as i128) as i64,
            cap_g: cap_for(inv_geo, 24),
            inv_dist: inv_dist.min(i64::MAX as i128) as i64,
            cap_d: cap_for(inv_dist, 24),
            s_pd: fnm + fx - 16,
            s_d16: fx - 16,
            normal: g.normal.is_some(),
            geo,
        })
    }

    /// A position difference at 16 fractional bits, capped so that three
    /// squares stay below 2^61 (past the cap every geometry term is capped).
    #[inline(always)]
    fn d16(&self, d: i64) -> i64 {
        shr(d, self.s_d16).clamp(-(1 << 29), 1 << 29)
    }
}

/// What a tap reads of one pixel (stored values, [`ld`] applied; the
/// guides a geometry does not use are left 0).
#[derive(Clone, Copy, Default)]
struct Px {
    g: [i64; 3],
    v: i64,
    n: [i64; 3],
    x: [i64; 3],
    z: i64,
}

/// The weight of tap `q` of pixel `p` in Q.16 (`h2`: the B3 product in
/// Q.16): the definition of the `i64` step, shared by the pixel loop and
/// the row loops.
#[inline(always)]
fn weight<const FLOAT: bool, const N: bool, const G: u8>(k: &Prep, p: &Px, q: &Px, h2: i64) -> i64 {
    let mut dc = 0i64;
    for c in 0..3 {
        let d = p.g[c] - q.g[c];
        dc += d * d;
    }
    let v = p.v.min(q.v).max(0); // negative variance counts as 0
    let den = shr(k.scale_q * v, k.den_shift) + k.eps_den;
    // Colour: |g_p - g_q|^2 (Q.2fs) over the denominator (Q.(2fs + 16)), as Q.8.
    let mut t8 = if den > 0 {
        div_floor_capped::<FLOAT>(dc << 24, den.max(1), COLOUR_CAP)
    } else if dc > 0 {
        COLOUR_CAP
    } else {
        0
    };
    if N {
        let mut dn = 0i64;
        for c in 0..3 {
            let d = p.n[c] - q.n[c];
            dn += d * d;
        }
        t8 += shr(dn.min(k.cap_n) * k.inv_n2, k.sn);
    }
    if G == G_PLANE || G == G_POS {
        let d: [i64; 3] = core::array::from_fn(|c| q.x[c] - p.x[c]);
        let gd = if G == G_PLANE {
            // Both pixels' tangent-plane distances at 16 fractional bits,
            // their squares averaged.
            let mut pd = 0i64;
            let mut qd = 0i64;
            for c in 0..3 {
                pd += p.n[c] * d[c];
                qd += q.n[c] * d[c];
            }
            let pd16 = shr(pd, k.s_pd).clamp(-(1 << 30), 1 << 30);
            let qd16 = shr(qd, k.s_pd).clamp(-(1 << 30), 1 << 30);
            let e: i64 = d.iter().map(|&v| k.d16(v) * k.d16(v)).sum();
            // `inv_dist` is 0 when the distance term is off (and its cap i64::MAX).
            t8 += shr(shr(e, 16).min(k.cap_d) * k.inv_dist, 24);
            shr(pd16 * pd16 + qd16 * qd16, 17)
        } else {
            shr(d.iter().map(|&v| k.d16(v) * k.d16(v)).sum::<i64>(), 16)
        };
        t8 += shr(gd.min(k.cap_g) * k.inv_geo, 24);
    } else if G == G_DEPTH {
        // (zq - zp)^2 / (zp zq) in Q.16 (depths clamped to one unit).
        let zp = p.z.max(1);
        let zq = q.z.max(1);
        let r2 = div_floor_capped::<FLOAT>((zq - zp).pow(2) << 16, zp * zq, i64::MAX >> 14);
        t8 += shr(r2.min(k.cap_g) * k.inv_geo, 24);
    }
    let t8 = t8.clamp(0, 1 << 28) as i32;
    (h2 * exp_q8(-t8) as i64) >> 16 // Q.16
}

/// Calls `$f::<N, G>` for the step's normal and geometry.
macro_rules! dispatch {
    ($k:expr, $f:ident, $args:tt) => {
        match ($k.normal, $k.geo) {
            (false, G_NONE) => dispatch!(@call $f, false, G_NONE, $args),
            (true, G_NONE) => dispatch!(@call $f, true, G_NONE, $args),
            // The plane geometry comes with normals, the position one without.
            (_, G_PLANE) => dispatch!(@call $f, true, G_PLANE, $args),
            (_, G_POS) => dispatch!(@call $f, false, G_POS, $args),
            (false, _) => dispatch!(@call $f, false, G_DEPTH, $args),
            (true, _) => dispatch!(@call $f, true, G_DEPTH, $args),
        }
    };
    (@call $f:ident, $n:expr, $g:expr, ($($a:expr),*)) => {
        $f::<$n, $g>($($a),*)
    };
}

/// One à-trous step in fixed point: [`step_wide`]'s arithmetic, bit for bit,
/// in `i64` (the geometry terms capped at [`TERM_CAP`] before they could
/// overflow), when the colour denominator's parameters fit; else
/// [`step_wide`]. On AVX2 and AVX-512 by rows ([`rows`]: the same bits).
#[allow(clippy::too_many_arguments)]
pub(crate) fn step(
    isa: crate::isa::Supported,
    level: u32,
    groups: usize,
    with_variance: bool,
    p: &AtrousParams,
    g: &AtrousGuides<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    let Some(k) = Prep::new(level, groups, p, g, src, dst) else {
        return step_wide(level, groups, with_variance, p, g, src, dst, y0);
    };
    #[cfg(target_arch = "x86_64")]
    if isa.isa() != crate::Isa::Scalar {
        return rows::step(isa, &k, with_variance, g, src, dst, y0);
    }
    let _ = isa;
    dispatch!(k, pixels, (&k, with_variance, g, src, dst, y0))
}

/// A pixel's guides as a tap reads them.
#[inline(always)]
fn px<const N: bool, const G: u8>(g: &AtrousGuides<'_, i16>, src: &View<'_, i16>, y: usize, x: usize) -> Px {
    let mut p = Px { g: core::array::from_fn(|c| at(src, c, y, x)), v: at(&g.noise, 0, y, x), ..Px::default() };
    if N {
        let n = g.normal.as_ref().expect("normal");
        p.n = core::array::from_fn(|c| at(n, c, y, x));
    }
    if G == G_PLANE || G == G_POS {
        let pos = g.position.as_ref().expect("position");
        p.x = core::array::from_fn(|c| at(pos, c, y, x));
    } else if G == G_DEPTH {
        p.z = at(g.depth.as_ref().expect("depth"), 0, y, x);
    }
    p
}

/// The portable step: pixel by pixel, integer divisions.
fn pixels<const N: bool, const G: u8>(
    k: &Prep,
    with_variance: bool,
    g: &AtrousGuides<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    let (w, h) = (src.width(), src.height());
    let (hole, nc, fs, fo) = (k.hole, k.nc, k.fs, k.fo);
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for x in 0..w {
            let pp = px::<N, G>(g, src, y, x);
            let mut wsum = 0i64;
            let mut acc = [0i64; 6];
            let mut accv = 0i64;
            for dy in 0..5 {
                let Some(qy) = (y + dy * hole).checked_sub(2 * hole).filter(|&v| v < h) else { continue };
                for dx in 0..5 {
                    let Some(qx) = (x + dx * hole).checked_sub(2 * hole).filter(|&v| v < w) else { continue };
                    let qq = px::<N, G>(g, src, qy, qx);
                    let wt = weight::<false, N, G>(k, &pp, &qq, B3_Q8[dy] * B3_Q8[dx]);
                    wsum += wt;
                    for (c, a) in acc.iter_mut().enumerate().take(nc) {
                        *a += wt * at(src, c, qy, qx);
                    }
                    if with_variance {
                        accv += (wt * wt) * at(src, nc, qy, qx);
                    }
                }
            }
            let wsum = wsum.max(1);
            for c in 0..nc {
                dst.row_mut(c, yo)[x] = sat16(rescale(div_round(acc[c], wsum), fs, fo));
            }
            if with_variance {
                let w2 = wsum * wsum;
                let var = (accv + w2 / 2) / w2;
                dst.row_mut(nc, yo)[x] = sat16(rescale(var, fs, fo));
                let centre = div_round(9216i64 << 16, wsum);
                dst.row_mut(nc + 1, yo)[x] = sat16(rescale(centre, 16, fo));
            }
        }
    }
}

/// The step by rows for AVX2 and AVX-512: per output row, strips of
/// [`rows::STRIP`] columns; per tap, the weights of the strip's pixels in
/// one loop that vectorises (f64 divisions corrected to the integer
/// quotients, [`div_floor_capped`]), then per channel the weighted sums.
/// Integer sums are exact, so the order does not change them: the same
/// bits as [`pixels`].
#[cfg(target_arch = "x86_64")]
mod rows {
    use super::*;

    /// Columns per strip (the accumulators live on the stack: 10 KiB).
    pub(super) const STRIP: usize = 256;

    pub(super) fn step(
        isa: crate::isa::Supported,
        k: &Prep,
        with_variance: bool,
        g: &AtrousGuides<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
    ) {
        match isa.isa() {
            // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
            crate::Isa::Avx512 => unsafe { avx512(k, with_variance, g, src, dst, y0) },
            // SAFETY: as above.
            _ => unsafe { avx2(k, with_variance, g, src, dst, y0) },
        }
    }

    #[target_feature(enable = "avx2,fma")]
    unsafe fn avx2(
        k: &Prep,
        with_variance: bool,
        g: &AtrousGuides<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
    ) {
        dispatch!(k, body, (k, with_variance, g, src, dst, y0))
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
    unsafe fn avx512(
        k: &Prep,
        with_variance: bool,
        g: &AtrousGuides<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
    ) {
        dispatch!(k, body, (k, with_variance, g, src, dst, y0))
    }

    /// Row `y`, columns `x ..x + n`, of every plane a tap reads (the absent
    /// guides' rows are the colour's, never read).
    #[derive(Clone, Copy)]
    struct Rows<'a> {
        g: [&'a [i16]; 3],
        v: &'a [i16],
        n: [&'a [i16]; 3],
        x: [&'a [i16]; 3],
        z: &'a [i16],
    }

    #[inline(always)]
    fn rows_at<'a>(g: &AtrousGuides<'a, i16>, src: &View<'a, i16>, y: usize, x: usize, n: usize) -> Rows<'a> {
        let r = |v: &View<'a, i16>, c: usize| &v.row(c, y)[x..x + n];
        let gr: [&[i16]; 3] = core::array::from_fn(|c| r(src, c));
        Rows {
            g: gr,
            v: r(&g.noise, 0),
            n: g.normal.as_ref().map_or(gr, |v| core::array::from_fn(|c| r(v, c))),
            x: g.position.as_ref().map_or(gr, |v| core::array::from_fn(|c| r(v, c))),
            z: g.depth.as_ref().map_or(gr[0], |v| r(v, 0)),
        }
    }

    #[inline(always)]
    fn lane<const N: bool, const G: u8>(r: &Rows<'_>, i: usize) -> Px {
        let l = |s: &[i16]| ld(s[i]) as i64;
        let mut p = Px { g: [l(r.g[0]), l(r.g[1]), l(r.g[2])], v: l(r.v), ..Px::default() };
        if N {
            p.n = [l(r.n[0]), l(r.n[1]), l(r.n[2])];
        }
        if G == G_PLANE || G == G_POS {
            p.x = [l(r.x[0]), l(r.x[1]), l(r.x[2])];
        } else if G == G_DEPTH {
            p.z = l(r.z);
        }
        p
    }

    /// `sat16(rescale(v, from, to))` of a row (the common right shift in a
    /// loop that vectorises).
    #[inline(always)]
    fn store(out: &mut [i16], q: &[i32], from: i32, to: i32) {
        let s = from - to;
        if (1..31).contains(&s) {
            let half = 1i64 << (s - 1);
            for (o, &v) in out.iter_mut().zip(q) {
                *o = sat16((v as i64 + half) >> s);
            }
        } else {
            for (o, &v) in out.iter_mut().zip(q) {
                *o = sat16(rescale(v as i64, from, to));
            }
        }
    }

    #[inline(always)]
    fn body<const N: bool, const G: u8>(
        k: &Prep,
        with_variance: bool,
        g: &AtrousGuides<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
    ) {
        let (w, h) = (src.width(), src.height());
        let (hole, nc, fs, fo) = (k.hole, k.nc, k.fs, k.fo);
        // Sums of weights and of weighted values are exact in `i32`: the
        // weights of a pixel sum to at most 65536 (the B3 products do, and
        // `exp_q8 <= 1`), the values are at most 32767 in magnitude.
        let mut wt = [0i32; STRIP];
        let mut wsum = [0i32; STRIP];
        let mut acc = [[0i32; STRIP]; 6];
        let mut accv = [0i64; STRIP];
        for yo in 0..dst.height() {
            let y = y0 + yo;
            let mut x0 = 0;
            while x0 < w {
                let x1 = (x0 + STRIP).min(w);
                let n = x1 - x0;
                wsum[..n].fill(0);
                for a in acc.iter_mut().take(nc) {
                    a[..n].fill(0);
                }
                accv[..n].fill(0);
                for dy in 0..5 {
                    let Some(qy) = (y + dy * hole).checked_sub(2 * hole).filter(|&v| v < h) else { continue };
                    for dx in 0..5 {
                        // Columns of the strip whose tap `x + off` is inside the image.
                        let off = (dx * hole) as isize - (2 * hole) as isize;
                        let xa = (x0 as isize).max(-off) as usize;
                        let xb = (x1 as isize).min(w as isize - off);
                        if xb <= xa as isize {
                            continue;
                        }
                        let m = xb as usize - xa;
                        let xq = (xa as isize + off) as usize;
                        let (rp, rq) = (rows_at(g, src, y, xa, m), rows_at(g, src, qy, xq, m));
                        let h2 = B3_Q8[dy] * B3_Q8[dx];
                        let wt = &mut wt[..m];
                        for i in 0..m {
                            let (pp, qq) = (lane::<N, G>(&rp, i), lane::<N, G>(&rq, i));
                            wt[i] = weight::<true, N, G>(k, &pp, &qq, h2) as i32;
                        }
                        let i0 = xa - x0;
                        for (s, &v) in wsum[i0..i0 + m].iter_mut().zip(wt.iter()) {
                            *s += v;
                        }
                        for (c, a) in acc.iter_mut().enumerate().take(nc) {
                            let q = &src.row(c, qy)[xq..xq + m];
                            for ((s, &v), &qv) in a[i0..i0 + m].iter_mut().zip(wt.iter()).zip(q) {
                                *s += v * ld(qv);
                            }
                        }
                        if with_variance {
                            let q = &src.row(nc, qy)[xq..xq + m];
                            for ((s, &v), &qv) in accv[i0..i0 + m].iter_mut().zip(wt.iter()).zip(q) {
                                *s += (v * v) as i64 * ld(qv) as i64;
                            }
                        }
                    }
                }
                // The normalisation in loops that vectorise: the quotients,
                // then their format.
                let q = &mut wt[..n];
                for c in 0..nc {
                    for ((o, &a), &s) in q.iter_mut().zip(&acc[c][..n]).zip(&wsum[..n]) {
                        *o = div_round_f::<true>(a as i64, s.max(1) as i64) as i32;
                    }
                    store(&mut dst.row_mut(c, yo)[x0..x1], q, fs, fo);
                }
                if with_variance {
                    for ((o, &a), &s) in q.iter_mut().zip(&accv[..n]).zip(&wsum[..n]) {
                        let w2 = s.max(1) as i64 * s.max(1) as i64;
                        // At most the largest variance (32767): sum w^2 v <= (sum w)^2 max v.
                        *o = div_trunc::<true>(a + w2 / 2, w2) as i32;
                    }
                    store(&mut dst.row_mut(nc, yo)[x0..x1], q, fs, fo);
                    for (o, &s) in q.iter_mut().zip(&wsum[..n]) {
                        *o = div_round_f::<true>(9216i64 << 16, s.max(1) as i64) as i32;
                    }
                    store(&mut dst.row_mut(nc + 1, yo)[x0..x1], q, 16, fo);
                }
                x0 = x1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;

    fn random(n: usize, lo: i32, hi: i32, seed: &mut u64) -> Vec<i16> {
        (0..n)
            .map(|_| {
                *seed ^= *seed << 13;
                *seed ^= *seed >> 7;
                *seed ^= *seed << 17;
                (lo + (*seed % (hi - lo + 1) as u64) as i32) as i16
            })
            .collect()
    }

    /// The `i64` step against the `i128` one, bit for bit, over levels, guide
    /// sets, groups, the variance plane, formats and parameters that reach
    /// the geometry caps.
    #[test]
    fn the_q8_taps_are_b3() {
        for (a, &b) in B3_Q8.iter().zip(&B3) {
            assert_eq!(*a as f32, b * 256.0);
        }
    }

    /// The `i64` step (pixel by pixel, and by rows on each SIMD instruction
    /// set this CPU has) against the `i128` one, bit for bit, over levels,
    /// guide sets, groups, the variance plane, formats, parameters that
    /// reach the geometry caps, and rows wider than a strip.
    #[test]
    fn the_i64_step_is_the_i128_step() {
        let isas: Vec<_> = [crate::Isa::Scalar, crate::Isa::Avx2, crate::Isa::Avx512]
            .into_iter()
            .filter_map(|i| i.check().ok())
            .collect();
        let mut seed = 0x1234_5678_9abc_def1u64;
        for case in 0..24 {
            let (w, h) = if case % 5 == 4 { (300usize, 7usize) } else { (23, 19) };
            let n = w * h;
            let (fs, fv, fnm, fx) = [(12, 10, 14, 8), (9, 14, 14, 2), (14, 6, 13, -4), (4, 12, 14, 12)][case % 4];
            let groups = 1 + case % 2;
            let with_variance = case % 3 == 0;
            let nc = 3 * groups + usize::from(with_variance);
            let src = random(nc * n, -3000, 32767, &mut seed);
            let noise = random(n, -50, 4000, &mut seed);
            let normal = random(3 * n, -16384, 16384, &mut seed);
            let position = random(3 * n, -32767, 32767, &mut seed);
            let depth = random(n, 0, 32767, &mut seed);
            let sv = View::new(&src, nc, w, h).unwrap().with_frac(fs);
            let nv = View::new(&noise, 1, w, h).unwrap().with_frac(fv);
            let normal_v = View::new(&normal, 3, w, h).unwrap().with_frac(fnm);
            let pos_v = View::new(&position, 3, w, h).unwrap().with_frac(fx);
            let depth_v = View::new(&depth, 1, w, h).unwrap().with_frac(fx);
            let guides = [
                AtrousGuides { noise: nv, normal: Some(normal_v), position: Some(pos_v), depth: None },
                AtrousGuides { noise: nv, normal: None, position: Some(pos_v), depth: None },
                AtrousGuides { noise: nv, normal: None, position: None, depth: Some(depth_v) },
                AtrousGuides { noise: nv, normal: Some(normal_v), position: None, depth: None },
                AtrousGuides { noise: nv, normal: Some(normal_v), position: None, depth: Some(depth_v) },
                AtrousGuides { noise: nv, normal: None, position: None, depth: None },
            ];
            let params = [
                AtrousParams::default(),
                AtrousParams { sigma_distance: 0.05, ..AtrousParams::default() },
                AtrousParams {
                    phi_color: 0.5,
                    sigma_normal: 0.01,
                    sigma_plane: 1.0e-4,
                    eps: 0.0,
                    ..AtrousParams::default()
                },
                AtrousParams {
                    phi_color: 4000.0,
                    sigma_normal: 3.0,
                    sigma_plane: 10.0,
                    sigma_depth: 1.0e-3,
                    ..AtrousParams::default()
                },
            ];
            for g in &guides {
                for p in &params {
                    for level in [0, 2, 4] {
                        let oc = 3 * groups + 2 * usize::from(with_variance);
                        let mut b = std::vec![1i16; oc * n];
                        let mut bv = ViewMut::new(&mut b, oc, w, h).unwrap().with_frac(fs - 1);
                        step_wide(level, groups, with_variance, p, g, &sv, &mut bv, 0);
                        for &isa in &isas {
                            let mut a = std::vec![0i16; oc * n];
                            let mut av = ViewMut::new(&mut a, oc, w, h).unwrap().with_frac(fs - 1);
                            // In two bands, so that a band's first row is not the image's.
                            let (mut top, mut bottom) = av.reborrow().split_rows_at(h / 2);
                            step(isa, level, groups, with_variance, p, g, &sv, &mut top, 0);
                            step(isa, level, groups, with_variance, p, g, &sv, &mut bottom, h / 2);
                            assert_eq!(a, b, "case {case} level {level} {isa:?} {p:?}");
                        }
                    }
                }
            }
        }
    }

    /// The f64 quotient corrected to the integer one, at the edges of its
    /// range: near the cap, exact multiples, the largest numerators.
    #[test]
    fn float_division_is_integer_division() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..200_000 {
            let den = (next() >> (2 + next() % 62)).max(1) as i64;
            let num = (next() >> (6 + next() % 58)) as i64;
            let caps = [COLOUR_CAP, i64::MAX >> 14, num / den, (num / den).saturating_sub(1).max(0)];
            // The caps the callers use are at most 2^49.
            for cap in caps.map(|c| c.min(i64::MAX >> 14)) {
                for nm in [num, (num / den) * den, ((num / den) * den).saturating_sub(1).max(0)] {
                    assert_eq!(
                        div_floor_capped::<true>(nm, den, cap),
                        div_floor_capped::<false>(nm, den, cap),
                        "{nm} / {den} cap {cap}"
                    );
                }
            }
            let a = (next() >> 14) as i64 - (1 << 49);
            let b = (next() >> 30).max(1) as i64;
            assert_eq!(div_round_f::<true>(a, b), div_round(a, b));
            assert_eq!(div_trunc::<true>(a, b), a / b);
        }
    }
}

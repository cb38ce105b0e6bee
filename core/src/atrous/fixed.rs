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

/// The largest `x` worth multiplying by `inv` before a right shift by `s`:
/// from `x >= cap_for(inv, s)` on, `x * inv >> s >= TERM_CAP` (and the
/// product of the cap with `inv` stays below 2^62 for `s <= 48`).
fn cap_for(inv: i128, s: i32) -> i64 {
    if inv <= 0 {
        return i64::MAX;
    }
    ((((TERM_CAP as i128) << s.clamp(0, 48)) / inv) + 1).min(i64::MAX as i128) as i64
}

/// One à-trous step in fixed point: [`step_wide`]'s arithmetic, bit for bit,
/// in `i64` (an `i64` division per tap instead of an `i128` one, the
/// geometry terms capped at [`TERM_CAP`] before they could overflow), when
/// the colour denominator's parameters fit; else [`step_wide`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn step(
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
    let scale_q = q16(p.phi_color / hole as f32);
    let eps_q = q16(p.eps);
    // The colour denominator at its largest (v = 32767), and the shifted
    // squared colour difference, must stay below 2^62.
    let den_max = sh(scale_q * 32767, fv - 2 * fs) + sh(eps_q, -2 * fs);
    let shifts_ok = (fv - 2 * fs) > -30 && 2 * fs < 30;
    if !(shifts_ok && den_max < (1i128 << 62) && scale_q < (1i128 << 46)) {
        return step_wide(level, groups, with_variance, p, g, src, dst, y0);
    }
    let (scale_q, eps_den) = (scale_q as i64, sh(eps_q, -2 * fs) as i64);
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
    let inv_dist =
        if geo_plane && p.sigma_distance > 0.0 { q16(1.0 / (p.sigma_distance * p.sigma_distance)) } else { 0 };
    let fnm = g.normal.as_ref().map_or(0, |n| n.frac() as i32);
    let fx = g.position.as_ref().map_or(0, |x| x.frac() as i32);
    // The geometry's left shifts must not overflow before their caps, and
    // the normal term's right shift must stay within `cap_for`'s range.
    if 2 * fnm + 8 > 48 || fnm + fx - 16 < -28 || fx - 16 < -40 {
        return step_wide(level, groups, with_variance, p, g, src, dst, y0);
    }
    let cap_n = cap_for(inv_n2, 2 * fnm + 8);
    let (cap_g, cap_d) = (cap_for(inv_geo, 24), cap_for(inv_dist, 24));
    let (inv_n2, inv_geo, inv_dist) = (
        inv_n2.min(i64::MAX as i128) as i64,
        inv_geo.min(i64::MAX as i128) as i64,
        inv_dist.min(i64::MAX as i128) as i64,
    );
    // Right shifts below 64 as in `sh` (a left shift by at most 60 there).
    let shr = |v: i64, s: i32| -> i64 {
        if s >= 0 {
            v >> s.min(63)
        } else {
            v << (-s).min(60)
        }
    };
    // A position difference at 16 fractional bits, capped so that three
    // squares stay below 2^61 (past the cap every geometry term is capped).
    let d16 = |d: i64| shr(d, fx - 16).clamp(-(1 << 29), 1 << 29);
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for x in 0..w {
            let gp = [at(src, 0, y, x), at(src, 1, y, x), at(src, 2, y, x)];
            let vp = at(&g.noise, 0, y, x);
            let mut wsum = 0i64;
            let mut acc = [0i64; 6];
            let mut accv = 0i64;
            for dy in 0..5 {
                let Some(qy) = (y + dy * hole).checked_sub(2 * hole).filter(|&v| v < h) else { continue };
                for dx in 0..5 {
                    let Some(qx) = (x + dx * hole).checked_sub(2 * hole).filter(|&v| v < w) else { continue };
                    let mut dc = 0i64;
                    for c in 0..3 {
                        let d = gp[c] - at(src, c, qy, qx);
                        dc += d * d;
                    }
                    let v = vp.min(at(&g.noise, 0, qy, qx)).max(0);
                    let den = shr(scale_q * v, fv - 2 * fs) + eps_den;
                    let mut t8: i64 = if den > 0 {
                        (dc << 24) / den
                    } else if dc > 0 {
                        1 << 40
                    } else {
                        0
                    };
                    if let Some(n) = &g.normal {
                        let mut dn = 0i64;
                        for c in 0..3 {
                            let d = at(n, c, y, x) - at(n, c, qy, qx);
                            dn += d * d;
                        }
                        t8 += shr(dn.min(cap_n) * inv_n2, 2 * fnm + 8);
                    }
                    if geo_plane || geo_pos {
                        let pos = g.position.as_ref().expect("position");
                        let d: [i64; 3] = core::array::from_fn(|c| at(pos, c, qy, qx) - at(pos, c, y, x));
                        let gd = if geo_plane {
                            let n = g.normal.as_ref().expect("normal");
                            let mut pd = 0i64;
                            let mut qd = 0i64;
                            for c in 0..3 {
                                pd += at(n, c, y, x) * d[c];
                                qd += at(n, c, qy, qx) * d[c];
                            }
                            let (pd16, qd16) = (
                                shr(pd, fnm + fx - 16).clamp(-(1 << 30), 1 << 30),
                                shr(qd, fnm + fx - 16).clamp(-(1 << 30), 1 << 30),
                            );
                            if inv_dist > 0 {
                                let e: i64 = d.iter().map(|&v| d16(v) * d16(v)).sum();
                                t8 += shr(shr(e, 16).min(cap_d) * inv_dist, 24);
                            }
                            shr(pd16 * pd16 + qd16 * qd16, 17)
                        } else {
                            shr(d.iter().map(|&v| d16(v) * d16(v)).sum::<i64>(), 16)
                        };
                        t8 += shr(gd.min(cap_g) * inv_geo, 24);
                    } else if geo_depth {
                        let dz = g.depth.as_ref().expect("depth");
                        let zp = at(dz, 0, y, x).max(1);
                        let zq = at(dz, 0, qy, qx).max(1);
                        let r2 = ((zq - zp).pow(2) << 16) / (zp * zq);
                        t8 += shr(r2.min(cap_g) * inv_geo, 24);
                    }
                    let t8 = t8.clamp(0, 1 << 28) as i32;
                    let h2 = B3_Q8[dy] * B3_Q8[dx]; // B3[dy] B3[dx] in Q.16, exactly
                    let wt = (h2 * exp_q8(-t8) as i64) >> 16; // Q.16
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

    #[test]
    fn the_i64_step_is_the_i128_step() {
        let (w, h) = (23usize, 19usize);
        let n = w * h;
        let mut seed = 0x1234_5678_9abc_def1u64;
        for case in 0..24 {
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
                        let mut a = std::vec![0i16; oc * n];
                        let mut b = std::vec![1i16; oc * n];
                        let mut av = ViewMut::new(&mut a, oc, w, h).unwrap().with_frac(fs - 1);
                        let mut bv = ViewMut::new(&mut b, oc, w, h).unwrap().with_frac(fs - 1);
                        step(level, groups, with_variance, p, g, &sv, &mut av, 0);
                        step_wide(level, groups, with_variance, p, g, &sv, &mut bv, 0);
                        assert_eq!(a, b, "case {case} level {level} {p:?}");
                    }
                }
            }
        }
    }
}

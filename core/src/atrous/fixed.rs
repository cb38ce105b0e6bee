//! The à-trous step in fixed point (integer only). The edge-stopping
//! exponent is assembled in Q.8 from the colour, normal and geometry terms
//! (products in `i128`, so no format combination overflows), the weight is
//! `h * exp_q8(-t)` in Q.16, sums are exact `i64`, ratios are rounded
//! integer divisions. See [`super`] for the definition.

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

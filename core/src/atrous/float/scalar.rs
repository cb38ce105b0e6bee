//! Portable à-trous step, pixel by pixel: taps row-major, out-of-image taps
//! left out, one `exp` per tap of the summed edge-stopping terms.

use super::{h2, Ctx, Geometry};
use crate::math::scalar::exp;
use crate::precision::FloatElement;
use crate::view::ViewMut;

/// Most values a pixel produces: 6 colour channels, variance, centre weight.
pub(crate) const MAX_OUT: usize = 8;

/// One output pixel into `out` (`3 * groups` colours, then variance and centre weight).
pub(crate) fn pixel<S: FloatElement>(c: &Ctx<'_, '_, S>, y: usize, x: usize, out: &mut [f32; MAX_OUT]) {
    let src = c.src;
    let (w, h) = (src.width(), src.height());
    let nc = 3 * c.groups;
    let inv_g = 1.0 / c.groups as f32;
    let guide = |yy: usize, xx: usize, ch: usize| {
        let mut s = 0.0;
        for g in 0..c.groups {
            s += src.at(3 * g + ch, yy, xx).to_f32();
        }
        s * inv_g
    };
    let gp = [guide(y, x, 0), guide(y, x, 1), guide(y, x, 2)];
    let vp = c.guides.noise.at(0, y, x).to_f32();
    let v3 = |v: &crate::view::View<'_, S>, yy: usize, xx: usize| {
        [v.at(0, yy, xx).to_f32(), v.at(1, yy, xx).to_f32(), v.at(2, yy, xx).to_f32()]
    };
    let np = c.guides.normal.as_ref().map(|n| v3(n, y, x)).unwrap_or([0.0; 3]);
    let xp = c.guides.position.as_ref().map(|p| v3(p, y, x)).unwrap_or([0.0; 3]);
    let zp = c.guides.depth.as_ref().map(|d| d.at(0, y, x).to_f32()).unwrap_or(0.0);
    let inv_zp = 1.0 / if zp > 1e-20 { zp } else { 1e-20 };
    let mut wsum = 0.0f32;
    let mut acc = [0.0f32; 6];
    let mut accv = 0.0f32;
    for dy in 0..5 {
        let Some(qy) = (y + dy * c.hole).checked_sub(2 * c.hole).filter(|&v| v < h) else { continue };
        for dx in 0..5 {
            let Some(qx) = (x + dx * c.hole).checked_sub(2 * c.hole).filter(|&v| v < w) else { continue };
            let mut dc = 0.0f32;
            for ch in 0..3 {
                let d = gp[ch] - guide(qy, qx, ch);
                dc += d * d;
            }
            // The smaller noise of the two pixels: a noisy pixel (say, on a
            // partially covered light edge) does not open the gate to clean ones.
            let vq = c.guides.noise.at(0, qy, qx).to_f32();
            let v = if vq < vp { vq } else { vp };
            let mut t = dc / (c.color_scale * v + c.eps);
            if let Some(n) = &c.guides.normal {
                let nq = v3(n, qy, qx);
                let dn = (np[0] - nq[0]) * (np[0] - nq[0])
                    + (np[1] - nq[1]) * (np[1] - nq[1])
                    + (np[2] - nq[2]) * (np[2] - nq[2]);
                t += dn * c.inv_normal2;
            }
            match c.geometry {
                Geometry::Plane | Geometry::Position => {
                    let xq = v3(c.guides.position.as_ref().expect("position"), qy, qx);
                    let d = [xq[0] - xp[0], xq[1] - xp[1], xq[2] - xp[2]];
                    let g = if c.geometry == Geometry::Plane {
                        let pd = np[0] * d[0] + np[1] * d[1] + np[2] * d[2];
                        pd * pd
                    } else {
                        d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                    };
                    t += g * c.inv_geom2;
                }
                Geometry::Depth => {
                    let zq = c.guides.depth.as_ref().expect("depth").at(0, qy, qx).to_f32();
                    let r = (zq - zp) * inv_zp;
                    t += r * r * c.inv_geom2;
                }
                Geometry::None => {}
            }
            let wt = h2(dy, dx) * exp(-t);
            wsum += wt;
            for (ch, a) in acc.iter_mut().enumerate().take(nc) {
                *a += wt * src.at(ch, qy, qx).to_f32();
            }
            if c.with_variance {
                accv += wt * wt * src.at(nc, qy, qx).to_f32();
            }
        }
    }
    // The centre tap contributes 9/64 (all terms are exactly 0 there).
    let inv = 1.0 / wsum;
    for ch in 0..nc {
        out[ch] = acc[ch] * inv;
    }
    if c.with_variance {
        out[nc] = accv * inv * inv;
        out[nc + 1] = h2(2, 2) * inv;
    }
}

pub(crate) fn step<S: FloatElement>(c: &Ctx<'_, '_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let mut out = [0.0f32; MAX_OUT];
    let n = dst.channels();
    for yo in 0..dst.height() {
        for x in 0..dst.width() {
            pixel(c, y0 + yo, x, &mut out);
            for (ch, &v) in out.iter().enumerate().take(n) {
                dst.row_mut(ch, yo)[x] = S::from_f32(v);
            }
        }
    }
}

//! Portable à-trous step, pixel by pixel: taps row-major, out-of-image taps
//! left out, one `exp` per tap of the summed edge-stopping terms. Generic
//! over the arithmetic `A`.

use super::{h2, Ctx, Geometry};
use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};

/// Most values a pixel produces: 6 colour channels, variance, centre weight.
pub(crate) const MAX_OUT: usize = 8;

#[inline(always)]
fn at<S: FloatElement, A: Real>(v: &View<'_, S>, c: usize, y: usize, x: usize) -> A {
    A::of(v.at(c, y, x).to_f32())
}

#[inline(always)]
fn v3<S: FloatElement, A: Real>(v: &View<'_, S>, y: usize, x: usize) -> [A; 3] {
    [at(v, 0, y, x), at(v, 1, y, x), at(v, 2, y, x)]
}

/// One output pixel into `out` (`3 * groups` colours, then variance and centre weight).
pub(crate) fn pixel<S: FloatElement, A: Real>(c: &Ctx<'_, '_, S>, y: usize, x: usize, out: &mut [f32; MAX_OUT]) {
    let src = c.src;
    let (w, h) = (src.width(), src.height());
    let nc = 3 * c.groups;
    // The colour guide is the first image.
    let guide = |yy: usize, xx: usize, ch: usize| at::<S, A>(src, ch, yy, xx);
    let gp = [guide(y, x, 0), guide(y, x, 1), guide(y, x, 2)];
    let vp: A = at(&c.guides.noise, 0, y, x);
    let np = c.guides.normal.as_ref().map(|n| v3::<S, A>(n, y, x)).unwrap_or([A::ZERO; 3]);
    let xp = c.guides.position.as_ref().map(|p| v3::<S, A>(p, y, x)).unwrap_or([A::ZERO; 3]);
    let zp: A = c.guides.depth.as_ref().map(|d| at(d, 0, y, x)).unwrap_or(A::ZERO);
    let zp_safe = if zp > A::of(1e-20) { zp } else { A::of(1e-20) };
    let (scale, eps) = (A::of(c.color_scale), A::of(c.eps));
    let (inv_n2, inv_geo) = (A::of(c.inv_normal2), A::of(c.inv_geom2));
    let mut wsum = A::ZERO;
    let mut acc = [A::ZERO; 6];
    let mut accv = A::ZERO;
    for dy in 0..5 {
        let Some(qy) = (y + dy * c.hole).checked_sub(2 * c.hole).filter(|&v| v < h) else { continue };
        for dx in 0..5 {
            let Some(qx) = (x + dx * c.hole).checked_sub(2 * c.hole).filter(|&v| v < w) else { continue };
            let mut dc = A::ZERO;
            for ch in 0..3 {
                let d = gp[ch] - guide(qy, qx, ch);
                dc += d * d;
            }
            // The smaller noise of the two pixels: a noisy pixel (say, on a
            // partially covered light edge) does not open the gate to clean ones.
            let vq: A = at(&c.guides.noise, 0, qy, qx);
            let v = if vq < vp { vq } else { vp };
            // A negative variance counts as 0.
            let v = if v > A::ZERO { v } else { A::ZERO };
            let mut t = dc / (scale * v + eps);
            if let Some(n) = &c.guides.normal {
                let nq = v3::<S, A>(n, qy, qx);
                let mut dn = A::ZERO;
                for k in 0..3 {
                    dn += (np[k] - nq[k]) * (np[k] - nq[k]);
                }
                t += dn * inv_n2;
            }
            match c.geometry {
                Geometry::Plane | Geometry::Position => {
                    let xq = v3::<S, A>(c.guides.position.as_ref().expect("position"), qy, qx);
                    let d = [xq[0] - xp[0], xq[1] - xp[1], xq[2] - xp[2]];
                    let g = if c.geometry == Geometry::Plane {
                        let nq = v3::<S, A>(c.guides.normal.as_ref().expect("normal"), qy, qx);
                        let pd = np[0] * d[0] + np[1] * d[1] + np[2] * d[2];
                        let qd = nq[0] * d[0] + nq[1] * d[1] + nq[2] * d[2];
                        if c.inv_dist2 > 0.0 {
                            t += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) * A::of(c.inv_dist2);
                        }
                        (pd * pd + qd * qd) * A::of(0.5)
                    } else {
                        d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                    };
                    t += g * inv_geo;
                }
                Geometry::Depth => {
                    let zq: A = at(c.guides.depth.as_ref().expect("depth"), 0, qy, qx);
                    let zq_safe = if zq > A::of(1e-20) { zq } else { A::of(1e-20) };
                    let dz = zq - zp;
                    t += dz * dz / (zp_safe * zq_safe) * inv_geo;
                }
                Geometry::None => {}
            }
            let wt = A::of(h2(dy, dx)) * (-t).exp();
            wsum += wt;
            for (ch, a) in acc.iter_mut().enumerate().take(nc) {
                *a += wt * at::<S, A>(src, ch, qy, qx);
            }
            if c.with_variance {
                accv += wt * wt * at::<S, A>(src, nc, qy, qx);
            }
        }
    }
    // The centre tap contributes 9/64 (all terms are exactly 0 there).
    let inv = A::ONE / wsum;
    for ch in 0..nc {
        out[ch] = (acc[ch] * inv).f32();
    }
    if c.with_variance {
        out[nc] = (accv * inv * inv).f32();
        out[nc + 1] = (A::of(h2(2, 2)) * inv).f32();
    }
}

pub(crate) fn step<S: FloatElement, A: Real>(c: &Ctx<'_, '_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let mut out = [0.0f32; MAX_OUT];
    let n = dst.channels();
    for yo in 0..dst.height() {
        for x in 0..dst.width() {
            pixel::<S, A>(c, y0 + yo, x, &mut out);
            for (ch, &v) in out.iter().enumerate().take(n) {
                dst.row_mut(ch, yo)[x] = S::from_f32(v);
            }
        }
    }
}

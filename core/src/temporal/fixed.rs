//! Temporal accumulation in fixed point (integer only; see [`super`] for the
//! method). Bilinear weights in Q1.14, squared distances in `i64` against the
//! limits converted to the position and normal formats, the blend weight
//! `max(1/(n+1), alpha_min)` by integer division; the reprojected history
//! and colour divide by the taps' weight sum through one reciprocal.

use super::{TemporalInputs, TemporalParams};
use crate::fixed::{div_round, ld, mul_recip, rescale, sat16, shr_round};
use crate::view::{View, ViewMut};

const ONE: i64 = 1 << 14;

#[inline(always)]
fn at(v: &View<'_, i16>, c: usize, y: usize, x: usize) -> i64 {
    ld(v.at(c, y, x)) as i64
}

#[inline(always)]
fn dist2(a: &View<'_, i16>, ya: usize, xa: usize, b: &View<'_, i16>, yb: usize, xb: usize) -> i64 {
    // Both in their own formats: bring b to a's.
    let (fb, fa) = (b.frac() as i32, a.frac() as i32);
    let mut s = 0;
    for c in 0..3 {
        let d = at(a, c, ya, xa) - rescale(at(b, c, yb, xb), fb, fa);
        s += d * d;
    }
    s
}

/// A limit in a format, squared (in that format's squared units).
fn limit2(l: f32, frac: i8) -> i64 {
    let q = (l.clamp(0.0, 1e6) as f64 * libm::exp2(frac as f64)) as i64;
    q.saturating_mul(q)
}

/// One geometry test's current values at a pixel (read once for its taps),
/// the previous frame's buffer, the shift that brings it to the current
/// format, and the squared limit.
#[derive(Clone, Copy)]
struct Test<'a> {
    cur: [i64; 3],
    prev: Option<(&'a View<'a, i16>, i32, i32, i64)>,
}

impl<'a> Test<'a> {
    #[inline(always)]
    fn new(a: &'a Option<View<'a, i16>>, b: &'a Option<View<'a, i16>>, limit: i64, y: usize, x: usize) -> Self {
        match (a, b) {
            (Some(a), Some(b)) => Test {
                cur: [at(a, 0, y, x), at(a, 1, y, x), at(a, 2, y, x)],
                prev: Some((b, b.frac() as i32, a.frac() as i32, limit)),
            },
            _ => Test { cur: [0; 3], prev: None },
        }
    }

    /// Whether previous pixel `(py, px)` passes (a test without buffers passes).
    #[inline(always)]
    fn passes(&self, py: usize, px: usize) -> bool {
        let Some((b, fb, fa, limit)) = self.prev else { return true };
        let mut s = 0;
        for c in 0..3 {
            let q = at(b, c, py, px);
            let d = self.cur[c] - if fb == fa { q } else { rescale(q, fb, fa) };
            s += d * d;
        }
        s < limit
    }
}

/// The integer square root (floor) of `v >= 0`.
fn isqrt(v: i64) -> i64 {
    if v <= 0 {
        return 0;
    }
    let mut r = libm::sqrt(v as f64) as i64;
    while r * r > v {
        r -= 1;
    }
    while (r + 1) * (r + 1) <= v {
        r += 1;
    }
    r
}

/// Pixels per tile of the history clamp's statistics (on the stack).
const TILE: usize = 32;
/// Colour channels whose clamp statistics a tile holds; more channels take
/// each pixel's window on its own.
const TILE_CH: usize = 4;

/// The history clamp's statistics of channel `c` for the pixels `x0 .. x1`
/// (at most [`TILE`]) of row `y`, in the colour's format: the window's mean
/// and population variance (both rounded); from exact `i64` column sums of
/// `v` and `v^2` (`|v| < 2^15`, at most 289 of them) and their prefix sums.
fn tile_bounds(
    v: &View<'_, i16>,
    c: usize,
    y: usize,
    (x0, x1): (usize, usize),
    r: usize,
    out: &mut [(i64, i64); TILE],
) {
    let (w, h) = (v.width(), v.height());
    let (ys, ye) = (y.saturating_sub(r), (y + r + 1).min(h));
    let (xs, xe) = (x0.saturating_sub(r), (x1 + r).min(w));
    let mut p1 = [0i64; TILE + 17];
    let mut p2 = [0i64; TILE + 17];
    for j in xs..xe {
        let (mut s1, mut s2) = (0i64, 0i64);
        for yy in ys..ye {
            let q = ld(v.row(c, yy)[j]) as i64;
            s1 += q;
            s2 += q * q;
        }
        let i = j - xs;
        p1[i + 1] = p1[i] + s1;
        p2[i + 1] = p2[i] + s2;
    }
    let rows = (ye - ys) as i64;
    for x in x0..x1 {
        let (a, b) = (x.saturating_sub(r) - xs, (x + r + 1).min(w) - xs);
        let n = rows * (b - a) as i64;
        let (sum, sq) = (p1[b] - p1[a], p2[b] - p2[a]);
        // n^2 var = n sum q^2 - (sum q)^2 (under 2^48).
        let var = div_round(n * sq - sum * sum, n * n);
        out[x - x0] = (div_round(sum, n), var);
    }
}

/// [`tile_bounds`] for one pixel.
fn clamp_bounds(v: &View<'_, i16>, c: usize, y: usize, x: usize, r: usize) -> (i64, i64) {
    let mut one = [(0, 0); TILE];
    tile_bounds(v, c, y, (x, x + 1), r, &mut one);
    one[0]
}

/// `h` clamped to `mu -+ k sqrt(var + (floor h)^2)`: `k` and `floor` in
/// Q.8, the square root an integer one, all in the colour's format.
#[inline]
fn clamp_to(h: i64, (mu, var): (i64, i64), k_q8: i64, floor_q8: i64) -> i64 {
    let fh = shr_round(floor_q8 * h, 8);
    let ks = shr_round(k_q8 * isqrt(var + fh * fh), 8);
    h.clamp(mu - ks, mu + ks)
}

pub(crate) fn accumulate(
    inp: &TemporalInputs<'_, i16>,
    p: &TemporalParams,
    color: &mut ViewMut<'_, i16>,
    history: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    let (w, h, ch) = (inp.color.width(), inp.color.height(), inp.color.channels());
    let lp = inp.position.as_ref().map_or(0, |v| limit2(p.pos_limit, v.frac()));
    let ln = inp.normal.as_ref().map_or(0, |v| limit2(p.normal_limit, v.frac()));
    let la = inp.albedo.as_ref().map_or(0, |v| limit2(p.albedo_limit, v.frac()));
    let (fc, fpc, fh) = (inp.color.frac() as i32, inp.prev_color.frac() as i32, inp.prev_history.frac() as i32);
    let (fo, fho) = (color.frac() as i32, history.frac() as i32);
    let amin = (p.alpha_min.clamp(0.0, 1.0) * ONE as f32) as i64;
    let cap = (p.history_cap.clamp(0.0, 1e6) as f64 * libm::exp2(fh as f64)) as i64;
    let k_q8 = libm::round(p.clamp_sigma.clamp(0.0, 1e6) as f64 * 256.0) as i64;
    let r = p.clamp_radius.min(8);
    let floor_q8 = libm::round(p.clamp_floor.clamp(0.0, 1e3) as f64 * 256.0) as i64;
    let tiled = k_q8 > 0 && ch <= TILE_CH;
    let mut bounds = [[(0i64, 0i64); TILE]; TILE_CH];
    for yo in 0..color.height() {
        let y = y0 + yo;
        for x in 0..w {
            if tiled && x % TILE == 0 {
                for (c, b) in bounds.iter_mut().enumerate().take(ch) {
                    tile_bounds(&inp.color, c, y, (x, (x + TILE).min(w)), r, b);
                }
            }
            // The accepted taps (at most the four bilinear ones), then their
            // sums: any number of colour channels.
            let mut taps = [(0usize, 0usize, 0i64); 4];
            let mut nt = 0;
            let mut take = |py: usize, px: usize, wt: i64| {
                taps[nt] = (py, px, wt);
                nt += 1;
            };
            let tests = [
                Test::new(&inp.position, &inp.prev_position, lp, y, x),
                Test::new(&inp.normal, &inp.prev_normal, ln, y, x),
                Test::new(&inp.albedo, &inp.prev_albedo, la, y, x),
            ];
            let agrees =
                |py: usize, px: usize| tests[0].passes(py, px) && tests[1].passes(py, px) && tests[2].passes(py, px);
            if let Some(m) = &inp.motion {
                let fm = m.frac().clamp(0, 14) as i32;
                let scale = 1i64 << fm;
                let fx = x as i64 * scale + rescale(at(m, 0, y, x), m.frac() as i32, fm);
                let fy = y as i64 * scale + rescale(at(m, 1, y, x), m.frac() as i32, fm);
                if fx > -scale && fy > -scale && fx < w as i64 * scale && fy < h as i64 * scale {
                    let (x0, y0i) = (fx.div_euclid(scale), fy.div_euclid(scale));
                    let (tx, ty) = (fx.rem_euclid(scale) << (14 - fm), fy.rem_euclid(scale) << (14 - fm));
                    for (dy, wy) in [(0i64, ONE - ty), (1, ty)] {
                        for (dx, wx) in [(0i64, ONE - tx), (1, tx)] {
                            let (py, px) = (y0i + dy, x0 + dx);
                            let wt = (wx * wy) >> 14;
                            if wt <= 0 || py < 0 || px < 0 || py >= h as i64 || px >= w as i64 {
                                continue;
                            }
                            let (py, px) = (py as usize, px as usize);
                            if agrees(py, px) {
                                take(py, px, wt);
                            }
                        }
                    }
                }
            } else if let (Some(a), Some(b)) = (&inp.position, &inp.prev_position) {
                let r = p.search_radius;
                let mut best: Option<(i64, usize, usize)> = None;
                for py in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for px in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let d = dist2(a, y, x, b, py, px);
                        if best.is_none_or(|(bd, _, _)| d < bd) {
                            best = Some((d, py, px));
                        }
                    }
                }
                if let Some((_, py, px)) = best {
                    if agrees(py, px) {
                        take(py, px, ONE);
                    }
                }
            }
            let taps = &taps[..nt];
            let (mut wsum, mut hist) = (0i64, 0i64);
            for &(py, px, wt) in taps {
                wsum += wt;
                hist += wt * at(&inp.prev_history, 0, py, px);
            }
            if wsum > 0 {
                // wsum <= 2^14 + 4 (bilinear weights of one pixel); the
                // values are under 32767 wsum, so the products stay under 2^62,
                // and the reciprocal's error moves a quotient by under 2^-17.
                let inv = (1i64 << 47) / wsum;
                let n = mul_recip(hist, inv, 47).max(0); // Q.fh
                let alpha = div_round(ONE << fh, n + (1i64 << fh)).max(amin).min(ONE); // Q.14
                for c in 0..ch {
                    let cur = at(&inp.color, c, y, x);
                    let mut prev = 0i64;
                    for &(py, px, wt) in taps {
                        prev += wt * at(&inp.prev_color, c, py, px);
                    }
                    let mut pv = rescale(mul_recip(prev, inv, 47), fpc, fc);
                    if k_q8 > 0 {
                        let st = if tiled { bounds[c][x % TILE] } else { clamp_bounds(&inp.color, c, y, x, r) };
                        pv = clamp_to(pv, st, k_q8, floor_q8);
                    }
                    let v = shr_round(alpha * cur + (ONE - alpha) * pv, 14);
                    color.row_mut(c, yo)[x] = sat16(rescale(v, fc, fo));
                }
                let next = (n + (1i64 << fh)).min(cap);
                history.row_mut(0, yo)[x] = sat16(rescale(next, fh, fho));
            } else {
                for c in 0..ch {
                    color.row_mut(c, yo)[x] = sat16(rescale(at(&inp.color, c, y, x), fc, fo));
                }
                history.row_mut(0, yo)[x] = 0;
            }
        }
    }
}

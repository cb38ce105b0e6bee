//! Temporal accumulation in f32 arithmetic over f32 or f16 storage. The
//! reprojection is a data-dependent gather; it runs as portable code on every
//! instruction set (the arithmetic per pixel is small next to the loads).

use super::{TemporalInputs, TemporalParams};
use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};

#[inline(always)]
fn get<S: FloatElement, A: Real>(v: &View<'_, S>, c: usize, y: usize, x: usize) -> A {
    A::of(v.at(c, y, x).to_f32())
}

#[inline(always)]
fn dist2<S: FloatElement, A: Real>(a: &View<'_, S>, ya: usize, xa: usize, b: &View<'_, S>, yb: usize, xb: usize) -> A {
    let mut d = A::ZERO;
    for c in 0..3 {
        let t = get::<S, A>(a, c, ya, xa) - get::<S, A>(b, c, yb, xb);
        d += t * t;
    }
    d
}

/// One geometry test's current values at a pixel (read once for its taps),
/// the previous frame's buffer and the squared limit.
#[derive(Clone, Copy)]
struct Test<'a, S, A> {
    cur: [A; 3],
    prev: Option<(&'a View<'a, S>, A)>,
}

impl<'a, S: FloatElement, A: Real> Test<'a, S, A> {
    #[inline(always)]
    fn new(a: &'a Option<View<'a, S>>, b: &'a Option<View<'a, S>>, limit: f32, y: usize, x: usize) -> Self {
        match (a, b) {
            (Some(a), Some(b)) => Test {
                cur: [get::<S, A>(a, 0, y, x), get::<S, A>(a, 1, y, x), get::<S, A>(a, 2, y, x)],
                prev: Some((b, A::of(limit) * A::of(limit))),
            },
            _ => Test { cur: [A::ZERO; 3], prev: None },
        }
    }

    /// Whether previous pixel `(py, px)` passes (a test without buffers
    /// passes); `!(d < limit)` rejects NaN distances too.
    #[inline(always)]
    fn passes(&self, py: usize, px: usize) -> bool {
        let Some((b, limit)) = self.prev else { return true };
        let mut d = A::ZERO;
        for c in 0..3 {
            let t = self.cur[c] - get::<S, A>(b, c, py, px);
            d += t * t;
        }
        d < limit
    }
}

/// Pixels per tile of the history clamp's statistics (on the stack: the
/// core allocates nothing, and runs on microcontrollers).
const TILE: usize = 32;
/// Colour channels whose clamp statistics a tile holds; more channels take
/// each pixel's window on its own ([`clamp_bounds`]).
const TILE_CH: usize = 4;

/// The history clamp's statistics of channel `c` for the pixels `x0 .. x1`
/// (at most [`TILE`]) of row `y`: the mean and the (population) variance of
/// the colour over the window of radius `r <= 8` (in-image pixels), from
/// column sums of `v` and `v^2` in f64 and their prefix sums; `None` where
/// the window holds a value that is not finite.
#[allow(clippy::too_many_arguments)]
fn tile_bounds<S: FloatElement>(
    v: &View<'_, S>,
    c: usize,
    y: usize,
    (x0, x1): (usize, usize),
    r: usize,
    out: &mut [Option<(f64, f64)>; TILE],
) {
    let (w, h) = (v.width(), v.height());
    let (ys, ye) = (y.saturating_sub(r), (y + r + 1).min(h));
    let (xs, xe) = (x0.saturating_sub(r), (x1 + r).min(w));
    // Prefix sums over the columns xs .. xe: sum, sum of squares, count of
    // values that are not finite.
    let mut p1 = [0.0f64; TILE + 17];
    let mut p2 = [0.0f64; TILE + 17];
    let mut bad = [0u32; TILE + 17];
    for j in xs..xe {
        let (mut s1, mut s2, mut b) = (0.0f64, 0.0f64, 0u32);
        for yy in ys..ye {
            let q = v.row(c, yy)[j].to_f32();
            if q.is_finite() {
                let q = q as f64;
                s1 += q;
                s2 += q * q;
            } else {
                b += 1;
            }
        }
        let i = j - xs;
        p1[i + 1] = p1[i] + s1;
        p2[i + 1] = p2[i] + s2;
        bad[i + 1] = bad[i] + b;
    }
    let rows = (ye - ys) as f64;
    for x in x0..x1 {
        let (a, b) = (x.saturating_sub(r) - xs, (x + r + 1).min(w) - xs);
        out[x - x0] = if bad[b] > bad[a] {
            None
        } else {
            let n = rows * (b - a) as f64;
            let mu = (p1[b] - p1[a]) / n;
            let var = ((p2[b] - p2[a]) / n - mu * mu).max(0.0);
            (mu.is_finite() && var.is_finite()).then_some((mu, var))
        };
    }
}

/// [`tile_bounds`] for one pixel (colours of more than [`TILE_CH`]
/// channels).
fn clamp_bounds<S: FloatElement>(v: &View<'_, S>, c: usize, y: usize, x: usize, r: usize) -> Option<(f64, f64)> {
    let mut one = [None; TILE];
    tile_bounds(v, c, y, (x, x + 1), r, &mut one);
    one[0]
}

/// `h` clamped to `mu -+ k sqrt(var + (floor h)^2)` (f64).
#[inline]
fn clamp_to(h: f64, (mu, var): (f64, f64), k: f64, floor: f64) -> f64 {
    let ks = k * libm::sqrt(var + (floor * h) * (floor * h));
    let (lo, hi) = (mu - ks, mu + ks);
    if !(lo.is_finite() && hi.is_finite()) {
        h
    } else if h < lo {
        lo
    } else if h > hi {
        hi
    } else {
        h
    }
}

pub(crate) fn accumulate<S: FloatElement, A: Real>(
    _isa: crate::isa::Supported,
    inp: &TemporalInputs<'_, S>,
    p: &TemporalParams,
    color: &mut ViewMut<'_, S>,
    history: &mut ViewMut<'_, S>,
    y0: usize,
) {
    let (w, h, ch) = (inp.color.width(), inp.color.height(), inp.color.channels());
    let (clamp, r) = (p.clamp_sigma > 0.0, p.clamp_radius.min(8));
    let tiled = clamp && ch <= TILE_CH;
    let mut bounds = [[None; TILE]; TILE_CH];
    for yo in 0..color.height() {
        let y = y0 + yo;
        for x in 0..w {
            if tiled && x % TILE == 0 {
                for (c, b) in bounds.iter_mut().enumerate().take(ch) {
                    tile_bounds(&inp.color, c, y, (x, (x + TILE).min(w)), r, b);
                }
            }
            // Gather the reprojected colour and history.
            // The accepted taps (at most the four bilinear ones), then their
            // sums: any number of colour channels.
            let mut taps = [(0usize, 0usize, A::ZERO); 4];
            let mut nt = 0;
            let mut take = |py: usize, px: usize, wt: A| {
                taps[nt] = (py, px, wt);
                nt += 1;
            };
            let tests = [
                Test::<S, A>::new(&inp.position, &inp.prev_position, p.pos_limit, y, x),
                Test::new(&inp.normal, &inp.prev_normal, p.normal_limit, y, x),
                Test::new(&inp.albedo, &inp.prev_albedo, p.albedo_limit, y, x),
            ];
            let agrees =
                |py: usize, px: usize| tests[0].passes(py, px) && tests[1].passes(py, px) && tests[2].passes(py, px);
            if let Some(m) = &inp.motion {
                let (mx, my): (f32, f32) = (get::<S, f32>(m, 0, y, x), get::<S, f32>(m, 1, y, x));
                // Previous position of the pixel centre, in pixel units.
                let fx = x as f32 + 0.5 + mx - 0.5;
                let fy = y as f32 + 0.5 + my - 0.5;
                if fx.is_finite() && fy.is_finite() && fx > -1.0 && fy > -1.0 && fx < w as f32 && fy < h as f32 {
                    let (x0, y0f) = (libm::floorf(fx), libm::floorf(fy));
                    let (tx, ty) = (fx - x0, fy - y0f);
                    let (x0, y0i) = (x0 as isize, y0f as isize);
                    for (dy, wy) in [(0isize, 1.0 - ty), (1, ty)] {
                        for (dx, wx) in [(0isize, 1.0 - tx), (1, tx)] {
                            let (py, px) = (y0i + dy, x0 + dx);
                            let wt = A::of(wx) * A::of(wy);
                            if wt <= A::ZERO || py < 0 || px < 0 || py as usize >= h || px as usize >= w {
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
                // Reprojection by world position: the closest previous position nearby.
                let r = p.search_radius;
                let mut best: Option<(A, usize, usize)> = None;
                for py in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for px in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let d = dist2::<S, A>(a, y, x, b, py, px);
                        if d.f32().is_finite() && best.is_none_or(|(bd, _, _)| d < bd) {
                            best = Some((d, py, px));
                        }
                    }
                }
                if let Some((_, py, px)) = best {
                    if agrees(py, px) {
                        take(py, px, A::ONE);
                    }
                }
            }
            let taps = &taps[..nt];
            let (mut wsum, mut hist) = (A::ZERO, A::ZERO);
            for &(py, px, wt) in taps {
                wsum += wt;
                hist += wt * get::<S, A>(&inp.prev_history, 0, py, px);
            }
            let cur = |c: usize| get::<S, A>(&inp.color, c, y, x);
            if wsum > A::ZERO {
                let inv = A::ONE / wsum;
                let n = (hist * inv).fmax(A::ZERO);
                let alpha = (A::ONE / (n + A::ONE)).fmax(A::of(p.alpha_min));
                for c in 0..ch {
                    let mut pv = A::ZERO;
                    for &(py, px, wt) in taps {
                        pv += wt * get::<S, A>(&inp.prev_color, c, py, px);
                    }
                    let mut pv = pv * inv;
                    if clamp {
                        let b = if tiled { bounds[c][x % TILE] } else { clamp_bounds(&inp.color, c, y, x, r) };
                        if let Some(st) = b {
                            let f = pv.f32() as f64;
                            let g = clamp_to(f, st, p.clamp_sigma as f64, p.clamp_floor as f64);
                            if g != f {
                                pv = A::of(g as f32);
                            }
                        }
                    }
                    let v = alpha * cur(c) + (A::ONE - alpha) * pv;
                    color.row_mut(c, yo)[x] = S::from_f32(v.f32());
                }
                let next = n + A::ONE;
                let capped = if next > A::of(p.history_cap) { A::of(p.history_cap) } else { next };
                history.row_mut(0, yo)[x] = S::from_f32(capped.f32());
            } else {
                for c in 0..ch {
                    color.row_mut(c, yo)[x] = S::from_f32(cur(c).f32());
                }
                history.row_mut(0, yo)[x] = S::from_f32(0.0);
            }
        }
    }
}

//! Temporal accumulation in f32 arithmetic over f32 or f16 storage. The
//! reprojection is a data-dependent gather; it runs as portable code on every
//! instruction set (the arithmetic per pixel is small next to the loads).

use super::{TemporalInputs, TemporalParams};
use crate::precision::FloatElement;
use crate::view::{View, ViewMut};
use crate::Isa;

const MAX_C: usize = 4;

fn get<S: FloatElement>(v: &View<'_, S>, c: usize, y: usize, x: usize) -> f32 {
    v.at(c, y, x).to_f32()
}

fn dist2<S: FloatElement>(a: &View<'_, S>, ya: usize, xa: usize, b: &View<'_, S>, yb: usize, xb: usize) -> f32 {
    let mut d = 0.0;
    for c in 0..3 {
        let t = get(a, c, ya, xa) - get(b, c, yb, xb);
        d += t * t;
    }
    d
}

/// Whether previous pixel `(py, px)` may stand for current pixel `(y, x)`.
fn agrees<S: FloatElement>(
    inp: &TemporalInputs<'_, S>,
    p: &TemporalParams,
    y: usize,
    x: usize,
    py: usize,
    px: usize,
) -> bool {
    if let (Some(a), Some(b)) = (&inp.position, &inp.prev_position) {
        // `!(d < limit)` rejects NaN distances too.
        if !(dist2(a, y, x, b, py, px) < p.pos_limit * p.pos_limit) {
            return false;
        }
    }
    if let (Some(a), Some(b)) = (&inp.normal, &inp.prev_normal) {
        if !(dist2(a, y, x, b, py, px) < p.normal_limit * p.normal_limit) {
            return false;
        }
    }
    true
}

pub(crate) fn accumulate<S: FloatElement>(
    _isa: Isa,
    inp: &TemporalInputs<'_, S>,
    p: &TemporalParams,
    color: &mut ViewMut<'_, S>,
    history: &mut ViewMut<'_, S>,
    y0: usize,
) {
    let (w, h, ch) = (inp.color.width(), inp.color.height(), inp.color.channels());
    let chm = ch.min(MAX_C);
    for yo in 0..color.height() {
        let y = y0 + yo;
        for x in 0..w {
            // Gather the reprojected colour and history.
            let mut wsum = 0.0f32;
            let mut hist = 0.0f32;
            let mut prev = [0.0f32; MAX_C];
            let mut take = |py: usize, px: usize, wt: f32| {
                wsum += wt;
                hist += wt * get(&inp.prev_history, 0, py, px);
                for (c, pv) in prev.iter_mut().enumerate().take(chm) {
                    *pv += wt * get(&inp.prev_color, c, py, px);
                }
            };
            if let Some(m) = &inp.motion {
                let (mx, my) = (get(m, 0, y, x), get(m, 1, y, x));
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
                            let wt = wx * wy;
                            if wt <= 0.0 || py < 0 || px < 0 || py as usize >= h || px as usize >= w {
                                continue;
                            }
                            let (py, px) = (py as usize, px as usize);
                            if agrees(inp, p, y, x, py, px) {
                                take(py, px, wt);
                            }
                        }
                    }
                }
            } else if let (Some(a), Some(b)) = (&inp.position, &inp.prev_position) {
                // Reprojection by world position: the closest previous position nearby.
                let r = p.search_radius;
                let mut best: Option<(f32, usize, usize)> = None;
                for py in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for px in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let d = dist2(a, y, x, b, py, px);
                        if d.is_finite() && best.is_none_or(|(bd, _, _)| d < bd) {
                            best = Some((d, py, px));
                        }
                    }
                }
                if let Some((_, py, px)) = best {
                    if agrees(inp, p, y, x, py, px) {
                        take(py, px, 1.0);
                    }
                }
            }
            let cur = |c: usize| get(&inp.color, c, y, x);
            if wsum > 0.0 {
                let inv = 1.0 / wsum;
                let n = (hist * inv).max(0.0);
                let alpha = (1.0 / (n + 1.0)).max(p.alpha_min);
                for c in 0..ch {
                    let pv = if c < chm { prev[c] * inv } else { cur(c) };
                    let v = alpha * cur(c) + (1.0 - alpha) * pv;
                    color.row_mut(c, yo)[x] = S::from_f32(v);
                }
                history.row_mut(0, yo)[x] = S::from_f32((n + 1.0).min(p.history_cap));
            } else {
                for c in 0..ch {
                    color.row_mut(c, yo)[x] = S::from_f32(cur(c));
                }
                history.row_mut(0, yo)[x] = S::from_f32(0.0);
            }
        }
    }
}

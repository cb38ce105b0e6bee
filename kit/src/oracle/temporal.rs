//! Temporal accumulation: by motion, and every path with rejection and position search.

/// Temporal accumulation with motion vectors (no geometry tests), as defined
/// in `mcdenoise_core::temporal`: bilinear taps of the previous colour at
/// `p + motion`, in-image taps renormalised, `alpha = max(1/(n+1), alpha_min)`.
#[allow(clippy::too_many_arguments)]
pub fn temporal_motion(
    color: &[f64],
    motion: &[f64],
    prev: &[f64],
    prev_hist: &[f64],
    alpha_min: f64,
    c: usize,
    w: usize,
    h: usize,
) -> Vec<f64> {
    let plane = w * h;
    let mut out = vec![0.0; c * plane];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let fx = x as f64 + motion[p];
            let fy = y as f64 + motion[plane + p];
            let (mut ws, mut n, mut acc) = (0.0, 0.0, vec![0.0; c]);
            if fx > -1.0 && fy > -1.0 && fx < w as f64 && fy < h as f64 {
                let (x0, y0) = (fx.floor(), fy.floor());
                let (tx, ty) = (fx - x0, fy - y0);
                for (dy, wy) in [(0.0, 1.0 - ty), (1.0, ty)] {
                    for (dx, wx) in [(0.0, 1.0 - tx), (1.0, tx)] {
                        let (py, px) = (y0 + dy, x0 + dx);
                        let wt = wx * wy;
                        if wt <= 0.0 || py < 0.0 || px < 0.0 || py >= h as f64 || px >= w as f64 {
                            continue;
                        }
                        let q = py as usize * w + px as usize;
                        ws += wt;
                        n += wt * prev_hist[q];
                        for ch in 0..c {
                            acc[ch] += wt * prev[ch * plane + q];
                        }
                    }
                }
            }
            for ch in 0..c {
                out[ch * plane + p] = if ws > 0.0 {
                    let n = (n / ws).max(0.0);
                    let a = (1.0 / (n + 1.0)).max(alpha_min);
                    a * color[ch * plane + p] + (1.0 - a) * acc[ch] / ws
                } else {
                    color[ch * plane + p]
                };
            }
        }
    }
    out
}

/// The inputs of [`temporal`]: packed f64 planes of `w x h` (`c` colour
/// planes, 3 for normals and positions, 2 for motion, 1 for history).
pub struct TemporalRef<'a> {
    /// Current colour.
    pub color: &'a [f64],
    /// Current normal.
    pub normal: Option<&'a [f64]>,
    /// Current world position.
    pub position: Option<&'a [f64]>,
    /// Motion (`previous = current + motion`, pixels).
    pub motion: Option<&'a [f64]>,
    /// Previous accumulated colour.
    pub prev_color: &'a [f64],
    /// Previous normal.
    pub prev_normal: Option<&'a [f64]>,
    /// Previous world position.
    pub prev_position: Option<&'a [f64]>,
    /// Previous history.
    pub prev_history: &'a [f64],
    /// Current albedo.
    pub albedo: Option<&'a [f64]>,
    /// Previous albedo.
    pub prev_albedo: Option<&'a [f64]>,
    /// Colour planes.
    pub c: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
}

/// Temporal accumulation in f64, every path of `core::temporal`: the
/// bilinear reprojection by motion, or (without motion) the previous pixel
/// within `radius` whose position is closest (first in row-major order on a
/// tie) taken whole; a tap counts when inside the image and, where both
/// buffers exist, `|dpos|^2 < pos_limit^2`, `|dn|^2 < normal_limit^2` and
/// `|dalbedo|^2 < albedo_limit^2`; accepted taps renormalised. No tap: the colour, history 0; else
/// `alpha = max(1/(n+1), alpha_min)` and history `min(n + 1, cap)`.
/// With `clamp = (k, r, f)`, `k > 0`, the reprojected colour `prev` is
/// first clamped per channel to `mean -+ k sqrt(var + (f prev)^2)`, the mean
/// and population variance of the current colour over the in-image pixels
/// of the `(2r + 1)^2` window (left alone when a bound is not finite).
/// Returns the colour (`c` planes) and the history (1 plane).
#[allow(clippy::too_many_arguments)]
pub fn temporal(
    t: &TemporalRef<'_>,
    pos_limit: f64,
    normal_limit: f64,
    alpha_min: f64,
    history_cap: f64,
    radius: usize,
    albedo_limit: f64,
    clamp: (f64, usize, f64),
) -> (Vec<f64>, Vec<f64>) {
    let (c, w, h) = (t.c, t.w, t.h);
    let plane = w * h;
    let d2 = |a: &[f64], p: usize, b: &[f64], q: usize| -> f64 {
        (0..3).map(|k| (a[k * plane + p] - b[k * plane + q]).powi(2)).sum()
    };
    let agrees = |p: usize, q: usize| -> bool {
        let pos_ok = match (t.position, t.prev_position) {
            (Some(a), Some(b)) => d2(a, p, b, q) < pos_limit * pos_limit,
            _ => true,
        };
        let n_ok = match (t.normal, t.prev_normal) {
            (Some(a), Some(b)) => d2(a, p, b, q) < normal_limit * normal_limit,
            _ => true,
        };
        let a_ok = match (t.albedo, t.prev_albedo) {
            (Some(a), Some(b)) => d2(a, p, b, q) < albedo_limit * albedo_limit,
            _ => true,
        };
        pos_ok && n_ok && a_ok
    };
    let mut out = vec![0.0; c * plane];
    let mut hist = vec![0.0; plane];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            // (previous pixel, weight) of the accepted taps.
            let mut taps: Vec<(usize, f64)> = Vec::new();
            if let Some(m) = t.motion {
                let (fx, fy) = (x as f64 + m[p], y as f64 + m[plane + p]);
                if fx > -1.0 && fy > -1.0 && fx < w as f64 && fy < h as f64 {
                    let (x0, y0) = (fx.floor(), fy.floor());
                    let (tx, ty) = (fx - x0, fy - y0);
                    for (py, wy) in [(y0, 1.0 - ty), (y0 + 1.0, ty)] {
                        for (px, wx) in [(x0, 1.0 - tx), (x0 + 1.0, tx)] {
                            let inside = py >= 0.0 && px >= 0.0 && py < h as f64 && px < w as f64;
                            if wx * wy > 0.0 && inside {
                                let q = py as usize * w + px as usize;
                                if agrees(p, q) {
                                    taps.push((q, wx * wy));
                                }
                            }
                        }
                    }
                }
            } else if let (Some(a), Some(b)) = (t.position, t.prev_position) {
                let mut best: Option<(f64, usize)> = None;
                for py in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                    for px in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                        let q = py * w + px;
                        let d = d2(a, p, b, q);
                        if best.is_none_or(|(bd, _)| d < bd) {
                            best = Some((d, q));
                        }
                    }
                }
                if let Some((_, q)) = best.filter(|&(_, q)| agrees(p, q)) {
                    taps.push((q, 1.0));
                }
            }
            let ws: f64 = taps.iter().map(|&(_, wt)| wt).sum();
            if ws > 0.0 {
                let n = (taps.iter().map(|&(q, wt)| wt * t.prev_history[q]).sum::<f64>() / ws).max(0.0);
                let a = (1.0 / (n + 1.0)).max(alpha_min);
                for ch in 0..c {
                    let mut prev = taps.iter().map(|&(q, wt)| wt * t.prev_color[ch * plane + q]).sum::<f64>() / ws;
                    let (k, r, fl) = clamp;
                    if k > 0.0 {
                        let win: Vec<f64> = (y.saturating_sub(r)..(y + r + 1).min(h))
                            .flat_map(|qy| (x.saturating_sub(r)..(x + r + 1).min(w)).map(move |qx| qy * w + qx))
                            .map(|q| t.color[ch * plane + q])
                            .collect();
                        let mu = win.iter().sum::<f64>() / win.len() as f64;
                        let var = win.iter().map(|v| (v - mu).powi(2)).sum::<f64>() / win.len() as f64;
                        let s = (var + (fl * prev).powi(2)).sqrt();
                        let (lo, hi) = (mu - k * s, mu + k * s);
                        if lo.is_finite() && hi.is_finite() {
                            prev = prev.clamp(lo, hi);
                        }
                    }
                    out[ch * plane + p] = a * t.color[ch * plane + p] + (1.0 - a) * prev;
                }
                hist[p] = (n + 1.0).min(history_cap);
            } else {
                for ch in 0..c {
                    out[ch * plane + p] = t.color[ch * plane + p];
                }
            }
        }
    }
    (out, hist)
}

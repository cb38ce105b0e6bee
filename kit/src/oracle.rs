//! The exact f64 reference of every operator, written from the papers' equations
//! independently of the kernels (no shift tricks, no tiling, no shared code).
//! The property tests compare against it and `mcdenoise precision` measures
//! every precision's error with it. (The oracle lives beside the host, not
//! in the `no_std` core.)
#![allow(clippy::needless_range_loop)]

/// Index of `(c, y, x)` in a planar `w x h` buffer.
#[inline]
fn ix(c: usize, y: usize, x: usize, w: usize, h: usize) -> usize {
    (c * h + y) * w + x
}

fn tap(y: usize, x: usize, dy: isize, dx: isize, w: usize, h: usize) -> Option<(usize, usize)> {
    let yy = y as isize + dy;
    let xx = x as isize + dx;
    (yy >= 0 && xx >= 0 && (yy as usize) < h && (xx as usize) < w).then_some((yy as usize, xx as usize))
}

/// `out_c(p) = sum_j K_j(p) r_c(p + o_j)`, out-of-image taps zero.
pub fn unfold(k: usize, kernel: &[f64], src: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let r = (k / 2) as isize;
    let mut out = vec![0.0; c * w * h];
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for ky in 0..k {
                    for kx in 0..k {
                        if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                            s += kernel[ix(ky * k + kx, y, x, w, h)] * src[ix(ch, yy, xx, w, h)];
                        }
                    }
                }
                out[ix(ch, y, x, w, h)] = s;
            }
        }
    }
    out
}

/// Clamps a logit the way the kernels document (±1e30, NaN to -1e30).
pub fn clamp_logit(v: f64) -> f64 {
    if v.is_nan() {
        -1e30
    } else {
        v.clamp(-1e30, 1e30)
    }
}

/// Per-pixel softmax weights over the window `k` (WSKP eq. 3), tap-major planes.
pub fn importance_kernels(k: usize, logits: &[f64], w: usize, h: usize) -> Vec<f64> {
    let r = (k / 2) as isize;
    let mut out = vec![0.0; k * k * w * h];
    for y in 0..h {
        for x in 0..w {
            let mut m = f64::NEG_INFINITY;
            for ky in 0..k {
                for kx in 0..k {
                    if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                        m = m.max(clamp_logit(logits[ix(0, yy, xx, w, h)]));
                    }
                }
            }
            let mut den = 0.0;
            for ky in 0..k {
                for kx in 0..k {
                    if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                        den += (clamp_logit(logits[ix(0, yy, xx, w, h)]) - m).exp();
                    }
                }
            }
            for ky in 0..k {
                for kx in 0..k {
                    if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                        out[ix(ky * k + kx, y, x, w, h)] = (clamp_logit(logits[ix(0, yy, xx, w, h)]) - m).exp() / den;
                    }
                }
            }
        }
    }
    out
}

/// Single-size importance filter (WSKP eq. 4).
pub fn window_filter(k: usize, logits: &[f64], rad: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let kern = importance_kernels(k, logits, w, h);
    unfold(k, &kern, rad, c, w, h)
}

/// Softmax over `n` planes at every pixel.
pub fn channel_softmax(src: &[f64], n: usize, w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; n * w * h];
    for y in 0..h {
        for x in 0..w {
            let m = (0..n).map(|c| clamp_logit(src[ix(c, y, x, w, h)])).fold(f64::NEG_INFINITY, f64::max);
            let den: f64 = (0..n).map(|c| (clamp_logit(src[ix(c, y, x, w, h)]) - m).exp()).sum();
            for c in 0..n {
                out[ix(c, y, x, w, h)] = (clamp_logit(src[ix(c, y, x, w, h)]) - m).exp() / den;
            }
        }
    }
    out
}

/// Fused filter (WSKP eq. 5): `albedo * sum_i alpha_i R_i`.
#[allow(clippy::too_many_arguments)]
pub fn fused(
    sizes: &[usize],
    imp: &[f64],
    fusion: Option<&[f64]>,
    albedo: Option<&[f64]>,
    rad: &[f64],
    c: usize,
    w: usize,
    h: usize,
) -> Vec<f64> {
    let m = sizes.len();
    let plane = w * h;
    let alpha = match fusion {
        Some(f) => channel_softmax(f, m, w, h),
        None => vec![1.0; plane],
    };
    let mut out = vec![0.0; c * plane];
    for (i, &k) in sizes.iter().enumerate() {
        let ri = window_filter(k, &imp[i * plane..(i + 1) * plane], rad, c, w, h);
        for ch in 0..c {
            for p in 0..plane {
                out[ch * plane + p] += alpha[i * plane + p] * ri[ch * plane + p];
            }
        }
    }
    if let Some(a) = albedo {
        for (o, &al) in out.iter_mut().zip(a) {
            *o *= al;
        }
    }
    out
}

/// Mean (or max) of the in-image pixels of each 2x2 cell.
pub fn reduce2x2(src: &[f64], c: usize, w: usize, h: usize, max: bool) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0; c * wc * hc];
    for ch in 0..c {
        for yc in 0..hc {
            for xc in 0..wc {
                let mut vals = Vec::new();
                for y in 2 * yc..(2 * yc + 2).min(h) {
                    for x in 2 * xc..(2 * xc + 2).min(w) {
                        vals.push(src[ix(ch, y, x, w, h)]);
                    }
                }
                out[ix(ch, yc, xc, wc, hc)] = if max {
                    vals.iter().copied().fold(f64::NEG_INFINITY, f64::max)
                } else {
                    vals.iter().sum::<f64>() / vals.len() as f64
                };
            }
        }
    }
    out
}

/// Nearest upsample of a `ceil(w/2) x ceil(h/2)` image to `w x h`.
pub fn upsample(src: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0; c * w * h];
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                out[ix(ch, y, x, w, h)] = src[ix(ch, y / 2, x / 2, wc, hc)];
            }
        }
    }
    out
}

/// `o = f - a U(D(f)) + a U(c)` with a one-plane `a`.
pub fn composite(fine: &[f64], coarse: &[f64], alpha: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let ud = upsample(&reduce2x2(fine, c, w, h, false), c, w, h);
    let uc = upsample(coarse, c, w, h);
    let plane = w * h;
    let mut out = vec![0.0; c * plane];
    for ch in 0..c {
        for p in 0..plane {
            let i = ch * plane + p;
            out[i] = fine[i] - alpha[p] * ud[i] + alpha[p] * uc[i];
        }
    }
    out
}

/// Convolution with zero padding, `[cout][cin][k][k]` weights.
#[allow(clippy::too_many_arguments)]
pub fn conv2d(
    k: usize,
    cin: usize,
    cout: usize,
    weights: &[f64],
    bias: Option<&[f64]>,
    leaky: Option<f64>,
    src: &[f64],
    w: usize,
    h: usize,
) -> Vec<f64> {
    let r = (k / 2) as isize;
    let mut out = vec![0.0; cout * w * h];
    for co in 0..cout {
        for y in 0..h {
            for x in 0..w {
                let mut s = bias.map_or(0.0, |b| b[co]);
                for ci in 0..cin {
                    for ky in 0..k {
                        for kx in 0..k {
                            if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                                s += weights[((co * cin + ci) * k + ky) * k + kx] * src[ix(ci, yy, xx, w, h)];
                            }
                        }
                    }
                }
                if let Some(slope) = leaky {
                    if s < 0.0 {
                        s *= slope;
                    }
                }
                out[ix(co, y, x, w, h)] = s;
            }
        }
    }
    out
}

/// Guides of the à-trous oracle.
pub struct AtrousGuides<'a> {
    /// Noise variance (1 plane).
    pub noise: &'a [f64],
    /// Normal (3 planes).
    pub normal: Option<&'a [f64]>,
    /// Position (3 planes).
    pub position: Option<&'a [f64]>,
    /// Depth (1 plane).
    pub depth: Option<&'a [f64]>,
}

/// One à-trous step from the definition in `mcdenoise_core::atrous` (f64):
/// returns the filtered `3 * groups` planes, then (with a variance plane as
/// the last input plane) the filtered variance and the centre weight.
#[allow(clippy::too_many_arguments)]
pub fn atrous_step(
    level: u32,
    groups: usize,
    with_var: bool,
    phi: f64,
    sigma_n: f64,
    sigma_plane: f64,
    sigma_depth: f64,
    sigma_dist: f64,
    eps: f64,
    g: &AtrousGuides<'_>,
    src: &[f64],
    w: usize,
    h: usize,
) -> Vec<f64> {
    let b3 = [1.0 / 16.0, 0.25, 0.375, 0.25, 1.0 / 16.0];
    let n = w * h;
    let hole = 1i64 << level;
    let nc = 3 * groups;
    let nout = nc + if with_var { 2 } else { 0 };
    let mut out = vec![0.0; nout * n];
    // The colour guide is the first image.
    let guide = |c: usize, i: usize| src[c * n + i];
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let p = (y * w as i64 + x) as usize;
            let (mut wsum, mut acc, mut accv) = (0.0, vec![0.0; nc], 0.0);
            for dy in 0..5i64 {
                for dx in 0..5i64 {
                    let (qy, qx) = (y + (dy - 2) * hole, x + (dx - 2) * hole);
                    if qy < 0 || qx < 0 || qy >= h as i64 || qx >= w as i64 {
                        continue;
                    }
                    let q = (qy * w as i64 + qx) as usize;
                    let dc: f64 = (0..3).map(|c| (guide(c, p) - guide(c, q)).powi(2)).sum();
                    let v = g.noise[p].min(g.noise[q]).max(0.0);
                    let mut t = dc / (phi / hole as f64 * v + eps);
                    if let Some(nm) = g.normal {
                        let dn: f64 = (0..3).map(|c| (nm[c * n + p] - nm[c * n + q]).powi(2)).sum();
                        t += dn / (sigma_n * sigma_n);
                    }
                    match (g.normal, g.position, g.depth) {
                        (Some(nm), Some(pos), _) => {
                            // The mean of the two pixels' squared tangent-plane distances.
                            let along = |i: usize| -> f64 {
                                (0..3).map(|c| nm[c * n + i] * (pos[c * n + q] - pos[c * n + p])).sum()
                            };
                            let (pd, qd) = (along(p), along(q));
                            t += 0.5 * (pd * pd + qd * qd) / (sigma_plane * sigma_plane);
                            if sigma_dist > 0.0 {
                                let d2: f64 = (0..3).map(|c| (pos[c * n + q] - pos[c * n + p]).powi(2)).sum();
                                t += d2 / (sigma_dist * sigma_dist);
                            }
                        }
                        (None, Some(pos), _) => {
                            let d2: f64 = (0..3).map(|c| (pos[c * n + q] - pos[c * n + p]).powi(2)).sum();
                            t += d2 / (sigma_plane * hole as f64).powi(2);
                        }
                        (_, None, Some(z)) => {
                            // Squared depth difference relative to both depths.
                            let r2 = (z[q] - z[p]).powi(2) / (z[p].max(1e-20) * z[q].max(1e-20));
                            t += r2 / (sigma_depth * hole as f64).powi(2);
                        }
                        _ => {}
                    }
                    let wt = b3[dy as usize] * b3[dx as usize] * (-t).exp();
                    wsum += wt;
                    for (c, a) in acc.iter_mut().enumerate() {
                        *a += wt * src[c * n + q];
                    }
                    if with_var {
                        accv += wt * wt * src[nc * n + q];
                    }
                }
            }
            for c in 0..nc {
                out[c * n + p] = acc[c] / wsum;
            }
            if with_var {
                out[nc * n + p] = accv / (wsum * wsum);
                out[(nc + 1) * n + p] = (9.0 / 64.0) / wsum;
            }
        }
    }
    out
}

/// The fused filter evaluated pixel by pixel without materialising kernel
/// maps (for full-size frames): same definition as [`fused`].
#[allow(clippy::too_many_arguments)]
pub fn fused_pixelwise(
    sizes: &[usize],
    imp: &[f64],
    fusion: Option<&[f64]>,
    albedo: Option<&[f64]>,
    rad: &[f64],
    c: usize,
    w: usize,
    h: usize,
) -> Vec<f64> {
    let m = sizes.len();
    let plane = w * h;
    let mut out = vec![0.0; c * plane];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let alpha: Vec<f64> = match fusion {
                Some(f) => {
                    let mx = (0..m).map(|i| clamp_logit(f[i * plane + p])).fold(f64::NEG_INFINITY, f64::max);
                    let e: Vec<f64> = (0..m).map(|i| (clamp_logit(f[i * plane + p]) - mx).exp()).collect();
                    let s: f64 = e.iter().sum();
                    e.iter().map(|v| v / s).collect()
                }
                None => vec![1.0; m],
            };
            for (i, &k) in sizes.iter().enumerate() {
                let r = (k / 2) as isize;
                let taps: Vec<(usize, usize)> = (-r..=r)
                    .flat_map(|dy| (-r..=r).map(move |dx| (dy, dx)))
                    .filter_map(|(dy, dx)| tap(y, x, dy, dx, w, h))
                    .collect();
                let mx = taps
                    .iter()
                    .map(|&(yy, xx)| clamp_logit(imp[i * plane + yy * w + xx]))
                    .fold(f64::NEG_INFINITY, f64::max);
                let mut den = 0.0;
                let mut num = vec![0.0; c];
                for &(yy, xx) in &taps {
                    let q = yy * w + xx;
                    let e = (clamp_logit(imp[i * plane + q]) - mx).exp();
                    den += e;
                    for ch in 0..c {
                        num[ch] += e * rad[ch * plane + q];
                    }
                }
                for ch in 0..c {
                    out[ch * plane + p] += alpha[i] * num[ch] / den;
                }
            }
            if let Some(a) = albedo {
                for ch in 0..c {
                    out[ch * plane + p] *= a[ch * plane + p];
                }
            }
        }
    }
    out
}

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
/// buffers exist, `|dpos|^2 < pos_limit^2` and `|dn|^2 < normal_limit^2`;
/// accepted taps renormalised. No tap: the colour, history 0; else
/// `alpha = max(1/(n+1), alpha_min)` and history `min(n + 1, cap)`.
/// Returns the colour (`c` planes) and the history (1 plane).
pub fn temporal(
    t: &TemporalRef<'_>,
    pos_limit: f64,
    normal_limit: f64,
    alpha_min: f64,
    history_cap: f64,
    radius: usize,
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
        pos_ok && n_ok
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
                    let prev = taps.iter().map(|&(q, wt)| wt * t.prev_color[ch * plane + q]).sum::<f64>() / ws;
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

/// The median of a list (the mean of the middle two of an even count).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len();
    if m % 2 == 1 {
        v[m / 2]
    } else {
        0.5 * (v[m / 2 - 1] + v[m / 2])
    }
}

/// The in-image values of the 3x3 neighbourhood of `(x, y)` in plane `c`.
fn neighbours(src: &[f64], c: usize, x: usize, y: usize, w: usize, h: usize, centre: bool) -> Vec<f64> {
    let mut v = Vec::new();
    for dy in -1..=1 {
        for dx in -1..=1 {
            if !centre && dx == 0 && dy == 0 {
                continue;
            }
            if let Some((yy, xx)) = tap(y, x, dy, dx, w, h) {
                v.push(src[ix(c, yy, xx, w, h)]);
            }
        }
    }
    v
}

/// Local noise variance of a single image: `0.84 |y - median of the in-image
/// 8 neighbours|^2`, mean over 3 channels (0 where a pixel has no neighbour).
pub fn local_noise(src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for c in 0..3 {
                let nb = neighbours(src, c, x, y, w, h, false);
                if !nb.is_empty() {
                    let d = src[ix(c, y, x, w, h)] - median(nb);
                    s += 0.84 * d * d;
                }
            }
            out[y * w + x] = s / 3.0;
        }
    }
    out
}

/// `1.27 x` the median of the in-image 3x3 neighbourhood (centre included).
pub fn median3(src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = 1.27 * median(neighbours(src, 0, x, y, w, h, true));
        }
    }
    out
}

// ---- gradients (the training engine's backward passes) --------------------
//
// Analytic f64 gradients written from the forward definitions above; the
// tests check each against central finite differences of the forward oracle.

/// The gradients of `z = conv(x) + b` (no activation) for the output
/// gradient `dz`: `(dx, dw, db)`.
#[allow(clippy::too_many_arguments)]
pub fn conv2d_grad(
    k: usize,
    cin: usize,
    cout: usize,
    weights: &[f64],
    src: &[f64],
    dz: &[f64],
    w: usize,
    h: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let r = (k / 2) as isize;
    let (mut dx, mut dw, mut db) = (vec![0.0; cin * w * h], vec![0.0; cout * cin * k * k], vec![0.0; cout]);
    for co in 0..cout {
        for y in 0..h {
            for x in 0..w {
                let g = dz[ix(co, y, x, w, h)];
                db[co] += g;
                for ci in 0..cin {
                    for ky in 0..k {
                        for kx in 0..k {
                            if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                                let wi = ((co * cin + ci) * k + ky) * k + kx;
                                dw[wi] += g * src[ix(ci, yy, xx, w, h)];
                                dx[ix(ci, yy, xx, w, h)] += g * weights[wi];
                            }
                        }
                    }
                }
            }
        }
    }
    (dx, dw, db)
}

/// The cell of fine pixel `(y, x)` and its in-image pixel count.
fn cell_count(y: usize, x: usize, w: usize, h: usize) -> f64 {
    let rows = if y / 2 * 2 + 1 < h { 2.0 } else { 1.0 };
    let cols = if x / 2 * 2 + 1 < w { 2.0 } else { 1.0 };
    rows * cols
}

/// The gradient of the 2x2 average pool of a `w x h` image.
pub fn avg_pool_grad(dy: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut dx = vec![0.0; c * w * h];
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                dx[ix(ch, y, x, w, h)] = dy[ix(ch, y / 2, x / 2, wc, hc)] / cell_count(y, x, w, h);
            }
        }
    }
    dx
}

/// The gradient of the 2x2 max pool: to each cell's first largest pixel.
pub fn max_pool_grad(src: &[f64], dy: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut dx = vec![0.0; c * w * h];
    for ch in 0..c {
        for yc in 0..hc {
            for xc in 0..wc {
                let mut best: Option<(usize, usize, f64)> = None;
                for y in 2 * yc..(2 * yc + 2).min(h) {
                    for x in 2 * xc..(2 * xc + 2).min(w) {
                        let v = src[ix(ch, y, x, w, h)];
                        if best.is_none_or(|b| v > b.2) {
                            best = Some((y, x, v));
                        }
                    }
                }
                if let Some((y, x, _)) = best {
                    dx[ix(ch, y, x, w, h)] = dy[ix(ch, yc, xc, wc, hc)];
                }
            }
        }
    }
    dx
}

/// The gradient of the nearest 2x upsample to `w x h`.
pub fn upsample_grad(dy: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut dx = vec![0.0; c * wc * hc];
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                dx[ix(ch, y / 2, x / 2, wc, hc)] += dy[ix(ch, y, x, w, h)];
            }
        }
    }
    dx
}

/// Bilinear 2x upsample (`align_corners = False`): fine `i` samples coarse
/// coordinate `(i + 0.5) / 2 - 0.5`, clamped to `[0, n - 1]`.
fn bilinear_taps(i: usize, n: usize) -> (usize, usize, f64) {
    let t = ((i as f64 + 0.5) / 2.0 - 0.5).clamp(0.0, (n - 1) as f64);
    let a = t.floor() as usize;
    let b = (a + 1).min(n - 1);
    (a, b, t - a as f64)
}

/// Bilinear 2x upsample of a `ceil(w/2) x ceil(h/2)` image to `w x h`.
pub fn upsample_bilinear(src: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0; c * w * h];
    for ch in 0..c {
        for y in 0..h {
            let (ya, yb, ty) = bilinear_taps(y, hc);
            for x in 0..w {
                let (xa, xb, tx) = bilinear_taps(x, wc);
                let v = |yy, xx| src[ix(ch, yy, xx, wc, hc)];
                let top = v(ya, xa) * (1.0 - tx) + v(ya, xb) * tx;
                let bot = v(yb, xa) * (1.0 - tx) + v(yb, xb) * tx;
                out[ix(ch, y, x, w, h)] = top * (1.0 - ty) + bot * ty;
            }
        }
    }
    out
}

/// The gradient of [`upsample_bilinear`].
pub fn upsample_bilinear_grad(dy: &[f64], c: usize, w: usize, h: usize) -> Vec<f64> {
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mut dx = vec![0.0; c * wc * hc];
    for ch in 0..c {
        for y in 0..h {
            let (ya, yb, ty) = bilinear_taps(y, hc);
            for x in 0..w {
                let (xa, xb, tx) = bilinear_taps(x, wc);
                let g = dy[ix(ch, y, x, w, h)];
                dx[ix(ch, ya, xa, wc, hc)] += g * (1.0 - ty) * (1.0 - tx);
                dx[ix(ch, ya, xb, wc, hc)] += g * (1.0 - ty) * tx;
                dx[ix(ch, yb, xa, wc, hc)] += g * ty * (1.0 - tx);
                dx[ix(ch, yb, xb, wc, hc)] += g * ty * tx;
            }
        }
    }
    dx
}

/// The gradients of [`composite`] (one alpha plane): `(d_fine, d_coarse, d_alpha)`.
pub fn composite_grad(
    fine: &[f64],
    coarse: &[f64],
    alpha: &[f64],
    g: &[f64],
    c: usize,
    w: usize,
    h: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let plane = w * h;
    let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
    let mean = reduce2x2(fine, c, w, h, false);
    let mut ag = vec![0.0; c * wc * hc];
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                ag[ix(ch, y / 2, x / 2, wc, hc)] += alpha[y * w + x] * g[ix(ch, y, x, w, h)];
            }
        }
    }
    let (mut df, mut da) = (vec![0.0; c * plane], vec![0.0; plane]);
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                let (i, ci) = (ix(ch, y, x, w, h), ix(ch, y / 2, x / 2, wc, hc));
                df[i] = g[i] - ag[ci] / cell_count(y, x, w, h);
                da[y * w + x] += g[i] * (coarse[ci] - mean[ci]);
            }
        }
    }
    (df, ag, da)
}

/// The gradient of the softmax over `n` planes, from its output `y`.
pub fn channel_softmax_grad(y: &[f64], dy: &[f64], n: usize, w: usize, h: usize) -> Vec<f64> {
    let plane = w * h;
    let mut dx = vec![0.0; n * plane];
    for p in 0..plane {
        let dot: f64 = (0..n).map(|c| y[c * plane + p] * dy[c * plane + p]).sum();
        for c in 0..n {
            dx[c * plane + p] = y[c * plane + p] * (dy[c * plane + p] - dot);
        }
    }
    dx
}

/// `1 / (1 + e^-x)`.
pub fn sigmoid(x: &[f64]) -> Vec<f64> {
    x.iter().map(|&v| 1.0 / (1.0 + (-v).exp())).collect()
}

/// The gradient of [`sigmoid`] from its output `y`: `dy y (1 - y)`.
pub fn sigmoid_grad(y: &[f64], dy: &[f64]) -> Vec<f64> {
    y.iter().zip(dy).map(|(&y, &g)| g * y * (1.0 - y)).collect()
}

/// The gradient of a LeakyReLU of slope `s` through its output `y`: `dy`
/// where `y > 0`, `s dy` elsewhere.
pub fn leaky_relu_grad(y: &[f64], dy: &[f64], s: f64) -> Vec<f64> {
    y.iter().zip(dy).map(|(&y, &g)| if y > 0.0 { g } else { s * g }).collect()
}

/// The gradients of the per-pixel kernel apply: `(d_kernel, d_src)`.
pub fn unfold_grad(
    k: usize,
    kernel: &[f64],
    src: &[f64],
    g: &[f64],
    c: usize,
    w: usize,
    h: usize,
) -> (Vec<f64>, Vec<f64>) {
    let r = (k / 2) as isize;
    let (mut dk, mut ds) = (vec![0.0; k * k * w * h], vec![0.0; c * w * h]);
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                let gv = g[ix(ch, y, x, w, h)];
                for ky in 0..k {
                    for kx in 0..k {
                        if let Some((yy, xx)) = tap(y, x, ky as isize - r, kx as isize - r, w, h) {
                            let j = ky * k + kx;
                            dk[ix(j, y, x, w, h)] += gv * src[ix(ch, yy, xx, w, h)];
                            ds[ix(ch, yy, xx, w, h)] += gv * kernel[ix(j, y, x, w, h)];
                        }
                    }
                }
            }
        }
    }
    (dk, ds)
}

/// The gradients of [`fused_pixelwise`] for the output gradient `g`:
/// `(d_importance, d_fusion, d_radiance)` (`d_fusion` empty without fusion
/// logits), each window with its own softmax, term by term.
#[allow(clippy::too_many_arguments)]
pub fn fused_grad(
    sizes: &[usize],
    imp: &[f64],
    fusion: Option<&[f64]>,
    albedo: Option<&[f64]>,
    rad: &[f64],
    g: &[f64],
    c: usize,
    w: usize,
    h: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let m = sizes.len();
    let plane = w * h;
    let (mut di, mut dc) = (vec![0.0; m * plane], vec![0.0; c * plane]);
    let mut dk = vec![0.0; m * plane];
    let alpha = match fusion {
        Some(f) => channel_softmax(f, m, w, h),
        None => vec![1.0; m * plane],
    };
    let alb = |ch: usize, p: usize| albedo.map_or(1.0, |a| a[ch * plane + p]);
    for (i, &k) in sizes.iter().enumerate() {
        let r = (k / 2) as isize;
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let taps: Vec<usize> = (-r..=r)
                    .flat_map(|dy| (-r..=r).map(move |dx| (dy, dx)))
                    .filter_map(|(dy, dx)| tap(y, x, dy, dx, w, h))
                    .map(|(yy, xx)| yy * w + xx)
                    .collect();
                let mx = taps.iter().map(|&q| clamp_logit(imp[i * plane + q])).fold(f64::NEG_INFINITY, f64::max);
                let e: Vec<f64> = taps.iter().map(|&q| (clamp_logit(imp[i * plane + q]) - mx).exp()).collect();
                let den: f64 = e.iter().sum();
                let rv: Vec<f64> = (0..c)
                    .map(|ch| taps.iter().zip(&e).map(|(&q, &ev)| ev * rad[ch * plane + q]).sum::<f64>() / den)
                    .collect();
                for ch in 0..c {
                    dk[i * plane + p] += g[ch * plane + p] * alb(ch, p) * rv[ch];
                    let gk = g[ch * plane + p] * alb(ch, p) * alpha[i * plane + p];
                    for (&q, &ev) in taps.iter().zip(&e) {
                        let wq = ev / den;
                        di[i * plane + q] += gk * wq * (rad[ch * plane + q] - rv[ch]);
                        dc[ch * plane + q] += gk * wq;
                    }
                }
            }
        }
    }
    let df = match fusion {
        Some(_) => channel_softmax_grad(&alpha, &dk, m, w, h),
        None => Vec::new(),
    };
    (di, df, dc)
}

// ---- cross-regression ----------------------------------------------------------

/// Mirrored index (`-1 -> 1`), periodic for windows wider than the image.
fn mirror_f(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let mut i = i;
    // Reflect until inside: the definition, step by step.
    loop {
        if i < 0 {
            i = -i;
        } else if i >= n as isize {
            i = 2 * (n as isize - 1) - i;
        } else {
            return i as usize;
        }
    }
}

/// Per-pixel variance: squared distance (summed over 3 channels) between a
/// pixel and the mean of its in-image 3x3 neighbours, the pixel excluded.
pub fn cross_variance(src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut v = 0.0;
            for c in 0..3 {
                let (mut s, mut n) = (0.0, 0usize);
                for dy in -1..=1isize {
                    for dx in -1..=1isize {
                        if (dy, dx) == (0, 0) {
                            continue;
                        }
                        if let Some((yy, xx)) = tap(y, x, dy, dx, w, h) {
                            s += src[ix(c, yy, xx, w, h)];
                            n += 1;
                        }
                    }
                }
                if n > 0 {
                    let d = s / n as f64 - src[ix(c, y, x, w, h)];
                    v += d * d;
                }
            }
            out[y * w + x] = v;
        }
    }
    out
}

/// The f64 cross-regression pilot: features and weights from `xs` (with
/// its variance `var`), fitted values from `ys`; see `mcdenoise_core::regress`.
/// Solves every centre with Gaussian elimination (partial pivoting).
pub fn cross_regression(xs: &[f64], var: &[f64], ys: &[f64], alb: &[f64], nrm: &[f64], w: usize, h: usize) -> Vec<f64> {
    const P: usize = 6;
    let at = |b: &[f64], c: usize, y: usize, x: usize| b[ix(c, y, x, w, h)];
    let weight = |cy: usize, cx: usize, y: usize, x: usize| {
        let d: f64 = (0..3).map(|c| (at(xs, c, y, x) - at(xs, c, cy, cx)).powi(2)).sum();
        (-d / (var[cy * w + cx] + var[y * w + x] + 1e-4)).exp() + 1e-7
    };
    let row = |cy: usize, cx: usize, y: usize, x: usize, k: usize| -> [f64; P] {
        let sd = |y: usize, x: usize| var[y * w + x].max(0.0).sqrt();
        [
            1.0,
            (at(xs, k, y, x) - at(xs, k, cy, cx)) / (sd(cy, cx) + sd(y, x) + 0.01),
            at(alb, k, y, x) - at(alb, k, cy, cx),
            at(nrm, 0, y, x) - at(nrm, 0, cy, cx),
            at(nrm, 1, y, x) - at(nrm, 1, cy, cx),
            at(nrm, 2, y, x) - at(nrm, 2, cy, cx),
        ]
    };
    let (ncx, ncy) = (w.div_ceil(4), h.div_ceil(4));
    // Coefficients of every centre: [cy][cx][k][P].
    let mut beta = vec![[[0.0f64; P]; 3]; ncx * ncy];
    for j in 0..ncy {
        for i in 0..ncx {
            let (cy, cx) = (4 * j, 4 * i);
            for k in 0..3 {
                let mut a = [[0.0f64; P + 1]; P];
                for dy in -8..=8isize {
                    for dx in -8..=8isize {
                        let (y, x) = (mirror_f(cy as isize + dy, h), mirror_f(cx as isize + dx, w));
                        let wt = weight(cy, cx, y, x);
                        let d = row(cy, cx, y, x, k);
                        for p in 0..P {
                            for q in 0..P {
                                a[p][q] += wt * d[p] * d[q];
                            }
                            a[p][P] += wt * d[p] * at(ys, k, y, x);
                        }
                    }
                }
                for p in 0..P {
                    a[p][p] += 1e-3;
                }
                // Gaussian elimination with partial pivoting.
                for col in 0..P {
                    let piv = (col..P).max_by(|&r1, &r2| a[r1][col].abs().total_cmp(&a[r2][col].abs())).unwrap();
                    a.swap(col, piv);
                    for r in 0..P {
                        if r != col {
                            let f = a[r][col] / a[col][col];
                            for q in col..=P {
                                a[r][q] -= f * a[col][q];
                            }
                        }
                    }
                }
                for p in 0..P {
                    beta[j * ncx + i][k][p] = a[p][P] / a[p][p];
                }
            }
        }
    }
    let mut out = vec![0.0; 3 * w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f64; 3];
            let mut ws = 0.0;
            for j in 0..ncy {
                for i in 0..ncx {
                    let (cy, cx) = (4 * j, 4 * i);
                    if (cy as isize - y as isize).abs() > 8 || (cx as isize - x as isize).abs() > 8 {
                        continue;
                    }
                    let wt = weight(cy, cx, y, x);
                    ws += wt;
                    for k in 0..3 {
                        let d = row(cy, cx, y, x, k);
                        acc[k] += wt * (0..P).map(|p| beta[j * ncx + i][k][p] * d[p]).sum::<f64>();
                    }
                }
            }
            for k in 0..3 {
                out[ix(k, y, x, w, h)] = (acc[k] / ws).max(0.0);
            }
        }
    }
    out
}

/// The f64 spatiotemporal filter's inputs (full frames, planar).
#[derive(Clone, Copy, Debug)]
pub struct CrossFilter<'a> {
    /// Pilot A (3 planes).
    pub pa: &'a [f64],
    /// Pilot B (3 planes).
    pub pb: &'a [f64],
    /// Albedo (3 planes).
    pub alb: &'a [f64],
    /// Normal (3 planes).
    pub nrm: &'a [f64],
    /// Warped previous output (3 planes).
    pub prev: &'a [f64],
    /// Its validity (1 plane).
    pub valid: &'a [f64],
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
}

impl CrossFilter<'_> {
    /// Outputs A, B and combined at pixel `(x, y)` for the raw outputs `r`,
    /// and the derivatives of outputs A and B by each raw output
    /// (`d[j][0..3]` output A, `d[j][3..6]` output B).
    pub fn pixel(&self, x: usize, y: usize, r: &[f64; 6]) -> ([f64; 9], [[f64; 6]; 6]) {
        let (w, h) = (self.w, self.h);
        let k: Vec<f64> = (0..5).map(|j| 1.0 / (r[j] * r[j] + 1e-4)).collect();
        let dk: Vec<f64> = (0..5).map(|j| -2.0 * r[j] * k[j] * k[j]).collect();
        let alpha = 1.0 / (1.0 + (-r[5]).exp());
        let at = |b: &[f64], c: usize, y: usize, x: usize| b[ix(c, y, x, w, h)];
        let d2 =
            |b: &[f64], y1: usize, x1: usize| (0..3).map(|c| (at(b, c, y1, x1) - at(b, c, y, x)).powi(2)).sum::<f64>();
        // Sums and their derivatives by the five bandwidth raw outputs.
        let mut s = [[0.0f64; 3]; 2];
        let mut ws = [0.0f64; 2];
        let mut ds = [[[0.0f64; 3]; 2]; 5];
        let mut dws = [[0.0f64; 2]; 5];
        for dy in -5..=5isize {
            for dx in -5..=5isize {
                let (yy, xx) = (mirror_f(y as isize + dy, h), mirror_f(x as isize + dx, w));
                let pd = ((dx * dx + dy * dy) as f64) / 25.0;
                let (dl, dn) = (d2(self.alb, yy, xx), d2(self.nrm, yy, xx));
                for (p, buf) in [self.pa, self.pb].into_iter().enumerate() {
                    let dc = d2(buf, yy, xx);
                    let e = k[p] * dc + k[2] * dl + k[3] * dn + k[4] * pd;
                    let wt = (-e).exp();
                    // d e / d r_j.
                    let mut de = [0.0f64; 5];
                    de[p] = dk[p] * dc;
                    de[2] = dk[2] * dl;
                    de[3] = dk[3] * dn;
                    de[4] = dk[4] * pd;
                    ws[p] += wt;
                    for c in 0..3 {
                        s[p][c] += wt * at(buf, c, yy, xx);
                    }
                    for j in 0..5 {
                        let dw = -wt * de[j];
                        dws[j][p] += dw;
                        for c in 0..3 {
                            ds[j][p][c] += dw * at(buf, c, yy, xx);
                        }
                    }
                }
            }
        }
        let v = self.valid[y * w + x];
        let a = v * alpha + 1.0 - v;
        let mut out = [0.0f64; 9];
        let mut d = [[0.0f64; 6]; 6];
        for c in 0..3 {
            let q = at(self.prev, c, y, x);
            let sp = [s[0][c] / ws[0], s[1][c] / ws[1]];
            out[c] = a * sp[0] + (1.0 - a) * q;
            out[3 + c] = a * sp[1] + (1.0 - a) * q;
            out[6 + c] = a * (s[0][c] + s[1][c]) / (ws[0] + ws[1]) + (1.0 - a) * q;
            for p in 0..2 {
                for j in 0..5 {
                    let dsp = (ds[j][p][c] * ws[p] - s[p][c] * dws[j][p]) / (ws[p] * ws[p]);
                    d[j][3 * p + c] = a * dsp;
                }
                d[5][3 * p + c] = v * alpha * (1.0 - alpha) * (sp[p] - q);
            }
        }
        (out, d)
    }

    /// The filter over the frame: 9 planes (outputs A, B, combined).
    pub fn forward(&self, params: &[f64]) -> Vec<f64> {
        let (w, h) = (self.w, self.h);
        let mut out = vec![0.0; 9 * w * h];
        for y in 0..h {
            for x in 0..w {
                let r: [f64; 6] = std::array::from_fn(|j| params[ix(j, y, x, w, h)]);
                let (o, _) = self.pixel(x, y, &r);
                for c in 0..9 {
                    out[ix(c, y, x, w, h)] = o[c];
                }
            }
        }
        out
    }

    /// The raw outputs' gradient (6 planes) for the gradients `g` of
    /// outputs A and B (6 planes).
    pub fn backward(&self, params: &[f64], g: &[f64]) -> Vec<f64> {
        let (w, h) = (self.w, self.h);
        let mut out = vec![0.0; 6 * w * h];
        for y in 0..h {
            for x in 0..w {
                let r: [f64; 6] = std::array::from_fn(|j| params[ix(j, y, x, w, h)]);
                let (_, d) = self.pixel(x, y, &r);
                for j in 0..6 {
                    out[ix(j, y, x, w, h)] = (0..6).map(|o| d[j][o] * g[ix(o, y, x, w, h)]).sum();
                }
            }
        }
        out
    }
}

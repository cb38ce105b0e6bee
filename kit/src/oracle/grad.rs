//! Gradients (the training engine's backward passes).

// Analytic f64 gradients written from the forward definitions in the
// sibling files; the tests check each against central finite differences
// of the forward oracle.

use super::pool::bilinear_taps;
use super::{channel_softmax, clamp_logit, ix, reduce2x2, tap};

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

/// The gradient of [`upsample_bilinear`](super::upsample_bilinear).
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

/// The gradients of [`composite`](super::composite) (one alpha plane): `(d_fine, d_coarse, d_alpha)`.
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

/// The gradients of [`fused_pixelwise`](super::fused_pixelwise) for the output gradient `g`:
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

//! The per-pixel kernels: apply, importance kernels, window and fused filters, channel softmax.

use super::{clamp_logit, ix, tap};

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

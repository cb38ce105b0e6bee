//! Resampling: 2x2 reductions, nearest and bilinear 2x upsampling, the scale compositor.

use super::ix;

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

/// Bilinear 2x upsample (`align_corners = False`): fine `i` samples coarse
/// coordinate `(i + 0.5) / 2 - 0.5`, clamped to `[0, n - 1]`.
pub(super) fn bilinear_taps(i: usize, n: usize) -> (usize, usize, f64) {
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

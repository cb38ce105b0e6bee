//! The convolution.

use super::{ix, tap};

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

//! Cross-regression: the per-pixel variance, the regression pilot and the spatiotemporal filter.

use super::{ix, tap};

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

//! Image error metrics against a reference, all over the three colour planes.
//!
//! | metric | definition |
//! |---|---|
//! | PSNR | `10 log10(1 / MSE)` of `clamp(x, 0, 1)^(1/2.2)` against the same of the reference (dB) |
//! | SSIM | Wang et al. 2004 on the same display values: 11x11 Gaussian window, sigma 1.5, `C1 = 0.01^2`, `C2 = 0.03^2`, mean over pixels and channels; windows are clipped at the border |
//! | relMSE | mean of `(x - r)^2 / (r^2 + 0.01)` on linear values |
//! | SMAPE | mean of `|x - r| / (|x| + |r| + 0.01)` on linear values |
//! | RMSE | `sqrt(mean (x - r)^2)` on linear values |
//! | flicker | of a sequence: `sqrt(mean ((d(x_t) - d(x_{t-1})) - (d(r_t) - d(r_{t-1})))^2)` over frames `t >= 1`, `d` the display map above: the error of the frame-to-frame change (temporal instability beyond the reference's own change) |
//!
//! Sums run in f64. Non-finite values count as 0 (the input contract's rule).

/// Every metric of one image against its reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scores {
    /// dB; `inf` for identical images.
    pub psnr: f64,
    /// In [-1, 1].
    pub ssim: f64,
    /// Relative MSE.
    pub relmse: f64,
    /// Symmetric mean absolute percentage error.
    pub smape: f64,
    /// Root mean squared error (linear).
    pub rmse: f64,
}

fn finite(v: f32) -> f64 {
    if v.is_finite() {
        v as f64
    } else {
        0.0
    }
}

/// `clamp(x, 0, 1)^(1/2.2)`.
pub fn display(v: f32) -> f64 {
    finite(v).clamp(0.0, 1.0).powf(1.0 / 2.2)
}

/// The mean of `((d(x) - d(px)) - (d(r) - d(pr)))^2` of one frame pair (see
/// the flicker row above); the sequence's flicker is the square root of its
/// mean over the frames.
pub fn flicker_mse(px: &[f32], x: &[f32], pr: &[f32], r: &[f32]) -> f64 {
    assert!(px.len() == x.len() && pr.len() == r.len() && x.len() == r.len());
    let mut se = 0.0;
    for i in 0..x.len() {
        let d = (display(x[i]) - display(px[i])) - (display(r[i]) - display(pr[i]));
        se += d * d;
    }
    se / x.len().max(1) as f64
}

/// All metrics of `x` against `r` (3 planes of `w x h` each).
pub fn score(x: &[f32], r: &[f32], w: usize, h: usize) -> Scores {
    assert_eq!(x.len(), r.len());
    assert_eq!(x.len(), 3 * w * h);
    let n = x.len() as f64;
    let (mut se_d, mut rel, mut sm, mut se) = (0.0, 0.0, 0.0, 0.0);
    for (&a, &b) in x.iter().zip(r) {
        let (a, b) = (finite(a), finite(b));
        let d = display(a as f32) - display(b as f32);
        se_d += d * d;
        rel += (a - b) * (a - b) / (b * b + 0.01);
        sm += (a - b).abs() / (a.abs() + b.abs() + 0.01);
        se += (a - b) * (a - b);
    }
    let mse_d = se_d / n;
    Scores {
        psnr: if mse_d == 0.0 { f64::INFINITY } else { 10.0 * (1.0 / mse_d).log10() },
        ssim: ssim(x, r, w, h),
        relmse: rel / n,
        smape: sm / n,
        rmse: (se / n).sqrt(),
    }
}

/// Mean SSIM over the three planes of display values.
pub fn ssim(x: &[f32], r: &[f32], w: usize, h: usize) -> f64 {
    const RADIUS: usize = 5;
    const SIGMA: f64 = 1.5;
    let g: Vec<f64> =
        (0..=2 * RADIUS).map(|i| (-((i as f64 - RADIUS as f64).powi(2)) / (2.0 * SIGMA * SIGMA)).exp()).collect();
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let plane = w * h;
    let mut total = 0.0;
    for c in 0..3 {
        let a: Vec<f64> = x[c * plane..(c + 1) * plane].iter().map(|&v| display(v)).collect();
        let b: Vec<f64> = r[c * plane..(c + 1) * plane].iter().map(|&v| display(v)).collect();
        // Separable Gaussian moments: mean a, mean b, a^2, b^2, ab.
        let fields: [Vec<f64>; 5] = [
            a.clone(),
            b.clone(),
            a.iter().map(|v| v * v).collect(),
            b.iter().map(|v| v * v).collect(),
            a.iter().zip(&b).map(|(p, q)| p * q).collect(),
        ];
        let blurred: Vec<Vec<f64>> = fields.iter().map(|f| blur(f, w, h, &g, RADIUS)).collect();
        let mut s = 0.0;
        let [m_a, m_b, m_aa, m_bb, m_ab] = &blurred[..] else { unreachable!() };
        for p in 0..plane {
            let (ma, mb) = (m_a[p], m_b[p]);
            let va = (m_aa[p] - ma * ma).max(0.0);
            let vb = (m_bb[p] - mb * mb).max(0.0);
            let cov = m_ab[p] - ma * mb;
            s += ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
        }
        total += s / plane as f64;
    }
    total / 3.0
}

/// Normalised separable Gaussian blur with the window clipped at the border.
fn blur(f: &[f64], w: usize, h: usize, g: &[f64], r: usize) -> Vec<f64> {
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut ws) = (0.0, 0.0);
            for (i, &gv) in g.iter().enumerate() {
                let xx = x as isize + i as isize - r as isize;
                if xx >= 0 && (xx as usize) < w {
                    s += gv * f[y * w + xx as usize];
                    ws += gv;
                }
            }
            tmp[y * w + x] = s / ws;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut ws) = (0.0, 0.0);
            for (i, &gv) in g.iter().enumerate() {
                let yy = y as isize + i as isize - r as isize;
                if yy >= 0 && (yy as usize) < h {
                    s += gv * tmp[yy as usize * w + x];
                    ws += gv;
                }
            }
            out[y * w + x] = s / ws;
        }
    }
    out
}

/// Mean squared error on linear values (for tables that quote MSE).
pub fn mse(x: &[f32], r: &[f32]) -> f64 {
    x.iter().zip(r).map(|(&a, &b)| (finite(a) - finite(b)).powi(2)).sum::<f64>() / x.len() as f64
}

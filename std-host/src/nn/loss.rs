//! Losses on linear HDR values, each with its gradient, averaged over the
//! elements: SMAPE `|x - r| / (|x| + |r| + eps)` (WSKP's, eps 0.01), relMSE
//! `(x - r)^2 / (r^2 + eps)` (eps 0.01) and L1 `|x - r|`.

/// Which loss.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Loss {
    /// Symmetric mean absolute percentage error, eps 0.01.
    Smape,
    /// Relative mean squared error, eps 0.01.
    #[value(name = "relmse")]
    RelMse,
    /// Mean absolute error.
    L1,
}

impl Loss {
    /// By name (`smape`, `relmse`, `l1`).
    pub fn parse(s: &str) -> Option<Loss> {
        match s {
            "smape" => Some(Loss::Smape),
            "relmse" => Some(Loss::RelMse),
            "l1" => Some(Loss::L1),
            _ => None,
        }
    }

    /// The name.
    pub fn name(self) -> &'static str {
        match self {
            Loss::Smape => "smape",
            Loss::RelMse => "relmse",
            Loss::L1 => "l1",
        }
    }

    /// The mean loss of `x` against `r`, and its gradient (of the mean) into
    /// `grad`, scaled by `scale` (e.g. 1 / batch).
    pub fn eval(self, x: &[f32], r: &[f32], grad: &mut [f32], scale: f32) -> f32 {
        let n = x.len().max(1) as f32;
        let k = scale / n;
        let mut total = 0.0f64;
        for ((g, &a), &b) in grad.iter_mut().zip(x).zip(r) {
            let d = a - b;
            let (l, dl) = match self {
                Loss::Smape => {
                    let den = a.abs() + b.abs() + 0.01;
                    let sd = if d > 0.0 {
                        1.0
                    } else if d < 0.0 {
                        -1.0
                    } else {
                        0.0
                    };
                    let sa = if a > 0.0 {
                        1.0
                    } else if a < 0.0 {
                        -1.0
                    } else {
                        0.0
                    };
                    (d.abs() / den, (sd * den - d.abs() * sa) / (den * den))
                }
                Loss::RelMse => {
                    let den = b * b + 0.01;
                    (d * d / den, 2.0 * d / den)
                }
                Loss::L1 => (
                    d.abs(),
                    if d > 0.0 {
                        1.0
                    } else if d < 0.0 {
                        -1.0
                    } else {
                        0.0
                    },
                ),
            };
            total += l as f64;
            *g = dl * k;
        }
        (total / n as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradients_match_finite_differences() {
        let x = [0.3f32, -0.2, 2.0, 0.011, 5.0, 0.0];
        let r = [0.25f32, 0.1, 2.5, 0.0, 4.0, 0.7];
        for loss in [Loss::Smape, Loss::RelMse, Loss::L1] {
            let mut g = [0.0f32; 6];
            loss.eval(&x, &r, &mut g, 1.0);
            for i in 0..6 {
                let h = 1e-3f64;
                let f = |d: f64| {
                    let mut v: Vec<f64> = x.iter().map(|&a| a as f64).collect();
                    v[i] += d;
                    let xs: Vec<f32> = v.iter().map(|&a| a as f32).collect();
                    let mut t = [0.0f32; 6];
                    loss.eval(&xs, &r, &mut t, 1.0) as f64
                };
                let fd = (f(h) - f(-h)) / (2.0 * h);
                // Central differences of an f32 loss with h = 1e-3: accurate to ~1e-3 relative where the loss bends.
                assert!((fd - g[i] as f64).abs() < 2e-3 + 5e-3 * fd.abs(), "{loss:?} element {i}: {} vs {fd}", g[i]);
            }
        }
    }
}

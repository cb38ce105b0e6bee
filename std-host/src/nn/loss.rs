//! Losses on linear HDR values, each with its gradient, averaged over the
//! elements, on the values times the frame's exposure `e` (so that `eps`
//! is relative to the frame's level, and a frame scaled by `k` trains as
//! the frame itself): SMAPE `|x - r| / (|x| + |r| + eps)` (WSKP's, eps
//! 0.01), relMSE `(x - r)^2 / (r^2 + eps)` (eps 0.01), L1 `|x - r|`, and
//! the noisy-target relMSE `(x - r)^2 / (sg(x)^2 + eps)`, and L1 in a
//! log space, `|s(x) - s(r)|` with `s(v) = sign(v) ln(1 + |v|)`.
//!
//! The noisy-target relMSE is the loss for targets rendered at a modest
//! sample count (Noise2Noise, Lehtinen et al. 2018): an L2-type loss whose
//! normaliser does not depend on the target is minimised by the target's
//! mean, so an unbiased noisy target trains to the same network as a
//! converged one (relMSE and SMAPE normalise by the target and are biased
//! by its noise). The normaliser is the output with its gradient stopped
//! (`sg`), as in that paper's HDR loss.
//!
//! It and L1 in log space differ on outliers. relMSE normalised by the
//! output costs a pixel at most about 1 where the output is far above the
//! target (a firefly kept: `(x - r)^2 / x^2 -> 1`) and without bound where
//! it is far below (a firefly of the target under a dark output), so it is
//! lenient with fireflies left in the output and spiky with those of a
//! noisy target. L1 in log space costs a firefly kept the log of its ratio
//! either way (robust, as Intel Open Image Denoise's L1 on a transfer
//! curve); its minimiser is the target's median in that space, not its
//! mean, so with noisy targets it is biased low where they are noisy.
//! L1 in log space is the default of `mcdenoise train`: on the same data,
//! steps and seed, WSKP-3 trained with it validates 0.35 dB higher than
//! with the noisy-target relMSE (docs/training.md).

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
    /// relMSE normalised by the output with its gradient stopped, eps 0.01:
    /// for noisy targets.
    #[value(name = "relmse-n2n")]
    RelMseN2n,
    /// L1 of `sign(v) ln(1 + |v|)`: robust to fireflies on either side.
    #[value(name = "l1-log")]
    L1Log,
}

impl Loss {
    /// By name (`smape`, `relmse`, `l1`).
    pub fn parse(s: &str) -> Option<Loss> {
        match s {
            "smape" => Some(Loss::Smape),
            "relmse" => Some(Loss::RelMse),
            "l1" => Some(Loss::L1),
            "relmse-n2n" => Some(Loss::RelMseN2n),
            "l1-log" => Some(Loss::L1Log),
            _ => None,
        }
    }

    /// The name.
    pub fn name(self) -> &'static str {
        match self {
            Loss::Smape => "smape",
            Loss::RelMse => "relmse",
            Loss::L1 => "l1",
            Loss::RelMseN2n => "relmse-n2n",
            Loss::L1Log => "l1-log",
        }
    }

    /// The mean loss of `x` against `r` times `exposure`, and its gradient
    /// (of the mean, with respect to `x`) into `grad`, scaled by `scale`
    /// (e.g. 1 / batch).
    pub fn eval(self, x: &[f32], r: &[f32], grad: &mut [f32], scale: f32, exposure: f32) -> f32 {
        let n = x.len().max(1) as f32;
        let e = if exposure > 0.0 && exposure.is_finite() { exposure } else { 1.0 };
        let k = scale / n * e;
        let mut total = 0.0f64;
        for ((g, &a), &b) in grad.iter_mut().zip(x).zip(r) {
            let (a, b) = (a * e, b * e);
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
                Loss::RelMseN2n => {
                    let den = a * a + 0.01;
                    (d * d / den, 2.0 * d / den)
                }
                Loss::L1Log => {
                    let (sa, sb) = (a.signum() * a.abs().ln_1p(), b.signum() * b.abs().ln_1p());
                    let dd = sa - sb;
                    let sg = if dd > 0.0 {
                        1.0
                    } else if dd < 0.0 {
                        -1.0
                    } else {
                        0.0
                    };
                    (dd.abs(), sg / (1.0 + a.abs()))
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

    /// The exposure scales values, not the loss's shape: the loss of `x`
    /// at exposure `e` is the loss of `e x` at 1, its gradient `e` times.
    #[test]
    fn exposure_scales_the_values() {
        let x = [0.3f32, 2.0, 0.011];
        let r = [0.25f32, 2.5, 0.0];
        for loss in [Loss::Smape, Loss::RelMse, Loss::L1, Loss::RelMseN2n, Loss::L1Log] {
            let (mut g1, mut g2) = ([0.0f32; 3], [0.0f32; 3]);
            let l1 = loss.eval(&x, &r, &mut g1, 1.0, 4.0);
            let (xs, rs) = (x.map(|v| 4.0 * v), r.map(|v| 4.0 * v));
            let l2 = loss.eval(&xs, &rs, &mut g2, 1.0, 1.0);
            assert!((l1 - l2).abs() <= 1e-6 * l2.abs().max(1.0), "{loss:?}");
            for (a, b) in g1.iter().zip(&g2) {
                assert!((a - 4.0 * b).abs() <= 1e-5 * b.abs().max(1.0), "{loss:?}: {a} {b}");
            }
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let x = [0.3f32, -0.2, 2.0, 0.011, 5.0, 0.0];
        let r = [0.25f32, 0.1, 2.5, 0.0, 4.0, 0.7];
        for loss in [Loss::Smape, Loss::RelMse, Loss::L1, Loss::RelMseN2n, Loss::L1Log] {
            let mut g = [0.0f32; 6];
            loss.eval(&x, &r, &mut g, 1.0, 1.0);
            for i in 0..6 {
                let h = 1e-3f64;
                let f = |d: f64| {
                    let mut v: Vec<f64> = x.iter().map(|&a| a as f64).collect();
                    v[i] += d;
                    let xs: Vec<f32> = v.iter().map(|&a| a as f32).collect();
                    let mut t = [0.0f32; 6];
                    match loss {
                        // The normaliser's gradient is stopped: hold it at x.
                        Loss::RelMseN2n => {
                            let a = xs[i] as f64;
                            let b = r[i] as f64;
                            let den = (x[i] as f64).powi(2) + 0.01;
                            let rest: f64 = (0..6)
                                .filter(|&j| j != i)
                                .map(|j| {
                                    let dj = (x[j] - r[j]) as f64;
                                    dj * dj / ((x[j] as f64).powi(2) + 0.01)
                                })
                                .sum();
                            ((a - b) * (a - b) / den + rest) / 6.0
                        }
                        _ => loss.eval(&xs, &r, &mut t, 1.0, 1.0) as f64,
                    }
                };
                let fd = (f(h) - f(-h)) / (2.0 * h);
                // Central differences of an f32 loss with h = 1e-3: accurate to ~1e-3 relative where the loss bends.
                assert!((fd - g[i] as f64).abs() < 2e-3 + 5e-3 * fd.abs(), "{loss:?} element {i}: {} vs {fd}", g[i]);
            }
        }
    }

    /// L1 in log space against an f64 oracle of its definition, on values
    /// from negative to firefly-bright; a firefly kept costs the log of its
    /// ratio.
    #[test]
    fn l1_log_is_its_definition() {
        let x = [0.3f32, -0.2, 2.0, 0.0, 5000.0, 1.0, 1e-4];
        let r = [0.25f32, 0.1, 2.5, 0.0, 1.0, 3000.0, 0.0];
        let s = |v: f64| v.signum() * (1.0 + v.abs()).ln();
        let want: f64 = x.iter().zip(&r).map(|(&a, &b)| (s(a as f64) - s(b as f64)).abs()).sum::<f64>() / 7.0;
        let mut g = [0.0f32; 7];
        let got = Loss::L1Log.eval(&x, &r, &mut g, 1.0, 1.0) as f64;
        assert!((got - want).abs() <= 1e-6 * want, "{got} vs {want}");
        let mut g1 = [0.0f32; 1];
        let firefly = Loss::L1Log.eval(&[100.0], &[1.0], &mut g1, 1.0, 1.0) as f64;
        assert!((firefly - (101.0f64 / 2.0).ln()).abs() < 1e-5, "{firefly}");
    }
}

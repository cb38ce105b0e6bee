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
//!
//! A band term can be added to any of them ([`Objective`]): the L1 of the
//! log-space error `s(x) - s(r)` band-passed as the difference of two box
//! means (5x5 minus 17x17, zero outside the crop), which a per-pixel loss
//! barely sees: an output's low-frequency blotches on a flat wall cost it
//! little per pixel, since they are small beside the noise of a 1-spp
//! input's neighbours, but they are what the eye sees (docs/quality.md,
//! "Blotches on flat walls", measures the same band with `tools/blotch.py`).

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

/// The band term's two box radii (5x5 and 17x17 windows).
pub const BAND_RADII: (usize, usize) = (2, 8);

/// A loss and the weight of the band term beside it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Objective {
    /// The per-element loss.
    pub loss: Loss,
    /// The band term's weight (0: none; [`band_l1_log`]).
    pub band: f32,
}

impl From<Loss> for Objective {
    fn from(loss: Loss) -> Self {
        Objective { loss, band: 0.0 }
    }
}

impl Objective {
    /// The loss of `x` against `r` (planes of `w` x `h`) times `exposure`,
    /// plus `band` times the band term, and the gradient of the sum into
    /// `grad`, scaled by `scale` ([`Loss::eval`]).
    #[allow(clippy::too_many_arguments)]
    pub fn eval(self, x: &[f32], r: &[f32], grad: &mut [f32], w: usize, h: usize, scale: f32, exposure: f32) -> f32 {
        let l = self.loss.eval(x, r, grad, scale, exposure);
        if self.band > 0.0 && w * h > 0 {
            l + self.band * band_l1_log(x, r, grad, w, h, self.band * scale, exposure)
        } else {
            l
        }
    }
}

/// The band-passed operator `B a = box_2(a) - box_8(a)` ([`BAND_RADII`]):
/// each box the mean over the `(2r+1)^2` window with zero outside the
/// plane (the same divisor everywhere, so `B` is symmetric: its transpose
/// is itself).
fn band_pass(a: &[f32], out: &mut [f32], w: usize, h: usize) {
    use crate::methods::features::box_sum;
    let area = |r: usize| ((2 * r + 1) * (2 * r + 1)) as f32;
    let (r0, r1) = BAND_RADII;
    let mut wide = a.to_vec();
    out.copy_from_slice(a);
    box_sum(out, w, h, r0);
    box_sum(&mut wide, w, h, r1);
    for (o, v) in out.iter_mut().zip(&wide) {
        *o = *o / area(r0) - v / area(r1);
    }
}

/// The band term: the mean over the elements of `|B (s(e x) - s(e r))|`,
/// per plane of `w` x `h` (`x.len() / (w h)` planes), with `s(v) = sign(v)
/// ln(1 + |v|)` and `B` the difference of the 5x5 and 17x17 box means
/// ([`BAND_RADII`]); its gradient with respect to `x`, times `scale`, is
/// added to `grad`.
pub fn band_l1_log(x: &[f32], r: &[f32], grad: &mut [f32], w: usize, h: usize, scale: f32, exposure: f32) -> f32 {
    let n = w * h;
    if n == 0 || x.is_empty() {
        return 0.0;
    }
    let e = if exposure > 0.0 && exposure.is_finite() { exposure } else { 1.0 };
    let s = |v: f32| v.signum() * v.abs().ln_1p();
    let (mut d, mut b) = (vec![0.0f32; n], vec![0.0f32; n]);
    let count = x.len() as f64;
    let mut total = 0.0f64;
    for ((xp, rp), gp) in x.chunks_exact(n).zip(r.chunks_exact(n)).zip(grad.chunks_exact_mut(n)) {
        for ((dv, &a), &t) in d.iter_mut().zip(xp).zip(rp) {
            *dv = s(e * a) - s(e * t);
        }
        band_pass(&d, &mut b, w, h);
        total += b.iter().map(|v| v.abs() as f64).sum::<f64>();
        // d/dd of sum |B d| is B^T sign(B d) = B sign(B d).
        for v in b.iter_mut() {
            *v = if *v > 0.0 {
                1.0
            } else if *v < 0.0 {
                -1.0
            } else {
                0.0
            };
        }
        band_pass(&b, &mut d, w, h);
        let k = scale as f64 / count * e as f64;
        for ((g, &a), &dv) in gp.iter_mut().zip(xp).zip(&d) {
            *g += (k * dv as f64 / (1.0 + (e * a).abs() as f64)) as f32;
        }
    }
    (total / count) as f32
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
    /// A xorshift sequence of values in `lo..hi`.
    fn values(seed: u32, len: usize, lo: f32, hi: f32) -> Vec<f32> {
        // (A small seed's first values are small: scramble it, skip some.)
        let mut next = crate::methods::test_noise::xorshift32(seed.wrapping_mul(0x9E37_79B9) | 1);
        (0..len + 8).map(|_| lo + (hi - lo) * (next() >> 8) as f32 / (1u32 << 24) as f32).skip(8).collect()
    }

    /// The band term against an f64 oracle of its definition: each box mean
    /// summed over the window's pixels inside the plane, divided by the
    /// whole window's size; planes smaller than the wide window included.
    #[test]
    fn band_term_is_its_definition() {
        let s = |v: f64| v.signum() * v.abs().ln_1p();
        for (w, h, exposure) in [(13usize, 10usize, 1.0f32), (30, 24, 0.25), (5, 40, 3.0)] {
            let n = w * h;
            let x = values(7 + w as u32, 3 * n, -0.2, 6.0);
            let r = values(99 + h as u32, 3 * n, 0.0, 5.0);
            let e = exposure as f64;
            let boxed = |d: &[f64], px: usize, py: usize, rad: usize| {
                let mut sum = 0.0;
                for qy in py.saturating_sub(rad)..(py + rad + 1).min(h) {
                    for qx in px.saturating_sub(rad)..(px + rad + 1).min(w) {
                        sum += d[qy * w + qx];
                    }
                }
                sum / ((2 * rad + 1) * (2 * rad + 1)) as f64
            };
            let mut want = 0.0;
            for c in 0..3 {
                let d: Vec<f64> = (0..n).map(|i| s(e * x[c * n + i] as f64) - s(e * r[c * n + i] as f64)).collect();
                for py in 0..h {
                    for px in 0..w {
                        want += (boxed(&d, px, py, BAND_RADII.0) - boxed(&d, px, py, BAND_RADII.1)).abs();
                    }
                }
            }
            want /= (3 * n) as f64;
            let mut g = vec![0.0f32; 3 * n];
            let got = band_l1_log(&x, &r, &mut g, w, h, 1.0, exposure) as f64;
            assert!((got - want).abs() <= 1e-5 * want.max(1e-3), "{w}x{h}: {got} vs {want}");
        }
    }

    /// The band term's gradient (added to what the loss wrote) against
    /// central differences of the objective, on a plane smaller than the wide
    /// window and one larger.
    #[test]
    fn band_gradient_matches_finite_differences() {
        for (w, h) in [(9usize, 7usize), (21, 19)] {
            let n = w * h;
            let x = values(3, 3 * n, 0.0, 4.0);
            let r = values(5, 3 * n, 0.0, 4.0);
            let obj = Objective { loss: Loss::L1Log, band: 2.5 };
            let mut g = vec![0.0f32; 3 * n];
            obj.eval(&x, &r, &mut g, w, h, 0.5, 1.5);
            let f = |i: usize, d: f64| {
                let mut xs = x.clone();
                xs[i] = (xs[i] as f64 + d) as f32;
                let mut t = vec![0.0f32; 3 * n];
                obj.eval(&xs, &r, &mut t, w, h, 0.5, 1.5) as f64 * 0.5
            };
            for i in (0..3 * n).step_by(7) {
                let hd = 1e-3;
                let fd = (f(i, hd) - f(i, -hd)) / (2.0 * hd);
                assert!((fd - g[i] as f64).abs() < 1e-4 + 1e-2 * fd.abs(), "{w}x{h} element {i}: {} vs {fd}", g[i]);
            }
        }
    }

    /// With no band weight the objective is the loss, value and gradient.
    #[test]
    fn no_band_is_the_loss() {
        let (w, h) = (11, 6);
        let x = values(1, 3 * w * h, 0.0, 3.0);
        let r = values(2, 3 * w * h, 0.0, 3.0);
        let (mut g1, mut g2) = (vec![0.0f32; 3 * w * h], vec![0.0f32; 3 * w * h]);
        let a = Objective::from(Loss::L1Log).eval(&x, &r, &mut g1, w, h, 0.3, 2.0);
        let b = Loss::L1Log.eval(&x, &r, &mut g2, 0.3, 2.0);
        assert_eq!(a, b);
        assert_eq!(g1, g2);
    }

    /// What the term is for: an error in 8-pixel blotches costs it many times
    /// what a pixel-scale error of the same per-pixel size does, which the
    /// per-pixel L1 in log space prices the same.
    #[test]
    fn blotches_cost_more_than_pixel_noise() {
        let (w, h) = (64, 64);
        let r = vec![1.0f32; w * h];
        // Up to 1.5 or down to 0.6: the same distance in log space,
        // ln(2.5 / 2) = ln(2 / 1.6).
        let down = 0.6f32;
        let pixel: Vec<f32> = (0..w * h).map(|i| if (i % w + i / w) % 2 == 0 { 1.5 } else { down }).collect();
        let blotch: Vec<f32> =
            (0..w * h).map(|i| if ((i % w) / 8 + (i / w) / 8) % 2 == 0 { 1.5 } else { down }).collect();
        let mut g = vec![0.0f32; w * h];
        let (lp, lb) =
            (Loss::L1Log.eval(&pixel, &r, &mut g, 1.0, 1.0), Loss::L1Log.eval(&blotch, &r, &mut g, 1.0, 1.0));
        assert!((lp - lb).abs() < 1e-6 * lp, "the same per-pixel loss: {lp} {lb}");
        let bp = band_l1_log(&pixel, &r, &mut g, w, h, 1.0, 1.0);
        let bb = band_l1_log(&blotch, &r, &mut g, w, h, 1.0, 1.0);
        assert!(bb > 5.0 * bp, "blotches {bb}, pixel noise {bp}");
    }
}

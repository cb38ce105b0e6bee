//! Cross-regression's core operators against the f64 oracle and their
//! identities, on every instruction set this CPU has and odd widths (1, 9,
//! 17): the regression reproduces an exactly linear image, the filter's
//! weights normalise (a constant image comes back unchanged), its backward
//! pass matches central finite differences of the f64 forward oracle, bands
//! compose bit-identically, scratch filled with garbage changes nothing,
//! and bad shapes are errors, not panics.

#![allow(clippy::needless_range_loop)]

use mcdenoise_core::regress::{self, FilterInputs, RegressionInputs};
use mcdenoise_core::Isa;
use mcdenoise_kit::registry::{errors, op, Config, Inputs, Layout};
use mcdenoise_tests::{isas_under_test, oracle, Img};
use proptest::prelude::*;

fn cfg(cases: u32) -> ProptestConfig {
    ProptestConfig { cases: mcdenoise_tests::cases(cases), ..ProptestConfig::default() }
}

fn width() -> impl Strategy<Value = usize> {
    prop_oneof![Just(1usize), Just(9), Just(17)]
}

/// The registry's cross-regression operators against their oracles (every
/// ISA, odd sizes, with padding), 1 and 3 threads bit-identical.
#[test]
fn registry_operators_match_the_oracle() {
    let one = mcdenoise::runtime::par::Pool::new(1).unwrap();
    let three = mcdenoise::runtime::par::Pool::new(3).unwrap();
    let mut checked = 0;
    for name in ["cross-variance", "cross-regression", "cross-filter", "cross-filter-grad"] {
        let op = op(name).expect("registered");
        for (si, &(w, h)) in [(1usize, 1usize), (9, 5), (17, 13), (1, 9), (23, 11)].iter().enumerate() {
            let inputs = Inputs::synth(w, h, 5 + si as u64);
            let want = (op.oracle)(&inputs, &one);
            for &isa in &isas_under_test() {
                for pad in [0, 3] {
                    let cfg = Config { isa, layout: Layout { pad }, out_frac: 0 };
                    let p = mcdenoise::runtime::precision::PrecisionKind::F32;
                    let mut run = op.prepare(p, cfg, &inputs).unwrap();
                    run.run(&one).unwrap();
                    let got = run.output();
                    assert!(run.padding_intact(), "{name} {w}x{h}: wrote into the padding");
                    let e = errors(&got, &want, op.tolerance(p));
                    assert!(
                        e.worst <= 1.0,
                        "{name} {} {w}x{h} pad {pad}: element {} is {} but the oracle says {} ({:.2}x tolerance)",
                        isa.name(),
                        e.at,
                        got[e.at],
                        want[e.at],
                        e.worst
                    );
                    let mut run3 = op.prepare(p, cfg, &inputs).unwrap();
                    run3.run(&three).unwrap();
                    assert_eq!(
                        got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        run3.output().iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "{name}: 3 threads differ from 1"
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked >= 40, "ran {checked} cases");
}

/// Buffers of a regression test.
struct Scene {
    x: Img,
    y: Img,
    alb: Img,
    nrm: Img,
    var: Img,
}

fn variance(isa: Isa, x: &Img) -> Img {
    let mut v = Img::zeros(1, x.w, x.h);
    regress::variance_rows(isa, &x.view(), &mut v.view_mut(), 0).unwrap();
    v
}

fn regression(isa: Isa, s: &Scene, y0: usize, rows: usize, garbage: f32) -> Img {
    let mut out = Img::zeros(3, s.x.w, rows);
    let mut scratch = vec![garbage; regress::regression_scratch_len(s.x.w)];
    let inp = RegressionInputs {
        x: s.x.view(),
        var: s.var.view(),
        y: s.y.view(),
        albedo: s.alb.view(),
        normal: s.nrm.view(),
    };
    regress::regression_rows(isa, &inp, &mut out.view_mut(), y0, &mut scratch).unwrap();
    out
}

proptest! {
    #![proptest_config(cfg(12))]

    /// A target that is exactly linear in the design's columns (albedo and
    /// normal here) comes back from the regression up to the 1e-3 ridge.
    #[test]
    fn regression_reproduces_a_linear_image(w in width(), h in 1usize..20, seed in 0u64..1000) {
        let alb = Img::random(3, w, h, 0.1, 0.9, seed);
        let nrm = Img::random(3, w, h, -0.6, 0.6, seed + 1);
        let x = Img::random(3, w, h, 0.0, 2.0, seed + 2);
        let coef = [[2.7, 0.5, 0.3, -0.2, 0.4], [2.2, -0.4, 0.1, 0.3, 0.2], [3.1, 0.8, -0.3, 0.1, -0.5]];
        let mut y = Img::zeros(3, w, h);
        for k in 0..3 {
            for yy in 0..h {
                for xx in 0..w {
                    let c = coef[k];
                    *y.at_mut(k, yy, xx) = c[0] + c[1] * alb.at(k, yy, xx)
                        + c[2] * nrm.at(0, yy, xx) + c[3] * nrm.at(1, yy, xx) + c[4] * nrm.at(2, yy, xx);
                }
            }
        }
        for isa in isas_under_test() {
            let var = variance(isa, &x);
            let s = Scene { x: x.clone(), y: y.clone(), alb: alb.clone(), nrm: nrm.clone(), var };
            let out = regression(isa, &s, 0, h, 0.0);
            let peak = y.data.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            for (i, (&a, &b)) in out.data.iter().zip(&y.data).enumerate() {
                // The ridge pulls small-variance fits toward zero slopes:
                // bounded by a few percent of the image's range on tiny images.
                prop_assert!((a - b).abs() <= 0.05 * peak + 1e-4, "{} {w}x{h}: element {i} {a} vs {b}", isa.name());
            }
        }
    }

    /// The regression over bands equals the whole image, bit for bit, and
    /// garbage in the scratch changes nothing; it matches the f64 oracle.
    #[test]
    fn regression_bands_compose_and_match_the_oracle(w in width(), h in 1usize..26, seed in 0u64..1000) {
        let x = Img::random(3, w, h, 0.0, 3.0, seed);
        let y = Img::random(3, w, h, 0.0, 3.0, seed + 7);
        let alb = Img::random(3, w, h, 0.05, 1.0, seed + 1);
        let nrm = Img::random(3, w, h, -1.0, 1.0, seed + 2);
        for isa in isas_under_test() {
            let var = variance(isa, &x);
            let want_var = oracle::cross_variance(&x.to_f64(), w, h);
            for (a, b) in var.data.iter().zip(&want_var) {
                prop_assert!((*a as f64 - b).abs() <= 1e-5 * (1.0 + b.abs()));
            }
            let s = Scene { x: x.clone(), y: y.clone(), alb: alb.clone(), nrm: nrm.clone(), var };
            let whole = regression(isa, &s, 0, h, 0.0);
            let split = h / 2 + 1;
            let (top, bottom) = (regression(isa, &s, 0, split.min(h), f32::NAN), regression(isa, &s, split.min(h), h - split.min(h), 1e30));
            let joined: Vec<f32> = (0..3).flat_map(|c| {
                let t = &top.data[c * w * top.h..(c + 1) * w * top.h];
                let b = &bottom.data[c * w * bottom.h..(c + 1) * w * bottom.h];
                t.iter().chain(b).copied().collect::<Vec<_>>()
            }).collect();
            prop_assert_eq!(whole.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), joined.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
            // f32 Cholesky of 6x6 systems, whose error grows with their condition:
            // 1e-3 of the peak, and 5e-3 on one-pixel-wide images, where the
            // systems are near-singular (their normal columns barely vary; w = 1,
            // h = 6, seed 4 is 0.0057 off at 1.89, peak about 3).
            let want = oracle::cross_regression(&s.x.to_f64(), &s.var.to_f64(), &y.to_f64(), &alb.to_f64(), &nrm.to_f64(), w, h);
            let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let k = if w == 1 { 5e-3 } else { 1e-3 };
            for (i, (&a, &b)) in whole.data.iter().zip(&want).enumerate() {
                prop_assert!((a as f64 - b).abs() <= k * peak + 1e-3 * b.abs(), "{}: element {i} {a} vs {b}", isa.name());
            }
        }
    }
}

struct FilterScene {
    pa: Img,
    pb: Img,
    alb: Img,
    nrm: Img,
    prev: Img,
    valid: Img,
}

impl FilterScene {
    fn random(w: usize, h: usize, seed: u64) -> FilterScene {
        FilterScene {
            pa: Img::random(3, w, h, 0.0, 2.0, seed),
            pb: Img::random(3, w, h, 0.0, 2.0, seed + 1),
            alb: Img::random(3, w, h, 0.0, 1.0, seed + 2),
            nrm: Img::random(3, w, h, -1.0, 1.0, seed + 3),
            prev: Img::random(3, w, h, 0.0, 2.0, seed + 4),
            valid: Img::random(1, w, h, 0.0, 1.0, seed + 5),
        }
    }
    fn inputs(&self) -> FilterInputs<'_> {
        FilterInputs {
            pilot_a: self.pa.view(),
            pilot_b: self.pb.view(),
            albedo: self.alb.view(),
            normal: self.nrm.view(),
            prev: self.prev.view(),
            valid: self.valid.view(),
        }
    }
    fn oracle(&self) -> [Vec<f64>; 6] {
        [
            self.pa.to_f64(),
            self.pb.to_f64(),
            self.alb.to_f64(),
            self.nrm.to_f64(),
            self.prev.to_f64(),
            self.valid.to_f64(),
        ]
    }
}

fn filter(isa: Isa, s: &FilterScene, params: &Img) -> Img {
    let mut out = Img::zeros(9, s.pa.w, s.pa.h);
    let mut scratch = vec![f32::NAN; regress::filter_scratch_len(s.pa.w)];
    regress::filter_rows(isa, &s.inputs(), &params.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
    out
}

proptest! {
    #![proptest_config(cfg(16))]

    /// Constant pilots with no history: every output is that constant
    /// (the weights normalise), whatever the bandwidths.
    #[test]
    fn filter_weights_normalise(w in width(), h in 1usize..14, seed in 0u64..1000, v in 0.0f32..4.0) {
        let mut s = FilterScene::random(w, h, seed);
        s.pa = Img::filled(3, w, h, v);
        s.pb = Img::filled(3, w, h, v);
        s.valid = Img::zeros(1, w, h);
        let params = Img::random(6, w, h, -3.0, 3.0, seed + 9);
        for isa in isas_under_test() {
            let out = filter(isa, &s, &params);
            for (i, &o) in out.data.iter().enumerate() {
                prop_assert!((o - v).abs() <= 2e-6 * (1.0 + v), "{}: element {i} {o} vs {v}", isa.name());
            }
        }
    }

    /// The backward pass against central differences of the f64 forward
    /// oracle of `sum g . (output A, output B)`.
    #[test]
    fn filter_gradient_matches_finite_differences(w in width(), h in 1usize..8, seed in 0u64..1000) {
        let s = FilterScene::random(w, h, seed);
        // Bandwidth raw outputs away from 0 (where k = 1/(r^2+1e-4) is
        // steep): |r| in [0.3, 2].
        let mut params = Img::random(6, w, h, 0.3, 2.0, seed + 11);
        let signs = Img::random(6, w, h, -1.0, 1.0, seed + 12);
        for (p, s) in params.data.iter_mut().zip(&signs.data) {
            if *s < 0.0 { *p = -*p; }
        }
        let g = Img::random(6, w, h, -1.0, 1.0, seed + 13);
        let [pa, pb, alb, nrm, prev, valid] = s.oracle();
        let f = oracle::CrossFilter { pa: &pa, pb: &pb, alb: &alb, nrm: &nrm, prev: &prev, valid: &valid, w, h };
        let gd = g.to_f64();
        let n = w * h;
        let loss = |p: &[f64]| -> f64 {
            let o = f.forward(p);
            o[..6 * n].iter().zip(&gd).map(|(a, b)| a * b).sum()
        };
        let x = params.to_f64();
        let mut v = x.clone();
        let want: Vec<f64> = (0..x.len()).map(|i| {
            let hh = 1e-6 * (1.0 + x[i].abs());
            v[i] = x[i] + hh;
            let a = loss(&v);
            v[i] = x[i] - hh;
            let b = loss(&v);
            v[i] = x[i];
            (a - b) / (2.0 * hh)
        }).collect();
        // The oracle's analytic gradient agrees with its own differences.
        let analytic = f.backward(&x, &gd);
        let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-3);
        for (a, b) in analytic.iter().zip(&want) {
            prop_assert!((a - b).abs() <= 1e-6 * scale + 1e-6 * b.abs(), "oracle analytic {a} vs {b}");
        }
        for isa in isas_under_test() {
            let mut dp = Img::zeros(6, w, h);
            let mut scratch = vec![f32::NAN; regress::filter_scratch_len(w)];
            regress::filter_grad_rows(isa, &s.inputs(), &params.view(), &g.view(), &mut dp.view_mut(), 0, &mut scratch).unwrap();
            for (i, (&a, &b)) in dp.data.iter().zip(&want).enumerate() {
                prop_assert!((a as f64 - b).abs() <= 2e-4 * scale + 2e-4 * b.abs(), "{} {w}x{h}: element {i} {a} vs {b}", isa.name());
            }
        }
    }
}

/// Pilots at the host's sanitised f32 range (±1e20, where squared colour
/// differences overflow) and bandwidths from tiny to huge: the filter and
/// its gradient stay finite on every instruction set.
#[test]
fn filter_and_gradient_stay_finite_at_the_range_limit() {
    let (w, h) = (13, 7);
    for (k, seed) in [(0usize, 3u64), (1, 4), (2, 5)] {
        let mut s = FilterScene::random(w, h, seed);
        for (i, v) in s.pa.data.iter_mut().enumerate() {
            if (i + k) % 5 == 0 {
                *v = 1e20;
            } else if (i + k) % 7 == 0 {
                *v = -1e20;
            }
        }
        for (i, v) in s.pb.data.iter_mut().enumerate() {
            if (i + 2 * k) % 3 == 0 {
                *v = 1e20;
            }
        }
        let mut params = Img::random(6, w, h, -2.0, 2.0, seed + 7);
        for (i, p) in params.data.iter_mut().enumerate() {
            *p = match i % 4 {
                0 => 1e19,
                1 => 1e-6,
                _ => *p,
            };
        }
        let g = Img::random(6, w, h, -1.0, 1.0, seed + 8);
        for isa in isas_under_test() {
            let out = filter(isa, &s, &params);
            assert!(out.data.iter().all(|v| v.is_finite()), "{isa:?}: non-finite filter output");
            let mut dp = Img::zeros(6, w, h);
            let mut scratch = vec![f32::NAN; regress::filter_scratch_len(w)];
            regress::filter_grad_rows(isa, &s.inputs(), &params.view(), &g.view(), &mut dp.view_mut(), 0, &mut scratch)
                .unwrap();
            assert!(dp.data.iter().all(|v| v.is_finite()), "{isa:?}: non-finite gradient");
        }
    }
}

/// The variance at the host's sanitised f32 range (±1e20): the squared
/// differences pass f32's range, and every instruction set saturates them
/// at `f32::MAX` where the f64 oracle is beyond it and agrees with the
/// oracle elsewhere (a case the `ops` fuzz target found: a non-finite
/// output from finite input).
#[test]
fn variance_saturates_at_the_range_limit() {
    let (w, h) = (16, 9);
    let mut x = Img::random(3, w, h, 0.0, 1.0, 11);
    for (i, v) in x.data.iter_mut().enumerate() {
        if i % 37 == 0 {
            *v = 1e20;
        } else if i % 41 == 0 {
            *v = -1e20;
        }
    }
    let want = oracle::cross_variance(&x.data.iter().map(|&v| v as f64).collect::<Vec<_>>(), w, h);
    assert!(want.iter().any(|&v| v > f32::MAX as f64), "the test's premise: some variance past f32");
    // Pixels whose 3x3 window holds a value of 1e20 in some channel: their
    // f32 window sums lose the small values to it (f32 keeps 7 digits), so
    // only the saturation and finiteness are asserted there.
    let huge = |i: usize| {
        let (px, py) = (i % w, i / w);
        (0..3).any(|c| {
            (py.saturating_sub(1)..(py + 2).min(h))
                .any(|y| (px.saturating_sub(1)..(px + 2).min(w)).any(|x2| x.data[(c * h + y) * w + x2].abs() >= 1e19))
        })
    };
    assert!((0..w * h).any(|i| !huge(i)), "the test's premise: some windows hold no such value");
    for isa in isas_under_test() {
        let got = variance(isa, &x);
        for (i, (&g, &o)) in got.data.iter().zip(&want).enumerate() {
            assert!(g.is_finite(), "{isa:?}: pixel {i} non-finite");
            if o > f32::MAX as f64 {
                assert_eq!(g, f32::MAX, "{isa:?}: pixel {i}");
            } else if !huge(i) {
                assert!((g as f64 - o).abs() <= 1e-4 * o.abs() + 1e-5, "{isa:?}: pixel {i}: {g} against {o}");
            }
        }
    }
}

/// Bad shapes and short scratch are errors naming the argument.
#[test]
fn bad_shapes_are_errors() {
    let s = FilterScene::random(9, 5, 1);
    let params = Img::zeros(6, 9, 5);
    let mut out = Img::zeros(9, 9, 5);
    let mut short = vec![0.0; 3];
    let e = regress::filter_rows(Isa::Scalar, &s.inputs(), &params.view(), &mut out.view_mut(), 0, &mut short);
    assert!(matches!(e, Err(mcdenoise_core::Error::ScratchTooSmall { .. })), "{e:?}");
    let mut scratch = vec![0.0; regress::filter_scratch_len(9)];
    let wrong = Img::zeros(5, 9, 5);
    let e = regress::filter_rows(Isa::Scalar, &s.inputs(), &wrong.view(), &mut out.view_mut(), 0, &mut scratch);
    assert!(e.unwrap_err().to_string().contains("filter parameters"));
    let mut tall = Img::zeros(9, 9, 5);
    let e = regress::filter_rows(Isa::Scalar, &s.inputs(), &params.view(), &mut tall.view_mut(), 2, &mut scratch);
    assert!(e.is_err());
    let x = Img::zeros(3, 9, 5);
    let var = Img::zeros(1, 8, 5);
    let inp = RegressionInputs { x: x.view(), var: var.view(), y: x.view(), albedo: x.view(), normal: x.view() };
    let mut o = Img::zeros(3, 9, 5);
    let mut sc = vec![0.0; regress::regression_scratch_len(9)];
    let e = regress::regression_rows(Isa::Scalar, &inp, &mut o.view_mut(), 0, &mut sc);
    assert!(e.unwrap_err().to_string().contains("regression variance"));
}

mod method {
    use std::path::Path;

    use mcdenoise::io::frame::{Buffer, Frame, Limits};
    use mcdenoise::methods::cross::Cross;
    use mcdenoise::methods::{self, Denoiser, MethodKind, Settings, Timings};
    use mcdenoise_tests::isas_under_test;

    fn frames() -> Vec<Frame> {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/seq_small");
        (0..4).map(|i| Frame::load(&dir.join(format!("frame_{i:04}.exr")), &Limits::default()).unwrap()).collect()
    }

    fn run(settings: &Settings, frames: &[Frame]) -> (Vec<Vec<f32>>, Vec<f32>) {
        let mut den = Cross::new(&frames[0], settings.seed, settings.load_state.as_deref(), None).unwrap();
        let mut ctx = methods::context(settings).unwrap();
        let mut t = Timings::default();
        let mut losses = Vec::new();
        let outs = frames
            .iter()
            .map(|f| {
                let o = den.denoise(f, &mut ctx, &mut t).unwrap();
                losses.push(den.last_loss);
                o
            })
            .collect();
        (outs, losses)
    }

    /// One online step per frame: outputs finite and non-negative, the loss
    /// finite, and everything bit-identical for 1, 2 and 3 threads and the
    /// same seed; another seed gives other weights.
    #[test]
    fn online_steps_are_deterministic_for_a_seed_and_any_thread_count() {
        let frames = frames();
        for isa in isas_under_test() {
            let base = Settings { isa, threads: 1, ..Settings::default() };
            let (one, losses) = run(&base, &frames);
            assert!(losses.iter().all(|l| l.is_finite() && *l > 0.0), "{losses:?}");
            assert!(one.iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
            for threads in [2, 3] {
                let (many, l2) = run(&Settings { threads, ..base.clone() }, &frames);
                assert_eq!(losses, l2, "{}: losses differ at {threads} threads", isa.name());
                for (a, b) in one.iter().zip(&many) {
                    assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "{threads} threads differ");
                }
            }
            let (other, _) = run(&Settings { seed: 7, ..base.clone() }, &frames);
            assert_ne!(one[0], other[0], "the seed changes the initial weights");
        }
    }

    /// A frame tall enough to be cut into several strips (the network's
    /// crops with their halo): still bit-identical for 1 and 3 threads.
    #[test]
    fn several_strips_are_thread_count_independent() {
        let src = frames();
        let (w, h) = (20usize, 400usize);
        let tall: Vec<Frame> = src[..2]
            .iter()
            .map(|f| {
                let tile = |b: Buffer| -> Vec<f32> {
                    let d = f.get(b).unwrap();
                    let c = b.channels();
                    let mut out = vec![0.0f32; c * w * h];
                    for ch in 0..c {
                        for y in 0..h {
                            for x in 0..w {
                                out[(ch * h + y) * w + x] =
                                    d[(ch * f.height + y % f.height) * f.width + (x * 3) % f.width];
                            }
                        }
                    }
                    out
                };
                let mut t = Frame::from_color("tall.exr", w, h, tile(Buffer::Color)).unwrap();
                for b in [Buffer::ColorB, Buffer::Albedo, Buffer::Normal, Buffer::Position] {
                    t.set(b, tile(b)).unwrap();
                }
                t
            })
            .collect();
        let base = Settings { threads: 1, ..Settings::default() };
        let (one, l1) = run(&base, &tall);
        let (three, l3) = run(&Settings { threads: 3, ..base.clone() }, &tall);
        assert_eq!(l1, l3);
        for (a, b) in one.iter().zip(&three) {
            assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "3 threads differ over strips");
        }
        assert!(one.iter().flatten().all(|v| v.is_finite()));
    }

    /// Tiny and odd frame sizes run (the network's input is padded to a
    /// multiple of 4), outputs finite.
    #[test]
    fn odd_and_tiny_frames_run() {
        for (w, h) in [(1usize, 1usize), (3, 5), (17, 9), (9, 1)] {
            let n = w * h;
            let ramp = |k: f32| (0..3 * n).map(|i| 0.2 + k * (i % 7) as f32).collect::<Vec<f32>>();
            let mut f = Frame::from_color("tiny.exr", w, h, ramp(0.3)).unwrap();
            f.set(Buffer::ColorB, ramp(0.2)).unwrap();
            f.set(Buffer::Albedo, vec![0.5; 3 * n]).unwrap();
            f.set(Buffer::Motion, vec![0.0; 2 * n]).unwrap();
            let frames = vec![f.clone(), f];
            let (outs, losses) = run(&Settings { threads: 2, ..Settings::default() }, &frames);
            assert!(losses.iter().all(|l| l.is_finite()), "{w}x{h}: {losses:?}");
            assert!(outs.iter().all(|o| o.len() == 3 * n && o.iter().all(|v| v.is_finite())), "{w}x{h}");
        }
    }

    /// The denoised frames are far closer to the reference than the input.
    #[test]
    fn output_beats_the_mean_of_the_two_estimates() {
        let frames = frames();
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/seq_small/ref");
        let (outs, _) = run(&Settings { threads: 2, ..Settings::default() }, &frames);
        for (i, (o, f)) in outs.iter().zip(&frames).enumerate() {
            let r = Frame::load(&dir.join(format!("frame_{i:04}.exr")), &Limits::default()).unwrap();
            let r = r.get(Buffer::Color).unwrap();
            let (a, b) = (f.get(Buffer::Color).unwrap(), f.get(Buffer::ColorB).unwrap());
            let mean: Vec<f32> = a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)).collect();
            let rel = |x: &[f32]| -> f64 {
                x.iter().zip(r).map(|(v, t)| ((v - t) as f64).powi(2) / ((*t as f64).powi(2) + 1e-2)).sum::<f64>()
                    / x.len() as f64
            };
            let (e_out, e_in) = (rel(o), rel(&mean));
            assert!(e_out < 0.5 * e_in, "frame {i}: relMSE {e_out} against (A+B)/2's {e_in}");
        }
    }

    /// Without `B.R,B.G,B.B` the method says which channels it needs.
    #[test]
    fn missing_second_estimate_is_named() {
        let mut f = frames().remove(0);
        f.remove(Buffer::ColorB);
        let e = methods::create(MethodKind::Cross, &Settings::default(), &f).err().expect("needs B").to_string();
        assert!(e.contains("B.R,B.G,B.B") && e.contains("cross"), "{e}");
    }

    /// The saved state holds the weights and Adam's state after the last
    /// step; loading it continues from exactly there.
    #[test]
    fn state_saves_and_loads() {
        let frames = frames();
        let path = std::env::temp_dir().join(format!("mcdenoise-cross-{}.safetensors", std::process::id()));
        let settings = Settings { threads: 2, ..Settings::default() };
        let mut den = Cross::new(&frames[0], settings.seed, None, Some(path.clone())).unwrap();
        let mut ctx = methods::context(&settings).unwrap();
        let mut t = Timings::default();
        for f in &frames[..2] {
            den.denoise(f, &mut ctx, &mut t).unwrap();
        }
        let init = Cross::new(&frames[0], settings.seed, None, None).unwrap();
        assert_ne!(den.params(), init.params(), "two steps moved the weights");
        let loaded = Cross::new(&frames[0], 99, Some(&path), None).unwrap();
        assert_eq!(den.params(), loaded.params());
        // Continuing: the loaded method's next step equals the original's.
        let mut a = den;
        let mut b = loaded;
        let mut ctx2 = methods::context(&settings).unwrap();
        a.denoise(&frames[2], &mut ctx, &mut t).unwrap();
        b.denoise(&frames[2], &mut ctx2, &mut t).unwrap();
        // The loaded one has no previous frame to reproject, so outputs
        // differ; the Adam step count carries on.
        assert_eq!(a.frames, 3);
        std::fs::remove_file(&path).ok();
        let bad = Cross::new(&frames[0], 1, Some(Path::new("/nonexistent/state.safetensors")), None);
        assert!(bad.err().unwrap().to_string().contains("/nonexistent/state.safetensors"));
    }

    /// A dim wall, clean (its two estimates differ by 1 %), around a bright
    /// noisy strip 8 pixels wide (a light's partly covered edge, 30 % noise), one
    /// albedo: a network that has had one step leaks the bright side into
    /// the wall. The blend's plain window beside the edge holds the bright
    /// side's noise, which hides the wall's error; the fallback after it,
    /// whose window holds the pixels of the centre's level only, brings the
    /// wall's columns beside the edge closer to the truth, and is in the
    /// plan (out of it with `with_fallback(false)`).
    #[test]
    fn the_fallback_returns_a_wall_beside_a_noisy_light_to_the_input() {
        let (w, h) = (48usize, 32usize);
        let n = w * h;
        let bright = |i: usize| ((i % n) % w).abs_diff(w / 2) < 4;
        let truth = |i: usize| if bright(i) { 4.0f32 } else { 0.05 };
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut noisy = |i: usize| {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            // Uniform on [-0.5, 0.5): standard deviation 0.29.
            let u = (seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
            truth(i) * (1.0 + if bright(i) { 1.0 } else { 0.035 } * u)
        };
        let frames: Vec<Frame> = (0..2)
            .map(|_| {
                let a: Vec<f32> = (0..3 * n).map(&mut noisy).collect();
                let b: Vec<f32> = (0..3 * n).map(&mut noisy).collect();
                let mut f = Frame::from_color("edge.exr", w, h, a).unwrap();
                f.set(Buffer::ColorB, b).unwrap();
                f.set(Buffer::Albedo, vec![0.6; 3 * n]).unwrap();
                f.set(Buffer::Motion, vec![0.0; 2 * n]).unwrap();
                f
            })
            .collect();
        let settings = Settings { threads: 2, ..Settings::default() };
        let last = |on: bool| {
            let mut den = Cross::new(&frames[0], settings.seed, None, None).unwrap().with_fallback(on);
            let stage = methods::fallback::STAGE_PAIR;
            assert_eq!(den.plan().built.contains(&stage), on);
            let mut ctx = methods::context(&settings).unwrap();
            let mut t = Timings::default();
            let mut out = Vec::new();
            for f in &frames {
                out = den.denoise(f, &mut ctx, &mut t).unwrap();
            }
            out
        };
        let (with, without) = (last(true), last(false));
        // Relative squared error over the wall's 5 columns each side of the strip.
        let wall = |o: &[f32]| -> f64 {
            (0..3 * n)
                .filter(|&i| !bright(i) && ((i % n) % w).abs_diff(w / 2) < 9)
                .map(|i| (f64::from(o[i]) / f64::from(truth(i)) - 1.0).powi(2))
                .sum()
        };
        let (e_with, e_without) = (wall(&with), wall(&without));
        assert!(e_without > 0.0 && e_with < 0.5 * e_without, "wall error with {e_with}, without {e_without}");
    }
}

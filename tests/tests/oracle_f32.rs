//! Every f32 operator, on every instruction set this CPU has, against the
//! independent f64 oracle in `mcdenoise_tests::oracle`.

use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{unfold, Isa, View, ViewMut, F32};
use mcdenoise_tests::{assert_close, isas_under_test, oracle, Img};
use proptest::prelude::*;

/// A map, its f64 definition, its relative tolerance.
type Case = (Map, fn(f64) -> f64, f64);

fn odd_k(max: usize) -> impl Strategy<Value = usize> {
    (0..=(max / 2)).prop_map(|i| 2 * i + 1)
}

fn cfg(cases: u32) -> ProptestConfig {
    ProptestConfig { cases: mcdenoise_tests::cases(cases), ..ProptestConfig::default() }
}

proptest! {
    #![proptest_config(cfg(48))]

    #[test]
    fn unfold_matches_oracle(w in 1usize..40, h in 1usize..30, c in 1usize..6, k in odd_k(15), seed: u64) {
        let kern = Img::random(k * k, w, h, -1.0, 1.0, seed);
        let src = Img::random(c, w, h, 0.0, 10.0, seed ^ 1);
        let want = oracle::unfold(k, &kern.to_f64(), &src.to_f64(), c, w, h);
        for isa in isas_under_test() {
            let mut out = Img::filled(c, w, h, f32::NAN);
            let mut scratch = vec![0.0; unfold::scratch_len::<F32>(k, c, w)];
            unfold::apply::<F32>(isa, k, &kern.view(), &src.view(), &mut out.view_mut(), &mut scratch).unwrap();
            // k*k products of magnitude <= 10 each: absolute error of a few ulp of 10 per tap.
            assert_close(&format!("unfold {isa:?} k={k}"), &out.data, &want, 1e-6 * (k * k) as f64 * 10.0, 1e-6);
        }
    }

    #[test]
    fn window_filter_matches_oracle(w in 1usize..40, h in 1usize..30, c in 1usize..5, k in odd_k(15),
                                    scale in prop_oneof![Just(1.0f32), Just(30.0), Just(1.0e4)], seed: u64) {
        let logits = Img::random(1, w, h, -scale, scale, seed);
        let rad = Img::random(c, w, h, 0.0, 10.0, seed ^ 2);
        let want = oracle::window_filter(k, &logits.to_f64(), &rad.to_f64(), c, w, h);
        for isa in isas_under_test() {
            for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                let mut out = Img::filled(c, w, h, f32::NAN);
                let mut scratch = vec![0.0; softmax::window_scratch_len::<F32>(path, k, c, w)];
                softmax::window_filter::<F32>(isa, path, k, &logits.view(), &rad.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
                // A convex combination of values in [0, 10]: relative error of the weights ~ k^2 ulp.
                assert_close(&format!("window filter {isa:?} {path:?} k={k} scale={scale}"), &out.data, &want, 2e-5, 2e-5);
            }
        }
    }

    #[test]
    fn fused_matches_oracle(w in 1usize..48, h in 1usize..40, m in 1usize..7, albedo: bool,
                            scale in prop_oneof![Just(2.0f32), Just(60.0)], seed: u64) {
        let sizes: Vec<usize> = (0..m).map(|i| 3 + 2 * i).collect();
        let imp = Img::random(m, w, h, -scale, scale, seed);
        let fus = Img::random(m, w, h, -scale, scale, seed ^ 3);
        let alb = Img::random(3, w, h, 0.0, 1.0, seed ^ 4);
        let rad = Img::random(3, w, h, 0.0, 100.0, seed ^ 5);
        let want = oracle::fused(&sizes, &imp.to_f64(), Some(&fus.to_f64()), albedo.then(|| alb.to_f64()).as_deref(), &rad.to_f64(), 3, w, h);
        for isa in isas_under_test() {
            for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                let inp = FusedInputs { sizes: &sizes, importance: imp.view(), fusion: Some(fus.view()), albedo: albedo.then(|| alb.view()), radiance: rad.view() };
                let mut out = Img::filled(3, w, h, f32::NAN);
                let mut scratch = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
                softmax::fused_filter::<F32>(isa, path, &inp, &mut out.view_mut(), 0, &mut scratch).unwrap();
                assert_close(&format!("fused {isa:?} {path:?} m={m}"), &out.data, &want, 1e-4, 3e-5);
            }
        }
    }

    #[test]
    fn importance_kernels_match_oracle(w in 1usize..30, h in 1usize..30, k in odd_k(15), seed: u64) {
        let logits = Img::random(1, w, h, -20.0, 20.0, seed);
        let want = oracle::importance_kernels(k, &logits.to_f64(), w, h);
        for isa in isas_under_test() {
            let mut out = Img::filled(k * k, w, h, f32::NAN);
            softmax::importance_kernels::<F32>(isa, k, &logits.view(), &mut out.view_mut(), 0).unwrap();
            assert_close(&format!("kernels {isa:?} k={k}"), &out.data, &want, 1e-7, 1e-5);
        }
    }

    #[test]
    fn channel_softmax_matches_oracle(w in 1usize..40, h in 1usize..10, n in 1usize..60, seed: u64) {
        let src = Img::random(n, w, h, -50.0, 50.0, seed);
        let want = oracle::channel_softmax(&src.to_f64(), n, w, h);
        for isa in isas_under_test() {
            let mut out = Img::filled(n, w, h, f32::NAN);
            softmax::channel_softmax::<F32>(isa, &src.view(), &mut out.view_mut()).unwrap();
            assert_close(&format!("channel softmax {isa:?}"), &out.data, &want, 1e-7, 1e-5);
        }
    }

    #[test]
    fn pools_match_oracle(w in 1usize..70, h in 1usize..20, c in 1usize..4, seed: u64) {
        let src = Img::random(c, w, h, -5.0, 5.0, seed);
        let (wc, hc) = (pool::coarse(w), pool::coarse(h));
        for isa in isas_under_test() {
            for (op, max) in [(Reduce::Mean, false), (Reduce::Max, true)] {
                let want = oracle::reduce2x2(&src.to_f64(), c, w, h, max);
                let mut out = Img::filled(c, wc, hc, f32::NAN);
                pool::reduce2x2::<F32>(isa, op, &src.view(), &mut out.view_mut(), 0).unwrap();
                assert_close(&format!("{op:?} {isa:?}"), &out.data, &want, 1e-6, 1e-6);
            }
            let coarse = Img::random(c, wc, hc, -5.0, 5.0, seed ^ 9);
            let want = oracle::upsample(&coarse.to_f64(), c, w, h);
            let mut out = Img::filled(c, w, h, f32::NAN);
            pool::upsample_nearest2x::<F32>(isa, &coarse.view(), &mut out.view_mut(), 0, h).unwrap();
            assert_close(&format!("upsample {isa:?}"), &out.data, &want, 0.0, 0.0);
            let alpha = Img::random(1, w, h, 0.0, 1.0, seed ^ 10);
            let want = oracle::composite(&src.to_f64(), &coarse.to_f64(), &alpha.to_f64(), c, w, h);
            let mut out = Img::filled(c, w, h, f32::NAN);
            pool::composite::<F32>(isa, &src.view(), &coarse.view(), &alpha.view(), &mut out.view_mut(), 0).unwrap();
            assert_close(&format!("composite {isa:?}"), &out.data, &want, 1e-5, 1e-6);
        }
    }

    #[test]
    fn conv_matches_oracle(w in 1usize..45, h in 1usize..12, cin in 1usize..16, cout in 1usize..16,
                           k in prop_oneof![Just(1usize), Just(3), Just(5)], bias: bool, leaky: bool, seed: u64) {
        let src = Img::random(cin, w, h, -1.0, 1.0, seed);
        let wts = Img::random(cout * cin * k * k, 1, 1, -0.5, 0.5, seed ^ 1).data;
        let b = Img::random(cout, 1, 1, -0.5, 0.5, seed ^ 2).data;
        let want = oracle::conv2d(k, cin, cout, &wts.iter().map(|&v| v as f64).collect::<Vec<_>>(),
            bias.then(|| b.iter().map(|&v| v as f64).collect::<Vec<_>>()).as_deref(), leaky.then_some(0.1f32 as f64), &src.to_f64(), w, h);
        let layer = Conv2d { k, cin, cout, weights: &wts, bias: bias.then_some(&b[..]),
            act: if leaky { Activation::LeakyRelu(0.1) } else { Activation::Identity }, weight_frac: 0 };
        for isa in isas_under_test() {
            let mut out = Img::filled(cout, w, h, f32::NAN);
            let mut scratch = vec![0.0; conv::conv2d_scratch_len::<F32>(k, cin, cout, w)];
            conv::conv2d::<F32>(isa, &layer, &src.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
            assert_close(&format!("conv {isa:?} k={k} {cin}->{cout}"), &out.data, &want, 1e-6 * (cin * k * k) as f64, 1e-5);
        }
    }

    #[test]
    fn tone_maps_match_oracle(w in 1usize..70, seed: u64) {
        let src = Img::random(3, w, 2, -2.0, 40.0, seed);
        let alb = Img::random(3, w, 2, 0.0, 1.0, seed ^ 7);
        for isa in isas_under_test() {
            let cases: [Case; 5] = [
                (Map::Gamma { gamma: 2.2, clamp: true }, |x| x.clamp(0.0, 1.0).powf(1.0 / 2.2), 3e-6),
                (Map::Gamma { gamma: 2.2, clamp: false }, |x| x.max(0.0).powf(1.0 / 2.2), 3e-6),
                (Map::Filmic, |x| { let v = x.max(0.0); ((v * (2.51 * v + 0.03)) / (v * (2.43 * v + 0.59) + 0.14)).clamp(0.0, 1.0) }, 1e-6),
                (Map::Log1p, |x| x.max(0.0).ln_1p(), 1e-6),
                (Map::Sanitize { limit: 10.0 }, |x| x.clamp(-10.0, 10.0), 0.0),
            ];
            for (op, f, rtol) in cases {
                let want: Vec<f64> = src.data.iter().map(|&v| f(v as f64)).collect();
                let mut out = Img::filled(3, w, 2, f32::NAN);
                tonemap::map::<F32>(isa, op, &src.view(), &mut out.view_mut()).unwrap();
                assert_close(&format!("{op:?} {isa:?}"), &out.data, &want, 1e-7, rtol);
            }
            let small = Img::random(3, w, 2, -3.0, 3.0, seed ^ 8);
            let want: Vec<f64> = small.data.iter().map(|&v| (v as f64).exp_m1()).collect();
            let mut out = Img::filled(3, w, 2, f32::NAN);
            tonemap::map::<F32>(isa, Map::Expm1, &small.view(), &mut out.view_mut()).unwrap();
            assert_close(&format!("expm1 {isa:?}"), &out.data, &want, 1e-7, 2e-6);
            let want: Vec<f64> = src.data.iter().zip(&alb.data).map(|(&r, &a)| r as f64 / (a as f64 + 1e-3f32 as f64)).collect();
            let mut out = Img::filled(3, w, 2, f32::NAN);
            tonemap::demodulate::<F32>(isa, &src.view(), &alb.view(), 1e-3, &mut out.view_mut()).unwrap();
            assert_close(&format!("demodulate {isa:?}"), &out.data, &want, 0.0, 2e-7);
        }
    }
}

#[test]
fn bands_compose_to_the_whole_image() {
    // Output computed in bands of rows equals the output computed at once.
    let (w, h) = (37, 29);
    let sizes = [3, 7, 13];
    let imp = Img::random(3, w, h, -8.0, 8.0, 1);
    let fus = Img::random(3, w, h, -3.0, 3.0, 2);
    let rad = Img::random(3, w, h, 0.0, 5.0, 3);
    for (isa, path) in isas_under_test().into_iter().flat_map(|i| [(i, WindowPath::BoxSum), (i, WindowPath::Separable)])
    {
        let inp = FusedInputs {
            sizes: &sizes,
            importance: imp.view(),
            fusion: Some(fus.view()),
            albedo: None,
            radiance: rad.view(),
        };
        let mut scratch = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
        let mut whole = Img::zeros(3, w, h);
        softmax::fused_filter::<F32>(isa, path, &inp, &mut whole.view_mut(), 0, &mut scratch).unwrap();
        let mut banded = Img::zeros(3, w, h);
        let mut rest = banded.view_mut();
        let mut y0 = 0;
        for band in [5usize, 1, 11, 12] {
            let (mut top, bottom) = rest.split_rows_at(band);
            softmax::fused_filter::<F32>(isa, path, &inp, &mut top, y0, &mut scratch).unwrap();
            y0 += band;
            rest = bottom;
        }
        assert_eq!(whole.data, banded.data, "{isa:?} {path:?}");
    }
}

#[test]
fn shape_errors_are_reported_not_panicked() {
    let img = Img::zeros(3, 8, 8);
    let mut out = Img::zeros(3, 8, 7);
    let kern = Img::zeros(49, 8, 8);
    let mut scratch = vec![0.0; 1024];
    let e =
        unfold::apply::<F32>(Isa::Scalar, 7, &kern.view(), &img.view(), &mut out.view_mut(), &mut scratch).unwrap_err();
    assert!(e.to_string().contains("unfold output"), "{e}");
    let mut ok = Img::zeros(3, 8, 8);
    let e =
        unfold::apply::<F32>(Isa::Scalar, 4, &kern.view(), &img.view(), &mut ok.view_mut(), &mut scratch).unwrap_err();
    assert!(e.to_string().contains("kernel size"), "{e}");
    let e = unfold::apply::<F32>(Isa::Scalar, 7, &kern.view(), &img.view(), &mut ok.view_mut(), &mut []).unwrap_err();
    assert!(matches!(e, mcdenoise_core::Error::ScratchTooSmall { .. }), "{e}");
    assert!(View::new(&[0.0f32; 10], 1, 4, 3).is_err());
    assert!(ViewMut::new(&mut [0.0f32; 12], 1, usize::MAX, 2).is_err());
}

#[test]
fn fused_across_many_tiles_matches_oracle() {
    // Wider than one 256-column tile and taller than one 48-row tile, with a
    // band split that cuts a tile, so halos, grid alignment and block starts
    // across tiles are all exercised.
    let (w, h) = (300, 110);
    let sizes = [3, 9, 15];
    let imp = Img::random(3, w, h, -12.0, 12.0, 21);
    let fus = Img::random(3, w, h, -4.0, 4.0, 22);
    let alb = Img::random(3, w, h, 0.0, 1.0, 23);
    let rad = Img::random(3, w, h, 0.0, 20.0, 24);
    let want = oracle::fused(&sizes, &imp.to_f64(), Some(&fus.to_f64()), Some(&alb.to_f64()), &rad.to_f64(), 3, w, h);
    for (isa, path) in isas_under_test().into_iter().flat_map(|i| [(i, WindowPath::BoxSum), (i, WindowPath::Separable)])
    {
        let inp = FusedInputs {
            sizes: &sizes,
            importance: imp.view(),
            fusion: Some(fus.view()),
            albedo: Some(alb.view()),
            radiance: rad.view(),
        };
        let mut scratch = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
        let mut out = Img::filled(3, w, h, f32::NAN);
        let (mut top, mut bottom) = out.view_mut().split_rows_at(70);
        softmax::fused_filter::<F32>(isa, path, &inp, &mut top, 0, &mut scratch).unwrap();
        softmax::fused_filter::<F32>(isa, path, &inp, &mut bottom, 70, &mut scratch).unwrap();
        assert_close(&format!("fused many tiles {isa:?} {path:?}"), &out.data, &want, 1e-4, 3e-5);
    }
}

#[test]
fn fused_box_path_with_logit_bands_90_nats_apart_matches_oracle() {
    // Bands of rows alternate between logits near +45 and near -45 (with
    // band heights that are no multiple of any window size): windows in a
    // low band under a tile maximum 90 nats higher have box sums that
    // underflow and fall back to the direct window; windows straddling two
    // bands mix weights e^-90 apart (subnormal ratios in f32).
    let (w, h) = (61, 83);
    let sizes = [3, 5, 7, 9, 11, 13, 15];
    let mut imp = Img::random(sizes.len(), w, h, -2.0, 2.0, 31);
    for c in 0..sizes.len() {
        for y in 0..h {
            let band = if (y / (4 + c)) % 2 == 0 { 45.0 } else { -45.0 };
            for x in 0..w {
                *imp.at_mut(c, y, x) += band;
            }
        }
    }
    let fus = Img::random(sizes.len(), w, h, -3.0, 3.0, 32);
    let rad = Img::random(3, w, h, 0.0, 50.0, 33);
    let want = oracle::fused(&sizes, &imp.to_f64(), Some(&fus.to_f64()), None, &rad.to_f64(), 3, w, h);
    for (isa, path) in isas_under_test().into_iter().flat_map(|i| [(i, WindowPath::BoxSum), (i, WindowPath::Separable)])
    {
        let inp = FusedInputs {
            sizes: &sizes,
            importance: imp.view(),
            fusion: Some(fus.view()),
            albedo: None,
            radiance: rad.view(),
        };
        let mut scratch = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
        let mut out = Img::filled(3, w, h, f32::NAN);
        softmax::fused_filter::<F32>(isa, path, &inp, &mut out.view_mut(), 0, &mut scratch).unwrap();
        assert_close(&format!("fused logit bands {isa:?} {path:?}"), &out.data, &want, 1e-4, 3e-5);
    }
}

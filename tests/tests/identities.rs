//! Operator identities, each checked against exact arithmetic facts rather than
//! against another implementation.

use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool;
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::{unfold, F32};
use mcdenoise_tests::{assert_close, isas_under_test, Img};
use proptest::prelude::*;

fn odd_k(max: usize) -> impl Strategy<Value = usize> {
    (0..=(max / 2)).prop_map(|i| 2 * i + 1)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: mcdenoise_tests::cases(64), ..ProptestConfig::default() })]

    /// Softmax weights lie in [0, 1] and sum to one within k^2 ulp + 1e-6, at
    /// every pixel including borders: for logits spread like a trained
    /// network's maps (+-50, where many taps carry weight and the sum is a
    /// real test) and for logits anywhere in +-1e4 (windows nearly one-hot:
    /// the extreme-range case).
    #[test]
    fn softmax_kernel_weights_are_a_partition_of_unity(w in 1usize..24, h in 1usize..24, k in odd_k(15),
                                                       scale in prop_oneof![Just(4.0f32), Just(50.0), Just(1.0e4)], seed: u64) {
        let logits = Img::random(1, w, h, -scale, scale, seed);
        let tol = (k * k) as f32 * f32::EPSILON + 1e-6;
        for isa in isas_under_test() {
            let mut out = Img::filled(k * k, w, h, f32::NAN);
            softmax::importance_kernels::<F32>(isa, k, &logits.view(), &mut out.view_mut(), 0).unwrap();
            for y in 0..h {
                for x in 0..w {
                    let mut s = 0.0f64;
                    for j in 0..k * k {
                        let v = out.at(j, y, x);
                        prop_assert!((0.0..=1.0).contains(&v), "{isa:?}: weight {v} at ({x},{y}) tap {j}");
                        s += v as f64;
                    }
                    prop_assert!((s - 1.0).abs() <= tol as f64, "{isa:?}: weights at ({x},{y}) sum to {s}");
                }
            }
        }
    }

    /// As above across channels: +-4 and +-50 (real fusion maps span about
    /// -61..34) and +-1e4.
    #[test]
    fn channel_softmax_is_a_partition_of_unity(w in 1usize..40, n in 1usize..50,
                                               scale in prop_oneof![Just(4.0f32), Just(50.0), Just(1.0e4)], seed: u64) {
        let src = Img::random(n, w, 3, -scale, scale, seed);
        let tol = n as f32 * f32::EPSILON + 1e-6;
        for isa in isas_under_test() {
            let mut out = Img::filled(n, w, 3, f32::NAN);
            softmax::channel_softmax::<F32>(isa, &src.view(), &mut out.view_mut()).unwrap();
            for y in 0..3 {
                for x in 0..w {
                    let s: f64 = (0..n).map(|c| out.at(c, y, x) as f64).sum();
                    prop_assert!((s - 1.0).abs() <= tol as f64, "{isa:?}: sum {s}");
                    prop_assert!((0..n).all(|c| (0.0..=1.0).contains(&out.at(c, y, x))));
                }
            }
        }
    }

    /// Adding a constant to every logit changes nothing. With logits on a grid
    /// of 1/64 and a shift of 512 every difference of logits is exact, so both
    /// paths must give bit-identical results; with an arbitrary shift (which
    /// rounds the logits) they agree to rounding.
    #[test]
    fn logit_shift_changes_nothing(w in 1usize..40, h in 1usize..30, k in odd_k(15), m in 1usize..4, seed: u64, c in -300.0f32..300.0) {
        let sizes: Vec<usize> = (0..m).map(|i| (k + 2 * i).min(15)).collect();
        let mut imp = Img::random(m, w, h, -40.0, 40.0, seed);
        for v in imp.data.iter_mut() { *v = (*v * 64.0).round() / 64.0; }
        let mut fus = Img::random(m, w, h, -5.0, 5.0, seed ^ 1);
        for v in fus.data.iter_mut() { *v = (*v * 64.0).round() / 64.0; }
        let rad = Img::random(3, w, h, 0.0, 4.0, seed ^ 2);
        let shifted = |img: &Img, d: f32| Img { data: img.data.iter().map(|v| v + d).collect(), ..img.clone() };
        for isa in isas_under_test() {
            for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                let run = |imp: &Img, fus: &Img| {
                    let inp = FusedInputs { sizes: &sizes, importance: imp.view(), fusion: Some(fus.view()), albedo: None, radiance: rad.view() };
                    let mut out = Img::filled(3, w, h, f32::NAN);
                    let mut scratch = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
                    softmax::fused_filter::<F32>(isa, path, &inp, &mut out.view_mut(), 0, &mut scratch).unwrap();
                    out
                };
                let base = run(&imp, &fus);
                let exact = run(&shifted(&imp, 512.0), &shifted(&fus, -512.0));
                prop_assert_eq!(&base.data, &exact.data, "{:?} {:?}: exact shift changed the output", isa, path);
                let rounded = run(&shifted(&imp, c), &shifted(&fus, c));
                let want: Vec<f64> = base.data.iter().map(|&v| v as f64).collect();
                // Rounding the logits to f32 after the shift perturbs each weight by up to |c| ulp.
                assert_close(&format!("{isa:?} {path:?} shift {c}"), &rounded.data, &want, 1e-5, 1e-6 * (1.0 + c.abs() as f64));
            }
        }
    }

    /// The box-sum and the separable paths each equal the direct path.
    #[test]
    fn boxsum_equals_direct(w in 1usize..70, h in 1usize..60, k in odd_k(15), scale in prop_oneof![Just(1.0f32), Just(50.0), Just(1.0e4)], seed: u64) {
        let logits = Img::random(1, w, h, -scale, scale, seed);
        let rad = Img::random(3, w, h, 0.0, 10.0, seed ^ 5);
        for isa in isas_under_test() {
            let mut outs = Vec::new();
            for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                let mut out = Img::filled(3, w, h, f32::NAN);
                let mut scratch = vec![0.0; softmax::window_scratch_len::<F32>(path, k, 3, w)];
                softmax::window_filter::<F32>(isa, path, k, &logits.view(), &rad.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
                outs.push(out);
            }
            let direct: Vec<f64> = outs[0].data.iter().map(|&v| v as f64).collect();
            assert_close(&format!("box-sum {isa:?} k={k} scale={scale}"), &outs[1].data, &direct, 2e-5, 2e-5);
            assert_close(&format!("separable {isa:?} k={k} scale={scale}"), &outs[2].data, &direct, 2e-5, 2e-5);
        }
    }

    /// Logits spread so that many windows lie 69 to 130 nats under their
    /// tile's largest (the box-sum and separable paths' second pass at a
    /// lower shift) and some further (window by window): both paths equal
    /// the direct one, for one window size and for the six fused.
    #[test]
    fn boxsum_equals_direct_at_spread_logits(w in 1usize..80, h in 1usize..60, k in odd_k(9), scale in prop_oneof![Just(45.0f32), Just(70.0), Just(110.0)], seed: u64) {
        let logits = Img::random(1, w, h, -scale, scale, seed);
        let rad = Img::random(3, w, h, 0.0, 10.0, seed ^ 5);
        let sizes = [3usize, 5, 7, 9, 11, 13];
        let imp = Img::random(6, w, h, -scale, scale, seed ^ 7);
        let fus = Img::random(6, w, h, -3.0, 3.0, seed ^ 9);
        for isa in isas_under_test() {
            let mut outs = Vec::new();
            let mut fused = Vec::new();
            for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                let mut out = Img::filled(3, w, h, f32::NAN);
                let mut scratch = vec![0.0; softmax::window_scratch_len::<F32>(path, k, 3, w)];
                softmax::window_filter::<F32>(isa, path, k, &logits.view(), &rad.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
                outs.push(out);
                let inp = FusedInputs { sizes: &sizes, importance: imp.view(), fusion: Some(fus.view()), albedo: None, radiance: rad.view() };
                let mut out = Img::filled(3, w, h, f32::NAN);
                let mut scratch = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
                softmax::fused_filter::<F32>(isa, path, &inp, &mut out.view_mut(), 0, &mut scratch).unwrap();
                fused.push(out);
            }
            let direct: Vec<f64> = outs[0].data.iter().map(|&v| v as f64).collect();
            assert_close(&format!("box-sum {isa:?} k={k} scale={scale}"), &outs[1].data, &direct, 2e-5, 2e-5);
            assert_close(&format!("separable {isa:?} k={k} scale={scale}"), &outs[2].data, &direct, 2e-5, 2e-5);
            let direct: Vec<f64> = fused[0].data.iter().map(|&v| v as f64).collect();
            assert_close(&format!("fused box-sum {isa:?} scale={scale}"), &fused[1].data, &direct, 2e-5, 2e-5);
            assert_close(&format!("fused separable {isa:?} scale={scale}"), &fused[2].data, &direct, 2e-5, 2e-5);
        }
    }

    /// A delta kernel (one at the centre tap) is the identity, bit for bit.
    #[test]
    fn delta_kernel_is_identity(w in 1usize..70, h in 1usize..20, c in 1usize..6, k in odd_k(15), seed: u64) {
        let src = Img::random(c, w, h, 0.0, 1.0e4, seed);
        let mut kern = Img::zeros(k * k, w, h);
        let centre = (k / 2) * k + k / 2;
        kern.data[centre * w * h..(centre + 1) * w * h].fill(1.0);
        for isa in isas_under_test() {
            let mut out = Img::filled(c, w, h, f32::NAN);
            let mut scratch = vec![0.0; unfold::scratch_len::<F32>(k, c, w)];
            unfold::apply::<F32>(isa, k, &kern.view(), &src.view(), &mut out.view_mut(), &mut scratch).unwrap();
            prop_assert_eq!(&out.data, &src.data, "{:?}", isa);
        }
    }

    /// A normalised kernel over a constant image returns the constant: the
    /// softmax kernels (normalised over in-image taps) through unfold, and the
    /// importance filter directly.
    #[test]
    fn normalised_kernel_keeps_a_constant(w in 1usize..50, h in 1usize..30, k in odd_k(15), v in 0.001f32..1.0e4, seed: u64) {
        let logits = Img::random(1, w, h, -30.0, 30.0, seed);
        let src = Img::filled(3, w, h, v);
        let want = vec![v as f64; 3 * w * h];
        for isa in isas_under_test() {
            let mut kern = Img::zeros(k * k, w, h);
            softmax::importance_kernels::<F32>(isa, k, &logits.view(), &mut kern.view_mut(), 0).unwrap();
            let mut out = Img::filled(3, w, h, f32::NAN);
            let mut scratch = vec![0.0; unfold::scratch_len::<F32>(k, 3, w)];
            unfold::apply::<F32>(isa, k, &kern.view(), &src.view(), &mut out.view_mut(), &mut scratch).unwrap();
            assert_close(&format!("unfold {isa:?}"), &out.data, &want, 0.0, (k * k + 2) as f64 * f32::EPSILON as f64);
            for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                let mut scratch = vec![0.0; softmax::window_scratch_len::<F32>(path, k, 3, w)];
                softmax::window_filter::<F32>(isa, path, k, &logits.view(), &src.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
                assert_close(&format!("filter {isa:?} {path:?}"), &out.data, &want, 0.0, 4.0 * (k + 2) as f64 * f32::EPSILON as f64);
            }
        }
    }

    /// Average pool of a nearest upsample is the identity, bit for bit, at every size.
    #[test]
    fn pool_of_upsample_is_identity(w in 1usize..80, h in 1usize..20, c in 1usize..4, seed: u64) {
        let (wc, hc) = (pool::coarse(w), pool::coarse(h));
        let coarse = Img::random(c, wc, hc, -1.0e3, 1.0e3, seed);
        for isa in isas_under_test() {
            let mut up = Img::filled(c, w, h, f32::NAN);
            pool::upsample_nearest2x::<F32>(isa, &coarse.view(), &mut up.view_mut(), 0, h).unwrap();
            let mut back = Img::filled(c, wc, hc, f32::NAN);
            pool::avg_pool2x2::<F32>(isa, &up.view(), &mut back.view_mut()).unwrap();
            prop_assert_eq!(&back.data, &coarse.data, "{:?}", isa);
        }
    }

    /// The compositor with a = 0 returns f, bit for bit.
    #[test]
    fn composite_with_zero_alpha_is_identity(w in 1usize..80, h in 1usize..20, c in 1usize..4, seed: u64) {
        let fine = Img::random(c, w, h, -1.0e3, 1.0e3, seed);
        let coarse = Img::random(c, pool::coarse(w), pool::coarse(h), -1.0e3, 1.0e3, seed ^ 1);
        let alpha = Img::zeros(1, w, h);
        for isa in isas_under_test() {
            let mut out = Img::filled(c, w, h, f32::NAN);
            pool::composite::<F32>(isa, &fine.view(), &coarse.view(), &alpha.view(), &mut out.view_mut(), 0).unwrap();
            prop_assert_eq!(&out.data, &fine.data, "{:?}", isa);
        }
    }

    /// conv(a x + b y) = a conv(x) + b conv(y) without bias or activation.
    #[test]
    fn conv_is_linear(w in 1usize..40, h in 1usize..10, cin in 1usize..8, cout in 1usize..8,
                      k in prop_oneof![Just(1usize), Just(3), Just(5)], a in -3.0f32..3.0, b in -3.0f32..3.0, seed: u64) {
        let x = Img::random(cin, w, h, -1.0, 1.0, seed);
        let y = Img::random(cin, w, h, -1.0, 1.0, seed ^ 1);
        let wts = Img::random(cout * cin * k * k, 1, 1, -0.5, 0.5, seed ^ 2).data;
        let layer = Conv2d { k, cin, cout, weights: &wts, bias: None, act: Activation::Identity, weight_frac: 0 };
        let mix = Img { data: x.data.iter().zip(&y.data).map(|(p, q)| a * p + b * q).collect(), ..x.clone() };
        for isa in isas_under_test() {
            let run = |src: &Img| {
                let mut out = Img::filled(cout, w, h, f32::NAN);
                let mut scratch = vec![0.0; conv::conv2d_scratch_len::<F32>(k, cin, cout, w)];
                conv::conv2d::<F32>(isa, &layer, &src.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
                out
            };
            let (cx, cy, cm) = (run(&x), run(&y), run(&mix));
            let want: Vec<f64> = cx.data.iter().zip(&cy.data).map(|(&p, &q)| a as f64 * p as f64 + b as f64 * q as f64).collect();
            assert_close(&format!("{isa:?}"), &cm.data, &want, 4e-6 * (cin * k * k) as f64, 1e-5);
        }
    }

    /// A centred delta kernel (identity channel map) is the identity, bit for bit.
    #[test]
    fn conv_delta_is_identity(w in 1usize..40, h in 1usize..10, c in 1usize..16, k in prop_oneof![Just(1usize), Just(3), Just(5)], seed: u64) {
        let x = Img::random(c, w, h, 0.0, 5.0, seed);
        let mut wts = vec![0.0f32; c * c * k * k];
        for i in 0..c {
            wts[((i * c + i) * k + k / 2) * k + k / 2] = 1.0;
        }
        let layer = Conv2d { k, cin: c, cout: c, weights: &wts, bias: None, act: Activation::Identity, weight_frac: 0 };
        for isa in isas_under_test() {
            let mut out = Img::filled(c, w, h, f32::NAN);
            let mut scratch = vec![0.0; conv::conv2d_scratch_len::<F32>(k, c, c, w)];
            conv::conv2d::<F32>(isa, &layer, &x.view(), &mut out.view_mut(), 0, &mut scratch).unwrap();
            prop_assert_eq!(&out.data, &x.data, "{:?}", isa);
        }
    }
}

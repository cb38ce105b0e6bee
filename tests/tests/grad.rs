//! The backward passes against central finite differences of the f64
//! forward oracle, at odd widths (1, 9, 17) and on every instruction set this
//! CPU has; the analytic f64 gradients of `oracle` against the same finite
//! differences; bands composing; the fused filter's gradient finite for
//! logits that overflow a naive `exp`.

use mcdenoise_core::conv::{grad as cgrad, Activation};
use mcdenoise_core::pool::{self, grad as pgrad, Reduce};
use mcdenoise_core::softmax::{self, grad as sgrad, FusedInputs};
use mcdenoise_core::unfold::grad as ugrad;
use mcdenoise_core::{Isa, F32};
use mcdenoise_tests::{isas_under_test, oracle, Img};
use proptest::prelude::*;

fn cfg(cases: u32) -> ProptestConfig {
    ProptestConfig { cases: mcdenoise_tests::cases(cases), ..ProptestConfig::default() }
}

fn width() -> impl Strategy<Value = usize> {
    prop_oneof![Just(1usize), Just(9), Just(17)]
}

/// Central differences of `f` at every element of `x` (step `h` relative to
/// the element's size).
fn fd(x: &[f64], f: impl Fn(&[f64]) -> f64) -> Vec<f64> {
    let mut v = x.to_vec();
    (0..x.len())
        .map(|i| {
            let h = 1e-6 * (1.0 + x[i].abs());
            v[i] = x[i] + h;
            let a = f(&v);
            v[i] = x[i] - h;
            let b = f(&v);
            v[i] = x[i];
            (a - b) / (2.0 * h)
        })
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// `|got - want| <= tol * (max |want| + 1e-3) + tol * |want|` everywhere.
#[track_caller]
fn close(what: &str, got: &[f32], want: &[f64], tol: f64) {
    close_floor(what, got, want, tol, 1e-3)
}

/// As [`close`], the scale at least `floor` (for gradients that are all
/// near zero where their terms are not: rounding of the terms is the error).
#[track_caller]
fn close_floor(what: &str, got: &[f32], want: &[f64], tol: f64, floor: f64) {
    assert_eq!(got.len(), want.len(), "{what}: lengths");
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(floor);
    for (i, (&a, &b)) in got.iter().zip(want).enumerate() {
        let e = (a as f64 - b).abs();
        assert!(
            e <= tol * scale + tol * b.abs(),
            "{what}: element {i} is {a} but finite differences say {b} (scale {scale})"
        );
    }
}

#[track_caller]
fn close64(what: &str, got: &[f64], want: &[f64], tol: f64) {
    let g: Vec<f32> = got.iter().map(|&v| v as f32).collect();
    close(what, &g, want, tol);
}

fn f32s(v: &[f64]) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}

proptest! {
    #![proptest_config(cfg(24))]

    #[test]
    fn conv_gradients_match_finite_differences(w in width(), h in 1usize..6, cin in 1usize..4, cout in 1usize..5,
                                               k in prop_oneof![Just(1usize), Just(3), Just(5)], act in 0usize..3, seed: u64) {
        let (slope, activation) = [(None, Activation::Identity), (Some(0.0), Activation::Relu), (Some(0.1), Activation::LeakyRelu(0.1))][act];
        let x = Img::random(cin, w, h, -1.0, 1.0, seed);
        let wt = Img::random(cout * cin * k * k, 1, 1, -0.5, 0.5, seed ^ 1);
        let b = Img::random(cout, 1, 1, -0.2, 0.2, seed ^ 2);
        let gy = Img::random(cout, w, h, -1.0, 1.0, seed ^ 3);
        let (xd, wd, bd, gd) = (x.to_f64(), wt.to_f64(), b.to_f64(), gy.to_f64());
        let loss = |xv: &[f64], wv: &[f64], bv: &[f64]| dot(&oracle::conv2d(k, cin, cout, wv, Some(bv), slope, xv, w, h), &gd);
        let (fx, fw, fb) = (fd(&xd, |v| loss(v, &wd, &bd)), fd(&wd, |v| loss(&xd, v, &bd)), fd(&bd, |v| loss(&xd, &wd, v)));
        // The analytic oracle agrees with the differences.
        let y64 = oracle::conv2d(k, cin, cout, &wd, Some(&bd), slope, &xd, w, h);
        let z64 = oracle::conv2d(k, cin, cout, &wd, Some(&bd), None, &xd, w, h);
        let dz64: Vec<f64> = z64.iter().zip(&gd).map(|(&z, &g)| match slope { Some(sl) if z <= 0.0 => sl * g, _ => g }).collect();
        let (ox, ow, ob) = oracle::conv2d_grad(k, cin, cout, &wd, &xd, &dz64, w, h);
        close64("oracle dx", &ox, &fx, 1e-6);
        close64("oracle dw", &ow, &fw, 1e-6);
        close64("oracle db", &ob, &fb, 1e-6);
        let y = Img { c: cout, w, h, data: f32s(&y64) };
        let mut tr = vec![0.0; wt.data.len()];
        cgrad::transpose_weights(k, cin, cout, &wt.data, &mut tr).unwrap();
        for isa in isas_under_test() {
            let mut dz = Img::zeros(cout, w, h);
            cgrad::activation_grad(activation, &y.view(), &gy.view(), &mut dz.view_mut()).unwrap();
            let mut dx = Img::filled(cin, w, h, f32::NAN);
            let mut s = vec![0.0; cgrad::grad_input_scratch_len(k, cin, cout, w)];
            cgrad::grad_input(isa, k, cin, cout, &tr, &dz.view(), &mut dx.view_mut(), 0, &mut s).unwrap();
            let (mut dw, mut db) = (vec![0.0; wt.data.len()], vec![0.0; cout]);
            cgrad::grad_weights(isa, k, &x.view(), &dz.view(), 0, h, &mut dw, Some(&mut db)).unwrap();
            close(&format!("dx {isa:?}"), &dx.data, &fx, 1e-4);
            close(&format!("dw {isa:?}"), &dw, &fw, 1e-4);
            close(&format!("db {isa:?}"), &db, &fb, 1e-4);
            // Two bands of rows add up to the whole (to rounding).
            let (mut dw2, mut db2) = (vec![0.0; wt.data.len()], vec![0.0; cout]);
            let mid = h / 2;
            cgrad::grad_weights(isa, k, &x.view(), &dz.view(), 0, mid, &mut dw2, Some(&mut db2)).unwrap();
            cgrad::grad_weights(isa, k, &x.view(), &dz.view(), mid, h - mid, &mut dw2, Some(&mut db2)).unwrap();
            close(&format!("dw in bands {isa:?}"), &dw2, &fw, 1e-4);
        }
    }

    #[test]
    fn pool_and_upsample_gradients_match_finite_differences(w in width(), h in 1usize..8, c in 1usize..3, seed: u64) {
        let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
        let x = Img::random(c, w, h, -1.0, 1.0, seed);
        let xc = Img::random(c, wc, hc, -1.0, 1.0, seed ^ 1);
        let gc = Img::random(c, wc, hc, -1.0, 1.0, seed ^ 2);
        let gf = Img::random(c, w, h, -1.0, 1.0, seed ^ 3);
        let (xd, xcd, gcd, gfd) = (x.to_f64(), xc.to_f64(), gc.to_f64(), gf.to_f64());
        let f_avg = fd(&xd, |v| dot(&oracle::reduce2x2(v, c, w, h, false), &gcd));
        let f_max = fd(&xd, |v| dot(&oracle::reduce2x2(v, c, w, h, true), &gcd));
        let f_up = fd(&xcd, |v| dot(&oracle::upsample(v, c, w, h), &gfd));
        let f_bil = fd(&xcd, |v| dot(&oracle::upsample_bilinear(v, c, w, h), &gfd));
        close64("oracle avg", &oracle::avg_pool_grad(&gcd, c, w, h), &f_avg, 1e-6);
        close64("oracle max", &oracle::max_pool_grad(&xd, &gcd, c, w, h), &f_max, 1e-6);
        close64("oracle nearest", &oracle::upsample_grad(&gfd, c, w, h), &f_up, 1e-6);
        close64("oracle bilinear", &oracle::upsample_bilinear_grad(&gfd, c, w, h), &f_bil, 1e-6);
        for isa in isas_under_test() {
            let mut d = Img::filled(c, w, h, f32::NAN);
            pgrad::avg_pool2x2_grad(isa, &gc.view(), &mut d.view_mut(), 0, h).unwrap();
            close(&format!("avg {isa:?}"), &d.data, &f_avg, 1e-5);
            pgrad::max_pool2x2_grad(isa, &x.view(), &gc.view(), &mut d.view_mut(), 0).unwrap();
            close(&format!("max {isa:?}"), &d.data, &f_max, 1e-5);
            let mut dc = Img::filled(c, wc, hc, f32::NAN);
            pgrad::upsample_nearest2x_grad(isa, &gf.view(), &mut dc.view_mut(), 0).unwrap();
            close(&format!("nearest {isa:?}"), &dc.data, &f_up, 1e-5);
            pgrad::upsample_bilinear2x_grad(isa, &gf.view(), &mut dc.view_mut(), 0).unwrap();
            close(&format!("bilinear {isa:?}"), &dc.data, &f_bil, 1e-5);
            // The bilinear forward against its oracle.
            let mut up = Img::filled(c, w, h, f32::NAN);
            pgrad::upsample_bilinear2x(isa, &xc.view(), &mut up.view_mut(), 0, h).unwrap();
            close(&format!("bilinear forward {isa:?}"), &up.data, &oracle::upsample_bilinear(&xcd, c, w, h), 1e-6);
        }
    }

    #[test]
    fn compositor_gradients_match_finite_differences(w in width(), h in 1usize..8, seed: u64) {
        let c = 3;
        let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
        let f = Img::random(c, w, h, 0.0, 2.0, seed);
        let co = Img::random(c, wc, hc, 0.0, 2.0, seed ^ 1);
        let a = Img::random(1, w, h, 0.0, 1.0, seed ^ 2);
        let g = Img::random(c, w, h, -1.0, 1.0, seed ^ 3);
        let (fd64, cd, ad, gd) = (f.to_f64(), co.to_f64(), a.to_f64(), g.to_f64());
        let loss = |fv: &[f64], cv: &[f64], av: &[f64]| dot(&oracle::composite(fv, cv, av, c, w, h), &gd);
        let (ff, fc, fa) = (fd(&fd64, |v| loss(v, &cd, &ad)), fd(&cd, |v| loss(&fd64, v, &ad)), fd(&ad, |v| loss(&fd64, &cd, v)));
        let (of, oc, oa) = oracle::composite_grad(&fd64, &cd, &ad, &gd, c, w, h);
        close64("oracle d_fine", &of, &ff, 1e-6);
        close64("oracle d_coarse", &oc, &fc, 1e-6);
        close64("oracle d_alpha", &oa, &fa, 1e-6);
        for isa in isas_under_test() {
            let (mut df, mut dc, mut da) = (Img::filled(c, w, h, f32::NAN), Img::filled(c, wc, hc, f32::NAN), Img::filled(1, w, h, f32::NAN));
            // In two bands split at an even row.
            let mid = (h / 2) & !1;
            for (y0, n) in [(0, mid), (mid, h - mid)] {
                let (c0, cn) = (y0 / 2, (y0 + n).div_ceil(2) - y0 / 2);
                let mut dfv = df.view_mut();
                let mut dcv = dc.view_mut();
                let mut dav = da.view_mut();
                pgrad::composite_grad(isa, &f.view(), &co.view(), &a.view(), &g.view(),
                    &mut dfv.rows_mut(y0, n).unwrap(), &mut dcv.rows_mut(c0, cn).unwrap(), &mut dav.rows_mut(y0, n).unwrap(), y0).unwrap();
            }
            close(&format!("d_fine {isa:?}"), &df.data, &ff, 1e-5);
            close(&format!("d_coarse {isa:?}"), &dc.data, &fc, 1e-5);
            close(&format!("d_alpha {isa:?}"), &da.data, &fa, 1e-5);
        }
    }

    #[test]
    fn softmax_and_sigmoid_gradients_match_finite_differences(w in width(), n in 1usize..7, scale in prop_oneof![Just(2.0f32), Just(40.0)], seed: u64) {
        let h = 2;
        let x = Img::random(n, w, h, -scale, scale, seed);
        let g = Img::random(n, w, h, -1.0, 1.0, seed ^ 1);
        let (xd, gd) = (x.to_f64(), g.to_f64());
        let f_soft = fd(&xd, |v| dot(&oracle::channel_softmax(v, n, w, h), &gd));
        let y64 = oracle::channel_softmax(&xd, n, w, h);
        close64("oracle softmax", &oracle::channel_softmax_grad(&y64, &gd, n, w, h), &f_soft, 1e-6);
        let xs = Img { data: x.data.iter().map(|v| v / scale * 6.0).collect(), ..x.clone() };
        let f_sig = fd(&xs.to_f64(), |v| dot(&oracle::sigmoid(v), &gd));
        for isa in isas_under_test() {
            let mut y = Img::filled(n, w, h, f32::NAN);
            softmax::channel_softmax::<F32>(isa, &x.view(), &mut y.view_mut()).unwrap();
            let mut dx = Img::filled(n, w, h, f32::NAN);
            sgrad::channel_softmax_grad(isa, &y.view(), &g.view(), &mut dx.view_mut()).unwrap();
            // y_i (dy_i - sum y dy) cancels terms of size |dy| ~ 1 where the
            // softmax saturates: their f32 rounding is the error's floor.
            close_floor(&format!("softmax {isa:?}"), &dx.data, &f_soft, 1e-4, 1e-2);
            let mut ys = Img::filled(n, w, h, f32::NAN);
            sgrad::sigmoid(isa, &xs.view(), &mut ys.view_mut()).unwrap();
            close(&format!("sigmoid forward {isa:?}"), &ys.data, &oracle::sigmoid(&xs.to_f64()), 1e-6);
            sgrad::sigmoid_grad(isa, &ys.view(), &g.view(), &mut dx.view_mut()).unwrap();
            close(&format!("sigmoid {isa:?}"), &dx.data, &f_sig, 1e-4);
        }
    }

    #[test]
    fn apply_gradients_match_finite_differences(w in width(), h in 1usize..7, c in 1usize..4, k in prop_oneof![Just(1usize), Just(3), Just(7)], seed: u64) {
        let kern = Img::random(k * k, w, h, -0.5, 0.5, seed);
        let src = Img::random(c, w, h, -1.0, 1.0, seed ^ 1);
        let g = Img::random(c, w, h, -1.0, 1.0, seed ^ 2);
        let (kd, sd, gd) = (kern.to_f64(), src.to_f64(), g.to_f64());
        let fk = fd(&kd, |v| dot(&oracle::unfold(k, v, &sd, c, w, h), &gd));
        let fs = fd(&sd, |v| dot(&oracle::unfold(k, &kd, v, c, w, h), &gd));
        let (ok, os) = oracle::unfold_grad(k, &kd, &sd, &gd, c, w, h);
        close64("oracle d_kernel", &ok, &fk, 1e-6);
        close64("oracle d_src", &os, &fs, 1e-6);
        for isa in isas_under_test() {
            let (mut dk, mut ds) = (Img::filled(k * k, w, h, f32::NAN), Img::filled(c, w, h, f32::NAN));
            ugrad::apply_grad(isa, k, &kern.view(), &src.view(), &g.view(), Some(&mut dk.view_mut()), Some(&mut ds.view_mut()), 0).unwrap();
            close(&format!("d_kernel {isa:?}"), &dk.data, &fk, 1e-5);
            close(&format!("d_src {isa:?}"), &ds.data, &fs, 1e-5);
        }
    }
}

/// The fused filter's gradients for one case, checked as above (against
/// finite differences when `fd_too`, else against the analytic oracle that
/// the small cases check against them).
#[allow(clippy::too_many_arguments)]
fn check_fused(w: usize, h: usize, sizes: &[usize], fusion: bool, albedo: bool, scale: f32, seed: u64, fd_too: bool) {
    let m = sizes.len();
    let imp = Img::random(m, w, h, -scale, scale, seed);
    let fus = Img::random(m, w, h, -3.0, 3.0, seed ^ 1);
    let alb = Img::random(3, w, h, 0.1, 1.0, seed ^ 2);
    let rad = Img::random(3, w, h, 0.0, 4.0, seed ^ 3);
    let g = Img::random(3, w, h, -1.0, 1.0, seed ^ 4);
    let (id, fdv, ad, rd, gd) = (imp.to_f64(), fus.to_f64(), alb.to_f64(), rad.to_f64(), g.to_f64());
    let fo = fusion.then_some(&fdv[..]);
    let ao = albedo.then_some(&ad[..]);
    let loss =
        |i: &[f64], f: Option<&[f64]>, r: &[f64]| dot(&oracle::fused_pixelwise(sizes, i, f, ao, r, 3, w, h), &gd);
    let (oi, of, oc) = oracle::fused_grad(sizes, &id, fo, ao, &rd, &gd, 3, w, h);
    let (fi, ff, fr) = if fd_too {
        let fi = fd(&id, |v| loss(v, fo, &rd));
        let fr = fd(&rd, |v| loss(&id, fo, v));
        let ff = if fusion { fd(&fdv, |v| loss(&id, Some(v), &rd)) } else { Vec::new() };
        close64("oracle d_importance", &oi, &fi, 1e-5);
        close64("oracle d_fusion", &of, &ff, 1e-5);
        close64("oracle d_radiance", &oc, &fr, 1e-5);
        (fi, ff, fr)
    } else {
        (oi, of, oc)
    };
    let inp = FusedInputs {
        sizes,
        importance: imp.view(),
        fusion: fusion.then(|| fus.view()),
        albedo: albedo.then(|| alb.view()),
        radiance: rad.view(),
    };
    let mut scratch = vec![f32::NAN; sgrad::fused_grad_scratch_len(m, 3, w)];
    let mut whole: Option<(Vec<f32>, Vec<f32>, Vec<f32>)> = None;
    for isa in isas_under_test() {
        for split in [h, h / 2, 1] {
            let (mut di, mut df, mut dr) =
                (Img::filled(m, w, h, f32::NAN), Img::filled(m, w, h, f32::NAN), Img::filled(3, w, h, f32::NAN));
            let mut y0 = 0;
            while y0 < h {
                let n = split.max(1).min(h - y0);
                let (mut div, mut dfv, mut drv) = (di.view_mut(), df.view_mut(), dr.view_mut());
                let (mut a, mut b, mut cc) =
                    (div.rows_mut(y0, n).unwrap(), dfv.rows_mut(y0, n).unwrap(), drv.rows_mut(y0, n).unwrap());
                let out = sgrad::FusedGrads { importance: &mut a, fusion: fusion.then_some(&mut b), radiance: &mut cc };
                sgrad::fused_filter_grad(isa, &inp, &g.view(), out, y0, &mut scratch).unwrap();
                y0 += n;
            }
            let what = format!("fused {isa:?} sizes {sizes:?} scale {scale} bands of {split}");
            // Terms of size |g| |c| (~4) cancel in these sums: their rounding sets the floor.
            close_floor(&format!("{what}: d_importance"), &di.data, &fi, 2e-5, 1.0);
            close_floor(&format!("{what}: d_radiance"), &dr.data, &fr, 2e-5, 1.0);
            if fusion {
                close_floor(&format!("{what}: d_fusion"), &df.data, &ff, 2e-5, 1.0);
            }
            // Bands and ISAs give the same bits.
            let got = (di.data, if fusion { df.data } else { Vec::new() }, dr.data);
            match &whole {
                None => whole = Some(got),
                Some(w0) => assert!(w0 == &got, "{what}: differs from the first run's bits"),
            }
        }
    }
}

proptest! {
    #![proptest_config(cfg(12))]

    #[test]
    fn fused_gradients_match_finite_differences(w in width(), h in 1usize..9, m in 1usize..4, fusion: bool, albedo: bool,
                                                scale in prop_oneof![Just(2.0f32), Just(30.0)], seed: u64) {
        let sizes: Vec<usize> = (0..m).map(|i| 3 + 4 * i).collect();
        check_fused(w, h, &sizes, fusion || m > 1, albedo, scale, seed, true);
    }
}

/// All six WSKP sizes on a frame taller and wider than a gradient tile, so
/// tile seams are crossed.
#[test]
fn fused_gradients_across_tiles() {
    check_fused(37, 41, &[3, 5, 7, 9, 11, 13], true, true, 4.0, 7, false);
    check_fused(300, 70, &[3, 13], true, true, 40.0, 8, false);
}

/// Logits of 1e4 and windows 90 nats apart (the shifted denominators of the
/// lower band underflow the region's shift): finite gradients, equal to the
/// f64 oracle's (which shifts each window by its own maximum).
#[test]
fn fused_gradients_survive_extreme_logits() {
    let (w, h, m) = (23, 40, 2);
    let sizes = [5usize, 9];
    let mut imp = Img::random(m, w, h, -2.0, 2.0, 3);
    for c in 0..m {
        for y in 0..h {
            for x in 0..w {
                if y < 12 {
                    *imp.at_mut(c, y, x) += 90.0; // a band 90 nats above the rest
                }
                if (x + y) % 17 == 0 {
                    *imp.at_mut(c, y, x) = 1e4;
                }
            }
        }
    }
    let fus = Img::random(m, w, h, -2.0, 2.0, 4);
    let rad = Img::random(3, w, h, 0.0, 4.0, 5);
    let g = Img::random(3, w, h, -1.0, 1.0, 6);
    let (oi, of, oc) =
        oracle::fused_grad(&sizes, &imp.to_f64(), Some(&fus.to_f64()), None, &rad.to_f64(), &g.to_f64(), 3, w, h);
    let inp = FusedInputs {
        sizes: &sizes,
        importance: imp.view(),
        fusion: Some(fus.view()),
        albedo: None,
        radiance: rad.view(),
    };
    let mut scratch = vec![0.0; sgrad::fused_grad_scratch_len(m, 3, w)];
    for isa in isas_under_test() {
        let (mut di, mut df, mut dr) = (Img::zeros(m, w, h), Img::zeros(m, w, h), Img::zeros(3, w, h));
        let out = sgrad::FusedGrads {
            importance: &mut di.view_mut(),
            fusion: Some(&mut df.view_mut()),
            radiance: &mut dr.view_mut(),
        };
        sgrad::fused_filter_grad(isa, &inp, &g.view(), out, 0, &mut scratch).unwrap();
        for v in di.data.iter().chain(&df.data).chain(&dr.data) {
            assert!(v.is_finite(), "{isa:?}: non-finite gradient");
        }
        close(&format!("extreme d_importance {isa:?}"), &di.data, &oi, 1e-4);
        close(&format!("extreme d_fusion {isa:?}"), &df.data, &of, 1e-4);
        close(&format!("extreme d_radiance {isa:?}"), &dr.data, &oc, 1e-4);
    }
}

/// Logits spread over 160 nats between neighbours (as a long-trained
/// ImportanceNet's): windows are taken at the tile's shift, at the lower
/// shifts of the extra passes, or one by one; every way equals the oracle.
#[test]
fn fused_gradients_at_spread_logits() {
    for (scale, seed) in [(80.0f32, 11u64), (35.0, 12), (60.0, 13)] {
        check_fused(45, 37, &[3, 5, 7, 9, 11, 13], true, true, scale, seed, false);
    }
}

/// The max pool's gradient follows the forward pool's choice: the pooled
/// value is the input at the pixel the gradient goes to.
#[test]
fn max_pool_gradient_goes_where_the_forward_took_its_value() {
    let (w, h) = (9, 5);
    let x = Img::random(2, w, h, -1.0, 1.0, 1);
    let mut pooled = Img::zeros(2, 5, 3);
    pool::reduce2x2::<F32>(Isa::Scalar, Reduce::Max, &x.view(), &mut pooled.view_mut(), 0).unwrap();
    let ones = Img::filled(2, 5, 3, 1.0);
    let mut d = Img::zeros(2, w, h);
    pgrad::max_pool2x2_grad(Isa::Scalar, &x.view(), &ones.view(), &mut d.view_mut(), 0).unwrap();
    for c in 0..2 {
        for yc in 0..3 {
            for xc in 0..5 {
                let hits: Vec<f32> = (2 * yc..(2 * yc + 2).min(h))
                    .flat_map(|y| (2 * xc..(2 * xc + 2).min(w)).map(move |x| (y, x)))
                    .filter(|&(y, xx)| d.at(c, y, xx) == 1.0)
                    .map(|(y, xx)| x.at(c, y, xx))
                    .collect();
                assert_eq!(hits, vec![pooled.at(c, yc, xc)], "cell ({xc}, {yc}) of plane {c}");
            }
        }
    }
}

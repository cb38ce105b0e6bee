//! The stability contract at the extremes, per operator and precision
//! (docs/contracts.md, "Stability contract"):
//! 1. A frame's values are sanitised first (`Map::Sanitize`: NaN -> 0,
//!    ±inf -> ±limit; the host does this on load) and stored in the
//!    precision (f16 saturates at ±65504, fixed point at its format's
//!    maximum). After that, every operator gives finite outputs for any
//!    radiance and any logits, at any image size.
//! 2. Logits may be anything, even unsanitised: NaN weighs 0, ±inf are
//!    clamped, so the importance filters' outputs stay convex combinations of
//!    the radiance in the window.
//! 3. Handed non-finite radiance directly, operators do not panic; NaN can
//!    then reach the outputs whose windows contain it (never from finite data).

use mcdenoise::runtime::precision::{HostPrecision, Kind, Planes};
use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{fixed, unfold, F16Arith, Fixed, Isa, F16, F32};
use mcdenoise_tests::{isas_under_test, Img};

const SIZES: [(usize, usize); 6] = [(1, 1), (1, 9), (9, 1), (2, 3), (13, 11), (40, 7)];

/// Radiance cases: name and value generator (x, y) -> value.
/// A named value field `(x, y) -> value`.
type Field = (&'static str, Box<dyn Fn(usize, usize) -> f32>);
/// A named logit field `(plane, x, y) -> logit`.
type LogitField = (&'static str, Box<dyn Fn(usize, usize, usize) -> f32>);

fn radiance_cases() -> Vec<Field> {
    vec![
        ("zero", Box::new(|_, _| 0.0)),
        ("denormal", Box::new(|_, _| 1e-30)),
        ("1e4", Box::new(|_, _| 1e4)),
        ("1e6", Box::new(|_, _| 1e6)),
        ("65504", Box::new(|_, _| 65504.0)),
        ("70000", Box::new(|_, _| 70000.0)),
        ("firefly", Box::new(|x, y| if (x, y) == (1, 1) { 1e5 } else { 0.1 })),
        ("negative", Box::new(|x, _| -5.0 - x as f32)),
        ("nan", Box::new(|x, y| if (x + y) % 3 == 0 { f32::NAN } else { 0.5 })),
        ("inf", Box::new(|x, _| if x % 2 == 0 { f32::INFINITY } else { f32::NEG_INFINITY })),
    ]
}

/// Logit cases.
fn logit_cases() -> Vec<LogitField> {
    vec![
        ("equal", Box::new(|_, _, _| 0.0)),
        ("pm1e4", Box::new(|c, x, y| if (c + x * 7 + y * 3) % 2 == 0 { 1e4 } else { -1e4 })),
        ("one-huge", Box::new(|c, x, y| if (c, x, y) == (0, 0, 0) { 1e4 } else { 0.01 * (x + y) as f32 })),
        ("nan-inf", Box::new(|c, x, _| [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 3.0][(c + x) % 4])),
    ]
}

fn image(c: usize, w: usize, h: usize, f: &dyn Fn(usize, usize) -> f32) -> Img {
    let mut img = Img::zeros(c, w, h);
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                *img.at_mut(ch, y, x) = f(x, y);
            }
        }
    }
    img
}

/// Sanitises with the core operator (step 1 of the contract), in f32.
fn sanitised(img: &Img, limit: f32) -> Img {
    let mut out = img.clone();
    tonemap::map::<F32>(Isa::Scalar, Map::Sanitize { limit }, &img.view(), &mut out.view_mut()).unwrap();
    out
}

fn store<P: HostPrecision>(img: &Img, kind: Kind) -> Planes<P::Store> {
    Planes::<P::Store>::encode_as::<P>(img.c, img.w, img.h, &img.data, kind)
}

fn logits<P: HostPrecision>(img: &Img) -> Planes<P::Store> {
    let frac = if P::NAME == "fixed" { fixed::LOGIT_FRAC } else { 0 };
    let mut p = Planes::<P::Store>::new(img.c, img.w, img.h).with_frac(frac);
    P::encode(&img.data, &mut p.data, frac);
    p
}

#[track_caller]
fn assert_finite(what: &str, v: &[f32]) {
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        panic!("{what}: output {i} is {}", v[i]);
    }
}

/// Runs every operator on sanitised inputs and checks finiteness and, where
/// it is a property of the operator, convexity.
fn matrix<P: HostPrecision>() {
    let limit = if P::NAME == "f32" { 1e20 } else { 65504.0 };
    for isa in isas_under_test() {
        for (w, h) in SIZES {
            for (rname, rf) in radiance_cases() {
                let rad = sanitised(&image(3, w, h, rf.as_ref()), limit);
                let rs = store::<P>(&rad, Kind::Image);
                let dec = rs.decode::<P>();
                let (lo, hi) = dec.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
                let tag = |op: &str| format!("{} {isa:?} {w}x{h} {rname} {op}", P::NAME);
                let outp = |c: usize, ww: usize, hh: usize| Planes::<P::Store>::new(c, ww, hh).with_frac(rs.frac);
                for (lname, lf) in logit_cases() {
                    let lg = logits::<P>(&image(3, w, h, &|x, y| lf(0, x, y)));
                    let sizes = [3usize, 7, 13];
                    let imp = logits::<P>(&{
                        let mut m = Img::zeros(3, w, h);
                        for c in 0..3 {
                            for y in 0..h {
                                for x in 0..w {
                                    *m.at_mut(c, y, x) = lf(c, x, y);
                                }
                            }
                        }
                        m
                    });
                    for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                        for k in [3usize, 7] {
                            let mut o = outp(3, w, h);
                            let mut s = vec![0.0; softmax::window_scratch_len::<P>(path, k, 3, w)];
                            let lv = lg.view().channel(0).unwrap();
                            softmax::window_filter::<P>(isa, path, k, &lv, &rs.view(), &mut o.view_mut(), 0, &mut s)
                                .unwrap();
                            let d = o.decode::<P>();
                            assert_finite(&tag(&format!("window {path:?} k={k} {lname}")), &d);
                            // A convex combination of the window's radiance, to the
                            // arithmetic's rounding (every f16 operation rounds: ~sqrt(k^2) ulp).
                            let rel = if P::NAME == "f16-arith" { 3e-2 } else { 1e-3 };
                            let slack = rel * (hi.abs().max(lo.abs()) + 1.0);
                            // In f16 arithmetic a window sum of radiance above 65504
                            // saturates (documented): convexity holds below that.
                            let f16_sum_overflows =
                                P::NAME == "f16-arith" && hi.abs().max(lo.abs()) * (k * k) as f32 > 65504.0;
                            assert!(
                                f16_sum_overflows || d.iter().all(|&v| v >= lo - slack && v <= hi + slack),
                                "{} not convex: {:?} in [{lo}, {hi}] k={k} {path:?}",
                                tag(lname),
                                d
                            );
                        }
                        let inp = FusedInputs {
                            sizes: &sizes,
                            importance: imp.view(),
                            fusion: Some(imp.view()),
                            albedo: None,
                            radiance: rs.view(),
                        };
                        let mut o = outp(3, w, h);
                        let mut s = vec![0.0; softmax::fused_scratch_len::<P>(path, &sizes, 3, w)];
                        softmax::fused_filter::<P>(isa, path, &inp, &mut o.view_mut(), 0, &mut s).unwrap();
                        assert_finite(&tag(&format!("fused {path:?} {lname}")), &o.decode::<P>());
                    }
                    let mut kern = Planes::<P::Store>::new(49, w, h).with_frac(fixed::KERNEL_FRAC);
                    softmax::importance_kernels::<P>(isa, 7, &lg.view().channel(0).unwrap(), &mut kern.view_mut(), 0)
                        .unwrap();
                    assert_finite(&tag(&format!("kernels {lname}")), &kern.decode::<P>());
                    let mut o = outp(3, w, h);
                    let mut s = vec![0.0; unfold::scratch_len::<P>(7, 3, w)];
                    unfold::apply::<P>(isa, 7, &kern.view(), &rs.view(), &mut o.view_mut(), &mut s).unwrap();
                    assert_finite(&tag(&format!("unfold {lname}")), &o.decode::<P>());
                    let mut cs = Planes::<P::Store>::new(3, w, h).with_frac(fixed::KERNEL_FRAC);
                    softmax::channel_softmax::<P>(isa, &imp.view(), &mut cs.view_mut()).unwrap();
                    let cd = cs.decode::<P>();
                    assert_finite(&tag(&format!("channel softmax {lname}")), &cd);
                    assert!(cd.iter().all(|&v| (-1e-3..=1.0 + 1e-3).contains(&v)), "{}", tag(lname));
                }
                // Pools and the compositor.
                let (wc, hc) = (pool::coarse(w), pool::coarse(h));
                for op in [Reduce::Mean, Reduce::Max] {
                    let mut o = outp(3, wc, hc);
                    pool::reduce2x2::<P>(isa, op, &rs.view(), &mut o.view_mut(), 0).unwrap();
                    assert_finite(&tag(&format!("{op:?}")), &o.decode::<P>());
                }
                let mut coarse = outp(3, wc, hc);
                pool::reduce2x2::<P>(isa, Reduce::Mean, &rs.view(), &mut coarse.view_mut(), 0).unwrap();
                let alpha = store::<P>(&Img::filled(1, w, h, 0.7), Kind::Unit);
                let mut o = outp(3, w, h);
                pool::composite::<P>(isa, &rs.view(), &coarse.view(), &alpha.view(), &mut o.view_mut(), 0).unwrap();
                assert_finite(&tag("composite"), &o.decode::<P>());
                // Convolution.
                let wts = Img::random(3 * 3 * 9, 1, 1, -0.1, 0.1, 7);
                let wfrac = if P::NAME == "fixed" { 12 } else { 0 };
                let mut ws = vec![P::Store::default(); wts.data.len()];
                P::encode(&wts.data, &mut ws, wfrac);
                let layer = Conv2d {
                    k: 3,
                    cin: 3,
                    cout: 3,
                    weights: &ws,
                    bias: None,
                    act: Activation::LeakyRelu(0.1),
                    weight_frac: wfrac,
                };
                let mut o = outp(3, w, h);
                let mut s = vec![0.0; conv::conv2d_scratch_len::<P>(3, 3, 3, w)];
                conv::conv2d::<P>(isa, &layer, &rs.view(), &mut o.view_mut(), 0, &mut s).unwrap();
                assert_finite(&tag("conv"), &o.decode::<P>());
                // Tone maps and (de)modulation.
                let alb = store::<P>(&Img::filled(3, w, h, 0.0), Kind::Unit);
                for op in [
                    Map::Gamma { gamma: 2.2, clamp: true },
                    Map::Filmic,
                    Map::Log1p,
                    Map::Expm1,
                    Map::Sanitize { limit: 10.0 },
                ] {
                    let mut o = Planes::<P::Store>::new(3, w, h).with_frac(fixed::KERNEL_FRAC - 4);
                    tonemap::map::<P>(isa, op, &rs.view(), &mut o.view_mut()).unwrap();
                    assert_finite(&tag(&format!("{op:?}")), &o.decode::<P>());
                }
                for divide in [true, false] {
                    let mut o = outp(3, w, h);
                    if divide {
                        tonemap::demodulate::<P>(isa, &rs.view(), &alb.view(), 1e-3, &mut o.view_mut()).unwrap();
                    } else {
                        tonemap::remodulate::<P>(isa, &rs.view(), &alb.view(), 1e-3, &mut o.view_mut()).unwrap();
                    }
                    assert_finite(&tag(&format!("modulate {divide}")), &o.decode::<P>());
                }
                // Temporal accumulation with zero motion and a history.
                let motion = store::<P>(&Img::filled(2, w, h, 0.3), Kind::Plain);
                let hist = Planes::<P::Store>::new(1, w, h).with_frac(8);
                let inp = TemporalInputs {
                    color: rs.view(),
                    normal: None,
                    position: None,
                    motion: Some(motion.view()),
                    prev_color: rs.view(),
                    prev_normal: None,
                    prev_position: None,
                    prev_history: hist.view(),
                    albedo: None,
                    prev_albedo: None,
                };
                let (mut o, mut hh) = (outp(3, w, h), Planes::<P::Store>::new(1, w, h).with_frac(8));
                temporal::accumulate::<P>(
                    isa,
                    &inp,
                    &TemporalParams::default(),
                    &mut o.view_mut(),
                    &mut hh.view_mut(),
                    0,
                )
                .unwrap();
                assert_finite(&tag("temporal"), &o.decode::<P>());
                // One à-trous level with a depth guide.
                let noise = store::<P>(&Img::filled(1, w, h, 0.01), Kind::Plain);
                let depth = store::<P>(&Img::filled(1, w, h, 2.0), Kind::Plain);
                let g = AtrousGuides { noise: noise.view(), normal: None, position: None, depth: Some(depth.view()) };
                let mut o = outp(3, w, h);
                let mut s = vec![f32::NAN; atrous::step_scratch_len::<P>(1)];
                let p = AtrousParams::default();
                atrous::step::<P>(isa, 1, 1, false, &p, &g, &rs.view(), &mut o.view_mut(), 0, &mut s).unwrap();
                assert_finite(&tag("atrous"), &o.decode::<P>());
            }
        }
    }
}

#[test]
fn stability_matrix_f32() {
    matrix::<F32>();
}

#[test]
fn stability_matrix_f16() {
    matrix::<F16>();
}

#[test]
fn stability_matrix_f16_arith() {
    matrix::<F16Arith>();
}

#[test]
fn stability_matrix_fixed() {
    matrix::<Fixed>();
}

/// Non-finite radiance straight into the kernels (no sanitising): no panic,
/// and a frame without non-finite values never produces one.
#[test]
fn raw_non_finite_input_does_not_panic() {
    for isa in isas_under_test() {
        let rad = image(3, 13, 11, &|x, y| [f32::NAN, f32::INFINITY, 1.0][(x + y) % 3]);
        let lg = Img::random(1, 13, 11, -3.0, 3.0, 1);
        let mut o = Img::zeros(3, 13, 11);
        for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
            let mut s = vec![0.0; softmax::window_scratch_len::<F32>(path, 7, 3, 13)];
            softmax::window_filter::<F32>(isa, path, 7, &lg.view(), &rad.view(), &mut o.view_mut(), 0, &mut s).unwrap();
        }
        let clean = image(3, 13, 11, &|x, _| x as f32);
        let mut s = vec![0.0; softmax::window_scratch_len::<F32>(WindowPath::BoxSum, 7, 3, 13)];
        softmax::window_filter::<F32>(
            isa,
            WindowPath::BoxSum,
            7,
            &lg.view(),
            &clean.view(),
            &mut o.view_mut(),
            0,
            &mut s,
        )
        .unwrap();
        assert_finite("clean frame", &o.data);
    }
}

/// f16 storage saturates instead of overflowing: 70000 is stored as 65504
/// and a constant image stays that constant through a normalised filter.
#[test]
fn f16_overflow_saturates() {
    let img = Img::filled(3, 9, 9, 70000.0);
    let s = Planes::<half::f16>::encode::<F16>(3, 9, 9, &img.data);
    assert!(s.decode::<F16>().iter().all(|&v| v == 65504.0));
    let lg = Planes::<half::f16>::encode::<F16>(1, 9, 9, &Img::filled(1, 9, 9, 0.5).data);
    for isa in isas_under_test() {
        let mut o = Planes::<half::f16>::new(3, 9, 9);
        let mut sc = vec![0.0; softmax::window_scratch_len::<F16>(WindowPath::BoxSum, 5, 3, 9)];
        softmax::window_filter::<F16>(isa, WindowPath::BoxSum, 5, &lg.view(), &s.view(), &mut o.view_mut(), 0, &mut sc)
            .unwrap();
        assert!(o.decode::<F16>().iter().all(|&v| v == 65504.0), "{isa:?}");
    }
}

//! The reduced precisions (f16 storage, f16 arithmetic, fixed point) against
//! the f64 oracle, on the inputs as they were stored (so the figure is the
//! arithmetic's error, not the inputs' quantisation), and the fixed-point
//! SIMD paths against scalar, bit for bit.

use mcdenoise::runtime::precision::{HostPrecision, Kind, Planes};
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::{fixed, unfold, F16Arith, Fixed, Isa, F16};
use mcdenoise_tests::{assert_close, isas_under_test, oracle, simd_isas, Img};
use proptest::prelude::*;

/// An image stored in precision `P` (its format chosen by the host policy).
fn store<P: HostPrecision>(img: &Img, kind: Kind) -> Planes<P::Store> {
    Planes::<P::Store>::encode_as::<P>(img.c, img.w, img.h, &img.data, kind)
}

/// The stored values as f64 (what the kernel really saw).
fn seen<P: HostPrecision>(p: &Planes<P::Store>) -> Vec<f64> {
    p.decode::<P>().iter().map(|&v| v as f64).collect()
}

/// An output buffer in `P` with the given format.
fn out<P: HostPrecision>(c: usize, w: usize, h: usize, frac: i8) -> Planes<P::Store> {
    Planes::<P::Store>::new(c, w, h).with_frac(frac)
}

/// Tolerance `(atol, rtol)` of precision `P` for a result built from `terms`
/// products, on values of magnitude `mag`, stored with `frac` bits (fixed).
fn tol<P: HostPrecision>(terms: usize, mag: f64, frac: i8) -> (f64, f64) {
    let n = terms as f64;
    match P::NAME {
        "f16" => (1e-6 * mag, 1.0e-3),
        "f16-arith" => (4e-3 * mag * n.sqrt(), 2e-3 * n.sqrt()),
        _ => (4.0 * (-(frac as f64)).exp2() + 2e-4 * mag, 2e-3),
    }
}

/// The radiance's scale in the checks: 1, or 2^-16 (a render in units
/// where the radiance is under 1.2e-4: fixed point's finest image formats;
/// fixed point only, as f16 holds such values as subnormals whatever the
/// arithmetic does).
fn scale(dim: bool) -> f32 {
    if dim {
        1.0 / 65536.0
    } else {
        1.0
    }
}

fn check_unfold<P: HostPrecision>(w: usize, h: usize, k: usize, dim: bool, seed: u64) {
    // Normalised non-negative kernels (the softmax kernels' kind), radiance in [0, 8).
    let mut kern = Img::random(k * k, w, h, 0.0, 1.0, seed);
    let n = w * h;
    for p in 0..n {
        let s: f32 = (0..k * k).map(|j| kern.data[j * n + p]).sum();
        for j in 0..k * k {
            kern.data[j * n + p] /= s;
        }
    }
    let s = scale(dim);
    let src = Img::random(3, w, h, 0.0, 8.0 * s, seed ^ 1);
    let (ks, ss) = (store::<P>(&kern, Kind::Unit), store::<P>(&src, Kind::Image));
    assert!(!dim || P::NAME != "fixed" || ss.frac > 14, "dim radiance in a format finer than Q1.14: {}", ss.frac);
    let want = oracle::unfold(k, &seen::<P>(&ks), &seen::<P>(&ss), 3, w, h);
    for isa in isas_under_test() {
        let mut o = out::<P>(3, w, h, ss.frac);
        let mut scratch = vec![0.0; unfold::scratch_len::<P>(k, 3, w)];
        unfold::apply::<P>(isa, k, &ks.view(), &ss.view(), &mut o.view_mut(), &mut scratch).unwrap();
        let (a, r) = tol::<P>(k * k, 8.0 * s as f64, o.frac);
        assert_close(&format!("{} unfold {isa:?} k={k} dim {dim}", P::NAME), &o.decode::<P>(), &want, a, r);
    }
}

fn check_fused<P: HostPrecision>(w: usize, h: usize, m: usize, dim: bool, seed: u64) {
    let sizes: Vec<usize> = (0..m).map(|i| 3 + 2 * i).collect();
    let imp = Img::random(m, w, h, -12.0, 12.0, seed);
    let fus = Img::random(m, w, h, -4.0, 4.0, seed ^ 1);
    let alb = Img::random(3, w, h, 0.0, 1.0, seed ^ 2);
    let s = scale(dim);
    let rad = Img::random(3, w, h, 0.0, 16.0 * s, seed ^ 3);
    // Logits in Q7.8 for fixed point (the float precisions ignore the format).
    let logit_store = |img: &Img| {
        let frac = if P::NAME == "fixed" { fixed::LOGIT_FRAC } else { 0 };
        let mut p = Planes::<P::Store>::new(img.c, img.w, img.h).with_frac(frac);
        P::encode(&img.data, &mut p.data, frac);
        p
    };
    let (is, fs) = (logit_store(&imp), logit_store(&fus));
    let (als, rs) = (store::<P>(&alb, Kind::Unit), store::<P>(&rad, Kind::Image));
    assert!(!dim || P::NAME != "fixed" || rs.frac > 14, "dim radiance in a format finer than Q1.14: {}", rs.frac);
    let want =
        oracle::fused(&sizes, &seen::<P>(&is), Some(&seen::<P>(&fs)), Some(&seen::<P>(&als)), &seen::<P>(&rs), 3, w, h);
    for isa in isas_under_test() {
        for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
            let inp = FusedInputs {
                sizes: &sizes,
                importance: is.view(),
                fusion: Some(fs.view()),
                albedo: Some(als.view()),
                radiance: rs.view(),
            };
            let mut o = out::<P>(3, w, h, rs.frac);
            let mut scratch = vec![0.0; softmax::fused_scratch_len::<P>(path, &sizes, 3, w)];
            softmax::fused_filter::<P>(isa, path, &inp, &mut o.view_mut(), 0, &mut scratch).unwrap();
            let (a, r) = tol::<P>(sizes.iter().map(|k| k * k).max().unwrap_or(1), 16.0 * s as f64, o.frac);
            // Fixed point: the weights come from a 1e-5 exp and 1/256-nat logits: looser relative bound.
            let r = if P::NAME == "fixed" { 2e-2 } else { r };
            assert_close(&format!("{} fused {isa:?} {path:?} dim {dim}", P::NAME), &o.decode::<P>(), &want, a, r);
        }
    }
}

fn check_pools<P: HostPrecision>(w: usize, h: usize, dim: bool, seed: u64) {
    let s = scale(dim);
    let src = Img::random(2, w, h, -4.0 * s, 4.0 * s, seed);
    let ss = store::<P>(&src, Kind::Image);
    let sv = seen::<P>(&ss);
    let (wc, hc) = (pool::coarse(w), pool::coarse(h));
    for isa in isas_under_test() {
        for (op, max) in [(Reduce::Mean, false), (Reduce::Max, true)] {
            let want = oracle::reduce2x2(&sv, 2, w, h, max);
            let mut o = out::<P>(2, wc, hc, ss.frac);
            pool::reduce2x2::<P>(isa, op, &ss.view(), &mut o.view_mut(), 0).unwrap();
            let (a, r) = tol::<P>(4, 4.0 * s as f64, o.frac);
            assert_close(&format!("{} {op:?} {isa:?} dim {dim}", P::NAME), &o.decode::<P>(), &want, a, r);
        }
        let coarse = Img::random(2, wc, hc, -4.0 * s, 4.0 * s, seed ^ 5);
        let cs = store::<P>(&coarse, Kind::Image);
        let alpha = Img::random(1, w, h, 0.0, 1.0, seed ^ 6);
        let als = store::<P>(&alpha, Kind::Unit);
        let want = oracle::composite(&sv, &seen::<P>(&cs), &seen::<P>(&als), 2, w, h);
        // f - a D(f) + a c overshoots the inputs' range: one bit of headroom.
        let mut o = out::<P>(2, w, h, ss.frac - 1);
        pool::composite::<P>(isa, &ss.view(), &cs.view(), &als.view(), &mut o.view_mut(), 0).unwrap();
        let (a, r) = tol::<P>(6, 8.0 * s as f64, o.frac);
        assert_close(&format!("{} composite {isa:?} dim {dim}", P::NAME), &o.decode::<P>(), &want, a, r);
    }
}

fn check_conv<P: HostPrecision>(w: usize, h: usize, k: usize, cin: usize, cout: usize, seed: u64) {
    let src = Img::random(cin, w, h, -1.0, 1.0, seed);
    let wts = Img::random(cout * cin * k * k, 1, 1, -0.3, 0.3, seed ^ 1);
    let bias = Img::random(cout, 1, 1, -0.2, 0.2, seed ^ 2);
    let ss = store::<P>(&src, Kind::Image);
    // Weights: a format whose per-channel sum |w| fits the fixed bit budget.
    let wfrac = if P::NAME == "fixed" { 10 } else { 0 };
    let mut ws = vec![P::Store::default(); wts.data.len()];
    P::encode(&wts.data, &mut ws, wfrac);
    let mut wseen = vec![0.0f32; ws.len()];
    P::decode(&ws, &mut wseen, wfrac);
    let ofrac = if P::NAME == "fixed" { 11 } else { 0 };
    let mut bs = vec![P::Store::default(); cout];
    P::encode(&bias.data, &mut bs, ofrac);
    let mut bseen = vec![0.0f32; cout];
    P::decode(&bs, &mut bseen, ofrac);
    let want = oracle::conv2d(
        k,
        cin,
        cout,
        &wseen.iter().map(|&v| v as f64).collect::<Vec<_>>(),
        Some(&bseen.iter().map(|&v| v as f64).collect::<Vec<_>>()),
        Some(0.1),
        &seen::<P>(&ss),
        w,
        h,
    );
    let layer =
        Conv2d { k, cin, cout, weights: &ws, bias: Some(&bs), act: Activation::LeakyRelu(0.1), weight_frac: wfrac };
    for isa in isas_under_test() {
        let mut o = out::<P>(cout, w, h, ofrac);
        let mut scratch = vec![0.0; conv::conv2d_scratch_len::<P>(k, cin, cout, w)];
        conv::conv2d::<P>(isa, &layer, &ss.view(), &mut o.view_mut(), 0, &mut scratch).unwrap();
        let (a, r) = tol::<P>(cin * k * k, 3.0, o.frac);
        assert_close(&format!("{} conv {isa:?} k={k}", P::NAME), &o.decode::<P>(), &want, a, r);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: mcdenoise_tests::cases(16), ..ProptestConfig::default() })]

    #[test]
    fn reduced_precision_unfold(w in 1usize..40, h in 1usize..20, k in prop_oneof![Just(3usize), Just(7), Just(13)],
                                dim: bool, seed: u64) {
        check_unfold::<F16>(w, h, k, false, seed);
        check_unfold::<F16Arith>(w, h, k, false, seed);
        check_unfold::<Fixed>(w, h, k, dim, seed);
    }

    #[test]
    fn reduced_precision_fused(w in 1usize..40, h in 1usize..30, m in 1usize..5, dim: bool, seed: u64) {
        check_fused::<F16>(w, h, m, false, seed);
        check_fused::<F16Arith>(w, h, m, false, seed);
        check_fused::<Fixed>(w, h, m, dim, seed);
    }

    #[test]
    fn reduced_precision_pools(w in 1usize..60, h in 1usize..12, dim: bool, seed: u64) {
        check_pools::<F16>(w, h, false, seed);
        check_pools::<F16Arith>(w, h, false, seed);
        check_pools::<Fixed>(w, h, dim, seed);
    }

    #[test]
    fn reduced_precision_conv(w in 1usize..40, h in 1usize..8, k in prop_oneof![Just(1usize), Just(3), Just(5)],
                              cin in 1usize..15, cout in 1usize..15, seed: u64) {
        check_conv::<F16>(w, h, k, cin, cout, seed);
        check_conv::<F16Arith>(w, h, k, cin, cout, seed);
        check_conv::<Fixed>(w, h, k, cin, cout, seed);
    }
}

/// The fixed-point fused filter over several tiles (columns past 256, rows
/// past a 48-row grid cell), run whole and in bands of rows starting off the
/// grid: the same bits on every instruction set and every split.
#[test]
fn fixed_fused_is_the_same_in_bands_and_tiles() {
    let (w, h) = (530, 101);
    let sizes = [3usize, 5, 7, 9, 11, 13];
    let m = sizes.len();
    let enc = |img: &Img, frac: i8| {
        let mut p = Planes::<i16>::new(img.c, img.w, img.h).with_frac(frac);
        Fixed::encode(&img.data, &mut p.data, frac);
        p
    };
    let is = enc(&Img::random(m, w, h, -30.0, 30.0, 5), 8);
    let fs = enc(&Img::random(m, w, h, -4.0, 4.0, 6), 11);
    let als = enc(&Img::random(3, w, h, 0.0, 1.0, 7), 14);
    let rs = store::<Fixed>(&Img::random(3, w, h, 0.0, 8.0, 8), Kind::Image);
    let inp = FusedInputs {
        sizes: &sizes,
        importance: is.view(),
        fusion: Some(fs.view()),
        albedo: Some(als.view()),
        radiance: rs.view(),
    };
    let mut sc = vec![0.0; softmax::fused_scratch_len::<Fixed>(WindowPath::BoxSum, &sizes, 3, w)];
    let mut whole = out::<Fixed>(3, w, h, rs.frac);
    softmax::fused_filter::<Fixed>(Isa::Scalar, WindowPath::BoxSum, &inp, &mut whole.view_mut(), 0, &mut sc).unwrap();
    for isa in isas_under_test() {
        let mut banded = out::<Fixed>(3, w, h, rs.frac);
        let mut y0 = 0;
        for band in [7usize, 41, 1, 30, 22] {
            let rows = band.min(h - y0);
            let mut all = banded.view_mut();
            let mut b = all.rows_mut(y0, rows).unwrap();
            softmax::fused_filter::<Fixed>(isa, WindowPath::BoxSum, &inp, &mut b, y0, &mut sc).unwrap();
            y0 += rows;
        }
        assert_eq!(y0, h);
        assert_eq!(banded.data, whole.data, "{isa:?}");
    }
}

/// Fixed point: every SIMD path gives the scalar path's bits, at every width,
/// with outputs pre-filled with different sentinels (the fused filter, whose
/// SIMD paths divide in f64 and correct to the integer quotient, included).
#[test]
fn fixed_simd_is_bit_identical_to_scalar() {
    for isa in simd_isas() {
        for w in 1..=70 {
            for h in [1, 5, 17] {
                let n = w * h;
                // Odd widths dim (fixed point's finest image format).
                let s = scale(w % 2 == 1);
                let src = Img::random(3, w, h, -3.0 * s, 3.0 * s, (w * h) as u64);
                let ss = store::<Fixed>(&src, Kind::Image);
                for k in [1, 3, 7, 15] {
                    let kern = Img::random(k * k, w, h, -1.5, 1.5, (w + k) as u64);
                    let ks = store::<Fixed>(&kern, Kind::Unit);
                    let run = |i: Isa, fill: i16| {
                        let mut o = out::<Fixed>(3, w, h, ss.frac);
                        o.data.fill(fill);
                        unfold::apply::<Fixed>(i, k, &ks.view(), &ss.view(), &mut o.view_mut(), &mut []).unwrap();
                        o.data
                    };
                    assert_eq!(run(Isa::Scalar, 1111), run(isa, -2222), "unfold {isa:?} {w}x{h} k={k}");
                }
                if h > 1 || w % 7 == 0 {
                    let sizes = [3usize, 5, 7, 9, 11, 13];
                    let m = sizes.len();
                    // Logits wide enough that some windows fall under the tile's
                    // shift by more than TINY_Q16 (the direct recomputation).
                    let li = Img::random(m, w, h, -40.0, 40.0, (w * 31 + h) as u64);
                    let lf = Img::random(m, w, h, -4.0, 4.0, (w * 17 + h) as u64);
                    let alb = Img::random(3, w, h, 0.0, 1.0, n as u64 ^ 9);
                    let enc = |img: &Img, frac: i8| {
                        let mut p = Planes::<i16>::new(img.c, img.w, img.h).with_frac(frac);
                        Fixed::encode(&img.data, &mut p.data, frac);
                        p
                    };
                    let (is, fs, als) = (enc(&li, 8), enc(&lf, 11), enc(&alb, 14));
                    for path in [WindowPath::BoxSum, WindowPath::Separable] {
                        let run = |i: Isa, fill: i16| {
                            let inp = FusedInputs {
                                sizes: &sizes,
                                importance: is.view(),
                                fusion: Some(fs.view()),
                                albedo: Some(als.view()),
                                radiance: ss.view(),
                            };
                            let mut o = out::<Fixed>(3, w, h, ss.frac);
                            o.data.fill(fill);
                            let mut sc = vec![0.0; softmax::fused_scratch_len::<Fixed>(path, &sizes, 3, w)];
                            softmax::fused_filter::<Fixed>(i, path, &inp, &mut o.view_mut(), 0, &mut sc).unwrap();
                            o.data
                        };
                        assert_eq!(run(Isa::Scalar, 1111), run(isa, -2222), "fused {isa:?} {path:?} {w}x{h}");
                    }
                }
                // The pools, into formats finer, equal and coarser than the input's.
                let (wc, hc) = (pool::coarse(w), pool::coarse(h));
                let cs = store::<Fixed>(&Img::random(3, wc, hc, -3.0 * s, 3.0 * s, n as u64 ^ 3), Kind::Image);
                let al = store::<Fixed>(&Img::random(3, w, h, 0.0, 1.0, n as u64 ^ 4), Kind::Unit);
                for of in [ss.frac - 2, ss.frac, ss.frac + 1] {
                    for op in [Reduce::Mean, Reduce::Max] {
                        let run = |i: Isa, fill: i16| {
                            let mut o = out::<Fixed>(3, wc, hc, of);
                            o.data.fill(fill);
                            pool::reduce2x2::<Fixed>(i, op, &ss.view(), &mut o.view_mut(), 0).unwrap();
                            o.data
                        };
                        assert_eq!(run(Isa::Scalar, 1111), run(isa, -2222), "reduce {op:?} {isa:?} {w}x{h} to {of}");
                    }
                    let run = |i: Isa, fill: i16| {
                        let mut o = out::<Fixed>(3, w, h, of);
                        o.data.fill(fill);
                        pool::upsample_nearest2x::<Fixed>(i, &cs.view(), &mut o.view_mut(), 0, h).unwrap();
                        o.data
                    };
                    assert_eq!(run(Isa::Scalar, 1111), run(isa, -2222), "upsample {isa:?} {w}x{h} to {of}");
                    let run = |i: Isa, fill: i16| {
                        let mut o = out::<Fixed>(3, w, h, of);
                        o.data.fill(fill);
                        pool::composite::<Fixed>(i, &ss.view(), &cs.view(), &al.view(), &mut o.view_mut(), 0).unwrap();
                        o.data
                    };
                    assert_eq!(run(Isa::Scalar, 1111), run(isa, -2222), "composite {isa:?} {w}x{h} to {of}");
                }
                for (k, cin, cout) in [(3, 14, 14), (5, 3, 7), (1, 5, 2)] {
                    let x = Img::random(cin, w, h, -1.0, 1.0, n as u64);
                    let xs = store::<Fixed>(&x, Kind::Image);
                    let wts = Img::random(cout * cin * k * k, 1, 1, -0.2, 0.2, cin as u64);
                    let mut ws = vec![0i16; wts.data.len()];
                    Fixed::encode(&wts.data, &mut ws, 10);
                    let bias: Vec<i16> = (0..cout as i16).map(|i| i * 37 - 100).collect();
                    // Output formats for an accumulator shift of about 11 and of
                    // about 20 (past 15, where adding the rounding half first could overflow).
                    for (act, of) in [
                        (Activation::Identity, 11),
                        (Activation::Relu, 11),
                        (Activation::LeakyRelu(0.1), 11),
                        (Activation::Identity, 2),
                        (Activation::LeakyRelu(0.1), 2),
                    ] {
                        let layer = Conv2d { k, cin, cout, weights: &ws, bias: Some(&bias), act, weight_frac: 10 };
                        let run = |i: Isa, fill: i16| {
                            let mut o = out::<Fixed>(cout, w, h, of);
                            o.data.fill(fill);
                            let mut sc = vec![0.0; conv::conv2d_scratch_len::<Fixed>(k, cin, cout, w)];
                            conv::conv2d::<Fixed>(i, &layer, &xs.view(), &mut o.view_mut(), 0, &mut sc).unwrap();
                            o.data
                        };
                        assert_eq!(
                            run(Isa::Scalar, 1111),
                            run(isa, -2222),
                            "conv {isa:?} {w}x{h} k={k} {act:?} out frac {of}"
                        );
                    }
                }
            }
        }
    }
}

/// Fixed-point convolution, SIMD against scalar bit for bit, on what the
/// test above does not reach: output bands starting below row 0 (the
/// kernels keep rows between output rows), odd and large channel counts,
/// stored values at both ends of i16 (-32768 reads as -32767), weights at
/// the edge of the bit budget, and shifts outside the vector range.
#[test]
fn fixed_conv_simd_matches_scalar_in_bands_at_the_extremes() {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for isa in simd_isas() {
        for (k, cin, cout) in [(3, 14, 14), (5, 7, 13), (3, 33, 3), (1, 1, 7), (5, 2, 1), (3, 3, 6)] {
            let per = cin * k * k;
            // sum |w| per output channel at most 65535 stored units.
            let wmax = (65535 / per) as u64;
            let weights: Vec<i16> =
                (0..cout * per).map(|_| ((next() % (2 * wmax + 1)) as i64 - wmax as i64) as i16).collect();
            let bias: Vec<i16> = (0..cout).map(|_| next() as i16 / 4).collect();
            for (w, h) in [(1, 1), (2, 3), (15, 2), (16, 7), (17, 5), (33, 12), (70, 4)] {
                let src: Vec<i16> = (0..cin * w * h)
                    .map(|_| match next() % 8 {
                        0 => i16::MIN,
                        1 => i16::MAX,
                        _ => next() as i16,
                    })
                    .collect();
                let sv = mcdenoise_core::View::new(&src, cin, w, h).unwrap().with_frac(8);
                for (wf, of) in [(12i8, 6i8), (4, 12)] {
                    for act in [Activation::Identity, Activation::Relu, Activation::LeakyRelu(0.1)] {
                        let layer = Conv2d { k, cin, cout, weights: &weights, bias: Some(&bias), act, weight_frac: wf };
                        let len = conv::conv2d_scratch_len::<Fixed>(k, cin, cout, w);
                        let mut want = vec![1111i16; cout * w * h];
                        let mut wv = mcdenoise_core::ViewMut::new(&mut want, cout, w, h).unwrap().with_frac(of);
                        conv::conv2d::<Fixed>(Isa::Scalar, &layer, &sv, &mut wv, 0, &mut vec![0.0; len]).unwrap();
                        for band in [1, 2, 5, h] {
                            let mut got = vec![-2222i16; cout * w * h];
                            let mut gv = mcdenoise_core::ViewMut::new(&mut got, cout, w, h).unwrap().with_frac(of);
                            // One scratch, reused dirty by every band.
                            let mut scratch = vec![f32::from_bits(0x7fc0_1234); len];
                            let mut y0 = 0;
                            while y0 < h {
                                let n = band.min(h - y0);
                                conv::conv2d::<Fixed>(
                                    isa,
                                    &layer,
                                    &sv,
                                    &mut gv.rows_mut(y0, n).unwrap(),
                                    y0,
                                    &mut scratch,
                                )
                                .unwrap();
                                y0 += n;
                            }
                            assert_eq!(
                                want, got,
                                "{isa:?} k={k} {cin}->{cout} {w}x{h} band {band} {act:?} s={wf}+8-{of}"
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn fixed_conv_refuses_weights_over_the_bit_budget() {
    let w = vec![30000i16; 9 * 2];
    let layer = Conv2d { k: 3, cin: 2, cout: 1, weights: &w, bias: None, act: Activation::Identity, weight_frac: 14 };
    let x = vec![0i16; 2 * 16];
    let mut o = vec![0i16; 16];
    let e = conv::conv2d::<Fixed>(
        Isa::Scalar,
        &layer,
        &mcdenoise_core::View::new(&x, 2, 4, 4).unwrap(),
        &mut mcdenoise_core::ViewMut::new(&mut o, 1, 4, 4).unwrap(),
        0,
        &mut [],
    )
    .unwrap_err();
    assert!(e.to_string().contains("sum of |w|"), "{e}");
}

/// The f16 rounding of the f16-arithmetic precision equals `half`'s
/// conversion (ties to even) everywhere below the saturation point.
#[test]
fn round16_matches_half() {
    let mut r = 0x1234_5678u32;
    for i in 0..2_000_000u32 {
        r ^= r << 13;
        r ^= r >> 17;
        r ^= r << 5;
        let v = match i % 4 {
            0 => f32::from_bits(r),
            1 => (r as f32 / u32::MAX as f32 - 0.5) * 1e-3,
            2 => (r as f32 / u32::MAX as f32 - 0.5) * 1.3e5,
            _ => f32::from_bits((r & 0x807f_ffff) | (((r >> 23) % 40 + 100) << 23)),
        };
        let want = if v.is_nan() {
            continue;
        } else {
            half::f16::from_f32(v.clamp(-65504.0, 65504.0)).to_f32()
        };
        let got = mcdenoise_core::real::round16(v);
        assert_eq!(got.to_bits(), want.to_bits(), "{v:e}");
    }
}

#[test]
fn f16_widening_matches_half_for_every_bit_pattern() {
    for b in 0..=u16::MAX {
        let want = half::f16::from_bits(b).to_f32();
        let got = mcdenoise_core::precision::f16_to_f32(b);
        assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()), "{b:#06x}: {got} vs {want}");
    }
}

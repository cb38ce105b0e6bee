//! Nothing in core panics on caller input: named regression cases for the
//! panics an audit found, then a property test that calls every public
//! operator with random (mostly consistent, sometimes not) shapes, bands,
//! kernel sizes, parameter values and scratch lengths, on every instruction
//! set this CPU has, and accepts `Ok` or `Err` — never a panic.

use half::f16;
use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams, SureSource};
use mcdenoise_core::conv::{self, grad as cgrad, Activation, Conv2d, ConvPrecision};
use mcdenoise_core::pool::{self, grad as pgrad, Reduce};
use mcdenoise_core::regress;
use mcdenoise_core::softmax::{self, grad as sgrad, FusedInputs, WindowPath};
use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::unfold::{self, grad as ugrad};
use mcdenoise_core::{Element, Error, F16Arith, Fixed, Isa, Precision, Shape, View, ViewMut, F16, F32};
use mcdenoise_tests::isas_under_test;
use proptest::prelude::*;

// ---------------------------------------------------------------- named cases

/// The compositor's gradient with no channels: it passed its checks, then
/// zeroed plane 0 of a 0-plane `d_alpha`.
#[test]
fn composite_grad_with_no_channels() {
    for isa in isas_under_test() {
        for (w, h) in [(0, 0), (3, 2), (1, 1)] {
            let z = Shape::new(0, w, h);
            let e: [f32; 0] = [];
            let v = |s: Shape| View::new(&e, s.channels, s.width, s.height).unwrap();
            let cs = Shape::new(0, w.div_ceil(2), h.div_ceil(2));
            let (mut a, mut b, mut c) = ([0.0f32; 0], [0.0f32; 0], [0.0f32; 0]);
            let mut df = ViewMut::new(&mut a, 0, w, h).unwrap();
            let mut dc = ViewMut::new(&mut b, 0, cs.width, cs.height).unwrap();
            let mut da = ViewMut::new(&mut c, 0, w, h).unwrap();
            let r = pgrad::composite_grad(isa, &v(z), &v(cs), &v(z), &v(z), &mut df, &mut dc, &mut da, 0);
            assert!(r.is_ok(), "{isa:?} {w}x{h}: {r:?}");
        }
    }
}

/// Temporal accumulation with a history band shorter than the colour band:
/// each band passed its own check, then the kernel wrote history rows by the
/// colour band's count (found by the property below in CI).
#[test]
fn temporal_history_band_must_match_the_colour_band() {
    let (w, h) = (5, 4);
    let c3 = vec![0.5f32; 3 * w * h];
    let m2 = vec![0.0f32; 2 * w * h];
    let h1 = vec![1.0f32; w * h];
    let inp = TemporalInputs {
        color: View::new(&c3, 3, w, h).unwrap(),
        normal: None,
        position: None,
        motion: Some(View::new(&m2, 2, w, h).unwrap()),
        prev_color: View::new(&c3, 3, w, h).unwrap(),
        prev_normal: None,
        prev_position: None,
        prev_history: View::new(&h1, 1, w, h).unwrap(),
        albedo: None,
        prev_albedo: None,
    };
    for isa in isas_under_test() {
        for hist_rows in [0, 1, 2] {
            let (mut cd, mut hd) = (vec![0.0f32; 3 * w * 3], vec![0.0f32; w * hist_rows]);
            let mut color = ViewMut::new(&mut cd, 3, w, 3).unwrap();
            let mut history = ViewMut::new(&mut hd, 1, w, hist_rows).unwrap();
            let r = temporal::accumulate::<F32>(isa, &inp, &TemporalParams::default(), &mut color, &mut history, 1);
            assert!(matches!(r, Err(Error::ShapeMismatch { what: "accumulated history", .. })), "{isa:?}: {r:?}");
        }
    }
}

/// The cross-regression filter with fewer parameter rows than output rows:
/// an error naming the output band, not a row index panic.
#[test]
fn cross_filter_output_band_must_match_the_parameters() {
    let (w, h) = (7, 6);
    let c3 = vec![0.25f32; 3 * w * h];
    let v1 = vec![1.0f32; w * h];
    let three = || View::new(&c3, 3, w, h).unwrap();
    let fin = regress::FilterInputs {
        pilot_a: three(),
        pilot_b: three(),
        albedo: three(),
        normal: three(),
        prev: three(),
        valid: View::new(&v1, 1, w, h).unwrap(),
    };
    let pd = vec![0.0f32; 6 * w * 2];
    let params = View::new(&pd, 6, w, 2).unwrap();
    let mut scr = vec![0.0f32; regress::filter_scratch_len(w)];
    for isa in isas_under_test() {
        let mut od = vec![0.0f32; 9 * w * 4];
        let r = regress::filter_rows(isa, &fin, &params, &mut ViewMut::new(&mut od, 9, w, 4).unwrap(), 0, &mut scr);
        assert!(matches!(r, Err(Error::ShapeMismatch { what: "filter output", .. })), "{isa:?}: {r:?}");
        let mut od = vec![0.0f32; 9 * w * 2];
        let r = regress::filter_rows(isa, &fin, &params, &mut ViewMut::new(&mut od, 9, w, 2).unwrap(), 0, &mut scr);
        assert_eq!(r, Ok(()), "{isa:?}");
    }
}

/// The fixed-point layer check on its own (it is public, hidden): weights of
/// the wrong length are an error, not a slice panic.
#[test]
fn fixed_check_layer_checks_the_weights_length() {
    let w = [1i16; 5];
    for (cin, cout, n) in [(2, 3, 5), (1, 1, 0), (4, 4, 5), (usize::MAX, 2, 5)] {
        let layer = Conv2d { k: 3, cin, cout, weights: &w[..n], bias: None, act: Activation::Identity, weight_frac: 8 };
        assert!(<Fixed as ConvPrecision>::check_layer(&layer).is_err(), "{cin} -> {cout}, {n} weights");
    }
    let ok = Conv2d { k: 1, cin: 1, cout: 5, weights: &w, bias: None, act: Activation::Relu, weight_frac: 8 };
    assert_eq!(<Fixed as ConvPrecision>::check_layer(&ok), Ok(()));
}

/// Every public `*_scratch_len` on absurd arguments saturates instead of
/// overflowing; the operator then refuses the scratch cleanly.
#[test]
fn scratch_lengths_saturate() {
    let m = usize::MAX;
    let sizes = [15usize, m];
    let lens = [
        sgrad::fused_grad_scratch_len(m, m, m),
        sgrad::fused_grad_scratch_len(3, m / 4, 7),
        atrous::sure_scratch_len(m),
        atrous::sure_levels_scratch_len(m, m),
        cgrad::grad_input_scratch_len(m, m, m, m),
        conv::conv2d_scratch_len::<F32>(m, 3, 3, 8),
        conv::conv2d_scratch_len::<Fixed>(m, 3, 3, 8),
        conv::conv2d_scratch_len::<Fixed>(5, m, m, m),
        unfold::scratch_len::<F32>(m, m, m),
        unfold::scratch_len::<F16>(m, 2, 2),
    ];
    assert!(lens.iter().all(|&l| l == m), "{lens:?}");
    // Sizes that need no scratch or a bounded amount: no overflow either.
    assert_eq!(unfold::scratch_len::<Fixed>(m, m, m), 0);
    assert!(atrous::step_scratch_len::<F32>(u32::MAX) < 1 << 30);
    for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
        let _ = softmax::fused_scratch_len::<F32>(path, &sizes, m, m);
        let _ = softmax::fused_scratch_len::<F16>(path, &sizes, m, m);
        let _ = softmax::fused_scratch_len::<Fixed>(path, &sizes, m, m);
        let _ = softmax::window_scratch_len::<F32>(path, m, m, m);
        let _ = softmax::window_scratch_len::<Fixed>(path, m, 3, 1 << 40);
        if path != WindowPath::Direct {
            assert_eq!(softmax::fused_scratch_len::<F32>(path, &sizes, m, m), m);
            assert_eq!(softmax::fused_scratch_len::<Fixed>(path, &sizes, m, m), m);
        }
    }
}

/// `ViewMut::rows_mut` returns an error like `View::rows` (it asserted).
#[test]
fn rows_mut_out_of_range_is_an_error() {
    let mut d = [0.0f32; 6];
    let mut v = ViewMut::new(&mut d, 1, 3, 2).unwrap();
    assert!(matches!(v.rows_mut(1, 2), Err(Error::BadParameter { .. })));
    assert!(matches!(v.rows_mut(usize::MAX, 2), Err(Error::BadParameter { .. })));
    assert_eq!(v.rows_mut(2, 0).unwrap().height(), 0);
}

/// A width-0 view with strides past the address space is refused.
#[test]
fn width_zero_views_check_their_strides() {
    assert!(View::<f32>::with_strides(&[], 2, 0, 2, 1 << 40, 1 << 50).is_err());
    assert!(ViewMut::<f32>::with_strides(&mut [], 3, 0, 2, usize::MAX / 2, usize::MAX / 2).is_err());
    assert!(View::<f32>::with_strides(&[], 2, 0, 2, 0, 0).is_ok());
}

// ---------------------------------------------------------------- the property

/// Stored values from f32 (the test's own conversion, saturating).
trait Val: Element {
    fn v(x: f32) -> Self;
}
impl Val for f32 {
    fn v(x: f32) -> Self {
        x
    }
}
impl Val for f16 {
    fn v(x: f32) -> Self {
        f16::from_f32(x)
    }
}
impl Val for i16 {
    fn v(x: f32) -> Self {
        if x.is_nan() {
            0
        } else {
            (x * 256.0).clamp(-32768.0, 32767.0) as i16
        }
    }
}

/// One random case: a base shape, a band, and per argument either the shape
/// the operator expects or a random one.
#[derive(Clone, Debug)]
struct Case {
    c: usize,
    w: usize,
    h: usize,
    y0: usize,
    n: usize,
    k: usize,
    pick: Vec<u8>,
    rand: Vec<(usize, usize, usize)>,
    vals: Vec<f32>,
    scratch: u8,
    extra: usize,
}

const SLOTS: usize = 24;

fn case() -> impl Strategy<Value = Case> {
    let val = prop_oneof![
        8 => -50.0f32..50.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(-f32::INFINITY),
        1 => Just(0.0f32),
        1 => Just(1e30f32),
    ];
    (
        (0usize..=4, 0usize..=9, 0usize..=9),
        (
            0usize..=10,
            0usize..=10,
            prop_oneof![Just(0usize), Just(1), Just(2), Just(3), Just(5), Just(7), Just(15), Just(17)],
        ),
        prop::collection::vec(any::<u8>(), SLOTS),
        prop::collection::vec((0usize..=6, 0usize..=10, 0usize..=10), SLOTS),
        prop::collection::vec(val, 16),
        (any::<u8>(), 0usize..=8),
    )
        .prop_map(|((c, w, h), (y0, n, k), pick, rand, vals, (scratch, extra))| Case {
            c,
            w,
            h,
            y0,
            n,
            k,
            pick,
            rand,
            vals,
            scratch,
            extra,
        })
}

/// Buffers made one argument at a time; views over them.
struct Gen<'c> {
    case: &'c Case,
    slot: usize,
}

impl Gen<'_> {
    /// The shape for the next argument: usually `want`, one time in five random.
    fn shape(&mut self, want: (usize, usize, usize)) -> Shape {
        let i = self.slot % SLOTS;
        self.slot += 1;
        let (c, w, h) = if self.case.pick[i].is_multiple_of(5) { self.case.rand[i] } else { want };
        Shape::new(c, w, h)
    }
    fn data<T: Val>(&self, s: Shape) -> Vec<T> {
        let n = s.channels * s.width * s.height;
        (0..n).map(|i| T::v(self.case.vals[(i * 7 + self.slot) % self.case.vals.len()])).collect()
    }
    fn buf<T: Val>(&mut self, want: (usize, usize, usize)) -> (Vec<T>, Shape) {
        let s = self.shape(want);
        (self.data(s), s)
    }
    fn flag(&mut self) -> bool {
        let i = self.slot % SLOTS;
        self.slot += 1;
        self.case.pick[i].is_multiple_of(2)
    }
    /// A scratch length around `needed`: 0, one short, exact, or more.
    fn scratch(&self, needed: usize) -> Vec<f32> {
        let n = match self.case.scratch % 4 {
            0 => 0,
            1 => needed.saturating_sub(1),
            _ => needed.min(1 << 22).saturating_add(self.case.extra),
        };
        vec![f32::NAN; n.min(1 << 22)]
    }
}

/// A tensor in the Q.8 format (ignored by the float precisions).
fn frac<T>(v: View<'_, T>) -> View<'_, T> {
    v.with_frac(8)
}
fn view<T>(d: &[T], s: Shape) -> View<'_, T> {
    View::new(d, s.channels, s.width, s.height).unwrap()
}
fn view_mut<T>(d: &mut [T], s: Shape) -> ViewMut<'_, T> {
    ViewMut::new(d, s.channels, s.width, s.height).unwrap()
}

/// The operators every precision has, generic over it.
fn generic_ops<P>(isa: Isa, cs: &Case)
where
    P: Precision
        + unfold::UnfoldPrecision
        + softmax::SoftmaxPrecision
        + pool::PoolPrecision
        + tonemap::TonemapPrecision
        + conv::ConvPrecision
        + temporal::TemporalPrecision
        + atrous::AtrousPrecision,
    P::Store: Val,
{
    let (c, w, h, y0, n, k) = (cs.c, cs.w, cs.h, cs.y0, cs.n, cs.k);
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    let mut g = Gen { case: cs, slot: 0 };

    // unfold
    let (kd, ks) = g.buf::<P::Store>((k * k, w, h));
    let (sd, ss) = g.buf::<P::Store>((c, w, h));
    let (mut dd, ds) = g.buf::<P::Store>((c, w, n));
    let mut scr = g.scratch(unfold::scratch_len::<P>(k, ss.channels, ss.width));
    let (kv, sv) = (view(&kd, ks).with_frac(14), frac(view(&sd, ss)));
    ok(unfold::apply_rows::<P>(isa, k, &kv, &sv, &mut view_mut(&mut dd, ds).with_frac(8), y0, &mut scr));
    let (mut dd, ds) = g.buf::<P::Store>((c, w, h));
    ok(unfold::apply::<P>(isa, k, &kv, &sv, &mut view_mut(&mut dd, ds), &mut scr));

    // softmax
    let (ld, ls) = g.buf::<P::Store>((k * k, w, h));
    let (mut od, os) = g.buf::<P::Store>((k * k, w, n));
    let lv = frac(view(&ld, ls));
    ok(softmax::importance_kernels::<P>(isa, k, &lv, &mut view_mut(&mut od, os).with_frac(14), y0));
    let (mut od, os) = g.buf::<P::Store>((ls.channels, w, h));
    ok(softmax::channel_softmax::<P>(isa, &lv, &mut view_mut(&mut od, os).with_frac(14)));
    let m = 1 + cs.extra % 3;
    let sizes: Vec<usize> = (0..m).map(|i| [k, 3, 1, 5, 15, 17][(i + cs.extra) % 6]).collect();
    let (id, is) = g.buf::<P::Store>((m, w, h));
    let (fd, fs) = g.buf::<P::Store>((m, w, h));
    let (ad, as_) = g.buf::<P::Store>((c, w, h));
    let (rd, rs) = g.buf::<P::Store>((c, w, h));
    let (with_f, with_a) = (g.flag(), g.flag());
    let inp = FusedInputs {
        sizes: &sizes,
        importance: frac(view(&id, is)),
        fusion: with_f.then(|| frac(view(&fd, fs))),
        albedo: with_a.then(|| view(&ad, as_).with_frac(14)),
        radiance: frac(view(&rd, rs)),
    };
    for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
        let (mut od, os) = g.buf::<P::Store>((c, w, n));
        let mut scr = g.scratch(softmax::fused_scratch_len::<P>(path, &sizes, rs.channels, rs.width));
        ok(softmax::fused_filter::<P>(isa, path, &inp, &mut view_mut(&mut od, os).with_frac(8), y0, &mut scr));
        let mut scr = g.scratch(softmax::window_scratch_len::<P>(path, k, rs.channels, rs.width));
        let (mut od, os) = g.buf::<P::Store>((c, w, n));
        ok(softmax::window_filter::<P>(
            isa,
            path,
            k,
            &inp.importance.channels_range(0, 1.min(is.channels)).unwrap(),
            &inp.radiance,
            &mut view_mut(&mut od, os),
            y0,
            &mut scr,
        ));
    }

    // pool
    let (pd, ps) = g.buf::<P::Store>((c, w, h));
    let pv = frac(view(&pd, ps));
    for op in [Reduce::Mean, Reduce::Max] {
        let (mut od, os) = g.buf::<P::Store>((c, hw, n));
        ok(pool::reduce2x2::<P>(isa, op, &pv, &mut view_mut(&mut od, os).with_frac(8), y0));
    }
    let (mut od, os) = g.buf::<P::Store>((c, hw, hh));
    ok(pool::avg_pool2x2::<P>(isa, &pv, &mut view_mut(&mut od, os)));
    ok(pool::max_pool2x2::<P>(isa, &pv, &mut view_mut(&mut od, os)));
    let (cd, css) = g.buf::<P::Store>((c, hw, hh));
    let cv = frac(view(&cd, css));
    let (mut od, os) = g.buf::<P::Store>((c, w, n));
    ok(pool::upsample_nearest2x::<P>(isa, &cv, &mut view_mut(&mut od, os), y0, h + cs.extra % 2));
    let na = if g.flag() { 1 } else { c };
    let (ad, as_) = g.buf::<P::Store>((na, w, h));
    let (mut od, os) = g.buf::<P::Store>((c, w, n));
    ok(pool::composite::<P>(isa, &pv, &cv, &view(&ad, as_).with_frac(14), &mut view_mut(&mut od, os), y0));

    // tonemap
    let limit = cs.vals[0];
    for op in [
        Map::Sanitize { limit },
        Map::Gamma { gamma: cs.vals[1], clamp: g.flag() },
        Map::Filmic,
        Map::Log1p,
        Map::Expm1,
    ] {
        let (mut od, os) = g.buf::<P::Store>((c, w, h));
        ok(tonemap::map::<P>(isa, op, &pv, &mut view_mut(&mut od, os)));
    }
    let (ad, as_) = g.buf::<P::Store>((c, w, h));
    let av = view(&ad, as_).with_frac(14);
    let (mut od, os) = g.buf::<P::Store>((c, w, h));
    ok(tonemap::demodulate::<P>(isa, &pv, &av, cs.vals[2], &mut view_mut(&mut od, os)));
    ok(tonemap::remodulate::<P>(isa, &pv, &av, cs.vals[3], &mut view_mut(&mut od, os)));

    // conv
    // Each argument wrong one time in four, so that some cases reach the kernel.
    let (cin, cout) = (c.max(1) - usize::from(g.flag() && g.flag() && c > 1), 1 + cs.extra % 4);
    let nw = (cout * cin * k * k).saturating_sub(usize::from(g.flag() && g.flag()));
    let wts: Vec<P::Store> = (0..nw).map(|i| P::Store::v(cs.vals[i % 16] / 64.0)).collect();
    let bias: Vec<P::Store> =
        (0..cout + usize::from(g.flag() && g.flag())).map(|i| P::Store::v(cs.vals[i % 16])).collect();
    let slope = cs.vals[4] / 40.0;
    let act = [Activation::Identity, Activation::Relu, Activation::LeakyRelu(slope)][cs.extra % 3];
    let layer = Conv2d { k, cin, cout, weights: &wts, bias: g.flag().then_some(&bias[..]), act, weight_frac: 10 };
    let (xd, xs) = g.buf::<P::Store>((cin, w, h));
    let (mut od, os) = g.buf::<P::Store>((cout, w, n));
    let mut scr = g.scratch(conv::conv2d_scratch_len::<P>(k, cin, cout, xs.width));
    ok(conv::conv2d::<P>(isa, &layer, &frac(view(&xd, xs)), &mut view_mut(&mut od, os).with_frac(8), y0, &mut scr));
    ok(P::check_layer(&layer));

    // temporal
    let bufs: Vec<(Vec<P::Store>, Shape)> =
        [(3, w, h), (3, w, h), (3, w, h), (2, w, h), (3, w, h), (3, w, h), (3, w, h), (1, w, h), (3, w, h), (3, w, h)]
            .into_iter()
            .map(|s| g.buf::<P::Store>(s))
            .collect();
    let opt = |g: &mut Gen<'_>, i: usize| g.flag().then(|| frac(view(&bufs[i].0, bufs[i].1)));
    let inp = TemporalInputs {
        color: frac(view(&bufs[0].0, bufs[0].1)),
        normal: opt(&mut g, 1),
        position: opt(&mut g, 2),
        motion: opt(&mut g, 3),
        prev_color: frac(view(&bufs[4].0, bufs[4].1)),
        prev_normal: opt(&mut g, 5),
        prev_position: opt(&mut g, 6),
        prev_history: frac(view(&bufs[7].0, bufs[7].1)),
        albedo: opt(&mut g, 8),
        prev_albedo: opt(&mut g, 9),
    };
    let params = TemporalParams {
        pos_limit: cs.vals[5],
        normal_limit: cs.vals[6],
        alpha_min: cs.vals[7] / 50.0,
        history_cap: cs.vals[8],
        search_radius: cs.extra,
        albedo_limit: cs.vals[9],
        clamp_sigma: cs.vals[10],
        clamp_radius: cs.extra,
        clamp_floor: cs.vals[11],
    };
    let clamped = TemporalParams { clamp_sigma: 1.0, clamp_radius: cs.extra.min(8), ..TemporalParams::default() };
    for p in [params, TemporalParams::default(), clamped] {
        let (mut od, os) = g.buf::<P::Store>((3, w, n));
        let (mut hd, hs) = g.buf::<P::Store>((1, w, n));
        ok(temporal::accumulate::<P>(
            isa,
            &inp,
            &p,
            &mut view_mut(&mut od, os).with_frac(8),
            &mut view_mut(&mut hd, hs).with_frac(8),
            y0,
        ));
    }

    // atrous
    let groups = 1 + cs.extra % 2;
    let with_var = g.flag();
    let level = (cs.extra % 6) as u32;
    let (nd, ns) = g.buf::<P::Store>((1, w, h));
    let (gd1, gs1) = g.buf::<P::Store>((3, w, h));
    let (gd2, gs2) = g.buf::<P::Store>((3, w, h));
    let (gd3, gs3) = g.buf::<P::Store>((1, w, h));
    let guides = AtrousGuides {
        noise: frac(view(&nd, ns)),
        normal: g.flag().then(|| frac(view(&gd1, gs1))),
        position: g.flag().then(|| frac(view(&gd2, gs2))),
        depth: g.flag().then(|| frac(view(&gd3, gs3))),
    };
    let (ad, as_) = g.buf::<P::Store>((3 * groups + usize::from(with_var), w, h));
    let (mut od, os) = g.buf::<P::Store>((3 * groups + 2 * usize::from(with_var), w, n));
    let mut scr = g.scratch(atrous::step_scratch_len::<P>(level));
    for params in [
        AtrousParams::default(),
        AtrousParams { phi_color: cs.vals[9], sigma_normal: cs.vals[10], ..AtrousParams::default() },
    ] {
        ok(atrous::step::<P>(
            isa,
            level,
            groups,
            with_var,
            &params,
            &guides,
            &frac(view(&ad, as_)),
            &mut view_mut(&mut od, os).with_frac(8),
            y0,
            &mut scr,
        ));
    }
}

/// The f32-only operators: the backward passes, SURE and the noise estimators.
fn f32_ops(isa: Isa, cs: &Case) {
    let (c, w, h, y0, n, k) = (cs.c, cs.w, cs.h, cs.y0, cs.n, cs.k);
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    let mut g = Gen { case: cs, slot: 3 };

    // softmax backward
    let (yd, ys) = g.buf::<f32>((c, w, h));
    let (dyd, dys) = g.buf::<f32>((c, w, h));
    let (mut dxd, dxs) = g.buf::<f32>((c, w, h));
    let (yv, dyv) = (view(&yd, ys), view(&dyd, dys));
    ok(sgrad::channel_softmax_grad(isa, &yv, &dyv, &mut view_mut(&mut dxd, dxs)));
    ok(sgrad::sigmoid(isa, &yv, &mut view_mut(&mut dxd, dxs)));
    ok(sgrad::sigmoid_grad(isa, &yv, &dyv, &mut view_mut(&mut dxd, dxs)));
    let m = 1 + cs.extra % 3;
    let sizes: Vec<usize> = (0..m).map(|i| [k, 3, 1, 5, 15, 17][(i + cs.extra) % 6]).collect();
    let (id, is) = g.buf::<f32>((m, w, h));
    let (fd, fs) = g.buf::<f32>((m, w, h));
    let (ad, as_) = g.buf::<f32>((c, w, h));
    let (rd, rs) = g.buf::<f32>((c, w, h));
    let (with_f, with_a) = (g.flag(), g.flag());
    let inp = FusedInputs {
        sizes: &sizes,
        importance: view(&id, is),
        fusion: with_f.then(|| view(&fd, fs)),
        albedo: with_a.then(|| view(&ad, as_)),
        radiance: view(&rd, rs),
    };
    let (gd, gs) = g.buf::<f32>((c, w, h));
    let (mut a, sa) = g.buf::<f32>((m, w, n));
    let (mut b, sb) = g.buf::<f32>((m, w, n));
    let (mut cc, sc) = g.buf::<f32>((c, w, n));
    let mut scr = g.scratch(sgrad::fused_grad_scratch_len(m, rs.channels, rs.width));
    let mut fv = view_mut(&mut b, sb);
    let (mut iv, mut rv) = (view_mut(&mut a, sa), view_mut(&mut cc, sc));
    let out = sgrad::FusedGrads {
        importance: &mut iv,
        // Present exactly when the inputs have fusion logits three times in four.
        fusion: if with_f != (g.flag() && g.flag()) { Some(&mut fv) } else { None },
        radiance: &mut rv,
    };
    ok(sgrad::fused_filter_grad(isa, &inp, &view(&gd, gs), out, y0, &mut scr));

    // conv backward
    let act = [Activation::Identity, Activation::Relu, Activation::LeakyRelu(cs.vals[0] / 40.0)][cs.extra % 3];
    let (mut dzd, dzs) = g.buf::<f32>((c, w, h));
    ok(cgrad::activation_grad(act, &yv, &dyv, &mut view_mut(&mut dzd, dzs)));
    let (cin, cout) = (c, 1 + cs.extra % 3);
    let nw = (cout * cin * k * k).saturating_sub(usize::from(g.flag()));
    let wts: Vec<f32> = (0..nw).map(|i| cs.vals[i % 16]).collect();
    let mut tw = vec![0.0f32; (cout * cin * k * k).saturating_sub(usize::from(g.flag()))];
    ok(cgrad::transpose_weights(k, cin, cout, &wts, &mut tw));
    let (dzd, dzs) = g.buf::<f32>((cout, w, h));
    let (mut dxd, dxs) = g.buf::<f32>((cin, w, n));
    let mut scr = g.scratch(cgrad::grad_input_scratch_len(k, cin, cout, w));
    ok(cgrad::grad_input(isa, k, cin, cout, &tw, &view(&dzd, dzs), &mut view_mut(&mut dxd, dxs), y0, &mut scr));
    let (xd, xs) = g.buf::<f32>((cin, w, h));
    let mut dw = vec![0.0f32; (cout * cin * k * k).saturating_sub(usize::from(g.flag()))];
    let mut db = vec![0.0f32; cout + usize::from(g.flag())];
    let db = g.flag().then_some(&mut db[..]);
    ok(cgrad::grad_weights(isa, k, &view(&xd, xs), &view(&dzd, dzs), y0, n, &mut dw, db));

    // pool backward and the bilinear upsample
    let (cd, css) = g.buf::<f32>((c, hw, hh));
    let cv = view(&cd, css);
    let (mut dxd, dxs) = g.buf::<f32>((c, w, n));
    ok(pgrad::avg_pool2x2_grad(isa, &cv, &mut view_mut(&mut dxd, dxs), y0, h + cs.extra % 2));
    ok(pgrad::max_pool2x2_grad(isa, &yv, &cv, &mut view_mut(&mut dxd, dxs), y0));
    let (mut dcd, dcs) = g.buf::<f32>((c, hw, n));
    ok(pgrad::upsample_nearest2x_grad(isa, &dyv, &mut view_mut(&mut dcd, dcs), y0));
    ok(pgrad::upsample_bilinear2x_grad(isa, &dyv, &mut view_mut(&mut dcd, dcs), y0));
    ok(pgrad::upsample_bilinear2x(isa, &cv, &mut view_mut(&mut dxd, dxs), y0, h + cs.extra % 2));
    let na = if g.flag() { 1 } else { c };
    let (ald, als) = g.buf::<f32>((na, w, h));
    let y0e = y0 & !usize::from(g.flag());
    let (mut d1, s1) = g.buf::<f32>((c, w, n));
    let (mut d2, s2) = g.buf::<f32>((c, hw, (y0e + n).div_ceil(2).saturating_sub(y0e / 2)));
    let (mut d3, s3) = g.buf::<f32>((als.channels, w, n));
    ok(pgrad::composite_grad(
        isa,
        &yv,
        &cv,
        &view(&ald, als),
        &dyv,
        &mut view_mut(&mut d1, s1),
        &mut view_mut(&mut d2, s2),
        &mut view_mut(&mut d3, s3),
        y0e,
    ));

    // unfold backward
    let (kd, ks) = g.buf::<f32>((k * k, w, h));
    let (mut dkd, dks) = g.buf::<f32>((k * k, w, n));
    let (mut dsd, dss) = g.buf::<f32>((c, w, n));
    let (gd, gs) = g.buf::<f32>((c, w, n));
    let mut dk = view_mut(&mut dkd, dks);
    let mut ds = view_mut(&mut dsd, dss);
    let (a, b) = (g.flag(), g.flag());
    ok(ugrad::apply_grad(isa, k, &view(&kd, ks), &yv, &view(&gd, gs), a.then_some(&mut dk), b.then_some(&mut ds), y0));

    // SURE and the noise estimators
    let cands: Vec<f32> = cs.vals[..1 + cs.extra % 4].iter().map(|v| v / 50.0).collect();
    ok(atrous::best_beta(cs.vals[5], cs.vals[6], &cands));
    for source in [SureSource::Pair, SureSource::Single] {
        let (pc, nc) = if source == SureSource::Pair { (6, 6) } else { (4, 5) };
        let (ad, as_) = g.buf::<f32>((pc, w, h));
        let (bd, bs) = g.buf::<f32>((nc, w, h));
        let (mut od, os) = g.buf::<f32>((3, w, n));
        let mut scr = g.scratch(atrous::sure_scratch_len(w));
        ok(atrous::sure_shrink::<f32>(
            isa,
            source,
            &cands,
            &view(&ad, as_),
            &view(&bd, bs),
            &mut view_mut(&mut od, os),
            y0,
            &mut scr,
        ));
        let ad16: Vec<f16> = ad.iter().map(|&v| f16::from_f32(v)).collect();
        let bd16: Vec<f16> = bd.iter().map(|&v| f16::from_f32(v)).collect();
        let images = [view(&ad16, as_), view(&bd16, bs), view(&bd16, bs)];
        let levels = 1 + cs.extra % 3;
        let mut scr = g.scratch(atrous::sure_levels_scratch_len(levels - 1, w));
        ok(atrous::sure_shrink_levels::<f16>(
            isa,
            source,
            &cands,
            &images[..levels],
            &mut view_mut(&mut od, os),
            y0,
            &mut scr,
        ));
    }
    let (sd, ss) = g.buf::<f32>((3, w, h));
    let (mut od, os) = g.buf::<f32>((1, w, n));
    ok(atrous::noise::local_noise_rows(&view(&sd, ss), &mut view_mut(&mut od, os), y0));
    let (sd, ss) = g.buf::<f32>((1, w, h));
    ok(atrous::noise::median3_rows(&view(&sd, ss), &mut view_mut(&mut od, os), y0));

    // cross-regression: variance, regression, the filter and its gradient
    let (sd, ss) = g.buf::<f32>((3, w, h));
    let (mut od, os) = g.buf::<f32>((1, w, n));
    ok(regress::variance_rows(isa, &view(&sd, ss), &mut view_mut(&mut od, os), y0));
    let three: Vec<(Vec<f32>, Shape)> = (0..6).map(|_| g.buf::<f32>((3, w, h))).collect();
    let (vd, vs) = g.buf::<f32>((1, w, h));
    let rin = regress::RegressionInputs {
        x: view(&three[0].0, three[0].1),
        var: view(&vd, vs),
        y: view(&three[1].0, three[1].1),
        albedo: view(&three[2].0, three[2].1),
        normal: view(&three[3].0, three[3].1),
    };
    let (mut od, os) = g.buf::<f32>((3, w, n));
    let mut scr = g.scratch(regress::regression_scratch_len(w));
    ok(regress::regression_rows(isa, &rin, &mut view_mut(&mut od, os), y0, &mut scr));
    let fin = regress::FilterInputs {
        pilot_a: view(&three[0].0, three[0].1),
        pilot_b: view(&three[1].0, three[1].1),
        albedo: view(&three[2].0, three[2].1),
        normal: view(&three[3].0, three[3].1),
        prev: view(&three[4].0, three[4].1),
        valid: view(&vd, vs),
    };
    let (pd, ps) = g.buf::<f32>((6, w, n));
    let (mut od, os) = g.buf::<f32>((9, w, n));
    let mut scr = g.scratch(regress::filter_scratch_len(w));
    ok(regress::filter_rows(isa, &fin, &view(&pd, ps), &mut view_mut(&mut od, os), y0, &mut scr));
    let (gd, gs) = g.buf::<f32>((6, w, n));
    let (mut dd, ds) = g.buf::<f32>((6, w, n));
    ok(regress::filter_grad_rows(isa, &fin, &view(&pd, ps), &view(&gd, gs), &mut view_mut(&mut dd, ds), y0, &mut scr));
}

/// The call sites (source lines) that returned `Ok` at least once, so that
/// the property can tell that it reached the kernels and not only the checks.
static REACHED: std::sync::Mutex<std::collections::BTreeSet<u32>> =
    std::sync::Mutex::new(std::collections::BTreeSet::new());
/// Every call site.
static CALLED: std::sync::Mutex<std::collections::BTreeSet<u32>> =
    std::sync::Mutex::new(std::collections::BTreeSet::new());

/// Records an operator call's outcome; any outcome but a panic is fine here.
#[track_caller]
fn ok<T>(r: Result<T, Error>) {
    let line = std::panic::Location::caller().line();
    CALLED.lock().unwrap().insert(line);
    if r.is_ok() {
        REACHED.lock().unwrap().insert(line);
    }
}

#[test]
fn no_public_operator_panics_on_caller_input() {
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases: mcdenoise_tests::cases(4000),
        ..ProptestConfig::default()
    });
    runner
        .run(&case(), |cs| {
            for isa in isas_under_test() {
                generic_ops::<F32>(isa, &cs);
                generic_ops::<F16>(isa, &cs);
                generic_ops::<F16Arith>(isa, &cs);
                generic_ops::<Fixed>(isa, &cs);
                f32_ops(isa, &cs);
            }
            Ok(())
        })
        .unwrap();
    // Every operator ran its kernel (returned Ok) in some case, so the
    // random shapes are not all turned away by the first check.
    let (called, reached) = (CALLED.lock().unwrap().clone(), REACHED.lock().unwrap().clone());
    let missed: Vec<u32> = called.difference(&reached).copied().collect();
    assert!(missed.is_empty(), "call sites at these lines of no_panic.rs never returned Ok: {missed:?}");
}

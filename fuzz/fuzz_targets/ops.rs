//! Differential fuzzing of the core operators: every shape, kernel size,
//! precision and value the fuzzer finds, run on the scalar path and the SIMD
//! path with outputs pre-filled with different sentinels. Fixed point must
//! agree bit for bit, floats within the stated tolerance; and on sanitised
//! radiance (the stability contract) every output must be finite. A machine
//! without a SIMD path fails the target: it would otherwise compare nothing.
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use mcdenoise::precision::{HostPrecision, Kind, Planes};
use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{fixed, unfold, Fixed, Isa, F16, F32};

#[derive(Arbitrary, Debug)]
struct Case {
    op: u8,
    precision: u8,
    w: u8,
    h: u8,
    k: u8,
    m: u8,
    scale: u8,
    seed: u64,
    specials: Vec<(u16, u8)>,
}

const SPECIALS: [f32; 10] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, 1e-30, 65504.0, 70000.0, 1e6, -5.0];

fn values(n: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut s = seed | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            lo + (hi - lo) * ((s >> 40) as f32 / (1u64 << 24) as f32)
        })
        .collect()
}

fn store<P: HostPrecision>(c: usize, w: usize, h: usize, v: &[f32], kind: Kind) -> Planes<P::Store> {
    Planes::<P::Store>::encode_as::<P>(c, w, h, v, kind)
}

/// Runs `f` on the scalar ISA and on each SIMD ISA this CPU has (AVX2,
/// AVX-512) with different sentinels and
/// compares (bits for fixed point); returns the scalar output, decoded.
fn both<P: HostPrecision>(shape: (usize, usize, usize), frac: i8, f: impl Fn(Isa, &mut Planes<P::Store>)) -> Vec<f32> {
    let run = |isa: Isa, fill: f32| {
        let mut o = Planes::<P::Store>::new(shape.0, shape.1, shape.2).with_frac(frac);
        P::encode(&vec![fill; o.data.len()], &mut o.data, frac);
        f(isa, &mut o);
        o
    };
    let da = run(Isa::Scalar, -7.0).decode::<P>();
    for isa in [Isa::Avx2, Isa::Avx512].into_iter().filter(|i| i.is_supported()) {
        let db = run(isa, 3.0).decode::<P>();
        if P::NAME == "fixed" {
            assert!(da == db, "fixed point: {} differs from scalar", isa.name());
        } else {
            // f32 differs by FMA and exp rounding; f16 storage can then round to
            // neighbouring f16 values (one f16 ulp, 2^-10 relative).
            let peak = da.iter().fold(0.0f32, |m, v| if v.is_finite() { m.max(v.abs()) } else { m });
            let ulp = if P::NAME == "f16" { 1.0 / 1024.0 } else { 0.0 };
            for (i, (&x, &y)) in db.iter().zip(&da).enumerate() {
                let ok = (x.is_nan() && y.is_nan())
                    || x == y
                    || (x - y).abs() <= 1e-4 * (peak + 1.0) + (1e-4 + ulp) * y.abs();
                assert!(ok, "{} {}: element {i}: SIMD {x} vs scalar {y}", P::NAME, isa.name());
            }
        }
    }
    da
}

fn finite(what: &str, v: &[f32]) {
    assert!(v.iter().all(|x| x.is_finite()), "{what}: non-finite output from sanitised input");
}

fn run<P: HostPrecision>(c: &Case) {
    let (w, h) = (c.w as usize % 48 + 1, c.h as usize % 24 + 1);
    let n = w * h;
    let k = 2 * (c.k as usize % 8) + 1;
    let m = c.m as usize % 4 + 1;
    let mag = [1.0f32, 100.0, 1e4, 1e-3][c.scale as usize % 4];
    let mut rad = values(3 * n, -0.1 * mag, mag, c.seed);
    for &(pos, sp) in c.specials.iter().take(8) {
        let i = pos as usize % rad.len();
        rad[i] = SPECIALS[sp as usize % SPECIALS.len()];
    }
    // The contract's first step: sanitise (NaN -> 0, clamp), then store.
    let limit = if P::NAME == "f32" { 1e20 } else { 65504.0 };
    let rad: Vec<f32> = rad.iter().map(|&v| if v.is_nan() { 0.0 } else { v.clamp(-limit, limit) }).collect();
    let rs = store::<P>(3, w, h, &rad, Kind::Image);
    let lfrac = if P::NAME == "fixed" { fixed::LOGIT_FRAC } else { 0 };
    let mut logits = values(m * n, -30.0, 30.0, c.seed ^ 1);
    for &(pos, sp) in c.specials.iter().skip(8).take(4) {
        let i = pos as usize % logits.len();
        logits[i] = SPECIALS[sp as usize % SPECIALS.len()];
    }
    let mut ls = Planes::<P::Store>::new(m, w, h).with_frac(lfrac);
    P::encode(&logits, &mut ls.data, lfrac);
    let f = rs.frac;
    match c.op % 8 {
        0 => {
            let mut kern = values(k * k * n, 0.0, 1.0, c.seed ^ 2);
            for p in 0..n {
                let s: f32 = (0..k * k).map(|j| kern[j * n + p]).sum::<f32>().max(1e-6);
                (0..k * k).for_each(|j| kern[j * n + p] /= s);
            }
            let ks = store::<P>(k * k, w, h, &kern, Kind::Unit);
            let out = both::<P>((3, w, h), f, |isa, o| {
                let mut s = vec![0.0; unfold::scratch_len::<P>(k, 3, w)];
                unfold::apply::<P>(isa, k, &ks.view(), &rs.view(), &mut o.view_mut(), &mut s).unwrap();
            });
            finite("unfold", &out);
        }
        1 | 2 => {
            let path = match (c.op % 8, c.seed % 2) {
                (1, _) => WindowPath::Direct,
                (_, 0) => WindowPath::BoxSum,
                _ => WindowPath::Separable,
            };
            let sizes: Vec<usize> = (0..m).map(|i| (k + 2 * i).min(15)).collect();
            let inp = FusedInputs {
                sizes: &sizes,
                importance: ls.view(),
                fusion: (m > 1).then(|| ls.view()),
                albedo: None,
                radiance: rs.view(),
            };
            let out = both::<P>((3, w, h), f, |isa, o| {
                let mut s = vec![0.0; softmax::fused_scratch_len::<P>(path, &sizes, 3, w)];
                softmax::fused_filter::<P>(isa, path, &inp, &mut o.view_mut(), 0, &mut s).unwrap();
            });
            finite("fused", &out);
        }
        3 => {
            let (wc, hc) = (pool::coarse(w), pool::coarse(h));
            for op in [Reduce::Mean, Reduce::Max] {
                let out = both::<P>((3, wc, hc), f, |isa, o| {
                    pool::reduce2x2::<P>(isa, op, &rs.view(), &mut o.view_mut(), 0).unwrap()
                });
                finite("pool", &out);
            }
            let mut coarse = Planes::<P::Store>::new(3, wc, hc).with_frac(f);
            pool::reduce2x2::<P>(Isa::Scalar, Reduce::Mean, &rs.view(), &mut coarse.view_mut(), 0).unwrap();
            let alpha = store::<P>(1, w, h, &values(n, 0.0, 1.0, c.seed ^ 3), Kind::Unit);
            let out = both::<P>((3, w, h), f - 1, |isa, o| {
                pool::composite::<P>(isa, &rs.view(), &coarse.view(), &alpha.view(), &mut o.view_mut(), 0).unwrap()
            });
            finite("composite", &out);
        }
        4 => {
            let kc = [1, 3, 5][c.k as usize % 3];
            let cout = m + 2;
            let wts = values(cout * 3 * kc * kc, -0.2, 0.2, c.seed ^ 4);
            let wfrac = if P::NAME == "fixed" { 10 } else { 0 };
            let mut ws = vec![<P::Store>::default(); wts.len()];
            P::encode(&wts, &mut ws, wfrac);
            let act = [Activation::Identity, Activation::Relu, Activation::LeakyRelu(0.1)][c.scale as usize % 3];
            let layer = Conv2d { k: kc, cin: 3, cout, weights: &ws, bias: None, act, weight_frac: wfrac };
            let out = both::<P>((cout, w, h), f, |isa, o| {
                let mut s = vec![0.0; conv::conv2d_scratch_len::<P>(kc, 3, cout, w)];
                conv::conv2d::<P>(isa, &layer, &rs.view(), &mut o.view_mut(), 0, &mut s).unwrap();
            });
            finite("conv", &out);
        }
        5 => {
            let noise = store::<P>(1, w, h, &values(n, 0.0, 0.1 * mag * mag, c.seed ^ 5), Kind::Plain);
            let normal = store::<P>(3, w, h, &values(3 * n, -1.0, 1.0, c.seed ^ 6), Kind::Unit);
            let pos = store::<P>(3, w, h, &values(3 * n, -2.0, 2.0, c.seed ^ 7), Kind::Plain);
            let g = AtrousGuides {
                noise: noise.view(),
                normal: Some(normal.view()),
                position: Some(pos.view()),
                depth: None,
            };
            let level = c.k as u32 % 5;
            let out = both::<P>((3, w, h), f, |isa, o| {
                // Garbage scratch: a weight read before it is written shows up.
                let mut scratch = vec![f32::NAN; atrous::step_scratch_len::<P>(level)];
                let p = AtrousParams::default();
                atrous::step::<P>(isa, level, 1, false, &p, &g, &rs.view(), &mut o.view_mut(), 0, &mut scratch).unwrap()
            });
            finite("atrous", &out);
        }
        6 => {
            for op in [Map::Gamma { gamma: 2.2, clamp: true }, Map::Log1p, Map::Filmic] {
                let out = both::<P>((3, w, h), fixed::KERNEL_FRAC - 4, |isa, o| {
                    tonemap::map::<P>(isa, op, &rs.view(), &mut o.view_mut()).unwrap()
                });
                finite("tone map", &out);
            }
        }
        _ => {
            let alb = store::<P>(3, w, h, &values(3 * n, 0.0, 1.0, c.seed ^ 8), Kind::Unit);
            let out = both::<P>((3, w, h), f, |isa, o| {
                tonemap::demodulate::<P>(isa, &rs.view(), &alb.view(), 1e-3, &mut o.view_mut()).unwrap()
            });
            finite("demodulate", &out);
        }
    }
}

fuzz_target!(|c: Case| {
    assert!(Isa::Avx2.is_supported(), "no SIMD path on this machine: the differential target would compare nothing");
    match c.precision % 3 {
        0 => run::<F32>(&c),
        1 => run::<F16>(&c),
        _ => run::<Fixed>(&c),
    }
});

//! Every SIMD path against the scalar path on every width 1..=67 (so every
//! vector remainder runs) and a few heights, with the two outputs pre-filled
//! with different sentinels: a value the SIMD path forgot to write shows up as
//! a mismatch. Pure add/mul paths must agree bit for bit; paths through `exp`,
//! `log` or FMA accumulation within the stated tolerance.

use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{unfold, Isa, F32};
use mcdenoise_tests::{assert_close32, simd_isas, Img};

const SENTINEL_SCALAR: f32 = -7777.0;
const SENTINEL_SIMD: f32 = 31337.0;
const WIDTHS: std::ops::RangeInclusive<usize> = 1..=67;
const HEIGHTS: [usize; 3] = [1, 6, 19];

/// Runs `f` with the scalar ISA and with `isa` on outputs pre-filled with
/// different sentinels and returns both.
fn both(isa: Isa, shape: (usize, usize, usize), f: impl Fn(Isa, &mut Img)) -> (Img, Img) {
    let mut a = Img::filled(shape.0, shape.1, shape.2, SENTINEL_SCALAR);
    let mut b = Img::filled(shape.0, shape.1, shape.2, SENTINEL_SIMD);
    f(Isa::Scalar, &mut a);
    f(isa, &mut b);
    (a, b)
}

#[test]
fn unfold_simd_matches_scalar() {
    for isa in simd_isas() {
        for h in HEIGHTS {
            for w in WIDTHS {
                for k in [1, 3, 5, 7, 9, 11, 13, 15] {
                    for c in [1, 3, 5] {
                        let kern = Img::random(k * k, w, h, -1.0, 1.0, (w * 100 + k) as u64);
                        let src = Img::random(c, w, h, 0.0, 8.0, (h * 7 + c) as u64);
                        let (a, b) = both(isa, (c, w, h), |i, out| {
                            let mut s = vec![0.0; unfold::scratch_len::<F32>(k, c, w)];
                            unfold::apply::<F32>(i, k, &kern.view(), &src.view(), &mut out.view_mut(), &mut s).unwrap();
                        });
                        // FMA vs mul+add: half an ulp per tap of the partial sums.
                        assert_close32(
                            &format!("unfold {isa:?} {w}x{h} k={k} c={c}"),
                            &b.data,
                            &a.data,
                            1e-6 * (k * k) as f32 * 8.0,
                            1e-6,
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn softmax_simd_matches_scalar() {
    for isa in simd_isas() {
        for h in HEIGHTS {
            for w in WIDTHS {
                let sizes = [3, 5, 7, 9, 11, 13];
                let imp = Img::random(6, w, h, -40.0, 40.0, w as u64);
                let fus = Img::random(6, w, h, -8.0, 8.0, h as u64);
                let alb = Img::random(3, w, h, 0.0, 1.0, 3);
                let rad = Img::random(3, w, h, 0.0, 50.0, 4);
                for path in [WindowPath::Direct, WindowPath::BoxSum, WindowPath::Separable] {
                    let inp = FusedInputs {
                        sizes: &sizes,
                        importance: imp.view(),
                        fusion: Some(fus.view()),
                        albedo: Some(alb.view()),
                        radiance: rad.view(),
                    };
                    let (a, b) = both(isa, (3, w, h), |i, out| {
                        let mut s = vec![0.0; softmax::fused_scratch_len::<F32>(path, &sizes, 3, w)];
                        softmax::fused_filter::<F32>(i, path, &inp, &mut out.view_mut(), 0, &mut s).unwrap();
                    });
                    assert_close32(&format!("fused {isa:?} {path:?} {w}x{h}"), &b.data, &a.data, 1e-5, 1e-5);
                }
                for k in [3, 7, 15] {
                    let (a, b) = both(isa, (k * k, w, h), |i, out| {
                        softmax::importance_kernels::<F32>(
                            i,
                            k,
                            &imp.view().channel(0).unwrap(),
                            &mut out.view_mut(),
                            0,
                        )
                        .unwrap();
                    });
                    assert_close32(&format!("kernels {isa:?} {w}x{h} k={k}"), &b.data, &a.data, 1e-9, 1e-5);
                }
                let (a, b) = both(isa, (6, w, h), |i, out| {
                    softmax::channel_softmax::<F32>(i, &imp.view(), &mut out.view_mut()).unwrap();
                });
                assert_close32(&format!("channel softmax {isa:?} {w}x{h}"), &b.data, &a.data, 1e-9, 1e-5);
            }
        }
    }
}

#[test]
fn pools_simd_match_scalar_bit_for_bit() {
    for isa in simd_isas() {
        for h in HEIGHTS.into_iter().chain([2, 7]) {
            for w in WIDTHS {
                let src = Img::random(2, w, h, -9.0, 9.0, (w * h) as u64);
                let (wc, hc) = (pool::coarse(w), pool::coarse(h));
                for op in [Reduce::Mean, Reduce::Max] {
                    let (a, b) = both(isa, (2, wc, hc), |i, out| {
                        pool::reduce2x2::<F32>(i, op, &src.view(), &mut out.view_mut(), 0).unwrap();
                    });
                    assert_eq!(a.data, b.data, "{op:?} {isa:?} {w}x{h}");
                }
                let coarse = Img::random(2, wc, hc, -9.0, 9.0, w as u64);
                let (a, b) = both(isa, (2, w, h), |i, out| {
                    pool::upsample_nearest2x::<F32>(i, &coarse.view(), &mut out.view_mut(), 0, h).unwrap();
                });
                assert_eq!(a.data, b.data, "upsample {isa:?} {w}x{h}");
                let alpha = Img::random(1, w, h, 0.0, 1.0, 5);
                let (a, b) = both(isa, (2, w, h), |i, out| {
                    pool::composite::<F32>(i, &src.view(), &coarse.view(), &alpha.view(), &mut out.view_mut(), 0)
                        .unwrap();
                });
                assert_eq!(a.data, b.data, "composite {isa:?} {w}x{h}");
            }
        }
    }
}

#[test]
fn conv_simd_matches_scalar() {
    for isa in simd_isas() {
        for h in HEIGHTS {
            for w in WIDTHS {
                for k in [1, 3, 5] {
                    for (cin, cout) in [(1, 1), (3, 7), (14, 14), (10, 13)] {
                        let src = Img::random(cin, w, h, -1.0, 1.0, (w + k) as u64);
                        let wts = Img::random(cout * cin * k * k, 1, 1, -0.5, 0.5, cin as u64).data;
                        let bias = Img::random(cout, 1, 1, -0.5, 0.5, cout as u64).data;
                        for act in [Activation::Identity, Activation::Relu, Activation::LeakyRelu(0.1)] {
                            let layer = Conv2d { k, cin, cout, weights: &wts, bias: Some(&bias), act, weight_frac: 0 };
                            let (a, b) = both(isa, (cout, w, h), |i, out| {
                                let mut s = vec![0.0; conv::conv2d_scratch_len::<F32>(k, cin, cout, w)];
                                conv::conv2d::<F32>(i, &layer, &src.view(), &mut out.view_mut(), 0, &mut s).unwrap();
                            });
                            assert_close32(
                                &format!("conv {isa:?} {w}x{h} k={k} {cin}->{cout} {act:?}"),
                                &b.data,
                                &a.data,
                                1e-6 * (cin * k * k) as f32,
                                1e-6,
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn tone_maps_simd_match_scalar() {
    for isa in simd_isas() {
        for w in WIDTHS {
            let mut src = Img::random(3, w, 2, -5.0, 200.0, w as u64);
            // Specials the maps must all handle.
            let specials = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, 1e-30, 65504.0, 7e4];
            for (i, v) in specials.iter().enumerate() {
                let n = src.data.len();
                src.data[i * 5 % n] = *v;
            }
            let alb = Img::random(3, w, 2, 0.0, 1.0, 9);
            let maps = [
                (Map::Sanitize { limit: 1000.0 }, 0.0),
                (Map::Gamma { gamma: 2.2, clamp: true }, 2e-6),
                (Map::Gamma { gamma: 2.2, clamp: false }, 2e-6),
                (Map::Filmic, 0.0),
                (Map::Log1p, 2e-6),
                (Map::Expm1, 4e-6),
            ];
            for (op, rtol) in maps {
                let (a, b) = both(isa, (3, w, 2), |i, out| {
                    tonemap::map::<F32>(i, op, &src.view(), &mut out.view_mut()).unwrap();
                });
                assert_close32(&format!("{op:?} {isa:?} w={w}"), &b.data, &a.data, 1e-30, rtol);
                if rtol == 0.0 {
                    assert_eq!(
                        a.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        b.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "{op:?} bits"
                    );
                }
            }
            for divide in [true, false] {
                let (a, b) = both(isa, (3, w, 2), |i, out| {
                    if divide {
                        tonemap::demodulate::<F32>(i, &src.view(), &alb.view(), 1e-3, &mut out.view_mut()).unwrap();
                    } else {
                        tonemap::remodulate::<F32>(i, &src.view(), &alb.view(), 1e-3, &mut out.view_mut()).unwrap();
                    }
                });
                assert_close32(&format!("modulate {divide} {isa:?} w={w}"), &b.data, &a.data, 0.0, 0.0);
            }
        }
    }
}

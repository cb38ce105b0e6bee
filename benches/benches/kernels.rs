//! Every f32 operator at 1280x720, on each instruction set this CPU has, on 1
//! and 2 threads (through the host's band runner), beside a naive baseline and
//! the machine's limits: a copy and a streaming read of the same bytes, and an
//! FMA-peak loop. Group names: `op/variant`, variants `naive`, `<isa>/<n>t`,
//! `copy`, `read`, `fma_peak`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use mcdenoise::par::{Pool, Scratch};
use mcdenoise_benches::*;
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool;
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{unfold, Fixed, Isa, View, ViewMut, F16, F32};

const PLANE: usize = W * H;

fn isas() -> Vec<Isa> {
    let v: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.is_supported()).collect();
    for i in Isa::ALL {
        if !i.is_supported() {
            eprintln!("skipped: {} is not supported on this CPU", i.name());
        }
    }
    v
}

fn pools() -> Vec<Pool> {
    vec![Pool::new(1).unwrap(), Pool::new(2).unwrap()]
}

fn bench_fused(c: &mut Criterion) {
    let sizes = [3usize, 5, 7, 9, 11, 13];
    let imp = values(6 * PLANE, -6.0, 6.0, 1);
    let fus = values(6 * PLANE, -3.0, 3.0, 2);
    let alb = values(3 * PLANE, 0.05, 1.0, 3);
    let rad = values(3 * PLANE, 0.0, 4.0, 4);
    let mut out = vec![0.0f32; 3 * PLANE];
    let mut g = c.benchmark_group("fused6_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    g.bench_function("naive/1t", |b| b.iter(|| naive_fused(&sizes, &imp, &fus, &alb, &rad, &mut out, W, H)));
    let inp = FusedInputs {
        sizes: &sizes,
        importance: View::new(&imp, 6, W, H).unwrap(),
        fusion: Some(View::new(&fus, 6, W, H).unwrap()),
        albedo: Some(View::new(&alb, 3, W, H).unwrap()),
        radiance: View::new(&rad, 3, W, H).unwrap(),
    };
    for isa in isas() {
        for (path, name) in [(WindowPath::BoxSum, "boxsum"), (WindowPath::Separable, "separable")] {
            for p in pools() {
                let len = softmax::fused_scratch_len::<F32>(path, &sizes, 3, W);
                let mut scratch = Scratch::new();
                let id = BenchmarkId::new(format!("{name}/{}", isa.name()), format!("{}t", p.threads()));
                g.bench_function(id, |b| {
                    b.iter(|| {
                        let dst = ViewMut::new(&mut out, 3, W, H).unwrap();
                        p.bands(dst, 48, &mut scratch, len, |band, y0, s| {
                            softmax::fused_filter::<F32>(isa, path, &inp, band, y0, s)
                        })
                        .unwrap()
                    })
                });
            }
        }
    }
    g.throughput(Throughput::Bytes(((6 + 6 + 3 + 3 + 3) * PLANE * 4) as u64));
    let src = values(21 * PLANE, 0.0, 1.0, 5);
    let mut dst = vec![0.0f32; 21 * PLANE];
    g.bench_function("copy_inputs_and_output", |b| b.iter(|| dst.copy_from_slice(black_box(&src))));
    g.finish();
}

fn bench_unfold(c: &mut Criterion) {
    let kern = values(49 * PLANE, 0.0, 0.04, 6);
    let src = values(3 * PLANE, 0.0, 4.0, 7);
    let mut out = vec![0.0f32; 3 * PLANE];
    let mut g = c.benchmark_group("apply7x7_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    g.throughput(Throughput::Bytes((49 * PLANE * 4) as u64));
    g.bench_function("naive/1t", |b| b.iter(|| naive_unfold(7, &kern, &src, &mut out, 3, W, H)));
    let kv = View::new(&kern, 49, W, H).unwrap();
    let sv = View::new(&src, 3, W, H).unwrap();
    for isa in isas() {
        for p in pools() {
            let len = unfold::scratch_len::<F32>(7, 3, W);
            let mut scratch = Scratch::new();
            g.bench_function(BenchmarkId::new(isa.name(), format!("{}t", p.threads())), |b| {
                b.iter(|| {
                    let dst = ViewMut::new(&mut out, 3, W, H).unwrap();
                    p.bands(dst, 1, &mut scratch, len, |band, y0, s| {
                        unfold::apply_rows::<F32>(isa, 7, &kv, &sv, band, y0, s)
                    })
                    .unwrap()
                })
            });
        }
    }
    // f16 storage and fixed point: half the bytes of the kernel map.
    let kern16: Vec<half::f16> = kern.iter().map(|&v| half::f16::from_f32(v)).collect();
    let src16: Vec<half::f16> = src.iter().map(|&v| half::f16::from_f32(v)).collect();
    let mut out16 = vec![half::f16::ZERO; 3 * PLANE];
    let (kv16, sv16) = (View::new(&kern16, 49, W, H).unwrap(), View::new(&src16, 3, W, H).unwrap());
    let kq: Vec<i16> = kern.iter().map(|&v| (v * 16384.0).round() as i16).collect();
    let sq: Vec<i16> = src.iter().map(|&v| (v * 4096.0).round() as i16).collect();
    let mut outq = vec![0i16; 3 * PLANE];
    let (kvq, svq) = (View::new(&kq, 49, W, H).unwrap().with_frac(14), View::new(&sq, 3, W, H).unwrap().with_frac(12));
    for isa in isas() {
        for p in pools() {
            let mut scratch = Scratch::new();
            let len = unfold::scratch_len::<F16>(7, 3, W);
            g.bench_function(BenchmarkId::new(format!("f16/{}", isa.name()), format!("{}t", p.threads())), |b| {
                b.iter(|| {
                    let dst = ViewMut::new(&mut out16, 3, W, H).unwrap();
                    p.bands(dst, 1, &mut scratch, len, |band, y0, s| {
                        unfold::apply_rows::<F16>(isa, 7, &kv16, &sv16, band, y0, s)
                    })
                    .unwrap()
                })
            });
            g.bench_function(BenchmarkId::new(format!("fixed/{}", isa.name()), format!("{}t", p.threads())), |b| {
                b.iter(|| {
                    let dst = ViewMut::new(&mut outq, 3, W, H).unwrap().with_frac(12);
                    p.bands(dst, 1, &mut scratch, 0, |band, y0, s| {
                        unfold::apply_rows::<Fixed>(isa, 7, &kvq, &svq, band, y0, s)
                    })
                    .unwrap()
                })
            });
        }
    }
    g.bench_function("read_kernel_map/1t", |b| b.iter(|| black_box(stream_sum(black_box(&kern)))));
    let mut copy = vec![0.0f32; 49 * PLANE];
    g.bench_function("copy_kernel_map/1t", |b| b.iter(|| copy.copy_from_slice(black_box(&kern))));
    g.finish();
}

fn bench_conv(c: &mut Criterion) {
    let mut g = c.benchmark_group("conv_14to14_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_secs(1));
    let (cin, cout) = (14, 14);
    let src = values(cin * PLANE, -1.0, 1.0, 8);
    let mut out = vec![0.0f32; cout * PLANE];
    let sv = View::new(&src, cin, W, H).unwrap();
    for k in [3usize, 5] {
        let wts = values(cout * cin * k * k, -0.2, 0.2, 9);
        let bias = values(cout, -0.1, 0.1, 10);
        let layer =
            Conv2d { k, cin, cout, weights: &wts, bias: Some(&bias), act: Activation::LeakyRelu(0.1), weight_frac: 0 };
        // Multiply-adds of the interior, counted as 2 flops each.
        g.throughput(Throughput::Elements((2 * cout * cin * k * k * PLANE) as u64));
        if k == 3 {
            g.bench_function(format!("k{k}/naive/1t"), |b| {
                b.iter(|| naive_conv(k, cin, cout, &wts, &src, &mut out, W, H))
            });
        }
        for isa in isas() {
            for p in pools() {
                let len = conv::conv2d_scratch_len::<F32>(k, cin, cout, W);
                let mut scratch = Scratch::new();
                g.bench_function(BenchmarkId::new(format!("k{k}/{}", isa.name()), format!("{}t", p.threads())), |b| {
                    b.iter(|| {
                        let dst = ViewMut::new(&mut out, cout, W, H).unwrap();
                        p.bands(dst, 1, &mut scratch, len, |band, y0, s| {
                            conv::conv2d::<F32>(isa, &layer, &sv, band, y0, s)
                        })
                        .unwrap()
                    })
                });
            }
        }
        // Fixed point: inputs in Q3.12, weights in Q1.14 (sum |w| per output
        // channel within the bit budget), outputs in Q3.12.
        let sq: Vec<i16> = src.iter().map(|&v| (v * 4096.0).round() as i16).collect();
        let wq: Vec<i16> = wts.iter().map(|&v| (v * 256.0).round() as i16).collect();
        let bq: Vec<i16> = bias.iter().map(|&v| (v * 4096.0).round() as i16).collect();
        let svq = View::new(&sq, cin, W, H).unwrap().with_frac(12);
        let mut outq = vec![0i16; cout * PLANE];
        let lq =
            Conv2d { k, cin, cout, weights: &wq, bias: Some(&bq), act: Activation::LeakyRelu(0.1), weight_frac: 8 };
        for isa in isas() {
            for p in pools() {
                let len = conv::conv2d_scratch_len::<Fixed>(k, cin, cout, W);
                let mut scratch = Scratch::new();
                g.bench_function(
                    BenchmarkId::new(format!("k{k}/fixed/{}", isa.name()), format!("{}t", p.threads())),
                    |b| {
                        b.iter(|| {
                            let dst = ViewMut::new(&mut outq, cout, W, H).unwrap().with_frac(12);
                            p.bands(dst, 1, &mut scratch, len, |band, y0, s| {
                                conv::conv2d::<Fixed>(isa, &lq, &svq, band, y0, s)
                            })
                            .unwrap()
                        })
                    },
                );
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    if Isa::Avx2.is_supported() {
        let iters = 10_000_000;
        g.throughput(Throughput::Elements((iters * 12 * 8 * 2) as u64));
        g.bench_function("fma_peak/1t", |b| b.iter(|| black_box(fma_peak(black_box(iters)))));
    }
    if Isa::Avx512.is_supported() {
        // Same iterations at twice the lanes: compare against twice the FLOPs.
        let iters = 10_000_000;
        g.throughput(Throughput::Elements((iters * 12 * 16 * 2) as u64));
        g.bench_function("fma_peak_avx512/1t", |b| b.iter(|| black_box(fma_peak512(black_box(iters)))));
    }
    g.finish();
}

fn bench_two_scale(c: &mut Criterion) {
    let mut g = c.benchmark_group("two_scale_1280x720");
    g.sample_size(20).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    let fine = values(3 * PLANE, 0.0, 4.0, 11);
    let coarse = values(3 * PLANE / 4, 0.0, 4.0, 12);
    let alpha = values(PLANE, 0.0, 1.0, 13);
    let mut out = vec![0.0f32; 3 * PLANE];
    let mut small = vec![0.0f32; 3 * PLANE / 4];
    let fv = View::new(&fine, 3, W, H).unwrap();
    let cv = View::new(&coarse, 3, W / 2, H / 2).unwrap();
    let av = View::new(&alpha, 1, W, H).unwrap();
    g.throughput(Throughput::Bytes((7 * PLANE * 4 + 3 * PLANE) as u64));
    for isa in isas() {
        for p in pools() {
            let mut scratch = Scratch::new();
            g.bench_function(BenchmarkId::new(format!("composite/{}", isa.name()), format!("{}t", p.threads())), |b| {
                b.iter(|| {
                    let dst = ViewMut::new(&mut out, 3, W, H).unwrap();
                    p.bands(dst, 2, &mut scratch, 0, |band, y0, _| pool::composite::<F32>(isa, &fv, &cv, &av, band, y0))
                        .unwrap()
                })
            });
            g.bench_function(BenchmarkId::new(format!("avg_pool/{}", isa.name()), format!("{}t", p.threads())), |b| {
                b.iter(|| {
                    let dst = ViewMut::new(&mut small, 3, W / 2, H / 2).unwrap();
                    p.bands(dst, 1, &mut scratch, 0, |band, y0, _| {
                        pool::reduce2x2::<F32>(isa, pool::Reduce::Mean, &fv, band, y0)
                    })
                    .unwrap()
                })
            });
        }
    }
    let mut copy = vec![0.0f32; 3 * PLANE];
    g.bench_function("copy_image/1t", |b| b.iter(|| copy.copy_from_slice(black_box(&fine))));
    g.finish();
}

fn bench_misc(c: &mut Criterion) {
    let mut g = c.benchmark_group("misc_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    let logits = values(49 * PLANE, -10.0, 10.0, 14);
    let rad = values(3 * PLANE, 0.0, 4.0, 15);
    let alb = values(3 * PLANE, 0.0, 1.0, 16);
    let mut out49 = vec![0.0f32; 49 * PLANE];
    let mut out3 = vec![0.0f32; 3 * PLANE];
    let lv = View::new(&logits, 49, W, H).unwrap();
    let rv = View::new(&rad, 3, W, H).unwrap();
    let av = View::new(&alb, 3, W, H).unwrap();
    let l1 = lv.channel(0).unwrap();
    for isa in isas() {
        let p = Pool::new(1).unwrap();
        let mut scratch = Scratch::new();
        g.bench_function(BenchmarkId::new("channel_softmax49", isa.name()), |b| {
            b.iter(|| {
                softmax::channel_softmax::<F32>(isa, &lv, &mut ViewMut::new(&mut out49, 49, W, H).unwrap()).unwrap()
            })
        });
        g.bench_function(BenchmarkId::new("importance_kernels7", isa.name()), |b| {
            b.iter(|| {
                softmax::importance_kernels::<F32>(isa, 7, &l1, &mut ViewMut::new(&mut out49, 49, W, H).unwrap(), 0)
                    .unwrap()
            })
        });
        for (k, path) in [
            (7, WindowPath::BoxSum),
            (13, WindowPath::BoxSum),
            (7, WindowPath::Separable),
            (13, WindowPath::Separable),
            (7, WindowPath::Direct),
        ] {
            let len = softmax::window_scratch_len::<F32>(path, k, 3, W);
            g.bench_function(BenchmarkId::new(format!("window{k}_{path:?}"), isa.name()), |b| {
                b.iter(|| {
                    let dst = ViewMut::new(&mut out3, 3, W, H).unwrap();
                    p.bands(dst, 48, &mut scratch, len, |band, y0, s| {
                        softmax::window_filter::<F32>(isa, path, k, &l1, &rv, band, y0, s)
                    })
                    .unwrap()
                })
            });
        }
        g.bench_function(BenchmarkId::new("demodulate", isa.name()), |b| {
            b.iter(|| {
                tonemap::demodulate::<F32>(isa, &rv, &av, 1e-3, &mut ViewMut::new(&mut out3, 3, W, H).unwrap()).unwrap()
            })
        });
        g.bench_function(BenchmarkId::new("gamma", isa.name()), |b| {
            b.iter(|| {
                tonemap::map::<F32>(
                    isa,
                    Map::Gamma { gamma: 2.2, clamp: true },
                    &rv,
                    &mut ViewMut::new(&mut out3, 3, W, H).unwrap(),
                )
                .unwrap()
            })
        });
    }
    g.finish();
}

/// The à-trous methods end to end (demodulation, noise estimate, 5 levels,
/// SURE, remodulation) on a 1280x720 frame of rendered content.
fn bench_atrous(c: &mut Criterion) {
    use mcdenoise::methods::{self, MethodKind, Settings, Timings};
    let frame = tiled_cornell();
    let mut g = c.benchmark_group("atrous_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(5)).warm_up_time(Duration::from_secs(1));
    for isa in isas() {
        for threads in [1, 2] {
            for kind in [MethodKind::Atrous, MethodKind::SureAtrous] {
                let settings = Settings { isa, threads, ..Settings::default() };
                let mut den = methods::create(kind, &settings, &frame).unwrap();
                let mut ctx = methods::context(&settings).unwrap();
                let mut t = Timings::default();
                g.bench_function(
                    BenchmarkId::new(format!("{}/{}", kind.name(), isa.name()), format!("{threads}t")),
                    |b| b.iter(|| den.denoise(&frame, &mut ctx, &mut t).unwrap()),
                );
            }
        }
    }
    g.finish();
}

/// One à-trous step (the core kernel alone) at level 0 and 4, on 64-byte
/// aligned planes.
fn bench_atrous_step(c: &mut Criterion) {
    use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
    let mut g = c.benchmark_group("atrous_step_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
    let src = values(3 * PLANE, 0.0, 1.0, 20);
    let noise = values(PLANE, 0.01, 0.02, 21);
    let mut normal = vec![0.0f32; 3 * PLANE];
    normal[2 * PLANE..].fill(1.0);
    let position = values(3 * PLANE, 0.0, 0.001, 22);
    // On cache lines, as the host allocates its planes.
    let al = mcdenoise::aligned::Aligned::from_slice;
    let (src, noise, normal, position) = (al(&src), al(&noise), al(&normal), al(&position));
    let mut out = mcdenoise::aligned::Aligned::<f32>::zeroed(3 * PLANE);
    let guides = AtrousGuides {
        noise: View::new(&noise, 1, W, H).unwrap(),
        normal: Some(View::new(&normal, 3, W, H).unwrap()),
        position: Some(View::new(&position, 3, W, H).unwrap()),
        depth: None,
    };
    let sv = View::new(&src, 3, W, H).unwrap();
    for isa in isas() {
        for level in [0u32, 4] {
            let mut scratch = vec![0.0f32; atrous::step_scratch_len::<F32>(level)];
            g.bench_function(BenchmarkId::new(format!("level{level}"), isa.name()), |b| {
                b.iter(|| {
                    let mut dv = ViewMut::new(&mut out, 3, W, H).unwrap();
                    let p = AtrousParams::default();
                    atrous::step::<F32>(isa, level, 1, false, &p, &guides, &sv, &mut dv, 0, &mut scratch).unwrap()
                })
            });
        }
    }
    g.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default();
    targets = bench_fused, bench_unfold, bench_conv, bench_two_scale, bench_misc, bench_atrous, bench_atrous_step
}
criterion_main!(benches);

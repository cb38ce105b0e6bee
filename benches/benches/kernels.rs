//! Every operator of the registry at 1280x720 in every precision, on each
//! instruction set this CPU has, on 1 and 2 threads (through the host's band
//! runner); beside them the baselines (naive loops, copies and streaming
//! reads of the same bytes, the FMA-peak loop), the à-trous methods end to
//! end and the à-trous step at two levels.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use mcdenoise::runtime::par::Pool;
use mcdenoise_benches::*;
use mcdenoise_core::{Isa, View, ViewMut, F32};
use mcdenoise_kit::registry::{self, Config, Inputs, Layout};

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

/// Every operator of the registry in every precision, on each instruction
/// set and on 1 and 2 threads: group `op/<name>`, ids `<precision>/<isa>/<n>t`
/// (filter with criterion's name argument, e.g. `cargo bench -- op/apply7x7`).
fn bench_ops(c: &mut Criterion) {
    let inputs = Inputs::synth(W, H, 0);
    let one = Pool::new(1).unwrap();
    for op in registry::ops() {
        // The fixed-point output format needs the oracle's peak; a small
        // frame of the same fields gives it.
        let small = Inputs::synth(64, 36, 0);
        let out_frac = op.fixed_frac(&(op.oracle)(&small, &one));
        let mut g = c.benchmark_group(format!("op/{}", op.name));
        g.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_secs(1));
        for &prec in op.precisions {
            for isa in isas() {
                let cfg = Config { isa, layout: Layout::default(), out_frac };
                for p in pools() {
                    let mut job = op.prepare(prec, cfg, &inputs).unwrap();
                    let id = BenchmarkId::new(format!("{}/{}", prec.name(), isa.name()), format!("{}t", p.threads()));
                    g.bench_function(id, |b| b.iter(|| job.run(&p).unwrap()));
                }
            }
        }
        g.finish();
    }
}

/// What the operators are measured against: naive loops of the same maths,
/// copies and streaming reads of their bytes, and the FMA / multiply-add
/// peak loops (in FLOP/s or multiply-adds through `Throughput::Elements`).
fn bench_baselines(c: &mut Criterion) {
    let mut g = c.benchmark_group("baselines_1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    let sizes = [3usize, 5, 7, 9, 11, 13];
    let imp = values(6 * PLANE, -6.0, 6.0, 1);
    let fus = values(6 * PLANE, -3.0, 3.0, 2);
    let alb = values(3 * PLANE, 0.05, 1.0, 3);
    let rad = values(3 * PLANE, 0.0, 4.0, 4);
    let mut out = vec![0.0f32; 3 * PLANE];
    g.bench_function("fused6/naive/1t", |b| b.iter(|| naive_fused(&sizes, &imp, &fus, &alb, &rad, &mut out, W, H)));
    let kern = values(49 * PLANE, 0.0, 0.04, 6);
    g.bench_function("apply7x7/naive/1t", |b| b.iter(|| naive_unfold(7, &kern, &rad, &mut out, 3, W, H)));
    let (cin, cout, k) = (14, 14, 3);
    let src = values(cin * PLANE, -1.0, 1.0, 8);
    let wts = values(cout * cin * k * k, -0.2, 0.2, 9);
    let mut cout_buf = vec![0.0f32; cout * PLANE];
    g.throughput(Throughput::Elements((2 * cout * cin * k * k * PLANE) as u64));
    g.bench_function("conv3x3/naive/1t", |b| b.iter(|| naive_conv(k, cin, cout, &wts, &src, &mut cout_buf, W, H)));
    #[cfg(target_arch = "x86_64")]
    if Isa::Avx2.is_supported() {
        let iters = 10_000_000;
        g.throughput(Throughput::Elements((iters * 12 * 8 * 2) as u64));
        g.bench_function("fma_peak/1t", |b| b.iter(|| black_box(fma_peak(black_box(iters)))));
    }
    #[cfg(target_arch = "x86_64")]
    if Isa::Avx512.is_supported() {
        // Same iterations at twice the lanes: compare against twice the FLOPs.
        let iters = 10_000_000;
        g.throughput(Throughput::Elements((iters * 12 * 16 * 2) as u64));
        g.bench_function("fma_peak_avx512/1t", |b| b.iter(|| black_box(fma_peak512(black_box(iters)))));
    }
    g.throughput(Throughput::Bytes((49 * PLANE * 4) as u64));
    g.bench_function("read_kernel_map/1t", |b| b.iter(|| black_box(stream_sum(black_box(&kern)))));
    let mut copy = vec![0.0f32; 49 * PLANE];
    g.bench_function("copy_kernel_map/1t", |b| b.iter(|| copy.copy_from_slice(black_box(&kern))));
    g.throughput(Throughput::Bytes((21 * PLANE * 4) as u64));
    let src21 = values(21 * PLANE, 0.0, 1.0, 5);
    let mut dst21 = vec![0.0f32; 21 * PLANE];
    g.bench_function("copy_fused_inputs_and_output/1t", |b| b.iter(|| dst21.copy_from_slice(black_box(&src21))));
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
    let al = mcdenoise::runtime::aligned::Aligned::from_slice;
    let (src, noise, normal, position) = (al(&src), al(&noise), al(&normal), al(&position));
    let mut out = mcdenoise::runtime::aligned::Aligned::<f32>::zeroed(3 * PLANE);
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
    targets = bench_ops, bench_baselines, bench_atrous, bench_atrous_step
}
criterion_main!(benches);

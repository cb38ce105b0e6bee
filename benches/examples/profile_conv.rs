//! One convolution layer, the fastest of REPS, with its share of this
//! machine's peak (the FMA-peak loop for f32, the `vpmaddwd` loop for fixed
//! point): `K=3 C=14 W=1280 H=720 ISA=avx2 P=f32|fixed profile_conv REPS`.
//! Small `W x H` keep the whole input in cache, to separate the kernel's own
//! speed from the memory system's.
use mcdenoise_benches::values;
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::{Fixed, Isa, View, ViewMut, F32};

#[allow(non_snake_case)]
fn main() {
    let dim = |k: &str, d: usize| std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d);
    let (W, H, K, C) = (dim("W", 1280), dim("H", 720), dim("K", 3), dim("C", 14));
    let reps: usize = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(5);
    let isa = std::env::var("ISA").ok().and_then(|s| Isa::from_name(&s)).unwrap_or(Isa::detect());
    let src = values(C * W * H, -1.0, 1.0, 1);
    let weights = values(C * C * K * K, -0.1, 0.1, 2);
    let bias = values(C, -0.1, 0.1, 3);
    let fixed = std::env::var("P").is_ok_and(|p| p == "fixed");
    let mut best = std::time::Duration::MAX;
    let mut all = Vec::new();
    if fixed {
        // Q3.12 activations; weights with as many fractional bits as the
        // layer's bit budget allows for this many taps (12 for 3x3, 10 for 5x5).
        let wf = if K <= 3 { 12 } else { 10 };
        let q = |v: &[f32], f: i32| v.iter().map(|&x| (x * (1 << f) as f32).round() as i16).collect::<Vec<i16>>();
        let (srcq, wq, bq) = (q(&src, 12), q(&weights, wf), q(&bias, 12));
        let layer = Conv2d {
            k: K,
            cin: C,
            cout: C,
            weights: &wq,
            bias: Some(&bq),
            act: Activation::Relu,
            weight_frac: wf as i8,
        };
        let mut out = vec![0i16; C * W * H];
        let mut scratch = vec![0.0f32; conv::conv2d_scratch_len::<Fixed>(K, C, C, W)];
        let sv = View::new(&srcq, C, W, H).unwrap().with_frac(12);
        for _ in 0..reps {
            let t = std::time::Instant::now();
            let mut dv = ViewMut::new(&mut out, C, W, H).unwrap().with_frac(12);
            conv::conv2d::<Fixed>(isa, &layer, &sv, &mut dv, 0, &mut scratch).unwrap();
            best = best.min(t.elapsed());
            all.push(t.elapsed());
        }
    } else {
        let layer = Conv2d {
            k: K,
            cin: C,
            cout: C,
            weights: &weights,
            bias: Some(&bias),
            act: Activation::Relu,
            weight_frac: 0,
        };
        let mut out = vec![0.0f32; C * W * H];
        let mut scratch = vec![0.0f32; conv::conv2d_scratch_len::<F32>(K, C, C, W)];
        let sv = View::new(&src, C, W, H).unwrap();
        for _ in 0..reps {
            let t = std::time::Instant::now();
            let mut dv = ViewMut::new(&mut out, C, W, H).unwrap();
            conv::conv2d::<F32>(isa, &layer, &sv, &mut dv, 0, &mut scratch).unwrap();
            best = best.min(t.elapsed());
            all.push(t.elapsed());
        }
    }
    // Peak: 8 f32 multiply-adds per FMA, 16 i16 ones per vpmaddwd.
    let (ops, peak, what) = if fixed {
        ((W * H * C * C * K * K) as f64 / 16.0, mcdenoise_benches::madd_peak_rate(), "vpmaddwd")
    } else {
        ((W * H * C * C * K * K) as f64 / 8.0, mcdenoise_benches::fma_peak_rate(), "FMA")
    };
    all.sort();
    let median = all[all.len() / 2];
    eprintln!(
        "conv {K}x{K} {C}->{C} {W}x{H} {} {}: {:.3} ms fastest ({:.1} % of the {what}-peak loop), {:.3} ms median of {reps}",
        if fixed { "fixed" } else { "f32" },
        isa.name(),
        best.as_secs_f64() * 1e3,
        100.0 * ops / best.as_secs_f64() / peak,
        median.as_secs_f64() * 1e3
    );
}

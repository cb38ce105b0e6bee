//! The fused 6-kernel reconstruction (sizes 3..13, fusion, albedo) at
//! 1280x720 on one thread, the fastest of N repetitions:
//! `ISA=avx2 profile_fused [REPS] [PATH]` with PATH `boxsum` (default), `separable` or `direct`.
use mcdenoise_benches::values;
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::{Isa, View, ViewMut, F32};

#[allow(non_snake_case)]
fn main() {
    // W / H override the 1280x720 frame (a small frame shows the in-cache speed).
    let dim = |v: &str, d: usize| std::env::var(v).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
    let (W, H) = (dim("W", mcdenoise_benches::W), dim("H", mcdenoise_benches::H));
    let plane = W * H;
    // SIZES=a,b,... (six odd sizes) replaces 3..13, to separate per-size costs.
    let sizes: Vec<usize> = std::env::var("SIZES")
        .map(|s| s.split(',').map(|v| v.parse().expect("SIZES: odd sizes")).collect())
        .unwrap_or_else(|_| vec![3, 5, 7, 9, 11, 13]);
    assert_eq!(sizes.len(), 6, "SIZES: six sizes");
    let imp = values(6 * plane, -6.0, 6.0, 1);
    let fus = values(6 * plane, -3.0, 3.0, 2);
    let alb = values(3 * plane, 0.05, 1.0, 3);
    let rad = values(3 * plane, 0.0, 4.0, 4);
    let mut out = vec![0.0f32; 3 * plane];
    let inp = FusedInputs {
        sizes: &sizes,
        importance: View::new(&imp, 6, W, H).unwrap(),
        fusion: Some(View::new(&fus, 6, W, H).unwrap()),
        albedo: Some(View::new(&alb, 3, W, H).unwrap()),
        radiance: View::new(&rad, 3, W, H).unwrap(),
    };
    let isa = std::env::var("ISA").ok().and_then(|s| Isa::from_name(&s)).unwrap_or(Isa::detect());
    let reps: usize = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(5);
    let path = match std::env::args().nth(2).as_deref() {
        Some("direct") => WindowPath::Direct,
        Some("separable") => WindowPath::Separable,
        _ => WindowPath::BoxSum,
    };
    let mut scratch = vec![0.0f32; softmax::fused_scratch_len::<F32>(path, &sizes, 3, W)];
    let mut best = std::time::Duration::MAX;
    for _ in 0..reps {
        let t = std::time::Instant::now();
        let mut dst = ViewMut::new(&mut out, 3, W, H).unwrap();
        softmax::fused_filter::<F32>(isa, path, &inp, &mut dst, 0, &mut scratch).unwrap();
        best = best.min(t.elapsed());
    }
    eprintln!(
        "fused6 {W}x{H} {} {path:?}: {:.3} ms (fastest of {reps}; checksum {})",
        isa.name(),
        best.as_secs_f64() * 1e3,
        out.iter().map(|&v| v as f64).sum::<f64>()
    );
}

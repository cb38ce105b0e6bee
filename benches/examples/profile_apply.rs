//! The 7x7 kernel apply from a 49-plane map at 1280x720 on one thread, the
//! fastest of N repetitions: `ISA=avx512 profile_apply [REPS] [f32|f16]`
//! (W and H override the frame size; a small frame shows the in-cache speed).
use mcdenoise_benches::values;
use mcdenoise_core::{unfold, Isa, View, ViewMut, F16, F32};

macro_rules! run {
    ($p:ty, $conv:expr, $back:expr, $isa:expr, $reps:expr) => {{
        let dim = |v: &str, d: usize| std::env::var(v).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
        #[allow(non_snake_case)]
        let (W, H) = (dim("W", mcdenoise_benches::W), dim("H", mcdenoise_benches::H));
        let plane = W * H;
        let kern: Vec<_> = values(49 * plane, 0.0, 0.04, 6).into_iter().map($conv).collect();
        let src: Vec<_> = values(3 * plane, 0.0, 4.0, 7).into_iter().map($conv).collect();
        let mut out: Vec<_> = vec![0.0f32; 3 * plane].into_iter().map($conv).collect();
        let kv = View::new(&kern, 49, W, H).unwrap();
        let sv = View::new(&src, 3, W, H).unwrap();
        let mut scratch = vec![0.0f32; unfold::scratch_len::<$p>(7, 3, W)];
        let mut best = std::time::Duration::MAX;
        for _ in 0..$reps {
            let t = std::time::Instant::now();
            let mut dv = ViewMut::new(&mut out, 3, W, H).unwrap();
            unfold::apply::<$p>($isa, 7, &kv, &sv, &mut dv, &mut scratch).unwrap();
            best = best.min(t.elapsed());
        }
        let sum: f64 = out.iter().map(|&v| $back(v) as f64).sum();
        eprintln!(
            "apply7x7 {W}x{H} {} {}: {:.3} ms (fastest of {}; checksum {sum})",
            $isa.name(),
            stringify!($p),
            best.as_secs_f64() * 1e3,
            $reps
        );
    }};
}

fn main() {
    let isa = std::env::var("ISA").ok().and_then(|s| Isa::from_name(&s)).unwrap_or(Isa::detect());
    let reps: usize = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(5);
    match std::env::args().nth(2).as_deref() {
        Some("f16") => run!(F16, half::f16::from_f32, half::f16::to_f32, isa, reps),
        _ => run!(F32, |v: f32| v, |v: f32| v, isa, reps),
    }
}

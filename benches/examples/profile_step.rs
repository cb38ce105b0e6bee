//! One à-trous step at 1280x720 on 64-byte aligned planes, the fastest of
//! REPS: `ISA=avx512 G=2 profile_step LEVEL REPS` (`G` colour groups, 1 or 2;
//! `W`, `H` resize; `NOGEO=1` drops the normal and position guides). Under
//! valgrind (`--tool=callgrind`) use `ISA=avx2`: valgrind has no AVX-512.
use mcdenoise_benches::values;
use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
use mcdenoise_core::{Isa, View, ViewMut, F32};

#[allow(non_snake_case)]
fn main() {
    let dim = |k: &str, d: usize| std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d);
    let (W, H) = (dim("W", mcdenoise_benches::W), dim("H", mcdenoise_benches::H));
    let plane = W * H;
    let level: u32 = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(0);
    let noise = values(plane, 0.01, 0.02, 21);
    let mut normal = vec![0.0f32; 3 * plane];
    normal[2 * plane..].fill(1.0);
    let position = values(3 * plane, 0.0, 0.001, 22);
    let groups = dim("G", 1);
    let pad = dim("PAD", 0);
    let ps = plane + pad;
    let src = values(3 * groups * ps, 0.0, 1.0, 20);
    let mut out = mcdenoise::runtime::aligned::Aligned::<f32>::zeroed(3 * groups * ps);
    // Buffers on cache lines, as the host allocates them.
    let al = mcdenoise::runtime::aligned::Aligned::from_slice;
    let (src, noise, normal, position) = (al(&src), al(&noise), al(&normal), al(&position));
    let guides = AtrousGuides {
        noise: View::new(&noise, 1, W, H).unwrap(),
        normal: (dim("NOGEO", 0) == 0).then(|| View::new(&normal, 3, W, H).unwrap()),
        position: (dim("NOGEO", 0) == 0).then(|| View::new(&position, 3, W, H).unwrap()),
        depth: None,
    };
    let sv = View::with_strides(&src, 3 * groups, W, H, W, ps).unwrap();
    let isa = std::env::var("ISA").ok().and_then(|s| Isa::from_name(&s)).unwrap_or(Isa::detect());
    let reps: usize = std::env::args().nth(2).and_then(|v| v.parse().ok()).unwrap_or(1);
    // The fastest of the repetitions: this VM's noise only ever adds time.
    let mut best = std::time::Duration::MAX;
    let mut scratch = vec![0.0f32; atrous::step_scratch_len::<F32>(level)];
    for _ in 0..reps {
        let t = std::time::Instant::now();
        let mut dv = ViewMut::with_strides(&mut out, 3 * groups, W, H, W, ps).unwrap();
        let p = AtrousParams::default();
        atrous::step::<F32>(isa, level, groups, false, &p, &guides, &sv, &mut dv, 0, &mut scratch).unwrap();
        best = best.min(t.elapsed());
    }
    eprintln!(
        "level {level} {W}x{H} {}: {:.3} ms per step, {:.2} ns/px (fastest of {reps}; checksum {})",
        isa.name(),
        best.as_secs_f64() * 1e3,
        best.as_secs_f64() * 1e9 / plane as f64,
        out.iter().sum::<f32>()
    );
}

//! The fused 6-kernel reconstruction (sizes 3..13, fusion, albedo) at
//! 1280x720 on one thread, the fastest of N repetitions:
//! `ISA=avx2 profile_fused [REPS] [PATH]` with PATH `boxsum` (default), `separable` or `direct`;
//! `PREC=fixed` runs the fixed-point filter on the same values (i16 formats
//! chosen for their ranges, the logits in Q7.8); `LOGIT_RANGE=R` draws the
//! importance logits from `[-R, R)` (default 6).
use mcdenoise_benches::values;
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::{fixed, Fixed, Isa, View, ViewMut, F32};

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
    let lr: f32 = std::env::var("LOGIT_RANGE").ok().and_then(|s| s.parse().ok()).unwrap_or(6.0);
    let imp = values(6 * plane, -lr, lr, 1);
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
    if std::env::var("PREC").as_deref() == Ok("fixed") {
        let q = |v: &[f32], frac: i8| -> Vec<i16> { v.iter().map(|&x| fixed::from_f32(x, frac)).collect() };
        let (iq, fq, aq, rq) = (q(&imp, 8), q(&fus, 12), q(&alb, 14), q(&rad, 12));
        let inp = FusedInputs {
            sizes: &sizes,
            importance: View::new(&iq, 6, W, H).unwrap().with_frac(8),
            fusion: Some(View::new(&fq, 6, W, H).unwrap().with_frac(12)),
            albedo: Some(View::new(&aq, 3, W, H).unwrap().with_frac(14)),
            radiance: View::new(&rq, 3, W, H).unwrap().with_frac(12),
        };
        let mut outq = vec![0i16; 3 * plane];
        let mut scratch = vec![0.0f32; softmax::fused_scratch_len::<Fixed>(path, &sizes, 3, W)];
        let mut best = std::time::Duration::MAX;
        for _ in 0..reps {
            let t = std::time::Instant::now();
            let mut dst = ViewMut::new(&mut outq, 3, W, H).unwrap().with_frac(12);
            softmax::fused_filter::<Fixed>(isa, path, &inp, &mut dst, 0, &mut scratch).unwrap();
            best = best.min(t.elapsed());
        }
        let mut dst = ViewMut::new(&mut out, 3, W, H).unwrap();
        softmax::fused_filter::<F32>(
            isa,
            path,
            &FusedInputs { ..inp_f32(&sizes, &imp, &fus, &alb, &rad, W, H) },
            &mut dst,
            0,
            &mut vec![0.0f32; softmax::fused_scratch_len::<F32>(path, &sizes, 3, W)],
        )
        .unwrap();
        let err = outq.iter().zip(&out).map(|(&a, &b)| ((a as f64) / 4096.0 - b as f64).abs()).fold(0.0, f64::max);
        eprintln!(
            "fused6 fixed {W}x{H} {} {path:?}: {:.3} ms (fastest of {reps}; largest difference from f32 {err:.2e})",
            isa.name(),
            best.as_secs_f64() * 1e3
        );
        return;
    }
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

fn inp_f32<'a>(
    sizes: &'a [usize],
    imp: &'a [f32],
    fus: &'a [f32],
    alb: &'a [f32],
    rad: &'a [f32],
    w: usize,
    h: usize,
) -> FusedInputs<'a, f32> {
    FusedInputs {
        sizes,
        importance: View::new(imp, 6, w, h).unwrap(),
        fusion: Some(View::new(fus, 6, w, h).unwrap()),
        albedo: Some(View::new(alb, 3, w, h).unwrap()),
        radiance: View::new(rad, 3, w, h).unwrap(),
    }
}

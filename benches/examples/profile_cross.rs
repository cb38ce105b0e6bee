//! The cross-regression operators beside the machine limit they are bound
//! by: `profile_cross [THREADS] [REPS]` (defaults 1 thread, 5 runs) runs
//! `cross-regression` (one pilot), `cross-filter` (forward, both pilots) and
//! `cross-filter-grad` (backward) of the registry at `W x H` (default
//! 1280x720) on the best ISA, and prints each one's fastest time, its
//! floating-point operations and their rate against this machine's FMA-peak
//! loop (two flops per lane of an 8-lane FMA, times the threads).
//!
//! The operation counts are per lane as the kernels are written (an add, a
//! multiply or a subtract is one, a fused multiply-add two, a division one,
//! the vectorised `exp` 16: 2 for the range reduction, 2 for the remainder,
//! 12 for its six-term polynomial); they are what the kernels execute, not a
//! minimum for the maths.
use mcdenoise::runtime::par::Pool;
use mcdenoise::runtime::precision::PrecisionKind;
use mcdenoise_core::regress::{centres, FILTER_WINDOW, REG_WINDOW};
use mcdenoise_core::Isa;
use mcdenoise_kit::registry::{self, Config, Inputs, Layout};

/// Flops of one `exp_vec`.
const EXP: f64 = 16.0;

/// Flops per centre and window pixel of the regression's normal equations:
/// the weight (colour differences 3, squared distance 5, variance sum and
/// division 3, sign 1, exp, `+1e-7` 1), the colour scale (3), the normal
/// columns (3), the weighted shared columns (4), the 10 shared products (20),
/// and per channel the two own columns and their weighted copies (4), the 11
/// own products (22) and the 6 right-hand sides (12).
const SOLVE_TAP: f64 = 3.0 + 5.0 + 3.0 + 1.0 + EXP + 1.0 + 3.0 + 3.0 + 4.0 + 20.0 + 3.0 * (4.0 + 22.0 + 12.0);
/// Flops per pixel and blended centre of the reconstruction: the weight (8
/// for the distance, 3 for the scale, 1 sign, exp, 1, 2 for the masks), the
/// colour scale (3), the weight sum (1) and per channel the six-term
/// prediction (2 + 4 + 3 + 3 x 3) and its accumulation (2).
const BLEND_TAP: f64 = 8.0 + 3.0 + 1.0 + EXP + 1.0 + 2.0 + 3.0 + 1.0 + 3.0 * (2.0 + 4.0 + 3.0 + 9.0 + 2.0);
/// Centres a pixel's reconstruction visits (5 centre rows x 5 columns; the
/// out-of-reach ones are computed and masked).
const BLENDED: f64 = 25.0;
/// Flops per pixel and window tap of the filter's forward pass: the pilots'
/// differences (6) and squared distances (10), albedo and normal distances
/// (16), the shared exponent (5), per pilot its exponent (3) and exp, the
/// six weighted sums (12) and two weight sums (2).
const FILTER_TAP: f64 = 6.0 + 10.0 + 16.0 + 5.0 + 2.0 * (3.0 + EXP) + 12.0 + 2.0;
/// The backward pass recomputes the forward's weights (all of the above) and
/// adds, per pilot, the gradient's dot product (5), four weighted distances
/// (4), four weighted products summed (8) and four plain sums (4).
const FILTER_GRAD_TAP: f64 = FILTER_TAP + 2.0 * (5.0 + 4.0 + 8.0 + 4.0);

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let threads: usize = args.first().and_then(|v| v.parse().ok()).unwrap_or(1);
    let reps: usize = args.get(1).and_then(|v| v.parse().ok()).unwrap_or(5);
    let dim = |v: &str, d: usize| std::env::var(v).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
    let (w, h) = (dim("W", mcdenoise_benches::W), dim("H", mcdenoise_benches::H));
    let isa = Isa::detect();
    let pool = Pool::new(threads).unwrap();
    let peak = 16.0 * mcdenoise_benches::fma_peak_rate() * threads as f64;
    let px = (w * h) as f64;
    let ncentres = (centres(w) * centres(h)) as f64;
    let reg_taps = (REG_WINDOW * REG_WINDOW) as f64;
    let filt_taps = (FILTER_WINDOW * FILTER_WINDOW) as f64;
    let ops: [(&str, f64); 3] = [
        ("cross-regression", ncentres * reg_taps * SOLVE_TAP + px * BLENDED * BLEND_TAP),
        ("cross-filter", px * filt_taps * FILTER_TAP),
        ("cross-filter-grad", px * filt_taps * FILTER_GRAD_TAP),
    ];
    eprintln!(
        "{w}x{h}, {threads} thread(s), {}: FMA-peak loop {:.1} GFLOP/s ({} x {:.1})",
        isa.name(),
        peak / 1e9,
        threads,
        peak / 1e9 / threads as f64
    );
    let inputs = Inputs::synth(w, h, 0);
    for (name, flops) in ops {
        let op = registry::op(name).expect("a registry operator");
        let cfg = Config { isa, layout: Layout::default(), out_frac: 0 };
        let mut job = op.prepare(PrecisionKind::F32, cfg, &inputs).unwrap();
        let mut best = std::time::Duration::MAX;
        for _ in 0..reps {
            let t = std::time::Instant::now();
            job.run(&pool).unwrap();
            best = best.min(t.elapsed());
        }
        let s = best.as_secs_f64();
        eprintln!(
            "{name:<18} {:>9.2} ms  {:>6.2} GFLOP  {:>6.1} GFLOP/s  {:>5.1} % of the FMA-peak loop",
            s * 1e3,
            flops / 1e9,
            flops / s / 1e9,
            100.0 * flops / s / peak
        );
    }
}

//! One operator of the registry, the fastest of REPS runs, with a checksum
//! of its output: `W=1280 H=720 profile_op OP [PRECISION] [ISA] [THREADS]
//! [REPS]` (defaults: f32, the best ISA, 1 thread, 5 runs). A small `W x H`
//! keeps the inputs in cache, to separate an operator's own speed from the
//! memory system's. `profile_op list` prints the operators.
use mcdenoise::runtime::par::Pool;
use mcdenoise::runtime::precision::PrecisionKind;
use mcdenoise_core::Isa;
use mcdenoise_kit::registry::{self, Config, Inputs, Layout};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map(String::as_str).unwrap_or("list");
    let Some(op) = registry::op(name) else {
        for op in registry::ops() {
            println!("{:<14} {}", op.name, op.about);
        }
        return;
    };
    let prec = args.get(1).map(|p| PrecisionKind::parse(p).unwrap()).unwrap_or(PrecisionKind::F32);
    let isa = args.get(2).and_then(|s| Isa::from_name(s)).unwrap_or(Isa::detect());
    let threads: usize = args.get(3).and_then(|v| v.parse().ok()).unwrap_or(1);
    let reps: usize = args.get(4).and_then(|v| v.parse().ok()).unwrap_or(5);
    let dim = |v: &str, d: usize| std::env::var(v).ok().and_then(|s| s.parse().ok()).unwrap_or(d);
    let (w, h) = (dim("W", mcdenoise_benches::W), dim("H", mcdenoise_benches::H));
    let pool = Pool::new(threads).unwrap();
    let inputs = Inputs::synth(w, h, 0);
    let out_frac = op.fixed_frac(&(op.oracle)(&Inputs::synth(64, 36, 0), &pool));
    let mut job = op.prepare(prec, Config { isa, layout: Layout::default(), out_frac }, &inputs).unwrap();
    let mut best = std::time::Duration::MAX;
    for _ in 0..reps {
        let t = std::time::Instant::now();
        job.run(&pool).unwrap();
        best = best.min(t.elapsed());
    }
    let sum: f64 = job.output().iter().map(|&v| v as f64).sum();
    eprintln!(
        "{} {w}x{h} {} {} {threads}t: {:.3} ms (fastest of {reps}; checksum {sum})",
        op.name,
        prec.name(),
        isa.name(),
        best.as_secs_f64() * 1e3
    );
}

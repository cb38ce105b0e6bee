//! Per-stage times of a method on the 1280x720 tiled Cornell frame:
//! `profile_method [atrous|sure-atrous] [threads] [reps]` (release);
//! `NOPAIR=1` drops the frame's second half-sample image.
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise_benches::tiled_cornell;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let kind = match args.get(1).map(String::as_str) {
        Some("sure-atrous") => MethodKind::SureAtrous,
        _ => MethodKind::Atrous,
    };
    let threads: usize = args.get(2).and_then(|v| v.parse().ok()).unwrap_or(1);
    let reps: u32 = args.get(3).and_then(|v| v.parse().ok()).unwrap_or(10);
    let mut frame = tiled_cornell();
    if std::env::var("NOPAIR").is_ok_and(|v| v == "1") {
        // The single-estimate path: no second half-sample image.
        frame.remove(mcdenoise::frame::Buffer::ColorB);
    }
    let settings = Settings { threads, ..Settings::default() };
    let mut den = methods::create(kind, &settings, &frame).unwrap();
    let mut ctx = methods::context(&settings).unwrap();
    let mut warm = Timings::default();
    den.denoise(&frame, &mut ctx, &mut warm).unwrap();
    let mut t = Timings::default();
    let t0 = std::time::Instant::now();
    let mut best = std::time::Duration::MAX;
    for _ in 0..reps {
        let t1 = std::time::Instant::now();
        den.denoise(&frame, &mut ctx, &mut t).unwrap();
        best = best.min(t1.elapsed());
    }
    let wall = t0.elapsed() / reps;
    println!(
        "{} {threads}t: {:.2} ms/frame wall (mean), {:.2} ms fastest",
        kind.name(),
        wall.as_secs_f64() * 1e3,
        best.as_secs_f64() * 1e3
    );
    for (stage, d, _) in t.stages() {
        println!("  {stage:24} {:8.2} ms", d.as_secs_f64() * 1e3 / reps as f64);
    }
}

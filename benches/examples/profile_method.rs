//! Per-stage times of a method on the 1280x720 tiled Cornell frame:
//! `profile_method [METHOD] [threads] [reps]` (release; METHOD as `--method`
//! takes it, default atrous; `LAYERS=3` for WSKP-3);
//! `NOPAIR=1` drops the frame's second half-sample image.
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise_benches::tiled_cornell;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let kind = MethodKind::parse(args.get(1).map_or("atrous", String::as_str)).unwrap();
    let threads: usize = args.get(2).and_then(|v| v.parse().ok()).unwrap_or(1);
    let reps: u32 = args.get(3).and_then(|v| v.parse().ok()).unwrap_or(10);
    let mut frame = tiled_cornell();
    if std::env::var("NOPAIR").is_ok_and(|v| v == "1") {
        // The single-estimate path: no second half-sample image.
        frame.remove(mcdenoise::io::frame::Buffer::ColorB);
    }
    let layers: usize = std::env::var("LAYERS").ok().and_then(|v| v.parse().ok()).unwrap_or(6);
    let settings = Settings { threads, layers, ..Settings::default() };
    // WSKP-3 has no bundled weights; its speed does not depend on their values.
    let mut den = if kind == MethodKind::Wskp && layers == 3 {
        let net = mcdenoise::methods::wskp::net(3).unwrap();
        let params = net.init(1);
        Box::new(
            mcdenoise::methods::wskp::Wskp::<mcdenoise_core::F32>::from_params(
                &frame,
                net,
                params,
                3,
                mcdenoise::methods::wskp::Sizes::ALL,
            )
            .unwrap(),
        )
    } else {
        methods::create(kind, &settings, &frame).unwrap()
    };
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

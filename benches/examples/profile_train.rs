//! One WSKP training step (forward, SMAPE, the fused filter's gradient,
//! backward, Adam) on a batch of synthetic crops, the median of REPS steps:
//! `profile_train [LAYERS] [THREADS] [REPS] [BATCH] [CROP]` (defaults 6, 2,
//! 20, 8, 128); `WEIGHTS=FILE` starts from a weights or checkpoint file.
use mcdenoise::methods::wskp;
use mcdenoise::nn::loss::Loss;
use mcdenoise::nn::{Nets, Trainer, Workspace};
use mcdenoise::runtime::par::Pool;
use mcdenoise_benches::values;
use mcdenoise_core::Isa;

fn main() {
    let arg = |i: usize, d: usize| std::env::args().nth(i).and_then(|v| v.parse().ok()).unwrap_or(d);
    let (layers, threads, reps, batch, s) = (arg(1, 6), arg(2, 2), arg(3, 20), arg(4, 8), arg(5, 128));
    let isa = std::env::var("ISA").ok().and_then(|v| Isa::from_name(&v)).unwrap_or(Isa::detect());
    let net = wskp::net(layers).unwrap();
    // WEIGHTS=FILE: start from trained (or checkpointed) parameters instead
    // of the initialisation (trained logits spread, which the filter's
    // gradient pays for).
    let params = match std::env::var("WEIGHTS") {
        Ok(f) => mcdenoise::train::load_params(std::path::Path::new(&f), &net, "wskp").expect("a WSKP weights file"),
        Err(_) => net.init(1),
    };
    let mut tr = Trainer::new(net, params, batch, s, s, 1e-3, 0.0).expect("a trainer");
    for wss in tr.workspaces() {
        wskp::crop_buffers(&mut wss[0]);
    }
    let n = s * s;
    let x = values(10 * n, 0.0, 1.0, 1);
    // The crop's data planes (wskp::DATA_PLANES): c, d, the reference, the
    // exposure (1) and the excess (0).
    let mut data = values(wskp::DATA_PLANES * n, 0.05, 1.0, 2);
    data[..3 * n].iter_mut().for_each(|v| *v *= 4.0);
    data[9 * n..10 * n].fill(1.0);
    data[10 * n..].fill(0.0);
    let pool = Pool::new(threads).unwrap();
    let fill = |_: usize, wss: &mut [Workspace]| {
        let ws = &mut wss[0];
        ws.input_mut().copy_from_slice(&x);
        ws.aux[0].copy_from_slice(&data);
        Ok(())
    };
    let head = |_: usize, _: &Nets<'_>, wss: &mut [Workspace]| {
        // The logit bound `mcdenoise train` uses by default.
        let bound = mcdenoise::train::TrainArgs::default().logit_bound;
        wskp::head(&mut wss[0], wskp::Sizes::ALL, Loss::Smape, 1.0 / batch as f32, bound, isa)
    };
    let mut times = Vec::new();
    for _ in 0..reps + 2 {
        let t = std::time::Instant::now();
        tr.step(&pool, isa, &fill, &head, true).unwrap();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let mut t = times[2..].to_vec();
    t.sort_by(f64::total_cmp);
    eprintln!(
        "wskp{layers} training step, batch {batch} of {s}x{s}, {threads} threads, {}: median {:.1} ms, fastest {:.1} ms ({reps} steps)",
        isa.name(),
        t[t.len() / 2],
        t[0]
    );
}

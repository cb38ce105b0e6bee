//! `mcdenoise train`: training a learned method on rendered sequences.
//!
//! Data: every sequence under `--data` (a directory of `frame_NNNN.exr`
//! with `ref/frame_NNNN.exr` references, or a directory of such
//! directories), loaded once, temporally accumulated, and turned into the
//! model's per-frame tensors. Each step draws a batch of random square
//! crops (frame, position, one of the 8 flips and 90-degree turns) from a
//! seeded generator, runs the network's forward and backward pass one crop
//! per task, sums the gradients in crop order and takes one Adam step: the
//! same seed and threads give the same weights, bit for bit (and the thread
//! count does not change them either).
//!
//! Every `--checkpoint-minutes` the parameters, Adam's state, the step and
//! the generator's state go to `OUT.ckpt` (`--resume OUT.ckpt` continues
//! from there); every `--val-every` steps the validation sequence is
//! denoised whole and its mean PSNR printed. At the end the weights go to
//! `OUT` (RepVGG branches; the loader merges them).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcdenoise_core::{Isa, F32};

use crate::error::{HostError, Result};
use crate::frame::{Buffer, Frame, Limits};
use crate::methods::{context, Denoiser, Settings, TemporalAccumulation, Timings};
use crate::metrics;
use crate::nn::loss::Loss;
use crate::nn::weights::{self, File, Form, Tensor};
use crate::nn::{Net, Nets, Rng, Trainer, Workspace};
use crate::precision::PrecisionKind;
use crate::run::list_inputs;
use crate::wskp;

/// Options of `mcdenoise train`.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainArgs {
    /// The method (`wskp`).
    pub method: String,
    /// Training sequences.
    pub data: PathBuf,
    /// Validation sequences.
    pub val: Option<PathBuf>,
    /// Output weights.
    pub out: PathBuf,
    /// Network layers (WSKP: 3 or 6).
    pub layers: usize,
    /// Stop after this many steps.
    pub steps: Option<u64>,
    /// Stop after this many minutes.
    pub minutes: Option<f64>,
    /// Crops per step.
    pub batch: usize,
    /// Crop side.
    pub crop: usize,
    /// Adam's learning rate.
    pub lr: f32,
    /// Gradient norm clip (0: none).
    pub clip: f32,
    /// The loss.
    pub loss: Loss,
    /// Seed of initialisation and sampling.
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
    /// Instruction set.
    pub isa: Isa,
    /// Continue from a checkpoint.
    pub resume: Option<PathBuf>,
    /// Minutes between checkpoints.
    pub checkpoint_minutes: f64,
    /// Steps between validations (0: only at the end).
    pub val_every: u64,
    /// A CSV of (step, seconds, loss, validation PSNR) rows.
    pub log: Option<PathBuf>,
}

impl Default for TrainArgs {
    fn default() -> Self {
        TrainArgs {
            method: "wskp".into(),
            data: PathBuf::new(),
            val: None,
            out: PathBuf::from("wskp.safetensors"),
            layers: 6,
            steps: None,
            minutes: None,
            batch: 8,
            crop: 128,
            lr: 1e-3,
            clip: 0.0,
            loss: Loss::Smape,
            seed: 1,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            isa: Isa::detect(),
            resume: None,
            checkpoint_minutes: 5.0,
            val_every: 500,
            log: None,
        }
    }
}

/// A rendered sequence: its frames (in order) and their references.
pub struct Sequence {
    /// Where it came from.
    pub dir: PathBuf,
    /// The frames.
    pub frames: Vec<Frame>,
    /// Each frame's reference radiance (3 planes).
    pub refs: Vec<Vec<f32>>,
}

/// The sequence directories under `dir` (itself when it holds `.exr` files).
pub fn sequence_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let has_exr = |d: &Path| {
        std::fs::read_dir(d)
            .map(|it| {
                it.filter_map(|e| e.ok()).any(|e| e.path().extension().is_some_and(|x| x.eq_ignore_ascii_case("exr")))
            })
            .unwrap_or(false)
    };
    if has_exr(dir) {
        return Ok(vec![dir.to_path_buf()]);
    }
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| HostError::read(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir() && has_exr(p))
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        return Err(HostError::bad(dir, "holds no sequence (a directory of frame_NNNN.exr with ref/)"));
    }
    Ok(dirs)
}

/// Loads a sequence and its references (`ref/<same name>`).
pub fn load_sequence(dir: &Path) -> Result<Sequence> {
    let files = list_inputs(&[dir.to_path_buf()])?;
    let mut frames = Vec::new();
    let mut refs = Vec::new();
    for f in files {
        let frame = Frame::load(&f, &Limits::default())?;
        let rp = dir.join("ref").join(f.file_name().expect("a file"));
        let r = Frame::load(&rp, &Limits::default())?;
        if (r.width, r.height) != (frame.width, frame.height) {
            return Err(HostError::bad(&rp, "reference size differs from its frame"));
        }
        refs.push(r.require(Buffer::Color, "training")?.to_vec());
        frames.push(frame);
    }
    Ok(Sequence { dir: dir.to_path_buf(), frames, refs })
}

/// The temporally accumulated radiance of every frame (f32).
pub fn accumulate(seq: &Sequence, threads: usize, isa: Isa) -> Result<Vec<Vec<f32>>> {
    let settings = Settings { threads, isa, precision: PrecisionKind::F32, ..Settings::default() };
    let mut ctx = context(&settings)?;
    let mut ta = TemporalAccumulation::<F32>::new(&seq.frames[0], false)?;
    let mut t = Timings::default();
    seq.frames.iter().map(|f| ta.denoise(f, &mut ctx, &mut t)).collect()
}

/// One frame's training tensors: `planes` of `w x h`, the network's input
/// first (`cin` planes), then the model's own.
struct Sample {
    w: usize,
    h: usize,
    data: Vec<f32>,
}

/// WSKP's samples: `[x (10), c (3), a + EPS (3), ref (3)]`.
fn wskp_samples(seqs: &[Sequence], threads: usize, isa: Isa) -> Result<Vec<Sample>> {
    let pool = crate::par::Pool::new(threads).map_err(HostError::Usage)?;
    let mut out = Vec::new();
    for s in seqs {
        let ta = accumulate(s, threads, isa)?;
        for ((f, t), r) in s.frames.iter().zip(&ta).zip(&s.refs) {
            wskp::check_inputs(f)?;
            let n = f.width * f.height;
            let mut data = vec![0.0f32; 19 * n];
            let (x, rest) = data.split_at_mut(10 * n);
            let (c, rest) = rest.split_at_mut(3 * n);
            let (alb, rf) = rest.split_at_mut(3 * n);
            wskp::inputs(&pool, isa, f, t, x, c, alb)?;
            rf.copy_from_slice(r);
            out.push(Sample { w: f.width, h: f.height, data });
        }
    }
    Ok(out)
}

/// Where a crop comes from: frame, corner, and which of the 8 symmetries.
#[derive(Clone, Copy, Debug)]
struct CropAt {
    frame: usize,
    x0: usize,
    y0: usize,
    t: u8,
}

/// Copies crop `at` (side `s`) of every plane of `sample`, planes `p0..p1`,
/// into `dst` (packed `s x s` planes): bit 0 flips x, bit 1 flips y, bit 2
/// transposes.
fn crop(sample: &Sample, at: CropAt, s: usize, p0: usize, p1: usize, dst: &mut [f32]) {
    let n = sample.w * sample.h;
    for (k, p) in (p0..p1).enumerate() {
        let src = &sample.data[p * n..(p + 1) * n];
        let out = &mut dst[k * s * s..(k + 1) * s * s];
        for y in 0..s {
            for x in 0..s {
                let (mut u, mut v) = if at.t & 4 != 0 { (y, x) } else { (x, y) };
                if at.t & 1 != 0 {
                    u = s - 1 - u;
                }
                if at.t & 2 != 0 {
                    v = s - 1 - v;
                }
                out[y * s + x] = src[(at.y0 + v) * sample.w + at.x0 + u];
            }
        }
    }
}

fn draw(rng: &mut Rng, samples: &[Sample], s: usize) -> CropAt {
    let frame = rng.below(samples.len());
    let (w, h) = (samples[frame].w, samples[frame].h);
    CropAt { frame, x0: rng.below(w - s + 1), y0: rng.below(h - s + 1), t: rng.below(8) as u8 }
}

/// Mean display PSNR of the method on sequences (each denoised whole, in order).
pub fn validate(
    seqs: &[Sequence],
    make: &dyn Fn(&Frame) -> Result<Box<dyn Denoiser>>,
    threads: usize,
    isa: Isa,
) -> Result<f64> {
    let settings = Settings { threads, isa, precision: PrecisionKind::F32, ..Settings::default() };
    let mut ctx = context(&settings)?;
    let (mut sum, mut n) = (0.0, 0);
    for s in seqs {
        let mut den = make(&s.frames[0])?;
        let mut t = Timings::default();
        for (f, r) in s.frames.iter().zip(&s.refs) {
            let out = den.denoise(f, &mut ctx, &mut t)?;
            sum += metrics::score(&out, r, f.width, f.height).psnr;
            n += 1;
        }
    }
    Ok(sum / n.max(1) as f64)
}

/// The mean display PSNR of the sequences' inputs.
fn input_psnr(seqs: &[Sequence]) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for s in seqs {
        for (f, r) in s.frames.iter().zip(&s.refs) {
            sum += metrics::score(f.get(Buffer::Color).expect("colour"), r, f.width, f.height).psnr;
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

fn checkpoint_path(out: &Path) -> PathBuf {
    let mut p = out.as_os_str().to_owned();
    p.push(".ckpt");
    PathBuf::from(p)
}

fn save_checkpoint(path: &Path, tr: &Trainer, step: u64, rng: &Rng, meta: &[(&str, String)]) -> Result<()> {
    let owned = weights::param_tensors(tr.net(), &tr.params, Form::Branches);
    let mut tensors: Vec<Tensor<'_>> =
        owned.iter().map(|(n, s, d)| Tensor { name: n.clone(), shape: s.clone(), data: d }).collect();
    tensors.push(Tensor { name: "adam.m".into(), shape: vec![tr.adam.m.len()], data: &tr.adam.m });
    tensors.push(Tensor { name: "adam.v".into(), shape: vec![tr.adam.v.len()], data: &tr.adam.v });
    let mut all = vec![
        ("format", "mcdenoise-wskp".to_string()),
        ("version", "1".to_string()),
        ("form", "branches".to_string()),
        ("step", step.to_string()),
        ("adam_t", tr.adam.t.to_string()),
        ("rng", rng.state().to_string()),
    ];
    all.extend(meta.iter().cloned());
    weights::save(path, &tensors, &all)
}

/// Runs `mcdenoise train`.
pub fn run(a: &TrainArgs) -> Result<()> {
    if a.method != "wskp" {
        return Err(HostError::Usage(format!("train --method: only wskp trains here so far, got '{}'", a.method)));
    }
    if a.steps.is_none() && a.minutes.is_none() {
        return Err(HostError::Usage("train: give --steps N or --minutes M".into()));
    }
    let t0 = Instant::now();
    let net = wskp::net(a.layers)?;
    let dirs = sequence_dirs(&a.data)?;
    eprintln!("train wskp: {} layers, {} parameters; loading {}", a.layers, net.params, a.data.display());
    let seqs: Vec<Sequence> = dirs.iter().map(|d| load_sequence(d)).collect::<Result<_>>()?;
    let samples = wskp_samples(&seqs, a.threads, a.isa)?;
    let s = a.crop;
    if let Some(small) = samples.iter().find(|x| x.w < s || x.h < s) {
        return Err(HostError::Usage(format!("--crop {s}: a frame is only {}x{}", small.w, small.h)));
    }
    let val: Vec<Sequence> = match &a.val {
        Some(v) => sequence_dirs(v)?.iter().map(|d| load_sequence(d)).collect::<Result<_>>()?,
        None => Vec::new(),
    };
    eprintln!(
        "{} sequences, {} frames loaded and accumulated in {:.1} s; validation: {} frames (input {:.2} dB)",
        seqs.len(),
        samples.len(),
        t0.elapsed().as_secs_f64(),
        val.iter().map(|v| v.frames.len()).sum::<usize>(),
        input_psnr(&val)
    );
    let layers_meta = ("layers", a.layers.to_string());
    let (mut params, mut step, mut rng) = (net.init(a.seed), 0u64, Rng::new(a.seed.wrapping_add(1)));
    let mut adam_state = None;
    if let Some(r) = &a.resume {
        let f = File::read(r)?;
        f.expect_meta("layers", &a.layers.to_string())?;
        params = f.params(&net, "wskp", &["adam.m", "adam.v"])?;
        let num = |k: &str| {
            f.meta(k)
                .and_then(|v| v.parse::<u64>().ok())
                .ok_or_else(|| HostError::bad(r, format!("checkpoint metadata {k} missing")))
        };
        step = num("step")?;
        rng = Rng::from_state(num("rng")?);
        adam_state = Some((f.tensor("adam.m", &[net.params])?, f.tensor("adam.v", &[net.params])?, num("adam_t")?));
        eprintln!("resumed from {} at step {step}", r.display());
    }
    let mut tr = Trainer::new(net, params, a.batch, s, s, a.lr, a.clip);
    if let Some((m, v, t)) = adam_state {
        (tr.adam.m, tr.adam.v, tr.adam.t) = (m, v, t);
    }
    for wss in tr.workspaces() {
        wskp::crop_buffers(&mut wss[0]);
    }
    let pool = crate::par::Pool::new(a.threads).map_err(HostError::Usage)?;
    let ckpt = checkpoint_path(&a.out);
    let start = Instant::now();
    let mut last_ckpt = Instant::now();
    let deadline = a.minutes.map(|m| Duration::from_secs_f64(m * 60.0));
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = indicatif::ProgressBar::new(a.steps.unwrap_or(0));
        b.set_style(
            indicatif::ProgressStyle::with_template("{elapsed_precise} step {pos} {msg}").expect("a valid template"),
        );
        b
    });
    let mut log = String::from("step,seconds,loss,val_psnr\n");
    let mut ema: Option<f32> = None;
    let (isa, loss, scale) = (a.isa, a.loss, 1.0 / a.batch as f32);
    let validate_now = |tr: &Trainer| -> Result<f64> {
        let p = tr.params.clone();
        let layers = a.layers;
        let net2 = wskp::net(layers)?;
        let make = move |f: &Frame| -> Result<Box<dyn Denoiser>> {
            Ok(Box::new(wskp::Wskp::<F32>::from_params(f, net2.clone(), p.clone(), layers)?))
        };
        validate(&val, &make, a.threads, a.isa)
    };
    loop {
        let done_steps = a.steps.is_some_and(|n| step >= n);
        let done_time = deadline.is_some_and(|d| start.elapsed() >= d);
        if done_steps || done_time {
            break;
        }
        let picks: Vec<CropAt> = (0..a.batch).map(|_| draw(&mut rng, &samples, s)).collect();
        let fill = |i: usize, wss: &mut [Workspace]| -> Result<()> {
            let ws = &mut wss[0];
            let at = picks[i];
            let sm = &samples[at.frame];
            crop(sm, at, s, 0, 10, ws.input_mut());
            crop(sm, at, s, 10, 19, &mut ws.aux[0]);
            Ok(())
        };
        let head = |_: usize, _: &Nets<'_>, wss: &mut [Workspace]| wskp::head(&mut wss[0], loss, scale, isa);
        let st = tr.step(&pool, a.isa, &fill, &head, true)?;
        step += 1;
        ema = Some(ema.map_or(st.loss, |e| 0.98 * e + 0.02 * st.loss));
        let secs = start.elapsed().as_secs_f64();
        let mut vpsnr = String::new();
        if !val.is_empty() && a.val_every > 0 && step % a.val_every == 0 {
            let p = validate_now(&tr)?;
            vpsnr = format!("{p:.3}");
            let line = format!("step {step}: loss {:.4}, validation PSNR {p:.2} dB ({secs:.0} s)", ema.unwrap_or(0.0));
            match &bar {
                Some(b) => b.println(line),
                None => eprintln!("{line}"),
            }
        }
        let _ = std::fmt::Write::write_fmt(&mut log, format_args!("{step},{secs:.2},{:.6},{vpsnr}\n", st.loss));
        let rate = step as f64 / secs.max(1e-9);
        match &bar {
            Some(b) => {
                b.set_position(step);
                b.set_message(format!(
                    "loss {:.4} (grad norm {:.3}) {rate:.2} steps/s",
                    ema.unwrap_or(0.0),
                    st.grad_norm
                ));
            }
            None if step % 100 == 0 => eprintln!("step {step}: loss {:.4}, {rate:.2} steps/s", ema.unwrap_or(0.0)),
            None => {}
        }
        if last_ckpt.elapsed().as_secs_f64() >= a.checkpoint_minutes * 60.0 {
            save_checkpoint(&ckpt, &tr, step, &rng, std::slice::from_ref(&layers_meta))?;
            last_ckpt = Instant::now();
        }
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    save_checkpoint(&ckpt, &tr, step, &rng, std::slice::from_ref(&layers_meta))?;
    weights::save_params(
        &a.out,
        tr.net(),
        &tr.params,
        Form::Branches,
        "wskp",
        &[layers_meta.clone(), ("steps", step.to_string())],
    )?;
    let secs = start.elapsed().as_secs_f64();
    let vp = if val.is_empty() { None } else { Some(validate_now(&tr)?) };
    eprintln!(
        "trained {step} steps in {secs:.1} s ({:.2} steps/s, {} threads, {}); final loss {:.4}{}; weights: {}",
        step as f64 / secs.max(1e-9),
        a.threads,
        a.isa.name(),
        ema.unwrap_or(0.0),
        vp.map(|p| format!(", validation PSNR {p:.2} dB")).unwrap_or_default(),
        a.out.display()
    );
    if let Some(l) = &a.log {
        if let Some(vp) = vp {
            let _ = std::fmt::Write::write_fmt(&mut log, format_args!("{step},{secs:.2},,{vp:.3}\n"));
        }
        std::fs::write(l, log).map_err(|e| HostError::write(l, e))?;
    }
    Ok(())
}

/// The parameters of a network from a file (for tests and tools).
pub fn load_params(path: &Path, net: &Net, model: &str) -> Result<Vec<f32>> {
    File::read(path)?.params(net, model, &["adam.m", "adam.v"])
}

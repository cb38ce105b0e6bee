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
use crate::io::frame::{Buffer, Frame, Limits};
use crate::io::list_inputs;
use crate::methods::{afn, wskp};
use crate::methods::{context, Denoiser, Settings, TemporalAccumulation, Timings};
use crate::metrics;
use crate::nn::loss::{Loss, Objective};
use crate::nn::weights::{self, File, Form, Tensor};
use crate::nn::{Net, Nets, Rng, Trainer, Workspace};
use crate::runtime::precision::PrecisionKind;

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
    /// WSKP: the importance and fusion logits are penalised beyond
    /// `±logit_bound` nats (0: no penalty; [`wskp::logit_penalty`]).
    pub logit_bound: f32,
    /// The loss.
    pub loss: Loss,
    /// The band term's weight beside the loss (0: none;
    /// [`crate::nn::loss::band_l1_log`]).
    pub band: f32,
    /// Seed of initialisation and sampling.
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
    /// Instruction set.
    pub isa: Isa,
    /// Continue from a checkpoint.
    pub resume: Option<PathBuf>,
    /// Start from these weights (a weights file of the same model): a new
    /// run (step 0, its own schedule, fresh optimiser state) that fine-tunes
    /// them; `resume` takes precedence.
    pub init: Option<PathBuf>,
    /// Minutes between checkpoints.
    pub checkpoint_minutes: f64,
    /// Steps between validations (0: only at the end).
    pub val_every: u64,
    /// A CSV of (step, seconds, loss, learning rate, validation PSNR, gradient norm) rows.
    pub log: Option<PathBuf>,
    /// AFN: which images it filters.
    pub variant: afn::Variant,
    /// WSKP: the window sizes.
    pub sizes: wskp::Sizes,
    /// Independent estimates of a frame used as inputs of its target: 1
    /// (`R,G,B`) or 2 (`R,G,B` and, where the frame has it, `B.*`).
    pub estimates: usize,
    /// Sample counts emulated by a copy of each sequence whose colour is
    /// `ref + (colour - ref) / sqrt(n)` (n cycling through the list over
    /// the sequences; empty: no copies). The renders are 1 spp; without
    /// these the filters learn one noise level and blur a 64-spp frame.
    pub emulate_spp: Vec<u32>,
    /// The learning rate's schedule.
    pub schedule: Schedule,
    /// The temporal accumulation's history clamp (standard deviations; 0:
    /// off) the inputs are made with; recorded in the weights (`ta_clamp`).
    pub ta_clamp: f32,
    /// The share of crops drawn from the sequences' first frames (no
    /// temporal history: the accumulation is the 1-spp frame itself), the
    /// rest uniformly over every sample (0: every crop uniformly).
    pub first_frames: f32,
    /// One frame in `frame_stride` of each copy of a sequence made a
    /// sample (1: every frame). Every frame is still accumulated in order,
    /// so the kept ones have their history; the first kept frame turns with
    /// each copy (copy `c` keeps frames `i` with `i % stride == c %
    /// stride`), so every frame position is drawn. The samples (in f16: 29
    /// planes a pixel for AFN, 23 for WSKP) are what fills memory: a stride
    /// of 2 holds twice the scenes in it.
    pub frame_stride: usize,
}

/// How the learning rate moves over a run of `--steps` steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Schedule {
    /// `--lr` throughout.
    Constant,
    /// A linear warm-up over the first `min(1000, steps / 20)` steps, then a
    /// cosine from `--lr` down to `--lr / 100` at step `--steps`.
    Cosine,
}

impl Schedule {
    /// The learning rate at `step` (from 0) of `total` steps.
    pub fn lr(self, base: f32, step: u64, total: Option<u64>) -> f32 {
        match (self, total) {
            (Schedule::Constant, _) | (_, None) => base,
            (Schedule::Cosine, Some(total)) => {
                let total = total.max(1) as f64;
                let warm = (total / 20.0).clamp(1.0, 1000.0);
                let s = step as f64;
                let f = if s < warm {
                    (s + 1.0) / warm
                } else {
                    let t = ((s - warm) / (total - warm).max(1.0)).min(1.0);
                    0.01 + 0.99 * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
                };
                (base as f64 * f) as f32
            }
        }
    }
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
            logit_bound: 30.0,
            loss: Loss::L1Log,
            band: 0.0,
            seed: 1,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            isa: Isa::detect(),
            resume: None,
            init: None,
            checkpoint_minutes: 5.0,
            val_every: 500,
            log: None,
            variant: afn::Variant::Fusion,
            sizes: wskp::Sizes::ALL,
            estimates: 2,
            emulate_spp: vec![4, 16, 64],
            first_frames: 0.0,
            frame_stride: 1,
            schedule: Schedule::Cosine,
            ta_clamp: crate::methods::TA_CLAMP,
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

/// The temporally accumulated radiance of every frame (f32), with the
/// history clamp `clamp` (standard deviations; 0: off) and the history
/// rejection WSKP and AFN run with ([`crate::methods::LEARNED_TA_REJECT`]
/// standard errors over [`crate::methods::LEARNED_TA_REJECT_SCALES`]
/// window sizes), so that the networks train on the inputs they denoise.
pub fn accumulate(seq: &Sequence, threads: usize, isa: Isa, clamp: f32) -> Result<Vec<Vec<f32>>> {
    let settings = Settings { threads, isa, precision: PrecisionKind::F32, ..Settings::default() };
    let mut ctx = context(&settings)?;
    let mut ta = TemporalAccumulation::<F32>::new(&seq.frames[0], false)?
        .with_clamp(clamp)?
        .with_reject(crate::methods::LEARNED_TA_REJECT)?
        .with_reject_scales(crate::methods::LEARNED_TA_REJECT_SCALES)?;
    let mut t = Timings::default();
    seq.frames.iter().map(|f| ta.denoise(f, &mut ctx, &mut t)).collect()
}

/// One frame's training tensors: planes of `w x h`, the network's input
/// first (`cin` planes), then the model's own less those that repeat an
/// input plane ([`Model::shared`]); held in f16 (thousands of frames fit
/// in memory), read back to f32 crop by crop ([`Model::fill_crop`]).
struct Sample {
    w: usize,
    h: usize,
    data: Vec<half::f16>,
}

/// The largest exposure-scaled value a sample holds ([`exposed`]), a power
/// of two well below f16's largest finite value (65504).
const SAMPLE_MAX: f32 = 16384.0;

/// Scales a sample's radiance planes by the frame's exposure `e` and sets
/// its exposure plane to 1 (but see below). Samples are held in f16: a nearly black frame's
/// exposure (4.5e5 on one generated frame) overflows f16, and its radiance
/// (1e-6) would be subnormal; exposure-scaled, both are near 0.18. The
/// heads and losses are linear in the radiance given the exposure, so
/// this changes no result but the rounding.
///
/// A dim frame with a light in view (`train_0616`: median radiance 1.9e-4,
/// its light 148) would go past f16's range once scaled (148 e = 1.9e5):
/// the value became `inf`, and every crop of the frame a non-finite loss.
/// So the scale is at most `SAMPLE_MAX / max |v|` and the exposure plane
/// holds the rest (`e / scale`, at most 2^15; the heads and losses read
/// it). Only values past 2^30 in exposure-normalised units (the key is
/// 0.18) are then clamped.
fn exposed(e: f32, planes: &mut [&mut [f32]], expo: &mut [f32]) {
    let peak = planes.iter().flat_map(|p| p.iter()).fold(0.0f32, |m, v| if v.is_finite() { m.max(v.abs()) } else { m });
    let mut scale = e;
    let mut rest = 1.0f32;
    if peak * e > SAMPLE_MAX {
        rest = (peak * e / SAMPLE_MAX).min(32768.0);
        scale = e / rest;
    }
    for p in planes.iter_mut() {
        p.iter_mut().for_each(|v| *v = (*v * scale).clamp(-2.0 * SAMPLE_MAX, 2.0 * SAMPLE_MAX));
    }
    expo.fill(rest);
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
                out[y * s + x] = src[(at.y0 + v) * sample.w + at.x0 + u].to_f32();
            }
        }
    }
}

/// Whether copy `copy` of a sequence (counted over the run) makes its frame
/// `i` a sample at `--frame-stride stride`: the kept frames start at
/// `copy % stride`, so any `stride` consecutive copies keep every frame
/// position once.
fn stride_keeps(copy: usize, stride: usize, i: usize) -> bool {
    i % stride == copy % stride
}

/// A crop's place: with probability `first` from one of the samples
/// `firsts` (the sequences' first frames), else from any sample. With
/// `first` 0 the generator's draws are those of a run without the option.
fn draw(rng: &mut Rng, samples: &[Sample], firsts: &[usize], first: f32, s: usize) -> CropAt {
    let frame = if first > 0.0 && !firsts.is_empty() && rng.uniform() < first {
        firsts[rng.below(firsts.len())]
    } else {
        rng.below(samples.len())
    };
    let (w, h) = (samples[frame].w, samples[frame].h);
    CropAt { frame, x0: rng.below(w - s + 1), y0: rng.below(h - s + 1), t: rng.below(8) as u8 }
}

/// Mean display PSNR of the method on sequences (each denoised whole, in
/// order), over the frames where it is finite: a frame whose display
/// values are saturated in the reference and the output alike (a very
/// bright scene clamps to white) scores `inf` and says nothing, and one
/// such frame made the mean `inf` (the generator's `val_0003`).
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
            let p = metrics::score(&out, r, f.width, f.height).psnr;
            if p.is_finite() {
                sum += p;
                n += 1;
            }
        }
    }
    Ok(sum / n.max(1) as f64)
}

/// The mean display PSNR of the sequences' inputs (over the frames where
/// it is finite, as [`validate`]).
fn input_psnr(seqs: &[Sequence]) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for s in seqs {
        for (f, r) in s.frames.iter().zip(&s.refs) {
            let p = metrics::score(f.get(Buffer::Color).expect("colour"), r, f.width, f.height).psnr;
            if p.is_finite() {
                sum += p;
                n += 1;
            }
        }
    }
    sum / n.max(1) as f64
}

fn checkpoint_path(out: &Path) -> PathBuf {
    let mut p = out.as_os_str().to_owned();
    p.push(".ckpt");
    PathBuf::from(p)
}

/// What is being trained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Model {
    /// WSKP with this many layers and these window sizes.
    Wskp(usize, wskp::Sizes),
    /// AFN, the kernel predictor and the refinement together.
    Afn(afn::Variant),
}

impl Model {
    fn name(self) -> &'static str {
        match self {
            Model::Wskp(..) => "wskp",
            Model::Afn(_) => "afn",
        }
    }
    fn nets(self) -> Result<Vec<Net>> {
        Ok(match self {
            Model::Wskp(l, s) => vec![wskp::net_for(l, s)?],
            Model::Afn(_) => vec![afn::kernel_net()?, afn::refine_net()?],
        })
    }
    /// Metadata every file of this model carries.
    fn meta(self) -> Vec<(&'static str, String)> {
        match self {
            Model::Wskp(l, s) => vec![
                ("layers", l.to_string()),
                ("sizes", s.name()),
                ("transform", crate::methods::features::TRANSFORM.to_string()),
            ],
            Model::Afn(v) => {
                vec![("variant", v.name().to_string()), ("transform", crate::methods::features::TRANSFORM.to_string())]
            }
        }
    }
    /// Planes of a crop: the network input, then the model's own.
    fn planes(self) -> (usize, usize) {
        match self {
            Model::Wskp(..) => (wskp::CIN, wskp::DATA_PLANES),
            Model::Afn(_) => (afn::CIN, afn::buf::DATA_PLANES),
        }
    }
    /// The model's own planes that repeat input planes, held once in a
    /// sample: `(input plane, own plane, count)`. AFN's refinement reads
    /// the kernel predictor's 7 auxiliary input planes (6..13) as its own
    /// 12..19; a sample leaves them out of its own (29 planes, not 36) and
    /// each crop copies them from the input.
    fn shared(self) -> Option<(usize, usize, usize)> {
        match self {
            Model::Wskp(..) => None,
            Model::Afn(_) => Some((6, 12, 7)),
        }
    }
    /// Planes a sample holds: the crop's, less the shared ones.
    fn sample_planes(self) -> usize {
        let (cin, own) = self.planes();
        cin + own - self.shared().map_or(0, |(_, _, k)| k)
    }
    /// Fills a crop's input `x` and the model's own planes `own` from
    /// `sample` at `at` (side `s`).
    fn fill_crop(self, sample: &Sample, at: CropAt, s: usize, x: &mut [f32], own: &mut [f32]) {
        let (cin, nown) = self.planes();
        crop(sample, at, s, 0, cin, x);
        match self.shared() {
            None => crop(sample, at, s, cin, cin + nown, own),
            Some((xi, oi, k)) => {
                let ss = s * s;
                crop(sample, at, s, cin, cin + oi, &mut own[..oi * ss]);
                own[oi * ss..(oi + k) * ss].copy_from_slice(&x[xi * ss..(xi + k) * ss]);
                crop(sample, at, s, cin + oi, cin + nown - k, &mut own[(oi + k) * ss..nown * ss]);
            }
        }
    }
    /// A sequence's samples, of the frames `keep` says (every frame
    /// accumulated), appended to `out` (each frame's data in f16).
    fn samples(
        self,
        s: &Sequence,
        pool: &crate::runtime::par::Pool,
        (isa, clamp): (Isa, f32),
        keep: &dyn Fn(usize) -> bool,
        out: &mut Vec<Sample>,
    ) -> Result<()> {
        let (cin, own) = self.planes();
        {
            let ta = accumulate(s, pool.threads(), isa, clamp)?;
            for (i, ((f, t), r)) in s.frames.iter().zip(&ta).zip(&s.refs).enumerate() {
                if !keep(i) {
                    continue;
                }
                let n = f.width * f.height;
                let mut data = vec![0.0f32; (cin + own) * n];
                let (x, rest) = data.split_at_mut(cin * n);
                match self {
                    Model::Wskp(..) => {
                        wskp::check_inputs(f)?;
                        let (c, rest) = rest.split_at_mut(3 * n);
                        let (alb, rest) = rest.split_at_mut(3 * n);
                        let (rf, rest) = rest.split_at_mut(3 * n);
                        let (expo, ex) = rest.split_at_mut(n);
                        let e = wskp::inputs(pool, f, t, x, c, alb, ex)?;
                        rf.copy_from_slice(r);
                        exposed(e, &mut [c, rf, ex], expo);
                    }
                    Model::Afn(variant) => {
                        afn::check_inputs(f)?;
                        let (c1, rest) = rest.split_at_mut(3 * n);
                        let (ct, rest) = rest.split_at_mut(3 * n);
                        let (alb, rest) = rest.split_at_mut(3 * n);
                        let (rf, rest) = rest.split_at_mut(3 * n);
                        // The refinement's auxiliary planes: left out of
                        // the sample, each crop copies them from the input.
                        let (_, rest) = rest.split_at_mut(7 * n);
                        let (expo, ex) = rest.split_at_mut(n);
                        let e = afn::inputs(pool, variant, f, t, x, c1, ct, alb, ex)?;
                        rf.copy_from_slice(r);
                        exposed(e, &mut [c1, ct, rf, ex], expo);
                    }
                }
                // The shared planes left out (see [`Model::shared`]).
                let skip = self.shared().map_or(0..0, |(_, oi, k)| (cin + oi) * n..(cin + oi + k) * n);
                let data = data[..skip.start].iter().chain(&data[skip.end..]);
                let data: Vec<half::f16> = data.map(|&v| half::f16::from_f32(v)).collect();
                debug_assert_eq!(data.len(), self.sample_planes() * n);
                out.push(Sample { w: f.width, h: f.height, data });
            }
        }
        Ok(())
    }
    /// The denoiser for validation, with the flat parameters of every network.
    fn denoiser(self, f: &Frame, nets: &[Net], params: &[f32]) -> Result<Box<dyn Denoiser>> {
        Ok(match self {
            Model::Wskp(l, s) => Box::new(wskp::Wskp::<F32>::from_params(f, nets[0].clone(), params.to_vec(), l, s)?),
            Model::Afn(v) => {
                let k = nets[0].params;
                Box::new(afn::Afn::<F32>::from_params(f, (params[..k].to_vec(), params[k..].to_vec()), true, v)?)
            }
        })
    }
    /// Saves the weights (and, with `adam`, a checkpoint).
    fn save(self, path: &Path, tr: &Trainer, extra: &[(&str, String)], adam: Option<(u64, &Rng)>) -> Result<()> {
        let nets: Vec<(&str, &Net, &[f32])> = tr
            .nets
            .iter()
            .enumerate()
            .map(|(k, net)| (if k == 0 { "" } else { "refine." }, net, tr.net_params(k)))
            .collect();
        let mut meta = self.meta();
        meta.extend(extra.iter().cloned());
        let mut tensors = Vec::new();
        if let Some((step, rng)) = adam {
            tensors.push(Tensor { name: "adam.m".into(), shape: vec![tr.adam.m.len()], data: &tr.adam.m });
            tensors.push(Tensor { name: "adam.v".into(), shape: vec![tr.adam.v.len()], data: &tr.adam.v });
            meta.extend([
                ("step", step.to_string()),
                ("adam_t", tr.adam.t.to_string()),
                ("rng", rng.state().to_string()),
            ]);
        }
        weights::save_model(path, self.name(), &nets, Form::Branches, &meta, &tensors)
    }
    /// Every network's parameters from a file of this model (flat).
    fn load(self, f: &File, nets: &[Net]) -> Result<Vec<f32>> {
        for (k, v) in self.meta() {
            f.expect_meta(k, &v)?;
        }
        Ok(match self {
            Model::Wskp(..) => f.params(&nets[0], "wskp", &["adam.m", "adam.v"])?,
            Model::Afn(_) => {
                let (kp, rp) = afn::split_params(f, &nets[0], &nets[1])?;
                [kp, rp].concat()
            }
        })
    }
}

/// Makes a sequence's estimates look like `n`-spp renders: each one's
/// difference from the reference is divided by `sqrt(n)` (the variance of a
/// mean of `n` independent samples). The result stays non-negative where
/// the colour and reference are (`ref + (c - ref) s >= (1 - s) ref`).
fn emulate_spp(seq: &mut Sequence, n: u32) -> Result<()> {
    let s = 1.0 / (n as f32).sqrt();
    for (f, r) in seq.frames.iter_mut().zip(&seq.refs) {
        for b in [Buffer::Color, Buffer::ColorB] {
            if let Some(c) = f.get(b) {
                let scaled: Vec<f32> = c.iter().zip(r).map(|(&c, &r)| r + (c - r) * s).collect();
                f.set(b, scaled)?;
            }
        }
    }
    Ok(())
}

/// Runs `mcdenoise train`.
pub fn run(a: &TrainArgs) -> Result<()> {
    let model = match a.method.as_str() {
        "wskp" => Model::Wskp(a.layers, a.sizes),
        "afn" => Model::Afn(a.variant),
        m => return Err(HostError::Usage(format!("train --method: expected wskp or afn, got '{m}'"))),
    };
    if a.steps.is_none() && a.minutes.is_none() {
        return Err(HostError::Usage("train: give --steps N or --minutes M".into()));
    }
    let t0 = Instant::now();
    let nets = model.nets()?;
    let dirs = sequence_dirs(&a.data)?;
    let nparams: usize = nets.iter().map(|n| n.params).sum();
    eprintln!("train {}: {} parameters; loading {}", model.name(), nparams, a.data.display());
    if a.band > 0.0 {
        eprintln!(
            "loss: {} + {} x the band term (5x5 - 17x17 box means of the log-space error)",
            a.loss.name(),
            a.band
        );
    }
    // One sequence at a time: its frames are dropped once its samples
    // (each estimate's accumulation and features) are made.
    let pool = crate::runtime::par::Pool::new(a.threads).map_err(HostError::Usage)?;
    let mut samples = Vec::new();
    // Where each sample comes from (named when a step is skipped).
    let mut origins: Vec<String> = Vec::new();
    // The samples that are a sequence's first frame (no history).
    let mut firsts: Vec<usize> = Vec::new();
    let mut nseqs = 0;
    // Copies of sequences made samples so far (each turns the first frame
    // `--frame-stride` keeps).
    let mut copies = 0usize;
    let stride = a.frame_stride;
    if stride == 0 {
        return Err(HostError::Usage("--frame-stride must be at least 1".into()));
    }
    let mut skipped_seqs = Vec::new();
    for (k, d) in dirs.iter().enumerate() {
        // A sequence still being rendered (a frame without its reference)
        // is left for a later run; one that does not load is named and
        // skipped, so that one bad file does not end a run of hours.
        let files = list_inputs(std::slice::from_ref(d))?;
        if let Some(f) = files.iter().find(|f| !d.join("ref").join(f.file_name().expect("a file")).exists()) {
            skipped_seqs.push(format!("{}: {} has no reference yet", d.display(), f.display()));
            continue;
        }
        let mut seq = match load_sequence(d) {
            Ok(s) => s,
            Err(e) => {
                skipped_seqs.push(format!("{}: {e}", d.display()));
                continue;
            }
        };
        // One copy of the sequence's samples (the frames the stride keeps):
        // its first frame's index kept where it is one, each frame's origin
        // named (`what`: which copy).
        let mut add = |seq: &Sequence, what: &str| -> Result<()> {
            let n0 = samples.len();
            let copy = copies;
            copies += 1;
            let keep = |i: usize| stride_keeps(copy, stride, i);
            model.samples(seq, &pool, (a.isa, a.ta_clamp), &keep, &mut samples)?;
            if keep(0) {
                firsts.push(n0);
            }
            let kept = (0..seq.frames.len()).filter(|&i| keep(i));
            origins.extend(kept.map(|j| format!("{} frame {j}{what}", d.display())));
            Ok(())
        };
        add(&seq, "")?;
        let swapped = a.estimates > 1 && seq.frames.iter().all(|f| f.has(Buffer::ColorB));
        if swapped {
            for f in &mut seq.frames {
                f.swap_estimates();
            }
            add(&seq, " (estimates swapped)")?;
        }
        if !a.emulate_spp.is_empty() {
            // Back to the first estimate; both scaled towards the reference.
            if swapped {
                for f in &mut seq.frames {
                    f.swap_estimates();
                }
            }
            let n = a.emulate_spp[nseqs % a.emulate_spp.len()];
            emulate_spp(&mut seq, n)?;
            add(&seq, &format!(" (as {n} spp)"))?;
        }
        nseqs += 1;
        if (k + 1) % 50 == 0 {
            eprintln!("  {} of {} sequences loaded ({} samples)", k + 1, dirs.len(), samples.len());
        }
    }
    for s in &skipped_seqs {
        eprintln!("skipped {s}");
    }
    if samples.is_empty() {
        return Err(HostError::bad(&a.data, "no complete sequence to train on"));
    }
    let s = a.crop;
    if let Some(small) = samples.iter().find(|x| x.w < s || x.h < s) {
        return Err(HostError::Usage(format!("--crop {s}: a frame is only {}x{}", small.w, small.h)));
    }
    if matches!(model, Model::Afn(_)) && !s.is_multiple_of(4) {
        return Err(HostError::Usage(format!("--crop {s}: afn needs a multiple of 4 (two 2x pools)")));
    }
    let val: Vec<Sequence> = match &a.val {
        Some(v) => sequence_dirs(v)?.iter().map(|d| load_sequence(d)).collect::<Result<_>>()?,
        None => Vec::new(),
    };
    eprintln!(
        "{} sequences, {} samples (frames x estimates{}) loaded and accumulated in {:.1} s; validation: {} frames (input {:.2} dB)",
        nseqs,
        samples.len(),
        if stride > 1 { format!(", one frame in {stride}") } else { String::new() },
        t0.elapsed().as_secs_f64(),
        val.iter().map(|v| v.frames.len()).sum::<usize>(),
        input_psnr(&val)
    );
    let mut params: Vec<f32> =
        nets.iter().enumerate().flat_map(|(k, n)| n.init(a.seed.wrapping_add(k as u64 * 1000))).collect();
    let (mut step, mut rng) = (0u64, Rng::new(a.seed.wrapping_add(1)));
    let mut adam_state = None;
    let mut seconds_before = 0.0f64;
    if let (None, Some(w)) = (&a.resume, &a.init) {
        let f = File::read(w)?;
        params = model.load(&f, &nets)?;
        let trained = crate::methods::ta_clamp_of(&f)?.unwrap_or(0.0);
        if trained != a.ta_clamp {
            return Err(HostError::bad(
                w,
                format!("these weights' inputs were made with --ta-clamp {trained}; fine-tune them with that value"),
            ));
        }
        eprintln!("initialised from {}", w.display());
    }
    if let Some(r) = &a.resume {
        let f = File::read(r)?;
        params = model.load(&f, &nets)?;
        let num = |k: &str| {
            f.meta(k)
                .and_then(|v| v.parse::<u64>().ok())
                .ok_or_else(|| HostError::bad(r, format!("checkpoint metadata {k} missing")))
        };
        let trained = crate::methods::ta_clamp_of(&f)?.unwrap_or(0.0);
        if trained != a.ta_clamp {
            return Err(HostError::bad(
                r,
                format!("the checkpoint's inputs were made with --ta-clamp {trained}; resume it with that value"),
            ));
        }
        step = num("step")?;
        seconds_before = f.meta("seconds").and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
        rng = Rng::from_state(num("rng")?);
        adam_state = Some((f.tensor("adam.m", &[nparams])?, f.tensor("adam.v", &[nparams])?, num("adam_t")?));
        eprintln!("resumed from {} at step {step}", r.display());
    }
    let ta_meta = ("ta_clamp", a.ta_clamp.to_string());
    // The accumulation's history rejection the inputs were made with (the
    // learned methods'; a record, not read back).
    let reject_meta = (
        "ta_reject",
        format!("{} over {} scales", crate::methods::LEARNED_TA_REJECT, crate::methods::LEARNED_TA_REJECT_SCALES),
    );
    let mut at = 0;
    let spec: Vec<(Net, Vec<f32>, (usize, usize))> = nets
        .iter()
        .map(|n| {
            let p = params[at..at + n.params].to_vec();
            at += n.params;
            (n.clone(), p, (s, s))
        })
        .collect();
    let mut tr = Trainer::with_nets(spec, a.batch, a.lr, a.clip)?;
    if let Some((m, v, t)) = adam_state {
        (tr.adam.m, tr.adam.v, tr.adam.t) = (m, v, t);
    }
    for wss in tr.workspaces() {
        match model {
            Model::Wskp(..) => wskp::crop_buffers(&mut wss[0]),
            Model::Afn(_) => afn::crop_buffers(wss),
        }
    }
    let pool = crate::runtime::par::Pool::new(a.threads).map_err(HostError::Usage)?;
    let ckpt = checkpoint_path(&a.out);
    // A checkpoint: the weights, Adam's state, the step and the sampler's.
    let save_ckpt = |tr: &Trainer, step: u64, rng: &Rng, secs: f64| {
        let meta = [("seconds", format!("{secs:.1}")), ta_meta.clone(), reject_meta.clone()];
        model.save(&ckpt, tr, &meta, Some((step, rng)))
    };
    let first_step = step;
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
    // The log is appended to at each checkpoint (rows up to the checkpoint's
    // step), so a run stopped and resumed leaves one row per step.
    let mut log = String::new();
    if let Some(l) = &a.log {
        if a.resume.is_none() || !l.exists() {
            std::fs::write(l, "step,seconds,loss,lr,val_psnr,grad_norm\n").map_err(|e| HostError::write(l, e))?;
        }
    }
    let flush_log = |log: &mut String| -> Result<()> {
        if let Some(l) = &a.log {
            use std::io::Write as _;
            let mut f = std::fs::OpenOptions::new().append(true).open(l).map_err(|e| HostError::write(l, e))?;
            f.write_all(log.as_bytes()).map_err(|e| HostError::write(l, e))?;
        }
        log.clear();
        Ok(())
    };
    let mut ema: Option<f32> = None;
    let mut skipped = 0u64;
    let (isa, loss, scale) = (a.isa, Objective { loss: a.loss, band: a.band }, 1.0 / a.batch as f32);
    let validate_now = |tr: &Trainer| -> Result<f64> {
        let make = |f: &Frame| model.denoiser(f, &tr.nets, &tr.params);
        validate(&val, &make, a.threads, a.isa)
    };
    loop {
        let done_steps = a.steps.is_some_and(|n| step >= n);
        let done_time = deadline.is_some_and(|d| start.elapsed() >= d);
        if done_steps || done_time {
            break;
        }
        tr.adam.lr = a.schedule.lr(a.lr, step, a.steps);
        let picks: Vec<CropAt> = (0..a.batch).map(|_| draw(&mut rng, &samples, &firsts, a.first_frames, s)).collect();
        let fill = |i: usize, wss: &mut [Workspace]| -> Result<()> {
            let ws = &mut wss[0];
            let at = picks[i];
            let sm = &samples[at.frame];
            let (x, own) = ws.input_and_aux_mut(0);
            model.fill_crop(sm, at, s, x, own);
            Ok(())
        };
        let head = |_: usize, nets: &Nets<'_>, wss: &mut [Workspace]| match model {
            Model::Wskp(_, s) => wskp::head(&mut wss[0], s, loss, scale, a.logit_bound, isa),
            Model::Afn(v) => afn::head(nets, wss, loss, scale, true, v),
        };
        let st = tr.step(&pool, a.isa, &fill, &head, true)?;
        step += 1;
        if st.skipped() {
            skipped += 1;
            let from: Vec<String> = st
                .bad_crops
                .iter()
                .map(|&i| format!("{} at ({}, {})", origins[picks[i].frame], picks[i].x0, picks[i].y0))
                .collect();
            let line = format!(
                "step {step}: skipped (loss or gradient not finite; gradient norm {}){}{}",
                st.grad_norm,
                if from.is_empty() { "" } else { "; crops from " },
                from.join(", ")
            );
            match &bar {
                Some(b) => b.println(line),
                None => eprintln!("{line}"),
            }
        } else {
            ema = Some(ema.map_or(st.loss, |e| 0.98 * e + 0.02 * st.loss));
        }
        let secs = seconds_before + start.elapsed().as_secs_f64();
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
        let _ = std::fmt::Write::write_fmt(
            &mut log,
            format_args!("{step},{secs:.2},{:.6},{:.3e},{vpsnr},{:.4e}\n", st.loss, tr.adam.lr, st.grad_norm),
        );
        let rate = (step - first_step) as f64 / start.elapsed().as_secs_f64().max(1e-9);
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
            save_ckpt(&tr, step, &rng, secs)?;
            flush_log(&mut log)?;
            last_ckpt = Instant::now();
        }
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let secs = seconds_before + start.elapsed().as_secs_f64();
    save_ckpt(&tr, step, &rng, secs)?;
    model.save(&a.out, &tr, &[("steps", step.to_string()), ta_meta, reject_meta], None)?;
    let vp = if val.is_empty() { None } else { Some(validate_now(&tr)?) };
    eprintln!(
        "trained {step} steps in {secs:.1} s ({:.2} steps/s this run, {} threads, {}){}; final loss {:.4}{}; weights: {}",
        (step - first_step) as f64 / start.elapsed().as_secs_f64().max(1e-9),
        a.threads,
        a.isa.name(),
        if skipped > 0 { format!(", {skipped} skipped (not finite)") } else { String::new() },
        ema.unwrap_or(0.0),
        vp.map(|p| format!(", validation PSNR {p:.2} dB")).unwrap_or_default(),
        a.out.display()
    );
    if let Some(vp) = vp {
        let _ = std::fmt::Write::write_fmt(&mut log, format_args!("{step},{secs:.2},,,{vp:.3},\n"));
    }
    flush_log(&mut log)?;
    Ok(())
}

/// The parameters of a network from a file (for tests and tools).
pub fn load_params(path: &Path, net: &Net, model: &str) -> Result<Vec<f32>> {
    File::read(path)?.params(net, model, &["adam.m", "adam.v"])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dim frame with a bright light: its samples stay finite in f16 and
    /// the exposure plane holds what the scale left out, so that the plane
    /// times the exposure plane is the radiance times the exposure within
    /// f16 rounding (an f64 check); a frame within range keeps the plain
    /// scaling (exposure plane 1, the same bits as `v * e`).
    #[test]
    fn exposed_samples_stay_in_f16_range() {
        let e = 950.0f32;
        let dim: Vec<f32> =
            (0..64).map(|i| 1.9e-4 * (1.0 + (i % 7) as f32) + if i == 5 { 148.0 } else { 0.0 }).collect();
        let mut a = dim.clone();
        let mut b = dim.iter().map(|v| v * 0.5).collect::<Vec<_>>();
        let mut expo = vec![0.0f32; 4];
        exposed(e, &mut [&mut a, &mut b], &mut expo);
        let rest = expo[0] as f64;
        assert!(rest > 1.0 && expo.iter().all(|&x| x == expo[0]), "{expo:?}");
        for (src, got) in [(&dim, &a), (&dim.iter().map(|v| v * 0.5).collect::<Vec<_>>(), &b)] {
            for (&v, &g) in src.iter().zip(got.iter()) {
                let h = half::f16::from_f32(g);
                assert!(h.is_finite(), "{g} overflows f16");
                let want = v as f64 * e as f64;
                let back = h.to_f64() * rest;
                assert!((back - want).abs() <= 1e-3 * want.abs() + 1e-9, "{v}: {back} vs {want}");
            }
        }
        let mut c: Vec<f32> = (0..16).map(|i| 0.001 * i as f32).collect();
        let want: Vec<f32> = c.iter().map(|v| v * e).collect();
        exposed(e, &mut [&mut c], &mut expo);
        assert_eq!(c, want);
        assert!(expo.iter().all(|&x| x == 1.0));
    }

    /// Each estimate's difference from the reference shrinks by `sqrt(n)`
    /// (checked in f64), so its variance over many pixels by `n`; buffers
    /// other than the estimates are untouched.
    #[test]
    fn emulated_spp_divides_the_noise_variance_by_n() {
        let (w, h) = (64, 48);
        let m = 3 * w * h;
        let mut state = 12345u64;
        let mut rnd = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 33) as f64 / (1u64 << 31) as f64) as f32
        };
        let reference: Vec<f32> = (0..m).map(|_| 0.2 + rnd()).collect();
        // 1-spp-like: 0 or 4x the reference, mean about the reference.
        let a: Vec<f32> = reference.iter().map(|&r| if rnd() < 0.25 { 4.0 * r } else { 0.0 }).collect();
        let b: Vec<f32> = reference.iter().map(|&r| r * 2.0 * rnd()).collect();
        let albedo: Vec<f32> = (0..m).map(|_| rnd()).collect();
        let mut f = Frame::from_color("f.exr", w, h, a.clone()).unwrap();
        f.set(Buffer::ColorB, b.clone()).unwrap();
        f.set(Buffer::Albedo, albedo.clone()).unwrap();
        let mut seq = Sequence { dir: PathBuf::from("s"), frames: vec![f], refs: vec![reference.clone()] };
        emulate_spp(&mut seq, 16).unwrap();
        let f = &seq.frames[0];
        for (src, buf) in [(&a, Buffer::Color), (&b, Buffer::ColorB)] {
            let got = f.get(buf).unwrap();
            let (mut v0, mut v1) = (0.0f64, 0.0f64);
            for i in 0..m {
                let (c, r) = (src[i] as f64, reference[i] as f64);
                let want = r + (c - r) / 4.0;
                assert!((got[i] as f64 - want).abs() < 1e-6 * (1.0 + want.abs()), "{i}: {} vs {want}", got[i]);
                assert!(got[i] >= 0.0);
                v0 += (c - r) * (c - r);
                v1 += (got[i] as f64 - r) * (got[i] as f64 - r);
            }
            assert!((v0 / v1 - 16.0).abs() < 1e-3, "variance ratio {}", v0 / v1);
        }
        assert_eq!(f.get(Buffer::Albedo).unwrap(), &albedo[..]);
    }

    /// A frame saturated on display in its reference and its input alike
    /// scores `inf` and is left out of the mean; the other frame's PSNR is
    /// the mean.
    #[test]
    fn input_psnr_leaves_out_frames_that_say_nothing() {
        let (w, h) = (8, 6);
        let m = 3 * w * h;
        let bright = vec![50.0f32; m];
        let r = vec![0.25f32; m];
        let noisy: Vec<f32> = (0..m).map(|i| if i % 2 == 0 { 0.5 } else { 0.0 }).collect();
        let seq = Sequence {
            dir: PathBuf::from("s"),
            frames: vec![
                Frame::from_color("a.exr", w, h, bright.iter().map(|v| v * 2.0).collect()).unwrap(),
                Frame::from_color("b.exr", w, h, noisy.clone()).unwrap(),
            ],
            refs: vec![bright, r.clone()],
        };
        let want = metrics::score(&noisy, &r, w, h).psnr;
        assert!(want.is_finite());
        let got = input_psnr(std::slice::from_ref(&seq));
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    }

    /// `--frame-stride`: any `stride` consecutive copies of an 8-frame
    /// sequence keep each frame exactly once between them, one copy
    /// keeps `ceil((8 - offset) / stride)` frames, and stride 1 keeps all.
    #[test]
    fn frame_stride_covers_every_frame_position() {
        for stride in 1..=5usize {
            for first in 0..7usize {
                let mut times = [0usize; 8];
                for copy in first..first + stride {
                    let kept: Vec<usize> = (0..8).filter(|&i| stride_keeps(copy, stride, i)).collect();
                    let offset = copy % stride;
                    assert_eq!(kept.len(), (8 - offset).div_ceil(stride), "stride {stride}, copy {copy}");
                    kept.iter().for_each(|&i| times[i] += 1);
                }
                assert_eq!(times, [1; 8], "stride {stride}, copies {first}..");
            }
        }
        assert!((0..8).all(|i| stride_keeps(5, 1, i)));
    }

    /// `--first-frames`: at 0 the draws are a plain uniform draw's (runs
    /// before the option repeat bit for bit); at 1 every crop comes from a
    /// first frame; at 0.3 about 0.3 + 0.7 x (their share of all samples).
    #[test]
    fn first_frames_share_of_the_crops() {
        let s = 4;
        let samples: Vec<Sample> = (0..40).map(|_| Sample { w: 6, h: 5, data: vec![half::f16::ZERO; 30] }).collect();
        let firsts: Vec<usize> = (0..40).step_by(8).collect();
        let (mut r0, mut r1) = (Rng::new(7), Rng::new(7));
        for _ in 0..1000 {
            let got = draw(&mut r0, &samples, &firsts, 0.0, s);
            let frame = r1.below(40);
            let (x0, y0, t) = (r1.below(3), r1.below(2), r1.below(8) as u8);
            assert_eq!((got.frame, got.x0, got.y0, got.t), (frame, x0, y0, t));
        }
        let mut r = Rng::new(9);
        assert!((0..1000).all(|_| draw(&mut r, &samples, &firsts, 1.0, s).frame.is_multiple_of(8)));
        let n = 20000;
        let hits = (0..n).filter(|_| draw(&mut r, &samples, &firsts, 0.3, s).frame.is_multiple_of(8)).count();
        let want = 0.3 + 0.7 * 5.0 / 40.0;
        let got = hits as f64 / n as f64;
        // Binomial standard deviation about 0.0035: 5 of them.
        assert!((got - want).abs() < 0.018, "{got} vs {want}");
    }
}

//! Cross-regression online denoiser (Choi et al. 2024, "Online Neural
//! Denoising with Cross-Regression for Interactive Rendering").
//!
//! Per frame, from the two half-sample estimates A (`R,G,B`) and B
//! (`B.R,B.G,B.B`) in `log1p` colour:
//! 1. cross-regression ([`mcdenoise_core::regress`]): features and weights
//!    from A fitted to B gives pilot A, and the other way round pilot B;
//! 2. reprojection of the previous output and pilots (the core's temporal
//!    reprojection with the blend forced to the history: motion vectors, or
//!    world positions, with its position and normal tests), the success mask
//!    eroded over 3x3, and each reprojected value kept only inside the range
//!    of its current counterpart over 7x7 (the authors' temporal screening);
//! 3. a U-Net (3x3 ReLU convs 8,8 / 16,16 / 32,32 with 2x2 max pools,
//!    nearest upsampling with skip concatenation back to 16,16 and 8, a 1x1
//!    head to 6 raw outputs) on 15 planes: both pilots, the warped previous
//!    output, albedo, normal;
//! 4. the 11x11 spatiotemporal cross-bilateral filter of both pilots;
//! 5. the loss `relMSE(out_A, pilot_B) + relMSE(out_B, pilot_A)` and the same
//!    against the reprojected previous pilots (0.5 each; where nothing
//!    reprojects, the current pilots), its gradient through the filter and the
//!    network, and exactly one Adam step (lr 1e-3) — the network starts from
//!    random weights at the first frame;
//! 6. two steps back towards the pair's mean where the output is estimated
//!    worse than it (neither in the paper): `blend_by_error` over a plain
//!    13x13 window, then the learned filters' fallback
//!    ([`crate::methods::fallback`], its noise from the pair, `--no-fallback`
//!    turns it off), whose window holds only the pixels of the centre's
//!    albedo and level. A network that has had one or two steps blurs edges
//!    and leaks a light into its ceiling; on the foreign 16-spp Cornell box
//!    the second step moved cross from 37.58 to 38.55 dB, on the 64-spp one
//!    from 41.71 to 42.74 (docs/quality.md).
//!
//! The frame is cut into horizontal strips (a fixed count for the frame
//! height, not the thread count) run as crops with a 24-row halo (more than
//! the network's receptive field), so the network's passes run in parallel
//! and the result does not depend on the thread count.

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use mcdenoise_core::conv::Activation;
use mcdenoise_core::regress::{self, FilterInputs, RegressionInputs};
use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::{View, ViewMut, F32};

use crate::error::{HostError, Result};
use crate::io::frame::{Buffer, Frame};
use crate::methods::{scene_scale, Ctx, Denoiser, Plan, Timings, POSITION_TOLERANCE};
use crate::nn::weights::{self, File, Form};
use crate::nn::{Conv, Layer, Net, NetDesc, Trainer};
use crate::runtime::par::Pool;

/// Network input planes.
pub const CIN: usize = 15;
/// Adam's learning rate.
pub const LR: f32 = 1e-3;
/// The input transform of the online network (log1p colour of both
/// pilots, the warped output, albedo, normal), recorded in a saved state
/// and checked when one is loaded.
pub const TRANSFORM: &str = "mcdenoise-cross-1";
/// The relMSE's epsilon.
pub const REL_EPS: f32 = 1e-2;
/// Rows of halo around each strip (a multiple of 4, over the receptive field).
pub const HALO: usize = 24;
/// Default seed of the initial weights.
pub const SEED: u64 = 2024;

/// The U-Net.
pub fn net() -> Net {
    let conv = |k, cout, act| Layer::Conv(Conv { k, cout, act, repvgg: false, bias: true });
    let relu = |c| conv(3, c, Activation::Relu);
    let layers = vec![
        relu(8),
        relu(8),
        Layer::Save,
        Layer::MaxPool,
        relu(16),
        relu(16),
        Layer::Save,
        Layer::MaxPool,
        relu(32),
        relu(32),
        Layer::Upsample { bilinear: false },
        Layer::Concat,
        relu(16),
        relu(16),
        Layer::Upsample { bilinear: false },
        Layer::Concat,
        relu(8),
        conv(1, regress::PARAMS, Activation::Identity),
    ];
    Net::new(NetDesc { cin: CIN, layers }).expect("the U-Net's layers fit together")
}

/// The frame's strips: `(crop start, tile start, tile end)` in rows, crops
/// `crop_h` rows of the padded frame.
fn strips(h: usize, hp: usize) -> (Vec<(usize, usize, usize)>, usize) {
    let n = ((h + 90) / 180).max(1);
    let tile = h.div_ceil(n).div_ceil(4) * 4;
    let crop_h = (tile + 2 * HALO).min(hp);
    let mut out = Vec::new();
    let mut t0 = 0;
    while t0 < h {
        let t1 = (t0 + tile).min(h);
        let c0 = t0.saturating_sub(HALO).min(hp - crop_h);
        out.push((c0, t0, t1));
        t0 = t1;
    }
    (out, crop_h)
}

/// What the next frame needs of this one.
struct Prev {
    /// Output (log), pilot A, pilot B: 9 planes.
    colors: Vec<f32>,
    normal: Option<Vec<f32>>,
    position: Option<Vec<f32>>,
}

/// Per-frame buffers, kept.
struct Bufs {
    a: Vec<f32>,
    b: Vec<f32>,
    var_a: Vec<f32>,
    var_b: Vec<f32>,
    pa: Vec<f32>,
    pb: Vec<f32>,
    /// Warped output, pilot A, pilot B (9 planes).
    warped: Vec<f32>,
    valid: Vec<f32>,
    /// The reprojection's current colour (unused: the blend takes the
    /// history whole), its history (1e30: never capped) and counts out.
    zeros: Vec<f32>,
    big: Vec<f32>,
    hist: Vec<f32>,
    /// The reprojection's success mask before its erosion.
    row_ok: Vec<f32>,
    /// The screening's window minimum and maximum, their row passes, and the
    /// current plane they are taken of (5 planes).
    window: Vec<f32>,
    /// Which parts of the history the screening keeps, per pixel.
    keep: Vec<u8>,
    albedo: Vec<f32>,
    normal: Vec<f32>,
    /// The network input at the padded size.
    input: Vec<f32>,
    /// Outputs A, B and combined (log), 9 planes.
    out: Vec<f32>,
}

/// Timing of the online step's parts, summed over the crops (CPU time).
#[derive(Default)]
struct StepClock {
    fill_end: Vec<Option<Instant>>,
    forward: Duration,
    head: Duration,
}

/// The `cross` method.
pub struct Cross {
    plan: Plan,
    trainer: Option<Trainer>,
    net: Net,
    init: Vec<f32>,
    adam: Option<(Vec<f32>, Vec<f32>, u64)>,
    params: TemporalParams,
    prev: Option<Prev>,
    bufs: Option<Bufs>,
    save_state: Option<PathBuf>,
    seed: u64,
    lr: f32,
    temporal: bool,
    /// The fallback to the input after the blend ([`crate::methods::fallback`]).
    fallback: bool,
    /// The last frame's loss.
    pub last_loss: f32,
    /// Frames seen.
    pub frames: u64,
}

fn require_b(f: &Frame) -> Result<()> {
    f.require(Buffer::ColorB, "cross (cross-regression needs two independent estimates)").map(|_| ())
}

impl Cross {
    /// Memory per frame (see [`crate::runtime::memory`]), in f32 whatever the
    /// precision: the per-frame buffers (56 planes with the reprojection's,
    /// the network input at the padded size), what the next frame
    /// reprojects (output and pilots, normal, position: 15), and the online
    /// step's workspaces, one per strip of `crop_h` padded rows (every U-Net
    /// tensor and its gradient, the filter's 9 + 6 planes per crop), kept
    /// from frame to frame; during a frame the next frame's history beside
    /// this one's and the output.
    pub fn footprint(info: &crate::io::frame::FrameInfo) -> crate::runtime::memory::Footprint {
        let (w, h) = (info.width.max(1), info.height.max(1));
        let (wp, hp) = (w.div_ceil(4) * 4, h.div_ceil(4) * 4);
        let (strips, crop_h) = strips(h, hp);
        let crop = crate::nn::Workspace::floats(&net(), wp, crop_h) + 15 * w * crop_h + regress::filter_scratch_len(w);
        let per_px = |floats: usize| (4 * floats as u64).div_ceil((w * h) as u64);
        let workspaces = per_px(strips.len() * crop);
        let input = per_px(CIN * wp * hp);
        // 39 per-frame planes, 17 of the reprojection and screening (and a
        // byte per pixel), 15 kept for the next frame.
        let kept = 4 * (39 + 17 + 15) + 1 + input + workspaces;
        let mut l = crate::runtime::memory::Ledger::default();
        l.alloc(kept).alloc(4 * 15).alloc(12);
        // The fallback to the input (its mean in the window planes).
        l.temp(crate::methods::fallback::TEMP_BYTES);
        crate::runtime::memory::Footprint { kept, peak: l.peak(), scratch: 0 }
    }

    /// For a sequence starting with `first`; `load` continues from a saved
    /// state, `save` writes the state after every frame.
    pub fn new(first: &Frame, seed: u64, load: Option<&std::path::Path>, save: Option<PathBuf>) -> Result<Cross> {
        require_b(first)?;
        let net = net();
        let mut plan = Plan::default();
        plan.built.extend(["log1p", "cross-regression (A->B, B->A)"]);
        let temporal = first.has(Buffer::Motion) || first.has(Buffer::Position);
        if temporal {
            plan.built.push("reprojection");
        } else {
            plan.skipped.push(("reprojection", "no motion and no position".into()));
        }
        plan.built.extend(["U-Net", "spatiotemporal filter 11x11", "relMSE loss", "one Adam step"]);
        crate::methods::fallback::plan(&mut plan, true, true);
        for b in [Buffer::Albedo, Buffer::Normal] {
            if !first.has(b) {
                plan.skipped.push((b.name(), "not in the input: zero planes".into()));
            }
        }
        let (init, adam) = match load {
            Some(path) => {
                let file = File::read(path)?;
                file.expect_transform(TRANSFORM)?;
                let p = file.params(&net, "cross", &["adam.m", "adam.v"])?;
                let m = file.tensor("adam.m", &[net.params])?;
                let v = file.tensor("adam.v", &[net.params])?;
                let t = file
                    .meta("adam_t")
                    .and_then(|s| s.parse::<u64>().ok())
                    .ok_or_else(|| HostError::bad(path, "metadata adam_t missing or not a number"))?;
                plan.built.insert(0, "state loaded");
                (p, Some((m, v, t)))
            }
            None => (net.init(seed), None),
        };
        let params = TemporalParams {
            pos_limit: POSITION_TOLERANCE * scene_scale(first),
            alpha_min: 1e-30,
            history_cap: f32::MAX,
            ..TemporalParams::default()
        };
        Ok(Cross {
            plan,
            trainer: None,
            net,
            init,
            adam,
            params,
            prev: None,
            bufs: None,
            save_state: save,
            seed,
            lr: LR,
            temporal,
            fallback: true,
            last_loss: 0.0,
            frames: 0,
        })
    }

    /// Adam's learning rate of the online step (default [`LR`], the
    /// authors'); positive and finite, else a usage error naming it.
    pub fn with_learning_rate(mut self, lr: f32) -> Result<Cross> {
        if !(lr > 0.0 && lr.is_finite()) {
            return Err(HostError::Usage(format!("--cross-lr: expected a positive finite number, got {lr}")));
        }
        self.lr = lr;
        Ok(self)
    }

    /// Without the temporal reuse (no reprojection, no temporal loss term;
    /// an ablation): the plan says so.
    pub fn spatial_only(mut self) -> Cross {
        if self.temporal {
            self.temporal = false;
            self.plan.built.retain(|s| *s != "reprojection");
            self.plan.skipped.push(("reprojection", "--cross-spatial-only".into()));
        }
        self
    }

    /// With or without the fallback to the input after the blend to the
    /// pair's mean (`--no-fallback`).
    pub fn with_fallback(mut self, on: bool) -> Cross {
        self.fallback = on;
        crate::methods::fallback::switch(&mut self.plan, on);
        self
    }

    /// Records that a precision other than f32 was asked for.
    pub fn note_precision(&mut self, name: &str) {
        self.plan.skipped.push(("precision", format!("{name} asked for; online training runs in f32")));
    }

    /// The network's parameters now.
    pub fn params(&self) -> &[f32] {
        self.trainer.as_ref().map_or(&self.init, |t| &t.params)
    }

    /// Writes the network's weights and Adam's state.
    pub fn save(&self, path: &std::path::Path) -> Result<()> {
        let empty = vec![0.0f32; self.net.params];
        let (m, v, t) = match &self.trainer {
            Some(tr) => (&tr.adam.m[..], &tr.adam.v[..], tr.adam.t),
            None => match &self.adam {
                Some((m, v, t)) => (&m[..], &v[..], *t),
                None => (&empty[..], &empty[..], 0),
            },
        };
        let adam = [
            weights::Tensor { name: "adam.m".into(), shape: vec![self.net.params], data: m },
            weights::Tensor { name: "adam.v".into(), shape: vec![self.net.params], data: v },
        ];
        let meta = [("adam_t", t.to_string()), ("seed", self.seed.to_string()), ("transform", TRANSFORM.to_string())];
        weights::save_model(path, "cross", &[("", &self.net, self.params())], Form::Branches, &meta, &adam)
    }
}

/// Side of the window whose range of current values screens the history
/// (the authors' temporal screening).
const SCREEN_WINDOW: usize = 7;

/// Minimum and maximum of `src` (one `w x h` plane) over the square of
/// radius `r` around each pixel (inside the image), by a
/// pass along rows into `tmin`/`tmax` and one along columns, each over
/// slices (so they vectorise) and in parallel over rows.
#[allow(clippy::too_many_arguments)]
fn window_range(
    pool: &Pool,
    src: &[f32],
    w: usize,
    h: usize,
    r: usize,
    tmin: &mut [f32],
    tmax: &mut [f32],
    mn: &mut [f32],
    mx: &mut [f32],
) {
    use rayon::prelude::*;
    pool.install(|| {
        src.par_chunks_exact(w).zip(tmin.par_chunks_exact_mut(w).zip(tmax.par_chunks_exact_mut(w))).for_each(
            |(row, (lo, hi))| {
                // Interior: the window's taps as shifted slices.
                if w > 2 * r {
                    let m = w - 2 * r;
                    lo[r..r + m].copy_from_slice(&row[..m]);
                    hi[r..r + m].copy_from_slice(&row[..m]);
                    for k in 1..=2 * r {
                        for ((l, h), &v) in lo[r..r + m].iter_mut().zip(&mut hi[r..r + m]).zip(&row[k..k + m]) {
                            *l = l.min(v);
                            *h = h.max(v);
                        }
                    }
                }
                // The edges (and rows narrower than the window): clipped spans.
                for x in (0..w).filter(|&x| x < r || x + r >= w) {
                    let span = &row[x.saturating_sub(r)..(x + r + 1).min(w)];
                    lo[x] = span.iter().fold(f32::INFINITY, |a, &v| a.min(v));
                    hi[x] = span.iter().fold(f32::NEG_INFINITY, |a, &v| a.max(v));
                }
            },
        );
        let (tmin, tmax) = (&*tmin, &*tmax);
        mn.par_chunks_exact_mut(w).zip(mx.par_chunks_exact_mut(w)).enumerate().for_each(|(y, (lo, hi))| {
            let (a, b) = (y.saturating_sub(r), (y + r + 1).min(h));
            lo.copy_from_slice(&tmin[a * w..(a + 1) * w]);
            hi.copy_from_slice(&tmax[a * w..(a + 1) * w]);
            for yy in a + 1..b {
                for ((l, h), (&vl, &vh)) in lo
                    .iter_mut()
                    .zip(hi.iter_mut())
                    .zip(tmin[yy * w..(yy + 1) * w].iter().zip(&tmax[yy * w..(yy + 1) * w]))
                {
                    *l = l.min(vl);
                    *h = h.max(vh);
                }
            }
        });
    });
}

/// The history the filter and the loss read. Where the reprojection failed
/// (`valid` 0), the previous output is replaced by the mean of the current
/// pilots and the previous pilots by the current ones. Elsewhere each of the
/// three (output against the pilots' mean, pilot A against pilot A, pilot B
/// against pilot B) is kept only if every channel lies strictly inside the
/// range of its current counterpart over the 7x7 window around the pixel,
/// else replaced by it; a replaced output also clears `valid`, so the
/// filter does not blend it (the authors' temporal screening).
fn screen(pool: &Pool, b: &mut Bufs, w: usize, h: usize) {
    let n = w * h;
    let (mean, rest) = b.window.split_at_mut(n);
    let (tmin, rest) = rest.split_at_mut(n);
    let (tmax, rest) = rest.split_at_mut(n);
    let (mn, mx) = rest.split_at_mut(n);
    // Which of the three keep their history (bit 0 output, 1 pilot A, 2 pilot B).
    let keep = &mut b.keep;
    for (k, &v) in keep.iter_mut().zip(&b.valid) {
        *k = if v > 0.0 { 0b111 } else { 0 };
    }
    for c in 0..3 {
        for (m, (&a, &bb)) in mean.iter_mut().zip(b.pa[c * n..(c + 1) * n].iter().zip(&b.pb[c * n..(c + 1) * n])) {
            *m = 0.5 * (a + bb);
        }
        for (g, cur) in [(0usize, &*mean), (1, &b.pa[c * n..(c + 1) * n]), (2, &b.pb[c * n..(c + 1) * n])] {
            window_range(pool, cur, w, h, SCREEN_WINDOW / 2, tmin, tmax, mn, mx);
            let prev = &b.warped[(3 * g + c) * n..(3 * g + c + 1) * n];
            for (((k, &p), &lo), &hi) in keep.iter_mut().zip(prev).zip(&*mn).zip(&*mx) {
                let inside = p > lo && p < hi;
                *k &= !(u8::from(!inside) << g);
            }
        }
    }
    for (i, &k) in b.keep.iter().enumerate() {
        if k & 1 == 0 {
            b.valid[i] = 0.0;
        }
        for c in 0..3 {
            let (a, bb) = (b.pa[c * n + i], b.pb[c * n + i]);
            if k & 1 == 0 {
                b.warped[c * n + i] = 0.5 * (a + bb);
            }
            if k & 2 == 0 {
                b.warped[(3 + c) * n + i] = a;
            }
            if k & 4 == 0 {
                b.warped[(6 + c) * n + i] = bb;
            }
        }
    }
}

/// `log1p(max(v, 0))`.
/// Half the side of [`blend_by_error`]'s window (13x13).
const BLEND_RADIUS: usize = 6;
/// How many times the input's own variance the output's estimated squared
/// error must exceed before [`blend_by_error`] moves towards the input.
const BLEND_MARGIN: f32 = 2.0;

/// Falls back towards the input mean `m = (A + B) / 2` where the output
/// `o` is estimated to be worse than it. The pair gives the mean's variance
/// without a reference: `v = (A - B)^2 / 4` (the estimates are
/// independent), and `(o - m)^2 - v` estimates the output's squared error
/// (its bias, when its own noise is small). Both are taken in `log1p`
/// colour (at 1 spp their linear values are ruled by single fireflies),
/// summed over the channels and over a 13x13 window (one pixel's estimate
/// is all noise). The linear output becomes `m + k (o - m)` with
/// `k = v / (v + max(e - 2 v, 0))`: the weight that minimises the expected
/// error of a blend of two estimates with independent errors, where the
/// margin (2, not 1) leaves the output alone unless its excess is clearly
/// above the noise (at 1 spp the estimate itself is noisy, and a `k` pulled
/// under 1 by that noise puts noise back). On a 64-spp frame that starts a
/// sequence, where the network has had one step, the filter's blur is
/// larger than the input's noise and `k` keeps the input: on the corpus'
/// 64-spp box relMSE 0.0017 became 0.0009 (the input's: 0.0013), and the
/// 1-spp sequences of docs/quality.md are unchanged or better.
fn blend_by_error(o: &mut [f32], a: &[f32], b: &[f32], logs: Logs, w: usize, h: usize, tmp: &mut [f32]) {
    let n = w * h;
    let (var, err) = tmp.split_at_mut(n);
    let (lo, la, lb) = logs;
    for i in 0..n {
        let (mut v, mut e) = (0.0f32, 0.0f32);
        for c in 0..3 {
            let (x, y, z) = (la[c * n + i], lb[c * n + i], lo[c * n + i]);
            let m = 0.5 * (x + y);
            v += 0.25 * (x - y) * (x - y);
            e += (z - m) * (z - m);
        }
        // (log1p colour keeps both finite for finite input; the guard is
        // large but small enough for the window sums' f64 running sums.)
        var[i] = if v.is_finite() { v } else { 1e12 };
        err[i] = if e.is_finite() { e } else { 1e12 };
    }
    // Window sums, not means: `k` is a ratio of the two, the same either way.
    crate::methods::features::box_sum(var, w, h, BLEND_RADIUS);
    crate::methods::features::box_sum(err, w, h, BLEND_RADIUS);
    for i in 0..n {
        let k = crate::methods::fallback::shrink(var[i], err[i], BLEND_MARGIN);
        for c in 0..3 {
            let m = 0.5 * (a[c * n + i] + b[c * n + i]);
            let out = m + k * (o[c * n + i] - m);
            if out.is_finite() {
                o[c * n + i] = out.max(0.0);
            }
        }
    }
}

/// The output, A and B in `log1p` colour (3 planes each).
type Logs<'a> = (&'a [f32], &'a [f32], &'a [f32]);

fn log1p_into(src: &[f32], dst: &mut [f32]) {
    for (d, &s) in dst.iter_mut().zip(src) {
        *d = s.max(0.0).ln_1p();
    }
}

/// Replicates the edges of a `w x h` plane set into the top-left of a `wp x hp` one.
fn pad_into(src: &[f32], c: usize, w: usize, h: usize, dst: &mut [f32], wp: usize, hp: usize) {
    for ch in 0..c {
        for y in 0..hp {
            let sy = y.min(h - 1);
            let srow = &src[(ch * h + sy) * w..(ch * h + sy + 1) * w];
            let drow = &mut dst[(ch * hp + y) * wp..(ch * hp + y + 1) * wp];
            drow[..w].copy_from_slice(srow);
            let last = srow[w - 1];
            drow[w..].fill(last);
        }
    }
}

impl Denoiser for Cross {
    fn name(&self) -> &'static str {
        "cross"
    }
    fn plan(&self) -> &Plan {
        &self.plan
    }
    fn save_state(&self, path: &std::path::Path) -> Result<()> {
        self.save(path)
    }
    fn denoise(&mut self, f: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        require_b(f)?;
        let (w, h) = (f.width, f.height);
        let n = w * h;
        let (wp, hp) = (w.div_ceil(4) * 4, h.div_ceil(4) * 4);
        let isa = ctx.isa;
        let (strips, crop_h) = strips(h, hp);
        if self.trainer.is_none() {
            let mut tr = Trainer::new(self.net.clone(), self.init.clone(), strips.len(), wp, crop_h, self.lr, 0.0)?;
            if let Some((m, v, step)) = self.adam.take() {
                tr.adam.m = m;
                tr.adam.v = v;
                tr.adam.t = step;
            }
            self.trainer = Some(tr);
        }
        let trainer = self.trainer.as_mut().expect("just built");
        if trainer.workspaces()[0][0].size() != (wp, crop_h) {
            return Err(HostError::bad(&f.path, "frame size differs from the sequence's first frame"));
        }
        let bufs = self.bufs.get_or_insert_with(|| Bufs {
            a: vec![0.0; 3 * n],
            b: vec![0.0; 3 * n],
            var_a: vec![0.0; n],
            var_b: vec![0.0; n],
            pa: vec![0.0; 3 * n],
            pb: vec![0.0; 3 * n],
            warped: vec![0.0; 9 * n],
            valid: vec![0.0; n],
            zeros: vec![0.0; 9 * n],
            big: vec![1e30; n],
            hist: vec![0.0; n],
            row_ok: vec![0.0; n],
            window: vec![0.0; 5 * n],
            keep: vec![0; n],
            albedo: vec![0.0; 3 * n],
            normal: vec![0.0; 3 * n],
            input: vec![0.0; CIN * wp * hp],
            out: vec![0.0; 9 * n],
        });
        // 1. Inputs and the cross-regression.
        t.time("regression", || -> Result<()> {
            log1p_into(f.require(Buffer::Color, "cross")?, &mut bufs.a);
            log1p_into(f.require(Buffer::ColorB, "cross")?, &mut bufs.b);
            match f.get(Buffer::Albedo) {
                Some(v) => bufs.albedo.copy_from_slice(v),
                None => bufs.albedo.fill(0.0),
            }
            match f.get(Buffer::Normal) {
                Some(v) => bufs.normal.copy_from_slice(v),
                None => bufs.normal.fill(0.0),
            }
            for (src, var) in [(&bufs.a, &mut bufs.var_a), (&bufs.b, &mut bufs.var_b)] {
                let sv = View::new(src, 3, w, h)?;
                ctx.pool.bands(ViewMut::new(var, 1, w, h)?, 1, &mut ctx.scratch, 0, |band, y0, _| {
                    regress::variance_rows(isa, &sv, band, y0)
                })?;
            }
            let len = regress::regression_scratch_len(w);
            for (x, var, y, out) in
                [(&bufs.a, &bufs.var_a, &bufs.b, &mut bufs.pa), (&bufs.b, &bufs.var_b, &bufs.a, &mut bufs.pb)]
            {
                let inp = RegressionInputs {
                    x: View::new(x, 3, w, h)?,
                    var: View::new(var, 1, w, h)?,
                    y: View::new(y, 3, w, h)?,
                    albedo: View::new(&bufs.albedo, 3, w, h)?,
                    normal: View::new(&bufs.normal, 3, w, h)?,
                };
                ctx.pool.bands(ViewMut::new(out, 3, w, h)?, 4, &mut ctx.scratch, len, |band, y0, s| {
                    regress::regression_rows(isa, &inp, band, y0, s)
                })?;
            }
            Ok(())
        })?;
        // 2. Reprojection of the previous output and pilots.
        t.time("reprojection", || -> Result<()> {
            bufs.valid.fill(0.0);
            // Spatial only (an ablation, `--cross-spatial-only`).
            if !self.temporal {
                return Ok(());
            }
            let Some(prev) = &self.prev else { return Ok(()) };
            let motion = f.view(Buffer::Motion);
            let position = f.view(Buffer::Position);
            let normal = f.view(Buffer::Normal);
            if motion.is_none() && (position.is_none() || prev.position.is_none()) {
                return Ok(());
            }
            // Output and both pilots (9 planes) in one pass: the geometry
            // tests and the bilinear taps are shared.
            let inp = TemporalInputs {
                color: View::new(&bufs.zeros, 9, w, h)?,
                normal,
                position,
                motion,
                prev_color: View::new(&prev.colors, 9, w, h)?,
                prev_normal: prev.normal.as_deref().map(|v| View::new(v, 3, w, h)).transpose()?,
                prev_position: prev.position.as_deref().map(|v| View::new(v, 3, w, h)).transpose()?,
                prev_history: View::new(&bufs.big, 1, w, h)?,
                // The pilots' temporal screening rejects what the albedo
                // test would (an emitter's outline) and more.
                albedo: None,
                prev_albedo: None,
            };
            let params = self.params;
            ctx.pool.bands2(
                ViewMut::new(&mut bufs.warped, 9, w, h)?,
                ViewMut::new(&mut bufs.hist, 1, w, h)?,
                1,
                &mut ctx.scratch,
                0,
                |band, hb, y0, _| temporal::accumulate::<F32>(isa, &inp, &params, band, hb, y0),
            )?;
            // Valid where the pixel and its 3x3 neighbours (inside the
            // image) all reprojected: the authors' erosion of the success
            // mask against bilinear-reprojection artefacts at its edges
            // (the mask's minimum over the 3x3 window).
            for (ok, &v) in bufs.row_ok.iter_mut().zip(&bufs.hist) {
                *ok = if v > 0.0 { 1.0 } else { 0.0 };
            }
            let (_, rest) = bufs.window.split_at_mut(n);
            let (tmin, rest) = rest.split_at_mut(n);
            let (tmax, rest) = rest.split_at_mut(n);
            let (_, mx) = rest.split_at_mut(n);
            window_range(&ctx.pool, &bufs.row_ok, w, h, 1, tmin, tmax, &mut bufs.valid, mx);
            Ok(())
        })?;
        // Where nothing reprojects, the current values stand in; where it
        // does, the history is screened against the current pilots.
        t.time("reprojection", || screen(&ctx.pool, bufs, w, h));
        // 3. The network input, padded to a multiple of 4.
        {
            let parts: [&[f32]; 5] = [&bufs.pa, &bufs.pb, &bufs.warped[..3 * n], &bufs.albedo, &bufs.normal];
            for (k, p) in parts.iter().enumerate() {
                pad_into(p, 3, w, h, &mut bufs.input[3 * k * wp * hp..3 * (k + 1) * wp * hp], wp, hp);
            }
        }
        // 4. Forward, filter, loss, backward, Adam: one step.
        let clock = Mutex::new(StepClock { fill_end: vec![None; strips.len()], ..StepClock::default() });
        let scale = 1.0 / (3 * n) as f32;
        let b: &Bufs = bufs;
        let fill = |i: usize, wss: &mut [crate::nn::Workspace]| -> Result<()> {
            let (c0, _, _) = strips[i];
            let dst = wss[0].input_mut();
            for ch in 0..CIN {
                let src = &b.input[(ch * hp + c0) * wp..(ch * hp + c0 + crop_h) * wp];
                dst[ch * crop_h * wp..(ch + 1) * crop_h * wp].copy_from_slice(src);
            }
            clock.lock().expect("clock").fill_end[i] = Some(Instant::now());
            Ok(())
        };
        let head = |i: usize, _nets: &crate::nn::Nets<'_>, wss: &mut [crate::nn::Workspace]| -> Result<f32> {
            let t_head = Instant::now();
            {
                let mut c = clock.lock().expect("clock");
                if let Some(e) = c.fill_end[i] {
                    c.forward += t_head - e;
                }
            }
            let (c0, t0, t1) = strips[i];
            let rows = t1 - t0;
            let (out6, g6, aux) = wss[0].head_parts();
            if aux.is_empty() {
                aux.push(vec![0.0; 9 * w * crop_h]);
                aux.push(vec![0.0; 6 * w * crop_h]);
                aux.push(vec![0.0; regress::filter_scratch_len(w)]);
            }
            let [outs, grads, scratch] = &mut aux[..] else {
                return Err(HostError::Kernel("cross: crop buffers".into()));
            };
            let inp = FilterInputs {
                pilot_a: View::new(&b.pa, 3, w, h)?,
                pilot_b: View::new(&b.pb, 3, w, h)?,
                albedo: View::new(&b.albedo, 3, w, h)?,
                normal: View::new(&b.normal, 3, w, h)?,
                prev: View::new(&b.warped[..3 * n], 3, w, h)?,
                valid: View::new(&b.valid, 1, w, h)?,
            };
            let off = (t0 - c0) * wp;
            let pv = View::with_strides(&out6[off..], regress::PARAMS, w, rows, wp, wp * crop_h)?;
            let mut ov = ViewMut::new(&mut outs[..9 * w * rows], 9, w, rows)?;
            regress::filter_rows(isa, &inp, &pv, &mut ov, t0, scratch)?;
            // The loss and its gradient by outputs A and B.
            let mut loss = 0.0f64;
            let g = &mut grads[..6 * w * rows];
            let rel = |o: f32, y: f32| {
                let d = 1.0 / (y * y + REL_EPS);
                ((o - y) * (o - y) * d, 2.0 * (o - y) * d)
            };
            for r in 0..rows {
                let y = t0 + r;
                for x in 0..w {
                    let (pi, oi) = (y * w + x, r * w + x);
                    for c in 0..3 {
                        let (oa, ob) = (outs[c * w * rows + oi], outs[(3 + c) * w * rows + oi]);
                        let (la, ga) = rel(oa, b.pb[c * n + pi]);
                        let (lb, gb) = rel(ob, b.pa[c * n + pi]);
                        let (ta, gta) = rel(oa, b.warped[(6 + c) * n + pi]);
                        let (tb, gtb) = rel(ob, b.warped[(3 + c) * n + pi]);
                        loss += 0.25 * (la + lb + ta + tb) as f64;
                        g[c * w * rows + oi] = 0.25 * (ga + gta) * scale;
                        g[(3 + c) * w * rows + oi] = 0.25 * (gb + gtb) * scale;
                    }
                }
            }
            g6.fill(0.0);
            let gv = View::new(g, 6, w, rows)?;
            let mut dv = ViewMut::with_strides(&mut g6[off..], regress::PARAMS, w, rows, wp, wp * crop_h)?;
            regress::filter_grad_rows(isa, &inp, &pv, &gv, &mut dv, t0, scratch)?;
            clock.lock().expect("clock").head += t_head.elapsed();
            Ok((loss * scale as f64) as f32)
        };
        let t_step = Instant::now();
        let stats = trainer.step(&ctx.pool, isa, &fill, &head, true)?;
        let wall = t_step.elapsed();
        // Apportion the step's wall time by the CPU time of its parts.
        {
            let c = clock.lock().expect("clock");
            let threads = ctx.pool.threads().min(strips.len()).max(1) as u32;
            let (fwd, head) = (c.forward / threads, c.head / threads);
            let fwd = fwd.min(wall);
            let head = head.min(wall - fwd);
            t.add("inference (U-Net forward)", fwd);
            t.add("filter (forward, loss, backward)", head);
            t.add("backpropagation + Adam", wall - fwd - head);
        }
        self.last_loss = stats.loss * strips.len() as f32;
        self.frames += 1;
        // Gather the crops' outputs.
        let wss = trainer.workspaces();
        for (i, &(_, t0, t1)) in strips.iter().enumerate() {
            let rows = t1 - t0;
            let o = &wss[i][0].aux[0];
            for c in 0..9 {
                bufs.out[c * n + t0 * w..c * n + t1 * w].copy_from_slice(&o[c * w * rows..(c + 1) * w * rows]);
            }
        }
        // A regression extrapolates: the output is held under the brightest
        // input sample within the screening window (per channel, in log1p
        // colour), so that a light or a firefly is never brightened.
        for c in 0..3 {
            let (src, rest) = bufs.window.split_at_mut(n);
            let (tmin, rest) = rest.split_at_mut(n);
            let (tmax, rest) = rest.split_at_mut(n);
            let (mn, mx) = rest.split_at_mut(n);
            for ((s, &a), &b) in src.iter_mut().zip(&bufs.a[c * n..(c + 1) * n]).zip(&bufs.b[c * n..(c + 1) * n]) {
                *s = a.max(b);
            }
            window_range(&ctx.pool, src, w, h, SCREEN_WINDOW / 2, tmin, tmax, mn, mx);
            for (o, &m) in bufs.out[(6 + c) * n..(7 + c) * n].iter_mut().zip(mx.iter()) {
                *o = o.min(m);
            }
        }
        // Keep what the next frame reprojects.
        let mut colors = vec![0.0f32; 9 * n];
        colors[..3 * n].copy_from_slice(&bufs.out[6 * n..9 * n]);
        colors[3 * n..6 * n].copy_from_slice(&bufs.pa);
        colors[6 * n..].copy_from_slice(&bufs.pb);
        self.prev = Some(Prev {
            colors,
            normal: f.get(Buffer::Normal).map(|v| v.to_vec()),
            position: f.get(Buffer::Position).map(|v| v.to_vec()),
        });
        let mut result: Vec<f32> = bufs.out[6 * n..9 * n].iter().map(|&v| v.exp_m1().max(0.0)).collect();
        let (a, b) = (f.get(Buffer::Color).expect("colour"), f.get(Buffer::ColorB).expect("checked"));
        let t_blend = Instant::now();
        blend_by_error(&mut result, a, b, (&bufs.out[6 * n..9 * n], &bufs.a, &bufs.b), w, h, &mut bufs.window[..2 * n]);
        t.add("fallback to the input (error estimate)", t_blend.elapsed());
        // Then the learned filters' fallback, with the pair's mean as the
        // input and its noise from the pair: its window holds the pixels of
        // the centre's albedo and level only, in exposure-normalised colour,
        // which the plain 13x13 window above does not (an edge blurred by a
        // network that has had one or two steps returns to the input there).
        if self.fallback {
            let mean = &mut bufs.window[..3 * n];
            for ((m, &x), &y) in mean.iter_mut().zip(a).zip(b) {
                *m = 0.5 * (x + y);
            }
            let e = crate::methods::features::exposure(mean, w, h);
            let pair = crate::io::frame::Pair { b, colour_is_mean: true };
            let albedo = &bufs.albedo;
            t.time("fallback", || {
                crate::methods::fallback::to_input(ctx, &mut result, mean, Some(pair), albedo, w, h, e)
            })?;
        }
        if let Some(path) = self.save_state.clone() {
            self.save(&path)?;
        }
        Ok(result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bufs(w: usize, h: usize) -> Bufs {
        let n = w * h;
        let z = |c: usize| vec![0.0f32; c * n];
        Bufs {
            a: z(3),
            b: z(3),
            var_a: z(1),
            var_b: z(1),
            pa: z(3),
            pb: z(3),
            warped: z(9),
            valid: z(1),
            zeros: z(9),
            big: z(1),
            hist: z(1),
            row_ok: z(1),
            window: z(5),
            keep: vec![0; n],
            albedo: z(3),
            normal: z(3),
            input: Vec::new(),
            out: z(9),
        }
    }

    /// The error-based blend against an f64 evaluation of its formula on
    /// frames whose window means are known (uniform halves): where the
    /// pair disagrees far more than the output departs from their mean,
    /// the output stays; where the pair agrees and the output is off, the
    /// input mean comes back; in between, the weight of the formula.
    #[test]
    fn blend_by_error_follows_the_estimated_errors() {
        let (w, h) = (40, 30);
        let n = w * h;
        for (da, off) in [(0.8f64, 0.05f64), (0.01, 0.5), (0.2, 0.3), (0.0, 0.0)] {
            // A = 1 + da, B = 1 - da, the output 1 + off, everywhere.
            let a = vec![(1.0 + da) as f32; 3 * n];
            let b = vec![(1.0 - da) as f32; 3 * n];
            let mut o = vec![(1.0 + off) as f32; 3 * n];
            let l = |v: &[f32]| v.iter().map(|x| x.ln_1p()).collect::<Vec<f32>>();
            let (lo, la, lb) = (l(&o), l(&a), l(&b));
            let mut tmp = vec![0.0f32; 2 * n];
            blend_by_error(&mut o, &a, &b, (&lo, &la, &lb), w, h, &mut tmp);
            let (x, y, z) = ((2.0 + da).ln(), (2.0 - da).ln(), (2.0 + off).ln());
            let v = 3.0 * 0.25 * (x - y) * (x - y);
            let e = 3.0 * (z - 0.5 * (x + y)).powi(2);
            let bias2 = (e - 2.0 * v).max(0.0);
            let k = if v + bias2 > 0.0 { v / (v + bias2) } else { 1.0 };
            let want = 1.0 + k * off;
            for &got in &o {
                assert!((got as f64 - want).abs() < 1e-5, "da {da} off {off}: {got} vs {want} (k {k})");
            }
            if da == 0.8 {
                assert!(k > 0.99, "noisy pair: k {k}");
            }
            if da == 0.01 {
                assert!(k < 0.01, "quiet pair: k {k}");
            }
        }
    }

    /// The window range against a direct minimum and maximum over the
    /// clipped 7x7 square, at sizes smaller and larger than the window.
    #[test]
    fn window_range_is_the_clipped_7x7_min_and_max() {
        for (w, h) in [(1, 1), (3, 9), (11, 8)] {
            let n = w * h;
            let src: Vec<f32> = (0..n).map(|i| ((i * 37 + 11) % 23) as f32 - 7.0).collect();
            let (mut t1, mut t2, mut mn, mut mx) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            window_range(&Pool::new(2).unwrap(), &src, w, h, 3, &mut t1, &mut t2, &mut mn, &mut mx);
            for y in 0..h {
                for x in 0..w {
                    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                    for yy in y.saturating_sub(3)..(y + 4).min(h) {
                        for xx in x.saturating_sub(3)..(x + 4).min(w) {
                            lo = lo.min(src[yy * w + xx]);
                            hi = hi.max(src[yy * w + xx]);
                        }
                    }
                    assert_eq!((mn[y * w + x], mx[y * w + x]), (lo, hi), "{w}x{h} at ({x}, {y})");
                }
            }
        }
    }

    /// Screening keeps a reprojected value strictly inside the current
    /// range, replaces one outside it (or on its edge) by the current value,
    /// clears `valid` only when the output is replaced, and replaces all
    /// three where the reprojection failed.
    #[test]
    fn screening_keeps_history_inside_the_current_range_only() {
        let (w, h) = (9, 9);
        let n = w * h;
        let mut b = bufs(w, h);
        // Current pilots vary over [0, 2) (A) and [1, 3) (B) across the image.
        for c in 0..3 {
            for i in 0..n {
                b.pa[c * n + i] = (i % 7) as f32 * 0.3;
                b.pb[c * n + i] = 1.0 + (i % 5) as f32 * 0.4;
            }
        }
        b.valid.fill(1.0);
        let centre = 4 * w + 4;
        let (inside_out, inside_a, inside_b) = (1.2f32, 0.5f32, 1.5f32);
        for c in 0..3 {
            for i in 0..n {
                b.warped[c * n + i] = inside_out;
                b.warped[(3 + c) * n + i] = inside_a;
                b.warped[(6 + c) * n + i] = inside_b;
            }
        }
        // At the centre: the output far above every current value, pilot A
        // on its range's minimum (not strictly inside), pilot B inside.
        b.warped[2 * n + centre] = 50.0;
        b.warped[3 * n + centre] = 0.0;
        // A pixel whose reprojection failed.
        let failed = 0;
        b.valid[failed] = 0.0;
        screen(&Pool::new(2).unwrap(), &mut b, w, h);
        for i in 0..n {
            let mean = |c: usize| 0.5 * (b.pa[c * n + i] + b.pb[c * n + i]);
            if i == failed {
                assert_eq!(b.valid[i], 0.0);
                for c in 0..3 {
                    assert_eq!(b.warped[c * n + i], mean(c));
                    assert_eq!(b.warped[(3 + c) * n + i], b.pa[c * n + i]);
                    assert_eq!(b.warped[(6 + c) * n + i], b.pb[c * n + i]);
                }
            } else if i == centre {
                assert_eq!(b.valid[i], 0.0, "the output was replaced");
                for c in 0..3 {
                    assert_eq!(b.warped[c * n + i], mean(c));
                    assert_eq!(b.warped[(3 + c) * n + i], b.pa[c * n + i], "on the edge is outside");
                    assert_eq!(b.warped[(6 + c) * n + i], inside_b);
                }
            } else {
                assert_eq!(b.valid[i], 1.0, "pixel {i}");
                for c in 0..3 {
                    assert_eq!(b.warped[c * n + i], inside_out, "pixel {i}");
                    assert_eq!(b.warped[(3 + c) * n + i], inside_a, "pixel {i}");
                    assert_eq!(b.warped[(6 + c) * n + i], inside_b, "pixel {i}");
                }
            }
        }
    }
}

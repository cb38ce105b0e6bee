//! Weight-sharing kernel prediction (WSKP; Fan et al. 2021): an
//! ImportanceNet predicts, per pixel, one importance logit per window size
//! (3, 5, ..., 13) and six fusion logits; the fused importance filter of the
//! core turns them into the denoised image without ever building a kernel.
//!
//! Inputs (10 channels, as the authors' code, with the HDR colour through
//! [`crate::methods::features`]' exposure and transfer curve instead of a
//! clamp): the temporally accumulated radiance `t` (3), albedo (3), normal
//! (3), depth normalised over the frame (1). The filter runs on the
//! demodulated irradiance `c = t / d` and remodulates with `d`, the
//! demodulation factor of [`crate::methods::features`] (see [`inputs`]):
//! `out(p) = d(p) sum_k alpha_k(p) [sum_q e_k(q) c(q)] / [sum_q e_k(q)]`.
//!
//! ImportanceNet: 6 layers (the authors': 10 -> 14, four 14 -> 14, 14 -> 12)
//! or 3 (10 -> 14 -> 14 -> 12), each a RepVGG block (5x5 + 3x3 + 1x1, and
//! the identity on the 14 -> 14 layers), LeakyReLU(0.1) after every layer
//! but the last.

use mcdenoise_core::conv::Activation;
use mcdenoise_core::softmax::{self, grad as sgrad, FusedInputs, WindowPath};
use mcdenoise_core::{View, ViewMut, F32};

use crate::error::{HostError, Result};
use crate::io::frame::{Buffer, Frame};
use crate::methods::{features, Ctx, Denoiser, Plan, TemporalAccumulation, Timings};
use crate::nn::infer::Inference;
use crate::nn::loss::Objective;
use crate::nn::weights::File;
use crate::nn::{Conv, Layer, Net, NetDesc, Workspace};
use crate::runtime::precision::{HostPrecision, Kind, Planes};

/// The window sizes, one importance map each.
pub const SIZES: [usize; 6] = [3, 5, 7, 9, 11, 13];
/// Input channels.
pub const CIN: usize = 10;

/// The window sizes a network predicts for: the paper's six, fused, or any
/// subset of them (one size alone: no fusion logits; the paper's Fig. 9
/// compares those with the fusion), and optionally size 1, the identity
/// (see [`KEEP_BIAS`]). A bit per size, so it is `Copy`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sizes(u16);

/// The bit of size 1 (the identity window) in [`Sizes`].
const KEEP: u16 = 1 << 6;

/// The offset of the identity's logit: its weight is
/// `beta = sigmoid(logit + KEEP_BIAS)`, so a network whose last layer gives
/// logits near 0 (as it starts) keeps about 2 % of its input.
///
/// Size 1 is this project's addition to WSKP. A pixel's importance is
/// shared by every window that holds it, so no two neighbours can both keep
/// their own value, and the smallest window is 3x3: the paper's network
/// cannot leave a clean (e.g. 64-spp) input alone and blurs its edges. With
/// size 1 the output is `(1 - beta) fused + beta c` per pixel, `c` the
/// filter's input at the pixel: fusing a 1x1 window (whose normalised
/// kernel is the identity whatever its importance) with a weight of its own.
/// Measured, it does not earn its place yet: a WSKP-3 trained with it
/// (`--sizes 1,3,5,7,9,11,13`, 20k steps) validates level with one without
/// (31.85 against 31.86 dB) and keeps about 5 % of its input everywhere, at
/// 4 spp as at 64: it does not learn to tell a clean input from a noisy one
/// (docs/training.md). The bundled weights do not use it; the learned
/// methods keep a clean input by the rule of [`crate::methods::fallback`].
pub const KEEP_BIAS: f32 = -4.0;

impl Sizes {
    /// The six sizes of the paper, fused.
    pub const ALL: Sizes = Sizes(0b11_1111);
    /// The six sizes and the identity (size 1).
    pub const ALL_AND_INPUT: Sizes = Sizes(0b11_1111 | KEEP);
    /// Parses `"1,3,5,7,9,11,13"`, `"3,5,7,9,11,13"` or `"7"` (sizes from 1
    /// and [`SIZES`], each once, at least one of [`SIZES`]).
    pub fn parse(s: &str) -> std::result::Result<Sizes, String> {
        let mut bits = 0u16;
        for part in s.split(',') {
            let k: usize =
                part.trim().parse().map_err(|_| format!("expected sizes from 1,3,5,7,9,11,13, got '{s}'"))?;
            let bit = if k == 1 {
                KEEP
            } else {
                let i = SIZES
                    .iter()
                    .position(|&v| v == k)
                    .ok_or_else(|| format!("expected sizes from 1,3,5,7,9,11,13, got {k} in '{s}'"))?;
                1 << i
            };
            if bits & bit != 0 {
                return Err(format!("size {k} given twice in '{s}'"));
            }
            bits |= bit;
        }
        if bits & !KEEP == 0 {
            return Err(format!("expected at least one window size from 3,5,7,9,11,13 in '{s}'"));
        }
        Ok(Sizes(bits))
    }
    /// The window sizes (3..13), ascending, in the first [`Sizes::count`]
    /// entries.
    pub fn array(self) -> [usize; 6] {
        let mut a = [0usize; 6];
        let mut m = 0;
        for (i, &k) in SIZES.iter().enumerate() {
            if self.0 & (1 << i) != 0 {
                a[m] = k;
                m += 1;
            }
        }
        a
    }
    /// How many window sizes (3..13; size 1 is not one).
    pub fn count(self) -> usize {
        (self.0 & !KEEP).count_ones() as usize
    }
    /// Whether size 1, the identity, is fused in (its logit is the
    /// network's last output plane).
    pub fn keep(self) -> bool {
        self.0 & KEEP != 0
    }
    /// The network's output planes: an importance logit per window size, a
    /// fusion logit per window size when there is more than one, and the
    /// identity's logit with size 1.
    pub fn outputs(self) -> usize {
        let m = self.count();
        let windows = if m > 1 { 2 * m } else { m };
        windows + usize::from(self.keep())
    }
    /// `"1,3,5,7,9,11,13"`: the form [`Sizes::parse`] reads (and the
    /// weights files' `sizes` metadata).
    pub fn name(self) -> String {
        let a = self.array();
        let mut v: Vec<String> = a[..self.count()].iter().map(|k| k.to_string()).collect();
        if self.keep() {
            v.insert(0, "1".into());
        }
        v.join(",")
    }
    /// The sizes of a weights file (its `sizes` metadata; files without it
    /// are the paper's six).
    pub fn of_file(file: &File) -> Result<Sizes> {
        match file.meta("sizes") {
            None => Ok(Sizes::ALL),
            Some(v) => Sizes::parse(&v).map_err(|e| HostError::Usage(format!("wskp weights: sizes metadata: {e}"))),
        }
    }
}

/// `sigmoid(l + KEEP_BIAS)`: the identity's weight from its logit.
#[inline]
pub fn keep_weight(l: f32) -> f32 {
    1.0 / (1.0 + (-(l + KEEP_BIAS)).exp())
}

/// The ImportanceNet with `layers` layers (3 or 6) for the six sizes.
pub fn net(layers: usize) -> Result<Net> {
    net_for(layers, Sizes::ALL)
}

/// The ImportanceNet with `layers` layers (3 or 6) for `sizes`.
pub fn net_for(layers: usize, sizes: Sizes) -> Result<Net> {
    if layers != 3 && layers != 6 {
        return Err(HostError::Usage(format!("--layers: expected 3 or 6, got {layers}")));
    }
    let block = |cout, act| Layer::Conv(Conv { k: 5, cout, act, repvgg: true, bias: false });
    let leaky = Activation::LeakyRelu(0.1);
    let mut l = vec![block(14, leaky)];
    for _ in 0..layers - 2 {
        l.push(block(14, leaky));
    }
    l.push(block(sizes.outputs(), Activation::Identity));
    Net::new(NetDesc { cin: CIN, layers: l })
}

/// The buffers WSKP reads from a frame, named for errors.
const NEEDS: [Buffer; 3] = [Buffer::Albedo, Buffer::Normal, Buffer::Depth];

/// Checks a frame has the network's inputs.
pub fn check_inputs(f: &Frame) -> Result<()> {
    for b in NEEDS {
        f.require(b, "wskp (the ImportanceNet's inputs)")?;
    }
    Ok(())
}

/// The network input `x` (10 planes), the demodulated irradiance `c` (3,
/// the part the filter averages), the demodulation factor `d` (3; the
/// filter's output is remodulated by it) and the excess `ex` (3, added back
/// at its pixel) of a frame from its accumulated radiance `t` (3 planes),
/// by the rules of [`crate::methods::features`]; returns the frame's
/// exposure. The output is `d (filter(c) + ex)`.
pub fn inputs(
    pool: &crate::runtime::par::Pool,
    f: &Frame,
    t: &[f32],
    x: &mut [f32],
    c: &mut [f32],
    d: &mut [f32],
    ex: &mut [f32],
) -> Result<f32> {
    check_inputs(f)?;
    let (w, h) = (f.width, f.height);
    let a = f.require(Buffer::Albedo, "wskp")?;
    features::demodulation(pool, a, w, h, d);
    let e = features::exposure(f.require(Buffer::Color, "wskp")?, w, h);
    features::network_inputs(pool, f, "wskp", e, &[t], d, x, &mut [&mut *c])?;
    features::clamp_fireflies(pool, c, t, a, w, h);
    let geometry = (f.require(Buffer::Normal, "wskp")?, f.require(Buffer::Depth, "wskp")?);
    features::split_excess(pool, c, a, Some(geometry), w, h, e, ex);
    Ok(e)
}

/// Planes of a training crop's data: `c`, `d`, the reference (3 each),
/// the frame's exposure (1, constant) and the excess (3).
pub const DATA_PLANES: usize = 13;

/// The per-crop buffers of training: the data ([`DATA_PLANES`]), the
/// filter's output, its gradient, the radiance gradient, and the two
/// scratch areas.
pub fn crop_buffers(ws: &mut Workspace) {
    if ws.aux.is_empty() {
        let (w, h) = ws.size();
        let n = w * h;
        ws.aux = vec![
            vec![0.0; DATA_PLANES * n],
            vec![0.0; 3 * n],
            vec![0.0; 3 * n],
            vec![0.0; 3 * n],
            vec![0.0; softmax::fused_scratch_len::<F32>(WindowPath::Separable, &SIZES, 3, w)],
            vec![0.0; sgrad::fused_grad_scratch_len(6, 3, w)],
        ];
    }
}

/// Weight of the penalty on logits beyond the bound ([`logit_penalty`]).
pub const LOGIT_PENALTY: f32 = 0.01;

/// The penalty `LOGIT_PENALTY * mean(max(0, |l| - bound)^2)` over
/// `logits`, its gradient times `scale` added to `grad`; 0 and nothing
/// added when `bound` is 0. A softmax does not change when its logits
/// shift together, so this costs the model nothing it needs while the
/// logits stay within `±bound`; it stops the ImportanceNet from spreading
/// them without limit (a weight `e^-60` is already 0 in f32), which would
/// leave the fused filter's windows more nats apart than its box sums'
/// passes cover and send them down the window-by-window path.
pub fn logit_penalty(logits: &[f32], grad: &mut [f32], bound: f32, scale: f32) -> f32 {
    if bound <= 0.0 || logits.is_empty() {
        return 0.0;
    }
    let k = LOGIT_PENALTY / logits.len() as f32;
    let mut total = 0.0f64;
    for (g, &l) in grad.iter_mut().zip(logits) {
        let over = l.abs() - bound;
        if over > 0.0 {
            total += (over * over) as f64;
            *g += scale * k * 2.0 * over * l.signum();
        }
    }
    (total * k as f64) as f32
}

/// The training head of a crop: the fused filter on the network's output,
/// the loss against the reference, and the output's gradient (of the batch
/// mean: `scale` = 1 / batch). With `bound` > 0 the importance and fusion
/// logits beyond `±bound` are penalised ([`logit_penalty`]; its share is
/// in the loss returned).
pub fn head(
    ws: &mut Workspace,
    sizes: Sizes,
    loss: impl Into<Objective>,
    scale: f32,
    bound: f32,
    isa: mcdenoise_core::Isa,
) -> Result<f32> {
    let (w, h) = ws.size();
    let n = w * h;
    let (logits, dy, aux) = ws.head_parts();
    let [data, out, g, drad, fs, gs] = &mut aux[..] else {
        return Err(HostError::Usage("wskp: crop buffers missing".into()));
    };
    let (arr, m) = (sizes.array(), sizes.count());
    let imp = View::new(&logits[..m * n], m, w, h)?;
    let fus = if m > 1 { Some(View::new(&logits[m * n..2 * m * n], m, w, h)?) } else { None };
    let inp = FusedInputs {
        sizes: &arr[..m],
        importance: imp,
        fusion: fus,
        albedo: Some(View::new(&data[3 * n..6 * n], 3, w, h)?),
        radiance: View::new(&data[..3 * n], 3, w, h)?,
    };
    softmax::fused_filter::<F32>(isa, WindowPath::Separable, &inp, &mut ViewMut::new(out, 3, w, h)?, 0, fs)?;
    // Size 1: `out = F + beta (d c - F)`, the difference kept in `drad`
    // until the loss's gradient is known.
    let kl = sizes.outputs() - 1;
    if sizes.keep() {
        let kept = &logits[kl * n..(kl + 1) * n];
        for ch in 0..3 {
            for (p, &l) in kept.iter().enumerate() {
                let k = ch * n + p;
                let diff = data[3 * n + k] * data[k] - out[k];
                drad[k] = diff;
                out[k] += keep_weight(l) * diff;
            }
        }
    }
    // The excess goes back at its pixel (a constant of the loss).
    for k in 0..3 * n {
        out[k] += data[3 * n + k] * data[10 * n + k];
    }
    let l = loss.into().eval(out, &data[6 * n..9 * n], g, w, h, scale, data[9 * n]);
    let (di, rest) = dy.split_at_mut(m * n);
    if sizes.keep() {
        // d/dlogit = sum_ch G (d c - F) beta (1 - beta); the filter's output
        // gradient is scaled by 1 - beta; the radiance's direct share,
        // beta d G, waits in `out` (no longer needed).
        let kept = &logits[kl * n..(kl + 1) * n];
        let dk = &mut rest[kl * n - m * n..(kl + 1) * n - m * n];
        for (p, &lg) in kept.iter().enumerate() {
            let b = keep_weight(lg);
            let mut s = 0.0f32;
            for ch in 0..3 {
                let k = ch * n + p;
                s += g[k] * drad[k];
                out[k] = b * data[3 * n + k] * g[k];
                g[k] *= 1.0 - b;
            }
            dk[p] = s * b * (1.0 - b);
        }
    }
    let gv = View::new(g, 3, w, h)?;
    let mut dfv = if m > 1 { Some(ViewMut::new(&mut rest[..m * n], m, w, h)?) } else { None };
    let grads = sgrad::FusedGrads {
        importance: &mut ViewMut::new(di, m, w, h)?,
        fusion: dfv.as_mut(),
        radiance: &mut ViewMut::new(drad, 3, w, h)?,
    };
    sgrad::fused_filter_grad(isa, &inp, &gv, grads, 0, gs)?;
    let nl = if m > 1 { 2 * m * n } else { n };
    let l = l + logit_penalty(&logits[..nl], &mut dy[..nl], bound, scale);
    if sizes.keep() {
        for (r, &o) in drad.iter_mut().zip(out.iter()) {
            *r += o;
        }
    }
    Ok(l)
}

/// The `wskp` method: temporal accumulation, the ImportanceNet and the fused
/// filter, every stage in precision `P`.
pub struct Wskp<P: HostPrecision> {
    plan: Plan,
    sizes: Sizes,
    net: Net,
    params: Vec<f32>,
    ta: TemporalAccumulation<P>,
    infer: Option<Inference<P>>,
    bufs: Option<Bufs>,
    /// The network input, radiance and albedo in the precision (not f32).
    stored: Option<Stored<P::Store>>,
    /// With the fallback to the input ([`crate::methods::fallback`]).
    fallback: bool,
    /// The network emulated in 8 bits ([`Inference::emulate_int8`]).
    int8: bool,
    /// With the wide pass ([`crate::methods::wide`]).
    wide: bool,
}

/// The network input, radiance and albedo stored in a precision other than f32.
type Stored<T> = (Vec<T>, Vec<T>, Vec<T>);

/// The f32 buffers a frame needs, kept from frame to frame.
struct Bufs {
    ta: Vec<f32>,
    x: Vec<f32>,
    c: Vec<f32>,
    alb: Vec<f32>,
    ex: Vec<f32>,
    /// The identity's weight per pixel (size 1; empty without it).
    keep: Vec<f32>,
    /// The history counts in f32 (for the wide pass).
    counts: Vec<f32>,
    /// The wide pass's buffers.
    wide: crate::methods::wide::Buffers,
}

impl Bufs {
    fn new(n: usize) -> Bufs {
        Bufs {
            ta: vec![0.0; 3 * n],
            x: vec![0.0; 10 * n],
            c: vec![0.0; 3 * n],
            alb: vec![0.0; 3 * n],
            ex: vec![0.0; 3 * n],
            keep: Vec::new(),
            counts: vec![0.0; n],
            wide: Default::default(),
        }
    }
}

impl<P: HostPrecision> Wskp<P> {
    /// For a sequence starting with `first`, with the weights in `file`.
    /// The window sizes come from the file ([`Sizes::of_file`]).
    pub fn new(first: &Frame, file: &File, layers: usize) -> Result<Self> {
        let sizes = Sizes::of_file(file)?;
        let net = net_for(layers, sizes)?;
        file.expect_meta("layers", &layers.to_string())?;
        file.expect_transform(features::TRANSFORM)?;
        let params = file.params(&net, "wskp", &["adam.m", "adam.v"])?;
        Self::from_params(first, net, params, layers, sizes)?.with_ta_clamp(crate::methods::basic::ta_clamp_for(file)?)
    }

    crate::methods::ta_builders!();

    /// Memory per frame (see [`crate::runtime::memory`]): the accumulation, the f32
    /// buffers kept (and their copies in another storage), the network's
    /// tensors (kept for the next frame), the output. The first frame in
    /// fixed point runs the network in f32 once for the formats, every
    /// tensor kept and each decoded in turn;
    /// every later frame runs the accumulation's step on top of what the
    /// first one kept. `scales`: the history rejection's.
    pub fn footprint(
        info: &crate::io::frame::FrameInfo,
        layers: usize,
        threads: usize,
        wide: bool,
        scales: usize,
    ) -> crate::runtime::memory::Footprint {
        use crate::runtime::precision::{store_bytes, store_is};
        let s = store_bytes::<P>();
        let f32s = store_is::<P, f32>();
        // (With the wide pass, the history counts in f32 too.)
        let bufs = 4 * (3 + 10 + 3 + 3 + 3 + 1 + u64::from(wide));
        let stored = if f32s { 0 } else { 16 * s };
        // Another layer count is refused when the method is built.
        let network = net_for(if layers == 3 { 3 } else { 6 }, Sizes::ALL_AND_INPUT).expect("3 or 6 layers");
        let net = crate::nn::infer::held_bytes_per_pixel(&network, s);
        let wide_kept = if wide { crate::methods::wide::KEPT_BYTES } else { 0 };
        let output = |l: &mut crate::runtime::memory::Ledger, wide_first: u64| {
            l.alloc(12);
            if !f32s {
                l.temp(3 * s);
            }
            // The input's noise, the wide pass (its buffers kept, allocated
            // on the first frame), then the fallback to the input.
            crate::methods::wide::ledger(l, wide, wide_first);
        };
        let mut first = crate::runtime::memory::Ledger::default();
        let history = TemporalAccumulation::<P>::step_ledger(info, &mut first, scales);
        first.alloc(bufs);
        if P::FIXED_POINT {
            first.temp(crate::nn::infer::ranges_bytes_per_pixel(&network));
        }
        first.alloc(stored + net);
        output(&mut first, wide_kept);
        let mut later = crate::runtime::memory::Ledger::default();
        later.alloc(bufs + stored + net + wide_kept);
        TemporalAccumulation::<P>::step_ledger(info, &mut later, scales);
        output(&mut later, 0);
        let w = info.width;
        let sl = softmax::fused_scratch_len::<P>(WindowPath::Separable, &SIZES, 3, w)
            .max(mcdenoise_core::conv::conv2d_scratch_len::<P>(5, 14, 14, w));
        crate::runtime::memory::Footprint {
            kept: history + bufs + stored + net + wide_kept,
            peak: first.peak().max(later.peak()),
            scratch: 4 * threads as u64 * sl as u64,
        }
    }

    /// For a sequence starting with `first`, with parameters in hand.
    pub fn from_params(first: &Frame, net: Net, params: Vec<f32>, layers: usize, sizes: Sizes) -> Result<Self> {
        check_inputs(first)?;
        let ta = TemporalAccumulation::<P>::new(first, false)?
            .with_reject(crate::methods::basic::LEARNED_TA_REJECT)?
            .with_reject_scales(crate::methods::basic::LEARNED_TA_REJECT_SCALES)?;
        let mut plan = ta.plan().clone();
        if first.colour_is_pair_mean {
            plan.built.insert(0, features::PAIR_CLAMP_STAGE);
        }
        plan.built.push(if layers == 6 { "ImportanceNet (6 layers)" } else { "ImportanceNet (3 layers)" });
        plan.built.push(match sizes {
            Sizes::ALL => "fused importance filter (sizes 3..13)",
            Sizes::ALL_AND_INPUT => "fused importance filter (sizes 3..13, and 1: the input kept by a learned weight)",
            s if s.count() == 1 => "importance filter (one window size, the weights' sizes metadata)",
            _ => "fused importance filter (the weights' sizes metadata)",
        });
        crate::methods::wide::plan(&mut plan, true);
        crate::methods::fallback::plan(&mut plan, true, first.has(crate::io::frame::Buffer::ColorB));
        Ok(Wskp {
            plan,
            sizes,
            net,
            params,
            ta,
            infer: None,
            bufs: None,
            stored: None,
            fallback: true,
            int8: false,
            wide: true,
        })
    }

    /// Emulates an 8-bit ImportanceNet ([`Inference::emulate_int8`]): its
    /// weights and tensors rounded to `i8`/`u8`, ranges from the first frame.
    /// Float precisions only: it measures what 8 bits cost.
    pub fn with_int8(mut self, on: bool) -> Result<Self> {
        if on && P::FIXED_POINT {
            return Err(HostError::Usage("--emulate-int8 runs in a float precision (f32, f16)".into()));
        }
        self.int8 = on;
        Ok(self)
    }

    /// With or without the wide pass ([`crate::methods::wide`]; on unless
    /// told).
    pub fn with_wide(mut self, on: bool) -> Self {
        self.wide = on;
        crate::methods::wide::plan(&mut self.plan, on);
        self
    }

    /// With or without the fallback to the input
    /// ([`crate::methods::fallback`]; on unless told).
    pub fn with_fallback(mut self, on: bool) -> Self {
        self.fallback = on;
        crate::methods::fallback::switch(&mut self.plan, on);
        self
    }
}

impl<P: HostPrecision> Denoiser for Wskp<P> {
    fn name(&self) -> &'static str {
        "wskp"
    }
    fn plan(&self) -> &Plan {
        &self.plan
    }
    fn denoise(&mut self, f: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        check_inputs(f)?;
        let (w, h) = (f.width, f.height);
        let n = w * h;
        let isa = ctx.isa;
        let (color, counts) = self.ta.step(f, ctx, t)?;
        let bufs = self.bufs.get_or_insert_with(|| Bufs::new(n));
        if bufs.x.len() != 10 * n {
            *bufs = Bufs::new(n);
        }
        if self.wide {
            t.time("decode", || P::decode(&counts.data, &mut bufs.counts, counts.frac));
        }
        // The accumulated colour in f32: borrowed when that is the storage.
        let ta: &[f32] = match P::store_as_f32(&color.data) {
            Some(v) => v,
            None => {
                t.time("decode", || {
                    crate::methods::basic::TemporalAccumulation::<P>::decode_color(&ctx.pool, color, f, &mut bufs.ta)
                });
                &bufs.ta
            }
        };
        let exposure = t.time("network inputs", || {
            inputs(&ctx.pool, f, ta, &mut bufs.x, &mut bufs.c, &mut bufs.alb, &mut bufs.ex)
        })?;
        if self.infer.is_none() {
            // Fixed point: the formats from an f32 run on the first frame.
            let ranges = if P::FIXED_POINT || self.int8 {
                t.time("fixed-point formats (first frame)", || -> Result<_> {
                    let mut f32net = Inference::<F32>::new(&self.net, &self.params, None, None)?;
                    Ok(Some(f32net.ranges(ctx, Planes::<f32>::from_vec(10, w, h, bufs.x.clone()))?))
                })?
            } else {
                None
            };
            let logit_frac = Some(mcdenoise_core::fixed::LOGIT_FRAC);
            let mut inf = Inference::<P>::new(&self.net, &self.params, ranges.as_deref(), logit_frac)?;
            if let (true, Some(r)) = (self.int8, &ranges) {
                inf.emulate_int8(r, true)?;
            }
            self.infer = Some(inf);
        }
        let infer = self.infer.as_mut().expect("just built");
        // The filter's inputs and output in the precision (the f32 buffers
        // themselves in f32), kept from frame to frame.
        let xf = infer.input_frac();
        let (cf, af) = t.time("encode", || {
            let cf = P::choose_frac(&bufs.c, Kind::Image);
            // What the radiance's format cannot hold goes back at its pixel
            // with the excess.
            crate::runtime::precision::keep_saturated::<P>(&mut bufs.c, &mut bufs.ex, cf);
            (cf, P::choose_frac(&bufs.alb, Kind::Plain))
        });
        let (xs, cs, als) = match (P::borrow_f32(&bufs.x), P::borrow_f32(&bufs.c), P::borrow_f32(&bufs.alb)) {
            (Some(x), Some(c), Some(a)) => (x, c, a),
            _ => {
                let st = self.stored.get_or_insert_with(|| (Vec::new(), Vec::new(), Vec::new()));
                t.time("encode", || {
                    for (dst, src, frac) in
                        [(&mut st.0, &bufs.x, xf), (&mut st.1, &bufs.c, cf), (&mut st.2, &bufs.alb, af)]
                    {
                        dst.resize(src.len(), P::Store::default());
                        crate::runtime::precision::encode_par::<P>(&ctx.pool, src, dst, frac);
                    }
                });
                (&st.0[..], &st.1[..], &st.2[..])
            }
        };
        let xv = View::new(xs, 10, w, h)?.with_frac(xf);
        let logits = t.time("ImportanceNet", || infer.run_view(ctx, xv))?;
        let lv = logits.view();
        let (arr, m) = (self.sizes.array(), self.sizes.count());
        if self.sizes.keep() {
            // Size 1: the identity's weight, from its logit (the last plane).
            let kl = self.sizes.outputs() - 1;
            bufs.keep.resize(n, 0.0);
            P::decode(&logits.data[kl * n..(kl + 1) * n], &mut bufs.keep, logits.frac);
            for v in bufs.keep.iter_mut() {
                *v = keep_weight(*v);
            }
        }
        let inp = FusedInputs {
            sizes: &arr[..m],
            importance: lv.channels_range(0, m)?,
            fusion: if m > 1 { Some(lv.channels_range(m, m)?) } else { None },
            albedo: Some(View::new(als, 3, w, h)?.with_frac(af)),
            radiance: View::new(cs, 3, w, h)?.with_frac(cf),
        };
        // The output format: the demodulated input's, rescaled by the albedo's
        // largest value.
        let amax = crate::runtime::precision::max_abs(&bufs.alb);
        let frac = cf - (amax.max(1.0).log2().ceil() as i8);
        let mut out = vec![0.0f32; 3 * n];
        let len = softmax::fused_scratch_len::<P>(WindowPath::Separable, &arr[..m], 3, w);
        match P::borrow_f32(&out).is_some() {
            // f32: the filter writes the returned frame itself.
            true => {
                let mut ov = ViewMut::new(&mut out, 3, w, h)?;
                let store: &mut ViewMut<'_, P::Store> = P::as_store_view_mut(&mut ov).expect("f32 storage");
                t.time("fused filter", || {
                    ctx.pool.bands(store.reborrow(), 48, &mut ctx.scratch, len, |b, y0, s| {
                        softmax::fused_filter::<P>(isa, WindowPath::Separable, &inp, b, y0, s)
                    })
                })?;
            }
            false => {
                let mut o = Planes::<P::Store>::new(3, w, h).with_frac(frac);
                t.time("fused filter", || {
                    ctx.pool.bands(o.view_mut(), 48, &mut ctx.scratch, len, |b, y0, s| {
                        softmax::fused_filter::<P>(isa, WindowPath::Separable, &inp, b, y0, s)
                    })
                })?;
                t.time("decode", || P::decode(&o.data, &mut out, o.frac));
            }
        }
        // Size 1, in f32 in every precision: `(1 - beta) fused + beta d c`.
        if self.sizes.keep() {
            for ch in 0..3 {
                let r = ch * n..(ch + 1) * n;
                for (((o, &d), &c), &b) in
                    out[r.clone()].iter_mut().zip(&bufs.alb[r.clone()]).zip(&bufs.c[r]).zip(&bufs.keep)
                {
                    *o += b * (d * c - *o);
                }
            }
        }
        // The excess the filter left out goes back at its pixel, remodulated.
        for ((o, &d), &e) in out.iter_mut().zip(&bufs.alb).zip(&bufs.ex) {
            *o += d * e;
        }
        let wide = self.wide.then_some((&mut bufs.wide, &bufs.counts[..]));
        crate::methods::wide::finish(ctx, t, &mut out, f, "wskp", wide, self.fallback, exposure)?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The penalty against an f64 oracle of its definition, and its
    /// gradient against central differences of that oracle; 0 within the
    /// bound, and nothing at all with the bound 0.
    #[test]
    fn logit_penalty_matches_its_definition_and_finite_differences() {
        let logits = [-80.0f32, -31.5, -30.0, -2.0, 0.0, 12.0, 29.99, 30.5, 47.0, 200.0];
        let oracle = |v: &[f64], b: f64| -> f64 {
            v.iter().map(|&l| (l.abs() - b).max(0.0).powi(2)).sum::<f64>() * LOGIT_PENALTY as f64 / v.len() as f64
        };
        let v: Vec<f64> = logits.iter().map(|&l| l as f64).collect();
        let mut g = [0.5f32; 10];
        let p = logit_penalty(&logits, &mut g, 30.0, 0.25);
        let want = oracle(&v, 30.0);
        assert!((p as f64 - want).abs() <= 1e-6 * want, "{p} vs {want}");
        for i in 0..logits.len() {
            let h = 1e-3;
            let (mut a, mut b) = (v.clone(), v.clone());
            a[i] += h;
            b[i] -= h;
            let fd = 0.25 * (oracle(&a, 30.0) - oracle(&b, 30.0)) / (2.0 * h);
            // The gradient is added to what was there (0.5).
            let got = g[i] as f64 - 0.5;
            assert!((got - fd).abs() <= 1e-6 + 1e-4 * fd.abs(), "logit {}: {got} vs {fd}", logits[i]);
        }
        for i in 2..7 {
            assert_eq!(g[i], 0.5, "logit {} is within the bound", logits[i]);
        }
        let mut g0 = [0.5f32; 10];
        assert_eq!(logit_penalty(&logits, &mut g0, 0.0, 1.0), 0.0);
        assert_eq!(g0, [0.5f32; 10]);
    }
}

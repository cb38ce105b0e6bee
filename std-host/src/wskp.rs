//! Weight-sharing kernel prediction (WSKP; Fan et al. 2021): an
//! ImportanceNet predicts, per pixel, one importance logit per window size
//! (3, 5, ..., 13) and six fusion logits; the fused importance filter of the
//! core turns them into the denoised image without ever building a kernel.
//!
//! Inputs (10 channels, as the authors' code): `clamp(t, 0, 1)^(1/2.2)` of
//! the temporally accumulated radiance `t` (3), albedo `a` (3), `n * 0.5 +
//! 0.5` of the normal (3), depth normalised to `[0, 1]` over the frame (1).
//! The filter runs on the demodulated irradiance `c = t / (a + EPS)` and
//! remodulates with `a + EPS`:
//! `out(p) = (a(p) + EPS) sum_k alpha_k(p) [sum_q e_k(q) c(q)] / [sum_q e_k(q)]`.
//!
//! ImportanceNet: 6 layers (the authors': 10 -> 14, four 14 -> 14, 14 -> 12)
//! or 3 (10 -> 14 -> 14 -> 12), each a RepVGG block (5x5 + 3x3 + 1x1, and
//! the identity on the 14 -> 14 layers), LeakyReLU(0.1) after every layer
//! but the last. The loss is SMAPE (eps 0.01) on linear HDR.

use mcdenoise_core::conv::Activation;
use mcdenoise_core::softmax::{self, grad as sgrad, FusedInputs, WindowPath};
use mcdenoise_core::{View, ViewMut, F32};

use crate::error::{HostError, Result};
use crate::frame::{Buffer, Frame};
use crate::methods::{Ctx, Denoiser, Plan, TemporalAccumulation, Timings};
use crate::nn::infer::Inference;
use crate::nn::loss::Loss;
use crate::nn::weights::File;
use crate::nn::{Conv, Layer, Net, NetDesc, Workspace};
use crate::precision::{HostPrecision, Kind, Planes};

/// Albedo epsilon of the (de)modulation.
pub const EPS: f32 = 0.01;
/// The window sizes, one importance map each.
pub const SIZES: [usize; 6] = [3, 5, 7, 9, 11, 13];
/// Input channels.
pub const CIN: usize = 10;

/// The ImportanceNet with `layers` layers (3 or 6).
pub fn net(layers: usize) -> Result<Net> {
    if layers != 3 && layers != 6 {
        return Err(HostError::Usage(format!("--layers: expected 3 or 6, got {layers}")));
    }
    let block = |cout, act| Layer::Conv(Conv { k: 5, cout, act, repvgg: true, bias: false });
    let leaky = Activation::LeakyRelu(0.1);
    let mut l = vec![block(14, leaky)];
    for _ in 0..layers - 2 {
        l.push(block(14, leaky));
    }
    l.push(block(12, Activation::Identity));
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

/// The network input, demodulated irradiance and remodulation albedo of a
/// frame from its accumulated radiance `t` (3 planes): `x` (10 planes), `c`
/// (3), `alb` (3, `a + EPS`).
pub fn inputs(f: &Frame, t: &[f32], x: &mut [f32], c: &mut [f32], alb: &mut [f32]) -> Result<()> {
    let n = f.width * f.height;
    let a = f.require(Buffer::Albedo, "wskp")?;
    let nrm = f.require(Buffer::Normal, "wskp")?;
    let d = f.require(Buffer::Depth, "wskp")?;
    for i in 0..3 * n {
        let tv = t[i];
        x[i] = tv.clamp(0.0, 1.0).powf(1.0 / 2.2);
        x[3 * n + i] = a[i];
        x[6 * n + i] = nrm[i] * 0.5 + 0.5;
        alb[i] = a[i] + EPS;
        c[i] = tv / alb[i];
    }
    let (lo, hi) = d.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    let span = hi - lo;
    for i in 0..n {
        x[9 * n + i] = if span > 0.0 { (d[i] - lo) / span } else { 0.0 };
    }
    Ok(())
}

/// The per-crop buffers of training: `[c, alb, ref]` (9 planes), the
/// filter's output, its gradient, the radiance gradient, and the two
/// scratch areas.
pub fn crop_buffers(ws: &mut Workspace) {
    if ws.aux.is_empty() {
        let (w, h) = ws.size();
        let n = w * h;
        ws.aux = vec![
            vec![0.0; 9 * n],
            vec![0.0; 3 * n],
            vec![0.0; 3 * n],
            vec![0.0; 3 * n],
            vec![0.0; softmax::fused_scratch_len::<F32>(WindowPath::Separable, &SIZES, 3, w)],
            vec![0.0; sgrad::fused_grad_scratch_len(6, 3, w)],
        ];
    }
}

/// The training head of a crop: the fused filter on the network's output,
/// the loss against the reference, and the output's gradient (of the batch
/// mean: `scale` = 1 / batch).
pub fn head(ws: &mut Workspace, loss: Loss, scale: f32, isa: mcdenoise_core::Isa) -> Result<f32> {
    let (w, h) = ws.size();
    let n = w * h;
    let (out12, dy, aux) = ws.head_parts();
    let [data, out, g, drad, fs, gs] = &mut aux[..] else {
        return Err(HostError::Usage("wskp: crop buffers missing".into()));
    };
    let imp = View::new(&out12[..6 * n], 6, w, h)?;
    let fus = View::new(&out12[6 * n..], 6, w, h)?;
    let inp = FusedInputs {
        sizes: &SIZES,
        importance: imp,
        fusion: Some(fus),
        albedo: Some(View::new(&data[3 * n..6 * n], 3, w, h)?),
        radiance: View::new(&data[..3 * n], 3, w, h)?,
    };
    softmax::fused_filter::<F32>(isa, WindowPath::Separable, &inp, &mut ViewMut::new(out, 3, w, h)?, 0, fs)?;
    let l = loss.eval(out, &data[6 * n..9 * n], g, scale);
    let gv = View::new(g, 3, w, h)?;
    let (di, df) = dy.split_at_mut(6 * n);
    let grads = sgrad::FusedGrads {
        importance: &mut ViewMut::new(di, 6, w, h)?,
        fusion: Some(&mut ViewMut::new(df, 6, w, h)?),
        radiance: &mut ViewMut::new(drad, 3, w, h)?,
    };
    sgrad::fused_filter_grad(isa, &inp, &gv, grads, 0, gs)?;
    Ok(l)
}

/// The `wskp` method: temporal accumulation, the ImportanceNet and the fused
/// filter, every stage in precision `P`.
pub struct Wskp<P: HostPrecision> {
    plan: Plan,
    net: Net,
    params: Vec<f32>,
    ta: TemporalAccumulation<P>,
    infer: Option<Inference<P>>,
    bufs: Option<(Vec<f32>, Vec<f32>, Vec<f32>)>,
}

impl<P: HostPrecision> Wskp<P> {
    /// For a sequence starting with `first`, with the weights in `file`.
    pub fn new(first: &Frame, file: &File, layers: usize) -> Result<Self> {
        let net = net(layers)?;
        file.expect_meta("layers", &layers.to_string())?;
        let params = file.params(&net, "wskp", &["adam.m", "adam.v"])?;
        Self::from_params(first, net, params, layers)
    }

    /// For a sequence starting with `first`, with parameters in hand.
    pub fn from_params(first: &Frame, net: Net, params: Vec<f32>, layers: usize) -> Result<Self> {
        check_inputs(first)?;
        let ta = TemporalAccumulation::<P>::new(first, false)?;
        let mut plan = ta.plan().clone();
        plan.built.push(if layers == 6 { "ImportanceNet (6 layers)" } else { "ImportanceNet (3 layers)" });
        plan.built.push("fused importance filter (sizes 3..13)");
        Ok(Wskp { plan, net, params, ta, infer: None, bufs: None })
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
        let (color, _) = self.ta.step(f, ctx, t)?;
        let ta = t.time("decode", || color.decode::<P>());
        let (x, c, alb) = self.bufs.get_or_insert_with(|| (vec![0.0; 10 * n], vec![0.0; 3 * n], vec![0.0; 3 * n]));
        if x.len() != 10 * n {
            *x = vec![0.0; 10 * n];
            *c = vec![0.0; 3 * n];
            *alb = vec![0.0; 3 * n];
        }
        t.time("network inputs", || inputs(f, &ta, x, c, alb))?;
        if self.infer.is_none() {
            // Fixed point: the formats from an f32 run on the first frame.
            let ranges = if P::NAME == "fixed" {
                let mut f32net = Inference::<F32>::new(&self.net, &self.params, None, None)?;
                Some(f32net.ranges(ctx, Planes::<f32>::from_vec(10, w, h, x.clone()))?)
            } else {
                None
            };
            self.infer = Some(Inference::<P>::new(
                &self.net,
                &self.params,
                ranges.as_deref(),
                Some(mcdenoise_core::fixed::LOGIT_FRAC),
            )?);
        }
        let infer = self.infer.as_mut().expect("just built");
        let mut xin = Planes::<P::Store>::new(10, w, h).with_frac(infer.input_frac());
        P::encode(x, &mut xin.data, xin.frac);
        let cs = Planes::<P::Store>::encode_as::<P>(3, w, h, c, Kind::Image);
        let als = Planes::<P::Store>::encode_as::<P>(3, w, h, alb, Kind::Plain);
        let logits = t.time("ImportanceNet", || infer.run(ctx, xin))?;
        let lv = logits.view();
        let inp = FusedInputs {
            sizes: &SIZES,
            importance: lv.channels_range(0, 6)?,
            fusion: Some(lv.channels_range(6, 6)?),
            albedo: Some(als.view()),
            radiance: cs.view(),
        };
        // The output format: the demodulated input's, rescaled by the albedo's
        // largest value.
        let amax = alb.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let frac = cs.frac - (amax.max(1.0).log2().ceil() as i8);
        let mut out = Planes::<P::Store>::new(3, w, h).with_frac(frac);
        let isa = ctx.isa;
        let len = softmax::fused_scratch_len::<P>(WindowPath::Separable, &SIZES, 3, w);
        t.time("fused filter", || {
            ctx.pool.bands(out.view_mut(), 48, &mut ctx.scratch, len, |b, y0, s| {
                softmax::fused_filter::<P>(isa, WindowPath::Separable, &inp, b, y0, s)
            })
        })?;
        Ok(t.time("decode", || out.decode::<P>()))
    }
}

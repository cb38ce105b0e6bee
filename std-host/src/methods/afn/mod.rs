//! The adaptive fusion network (AFN; the paper in shared/seeds/000): one
//! light autoencoder predicts two 7x7 kernel maps from the 1-spp image, the
//! temporally accumulated (TA) image and the auxiliary buffers; `K_1spp`
//! filters the 2x average-pooled 1-spp image, `K_TA` the TA image at full
//! scale; the scale compositor fuses them,
//! `i = d_TA - a U(D(d_TA)) + a U(d_1spp)`, with a predicted weight `a`; a
//! small residual CNN refines, `o = i + R(i, f)`.
//!
//! No public code exists; the choices here (light by design: about 15 k
//! multiply-adds per pixel for the kernel predictor, 2.7 k for the
//! refinement):
//! - everything is filtered in demodulated irradiance `c = x / d` and
//!   remodulated by `d` at the end, as the paper's loss on `o * albedo`,
//!   `d` the demodulation factor of [`crate::methods::features`];
//! - network input (13 channels, [`crate::methods::features`]): the 1-spp
//!   and the TA radiance through the exposure and the transfer curve
//!   (3 + 3), albedo (3), normal (3), depth normalised over the frame (1);
//! - kernel predictor: 3x3 convolutions with ReLU, 13 -> 12 (full), max pool,
//!   12 -> 24 (half), max pool, 24 -> 32 -> 32 (quarter), nearest upsample,
//!   concatenation with the half-scale features, 56 -> 32 (half); from there
//!   a 1x1 head 32 -> 49 gives `K_1spp` (half scale); nearest upsample,
//!   concatenation with the full-scale features, 44 -> 16 (full) and a 1x1
//!   head 16 -> 50 gives `K_TA` (49) and the fusion weight's logit (1);
//! - kernels are the softmax of their 49 logits per pixel (convex weights,
//!   robust to HDR), the fusion weight a sigmoid;
//! - refinement: input `log1p(e i)` (3, `e` the frame's exposure) and the
//!   auxiliary buffers (7); 3x3 convolutions 10 -> 12 -> 12 (ReLU) -> 3; the
//!   residual is added in `log1p` space, `o = expm1(log1p(e i) + R) / e`, so
//!   a bright pixel's correction scales with it and the output with the
//!   input.

use mcdenoise_core::conv::{self as cconv, Activation, Conv2d};
use mcdenoise_core::pool::{self, grad as pgrad, Reduce};
use mcdenoise_core::softmax::{self, grad as sgrad};
use mcdenoise_core::unfold::{self, grad as ugrad};
use mcdenoise_core::{Isa, View, ViewMut, F32};

use crate::error::{HostError, Result};
use crate::io::frame::{Buffer, Frame};
use crate::methods::{features, Ctx, Denoiser, Plan, TemporalAccumulation, Timings};
use crate::nn::infer::Inference;
use crate::nn::loss::Objective;
use crate::nn::weights::File;
use crate::nn::{Conv, Layer, Net, NetDesc, Nets, Workspace};
use crate::runtime::par::Pool;
use crate::runtime::precision::{HostPrecision, Kind, Planes};

/// Which images the network filters (the paper's Table 11 ablation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Variant {
    /// Both, fused by the scale compositor: AFN.
    Fusion,
    /// The TA image only (full scale, its kernels; the network sees TA twice).
    TaOnly,
    /// The 1-spp image only (full scale, the full-scale kernels; the network
    /// sees the 1-spp image twice).
    #[value(name = "1spp-only")]
    OneSppOnly,
}

impl Variant {
    /// The name in weights files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Variant::Fusion => "fusion",
            Variant::TaOnly => "ta-only",
            Variant::OneSppOnly => "1spp-only",
        }
    }
    /// By name.
    pub fn parse(s: &str) -> Option<Variant> {
        [Variant::Fusion, Variant::TaOnly, Variant::OneSppOnly].into_iter().find(|v| v.name() == s)
    }
}
/// Kernel size.
pub const K: usize = 7;
/// Taps per kernel.
pub const TAPS: usize = K * K;
/// Kernel-predictor input channels.
pub const CIN: usize = 13;
/// Refinement input channels.
pub const RIN: usize = 10;

fn conv(k: usize, cout: usize, act: Activation) -> Layer {
    Layer::Conv(Conv { k, cout, act, repvgg: false, bias: true })
}

/// The kernel predictor (two heads: `K_1spp` logits at half scale; `K_TA`
/// logits and the fusion logit at full scale).
pub fn kernel_net() -> Result<Net> {
    let r = Activation::Relu;
    Net::new(NetDesc {
        cin: CIN,
        layers: vec![
            conv(3, 12, r),
            Layer::Save,
            Layer::MaxPool,
            conv(3, 24, r),
            Layer::Save,
            Layer::MaxPool,
            conv(3, 32, r),
            conv(3, 32, r),
            Layer::Upsample { bilinear: false },
            Layer::Concat,
            conv(3, 32, r),
            Layer::Save,
            conv(1, TAPS, Activation::Identity),
            Layer::Output,
            Layer::Pop,
            Layer::Upsample { bilinear: false },
            Layer::Concat,
            conv(3, 16, r),
            conv(1, TAPS + 1, Activation::Identity),
        ],
    })
}

/// The refinement network (`log1p(e i)` and the auxiliary buffers to the
/// residual in `log1p` space).
pub fn refine_net() -> Result<Net> {
    let r = Activation::Relu;
    Net::new(NetDesc { cin: RIN, layers: vec![conv(3, 12, r), conv(3, 12, r), conv(3, 3, Activation::Identity)] })
}

/// Checks a frame has the networks' inputs.
pub fn check_inputs(f: &Frame) -> Result<()> {
    for b in [Buffer::Albedo, Buffer::Normal, Buffer::Depth] {
        f.require(b, "afn (its networks' inputs)")?;
    }
    Ok(())
}

/// The network input `x` (13 planes), the demodulated 1-spp and TA
/// irradiance `c1`, `ct` (3 each, the parts the filters average), the
/// demodulation factor `d` (3) and the 1-spp image's excess `ex` (3, added
/// back at its pixel: a light seen directly is exact at 1 spp) of a frame
/// from its accumulated radiance `t`, by the rules of
/// [`crate::methods::features`]; returns the frame's exposure. A
/// single-image variant sees its image in both slots. The output is `d
/// (refine(fuse(filter(c1), filter(ct))) + ex)`.
#[allow(clippy::too_many_arguments)]
pub fn inputs(
    pool: &Pool,
    variant: Variant,
    f: &Frame,
    t: &[f32],
    x: &mut [f32],
    c1: &mut [f32],
    ct: &mut [f32],
    d: &mut [f32],
    ex: &mut [f32],
) -> Result<f32> {
    check_inputs(f)?;
    let r = f.require(Buffer::Color, "afn")?;
    let e = features::exposure(r, f.width, f.height);
    let (r, t) = match variant {
        Variant::Fusion => (r, t),
        Variant::TaOnly => (t, t),
        Variant::OneSppOnly => (r, r),
    };
    let a = f.require(Buffer::Albedo, "afn")?;
    features::demodulation(pool, a, f.width, f.height, d);
    features::network_inputs(pool, f, "afn", e, &[r, t], d, x, &mut [&mut *c1, &mut *ct])?;
    features::clamp_fireflies(pool, c1, r, a, f.width, f.height);
    features::clamp_fireflies(pool, ct, t, a, f.width, f.height);
    // The TA image's excess is dropped (`ex` holds it for a moment): the
    // 1-spp image's goes back.
    features::split_excess(pool, ct, a, None, f.width, f.height, e, ex);
    let geometry = (f.require(Buffer::Normal, "afn")?, f.require(Buffer::Depth, "afn")?);
    features::split_excess(pool, c1, a, Some(geometry), f.width, f.height, e, ex);
    Ok(e)
}

/// The training buffers of a crop, in `wss[0].aux` (the refinement net's
/// workspace is `wss[1]`).
pub mod buf {
    /// `c1, ct, alb, ref` (3 planes each), the refinement's auxiliary
    /// buffers (7), the frame's exposure (1, constant) and the excess (3):
    /// 23 planes, full scale.
    pub const DATA: usize = 0;
    /// `K_1spp` (49, half).
    pub const K1: usize = 1;
    /// `K_TA` (49, full).
    pub const KT: usize = 2;
    /// Fusion weight (1, full).
    pub const ALPHA: usize = 3;
    /// The pooled 1-spp irradiance (3, half).
    pub const D1: usize = 4;
    /// Filtered 1 spp (3, half).
    pub const F1: usize = 5;
    /// Filtered TA (3, full).
    pub const FT: usize = 6;
    /// Fused `i` (3, full).
    pub const I: usize = 7;
    /// Refined `o` (3, full).
    pub const O: usize = 8;
    /// The remodulated output (3, full).
    pub const OUT: usize = 9;
    /// Gradient of the output (3, full).
    pub const G_OUT: usize = 10;
    /// Gradient of `i` (3, full).
    pub const G_I: usize = 11;
    /// Gradient of `d_TA` (3, full).
    pub const G_FT: usize = 12;
    /// Gradient of `d_1spp` (3, half).
    pub const G_F1: usize = 13;
    /// Gradient of the fusion weight (1, full).
    pub const G_ALPHA: usize = 14;
    /// Gradient of `K_TA` (49, full).
    pub const G_KT: usize = 15;
    /// Gradient of `K_1spp` (49, half).
    pub const G_K1: usize = 16;
    /// Scratch of the apply.
    pub const SCRATCH: usize = 17;
    /// Planes of [`DATA`].
    pub const DATA_PLANES: usize = 23;
}

/// Allocates a crop's training buffers once.
pub fn crop_buffers(wss: &mut [Workspace]) {
    let (w, h) = wss[0].size();
    if !wss[0].aux.is_empty() {
        return;
    }
    let (n, nh) = (w * h, w.div_ceil(2) * h.div_ceil(2));
    let sizes = [
        buf::DATA_PLANES * n,
        TAPS * nh,
        TAPS * n,
        n,
        3 * nh,
        3 * nh,
        3 * n,
        3 * n,
        3 * n,
        3 * n,
        3 * n,
        3 * n,
        3 * n,
        3 * nh,
        n,
        TAPS * n,
        TAPS * nh,
        unfold::scratch_len::<F32>(K, 3, w),
    ];
    wss[0].aux = sizes.iter().map(|&s| vec![0.0; s]).collect();
    if wss.len() > 1 {
        wss[1].want_input_grad = true;
    }
}

fn v(d: &[f32], c: usize, w: usize, h: usize) -> Result<View<'_, f32>> {
    Ok(View::new(d, c, w, h)?)
}

fn vm(d: &mut [f32], c: usize, w: usize, h: usize) -> Result<ViewMut<'_, f32>> {
    Ok(ViewMut::new(d, c, w, h)?)
}

/// The training head of a crop: kernels, filtering, fusion, (refinement),
/// the loss against the reference and every gradient back to the kernel
/// predictor's heads. `refine`: with the refinement network (`wss[1]`).
pub fn head(
    nets: &Nets<'_>,
    wss: &mut [Workspace],
    loss: impl Into<Objective>,
    scale: f32,
    refine: bool,
    variant: Variant,
) -> Result<f32> {
    let isa = nets.isa;
    let (w, h) = wss[0].size();
    let (wh, hh) = (w.div_ceil(2), h.div_ceil(2));
    let n = w * h;
    let (ws0, rest) = wss.split_first_mut().expect("a workspace per network");
    let (outs, mut grads, aux) = ws0.heads(nets.net(0));
    let (logit1, logit_t) = (outs[0], outs[1]);
    let [data, k1, kt, alpha, d1, f1, ft, ib, ob, outb, g_out, g_i, g_ft, g_f1, g_a, g_kt, g_k1, scratch] = aux
        .get_disjoint_mut([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17])
        .map_err(|_| HostError::Usage("afn: crop buffers missing".into()))?;
    let (c1, rest_d) = data.split_at(3 * n);
    let (ct, rest_d) = rest_d.split_at(3 * n);
    let (alb, rest_d) = rest_d.split_at(3 * n);
    let (reff, rest_d) = rest_d.split_at(3 * n);
    let (feats, rest_d) = rest_d.split_at(7 * n);
    let (expo, excess) = rest_d.split_at(n);
    let e = expo[0];
    // Kernels and the fusion weight.
    softmax::channel_softmax::<F32>(isa, &v(logit1, TAPS, wh, hh)?, &mut vm(k1, TAPS, wh, hh)?)?;
    softmax::channel_softmax::<F32>(isa, &v(&logit_t[..TAPS * n], TAPS, w, h)?, &mut vm(kt, TAPS, w, h)?)?;
    sgrad::sigmoid(isa, &v(&logit_t[TAPS * n..], 1, w, h)?, &mut vm(alpha, 1, w, h)?)?;
    // Filtering: K_1spp on the pooled 1 spp, K_TA on TA; then the fusion.
    pool::reduce2x2::<F32>(isa, Reduce::Mean, &v(c1, 3, w, h)?, &mut vm(d1, 3, wh, hh)?, 0)?;
    let sl = unfold::scratch_len::<F32>(K, 3, wh);
    unfold::apply::<F32>(
        isa,
        K,
        &v(k1, TAPS, wh, hh)?,
        &v(d1, 3, wh, hh)?,
        &mut vm(f1, 3, wh, hh)?,
        &mut scratch[..sl],
    )?;
    unfold::apply::<F32>(isa, K, &v(kt, TAPS, w, h)?, &v(ct, 3, w, h)?, &mut vm(ft, 3, w, h)?, scratch)?;
    // A single-image variant filters it at full scale with the full-scale
    // kernels (its data slot `ct` holds that image) and skips the fusion.
    let fused = variant == Variant::Fusion;
    if fused {
        pool::composite::<F32>(
            isa,
            &v(ft, 3, w, h)?,
            &v(f1, 3, wh, hh)?,
            &v(alpha, 1, w, h)?,
            &mut vm(ib, 3, w, h)?,
            0,
        )?;
    } else {
        ib.copy_from_slice(ft);
    }
    // Refinement in log1p space of the exposure-scaled image.
    if refine {
        let ws1 = &mut rest[0];
        let inp = ws1.input_mut();
        for (d, &iv) in inp[..3 * n].iter_mut().zip(ib.iter()) {
            *d = (e * iv).max(0.0).ln_1p();
        }
        inp[3 * n..].copy_from_slice(feats);
        nets.forward(1, ws1)?;
        let rr = ws1.output();
        for k in 0..3 * n {
            let s = (e * ib[k]).max(0.0).ln_1p();
            ob[k] = (s + rr[k].clamp(-refine_limit(s), refine_limit(s))).exp_m1() / e;
        }
    } else {
        ob.copy_from_slice(ib);
    }
    // Remodulate, the loss and its gradient.
    for k in 0..3 * n {
        outb[k] = (ob[k] + excess[k]) * alb[k];
    }
    let l = loss.into().eval(outb, reff, g_out, w, h, scale, e);
    // Back through the remodulation and the refinement to i.
    if refine {
        let ws1 = &mut rest[0];
        let (rr, rg, _) = ws1.head_parts();
        for k in 0..3 * n {
            // No gradient where the residual is clamped.
            let s = (e * ib[k]).max(0.0).ln_1p();
            rg[k] = if rr[k].abs() < refine_limit(s) { rg_value(g_out[k], alb[k], ob[k], e) } else { 0.0 };
        }
        nets.backward(1, ws1)?;
        let gin = ws1.input_grad();
        for k in 0..3 * n {
            let through = rg_value(g_out[k], alb[k], ob[k], e) + gin[k];
            g_i[k] = if ib[k] > 0.0 { through * e / (1.0 + e * ib[k]) } else { 0.0 };
        }
    } else {
        for k in 0..3 * n {
            g_i[k] = g_out[k] * alb[k];
        }
    }
    // The compositor, the applies, the softmaxes and the sigmoid.
    if !fused {
        g_ft.copy_from_slice(g_i);
        g_f1.fill(0.0);
        g_a.fill(0.0);
    } else {
        pgrad::composite_grad(
            isa,
            &v(ft, 3, w, h)?,
            &v(f1, 3, wh, hh)?,
            &v(alpha, 1, w, h)?,
            &v(g_i, 3, w, h)?,
            &mut vm(g_ft, 3, w, h)?,
            &mut vm(g_f1, 3, wh, hh)?,
            &mut vm(g_a, 1, w, h)?,
            0,
        )?;
    }
    ugrad::apply_grad(
        isa,
        K,
        &v(kt, TAPS, w, h)?,
        &v(ct, 3, w, h)?,
        &v(g_ft, 3, w, h)?,
        Some(&mut vm(g_kt, TAPS, w, h)?),
        None,
        0,
    )?;
    ugrad::apply_grad(
        isa,
        K,
        &v(k1, TAPS, wh, hh)?,
        &v(d1, 3, wh, hh)?,
        &v(g_f1, 3, wh, hh)?,
        Some(&mut vm(g_k1, TAPS, wh, hh)?),
        None,
        0,
    )?;
    sgrad::channel_softmax_grad(isa, &v(k1, TAPS, wh, hh)?, &v(g_k1, TAPS, wh, hh)?, &mut vm(grads[0], TAPS, wh, hh)?)?;
    let (gkt_logits, ga_logit) = grads[1].split_at_mut(TAPS * n);
    sgrad::channel_softmax_grad(isa, &v(kt, TAPS, w, h)?, &v(g_kt, TAPS, w, h)?, &mut vm(gkt_logits, TAPS, w, h)?)?;
    sgrad::sigmoid_grad(isa, &v(alpha, 1, w, h)?, &v(g_a, 1, w, h)?, &mut vm(ga_logit, 1, w, h)?)?;
    let _ = &mut grads;
    Ok(l)
}

/// The largest residual of the refinement in `log1p` space (a factor of
/// about 2 either way on bright pixels): an untrained or odd network cannot
/// overflow the output (a nearly black training frame did, with an exposure
/// of 4.5e5), and a refinement is a correction, not a second filter. The
/// bundled weights were trained with a limit of 6; at inference these
/// limits only cut what harmed them on the foreign set (gallery relMSE
/// 37.9 -> 0.48, HDR corpus room 0.236 -> 0.024).
pub const REFINE_LIMIT: f32 = 0.7;

/// The refinement's residual is also at most `REFINE_REL` times the
/// pixel's own `s = log1p(e i)`: the output stays within
/// `(1 + e i)^(1 +- REFINE_REL)`, so a dark pixel changes by at most that
/// fraction of itself and a black one stays black. (An absolute limit let
/// the residual, additive in `log1p` space and so in linear space for dark
/// pixels, add light to dark walls and glass: relMSE 37.9 on a foreign
/// gallery sequence, against 0.16 without the refinement.)
pub const REFINE_REL: f32 = 0.5;

/// The bound of the refinement's residual at a pixel whose fused value is
/// `s = log1p(e i)`.
#[inline]
pub fn refine_limit(s: f32) -> f32 {
    (REFINE_REL * s).min(REFINE_LIMIT)
}

/// The refinement output's gradient: with `o = expm1(log1p(e i) + r) / e`,
/// `d out / d r = alb (o + 1 / e)` times the output's gradient.
#[inline]
fn rg_value(g_out: f32, alb: f32, o: f32, e: f32) -> f32 {
    g_out * alb * (o + 1.0 / e)
}

/// The `afn` method: temporal accumulation, the kernel predictor, the two
/// filters, the scale compositor and (unless `--no-refine`) the refinement,
/// every operator in precision `P` (the sigmoid and the `log1p`-space
/// residual in f32).
pub struct Afn<P: HostPrecision> {
    plan: Plan,
    kernel_net: Net,
    refine_net: Net,
    params: (Vec<f32>, Vec<f32>),
    refine: bool,
    variant: Variant,
    ta: TemporalAccumulation<P>,
    infer: Option<Infer<P>>,
    bufs: Option<Vec<Vec<f32>>>,
    whole_maps: bool,
    /// With the fallback to the input ([`crate::methods::fallback`]).
    fallback: bool,
    /// The networks emulated in 8 bits ([`Inference::emulate_int8`]).
    int8: bool,
    /// With the wide pass ([`crate::methods::wide`]).
    wide: bool,
    /// The wide pass's buffers.
    wide_bufs: crate::methods::wide::Buffers,
}

/// The networks ready to run in `P`: the kernel predictor without its
/// full-scale head, the head (1x1, 16 -> 50) as weights in `P`, the
/// refinement.
struct Infer<P: HostPrecision> {
    body: Inference<P>,
    head_w: Vec<P::Store>,
    head_b: Vec<P::Store>,
    head_frac: i8,
    refine: Inference<P>,
}

/// Rows per band of the streamed full-scale head (even, so the compositor's
/// 2x2 cells stay inside a band).
pub const STREAM_ROWS: usize = 16;

/// The kernel predictor without its last layer (the full-scale 1x1 head),
/// and that layer's parameter offset.
fn body_net(kn: &Net) -> Result<(Net, usize)> {
    let mut layers = kn.desc.layers.clone();
    layers.pop();
    let body = Net::new(NetDesc { cin: kn.desc.cin, layers })?;
    let last = kn.convs.last().expect("the head is a conv");
    Ok((body, last.offset))
}

/// The tensor names of the two networks in one weights file: the kernel
/// predictor's as `layers.*` (see [`crate::nn::weights`]), the refinement's
/// the same under `refine.` (saved by [`save`]).
pub fn split_params(file: &File, kn: &Net, rn: &Net) -> Result<(Vec<f32>, Vec<f32>)> {
    file.expect_meta("format", "mcdenoise-afn")?;
    let all = file.names();
    let refine_names: Vec<&str> = all.iter().map(|s| s.as_str()).filter(|n| n.starts_with("refine.")).collect();
    let mut extra: Vec<&str> = refine_names.clone();
    extra.extend(["adam.m", "adam.v"]);
    let kp = file.params(kn, "afn", &extra)?;
    let rp = file.params_prefixed(rn, "refine.")?;
    Ok((kp, rp))
}

/// Saves both networks' parameters (with this build's input transform).
pub fn save(path: &std::path::Path, kn: &Net, kp: &[f32], rn: &Net, rp: &[f32], meta: &[(&str, String)]) -> Result<()> {
    use crate::nn::weights::{save_model, Form};
    let mut all = vec![("transform", features::TRANSFORM.to_string())];
    all.extend(meta.iter().filter(|(k, _)| *k != "transform").cloned());
    save_model(path, "afn", &[("", kn, kp), ("refine.", rn, rp)], Form::Branches, &all, &[])
}

impl<P: HostPrecision> Afn<P> {
    /// For a sequence starting with `first`, with the weights in `file`.
    pub fn new(first: &Frame, file: &File, refine: bool) -> Result<Self> {
        let (kn, rn) = (kernel_net()?, refine_net()?);
        file.expect_transform(features::TRANSFORM)?;
        let params = split_params(file, &kn, &rn)?;
        let variant = match file.meta("variant") {
            None => Variant::Fusion,
            Some(v) => {
                Variant::parse(&v).ok_or_else(|| HostError::Usage(format!("afn weights: unknown variant '{v}'")))?
            }
        };
        Self::from_params(first, params, refine, variant)?.with_ta_clamp(crate::methods::basic::ta_clamp_for(file)?)
    }

    crate::methods::ta_builders!();

    /// Memory per frame (see [`crate::runtime::memory`]): the accumulation, the f32
    /// buffers kept, the kernel predictor's tensors (kept for the next frame:
    /// full scale 12 + 44 + 16 planes, half 24 + 56 + 32 + 49, quarter 32 +
    /// 32), the half-scale kernels, the stored irradiance, the filtered and
    /// fused images, the refinement and its tensors; the full-scale kernels
    /// stream in bands (scratch, not per pixel).
    /// With `whole_maps` ([`Afn::with_whole_maps`]), the full-scale logits
    /// and kernels held whole for a moment are added to the peak.
    /// `scales`: the history rejection's.
    pub fn footprint(
        info: &crate::io::frame::FrameInfo,
        threads: usize,
        whole_maps: bool,
        wide: bool,
        scales: usize,
    ) -> crate::runtime::memory::Footprint {
        use crate::runtime::precision::store_bytes;
        let s = store_bytes::<P>();
        use crate::nn::infer::{held_bytes_per_pixel, ranges_bytes_per_pixel, tensors_bytes_per_pixel};
        let bufs = 4 * (CIN as u64 + 12);
        let kn = kernel_net().expect("the kernel predictor");
        let (body_n, _) = body_net(&kn).expect("its body");
        let refine_n = refine_net().expect("the refinement network");
        let body = held_bytes_per_pixel(&body_n, s);
        let refine_net = held_bytes_per_pixel(&refine_n, s);
        let k1 = (TAPS as u64 * s).div_ceil(4);
        // After the networks ran: kernels, c1 ct, d1 f1, fused; i decoded;
        // refinement input, output, r decoded.
        let wide_kept = if wide { crate::methods::wide::KEPT_BYTES } else { 0 };
        let tail = |l: &mut crate::runtime::memory::Ledger, wide_first: u64| {
            l.alloc(k1).alloc(6 * s).alloc((6 * s).div_ceil(4)).alloc(3 * s);
            l.alloc(12).free(3 * s);
            l.alloc(4 * RIN as u64 + RIN as u64 * s).alloc(12).temp(12);
            // The wide pass (its buffers kept, allocated on the first
            // frame; the history counts it reads were decoded at the start
            // of the frame), then the fallback to the input.
            crate::methods::wide::ledger(l, wide, wide_first);
        };
        // The first frame: the accumulation, the TA decode, the buffers (in
        // fixed point, the f32 range runs: the body's tensors kept while the
        // refinement's run), the encoded input and the networks' tensors as
        // they are made.
        let mut first = crate::runtime::memory::Ledger::default();
        let history = TemporalAccumulation::<P>::step_ledger(info, &mut first, scales);
        first.alloc(12 + 4 * u64::from(wide)).alloc(bufs);
        if P::FIXED_POINT {
            first.temp(
                ranges_bytes_per_pixel(&body_n)
                    .max(tensors_bytes_per_pixel(&body_n, 4) + ranges_bytes_per_pixel(&refine_n)),
            );
        }
        first.alloc(CIN as u64 * s).alloc(body + refine_net);
        tail(&mut first, wide_kept);
        // Every later frame: what the frame before kept, then the
        // accumulation's step on top of it and the rest of the frame.
        let mut later = crate::runtime::memory::Ledger::default();
        later.alloc(bufs + CIN as u64 * s + body + refine_net + wide_kept);
        TemporalAccumulation::<P>::step_ledger(info, &mut later, scales);
        later.alloc(12 + 4 * u64::from(wide));
        tail(&mut later, 0);
        let w = info.width;
        let sl = stream_scratch_len::<P>(w, STREAM_ROWS).max(unfold::scratch_len::<P>(K, 3, w));
        let whole = if whole_maps {
            (4 * stream_scratch_len::<P>(w, info.height) as u64).div_ceil(info.pixels().max(1))
        } else {
            0
        };
        crate::runtime::memory::Footprint {
            kept: history + 12 + bufs + CIN as u64 * s + body + refine_net + wide_kept,
            peak: first.peak().max(later.peak()) + whole,
            scratch: 4 * threads as u64 * sl as u64,
        }
    }

    /// With parameters in hand (kernel predictor, refinement).
    pub fn from_params(first: &Frame, params: (Vec<f32>, Vec<f32>), refine: bool, variant: Variant) -> Result<Self> {
        check_inputs(first)?;
        let ta = TemporalAccumulation::<P>::new(first, false)?
            .with_reject(crate::methods::basic::LEARNED_TA_REJECT)?
            .with_reject_scales(crate::methods::basic::LEARNED_TA_REJECT_SCALES)?;
        let mut plan = ta.plan().clone();
        if first.colour_is_pair_mean {
            plan.built.insert(0, features::PAIR_CLAMP_STAGE);
        }
        match variant {
            Variant::Fusion => plan.built.extend([
                "kernel predictor (7x7 kernels at two scales)",
                "filter 1 spp (half scale) and TA",
                "scale compositor",
            ]),
            Variant::TaOnly => plan.built.extend(["kernel predictor", "filter TA (7x7)"]),
            Variant::OneSppOnly => plan.built.extend(["kernel predictor", "filter 1 spp (7x7, full scale)"]),
        }
        if refine {
            plan.built.push("refinement");
        } else {
            plan.skipped.push(("refinement", "--no-refine".into()));
        }
        if variant != Variant::Fusion {
            plan.skipped.push(("scale compositor", format!("the {} variant filters one image", variant.name())));
        }
        crate::methods::wide::plan(&mut plan, true);
        crate::methods::fallback::plan(&mut plan, true, first.has(crate::io::frame::Buffer::ColorB));
        Ok(Afn {
            plan,
            kernel_net: kernel_net()?,
            refine_net: refine_net()?,
            params,
            refine,
            variant,
            ta,
            infer: None,
            bufs: None,
            whole_maps: false,
            fallback: true,
            int8: false,
            wide: true,
            wide_bufs: Default::default(),
        })
    }

    /// Emulates 8-bit networks ([`Inference::emulate_int8`]): the kernel
    /// predictor (its head too) and the refinement, ranges from the first
    /// frame. Float precisions only: it measures what 8 bits cost.
    pub fn with_int8(mut self, on: bool) -> Result<Self> {
        if on && P::FIXED_POINT {
            return Err(HostError::Usage("--emulate-int8 runs in a float precision (f32, f16)".into()));
        }
        self.int8 = on;
        Ok(self)
    }

    /// Holds the full-scale logits and kernels whole instead of streaming
    /// them in bands (for measuring what streaming saves; the memory
    /// estimate counts it).
    pub fn with_whole_maps(mut self, whole: bool) -> Self {
        self.whole_maps = whole;
        self
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

impl<P: HostPrecision> Denoiser for Afn<P> {
    fn name(&self) -> &'static str {
        "afn"
    }
    fn plan(&self) -> &Plan {
        &self.plan
    }
    fn denoise(&mut self, f: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        check_inputs(f)?;
        let (w, h) = (f.width, f.height);
        let (wh, hh) = (w.div_ceil(2), h.div_ceil(2));
        let n = w * h;
        let isa = ctx.isa;
        let (color, counts) = self.ta.step(f, ctx, t)?;
        let mut ta = Vec::new();
        t.time("decode", || {
            crate::methods::basic::TemporalAccumulation::<P>::decode_color(&ctx.pool, color, f, &mut ta)
        });
        let counts = if self.wide { t.time("decode", || counts.decode::<P>()) } else { Vec::new() };
        let bufs = self.bufs.get_or_insert_with(Vec::new);
        if bufs.first().is_none_or(|x| x.len() != CIN * n) {
            *bufs = vec![vec![0.0; CIN * n], vec![0.0; 3 * n], vec![0.0; 3 * n], vec![0.0; 3 * n], vec![0.0; 3 * n]];
        }
        let [x, c1, ct, alb, ex] = bufs.get_disjoint_mut([0, 1, 2, 3, 4]).expect("five buffers");
        let variant = self.variant;
        let e = t.time("network inputs", || inputs(&ctx.pool, variant, f, &ta, x, c1, ct, alb, ex))?;
        if self.infer.is_none() {
            let (body, head_at) = body_net(&self.kernel_net)?;
            let last = *self.kernel_net.convs.last().expect("the head is a conv");
            let (bp, hp) = self.params.0.split_at(head_at);
            let (hw, hb) = hp.split_at(last.spec.cout * last.cin);
            let (br, rr) = if P::FIXED_POINT || self.int8 {
                // The formats from an f32 run on the first frame.
                let t0 = std::time::Instant::now();
                let mut k32 = Inference::<F32>::new(&body, bp, None, None)?;
                let br = k32.ranges(ctx, Planes::<f32>::from_vec(CIN, w, h, x.clone()))?;
                let mut r32 = Inference::<F32>::new(&self.refine_net, &self.params.1, None, None)?;
                let mut rin = vec![0.0f32; RIN * n];
                rin[3 * n..].copy_from_slice(&x[6 * n..]);
                for (d, &tv) in rin[..3 * n].iter_mut().zip(ct.iter()) {
                    *d = (e * tv).max(0.0).ln_1p();
                }
                let rr = r32.ranges(ctx, Planes::<f32>::from_vec(RIN, w, h, rin))?;
                t.add("fixed-point formats (first frame)", t0.elapsed());
                (Some(br), Some(rr))
            } else {
                (None, None)
            };
            // The head's weights: as many fractional bits as each output's
            // bit budget allows (fixed point); its output in the logit format.
            let head_frac = P::frac_or_zero(crate::nn::quant::weight_frac(hw, last.cin));
            let logit_frac = P::frac_or_zero(mcdenoise_core::fixed::LOGIT_FRAC);
            let mut head_w = vec![P::Store::default(); hw.len()];
            if self.int8 {
                let mut q = hw.to_vec();
                crate::nn::infer::int8_weights(&mut q, last.cin);
                P::encode(&q, &mut head_w, head_frac);
            } else {
                P::encode(hw, &mut head_w, head_frac);
            }
            let mut head_b = vec![P::Store::default(); hb.len()];
            P::encode(hb, &mut head_b, logit_frac);
            let mut body = Inference::<P>::new(&body, bp, br.as_deref(), None)?;
            let mut refine = Inference::<P>::new(&self.refine_net, &self.params.1, rr.as_deref(), None)?;
            if let (true, Some(br), Some(rr)) = (self.int8, &br, &rr) {
                // The body's output is the head's input: rounded too.
                body.emulate_int8(br, false)?;
                refine.emulate_int8(rr, true)?;
            }
            self.infer = Some(Infer { body, head_w, head_b, head_frac, refine });
        }
        let inf = self.infer.as_mut().expect("just built");
        let xin = t.time("encode", || {
            let mut p = Planes::<P::Store>::new(CIN, w, h).with_frac(inf.body.input_frac());
            crate::runtime::precision::encode_par::<P>(&ctx.pool, x, &mut p.data, p.frac);
            p
        });
        t.time("kernel predictor", || inf.body.run(ctx, xin))?;
        let (l1, feats) = (inf.body.output(0).view(), inf.body.output(1).view());
        // The half-scale kernels whole (a quarter of the pixels).
        let kfrac = P::frac_or_zero(mcdenoise_core::fixed::KERNEL_FRAC);
        let mut k1 = Planes::<P::Store>::new(TAPS, wh, hh).with_frac(kfrac);
        t.time("kernel softmax", || softmax::channel_softmax::<P>(isa, &l1, &mut k1.view_mut()))?;
        let (c1s, cts) = t.time("encode", || {
            // Both images are kept within the smaller of their formats'
            // bounds (each kept at its own, a pixel beyond both would come
            // out by the fusion's share of their difference too bright or
            // too dark), and what lies beyond it in both goes back at its
            // pixel with the 1-spp image's excess: a highlight the history
            // holds too (the corridor's window in its glossy floor), not a
            // 1-spp firefly the history has averaged away, which f32
            // filters out (the generator's dim `test_0001`, whose fireflies
            // of 1-2 on near-black surfaces lie far beyond the TA image's
            // bound: 0.60 dB under f32 while the 1-spp image's whole excess
            // went back, 0.02 now).
            let (f1, ft) =
                (P::frac_or_zero(P::choose_frac(c1, Kind::Image)), P::frac_or_zero(P::choose_frac(ct, Kind::Image)));
            let m = P::store_max(f1).min(P::store_max(ft));
            crate::runtime::precision::keep_shared_within(c1, ct, ex, m);
            let mut c1s = Planes::<P::Store>::new(3, w, h).with_frac(f1);
            crate::runtime::precision::encode_par::<P>(&ctx.pool, c1, &mut c1s.data, f1);
            let mut cts = Planes::<P::Store>::new(3, w, h).with_frac(ft);
            crate::runtime::precision::encode_par::<P>(&ctx.pool, ct, &mut cts.data, ft);
            (c1s, cts)
        });
        let mut d1 = Planes::<P::Store>::new(3, wh, hh).with_frac(c1s.frac);
        let mut f1 = Planes::<P::Store>::new(3, wh, hh).with_frac(c1s.frac);
        let mut fused = Planes::<P::Store>::new(3, w, h).with_frac(cts.frac.min(c1s.frac) - 1);
        let head = Conv2d {
            k: 1,
            cin: feats.channels(),
            cout: TAPS + 1,
            weights: &inf.head_w,
            bias: Some(&inf.head_b),
            act: Activation::Identity,
            weight_frac: inf.head_frac,
        };
        let whole = self.whole_maps;
        t.time("filter and fuse", || -> Result<()> {
            let c1v = c1s.view();
            ctx.pool.bands(d1.view_mut(), 1, &mut ctx.scratch, 0, |b, y0, _| {
                pool::reduce2x2::<P>(isa, Reduce::Mean, &c1v, b, y0)
            })?;
            let (k1v, d1v) = (k1.view(), d1.view());
            let len = unfold::scratch_len::<P>(K, 3, w);
            ctx.pool.bands(f1.view_mut(), 1, &mut ctx.scratch, len, |b, y0, s| {
                unfold::apply_rows::<P>(isa, K, &k1v, &d1v, b, y0, s)
            })?;
            let job = StreamJob { head: &head, feats, ta: cts.view(), coarse: f1.view(), variant, kfrac };
            if whole {
                // The naive layout, for measuring what streaming saves:
                // the full-scale logits and kernels held whole.
                let mut s = vec![0.0f32; stream_scratch_len::<P>(w, h)];
                Ok(stream_band::<P>(isa, &job, &mut fused.view_mut(), 0, h, &mut s)?)
            } else {
                ctx.pool.bands(
                    fused.view_mut(),
                    STREAM_ROWS,
                    &mut ctx.scratch,
                    stream_scratch_len::<P>(w, STREAM_ROWS),
                    |b, y0, s| {
                        let mut y = 0;
                        while y < b.height() {
                            let rows = STREAM_ROWS.min(b.height() - y);
                            let mut sub = b.rows_mut(y, rows)?;
                            stream_band::<P>(isa, &job, &mut sub, y0 + y, rows, s)?;
                            y += rows;
                        }
                        Ok(())
                    },
                )?;
                Ok(())
            }
        })?;
        let rinf = &mut inf.refine;
        let i = t.time("decode", || fused.decode::<P>());
        let mut out = vec![0.0f32; 3 * n];
        if self.refine {
            let mut rin = vec![0.0f32; RIN * n];
            for (d, &iv) in rin[..3 * n].iter_mut().zip(&i) {
                *d = (e * iv).max(0.0).ln_1p();
            }
            rin[3 * n..].copy_from_slice(&x[6 * n..]);
            let mut rp = Planes::<P::Store>::new(RIN, w, h).with_frac(rinf.input_frac());
            P::encode(&rin, &mut rp.data, rp.frac);
            let r = t.time("refinement", || rinf.run(ctx, rp))?.decode::<P>();
            for k in 0..3 * n {
                let lim = refine_limit(rin[k]);
                out[k] = ((rin[k] + r[k].clamp(-lim, lim)).exp_m1() / e + ex[k]) * alb[k];
            }
        } else {
            for k in 0..3 * n {
                out[k] = (i[k] + ex[k]) * alb[k];
            }
        }
        let wide = self.wide.then_some((&mut self.wide_bufs, &counts[..]));
        crate::methods::wide::finish(ctx, t, &mut out, f, "afn", wide, self.fallback, e)?;
        Ok(out)
    }
}

/// What the streamed full-scale head reads.
struct StreamJob<'a, T> {
    head: &'a Conv2d<'a, T>,
    /// The body's full-scale features (the head's input).
    feats: View<'a, T>,
    /// The TA (or, for a single-image variant, that image's) irradiance, whole.
    ta: View<'a, T>,
    /// The filtered half-scale 1 spp, whole.
    coarse: View<'a, T>,
    variant: Variant,
    kfrac: i8,
}

/// Scratch words of [`stream_band`] for bands of `rows` rows `w` wide (every
/// buffer of the band: the head's 50 planes, the kernels with a 3-row halo,
/// the fusion weight, the filtered band, the conv's and the apply's scratch).
fn stream_scratch_len<P: HostPrecision>(w: usize, rows: usize) -> usize {
    let r = K / 2;
    // Elements of at most 4 bytes: a word each is enough.
    (TAPS + 1) * rows * w
        + TAPS * (rows + 2 * r) * w
        + rows * w
        + 2 * rows * w
        + 3 * rows * w
        + cconv::conv2d_scratch_len::<P>(1, 16, TAPS + 1, w)
        + unfold::scratch_len::<P>(K, 3, w)
        + 64
}

/// Typed `n` elements at the front of `s`, and the rest.
fn carve<T: bytemuck::Pod>(s: &mut [f32], n: usize) -> (&mut [T], &mut [f32]) {
    let words = (n * std::mem::size_of::<T>()).div_ceil(4);
    let (a, b) = s.split_at_mut(words);
    (&mut bytemuck::cast_slice_mut::<f32, T>(a)[..n], b)
}

/// Rows `y0 .. y0 + rows` (`y0` even) of the fused image: the full-scale
/// head for these rows only, its kernels' softmax and the fusion weight, the
/// 7x7 apply on the TA image and the compositor (or, for a single-image
/// variant, the filtered image itself) — so the full-scale kernel maps are
/// never held whole.
fn stream_band<P: HostPrecision>(
    isa: Isa,
    j: &StreamJob<'_, P::Store>,
    out: &mut ViewMut<'_, P::Store>,
    y0: usize,
    rows: usize,
    s: &mut [f32],
) -> mcdenoise_core::Result<()> {
    let (w, h) = (j.ta.width(), j.ta.height());
    let r = K / 2;
    let (sy0, sy1) = (y0.saturating_sub(r), (y0 + rows + r).min(h));
    let sub = sy1 - sy0;
    let (logits, s) = carve::<P::Store>(s, (TAPS + 1) * rows * w);
    let (kern, s) = carve::<P::Store>(s, TAPS * sub * w);
    let (alpha, s) = carve::<P::Store>(s, rows * w);
    let (a32, s) = s.split_at_mut(rows * w);
    let (l32, s) = s.split_at_mut(rows * w);
    let (ft, s) = carve::<P::Store>(s, 3 * rows * w);
    let conv_len = cconv::conv2d_scratch_len::<P>(1, j.feats.channels(), TAPS + 1, w);
    let (cs, s) = s.split_at_mut(conv_len);
    let logit_frac = P::frac_or_zero(mcdenoise_core::fixed::LOGIT_FRAC);
    let mut lv = ViewMut::new(logits, TAPS + 1, w, rows)?.with_frac(logit_frac);
    cconv::conv2d::<P>(isa, j.head, &j.feats, &mut lv, y0, cs)?;
    let lv = lv.as_view();
    // Kernels into the band's rows of a halo-sized map (the apply reads
    // only the output rows' kernels).
    let mut kv = ViewMut::new(kern, TAPS, w, sub)?.with_frac(j.kfrac);
    softmax::channel_softmax::<P>(isa, &lv.channels_range(0, TAPS)?, &mut kv.rows_mut(y0 - sy0, rows)?)?;
    let mut fv = ViewMut::new(ft, 3, w, rows)?.with_frac(j.ta.frac());
    unfold::apply_rows::<P>(isa, K, &kv.as_view(), &j.ta.rows(sy0, sub)?, &mut fv, y0 - sy0, s)?;
    if j.variant != Variant::Fusion {
        for c in 0..3 {
            for yy in 0..rows {
                out.row_mut(c, yy).copy_from_slice(fv.row(c, yy));
            }
        }
        return Ok(());
    }
    // The fusion weight: the sigmoid of the 50th plane (f32).
    let lp = lv.channels_range(TAPS, 1)?;
    for yy in 0..rows {
        P::decode(lp.row(0, yy), &mut l32[yy * w..(yy + 1) * w], lp.frac());
    }
    sgrad::sigmoid(isa, &View::new(l32, 1, w, rows)?, &mut ViewMut::new(a32, 1, w, rows)?)?;
    let afrac = P::frac_or_zero(mcdenoise_core::fixed::KERNEL_FRAC);
    P::encode(a32, alpha, afrac);
    let av = View::new(alpha, 1, w, rows)?.with_frac(afrac);
    // The compositor on the band as an image of its own (2x2 cells inside it).
    let (cy0, crows) = (y0 / 2, rows.div_ceil(2));
    pool::composite::<P>(isa, &fv.as_view(), &j.coarse.rows(cy0, crows)?, &av, out, 0)
}

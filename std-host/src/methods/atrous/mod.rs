//! `atrous` (edge-avoiding à-trous, 5 levels) and `sure-atrous` (the same
//! levels with SURE shrinkage of the detail coefficients).
//!
//! When the frame carries the second estimate `B.*`, both methods filter the
//! mean `M = (A + B) / 2` of the two estimates (so they see the same samples),
//! and the noise comes from the frame itself:
//! - noise variance of the input per pixel: `v = |A - B|^2 / 4` (the variance
//!   of `M`, unbiased for independent `A`, `B`), mean over channels, 3x3
//!   box, capped at [`NOISE_CAP`] times its 3x3 median and floored at the
//!   noise floor (below);
//! - `sure-atrous` filters `M` and `H = (A - B) / 2` with the *same* weights
//!   (guided by `M`, so the levels of `M` are exactly the baseline's); the
//!   detail of `M` is `D_M` and its noise variance `|D_H|^2` (which equals
//!   `|D_A - D_B|^2 / 4`: the filter is linear).
//!   That is an unbiased, per-pixel, per-level estimate of the detail noise
//!   with no model of the filter's effective kernel. `H` is stored times
//!   `sqrt(SURE_SAFETY_PAIR)`, so SURE sees that noise times the factor
//!   (see [`SURE_SAFETY_PAIR`]).
//!
//! Without `B.*` the input's noise variance is estimated locally,
//! `0.84 |y - median of the 8 neighbours|^2` (about unbiased for white noise
//! on a locally flat signal, and blind to a single edge), then a 3x3 median
//! (scaled to the mean for white noise), floored at a quarter of the frame's
//! median 5x5 sample variance ([`NOISE_FLOOR_DIV`]); `sure-atrous` then
//! propagates it (times [`SURE_SAFETY_SINGLE`]) through the levels with the
//! squared normalised weights (as SVGF does) and takes
//! `Var(D_i) = Var(c_i) (1 - 2 w_centre) + Var(c_{i+1})` per channel.
//!
//! Before all that, unless `--firefly-clamp 0`, each estimate is demodulated
//! and its fireflies clamped ([`FIREFLY_K`], `prepare::firefly_clamp`). The
//! colour gate's multiple defaults to [`PHI_PAIR`] or [`PHI_SINGLE`], and the
//! geometry adds a world-space distance term ([`DISTANCE_TOLERANCE`]).
//! Pixels without albedo (emitters, [`crate::methods::EMITTER_ALBEDO`]) are
//! demodulated and remodulated by 1.
//!
//! The SURE of linear shrinkage is summed over a 5x5 window and the three
//! channels; [`mcdenoise_core::atrous::sure_shrink_levels`] picks per pixel
//! and level from {0, 0.2, 0.4, 0.6, 0.8, 1} (the rule is
//! [`mcdenoise_core::atrous::best_beta`]). With albedo, everything runs on
//! demodulated irradiance `c / (albedo + 0.001)`.

use std::marker::PhantomData;

use mcdenoise_core::atrous::{self, noise, AtrousGuides, AtrousParams, SureSource, SURE_CANDIDATES};
use mcdenoise_core::softmax::{self, WindowPath};
use mcdenoise_core::{View, ViewMut};

use super::{Ctx, Denoiser, Plan, Timings};
use crate::error::{HostError, Result};
use crate::io::frame::{Buffer, Frame, FrameInfo};
use crate::runtime::memory::{Footprint, Ledger};
use crate::runtime::precision::{store_bytes, store_is, HostPrecision, Kind, Planes};

mod plan;
mod prepare;

use crate::methods::features::{self, is_emitter};
use prepare::{demodulate, firefly_clamp, prepare, Bufs, RUN};

/// Levels (hole spacings 1, 2, 4, 8, 16).
pub const LEVELS: u32 = 5;
/// Radius of the box the noise variance estimate is smoothed with (3x3, as SVGF).
pub const NOISE_RADIUS: usize = 1;
/// Tangent-plane tolerance as a fraction of the scene scale.
pub const PLANE_TOLERANCE: f32 = 0.005;
/// The distance term's scale (`AtrousParams::sigma_distance`) as a fraction
/// of the scene scale, at the base noise level: on the test corpus 0.03
/// beat 0.02 and 0.05 overall and gained 2 to 5 dB over no distance term
/// (docs/quality.md). Each frame multiplies it by [`distance_scale`] of its
/// noise level.
pub const DISTANCE_TOLERANCE: f32 = 0.017;
/// Default `phi_color` with the second estimate `B.*`.
pub const PHI_PAIR: f32 = 64.0;
/// Default `phi_color` with one estimate. The local noise estimate is a
/// median of squared deviations: for Monte Carlo noise, whose distribution
/// has a long bright tail, it sits 2 to 5 times below the variance, and the
/// corpus sweep (docs/quality.md) puts the best multiple near 2048.
pub const PHI_SINGLE: f32 = 2048.0;
/// Above this relative noise ([`NoiseStats::relative`]) with one estimate,
/// the default `phi_color` is multiplied by the ratio (up to
/// [`PHI_MAX_SCALE`]). There most 5x5 windows hold a few bright samples
/// among zeros (sparse light at 1 spp), and the noise estimates
/// (median-based with one estimate; capped, with the pair) sit far below the
/// variance. On the corpus only the dim room is above it (5.4): +1.2 dB
/// there; the others (up to 0.43) are unchanged (docs/quality.md).
pub const PHI_REL_SINGLE: f32 = 1.0;
/// The same with the pair (half the relative noise for the same samples):
/// the dim room (2.9) gains 2.4 dB.
pub const PHI_REL_PAIR: f32 = 0.5;
/// Above this relative noise of the (first) estimate, the firefly clamp's
/// threshold is multiplied by the ratio: on the corpus's dim room (5.4),
/// whose light arrives as sparse bright samples, the clamp at its
/// default threshold cost 0.4 dB with the pair and 0.8 dB with one
/// estimate once the colour gate widened there ([`PHI_REL_SINGLE`]).
pub const CLAMP_REL: f32 = 1.0;
/// The largest multiple of the default `phi_color` the noise level sets.
pub const PHI_MAX_SCALE: f32 = 16.0;
/// The single estimate's noise floor is the frame's median 5x5 sample
/// variance over this: 4 lifted the dim 1-spp corpus scene by 9 dB and
/// moved the others by under 0.5 dB either way (docs/quality.md).
pub const NOISE_FLOOR_DIV: f32 = 4.0;
/// With the pair, a pixel's noise variance (the 3x3 box average of
/// `|A - B|^2 / 4`) is capped at this many times the 3x3 median of the
/// same (or the noise floor, if larger). On the corpus, 256 gained 0.3 to
/// 1.4 dB on six scenes, lost 0.56 dB on the 16-spp box (whose pixels
/// straddling the light's edge are then filtered towards the ceiling) and
/// brought fixed point on the 4-spp box from 39 to 47 dB of f32: f32 had
/// relied on variances above what the fixed-point guide holds
/// (docs/quality.md).
pub const NOISE_CAP: f32 = 256.0;
/// The relative noise ([`distance_scale`]) at which the distance term has
/// its base scale, with one estimate. The corpus's 16-spp Cornell box is
/// near it; its 1-spp rooms (0.15 to 6) get 1.2 to 3 times the distance,
/// its 64-spp scenes 0.75 (docs/quality.md).
pub const DISTANCE_REL_SINGLE: f32 = 0.08;
/// The same with the pair (whose mean has half the variance of one
/// estimate, so half the relative noise for the same samples per pixel).
pub const DISTANCE_REL_PAIR: f32 = 0.04;
/// On a light's outline the noise is raised at most this many times
/// ([`light_outline`]).
pub const OUTLINE_CAP: f32 = 256.0;
/// In fixed point the noise floor is held with at least this many steps
/// of the noise guide's format ([`noise_frac`]).
pub const NOISE_FLOOR_LSB: f32 = 64.0;
/// The noise floor's median is taken on every 4th pixel in each direction
/// (frames at least 32 pixels on a side).
pub const FLOOR_STRIDE: usize = 4;
/// SURE's noise term with the second estimate is multiplied by this. The
/// risk is estimated over a 5x5 window of heavy-tailed Monte Carlo noise, so
/// it is itself noisy, and taking the candidate of least estimated risk
/// favours the ones whose noise was underestimated: it keeps noise. A
/// safety factor moves the choice towards `beta = 0` (plain à-trous); on the
/// corpus 1 lost up to 1.4 dB to `atrous`, 4 up to 0.05 dB; once the
/// distance term widened with the noise, 16 lost 0.07 dB on the dim room,
/// 64 at most 0.01 (docs/quality.md).
pub const SURE_SAFETY_PAIR: f32 = 64.0;
/// The same for one estimate, whose propagated variance comes from the
/// local estimate (2 to 5 times below the variance, see [`PHI_SINGLE`]):
/// 64 lost 0.12 dB to `atrous` on the dim room, 256 none.
pub const SURE_SAFETY_SINGLE: f32 = 256.0;
/// Default threshold of the firefly clamp with one estimate, in local
/// standard deviations (`--firefly-clamp`).
pub const FIREFLY_K: f32 = 6.0;
/// The same with the pair. Its noise estimate and the distance term's
/// noise-driven width already spread a firefly thin, and clamping takes
/// energy: on the dim 1+1-spp room 6 cost 0.8 dB against no clamp, 16 gains
/// 0.1 there and 1.0 and 0.4 dB on the glossy and HDR rooms
/// (docs/quality.md).
pub const FIREFLY_K_PAIR: f32 = 16.0;

/// The à-trous methods.
pub struct Atrous<P: HostPrecision> {
    name: &'static str,
    plan: Plan,
    sure: bool,
    pair: bool,
    demod: bool,
    use_normal: bool,
    use_position: bool,
    use_depth: bool,
    params: AtrousParams,
    /// `phi_color` is the default (not given by the user).
    phi_auto: bool,
    /// Firefly clamp threshold (0: off).
    clamp: f32,
    bufs: Option<Bufs<P::Store>>,
    _p: PhantomData<P>,
}

impl<P: HostPrecision> Atrous<P> {
    /// Memory per frame (see [`crate::runtime::memory`]), replaying
    /// [`Denoiser::denoise`]: the buffers kept across frames (`Bufs`), the
    /// guides and level-0 images in storage (f32 borrows the frame's), the
    /// output, the fixed-point decode of the kept levels (`sure-atrous`) and
    /// the output's round trip through the storage type; with the band
    /// scratch of `threads` threads at the frame's width.
    pub fn footprint(info: &FrameInfo, sure: bool, settings: &crate::methods::Settings) -> Footprint {
        let threads = settings.threads;
        let s = store_bytes::<P>();
        let (f32s, f16s) = (store_is::<P, f32>(), store_is::<P, half::f16>());
        let has = |b: Buffer| u64::from(info.has(b));
        let pair = info.has(Buffer::ColorB);
        let (normal, position) = (has(Buffer::Normal), has(Buffer::Position));
        let depth = u64::from(position == 0) * has(Buffer::Depth);
        let groups = if sure && pair { 2 } else { 1 };
        let single = u64::from(sure && !pair);
        let (nsrc, nout) = (3 * groups + single, 3 * groups + 2 * single);
        let levels = LEVELS as u64;
        // c0, noise_raw, noise, zeros, the level outputs, out.
        let kept = 4 * nsrc + 3 * 4 + if sure { levels * nout * s } else { 2 * nout * s } + 12;
        // The firefly clamp's planes.
        let k = settings.firefly_clamp.unwrap_or(if pair { FIREFLY_K_PAIR } else { FIREFLY_K });
        let kept = kept + 4 * clamp_planes(k, pair) as u64;
        // The demodulation factor (3 f32 planes, with albedo).
        let kept = kept + 12 * has(Buffer::Albedo);
        let guides = if f32s { 0 } else { s + 3 * s * normal + 3 * s * position + s * depth + nsrc * s };
        let mut l = Ledger::default();
        l.alloc(kept);
        if !f32s {
            l.alloc(guides - nsrc * s).alloc(nsrc * s);
        }
        l.alloc(12); // the output
        if sure && !f32s && !f16s {
            l.temp(4 * (nsrc + levels * nout)); // every level decoded for the shrinkage
        }
        if !f32s {
            l.alloc(3 * s).alloc(12).free(12).free(3 * s);
        }
        l.free(guides);
        let w = info.width;
        let mut len = (0..LEVELS).map(atrous::step_scratch_len::<P>).max().unwrap_or(0);
        if pair {
            let k = 2 * NOISE_RADIUS + 1;
            len = len.max(softmax::window_scratch_len::<mcdenoise_core::F32>(WindowPath::BoxSum, k, 1, w));
        }
        if sure {
            len = len.max(atrous::sure_levels_scratch_len(LEVELS as usize, w));
        }
        Footprint { kept, peak: l.peak(), scratch: 4 * (threads as u64) * len as u64 }
    }
}

/// Runs a core kernel over bands of `dst` on the context's threads.
fn bands<T: Send>(
    ctx: &mut Ctx,
    dst: ViewMut<'_, T>,
    align: usize,
    scratch_len: usize,
    f: impl Fn(&mut ViewMut<'_, T>, usize, &mut [f32]) -> mcdenoise_core::Result<()> + Sync,
) -> Result<()> {
    Ok(ctx.pool.bands(dst, align, &mut ctx.scratch, scratch_len, f)?)
}

/// Normalised box average over a `2r+1` window of the `channels` planes of
/// `src` into `out` (the importance filter with all logits equal).
#[allow(clippy::too_many_arguments)]
fn box_average(
    ctx: &mut Ctx,
    src: &[f32],
    zeros: &[f32],
    channels: usize,
    w: usize,
    h: usize,
    r: usize,
    out: &mut [f32],
) -> Result<()> {
    let (k, isa) = (2 * r + 1, ctx.isa);
    let len = softmax::window_scratch_len::<mcdenoise_core::F32>(WindowPath::BoxSum, k, channels, w);
    let sv = View::new(src, channels, w, h)?;
    let zv = View::new(zeros, channels, w, h)?;
    bands(ctx, ViewMut::new(out, channels, w, h)?, 48, len, |band, y0, s| {
        softmax::window_filter::<mcdenoise_core::F32>(isa, WindowPath::BoxSum, k, &zv, &sv, band, y0, s)
    })
}

/// f32 data in the pipeline's storage: borrowed when that is f32, else encoded.
enum Held<'a, T: bytemuck::Pod> {
    Borrowed(&'a [T]),
    Owned(Planes<T>),
}

impl<'a, T: bytemuck::Pod + Default> Held<'a, T> {
    fn new<P: HostPrecision<Store = T>>(d: &'a [f32], ch: usize, w: usize, h: usize, kind: Kind) -> Self {
        Self::with_frac::<P>(d, ch, w, h, || P::choose_frac(d, kind))
    }
    /// As [`Held::new`], in the fixed-point format `frac()` gives (asked
    /// only when the data is encoded).
    fn with_frac<P: HostPrecision<Store = T>>(
        d: &'a [f32],
        ch: usize,
        w: usize,
        h: usize,
        frac: impl FnOnce() -> i8,
    ) -> Self {
        match P::borrow_f32(d) {
            Some(s) => Held::Borrowed(s),
            None => Held::Owned(Planes::encode_frac::<P>(ch, w, h, d, frac())),
        }
    }
    fn view(&self, ch: usize, w: usize, h: usize) -> View<'_, T> {
        match self {
            Held::Borrowed(s) => View::new(s, ch, w, h).expect("shape"),
            Held::Owned(p) => p.view(),
        }
    }
    fn frac(&self) -> i8 {
        match self {
            Held::Borrowed(_) => 0,
            Held::Owned(p) => p.frac,
        }
    }
    fn data(&self) -> &[T] {
        match self {
            Held::Borrowed(s) => s,
            Held::Owned(p) => &p.data[..],
        }
    }
}

/// Every level's SURE shrinkage and the reconstruction `c_N + sum beta_i
/// D_i` into `out` (3 planes), in bands, one pass over the level images
/// (`images[0]` the first level's input, then each level's output: data,
/// planes, fixed-point format). Storage other than f32 and f16 (fixed point)
/// is decoded to f32 first.
fn shrink_levels<P: HostPrecision>(
    ctx: &mut Ctx,
    source: SureSource,
    images: &[(&[P::Store], usize, i8)],
    out: &mut [f32],
    w: usize,
    h: usize,
) -> Result<()> {
    let isa = ctx.isa;
    let len = atrous::sure_levels_scratch_len(images.len() - 1, w);
    let ov = ViewMut::new(out, 3, w, h)?;
    macro_rules! go {
        ($data:expr) => {{
            let views = images
                .iter()
                .zip($data)
                .map(|(&(_, c, _), d)| View::new(d, c, w, h))
                .collect::<std::result::Result<Vec<_>, _>>()?;
            bands(ctx, ov, 1, len, |band, y0, s| {
                atrous::sure_shrink_levels(isa, source, &SURE_CANDIDATES, &views, band, y0, s)
            })
        }};
    }
    let f32s: Option<Vec<&[f32]>> = images.iter().map(|&(d, _, _)| P::store_as_f32(d)).collect();
    let f16s: Option<Vec<&[half::f16]>> = images.iter().map(|&(d, _, _)| P::store_as_f16(d)).collect();
    if let Some(d) = f32s {
        go!(d)
    } else if let Some(d) = f16s {
        go!(d)
    } else {
        let decoded: Vec<Vec<f32>> = images
            .iter()
            .map(|&(d, _, frac)| {
                let mut v = vec![0.0f32; d.len()];
                P::decode(d, &mut v, frac);
                v
            })
            .collect();
        go!(decoded.iter().map(|v| &v[..]))
    }
}

impl<P: HostPrecision> Denoiser for Atrous<P> {
    fn name(&self) -> &'static str {
        self.name
    }
    fn plan(&self) -> &Plan {
        &self.plan
    }
    fn denoise(&mut self, f: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        let (w, h) = (f.width, f.height);
        let n = w * h;
        let need = |b: Buffer, on: bool| -> Result<Option<&[f32]>> {
            if !on {
                return Ok(None);
            }
            f.get(b)
                .map(Some)
                .ok_or_else(|| HostError::bad(&f.path, format!("lacks {} channels the first frame had", b.name())))
        };
        let a = f.require(Buffer::Color, self.name)?;
        let b = need(Buffer::ColorB, self.pair)?;
        let albedo = need(Buffer::Albedo, self.demod)?;
        let normal = need(Buffer::Normal, self.use_normal)?;
        let position = need(Buffer::Position, self.use_position)?;
        let depth = need(Buffer::Depth, self.use_depth)?;
        // Level images: [M, H] (sure with a pair), [M] or [A] otherwise, +
        // variance (sure, single); a level's output adds the filtered
        // variance and the centre weight (sure, single).
        let sure_pair = self.sure && self.pair;
        let sure_single = self.sure && !self.pair;
        let groups = if sure_pair { 2 } else { 1 };
        let nsrc = 3 * groups + usize::from(sure_single);
        let nout = 3 * groups + 2 * usize::from(sure_single);
        let bufs = match self.bufs.take() {
            Some(bf) if bf.n == n && bf.ping.width == w && bf.ping.channels == nout => bf,
            _ => Bufs::new(w, h, nsrc, nout, self.sure, clamp_planes(self.clamp, self.pair)),
        };
        let mut bf = bufs;
        let result = self.run(f, ctx, t, &mut bf, (a, b, albedo, normal, position, depth), (groups, nsrc, nout));
        self.bufs = Some(bf);
        result
    }
}

/// The frame's buffers a run reads.
type Inputs<'a> =
    (&'a [f32], Option<&'a [f32]>, Option<&'a [f32]>, Option<&'a [f32]>, Option<&'a [f32]>, Option<&'a [f32]>);

impl<P: HostPrecision> Atrous<P> {
    #[allow(clippy::type_complexity)]
    fn run(
        &self,
        f: &Frame,
        ctx: &mut Ctx,
        t: &mut Timings,
        bf: &mut Bufs<P::Store>,
        (a, b, albedo, normal, position, depth): Inputs<'_>,
        (groups, nsrc, nout): (usize, usize, usize),
    ) -> Result<Vec<f32>> {
        let (w, h) = (f.width, f.height);
        let n = w * h;
        let mut demod_buf = std::mem::take(&mut bf.demod);
        let demod = match albedo {
            Some(al) => {
                demod_buf.resize(3 * n, 0.0);
                t.time("demodulation factor", || features::demodulation(&ctx.pool, al, w, h, &mut demod_buf));
                Some(&demod_buf[..])
            }
            None => None,
        };
        let result =
            self.run_demodulated(f, ctx, t, bf, (a, b, albedo, demod), (normal, position, depth), (groups, nsrc, nout));
        bf.demod = demod_buf;
        result
    }

    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn run_demodulated(
        &self,
        f: &Frame,
        ctx: &mut Ctx,
        t: &mut Timings,
        bf: &mut Bufs<P::Store>,
        (a, b, albedo, demod): (&[f32], Option<&[f32]>, Option<&[f32]>, Option<&[f32]>),
        (normal, position, depth): (Option<&[f32]>, Option<&[f32]>, Option<&[f32]>),
        (groups, nsrc, nout): (usize, usize, usize),
    ) -> Result<Vec<f32>> {
        let (w, h) = (f.width, f.height);
        let n = w * h;
        let sure_pair = self.sure && self.pair;
        let sure_single = self.sure && !self.pair;
        // The firefly clamp works on the demodulated estimates, which
        // prepare then reads instead of the frame's.
        let (pa, pb, demod_by) = if self.clamp > 0.0 {
            let k = self.clamp;
            let (ca, rest) = bf.clamp.split_at_mut(3 * n);
            let (cb, scratch) = rest.split_at_mut(if b.is_some() { 3 * n } else { 0 });
            t.time("firefly clamp", || {
                demodulate(ctx, a, demod, ca);
                // In sparse light (relative noise of one estimate above
                // CLAMP_REL) the threshold rises with the noise level: the
                // bright samples are most of the signal there.
                let rel = noise_floor(ctx, ca, w, h, scratch).relative;
                let k = k * (rel / CLAMP_REL).clamp(1.0, 1e6);
                firefly_clamp(ctx, ca, a, albedo, scratch, w, h, k);
                if let Some(b) = b {
                    demodulate(ctx, b, demod, cb);
                    firefly_clamp(ctx, cb, b, albedo, scratch, w, h, k);
                }
            });
            (&*ca, b.map(|_| &*cb), None)
        } else {
            (a, b, demod)
        };
        t.time("prepare", || prepare(ctx, n, pa, pb, demod_by, sure_pair, &mut bf.c0, &mut bf.noise_raw));
        // Noise variance of the filtered input, per pixel.
        let mut stats = NoiseStats::default();
        t.time("noise estimate", || -> Result<()> {
            // The floor: where most samples are 0 (a dim region at 1 spp)
            // the median-based estimate is 0 and would stop all smoothing;
            // with a pair, a variance of 0 (or below fixed point's
            // resolution) would do the same. (`bf.out` is free until the
            // reconstruction: scratch here.)
            stats = noise_floor(ctx, &bf.c0[..3 * n], w, h, &mut bf.out[..2 * n]);
            let floor = stats.floor;
            if b.is_some() {
                box_average(ctx, &bf.noise_raw, &bf.zeros, 1, w, h, NOISE_RADIUS, &mut bf.noise)?;
                // The cap: a pixel's box average is at most NOISE_CAP times
                // its 3x3 median (or the floor), so that one neighbour's
                // huge variance (a pixel straddling a light's edge,
                // demodulated by a small albedo) does not open the pixel's
                // colour gate to that neighbour.
                let med = &mut bf.out[..n];
                median3(ctx, &bf.noise_raw, w, h, med)?;
                let (med, raw, al) = (&*med, &bf.noise_raw[..], albedo);
                ctx.pool.planes(vec![&mut bf.noise[..]], 1 << 14, |s, runs| {
                    for (v, &m) in runs[0].iter_mut().zip(&med[s..]) {
                        *v = v.min(NOISE_CAP * m.max(floor)).max(floor);
                    }
                });
                if let Some(al) = al {
                    light_outlines(ctx, &mut bf.noise, raw, al, w, h);
                }
            } else {
                local_noise(ctx, &bf.c0[..3 * n], w, h, &mut bf.noise_raw)?;
                // A 3x3 median, not a box: where the local estimate mistook an
                // edge for noise, those pixels are a minority of the window.
                median3(ctx, &bf.noise_raw, w, h, &mut bf.noise)?;
                ctx.pool.planes(vec![&mut bf.noise[..]], 1 << 14, |_, runs| {
                    for v in runs[0].iter_mut() {
                        *v = v.max(floor);
                    }
                });
                if let Some(al) = albedo {
                    light_outlines(ctx, &mut bf.noise, &bf.noise_raw, al, w, h);
                }
            }
            Ok(())
        })?;
        // Unless the user set it, the colour gate widens with a noise level
        // above that of 1-spp light, where the noise estimates fall short of
        // the variance; SURE's noise term (one estimate) by the same factor.
        let phi_scale = if self.phi_auto {
            let r1 = if self.pair { PHI_REL_PAIR } else { PHI_REL_SINGLE };
            (stats.relative / r1).clamp(1.0, PHI_MAX_SCALE)
        } else {
            1.0
        };
        if sure_single {
            bf.c0[3 * n..4 * n].copy_from_slice(&bf.noise);
            for v in &mut bf.c0[3 * n..4 * n] {
                *v *= SURE_SAFETY_SINGLE * phi_scale;
            }
        }
        // The guides and the level-0 images in the storage precision (the
        // frame's own f32 data when that is the precision).
        let (noise_g, normal_g, position_g, depth_g, c0) = t.time("guides", || {
            (
                Held::with_frac::<P>(&bf.noise, 1, w, h, || noise_frac::<P>(&bf.noise, stats.floor)),
                normal.map(|d| Held::new::<P>(d, 3, w, h, Kind::Unit)),
                position.map(|d| Held::new::<P>(d, 3, w, h, Kind::Plain)),
                depth.map(|d| Held::new::<P>(d, 1, w, h, Kind::Plain)),
                // The format from the images alone: `sure-atrous`'s variance
                // plane (one estimate) shares it and may saturate (SURE then
                // reads "more noise than representable", and smooths).
                Held::with_frac::<P>(&bf.c0, nsrc, w, h, || P::choose_frac(&bf.c0[..3 * groups * n], Kind::Image)),
            )
        });
        let guides = AtrousGuides {
            noise: noise_g.view(1, w, h),
            normal: normal_g.as_ref().map(|p| p.view(3, w, h)),
            position: position_g.as_ref().map(|p| p.view(3, w, h)),
            depth: depth_g.as_ref().map(|p| p.view(1, w, h)),
        };
        let (isa, mut params) = (ctx.isa, self.params);
        // The distance term widens with the frame's noise level.
        let r0 = if self.pair { DISTANCE_REL_PAIR } else { DISTANCE_REL_SINGLE };
        params.sigma_distance *= distance_scale(stats.relative, r0);
        params.phi_color *= phi_scale;
        let source = if sure_pair { SureSource::Pair } else { SureSource::Single };
        let frac = c0.frac();
        bf.ping.frac = frac;
        bf.pong.frac = frac;
        let mut out = vec![0.0f32; 3 * n];
        // What remodulation reads when there is albedo (else the result is
        // already in `out`).
        let base: Option<&[f32]> = if self.sure {
            // Every level's output kept, then one pass of shrinkage and
            // reconstruction (c_N + the kept detail) over all of them.
            for l in &mut bf.levels {
                l.frac = frac;
            }
            for level in 0..LEVELS {
                let (done, rest) = bf.levels.split_at_mut(level as usize);
                let cv = match done.last() {
                    None => c0.view(nsrc, w, h),
                    Some(prev) => prev.view().channels_range(0, nsrc)?,
                };
                let dv = rest[0].view_mut();
                t.time("a-trous levels", || {
                    bands(ctx, dv, 1, atrous::step_scratch_len::<P>(level), |band, y0, s| {
                        atrous::step::<P>(isa, level, groups, sure_single, &params, &guides, &cv, band, y0, s)
                    })
                })?;
            }
            let mut images = vec![(c0.data(), nsrc, frac)];
            images.extend(bf.levels.iter().map(|l| (&l.data[..], nout, frac)));
            let sum = if albedo.is_some() { &mut bf.out[..] } else { &mut out[..] };
            t.time("SURE shrinkage + reconstruct", || shrink_levels::<P>(ctx, source, &images, sum, w, h))?;
            albedo.map(|_| &bf.out[..])
        } else {
            let (mut src, mut dst) = (&mut bf.ping, &mut bf.pong);
            for level in 0..LEVELS {
                // Level 0 reads the prepared images; later levels the previous
                // output's first nsrc planes.
                let cv = if level == 0 { c0.view(nsrc, w, h) } else { src.view().channels_range(0, nsrc)? };
                let dv = dst.view_mut();
                t.time("a-trous levels", || {
                    bands(ctx, dv, 1, atrous::step_scratch_len::<P>(level), |band, y0, s| {
                        atrous::step::<P>(isa, level, groups, sure_single, &params, &guides, &cv, band, y0, s)
                    })
                })?;
                debug_assert_eq!(dst.channels, nout);
                std::mem::swap(&mut src, &mut dst);
            }
            // c_N of the first image (the last output, now in src), then
            // remodulated: read in place when the level output is f32, else
            // decoded into `bf.out` (or the output) first.
            let last = src;
            match P::store_as_f32(&last.data[..3 * n]).filter(|_| albedo.is_some()) {
                Some(c) => Some(c),
                None => {
                    t.time("reconstruct", || {
                        let sum = if albedo.is_some() { &mut bf.out[..] } else { &mut out[..] };
                        let (data, frac) = (&last.data[..3 * n], last.frac);
                        // Runs of whole rows in parallel (a serial pass was 2 ms of a 2-thread frame).
                        ctx.pool.planes(vec![sum], w * 32, |start, runs| {
                            let o = &mut *runs[0];
                            let src = &data[start..start + o.len()];
                            match P::store_as_f32(src) {
                                Some(c) => o.copy_from_slice(c),
                                None => P::decode(src, o, frac),
                            }
                        });
                    });
                    albedo.map(|_| &bf.out[..])
                }
            }
        };
        if let (Some(d), Some(base)) = (demod, base) {
            t.time("remodulate", || {
                ctx.pool.planes(out.chunks_mut(n).collect(), RUN, |s, runs| {
                    for (c, o) in runs.iter_mut().enumerate() {
                        let (bc, dc) = (&base[c * n + s..], &d[c * n + s..]);
                        for ((o, &v), &q) in o.iter_mut().zip(bc).zip(dc) {
                            *o = v * q;
                        }
                    }
                })
            });
        }
        // The output passes through the pipeline's storage precision.
        if P::borrow_f32(&out).is_none() {
            out = Planes::<P::Store>::encode::<P>(3, w, h, &out).decode::<P>();
        }
        Ok(out)
    }
}

/// The noise guide's fixed-point format: the image policy's (its 99.9th
/// percentile representable), or finer where that leaves the noise floor
/// fewer than [`NOISE_FLOOR_LSB`] steps. The colour gate divides by the
/// variance, so it needs relative precision at the low end; at 1 spp in a
/// scene with a visible light the variance spans 7 decades, more than i16
/// holds, and the bright tail saturates instead (a gate a little narrower
/// on the noisiest pixels, against one that closes on every quiet pixel).
fn noise_frac<P: HostPrecision>(noise: &[f32], floor: f32) -> i8 {
    let image = P::choose_frac(noise, Kind::Image);
    if !(P::FIXED_POINT && floor > 0.0 && floor.is_finite()) {
        return image;
    }
    let need = (NOISE_FLOOR_LSB / floor).log2().ceil().clamp(-8.0, 14.0) as i8;
    image.max(need)
}

/// On a light's outline (a pixel that is not an emitter with an emitter in
/// its 3x3 window), some of a pixel's samples see the light and others do
/// not: its noise `v` is raised to the largest raw estimate among the
/// window's non-emitters, so that the colour gate lets those pixels average
/// with each other (the emitters themselves stay apart: their own noise is
/// small and the gate takes the smaller of the two pixels'). At most
/// [`OUTLINE_CAP`] times the pixel's own (floored) noise: an unbounded raise
/// (the raw estimate of a pixel demodulated by a small albedo) set the
/// fixed-point format of `sure-atrous`'s variance plane and lost the rest.
///
/// In runs of whole rows; a row with no emitter within one row of it (the
/// common case, tested on the first albedo plane) is skipped.
fn light_outlines(ctx: &Ctx, noise: &mut [f32], raw: &[f32], al: &[f32], w: usize, h: usize) {
    let n = w * h;
    if n == 0 {
        return;
    }
    let row_has = |y: usize| (y * w..(y + 1) * w).any(|i| is_emitter(al, n, i));
    ctx.pool.planes(vec![noise], w * 16, |s, runs| {
        let run = &mut *runs[0];
        let (ya, yb) = (s / w, (s + run.len()) / w);
        for y in ya..yb {
            if !(y.saturating_sub(1)..(y + 2).min(h)).any(row_has) {
                continue;
            }
            for x in 0..w {
                let i = y * w + x;
                light_outline(&mut run[i - s], y, x, raw, al, w, h);
            }
        }
    });
}

fn light_outline(v: &mut f32, y: usize, x: usize, raw: &[f32], al: &[f32], w: usize, h: usize) {
    let n = w * h;
    if is_emitter(al, n, y * w + x) {
        return;
    }
    let (ya, yb, xa, xb) = (y.saturating_sub(1), (y + 2).min(h), x.saturating_sub(1), (x + 2).min(w));
    if !(ya..yb).any(|yy| (xa..xb).any(|xx| is_emitter(al, n, yy * w + xx))) {
        return;
    }
    let cap = OUTLINE_CAP * *v;
    for yy in ya..yb {
        for xx in xa..xb {
            let q = yy * w + xx;
            if !is_emitter(al, n, q) {
                *v = v.max(raw[q].min(cap));
            }
        }
    }
}

/// The local noise variance of the single estimate `y` (3 planes) into `v`
/// (core's [`noise::local_noise_rows`]), in bands.
fn local_noise(ctx: &mut Ctx, y: &[f32], w: usize, h: usize, v: &mut [f32]) -> Result<()> {
    let src = View::new(y, 3, w, h)?;
    bands(ctx, ViewMut::new(v, 1, w, h)?, 1, 0, |band, y0, _| noise::local_noise_rows(&src, band, y0))
}

/// The scaled 3x3 median of `v` into `out` (core's [`noise::median3_rows`]), in bands.
fn median3(ctx: &mut Ctx, v: &[f32], w: usize, h: usize, out: &mut [f32]) -> Result<()> {
    let src = View::new(v, 1, w, h)?;
    bands(ctx, ViewMut::new(out, 1, w, h)?, 1, 0, |band, y0, _| noise::median3_rows(&src, band, y0))
}

/// Planes the firefly clamp keeps (demodulated `A`, `B` with a pair, the
/// luminance, the factor and two planes of row sums), 0 when it is off.
fn clamp_planes(k: f32, pair: bool) -> usize {
    if k > 0.0 {
        3 + 3 * usize::from(pair) + 4
    } else {
        0
    }
}

/// What the frame's noise says: [`noise_floor`]'s floor and the median
/// relative variance.
#[derive(Clone, Copy, Debug, Default)]
struct NoiseStats {
    /// The noise floor.
    floor: f32,
    /// The median over the grid of the 5x5 sample variance over the squared
    /// 5x5 mean (both over the channels): about 1/spp times the samples'
    /// relative variance, a scene's noise level independent of its exposure.
    relative: f32,
}

/// The noise floor: the median over the frame (on a grid of every
/// [`FLOOR_STRIDE`]-th pixel) of the 5x5 sample variance of `y` (3 planes,
/// mean over the channels), over [`NOISE_FLOOR_DIV`]; and the median of
/// that variance relative to the squared mean ([`NoiseStats`]). `tmp` (`2 w
/// h` floats) is overwritten. The median of windowed variances is blind to
/// edges (a minority of windows) but, unlike the median-based local
/// estimate, sees sparse bright samples.
fn noise_floor(ctx: &Ctx, y: &[f32], w: usize, h: usize, tmp: &mut [f32]) -> NoiseStats {
    let n = w * h;
    // On a grid of every FLOOR_STRIDE-th pixel in each direction: a median
    // over the frame needs no more.
    let st = if w.min(h) >= 8 * FLOOR_STRIDE { FLOOR_STRIDE } else { 1 };
    let (gw, gh) = (w.div_ceil(st), h.div_ceil(st));
    let m = gw * gh;
    if m == 0 {
        return NoiseStats::default();
    }
    let (var, rest) = tmp.split_at_mut(m);
    let rel = &mut rest[..m];
    ctx.pool.planes(vec![&mut *var, &mut *rel], gw * 16, |s, runs| {
        let (vr, rl) = runs.split_at_mut(1);
        for (j, (o, r)) in vr[0].iter_mut().zip(rl[0].iter_mut()).enumerate() {
            let g = s + j;
            let (py, px) = ((g / gw) * st + st / 2, (g % gw) * st + st / 2);
            let (py, px) = (py.min(h - 1), px.min(w - 1));
            let (mut acc, mut mean) = (0.0f64, 0.0f64);
            for c in 0..3 {
                let (mut cnt, mut s1, mut s2) = (0.0f64, 0.0f64, 0.0f64);
                for yy in py.saturating_sub(2)..(py + 3).min(h) {
                    for xx in px.saturating_sub(2)..(px + 3).min(w) {
                        let v = y[c * n + yy * w + xx] as f64;
                        cnt += 1.0;
                        s1 += v;
                        s2 += v * v;
                    }
                }
                let m = s1 / cnt;
                acc += (s2 / cnt - m * m).max(0.0);
                mean += m;
            }
            let (v, mean) = (acc / 3.0, mean / 3.0);
            *o = v as f32;
            *r = if v > 0.0 { (v / (mean * mean).max(1e-30)) as f32 } else { 0.0 };
        }
    });
    let median = |a: &mut [f32]| {
        let mid = a.len() / 2;
        let v = *a.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
        if v.is_finite() {
            v
        } else {
            0.0
        }
    };
    NoiseStats { floor: median(var) / NOISE_FLOOR_DIV, relative: median(rel) }
}

/// The distance term's multiple for a frame of relative noise `rel`
/// ([`NoiseStats::relative`]): `(rel / r0)^0.3` within [0.75, 3], with
/// `r0` [`DISTANCE_REL_PAIR`] or [`DISTANCE_REL_SINGLE`]. Noisier frames
/// want a wider support (docs/quality.md).
fn distance_scale(rel: f32, r0: f32) -> f32 {
    if !(rel > 0.0 && rel.is_finite()) {
        return 1.0;
    }
    (rel / r0).powf(0.3).clamp(0.75, 3.0)
}

//! `atrous` (edge-avoiding à-trous, 5 levels) and `sure-atrous` (the same
//! levels with SURE shrinkage of the detail coefficients).
//!
//! When the frame carries the second estimate `B.*`, both methods filter the
//! mean `M = (A + B) / 2` of the two estimates (so they see the same samples),
//! and the noise comes from the frame itself:
//! - noise variance of the input per pixel: `v = |A - B|^2 / 4` (the variance
//!   of `M`, unbiased for independent `A`, `B`), mean over channels, 3x3 box;
//! - `sure-atrous` filters `M` and `H = (A - B) / 2` with the *same* weights
//!   (guided by `M`, so the levels of `M` are exactly the baseline's); the
//!   detail of `M` is `D_M` and its noise variance `|D_H|^2` (which equals
//!   `|D_A - D_B|^2 / 4`: the filter is linear).
//!   That is an unbiased, per-pixel, per-level estimate of the detail noise
//!   with no model of the filter's effective kernel.
//!
//! Without `B.*` the input's noise variance is estimated locally,
//! `0.84 |y - median of the 8 neighbours|^2` (about unbiased for white noise
//! on a locally flat signal, and blind to a single edge), then a 3x3 median
//! (scaled to the mean for white noise); `sure-atrous` then propagates it through the
//! levels with the squared normalised weights (as SVGF does) and takes
//! `Var(D_i) = Var(c_i) (1 - 2 w_centre) + Var(c_{i+1})` per channel.
//!
//! The SURE of linear shrinkage is summed over a 5x5 window and the three
//! channels; [`mcdenoise_core::atrous::sure_pick`] picks per pixel and level
//! from {0, 0.2, 0.4, 0.6, 0.8, 1}. With albedo, everything runs on
//! demodulated irradiance `c / (albedo + 0.001)`.

use std::marker::PhantomData;

use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams, SureSource, SURE_CANDIDATES};
use mcdenoise_core::softmax::{self, WindowPath};
use mcdenoise_core::tonemap;
use mcdenoise_core::{View, ViewMut};

use super::{scene_scale, Ctx, Denoiser, Plan, Timings};
use crate::aligned::Aligned;
use crate::error::{HostError, Result};
use crate::frame::{Buffer, Frame};
use crate::precision::{HostPrecision, Kind, Planes};

/// Albedo epsilon of (de)modulation.
pub const ALBEDO_EPS: f32 = 1e-3;
/// Levels (hole spacings 1, 2, 4, 8, 16).
pub const LEVELS: u32 = 5;
/// Radius of the box the noise variance estimate is smoothed with (3x3, as SVGF).
pub const NOISE_RADIUS: usize = 1;
/// Tangent-plane tolerance as a fraction of the scene scale.
pub const PLANE_TOLERANCE: f32 = 0.005;

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
    bufs: Option<Bufs<P::Store>>,
    _p: PhantomData<P>,
}

impl<P: HostPrecision> Atrous<P> {
    /// For a sequence starting with `first`; `sure` selects `sure-atrous`.
    pub fn new(first: &Frame, sure: bool, phi_color: Option<f32>) -> Result<Self> {
        let name = if sure { "sure-atrous" } else { "atrous" };
        let pair = first.has(Buffer::ColorB);
        let demod = first.has(Buffer::Albedo);
        let use_normal = first.has(Buffer::Normal);
        let use_position = first.has(Buffer::Position);
        let use_depth = !use_position && first.has(Buffer::Depth);
        let mut plan = Plan::default();
        if demod {
            plan.built.push("demodulate");
        } else {
            plan.skipped.push(("demodulation", "no albedo".into()));
        }
        plan.built.push(if pair { "noise from A-B" } else { "local noise estimate" });
        if pair {
            plan.built.push("mean of A and B");
        } else {
            plan.skipped.push(("second estimate", "no B.R,B.G,B.B: noise estimated locally".into()));
        }
        plan.built.push("5 a-trous levels");
        if sure {
            plan.built.push("SURE shrinkage");
        }
        if demod {
            plan.built.push("remodulate");
        }
        if !use_normal {
            plan.skipped.push(("normal edge-stopping", "no normal".into()));
        }
        if !use_position && !use_depth {
            plan.skipped.push(("geometry edge-stopping", "no position or depth".into()));
        }
        let mut params = AtrousParams { sigma_plane: PLANE_TOLERANCE * scene_scale(first), ..AtrousParams::default() };
        if let Some(phi) = phi_color {
            params.phi_color = phi;
        }
        Ok(Atrous {
            name,
            plan,
            sure,
            pair,
            demod,
            use_normal,
            use_position,
            use_depth,
            params,
            bufs: None,
            _p: PhantomData,
        })
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

/// `d` as a slice of the storage type when that type is f32 (no copy).
fn as_store<T: 'static>(d: &[f32]) -> Option<&[T]> {
    if std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>() {
        // SAFETY: T is f32 (same TypeId), so the layout is the same.
        Some(unsafe { std::slice::from_raw_parts(d.as_ptr() as *const T, d.len()) })
    } else {
        None
    }
}

/// `d` as f32 when the storage type is f32 (no copy).
fn as_f32<T: 'static>(d: &[T]) -> Option<&[f32]> {
    if std::any::TypeId::of::<T>() == std::any::TypeId::of::<f32>() {
        // SAFETY: T is f32 (same TypeId).
        Some(unsafe { std::slice::from_raw_parts(d.as_ptr() as *const f32, d.len()) })
    } else {
        None
    }
}

/// `d` as f16 when the storage type is f16 (no copy).
fn as_f16<T: 'static>(d: &[T]) -> Option<&[half::f16]> {
    if std::any::TypeId::of::<T>() == std::any::TypeId::of::<half::f16>() {
        // SAFETY: T is half::f16 (same TypeId).
        Some(unsafe { std::slice::from_raw_parts(d.as_ptr() as *const half::f16, d.len()) })
    } else {
        None
    }
}

/// f32 data in the pipeline's storage: borrowed when that is f32, else encoded.
enum Held<'a, T: bytemuck::Pod> {
    Borrowed(&'a [T]),
    Owned(Planes<T>),
}

impl<'a, T: bytemuck::Pod + Default> Held<'a, T> {
    fn new<P: HostPrecision<Store = T>>(d: &'a [f32], ch: usize, w: usize, h: usize, kind: Kind) -> Self {
        match as_store::<T>(d) {
            Some(s) => Held::Borrowed(s),
            None => Held::Owned(Planes::encode_as::<P>(ch, w, h, d, kind)),
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

/// Buffers kept across the frames of a sequence (no allocation and no page
/// faults per frame once warm).
struct Bufs<T: bytemuck::Pod> {
    n: usize,
    /// Level-0 images in f32: `[M]`, `[M, H]` or `[A, variance]`.
    c0: Aligned<f32>,
    /// Raw and smoothed noise variance.
    noise_raw: Aligned<f32>,
    noise: Aligned<f32>,
    zeros: Aligned<f32>,
    /// Level outputs, alternating (`atrous`).
    ping: Planes<T>,
    pong: Planes<T>,
    /// Every level's output (`sure-atrous`: the shrinkage reads them all in
    /// one pass after the levels).
    levels: Vec<Planes<T>>,
    out: Aligned<f32>,
}

impl<T: bytemuck::Pod + Default> Bufs<T> {
    fn new(w: usize, h: usize, nsrc: usize, nout: usize, sure: bool) -> Self {
        let n = w * h;
        // `sure-atrous` keeps every level's output instead of two.
        let (rows, kept) = if sure { (0, LEVELS as usize) } else { (h, 0) };
        Bufs {
            n,
            c0: Aligned::zeroed(nsrc * n),
            noise_raw: Aligned::zeroed(n),
            noise: Aligned::zeroed(n),
            zeros: Aligned::zeroed(n),
            ping: Planes::new(nout, w, rows),
            pong: Planes::new(nout, w, rows),
            levels: (0..kept).map(|_| Planes::new(nout, w, h)).collect(),
            out: Aligned::zeroed(3 * n),
        }
    }
}

/// Pixels per job of the per-pixel passes.
const RUN: usize = 1 << 14;

/// Demodulates `a` (and `b`) and forms the level-0 images: with `b`, the
/// mean `M` (and, for `half_diff`, `H = (A - B) / 2`) and the raw noise
/// `|A - B|^2 / 12` (the variance of `M`, mean over channels); without it,
/// `A` itself.
#[allow(clippy::too_many_arguments)]
fn prepare(
    ctx: &Ctx,
    n: usize,
    a: &[f32],
    b: Option<&[f32]>,
    albedo: Option<&[f32]>,
    half_diff: bool,
    c0: &mut [f32],
    noise: &mut [f32],
) {
    let imgs = if b.is_some() && half_diff { 6 } else { 3 };
    let mut planes: Vec<&mut [f32]> = c0.chunks_mut(n).take(imgs).collect();
    planes.push(noise);
    ctx.pool.planes(planes, RUN, |s, runs| {
        let (img, nz) = runs.split_at_mut(imgs);
        let nz = &mut *nz[0];
        let len = nz.len();
        // This run of channel `c` of a frame buffer.
        fn seg(src: &[f32], c: usize, n: usize, s: usize, len: usize) -> &[f32] {
            &src[c * n + s..c * n + s + len]
        }
        // Slices of one length and the albedo test hoisted out of the loops,
        // so that the compiler may vectorise them (not checked in the
        // assembly; the stage is near memory bandwidth either way).
        match b {
            Some(b) => {
                nz.fill(0.0);
                let (mean, half) = img.split_at_mut(3);
                for (c, m) in mean.iter_mut().enumerate() {
                    let (ac, bc) = (seg(a, c, n, s, len), seg(b, c, n, s, len));
                    let mut h = half.get_mut(c).map(|v| &mut **v);
                    let mut one = |i: usize, ai: f32, bi: f32| {
                        m[i] = 0.5 * (ai + bi);
                        if let Some(h) = h.as_deref_mut() {
                            h[i] = 0.5 * (ai - bi);
                        }
                        let d = ai - bi;
                        nz[i] += d * d;
                    };
                    match albedo {
                        Some(al) => {
                            let alc = seg(al, c, n, s, len);
                            for i in 0..len {
                                let q = alc[i] + ALBEDO_EPS;
                                one(i, ac[i] / q, bc[i] / q);
                            }
                        }
                        None => {
                            for i in 0..len {
                                one(i, ac[i], bc[i]);
                            }
                        }
                    }
                }
                for v in nz.iter_mut() {
                    *v /= 12.0; // |A - B|^2 / 4, mean of 3 channels
                }
            }
            None => {
                for (c, im) in img.iter_mut().enumerate() {
                    let ac = seg(a, c, n, s, len);
                    match albedo {
                        Some(al) => {
                            for ((o, &v), &q) in im.iter_mut().zip(ac).zip(seg(al, c, n, s, len)) {
                                *o = v / (q + ALBEDO_EPS);
                            }
                        }
                        None => im.copy_from_slice(ac),
                    }
                }
            }
        }
    });
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
    let f32s: Option<Vec<&[f32]>> = images.iter().map(|&(d, _, _)| as_f32(d)).collect();
    let f16s: Option<Vec<&[half::f16]>> = images.iter().map(|&(d, _, _)| as_f16(d)).collect();
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
            _ => Bufs::new(w, h, nsrc, nout, self.sure),
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
        let sure_pair = self.sure && self.pair;
        let sure_single = self.sure && !self.pair;
        t.time("prepare", || prepare(ctx, n, a, b, albedo, sure_pair, &mut bf.c0, &mut bf.noise_raw));
        // Noise variance of the filtered input, per pixel.
        t.time("noise estimate", || -> Result<()> {
            if b.is_some() {
                box_average(ctx, &bf.noise_raw, &bf.zeros, 1, w, h, NOISE_RADIUS, &mut bf.noise)
            } else {
                local_noise(ctx, &bf.c0[..3 * n], w, h, &mut bf.noise_raw);
                // A 3x3 median, not a box: where the local estimate mistook an
                // edge for noise, those pixels are a minority of the window.
                median3(ctx, &bf.noise_raw, w, h, &mut bf.noise);
                Ok(())
            }
        })?;
        if sure_single {
            bf.c0[3 * n..4 * n].copy_from_slice(&bf.noise);
        }
        // The guides and the level-0 images in the storage precision (the
        // frame's own f32 data when that is the precision).
        let (noise_g, normal_g, position_g, depth_g, c0) = t.time("guides", || {
            (
                Held::new::<P>(&bf.noise, 1, w, h, Kind::Plain),
                normal.map(|d| Held::new::<P>(d, 3, w, h, Kind::Unit)),
                position.map(|d| Held::new::<P>(d, 3, w, h, Kind::Plain)),
                depth.map(|d| Held::new::<P>(d, 1, w, h, Kind::Plain)),
                Held::new::<P>(&bf.c0, nsrc, w, h, Kind::Image),
            )
        });
        let guides = AtrousGuides {
            noise: noise_g.view(1, w, h),
            normal: normal_g.as_ref().map(|p| p.view(3, w, h)),
            position: position_g.as_ref().map(|p| p.view(3, w, h)),
            depth: depth_g.as_ref().map(|p| p.view(1, w, h)),
        };
        let (isa, params) = (ctx.isa, self.params);
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
            match as_f32(&last.data[..3 * n]).filter(|_| albedo.is_some()) {
                Some(c) => Some(c),
                None => {
                    t.time("reconstruct", || {
                        let sum = if albedo.is_some() { &mut bf.out[..] } else { &mut out[..] };
                        let (data, frac) = (&last.data[..3 * n], last.frac);
                        // Runs of whole rows in parallel (a serial pass was 2 ms of a 2-thread frame).
                        ctx.pool.planes(vec![sum], w * 32, |start, runs| {
                            let o = &mut *runs[0];
                            let src = &data[start..start + o.len()];
                            match as_f32(src) {
                                Some(c) => o.copy_from_slice(c),
                                None => P::decode(src, o, frac),
                            }
                        });
                    });
                    albedo.map(|_| &bf.out[..])
                }
            }
        };
        if let (Some(al), Some(base)) = (albedo, base) {
            t.time("remodulate", || -> Result<()> {
                let (sv, av) = (View::new(base, 3, w, h)?, View::new(al, 3, w, h)?);
                bands(ctx, ViewMut::new(&mut out, 3, w, h)?, 1, 0, |band, y0, _| {
                    let rows = band.height();
                    tonemap::remodulate::<mcdenoise_core::F32>(
                        isa,
                        &sv.rows(y0, rows)?,
                        &av.rows(y0, rows)?,
                        ALBEDO_EPS,
                        band,
                    )
                })
            })?;
        }
        // The output passes through the pipeline's storage precision.
        if as_store::<P::Store>(&out).is_none() {
            out = Planes::<P::Store>::encode::<P>(3, w, h, &out).decode::<P>();
        }
        Ok(out)
    }
}

/// Compare-exchange: afterwards `v[i] <= v[j]` (selects, no branches, so the
/// pixel loops that run the networks below vectorise).
#[inline(always)]
fn cx<const N: usize>(v: &mut [f32; N], i: usize, j: usize) {
    let (a, b) = (v[i], v[j]);
    let swap = b < a;
    v[i] = if swap { b } else { a };
    v[j] = if swap { a } else { b };
}

/// Sorts eight values (Batcher's odd-even merge network, 19 exchanges).
#[inline(always)]
fn sort8(v: &mut [f32; 8]) {
    for (i, j) in [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (1, 2), (5, 6)] {
        cx(v, i, j);
    }
    for (i, j) in [(0, 4), (1, 5), (2, 6), (3, 7), (2, 4), (3, 5), (1, 2), (3, 4), (5, 6)] {
        cx(v, i, j);
    }
}

/// The median of nine values (a 19-exchange selection network; `v` is left
/// partly sorted).
#[inline(always)]
fn median9(v: &mut [f32; 9]) -> f32 {
    for (i, j) in [(1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3)] {
        cx(v, i, j);
    }
    for (i, j) in [(5, 8), (4, 7), (3, 6), (1, 4), (2, 5), (4, 7), (2, 4), (4, 6), (2, 4)] {
        cx(v, i, j);
    }
    v[4]
}

/// The median of the in-image values among the 3x3 neighbourhood of
/// `(px, py)` in plane `p` (`centre`: whether the pixel itself counts), by
/// sorting: the border pixels' path, and the reference of the networks.
fn median_at(p: &[f32], w: usize, h: usize, px: usize, py: usize, centre: bool) -> Option<f32> {
    let mut nb = [0.0f32; 9];
    let mut m = 0;
    for qy in py.saturating_sub(1)..(py + 2).min(h) {
        for qx in px.saturating_sub(1)..(px + 2).min(w) {
            if centre || (qy, qx) != (py, px) {
                nb[m] = p[qy * w + qx];
                m += 1;
            }
        }
    }
    let vals = &mut nb[..m];
    vals.sort_unstable_by(f32::total_cmp);
    (m > 0).then(|| if m % 2 == 1 { vals[m / 2] } else { 0.5 * (vals[m / 2 - 1] + vals[m / 2]) })
}

/// Rows `py - 1 ..= py + 1` of plane `p` when row `py` has interior pixels
/// (pixels whose 3x3 neighbourhood lies inside the image: columns `1 .. w - 1`).
fn rows_3x3(p: &[f32], w: usize, h: usize, py: usize) -> Option<[&[f32]; 3]> {
    (py >= 1 && py + 1 < h && w >= 3).then(|| core::array::from_fn(|k| &p[(py + k - 1) * w..(py + k) * w]))
}

/// The 3x3 neighbourhood of interior column `x`, row-major (centre at 4).
#[inline(always)]
fn nb_3x3(r: &[&[f32]; 3], x: usize) -> [f32; 9] {
    let (a, b, c) = (&r[0][x - 1..x + 2], &r[1][x - 1..x + 2], &r[2][x - 1..x + 2]);
    [a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]]
}

/// 3x3 median (of the in-image pixels), scaled by 1.27: the median of nine
/// chi-square(3)/3 variates is about 0.79 of their mean. Rows in parallel;
/// interior pixels through a selection network.
// Index loops: the enumerate/skip/take form measured slower (4.8-6.3 against 3.8-4.4 ms per frame).
#[allow(clippy::needless_range_loop)]
fn median3(ctx: &Ctx, v: &[f32], w: usize, h: usize, out: &mut [f32]) {
    ctx.pool.planes(vec![out], w, |start, runs| {
        let py = start / w;
        let o = &mut *runs[0];
        let border = |x: usize| 1.27 * median_at(v, w, h, x, py, true).unwrap_or(0.0);
        match rows_3x3(v, w, h, py) {
            Some(r) => {
                for x in 1..w - 1 {
                    o[x] = 1.27 * median9(&mut nb_3x3(&r, x));
                }
                o[0] = border(0);
                o[w - 1] = border(w - 1);
            }
            None => o.iter_mut().enumerate().for_each(|(x, o)| *o = border(x)),
        }
    });
}

/// The local noise variance of a single estimate: `0.84 |y - median of the
/// 8 neighbours|^2`, mean over channels. The median (not the mean) keeps an
/// edge from reading as noise: next to a light's edge the neighbours on the
/// other side are a minority. For white noise `Var(median of 8) ~ 0.2 sigma^2`,
/// hence `E|y - median|^2 ~ 1.2 sigma^2` and the factor 0.84. At borders the
/// median of the neighbours there is. Rows in parallel; interior pixels sort
/// their neighbours with a network (the border ones with a sort).
#[allow(clippy::needless_range_loop)] // as in median3
fn local_noise(ctx: &Ctx, y: &[f32], w: usize, h: usize, v: &mut [f32]) {
    let n = w * h;
    ctx.pool.planes(vec![v], w, |start, runs| {
        let py = start / w;
        let o = &mut *runs[0];
        o.fill(0.0);
        for c in 0..3 {
            let p = &y[c * n..(c + 1) * n];
            let border = |x: usize, o: &mut f32| {
                if let Some(med) = median_at(p, w, h, x, py, false) {
                    let d = p[py * w + x] - med;
                    *o += 0.84 * d * d;
                }
            };
            match rows_3x3(p, w, h, py) {
                Some(r) => {
                    for x in 1..w - 1 {
                        let nb = nb_3x3(&r, x);
                        let mut e = [nb[0], nb[1], nb[2], nb[3], nb[5], nb[6], nb[7], nb[8]];
                        sort8(&mut e);
                        let d = nb[4] - 0.5 * (e[3] + e[4]);
                        o[x] += 0.84 * d * d;
                    }
                    border(0, &mut o[0]);
                    border(w - 1, &mut o[w - 1]);
                }
                None => o.iter_mut().enumerate().for_each(|(x, o)| border(x, o)),
            }
        }
        for o in o.iter_mut() {
            *o /= 3.0;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::{context, Settings};

    /// A small generator (xorshift) of values with many ties and both zeros.
    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.max(1);
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let v = ((s >> 40) % 11) as f32 - 5.0;
                if v == 0.0 && s & 1 == 1 {
                    -0.0
                } else {
                    v * 0.37
                }
            })
            .collect()
    }

    #[test]
    fn networks_sort_and_select_like_a_sort() {
        for seed in 1..2000u64 {
            let v = values(9, seed);
            let mut sorted = v.clone();
            sorted.sort_unstable_by(f32::total_cmp);
            let mut a8: [f32; 8] = core::array::from_fn(|i| v[i]);
            sort8(&mut a8);
            let mut s8 = v[..8].to_vec();
            s8.sort_unstable_by(f32::total_cmp);
            assert!(a8.iter().zip(&s8).all(|(a, b)| a == b), "sort8 {v:?}: {a8:?}");
            let mut a9: [f32; 9] = core::array::from_fn(|i| v[i]);
            assert_eq!(median9(&mut a9), sorted[4], "median9 {v:?}");
        }
    }

    #[test]
    fn noise_estimates_equal_the_sorting_reference() {
        let ctx = context(&Settings { threads: 2, ..Settings::default() }).unwrap();
        for (w, h) in [(37, 23), (3, 3), (2, 5), (1, 1), (9, 1), (1, 7)] {
            let n = w * h;
            let img = values(3 * n, (w * 31 + h) as u64);
            let mut got = vec![f32::NAN; n];
            local_noise(&ctx, &img, w, h, &mut got);
            let mut med = vec![f32::NAN; n];
            median3(&ctx, &got, w, h, &mut med);
            for py in 0..h {
                for px in 0..w {
                    let mut s = 0.0f32;
                    for c in 0..3 {
                        let p = &img[c * n..(c + 1) * n];
                        if let Some(m) = median_at(p, w, h, px, py, false) {
                            let d = p[py * w + px] - m;
                            s += 0.84 * d * d;
                        }
                    }
                    assert_eq!(got[py * w + px], s / 3.0, "local noise {w}x{h} at ({px}, {py})");
                    let m9 = 1.27 * median_at(&got, w, h, px, py, true).unwrap();
                    assert_eq!(med[py * w + px], m9, "median3 {w}x{h} at ({px}, {py})");
                }
            }
        }
    }
}

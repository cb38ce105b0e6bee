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

use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams, SURE_CANDIDATES};
use mcdenoise_core::softmax::{self, WindowPath};
use mcdenoise_core::tonemap;
use mcdenoise_core::{View, ViewMut};

use super::{scene_scale, Ctx, Denoiser, Plan, Timings};
use crate::error::{HostError, Result};
use crate::frame::{Buffer, Frame};
use crate::precision::{HostPrecision, Kind, Planes};

/// Albedo epsilon of (de)modulation.
pub const ALBEDO_EPS: f32 = 1e-3;
/// Levels (hole spacings 1, 2, 4, 8, 16).
pub const LEVELS: u32 = 5;
/// Radius of the box the noise variance estimate is smoothed with (3x3, as SVGF).
pub const NOISE_RADIUS: usize = 1;
/// Radius of the window the SURE is summed over.
pub const SURE_RADIUS: usize = 2;
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
        Ok(Atrous { name, plan, sure, pair, demod, use_normal, use_position, use_depth, params, _p: PhantomData })
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

/// Normalised box average of the planes of `src` over a `2r+1` window
/// (the importance filter with all logits equal).
fn box_average(ctx: &mut Ctx, src: &Planes<f32>, zeros: &Planes<f32>, r: usize) -> Result<Planes<f32>> {
    let mut out = Planes::new(src.channels, src.width, src.height);
    let (k, isa) = (2 * r + 1, ctx.isa);
    let len = softmax::window_scratch_len::<mcdenoise_core::F32>(WindowPath::BoxSum, k, src.channels, src.width);
    let (sv, zv) = (src.view(), zeros.view());
    bands(ctx, out.view_mut(), 48, len, |band, y0, s| {
        softmax::window_filter::<mcdenoise_core::F32>(isa, WindowPath::BoxSum, k, &zv, &sv, band, y0, s)
    })?;
    Ok(out)
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
        // Demodulate (in f32: it is the input stage) and form the images to filter.
        let (a_irr, b_irr) = t.time("demodulate", || {
            let demod = |c: &[f32]| -> Vec<f32> {
                match albedo {
                    Some(al) => c.iter().zip(al).map(|(&v, &a)| v / (a + ALBEDO_EPS)).collect(),
                    None => c.to_vec(),
                }
            };
            (demod(a), b.map(demod))
        });
        // Noise variance of the filtered input, per pixel (mean over channels).
        let noise_raw = t.time("noise estimate", || {
            let mut v = vec![0.0f32; n];
            match &b_irr {
                Some(bb) => {
                    for p in 0..n {
                        let mut s = 0.0;
                        for c in 0..3 {
                            let d = a_irr[c * n + p] - bb[c * n + p];
                            s += d * d;
                        }
                        v[p] = s / 12.0; // |A - B|^2 / 4, mean of 3 channels
                    }
                }
                None => local_noise(&a_irr, w, h, &mut v),
            }
            v
        });
        let zeros = Planes::<f32>::new(1, w, h);
        let noise32 = t.time("noise estimate", || {
            if b_irr.is_some() {
                box_average(ctx, &Planes::from_vec(1, w, h, noise_raw), &zeros, NOISE_RADIUS)
            } else {
                // A 3x3 median, not a box: where the local estimate mistook an
                // edge for noise, those pixels are a minority of the window.
                Ok(Planes::from_vec(1, w, h, median3(&noise_raw, w, h)))
            }
        })?;
        let enc = |ch: usize, d: &[f32], kind: Kind| Planes::<P::Store>::encode_as::<P>(ch, w, h, d, kind);
        let noise = enc(1, &noise32.data, Kind::Plain);
        let normal = if self.use_normal { need(Buffer::Normal, true)?.map(|d| enc(3, d, Kind::Unit)) } else { None };
        let position =
            if self.use_position { need(Buffer::Position, true)?.map(|d| enc(3, d, Kind::Plain)) } else { None };
        let depth = if self.use_depth { need(Buffer::Depth, true)?.map(|d| enc(1, d, Kind::Plain)) } else { None };
        let guides = AtrousGuides {
            noise: noise.view(),
            normal: normal.as_ref().map(|p| p.view()),
            position: position.as_ref().map(|p| p.view()),
            depth: depth.as_ref().map(|p| p.view()),
        };
        // Level 0 images: [M, H] (sure with a pair), [M] otherwise, + variance (sure, single).
        let sure_pair = self.sure && self.pair;
        let sure_single = self.sure && !self.pair;
        let groups = if sure_pair { 2 } else { 1 };
        let mut c0 = vec![0.0f32; (3 * groups + usize::from(sure_single)) * n];
        match (&b_irr, sure_pair) {
            (Some(bb), true) => {
                for i in 0..3 * n {
                    c0[i] = 0.5 * (a_irr[i] + bb[i]);
                    c0[3 * n + i] = 0.5 * (a_irr[i] - bb[i]);
                }
            }
            (Some(bb), false) => {
                for i in 0..3 * n {
                    c0[i] = 0.5 * (a_irr[i] + bb[i]);
                }
            }
            (None, _) => c0[..3 * n].copy_from_slice(&a_irr),
        }
        if sure_single {
            c0[3 * n..].copy_from_slice(&noise32.data);
        }
        let nch = 3 * groups + usize::from(sure_single);
        let _ = nch;
        let mut cur = enc(3 * groups + usize::from(sure_single), &c0, Kind::Image);
        // Reconstruction of the mean image, in f32: sum of beta * D, then c_N.
        let mut recon = vec![0.0f32; 3 * n];
        let isa = ctx.isa;
        let params = self.params;
        for level in 0..LEVELS {
            let out_ch = 3 * groups + 2 * usize::from(sure_single);
            let mut next = Planes::<P::Store>::new(out_ch, w, h).with_frac(cur.frac);
            let cv = cur.view();
            t.time("a-trous levels", || {
                bands(ctx, next.view_mut(), 1, 0, |band, y0, _| {
                    atrous::step::<P>(isa, level, groups, sure_single, &params, &guides, &cv, band, y0)
                })
            })?;
            if self.sure {
                let cf = cur.decode::<P>();
                let nf = next.decode::<P>();
                let (e, s, d) = t.time("SURE terms", || sure_terms(&cf, &nf, groups, sure_single, n));
                let es = Planes::from_vec(2, w, h, [e, s].concat());
                let avg = t.time("SURE window", || box_average(ctx, &es, &zeros, SURE_RADIUS))?;
                t.time("SURE pick", || {
                    let dv = View::new(&d, 3, w, h).expect("shape");
                    let ev = View::new(&avg.data[..n], 1, w, h).expect("shape");
                    let sv = View::new(&avg.data[n..], 1, w, h).expect("shape");
                    let mut rv = ViewMut::new(&mut recon, 3, w, h).expect("shape");
                    atrous::sure_pick(&ev, &sv, &SURE_CANDIDATES, &dv, &mut rv)
                })?;
            }
            // Next level's input: the colour planes (+ the propagated variance).
            cur = if sure_single {
                let mut nx = Planes::<P::Store>::new(4, w, h).with_frac(next.frac);
                nx.data.copy_from_slice(&next.data[..4 * n]);
                nx
            } else {
                next
            };
        }
        // c_N of the mean image (+ the kept detail).
        let last = cur.decode::<P>();
        let mut out = vec![0.0f32; 3 * n];
        for i in 0..3 * n {
            out[i] = last[i] + recon[i];
        }
        if let Some(al) = albedo {
            t.time("remodulate", || {
                let alv = View::new(al, 3, w, h).expect("shape");
                let src = out.clone();
                tonemap::remodulate::<mcdenoise_core::F32>(
                    isa,
                    &View::new(&src, 3, w, h).expect("shape"),
                    &alv,
                    ALBEDO_EPS,
                    &mut ViewMut::new(&mut out, 3, w, h).expect("shape"),
                )
            })?;
        }
        // The output passes through the pipeline's storage precision.
        Ok(Planes::<P::Store>::encode::<P>(3, w, h, &out).decode::<P>())
    }
}

/// Per-pixel SURE terms of one level: detail energy `e = sum_c D_c^2`, detail
/// noise `s` (sum over channels) and the detail `D` of the mean image.
fn sure_terms(cur: &[f32], next: &[f32], groups: usize, single: bool, n: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut e = vec![0.0f32; n];
    let mut s = vec![0.0f32; n];
    let mut d = vec![0.0f32; 3 * n];
    for p in 0..n {
        let (mut ee, mut ss) = (0.0f32, 0.0f32);
        for c in 0..3 {
            let i = c * n + p;
            let (dm, noise) = if groups == 2 {
                let dh = cur[3 * n + i] - next[3 * n + i];
                (cur[i] - next[i], dh * dh)
            } else if single {
                // Var(D) = Var(c_i)(1 - 2 w_centre) + Var(c_{i+1}), per channel.
                let var_i = cur[3 * n + p];
                let var_n = next[3 * n + p];
                let wc = next[4 * n + p];
                (cur[i] - next[i], (var_i * (1.0 - 2.0 * wc) + var_n).max(0.0))
            } else {
                (cur[i] - next[i], 0.0)
            };
            d[i] = dm;
            ee += dm * dm;
            ss += noise;
        }
        e[p] = ee;
        s[p] = ss;
    }
    (e, s, d)
}

/// 3x3 median (of the in-image pixels), scaled by 1.27: the median of nine
/// chi-square(3)/3 variates is about 0.79 of their mean.
fn median3(v: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; w * h];
    let mut nb = [0.0f32; 9];
    for py in 0..h {
        for px in 0..w {
            let mut m = 0;
            for qy in py.saturating_sub(1)..(py + 2).min(h) {
                for qx in px.saturating_sub(1)..(px + 2).min(w) {
                    nb[m] = v[qy * w + qx];
                    m += 1;
                }
            }
            let vals = &mut nb[..m];
            vals.sort_unstable_by(f32::total_cmp);
            let med = if m % 2 == 1 { vals[m / 2] } else { 0.5 * (vals[m / 2 - 1] + vals[m / 2]) };
            out[py * w + px] = 1.27 * med;
        }
    }
    out
}

/// The local noise variance of a single estimate: `0.84 |y - median of the
/// 8 neighbours|^2`, mean over channels. The median (not the mean) keeps an
/// edge from reading as noise: next to a light's edge the neighbours on the
/// other side are a minority. For white noise `Var(median of 8) ~ 0.2 sigma^2`,
/// hence `E|y - median|^2 ~ 1.2 sigma^2` and the factor 0.84. At borders the
/// median of the neighbours there is.
fn local_noise(y: &[f32], w: usize, h: usize, v: &mut [f32]) {
    let n = w * h;
    let mut nb = [0.0f32; 8];
    for py in 0..h {
        for px in 0..w {
            let mut s = 0.0;
            for c in 0..3 {
                let mut m = 0;
                for qy in py.saturating_sub(1)..(py + 2).min(h) {
                    for qx in px.saturating_sub(1)..(px + 2).min(w) {
                        if (qy, qx) != (py, px) {
                            nb[m] = y[c * n + qy * w + qx];
                            m += 1;
                        }
                    }
                }
                if m > 0 {
                    let vals = &mut nb[..m];
                    vals.sort_unstable_by(f32::total_cmp);
                    let med = if m % 2 == 1 { vals[m / 2] } else { 0.5 * (vals[m / 2 - 1] + vals[m / 2]) };
                    let d = y[c * n + py * w + px] - med;
                    s += 0.84 * d * d;
                }
            }
            v[py * w + px] = s / 3.0;
        }
    }
}

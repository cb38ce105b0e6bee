//! The per-pixel features every method derives from a frame's buffers, in
//! one place: the demodulation factor (what radiance is divided by before
//! filtering and multiplied by after), the exposure, the HDR transfer curve
//! of the networks' colour inputs, normals and depth as network inputs.
//! Every method and every precision uses these, in inference and in
//! training; a weights file records [`TRANSFORM`] and is refused under
//! another one.
//!
//! # Demodulation
//!
//! Filtering irradiance (radiance over albedo) instead of radiance keeps
//! texture out of the filter. It needs a factor `d` that is continuous in
//! the albedo and does not amplify, because the filters average
//! neighbours' `L(q) / d(q)` and multiply by `d(p)`: a neighbour whose
//! factor is much smaller than the pixel's brings its radiance in scaled by
//! `d(p) / d(q)`. Renderers' albedo buffers are not always reflectances:
//! Mitsuba's raw AOV is 0 on smooth metals and glass, runs from about 46 at
//! normal incidence to 1e-20 at grazing angles over one rough gold sphere,
//! and emitters seen directly have albedo 0. So, per pixel and channel,
//! from the albedo `a`:
//!
//! 1. `a` is clamped to `[0, 1]` (beyond 1 it is no reflectance);
//! 2. the albedo's weight `w = smoothstep(0, TAU, max(a_r, a_g, a_b))` says
//!    how much it tells about the pixel: where it is (near) zero (emitters,
//!    glass, mirrors in raw AOVs, black paint) the pixel is filtered as
//!    radiance, `b = w * max(a, KAPPA * max_c a) + (1 - w)`, which runs
//!    continuously from 1 at albedo 0 to the albedo itself from `TAU` on
//!    (the chromatic floor `KAPPA` keeps a saturated colour's dark channels
//!    from being divided by nearly nothing);
//! 3. `d` is the smallest factor at least `b` whose logarithm changes by at
//!    most `ln(1 / DECAY)` a pixel step: `d(p) = max_q b(q) DECAY^(|dx| +
//!    |dy|)`. Any two pixels `r` steps apart then have factors within
//!    `DECAY^-r` of each other, so no filter window mixes values demodulated
//!    by very different factors (a 3x3 window at most 4x, 7x7 64x), whatever
//!    the albedo buffer holds; a texture's albedo edges keep their contrast
//!    outside a band of about `log(contrast) / log(1 / DECAY)` pixels.
//!
//! No threshold splits a surface: `d` is continuous in the albedo, equal to
//! it on reflectances above `TAU` away from much brighter neighbours, 1 where
//! the albedo is 0, and at most 1 everywhere.
//!
//! # Network inputs
//!
//! The learned filters average the demodulated irradiance below a level
//! where a pixel is an emitter and leave the excess at its pixel
//! ([`split_excess`]): emitters seen directly stay sharp. Their inputs'
//! fireflies are clamped first ([`clamp_fireflies`]).
//!
//! The learned methods scale the colour by the frame's exposure (OIDN's
//! autoexposure: `0.18 / exp(mean log luminance)` over 16x16 bins brighter
//! than 1e-8) and pass it through `log1p` ([`transfer`]) before the
//! network; the albedo input is `clamp(a, 0, 1)`, the normal `n / 2 + 1/2`,
//! the depth normalised over the frame. The filters themselves are linear
//! in the radiance, so with exposure-normalised inputs a frame scaled by `k`
//! is denoised into the output scaled by `k`.

use mcdenoise_core::tonemap::Map;
use mcdenoise_core::{Isa, View, ViewMut, F32};

use crate::io::frame::{Buffer, Frame};
use crate::runtime::par::Pool;

/// The input transform's name and version, recorded in every weights file
/// of a learned method (metadata `transform`): weights trained under one
/// transform are refused under another.
pub const TRANSFORM: &str = "mcdenoise-features-7";

/// The albedo (largest channel) from which a pixel is fully demodulated;
/// below it the factor blends towards 1 (radiance).
pub const TAU: f32 = 0.02;
/// A channel's factor is at least this fraction of the pixel's largest
/// channel (saturated albedo colours).
pub const KAPPA: f32 = 0.1;
/// Neighbouring factors differ by at most `1 / DECAY` per pixel step.
pub const DECAY: f32 = 0.5;

/// Exposure's target: the frame's mean log luminance is mapped to this.
pub const EXPOSURE_KEY: f32 = 0.18;

/// The lowest level, in exposure-normalised units (5.5 times the exposure
/// key), above which a pixel without albedo keeps its irradiance out of
/// the learned filters ([`split_excess`]).
pub const EXCESS_FLOOR: f32 = 1.0;
/// The learned filters' firefly clamp ([`clamp_fireflies`]): standard
/// deviations above the 5x5 neighbours' mean.
pub const FIREFLY_K: f32 = 6.0;
/// A pixel whose albedo is under `1 - PARTIAL_FROM` of its 3x3 neighbours'
/// largest starts to count as covered in part by an emitter (a light one or
/// two pixels thin has no pixel without albedo), fully under `1 -
/// PARTIAL_FULL`; on a plain surface such a pixel's irradiance stays under
/// the level and nothing changes. (A corridor's strip light covering 40-50 %
/// of its row has albedo 0.40-0.52 beside the ceiling's 0.8: all of it must
/// count, or the part that does not is spread into the ceiling.)
pub const PARTIAL_FROM: f32 = 0.15;
/// See [`PARTIAL_FROM`].
pub const PARTIAL_FULL: f32 = 0.3;
/// A pixel above [`CORE_FLOOR`] whose 3x3 neighbourhood's luminance is at least
/// this fraction of its largest counts as an emitter even with albedo
/// (Mitsuba's Cornell box gives its light the walls' white BSDF).
pub const SMOOTH: f32 = 0.5;
/// The level, in exposure-normalised units (44 times the exposure key),
/// above which a smooth pixel with albedo counts as an emitter ([`SMOOTH`]).
/// A lit wall is smooth too once the input has a few samples (a 64-spp
/// Cornell box's wall beside the light, 1.2-2 in these units; the walls
/// a moving light sweeps, up to 7 in a converged image); its noise above
/// the surroundings' level was kept out of the filters, a patch of bright
/// speckles. The box's light is at 52.
pub const CORE_FLOOR: f32 = 8.0;
/// ... and the multiple of the surrounding surfaces' level above which.
pub const EXCESS_RATIO: f32 = 4.0;
/// The same multiple for a pixel known to be a light (covered in part by
/// one, or bright and smooth): the filters see it at the level of the
/// surfaces around it, so its neighbours (a Cornell box light's dark rim,
/// ref 0.01) get nothing of it.
pub const LIGHT_RATIO: f32 = 1.0;
/// The reach of the averaging of partly covered pixels' excess
/// ([`split_excess`], its last step).
pub const PARTIAL_RADIUS: usize = 3;
/// Two partly covered pixels count as covered alike where their albedos
/// are within this fraction of the larger (per channel, plus 0.01) ...
pub const PARTIAL_ALBEDO_TOL: f32 = 0.3;
/// ... their normals within this cosine ...
pub const PARTIAL_NORMAL_COS: f32 = 0.97;
/// ... and their depths within this fraction of the larger.
pub const PARTIAL_DEPTH_TOL: f32 = 0.02;
/// A partly covered pixel whose albedo (largest channel) is under this
/// keeps its own excess: a near-black surface beside a brighter one reads as
/// covered in part, and its excess is a glossy highlight, not a light.
pub const PARTIAL_MIN_ALBEDO: f32 = 0.1;
/// The reach of the learned filters (WSKP's 13x13 windows, AFN's 7x7 at
/// half scale), over which those surroundings are measured.
pub const EXCESS_RADIUS: usize = 7;
/// The wider reach of [`split_excess`]'s level, in reaches: where a light
/// without albedo is wider than the filters' reach, its middle takes the
/// level of the surfaces within this many reaches.
pub const EXCESS_WIDE: usize = 4;
/// How many pixels' worth of the wider reach's mean the reach's mean of a
/// pixel without albedo is drawn towards ([`split_excess`]).
pub const EXCESS_BLEND: f32 = 8.0;

/// The factor of step 2 of the module's rule for one pixel: albedo `a`
/// (any values) to `b` (in `(0, 1]` per channel).
#[inline]
pub fn blend(a: [f32; 3]) -> [f32; 3] {
    let c = a.map(|v| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) });
    let m = c[0].max(c[1]).max(c[2]);
    let t = (m / TAU).min(1.0);
    let w = t * t * (3.0 - 2.0 * t);
    c.map(|v| w * v.max(KAPPA * m) + (1.0 - w))
}

/// The envelope's reach: a factor is at least `KAPPA * TAU` (step 2), and
/// `DECAY^REACH` times the largest factor (1) is below that, so no pixel
/// farther than `REACH` steps can raise another's factor.
const REACH: usize = 9;
const _: () = assert!(KAPPA * TAU > 0.001_953_125 && DECAY == 0.5); // 0.5^9

/// `row[x] = max(row[x], DECAY^|d| row[x + d])` for `0 < |d| < 16` (at
/// least [`REACH`]): the one-dimensional envelope, by doubling shifts (each
/// step a max over shifted slices, which vectorises), forward then back.
fn envelope_1d(row: &mut [f32], tmp: &mut Vec<f32>) {
    let n = row.len();
    tmp.resize(n, 0.0);
    for s in [1usize, 2, 4, 8] {
        if s >= n {
            break;
        }
        let f = DECAY.powi(s as i32);
        tmp.copy_from_slice(row);
        for (r, &t) in row[s..].iter_mut().zip(&tmp[..n - s]) {
            *r = r.max(f * t);
        }
        for (r, &t) in row[..n - s].iter_mut().zip(&tmp[s..]) {
            *r = r.max(f * t);
        }
    }
}

/// The demodulation factor `d` (3 planes of `w x h`, written into `d`) of
/// the albedo `albedo` (3 planes): the module's rule. Rows in parallel on
/// `pool` (the blend and the envelope along the row), then bands of rows
/// (the envelope along the columns, with `REACH` rows of halo).
pub fn demodulation(pool: &Pool, albedo: &[f32], w: usize, h: usize, d: &mut [f32]) {
    let n = w * h;
    assert!(albedo.len() >= 3 * n && d.len() >= 3 * n, "demodulation: 3 planes of {w}x{h}");
    if n == 0 {
        return;
    }
    const _: () = assert!(REACH < 16);
    // Steps 1 and 2, and the envelope along each row.
    {
        let (d0, rest) = d[..3 * n].split_at_mut(n);
        let (d1, d2) = rest.split_at_mut(n);
        type Row<'a> = (usize, &'a mut [f32], &'a mut [f32], &'a mut [f32]);
        let rows: Vec<Row<'_>> = d0
            .chunks_mut(w)
            .zip(d1.chunks_mut(w))
            .zip(d2.chunks_mut(w))
            .enumerate()
            .map(|(y, ((a, b), c))| (y, a, b, c))
            .collect();
        pool.install(|| {
            use rayon::prelude::*;
            rows.into_par_iter().with_min_len(16).for_each_init(Vec::new, |tmp, (y, r0, r1, r2)| {
                for x in 0..w {
                    let i = y * w + x;
                    let b = blend([albedo[i], albedo[n + i], albedo[2 * n + i]]);
                    r0[x] = b[0];
                    r1[x] = b[1];
                    r2[x] = b[2];
                }
                for r in [r0, r1, r2] {
                    envelope_1d(r, tmp);
                }
            });
        });
    }
    // The envelope along columns: forward and backward recurrences over the
    // rows, each step a vector operation along a whole row; the planes in
    // parallel.
    let planes: Vec<&mut [f32]> = d[..3 * n].chunks_mut(n).collect();
    pool.install(|| {
        use rayon::prelude::*;
        planes.into_par_iter().for_each(|plane| {
            for y in 1..h {
                let (above, below) = plane.split_at_mut(y * w);
                for (v, &p) in below[..w].iter_mut().zip(&above[(y - 1) * w..]) {
                    *v = v.max(DECAY * p);
                }
            }
            for y in (0..h.saturating_sub(1)).rev() {
                let (above, below) = plane.split_at_mut((y + 1) * w);
                for (v, &p) in above[y * w..].iter_mut().zip(&below[..w]) {
                    *v = v.max(DECAY * p);
                }
            }
        });
    });
}

/// The demodulation factor of a frame's albedo (3 planes), or `None`
/// without albedo.
pub fn frame_demodulation(pool: &Pool, f: &Frame) -> Option<Vec<f32>> {
    let a = f.get(Buffer::Albedo)?;
    let mut d = vec![0.0f32; 3 * f.width * f.height];
    demodulation(pool, a, f.width, f.height, &mut d);
    Some(d)
}

/// Rec. 709 luminance.
#[inline]
pub fn luminance(r: f32, g: f32, b: f32) -> f32 {
    0.2126 * r + 0.7152 * g + 0.0722 * b
}

/// The exposure of linear radiance `rgb` (3 planes of `w x h`): the mean
/// luminance over bins of at most 16x16 pixels, the mean of the logarithm
/// over the bins brighter than 1e-8, `EXPOSURE_KEY / exp(mean)`; 1 for a
/// frame with no such bin. Scaling the radiance by `k` scales the exposure
/// by `1 / k` (exactly, up to rounding).
pub fn exposure(rgb: &[f32], w: usize, h: usize) -> f32 {
    let n = w * h;
    if n == 0 || rgb.len() < 3 * n {
        return 1.0;
    }
    let (bx, by) = (w.div_ceil(16), h.div_ceil(16));
    let (mut sum, mut count) = (0.0f64, 0usize);
    for j in 0..by {
        let (y0, y1) = (j * h / by, (j + 1) * h / by);
        for i in 0..bx {
            let (x0, x1) = (i * w / bx, (i + 1) * w / bx);
            let mut l = 0.0f64;
            for y in y0..y1 {
                for x in x0..x1 {
                    let p = y * w + x;
                    let v = luminance(rgb[p], rgb[n + p], rgb[2 * n + p]);
                    if v.is_finite() {
                        l += v.max(0.0) as f64;
                    }
                }
            }
            let l = l / ((y1 - y0) * (x1 - x0)).max(1) as f64;
            if l > 1e-8 {
                sum += l.ln();
                count += 1;
            }
        }
    }
    if count == 0 {
        return 1.0;
    }
    let e = EXPOSURE_KEY as f64 / (sum / count as f64).exp();
    if e.is_finite() && e > 0.0 {
        e as f32
    } else {
        1.0
    }
}

/// The HDR transfer curve of the networks' colour inputs, applied to
/// exposure-scaled radiance: `log1p(max(x, 0))` (0.17 at the exposure
/// key, 4.6 at 100 times it). [`network_inputs`] applies it through the
/// core's `tonemap::Map::Log1p` (its SIMD path).
#[inline]
pub fn transfer(x: f32) -> f32 {
    Map::Log1p.apply(x)
}

/// Splits demodulated irradiance `c` (3 planes of `w x h`, in place) into
/// the part the learned filters average and the `excess` (3 planes) they
/// leave at its own pixel, added back after filtering. A kernel-predicting
/// filter cannot keep a light out of its neighbours by itself (WSKP's
/// weights are shared by every window that contains a pixel), so:
///
/// - a pixel takes part where it or a neighbour within 2 pixels has no albedo to speak
///   of (`keep = max over 5x5 of 1 - w`, [`albedo_weight`]): emitters seen
///   directly, their outline, glass and mirrors in raw AOVs; and where a
///   light covers it in part (its albedo well under its neighbours',
///   [`PARTIAL_FROM`], near (5x5) another such pixel at least half as bright:
///   a light one or two pixels thin, which has no pixel without albedo).
///   Other pixels are averaged whole (their fireflies are noise to spread,
///   and a firefly is alone);
/// - its level is `T = max(EXCESS_FLOOR / exposure, EXCESS_RATIO m)`, `m`
///   the mean luminance of the surfaces with albedo within
///   [`EXCESS_RADIUS`] pixels (the filters' reach), with `LIGHT_RATIO`
///   instead of `EXCESS_RATIO` where the pixel is known to be a light
///   (covered in part, or bright and smooth); where the reach has no
///   surfaces, the floor inside a light known to be one, and elsewhere (a
///   light without albedo, a mirror or a pane of glass in a raw AOV) the
///   same rule over [`EXCESS_WIDE`] reaches, for a share of the excess that
///   falls from 1 to 0 over the next reach inwards (on pixels without
///   albedo the reach's mean drawn towards the wider one's by
///   [`EXCESS_BLEND`] pixels' worth): a light wider than the
///   reach is split at one level from its outline to its middle (no step
///   where the reach's surfaces run out: a bright and a dark line after
///   filtering), and a region wider still is filtered whole in its middle;
/// - `excess = share keep max(c - T, 0)` per channel, `c` keeps the rest.
///
/// So a light stays sharp and bleeds at most `EXCESS_RATIO` times the
/// level of the walls around it into them; continuous in the albedo.
///
/// With `geometry` (the frame's normal and depth planes, 3 + 1), the
/// excess of the pixels a light covers in part is then averaged over those
/// covered alike (`smooth_partial`): at a few samples per pixel a thin
/// light's or a light's edge's coverage is noise the filters do not see.
#[allow(clippy::too_many_arguments)]
pub fn split_excess(
    pool: &Pool,
    c: &mut [f32],
    albedo: &[f32],
    geometry: Option<(&[f32], &[f32])>,
    w: usize,
    h: usize,
    exposure: f32,
    excess: &mut [f32],
) {
    let n = w * h;
    if n == 0 || c.len() < 3 * n || excess.len() < 3 * n || albedo.len() < 3 * n {
        return;
    }
    let unit = if exposure > 0.0 && exposure.is_finite() { exposure } else { 1.0 };
    let (floor, core_floor) = (EXCESS_FLOOR / unit, CORE_FLOOR / unit);
    // keep0 = 1 - w, or the part of a pixel a thin emitter covers (its
    // albedo well under its neighbours'), then the 3x3 maximum.
    // (Each pass writes its planes in runs of pixels on `pool`, reading
    // only planes made before it; a run walks its pixels' (x, y) along.)
    const RUN: usize = 1 << 13;
    let (mut amax, mut none) = (vec![0.0f32; n], vec![0.0f32; n]);
    pool.planes(vec![&mut amax[..], &mut none[..]], RUN, |start, runs| {
        let (am, no) = runs.split_at_mut(1);
        for (i, (am, no)) in am[0].iter_mut().zip(no[0].iter_mut()).enumerate() {
            let p = start + i;
            let a = [albedo[p], albedo[n + p], albedo[2 * n + p]];
            *am = a[0].max(a[1]).max(a[2]).clamp(0.0, 1.0);
            *no = 1.0 - albedo_weight(a);
        }
    });
    let (amax, none) = (&amax, &none);
    // `coverage`: the part of the pixel its albedo's drop says a light
    // without albedo covers, `1 - a / m`.
    let mut covered = vec![0.0f32; n];
    let mut coverage = vec![0.0f32; n];
    window_max(pool, amax, w, h, 1, &mut covered);
    pool.planes(vec![&mut covered[..], &mut coverage[..]], RUN, |start, runs| {
        let (cv, cg) = runs.split_at_mut(1);
        for (i, (o, g)) in cv[0].iter_mut().zip(cg[0].iter_mut()).enumerate() {
            let (p, m) = (start + i, *o);
            *o = 0.0;
            if m > 0.0 {
                *g = (1.0 - amax[p] / m).clamp(0.0, 1.0);
                *o = ((*g - PARTIAL_FROM) / (PARTIAL_FULL - PARTIAL_FROM)).clamp(0.0, 1.0);
            }
        }
    });
    // A covered pixel counts only near another emitter pixel at least half
    // as bright, within 2 pixels (a light is a line or a region; a firefly
    // on the dark side of a texture's edge is alone, and is averaged). At
    // 1 spp about half of a strip light's samples miss it, so the next hit
    // along the strip may be two pixels away.
    const SUPPORT: usize = 2;
    let mut lum = vec![0.0f32; n];
    {
        let c: &[f32] = c;
        pool.planes(vec![&mut lum[..]], RUN, |start, runs| {
            for (i, o) in runs[0].iter_mut().enumerate() {
                let p = start + i;
                *o = luminance(c[p], c[n + p], c[2 * n + p]).max(0.0);
            }
        });
    }
    let (lum, covered) = (&lum, &covered);
    let mut keep0 = none.clone();
    // How much a pixel is known to be a light (covered in part, or bright
    // and smooth): its level is the surroundings' own, not EXCESS_RATIO
    // times it (pixels without albedo may be glass or a mirror, noisy at
    // 1 spp: they keep the wider level).
    let mut tight = vec![0.0f32; n];
    // The part covered stands only where the light without albedo is seen
    // beside the pixel: a pixel without albedo in its 3x3 neighbourhood at
    // least half as bright as the neighbourhood's brightest (an albedo drop
    // beside a dark background is a thin object's edge, not a light's).
    pool.planes(vec![&mut keep0[..], &mut tight[..], &mut coverage[..]], RUN, |start, runs| {
        let (k0, rest) = runs.split_at_mut(1);
        let (ti, cg) = rest.split_at_mut(1);
        let mut at = Walk::new(start, w);
        for ((k0, ti), cg) in k0[0].iter_mut().zip(ti[0].iter_mut()).zip(cg[0].iter_mut()) {
            let (p, x, y) = at.next();
            if covered[p] <= *k0 {
                *cg = 0.0;
                continue;
            }
            let mut supported = false;
            for yy in y.saturating_sub(SUPPORT)..(y + SUPPORT + 1).min(h) {
                for xx in x.saturating_sub(SUPPORT)..(x + SUPPORT + 1).min(w) {
                    let q = yy * w + xx;
                    supported |= q != p && (none[q] > 0.0 || covered[q] > 0.0) && 2.0 * lum[q] >= lum[p];
                }
            }
            if supported {
                *k0 = covered[p];
                *ti = covered[p];
            }
            let (mut bright, mut bare) = (0.0f32, 0.0f32);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    let q = yy * w + xx;
                    bright = bright.max(lum[q]);
                    if none[q] >= 0.5 {
                        bare = bare.max(lum[q]);
                    }
                }
            }
            if !supported || bare < 0.5 * bright || bare <= 0.0 {
                *cg = 0.0;
            }
        }
    });
    // (The pixels a light covers in part, before the lights with albedo
    // join; kept only for the averaging, which needs the geometry.)
    let partial = geometry.map(|_| tight.clone());
    // An emitter with albedo (a light's own diffuse surface): bright and
    // smooth, its 3x3 neighbourhood within SMOOTH of its largest value. Noisy
    // surfaces are not; a smooth one's excess stays at its pixel as
    // accurate as it came.
    let mut core = none.clone();
    pool.planes(vec![&mut core[..], &mut keep0[..], &mut tight[..]], RUN, |start, runs| {
        let mut at = Walk::new(start, w);
        for i in 0..runs[0].len() {
            let (p, x, y) = at.next();
            if lum[p] <= core_floor {
                continue;
            }
            let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    lo = lo.min(lum[yy * w + xx]);
                    hi = hi.max(lum[yy * w + xx]);
                }
            }
            if lo >= SMOOTH * hi {
                for r in runs.iter_mut() {
                    r[i] = 1.0;
                }
            }
        }
    });
    if keep0.iter().all(|&k| k == 0.0) {
        excess[..3 * n].fill(0.0);
        return;
    }
    const OUTLINE: usize = 2;
    let mut keep = vec![0.0f32; n];
    // The outline of an emitter (two pixels: the smoothness test leaves out
    // a light's last pixel row and the one inside it, whose 3x3 reaches the
    // dark side); a covered pixel itself.
    window_max(pool, &core, w, h, OUTLINE, &mut keep);
    let keep0 = &keep0;
    pool.planes(vec![&mut keep[..]], RUN, |start, runs| {
        for (i, o) in runs[0].iter_mut().enumerate() {
            *o = o.max(keep0[start + i]);
        }
    });
    // Box sums over the reach of (1 - keep) lum(c) and (1 - keep), and over
    // EXCESS_WIDE times it.
    let r = EXCESS_RADIUS;
    let mut num = vec![0.0f32; n];
    let mut den = vec![0.0f32; n];
    {
        let (c, keep): (&[f32], &[f32]) = (c, &keep);
        pool.planes(vec![&mut num[..], &mut den[..]], RUN, |start, runs| {
            let (nu, de) = runs.split_at_mut(1);
            for (i, (nu, de)) in nu[0].iter_mut().zip(de[0].iter_mut()).enumerate() {
                let p = start + i;
                let a = 1.0 - keep[p];
                *nu = a * luminance(c[p], c[n + p], c[2 * n + p]).max(0.0);
                *de = a;
            }
        });
    }
    // (Before the reach's sums: the wider reach's, and `near`, start from
    // the same planes.)
    let (mut num_wide, mut den_wide) = (num.clone(), den.clone());
    pool.install(|| rayon::join(|| box_sum(&mut num, w, h, r), || box_sum(&mut den, w, h, r)));
    // The wider reach is read only by a kept pixel without albedo (the
    // blend) or without surfaces within the reach and not known to be a
    // light; `near` only by the latter. Most frames' lights lie within
    // the reach of surfaces: neither is made.
    let (need_wide, need_near) = {
        use rayon::prelude::*;
        let (keep, den, tight) = (&keep, &den, &tight);
        // (As the level's arms test them: NaN counts as neither.)
        let beyond = |p: usize| matches!((den[p] > 0.5, tight[p] > 0.0), (false, false));
        pool.install(|| {
            let kept = || (0..n).into_par_iter().with_min_len(RUN).filter(|&p| keep[p] > 0.0);
            let near = kept().any(beyond);
            (near || kept().any(|p| none[p] >= 0.5), near)
        })
    };
    // How near the reach's edge a pixel beyond it lies: the surfaces
    // dilated by the reach, summed over the reach (for a straight edge
    // `2 r + 1 - (D - r)` columns of the window at distance `D`, however
    // thin the surface).
    let mut near = vec![0.0f32; n];
    if need_near {
        window_max(pool, &den_wide, w, h, r, &mut near);
    }
    if need_wide {
        pool.install(|| {
            rayon::join(
                || {
                    if need_near {
                        box_sum(&mut near, w, h, r)
                    }
                },
                || {
                    rayon::join(
                        || box_sum(&mut num_wide, w, h, EXCESS_WIDE * r),
                        || box_sum(&mut den_wide, w, h, EXCESS_WIDE * r),
                    )
                },
            )
        });
    }
    let mut planes: Vec<&mut [f32]> = c[..3 * n].chunks_mut(n).collect();
    planes.extend(excess[..3 * n].chunks_mut(n));
    let (keep, num, den, tight) = (&keep, &num, &den, &tight);
    let (num_wide, den_wide, near) = (&num_wide, &den_wide, &near);
    let fade = ((2 * r + 1) * (r + 1)) as f32;
    let rw = EXCESS_WIDE * r;
    let (wide_full, wide_none) = (((2 * rw + 1) * (rw - r)) as f32, ((2 * rw + 1) * (rw - 2 * r)) as f32);
    pool.planes(planes, 1 << 14, |start, runs| {
        let (cs, ex) = runs.split_at_mut(3);
        for i in 0..cs[0].len() {
            let p = start + i;
            let k = keep[p];
            let ratio = EXCESS_RATIO + tight[p] * (LIGHT_RATIO - EXCESS_RATIO);
            // The surroundings' mean: the reach's where it has surfaces,
            // else the wider reach's; on a pixel without albedo the reach's
            // sums drawn towards the wider mean by EXCESS_BLEND pixels'
            // worth, so the level runs on where the reach's surfaces run
            // out. Inside a large light known to be one no surface is within
            // reach: its level is the floor (the light stays as it came, and
            // the kernels of the surfaces beside it, which reach into it,
            // find nothing of it). Elsewhere beyond the reach, the wider
            // reach's level, for a share of the excess that falls with the
            // distance: 1 one reach from the surfaces (`near` is a straight
            // edge's `fade` there), 0 from two (filtered whole, a partly
            // covered outline smoothed); or by the wider reach's count of
            // surfaces, 1 from a straight edge's one reach in to 0 from two
            // reaches in, whichever is larger: a light surrounded by
            // surfaces is split alike to its middle.
            let wide = (need_wide && den_wide[p] > 0.5).then(|| num_wide[p] / den_wide[p]);
            let mean = match wide {
                Some(m) if none[p] >= 0.5 => Some((num[p] + EXCESS_BLEND * m) / (den[p] + EXCESS_BLEND)),
                _ if den[p] > 0.5 => Some(num[p] / den[p]),
                other => other,
            };
            let (level, share) = match mean {
                Some(m) if den[p] > 0.5 => ((ratio * m).max(floor), 1.0),
                _ if tight[p] > 0.0 => (floor / tight[p], 1.0),
                Some(m) => (
                    (ratio * m).max(floor),
                    (near[p] / fade).max((den_wide[p] - wide_none) / (wide_full - wide_none)).clamp(0.0, 1.0),
                ),
                None => (f32::INFINITY, 1.0),
            };
            for ch in 0..3 {
                let v = cs[ch][i];
                let e = if k > 0.0 { share * k * (v - level).max(0.0) } else { 0.0 };
                cs[ch][i] = v - e;
                ex[ch][i] = e;
            }
        }
    });
    if let (Some((normal, depth)), Some(partial)) = (geometry, partial) {
        let light = Partial { partial: &partial, coverage: &coverage };
        smooth_partial(pool, excess, &light, albedo, normal, depth, w, h);
    }
}

/// The planes [`smooth_partial`] reads beside the frame's: which pixels a
/// light covers in part and the part (from the albedo's drop).
struct Partial<'a> {
    partial: &'a [f32],
    coverage: &'a [f32],
}

/// The last step of [`split_excess`]: the excess of a pixel a light
/// covers in part is the light's radiance times the part covered, and at a
/// few samples per pixel each sample hits the light or misses it: a strip
/// light at 1 spp comes out as a dotted line, a light's edge as a ragged
/// one. Such a pixel's excess becomes its part covered, from its albedo's
/// drop (renderers' albedo buffers are cleaner than their colour), times
/// the light's excess per part covered, `sum e / sum part` over the pixels
/// within [`PARTIAL_RADIUS`] covered in part on the same surface (normal
/// and depth: a light's edge in front of another surface does not spread
/// onto that surface's texture); pixels covered alike get the mean of
/// their excess. Pixels with albedo under [`PARTIAL_MIN_ALBEDO`] keep
/// theirs.
#[allow(clippy::too_many_arguments)]
fn smooth_partial(
    pool: &Pool,
    excess: &mut [f32],
    light: &Partial,
    albedo: &[f32],
    normal: &[f32],
    depth: &[f32],
    w: usize,
    h: usize,
) {
    let n = w * h;
    let Partial { partial, coverage } = *light;
    if !partial.iter().any(|&t| t > 0.0) || normal.len() < 3 * n || depth.len() < n || albedo.len() < 3 * n {
        return;
    }
    let r = PARTIAL_RADIUS;
    let src = excess[..3 * n].to_vec();
    let src = &src;
    let at3 = |b: &[f32], p: usize| [b[p], b[n + p], b[2 * n + p]];
    let len = |v: [f32; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    // A pixel whose samples found a surface in part and nothing in part (a
    // light without a surface: a sky through a window; normal and depth 0
    // there) has its normal and depth scaled alike by the part: its
    // normal's length gives its surface's depth back.
    fn surface_depth(d: f32, l: f32) -> f32 {
        if l > 0.25 && l < 0.99 {
            d / l
        } else {
            d
        }
    }
    fn as_came(d: f32, _: f32) -> f32 {
        d
    }
    pool.planes(excess[..3 * n].chunks_mut(n).collect(), 1 << 12, |start, runs| {
        let mut at = Walk::new(start, w);
        for i in 0..runs[0].len() {
            let (p, x, y) = at.next();
            let ap = at3(albedo, p);
            if partial[p] <= 0.0 || ap[0].max(ap[1]).max(ap[2]) < PARTIAL_MIN_ALBEDO {
                continue;
            }
            let np = at3(normal, p);
            let lp = len(np);
            // With its part covered known (a light without albedo seen
            // beside it), the pixels whose parts are known, their depths read
            // through their normals' length and a normal missing from a
            // quarter of unit length down; without, the mean over those
            // covered alike (weights 1, depths as they came, a normal
            // missing from half).
            let known = coverage[p] > 0.0;
            let (missing, depth_of): (f32, fn(f32, f32) -> f32) =
                if known { (0.25, surface_depth) } else { (0.5, as_came) };
            let dp = depth_of(depth[p], lp);
            let (mut sum, mut parts) = ([0.0f32; 3], 0.0f32);
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    let q = yy * w + xx;
                    if partial[q] <= 0.0 || (known && coverage[q] <= 0.0) {
                        continue;
                    }
                    let aq = at3(albedo, q);
                    let alike = (0..3)
                        .all(|c| (aq[c] - ap[c]).abs() <= PARTIAL_ALBEDO_TOL * aq[c].abs().max(ap[c].abs()) + 0.01);
                    // Normals alike (both missing counts as alike).
                    let nq = at3(normal, q);
                    let lq = len(nq);
                    let dot = np[0] * nq[0] + np[1] * nq[1] + np[2] * nq[2];
                    let facing = if lp < missing || lq < missing {
                        lp < missing && lq < missing
                    } else {
                        dot >= PARTIAL_NORMAL_COS * lp * lq
                    };
                    let dq = depth_of(depth[q], lq);
                    let near = !(dp.is_finite() && dq.is_finite())
                        || (dq - dp).abs() <= PARTIAL_DEPTH_TOL * dq.abs().max(dp.abs());
                    if alike && facing && near {
                        for (c, s) in sum.iter_mut().enumerate() {
                            *s += src[c * n + q];
                        }
                        parts += if known { coverage[q] } else { 1.0 };
                    }
                }
            }
            // (The pixel itself always counts, its part over PARTIAL_FROM.)
            if parts > 0.0 {
                for (c, run) in runs.iter_mut().enumerate() {
                    let v = if known { coverage[p] } else { 1.0 } * sum[c] / parts;
                    if v.is_finite() {
                        run[i] = v;
                    }
                }
            }
        }
    });
}

/// The firefly clamp of the learned filters' inputs (the à-trous methods'
/// rule, `FIREFLY_K` standard deviations): on the demodulated planes `c`
/// (3 of `w x h`) made from `radiance`, a pixel whose radiance luminance
/// `L` exceeds `T = m + FIREFLY_K s` (`m`, `s` the mean and standard
/// deviation of its 5x5 neighbours, the centre left out) is scaled by
/// `T / L`. Emitters ([`is_emitter`]) are left alone (their excess is kept
/// out of the filters by [`split_excess`]). A kernel filter conserves
/// energy: a 1-spp firefly of 1000 times its neighbours, spread over a
/// 7x7 window, leaves a 20-times-too-bright blotch; clamped, it leaves
/// nothing (a small bias, OIDN's choice too).
pub fn clamp_fireflies(pool: &Pool, c: &mut [f32], radiance: &[f32], albedo: &[f32], w: usize, h: usize) {
    let n = w * h;
    if n == 0 || c.len() < 3 * n || radiance.len() < 3 * n || albedo.len() < 3 * n {
        return;
    }
    let (mut lum, mut s1, mut s2) = (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
    pool.planes(vec![&mut lum[..], &mut s1[..], &mut s2[..]], 1 << 14, |start, runs| {
        for j in 0..runs[0].len() {
            let i = start + j;
            let l = (radiance[i] + radiance[n + i] + radiance[2 * n + i]) / 3.0;
            let v = if l.is_finite() { l } else { 0.0 };
            (runs[0][j], runs[1][j], runs[2][j]) = (l, v, v * v);
        }
    });
    pool.install(|| rayon::join(|| box_sum(&mut s1, w, h, 2), || box_sum(&mut s2, w, h, 2)));
    let (lum, s1, s2) = (&lum, &s1, &s2);
    pool.planes(c[..3 * n].chunks_mut(n).collect(), 1 << 14, |start, runs| {
        let mut at = Walk::new(start, w);
        for j in 0..runs[0].len() {
            let (i, x, y) = at.next();
            let li = lum[i];
            // (NaN fails the test too.)
            if li.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || is_emitter(albedo, n, i) {
                continue;
            }
            let cnt = (((x + 3).min(w) - x.saturating_sub(2)) * ((y + 3).min(h) - y.saturating_sub(2))) as f64 - 1.0;
            if cnt < 1.0 {
                continue;
            }
            let (a, b) = (s1[i] as f64 - li as f64, s2[i] as f64 - li as f64 * li as f64);
            let m = a / cnt;
            let sd = (b / cnt - m * m).max(0.0).sqrt();
            let t = m + FIREFLY_K as f64 * sd;
            if (li as f64) > t {
                let f = (t.max(0.0) / li as f64) as f32;
                for r in runs.iter_mut() {
                    r[j] *= f;
                }
            }
        }
    });
}

/// The stage's name in plans ([`clamp_pair_fireflies`]).
pub const PAIR_CLAMP_STAGE: &str = "pair firefly clamp (a firefly one estimate alone holds where there is no albedo)";

/// Under the pair's mean ([`Frame::average_pair`], `--pair mean`): a
/// firefly that one estimate alone holds at a pixel without albedo is
/// clamped in that estimate, and the colour (their mean) with it, in place.
///
/// Such a pixel's irradiance above its surroundings' level is kept out of
/// the learned filters ([`split_excess`]: a light seen directly stays
/// sharp), and [`clamp_fireflies`] leaves it alone, so a firefly there (a
/// chrome sphere or a pane of glass in a raw AOV, whose albedo is 0) came
/// back at half its height and the accumulation carried it into the next
/// frames. A light seen directly is in both estimates; a firefly in one.
/// Where the colour's luminance exceeds `t = m + FIREFLY_K sd`, `m` and
/// `sd` those of its 5x5 neighbours (the pixel left out: the rule of
/// [`clamp_fireflies`], which clamps the colour to `t` where there is
/// albedo) and one estimate's luminance does not, the other estimate is
/// scaled down until the colour's luminance is `t`. A light's outline,
/// where the two estimates differ by what each sample covered, has bright
/// neighbours and a high `t`.
///
/// Returns how many pixels changed; nothing happens unless the colour is
/// the pair's mean and the frame has albedo.
pub fn clamp_pair_fireflies(f: &mut Frame) -> usize {
    if !f.colour_is_pair_mean {
        return 0;
    }
    let (w, h) = (f.width, f.height);
    let n = w * h;
    let Some((c, b, a)) = f.pair_planes_mut() else { return 0 };
    if n == 0 || c.len() < 3 * n || b.len() < 3 * n || a.len() < 3 * n {
        return 0;
    }
    let lum = |p: &[f32], i: usize| (p[i] + p[n + i] + p[2 * n + i]) / 3.0;
    // The colour's luminance before any change: each pixel is judged
    // against its neighbours as they came.
    let lc: Vec<f32> = (0..n).map(|i| lum(c, i)).collect();
    let mut changed = 0;
    let mut window = Vec::with_capacity(24);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let li = lc[i] as f64;
            if !li.is_finite() || !is_emitter(a, n, i) {
                continue;
            }
            // The neighbours' mean and spread in f64, around their mean
            // (pixels without albedo are few; a firefly's square in a
            // window sum of f32 would blur the spread of its neighbours).
            window.clear();
            for yy in y.saturating_sub(2)..(y + 3).min(h) {
                for xx in x.saturating_sub(2)..(x + 3).min(w) {
                    let l = lc[yy * w + xx] as f64;
                    if (xx, yy) != (x, y) {
                        window.push(if l.is_finite() { l } else { 0.0 });
                    }
                }
            }
            if window.is_empty() {
                continue;
            }
            let cnt = window.len() as f64;
            let m = window.iter().sum::<f64>() / cnt;
            let sd = (window.iter().map(|l| (l - m) * (l - m)).sum::<f64>() / cnt).sqrt();
            let t = m + FIREFLY_K as f64 * sd;
            let lb = lum(b, i) as f64;
            let la = 2.0 * li - lb;
            let (in_b, hi, lo) = if lb > la { (true, lb, la) } else { (false, la, lb) };
            // (NaN fails these tests too.)
            if !(li > t && hi > 0.0 && lo <= t) {
                continue;
            }
            let k = ((2.0 * t - lo).max(0.0) / hi) as f32;
            for j in [i, n + i, 2 * n + i] {
                let (ea, eb) = (2.0 * c[j] - b[j], b[j]);
                let (ea, eb) = if in_b { (ea, eb * k) } else { (ea * k, eb) };
                (b[j], c[j]) = (eb, 0.5 * (ea + eb));
            }
            changed += 1;
        }
    }
    changed
}

/// `out` = the largest of 0 and the values of `src` (NaN ignored) over the
/// `(2r+1)^2` window around each pixel, clipped at the border: the largest
/// along rows, then along columns (the same maximum, 2(2r+1) comparisons a
/// pixel instead of (2r+1)^2); rows on `pool`.
fn window_max(pool: &Pool, src: &[f32], w: usize, h: usize, r: usize, out: &mut [f32]) {
    use rayon::prelude::*;
    let n = w * h;
    if n == 0 {
        return;
    }
    let mut rows = vec![0.0f32; n];
    pool.install(|| {
        rows.par_chunks_mut(w).zip(src[..n].par_chunks(w)).with_min_len(8).for_each(|(o, s)| {
            for (x, o) in o.iter_mut().enumerate() {
                *o = s[x.saturating_sub(r)..(x + r + 1).min(w)].iter().fold(0.0f32, |m, &v| m.max(v));
            }
        });
        let rows = &rows;
        out[..n].par_chunks_mut(w).enumerate().with_min_len(8).for_each(|(y, o)| {
            o.fill(0.0);
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for (o, &v) in o.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
                    *o = o.max(v);
                }
            }
        });
    });
}

/// Pixels of the window of radius `r` around position `p` along an axis of
/// `len` (clipped at the ends), as f32: a box sum over the count is the mean.
#[inline]
pub(crate) fn window_span(p: usize, len: usize, r: usize) -> f32 {
    ((p + r).min(len - 1) - p.saturating_sub(r) + 1) as f32
}

/// Pixel index and `(x, y)` of consecutive pixels of a row-major image
/// `w` wide, from `start` on (one division per run, not per pixel).
pub(crate) struct Walk {
    p: usize,
    x: usize,
    y: usize,
    w: usize,
}

impl Walk {
    pub(crate) fn new(start: usize, w: usize) -> Self {
        let w = w.max(1);
        Walk { p: start, x: start % w, y: start / w, w }
    }
    /// This pixel's `(p, x, y)`; moves to the next.
    #[inline(always)]
    pub(crate) fn next(&mut self) -> (usize, usize, usize) {
        let r = (self.p, self.x, self.y);
        self.p += 1;
        self.x += 1;
        if self.x == self.w {
            self.x = 0;
            self.y += 1;
        }
        r
    }
}

/// In place: each value becomes the sum over the `(2r+1)^2` window around
/// it (clipped at the border): running sums along each row, then a window
/// of rows sliding down the image (row-major throughout; sums in f64).
pub(crate) fn box_sum(v: &mut [f32], w: usize, h: usize, r: usize) {
    if w == 0 || h == 0 {
        return;
    }
    let mut tmp = vec![0.0f64; w];
    for y in 0..h {
        let row = &mut v[y * w..(y + 1) * w];
        let mut acc = 0.0f64;
        for (x, t) in tmp.iter_mut().enumerate() {
            acc += row[x] as f64;
            *t = acc;
        }
        for (x, o) in row.iter_mut().enumerate() {
            let hi = tmp[(x + r).min(w - 1)];
            let lo = if x > r { tmp[x - r - 1] } else { 0.0 };
            *o = (hi - lo) as f32;
        }
    }
    let rows = v.to_vec();
    let row = |y: usize| &rows[y * w..(y + 1) * w];
    let col = &mut tmp;
    col.fill(0.0);
    for y in 0..=r.min(h - 1) {
        for (c, &x) in col.iter_mut().zip(row(y)) {
            *c += x as f64;
        }
    }
    for y in 0..h {
        for (o, &c) in v[y * w..(y + 1) * w].iter_mut().zip(col.iter()) {
            *o = c as f32;
        }
        if y + r + 1 < h {
            for (c, &x) in col.iter_mut().zip(row(y + r + 1)) {
                *c += x as f64;
            }
        }
        if y >= r {
            for (c, &x) in col.iter_mut().zip(row(y - r)) {
                *c -= x as f64;
            }
        }
    }
}

/// The normal as a network input, `n / 2 + 1/2`.
#[inline]
pub fn normal_input(n: f32) -> f32 {
    n * 0.5 + 0.5
}

/// The albedo as a network input, `clamp(a, 0, 1)` (NaN as 0).
#[inline]
pub fn albedo_input(a: f32) -> f32 {
    if a.is_nan() {
        0.0
    } else {
        a.clamp(0.0, 1.0)
    }
}

/// Depth normalised over the frame: `(lo, 1 / (hi - lo))`, the scale 0 when
/// the depth is constant; `(v - lo) * scale` is the input.
pub fn depth_range(depth: &[f32]) -> (f32, f32) {
    let (lo, hi) = depth
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    if hi > lo {
        (lo, 1.0 / (hi - lo))
    } else {
        (if lo.is_finite() { lo } else { 0.0 }, 0.0)
    }
}

/// How much a pixel's albedo tells about it, the `w` of step 2 (0 where
/// the albedo is 0: emitters, glass and mirrors in raw AOVs, black paint;
/// 1 from `TAU` on). The à-trous methods' light-outline rule and firefly
/// clamp treat pixels with `w < 1/2` as emitters.
#[inline]
pub fn albedo_weight(a: [f32; 3]) -> f32 {
    let m = a.map(|v| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) });
    let t = (m[0].max(m[1]).max(m[2]) / TAU).min(1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Whether pixel `i` of the 3-plane albedo `a` (`n` pixels a plane) has
/// no albedo to speak of ([`albedo_weight`] below 1/2).
#[inline]
pub fn is_emitter(a: &[f32], n: usize, i: usize) -> bool {
    albedo_weight([a[i], a[n + i], a[2 * n + i]]) < 0.5
}

/// The learned methods' network inputs and filter inputs of a frame, in
/// one pass (runs of pixels in parallel on `pool`):
/// - `x`: for each of `colours` (3 planes each, linear radiance),
///   [`transfer`] of the colour times `exposure` (3 planes); then the albedo
///   input (3), the normal input (3) and the depth normalised over the
///   frame (1);
/// - `demodulated[k]`: `colours[k] / d` (3 planes each), `d` the frame's
///   demodulation factor (3 planes, [`demodulation`]).
///
/// The frame needs albedo, normal and depth (`who` names the method in
/// the error).
#[allow(clippy::too_many_arguments)]
pub fn network_inputs(
    pool: &Pool,
    f: &Frame,
    who: &str,
    exposure: f32,
    colours: &[&[f32]],
    d: &[f32],
    x: &mut [f32],
    demodulated: &mut [&mut [f32]],
) -> crate::Result<()> {
    let n = f.width * f.height;
    let a = f.require(Buffer::Albedo, who)?;
    let nrm = f.require(Buffer::Normal, who)?;
    let depth = f.require(Buffer::Depth, who)?;
    let k = colours.len();
    if x.len() != (3 * k + 7) * n || d.len() != 3 * n || demodulated.len() != k {
        return Err(crate::HostError::Usage(format!("{who}: network input buffers of the wrong size")));
    }
    if colours.iter().any(|c| c.len() != 3 * n) || demodulated.iter().any(|c| c.len() != 3 * n) {
        return Err(crate::HostError::Usage(format!("{who}: colour buffers of the wrong size")));
    }
    let (lo, scale) = depth_range(depth);
    let isa = Isa::detect();
    let mut planes: Vec<&mut [f32]> = x.chunks_mut(n.max(1)).collect();
    for c in demodulated.iter_mut() {
        planes.extend(c.chunks_mut(n.max(1)));
    }
    if n == 0 {
        return Ok(());
    }
    pool.planes(planes, 1 << 14, |start, runs| {
        let len = runs[0].len();
        let seg = |v: &'_ [f32], ch: usize| -> std::ops::Range<usize> {
            let _ = v;
            ch * n + start..ch * n + start + len
        };
        let (xs, dem) = runs.split_at_mut(3 * k + 7);
        for (j, col) in colours.iter().enumerate() {
            for ch in 0..3 {
                let src = &col[seg(col, ch)];
                // The exposure-scaled colour, through the core's SIMD log1p
                // (the demodulated plane holds it for a moment).
                for (o, &v) in dem[3 * j + ch].iter_mut().zip(src) {
                    *o = v * exposure;
                }
                let from = View::new(&*dem[3 * j + ch], 1, len, 1).expect("a run");
                let mut to = ViewMut::new(&mut *xs[3 * j + ch], 1, len, 1).expect("a run");
                mcdenoise_core::tonemap::map::<F32>(isa, Map::Log1p, &from, &mut to).expect("checked ISA and shapes");
                let dv = &d[seg(d, ch)];
                for ((o, &v), &q) in dem[3 * j + ch].iter_mut().zip(src).zip(dv) {
                    *o = v / q;
                }
            }
        }
        for ch in 0..3 {
            for (o, &v) in xs[3 * k + ch].iter_mut().zip(&a[seg(a, ch)]) {
                *o = albedo_input(v);
            }
            for (o, &v) in xs[3 * k + 3 + ch].iter_mut().zip(&nrm[seg(nrm, ch)]) {
                *o = normal_input(v);
            }
        }
        for (o, &v) in xs[3 * k + 6].iter_mut().zip(&depth[seg(depth, 0)]) {
            *o = if v.is_finite() { (v - lo) * scale } else { 0.0 };
        }
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pool() -> Pool {
        Pool::new(2).unwrap()
    }

    /// A frame of the pair (`a`, `b`: 3 planes each) and albedo, its colour
    /// made the pair's mean.
    fn pair_frame(w: usize, h: usize, a: &[f32], b: &[f32], albedo: &[f32]) -> Frame {
        let mut f = Frame::from_color("pair.exr", w, h, a.to_vec()).unwrap();
        f.set(Buffer::ColorB, b.to_vec()).unwrap();
        f.set(Buffer::Albedo, albedo.to_vec()).unwrap();
        assert!(f.average_pair());
        f
    }

    /// Two estimates of a dim chrome-like surface (no albedo), each pixel
    /// about 0.2 with noise, deterministic.
    fn dim_pair(w: usize, h: usize) -> (Vec<f32>, Vec<f32>) {
        let mut next = crate::methods::test_noise::xorshift32(0x2545_f491);
        let mut plane = || (0..3 * w * h).map(|_| 0.1 + (next() % 1000) as f32 / 5000.0).collect::<Vec<f32>>();
        (plane(), plane())
    }

    /// The threshold `m + FIREFLY_K sd` of the pair's mean luminance over
    /// the 5x5 window around `(x, y)` without it, in f64 from the
    /// estimates themselves.
    fn pair_threshold(a: &[f32], b: &[f32], w: usize, h: usize, x: usize, y: usize) -> f64 {
        let n = w * h;
        let lum = |i: usize| (0..3).map(|k| 0.5 * (a[k * n + i] as f64 + b[k * n + i] as f64)).sum::<f64>() / 3.0;
        let mut v = Vec::new();
        for yy in y.saturating_sub(2)..(y + 3).min(h) {
            for xx in x.saturating_sub(2)..(x + 3).min(w) {
                if (xx, yy) != (x, y) {
                    v.push(lum(yy * w + xx));
                }
            }
        }
        let m = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|l| (l - m) * (l - m)).sum::<f64>() / v.len() as f64;
        m + FIREFLY_K as f64 * var.sqrt()
    }

    /// A firefly in either estimate at a pixel without albedo is scaled in
    /// that estimate until the colour (their mean) is at the threshold;
    /// the other estimate and every other pixel stay bit for bit; which
    /// estimate held it does not matter.
    #[test]
    fn a_firefly_one_estimate_holds_without_albedo_is_clamped() {
        let (w, h) = (12usize, 10usize);
        let n = w * h;
        let albedo = vec![0.0f32; 3 * n];
        for &(x, y) in &[(5usize, 4usize), (0, 0), (11, 9)] {
            let p = y * w + x;
            let (a, mut b) = dim_pair(w, h);
            for (k, v) in [40.0f32, 65.0, 30.0].into_iter().enumerate() {
                b[k * n + p] = v;
            }
            let t = pair_threshold(&a, &b, w, h, x, y);
            let mut outs = Vec::new();
            for swap in [false, true] {
                let (ea, eb) = if swap { (&b, &a) } else { (&a, &b) };
                let mut f = pair_frame(w, h, ea, eb, &albedo);
                let before = f.get(Buffer::Color).unwrap().to_vec();
                assert_eq!(clamp_pair_fireflies(&mut f), 1, "at ({x}, {y})");
                let (c, eb2) = (f.get(Buffer::Color).unwrap(), f.get(Buffer::ColorB).unwrap());
                // The firefly's estimate and the other one, from the frame.
                let ea2: Vec<f32> = (0..3 * n).map(|j| 2.0 * c[j] - eb2[j]).collect();
                let (fly, other) = if swap { (&ea2[..], eb2) } else { (eb2, &ea2[..]) };
                let lum = |v: &[f32]| (v[p] as f64 + v[n + p] as f64 + v[2 * n + p] as f64) / 3.0;
                let (l, lo) = (lum(fly), lum(&a));
                assert!((0.5 * (l + lo) - t).abs() <= 1e-5 * t, "the mean at {}, threshold {t}", 0.5 * (l + lo));
                for k in 0..3 {
                    let want = [40.0f32, 65.0, 30.0][k] as f64 * (2.0 * t - lo) / 45.0;
                    assert!((fly[k * n + p] as f64 - want).abs() <= 1e-5 * want, "channel {k} keeps its hue");
                    // (`A` is `2 M - B` in the frame: within a few ulps of the firefly's 65.)
                    assert!((other[k * n + p] - a[k * n + p]).abs() <= 4e-5, "the other estimate kept");
                }
                for j in 0..3 * n {
                    if j % n != p {
                        assert_eq!(c[j].to_bits(), before[j].to_bits(), "pixel {} unchanged", j % n);
                    }
                }
                outs.push(c.to_vec());
            }
            for (u, v) in outs[0].iter().zip(&outs[1]) {
                assert!((u - v).abs() <= 4e-5, "A and B alike: {u} and {v}");
            }
        }
    }

    /// What both estimates hold stays: a light without albedo (a 3x3 one
    /// and a single pixel, the estimates differing by noise), a light's
    /// outline that one estimate's sample covered and the other's did not,
    /// and a firefly on a surface with albedo (left to [`clamp_fireflies`]);
    /// and nothing changes when the colour is not the pair's mean.
    #[test]
    fn what_both_estimates_hold_stays() {
        let (w, h) = (16usize, 12usize);
        let n = w * h;
        let (mut a, mut b) = dim_pair(w, h);
        let mut albedo = vec![0.0f32; 3 * n];
        for y in 3..6 {
            for x in 3..6 {
                for k in 0..3 {
                    a[k * n + y * w + x] = 50.0;
                    b[k * n + y * w + x] = 48.0;
                }
            }
        }
        // The light's outline: row 6 under it, the sample of A in the light.
        for x in 3..6 {
            for k in 0..3 {
                a[k * n + 6 * w + x] = 50.0;
            }
        }
        let single = 9 * w + 12;
        for k in 0..3 {
            a[k * n + single] = 30.0;
            b[k * n + single] = 33.0;
        }
        // A firefly in B on a surface with albedo.
        let lit = 2 * w + 13;
        for k in 0..3 {
            albedo[k * n + lit] = 0.5;
            b[k * n + lit] = 60.0;
        }
        let mut f = pair_frame(w, h, &a, &b, &albedo);
        let before = f.get(Buffer::Color).unwrap().to_vec();
        assert_eq!(clamp_pair_fireflies(&mut f), 0);
        assert_eq!(f.get(Buffer::Color).unwrap(), &before[..]);
        // One estimate: nothing to compare with.
        let mut g = Frame::from_color("one.exr", w, h, b.clone()).unwrap();
        g.set(Buffer::ColorB, a.clone()).unwrap();
        g.set(Buffer::Albedo, vec![0.0; 3 * n]).unwrap();
        assert_eq!(clamp_pair_fireflies(&mut g), 0);
        assert_eq!(g.get(Buffer::Color).unwrap(), &b[..]);
    }

    /// The separable window maximum against the window's own maximum (of 0
    /// and the values, NaN ignored), borders clipped.
    #[test]
    fn window_max_is_the_windows_largest() {
        let mut next = crate::methods::test_noise::xorshift32(0x9e37_79b9_u32);
        for &(w, h, r) in &[(1usize, 1usize, 1usize), (7, 5, 1), (9, 13, 2), (4, 3, 6), (33, 17, 2)] {
            let src: Vec<f32> = (0..w * h)
                .map(|_| match next() % 10 {
                    0 => f32::NAN,
                    1 => -1.0,
                    _ => (next() % 1000) as f32 / 100.0,
                })
                .collect();
            let mut out = vec![7.0f32; w * h];
            window_max(&pool(), &src, w, h, r, &mut out);
            for y in 0..h {
                for x in 0..w {
                    let mut m = 0.0f32;
                    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                            let v = src[yy * w + xx];
                            if v > m {
                                m = v;
                            }
                        }
                    }
                    assert_eq!(out[y * w + x], m, "{w}x{h} r {r} at ({x}, {y})");
                }
            }
        }
    }

    /// The excess split on a lit wall (albedo 0.7, exposure 1) with a light
    /// of the wall's own albedo in it: the light's irradiance (50, over
    /// [`CORE_FLOOR`]) is kept out of the filters; the wall, smooth and
    /// bright (3, over [`EXCESS_FLOOR`] but under [`CORE_FLOOR`]) as a
    /// 64-spp input's is, with its noise, keeps none (its brighter pixels
    /// are noise to filter, not a light). `c + excess` is the input.
    #[test]
    fn excess_keeps_a_light_out_and_a_bright_wall_in() {
        let (w, h) = (40, 30);
        let n = w * h;
        let light = |x: usize, y: usize| (14..26).contains(&x) && (10..20).contains(&y);
        let mut next = crate::methods::test_noise::xorshift32(0x1234_5678);
        let mut c = vec![0.0f32; 3 * n];
        for y in 0..h {
            for x in 0..w {
                let seed = next();
                // +-15 % noise on the wall; the light is constant.
                let v = if light(x, y) { 50.0 } else { 3.0 * (0.85 + 0.3 * (seed % 1000) as f32 / 1000.0) };
                for ch in 0..3 {
                    c[ch * n + y * w + x] = v;
                }
            }
        }
        let albedo = vec![0.7f32; 3 * n];
        let orig = c.clone();
        let mut excess = vec![0.0f32; 3 * n];
        split_excess(&pool(), &mut c, &albedo, None, w, h, 1.0, &mut excess);
        for i in 0..3 * n {
            assert!((c[i] + excess[i] - orig[i]).abs() <= 1e-5 * orig[i], "conserved at {i}");
            assert!(excess[i] >= 0.0 && c[i] >= 0.0, "non-negative at {i}");
        }
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let inner = (16..24).contains(&x) && (12..18).contains(&y);
                let far = !(10..30).contains(&x) || !(6..24).contains(&y);
                if inner {
                    assert!(excess[p] > 0.9 * orig[p], "the light's interior kept out at ({x}, {y}): {}", excess[p]);
                }
                if far {
                    assert_eq!(excess[p], 0.0, "the wall is filtered whole at ({x}, {y})");
                }
            }
        }
        // The same wall without the light: no excess anywhere.
        let mut c: Vec<f32> = orig.iter().map(|&v| if v == 50.0 { 3.0 } else { v }).collect();
        split_excess(&pool(), &mut c, &albedo, None, w, h, 1.0, &mut excess);
        assert!(excess.iter().all(|&e| e == 0.0), "a bright smooth wall is no light");
    }

    /// A light seen directly (no albedo, constant 3) wider than the filters'
    /// reach, on a wall (albedo 0.5, 0.5): its level, 4 times the wall's,
    /// is 2 by the wall, and it stays 2 inside it (the wider reach's mean),
    /// so the part the filters average is the same on both sides of where
    /// the reach's surfaces run out (the level was infinite there: a step
    /// of 1, a bright and a dark line after filtering). A light wider than
    /// the wider reach is split less and less over a reach (its middle
    /// filtered whole): no step over a pixel larger than a sixth of the
    /// excess (a seventh on a straight edge). On a wall whose brightness
    /// runs across the frame the reach's mean and the wider one's differ;
    /// the pixels without albedo drawing the one towards the other keep
    /// the steps under a sixth too (a step of 0.22 without).
    #[test]
    fn a_wide_light_is_split_without_a_step() {
        // (The third: a wall whose luminance runs from 0.3 to 0.7 across the
        // frame, so that the reach's and the wider reach's means differ:
        // 4 times 0.37 by the light's left edge against about 0.5.)
        for (size, light, slope) in [(60usize, 15..45usize, 0.0f32), (160, 10..150, 0.0), (60, 15..45, 0.4)] {
            let (w, h) = (size, size);
            let n = w * h;
            let inside = |x: usize, y: usize| light.contains(&x) && light.contains(&y);
            let mut c = vec![0.0f32; 3 * n];
            let mut albedo = vec![0.5f32; 3 * n];
            for y in 0..h {
                for x in 0..w {
                    for ch in 0..3 {
                        let wall = 0.5 + slope * (x as f32 / (w - 1) as f32 - 0.5);
                        c[ch * n + y * w + x] = if inside(x, y) { 3.0 } else { wall };
                        if inside(x, y) {
                            albedo[ch * n + y * w + x] = 0.0;
                        }
                    }
                }
            }
            let orig = c.clone();
            let mut excess = vec![0.0f32; 3 * n];
            split_excess(&pool(), &mut c, &albedo, None, w, h, 1.0, &mut excess);
            for i in 0..3 * n {
                assert!((c[i] + excess[i] - orig[i]).abs() <= 1e-5 * orig[i], "conserved at {i}");
            }
            // Inside the light but for its 3-pixel outline (the smoothness
            // test's and the outline's rows).
            let core = |x: usize, y: usize| {
                (light.start + 3..light.end - 3).contains(&x) && (light.start + 3..light.end - 3).contains(&y)
            };
            let mut steepest = 0.0f32;
            for y in 0..h {
                for x in 0..w {
                    if !core(x, y) {
                        continue;
                    }
                    let p = y * w + x;
                    if size == 60 && slope == 0.0 {
                        assert!((c[p] - 2.0).abs() < 1e-4, "{size}: the level at ({x}, {y}) is {}, not 2", c[p]);
                    }
                    for q in [p + 1, p + w] {
                        if core(q % w, q / w) {
                            steepest = steepest.max((c[q] - c[p]).abs());
                        }
                    }
                }
            }
            assert!(steepest <= 1.0 / 6.0, "{size} {slope}: a step of {steepest} between neighbours inside the light");
            if size == 160 {
                let mid = 80 * w + 80;
                assert!(
                    (c[mid] - 3.0).abs() < 1e-4,
                    "the middle of a light wider than the wider reach is filtered whole"
                );
            }
        }
    }

    /// A strip light one pixel thin across a ceiling (albedo 0.8; the strip's
    /// pixels half covered, albedo 0.4) at 1 spp: each strip pixel's sample
    /// hits the light (60) or misses it (the ceiling's 0.3). Without
    /// geometry the excess is the dotted line it came as; with it, each strip
    /// pixel's excess is the mean (f64) of the strip's excess within
    /// PARTIAL_RADIUS (the partly covered ones: a lone hit is a firefly and
    /// keeps its own). A row of another surface (normal turned away, the
    /// same albedo drop: a texture) 3 pixels from the strip gets none of
    /// its light (and does when it faces the ceiling's way); near-black
    /// pixels beside the ceiling keep their own; the filtered part `c` is
    /// the same either way.
    #[test]
    fn a_partly_covered_strip_gets_its_mean_excess() {
        let (w, h) = (48, 16);
        let n = w * h;
        let (strip, other, black) = (6usize, 9usize, 12usize);
        let mut next = crate::methods::test_noise::xorshift32(0x2545_f491_u32);
        let mut c = vec![0.0f32; 3 * n];
        let mut albedo = vec![0.8f32; 3 * n];
        let mut normal = vec![0.0f32; 3 * n];
        let depth = vec![2.0f32; n];
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let on_strip = y == strip && (4..w - 4).contains(&x);
                let hit = on_strip && next().is_multiple_of(2);
                let v = if hit { 60.0 } else { 0.3 * (0.9 + 0.2 * (next() % 100) as f32 / 100.0) };
                let a = if on_strip || y == other {
                    0.4
                } else if y == black {
                    0.02
                } else {
                    0.8
                };
                for ch in 0..3 {
                    c[ch * n + p] = if y == black && x % 5 == 0 { 20.0 } else { v };
                    albedo[ch * n + p] = a;
                }
                normal[2 * n + p] = 1.0;
                if y == other {
                    (normal[p], normal[2 * n + p]) = (1.0, 0.0);
                }
            }
        }
        let (ex0, ex1) = split_both(&c, &albedo, &normal, &depth, w, h);
        let r = PARTIAL_RADIUS;
        let (mut zeros, mut hits) = (0, 0);
        for x in 4..w - 4 {
            let p = strip * w + x;
            if ex0[p] == 0.0 {
                zeros += 1;
            } else if ex0[p] > 30.0 {
                hits += 1;
            }
            // Partly covered: a miss, or a hit with another within 2
            // pixels (a lone hit is a firefly, averaged whole: its own
            // excess stays).
            let lum = |q: usize| c[strip * w + q];
            let partial = |q: usize| {
                lum(q) < 1.0
                    || (q.saturating_sub(2)..=(q + 2).min(w - 5)).any(|o| o != q && o >= 4 && 2.0 * lum(o) >= lum(q))
            };
            if !partial(x) {
                assert_eq!(ex1[p], ex0[p], "a lone hit at x {x} keeps its own");
                continue;
            }
            let near: Vec<usize> = (x.saturating_sub(r).max(4)..=(x + r).min(w - 5)).filter(|&q| partial(q)).collect();
            let mean = near.iter().map(|&q| ex0[strip * w + q] as f64).sum::<f64>() / near.len() as f64;
            for ch in 0..3 {
                let got = ex1[ch * n + p] as f64;
                assert!(
                    (got - mean).abs() <= 1e-4 * mean.max(1.0),
                    "strip x {x} channel {ch}: {got} against the mean {mean}"
                );
            }
        }
        assert!(zeros > 8 && hits > 8, "the unsmoothed strip is dotted: {zeros} misses, {hits} hits");
        for x in 0..w {
            for y in [other, black] {
                let p = y * w + x;
                assert_eq!(ex1[p], ex0[p], "row {y} x {x} keeps its own excess");
            }
        }
        // Facing the ceiling's way, the same row is covered alike and takes
        // the strip's light.
        let mut facing = normal.clone();
        for x in 0..w {
            (facing[other * w + x], facing[2 * n + other * w + x]) = (0.0, 1.0);
        }
        let (mut c2, mut ex2) = (c.clone(), vec![0.0f32; 3 * n]);
        split_excess(&pool(), &mut c2, &albedo, Some((&facing, &depth)), w, h, 1.0, &mut ex2);
        assert!((0..w).any(|x| ex2[other * w + x] > 1.0), "without the normals' guard the light spreads");
    }

    /// `c` split without and with the geometry (`normal`, `depth`): the
    /// excess of each; the filtered part must be the same either way (the
    /// geometry only moves excess between partly covered pixels).
    fn split_both(
        c: &[f32],
        albedo: &[f32],
        normal: &[f32],
        depth: &[f32],
        w: usize,
        h: usize,
    ) -> (Vec<f32>, Vec<f32>) {
        let n = w * h;
        let (mut c0, mut ex0) = (c.to_vec(), vec![0.0f32; 3 * n]);
        split_excess(&pool(), &mut c0, albedo, None, w, h, 1.0, &mut ex0);
        let (mut c1, mut ex1) = (c.to_vec(), vec![0.0f32; 3 * n]);
        split_excess(&pool(), &mut c1, albedo, Some((normal, depth)), w, h, 1.0, &mut ex1);
        assert_eq!(c0, c1, "the filtered part is the same");
        (ex0, ex1)
    }

    /// A light without a surface (a sky through a window: albedo, normal and
    /// depth 0, radiance 60) above a wall (albedo 0.8, normal +z, depth 2):
    /// the edge row between them is covered 0.4 to 0.55, each pixel's AOVs
    /// the wall's times the part it misses (its normal shortened, its depth
    /// scaled), its 1-spp colour a hit (60) or a miss (0.3). Each edge
    /// pixel's excess is its part covered times the row's excess per part
    /// covered within PARTIAL_RADIUS (f64, the parts from the albedos),
    /// which needs the depths read through the normals' length (as they
    /// came, they differ by up to 25 %; the albedos are all alike).
    #[test]
    fn a_light_edge_gets_its_part_of_the_lights_excess() {
        let (w, h) = (40, 12);
        let n = w * h;
        let edge = 4usize;
        let part = |x: usize| 0.4 + 0.05 * (x % 4) as f32;
        let mut next = crate::methods::test_noise::xorshift32(0x9e37_79b9_u32);
        let (mut c, mut albedo) = (vec![0.0f32; 3 * n], vec![0.0f32; 3 * n]);
        let (mut normal, mut depth) = (vec![0.0f32; 3 * n], vec![0.0f32; n]);
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let (v, a, nz, d) = if y < edge {
                    (60.0, 0.0, 0.0, 0.0)
                } else if y == edge {
                    let hit = (next() % 1000) as f32 / 1000.0 < part(x);
                    let miss = 1.0 - part(x);
                    (if hit { 60.0 } else { 0.3 }, 0.8 * miss, miss, 2.0 * miss)
                } else {
                    (0.3 * (0.9 + 0.2 * (next() % 100) as f32 / 100.0), 0.8, 1.0, 2.0)
                };
                for ch in 0..3 {
                    c[ch * n + p] = v;
                    albedo[ch * n + p] = a;
                }
                normal[2 * n + p] = nz;
                depth[p] = d;
            }
        }
        let (ex0, ex1) = split_both(&c, &albedo, &normal, &depth, w, h);
        let r = PARTIAL_RADIUS;
        let row = |x: usize| edge * w + x;
        assert!((0..w).any(|x| ex0[row(x)] == 0.0) && (0..w).any(|x| ex0[row(x)] > 30.0), "a dotted edge");
        for x in 0..w {
            let near = x.saturating_sub(r)..(x + r + 1).min(w);
            let per_part = near.clone().map(|q| ex0[row(q)] as f64).sum::<f64>()
                / near.map(|q| 1.0 - albedo[row(q)] as f64 / 0.8).sum::<f64>();
            let want = (1.0 - albedo[row(x)] as f64 / 0.8) * per_part;
            for ch in 0..3 {
                let got = ex1[ch * n + row(x)] as f64;
                assert!((got - want).abs() <= 1e-4 * want.max(1.0), "edge x {x} channel {ch}: {got} against {want}");
            }
        }
    }

    /// The envelope against its definition, `max_q b(q) DECAY^(|dx|+|dy|)`.
    #[test]
    fn demodulation_is_the_envelope_of_the_blend() {
        let (w, h) = (13, 9);
        let n = w * h;
        let mut a = vec![0.0f32; 3 * n];
        let mut s = 12345u32;
        for v in a.iter_mut() {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            let u = (s >> 8) as f32 / (1 << 24) as f32;
            *v = if u < 0.3 {
                0.0
            } else if u < 0.4 {
                50.0 * u
            } else {
                u * u * 0.9
            };
        }
        let mut d = vec![0.0f32; 3 * n];
        demodulation(&pool(), &a, w, h, &mut d);
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    let mut best = 0.0f64;
                    for qy in 0..h {
                        for qx in 0..w {
                            let q = qy * w + qx;
                            let b = blend([a[q], a[n + q], a[2 * n + q]])[c] as f64;
                            let dist = (x as i64 - qx as i64).abs() + (y as i64 - qy as i64).abs();
                            best = best.max(b * (DECAY as f64).powi(dist as i32));
                        }
                    }
                    let got = d[c * n + y * w + x] as f64;
                    assert!((got - best).abs() <= 1e-6 * best, "({x},{y}) channel {c}: {got} against {best}");
                }
            }
        }
    }

    /// Neighbours' factors within 1 / DECAY; every factor in (0, 1].
    #[test]
    fn factors_are_bounded_and_log_lipschitz() {
        let (w, h) = (32, 17);
        let n = w * h;
        let mut a = vec![0.0f32; 3 * n];
        for (i, v) in a.iter_mut().enumerate() {
            *v = match i % 7 {
                0 => 0.0,
                1 => 46.0,
                2 => 1e-20,
                3 => 0.5,
                4 => f32::NAN,
                5 => 0.004,
                _ => 0.9,
            };
        }
        let mut d = vec![0.0f32; 3 * n];
        demodulation(&pool(), &a, w, h, &mut d);
        for c in 0..3 {
            for y in 0..h {
                for x in 0..w {
                    let v = d[c * n + y * w + x];
                    assert!(v > 0.0 && v <= 1.0, "{v}");
                    if x + 1 < w {
                        let r = d[c * n + y * w + x + 1] / v;
                        assert!((DECAY..=1.0 / DECAY).contains(&r), "{r}");
                    }
                    if y + 1 < h {
                        let r = d[c * n + (y + 1) * w + x] / v;
                        assert!((DECAY..=1.0 / DECAY).contains(&r), "{r}");
                    }
                }
            }
        }
    }

    /// Continuous in the albedo: 1 at 0, the albedo from TAU on (alone).
    #[test]
    fn blend_is_continuous_and_ends_at_radiance_and_albedo() {
        assert_eq!(blend([0.0; 3]), [1.0; 3]);
        assert_eq!(blend([0.5, 0.5, 0.5]), [0.5; 3]);
        let b = blend([0.8, 0.0, 0.4]);
        assert!(b[0] == 0.8 && (b[1] - KAPPA * 0.8).abs() < 1e-7 && b[2] == 0.4, "{b:?}");
        let mut prev = blend([0.0; 3])[0];
        for i in 1..=2000 {
            let a = i as f32 * 1e-5;
            let b = blend([a; 3])[0];
            assert!((b - prev).abs() < 2e-3, "jump at {a}: {prev} -> {b}");
            prev = b;
        }
    }

    #[test]
    fn exposure_scales_inversely() {
        let (w, h) = (40, 23);
        let rgb: Vec<f32> = (0..3 * w * h).map(|i| ((i * 37) % 101) as f32 / 50.0).collect();
        let e1 = exposure(&rgb, w, h);
        for k in [1.0 / 64.0, 0.5, 8.0, 64.0] {
            let scaled: Vec<f32> = rgb.iter().map(|v| v * k).collect();
            let ek = exposure(&scaled, w, h);
            assert!((ek * k / e1 - 1.0).abs() < 1e-5, "k {k}: {ek} {e1}");
        }
        assert_eq!(exposure(&vec![0.0; 3 * w * h], w, h), 1.0);
    }

    /// Window sums against the sums written out in f64, at sizes and radii
    /// from one pixel to windows larger than the image.
    #[test]
    fn box_sum_is_the_window_sum() {
        for &(w, h, r) in &[(1usize, 1usize, 0usize), (7, 5, 1), (9, 13, 3), (4, 3, 6), (31, 17, 2), (16, 40, 7)] {
            let v: Vec<f32> = (0..w * h).map(|i| ((i * 37 + 11) % 23) as f32 * 0.25 - 2.0).collect();
            let mut got = v.clone();
            box_sum(&mut got, w, h, r);
            for y in 0..h {
                for x in 0..w {
                    let mut s = 0.0f64;
                    for qy in y.saturating_sub(r)..(y + r + 1).min(h) {
                        for qx in x.saturating_sub(r)..(x + r + 1).min(w) {
                            s += v[qy * w + qx] as f64;
                        }
                    }
                    assert!((got[y * w + x] as f64 - s).abs() < 1e-4, "{w}x{h} r {r} at ({x}, {y})");
                }
            }
        }
    }
}

//! The two baseline methods: pass-through and temporal accumulation.

use std::marker::PhantomData;

use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};

use super::{Ctx, Denoiser, Plan, Timings};
use crate::error::{HostError, Result};
use crate::io::frame::{Buffer, Frame, FrameInfo};
use crate::runtime::memory::{Footprint, Ledger};
use crate::runtime::precision::{store_bytes, HostPrecision, Kind, Planes};

/// `--method none`: the (sanitised) input through the pipeline's precision.
pub struct Passthrough<P: HostPrecision> {
    plan: Plan,
    _p: PhantomData<P>,
}

impl<P: HostPrecision> Passthrough<P> {
    /// For a sequence starting with `first`.
    pub fn new(_first: &Frame) -> Self {
        Passthrough { plan: Plan { built: vec!["encode", "decode"], skipped: vec![] }, _p: PhantomData }
    }
}

impl<P: HostPrecision> Passthrough<P> {
    /// Memory per frame (see [`crate::runtime::memory`]): the colour in storage, then
    /// the f32 output decoded from it.
    pub fn footprint(_info: &FrameInfo) -> Footprint {
        let s = store_bytes::<P>();
        let mut l = Ledger::default();
        l.alloc(3 * s).alloc(12).free(3 * s);
        Footprint { kept: 0, peak: l.peak(), scratch: 0 }
    }
}

impl<P: HostPrecision> Denoiser for Passthrough<P> {
    fn name(&self) -> &'static str {
        "none"
    }
    fn plan(&self) -> &Plan {
        &self.plan
    }
    fn denoise(&mut self, f: &Frame, _ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        let color = f.require(Buffer::Color, "none")?;
        let enc = t.time("encode", || Planes::<P::Store>::encode::<P>(3, f.width, f.height, color));
        Ok(t.time("decode", || enc.decode::<P>()))
    }
}

/// The scene scale used for the temporal position test: the diagonal of the
/// bounding box of the frame's hit positions (pixels with depth 0 or position
/// exactly 0 are background). 1.0 when there are none.
pub fn scene_scale(f: &Frame) -> f32 {
    let Some(p) = f.get(Buffer::Position) else { return 1.0 };
    let n = f.width * f.height;
    let depth = f.get(Buffer::Depth);
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for i in 0..n {
        let v = [p[i], p[n + i], p[2 * n + i]];
        let background = v == [0.0; 3] || depth.is_some_and(|d| d[i] == 0.0);
        if background {
            continue;
        }
        for c in 0..3 {
            lo[c] = lo[c].min(v[c]);
            hi[c] = hi[c].max(v[c]);
        }
    }
    let d2: f32 = (0..3).map(|c| (hi[c] - lo[c]).powi(2)).sum();
    if d2.is_finite() && d2 > 0.0 {
        d2.sqrt()
    } else {
        1.0
    }
}

/// Fixed-point format of the history counts (Q7.8: up to 127 frames).
pub const HISTORY_FRAC: i8 = 8;

/// Fraction of the scene scale a reprojected tap's world position may differ by.
pub const POSITION_TOLERANCE: f32 = 0.02;

/// The history clamp's width of the `ta` method and of training (standard
/// deviations of the current colour over a 5x5 window, widened by half the
/// history; see [`mcdenoise_core::temporal`]): a light that moved is not
/// dragged along for five frames. Chosen on the generator's `val` scenes
/// and training scenes with moving lights. TA's own PSNR chose the width
/// and the window (1 against 0.5 and 1.5, radius 2 against 1: +0.1 to +4.3
/// dB over no clamp on every one of them), the denoisers' the floor: without
/// it a window of zeros (a dim wall at 1 spp) wiped the history out, and
/// WSKP-6 lost 0.04-0.45 dB on five of the seven usable `val` scenes; with
/// it (0.5) WSKP-6 is within 0.13 dB of no clamp on every `val` scene
/// (mean 35.14 against 35.18 dB) and 0.0 to 0.8 dB over it on four
/// training scenes with moving lights; a floor of 0.25 gained 0.4 dB more
/// there and lost 0.1 dB more on `val`.
pub const TA_CLAMP: f32 = 1.0;
/// The history clamp's window radius.
pub const TA_CLAMP_RADIUS: usize = 2;
/// The clamp's name in plans.
pub const CLAMP_STAGE: &str = "history clamp (5x5 mean -+ k sd of the frame)";

/// The history rejection's threshold ([`reject_stale`]): where the 9x9
/// mean luminance of the accumulated colour and of the frame differ by
/// more than `TA_REJECT` standard errors of the frame's mean, the history
/// starts to give way, and by `2 TA_REJECT` it is gone.
pub const TA_REJECT: f32 = 3.0;
/// The history rejection's threshold for the accumulation WSKP and AFN
/// read (the `ta` method's is [`TA_REJECT`]; training makes its inputs with
/// [`TA_REJECT`] too, as the bundled weights were). A network filters the
/// accumulation's noise, not its lag: at 2 standard errors instead of 3 the
/// history gives way sooner to a light that moved. Prompted by the foreign
/// set's moving light (AFN 30.27 -> 30.85 dB), chosen on the generator's
/// scenes: on the 35 training scenes rendered here with a moving light
/// (8 frames each) AFN +0.04, WSKP-6 +0.17, WSKP-3 +0.16 dB on average
/// (1.5: +0.04, +0.26, +0.23); on the held-out `hi` and `val` scenes
/// +0.01 to +0.03 (1.5: AFN -0.003); TA alone loses 0.05-0.18 dB at 2, so
/// its own threshold stays (docs/quality.md, "The history rejection for
/// the networks").
pub const LEARNED_TA_REJECT: f32 = 2.0;
/// The rejection's window radius (9x9 means).
pub const TA_REJECT_RADIUS: usize = 4;
/// The rejection's scales ([`reject_stale`]): the radius of the windows
/// whose means are compared and the multiple of the threshold used there.
/// The first is the 9x9 means' (`TA_REJECT_RADIUS`); `--ta-reject-scales k`
/// tests the first `k`.
pub const REJECT_SCALES: [(usize, f32); 3] = [(TA_REJECT_RADIUS, 1.0), (8, 1.0), (16, 1.5)];
/// The scales `ta` tests at: the 9x9 means alone. `ta`'s PSNR is its
/// noise, and every history let go adds to it (on the foreign moving light
/// 22.71 dB with one scale, 22.41 with two, 21.68 with three).
pub const TA_REJECT_SCALES: usize = 1;
/// The scales WSKP and AFN test at: 9x9, 17x17 and 33x33 means (the last
/// at 1.5 times the threshold). A light that moves leaves a lag spread
/// thin over a wall, under the 9x9 means' standard error (a ninth of a
/// pixel's noise) yet over a 33x33 mean's (a 33rd); a network filters the
/// noise of a history let go, not its lag. Chosen on the 50 rendered
/// training scenes with a moving light (docs/quality.md, "The history
/// rejection at three scales").
pub const LEARNED_TA_REJECT_SCALES: usize = 3;
/// The rejection's name in plans with 1, 2 and 3 scales.
pub const REJECT_STAGES: [&str; 3] = [
    "history rejection (9x9 means against the frame's noise)",
    "history rejection (9x9 and 17x17 means against the frame's noise)",
    "history rejection (9x9, 17x17 and 33x33 means against the frame's noise)",
];
/// The rejection's name in plans at one scale (`ta`'s).
pub const REJECT_STAGE: &str = REJECT_STAGES[0];
/// Bytes per pixel the rejection holds for a moment at `scales` scales:
/// the accumulated colour in f32, three statistics planes, the box sums'
/// copies of the planes they sum (the three run at once) and the blend;
/// with more than one scale, one copy of the three planes at a time to
/// sum for every scale but the last; and the relighting's share of the
/// counts kept, held throughout. While the relighting runs it holds its
/// factors, four planes to sum, the four sums' copies (they run at once)
/// and a byte of mask a pixel instead of the tests' blend and sums.
pub const fn reject_temp_bytes(scales: usize) -> u64 {
    let tests = (11 + if scales > 1 { 3 } else { 0 }) * 4;
    let relight = 16 * 4 + 1;
    if tests > relight {
        tests
    } else {
        relight
    }
}

/// Checks the number of the history rejection's scales given by the user.
pub fn check_reject_scales(k: usize) -> Result<usize> {
    if (1..=REJECT_SCALES.len()).contains(&k) {
        Ok(k)
    } else {
        Err(HostError::Usage(format!(
            "--ta-reject-scales: expected 1 (9x9 means), 2 (and 17x17) or 3 (and 33x33); got {k}"
        )))
    }
}

/// Checks the history rejection's threshold given by the user.
pub fn check_reject(z: f32) -> Result<f32> {
    check_off_to_1e6(z, "--ta-reject", "a threshold", "standard errors")
}

/// `v` if it is in `[0, 1e6]`, else a usage error naming `option`.
fn check_off_to_1e6(v: f32, option: &str, what: &str, unit: &str) -> Result<f32> {
    if v.is_finite() && (0.0..=1e6).contains(&v) {
        Ok(v)
    } else {
        Err(HostError::Usage(format!("{option}: expected {what} from 0 (off) to 1e6 {unit}; got {v}")))
    }
}

/// The history rejection (after A-SVGF's idea, Schied et al. 2018: let the
/// history go where the frame says the signal changed). The clamp
/// ([`TemporalParams::clamp_sigma`]) compares a pixel's history with the
/// spread of its 5x5 neighbours, which at 1 spp is as wide as the signal:
/// a light that moved, dimming or brightening a wall by half, passes it,
/// and the accumulation lags for `1 / alpha_min` frames. A mean over a
/// window is far less noisy than its pixels: with `m_f` and `m_t` the 9x9
/// mean luminance of the frame `a` (of `(a + b) / 2` with the second
/// estimate `b`) and of the accumulated colour, and `se` the standard
/// error of `m_f` (from the pair's squared difference with `b`, else from
/// the squared differences of neighbouring pixels, which count a little of
/// the signal's variation as noise and so reject a little less; with one
/// estimate the test also has half the samples), `z = |m_f - m_t| / se`; the accumulated colour
/// moves towards the frame by `beta = clamp(z / z0 - 1, 0, 1)` and the
/// history counts shrink by `1 - beta`. A static scene's windows stay
/// under `z0` (about 2 % of the pixels of a lounge pan at `z0 = 3`);
/// a moving light's over it. With several `scales` ([`REJECT_SCALES`]:
/// window radius, multiple of `z0`) each tests its own window means and
/// `beta` is the largest of theirs: a wider window's mean has a smaller
/// standard error and finds a lag too small for a 9x9 one. With `relit`,
/// the accumulated colour is first relit where a light moved ([`relight`])
/// and the tests compare the frame with the history relit.
#[allow(clippy::too_many_arguments)]
pub fn reject_stale<P: HostPrecision>(
    pool: &crate::runtime::par::Pool,
    a: &[f32],
    b: Option<crate::io::frame::Pair<'_>>,
    w: usize,
    h: usize,
    z0: f32,
    scales: &[(usize, f32)],
    relit: bool,
    albedo: Option<&[f32]>,
    out: &mut Planes<P::Store>,
    hist: &mut Planes<P::Store>,
) {
    let n = w * h;
    if n == 0 || z0 <= 0.0 || scales.is_empty() || a.len() < 3 * n || out.data.len() != 3 * n || hist.data.len() != n {
        return;
    }
    let b = b.filter(|p| p.b.len() >= 3 * n);
    const RUN: usize = 1 << 14;
    let lum = |v: &[f32], p: usize| {
        let l = crate::methods::features::luminance(v[p], v[n + p], v[2 * n + p]);
        if l.is_finite() {
            l
        } else {
            0.0
        }
    };
    let mut oc = vec![0.0f32; 3 * n];
    crate::runtime::precision::decode_par::<P>(pool, &out.data, &mut oc, out.frac);
    // The frame's luminance, its squared noise term, the accumulated one.
    let (mut mf, mut v, mut mt) = (vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]);
    {
        let oc = &oc;
        pool.planes(vec![&mut mf[..], &mut v[..], &mut mt[..]], RUN, |start, runs| {
            let mut at = crate::methods::features::Walk::new(start, w);
            for j in 0..runs[0].len() {
                let (p, x, y) = at.next();
                let la = lum(a, p);
                let (f, d) = match b {
                    // The mean of the pair and its variance (half of one
                    // estimate's, which (a - b)^2 / 2 estimates).
                    Some(pair) => pair.mean_and_variance(la, lum(pair.b, p)),
                    // One estimate: half the squared difference from the
                    // right and the lower neighbour, whose expectation is the
                    // noise variance plus half the squared one-pixel change
                    // of the signal (a difference-based estimate, after
                    // Rice 1984): a window's own variance would count every
                    // gradient, edge and shadow in it as noise.
                    None => (la, neighbour_variance(|q| lum(a, q), p, x, y, w, h)),
                };
                runs[0][j] = f;
                runs[1][j] = d;
                runs[2][j] = lum(oc, p);
            }
        });
    }
    // The history counts' share kept by the relighting (1: not relit).
    let mut keep = vec![1.0f32; n];
    if relit {
        // The emitter rule's floor in this frame's radiance.
        let e = crate::methods::fallback::positive_exposure(crate::methods::features::exposure(a, w, h));
        let lights = crate::methods::features::CORE_FLOOR / e;
        relight(pool, w, h, z0, &mf, &v, &mut mt, &mut oc, &mut keep, albedo, P::store_max(out.frac), lights);
    }
    // Each scale's blend towards the frame; `beta` keeps the largest.
    let mut beta = vec![0.0f32; n];
    let last = scales.len() - 1;
    for (k, &(r, m)) in scales.iter().enumerate() {
        let z0 = z0 * m;
        // The last scale sums the planes themselves.
        let (mut sf, mut sv, mut st) = if k == last {
            (std::mem::take(&mut mf), std::mem::take(&mut v), std::mem::take(&mut mt))
        } else {
            (mf.clone(), v.clone(), mt.clone())
        };
        let sums = |x: &mut Vec<f32>| crate::methods::features::box_sum(x, w, h, r);
        pool.install(|| {
            rayon::join(|| sums(&mut sf), || rayon::join(|| sums(&mut sv), || sums(&mut st)));
        });
        let span = |p: usize, len: usize| crate::methods::features::window_span(p, len, r);
        let (sf, sv, st) = (&sf, &sv, &st);
        pool.planes(vec![&mut beta[..]], RUN, |start, runs| {
            let mut at = crate::methods::features::Walk::new(start, w);
            for b in runs[0].iter_mut() {
                let (p, x, y) = at.next();
                let cnt = span(x, w) * span(y, h);
                let (f, t) = (sf[p] / cnt, st[p] / cnt);
                // The frame mean's variance: the window's mean of the
                // per-pixel variance over the count.
                let var = sv[p] / cnt / cnt;
                let z = (f - t).abs() / var.max(1e-20).sqrt();
                if z.is_finite() {
                    *b = b.max((z / z0 - 1.0).clamp(0.0, 1.0));
                }
            }
        });
    }
    let mut hv = vec![0.0f32; n];
    P::decode(&hist.data, &mut hv, hist.frac);
    let (beta, keep) = (&beta, &keep);
    let mut planes: Vec<&mut [f32]> = oc.chunks_mut(n).collect();
    planes.push(&mut hv[..]);
    pool.planes(planes, RUN, |start, runs| {
        for j in 0..runs[0].len() {
            let p = start + j;
            runs[3][j] *= keep[p];
            let beta = beta[p];
            if beta > 0.0 {
                for (ch, run) in runs[..3].iter_mut().enumerate() {
                    let cur = a[ch * n + p];
                    if cur.is_finite() {
                        run[j] += beta * (cur - run[j]);
                    }
                }
                runs[3][j] *= 1.0 - beta;
            }
        }
    });
    crate::runtime::precision::encode_par::<P>(pool, &oc, &mut out.data, out.frac);
    P::encode(&hv, &mut hist.data, hist.frac);
}

/// The relighting's window radius (65x65 means; [`relight`]).
pub const RELIGHT_RADIUS: usize = 32;
/// The radius of the relighting's local check (17x17 means).
pub const RELIGHT_CHECK_RADIUS: usize = 8;
/// The largest factor the relighting scales a history by (and the
/// smallest, its inverse).
pub const RELIGHT_MAX: f32 = 4.0;
/// The share of a pixel's history count that a full relighting takes away
/// (the history relit is not as good as one that held: its level is the
/// frame's wide mean, whose noise the filters after it should see).
pub const RELIGHT_COUNT: f32 = 0.5;
/// The relighting's name in plans.
pub const RELIGHT_STAGE: &str = "history relighting (65x65 means, where a light moved)";

/// Relights the accumulated colour `oc` (3 planes of `w x h`) where a light
/// moved, before the rejection's tests ([`reject_stale`]). With `F` and
/// `T` the [`RELIGHT_RADIUS`] window means of the frame's luminance `mf`
/// and of the accumulated one `mt` over the pixels that are not lights
/// (with `albedo`, those that have some; and whose `mt` is not above
/// `lights`, the emitter rule's floor: a light that covers its pixels in
/// part has the albedo of what it covers), and `z` their difference in standard
/// errors of `F` (from the per-pixel noise `v`, as the rejection's), the
/// accumulated colour is scaled by `g = (F / T)^gamma`, `gamma = clamp(z /
/// z0 - 1, 0, 1)`, held within `1 / RELIGHT_MAX ..= RELIGHT_MAX`, and
/// only where it brings the [`RELIGHT_CHECK_RADIUS`] window means of the
/// two closer (`|f - g t| < |f - t|`: a window holding a spotlight's cone
/// and the dark around it relights the cone, not the dark). `mt` is scaled
/// with it, and `keep[p]` is set to the share of the history count kept:
/// `1 - RELIGHT_COUNT gamma` where relit, else 1. Lights and values at the
/// storage format's `bound` (saturated: their level is not known) are not
/// relit.
///
/// A light that moves changes a wall's shading by a smooth factor: scaled
/// by it, the history keeps its samples where the rejection alone moves it
/// to the frame's one sample. What the factor does not explain (a shadow's
/// edge, an object that moved) the rejection's tests still find. A wide
/// window's mean has a small standard error (a 65th of a pixel's noise);
/// narrower ones (a ratio from 9x9 to 33x33 means, the narrowest whose
/// standard error is under 5 or 10 % of its mean) scored lower (docs/quality.md,
/// "The history relit where a light moved").
#[allow(clippy::too_many_arguments)]
pub fn relight(
    pool: &crate::runtime::par::Pool,
    w: usize,
    h: usize,
    z0: f32,
    mf: &[f32],
    v: &[f32],
    mt: &mut [f32],
    oc: &mut [f32],
    keep: &mut [f32],
    albedo: Option<&[f32]>,
    bound: f32,
    lights: f32,
) {
    let n = w * h;
    if n == 0 || z0 <= 0.0 || mf.len() != n || v.len() != n || mt.len() != n || oc.len() != 3 * n || keep.len() != n {
        return;
    }
    let albedo = albedo.filter(|a| a.len() >= 3 * n);
    // A light seen directly (no albedo; or its accumulated luminance above
    // the emitter rule's floor `lights` with two of its 8 neighbours over
    // half of it: a light that covers its pixels in part has the albedo of
    // what it covers, and a lone firefly is not a light) is neither counted
    // nor relit. (A floor on the pixel alone left out the frame's fireflies
    // but not their share in the history, and the means went apart.)
    let mask: Vec<bool> = {
        let mt: &[f32] = mt;
        let light = |p: usize| {
            if mt[p] <= lights {
                return false;
            }
            let (x, y) = (p % w, p / w);
            let mut bright = 0;
            for qy in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                for qx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                    let q = qy * w + qx;
                    if q != p && mt[q] > crate::methods::features::SMOOTH * lights {
                        bright += 1;
                    }
                }
            }
            bright >= 2
        };
        (0..n).map(|p| !light(p) && albedo.is_none_or(|a| !crate::methods::features::is_emitter(a, n, p))).collect()
    };
    let surface = |p: usize| mask[p];
    // A plane over the surfaces alone (0 elsewhere).
    let masked =
        |x: &[f32]| -> Vec<f32> { x.iter().enumerate().map(|(p, &v)| if surface(p) { v } else { 0.0 }).collect() };
    const RUN: usize = 1 << 14;
    let mut gain = vec![1.0f32; n];
    {
        let r = RELIGHT_RADIUS;
        let (mut sf, mut sv, mut st) = (masked(mf), masked(v), masked(mt));
        let mut sc: Vec<f32> = (0..n).map(|p| if surface(p) { 1.0 } else { 0.0 }).collect();
        let sums = |x: &mut Vec<f32>| crate::methods::features::box_sum(x, w, h, r);
        pool.install(|| {
            rayon::join(
                || rayon::join(|| sums(&mut sf), || sums(&mut sc)),
                || rayon::join(|| sums(&mut sv), || sums(&mut st)),
            );
        });
        let (sf, sv, st, sc) = (&sf, &sv, &st, &sc);
        // A value at the storage format's bound is saturated: its level is
        // not known, and scaled it would no longer read as saturated
        // ([`restore_saturated`](crate::runtime::precision::restore_saturated)).
        let ocr: &[f32] = oc;
        let saturated = |p: usize| (0..3).any(|c| ocr[c * n + p].abs() >= bound);
        pool.planes(vec![&mut gain[..], &mut keep[..]], RUN, |start, runs| {
            for j in 0..runs[0].len() {
                let p = start + j;
                runs[1][j] = 1.0;
                let cnt = sc[p];
                if !surface(p) || saturated(p) || cnt < 0.5 {
                    continue;
                }
                let (f, t) = (sf[p] / cnt, st[p] / cnt);
                let se = (sv[p] / cnt / cnt).max(1e-20).sqrt();
                let gamma = ((f - t).abs() / se / z0 - 1.0).clamp(0.0, 1.0);
                if gamma > 0.0 && f > 0.0 && t > 0.0 {
                    let g = (f / t).clamp(1.0 / RELIGHT_MAX, RELIGHT_MAX).powf(gamma);
                    if g.is_finite() {
                        runs[0][j] = g;
                        runs[1][j] = 1.0 - RELIGHT_COUNT * gamma;
                    }
                }
            }
        });
    }
    {
        let r = RELIGHT_CHECK_RADIUS;
        let (mut sf, mut st) = (masked(mf), masked(mt));
        let sums = |x: &mut Vec<f32>| crate::methods::features::box_sum(x, w, h, r);
        pool.install(|| {
            rayon::join(|| sums(&mut sf), || sums(&mut st));
        });
        let (sf, st) = (&sf, &st);
        // (The windows' sums, not their means: the comparison is the same.)
        pool.planes(vec![&mut gain[..], &mut keep[..]], RUN, |start, runs| {
            for j in 0..runs[0].len() {
                let p = start + j;
                let g = runs[0][j];
                let closer = (sf[p] - g * st[p]).abs() < (sf[p] - st[p]).abs();
                if g != 1.0 && !closer {
                    runs[0][j] = 1.0;
                    runs[1][j] = 1.0;
                }
            }
        });
    }
    let gain = &gain;
    let mut planes: Vec<&mut [f32]> = oc.chunks_mut(n).collect();
    planes.push(mt);
    pool.planes(planes, RUN, |start, runs| {
        for run in runs.iter_mut() {
            for (j, val) in run.iter_mut().enumerate() {
                *val *= gain[start + j];
            }
        }
    });
}

/// Floors the history counts at 1: every pixel's accumulated colour holds
/// at least the frame just blended in. The accumulation marks a pixel that
/// restarted (no tap of the previous frame accepted) with a count of 0
/// and the rejection shrinks counts towards 0, and the next frame's blend,
/// `alpha = max(1 / (n + 1), alpha_min)`, would take such a history for
/// nothing (`alpha = 1`) and throw the frame in it away; with the floor it
/// averages the two, as BMFR counts a restarted pixel's one sample.
pub fn floor_counts<P: HostPrecision>(pool: &crate::runtime::par::Pool, hist: &mut Planes<P::Store>) {
    let n = hist.data.len();
    let mut hv = vec![0.0f32; n];
    P::decode(&hist.data, &mut hv, hist.frac);
    pool.planes(vec![&mut hv[..]], 1 << 14, |_, runs| {
        for c in runs[0].iter_mut() {
            *c = if c.is_finite() { c.max(1.0) } else { 1.0 };
        }
    });
    P::encode(&hv, &mut hist.data, hist.frac);
}

/// One estimate's noise variance at pixel `p = (x, y)` of a `w x h` image
/// `v`: half the squared difference from its right and its lower
/// neighbour, averaged over those inside (0 for a single pixel). Its
/// expectation is the noise variance plus half the squared one-pixel change
/// of the signal (Rice 1984).
#[inline]
pub fn neighbour_variance(v: impl Fn(usize) -> f32, p: usize, x: usize, y: usize, w: usize, h: usize) -> f32 {
    let here = v(p);
    let (mut sum, mut k) = (0.0f32, 0.0f32);
    for q in [(x + 1 < w).then_some(p + 1), (y + 1 < h).then_some(p + w)].into_iter().flatten() {
        let d = here - v(q);
        sum += 0.5 * d * d;
        k += 1.0;
    }
    if k > 0.0 {
        sum / k
    } else {
        0.0
    }
}

/// Records the history rejection at `z` and `scales` in `plan`: built when
/// `z > 0`, else skipped (replacing an earlier entry of any number of
/// scales).
pub fn reject_plan(plan: &mut Plan, z: f32, scales: usize) {
    let name = REJECT_STAGES[scales.clamp(1, REJECT_STAGES.len()) - 1];
    plan.built.retain(|s| !REJECT_STAGES.contains(s));
    plan.skipped.retain(|(s, _)| !REJECT_STAGES.contains(s));
    stage_plan(plan, name, z > 0.0, "--ta-reject 0");
    relight_first(plan);
}

/// Lists a built relighting just before the rejection it runs first
/// within (where it is, without one).
fn relight_first(plan: &mut Plan) {
    if let Some(at) = plan.built.iter().position(|s| *s == RELIGHT_STAGE) {
        let stage = plan.built.remove(at);
        let r = plan.built.iter().position(|s| REJECT_STAGES.contains(s)).unwrap_or(at);
        plan.built.insert(r, stage);
    }
}

/// Records the relighting in `plan`: built when `on` and the rejection
/// (threshold `z`) runs, else skipped (replacing an earlier entry).
pub fn relight_plan(plan: &mut Plan, z: f32, on: bool) {
    let why = if on { "--ta-reject 0" } else { "--ta-relight off" };
    stage_plan(plan, RELIGHT_STAGE, on && z > 0.0, why);
    relight_first(plan);
}

/// Records `stage` in `plan` as built when `on`, else as skipped for `why`
/// (replacing an earlier entry).
fn stage_plan(plan: &mut Plan, stage: &'static str, on: bool, why: &str) {
    plan.built.retain(|s| *s != stage);
    plan.skipped.retain(|(s, _)| *s != stage);
    if on {
        plan.built.push(stage);
    } else {
        plan.skipped.push((stage, why.into()));
    }
}

/// Records the history clamp of width `k` in `plan`: built when `k > 0`,
/// else skipped for `why` (replacing an earlier entry).
pub fn clamp_plan(plan: &mut Plan, k: f32, why: &str) {
    stage_plan(plan, CLAMP_STAGE, k > 0.0, why);
}

/// The accumulation's builders of a learned method whose struct holds its
/// accumulation in `ta` and its plan in `plan` (AFN and WSKP): the history
/// clamp, the rejection's threshold and its scales, each recorded in the
/// plan.
macro_rules! ta_builders {
    () => {
        /// With the accumulation's history clamp of width `k` (0: off; unless
        /// told, the weights' own, `ta_clamp`: see [`crate::methods::ta_clamp_for`]).
        ///
        /// # Errors
        /// A width outside `[0, 1e6]`.
        pub fn with_ta_clamp(mut self, k: f32) -> crate::error::Result<Self> {
            self.ta = self.ta.with_clamp(k)?;
            crate::methods::basic::clamp_plan(&mut self.plan, k, "--ta-clamp 0, or weights trained with it off");
            Ok(self)
        }

        /// With the accumulation's history rejection at `z` standard errors
        /// ([`crate::methods::basic::reject_stale`]; 0: off).
        pub fn with_ta_reject(mut self, z: f32) -> crate::error::Result<Self> {
            self.ta = self.ta.with_reject(z)?;
            crate::methods::basic::reject_plan(&mut self.plan, z, self.ta.reject_scales());
            crate::methods::basic::relight_plan(&mut self.plan, z, self.ta.relight());
            Ok(self)
        }

        /// With the accumulation's history relit where a light moved
        /// ([`crate::methods::basic::relight`]; on unless told).
        pub fn with_ta_relight(mut self, on: bool) -> Self {
            self.ta = self.ta.with_relight(on);
            crate::methods::basic::relight_plan(&mut self.plan, self.ta.reject(), on);
            self
        }

        /// With the accumulation's history rejection testing the first `k`
        /// of [`crate::methods::basic::REJECT_SCALES`] (default
        /// [`crate::methods::basic::LEARNED_TA_REJECT_SCALES`]).
        pub fn with_ta_reject_scales(mut self, k: usize) -> crate::error::Result<Self> {
            self.ta = self.ta.with_reject_scales(k)?;
            crate::methods::basic::reject_plan(&mut self.plan, self.ta.reject(), k);
            Ok(self)
        }
    };
}
pub(crate) use ta_builders;

/// The history clamp a learned method's weights were trained with
/// (metadata `ta_clamp`; `None` for files made before it, whose inputs had
/// no clamp).
pub fn ta_clamp_of(file: &crate::nn::weights::File) -> Result<Option<f32>> {
    match file.meta("ta_clamp") {
        None => Ok(None),
        Some(v) => {
            v.parse::<f32>().ok().filter(|k| k.is_finite() && *k >= 0.0).map(Some).ok_or_else(|| {
                HostError::bad(file.path(), format!("metadata ta_clamp is '{v}', expected a number >= 0"))
            })
        }
    }
}

/// The history clamp a learned method denoises with by default: its
/// weights' own, and [`TA_CLAMP`] for weights made before the clamp
/// existed. (Those were trained without it, yet denoise better with it:
/// WSKP-6 on the foreign moving light 24.33 -> 26.69 dB, relMSE 0.21 ->
/// 0.034; AFN 27.47 -> 28.60; the camera pan +0.2 and 0.0 dB.)
pub fn ta_clamp_for(file: &crate::nn::weights::File) -> Result<f32> {
    Ok(ta_clamp_of(file)?.unwrap_or(TA_CLAMP))
}

/// Checks a history clamp's width given by the user.
pub fn check_clamp(k: f32) -> Result<f32> {
    check_off_to_1e6(k, "--ta-clamp", "a width", "standard deviations")
}

/// The accumulated colour and the history counts of a step.
pub type StepOut<'a, P> =
    (&'a Planes<<P as mcdenoise_core::Precision>::Store>, &'a Planes<<P as mcdenoise_core::Precision>::Store>);

/// Temporal accumulation state (also a stage inside other methods).
pub struct TemporalAccumulation<P: HostPrecision> {
    plan: Plan,
    params: TemporalParams,
    use_normal: bool,
    use_position: bool,
    use_motion: bool,
    use_albedo: bool,
    prev: Option<History<P>>,
    /// The history rejection's threshold ([`reject_stale`]; 0: off).
    reject: f32,
    /// The first this many of [`REJECT_SCALES`] are tested.
    reject_scales: usize,
    /// Whether the rejection relights the history first ([`relight`]).
    relight: bool,
}

struct History<P: HostPrecision> {
    color: Planes<P::Store>,
    hist: Planes<P::Store>,
    normal: Option<Planes<P::Store>>,
    position: Option<Planes<P::Store>>,
    albedo: Option<Planes<P::Store>>,
}

impl<P: HostPrecision> TemporalAccumulation<P> {
    /// For a sequence starting with `first`. With `required`, a frame without
    /// motion or position is an error naming the missing buffers.
    pub fn new(first: &Frame, required: bool) -> Result<Self> {
        let use_motion = first.has(Buffer::Motion);
        let use_position = first.has(Buffer::Position);
        let use_normal = first.has(Buffer::Normal);
        let use_albedo = first.has(Buffer::Albedo);
        if required && !use_motion && !use_position {
            return Err(HostError::MissingChannel {
                path: first.path.clone(),
                buffer: "motion or position",
                wanted: "motion.X,motion.Y or position.X,position.Y,position.Z".into(),
                needed_by: "temporal accumulation".into(),
            });
        }
        let mut plan = Plan::default();
        plan.built.push("temporal accumulation");
        if !use_motion {
            plan.skipped.push(("motion reprojection", "no motion vectors: reprojecting by world position".into()));
        }
        if !use_position {
            plan.skipped.push(("position test", "no position".into()));
        }
        if !use_normal {
            plan.skipped.push(("normal test", "no normal".into()));
        }
        if !use_albedo {
            plan.skipped.push(("albedo test", "no albedo".into()));
        }
        let params = TemporalParams { pos_limit: POSITION_TOLERANCE * scene_scale(first), ..TemporalParams::default() };
        plan.built.push(RELIGHT_STAGE);
        plan.built.push(REJECT_STAGE);
        Ok(TemporalAccumulation {
            plan,
            params,
            use_normal,
            use_position,
            use_motion,
            use_albedo,
            prev: None,
            reject: TA_REJECT,
            reject_scales: TA_REJECT_SCALES,
            relight: true,
        })
    }

    /// With the history relit where a light moved ([`relight`], on unless
    /// told; it runs within the rejection, so not with `--ta-reject 0`).
    pub fn with_relight(mut self, on: bool) -> Self {
        self.relight = on;
        relight_plan(&mut self.plan, self.reject, on);
        self
    }

    /// Whether the history is relit where a light moved.
    pub fn relight(&self) -> bool {
        self.relight
    }

    /// With the history rejection at `z` standard errors ([`reject_stale`];
    /// 0: off).
    ///
    /// # Errors
    /// A threshold outside `[0, 1e6]`.
    pub fn with_reject(mut self, z: f32) -> Result<Self> {
        self.reject = check_reject(z)?;
        reject_plan(&mut self.plan, self.reject, self.reject_scales);
        relight_plan(&mut self.plan, self.reject, self.relight);
        Ok(self)
    }

    /// With the history rejection testing the first `k` of
    /// [`REJECT_SCALES`] (1: the 9x9 means alone).
    ///
    /// # Errors
    /// `k` outside 1 to 3.
    pub fn with_reject_scales(mut self, k: usize) -> Result<Self> {
        self.reject_scales = check_reject_scales(k)?;
        reject_plan(&mut self.plan, self.reject, self.reject_scales);
        Ok(self)
    }

    /// The history rejection's threshold (0: off).
    pub fn reject(&self) -> f32 {
        self.reject
    }

    /// How many of [`REJECT_SCALES`] the history rejection tests.
    pub fn reject_scales(&self) -> usize {
        self.reject_scales
    }

    /// With the history clamp of width `k` standard deviations (0: off).
    ///
    /// # Errors
    /// A width outside `[0, 1e6]`.
    pub fn with_clamp(mut self, k: f32) -> Result<Self> {
        self.params.clamp_sigma = check_clamp(k)?;
        self.params.clamp_radius = TA_CLAMP_RADIUS;
        clamp_plan(&mut self.plan, k, "--ta-clamp 0");
        Ok(self)
    }

    /// The history clamp's width (0: off).
    pub fn clamp(&self) -> f32 {
        self.params.clamp_sigma
    }

    /// Memory per frame (see [`crate::runtime::memory`]), replaying [`Self::step`]
    /// and [`Denoiser::denoise`]: the history (colour, counts, normal and
    /// position) is kept; a frame encodes its buffers, accumulates into new
    /// colour and counts, drops the previous history, then decodes a copy.
    /// `scales`: the rejection's ([`Self::with_reject_scales`]).
    pub fn footprint(info: &FrameInfo, scales: usize) -> Footprint {
        let s = store_bytes::<P>();
        let mut l = Ledger::default();
        let history = Self::step_ledger(info, &mut l, scales);
        l.alloc(3 * s).alloc(12).free(3 * s); // the copy decoded to the output
        Footprint { kept: history, peak: l.peak(), scratch: 0 }
    }

    /// What [`TemporalAccumulation::step`] allocates and frees, onto `l`; the
    /// bytes per pixel it keeps (the history, live after the step), with the
    /// rejection at `scales` scales.
    pub fn step_ledger(info: &FrameInfo, l: &mut Ledger, scales: usize) -> u64 {
        let s = store_bytes::<P>();
        let has = |b: Buffer| u64::from(info.has(b));
        let (normal, position, motion) = (has(Buffer::Normal), has(Buffer::Position), has(Buffer::Motion));
        let albedo = has(Buffer::Albedo);
        let history = 4 * s + 3 * s * (normal + position + albedo);
        l.alloc(history);
        l.alloc(3 * s); // colour
        l.alloc(3 * s * (normal + position + albedo) + 2 * s * motion);
        l.alloc(4 * s); // accumulated colour, history counts
        l.temp(reject_temp_bytes(scales));
        l.free(history).free(3 * s + 2 * s * motion);
        history
    }

    /// The accumulated colour of a [`step`](Self::step) decoded to f32 into
    /// `out` (resized to fit) over `pool`'s threads, with the frame's own
    /// value taken where the colour's format saturated it
    /// ([`restore_saturated`](crate::runtime::precision::restore_saturated)):
    /// how `ta`, WSKP and AFN all read the accumulation. Nothing is restored
    /// in f32 or where the frame has no colour.
    pub fn decode_color(pool: &crate::runtime::par::Pool, color: &Planes<P::Store>, f: &Frame, out: &mut Vec<f32>) {
        out.resize(color.data.len(), 0.0);
        crate::runtime::precision::decode_par::<P>(pool, &color.data, out, color.frac);
        if let Some(x) = f.get(Buffer::Color) {
            crate::runtime::precision::restore_saturated(out, x, P::store_max(color.frac));
        }
    }

    /// Accumulates one frame; returns the accumulated colour and the history counts.
    pub fn step(&mut self, f: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<StepOut<'_, P>> {
        let (w, h) = (f.width, f.height);
        let pool = &ctx.pool;
        let enc = |b: Buffer, kind: Kind| {
            f.get(b).map(|d| Planes::<P::Store>::encode_as_par::<P>(pool, b.channels(), w, h, d, kind))
        };
        let (color, normal, albedo, position, motion) = t.time("encode", || {
            (
                enc(Buffer::Color, Kind::Image),
                if self.use_normal { enc(Buffer::Normal, Kind::Unit) } else { None },
                if self.use_albedo { enc(Buffer::Albedo, Kind::Unit) } else { None },
                if self.use_position { enc(Buffer::Position, Kind::Plain) } else { None },
                if self.use_motion { enc(Buffer::Motion, Kind::Plain) } else { None },
            )
        });
        let color = color.ok_or_else(|| HostError::bad(&f.path, "no colour"))?;
        if (self.use_motion && motion.is_none()) || (self.use_position && position.is_none()) {
            return Err(HostError::bad(&f.path, "lacks a buffer the first frame of the sequence had"));
        }
        let next = match self.prev.take() {
            None => {
                // The first frame's history holds that frame.
                let mut hist = Planes::new(1, w, h).with_frac(HISTORY_FRAC);
                P::encode(&vec![1.0f32; w * h], &mut hist.data, hist.frac);
                History { color, hist, normal, position, albedo }
            }
            Some(prev) => {
                let mut out = Planes::new(3, w, h).with_frac(color.frac);
                let mut hist = Planes::new(1, w, h).with_frac(HISTORY_FRAC);
                let inp = TemporalInputs {
                    color: color.view(),
                    normal: normal.as_ref().map(|p| p.view()),
                    position: position.as_ref().map(|p| p.view()),
                    motion: motion.as_ref().map(|p| p.view()),
                    prev_color: prev.color.view(),
                    prev_normal: prev.normal.as_ref().map(|p| p.view()),
                    prev_position: prev.position.as_ref().map(|p| p.view()),
                    prev_history: prev.hist.view(),
                    albedo: albedo.as_ref().map(|p| p.view()),
                    prev_albedo: prev.albedo.as_ref().map(|p| p.view()),
                };
                let params = self.params;
                let isa = ctx.isa;
                t.time("temporal accumulation", || {
                    ctx.pool.bands2(out.view_mut(), hist.view_mut(), 1, &mut ctx.scratch, 0, |band, hb, y0, _| {
                        temporal::accumulate::<P>(isa, &inp, &params, band, hb, y0)
                    })
                })?;
                if self.reject > 0.0 {
                    if let Some(a) = f.get(Buffer::Color) {
                        let z0 = self.reject;
                        let scales = &REJECT_SCALES[..self.reject_scales];
                        t.time("history rejection", || {
                            reject_stale::<P>(
                                &ctx.pool,
                                a,
                                f.pair(),
                                w,
                                h,
                                z0,
                                scales,
                                self.relight,
                                f.get(Buffer::Albedo),
                                &mut out,
                                &mut hist,
                            )
                        });
                    }
                }
                t.time("history counts floor", || floor_counts::<P>(&ctx.pool, &mut hist));
                History { color: out, hist, normal, position, albedo }
            }
        };
        self.prev = Some(next);
        let p = self.prev.as_ref().expect("just set");
        Ok((&p.color, &p.hist))
    }
}

impl<P: HostPrecision> Denoiser for TemporalAccumulation<P> {
    fn name(&self) -> &'static str {
        "ta"
    }
    fn plan(&self) -> &Plan {
        &self.plan
    }
    fn denoise(&mut self, f: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        let (color, _) = self.step(f, ctx, t)?;
        let mut out = Vec::new();
        t.time("decode", || Self::decode_color(&ctx.pool, color, f, &mut out));
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcdenoise_core::F32;

    /// 1-spp-like noise: `level` times an exponential-ish factor of mean 1
    /// (a deterministic hash), per pixel and channel.
    fn noisy(level: &[f32], seed: u32) -> Vec<f32> {
        let mut s = seed;
        level
            .iter()
            .map(|&l| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                let u = ((s >> 8) as f32 + 0.5) / (1u32 << 24) as f32;
                l * -u.ln()
            })
            .collect()
    }

    /// The history rejection, in f32 and fixed point: an accumulated colour
    /// that agrees with the frame (a static scene, its history 0.2 of the
    /// 1-spp noise) keeps nearly every pixel; one from before a light
    /// moved (three times or a third of the frame's level over the right half) gives
    /// way to the frame there and keeps the left half; without the pair,
    /// with it, and with the pair's mean as the colour.
    #[test]
    fn rejection_lets_a_moved_light_go_and_keeps_a_static_history() {
        // `pair`: 0 none, 1 the second estimate beside A, 2 beside the
        // pair's mean as the colour.
        fn run<P: HostPrecision>(pair: u8) {
            let (w, h) = (64, 48);
            let n = w * h;
            let pool = crate::runtime::par::Pool::new(2).unwrap();
            let level: Vec<f32> = (0..3 * n).map(|i| 0.3 + 0.2 * ((i % n) % w) as f32 / w as f32).collect();
            let mut a = noisy(&level, 7);
            let b = noisy(&level, 8);
            if pair == 2 {
                a.iter_mut().zip(&b).for_each(|(x, &y)| *x = 0.5 * (*x + y));
            }
            let b = (pair > 0).then_some(crate::io::frame::Pair { b: &b[..], colour_is_mean: pair == 2 });
            // A history close to the truth: its noise a fifth of the frame's.
            let calm: Vec<f32> = level.iter().zip(noisy(&level, 9)).map(|(&l, v)| l + 0.2 * (v - l)).collect();
            for (name, factor) in [("static", 1.0f32), ("brighter before", 3.0), ("dimmer before", 1.0 / 3.0)] {
                let hist_c: Vec<f32> =
                    calm.iter().enumerate().map(|(i, &v)| if (i % n) % w >= w / 2 { v * factor } else { v }).collect();
                let frac = P::frac_or_zero(P::choose_frac(&hist_c, Kind::Image));
                let mut out = Planes::<P::Store>::new(3, w, h).with_frac(frac);
                P::encode(&hist_c, &mut out.data, frac);
                let mut hist = Planes::<P::Store>::new(1, w, h).with_frac(P::frac_or_zero(HISTORY_FRAC));
                P::encode(&vec![8.0f32; n], &mut hist.data, hist.frac);
                reject_stale::<P>(&pool, &a, b, w, h, TA_REJECT, &REJECT_SCALES[..1], false, None, &mut out, &mut hist);
                let (oc, hv) = (out.decode::<P>(), hist.decode::<P>());
                let (mut kept, mut gone, mut half, mut left, mut right) = (0usize, 0usize, 0usize, 0usize, 0usize);
                for y in 0..h {
                    // Away from the halves' border (the 9x9 windows).
                    for x in (0..w).filter(|&x| x.abs_diff(w / 2) > TA_REJECT_RADIUS + 1) {
                        let p = y * w + x;
                        let same = (0..3)
                            .all(|c| (oc[c * n + p] - hist_c[c * n + p]).abs() <= 2e-3 * hist_c[c * n + p] + 1e-3);
                        let frame = (0..3).all(|c| (oc[c * n + p] - a[c * n + p]).abs() <= 2e-3 * a[c * n + p] + 1e-3);
                        // At least halfway from the history to the frame.
                        let halfway = (0..3).all(|c| {
                            let (o, hc, f) = (oc[c * n + p], hist_c[c * n + p], a[c * n + p]);
                            (o - f).abs() <= 0.5 * (hc - f).abs() + 1e-3
                        });
                        if x < w / 2 || factor == 1.0 {
                            left += 1;
                            kept += usize::from(same && hv[p] == 8.0);
                        } else {
                            right += 1;
                            gone += usize::from(frame && hv[p] == 0.0);
                            half += usize::from(halfway && hv[p] <= 4.0);
                        }
                    }
                }
                assert!(kept as f64 >= 0.97 * left as f64, "{name}, pair {pair}: {kept} of {left} kept");
                if factor != 1.0 {
                    assert!(gone as f64 >= 0.9 * right as f64, "{name}, pair {pair}: {gone} of {right} let go");
                    assert!(half as f64 >= 0.99 * right as f64, "{name}, pair {pair}: {half} of {right} halfway");
                }
            }
        }
        for pair in [0, 1, 2] {
            run::<F32>(pair);
            run::<mcdenoise_core::Fixed>(pair);
        }
    }

    /// The rejection's wider scales, in f32 and fixed point, one estimate:
    /// a history 15 % too bright over the right half (a light's lag, at
    /// 1.8 standard errors of a 9x9 mean of 1-spp noise, 3.4 of a 17x17 one
    /// and 6.6 of a 33x33 one) mostly stays with the 9x9 means alone and
    /// mostly goes with three scales, while a static history (the left
    /// half) is kept as with one scale; a lag of 2.8 % (2.5 standard errors
    /// of a 33x33 mean, under the 1.5 times 2 that scale asks for) stays.
    #[test]
    fn wider_scales_let_a_small_lag_go_and_keep_a_static_history() {
        fn run<P: HostPrecision>() {
            let (w, h) = (128, 96);
            let n = w * h;
            let pool = crate::runtime::par::Pool::new(2).unwrap();
            let level = vec![0.5f32; 3 * n];
            let a = noisy(&level, 11);
            let calm: Vec<f32> = level.iter().zip(noisy(&level, 12)).map(|(&l, v)| l + 0.2 * (v - l)).collect();
            let hist_c: Vec<f32> =
                calm.iter().enumerate().map(|(i, &v)| if (i % n) % w >= w / 2 { v * 1.15 } else { v }).collect();
            // (moved towards the frame: its mean over the right half's
            // pixels whose 33x33 windows are whole and inside it; kept: the
            // share of the left half's pixels as far inside left alone)
            let measure = |k: usize, hist_c: &[f32]| {
                let frac = P::frac_or_zero(P::choose_frac(hist_c, Kind::Image));
                let mut out = Planes::<P::Store>::new(3, w, h).with_frac(frac);
                P::encode(hist_c, &mut out.data, frac);
                let mut hist = Planes::<P::Store>::new(1, w, h).with_frac(P::frac_or_zero(HISTORY_FRAC));
                P::encode(&vec![8.0f32; n], &mut hist.data, hist.frac);
                reject_stale::<P>(
                    &pool,
                    &a,
                    None,
                    w,
                    h,
                    LEARNED_TA_REJECT,
                    &REJECT_SCALES[..k],
                    false,
                    None,
                    &mut out,
                    &mut hist,
                );
                let hv = hist.decode::<P>();
                let (mut moved, mut right, mut kept, mut left) = (0.0f64, 0usize, 0usize, 0usize);
                for y in 16..h - 16 {
                    for x in (16..w - 16).filter(|&x| x.abs_diff(w / 2) > 17) {
                        let p = y * w + x;
                        if x >= w / 2 {
                            right += 1;
                            moved += 1.0 - f64::from(hv[p]) / 8.0;
                        } else {
                            left += 1;
                            kept += usize::from(hv[p] == 8.0);
                        }
                    }
                }
                (moved / right as f64, kept as f64 / left as f64, hv)
            };
            let (moved1, kept1, hv1) = measure(1, &hist_c);
            let (moved3, kept3, hv3) = measure(3, &hist_c);
            assert!(moved1 < 0.3, "one scale moved {moved1} of the lag");
            assert!(moved3 > 0.8, "three scales moved {moved3} of the lag");
            assert!(kept3 > 0.9 && kept3 > kept1 - 0.03, "static history kept: {kept3} (one scale {kept1})");
            // The largest blend of the scales: never less than one scale's.
            assert!(hv3.iter().zip(&hv1).all(|(a, b)| a <= b), "three scales kept more history than one somewhere");
            // The 33x33 test at 1.5 times the threshold: a 2.8 % lag (2.5
            // standard errors of those means, 0.3 and 0.6 of the smaller
            // ones) stays.
            let small: Vec<f32> =
                calm.iter().enumerate().map(|(i, &v)| if (i % n) % w >= w / 2 { v * 1.028 } else { v }).collect();
            let (moved_small, _, _) = measure(3, &small);
            assert!(moved_small < 0.1, "three scales moved {moved_small} of a 2.8 % lag");
        }
        run::<F32>();
        run::<mcdenoise_core::Fixed>();
    }

    /// The history holds the frames blended into it: on a static sequence
    /// without rejection or clamp, `ta`'s second output is the mean of the
    /// first two frames and its third the mean of all three (each to 1e-6
    /// of the f64 mean), in f32 and fixed point (to its step); a pixel
    /// whose history was let go counts as one frame, not none, so the next
    /// frame is averaged with it.
    #[test]
    fn the_history_counts_the_frames_in_it() {
        fn run<P: HostPrecision>(tol: f64) {
            let seq = frames(&[0.5, 0.5, 0.5], 0.4);
            let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
            let mut ta = TemporalAccumulation::<P>::new(&seq[0], true)
                .unwrap()
                .with_clamp(0.0)
                .unwrap()
                .with_reject(0.0)
                .unwrap();
            let mut t = Timings::default();
            for (k, f) in seq.iter().enumerate() {
                let out = ta.denoise(f, &mut ctx, &mut t).unwrap();
                for (p, &o) in out.iter().enumerate() {
                    let want = seq[..=k].iter().map(|g| f64::from(g.get(Buffer::Color).unwrap()[p])).sum::<f64>()
                        / (k + 1) as f64;
                    assert!((f64::from(o) - want).abs() <= tol, "frame {k}, value {p}: {o} against the mean {want}");
                }
            }
            let mut hist = Planes::<P::Store>::new(1, 3, 2).with_frac(P::frac_or_zero(HISTORY_FRAC));
            P::encode(&[0.0, 0.25, 1.0, 3.0, f32::NAN, 64.0], &mut hist.data, hist.frac);
            floor_counts::<P>(&crate::runtime::par::Pool::new(2).unwrap(), &mut hist);
            let got = hist.decode::<P>();
            assert_eq!(&got[..4], &[1.0, 1.0, 1.0, 3.0]);
            assert_eq!(got[5], 64.0);
            assert!(got[4] == 1.0 || P::FIXED_POINT, "NaN -> {}", got[4]);
        }
        run::<F32>(1e-6);
        run::<mcdenoise_core::Fixed>(2e-3);
    }

    /// A light smaller than the 0.1 % the accumulation's fixed-point format
    /// lets saturate keeps its value and its hue in `ta`'s output, on the
    /// first frame and on a static second one, as in f32; the rest of the
    /// frame is within the format's step of f32.
    #[test]
    fn a_small_light_keeps_its_colour_in_fixed_point() {
        let (w, h) = (48usize, 48usize);
        let n = w * h;
        let mut c: Vec<f32> = (0..3 * n).map(|i| 0.05 + 0.001 * ((i * 7919) % 97) as f32).collect();
        // Two pixels of a bluish light: 0.09 % of the frame.
        let light = [20 * w + 30, 20 * w + 31];
        for &p in &light {
            for (k, v) in [2.3f32, 2.9, 3.2].into_iter().enumerate() {
                c[k * n + p] = v;
            }
        }
        let mut f = Frame::from_color("light.exr", w, h, c.clone()).unwrap();
        f.set(Buffer::Motion, vec![0.0; 2 * n]).unwrap();
        let m = <mcdenoise_core::Fixed as HostPrecision>::store_max(
            <mcdenoise_core::Fixed as HostPrecision>::choose_frac(&c, Kind::Image),
        );
        assert!(m < 2.3, "the light lies beyond the format ({m})");
        let run = |fixed: bool| -> Vec<Vec<f32>> {
            let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
            let mut t = Timings::default();
            if fixed {
                let mut ta = TemporalAccumulation::<mcdenoise_core::Fixed>::new(&f, false).unwrap();
                (0..2).map(|_| ta.denoise(&f, &mut ctx, &mut t).unwrap()).collect()
            } else {
                let mut ta = TemporalAccumulation::<F32>::new(&f, false).unwrap();
                (0..2).map(|_| ta.denoise(&f, &mut ctx, &mut t).unwrap()).collect()
            }
        };
        let (want, got) = (run(false), run(true));
        for (k, (a, b)) in want.iter().zip(&got).enumerate() {
            for j in 0..3 * n {
                let tol = if light.contains(&(j % n)) { 1e-6 * a[j].abs() } else { 2e-3 };
                assert!((a[j] - b[j]).abs() <= tol, "frame {k}, value {j}: f32 {} fixed {}", a[j], b[j]);
            }
        }
    }

    /// The plan names the rejection's scales, once: built while the
    /// threshold is above 0, skipped at 0.
    #[test]
    fn the_plan_names_the_rejection_scales() {
        let seq = frames(&[0.5], 0.1);
        let count = |p: &Plan| {
            p.built.iter().filter(|s| REJECT_STAGES.contains(s)).count()
                + p.skipped.iter().filter(|(s, _)| REJECT_STAGES.contains(s)).count()
        };
        assert!(TemporalAccumulation::<F32>::new(&seq[0], true).unwrap().plan().built.contains(&REJECT_STAGE));
        for k in [3, 2, 1, 3] {
            let ta = TemporalAccumulation::<F32>::new(&seq[0], true).unwrap().with_reject_scales(k).unwrap();
            assert!(ta.plan().built.contains(&REJECT_STAGES[k - 1]), "{k} scales: {:?}", ta.plan());
            assert_eq!(count(ta.plan()), 1, "{k} scales: {:?}", ta.plan());
            let off = ta.with_reject(0.0).unwrap();
            assert!(off.plan().skipped.iter().any(|(s, _)| *s == REJECT_STAGES[k - 1]), "{k} scales, off");
            assert_eq!(count(off.plan()), 1, "{k} scales, off: {:?}", off.plan());
            let on = off.with_reject(2.0).unwrap().with_reject_scales(1).unwrap();
            assert!(on.plan().built.contains(&REJECT_STAGES[0]) && count(on.plan()) == 1, "{:?}", on.plan());
        }
        assert!(TemporalAccumulation::<F32>::new(&seq[0], true).unwrap().with_reject_scales(4).is_err());
    }

    /// The one-estimate noise variance against its definition in f64, and
    /// on a steep ramp under normal noise its mean against its expectation
    /// (the noise variance plus a quarter of the squared slope: half the
    /// horizontal step's square, averaged with the flat vertical step),
    /// where a 9x9 window's own variance is several times the noise's.
    #[test]
    fn neighbour_variance_counts_the_noise_and_little_of_a_ramp() {
        let (w, h) = (97, 61);
        let mut normal = crate::methods::test_noise::normal(0x9e37_79b9_7f4a_7c15);
        let (slope, sd) = (0.25f64, 0.3f64);
        let img: Vec<f32> = (0..w * h).map(|p| (1.0 + slope * (p % w) as f64 + sd * normal()) as f32).collect();
        let (mut sum, mut win) = (0.0f64, 0.0f64);
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let got = neighbour_variance(|q| img[q], p, x, y, w, h) as f64;
                let mut d = Vec::new();
                if x + 1 < w {
                    d.push(0.5 * (img[p] as f64 - img[p + 1] as f64).powi(2));
                }
                if y + 1 < h {
                    d.push(0.5 * (img[p] as f64 - img[p + w] as f64).powi(2));
                }
                let want = if d.is_empty() { 0.0 } else { d.iter().sum::<f64>() / d.len() as f64 };
                assert!((got - want).abs() <= 1e-5 * (1.0 + want), "({x},{y}): {got} against {want}");
                sum += got;
                if (4..w - 4).contains(&x) && (4..h - 4).contains(&y) {
                    let vals: Vec<f64> = (y - 4..=y + 4)
                        .flat_map(|yy| (x - 4..=x + 4).map(move |xx| yy * w + xx))
                        .map(|q| img[q] as f64)
                        .collect();
                    let m = vals.iter().sum::<f64>() / 81.0;
                    win += vals.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / 81.0 / ((w - 8) * (h - 8)) as f64;
                }
            }
        }
        let mean = sum / (w * h) as f64;
        let expect = sd * sd + 0.25 * slope * slope;
        assert!((mean / expect - 1.0).abs() < 0.05, "{mean} against {expect}");
        assert!(win > 4.0 * sd * sd, "the window's own variance: {win}");
    }

    /// A static 12x10 sequence: `frames` of flat `level` with uniform noise
    /// of half-width `amp` (a deterministic hash), zero motion.
    fn frames(levels: &[f32], amp: f32) -> Vec<Frame> {
        frames_by(levels, 12, 10, 99, |l, u| l + amp * 2.0 * u)
    }

    /// A static sequence of `w x h`, a frame per level of `levels`, each
    /// value `value(level, u)` with `u` uniform in `[-1/2, 1/2)` (a
    /// deterministic hash from `seed`), zero motion.
    fn frames_by(levels: &[f32], w: usize, h: usize, seed: u32, value: impl Fn(f32, f32) -> f32) -> Vec<Frame> {
        let mut s = seed;
        levels
            .iter()
            .map(|&l| {
                let c: Vec<f32> = (0..3 * w * h)
                    .map(|_| {
                        s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                        value(l, (s >> 8) as f32 / (1u32 << 24) as f32 - 0.5)
                    })
                    .collect();
                let mut f = Frame::from_color("test.exr", w, h, c).unwrap();
                f.set(Buffer::Motion, vec![0.0; 2 * w * h]).unwrap();
                f
            })
            .collect()
    }

    /// The mean of the last frame `ta` returns for `seq` (with the clamp
    /// and the rejection given), and its mean squared deviation from `truth`.
    fn run_with(seq: &[Frame], clamp: f32, reject: f32, truth: f32) -> (f32, f32) {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let mut ta = TemporalAccumulation::<F32>::new(&seq[0], true)
            .unwrap()
            .with_clamp(clamp)
            .unwrap()
            .with_reject(reject)
            .unwrap();
        let mut t = Timings::default();
        let mut last = Vec::new();
        for f in seq {
            last = ta.denoise(f, &mut ctx, &mut t).unwrap();
        }
        let n = last.len() as f32;
        (last.iter().sum::<f32>() / n, last.iter().map(|v| (v - truth).powi(2)).sum::<f32>() / n)
    }

    /// `relight` against an f64 oracle written from its definition: window
    /// means by brute force over the clipped 65x65 and 17x17 windows, the
    /// factor, the check and the counts' share. A history lit by a factor
    /// that runs from 0.5 to 1.6 across the frame (and, in a strip, by one
    /// the 17x17 check refuses), noisy frame, mixed noise levels; without
    /// albedo, and with a block without albedo and pixels above the emitter
    /// floor (left out of the windows and never relit) and values at the
    /// format's bound (never relit).
    #[test]
    fn relight_matches_an_f64_oracle() {
        let (w, h) = (83, 71);
        let n = w * h;
        let mut s = 7u32;
        let mut rnd = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (s >> 8) as f32 / (1u32 << 24) as f32
        };
        let base: Vec<f32> = (0..n).map(|p| 0.2 + 0.8 * ((p % w) as f32 / w as f32) + 0.3 * rnd()).collect();
        let mf: Vec<f32> = base.iter().map(|b| b * (0.7 + 0.6 * rnd())).collect();
        let v: Vec<f32> = (0..n).map(|p| if (p / w) % 3 == 0 { 1e-4 } else { 0.02 * rnd() }).collect();
        let k = |p: usize| {
            let (x, y) = (p % w, p / w);
            if (30..36).contains(&y) {
                // A strip whose history is already right: the wide windows
                // around it say otherwise, its own 17x17 windows mostly not.
                1.0
            } else {
                0.5 + 1.1 * x as f32 / w as f32
            }
        };
        // A light one pixel wide (bright in the history; the case with
        // albedo leaves it out by the emitter floor given) and lone bright
        // pixels (fireflies, counted).
        let line = |p: usize| p % w == 70 && (40..60).contains(&(p / w));
        let mt0: Vec<f32> = (0..n).map(|p| if line(p) || p % 89 == 5 { 30.0 } else { base[p] * k(p) }).collect();
        let oc0: Vec<f32> = (0..3 * n).map(|i| mt0[i % n] * (0.5 + 0.5 * (i / n) as f32) + 0.01 * rnd()).collect();
        let z0 = 2.0f32;
        // A block without albedo (a light, a mirror in a raw AOV) and the
        // storage format's bound under the block's and a few pixels' colour.
        let dark = |p: usize| (40..60).contains(&(p % w)) && (10..25).contains(&(p / w));
        let albedo: Vec<f32> = (0..3 * n).map(|i| if dark(i % n) { 0.0 } else { 0.6 }).collect();
        let mut oc0 = oc0;
        for p in (0..n).filter(|p| dark(*p) || p % 97 == 0) {
            oc0[p] = 9.0;
        }
        let pool = crate::runtime::par::Pool::new(2).unwrap();
        for case in 0..2 {
            let (al, bound, lights) =
                if case == 0 { (None, f32::INFINITY, f32::INFINITY) } else { (Some(&albedo[..]), 8.0, 20.0) };
            let light = |q: usize| {
                let (x, y) = ((q % w) as i64, (q / w) as i64);
                let bright = (-1i64..=1)
                    .flat_map(|dy| (-1i64..=1).map(move |dx| (x + dx, y + dy)))
                    .filter(|&(qx, qy)| (qx, qy) != (x, y) && qx >= 0 && qy >= 0 && qx < w as i64 && qy < h as i64)
                    .filter(|&(qx, qy)| mt0[qy as usize * w + qx as usize] > 0.5 * lights)
                    .count();
                mt0[q] > lights && bright >= 2
            };
            let surface = |q: usize| !light(q) && (al.is_none() || !dark(q));
            let (mut mt, mut oc, mut keep) = (mt0.clone(), oc0.clone(), vec![0.9f32; n]);
            relight(&pool, w, h, z0, &mf, &v, &mut mt, &mut oc, &mut keep, al, bound, lights);
            let win = |x: usize, y: usize, r: usize, f: &dyn Fn(usize) -> f64| {
                let (mut sum, mut cnt) = (0.0f64, 0.0f64);
                for qy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                    for qx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                        let q = qy * w + qx;
                        if surface(q) {
                            sum += f(q);
                            cnt += 1.0;
                        }
                    }
                }
                (sum, cnt)
            };
            let (mut relit, mut checked, mut refused) = (0, 0, 0);
            for y in 0..h {
                for x in 0..w {
                    let p = y * w + x;
                    let (sf, c) = win(x, y, RELIGHT_RADIUS, &|q| mf[q] as f64);
                    let (st, _) = win(x, y, RELIGHT_RADIUS, &|q| mt0[q] as f64);
                    let (sv, _) = win(x, y, RELIGHT_RADIUS, &|q| v[q] as f64);
                    let (f, t, se) = (sf / c, st / c, (sv / c / c).sqrt());
                    let held = surface(p) && (0..3).all(|ch| (oc0[ch * n + p].abs() as f64) < bound as f64);
                    let gamma = if held { ((f - t).abs() / se / z0 as f64 - 1.0).clamp(0.0, 1.0) } else { 0.0 };
                    let mut g = if gamma > 0.0 { (f / t).clamp(0.25, 4.0).powf(gamma) } else { 1.0 };
                    let mut share = 1.0 - 0.5 * gamma;
                    let (lf, _) = win(x, y, RELIGHT_CHECK_RADIUS, &|q| mf[q] as f64);
                    let (lt, _) = win(x, y, RELIGHT_CHECK_RADIUS, &|q| mt0[q] as f64);
                    let margin = (lf - lt).abs() - (lf - g * lt).abs();
                    if g != 1.0 {
                        if margin.abs() < 1e-3 * lf.abs() {
                            continue; // too close to the check's edge for f32
                        }
                        checked += 1;
                        if margin <= 0.0 {
                            g = 1.0;
                            share = 1.0;
                            refused += 1;
                        } else {
                            relit += 1;
                        }
                    }
                    let close = |a: f32, b: f64| ((a as f64) - b).abs() <= 1e-4 * b.abs().max(1e-3);
                    assert!(
                        close(mt[p], mt0[p] as f64 * g),
                        "mt at ({x},{y}): {} against {}",
                        mt[p],
                        mt0[p] as f64 * g
                    );
                    for ch in 0..3 {
                        let want = oc0[ch * n + p] as f64 * g;
                        assert!(
                            close(oc[ch * n + p], want),
                            "colour {ch} at ({x},{y}): {} against {want}",
                            oc[ch * n + p]
                        );
                    }
                    assert!(close(keep[p], share), "share kept at ({x},{y}): {} against {share}", keep[p]);
                }
            }
            assert!(
                relit > n / 4 && refused > 50 && checked > relit,
                "case {case}: relit {relit}, refused {refused} of {n}"
            );
        }
    }

    /// A static sequence of `w x h` whose level follows `levels`, each
    /// value drawn from a uniform spread of `rel` times it either side
    /// (1 spp-like noise), zero motion.
    fn frames_rel(levels: &[f32], rel: f32, w: usize, h: usize) -> Vec<Frame> {
        frames_by(levels, w, h, 5, |l, u| l * (1.0 + rel * 2.0 * u))
    }

    /// A wall a moving light dims by 15 % a frame: the rejection alone
    /// restarts the history every frame (the 9x9 to 33x33 means tell the
    /// change); relit, the history follows the light and keeps averaging.
    /// Both track the level; the relit one's error is under 0.6 times the
    /// other's. On a static wall the relighting changes the level by
    /// nothing the noise does not.
    #[test]
    fn a_dimming_light_keeps_the_history_relit() {
        let (w, h) = (72, 56);
        let levels: Vec<f32> = (0..12).map(|t| 0.85f32.powi(t)).collect();
        let truth = *levels.last().unwrap();
        let run = |seq: &[Frame], relight: bool| {
            let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
            let mut ta = TemporalAccumulation::<F32>::new(&seq[0], true)
                .unwrap()
                .with_reject(LEARNED_TA_REJECT)
                .unwrap()
                .with_reject_scales(LEARNED_TA_REJECT_SCALES)
                .unwrap()
                .with_relight(relight);
            let mut t = Timings::default();
            let mut last = Vec::new();
            for f in seq {
                last = ta.denoise(f, &mut ctx, &mut t).unwrap();
            }
            let n = last.len() as f32;
            let mean = last.iter().sum::<f32>() / n;
            (mean, (last.iter().map(|v| (v - truth).powi(2)).sum::<f32>() / n).sqrt())
        };
        let seq = frames_rel(&levels, 0.9, w, h);
        let (m_off, e_off) = run(&seq, false);
        let (m_on, e_on) = run(&seq, true);
        for m in [m_off, m_on] {
            assert!((m / truth - 1.0).abs() < 0.05, "level {m} against {truth}");
        }
        assert!(e_on < 0.6 * e_off, "relit {e_on} against {e_off}");
        let still = frames_rel(&[0.5; 12], 0.9, w, h);
        let (s_off, _) = run(&still, false);
        let (s_on, _) = run(&still, true);
        assert!((s_on / s_off - 1.0).abs() < 0.01, "static: {s_on} against {s_off}");
    }

    /// The relighting is in the plan where the rejection runs, just before
    /// it, and skipped with `with_relight(false)` or without the rejection.
    #[test]
    fn the_relighting_is_planned_within_the_rejection() {
        let seq = frames(&[1.0], 0.1);
        let ta = TemporalAccumulation::<F32>::new(&seq[0], true).unwrap();
        let b = &ta.plan().built;
        let at = b.iter().position(|s| *s == RELIGHT_STAGE).expect("built");
        assert_eq!(b.get(at + 1), Some(&REJECT_STAGE), "{b:?}");
        let off = ta.with_relight(false);
        assert!(off.plan().skipped.iter().any(|(s, why)| *s == RELIGHT_STAGE && why.contains("--ta-relight off")));
        let none = TemporalAccumulation::<F32>::new(&seq[0], true).unwrap().with_reject(0.0).unwrap();
        assert!(none.plan().skipped.iter().any(|(s, why)| *s == RELIGHT_STAGE && why.contains("--ta-reject 0")));
    }

    /// [`run_with`] with the clamp alone.
    fn run(seq: &[Frame], clamp: f32, truth: f32) -> (f32, f32) {
        run_with(seq, clamp, 0.0, truth)
    }

    /// The rejection alone (no clamp) in the accumulation: a light switched
    /// down to a third is followed at once; a static noisy sequence is
    /// still averaged (the 9x9 means agree within the frame's noise).
    #[test]
    fn the_rejection_follows_a_changed_light_and_keeps_averaging() {
        let seq = frames(&[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.33, 0.33, 0.33], 0.3);
        let (off, _) = run_with(&seq, 0.0, 0.0, 0.33);
        let (on, _) = run_with(&seq, 0.0, TA_REJECT, 0.33);
        assert!(off > 0.6, "without it the old light lingers: {off}");
        assert!((on - 0.33).abs() < 0.03, "with it the frame's level: {on}");
        let noisy = frames(&[1.0; 10], 0.5);
        let one = run_with(&noisy[..1], 0.0, TA_REJECT, 1.0).1;
        let (mean, ten) = run_with(&noisy, 0.0, TA_REJECT, 1.0);
        assert!((mean - 1.0).abs() < 0.05, "no bias on a static frame: {mean}");
        assert!(ten < 0.3 * one, "ten frames average the noise down: {ten} against one frame's {one}");
    }

    /// A light switched down to a tenth: without the clamp the history
    /// keeps 80 % of the old level a frame (0.1 + 0.9 x 0.8^3 = 0.56 after
    /// three frames); with it at most half of it goes in (the floor) and the
    /// output follows the frame within three frames (about 0.22). On a
    /// static noisy sequence the clamp still averages the noise down.
    #[test]
    fn the_history_clamp_lets_a_changed_light_through_and_keeps_averaging() {
        let seq = frames(&[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.1, 0.1, 0.1], 0.02);
        let (off, _) = run(&seq, 0.0, 0.1);
        let (on, _) = run(&seq, TA_CLAMP, 0.1);
        assert!(off > 0.5, "without the clamp the old light lingers: {off}");
        assert!(on < 0.25, "with it the frame's level wins: {on}");
        let noisy = frames(&[1.0; 10], 0.5);
        let one = run(&noisy[..1], TA_CLAMP, 1.0).1;
        let (mean, ten) = run(&noisy, TA_CLAMP, 1.0);
        assert!((mean - 1.0).abs() < 0.05, "the clamp does not bias a static frame: {mean}");
        assert!(ten < 0.5 * one, "ten frames average the noise down: {ten} against one frame's {one}");
    }

    /// The weights' `ta_clamp`: the bundled files record 1; a file saying
    /// nothing (made before the clamp) gets the default; a file saying 0
    /// turns it off; a bad value names the file.
    #[test]
    fn the_weights_say_which_clamp_they_were_trained_with() {
        use crate::nn::weights::{save_model, Form};
        let w3 = crate::methods::bundled::wskp(None, 3).unwrap();
        let w6 = crate::methods::bundled::wskp(None, 6).unwrap();
        let afn = crate::methods::bundled::afn(None).unwrap();
        for w in [&w3, &w6, &afn] {
            assert_eq!(ta_clamp_of(w).unwrap(), Some(1.0));
        }
        let dir = tempfile::tempdir().unwrap();
        let net = crate::methods::wskp::net_for(3, crate::methods::wskp::Sizes::ALL).unwrap();
        let params = vec![0.0f32; net.params];
        let p = dir.path().join("old.safetensors");
        save_model(&p, "wskp", &[("", &net, &params)], Form::Branches, &[], &[]).unwrap();
        let old = crate::nn::weights::File::read(&p).unwrap();
        assert_eq!(ta_clamp_of(&old).unwrap(), None);
        assert_eq!(ta_clamp_for(&old).unwrap(), TA_CLAMP);
        for (v, want) in [("0", Ok(0.0f32)), ("2.5", Ok(2.5)), ("abc", Err(())), ("-1", Err(()))] {
            let p = dir.path().join(format!("w{v}.safetensors"));
            save_model(&p, "wskp", &[("", &net, &params)], Form::Branches, &[("ta_clamp", v.to_string())], &[])
                .unwrap();
            let f = crate::nn::weights::File::read(&p).unwrap();
            match (ta_clamp_for(&f), want) {
                (Ok(k), Ok(w)) => assert_eq!(k, w),
                (Err(e), Err(())) => assert!(e.to_string().contains(&p.display().to_string()), "{e}"),
                (got, w) => panic!("ta_clamp '{v}': {got:?}, expected {w:?}"),
            }
        }
    }

    /// The clamp's width is checked.
    #[test]
    fn a_bad_clamp_width_is_refused() {
        let seq = frames(&[1.0], 0.0);
        for k in [-1.0, f32::NAN, f32::INFINITY, 2e6] {
            assert!(TemporalAccumulation::<F32>::new(&seq[0], true).unwrap().with_clamp(k).is_err(), "{k}");
        }
    }
}

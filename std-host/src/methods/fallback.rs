//! The learned filters' fallback to their input: where a network's output
//! differs from the image it filtered by clearly more than that image's
//! noise explains, the difference is the filter's own error (a blurred
//! edge, a clean 64-spp frame smoothed, a light leaking into the wall beside
//! it), and the output moves back towards the input. WSKP and AFN end with
//! it in every precision (in f32, on their decoded output), `cross` with the
//! pair's mean as the input.
//!
//! With `y` the input (the current frame's colour, `A`), `o` the output
//! and `v` the input's noise variance, `(o - y)^2 - v` estimates the
//! output's squared error (its bias, when the output's own noise is small),
//! and the blend `y + k (o - y)` with
//! `k = v / (v + max(e - M v, 0))` minimises the expected error of a blend
//! of two estimates with independent errors (the shrinkage of the
//! SURE-based filter, Kim et al. 2016, applied to the network's residual).
//! Everything is taken in exposure-normalised `log1p` colour (at 1 spp
//! linear values are ruled by single fireflies; the exposure keeps
//! `denoise(k x) = k denoise(x)`), summed over the channels and over the
//! pixels of a 7x7 window whose albedo matches the centre's and whose input
//! is within [`RANGE`] of its (one pixel's estimate is all noise; a light's
//! partially covered edge beside a wall reads as noise and, counted, would
//! hide the wall pixel's error, and the wall's and the light's pixels say
//! nothing of the edge row's).
//!
//! The current frame, not the temporal accumulation the filters read: the
//! accumulation's error is the output's too (a light that moved lags in
//! both), so it cannot tell the output's error apart.
//!
//! The margin `M` leaves the output alone unless its excess is clearly
//! above the noise: `M` is 2 where the window's mean noise variance is
//! [`NOISY`] or more, falling to 1 (the plain estimate) on a clean input.
//!
//! Only on frames that are not 1-spp-noisy ([`fade`]; with the pair's mean
//! as the colour, on the level of one of the two estimates the noise comes
//! from, twice the mean's): at 1 spp the noise
//! estimate of a dark region is itself unreliable (most samples are 0), and
//! where the output is truly off (a light that moved, which the
//! accumulation lags) the blend brought the 1-spp noise back in blotches:
//! better PSNR and relMSE on the foreign moving-light sequence (+1.7 dB),
//! a worse picture. The frame's noise level, the median over the pixels of
//! their window's mean noise variance, separates the sample counts. A
//! frame's median can be clean while a large part of it is 1-spp-noisy
//! (open sky or a sunlit floor beside walls lit through openings: the
//! generator's `test_0003`, 22 dB with the fallback against 37 without), so
//! each pixel's fade is the later of the frame's and its region's, the
//! median level over a 32-pixel tile ([`region_fade`], on a band 6 times
//! the frame's). With one estimate, only on frames whose squared
//! coefficient of variation says few samples a pixel ([`REGION_CV2`]): on a
//! 16-spp frame a region that reads as noisy is texture the one-estimate
//! noise takes for noise (the generator's `test_0005`, where the region fade
//! cost WSKP-3 2 dB); the pair's noise does not, and on the generator's
//! 8-spp `val_0022` the region fade gains 0.2 to 0.3 dB with it.
//!
//! The input's noise: where the frame has a second, independent estimate
//! `B` of the same pixels (the pair `cross` and the à-trous methods read),
//! from the pair: in the same colour, the mean of the squared differences
//! of `A`'s and `B`'s values from the colour's ([`Pair::spread`]; one
//! estimate, `y = A`: `(y - b)^2 / 2`; the pair's mean: `(a - b)^2 / 4` on
//! linear values), whose expectation is `y`'s variance whatever the image
//! holds. Through `log1p` the mean's estimate must take both differences:
//! `log M` lies near the larger of the two, so `(log M - log B)^2` alone
//! read a firefly in `B` as no noise and put it back at half its height
//! (the generator's 16-spp `test_0006`: relMSE 0.0029 -> 0.0006 with the
//! pair; docs/quality.md, "A firefly in one estimate"); otherwise from the image
//! itself (one estimate), the local estimate of the à-trous methods
//! ([`mcdenoise_core::atrous::noise`]), `0.84 |y - median of the 8
//! neighbours|^2`. (Its 3x3 median, which the à-trous colour gate uses,
//! falls short at 1 spp, where most pixels' neighbourhoods are dark: on the
//! corpus' 1-spp rooms it put the noise back, relMSE 0.018 -> 0.13.) The
//! one-estimate rule reads texture as noise: on the generator's `test_0005`
//! (16 spp, a fine checker on a plastic box behind glass) it estimates 3.5
//! times the true variance, so the output's blur of the checker stays; the
//! pair's estimate is within 4 % of it there. `cross` ends with its own
//! rule over a plain window (`cross::blend_by_error`), then this one with
//! the pair's mean as the input.
//!
//! Measured (relMSE, bundled weights, without -> with): on the test corpus
//! (`tests/tests/corpus.rs`) WSKP-3 on the 64-spp box 0.0042 -> 0.0022 (the
//! input: 0.0024) and the 64-spp Cornell box 0.0040 -> 0.0027 (0.0045);
//! WSKP-6 0.0044 -> 0.0016 and 0.0059 -> 0.0025; the 1-spp rooms
//! unchanged. On the foreign Cornell box (docs/quality.md) at 16 spp +1.3
//! to +1.5 dB, at 64 spp +2.2 to +3.7 dB; the 1-spp sequences unchanged.
//! The one-estimate noise from the neighbours of the pixel's own surface
//! (`surface_noise`) then moved WSKP-6 on the foreign 64-spp box from
//! 40.78 to 42.24 dB (docs/quality.md).

use mcdenoise_core::atrous::noise;
use mcdenoise_core::{View, ViewMut};

use crate::error::Result;
use crate::io::frame::Pair;
use crate::methods::Ctx;

/// Half the side of the window (7x7).
pub const RADIUS: usize = 3;
/// How many times the input's noise variance the output's squared
/// difference from it must exceed before the output moves towards it.
pub const MARGIN: f32 = 2.0;
/// The mean noise variance (per channel, exposure-normalised `log1p`
/// colour) from which the margin is [`MARGIN`]; below it the margin falls
/// linearly to 1 at no noise.
pub const NOISY: f32 = 0.003;

/// From this frame noise level on, the fallback fades out ([`fade`]).
pub const FADE_FROM: f32 = 0.002;
/// The frame noise level where the fallback has faded out.
pub const FADE_TO: f32 = 0.005;
/// From this region noise level on (the median of the window levels over a
/// [`TILE`]-square region), the fallback fades out there too
/// ([`region_fade`]).
pub const REGION_FADE_FROM: f32 = 6.0 * FADE_FROM;
/// The region noise level where the fallback has faded out there.
pub const REGION_FADE_TO: f32 = 6.0 * FADE_TO;
/// With one estimate, the frame's squared coefficient of variation (the
/// median over the pixels of their window's noise variance over their
/// window's squared mean, linear) from which the region fade applies:
/// below it the frame has many samples a pixel, and a region that reads as
/// noisy is texture the one-estimate noise takes for noise (the generator's
/// 16-spp `test_0005`, a fine checker behind glass, 0.028; its 1-spp
/// `test_0003` 0.31). With the pair the region fade always applies.
pub const REGION_CV2: f32 = 0.05;

/// Two albedos count as the same surface's within this fraction of the
/// larger (per channel) plus [`ALBEDO_FLOOR`].
pub const ALBEDO_TOL: f32 = 0.2;
/// See [`ALBEDO_TOL`].
pub const ALBEDO_FLOOR: f32 = 0.02;

/// The window holds only the pixels whose input is within this of the
/// centre's (mean over the channels, exposure-normalised `log1p` colour,
/// about 22 %): a light's edge row that has the walls' albedo (Mitsuba's
/// Cornell box) is its own window, not one diluted by the light's and the
/// wall's pixels, whose squared differences say nothing of its error.
pub const RANGE: f32 = 0.2;

/// Bytes per pixel [`to_input`] allocates for the time it runs.
pub const TEMP_BYTES: u64 = 4 * 7;

/// Records the stage in a method's plan: built (with the noise from the
/// pair when `pair`), or skipped by `--no-fallback` (replacing an earlier
/// entry of either kind).
pub fn plan(plan: &mut crate::methods::Plan, on: bool, pair: bool) {
    plan.built.retain(|s| *s != STAGE && *s != STAGE_PAIR);
    plan.skipped.retain(|(s, _)| *s != STAGE && *s != STAGE_PAIR);
    let stage = if pair { STAGE_PAIR } else { STAGE };
    if on {
        plan.built.push(stage);
    } else {
        plan.skipped.push((stage, "--no-fallback".into()));
    }
}

/// Turns the stage on or off in a plan that records it already, keeping
/// where its noise comes from ([`plan`]'s `pair`).
pub fn switch(plan: &mut crate::methods::Plan, on: bool) {
    let pair = plan.built.contains(&STAGE_PAIR) || plan.skipped.iter().any(|(s, _)| *s == STAGE_PAIR);
    self::plan(plan, on, pair);
}

/// The stage's name in plans (the noise from the image itself).
pub const STAGE: &str = "fallback to the input";
/// The stage's name in plans when the noise comes from the pair `A`, `B`.
pub const STAGE_PAIR: &str = "fallback to the input (its noise from the pair A, B)";

/// Moves the output `o` (3 planes, linear) towards the input `y` (3 planes)
/// where it differs from it by more than `y`'s noise explains (see the
/// module). `pair`: a second independent estimate of `y`'s pixels (3
/// planes), whose difference from `y` gives the noise (`y` is one estimate
/// or the pair's mean, [`Pair`]).
#[allow(clippy::too_many_arguments)]
pub fn to_input(
    ctx: &mut Ctx,
    o: &mut [f32],
    y: &[f32],
    pair: Option<Pair<'_>>,
    albedo: &[f32],
    w: usize,
    h: usize,
    exposure: f32,
) -> Result<()> {
    if w * h == 0 {
        return Ok(());
    }
    let noise = Noise::of(ctx, y, pair, w, h, exposure)?;
    to_input_with(ctx, o, y, noise, pair, albedo, w, h, exposure)
}

/// Bytes per pixel a [`Noise`] holds.
pub const NOISE_BYTES: u64 = 4 * 5;
/// Bytes per pixel [`Noise::of`] allocates at its peak (the exposure-scaled
/// input beside its `log1p`).
pub const NOISE_PEAK_BYTES: u64 = 4 * 6;
/// Bytes per pixel [`to_input_with`] allocates for the time it runs,
/// besides the [`Noise`] it is given.
pub const WITH_TEMP_BYTES: u64 = 4 * 2;

/// The input's noise, as the fallback and the wide pass
/// ([`crate::methods::wide`]) read it: computed once a frame for both.
#[derive(Debug)]
pub struct Noise {
    /// The input in exposure-normalised `log1p` colour (3 planes).
    ly: Vec<f32>,
    /// Its noise variance per pixel (the channels' mean; [`log_and_noise`]).
    raw: Vec<f32>,
    /// `raw`'s mean over each pixel's 7x7 window ([`window_means`]).
    means: Vec<f32>,
}

impl Noise {
    /// The noise of the input `y` (3 planes of `w x h`, linear), from
    /// `pair` where given, at the exposure `exposure`.
    pub fn of(ctx: &mut Ctx, y: &[f32], pair: Option<Pair<'_>>, w: usize, h: usize, exposure: f32) -> Result<Noise> {
        let (ly, raw) = log_and_noise(ctx, y, pair, w, h, positive_exposure(exposure))?;
        let mut means = raw.clone();
        window_means(ctx, &mut means, w, h);
        Ok(Noise { ly, raw, means })
    }

    /// The noise variance's 7x7 window mean per pixel.
    pub fn means(&self) -> &[f32] {
        &self.means
    }
}

/// The frame's squared coefficient of variation: the median over the
/// pixels of their window's `log1p` noise variance (`m`, the window means
/// of the noise of `ly`) over the slope of `log1p` at the window's mean
/// level, squared, over that level squared. `scratch` (`w x h` values) is
/// overwritten.
fn noise_cv2(ctx: &mut Ctx, ly: &[f32], m: &[f32], scratch: &mut [f32], w: usize, h: usize) -> f32 {
    const RUN: usize = 1 << 14;
    let n = w * h;
    ctx.pool.planes(vec![&mut scratch[..]], RUN, |start, runs| {
        for (j, v) in runs[0].iter_mut().enumerate() {
            let i = start + j;
            *v = (ly[i] + ly[n + i] + ly[2 * n + i]) / 3.0;
        }
    });
    window_means(ctx, scratch, w, h);
    ctx.pool.planes(vec![&mut scratch[..]], RUN, |start, runs| {
        for (v, &level) in runs[0].iter_mut().zip(&m[start..]) {
            let x = v.exp_m1().max(1e-3);
            *v = level * ((1.0 + x) / x).powi(2);
        }
    });
    *scratch.select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b)).1
}

/// [`to_input`] with the input's noise computed already (`noise`, of `y`,
/// `pair` and `exposure`, as [`Noise::of`] makes it).
#[allow(clippy::too_many_arguments)]
pub fn to_input_with(
    ctx: &mut Ctx,
    o: &mut [f32],
    y: &[f32],
    noise: Noise,
    pair: Option<Pair<'_>>,
    albedo: &[f32],
    w: usize,
    h: usize,
    exposure: f32,
) -> Result<()> {
    let n = w * h;
    if n == 0 {
        return Ok(());
    }
    if noise.ly.len() != 3 * n || noise.raw.len() != n || noise.means.len() != n {
        return Err(crate::error::HostError::Kernel(format!(
            "fallback: the input's noise is of {} pixels, the frame has {n}",
            noise.raw.len()
        )));
    }
    let e = positive_exposure(exposure);
    let log = |v: f32| if v.is_finite() { (e * v).max(0.0).ln_1p() } else { 0.0 };
    // (Per-pixel passes run in runs of pixels on the pool.)
    const RUN: usize = 1 << 14;
    let Noise { ly, mut raw, means: mut m } = noise;
    let ly = &ly;
    let fin = |v: f32| if v.is_finite() { v.min(1e12) } else { 1e12 };
    // The noise levels: the 7x7 window mean of the estimate (per channel)
    // at every pixel (`m`); the frame's is their median, a region's the
    // median over its tile ([`region_levels`]). A 1-spp frame ends here.
    let mut sorted = m.clone();
    let level = *sorted.select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b)).1;
    // The fade asks how reliable the noise estimate is, which depends on the
    // samples of each estimate it comes from: with the pair's mean as the
    // colour it comes from two estimates as noisy as one at twice the mean's
    // level (a 1-spp pair stays a 1-spp frame here).
    let per_estimate = if pair.is_some_and(|p| p.colour_is_mean && p.b.len() == 3 * n) { 2.0 } else { 1.0 };
    let frame = fade(per_estimate * level);
    if frame >= 1.0 {
        return Ok(());
    }
    // One estimate: the window's noise from the residuals against the
    // neighbours of the pixel's own surface and level ([`surface_noise`]);
    // the frame's level above stays the plain estimate's.
    let paired = pair.is_some_and(|p| p.b.len() == 3 * n);
    if !paired {
        // (Finite: `ly` is, and at most about 89.)
        surface_noise(ctx, &mut raw, ly, albedo, w, h);
    }
    // Each pixel's fade (into `m`), the later of the frame's and its
    // region's ([`region_fade`]): a frame half open sky or clean floor and
    // half 1-spp-noisy walls has a clean median, and its walls must still
    // count as 1 spp.
    // With one estimate, the region fade applies only if the frame's squared
    // coefficient of variation ([`REGION_CV2`]) says few samples a pixel
    // (computed into `sorted`, in place: the window's `log1p` variance over
    // the slope of `log1p` at the window's mean level, squared, over that
    // level squared); the pair's noise does not take texture for noise.
    let regions = paired || noise_cv2(ctx, ly, &m, &mut sorted, w, h) >= REGION_CV2;
    region_levels(&mut m, &mut sorted, w, h);
    drop(sorted);
    let mut any = false;
    for v in m.iter_mut() {
        *v = if regions { frame.max(region_fade(per_estimate * *v)) } else { frame };
        any |= *v < 1.0;
    }
    if !any {
        return Ok(());
    }
    let fades = &m;
    // The squared difference in the same colour, summed over the channels.
    let mut err = vec![0.0f32; n];
    {
        let o: &[f32] = o;
        ctx.pool.planes(vec![&mut err[..]], RUN, |start, runs| {
            for (j, e) in runs[0].iter_mut().enumerate() {
                let i = start + j;
                let mut d2 = 0.0f32;
                for c in 0..3 {
                    let d = log(o[c * n + i]) - ly[c * n + i];
                    d2 += d * d;
                }
                *e = fin(d2);
            }
        });
    }
    // Window sums over the pixels of the same albedo as the centre (within
    // ALBEDO_TOL of the larger, per channel) and an input within RANGE of
    // its: a light's partially covered edge beside a wall reads as noise
    // and would hide the wall pixel's error.
    let mut ks = vec![1.0f32; n];
    let win = Window { albedo, ly, raw: &raw, err: &err, w, h };
    let isa = ctx.isa;
    // Runs of whole rows, about 4096 pixels each.
    ctx.pool.planes(vec![&mut ks[..]], w * (4096 / w).max(1), |start, runs| {
        let mut sums = vec![0.0f32; 3 * w];
        for (r, ks) in runs[0].chunks_mut(w).enumerate() {
            let (vs, rest) = sums.split_at_mut(w);
            let (es, cnt) = rest.split_at_mut(w);
            // SAFETY: `ctx.isa` is one this CPU has (checked when the
            // context was made).
            unsafe { window_row_on(isa, &win, start / w + r, vs, es, cnt) };
            for (x, k) in ks.iter_mut().enumerate() {
                // (The estimate is the channels' mean: their sum is 3 times it.)
                *k = blend_weight(3.0 * vs[x], es[x], vs[x] / cnt[x].max(1.0));
            }
        }
    });
    let ks = &ks;
    ctx.pool.planes(o[..3 * n].chunks_mut(n).collect(), RUN, |start, runs| {
        for (c, run) in runs.iter_mut().enumerate() {
            for (j, ov) in run.iter_mut().enumerate() {
                let i = start + j;
                let k = ks[i] + fades[i] * (1.0 - ks[i]);
                let yv = y[c * n + i];
                let out = yv + k * (*ov - yv);
                if out.is_finite() {
                    *ov = out.max(0.0);
                }
            }
        }
    });
    Ok(())
}

/// The planes the fallback's window sums read: the albedo and the
/// exposure-normalised `log1p` input (3 planes each), the noise estimate
/// and the squared difference (1 each), all of `w x h`.
struct Window<'a> {
    albedo: &'a [f32],
    ly: &'a [f32],
    raw: &'a [f32],
    err: &'a [f32],
    w: usize,
    h: usize,
}

/// The window sums of row `y` (into `vs`, `es`, `cnt`, each `w` long): over
/// the pixels of the 7x7 window [`alike`] the centre, their noise
/// estimate, their squared difference and their count. Neighbour by
/// neighbour along the row (each in the order of the window's rows, then
/// columns: every pixel's sums are added up as a loop over its own window
/// adds them), so that the compiler can take the row's pixels in blocks.
#[inline(always)]
fn window_row(win: &Window<'_>, y: usize, vs: &mut [f32], es: &mut [f32], cnt: &mut [f32]) {
    let Window { albedo, ly, raw, err, w, h } = *win;
    let n = w * h;
    let (vs, es, cnt) = (&mut vs[..w], &mut es[..w], &mut cnt[..w]);
    vs.fill(0.0);
    es.fill(0.0);
    cnt.fill(0.0);
    // Row `y` of plane `c` of `v`; `len` values of `v` from `o`.
    fn plane_row(v: &[f32], c: usize, y: usize, w: usize, n: usize) -> &[f32] {
        &v[c * n + y * w..c * n + (y + 1) * w]
    }
    fn span(v: &[f32], o: usize, len: usize) -> &[f32] {
        &v[o..o + len]
    }
    let row = |v, c, y| plane_row(v, c, y, w, n);
    let (a0, a1, a2) = (row(albedo, 0, y), row(albedo, 1, y), row(albedo, 2, y));
    let (l0, l1, l2) = (row(ly, 0, y), row(ly, 1, y), row(ly, 2, y));
    for qy in y.saturating_sub(RADIUS)..(y + RADIUS + 1).min(h) {
        let (b0, b1, b2) = (row(albedo, 0, qy), row(albedo, 1, qy), row(albedo, 2, qy));
        let (m0, m1, m2) = (row(ly, 0, qy), row(ly, 1, qy), row(ly, 2, qy));
        let (rq, eq) = (row(raw, 0, qy), row(err, 0, qy));
        for dx in -(RADIUS as isize)..=RADIUS as isize {
            // The centres `x` whose neighbour `x + dx` is inside the row.
            let (x0, x1) = ((-dx).max(0) as usize, (w as isize - dx.max(0)).max(0) as usize);
            if x0 >= x1 {
                continue;
            }
            let len = x1 - x0;
            let q0 = (x0 as isize + dx) as usize;
            let at = |v, o| span(v, o, len);
            let (a0, a1, a2, l0, l1, l2) = (at(a0, x0), at(a1, x0), at(a2, x0), at(l0, x0), at(l1, x0), at(l2, x0));
            let (b0, b1, b2, m0, m1, m2) = (at(b0, q0), at(b1, q0), at(b2, q0), at(m0, q0), at(m1, q0), at(m2, q0));
            let (rq, eq) = (at(rq, q0), at(eq, q0));
            let (vs, es, cnt) = (&mut vs[x0..x1], &mut es[x0..x1], &mut cnt[x0..x1]);
            for k in 0..len {
                let range = ((m0[k] - l0[k]).abs() + (m1[k] - l1[k]).abs() + (m2[k] - l2[k]).abs()) / 3.0;
                let ok = same_albedo(a0[k], b0[k])
                    & same_albedo(a1[k], b1[k])
                    & same_albedo(a2[k], b2[k])
                    & (range <= RANGE);
                vs[k] += if ok { rq[k] } else { 0.0 };
                es[k] += if ok { eq[k] } else { 0.0 };
                cnt[k] += if ok { 1.0 } else { 0.0 };
            }
        }
    }
}

/// [`window_row`] in the build for `isa`.
///
/// # Safety
///
/// `isa` must be one this CPU has ([`mcdenoise_core::Isa::check`]).
unsafe fn window_row_on(
    isa: mcdenoise_core::Isa,
    win: &Window<'_>,
    y: usize,
    vs: &mut [f32],
    es: &mut [f32],
    cnt: &mut [f32],
) {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the caller's `isa` is one this CPU has.
        mcdenoise_core::Isa::Avx512 => unsafe { window_row_avx512(win, y, vs, es, cnt) },
        // SAFETY: as above.
        mcdenoise_core::Isa::Avx2 => unsafe { window_row_avx2(win, y, vs, es, cnt) },
        mcdenoise_core::Isa::Scalar => window_row(win, y, vs, es, cnt),
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = isa;
        window_row(win, y, vs, es, cnt)
    }
}

/// [`window_row`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn window_row_avx2(win: &Window<'_>, y: usize, vs: &mut [f32], es: &mut [f32], cnt: &mut [f32]) {
    window_row(win, y, vs, es, cnt)
}

/// [`window_row`] compiled for AVX-512.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2")]
unsafe fn window_row_avx512(win: &Window<'_>, y: usize, vs: &mut [f32], es: &mut [f32], cnt: &mut [f32]) {
    window_row(win, y, vs, es, cnt)
}

/// `exposure` where it is positive and finite, else 1.
pub(crate) fn positive_exposure(exposure: f32) -> f32 {
    if exposure > 0.0 && exposure.is_finite() {
        exposure
    } else {
        1.0
    }
}

/// The input `y` (3 planes of `w x h`) in exposure-normalised `log1p`
/// colour (`e` the exposure; non-finite values read as 0), and its noise
/// variance per pixel (the channels' mean, finite, at most 1e12): from the
/// pair where the frame has it, else the one-estimate local estimate
/// ([`noise::local_noise_rows`]).
pub(crate) fn log_and_noise(
    ctx: &mut Ctx,
    y: &[f32],
    pair: Option<Pair<'_>>,
    w: usize,
    h: usize,
    e: f32,
) -> Result<(Vec<f32>, Vec<f32>)> {
    use mcdenoise_core::tonemap::{map, Map};
    let n = w * h;
    const RUN: usize = 1 << 14;
    // `log(y)`: the exposure-scaled input (non-finite values as 0) through
    // the core's SIMD `log1p`.
    let mut ey = vec![0.0f32; 3 * n];
    ctx.pool.planes(vec![&mut ey[..]], RUN, |start, runs| {
        for (o, &v) in runs[0].iter_mut().zip(&y[start..]) {
            *o = if v.is_finite() { e * v } else { 0.0 };
        }
    });
    let mut ly = vec![0.0f32; 3 * n];
    {
        map::<mcdenoise_core::F32>(
            ctx.isa,
            Map::Log1p,
            &View::new(&ey, 3, w, h)?,
            &mut ViewMut::new(&mut ly, 3, w, h)?,
        )?;
    }
    drop(ey);
    let mut raw = vec![0.0f32; n];
    match pair {
        Some(p) if p.b.len() == 3 * n => {
            let ly = &ly;
            let b = p.b;
            let isa = ctx.isa;
            // `log(b)`, and `log(a)` where the colour is the mean (`A`
            // recovered from it; otherwise `log(a)` is `ly` itself), a run at
            // a time through the core's SIMD `log1p` ([`Pair::spread`]).
            let k = if p.colour_is_mean { 2 } else { 1 };
            ctx.pool.planes(vec![&mut raw[..]], RUN, |start, runs| {
                let r = &mut *runs[0];
                let len = r.len();
                let (mut eba, mut lba) = (vec![0.0f32; k * len], vec![0.0f32; k * len]);
                r.fill(0.0);
                for c in 0..3 {
                    let (eb, ea) = eba.split_at_mut(len);
                    for (j, db) in eb.iter_mut().enumerate() {
                        let i = c * n + start + j;
                        let bv = if b[i].is_finite() { b[i] } else { 0.0 };
                        *db = e * bv;
                        if let Some(da) = ea.get_mut(j) {
                            let yv = if y[i].is_finite() { y[i] } else { 0.0 };
                            *da = e * p.first(yv, bv);
                        }
                    }
                    let src = View::new(&eba, 1, k * len, 1).expect("a run's shape");
                    let mut dst = ViewMut::new(&mut lba, 1, k * len, 1).expect("a run's shape");
                    map::<mcdenoise_core::F32>(isa, Map::Log1p, &src, &mut dst).expect("log1p takes every value");
                    let (lb, la) = lba.split_at(len);
                    for (j, (r, (&tb, &ty))) in r.iter_mut().zip(lb.iter().zip(&ly[c * n + start..])).enumerate() {
                        *r += Pair::spread(ty, la.get(j).copied().unwrap_or(ty), tb);
                    }
                }
                for r in r.iter_mut() {
                    *r /= 3.0;
                }
            });
        }
        _ => {
            let src = View::new(&ly, 3, w, h)?;
            let (pool, scratch) = (&ctx.pool, &mut ctx.scratch);
            pool.bands(ViewMut::new(&mut raw, 1, w, h)?, 16, scratch, 0, |b, y0, _| {
                noise::local_noise_rows(&src, b, y0)
            })?;
        }
    }
    let fin = |v: f32| if v.is_finite() { v.min(1e12) } else { 1e12 };
    ctx.pool.planes(vec![&mut raw[..]], RUN, |_, runs| {
        for v in runs[0].iter_mut() {
            *v = fin(*v);
        }
    });
    Ok((ly, raw))
}

/// Replaces each value of `m` (`w` x `h`) by the mean over its 7x7 window
/// (the pixels inside the frame).
pub(crate) fn window_means(ctx: &mut Ctx, m: &mut [f32], w: usize, h: usize) {
    crate::methods::features::box_sum(m, w, h, RADIUS);
    let span = |p: usize, len: usize| crate::methods::features::window_span(p, len, RADIUS);
    // Runs of whole rows.
    ctx.pool.planes(vec![m], w * 16, |start, runs| {
        for (r, row) in runs[0].chunks_mut(w).enumerate() {
            let sy = span(start / w + r, h);
            for (x, v) in row.iter_mut().enumerate() {
                *v /= span(x, w) * sy;
            }
        }
    });
}

/// Side of the square tiles whose median window level is a region's noise
/// level (see [`region_fade`]).
pub const TILE: usize = 32;

/// Replaces each pixel's window level in `m` (`w` x `h`) by its region's:
/// the median over each tile (the frame split evenly into tiles of at most
/// [`TILE`] pixels a side), taken at the tile's centre and interpolated
/// bilinearly between the centres (held beyond the outer ones). A median,
/// so that the edges a 64-spp frame's one-estimate noise reads as noise do
/// not make its region noisy. `scratch` holds at least `TILE * TILE`
/// values; its contents are lost.
fn region_levels(m: &mut [f32], scratch: &mut [f32], w: usize, h: usize) {
    let (tx, ty) = (w.div_ceil(TILE).max(1), h.div_ceil(TILE).max(1));
    let bounds = |t: usize, count: usize, len: usize| (t * len / count, (t + 1) * len / count);
    let mut grid = vec![0.0f32; tx * ty];
    for j in 0..ty {
        let (y0, y1) = bounds(j, ty, h);
        for i in 0..tx {
            let (x0, x1) = bounds(i, tx, w);
            let mut k = 0;
            for y in y0..y1 {
                for x in x0..x1 {
                    scratch[k] = m[y * w + x];
                    k += 1;
                }
            }
            grid[j * tx + i] =
                if k == 0 { 0.0 } else { *scratch[..k].select_nth_unstable_by(k / 2, |a, b| a.total_cmp(b)).1 };
        }
    }
    // A pixel's position in tile-centre units along one axis: the lower
    // centre's index and the weight of the next.
    let at = |p: usize, count: usize, len: usize| {
        let u = ((p as f32 + 0.5) * count as f32 / len as f32 - 0.5).clamp(0.0, (count - 1) as f32);
        let t0 = (u as usize).min(count - 1);
        (t0, (t0 + 1).min(count - 1), u - t0 as f32)
    };
    for y in 0..h {
        let (j0, j1, fy) = at(y, ty, h);
        for x in 0..w {
            let (i0, i1, fx) = at(x, tx, w);
            let g = |j: usize, i: usize| grid[j * tx + i];
            let top = g(j0, i0) + fx * (g(j0, i1) - g(j0, i0));
            let bottom = g(j1, i0) + fx * (g(j1, i1) - g(j1, i0));
            m[y * w + x] = top + fy * (bottom - top);
        }
    }
}

/// Whether one channel of a centre's albedo `ai` and a neighbour's `aq` are
/// the same surface's: within [`ALBEDO_TOL`] of the larger plus
/// [`ALBEDO_FLOOR`]. Shared by [`alike`] and [`window_row`], so that the
/// vectorised window sums and their per-pixel reference test one rule.
#[inline(always)]
fn same_albedo(ai: f32, aq: f32) -> bool {
    (aq - ai).abs() <= ALBEDO_TOL * aq.abs().max(ai.abs()) + ALBEDO_FLOOR
}

/// Whether pixel `q` counts as pixel `i`'s surface at its level: the same
/// albedo (within [`ALBEDO_TOL`] of the larger, per channel, plus
/// [`ALBEDO_FLOOR`]) and an input within [`RANGE`] (mean over the channels
/// of `ly`, the exposure-normalised `log1p` colour). `n`: pixels per plane.
#[inline]
fn alike(albedo: &[f32], ly: &[f32], n: usize, i: usize, q: usize) -> bool {
    (0..3).all(|c| same_albedo(albedo[c * n + i], albedo[c * n + q]))
        && (0..3).map(|c| (ly[c * n + q] - ly[c * n + i]).abs()).sum::<f32>() / 3.0 <= RANGE
}

/// The one-estimate noise the window sums: `0.84 |y - m|^2`, mean over the
/// channels, with `m` the median of those of the 8 neighbours that are
/// [`alike`] the pixel (the mean of the middle two of an even count),
/// written over `raw`, which holds the plain estimate (the median of all 8)
/// and keeps it where no neighbour is alike or where neighbours lie beyond
/// [`RANGE`] both above and below the pixel (mean over the channels): a
/// pixel between brighter and darker ones is noise, not an edge, and the
/// few neighbours within the range would understate it (a 16-spp
/// highlight's speckle came back).
///
/// The plain estimate (the median of all 8) reads a clean input's thin
/// features as noise: the Cornell box's light's edge row, a corner's
/// shading, a line one or two pixels wide, whose neighbours are mostly
/// the other side; counted as noise, it kept the blur the filter left there
/// (WSKP's weights are the neighbour's, shared by every window, so it cannot
/// keep an edge in the irradiance). With only the pixel's own surface and
/// level, those pixels' residuals are their noise. With one neighbour the
/// residual's variance is twice the noise's (the factor stays, so the
/// estimate leans to keeping the output). Measured in
/// docs/quality.md ("The fallback's noise on one estimate").
fn surface_noise(ctx: &mut Ctx, raw: &mut [f32], ly: &[f32], albedo: &[f32], w: usize, h: usize) {
    let n = w * h;
    ctx.pool.planes(vec![raw], 1 << 12, |start, runs| {
        for (j, r) in runs[0].iter_mut().enumerate() {
            let i = start + j;
            let (px, py) = (i % w, i / w);
            let mut nb = [0usize; 8];
            let (mut m, mut above, mut below) = (0, false, false);
            for qy in py.saturating_sub(1)..(py + 2).min(h) {
                for qx in px.saturating_sub(1)..(px + 2).min(w) {
                    let q = qy * w + qx;
                    if q == i {
                        continue;
                    }
                    let d = (0..3).map(|c| ly[c * n + q] - ly[c * n + i]).sum::<f32>() / 3.0;
                    above |= d > RANGE;
                    below |= d < -RANGE;
                    if alike(albedo, ly, n, i, q) {
                        nb[m] = q;
                        m += 1;
                    }
                }
            }
            // No neighbour alike (a lone firefly), or neighbours beyond the
            // range on both sides (noise, not an edge): the plain estimate.
            if m == 0 || (above && below) {
                continue;
            }
            let alike_nb = &nb[..m];
            let mut d2 = 0.0f32;
            for c in 0..3 {
                let mut v = [0.0f32; 8];
                for (v, &q) in v.iter_mut().zip(alike_nb) {
                    *v = ly[c * n + q];
                }
                let v = &mut v[..alike_nb.len()];
                v.sort_unstable_by(f32::total_cmp);
                let l = v.len();
                let med = if l % 2 == 1 { v[l / 2] } else { 0.5 * (v[l / 2 - 1] + v[l / 2]) };
                let d = ly[c * n + i] - med;
                d2 += 0.84 * d * d;
            }
            *r = d2 / 3.0;
        }
    });
}

/// How far the fallback is faded out (0: fully on, 1: off) at the frame's
/// noise level `level` (the median over the pixels of the 7x7 window mean
/// of their noise variance, every pixel of the window): on from [`FADE_FROM`] down, off from [`FADE_TO`] up. On
/// a noisy frame the output's difference from the input is mostly the
/// noise removed, and where it is not, a blend puts the input's noise back
/// in patches: with a light that moved, which the temporal accumulation
/// lags, the lounge's dark wall came back as blotches of 1-spp noise
/// (PSNR and relMSE better, the picture worse). The level separates the
/// sample counts (7x7 windows, exposure-normalised `log1p` colour): 1 spp
/// 0.007-0.016 on the foreign set, 4 spp 0.0056, 16 spp 0.0016, 64 spp
/// 0.0002-0.0004.
#[inline]
pub fn fade(level: f32) -> f32 {
    ((level - FADE_FROM) / (FADE_TO - FADE_FROM)).clamp(0.0, 1.0)
}

/// How far the fallback is faded out in a region whose noise level (the
/// median window level over its tile, interpolated between the tiles'
/// centres) is `level`: [`fade`]'s ramp, from
/// [`REGION_FADE_FROM`] to [`REGION_FADE_TO`]. A region's level does not
/// tell the sample count as well as a frame's: a dark 16-spp room's dim
/// corners reach 0.03-0.1 (where the fallback still restores thin bright
/// edges), and the 1-spp walls of a frame whose median is open sky reach
/// 0.04-0.26. Chosen on the generator's held-out scenes (docs/quality.md,
/// "The fallback's fade per region"): at 1x the frame's band, a 16-spp
/// room lost up to 1.6 dB; at 6x the 16- to 64-spp scenes lose 0.01 to
/// 0.05 dB on the mean (1.15 on the dark `hi_0061` with one estimate, 0.11
/// with the pair) and `test_0003` gains 13.5 to 14.1 dB.
#[inline]
pub fn region_fade(level: f32) -> f32 {
    ((level - REGION_FADE_FROM) / (REGION_FADE_TO - REGION_FADE_FROM)).clamp(0.0, 1.0)
}

/// The margin at a window's mean noise variance `vbar` (per channel, in
/// exposure-normalised `log1p` colour): from 1 on a clean input to
/// [`MARGIN`] from [`NOISY`] on.
#[inline]
pub fn margin(vbar: f32) -> f32 {
    1.0 + (MARGIN - 1.0) * (vbar / NOISY).clamp(0.0, 1.0)
}

/// The output's weight from the input's noise `v` and the squared
/// difference `e` (window sums), at mean noise `vbar`:
/// `v / (v + max(e - M v, 0))` with `M = margin(vbar)`, 1 where both
/// vanish.
#[inline]
pub fn blend_weight(v: f32, e: f32, vbar: f32) -> f32 {
    shrink(v, e, margin(vbar))
}

/// The output's weight in a blend with an input of noise variance `v`,
/// the output's squared difference from it being `e`:
/// `v / (v + max(e - margin v, 0))` (the output's excess over the noise
/// taken as its squared error), 1 where both vanish. `cross` falls back to
/// its pair's mean by the same weight.
#[inline]
pub fn shrink(v: f32, e: f32, margin: f32) -> f32 {
    let bias2 = (e - margin * v).max(0.0);
    if v + bias2 > 0.0 {
        v / (v + bias2)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::test_noise::lcg;

    /// A flat input whose output carries a step: the window sees no noise in
    /// the input, so the output returns to it; an input with strong noise
    /// and an output equal to its smooth mean is left alone.
    #[test]
    fn keeps_a_clean_input_and_leaves_a_denoised_noisy_one() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (24, 20);
        let n = w * h;
        let y = vec![0.5f32; 3 * n];
        let mut o: Vec<f32> = (0..3 * n).map(|i| if (i % n) % w < w / 2 { 0.3 } else { 0.7 }).collect();
        to_input(&mut ctx, &mut o, &y, None, &vec![0.5; 3 * n], w, h, 1.0).unwrap();
        assert!(o.iter().all(|&v| (v - 0.5).abs() < 1e-6), "a clean input is kept");
        // Noisy input (deterministic hash noise), output its mean.
        let mut s = 12345u32;
        let y: Vec<f32> = (0..3 * n).map(|_| 0.5 + (lcg(&mut s) - 0.5)).collect();
        let mean = y.iter().sum::<f32>() / (3 * n) as f32;
        let mut o = vec![mean; 3 * n];
        to_input(&mut ctx, &mut o, &y, None, &vec![0.5; 3 * n], w, h, 1.0).unwrap();
        assert!(o.iter().all(|&v| (v - mean).abs() < 1e-6), "noise removed is not put back");
    }

    /// A frame of `w` x `h` whose left `noisy_to` columns are 1-spp-noisy
    /// (uniform in 1 +- 0.9, about 0.08 in log1p) and whose other pixels are
    /// `rest(u)` for a uniform `u` in -0.5..0.5: two independent estimates.
    fn half_noisy(w: usize, h: usize, noisy_to: usize, rest: impl Fn(f32) -> f32) -> (Vec<f32>, Vec<f32>) {
        let n = w * h;
        let mut next = crate::methods::test_noise::xorshift32(4242);
        let mut estimate = || {
            (0..3 * n)
                .map(|i| {
                    let u = (next() >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
                    if (i % n) % w < noisy_to {
                        1.0 + 1.8 * u
                    } else {
                        rest(u)
                    }
                })
                .collect::<Vec<f32>>()
        };
        (estimate(), estimate())
    }

    /// A frame whose larger part is dim and clean in `log1p` (a floor in
    /// shade, at 1 spp) and whose left part is 1-spp-noisy has a clean
    /// median level, and the fallback must still stay off on the noisy
    /// part: there its noise estimate is the unreliable one the fade guards
    /// against (the generator's `test_0003`: 22 dB with the fallback, 37
    /// without). An output off by far more than the noise stays on the noisy
    /// part and returns to the input on the clean part, with the pair's
    /// noise and with one estimate's.
    #[test]
    fn a_noisy_region_of_a_clean_frame_is_faded_out() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (4 * TILE, 2 * TILE);
        let n = w * h;
        let noisy_to = 3 * TILE / 2;
        // The rest: 0.02 +- 50 %, a squared coefficient of variation of
        // 1/12 (a few samples a pixel), about 3e-5 in log1p.
        let (a, b) = half_noisy(w, h, noisy_to, |u| 0.02 * (1.0 + u));
        let noisy: f64 = (0..3 * n)
            .filter(|i| (i % n) % w < noisy_to)
            .map(|i| 0.5 * ((a[i] as f64).ln_1p() - (b[i] as f64).ln_1p()).powi(2))
            .sum::<f64>()
            / (3 * h * noisy_to) as f64;
        assert!(noisy > 2.0 * REGION_FADE_TO as f64 && noisy_to < w / 2, "the test's premise: {noisy}");
        const { assert!(1.0 / 12.0 > 1.5 * REGION_CV2, "the test's premise") };
        for pair in [Some(Pair { b: &b, colour_is_mean: false }), None] {
            let mut o = vec![2.0f32; 3 * n];
            to_input(&mut ctx, &mut o, &a, pair, &vec![0.5; 3 * n], w, h, 1.0).unwrap();
            let with = if pair.is_some() { "the pair" } else { "one estimate" };
            for c in 0..3 {
                for y in 0..h {
                    for x in 0..TILE / 2 {
                        assert_eq!(o[c * n + y * w + x], 2.0, "{with}: the noisy part is left alone at ({x}, {y})");
                    }
                    for x in w - TILE / 2..w {
                        let i = c * n + y * w + x;
                        assert!((o[i] - a[i]).abs() < 0.01, "{with}: the clean part returns at ({x}, {y}): {}", o[i]);
                    }
                }
            }
        }
    }

    /// The same frame with its larger part exactly constant (many samples a
    /// pixel: the frame's squared coefficient of variation is 0): one
    /// estimate's noise reads the noisy-looking part as texture, as on the
    /// generator's 16-spp `test_0005` (a fine checker behind glass, where
    /// the region fade cost WSKP-3 2 dB), so the region fade does not apply
    /// and the fallback moves the output there. The pair's noise says it is
    /// noise (its two estimates differ there), and the region fade leaves
    /// the output alone.
    #[test]
    fn a_frame_of_many_samples_keeps_the_fallback_on_its_textured_region() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (4 * TILE, 2 * TILE);
        let n = w * h;
        let (a, b) = half_noisy(w, h, 3 * TILE / 2, |_| 1.0);
        let moved = |pair: Option<Pair<'_>>, ctx: &mut Ctx| {
            let mut o = vec![2.0f32; 3 * n];
            to_input(ctx, &mut o, &a, pair, &vec![0.5; 3 * n], w, h, 1.0).unwrap();
            (0..3)
                .flat_map(|c| (0..h).flat_map(move |y| (0..TILE / 2).map(move |x| c * n + y * w + x)))
                .filter(|&i| o[i] < 2.0)
                .count()
        };
        let all = 3 * h * TILE / 2;
        let one = moved(None, &mut ctx);
        assert!(one > all / 2, "one estimate: {one} of {all} pixels of the textured part moved");
        let paired = moved(Some(Pair { b: &b, colour_is_mean: false }), &mut ctx);
        assert_eq!(paired, 0, "the pair: {paired} of {all} pixels of the noisy part moved");
    }

    /// The region levels: the tiles' medians at their centres, linear
    /// between them, held beyond the outer centres.
    #[test]
    fn region_levels_interpolate_the_tiles_medians() {
        let (w, h) = (4 * TILE, TILE);
        // Tile i holds i + 1 on most pixels and a few outliers of 100.
        let mut m: Vec<f32> = (0..w * h)
            .map(|p| if p % 7 == 0 && (p / w) % 3 == 0 { 100.0 } else { ((p % w) / TILE + 1) as f32 })
            .collect();
        let mut scratch = vec![0.0f32; w * h];
        region_levels(&mut m, &mut scratch, w, h);
        for y in 0..h {
            for x in 0..w {
                let u = ((x as f64 + 0.5) / TILE as f64 - 0.5).clamp(0.0, 3.0);
                let want = u + 1.0;
                assert!((m[y * w + x] as f64 - want).abs() < 1e-5, "({x}, {y}): {} against {want}", m[y * w + x]);
            }
        }
    }

    /// The window holds only inputs within RANGE of the centre's: a dark
    /// half whose output is within its noise of the input stays as the
    /// filter left it beside a bright half (the same albedo, 5 pixels on)
    /// whose output is off by 40 % and returns to its input.
    #[test]
    fn the_window_holds_only_inputs_near_the_centres() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (24, 20);
        let n = w * h;
        let mut s = 4242u32;
        let y: Vec<f32> = (0..3 * n)
            .map(|i| {
                let base = if (i % n) % w < w / 2 { 0.1 } else { 1.0 };
                base * (1.0 + 0.05 * (lcg(&mut s) - 0.5))
            })
            .collect();
        let dark = |i: usize| (i % n) % w < w / 2;
        let o0: Vec<f32> = y.iter().enumerate().map(|(i, &v)| if dark(i) { v * 1.01 } else { v * 0.6 }).collect();
        let mut o = o0.clone();
        to_input(&mut ctx, &mut o, &y, None, &vec![0.5; 3 * n], w, h, 1.0).unwrap();
        for i in 0..3 * n {
            let x = (i % n) % w;
            if dark(i) && x >= 2 && (i % n) / w >= 3 && (i % n) / w < h - 3 {
                assert!((o[i] - o0[i]).abs() <= 1e-4 * o0[i], "dark pixel {i} (x {x}) moved: {} -> {}", o0[i], o[i]);
            }
            if !dark(i) && x >= w / 2 + 4 {
                assert!(
                    (o[i] - y[i]).abs() < 0.1 * y[i],
                    "bright pixel {i} not back at its input: {} against {}",
                    o[i],
                    y[i]
                );
            }
        }
    }

    /// The window sums of every row, on every instruction set this CPU
    /// has, against their definition in f64: over the 7x7 window clipped
    /// to the image, the pixels whose albedo (per channel, within
    /// ALBEDO_TOL of the larger plus ALBEDO_FLOOR) and mean `log1p` input
    /// (within RANGE) match the centre's; the count exactly. Albedos and
    /// inputs are drawn from a few levels, so that many neighbours match and
    /// many do not, also on frames narrower than the window near its edges;
    /// and bit for bit the sums of a loop over each pixel's own window.
    #[test]
    fn window_sums_are_their_definition_on_every_path() {
        for (w, h) in [(37, 9), (5, 4), (1, 8)] {
            let n = w * h;
            let mut s = 77u32 + w as u32;
            let mut level = |k: f32| (lcg(&mut s) * k).floor() / k;
            // Grey albedos of two levels, a little apart per channel.
            let base: Vec<f32> = (0..n).map(|_| 0.1 + 0.5 * level(2.0)).collect();
            let albedo: Vec<f32> = (0..3 * n).map(|i| base[i % n] + 0.01 * (i / n) as f32).collect();
            let ly: Vec<f32> = (0..3 * n).map(|_| 0.5 * level(3.0)).collect();
            let raw: Vec<f32> = (0..n).map(|_| level(100.0)).collect();
            let err: Vec<f32> = (0..n).map(|_| 3.0 * level(100.0)).collect();
            let win = Window { albedo: &albedo, ly: &ly, raw: &raw, err: &err, w, h };
            for isa in mcdenoise_core::Isa::ALL.iter().copied().filter(|i| i.check().is_ok()) {
                for y in 0..h {
                    let (mut vs, mut es, mut cnt) = (vec![9.0f32; w], vec![9.0f32; w], vec![9.0f32; w]);
                    // SAFETY: `isa` passed its check.
                    unsafe { window_row_on(isa, &win, y, &mut vs, &mut es, &mut cnt) };
                    for x in 0..w {
                        let i = y * w + x;
                        let (mut v, mut e, mut c) = (0.0f64, 0.0f64, 0.0f64);
                        for qy in y.saturating_sub(3)..(y + 4).min(h) {
                            for qx in x.saturating_sub(3)..(x + 4).min(w) {
                                let q = qy * w + qx;
                                let at = |b: &[f32], k: usize, p: usize| b[k * n + p] as f64;
                                let same = (0..3).all(|k| {
                                    let (ai, aq) = (at(&albedo, k, i), at(&albedo, k, q));
                                    (aq - ai).abs() <= 0.2 * aq.max(ai) + 0.02 + 1e-6
                                });
                                let d = (0..3).map(|k| (at(&ly, k, q) - at(&ly, k, i)).abs()).sum::<f64>() / 3.0;
                                if same && d <= 0.2 + 1e-6 {
                                    v += raw[q] as f64;
                                    e += err[q] as f64;
                                    c += 1.0;
                                }
                            }
                        }
                        let at = format!("{isa:?}, {w}x{h}, pixel ({x}, {y})");
                        // Bit for bit the per-pixel loop's f32 sums (over
                        // the window's rows, then columns, by `alike`).
                        let (mut v32, mut e32) = (0.0f32, 0.0f32);
                        for qy in y.saturating_sub(3)..(y + 4).min(h) {
                            for qx in x.saturating_sub(3)..(x + 4).min(w) {
                                let q = qy * w + qx;
                                if alike(&albedo, &ly, n, i, q) {
                                    v32 += raw[q];
                                    e32 += err[q];
                                }
                            }
                        }
                        assert_eq!((vs[x].to_bits(), es[x].to_bits()), (v32.to_bits(), e32.to_bits()), "{at}: bits");
                        assert_eq!(cnt[x] as f64, c, "{at}: count");
                        assert!((vs[x] as f64 - v).abs() <= 1e-5 * v.max(1.0), "{at}: noise {} against {v}", vs[x]);
                        assert!(
                            (es[x] as f64 - e).abs() <= 1e-5 * e.max(1.0),
                            "{at}: difference {} against {e}",
                            es[x]
                        );
                    }
                }
            }
        }
    }

    /// A clean input with a bright line one pixel wide, which the output
    /// blurred into the rows beside it: the line's pixels return to their
    /// input. (With the residual against the median of all 8 neighbours, 6
    /// of them the background, the line read as noise and stayed blurred.)
    #[test]
    fn a_thin_line_is_not_read_as_noise() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (24, 20);
        let n = w * h;
        let line = |i: usize| (i % n) / w == 10;
        let beside = |i: usize| (i % n) / w == 9 || (i % n) / w == 11;
        let mut s = 99u32;
        let y: Vec<f32> =
            (0..3 * n).map(|i| if line(i) { 1.0 } else { 0.1 } * (1.0 + 0.01 * (lcg(&mut s) - 0.5))).collect();
        let mut o: Vec<f32> = y
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                if line(i) {
                    0.55
                } else if beside(i) {
                    0.3
                } else {
                    v
                }
            })
            .collect();
        to_input(&mut ctx, &mut o, &y, None, &vec![0.5; 3 * n], w, h, 1.0).unwrap();
        for i in (0..3 * n).filter(|&i| line(i) && (i % n) % w >= 3 && (i % n) % w < w - 3) {
            assert!((o[i] - y[i]).abs() < 0.05 * y[i], "line pixel {i}: {} against its input {}", o[i], y[i]);
        }
    }

    /// The surface estimate on a patch of speckle (each pixel 0.05, 0.5 or 5
    /// at random, log colour): a pixel with neighbours beyond the range both
    /// above and below keeps the plain estimate (the residual against the
    /// median of all 8, computed here independently); one whose neighbours
    /// beyond the range are all on one side takes the residual against its
    /// alike neighbours, which agree with it exactly (0).
    #[test]
    fn speckle_keeps_the_plain_estimate() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (12, 10);
        let n = w * h;
        let mut s = 2024u32;
        let level: Vec<f32> =
            (0..n).map(|_| [0.05f32, 0.5, 5.0][((lcg(&mut s) * 3.0) as usize).min(2)].ln_1p()).collect();
        let ly: Vec<f32> = (0..3 * n).map(|i| level[i % n]).collect();
        let plain = |x: usize, y: usize| {
            let mut v: Vec<f64> =
                (0..9).filter(|&k| k != 4).map(|k| level[(y + k / 3 - 1) * w + x + k % 3 - 1] as f64).collect();
            v.sort_by(f64::total_cmp);
            let d = level[y * w + x] as f64 - 0.5 * (v[3] + v[4]);
            0.84 * d * d
        };
        let mut raw: Vec<f32> = (0..n)
            .map(|i| {
                if (1..w - 1).contains(&(i % w)) && (1..h - 1).contains(&(i / w)) {
                    plain(i % w, i / w) as f32
                } else {
                    0.0
                }
            })
            .collect();
        surface_noise(&mut ctx, &mut raw, &ly, &vec![0.5; 3 * n], w, h);
        let (mut both, mut one_side) = (0, 0);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let i = y * w + x;
                let d: Vec<f32> =
                    (0..9).filter(|&k| k != 4).map(|k| level[(y + k / 3 - 1) * w + x + k % 3 - 1] - level[i]).collect();
                let (above, below) = (d.iter().any(|&d| d > RANGE), d.iter().any(|&d| d < -RANGE));
                let alike = d.iter().any(|&d| d.abs() <= RANGE);
                if above && below {
                    both += 1;
                    assert!(
                        (raw[i] as f64 - plain(x, y)).abs() <= 1e-6 * plain(x, y).max(1e-6),
                        "pixel ({x}, {y}): {}",
                        raw[i]
                    );
                } else if alike {
                    one_side += 1;
                    assert!(raw[i].abs() < 1e-9, "pixel ({x}, {y}) with neighbours on one side: {}", raw[i]);
                }
            }
        }
        assert!(both >= 10 && one_side >= 5, "{both} pixels between levels, {one_side} on one side");
    }

    /// A fine checker (2 px) with light noise, its output blurred: the
    /// one-estimate noise reads the checker as noise and keeps the blur; the
    /// pair's difference gives the true noise and the output returns to the
    /// input.
    #[test]
    fn the_pair_tells_texture_from_noise() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (32, 24);
        let n = w * h;
        let truth: Vec<f32> =
            (0..3 * n).map(|i| if ((i % n) % w / 2 + (i % n) / w / 2) % 2 == 0 { 0.1 } else { 0.6 }).collect();
        let mut s = 777u32;
        let mut noisy = |t: &[f32]| -> Vec<f32> { t.iter().map(|&v| v * (1.0 + 0.02 * (lcg(&mut s) - 0.5))).collect() };
        let (y, b) = (noisy(&truth), noisy(&truth));
        // The output: the input's 3x3 mean (the checker blurred away).
        let mut blurred = vec![0.0f32; 3 * n];
        for c in 0..3 {
            for py in 0..h {
                for px in 0..w {
                    let (mut sum, mut cnt) = (0.0f32, 0.0f32);
                    for qy in py.saturating_sub(1)..(py + 2).min(h) {
                        for qx in px.saturating_sub(1)..(px + 2).min(w) {
                            sum += y[c * n + qy * w + qx];
                            cnt += 1.0;
                        }
                    }
                    blurred[c * n + py * w + px] = sum / cnt;
                }
            }
        }
        let err = |o: &[f32]| o.iter().zip(&truth).map(|(a, t)| ((a - t) as f64).powi(2)).sum::<f64>() / o.len() as f64;
        let (e_in, e_blur) = (err(&y), err(&blurred));
        let alb = vec![0.5f32; 3 * n];
        let mut one = blurred.clone();
        to_input(&mut ctx, &mut one, &y, None, &alb, w, h, 1.0).unwrap();
        let mut two = blurred.clone();
        to_input(&mut ctx, &mut two, &y, Some(Pair { b: &b, colour_is_mean: false }), &alb, w, h, 1.0).unwrap();
        assert!(e_blur > 100.0 * e_in, "the blur is the output's error: {e_blur} against the input's {e_in}");
        assert!(
            err(&one) > 0.9 * e_blur,
            "one estimate: the checker reads as noise, the blur stays ({} of {e_blur})",
            err(&one)
        );
        assert!(err(&two) < 2.0 * e_in, "the pair: back to the input ({} against the input's {e_in})", err(&two));
    }

    /// Images of `len` values uniform in `1 +- width / 2`, one a call, from
    /// the generator seeded with `seed`.
    fn around_one(seed: u32, len: usize, width: f32) -> impl FnMut() -> Vec<f32> {
        let mut next = crate::methods::test_noise::xorshift32(seed);
        move || (0..len).map(|_| 1.0 + width * ((next() >> 8) as f32 / (1u32 << 24) as f32 - 0.5)).collect()
    }

    /// The fade under the pair's mean: a pair of estimates whose own noise
    /// level is past [`FADE_TO`] leaves the output alone when the colour is
    /// their mean (whose level, half of it, is below [`FADE_TO`]), and the
    /// same images read as one estimate beside a second (the flag off, a
    /// quarter of that level) move the output back.
    #[test]
    fn a_pairs_mean_is_faded_as_its_estimates_are() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (32, 24);
        let n = w * h;
        // Uniform in 1 +- 0.31: variance 0.032, about 0.008 in log1p at 1
        // (slope 1/2).
        let mut noisy = around_one(777, 3 * n, 0.62);
        let (a, b) = (noisy(), noisy());
        let m: Vec<f32> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
        // The levels in f64: one estimate's and the mean's (median of the
        // windows' means is close to the pixels' mean here).
        let one: f64 =
            a.iter().zip(&b).map(|(&x, &y)| 0.5 * ((x as f64).ln_1p() - (y as f64).ln_1p()).powi(2)).sum::<f64>()
                / (3 * n) as f64;
        assert!(one > 1.2 * FADE_TO as f64 && 0.5 * one < FADE_TO as f64, "the test's premise: {one}");
        let alb = vec![0.5f32; 3 * n];
        let wrong = vec![2.0f32; 3 * n];
        let mut o = wrong.clone();
        to_input(&mut ctx, &mut o, &m, Some(Pair { b: &b, colour_is_mean: true }), &alb, w, h, 1.0).unwrap();
        assert_eq!(o, wrong, "a 1-spp pair's mean: faded out");
        let mut o = wrong.clone();
        to_input(&mut ctx, &mut o, &m, Some(Pair { b: &b, colour_is_mean: false }), &alb, w, h, 1.0).unwrap();
        assert!(o.iter().zip(&wrong).filter(|(x, y)| x != y).count() > 3 * n / 2, "read as one estimate: on");
    }

    /// A firefly in one estimate of the pair, on a clean flat surface the
    /// output has right: the colour is the pair's mean, so it holds half
    /// the firefly, and its noise must say so whichever estimate holds it.
    /// Taken as `(log M - log B)^2` alone, a firefly in `B` read as nearly
    /// noise-free (`log M` lies near `log B`) and the output went back to
    /// the mean, the firefly restored at half its height (the generator's
    /// 16-spp `test_0006`: a pixel of 0.11 back at 3.5).
    #[test]
    fn a_firefly_in_either_estimate_stays_out() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (24, 16);
        let n = w * h;
        let mut noisy = around_one(4242, 3 * n, 0.1);
        let (a0, b0) = (noisy(), noisy());
        let alb = vec![0.5f32; 3 * n];
        let at = 7 * w + 11;
        let mut outs = Vec::new();
        for firefly_in_b in [true, false] {
            let (mut a, mut b) = (a0.clone(), b0.clone());
            for c in 0..3 {
                if firefly_in_b {
                    b[c * n + at] = 40.0;
                } else {
                    a[c * n + at] = 40.0;
                }
            }
            let m: Vec<f32> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
            let mut o = vec![1.0f32; 3 * n];
            to_input(&mut ctx, &mut o, &m, Some(Pair { b: &b, colour_is_mean: true }), &alb, w, h, 1.0).unwrap();
            for c in 0..3 {
                let v = o[c * n + at];
                assert!(
                    (v - 1.0).abs() < 0.1,
                    "firefly in {}: the output went back to {v}",
                    if firefly_in_b { "B" } else { "A" }
                );
            }
            // Elsewhere the output stays within the input's noise of 1
            // (the stage is on: the frame is clean).
            assert!(o.iter().all(|&v| (v - 1.0).abs() <= 0.06), "elsewhere");
            assert!(o.iter().any(|&v| v != 1.0), "the test's premise: the stage moved some pixel");
            outs.push((0..3).map(|c| o[c * n + at]).collect::<Vec<f32>>());
        }
        assert_eq!(outs[0], outs[1], "the same output whichever estimate holds the firefly");
    }

    /// The pair's noise estimates against their definitions in f64, and
    /// their expectations (Monte Carlo over normal pairs, in f64) against
    /// the true variance of the colour, one estimate or the pair's mean.
    #[test]
    fn the_pairs_variance_has_the_colours_expectation() {
        for &(a, b) in &[(0.0f32, 0.0f32), (1.0, 0.5), (-2.0, 3.0), (1e-3, 2e-3), (7.5, 7.5)] {
            let d = a as f64 - b as f64;
            let one = Pair { b: &[], colour_is_mean: false };
            assert!((one.variance(a, b) as f64 - 0.5 * d * d).abs() <= 1e-6 * (1.0 + d * d), "{a} {b}");
            let (m, v) = one.mean_and_variance(a, b);
            assert!((m as f64 - 0.5 * (a as f64 + b as f64)).abs() <= 1e-6 * (1.0 + d.abs()));
            assert!((v as f64 - 0.25 * d * d).abs() <= 1e-6 * (1.0 + d * d));
            // The colour is the mean m = (a + b) / 2 of a and b.
            let mean = Pair { b: &[], colour_is_mean: true };
            let m = 0.5 * (a + b);
            let dm = m as f64 - b as f64;
            assert!((mean.variance(m, b) as f64 - dm * dm).abs() <= 1e-6 * (1.0 + d * d), "{a} {b}");
            assert_eq!(mean.mean_and_variance(m, b), (m, mean.variance(m, b)));
            // The spread on linear values is the same variance, either way.
            for (p, y) in [(one, a), (mean, m)] {
                let s = Pair::spread(y, p.first(y, b), b) as f64;
                let want = p.variance(y, b) as f64;
                assert!((s - want).abs() <= 1e-5 * (1.0 + d * d), "{a} {b}: {s} against {want}");
            }
            // Through log1p, the mean's spread is symmetric in A and B
            // (f64: the same sum of the two squared log differences).
            let l64 = |v: f64| v.max(0.0).ln_1p();
            let lm = l64(0.5 * (a as f64 + b as f64));
            let want = 0.5 * ((lm - l64(a as f64)).powi(2) + (lm - l64(b as f64)).powi(2));
            let l = |v: f32| v.max(0.0).ln_1p();
            let got = Pair::spread(l(m), l(mean.first(m, b)), l(b)) as f64;
            assert!((got - want).abs() <= 1e-4 * (1.0 + want), "{a} {b}: {got} against {want}");
        }
        // Normal pairs of standard deviation 0.3 around 1: one estimate's
        // variance is 0.09, the mean's 0.045.
        let mut normal = crate::methods::test_noise::normal(0x2545_f491_4f6c_dd1d);
        let (k, sd) = (200_000, 0.3);
        let (mut one_sum, mut mean_sum, mut joint_sum) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..k {
            let (a, b) = ((1.0 + sd * normal()) as f32, (1.0 + sd * normal()) as f32);
            one_sum += Pair { b: &[], colour_is_mean: false }.variance(a, b) as f64;
            joint_sum += Pair { b: &[], colour_is_mean: false }.mean_and_variance(a, b).1 as f64;
            mean_sum += Pair { b: &[], colour_is_mean: true }.variance(0.5 * (a + b), b) as f64;
        }
        let var = sd * sd;
        for (got, want, what) in [
            (one_sum, var, "one estimate"),
            (mean_sum, var / 2.0, "the mean"),
            (joint_sum, var / 2.0, "the pair's mean from one estimate"),
        ] {
            let got = got / k as f64;
            assert!((got / want - 1.0).abs() < 0.02, "{what}: {got} against {want}");
        }
    }

    /// The fade: on up to FADE_FROM, off from FADE_TO, linear between.
    #[test]
    fn fade_runs_from_on_to_off() {
        assert_eq!(fade(0.0), 0.0);
        assert_eq!(fade(FADE_FROM), 0.0);
        assert!((fade(0.5 * (FADE_FROM + FADE_TO)) - 0.5).abs() < 1e-6);
        assert_eq!(fade(FADE_TO), 1.0);
        assert_eq!(fade(1.0), 1.0);
    }

    /// The weight against the formula in f64.
    #[test]
    fn blend_weight_is_the_formula() {
        for &(v, e) in &[(1.0f32, 0.5f32), (1.0, 2.0), (1.0, 3.0), (0.1, 10.0), (0.0, 1.0), (0.0, 0.0), (2.0, 100.0)] {
            // The margin from 1 at no noise to 2 from NOISY on.
            for &(f, m) in &[(0.0f32, 1.0f64), (0.1, 1.1), (0.5, 1.5), (1.0, 2.0), (10.0, 2.0)] {
                let vbar = f * NOISY;
                let (v64, e64) = (v as f64, e as f64);
                let b = (e64 - m * v64).max(0.0);
                let k = if v64 + b > 0.0 { v64 / (v64 + b) } else { 1.0 };
                assert!((blend_weight(v, e, vbar) as f64 - k).abs() < 1e-6, "v {v} e {e} vbar {vbar}");
            }
        }
    }
}

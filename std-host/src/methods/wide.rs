//! The wide pass: an edge-avoiding à-trous filter (Dammertz et al. 2010)
//! over the learned filters' output, its colour gate set by the noise the
//! output has left where the temporal history is short.
//!
//! Without history (a sequence's first frame, a region a pan has just
//! uncovered, a light that moved and whose history is rejected) a 13x13
//! (WSKP) or 7x7-at-two-scales (AFN) kernel over 1-spp noise leaves
//! low-frequency blotches on flat walls, 10-20 pixels across
//! (`tools/blotch.py`, docs/quality.md). This pass filters the output
//! once more: [`LEVELS`] à-trous steps of the 3-tap B-spline
//! `(1/4, 1/2, 1/4)` (holes 1, 2, 4 and 8 pixels apart, a 31x31 reach),
//! each tap weighted by `exp(-t)`,
//!
//! ```text
//! t = |n_p - n_q|^2 / s_n^2 + |a_p - a_q|^2 / s_a^2
//!     + |z_p - z_q| / (s_z hole z_p) + |c_p - c_q|^2 / (v_p + v_q)
//! ```
//!
//! with `n` the normal, `a` the albedo, `z` the depth, `c` the output's
//! colour and `v` its residual noise variance. `v` starts as [`GATE`] times
//! the input's noise variance (its 7x7 window mean; from the pair where the
//! frame has one) over the pixel's history count, and is carried from
//! level to level with the squared normalised weights, as the
//! variance-guided à-trous filter of Schied et al. 2017 (SVGF) carries
//! its variance: where the history is long `v` is small and the gate
//! closes; where it is short the blotches, whose amplitude is a fraction of
//! the input's noise, are averaged over the surface, and shading, albedo
//! and geometry edges stop the filter.
//!
//! From level [`SYMMETRIC_FROM`] on (the fourth, holes 8 apart) the taps
//! are weighted in mirrored pairs: each tap and the tap opposite it through
//! the pixel take the larger `t` of the two. A bilateral weight follows
//! the noise: a pixel inside a bright blotch finds its like on the side
//! where the blotch goes on and keeps it; weighted in pairs, a tap counts
//! only as much as its opposite, so a blotch is averaged with both sides of
//! it, and a linear shading gradient (whose two sides differ from the pixel
//! alike) keeps its value. On the first three levels plain weights score
//! better (mirrored pairs on every level cost 0.2-0.5 dB on three of four
//! foreign first frames: near edges and texture a pair drops both taps
//! where one would do); the fourth level with plain weights did not pay
//! (docs/quality.md, "The fourth level" and "Blotches: noise and bias").
//!
//! Everything in exposure-normalised `log1p` colour, as the fallback
//! ([`crate::methods::fallback`]), so that `denoise(k x) = k denoise(x)`;
//! in f32 on the decoded output in every precision, before the fallback.

use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{Isa, View, ViewMut, F32};

use crate::error::Result;
use crate::io::frame::{Buffer, Frame};
use crate::methods::fallback::{positive_exposure, Noise};
use crate::methods::{Ctx, Timings};

/// À-trous levels (holes 1, 2, 4 and 8 pixels apart). With plain weights
/// four and five levels scored lower than three on the generator's `val`
/// scenes (docs/quality.md, "A wider reach"); the fourth is weighted in
/// mirrored pairs ([`SYMMETRIC_FROM`]).
pub const LEVELS: u32 = 4;
/// The first level (from 0) whose taps are weighted in mirrored pairs (see
/// the module).
pub const SYMMETRIC_FROM: u32 = 3;
/// The colour gate: a squared colour difference (summed over the
/// channels) is compared with this multiple of the two pixels' residual
/// noise variances' sum. Chosen on the generator's `val` scenes (8, 16
/// and 32 tried: 16 gains 0.0-0.3 dB over 8, 32 is within 0.05 dB of 16 on
/// average and blurs more).
pub const GATE: f32 = 16.0;
/// Normal difference scale.
pub const SIGMA_NORMAL: f32 = 0.3;
/// Albedo difference scale.
pub const SIGMA_ALBEDO: f32 = 0.2;
/// Relative depth difference scale, per pixel of hole spacing.
pub const SIGMA_DEPTH: f32 = 0.02;

/// The stage's name in plans.
pub const STAGE: &str = "wide pass (à-trous over the output where the history is short)";

/// Bytes per pixel of [`Buffers`], kept from frame to frame: two copies of
/// the colour and variance, the guides.
pub const KEPT_BYTES: u64 = 4 * 15;

/// The pass's buffers, kept from frame to frame (a frame's worth of fresh
/// pages each frame costs their page faults).
#[derive(Debug, Default)]
pub struct Buffers {
    a: Vec<f32>,
    b: Vec<f32>,
    g: Vec<f32>,
}

/// Records the stage in a method's plan: built, or skipped by
/// `--no-wide-pass` (replacing an earlier entry of either kind).
pub fn plan(plan: &mut crate::methods::Plan, on: bool) {
    plan.built.retain(|s| *s != STAGE);
    plan.skipped.retain(|(s, _)| *s != STAGE);
    if on {
        // Before the fallback to the input, which runs after it.
        let at = plan.built.iter().position(|s| s.starts_with("fallback to the input")).unwrap_or(plan.built.len());
        plan.built.insert(at, STAGE);
    } else {
        plan.skipped.push((STAGE, "--no-wide-pass".into()));
    }
}

/// The guides of the pass, each of `w x h` pixels: albedo and normal (3
/// planes), depth (1 plane).
#[derive(Clone, Copy, Debug)]
pub struct Guides<'a> {
    /// The albedo.
    pub albedo: &'a [f32],
    /// The world-space normal.
    pub normal: &'a [f32],
    /// The depth.
    pub depth: &'a [f32],
}

impl<'a> Guides<'a> {
    /// The frame's albedo, normal and depth; a missing one is an error
    /// naming the buffer and `who` (the method).
    pub fn of(f: &'a Frame, who: &str) -> Result<Guides<'a>> {
        Ok(Guides {
            albedo: f.require(Buffer::Albedo, who)?,
            normal: f.require(Buffer::Normal, who)?,
            depth: f.require(Buffer::Depth, who)?,
        })
    }
}

/// The edge-stopping scales.
#[derive(Clone, Copy, Debug)]
struct Stops {
    normal: f32,
    albedo: f32,
    depth: f32,
}

/// The tail WSKP and AFN share after their filters: the input's noise,
/// computed once ([`Noise`]), then the wide pass over `out` (where `wide`
/// gives its buffers and the history counts) and the fallback to the input
/// (where `fallback`), each timed as its own stage. `who`, the method,
/// names a missing buffer.
#[allow(clippy::too_many_arguments)]
pub fn finish(
    ctx: &mut Ctx,
    t: &mut Timings,
    out: &mut [f32],
    f: &Frame,
    who: &str,
    wide: Option<(&mut Buffers, &[f32])>,
    fallback: bool,
    exposure: f32,
) -> Result<()> {
    if wide.is_none() && !fallback {
        return Ok(());
    }
    let (w, h) = (f.width, f.height);
    let colour = f.require(Buffer::Color, who)?;
    let pair = f.pair();
    let noise = t.time(NOISE_STAGE, || Noise::of(ctx, colour, pair, w, h, exposure))?;
    if let Some((bufs, counts)) = wide {
        let guides = Guides::of(f, who)?;
        t.time("wide pass", || pass(ctx, bufs, out, noise.means(), counts, guides, w, h, exposure))?;
    }
    if fallback {
        let albedo = f.require(Buffer::Albedo, who)?;
        t.time("fallback", || {
            crate::methods::fallback::to_input_with(ctx, out, colour, noise, pair, albedo, w, h, exposure)
        })?;
    }
    Ok(())
}

/// The `--timings` stage of [`finish`]'s noise estimate.
pub const NOISE_STAGE: &str = "input noise (wide pass, fallback)";

/// Records [`finish`]'s allocations in a method's ledger: the noise (kept
/// through both stages), the pass's buffers if `wide` (`wide_first` bytes
/// a pixel allocated now: on the first frame), the fallback's own (counted
/// whether or not it runs: an upper bound).
pub fn ledger(l: &mut crate::runtime::memory::Ledger, wide: bool, wide_first: u64) {
    use crate::methods::fallback::{NOISE_BYTES, NOISE_PEAK_BYTES, WITH_TEMP_BYTES};
    l.temp(NOISE_PEAK_BYTES).alloc(NOISE_BYTES);
    if wide {
        l.alloc(wide_first);
    }
    l.temp(WITH_TEMP_BYTES).free(NOISE_BYTES);
}

/// Filters the output `o` (3 planes of `w x h`, linear) in place (see the
/// module). `v`: the frame's colour's noise variance, its 7x7 window mean
/// per pixel ([`Noise::means`], at the same `exposure`), which over
/// `counts` (the history count per pixel, 1 plane; a count under 1 counts
/// as 1) is the output's residual noise estimate.
#[allow(clippy::too_many_arguments)]
pub fn pass(
    ctx: &mut Ctx,
    bufs: &mut Buffers,
    o: &mut [f32],
    v: &[f32],
    counts: &[f32],
    guides: Guides<'_>,
    w: usize,
    h: usize,
    exposure: f32,
) -> Result<()> {
    let n = w * h;
    if n == 0 {
        return Ok(());
    }
    if v.len() != n || counts.len() != n || o.len() < 3 * n {
        return Err(crate::error::HostError::Kernel(format!(
            "wide pass: {} noise values, {} counts and {} outputs for {n} pixels",
            v.len(),
            counts.len(),
            o.len()
        )));
    }
    let e = positive_exposure(exposure);
    const RUN: usize = 1 << 14;
    let st = Stops { normal: SIGMA_NORMAL, albedo: SIGMA_ALBEDO, depth: SIGMA_DEPTH };
    let fin = |v: f32| if v.is_finite() { v } else { 0.0 };
    let isa = ctx.isa;
    // Planes: colour (3) and residual variance in `a`; albedo (3), normal
    // (3) and depth in `g`.
    // (Every value of the three is written below before it is read.)
    bufs.a.resize(4 * n, 0.0);
    bufs.b.resize(4 * n, 0.0);
    bufs.g.resize(7 * n, 0.0);
    let Buffers { a, b, g } = bufs;
    let (mut a, mut b) = (a, b);
    {
        let o: &[f32] = o;
        // (The core's SIMD `log1p`, through `b`.)
        ctx.pool.planes(vec![&mut b[..3 * n]], RUN, |start, runs| {
            for (d, &s) in runs[0].iter_mut().zip(&o[start..]) {
                *d = fin(e * s);
            }
        });
        let (ac, av) = a.split_at_mut(3 * n);
        tonemap::map::<F32>(isa, Map::Log1p, &View::new(&b[..3 * n], 3, w, h)?, &mut ViewMut::new(ac, 3, w, h)?)?;
        ctx.pool.planes(vec![av], RUN, |start, runs| {
            for ((d, &v), &c) in runs[0].iter_mut().zip(&v[start..]).zip(&counts[start..]) {
                let c = if c.is_finite() { c.max(1.0) } else { 1.0 };
                *d = GATE * v / c;
            }
        });
        let (ga, gn) = g.split_at_mut(3 * n);
        let (gn, gz) = gn.split_at_mut(3 * n);
        let gd = guides;
        ctx.pool.planes(vec![ga, gn], RUN, |start, runs| {
            for (k, run) in runs.iter_mut().enumerate() {
                let src = if k == 0 { gd.albedo } else { gd.normal };
                for (d, &s) in run.iter_mut().zip(&src[start..]) {
                    *d = fin(s);
                }
            }
        });
        ctx.pool.planes(vec![gz], RUN, |start, runs| {
            for (d, &s) in runs[0].iter_mut().zip(&gd.depth[start..]) {
                *d = fin(s).max(0.0);
            }
        });
    }
    let inv =
        Stops { normal: 1.0 / (st.normal * st.normal), albedo: 1.0 / (st.albedo * st.albedo), depth: 1.0 / st.depth };
    for level in 0..LEVELS {
        let (src, g): (&[f32], &[f32]) = (a, g);
        let rows: Vec<(usize, &mut [f32])> = b.chunks_mut(w).enumerate().collect();
        // Row r of plane k is chunk k h + r: one job per row, its four planes.
        let mut by_row: Vec<Vec<&mut [f32]>> = (0..h).map(|_| Vec::with_capacity(4)).collect();
        for (r, row) in rows {
            by_row[r % h].push(row);
        }
        ctx.pool.install(|| {
            use rayon::prelude::*;
            by_row.into_par_iter().enumerate().with_min_len(4).for_each(|(y, mut out)| {
                // SAFETY: `ctx.isa` is one this CPU has (checked when the
                // context was made).
                unsafe {
                    step_row_on(
                        isa,
                        &Step { src, g, inv: &inv, w, h, s: 1 << level, sym: level >= SYMMETRIC_FROM },
                        y,
                        &mut out,
                    )
                }
            });
        });
        std::mem::swap(&mut a, &mut b);
    }
    tonemap::map::<F32>(
        isa,
        Map::Expm1,
        &View::new(&a[..3 * n], 3, w, h)?,
        &mut ViewMut::new(&mut b[..3 * n], 3, w, h)?,
    )?;
    let b: &[f32] = b;
    ctx.pool.planes(o[..3 * n].chunks_mut(n).collect(), RUN, |start, runs| {
        for (c, run) in runs.iter_mut().enumerate() {
            for (j, ov) in run.iter_mut().enumerate() {
                let r = b[c * n + start + j] / e;
                if r.is_finite() {
                    *ov = r.max(0.0);
                }
            }
        }
    });
    Ok(())
}

/// Pixels a block of [`step_row`] holds in registers: one AVX2 register
/// of f32 a plane (AVX-512 builds take 16).
const LANES: usize = 8;

/// One à-trous step `st` ([`Step`]) of row `y` into `out` (the row of each
/// of the 4 planes: colour, residual variance). The row's inner pixels in
/// blocks of `LANES`, every tap of a block summed in registers
/// (the loop over the block's pixels vectorises); the pixels within `s` of
/// the row's ends one by one, their taps outside the image left out.
#[inline(always)]
fn step_row<const LANES: usize>(st: &Step<'_>, y: usize, out: &mut [&mut [f32]]) {
    let &Step { src, g, inv, w, h, s, sym } = st;
    let n = w * h;
    let zs = inv.depth / s as f32;
    // The 11 planes (colour 3, variance, albedo 3, normal 3, depth) of row yy.
    let planes = |yy: usize| -> [&[f32]; 11] {
        core::array::from_fn(|k| {
            let (v, k) = if k < 4 { (src, k) } else { (g, k - 4) };
            &v[k * n + yy * w..k * n + yy * w + w]
        })
    };
    let p = planes(y);
    // (The row tap's weight and the row's planes, for the rows inside.)
    type Row<'a> = Option<(f32, [&'a [f32]; 11])>;
    let rows: [Row<'_>; 3] = core::array::from_fn(|dy| {
        let qy = y as isize + (dy as isize - 1) * s as isize;
        (qy >= 0 && qy < h as isize).then(|| (TAPS[dy], planes(qy as usize)))
    });
    // The weight's exponent between pixel values `a` and tap values `b`
    // (the 11 planes' values at each).
    #[inline(always)]
    fn exponent(a: [f32; 11], b: [f32; 11], inv: &Stops, zs: f32) -> f32 {
        let sq3 = |k: usize| (a[k] - b[k]).powi(2) + (a[k + 1] - b[k + 1]).powi(2) + (a[k + 2] - b[k + 2]).powi(2);
        sq3(7) * inv.normal
            + sq3(4) * inv.albedo
            + (a[10] - b[10]).abs() * zs / a[10].max(1e-3)
            + sq3(0) / (a[3] + b[3] + 1e-12)
    }
    let write = |out: &mut [&mut [f32]], x: usize, acc: [f32; 5]| {
        let r = 1.0 / acc[3];
        out[0][x] = acc[0] * r;
        out[1][x] = acc[1] * r;
        out[2][x] = acc[2] * r;
        out[3][x] = acc[4] * r * r;
    };
    // One pixel (near the row's ends: the taps outside the image left out).
    let pixel = |x: usize| -> [f32; 5] {
        let a: [f32; 11] = core::array::from_fn(|k| p[k][x]);
        // Each tap's exponent (`None`: outside the image; the centre's 0).
        let mut t = [[None; 3]; 3];
        for (dy, row) in rows.iter().enumerate() {
            let Some((_, q)) = row else { continue };
            for (dx, td) in t[dy].iter_mut().enumerate() {
                let qx = x as isize + (dx as isize - 1) * s as isize;
                if (0..w as isize).contains(&qx) {
                    let b: [f32; 11] = core::array::from_fn(|k| q[k][qx as usize]);
                    *td = Some(if dy == 1 && dx == 1 { 0.0 } else { exponent(a, b, inv, zs) });
                }
            }
        }
        let mut acc = [0.0f32; 5];
        for (dy, row) in rows.iter().enumerate() {
            let Some((hy, q)) = row else { continue };
            for (dx, &hx) in TAPS.iter().enumerate() {
                let Some(own) = t[dy][dx] else { continue };
                let qx = (x as isize + (dx as isize - 1) * s as isize) as usize;
                let e = match t[2 - dy][2 - dx] {
                    Some(m) if sym => own.max(m),
                    _ => own,
                };
                let wt = if dy == 1 && dx == 1 { hy * hx } else { hy * hx * mcdenoise_core::exp_select(-e) };
                acc[0] += wt * q[0][qx];
                acc[1] += wt * q[1][qx];
                acc[2] += wt * q[2][qx];
                acc[3] += wt;
                acc[4] += wt * wt * q[3][qx];
            }
        }
        acc
    };
    let (lo, hi) = (s.min(w), w.saturating_sub(s).max(s.min(w)));
    for x in 0..lo {
        write(out, x, pixel(x));
    }
    let mut x = lo;
    while x + LANES <= hi {
        let block = |v: &[f32], at: usize| -> [f32; LANES] { v[at..at + LANES].try_into().expect("LANES values") };
        let pa: [[f32; LANES]; 11] = core::array::from_fn(|k| block(p[k], x));
        // Every tap's exponent per pixel of the block (the block's taps
        // are inside the image across; a row outside it has none).
        let mut t = [[[0.0f32; LANES]; 3]; 3];
        for (dy, row) in rows.iter().enumerate() {
            let Some((_, q)) = row else { continue };
            for (dx, td) in t[dy].iter_mut().enumerate() {
                if dy == 1 && dx == 1 {
                    continue;
                }
                let at = (x as isize + (dx as isize - 1) * s as isize) as usize;
                let qb: [[f32; LANES]; 11] = core::array::from_fn(|k| block(q[k], at));
                for (l, tl) in td.iter_mut().enumerate() {
                    let a: [f32; 11] = core::array::from_fn(|k| pa[k][l]);
                    let b: [f32; 11] = core::array::from_fn(|k| qb[k][l]);
                    *tl = exponent(a, b, inv, zs);
                }
            }
        }
        if sym {
            // Each mirrored pair of taps inside the image takes the larger
            // exponent of the two.
            for (dy, dx) in [(0usize, 0usize), (0, 1), (0, 2), (1, 0)] {
                if rows[dy].is_some() && rows[2 - dy].is_some() {
                    let (a, b) = (t[dy][dx], t[2 - dy][2 - dx]);
                    let m: [f32; LANES] = core::array::from_fn(|l| a[l].max(b[l]));
                    t[dy][dx] = m;
                    t[2 - dy][2 - dx] = m;
                }
            }
        }
        let mut acc = [[0.0f32; LANES]; 5];
        for (dy, row) in rows.iter().enumerate() {
            let Some((hy, q)) = row else { continue };
            for (dx, &hx) in TAPS.iter().enumerate() {
                let at = (x as isize + (dx as isize - 1) * s as isize) as usize;
                let qb: [[f32; LANES]; 4] = core::array::from_fn(|k| block(q[k], at));
                let hw = hy * hx;
                let centre = dy == 1 && dx == 1;
                for l in 0..LANES {
                    let wt = if centre { hw } else { hw * mcdenoise_core::exp_select(-t[dy][dx][l]) };
                    acc[0][l] += wt * qb[0][l];
                    acc[1][l] += wt * qb[1][l];
                    acc[2][l] += wt * qb[2][l];
                    acc[3][l] += wt;
                    acc[4][l] += wt * wt * qb[3][l];
                }
            }
        }
        for (l, xl) in (x..x + LANES).enumerate() {
            write(out, xl, core::array::from_fn(|k| acc[k][l]));
        }
        x += LANES;
    }
    for x in x..w {
        write(out, x, pixel(x));
    }
}

/// The arguments of one à-trous step over the planes `src` (colour,
/// residual variance) guided by the planes `g` (albedo, normal, depth),
/// each `w x h`; `inv` holds the stops' inverse squares (the depth's
/// inverse); `s` the hole; `sym`: the taps weighted in mirrored pairs
/// ([`SYMMETRIC_FROM`]).
struct Step<'a> {
    src: &'a [f32],
    g: &'a [f32],
    inv: &'a Stops,
    w: usize,
    h: usize,
    s: usize,
    sym: bool,
}

/// [`step_row`] in the build for `isa`: blocks of 8 pixels on AVX2, 16
/// on AVX-512.
///
/// # Safety
///
/// `isa` must be one this CPU has ([`Isa::check`]).
unsafe fn step_row_on(isa: Isa, st: &Step<'_>, y: usize, out: &mut [&mut [f32]]) {
    #[cfg(target_arch = "x86_64")]
    match isa {
        // SAFETY: the caller's `isa` is one this CPU has.
        Isa::Avx512 => unsafe { step_row_avx512(st, y, out) },
        // SAFETY: as above (AVX2 and FMA).
        Isa::Avx2 => unsafe { step_row_avx2(st, y, out) },
        Isa::Scalar => step_row::<LANES>(st, y, out),
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = isa;
        step_row::<LANES>(st, y, out)
    }
}

/// [`step_row`] compiled for AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn step_row_avx2(st: &Step<'_>, y: usize, out: &mut [&mut [f32]]) {
    step_row::<LANES>(st, y, out)
}

/// [`step_row`] compiled for AVX-512, on blocks of 16 pixels.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn step_row_avx512(st: &Step<'_>, y: usize, out: &mut [&mut [f32]]) {
    step_row::<16>(st, y, out)
}

/// The 3-tap B-spline of one à-trous step.
const TAPS: [f32; 3] = [0.25, 0.5, 0.25];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::test_noise::lcg;

    /// One step of the pass at pixel `(x, y)` straight from its
    /// definition, in f64: the 3x3 B-spline taps `s` pixels apart inside the
    /// image, each weighted by `exp(-t)` of the guides' and the colours'
    /// differences (the centre by its tap alone; with `sym`, a tap whose
    /// opposite through the pixel is inside the image by the larger `t` of
    /// the two); the colour and the variance (squared normalised weights)
    /// out.
    #[allow(clippy::too_many_arguments)]
    fn oracle(
        src: &[f32],
        g: &[f32],
        st: &Stops,
        w: usize,
        h: usize,
        x: usize,
        y: usize,
        s: usize,
        sym: bool,
    ) -> [f64; 4] {
        let n = w * h;
        let at = |v: &[f32], k: usize, p: usize| v[k * n + p] as f64;
        let p = y * w + x;
        let inside = |dx: i64, dy: i64| -> Option<usize> {
            let (qx, qy) = (x as i64 + dx * s as i64, y as i64 + dy * s as i64);
            (qx >= 0 && qy >= 0 && qx < w as i64 && qy < h as i64).then(|| qy as usize * w + qx as usize)
        };
        let t = |q: usize| -> f64 {
            let d2 = |k0: usize, v: &[f32]| (k0..k0 + 3).map(|k| (at(v, k, p) - at(v, k, q)).powi(2)).sum::<f64>();
            d2(3, g) / (st.normal as f64).powi(2)
                + d2(0, g) / (st.albedo as f64).powi(2)
                + (at(g, 6, p) - at(g, 6, q)).abs() / (st.depth as f64 * s as f64 * at(g, 6, p).max(1e-3))
                + d2(0, src) / (at(src, 3, p) + at(src, 3, q) + 1e-12)
        };
        let (mut acc, mut ws, mut vs) = ([0.0f64; 3], 0.0f64, 0.0f64);
        for dy in -1i64..=1 {
            for dx in -1i64..=1 {
                let Some(q) = inside(dx, dy) else { continue };
                let tap = [0.25, 0.5, 0.25][(dy + 1) as usize] * [0.25, 0.5, 0.25][(dx + 1) as usize];
                let mut wt = tap;
                if q != p {
                    let own = t(q);
                    let e = match inside(-dx, -dy) {
                        Some(m) if sym => own.max(t(m)),
                        _ => own,
                    };
                    wt *= (-e).exp();
                }
                for (k, a) in acc.iter_mut().enumerate() {
                    *a += wt * at(src, k, q);
                }
                ws += wt;
                vs += wt * wt * at(src, 3, q);
            }
        }
        [acc[0] / ws, acc[1] / ws, acc[2] / ws, vs / (ws * ws)]
    }

    /// Every row of a step through [`step_row`] (and its builds for AVX2 and
    /// AVX-512 where this CPU has them) against the f64 oracle, at holes 1,
    /// 2, 4 and 8, with plain weights and in mirrored pairs (blocks of 8 and
    /// 16 pixels, the rows' ends, rows whose taps leave the image; 19 rows,
    /// so that at hole 8 the middle three pair every tap) on a
    /// small random image whose guides differ from pixel to pixel by about
    /// their stops (so that the weights spread over their range).
    #[test]
    fn a_step_matches_an_f64_oracle() {
        let (w, h) = (43, 19);
        let n = w * h;
        let mut s = 7u32;
        let mut src: Vec<f32> = (0..4 * n).map(|_| lcg(&mut s)).collect();
        for v in &mut src[3 * n..] {
            *v = 0.05 + 0.2 * *v;
        }
        let mut g: Vec<f32> = (0..7 * n).map(|_| lcg(&mut s) * 0.3).collect();
        for v in &mut g[6 * n..] {
            *v += 1.0;
        }
        let st = Stops { normal: SIGMA_NORMAL, albedo: SIGMA_ALBEDO, depth: SIGMA_DEPTH };
        let inv = Stops {
            normal: 1.0 / (st.normal * st.normal),
            albedo: 1.0 / (st.albedo * st.albedo),
            depth: 1.0 / st.depth,
        };
        // Every build this CPU runs: scalar, AVX2 (blocks of 8), AVX-512 (16).
        let paths: Vec<Isa> = Isa::ALL.iter().copied().filter(|i| i.check().is_ok()).collect();
        let mut spread = (f64::MAX, 0.0f64);
        for isa in paths {
            for (s, sym) in [(1usize, false), (2, false), (4, false), (8, false), (1, true), (4, true), (8, true)] {
                let mut out = vec![0.0f32; 4 * w];
                for y in 0..h {
                    let mut rows: Vec<&mut [f32]> = out.chunks_mut(w).collect();
                    // SAFETY: `paths` holds the ISAs this CPU has.
                    unsafe { step_row_on(isa, &Step { src: &src, g: &g, inv: &inv, w, h, s, sym }, y, &mut rows) };
                    for x in 0..w {
                        let want = oracle(&src, &g, &st, w, h, x, y, s, sym);
                        for k in 0..4 {
                            let got = out[k * w + x] as f64;
                            assert!(
                                (got - want[k]).abs() <= 2e-5 * want[k].abs().max(1e-2),
                                "{isa:?}, hole {s}, pairs {sym}, pixel ({x}, {y}), plane {k}: {got} against {}",
                                want[k]
                            );
                        }
                        // How far the step moved the pixel: the weights are not all 0 or 1.
                        let moved = (want[0] - src[y * w + x] as f64).abs();
                        spread = (spread.0.min(moved), spread.1.max(moved));
                    }
                }
            }
        }
        assert!(spread.1 > 0.05 && spread.0 < 0.01, "the test's weights spread: {spread:?}");
    }

    /// A scene of two walls meeting at a vertical edge (other normal, other
    /// albedo, other shading): the output carries 10 % blotches (a smooth
    /// random field), the input 1-spp noise. Returns (output, input,
    /// albedo, normal, depth, the output's blotch field).
    #[allow(clippy::type_complexity)]
    fn two_walls(w: usize, h: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let n = w * h;
        let mut s = 99u32;
        let left = |i: usize| (i % w) < w / 2;
        // Blotches: white noise box-filtered twice over 5x5, scaled to +-10 %.
        let mut f: Vec<f32> = (0..n).map(|_| lcg(&mut s) - 0.5).collect();
        for _ in 0..2 {
            crate::methods::features::box_sum(&mut f, w, h, 2);
        }
        let m = f.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let base = |i: usize| if left(i) { 0.5 } else { 0.2 };
        let o: Vec<f32> = (0..3 * n).map(|k| base(k % n) * (1.0 + 0.1 * f[k % n] / m)).collect();
        let y: Vec<f32> = (0..3 * n).map(|k| base(k % n) * 2.0 * lcg(&mut s)).collect();
        let albedo: Vec<f32> = (0..3 * n).map(|k| if left(k % n) { 0.7 } else { 0.3 }).collect();
        let normal: Vec<f32> = (0..3 * n)
            .map(|k| match (k / n, left(k % n)) {
                (2, true) | (0, false) => 1.0,
                _ => 0.0,
            })
            .collect();
        let depth = vec![2.0f32; n];
        (o, y, albedo, normal, depth)
    }

    /// Standard deviation of `log(v)` over the pixels `keep` selects (plane 0).
    fn log_sd(v: &[f32], keep: impl Fn(usize) -> bool, n: usize) -> f64 {
        let l: Vec<f64> = (0..n).filter(|&i| keep(i)).map(|i| (v[i] as f64).ln()).collect();
        let m = l.iter().sum::<f64>() / l.len() as f64;
        (l.iter().map(|x| (x - m).powi(2)).sum::<f64>() / l.len() as f64).sqrt()
    }

    /// Without history the blotches on each wall shrink by more than a quarter
    /// while the edge between the walls stays where it was (each wall's
    /// column beside it keeps its level within 2 %); with a long history
    /// the output moves by under 1.5 % (and a quarter of what it moves
    /// without); scaling the frame by `k` (and the
    /// exposure by `1 / k`) scales the result by `k`.
    #[test]
    fn blotches_without_history_go_and_an_edge_stays() {
        let mut ctx = crate::methods::context(&crate::methods::Settings::default()).unwrap();
        let (w, h) = (48, 32);
        let n = w * h;
        let (o, y, albedo, normal, depth) = two_walls(w, h);
        let guides = Guides { albedo: &albedo, normal: &normal, depth: &depth };
        let walls = [4..w / 2 - 4, w / 2 + 4..w - 4];
        let run = |ctx: &mut Ctx, o: &[f32], y: &[f32], count: f32, e: f32| {
            let mut r = o.to_vec();
            let noise = Noise::of(ctx, y, None, w, h, e).unwrap();
            pass(ctx, &mut Buffers::default(), &mut r, noise.means(), &vec![count; n], guides, w, h, e).unwrap();
            r
        };
        let short = run(&mut ctx, &o, &y, 1.0, 1.0);
        for (k, wall) in walls.iter().enumerate() {
            let inside = |i: usize| wall.contains(&(i % w));
            let (before, after) = (log_sd(&o, inside, n), log_sd(&short, inside, n));
            assert!(after < 0.75 * before, "wall {k}'s blotches: log sd {before:.4} -> {after:.4}");
        }
        for (x, level) in [(w / 2 - 1, 0.5f64), (w / 2, 0.2)] {
            let col: f64 = (0..h).map(|yy| short[yy * w + x] as f64).sum::<f64>() / h as f64;
            let was: f64 = (0..h).map(|yy| o[yy * w + x] as f64).sum::<f64>() / h as f64;
            assert!((col / was - 1.0).abs() < 0.02, "column {x} beside the edge: {was} -> {col} (level {level})");
        }
        let long = run(&mut ctx, &o, &y, 1e4, 1.0);
        let moved = |r: &[f32]| r.iter().zip(&o).map(|(a, b)| (a / b - 1.0).abs()).fold(0.0f32, f32::max);
        let (worst, without) = (moved(&long), moved(&short));
        assert!(worst < 0.015 && worst < without / 4.0, "a long history: moved by {worst} (without: {without})");
        for k in [1.0f32 / 64.0, 64.0] {
            let (ok, yk): (Vec<f32>, Vec<f32>) = (o.iter().map(|v| v * k).collect(), y.iter().map(|v| v * k).collect());
            let scaled = run(&mut ctx, &ok, &yk, 1.0, 1.0 / k);
            let worst = scaled.iter().zip(&short).map(|(a, b)| (a / (k * b) - 1.0).abs()).fold(0.0f32, f32::max);
            assert!(worst < 1e-4, "scaled by {k}: off by {worst}");
        }
    }
}

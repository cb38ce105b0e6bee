//! The buffers a sequence keeps, and the first pass over a frame:
//! demodulation and, with a second estimate, the mean, half-difference and
//! raw noise of the pair.

use super::{LEVELS, SURE_SAFETY_PAIR};

/// `H = (A - B) / 2` times the square root of the pair's SURE safety factor
/// (so its detail energy, SURE's noise term, comes out times the factor).
const SURE_H_SCALE: f32 = 0.5 * 8.0;
const _: () = assert!(SURE_SAFETY_PAIR == 64.0); // SURE_H_SCALE = 0.5 sqrt(64)
use crate::methods::Ctx;
use crate::runtime::aligned::Aligned;
use crate::runtime::precision::Planes;

/// Buffers kept across the frames of a sequence. Once warm, an f32 run
/// allocates no image-sized buffer per frame besides its output (the guides
/// and level-0 images are the frame's own data): about 2 KB of bookkeeping
/// (band lists, the thread pool's jobs). The other precisions store the
/// guides and the level-0 images anew each frame (about 35 bytes a pixel
/// for f16). `tests/tests/load.rs` measures both and holds f32 to it.
pub(super) struct Bufs<T: bytemuck::Pod> {
    pub(super) n: usize,
    /// Level-0 images in f32: `[M]`, `[M, H]` or `[A, variance]`.
    pub(super) c0: Aligned<f32>,
    /// Raw and smoothed noise variance.
    pub(super) noise_raw: Aligned<f32>,
    pub(super) noise: Aligned<f32>,
    pub(super) zeros: Aligned<f32>,
    /// Level outputs, alternating (`atrous`).
    pub(super) ping: Planes<T>,
    pub(super) pong: Planes<T>,
    /// Every level's output (`sure-atrous`: the shrinkage reads them all in
    /// one pass after the levels).
    pub(super) levels: Vec<Planes<T>>,
    pub(super) out: Aligned<f32>,
    /// The firefly clamp's demodulated, clamped estimates (`A`, and `B` with
    /// a pair), then its luminance and factor planes; empty when it is off.
    pub(super) clamp: Aligned<f32>,
    /// The demodulation factor ([`crate::methods::features`]), 3 planes;
    /// empty without albedo.
    pub(super) demod: Vec<f32>,
}

impl<T: bytemuck::Pod + Default> Bufs<T> {
    pub(super) fn new(w: usize, h: usize, nsrc: usize, nout: usize, sure: bool, clamp_planes: usize) -> Self {
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
            clamp: Aligned::zeroed(clamp_planes * n),
            demod: Vec::new(),
        }
    }
}

/// Pixels per job of the per-pixel passes.
pub(super) const RUN: usize = 1 << 14;

/// Demodulates `a` (and `b`) and forms the level-0 images: with `b`, the
/// mean `M` (and, for `half_diff`, `H = (A - B) / 2`) and the raw noise
/// `|A - B|^2 / 12` (the variance of `M`, mean over channels); without it,
/// `A` itself.
#[allow(clippy::too_many_arguments)]
pub(super) fn prepare(
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
                            h[i] = SURE_H_SCALE * (ai - bi);
                        }
                        let d = ai - bi;
                        nz[i] += d * d;
                    };
                    match albedo {
                        Some(al) => {
                            for i in 0..len {
                                let q = demod_factor(al, n, c, s + i);
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
                            for (i, (o, &v)) in im.iter_mut().zip(ac).enumerate() {
                                *o = v / demod_factor(al, n, c, s + i);
                            }
                        }
                        None => im.copy_from_slice(ac),
                    }
                }
            }
        }
    });
}

pub(super) use crate::methods::features::is_emitter;

/// What channel `c` of pixel `i` is demodulated by: the factor `d` of
/// [`crate::methods::features`].
#[inline]
pub(super) fn demod_factor(d: &[f32], n: usize, c: usize, i: usize) -> f32 {
    d[c * n + i]
}

/// The firefly clamp, in place on the 3 demodulated planes of `img` (`w x
/// h`), demodulated from `radiance`: a pixel whose luminance (mean of the
/// channels of `radiance`) `L` exceeds `T = m + k s`, with
/// `m` and `s` the mean and standard deviation of its 5x5 neighbours (the
/// centre left out, the window clipped at the border), is scaled by `T / L`
/// (its colour kept). Emitters ([`crate::methods::features::is_emitter`]) are
/// left alone (they are filtered as radiance). The test is on radiance,
/// not on the demodulated values, because a pixel straddling a light's
/// edge has a small albedo and so a demodulated value far above its
/// neighbours' while its radiance is not (clamping it darkened the light's
/// outline). `scratch` holds 4
/// planes of `w h` floats: the luminance, the factor and the two row sums
/// of the separable window sums.
#[allow(clippy::too_many_arguments)]
pub(super) fn firefly_clamp(
    ctx: &Ctx,
    img: &mut [f32],
    radiance: &[f32],
    albedo: Option<&[f32]>,
    scratch: &mut [f32],
    w: usize,
    h: usize,
    k: f32,
) {
    let n = w * h;
    if n == 0 {
        return;
    }
    let (lum, rest) = scratch.split_at_mut(n);
    let (fac, rest) = rest.split_at_mut(n);
    let (rs1, rest) = rest.split_at_mut(n);
    let rs2 = &mut rest[..n];
    ctx.pool.planes(vec![&mut *lum], RUN, |s, runs| {
        for (j, l) in runs[0].iter_mut().enumerate() {
            let i = s + j;
            *l = (radiance[i] + radiance[n + i] + radiance[2 * n + i]) / 3.0;
        }
    });
    {
        // Row sums of L and L^2 over the 5 columns around each pixel.
        let lum = &*lum;
        ctx.pool.planes(vec![&mut *rs1, &mut *rs2], w * 16, |s, runs| {
            let (r1, r2) = runs.split_at_mut(1);
            let (r1, r2) = (&mut *r1[0], &mut *r2[0]);
            for (row, (o1, o2)) in r1.chunks_mut(w).zip(r2.chunks_mut(w)).enumerate() {
                let l = &lum[s + row * w..s + row * w + w];
                for x in 0..w {
                    let (mut a, mut b) = (0.0f64, 0.0f64);
                    for &v in &l[x.saturating_sub(2)..(x + 3).min(w)] {
                        a += v as f64;
                        b += v as f64 * v as f64;
                    }
                    o1[x] = a as f32;
                    o2[x] = b as f32;
                }
            }
        });
    }
    {
        let (lum, rs1, rs2) = (&*lum, &*rs1, &*rs2);
        ctx.pool.planes(vec![&mut *fac], w * 16, |s, runs| {
            for (j, f) in runs[0].iter_mut().enumerate() {
                let i = s + j;
                let (y, x) = (i / w, i % w);
                let li = lum[i];
                *f = 1.0;
                if li.is_nan() || li <= 0.0 || albedo.is_some_and(|a| is_emitter(a, n, i)) {
                    continue;
                }
                let (y0, y1) = (y.saturating_sub(2), (y + 3).min(h));
                let cols = ((x + 3).min(w) - x.saturating_sub(2)) as f64;
                let (mut s1, mut s2) = (0.0f64, 0.0f64);
                for yy in y0..y1 {
                    s1 += rs1[yy * w + x] as f64;
                    s2 += rs2[yy * w + x] as f64;
                }
                // The centre left out.
                let cnt = cols * (y1 - y0) as f64 - 1.0;
                if cnt < 1.0 {
                    continue;
                }
                let (s1, s2) = (s1 - li as f64, s2 - li as f64 * li as f64);
                let m = s1 / cnt;
                let sd = (s2 / cnt - m * m).max(0.0).sqrt();
                let t = m + k as f64 * sd;
                if (li as f64) > t {
                    *f = (t.max(0.0) / li as f64) as f32;
                }
            }
        });
    }
    let fac = &*fac;
    ctx.pool.planes(img.chunks_mut(n).take(3).collect(), RUN, |s, runs| {
        for r in runs.iter_mut() {
            for (v, &f) in r.iter_mut().zip(&fac[s..]) {
                *v *= f;
            }
        }
    });
}

/// Demodulates `src` (3 planes) by `albedo + eps` into `dst` (a copy without albedo).
pub(super) fn demodulate(ctx: &Ctx, src: &[f32], albedo: Option<&[f32]>, dst: &mut [f32]) {
    ctx.pool.planes(dst.chunks_mut(src.len() / 3).take(3).collect(), RUN, |s, runs| {
        let n = src.len() / 3;
        for (c, r) in runs.iter_mut().enumerate() {
            let len = r.len();
            let a = &src[c * n + s..c * n + s + len];
            match albedo {
                Some(al) => {
                    for (i, (o, &v)) in r.iter_mut().zip(a).enumerate() {
                        *o = v / demod_factor(al, n, c, s + i);
                    }
                }
                None => r.copy_from_slice(a),
            }
        }
    });
}

//! AVX-512 convolution: the AVX2 scheme ([`super::avx2`]) at sixteen lanes.
//! Output channels go in blocks of at most seven; a block times 32 pixels
//! lives in fourteen accumulators while every input channel and tap streams
//! past. The first and last columns of a row run as masked 16-lane blocks
//! whose outside taps load as 0 (the zero padding), so no column falls back
//! to the scalar pixel (at 128 columns the scalar border columns were half
//! the layer's time).

use core::arch::x86_64::*;

use super::scalar;
use crate::conv::{Activation, Conv2d};
use crate::precision::FloatElement;
use crate::simd::avx512::{first_lanes, load16_mask, store16_mask};
use crate::view::{View, ViewMut};

/// Sixteen elements from `p` as f32 lanes (full load).
///
/// # Safety
/// `p .. p + 16` must be readable.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
unsafe fn load16_full<S: FloatElement>(p: *const S) -> __m512 {
    // SAFETY: as the caller's contract.
    unsafe { load16_mask(p, 0xffff) }
}

/// Largest output-channel block.
const MAX_OB: usize = 7;

/// # Safety
/// AVX-512 F/BW/DQ/VL, AVX2, FMA and F16C must be supported.
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
pub(crate) unsafe fn forward<S: FloatElement>(
    layer: &Conv2d<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let nw = layer.weights.len();
    let (wf, _) = scratch.split_at_mut(nw);
    for (d, s) in wf.iter_mut().zip(layer.weights) {
        *d = s.to_f32();
    }
    let wf: &[f32] = wf;
    let nblocks = layer.cout.div_ceil(MAX_OB);
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let ky_lo = p.saturating_sub(y);
        let ky_hi = k.min(h + p - y);
        let mut co0 = 0;
        for b in 0..nblocks {
            // Near-equal blocks: 14 channels go as 7, 7.
            let ob = layer.cout / nblocks + usize::from(b < layer.cout % nblocks);
            let ctx = Ctx { layer, wf, src, y, ky_lo, ky_hi, co0 };
            let mut x = 0;
            macro_rules! run {
                ($k:literal, $ob:literal) => {{
                    // SAFETY (every call): interior blocks read columns
                    // x - p .. x + 16 NV + p inside the row; edge blocks read
                    // only the in-image lanes of each tap.
                    unsafe {
                        // The first block, its left taps partly outside.
                        let len = w.min(16);
                        block::<S, $k, $ob, 1, true>(&ctx, dst, yo, 0, len);
                        x = len;
                        while x + 32 + p <= w {
                            block::<S, $k, $ob, 2, false>(&ctx, dst, yo, x, 16);
                            x += 32;
                        }
                        while x + 16 + p <= w {
                            block::<S, $k, $ob, 1, false>(&ctx, dst, yo, x, 16);
                            x += 16;
                        }
                        while x < w {
                            let len = (w - x).min(16);
                            block::<S, $k, $ob, 1, true>(&ctx, dst, yo, x, len);
                            x += len;
                        }
                    }
                }};
            }
            match (k, ob) {
                (1, 1) => run!(1, 1),
                (1, 2) => run!(1, 2),
                (1, 3) => run!(1, 3),
                (1, 4) => run!(1, 4),
                (1, 5) => run!(1, 5),
                (1, 6) => run!(1, 6),
                (1, 7) => run!(1, 7),
                (3, 1) => run!(3, 1),
                (3, 2) => run!(3, 2),
                (3, 3) => run!(3, 3),
                (3, 4) => run!(3, 4),
                (3, 5) => run!(3, 5),
                (3, 6) => run!(3, 6),
                (3, 7) => run!(3, 7),
                (5, 1) => run!(5, 1),
                (5, 2) => run!(5, 2),
                (5, 3) => run!(5, 3),
                (5, 4) => run!(5, 4),
                (5, 5) => run!(5, 5),
                (5, 6) => run!(5, 6),
                (5, 7) => run!(5, 7),
                _ => {
                    // unreachable (k and ob are checked): the scalar pixel
                    for co in co0..co0 + ob {
                        for xx in 0..w {
                            dst.row_mut(co, yo)[xx] = S::from_f32(scalar::pixel(layer, src, co, y, xx));
                        }
                    }
                }
            }
            let _ = x;
            co0 += ob;
        }
    }
}

struct Ctx<'c, 'a, S> {
    layer: &'c Conv2d<'a, S>,
    wf: &'c [f32],
    src: &'c View<'a, S>,
    y: usize,
    ky_lo: usize,
    ky_hi: usize,
    co0: usize,
}

/// Output channels `co0 .. co0 + OB`, pixels `x .. x + 16 * NV` of row `yo`
/// (with `EDGE`, `NV = 1` and only the first `len` lanes, each tap loading
/// only its in-image lanes).
///
/// # Safety
/// AVX-512/FMA/F16C; without `EDGE`, `x >= K / 2` and `x + 16 NV + K / 2 <=
/// width`; with it, `x + len <= width`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
unsafe fn block<S: FloatElement, const K: usize, const OB: usize, const NV: usize, const EDGE: bool>(
    ctx: &Ctx<'_, '_, S>,
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    x: usize,
    len: usize,
) {
    let p = K / 2;
    let cin = ctx.layer.cin;
    let ostride = cin * K * K;
    let w = ctx.src.width() as isize;
    let out_mask = if EDGE { first_lanes(len) } else { 0xffff };
    // The in-image lanes of the taps at column offset kx (EDGE only).
    let tap_mask: [__mmask16; K] = core::array::from_fn(|kx| {
        let c0 = x as isize - p as isize + kx as isize;
        let lo = (-c0).clamp(0, 16) as usize;
        let hi = (w - c0).clamp(0, len as isize) as usize;
        if hi > lo {
            first_lanes(hi) & !first_lanes(lo)
        } else {
            0
        }
    });
    let mut acc = [[_mm512_setzero_ps(); NV]; OB];
    for (o, a) in acc.iter_mut().enumerate() {
        let b = _mm512_set1_ps(ctx.layer.bias.map_or(0.0, |b| b[ctx.co0 + o].to_f32()));
        *a = [b; NV];
    }
    let wp = ctx.wf.as_ptr();
    for ci in 0..cin {
        for ky in ctx.ky_lo..ctx.ky_hi {
            let sp = ctx.src.ptr(ci, ctx.y + ky - p).wrapping_add(x).wrapping_sub(p);
            let wrow = ((ctx.co0 * cin + ci) * K + ky) * K;
            for kx in 0..K {
                // SAFETY: interior blocks lie inside the row (caller); edge
                // blocks read only the lanes of their tap's mask.
                let s: [__m512; NV] = core::array::from_fn(|v| unsafe {
                    if EDGE {
                        load16_mask(sp.wrapping_add(kx), tap_mask[kx])
                    } else {
                        load16_full(sp.add(kx + 16 * v))
                    }
                });
                for (o, a) in acc.iter_mut().enumerate() {
                    // SAFETY: the weight index is below cout * cin * K * K.
                    let wv = _mm512_set1_ps(unsafe { *wp.add(wrow + o * ostride + kx) });
                    for v in 0..NV {
                        a[v] = _mm512_fmadd_ps(wv, s[v], a[v]);
                    }
                }
            }
        }
    }
    let zero = _mm512_setzero_ps();
    for (o, a) in acc.iter().enumerate() {
        for (v, &val) in a.iter().enumerate() {
            let r = match ctx.layer.act {
                Activation::Identity => val,
                Activation::Relu => _mm512_max_ps(val, zero),
                Activation::LeakyRelu(s) => _mm512_max_ps(val, _mm512_mul_ps(_mm512_set1_ps(s), val)),
            };
            // SAFETY: the lanes of out_mask (EDGE) or all 16 are below width.
            unsafe { store16_mask(dst.ptr_mut(ctx.co0 + o, yo).add(x + 16 * v), out_mask, r) };
        }
    }
}

//! AVX-512 convolution: the AVX2 scheme ([`super::avx2`]) at sixteen lanes.
//! Output channels go in blocks of at most seven; a block times 32 pixels
//! lives in fourteen accumulators while every input channel and tap streams
//! past. The row's last pixels run as a masked 16-lane block; only the
//! `k / 2` border columns use the scalar pixel (same summation order).

use core::arch::x86_64::*;

use super::scalar;
use crate::conv::{Activation, Conv2d};
use crate::precision::FloatElement;
use crate::simd::avx512::{first_lanes, load16_mask, store16_mask};
use crate::view::{View, ViewMut};

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
            let mut x = p;
            macro_rules! run {
                ($k:literal, $ob:literal) => {{
                    while x + 32 + p <= w {
                        // SAFETY: columns x - p .. x + 32 + p lie inside the row.
                        unsafe { block::<S, $k, $ob, 2>(&ctx, dst, yo, x, 0xffff) };
                        x += 32;
                    }
                    while x + p < w {
                        let m = first_lanes(w - p - x);
                        // SAFETY: as above for the lanes of m.
                        unsafe { block::<S, $k, $ob, 1>(&ctx, dst, yo, x, m) };
                        x = (x + 16).min(w - p);
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
                _ => x = p, // unreachable: k and ob are checked; everything goes scalar
            }
            for co in co0..co0 + ob {
                for xx in (0..p.min(w)).chain(x.max(p.min(w))..w) {
                    dst.row_mut(co, yo)[xx] = S::from_f32(scalar::pixel(layer, src, co, y, xx));
                }
            }
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
/// (with `NV = 1`, only the lanes of `m`).
///
/// # Safety
/// AVX-512/FMA/F16C; `x >= K / 2` and `x + lane + K / 2 < width` for every
/// pixel written.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
unsafe fn block<S: FloatElement, const K: usize, const OB: usize, const NV: usize>(
    ctx: &Ctx<'_, '_, S>,
    dst: &mut ViewMut<'_, S>,
    yo: usize,
    x: usize,
    m: __mmask16,
) {
    let p = K / 2;
    let cin = ctx.layer.cin;
    let ostride = cin * K * K;
    let mask = |v: usize| if NV == 1 && v == 0 { m } else { 0xffff };
    let mut acc = [[_mm512_setzero_ps(); NV]; OB];
    for (o, a) in acc.iter_mut().enumerate() {
        let b = _mm512_set1_ps(ctx.layer.bias.map_or(0.0, |b| b[ctx.co0 + o].to_f32()));
        *a = [b; NV];
    }
    let wp = ctx.wf.as_ptr();
    for ci in 0..cin {
        for ky in ctx.ky_lo..ctx.ky_hi {
            let sp = ctx.src.ptr(ci, ctx.y + ky - p).wrapping_add(x - p);
            let wrow = ((ctx.co0 * cin + ci) * K + ky) * K;
            for kx in 0..K {
                // SAFETY: the lanes of mask(v) are inside the row (caller).
                let s: [__m512; NV] = core::array::from_fn(|v| unsafe { load16_mask(sp.add(kx + 16 * v), mask(v)) });
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
            // SAFETY: the lanes of mask(v) are below width.
            unsafe { store16_mask(dst.ptr_mut(ctx.co0 + o, yo).add(x + 16 * v), mask(v), r) };
        }
    }
}

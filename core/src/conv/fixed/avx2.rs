//! AVX2 fixed-point convolution: taps `t` of the flattened `(ci, ky, kx)`
//! index go in pairs; the two input rows are interleaved (`vpunpck[lh]wd`)
//! and each output channel's packed weight pair multiplies-and-adds them
//! (`vpmaddwd`: 16 products per instruction, twice FMA's 8). Blocks of up to
//! six output channels times sixteen pixels in twelve accumulators; border
//! columns use the scalar pixel.

use core::arch::x86_64::*;

use super::{finish, scalar, shift};
use crate::conv::{Activation, Conv2d};
use crate::fixed::{KERNEL_FRAC, QMAX};
use crate::view::{View, ViewMut};

const MAX_OB: usize = 6;

/// # Safety
/// AVX2 must be supported.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn forward(layer: &Conv2d<'_, i16>, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let s = shift(layer, src, dst);
    let nblocks = layer.cout.div_ceil(MAX_OB);
    // acc + 2^(s-1) stays below 2^31 for s <= 15 under the layer's bit budget.
    let vec_ok = s > 0 && s <= 15;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        // The taps of this row that stay inside the image: (plane, row offset, column offset).
        let mut taps = [(0usize, 0usize, 0usize, 0usize); 16 * 25];
        let mut nt = 0;
        for ci in 0..layer.cin {
            for ky in 0..k {
                let Some(sy) = (y + ky).checked_sub(p).filter(|&v| v < h) else { continue };
                for kx in 0..k {
                    if nt < taps.len() {
                        taps[nt] = (ci, sy, kx, (ci * k + ky) * k + kx);
                    }
                    nt += 1;
                }
            }
        }
        let fits = nt <= taps.len();
        let mut co0 = 0;
        for b in 0..nblocks {
            let ob = layer.cout / nblocks + usize::from(b < layer.cout % nblocks);
            let mut x = p;
            if vec_ok && fits {
                macro_rules! run {
                    ($ob:literal) => {
                        while x + 16 + p <= w {
                            // SAFETY: columns x - p .. x + 16 + p are inside the row.
                            unsafe { block::<$ob>(layer, src, dst, &taps[..nt], co0, yo, x, s) };
                            x += 16;
                        }
                    };
                }
                match ob {
                    1 => run!(1),
                    2 => run!(2),
                    3 => run!(3),
                    4 => run!(4),
                    5 => run!(5),
                    _ => run!(6),
                }
            }
            for co in co0..co0 + ob {
                for xx in (0..p.min(w)).chain(x.max(p.min(w))..w) {
                    let acc = scalar::pixel(layer, src, co, y, xx);
                    dst.row_mut(co, yo)[xx] = finish(layer, co, acc, s);
                }
            }
            co0 += ob;
        }
    }
}

#[inline(always)]
unsafe fn ld16(p: *const i16) -> __m256i {
    // SAFETY: the caller guarantees 16 readable values; -32768 reads as -32767.
    unsafe { _mm256_max_epi16(_mm256_loadu_si256(p as *const __m256i), _mm256_set1_epi16(-QMAX as i16)) }
}

/// # Safety
/// AVX2; columns `x - p .. x + 16 + p` inside the image; `0 < s <= 15`.
#[inline]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn block<const OB: usize>(
    layer: &Conv2d<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    taps: &[(usize, usize, usize, usize)],
    co0: usize,
    yo: usize,
    x: usize,
    s: i32,
) {
    let k = layer.k;
    let p = k / 2;
    let per = layer.cin * k * k;
    let zero = _mm256_setzero_si256();
    let mut lo = [zero; OB];
    let mut hi = [zero; OB];
    let load = |t: usize| -> (__m256i, usize) {
        match taps.get(t) {
            // SAFETY: in range (caller).
            Some(&(ci, sy, kx, widx)) => (unsafe { ld16(src.ptr(ci, sy).add(x + kx - p)) }, widx),
            None => (zero, usize::MAX),
        }
    };
    let wt = |co: usize, widx: usize| -> i32 {
        if widx == usize::MAX {
            0
        } else {
            crate::fixed::ld(layer.weights[co * per + widx])
        }
    };
    let mut t = 0;
    while t < taps.len() {
        let (xa, wa) = load(t);
        let (xb, wb) = load(t + 1);
        let il = _mm256_unpacklo_epi16(xa, xb);
        let ih = _mm256_unpackhi_epi16(xa, xb);
        for o in 0..OB {
            let co = co0 + o;
            let pair = (wt(co, wa) as u16 as u32) | ((wt(co, wb) as u16 as u32) << 16);
            let wv = _mm256_set1_epi32(pair as i32);
            lo[o] = _mm256_add_epi32(lo[o], _mm256_madd_epi16(il, wv));
            hi[o] = _mm256_add_epi32(hi[o], _mm256_madd_epi16(ih, wv));
        }
        t += 2;
    }
    let half = _mm256_set1_epi32(1 << (s - 1));
    let sh = _mm_cvtsi32_si128(s);
    for o in 0..OB {
        let co = co0 + o;
        let bias = _mm256_set1_epi32(layer.bias.map_or(0, |b| crate::fixed::ld(b[co])));
        let lim = _mm256_set1_epi32(super::PRE_ACT_MAX as i32);
        let nlim = _mm256_set1_epi32(-super::PRE_ACT_MAX as i32);
        let clampv = |v: __m256i| _mm256_max_epi32(_mm256_min_epi32(v, lim), nlim);
        let mut l = clampv(_mm256_add_epi32(_mm256_sra_epi32(_mm256_add_epi32(lo[o], half), sh), bias));
        let mut r = clampv(_mm256_add_epi32(_mm256_sra_epi32(_mm256_add_epi32(hi[o], half), sh), bias));
        match layer.act {
            Activation::Identity => {}
            Activation::Relu => {
                l = _mm256_max_epi32(l, zero);
                r = _mm256_max_epi32(r, zero);
            }
            Activation::LeakyRelu(sl) => {
                let q = _mm256_set1_epi32(crate::fixed::from_f32(sl, KERNEL_FRAC) as i32);
                let rnd = _mm256_set1_epi32(1 << (KERNEL_FRAC - 1));
                let leak = |v: __m256i| {
                    let m =
                        _mm256_srai_epi32::<{ KERNEL_FRAC as i32 }>(_mm256_add_epi32(_mm256_mullo_epi32(v, q), rnd));
                    _mm256_blendv_epi8(m, v, _mm256_cmpgt_epi32(v, zero))
                };
                l = leak(l);
                r = leak(r);
            }
        }
        let out = _mm256_max_epi16(_mm256_packs_epi32(l, r), _mm256_set1_epi16(-QMAX as i16));
        // SAFETY: x + 16 <= width.
        unsafe { _mm256_storeu_si256(dst.ptr_mut(co, yo).add(x) as *mut __m256i, out) };
    }
}

//! AVX2 fixed-point convolution: taps `t` of the flattened `(ci, ky, kx)`
//! index go in pairs; the two input rows are interleaved (`vpunpck[lh]wd`)
//! and multiplied-and-added (`vpmaddwd`: 16 products per instruction, twice
//! FMA's 8) with each output channel's weight pair, packed once per set of
//! valid tap rows into the scratch and broadcast from memory. Blocks of up to
//! six output channels times sixteen pixels live in twelve accumulators;
//! border columns use the scalar pixel.

use core::arch::x86_64::*;

use super::{pack_pairs, row_taps, scalar_columns, shift, Block, Tap};
use crate::conv::{Activation, Conv2d};
use crate::fixed::{ld, KERNEL_FRAC, QMAX};
use crate::view::{View, ViewMut};

const MAX_OB: usize = 6;

/// # Safety
/// AVX2 must be supported.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn forward(
    layer: &Conv2d<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    packed: &mut [i32],
) {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let s = shift(layer, src, dst);
    let nblocks = layer.cout.div_ceil(MAX_OB);
    // acc + 2^(s-1) stays below 2^31 for s <= 15 under the layer's bit budget.
    let vec_ok = s > 0 && s <= 15;
    let mut taps = [Tap::default(); 16 * 25];
    let mut packed_for = None::<(usize, usize)>;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let (nt, ky_lo, ky_hi) = row_taps(layer, y, h, &mut taps);
        let fits = nt <= taps.len() && nt.div_ceil(2) * layer.cout <= packed.len();
        if vec_ok && fits && packed_for != Some((ky_lo, ky_hi)) {
            pack_pairs(layer, nt, ky_lo, ky_hi, packed);
            packed_for = Some((ky_lo, ky_hi));
        }
        let npairs = nt.div_ceil(2);
        let mut co0 = 0;
        for b in 0..nblocks {
            let ob = layer.cout / nblocks + usize::from(b < layer.cout % nblocks);
            let mut x = p;
            if vec_ok && fits {
                let ctx = Block { src, taps: &taps[..nt], packed: &packed[co0 * npairs..], npairs, x: 0, s, p };
                macro_rules! run {
                    ($ob:literal) => {{
                        while x + 16 + p <= w {
                            // SAFETY: columns x - p .. x + 16 + p are inside the row.
                            unsafe { block::<$ob>(layer, &Block { x, ..ctx }, dst, co0, yo) };
                            x += 16;
                        }
                        // The tail: one more block ending at the last interior column,
                        // overlapping the previous one (same values written twice).
                        if x < w - p && w >= 16 + 2 * p {
                            let xl = w - p - 16;
                            // SAFETY: as above.
                            unsafe { block::<$ob>(layer, &Block { x: xl, ..ctx }, dst, co0, yo) };
                            x = w - p;
                        }
                    }};
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
            scalar_columns(layer, src, dst, (co0, ob), (y, yo), x, s);
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
/// AVX2; columns `x - p .. x + 16 + p` inside the image; `0 < s <= 15`;
/// `packed` holds `OB * npairs` pairs.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn block<const OB: usize>(
    layer: &Conv2d<'_, i16>,
    b: &Block<'_, '_>,
    dst: &mut ViewMut<'_, i16>,
    co0: usize,
    yo: usize,
) {
    let zero = _mm256_setzero_si256();
    let mut lo = [zero; OB];
    let mut hi = [zero; OB];
    let (x, p) = (b.x, b.p);
    let load = |t: usize| -> __m256i {
        match b.taps.get(t) {
            // SAFETY: in range (caller).
            Some(tp) => unsafe { ld16(b.src.ptr(tp.ci, tp.sy).add(x + tp.kx - p)) },
            None => zero,
        }
    };
    assert!(b.packed.len() >= OB * b.npairs);
    let wp = b.packed.as_ptr();
    for pi in 0..b.npairs {
        let (xa, xb) = (load(2 * pi), load(2 * pi + 1));
        let il = _mm256_unpacklo_epi16(xa, xb);
        let ih = _mm256_unpackhi_epi16(xa, xb);
        for o in 0..OB {
            // SAFETY: o * npairs + pi < OB * npairs <= packed.len() (asserted).
            let wv = _mm256_set1_epi32(unsafe { *wp.add(o * b.npairs + pi) });
            lo[o] = _mm256_add_epi32(lo[o], _mm256_madd_epi16(il, wv));
            hi[o] = _mm256_add_epi32(hi[o], _mm256_madd_epi16(ih, wv));
        }
    }
    let s = b.s;
    let half = _mm256_set1_epi32(1 << (s - 1));
    let sh = _mm_cvtsi32_si128(s);
    for o in 0..OB {
        let co = co0 + o;
        let bias = _mm256_set1_epi32(layer.bias.map_or(0, |bb| ld(bb[co])));
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

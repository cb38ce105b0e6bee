//! AVX2 fixed-point convolution: taps `t` of the flattened `(ci, ky, kx)`
//! index go in pairs; the two input rows are interleaved (`vpunpck[lh]wd`)
//! and multiplied-and-added (`vpmaddwd`: 16 products per instruction, twice
//! FMA's 8) with each output channel's weight pair, packed once per set of
//! valid tap rows into the scratch and broadcast from memory. Blocks of up to
//! six output channels times sixteen pixels live in twelve accumulators. The
//! first and last sixteen columns of a row load their taps through a small
//! buffer that holds 0 for the columns outside the image (the zero padding),
//! the last block overlapping the one before; rows narrower than sixteen use
//! the scalar pixel.

use core::arch::x86_64::*;

use super::{row_taps, scalar_columns, shift, Block, Tap};
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
    // Each tap's element offset from the source's first element, so a tap
    // load is one table read plus the column.
    let mut offs = [0isize; 16 * 25];
    let (ps, rs) = (src.plane_stride() as isize, src.row_stride() as isize);
    let mut packed_for = None::<(usize, usize)>;
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let (nt, ky_lo, ky_hi) = row_taps(layer, y, h, &mut taps);
        for (o, t) in offs.iter_mut().zip(&taps).take(nt) {
            *o = t.ci as isize * ps + t.sy as isize * rs + t.kx as isize - p as isize;
        }
        let fits = nt <= taps.len() && nt.div_ceil(2) * layer.cout <= packed.len();
        if vec_ok && fits && packed_for != Some((ky_lo, ky_hi)) {
            pack_pairs_by_pair(layer, nt, ky_lo, ky_hi, packed);
            packed_for = Some((ky_lo, ky_hi));
        }
        let npairs = nt.div_ceil(2);
        let mut co0 = 0;
        for b in 0..nblocks {
            let ob = layer.cout / nblocks + usize::from(b < layer.cout % nblocks);
            let mut x = 0;
            if vec_ok && fits && w >= 16 {
                let ctx = Block { src, taps: &taps[..nt], packed: &packed[co0..], npairs, x: 0, s, p };
                let offs = &offs[..nt];
                macro_rules! run {
                    ($ob:literal) => {{
                        // SAFETY (every block): the edge blocks read only
                        // in-image columns; interior ones have columns
                        // x - p .. x + 16 + p inside the row.
                        unsafe {
                            block::<$ob, true>(layer, &Block { x: 0, ..ctx }, offs, dst, co0, yo);
                            x = 16;
                            while x + 16 + p <= w {
                                block::<$ob, false>(layer, &Block { x, ..ctx }, offs, dst, co0, yo);
                                x += 16;
                            }
                            // The rest, the last block ending at the row's end
                            // (overlapping the one before: same values twice).
                            while x < w {
                                let xc = x.min(w - 16);
                                block::<$ob, true>(layer, &Block { x: xc, ..ctx }, offs, dst, co0, yo);
                                x = xc + 16;
                            }
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
            if x < w {
                // Not vectorised (a narrow row, or outside the bit budget):
                // every column by the scalar pixel.
                scalar_columns(layer, src, dst, (co0, ob), (y, yo), 0, s);
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

/// Weight pairs of the `nt` valid taps (kernel rows `ky_lo .. ky_hi`),
/// `(w_2i, w_2i+1)` as one i32 (low half first), pair-major:
/// `packed[i * cout + co]`, so a block's channels for one pair sit side by
/// side behind one pointer; an odd count ends with a zero weight. The same
/// values as [`super::pack_pairs`] (channel-major, which the AVX-512 kernel
/// reads).
fn pack_pairs_by_pair(layer: &Conv2d<'_, i16>, nt: usize, ky_lo: usize, ky_hi: usize, packed: &mut [i32]) {
    let k = layer.k;
    let per = layer.cin * k * k;
    let rows = ky_hi - ky_lo;
    let widx = |co: usize, n: usize| -> i32 {
        if n >= nt {
            return 0;
        }
        let (ci, r) = (n / (rows * k), n % (rows * k));
        let (ky, kx) = (ky_lo + r / k, r % k);
        ld(layer.weights[co * per + (ci * k + ky) * k + kx])
    };
    for pi in 0..nt.div_ceil(2) {
        for co in 0..layer.cout {
            let (a, b) = (widx(co, 2 * pi), widx(co, 2 * pi + 1));
            packed[pi * layer.cout + co] = ((a as u16 as u32) | ((b as u16 as u32) << 16)) as i32;
        }
    }
}

/// Values per row segment of an edge block's padded copy: the block's
/// sixteen columns and `k / 2 <= 2` more on each side, rounded up.
const SEG: usize = 24;

/// An edge block's input: for each valid tap row `(ci, sy)` (taps `K`
/// apart), columns `x - p .. x + 16 + p` with 0 outside the image, `SEG`
/// values per row, so the block's loads need no masks.
///
/// # Safety
/// AVX2; `taps` in `(ci, ky, kx)` order, `K` per row; `pad` holds
/// `16 * 5 * SEG` values.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn pad_rows(b: &Block<'_, '_>, k: usize, pad: *mut i16) {
    let w = b.src.width() as isize;
    let c0 = b.x as isize - b.p as isize;
    let n = 16 + 2 * b.p;
    for (r, t) in b.taps.iter().step_by(k).enumerate() {
        let row = b.src.row(t.ci, t.sy);
        for i in 0..n {
            let c = c0 + i as isize;
            let v = if c >= 0 && c < w { row[c as usize] } else { 0 };
            // SAFETY: r < 16 * 5 rows (cin <= 16, k <= 5) and i < n <= SEG.
            unsafe { pad.add(r * SEG + i).write(v) };
        }
    }
}

/// # Safety
/// AVX2; `0 < s <= 15`; `b.packed` starts at the block's first channel of
/// the pair-major weights ([`pack_pairs_by_pair`]); without `EDGE`,
/// columns `x - p .. x + 16 + p` inside the image, with it `x + 16 <= width`.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn block<const OB: usize, const EDGE: bool>(
    layer: &Conv2d<'_, i16>,
    b: &Block<'_, '_>,
    offs: &[isize],
    dst: &mut ViewMut<'_, i16>,
    co0: usize,
    yo: usize,
) {
    let zero = _mm256_setzero_si256();
    let mut lo = [zero; OB];
    let mut hi = [zero; OB];
    let (x, p) = (b.x, b.p);
    let k = layer.k;
    let base = b.src.ptr(0, 0);
    let nt = offs.len();
    // Left uninitialised (interior blocks never touch it); an edge block
    // writes every element it reads, `16 + 2 p` per valid row.
    let mut pad = core::mem::MaybeUninit::<[i16; 16 * 5 * SEG]>::uninit();
    if EDGE {
        // SAFETY: forwarded; pad_rows writes through the pointer only.
        unsafe { pad_rows(b, k, pad.as_mut_ptr() as *mut i16) };
    }
    let _ = p;
    let cout = layer.cout;
    assert!(b.npairs >= 1 && b.packed.len() >= (b.npairs - 1) * cout + OB);
    assert!(b.taps.len() == nt && b.npairs == nt.div_ceil(2) && offs.len() == nt);
    let wp = b.packed.as_ptr();
    let padp = pad.as_ptr() as *const i16;
    // Macros rather than closures: the hot loop must not depend on the
    // inliner (a closure left out of line costs a third of the layer).
    macro_rules! load {
        ($t:expr) => {{
            let t: usize = $t;
            // SAFETY: tap t's columns x - p + kx .. + 16 lie inside the row
            // (caller), or (edge) inside its padded segment.
            unsafe {
                if EDGE {
                    ld16(padp.add((t / k) * SEG + t % k))
                } else {
                    ld16(base.offset(*offs.get_unchecked(t) + x as isize))
                }
            }
        }};
    }
    macro_rules! pair {
        ($pi:expr, $xa:expr, $xb:expr) => {{
            let pi: usize = $pi;
            let il = _mm256_unpacklo_epi16($xa, $xb);
            let ih = _mm256_unpackhi_epi16($xa, $xb);
            for o in 0..OB {
                // SAFETY: pi * cout + o < (npairs - 1) * cout + OB <= packed.len() (asserted).
                let wv = _mm256_set1_epi32(unsafe { *wp.add(pi * cout + o) });
                lo[o] = _mm256_add_epi32(lo[o], _mm256_madd_epi16(il, wv));
                hi[o] = _mm256_add_epi32(hi[o], _mm256_madd_epi16(ih, wv));
            }
        }};
    }
    for pi in 0..nt / 2 {
        let (xa, xb) = (load!(2 * pi), load!(2 * pi + 1));
        pair!(pi, xa, xb);
    }
    if nt % 2 == 1 {
        // The odd last tap pairs with a zero weight (and a zero input).
        let xa = load!(nt - 1);
        pair!(nt / 2, xa, zero);
    }
    let s = b.s;
    let half = _mm256_set1_epi32(1 << (s - 1));
    let sh = _mm_cvtsi32_si128(s);
    for o in 0..OB {
        let co = co0 + o;
        let bias = _mm256_set1_epi32(layer.bias.map_or(0, |bb| ld(bb[co])));
        let lim = _mm256_set1_epi32(super::PRE_ACT_MAX as i32);
        let nlim = _mm256_set1_epi32(-super::PRE_ACT_MAX as i32);
        let mut l = _mm256_add_epi32(_mm256_sra_epi32(_mm256_add_epi32(lo[o], half), sh), bias);
        let mut r = _mm256_add_epi32(_mm256_sra_epi32(_mm256_add_epi32(hi[o], half), sh), bias);
        l = _mm256_max_epi32(_mm256_min_epi32(l, lim), nlim);
        r = _mm256_max_epi32(_mm256_min_epi32(r, lim), nlim);
        match layer.act {
            Activation::Identity => {}
            Activation::Relu => {
                l = _mm256_max_epi32(l, zero);
                r = _mm256_max_epi32(r, zero);
            }
            Activation::LeakyRelu(sl) => {
                let q = _mm256_set1_epi32(crate::fixed::from_f32(sl, KERNEL_FRAC) as i32);
                let rnd = _mm256_set1_epi32(1 << (KERNEL_FRAC - 1));
                macro_rules! leak {
                    ($v:expr) => {{
                        let v = $v;
                        let m = _mm256_srai_epi32::<{ KERNEL_FRAC as i32 }>(_mm256_add_epi32(
                            _mm256_mullo_epi32(v, q),
                            rnd,
                        ));
                        _mm256_blendv_epi8(m, v, _mm256_cmpgt_epi32(v, zero))
                    }};
                }
                l = leak!(l);
                r = leak!(r);
            }
        }
        let out = _mm256_max_epi16(_mm256_packs_epi32(l, r), _mm256_set1_epi16(-QMAX as i16));
        // SAFETY: x + 16 <= width.
        unsafe { _mm256_storeu_si256(dst.ptr_mut(co, yo).add(x) as *mut __m256i, out) };
    }
}

//! AVX2 fixed-point convolution by channel pairs.
//!
//! Each input row the band needs is copied once into a ring in the scratch
//! with its channels interleaved in pairs: word `i` of pair `cp`'s row holds
//! channel `2 cp` (low half) and `2 cp + 1` (high half, 0 past the last
//! channel) at column `i - k / 2`, 0 outside the image (the zero padding).
//! Eight consecutive words are then eight pixels' channel pairs, which
//! `vpmaddwd` multiplies by one output channel's broadcast weight pair and
//! adds in pairs: 16 products per instruction (twice FMA's 8), with no
//! shuffle in the inner loop, no clamp per load (the copy clamps -32768 to
//! -32767 once, as [`crate::fixed::ld`] reads it), and no border case (the
//! padded ring rows cover every block). Blocks of up to six output channels
//! times sixteen pixels keep twelve accumulators in registers. The exact i32
//! sums do not depend on their order, so the output is the scalar path's
//! bits.

use core::arch::x86_64::*;

use super::{ring_row, scalar_columns, shift, weight_words};
use crate::conv::{Activation, Conv2d};
use crate::fixed::{ld, KERNEL_FRAC, QMAX};
use crate::view::{View, ViewMut};

/// Output channels per block (twelve accumulators).
const MAX_OB: usize = 6;

/// # Safety
/// AVX2 must be supported; `scratch.len() >= scratch_len(...)` of the layer
/// and the source's width (checked by the caller).
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn forward(
    layer: &Conv2d<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    scratch: &mut [i32],
) {
    let (w, h) = (src.width(), src.height());
    let (k, cin, cout) = (layer.k, layer.cin, layer.cout);
    let p = k / 2;
    let s = shift(layer, src, dst);
    // A right shift of 1 to 31 bits (rounded without overflow, below); a left
    // shift, or a kernel over 5x5, runs the scalar pixel.
    if !(s > 0 && s <= 31) || k > 5 {
        for yo in 0..dst.height() {
            let mut co0 = 0;
            while co0 < cout {
                let ob = (cout - co0).min(MAX_OB);
                scalar_columns(layer, src, dst, (co0, ob), (y0 + yo, yo), 0, s);
                co0 += ob;
            }
        }
        return;
    }
    let cpn = cin.div_ceil(2);
    let rw = ring_row(w, p);
    let (weights, ring) = scratch.split_at_mut(weight_words(k, cin, cout));
    let ring = &mut ring[..k * cpn * rw];
    // The padding columns of every ring row are 0 for any row held there.
    for row in ring.chunks_exact_mut(rw) {
        row[..p].fill(0);
        row[p + w..].fill(0);
    }
    // held[slot]: the input row the slot holds (ring slot of row sy: sy % k).
    let mut held = [usize::MAX; 5];
    let mut packed_for = None::<(usize, usize)>;
    let nblocks = cout.div_ceil(MAX_OB);
    for yo in 0..dst.height() {
        let y = y0 + yo;
        // Kernel rows whose input row lies inside the image.
        let ky_lo = p.saturating_sub(y);
        let ky_hi = k.min(h + p - y);
        let mut slots = [0usize; 5];
        for (r, ky) in (ky_lo..ky_hi).enumerate() {
            let sy = y + ky - p;
            let slot = sy % k;
            if held[slot] != sy {
                // SAFETY: AVX2 (caller); the slot's rows lie inside the ring.
                unsafe { interleave_row(src, sy, ring[slot * cpn * rw..(slot + 1) * cpn * rw].as_mut_ptr(), rw, p) };
                held[slot] = sy;
            }
            slots[r] = slot;
        }
        let slots = &slots[..ky_hi - ky_lo];
        if packed_for != Some((ky_lo, ky_hi)) {
            pack_weights(layer, ky_lo, ky_hi, weights);
            packed_for = Some((ky_lo, ky_hi));
        }
        let rows = Rows { ring: ring.as_ptr(), slots, cpn, rw };
        let mut co0 = 0;
        for b in 0..nblocks {
            let ob = cout / nblocks + usize::from(b < cout % nblocks);
            macro_rules! run {
                ($ob:literal, $k:literal) => {{
                    let mut x = 0;
                    while x < w {
                        // SAFETY: the block reads ring words x .. x + 16 + 2p
                        // of held rows (inside, by ring_row) and weight words
                        // below (ky_hi - ky_lo) k cpn cout.
                        unsafe { block::<$ob, $k>(layer, &rows, weights[co0..].as_ptr(), s, dst, co0, yo, x) };
                        x += 16;
                    }
                }};
            }
            macro_rules! by_k {
                ($ob:literal) => {
                    match k {
                        1 => run!($ob, 1),
                        3 => run!($ob, 3),
                        _ => run!($ob, 5),
                    }
                };
            }
            match ob {
                1 => by_k!(1),
                2 => by_k!(2),
                3 => by_k!(3),
                4 => by_k!(4),
                5 => by_k!(5),
                _ => by_k!(6),
            }
            co0 += ob;
        }
    }
}

/// Input row `sy` of every channel pair into the ring slot at `out`
/// (`cpn` rows of `rw` words), columns at word `x + p`; the padding words
/// are left alone (zero).
///
/// # Safety
/// AVX2; `out` holds `cin.div_ceil(2) * rw` words, `rw >= w + 2 p`.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn interleave_row(src: &View<'_, i16>, sy: usize, out: *mut i32, rw: usize, p: usize) {
    let (w, cin) = (src.width(), src.channels());
    let floor = _mm256_set1_epi16(-QMAX as i16);
    for cp in 0..cin.div_ceil(2) {
        let a = src.row(2 * cp, sy);
        let b = (2 * cp + 1 < cin).then(|| src.row(2 * cp + 1, sy));
        // SAFETY: words p .. p + w of the pair's row.
        let o = unsafe { out.add(cp * rw + p) };
        let mut x = 0;
        while x + 16 <= w {
            // SAFETY: columns x .. x + 16 of the rows; words x .. x + 16 of o.
            unsafe {
                let va = _mm256_max_epi16(_mm256_loadu_si256(a.as_ptr().add(x) as *const __m256i), floor);
                let vb = match b {
                    Some(b) => _mm256_max_epi16(_mm256_loadu_si256(b.as_ptr().add(x) as *const __m256i), floor),
                    None => _mm256_setzero_si256(),
                };
                // Per 128-bit lane: lo = pixels 0-3 | 8-11, hi = 4-7 | 12-15.
                let lo = _mm256_unpacklo_epi16(va, vb);
                let hi = _mm256_unpackhi_epi16(va, vb);
                _mm256_storeu_si256(o.add(x) as *mut __m256i, _mm256_permute2x128_si256::<0x20>(lo, hi));
                _mm256_storeu_si256(o.add(x + 8) as *mut __m256i, _mm256_permute2x128_si256::<0x31>(lo, hi));
            }
            x += 16;
        }
        for xx in x..w {
            let (lo, hi) = (ld(a[xx]), b.map_or(0, |b| ld(b[xx])));
            // SAFETY: word xx of o.
            unsafe { o.add(xx).write(((lo as u16 as u32) | ((hi as u16 as u32) << 16)) as i32) };
        }
    }
}

/// The weight pairs of kernel rows `ky_lo .. ky_hi`, in the order the block
/// walks them (channel pair, kernel row, column), one word per output
/// channel: `packed[((cp * rows + r) * k + kx) * cout + co]` holds
/// `(w[co][2 cp][ky][kx], w[co][2 cp + 1][ky][kx])`, low half first (0 for a
/// channel past the last).
fn pack_weights(layer: &Conv2d<'_, i16>, ky_lo: usize, ky_hi: usize, packed: &mut [i32]) {
    let (k, cin, cout) = (layer.k, layer.cin, layer.cout);
    let wt = |co: usize, ci: usize, ky: usize, kx: usize| -> i32 {
        if ci < cin {
            ld(layer.weights[((co * cin + ci) * k + ky) * k + kx])
        } else {
            0
        }
    };
    let mut i = 0;
    for cp in 0..cin.div_ceil(2) {
        for ky in ky_lo..ky_hi {
            for kx in 0..k {
                for co in 0..cout {
                    let (a, b) = (wt(co, 2 * cp, ky, kx), wt(co, 2 * cp + 1, ky, kx));
                    packed[i] = ((a as u16 as u32) | ((b as u16 as u32) << 16)) as i32;
                    i += 1;
                }
            }
        }
    }
}

/// Where an output row's input rows are: ring slot of each valid kernel row.
struct Rows<'a> {
    ring: *const i32,
    slots: &'a [usize],
    cpn: usize,
    rw: usize,
}

/// Output channels `co0 .. co0 + OB`, columns `x .. x + 16` (those below
/// the width are stored) of band row `yo`, for kernel size `K`.
///
/// # Safety
/// AVX2; `0 < s <= 31`; the rows held and packed for this output row; `wp`
/// points at channel `co0` of the packed weights.
#[inline]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn block<const OB: usize, const K: usize>(
    layer: &Conv2d<'_, i16>,
    rows: &Rows<'_>,
    wp: *const i32,
    s: i32,
    dst: &mut ViewMut<'_, i16>,
    co0: usize,
    yo: usize,
    x: usize,
) {
    let zero = _mm256_setzero_si256();
    // a0: pixels x .. x + 8, a1: x + 8 .. x + 16.
    let mut a0 = [zero; OB];
    let mut a1 = [zero; OB];
    let cout = layer.cout;
    let mut wq = wp;
    // Word offsets of the slots' rows of channel pair 0.
    let mut at = [0usize; 5];
    for (a, &slot) in at.iter_mut().zip(rows.slots) {
        *a = slot * rows.cpn * rows.rw + x;
    }
    let at = &at[..rows.slots.len()];
    let mut pair = rows.ring;
    for _ in 0..rows.cpn {
        for &a in at {
            // SAFETY (the body): ring words x + kx .. x + kx + 16 of a held
            // row (caller); weight words of this pair and channels.
            unsafe {
                let row = pair.add(a);
                for kx in 0..K {
                    let v0 = _mm256_loadu_si256(row.add(kx) as *const __m256i);
                    let v1 = _mm256_loadu_si256(row.add(kx + 8) as *const __m256i);
                    for o in 0..OB {
                        let wv = _mm256_set1_epi32(*wq.add(o));
                        a0[o] = _mm256_add_epi32(a0[o], _mm256_madd_epi16(v0, wv));
                        a1[o] = _mm256_add_epi32(a1[o], _mm256_madd_epi16(v1, wv));
                    }
                    // An empty asm statement per accumulator pair: the
                    // compiler may no longer re-associate the integer sums
                    // across taps (it summed two taps' products before
                    // adding them in, needing more registers than there are
                    // and spilling six accumulators per tap: 5x5 ran 78 ms
                    // against 72 ms with this, 1280x720, 1 thread).
                    for o in 0..OB {
                        core::arch::asm!(
                            "/* {0} {1} */",
                            inout(ymm_reg) a0[o],
                            inout(ymm_reg) a1[o],
                            options(pure, nomem, nostack, preserves_flags)
                        );
                    }
                    wq = wq.add(cout);
                }
            }
        }
        pair = pair.wrapping_add(rows.rw);
    }
    // Rounded half up without overflow for any s >= 1: ((acc >> (s - 1)) + 1) >> 1
    // equals (acc + 2^(s-1)) >> s, and its terms stay in range.
    let one = _mm256_set1_epi32(1);
    let sh = _mm_cvtsi32_si128(s - 1);
    let lim = _mm256_set1_epi32(super::PRE_ACT_MAX as i32);
    let nlim = _mm256_set1_epi32(-super::PRE_ACT_MAX as i32);
    let n = (dst.width() - x).min(16);
    for o in 0..OB {
        let co = co0 + o;
        let bias = _mm256_set1_epi32(layer.bias.map_or(0, |bb| ld(bb[co])));
        let round = |a: __m256i| _mm256_srai_epi32::<1>(_mm256_add_epi32(_mm256_sra_epi32(a, sh), one));
        let mut l = _mm256_add_epi32(round(a0[o]), bias);
        let mut r = _mm256_add_epi32(round(a1[o]), bias);
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
        // packs gives l0-3 r0-3 | l4-7 r4-7; the permute restores the order.
        let packed = _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_packs_epi32(l, r));
        let out = _mm256_max_epi16(packed, _mm256_set1_epi16(-QMAX as i16));
        // SAFETY: columns x .. x + n of the row (n = 16 unless the row ends).
        unsafe {
            let d = dst.ptr_mut(co, yo).add(x);
            if n == 16 {
                _mm256_storeu_si256(d as *mut __m256i, out);
            } else {
                let mut t = [0i16; 16];
                _mm256_storeu_si256(t.as_mut_ptr() as *mut __m256i, out);
                core::ptr::copy_nonoverlapping(t.as_ptr(), d, n);
            }
        }
    }
}

//! AVX-512 fixed-point convolution: the AVX2 scheme ([`super::avx2`]) at
//! thirty-two pixels a block. Taps go in pairs, the two input rows are
//! interleaved per 128-bit lane and multiplied-and-added with each output
//! channel's broadcast weight pair: `vpdpwssd` (AVX512-VNNI, 32 products
//! into 16 sums per instruction) where the CPU has it, `vpmaddwd` + `vpaddd`
//! otherwise; both are the same exact i32 sums, so the output is the same
//! bits as every other path. Blocks of up to seven output channels keep 14
//! accumulators in registers; border columns use the scalar pixel.

use core::arch::x86_64::*;

use super::{pack_pairs, row_taps, scalar_columns, shift, Block, Tap};
use crate::conv::{Activation, Conv2d};
use crate::fixed::{ld, KERNEL_FRAC, QMAX};
use crate::view::{View, ViewMut};

const MAX_OB: usize = 7;

/// Values of one edge strip: `cin k (32 + k - 1)` is largest for `k = 1`
/// under the 400-tap bound (`400 x 32`).
const STRIP: usize = 400 * 32;

/// # Safety
/// AVX-512 F/BW/DQ/VL and AVX2 must be supported; with `vnni`, AVX512-VNNI too.
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
pub(crate) unsafe fn forward(
    layer: &Conv2d<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    packed: &mut [i32],
    vnni: bool,
) {
    let (w, h) = (src.width(), src.height());
    let k = layer.k;
    let p = k / 2;
    let s = shift(layer, src, dst);
    let nblocks = layer.cout.div_ceil(MAX_OB);
    // A right shift of 1 to 31 bits (rounded without overflow in `block`).
    let vec_ok = s > 0 && s <= 31;
    let mut taps = [Tap::default(); 16 * 25];
    let mut packed_for = None::<(usize, usize)>;
    // The edges: the image's first and last 32 + p columns of the k rows of
    // an output row, zero-padded by p columns outside the image, so that
    // the border pixels run the same blocks (with taps into the strips).
    let sw = 32 + 2 * p;
    let strip_len = layer.cin * k * sw;
    let mut strips = [[0i16; STRIP]; 2];
    let mut staps = [Tap::default(); 16 * 25];
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let (nt, ky_lo, ky_hi) = row_taps(layer, y, h, &mut taps);
        let fits = nt <= taps.len() && nt.div_ceil(2) * layer.cout <= packed.len();
        if vec_ok && fits && packed_for != Some((ky_lo, ky_hi)) {
            pack_pairs(layer, nt, ky_lo, ky_hi, packed);
            packed_for = Some((ky_lo, ky_hi));
        }
        let edges = vec_ok && fits && strip_len <= STRIP && w >= sw;
        if edges {
            let top = y as isize - p as isize;
            for ci in 0..layer.cin {
                for r in 0..k {
                    let o = (ci * k + r) * sw;
                    let sy = top + r as isize;
                    let [left, right] = &mut strips;
                    let (left, right) = (&mut left[o..o + sw], &mut right[o..o + sw]);
                    if sy < 0 || sy as usize >= h {
                        left.fill(0);
                        right.fill(0);
                        continue;
                    }
                    let row = src.row(ci, sy as usize);
                    left[..p].fill(0);
                    left[p..].copy_from_slice(&row[..32 + p]);
                    right[..32 + p].copy_from_slice(&row[w - 32 - p..]);
                    right[32 + p..].fill(0);
                }
            }
            for (st, tp) in staps[..nt].iter_mut().zip(&taps[..nt]) {
                *st = Tap { ci: tp.ci, sy: (tp.sy as isize - top) as usize, kx: tp.kx };
            }
        }
        let [sl, sr] = &strips;
        let left = View::new(&sl[..strip_len], layer.cin, sw, k).map(|v| v.with_frac(src.frac()));
        let right = View::new(&sr[..strip_len], layer.cin, sw, k).map(|v| v.with_frac(src.frac()));
        let npairs = nt.div_ceil(2);
        let mut co0 = 0;
        for b in 0..nblocks {
            let ob = layer.cout / nblocks + usize::from(b < layer.cout % nblocks);
            let mut x = p;
            if vec_ok && fits {
                let ctx = Block { src, taps: &taps[..nt], packed: &packed[co0 * npairs..], npairs, x: 0, xo: 0, s, p };
                macro_rules! run {
                    ($ob:literal) => {{
                        let go = |bl: &Block<'_, '_>, dst: &mut ViewMut<'_, i16>| {
                            // SAFETY: the columns of the block are inside the row (below).
                            unsafe {
                                if vnni {
                                    block_vnni::<$ob>(layer, bl, dst, co0, yo)
                                } else {
                                    block_bw::<$ob>(layer, bl, dst, co0, yo)
                                }
                            }
                        };
                        if let (true, Ok(lv), Ok(rv)) = (edges, &left, &right) {
                            // Output columns 0 .. 32 and w - 32 .. w from the strips.
                            let st = &staps[..nt];
                            go(&Block { src: lv, taps: st, x: p, xo: 0, ..ctx }, dst);
                            go(&Block { src: rv, taps: st, x: p, xo: w - 32, ..ctx }, dst);
                            x = 32;
                        }
                        while x + 32 + p <= w {
                            // Columns x - p .. x + 32 + p are inside the row.
                            go(&Block { x, xo: x, ..ctx }, dst);
                            x += 32;
                        }
                        // The tail: one more block ending at the last interior column,
                        // overlapping the previous one (same values written twice).
                        if x < w - p && w >= 32 + 2 * p {
                            go(&Block { x: w - p - 32, xo: w - p - 32, ..ctx }, dst);
                            x = w - p;
                        }
                        if edges {
                            x = w;
                        }
                    }};
                }
                match ob {
                    1 => run!(1),
                    2 => run!(2),
                    3 => run!(3),
                    4 => run!(4),
                    5 => run!(5),
                    6 => run!(6),
                    _ => run!(7),
                }
            }
            if !(edges && x == w) {
                scalar_columns(layer, src, dst, (co0, ob), (y, yo), x, s);
            }
            co0 += ob;
        }
    }
}

/// # Safety
/// AVX-512 F/BW/DQ/VL and AVX512-VNNI; as [`block`].
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx512vnni,avx2,fma")]
unsafe fn block_vnni<const OB: usize>(
    layer: &Conv2d<'_, i16>,
    b: &Block<'_, '_>,
    dst: &mut ViewMut<'_, i16>,
    co0: usize,
    yo: usize,
) {
    // SAFETY: forwarded.
    unsafe { block::<OB, true>(layer, b, dst, co0, yo) }
}

/// # Safety
/// AVX-512 F/BW/DQ/VL; as [`block`].
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn block_bw<const OB: usize>(
    layer: &Conv2d<'_, i16>,
    b: &Block<'_, '_>,
    dst: &mut ViewMut<'_, i16>,
    co0: usize,
    yo: usize,
) {
    // SAFETY: forwarded.
    unsafe { block::<OB, false>(layer, b, dst, co0, yo) }
}

/// Output channels `co0 .. co0 + OB`, pixels `x .. x + 32` of row `yo`.
///
/// # Safety
/// AVX-512 (and VNNI when `VNNI`); columns `x - p .. x + 32 + p` inside the
/// image; `0 < s <= 31`; `packed` holds `OB * npairs` pairs.
#[inline(always)]
unsafe fn block<const OB: usize, const VNNI: bool>(
    layer: &Conv2d<'_, i16>,
    b: &Block<'_, '_>,
    dst: &mut ViewMut<'_, i16>,
    co0: usize,
    yo: usize,
) {
    // SAFETY: only reached through block_vnni / block_bw, whose target
    // features cover every intrinsic here (VNNI only when VNNI is set).
    unsafe {
        let zero = _mm512_setzero_si512();
        let mut lo = [zero; OB];
        let mut hi = [zero; OB];
        let (x, p) = (b.x, b.p);
        let floor = _mm512_set1_epi16(-QMAX as i16);
        let load = |t: usize| -> __m512i {
            match b.taps.get(t) {
                // SAFETY: in range (caller); -32768 reads as -32767.
                Some(tp) => {
                    _mm512_max_epi16(_mm512_loadu_si512(b.src.ptr(tp.ci, tp.sy).add(x + tp.kx - p) as *const _), floor)
                }
                None => zero,
            }
        };
        assert!(b.packed.len() >= OB * b.npairs);
        let wp = b.packed.as_ptr();
        for pi in 0..b.npairs {
            let (xa, xb) = (load(2 * pi), load(2 * pi + 1));
            let il = _mm512_unpacklo_epi16(xa, xb);
            let ih = _mm512_unpackhi_epi16(xa, xb);
            for o in 0..OB {
                // SAFETY: o * npairs + pi < OB * npairs <= packed.len() (asserted).
                let wv = _mm512_set1_epi32(*wp.add(o * b.npairs + pi));
                if VNNI {
                    lo[o] = _mm512_dpwssd_epi32(lo[o], il, wv);
                    hi[o] = _mm512_dpwssd_epi32(hi[o], ih, wv);
                } else {
                    lo[o] = _mm512_add_epi32(lo[o], _mm512_madd_epi16(il, wv));
                    hi[o] = _mm512_add_epi32(hi[o], _mm512_madd_epi16(ih, wv));
                }
            }
        }
        let s = b.s;
        // ((acc >> (s - 1)) + 1) >> 1 = (acc + 2^(s-1)) >> s, without overflow.
        let one = _mm512_set1_epi32(1);
        let sh = _mm_cvtsi32_si128(s - 1);
        let round = |a: __m512i| _mm512_srai_epi32::<1>(_mm512_add_epi32(_mm512_sra_epi32(a, sh), one));
        for o in 0..OB {
            let co = co0 + o;
            let bias = _mm512_set1_epi32(layer.bias.map_or(0, |bb| ld(bb[co])));
            let lim = _mm512_set1_epi32(super::PRE_ACT_MAX as i32);
            let nlim = _mm512_set1_epi32(-super::PRE_ACT_MAX as i32);
            let clampv = |v: __m512i| _mm512_max_epi32(_mm512_min_epi32(v, lim), nlim);
            let mut l = clampv(_mm512_add_epi32(round(lo[o]), bias));
            let mut r = clampv(_mm512_add_epi32(round(hi[o]), bias));
            match layer.act {
                Activation::Identity => {}
                Activation::Relu => {
                    l = _mm512_max_epi32(l, zero);
                    r = _mm512_max_epi32(r, zero);
                }
                Activation::LeakyRelu(sl) => {
                    let q = _mm512_set1_epi32(crate::fixed::from_f32(sl, KERNEL_FRAC) as i32);
                    let rnd = _mm512_set1_epi32(1 << (KERNEL_FRAC - 1));
                    let leak = |v: __m512i| {
                        let m = _mm512_srai_epi32::<{ KERNEL_FRAC as u32 }>(_mm512_add_epi32(
                            _mm512_mullo_epi32(v, q),
                            rnd,
                        ));
                        _mm512_mask_blend_epi32(_mm512_cmpgt_epi32_mask(v, zero), m, v)
                    };
                    l = leak(l);
                    r = leak(r);
                }
            }
            // packs works per 128-bit lane, undoing the unpack's lane split.
            let out = _mm512_max_epi16(_mm512_packs_epi32(l, r), floor);
            // SAFETY: xo + 32 <= the output's width.
            _mm512_storeu_si512(dst.ptr_mut(co, yo).add(b.xo) as *mut _, out);
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::vec::Vec;

    use super::*;

    /// The `vpdpwssd` and `vpmaddwd` + `vpaddd` kernels give the same bits
    /// (only one of them runs through the public API on a given CPU).
    #[test]
    fn vnni_and_bw_kernels_agree() {
        if !crate::isa::avx512_vnni() {
            std::eprintln!("skipped: AVX512-VNNI is not supported on this CPU");
            return;
        }
        let (w, h, cin, cout, k) = (75usize, 4usize, 5usize, 9usize, 3usize);
        let mut seed = 0x2545_f491_u32;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        let src: Vec<i16> = (0..cin * w * h).map(|_| (next() % 60001) as i16 - 30000).collect();
        let weights: Vec<i16> = (0..cout * cin * k * k).map(|_| (next() % 801) as i16 - 400).collect();
        let bias: Vec<i16> = (0..cout as i16).map(|i| i * 91 - 300).collect();
        for act in [Activation::Identity, Activation::Relu, Activation::LeakyRelu(0.1)] {
            let layer = Conv2d { k, cin, cout, weights: &weights, bias: Some(&bias), act, weight_frac: 10 };
            let sv = View::new(&src, cin, w, h).unwrap().with_frac(8);
            let run = |vnni: bool, fill: i16| {
                let mut out = std::vec![fill; cout * w * h];
                let mut packed = std::vec![0i32; crate::conv::conv2d_scratch_len::<crate::Fixed>(k, cin, cout, w)];
                let mut dv = ViewMut::new(&mut out, cout, w, h).unwrap().with_frac(6);
                // SAFETY: AVX-512 and VNNI were checked above.
                unsafe { forward(&layer, &sv, &mut dv, 0, &mut packed, vnni) };
                out
            };
            assert_eq!(run(true, 1111), run(false, -2222), "{act:?}");
        }
    }
}

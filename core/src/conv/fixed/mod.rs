//! Convolution in fixed point: i16 weights and activations, exact i32 sums
//! (the layer check bounds them below 2^31), `>> (w + in - out)` rounded half
//! up, plus the bias (output format), activation, saturation. Exact integer
//! sums do not depend on their order, so every path gives the same bits.

use crate::conv::{Activation, Conv2d};
use crate::fixed::{ld, sat16, shr_round, KERNEL_FRAC};
use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;

pub(crate) fn forward(
    isa: crate::isa::Supported,
    layer: &Conv2d<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    scratch: &mut [i32],
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 => unsafe { avx2::forward(layer, src, dst, y0, scratch) },
        // The AVX-512 kernel holds at most 400 taps (cin k^2) and wants rows
        // of 32 + k - 1 pixels; anything else runs the AVX2 kernel, which
        // takes any channel count and width (not the scalar pixel).
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA; VNNI is probed here.
        Isa::Avx512 if layer.cin * layer.k * layer.k <= 16 * 25 && src.width() >= 32 + layer.k - 1 => unsafe {
            avx512::forward(layer, src, dst, y0, scratch, crate::isa::avx512_vnni())
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: AVX-512 implies AVX2, FMA and F16C (the token checked them).
        Isa::Avx512 => unsafe { avx2::forward(layer, src, dst, y0, scratch) },
        _ => {
            let _ = scratch;
            scalar::forward(layer, src, dst, y0)
        }
    }
}

/// Words of one ring row of the AVX2 kernel: columns `-p .. round_up(w,
/// 16) + p`, so the sixteen-pixel block at any `x < w` (a multiple of 16)
/// reads inside.
pub(crate) fn ring_row(w: usize, p: usize) -> usize {
    w.div_ceil(16).saturating_mul(16).saturating_add(2 * p)
}

/// Words of packed weight pairs by channel pair: one per output channel,
/// channel pair and tap (at least the tap-pair packing's
/// `cout * ceil(cin k^2 / 2)` the AVX-512 kernel uses).
pub(crate) fn weight_words(k: usize, cin: usize, cout: usize) -> usize {
    cout.saturating_mul(cin.div_ceil(2)).saturating_mul(k.saturating_mul(k))
}

/// Scratch words of the fixed-point convolution: the weight pairs, then the
/// AVX2 kernel's ring of `k` input rows of every channel pair.
pub(crate) fn scratch_len(k: usize, cin: usize, cout: usize, width: usize) -> usize {
    let ring = k.saturating_mul(cin.div_ceil(2)).saturating_mul(ring_row(width, k / 2));
    weight_words(k, cin, cout).saturating_add(ring)
}

/// One valid tap of an output row: input plane, input row, column offset.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
#[derive(Clone, Copy, Default)]
pub(crate) struct Tap {
    pub(crate) ci: usize,
    pub(crate) sy: usize,
    pub(crate) kx: usize,
}

/// The taps of output row `y` that fall inside the image, in `(ci, ky, kx)`
/// order, into `taps` (as many as fit). Returns their count (possibly more
/// than `taps.len()`) and the kernel rows `ky_lo .. ky_hi` they come from.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) fn row_taps(layer: &Conv2d<'_, i16>, y: usize, h: usize, taps: &mut [Tap]) -> (usize, usize, usize) {
    let (k, p) = (layer.k, layer.k / 2);
    let ky_lo = p.saturating_sub(y);
    let ky_hi = k.min(h + p - y);
    let mut nt = 0;
    for ci in 0..layer.cin {
        for ky in ky_lo..ky_hi {
            for kx in 0..k {
                if let Some(t) = taps.get_mut(nt) {
                    *t = Tap { ci, sy: y + ky - p, kx };
                }
                nt += 1;
            }
        }
    }
    (nt, ky_lo, ky_hi)
}

/// Weight pairs of the `nt` valid taps (kernel rows `ky_lo .. ky_hi`) per
/// output channel, `(w_2i, w_2i+1)` as one i32 (low half first), at
/// `packed[co * npairs + i]`; an odd count ends with a zero weight.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) fn pack_pairs(layer: &Conv2d<'_, i16>, nt: usize, ky_lo: usize, ky_hi: usize, packed: &mut [i32]) {
    let k = layer.k;
    let per = layer.cin * k * k;
    let npairs = nt.div_ceil(2);
    for co in 0..layer.cout {
        let widx = |n: usize| -> i32 {
            if n >= nt {
                return 0;
            }
            let (ci, r) = (n / ((ky_hi - ky_lo) * k), n % ((ky_hi - ky_lo) * k));
            let (ky, kx) = (ky_lo + r / k, r % k);
            ld(layer.weights[co * per + (ci * k + ky) * k + kx])
        };
        for pi in 0..npairs {
            let (a, b) = (widx(2 * pi), widx(2 * pi + 1));
            packed[co * npairs + pi] = ((a as u16 as u32) | ((b as u16 as u32) << 16)) as i32;
        }
    }
}

/// What a SIMD block kernel reads: the input, the row's valid taps and
/// their packed weight pairs, the block's first column, the shift, `k / 2`.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Block<'c, 'a> {
    pub(crate) src: &'c View<'a, i16>,
    pub(crate) taps: &'c [Tap],
    pub(crate) packed: &'c [i32],
    pub(crate) npairs: usize,
    /// The block's first column in `src`.
    pub(crate) x: usize,
    /// The block's first column in the output (`x` but for the edge strips).
    pub(crate) xo: usize,
    pub(crate) s: i32,
    pub(crate) p: usize,
}

/// The scalar pixel for output channels `co0 .. co0 + ob` of row `y` (band
/// row `yo`) at the `p` left border columns and from column `from` on: what
/// the SIMD blocks of a row leave.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn scalar_columns(
    layer: &Conv2d<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    (co0, ob): (usize, usize),
    (y, yo): (usize, usize),
    from: usize,
    s: i32,
) {
    let (w, p) = (src.width(), layer.k / 2);
    for co in co0..co0 + ob {
        for xx in (0..p.min(w)).chain(from.max(p.min(w))..w) {
            let acc = scalar::pixel(layer, src, co, y, xx);
            dst.row_mut(co, yo)[xx] = finish(layer, co, acc, s);
        }
    }
}

/// Bound of pre-activation values (2^17 - 1).
pub(crate) const PRE_ACT_MAX: i64 = (1 << 17) - 1;

/// The accumulator's right shift to the output format.
pub(crate) fn shift(layer: &Conv2d<'_, i16>, src: &View<'_, i16>, dst: &ViewMut<'_, i16>) -> i32 {
    layer.weight_frac as i32 + src.frac() as i32 - dst.frac() as i32
}

/// Accumulator to output: shift, bias, activation, saturation.
#[inline(always)]
pub(crate) fn finish(layer: &Conv2d<'_, i16>, co: usize, acc: i32, shift: i32) -> i16 {
    let v = shr_round(acc as i64, shift) + layer.bias.map_or(0, |b| ld(b[co]) as i64);
    // Pre-activation values are clamped to four times the storage range, so
    // the slope multiply fits i32 in every path (it saturates anyway for
    // identity and ReLU).
    let v = v.clamp(-PRE_ACT_MAX, PRE_ACT_MAX);
    let v = match layer.act {
        Activation::Identity => v,
        Activation::Relu => v.max(0),
        Activation::LeakyRelu(s) => {
            if v > 0 {
                v
            } else {
                // The slope in Q1.14 (exact for 0.1 to within 2^-15).
                shr_round(v * crate::fixed::from_f32(s, KERNEL_FRAC) as i64, KERNEL_FRAC as i32)
            }
        }
    };
    sat16(v)
}

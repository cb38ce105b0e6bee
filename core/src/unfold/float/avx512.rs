//! AVX-512 unfold: the AVX2 scheme ([`super::avx2`]) at sixteen lanes. One
//! tap row at a time over the output row (`k` kernel-plane streams), partial
//! sums in a row buffer of the scratch; 32 or 16 pixels a chunk, the row's
//! last chunk under a lane mask (so no chunk overlaps another and one buffer
//! is enough). Border rows and the `k/2` border columns use the scalar code;
//! f16 source rows are widened once into the AVX2 path's ring (same scratch).

use core::arch::x86_64::*;

use super::{avx2, scalar};
use crate::precision::FloatElement;
use crate::simd::avx512::{first_lanes, load16_mask, store16_mask};
use crate::view::{View, ViewMut};

/// How far ahead (in elements) the kernel planes are prefetched.
const PREFETCH: usize = 128;

/// # Safety
/// The CPU must support AVX-512 F/BW/DQ/VL, AVX2, FMA and F16C.
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
pub(crate) unsafe fn run<S: FloatElement>(
    k: usize,
    kernel: &View<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    let (w, h, ch) = (src.width(), src.height(), src.channels());
    let r = k / 2;
    let (acc, rest) = scratch.split_at_mut(ch * w);
    let ring = &mut rest[ch * w..];
    let mut held = [usize::MAX; 16]; // image row in each ring slot
    for yo in 0..dst.height() {
        let y = y0 + yo;
        if y < r || y + r >= h || w <= 2 * r {
            scalar::row::<S, f32>(k, kernel, src, dst, y0, yo, acc);
            continue;
        }
        let mut srows = [[core::ptr::null::<f32>(); 15]; 4];
        let mut srows_s = [[core::ptr::null::<S>(); 15]; 4];
        if S::IS_F16 {
            for sy in y - r..=y + r {
                if held[sy % k] != sy {
                    avx2::fill_slot(src, sy, k, ring);
                    held[sy % k] = sy;
                }
            }
        }
        let mut c0 = 0;
        while c0 < ch {
            let n = (ch - c0).min(4);
            for c in 0..n {
                for ky in 0..k {
                    let sy = y - r + ky;
                    if S::IS_F16 {
                        srows[c][ky] = ring[((sy % k) * ch + c0 + c) * w..].as_ptr();
                    } else {
                        srows_s[c][ky] = src.ptr(c0 + c, sy);
                    }
                }
            }
            let (lo, hi) = (r, w - r);
            for ky in 0..k {
                let part = Part { ky, first: ky == 0, last: ky + 1 == k, buf: acc.as_mut_ptr(), w };
                let mut x = lo;
                while x + 32 <= hi {
                    // SAFETY: y is an interior row; columns x - r .. x + 32 + r are inside.
                    unsafe { dispatch(k, n, true, 0xffff, &part, kernel, &srows, &srows_s, dst, y, yo, c0, x) };
                    x += 32;
                }
                while x < hi {
                    let m = first_lanes(hi - x);
                    // SAFETY: as above for the lanes of m (x + lane < w - r).
                    unsafe { dispatch(k, n, false, m, &part, kernel, &srows, &srows_s, dst, y, yo, c0, x) };
                    x += 16;
                }
            }
            for c in c0..c0 + n {
                for x in (0..r).chain(w - r..w) {
                    let v = scalar::pixel(k, kernel, src, c, y, x);
                    dst.row_mut(c, yo)[x] = S::from_f32(v);
                }
            }
            c0 += n;
        }
    }
}

/// Which tap row a chunk adds; the partial sums live in `buf` (`w` values
/// per channel of the block, channel `c` at `c * w`).
struct Part {
    ky: usize,
    first: bool,
    last: bool,
    buf: *mut f32,
    w: usize,
}

/// [`chunk16`] for the run-time `k` and channel count `n`.
///
/// # Safety
/// As for [`chunk16`].
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn dispatch<S: FloatElement>(
    k: usize,
    n: usize,
    wide: bool,
    m: __mmask16,
    part: &Part,
    kernel: &View<'_, S>,
    srows: &[[*const f32; 15]; 4],
    srows_s: &[[*const S; 15]; 4],
    dst: &mut ViewMut<'_, S>,
    y: usize,
    yo: usize,
    c0: usize,
    x: usize,
) {
    macro_rules! go {
        ($($kk:literal),*) => {
            match (k, n, wide) {
                $(
                    ($kk, 1, false) => chunk16::<S, $kk, 1, 1>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, 2, false) => chunk16::<S, $kk, 2, 1>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, 3, false) => chunk16::<S, $kk, 3, 1>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, _, false) => chunk16::<S, $kk, 4, 1>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, 1, true) => chunk16::<S, $kk, 1, 2>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, 2, true) => chunk16::<S, $kk, 2, 2>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, 3, true) => chunk16::<S, $kk, 3, 2>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                    ($kk, _, true) => chunk16::<S, $kk, 4, 2>(m, part, kernel, srows, srows_s, dst, y, yo, c0, x),
                )*
                _ => unreachable!("k is checked odd in 1..=15"),
            }
        };
    }
    // SAFETY: forwarded from the caller.
    unsafe { go!(1, 3, 5, 7, 9, 11, 13, 15) }
}

/// Tap row `part.ky` of `16 V` interior pixels from `x` of row `y` (with
/// `V = 1` only the lanes of `m`), channels `c0 .. c0 + N`: partial sums from
/// the buffer (none for the first tap row) plus this row's taps, back to the
/// buffer or, for the last tap row, to the output.
///
/// # Safety
/// AVX-512/FMA/F16C; every tap of the pixels inside the image; the row
/// pointers valid for columns `x - K/2 .. x + 16 V + K/2` (the lanes of
/// `m`); the buffer holds `N * part.w` values.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn chunk16<S: FloatElement, const K: usize, const N: usize, const V: usize>(
    m: __mmask16,
    part: &Part,
    kernel: &View<'_, S>,
    srows: &[[*const f32; 15]; 4],
    srows_s: &[[*const S; 15]; 4],
    dst: &mut ViewMut<'_, S>,
    y: usize,
    yo: usize,
    c0: usize,
    x: usize,
) {
    let r = K / 2;
    let ky = part.ky;
    let kstride = kernel.plane_stride();
    let kp = kernel.ptr(0, y).wrapping_add(ky * K * kstride);
    let line = 64 / core::mem::size_of::<S>();
    for j in 0..K {
        let p = kp.wrapping_add(j * kstride + x + PREFETCH);
        let mut off = 0;
        while off < 16 * V {
            _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(off) as *const i8);
            off += line;
        }
    }
    let mask = |v: usize| if V == 1 && v == 0 { m } else { 0xffff };
    let mut acc = [[_mm512_setzero_ps(); V]; N];
    if !part.first {
        for (c, a) in acc.iter_mut().enumerate() {
            for (v, av) in a.iter_mut().enumerate() {
                // SAFETY: c * w + x + lane < N * w for the lanes of mask(v).
                *av = unsafe { _mm512_maskz_loadu_ps(mask(v), part.buf.add(c * part.w + x + 16 * v)) };
            }
        }
    }
    for kx in 0..K {
        for v in 0..V {
            let xv = x + 16 * v;
            let mv = mask(v);
            // SAFETY: plane ky*K+kx exists and the lanes of mv are < w.
            let kv = unsafe { load16_mask(kp.add(kx * kstride + xv), mv) };
            for c in 0..N {
                // SAFETY: columns xv - r + kx + lane are inside the row (caller).
                let sv = unsafe {
                    if S::IS_F16 {
                        _mm512_maskz_loadu_ps(mv, srows[c][ky].add(xv + kx - r))
                    } else {
                        load16_mask(srows_s[c][ky].add(xv + kx - r), mv)
                    }
                };
                acc[c][v] = _mm512_fmadd_ps(kv, sv, acc[c][v]);
            }
        }
    }
    for c in 0..N {
        for v in 0..V {
            // SAFETY: the lanes of mask(v) are below w.
            unsafe {
                if part.last {
                    store16_mask(dst.ptr_mut(c0 + c, yo).add(x + 16 * v), mask(v), acc[c][v]);
                } else {
                    _mm512_mask_storeu_ps(part.buf.add(c * part.w + x + 16 * v), mask(v), acc[c][v]);
                }
            }
        }
    }
}

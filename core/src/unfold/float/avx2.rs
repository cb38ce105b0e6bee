//! AVX2 + FMA unfold. Rows whose taps all stay inside the image run a
//! register-blocked kernel: eight (or sixteen) output pixels, up to four
//! channels accumulated in registers, one tap row at a time over the whole
//! output row, so only `k` kernel planes stream at once, each as a long run
//! (all `k^2` at once, 49 streams for 7x7, measured a third slower: more
//! streams than the memory system keeps in flight). The partial sums of the
//! tap rows so far wait in two row buffers in the scratch (f32, exact, same
//! FMA sequence per pixel as accumulating in registers). Near the top and
//! bottom the tap rows outside the image are skipped; the first eight
//! columns and the ones past the last whole chunk load their taps under a
//! lane mask (outside taps read as 0), the last chunk ending at the row's end
//! and overlapping the one before. Rows narrower than eight use the scalar
//! code. (The scalar border pixel took 30 % of an f16 frame.)
//!
//! With f16 storage the source rows are widened to f32 once, into a ring of
//! `k` rows in the scratch, so each source value is converted once instead of
//! once per tap (`k^2` times); the kernel map is converted as it streams.

use core::arch::x86_64::*;

use super::scalar;
use crate::precision::FloatElement;
use crate::simd::avx2::{load8, load8_range, store8};
use crate::view::{View, ViewMut};

/// How far ahead (in bytes) the kernel planes are prefetched.
const PF_BYTES: usize = 512;

/// Scratch words of the AVX2 path: the scalar row accumulator, plus (f16)
/// the ring of widened source rows.
pub(crate) fn scratch_len(k: usize, channels: usize, width: usize, f16: bool) -> usize {
    let row = channels.saturating_mul(width);
    // Two row accumulators (ping-pong between tap rows), then the ring.
    if f16 {
        row.saturating_mul(k.saturating_add(2))
    } else {
        row.saturating_mul(2)
    }
}

/// Widens row `sy` of every channel into ring slot `sy % k`.
#[target_feature(enable = "avx2,fma,f16c")]
pub(super) fn fill_slot<S: FloatElement>(src: &View<'_, S>, sy: usize, k: usize, ring: &mut [f32]) {
    let (w, ch) = (src.width(), src.channels());
    let slot = sy % k;
    for c in 0..ch {
        let row = src.row(c, sy);
        let out = &mut ring[(slot * ch + c) * w..(slot * ch + c + 1) * w];
        let mut x = 0;
        while x + 8 <= w {
            // SAFETY: x + 8 <= w for both rows.
            unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(x), load8(row.as_ptr().add(x))) };
            x += 8;
        }
        for x in x..w {
            out[x] = row[x].to_f32();
        }
    }
}

/// # Safety
/// The CPU must support AVX2, FMA and F16C.
#[target_feature(enable = "avx2,fma,f16c")]
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
    let (acc2, ring) = rest.split_at_mut(ch * w);
    let mut held = [usize::MAX; 16]; // image row in each ring slot
    for yo in 0..dst.height() {
        let y = y0 + yo;
        if w < 8 {
            scalar::row::<S, f32>(k, kernel, src, dst, y0, yo, acc);
            continue;
        }
        // The tap rows inside the image (all but near the top and bottom).
        let ky_lo = r.saturating_sub(y);
        let ky_hi = k.min(h + r - y);
        // Row pointers of the k source rows, per channel.
        let mut srows = [[core::ptr::null::<f32>(); 15]; 4];
        let mut srows_s = [[core::ptr::null::<S>(); 15]; 4];
        if S::IS_F16 {
            for sy in y + ky_lo - r..y + ky_hi - r {
                if held[sy % k] != sy {
                    fill_slot(src, sy, k, ring);
                    held[sy % k] = sy;
                }
            }
        }
        let mut c0 = 0;
        while c0 < ch {
            let n = (ch - c0).min(4);
            for c in 0..n {
                for ky in ky_lo..ky_hi {
                    let sy = y + ky - r;
                    if S::IS_F16 {
                        srows[c][ky] = ring[((sy % k) * ch + c0 + c) * w..].as_ptr();
                    } else {
                        srows_s[c][ky] = src.ptr(c0 + c, sy);
                    }
                }
            }
            // One tap row at a time (k kernel planes in flight instead of
            // k^2, each read as a long run), the partial sums carried in two
            // row buffers that swap roles after each tap row, so an
            // overlapping chunk reads what the row before left and writes
            // the same values again. Tap rows outside the image are skipped
            // (they add nothing).
            for ky in ky_lo..ky_hi {
                let (src_acc, dst_acc) = if ky % 2 == 0 { (&*acc2, &mut *acc) } else { (&*acc, &mut *acc2) };
                let part = Part {
                    ky,
                    first: ky == ky_lo,
                    last: ky + 1 == ky_hi,
                    from: src_acc.as_ptr(),
                    to: dst_acc.as_mut_ptr(),
                    w,
                };
                // SAFETY: tap rows ky_lo .. ky_hi are inside; the row
                // pointers cover every column the chunks read.
                unsafe { dispatch(k, n, &part, kernel, &srows, &srows_s, dst, y, yo, c0) };
            }
            c0 += n;
        }
    }
}

/// Which tap row a chunk adds, and where its partial sums come from and go
/// (row buffers of `w` values per channel, channel `c` of the block at `c * w`).
struct Part {
    ky: usize,
    first: bool,
    last: bool,
    from: *const f32,
    to: *mut f32,
    w: usize,
}

/// [`tap_row`] for the run-time `k` and channel count `n` (one dispatch per
/// tap row, not per chunk: the per-chunk match and pointer reloads were a
/// fifth of the f16 frame's instructions).
///
/// # Safety
/// As for [`tap_row`].
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn dispatch<S: FloatElement>(
    k: usize,
    n: usize,
    part: &Part,
    kernel: &View<'_, S>,
    srows: &[[*const f32; 15]; 4],
    srows_s: &[[*const S; 15]; 4],
    dst: &mut ViewMut<'_, S>,
    y: usize,
    yo: usize,
    c0: usize,
) {
    macro_rules! go {
        ($($kk:literal),*) => {
            match (k, n) {
                $(
                    ($kk, 1) => tap_row::<S, $kk, 1>(part, kernel, srows, srows_s, dst, y, yo, c0),
                    ($kk, 2) => tap_row::<S, $kk, 2>(part, kernel, srows, srows_s, dst, y, yo, c0),
                    ($kk, 3) => tap_row::<S, $kk, 3>(part, kernel, srows, srows_s, dst, y, yo, c0),
                    ($kk, _) => tap_row::<S, $kk, 4>(part, kernel, srows, srows_s, dst, y, yo, c0),
                )*
                _ => unreachable!("k is checked odd in 1..=15"),
            }
        };
    }
    // SAFETY: forwarded from the caller.
    unsafe { go!(1, 3, 5, 7, 9, 11, 13, 15) }
}

/// Tap row `part.ky` over a whole output row (`w >= 8`): the first eight
/// columns with masked taps, then sixteen pixels a step (two independent
/// FMA chains per channel), then eight, then masked chunks to the row's end
/// (the last one ending at `w`, overlapping the one before).
///
/// # Safety
/// As for [`chunk8`], for every chunk of the row.
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn tap_row<S: FloatElement, const K: usize, const N: usize>(
    part: &Part,
    kernel: &View<'_, S>,
    srows: &[[*const f32; 15]; 4],
    srows_s: &[[*const S; 15]; 4],
    dst: &mut ViewMut<'_, S>,
    y: usize,
    yo: usize,
    c0: usize,
) {
    let (r, w) = (K / 2, part.w);
    // SAFETY (every chunk): columns x - r .. x + 8 (16) + r are inside, or
    // (EDGE) the source loads are masked.
    unsafe {
        if r > 0 {
            chunk8::<S, K, N, 1, true>(part, kernel, srows, srows_s, dst, y, yo, c0, 0);
        } else {
            chunk8::<S, K, N, 1, false>(part, kernel, srows, srows_s, dst, y, yo, c0, 0);
        }
        let mut x = 8;
        while x + 16 + r <= w {
            chunk8::<S, K, N, 2, false>(part, kernel, srows, srows_s, dst, y, yo, c0, x);
            x += 16;
        }
        while x + 8 + r <= w {
            chunk8::<S, K, N, 1, false>(part, kernel, srows, srows_s, dst, y, yo, c0, x);
            x += 8;
        }
        while x < w {
            let xc = x.min(w - 8);
            chunk8::<S, K, N, 1, true>(part, kernel, srows, srows_s, dst, y, yo, c0, xc);
            x = xc + 8;
        }
    }
}

/// Tap row `part.ky` of `8 V` interior pixels from `x` of row `y`, channels
/// `c0 .. c0 + N`: the partial sums of the rows above (`part.from`, none for
/// the first) plus this row's taps, to `part.to` or, for the last tap row,
/// to the output. Source rows come from `srows` (widened f32) for f16
/// storage, `srows_s` (the storage itself) otherwise.
///
/// # Safety
/// AVX2/FMA/F16C; every tap of the eight pixels inside the image; the row
/// pointers valid for columns `x - K/2 .. x + 8 + K/2`; the part buffers
/// hold `N * part.w` values.
#[inline]
#[target_feature(enable = "avx2,fma,f16c")]
#[allow(clippy::too_many_arguments)]
unsafe fn chunk8<S: FloatElement, const K: usize, const N: usize, const V: usize, const EDGE: bool>(
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
    // Each kernel plane of the row is its own stream: fetch each one's line
    // PF_BYTES ahead, once per 64-byte line: by the chunk whose columns
    // `x .. x + 8 V` hold a multiple of the line's values (16 f32, 32 f16).
    // (Was `x % 16 < 8`, which the wide chunks, at 8 mod 16, never met.)
    let line = 64 / core::mem::size_of::<S>();
    if x.is_multiple_of(line) || x % line + 8 * V > line {
        for j in 0..K {
            _mm_prefetch::<_MM_HINT_T0>(
                kp.wrapping_add(j * kstride + x + PF_BYTES / core::mem::size_of::<S>()) as *const i8
            );
        }
    }
    // N channels times V vectors of independent FMA chains.
    let mut acc = [[_mm256_setzero_ps(); V]; N];
    if !part.first {
        for (c, a) in acc.iter_mut().enumerate() {
            for (v, av) in a.iter_mut().enumerate() {
                // SAFETY: c * w + x + 8 V <= N * w.
                *av = unsafe { _mm256_loadu_ps(part.from.add(c * part.w + x + 8 * v)) };
            }
        }
    }
    let w = part.w as isize;
    for kx in 0..K {
        for v in 0..V {
            let xv = x + 8 * v;
            // SAFETY: plane ky*K+kx exists and xv + 8 <= w.
            let kv = unsafe { load8(kp.add(kx * kstride + xv)) };
            // First column of the taps; under EDGE, the in-image lanes.
            let c0s = xv as isize + kx as isize - r as isize;
            let (lo, hi) = ((-c0s).clamp(0, 8) as usize, (w - c0s).clamp(0, 8) as usize);
            for c in 0..N {
                // SAFETY: columns c0s .. + 8 inside the row (caller), or
                // (EDGE) only the in-image lanes are read.
                let sv = unsafe {
                    match (S::IS_F16, EDGE) {
                        (true, false) => _mm256_loadu_ps(srows[c][ky].offset(c0s)),
                        (true, true) => load8_range(srows[c][ky].wrapping_offset(c0s), lo, hi.max(lo)),
                        (false, false) => load8(srows_s[c][ky].offset(c0s)),
                        (false, true) => load8_range(srows_s[c][ky].wrapping_offset(c0s), lo, hi.max(lo)),
                    }
                };
                acc[c][v] = _mm256_fmadd_ps(kv, sv, acc[c][v]);
            }
        }
    }
    for c in 0..N {
        for v in 0..V {
            // SAFETY: x + 8 V <= w.
            unsafe {
                if part.last {
                    store8(dst.ptr_mut(c0 + c, yo).add(x + 8 * v), acc[c][v]);
                } else {
                    _mm256_storeu_ps(part.to.add(c * part.w + x + 8 * v), acc[c][v]);
                }
            }
        }
    }
}

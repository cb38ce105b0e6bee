//! The softmax operators in fixed point.
//!
//! Logits are read in any format and brought to Q7.8; `e^(l - shift)` comes
//! from `exp_q8` in Q.16 (branch-free, so its rows vectorise); window
//! sums are exact `i64` sums, so the box-sum path can sum in any order (column
//! sums slid down the tile, then window sums along a row) without
//! cancellation error. A tile shares one shift (its grid cell's maximum, as
//! in the float path); a window whose weight sum is below [`TINY_Q16`] (every
//! weight at least ~10 nats under the tile maximum, where Q.16 has under 10
//! bits left) is recomputed with its own maximum. A ratio is a product with
//! one reciprocal per window, rounded to nearest (see [`RECIP`]).
//!
//! The box-sum path is one body compiled for each instruction set, its row
//! loops written to vectorise, so every ISA gives the same bits; on the SIMD
//! paths the reciprocals' divisions are f64 divisions corrected to the exact
//! integer quotient. The portable path uses integer operations only.

use super::{FusedInputs, WindowPath, MAX_CHANNELS, MAX_FUSED};
use crate::fixed::{exp_q8, ld, mul_recip, rescale, sat16, shr_round, LOGIT_FRAC, QMAX};
use crate::view::{View, ViewMut};

/// A box-sum window with a weight sum below this (Q.16: 2^10 = 1/64) is recomputed directly.
pub const TINY_Q16: i64 = 1 << 10;
/// Output rows per tile (the same grid as the float path).
const TILE_H: usize = super::float::TILE_H;
/// Output columns per tile.
const TILE_W: usize = super::float::TILE_W;

/// A logit in Q7.8 (any input format; the i16 range bounds it, and a
/// generous clamp keeps differences of two logits inside i32).
#[inline(always)]
fn logit8(v: i16, frac: i8) -> i32 {
    rescale(ld(v) as i64, frac as i32, LOGIT_FRAC as i32).clamp(-(1 << 28), 1 << 28) as i32
}

/// Reciprocals stand in for divisions: `num / den` is `num * floor(2^RECIP / den) / 2^RECIP`,
/// rounded half away from zero ([`mul_recip`]), one division per window instead of
/// one per channel. With `|num| <= 32767 den` (a weighted mean of stored values)
/// the product stays below 2^62, and `den < 2^24` keeps 23 bits in the
/// reciprocal: the result is within 0.004 of the exact ratio before rounding.
const RECIP: u32 = 47;
/// The fusion weights' reciprocal shift: `e <= 2^16` over a sum in
/// `[2^16, 2^19]`, so `2^40 / sum` keeps 21 bits and `e * inv < 2^40`.
const RECIP_ALPHA: u32 = 40;

/// `floor(2^shift / den)` for `1 <= den < 2^31` and `shift <= 47`. With
/// `FLOAT`, from the f64 quotient, which is within 2^-16 of the exact one
/// (a quotient below 2^47 with 53-bit rounding) and never rounds below an
/// integer under it, so its truncation is the floor or one more; the
/// remainder's sign tells which. The same value as the integer division.
#[inline(always)]
fn recip_exact<const FLOAT: bool>(shift: u32, den: i64) -> i64 {
    let n = 1i64 << shift;
    if FLOAT {
        let q = (n as f64 / den as f64) as i64;
        if n - q * den < 0 {
            q - 1
        } else {
            q
        }
    } else {
        n / den
    }
}

/// `logit8` of a row of stored values, with the common formats (a right
/// shift of 1 to 62 bits, or a left shift of up to 20) in loops that vectorise.
#[inline(always)]
fn logits_row(src: &[i16], frac: i8, out: &mut [i64]) {
    let s = frac as i32 - LOGIT_FRAC as i32;
    let lim = 1i64 << 28;
    if s > 0 && s < 63 {
        let half = 1i64 << (s - 1);
        for (o, &v) in out.iter_mut().zip(src) {
            *o = ((ld(v) as i64 + half) >> s).clamp(-lim, lim);
        }
    } else if (-20..=0).contains(&s) {
        for (o, &v) in out.iter_mut().zip(src) {
            *o = ((ld(v) as i64) << -s).clamp(-lim, lim);
        }
    } else {
        for (o, &v) in out.iter_mut().zip(src) {
            *o = logit8(v, frac) as i64;
        }
    }
}

/// Softmax weights of the `m` fusion logits at a pixel, Q.16 (as [`fusion_weights`]).
fn alphas(f: &View<'_, i16>, y: usize, x: usize, out: &mut [i64; MAX_FUSED]) {
    let m = f.channels();
    let mut mx = i32::MIN;
    for i in 0..m {
        mx = mx.max(logit8(f.at(i, y, x), f.frac()));
    }
    let mut e = [0i64; MAX_FUSED];
    let mut sum = 0i64;
    for i in 0..m {
        e[i] = exp_q8(logit8(f.at(i, y, x), f.frac()) - mx) as i64;
        sum += e[i];
    }
    let inv = (1i64 << RECIP_ALPHA) / sum; // sum >= 2^16: the maximum's weight is 1
    for i in 0..m {
        out[i] = (e[i] * inv + (1 << 23)) >> 24;
    }
}

/// The fusion weights of a tile, Q.16, into `alpha` (`m` planes of `th x tw`),
/// a row at a time; `tmp` holds `(m + 2) * tw` words. The same arithmetic as [`alphas`].
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn fusion_weights<const FLOAT_DIV: bool>(
    f: Option<&View<'_, i16>>,
    m: usize,
    y: usize,
    th: usize,
    tx: usize,
    tw: usize,
    alpha: &mut [i64],
    tmp: &mut [i64],
) {
    let Some(f) = f else {
        alpha[..m * th * tw].fill(1 << 16);
        return;
    };
    let (lg, rest) = tmp.split_at_mut(m * tw);
    let (mx, rest) = rest.split_at_mut(tw);
    let sum = &mut rest[..tw];
    for t in 0..th {
        mx.fill(i64::MIN);
        for i in 0..m {
            let l = &mut lg[i * tw..(i + 1) * tw];
            logits_row(&f.row(i, y + t)[tx..tx + tw], f.frac(), l);
            for (a, &b) in mx.iter_mut().zip(l.iter()) {
                *a = (*a).max(b);
            }
        }
        sum.fill(0);
        for i in 0..m {
            for ((l, &a), s) in lg[i * tw..(i + 1) * tw].iter_mut().zip(mx.iter()).zip(sum.iter_mut()) {
                *l = exp_q8((*l - a) as i32) as i64;
                *s += *l;
            }
        }
        for s in sum.iter_mut() {
            *s = recip_exact::<FLOAT_DIV>(RECIP_ALPHA, *s);
        }
        for i in 0..m {
            let row = &mut alpha[(i * th + t) * tw..(i * th + t + 1) * tw];
            for ((a, &e), &inv) in row.iter_mut().zip(&lg[i * tw..(i + 1) * tw]).zip(sum.iter()) {
                *a = (e * inv + (1 << 23)) >> 24;
            }
        }
    }
}

/// Direct window of size `k` at `(y, x)` with the window's own maximum:
/// `R_c` in the radiance's format.
fn direct_window(
    k: usize,
    imp: &View<'_, i16>,
    plane: usize,
    rad: &View<'_, i16>,
    y: usize,
    x: usize,
    out: &mut [i64; MAX_CHANNELS],
) {
    let (w, h) = (rad.width(), rad.height());
    let r = k / 2;
    let (ylo, yhi, xlo, xhi) = (y.saturating_sub(r), (y + r + 1).min(h), x.saturating_sub(r), (x + r + 1).min(w));
    let mut m = i32::MIN;
    for yy in ylo..yhi {
        for xx in xlo..xhi {
            m = m.max(logit8(imp.at(plane, yy, xx), imp.frac()));
        }
    }
    let ch = rad.channels();
    let mut den = 0i64;
    let mut num = [0i64; MAX_CHANNELS];
    for yy in ylo..yhi {
        for xx in xlo..xhi {
            let e = exp_q8(logit8(imp.at(plane, yy, xx), imp.frac()) - m) as i64;
            den += e;
            for c in 0..ch {
                num[c] += e * ld(rad.at(c, yy, xx)) as i64;
            }
        }
    }
    // den >= 65536: the maximum's weight is exp(0) = 1.
    let inv = (1i64 << RECIP) / den;
    for c in 0..ch {
        out[c] = mul_recip(num[c], inv, RECIP);
    }
}

/// Combines per-size results with the fusion weights and albedo into the output's format.
fn emit(
    inp: &FusedInputs<'_, i16>,
    acc: &[i64; MAX_CHANNELS],
    y: usize,
    x: usize,
    dst: &mut ViewMut<'_, i16>,
    yo: usize,
) {
    let (fr, fd) = (inp.radiance.frac() as i32, dst.frac() as i32);
    for c in 0..inp.radiance.channels() {
        // acc: Q.(16 + fr).
        let v = match &inp.albedo {
            Some(a) => shr_round(acc[c] * ld(a.at(c, y, x)) as i64, 16 + fr + a.frac() as i32 - fd),
            None => shr_round(acc[c], 16 + fr - fd),
        };
        dst.row_mut(c, yo)[x] = sat16(v);
    }
}

fn pixel_direct(inp: &FusedInputs<'_, i16>, y: usize, x: usize) -> [i64; MAX_CHANNELS] {
    let mut alpha = [1i64 << 16; MAX_FUSED];
    if let Some(f) = &inp.fusion {
        alphas(f, y, x, &mut alpha);
    }
    let mut acc = [0i64; MAX_CHANNELS];
    for (i, &k) in inp.sizes.iter().enumerate() {
        let mut rr = [0i64; MAX_CHANNELS];
        direct_window(k, &inp.importance, i, &inp.radiance, y, x, &mut rr);
        for c in 0..inp.radiance.channels() {
            acc[c] += alpha[i] * rr[c];
        }
    }
    acc
}

/// Scratch words of the box-sum path: `i64` (two words each) prefix tables
/// for one size, plus the tile's accumulators and fusion weights.
pub(crate) fn boxsum_scratch_len(sizes: &[usize], channels: usize, width: usize) -> usize {
    let rmax = sizes.iter().copied().max().unwrap_or(1) / 2;
    let tw = width.min(TILE_W);
    let halo = rmax.saturating_mul(2).saturating_add(1);
    let tables = crate::sat_prod(&[channels.saturating_add(1), TILE_H.saturating_add(halo), tw.saturating_add(halo)]);
    let tile = crate::sat_prod(&[channels.saturating_add(sizes.len()), TILE_H, tw]);
    let rows = rowbuf_words(tw, rmax);
    // +1: the i64 tables start on an 8-byte boundary inside the f32 scratch.
    crate::sat_sum(&[crate::sat_prod(&[2, crate::sat_sum(&[tables, tile, rows])]), 1])
}

/// Row buffers of the box-sum path: the column sums of every plane, a row of
/// window sums, of their weights and of reciprocals; the fusion weights'
/// logits, maxima and sums.
fn rowbuf_words(tw: usize, rmax: usize) -> usize {
    let cols = tw.saturating_add(rmax.saturating_mul(2));
    crate::sat_sum(&[crate::sat_prod(&[MAX_CHANNELS + 1, cols]), crate::sat_prod(&[MAX_FUSED + 4, tw])])
}

pub(crate) fn fused(
    isa: crate::isa::Supported,
    path: WindowPath,
    inp: &FusedInputs<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    scratch: &mut [f32],
) {
    match path {
        WindowPath::Direct => {
            for yo in 0..dst.height() {
                for x in 0..dst.width() {
                    let acc = pixel_direct(inp, y0 + yo, x);
                    emit(inp, &acc, y0 + yo, x, dst, yo);
                }
            }
        }
        // Integer sums are exact, so the separable order gives the same result.
        WindowPath::BoxSum | WindowPath::Separable => {
            // Skip a word if the scratch is not 8-byte aligned (it is 4-byte aligned).
            let off = usize::from(!(scratch.as_ptr() as usize).is_multiple_of(8)).min(scratch.len());
            let words = (scratch.len() - off) / 2 * 2;
            match bytemuck::try_cast_slice_mut(&mut scratch[off..off + words]) {
                Ok(s) => boxsum(isa, inp, dst, y0, s),
                Err(_) => unreachable!("an 8-byte aligned even-length f32 slice casts to i64"),
            }
        }
    }
}

/// The box-sum path on `isa`: one body, compiled for each instruction set
/// (the loops over a row are written to vectorise), so every ISA gives the
/// same bits.
fn boxsum(
    isa: crate::isa::Supported,
    inp: &FusedInputs<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    scratch: &mut [i64],
) {
    #[cfg(target_arch = "x86_64")]
    match isa.isa() {
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        crate::Isa::Avx512 => return unsafe { boxsum_avx512(inp, dst, y0, scratch) },
        // SAFETY: as above.
        crate::Isa::Avx2 => return unsafe { boxsum_avx2(inp, dst, y0, scratch) },
        crate::Isa::Scalar => {}
    }
    let _ = isa;
    boxsum_body::<false>(inp, dst, y0, scratch)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn boxsum_avx2(inp: &FusedInputs<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize, scratch: &mut [i64]) {
    boxsum_body::<true>(inp, dst, y0, scratch)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn boxsum_avx512(inp: &FusedInputs<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize, scratch: &mut [i64]) {
    boxsum_body::<true>(inp, dst, y0, scratch)
}

/// Tile by tile on the fixed grid; per size, the rows of `e` and `e * r_c`
/// over the tile and its halo, then for each output row the column sums over
/// the window's rows (slid down by one row's add and one's subtract) and the
/// window sums along the row (`k` shifted adds), the reciprocals and the
/// weighted means. Integer sums are exact, so the order does not matter.
///
/// `FLOAT_DIV`: the reciprocals' divisions as f64 divisions corrected to the
/// exact integer quotient ([`recip_exact`]; the SIMD paths, where they
/// vectorise), else integer divisions (the portable path, for CPUs without
/// an FPU). The quotients, and so the outputs, are the same bits either way.
#[inline(always)]
fn boxsum_body<const FLOAT_DIV: bool>(
    inp: &FusedInputs<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
    scratch: &mut [i64],
) {
    let rad = &inp.radiance;
    let imp = &inp.importance;
    let (w, h, ch) = (rad.width(), rad.height(), rad.channels());
    let np = 1 + ch;
    let m = inp.sizes.len();
    let rmax = inp.sizes.iter().copied().max().unwrap_or(1) / 2;
    let y_end = y0 + dst.height();
    let mut y = y0;
    while y < y_end {
        let cell = y - y % TILE_H;
        let th = (cell + TILE_H).min(y_end) - y;
        let mut tx = 0;
        while tx < w {
            let tw = TILE_W.min(w - tx);
            let (acc, rest) = scratch.split_at_mut(ch * th * tw);
            let (alpha, rest) = rest.split_at_mut(m * th * tw);
            let (rowbuf, sat) = rest.split_at_mut(rowbuf_words(tw, rmax));
            acc.fill(0);
            fusion_weights::<FLOAT_DIV>(inp.fusion.as_ref(), m, y, th, tx, tw, alpha, rowbuf);
            for (i, &k) in inp.sizes.iter().enumerate() {
                let r = k / 2;
                // Shift: the maximum over the grid cell and halo (as the float
                // path); `logit8` is monotonic, so it is that of the largest stored value.
                let (cx0, cx1) = (tx.saturating_sub(r), (tx + tw + r).min(w));
                let mut top = i16::MIN;
                for yy in cell.saturating_sub(r)..(cell + TILE_H + r).min(h) {
                    top = imp.row(i, yy)[cx0..cx1].iter().fold(top, |a, &v| a.max(v));
                }
                let shift = logit8(top, imp.frac()) as i64;
                let d = 2 * r + 1;
                let (rows, cols) = (th + 2 * r, tw + 2 * r);
                // Halo column b is image column tx - r + b; halo row a image row y - r + a.
                let b_lo = r.saturating_sub(tx).min(cols);
                let b_hi = (w + r - tx).min(cols).max(b_lo);
                let (colsum, rest) = rowbuf.split_at_mut(np * cols);
                let (hrow, rest) = rest.split_at_mut(tw);
                let (den, rest) = rest.split_at_mut(tw);
                let inv = &mut rest[..tw];
                let plane = rows * cols;
                // The weights and weighted values of every halo row (0 outside the image).
                for a in 0..rows {
                    let yy = y as isize - r as isize + a as isize;
                    let (e_rows, v_rows) = sat.split_at_mut(plane);
                    let e = &mut e_rows[a * cols..(a + 1) * cols];
                    if yy < 0 || yy as usize >= h {
                        e.fill(0);
                        for q in 1..np {
                            v_rows[(q - 1) * plane + a * cols..(q - 1) * plane + (a + 1) * cols].fill(0);
                        }
                        continue;
                    }
                    let yy = yy as usize;
                    let x_lo = tx + b_lo - r;
                    let n = b_hi - b_lo;
                    e[..b_lo].fill(0);
                    e[b_hi..].fill(0);
                    logits_row(&imp.row(i, yy)[x_lo..x_lo + n], imp.frac(), &mut e[b_lo..b_hi]);
                    for v in e[b_lo..b_hi].iter_mut() {
                        *v = exp_q8((*v - shift) as i32) as i64;
                    }
                    for q in 1..np {
                        let row = &mut v_rows[(q - 1) * plane + a * cols..(q - 1) * plane + (a + 1) * cols];
                        row[..b_lo].fill(0);
                        row[b_hi..].fill(0);
                        let rr = &rad.row(q - 1, yy)[x_lo..x_lo + n];
                        for ((o, &ev), &v) in row[b_lo..b_hi].iter_mut().zip(&e[b_lo..b_hi]).zip(rr) {
                            // e <= 2^16 and |v| <= 32767: the product fits i32.
                            *o = ev * ld(v) as i64;
                        }
                    }
                }
                // Column sums over the window's rows, slid down one output row at a time.
                for q in 0..np {
                    let cs = &mut colsum[q * cols..(q + 1) * cols];
                    cs.copy_from_slice(&sat[q * plane..q * plane + cols]);
                    for a in 1..d {
                        let row = &sat[q * plane + a * cols..q * plane + (a + 1) * cols];
                        for (s, &v) in cs.iter_mut().zip(row) {
                            *s += v;
                        }
                    }
                }
                for t in 0..th {
                    if t > 0 {
                        for q in 0..np {
                            let cs = &mut colsum[q * cols..(q + 1) * cols];
                            let add = &sat[q * plane + (t + d - 1) * cols..q * plane + (t + d) * cols];
                            let sub = &sat[q * plane + (t - 1) * cols..q * plane + t * cols];
                            for ((s, &a), &b) in cs.iter_mut().zip(add).zip(sub) {
                                *s += a - b;
                            }
                        }
                    }
                    // Window sums along the row: d shifted column sums.
                    window_row(&colsum[..cols], d, den);
                    for (iv, &dv) in inv.iter_mut().zip(den.iter()) {
                        let q = recip_exact::<FLOAT_DIV>(RECIP, dv.max(1));
                        *iv = if dv >= TINY_Q16 { q } else { 0 };
                    }
                    let al = &alpha[(i * th + t) * tw..(i * th + t + 1) * tw];
                    for c in 0..ch {
                        window_row(&colsum[(1 + c) * cols..(2 + c) * cols], d, hrow);
                        let ac = &mut acc[(c * th + t) * tw..(c * th + t + 1) * tw];
                        for (((a, &num), &iv), &w) in ac.iter_mut().zip(hrow.iter()).zip(inv.iter()).zip(al) {
                            *a += w * mul_recip(num, iv, RECIP);
                        }
                    }
                    // Windows whose weights all lie far under the shift: their own maximum.
                    for xo in 0..tw {
                        if den[xo] < TINY_Q16 {
                            let mut rr = [0i64; MAX_CHANNELS];
                            direct_window(k, imp, i, rad, y + t, tx + xo, &mut rr);
                            for c in 0..ch {
                                acc[(c * th + t) * tw + xo] += al[xo] * rr[c];
                            }
                        }
                    }
                }
            }
            for t in 0..th {
                emit_row(inp, &acc[..ch * th * tw], th, t, tx, tw, y + t, dst, y + t - y0);
            }
            tx += tw;
        }
        y += th;
    }
}

/// `out[x] = sum of src[x .. x + d]` for every `x` of `out` (`src` holds
/// `out.len() + d - 1` values): 8 outputs at a time summed in a register
/// (one vector on AVX-512, two on AVX2), the rest one by one.
#[inline(always)]
fn window_row(src: &[i64], d: usize, out: &mut [i64]) {
    const L: usize = 8;
    let n = out.len();
    let mut x = 0;
    while x + L <= n {
        let mut acc = [0i64; L];
        for j in 0..d {
            let s: &[i64; L] = src[x + j..x + j + L].try_into().expect("L values");
            for l in 0..L {
                acc[l] += s[l];
            }
        }
        out[x..x + L].copy_from_slice(&acc);
        x += L;
    }
    for (o, xx) in out[x..].iter_mut().zip(x..) {
        *o = src[xx..xx + d].iter().sum();
    }
}

/// [`emit`] for a tile row: `acc` holds `ch` planes of `th x tw`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn emit_row(
    inp: &FusedInputs<'_, i16>,
    acc: &[i64],
    th: usize,
    t: usize,
    tx: usize,
    tw: usize,
    y: usize,
    dst: &mut ViewMut<'_, i16>,
    yo: usize,
) {
    let (fr, fd) = (inp.radiance.frac() as i32, dst.frac() as i32);
    for c in 0..inp.radiance.channels() {
        let a = &acc[(c * th + t) * tw..(c * th + t + 1) * tw];
        let (alb, s) = match &inp.albedo {
            Some(al) => (Some(&al.row(c, y)[tx..tx + tw]), 16 + fr + al.frac() as i32 - fd),
            None => (None, 16 + fr - fd),
        };
        let out = &mut dst.row_mut(c, yo)[tx..tx + tw];
        match alb {
            Some(alb) if s > 0 && s < 63 => {
                let half = 1i64 << (s - 1);
                for ((o, &v), &d) in out.iter_mut().zip(a).zip(alb) {
                    *o = ((v * ld(d) as i64 + half) >> s).clamp(-(QMAX as i64), QMAX as i64) as i16;
                }
            }
            Some(alb) => {
                for ((o, &v), &d) in out.iter_mut().zip(a).zip(alb) {
                    *o = sat16(shr_round(v * ld(d) as i64, s));
                }
            }
            None => {
                for (o, &v) in out.iter_mut().zip(a) {
                    *o = sat16(shr_round(v, s));
                }
            }
        }
    }
}

/// A weight `e / den` in the output format `fo` (`den >= 2^16`, the largest
/// `e` being 1 in Q.16), saturated, given `inv = 2^46 / den` (at least 22
/// bits for `den < 2^24`; `e * inv < 2^47`): one division per window, not
/// per weight, for the formats a weight is stored in; a division otherwise.
#[inline(always)]
fn normalised(e: i64, den: i64, inv: i64, fo: i32) -> i16 {
    let sh = 46 - fo;
    if (1..63).contains(&sh) {
        sat16((e * inv + (1i64 << (sh - 1))) >> sh)
    } else {
        sat16(crate::fixed::div_round(shr_round(e, -fo), den))
    }
}

/// Materialised kernels: Q1.14 weights of the window around each pixel.
pub(crate) fn kernels(k: usize, logits: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (w, h) = (logits.width(), logits.height());
    let r = k / 2;
    let fo = dst.frac() as i32;
    let mut e = [0i64; 15 * 15];
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for x in 0..w {
            let tap = |j: usize| {
                let sy = (y + j / k).checked_sub(r).filter(|&v| v < h);
                let sx = (x + j % k).checked_sub(r).filter(|&v| v < w);
                sy.zip(sx)
            };
            let mut m = i32::MIN;
            for j in 0..k * k {
                if let Some((sy, sx)) = tap(j) {
                    m = m.max(logit8(logits.at(0, sy, sx), logits.frac()));
                }
            }
            let mut den = 0i64;
            for j in 0..k * k {
                e[j] = tap(j).map_or(0, |(sy, sx)| exp_q8(logit8(logits.at(0, sy, sx), logits.frac()) - m) as i64);
                den += e[j];
            }
            let inv = (1i64 << 46) / den;
            for j in 0..k * k {
                dst.row_mut(j, yo)[x] = normalised(e[j], den, inv, fo);
            }
        }
    }
}

/// Channel softmax: weights in the output's format. A row at a time in
/// chunks of [`CHUNK`] pixels (one body per instruction set, the loops over
/// a chunk written to vectorise): the largest stored logit (`logit8` is
/// monotonic), the sum of the weights, one reciprocal per pixel, then each
/// channel's weight again and its product with the reciprocal.
pub(crate) fn channel(isa: crate::isa::Supported, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
    #[cfg(target_arch = "x86_64")]
    match isa.isa() {
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        crate::Isa::Avx512 => return unsafe { channel_avx512(src, dst) },
        // SAFETY: as above.
        crate::Isa::Avx2 => return unsafe { channel_avx2(src, dst) },
        crate::Isa::Scalar => {}
    }
    let _ = isa;
    channel_body::<false>(src, dst)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn channel_avx2(src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
    channel_body::<true>(src, dst)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
unsafe fn channel_avx512(src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
    channel_body::<true>(src, dst)
}

/// Pixels per chunk of the channel softmax.
const CHUNK: usize = 64;

#[inline(always)]
fn channel_body<const FLOAT_DIV: bool>(src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
    let n = src.channels();
    let (w, fi, fo) = (src.width(), src.frac(), dst.frac() as i32);
    // The sum of the weights is below n 2^16; the float reciprocal wants it below 2^31.
    let float_div = FLOAT_DIV && n < 1 << 14;
    let sh = 46 - fo;
    let mut top = [0i16; CHUNK];
    let mut mx = [0i64; CHUNK];
    let mut l = [0i64; CHUNK];
    let mut den = [0i64; CHUNK];
    for y in 0..src.height() {
        let mut x0 = 0;
        while x0 < w {
            let cw = CHUNK.min(w - x0);
            top[..cw].copy_from_slice(&src.row(0, y)[x0..x0 + cw]);
            for c in 1..n {
                for (t, &v) in top[..cw].iter_mut().zip(&src.row(c, y)[x0..x0 + cw]) {
                    *t = (*t).max(v);
                }
            }
            logits_row(&top[..cw], fi, &mut mx[..cw]);
            den[..cw].fill(0);
            for c in 0..n {
                logits_row(&src.row(c, y)[x0..x0 + cw], fi, &mut l[..cw]);
                for ((d, &v), &m) in den[..cw].iter_mut().zip(&l[..cw]).zip(&mx[..cw]) {
                    *d += exp_q8((v - m) as i32) as i64;
                }
            }
            // den >= 2^16: the maximum's weight is 1. `l` takes the reciprocals.
            let mut inv = [0i64; CHUNK];
            for (iv, &d) in inv[..cw].iter_mut().zip(&den[..cw]) {
                *iv = if float_div { recip_exact::<true>(46, d) } else { (1i64 << 46) / d };
            }
            for c in 0..n {
                logits_row(&src.row(c, y)[x0..x0 + cw], fi, &mut l[..cw]);
                let out = &mut dst.row_mut(c, y)[x0..x0 + cw];
                if (1..63).contains(&sh) {
                    let half = 1i64 << (sh - 1);
                    for (((o, &v), &m), &iv) in out.iter_mut().zip(&l[..cw]).zip(&mx[..cw]).zip(&inv[..cw]) {
                        let e = exp_q8((v - m) as i32) as i64;
                        *o = ((e * iv + half) >> sh).clamp(-(QMAX as i64), QMAX as i64) as i16;
                    }
                } else {
                    for (i, o) in out.iter_mut().enumerate() {
                        let e = exp_q8((l[i] - mx[i]) as i32) as i64;
                        *o = normalised(e, den[i], inv[i], fo);
                    }
                }
            }
            x0 += cw;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn branch_free_exp_is_the_exp2_composition_bit_for_bit() {
        // The composition exp_q8 replaced: exp2_q8 of x log2(e) rounded in i64.
        let reference = |x: i32| {
            let y = crate::fixed::shr_round(x as i64 * 23637, 14);
            crate::fixed::exp2_q8(y.max(i32::MIN as i64) as i32)
        };
        for x in -80_000..=300 {
            assert_eq!(exp_q8(x), reference(x), "x = {x}");
        }
        for x in [i32::MIN / 2, -(1 << 29), 1 << 28] {
            assert_eq!(exp_q8(x), reference(x), "x = {x}");
        }
    }

    #[test]
    fn float_reciprocal_is_the_integer_quotient() {
        // Every divisor up to 2^20, then a sweep up to 2^31 with the
        // neighbours of powers of two and of divisors of 2^47.
        extern crate std;
        let mut dens: std::vec::Vec<i64> = (1..1 << 20).collect();
        let mut d = 1i64 << 20;
        while d < 1 << 31 {
            dens.extend([d - 1, d, d + 1, d + 7919]);
            d = d * 9 / 8 + 1;
        }
        for shift in [RECIP, RECIP_ALPHA, 46] {
            for &den in &dens {
                assert_eq!(recip_exact::<true>(shift, den), (1i64 << shift) / den, "2^{shift} / {den}");
                assert_eq!(recip_exact::<false>(shift, den), (1i64 << shift) / den);
            }
        }
    }

    #[test]
    fn reciprocal_product_is_the_rounded_ratio() {
        // Against the exact rounded quotient over the ranges the callers guarantee:
        // |num| <= 32767 den, 1024 <= den < 2^24.
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for _ in 0..200_000 {
            let den = 1024 + (next() % ((1 << 24) - 1024)) as i64;
            let num = (next() % (2 * 32767 * den as u64 + 1)) as i64 - 32767 * den;
            let inv = recip_exact::<false>(RECIP, den);
            let got = mul_recip(num, inv, RECIP);
            let exact = num as f64 / den as f64;
            assert!((got as f64 - exact).abs() <= 0.5 + 0.004, "{num} / {den}: {got} against {exact}");
        }
    }
}

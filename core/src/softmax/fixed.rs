//! The softmax operators in fixed point (portable integer code on every ISA).
//!
//! Logits are read in any format and brought to Q7.8; `e^(l - shift)` comes
//! from [`exp_q8`] in Q.16; window sums are exact `i64` sums, so the box-sum
//! path can use summed-area tables (prefix sums): an integer difference of
//! prefix sums has no cancellation error, and the cost per pixel does not grow
//! with `k`. A tile shares one shift (its grid cell's maximum, as in the
//! float path); a window whose weight sum is below [`TINY_Q16`] (every weight
//! at least ~10 nats under the tile maximum, where Q.16 has under 10 bits
//! left) is recomputed with its own maximum. Ratios use an integer division
//! rounded to nearest (the reciprocal for normalisation).

use super::{FusedInputs, WindowPath, MAX_CHANNELS, MAX_FUSED};
use crate::fixed::{div_round, exp_q8, ld, rescale, sat16, shr_round, LOGIT_FRAC};
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

/// Softmax weights of the `m` fusion logits at a pixel, Q.16.
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
    for i in 0..m {
        out[i] = div_round(e[i] << 16, sum);
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
    for c in 0..ch {
        out[c] = div_round(num[c], den);
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
    // +1: the i64 tables start on an 8-byte boundary inside the f32 scratch.
    crate::sat_sum(&[crate::sat_prod(&[2, tables.saturating_add(tile)]), 1])
}

pub(crate) fn fused(
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
                Ok(s) => boxsum(inp, dst, y0, s),
                Err(_) => unreachable!("an 8-byte aligned even-length f32 slice casts to i64"),
            }
        }
    }
}

/// Tile by tile on the fixed grid; per size, summed-area tables of `e` and
/// `e * r_c` over the tile and its halo.
fn boxsum(inp: &FusedInputs<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize, scratch: &mut [i64]) {
    let rad = &inp.radiance;
    let imp = &inp.importance;
    let (w, h, ch) = (rad.width(), rad.height(), rad.channels());
    let np = 1 + ch;
    let m = inp.sizes.len();
    let y_end = y0 + dst.height();
    let mut y = y0;
    while y < y_end {
        let cell = y - y % TILE_H;
        let th = (cell + TILE_H).min(y_end) - y;
        let mut tx = 0;
        while tx < w {
            let tw = TILE_W.min(w - tx);
            let (acc, rest) = scratch.split_at_mut(ch * th * tw);
            let (alpha, sat) = rest.split_at_mut(m * th * tw);
            acc.fill(0);
            for t in 0..th {
                for xo in 0..tw {
                    let mut a = [1i64 << 16; MAX_FUSED];
                    if let Some(f) = &inp.fusion {
                        alphas(f, y + t, tx + xo, &mut a);
                    }
                    for i in 0..m {
                        alpha[(i * th + t) * tw + xo] = a[i];
                    }
                }
            }
            for (i, &k) in inp.sizes.iter().enumerate() {
                let r = k / 2;
                let (ty0, ty1) = (y as isize - r as isize, (y + th + r) as isize);
                let (tx0, tx1) = (tx as isize - r as isize, (tx + tw + r) as isize);
                // Shift: the maximum over the grid cell and halo (as the float path).
                let mut shift = i32::MIN;
                for yy in cell.saturating_sub(r)..(cell + TILE_H + r).min(h) {
                    for xx in (tx0.max(0) as usize)..(tx1.min(w as isize) as usize) {
                        shift = shift.max(logit8(imp.at(i, yy, xx), imp.frac()));
                    }
                }
                let (rows, cols) = ((ty1 - ty0) as usize + 1, (tx1 - tx0) as usize + 1);
                let at = |q: usize, a: usize, b: usize| (q * rows + a) * cols + b;
                for q in 0..np {
                    for b in 0..cols {
                        sat[at(q, 0, b)] = 0;
                    }
                }
                for a in 1..rows {
                    let yy = ty0 + a as isize - 1;
                    let mut run = [0i64; 1 + MAX_CHANNELS];
                    for q in 0..np {
                        sat[at(q, a, 0)] = 0;
                    }
                    for b in 1..cols {
                        let xx = tx0 + b as isize - 1;
                        if yy >= 0 && xx >= 0 && (yy as usize) < h && (xx as usize) < w {
                            let (yu, xu) = (yy as usize, xx as usize);
                            let e = exp_q8(logit8(imp.at(i, yu, xu), imp.frac()) - shift) as i64;
                            run[0] += e;
                            for c in 0..ch {
                                run[1 + c] += e * ld(rad.at(c, yu, xu)) as i64;
                            }
                        }
                        for q in 0..np {
                            sat[at(q, a, b)] = sat[at(q, a - 1, b)] + run[q];
                        }
                    }
                }
                for t in 0..th {
                    for xo in 0..tw {
                        // Window rows t ..= t + 2r, columns xo ..= xo + 2r (table offset 1).
                        let (a0, a1, b0, b1) = (t, t + 2 * r + 1, xo, xo + 2 * r + 1);
                        let sum = |q: usize| {
                            sat[at(q, a1, b1)] - sat[at(q, a0, b1)] - sat[at(q, a1, b0)] + sat[at(q, a0, b0)]
                        };
                        let den = sum(0);
                        let mut rr = [0i64; MAX_CHANNELS];
                        if den >= TINY_Q16 {
                            for c in 0..ch {
                                rr[c] = div_round(sum(1 + c), den);
                            }
                        } else {
                            direct_window(k, imp, i, rad, y + t, tx + xo, &mut rr);
                        }
                        let al = alpha[(i * th + t) * tw + xo];
                        for c in 0..ch {
                            acc[(c * th + t) * tw + xo] += al * rr[c];
                        }
                    }
                }
            }
            for t in 0..th {
                for xo in 0..tw {
                    let mut a = [0i64; MAX_CHANNELS];
                    for c in 0..ch {
                        a[c] = acc[(c * th + t) * tw + xo];
                    }
                    emit(inp, &a, y + t, tx + xo, dst, y + t - y0);
                }
            }
            tx += tw;
        }
        y += th;
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
            for j in 0..k * k {
                dst.row_mut(j, yo)[x] = sat16(div_round(shr_round(e[j], -fo), den));
            }
        }
    }
}

/// Channel softmax: weights in the output's format.
pub(crate) fn channel(src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
    let n = src.channels();
    let fo = dst.frac() as i32;
    for y in 0..src.height() {
        for x in 0..src.width() {
            let mut m = i32::MIN;
            for c in 0..n {
                m = m.max(logit8(src.at(c, y, x), src.frac()));
            }
            let mut den = 0i64;
            for c in 0..n {
                den += exp_q8(logit8(src.at(c, y, x), src.frac()) - m) as i64;
            }
            for c in 0..n {
                let e = exp_q8(logit8(src.at(c, y, x), src.frac()) - m) as i64;
                dst.row_mut(c, y)[x] = sat16(div_round(shr_round(e, -fo), den));
            }
        }
    }
}

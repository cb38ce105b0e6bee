//! Per-pixel noise estimates of a single image (no second estimate):
//! the à-trous methods' colour gate and the single-estimate SURE need the
//! input's noise variance per pixel.
//!
//! - [`local_noise_rows`]: `0.84 |y - median of the 8 neighbours|^2`, mean
//!   over the three channels. The median (not the mean) keeps an edge from
//!   reading as noise: next to a light's edge the neighbours on the other
//!   side are a minority. For white noise `Var(median of 8) ~ 0.2 sigma^2`,
//!   hence `E|y - median|^2 ~ 1.2 sigma^2` and the factor 0.84. At borders the
//!   median of the in-image neighbours (the mean of the middle two of an even
//!   count).
//! - [`median3_rows`]: the 3x3 median of the in-image pixels, scaled by 1.27
//!   (the median of nine chi-square(3)/3 variates is about 0.79 of their
//!   mean): where the local estimate mistook an edge for noise, those pixels
//!   are a minority of the window.
//!
//! Interior pixels go through sorting networks (branch-free, so the row
//! loops vectorise); border pixels sort their few neighbours. f32 only: the
//! host estimates noise before storing anything in a precision. Scalar code
//! for every [`Isa`](crate::Isa) (the compiler vectorises the networks).

use crate::error::{check_shape, Result, Shape};
use crate::unfold::check_band;
use crate::view::{View, ViewMut};

/// Compare-exchange: afterwards `v[i] <= v[j]` (selects, no branches).
#[inline(always)]
fn cx<const N: usize>(v: &mut [f32; N], i: usize, j: usize) {
    let (a, b) = (v[i], v[j]);
    let swap = b < a;
    v[i] = if swap { b } else { a };
    v[j] = if swap { a } else { b };
}

/// Sorts eight values (Batcher's odd-even merge network, 19 exchanges).
#[inline(always)]
fn sort8(v: &mut [f32; 8]) {
    for (i, j) in [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (1, 2), (5, 6)] {
        cx(v, i, j);
    }
    for (i, j) in [(0, 4), (1, 5), (2, 6), (3, 7), (2, 4), (3, 5), (1, 2), (3, 4), (5, 6)] {
        cx(v, i, j);
    }
}

/// The median of nine values (a 19-exchange selection network; `v` is left
/// partly sorted).
#[inline(always)]
fn median9(v: &mut [f32; 9]) -> f32 {
    for (i, j) in [(1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3)] {
        cx(v, i, j);
    }
    for (i, j) in [(5, 8), (4, 7), (3, 6), (1, 4), (2, 5), (4, 7), (2, 4), (4, 6), (2, 4)] {
        cx(v, i, j);
    }
    v[4]
}

/// The median of the in-image values among the 3x3 neighbourhood of
/// `(px, py)` in plane `c` (`centre`: whether the pixel itself counts), by
/// sorting: the border pixels' path.
fn median_at(p: &View<'_, f32>, c: usize, px: usize, py: usize, centre: bool) -> Option<f32> {
    let (w, h) = (p.width(), p.height());
    let mut nb = [0.0f32; 9];
    let mut m = 0;
    for qy in py.saturating_sub(1)..(py + 2).min(h) {
        let row = p.row(c, qy);
        for qx in px.saturating_sub(1)..(px + 2).min(w) {
            if centre || (qy, qx) != (py, px) {
                nb[m] = row[qx];
                m += 1;
            }
        }
    }
    let vals = &mut nb[..m];
    vals.sort_unstable_by(f32::total_cmp);
    (m > 0).then(|| if m % 2 == 1 { vals[m / 2] } else { 0.5 * (vals[m / 2 - 1] + vals[m / 2]) })
}

/// Rows `py - 1 ..= py + 1` of plane `c` when row `py` has interior pixels
/// (pixels whose 3x3 neighbourhood lies inside the image: columns `1 .. w - 1`).
fn rows_3x3<'a>(p: &View<'a, f32>, c: usize, py: usize) -> Option<[&'a [f32]; 3]> {
    (py >= 1 && py + 1 < p.height() && p.width() >= 3).then(|| core::array::from_fn(|k| p.row(c, py + k - 1)))
}

/// The 3x3 neighbourhood of interior column `x`, row-major (centre at 4).
#[inline(always)]
fn nb_3x3(r: &[&[f32]; 3], x: usize) -> [f32; 9] {
    let (a, b, c) = (&r[0][x - 1..x + 2], &r[1][x - 1..x + 2], &r[2][x - 1..x + 2]);
    [a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]]
}

/// The local noise variance of a single estimate (see the module): rows
/// `y0 ..` of `dst` (1 plane) from `src` (3 planes, the whole image). No
/// scratch.
///
/// # Errors
/// `src` without 3 planes, or `dst` not a 1-plane band of the same width
/// starting at `y0` inside the image.
pub fn local_noise_rows(src: &View<'_, f32>, dst: &mut ViewMut<'_, f32>, y0: usize) -> Result<()> {
    let s = src.shape();
    check_shape("noise estimate input", Shape::new(3, s.width, s.height), s)?;
    check_band("noise estimate output", Shape::new(1, s.width, s.height), dst.shape(), y0)?;
    let w = s.width;
    for r in 0..dst.height() {
        let py = y0 + r;
        let o = dst.row_mut(0, r);
        o.fill(0.0);
        for c in 0..3 {
            let centre = src.row(c, py);
            let border = |x: usize, o: &mut f32| {
                if let Some(med) = median_at(src, c, x, py, false) {
                    let d = centre[x] - med;
                    *o += 0.84 * d * d;
                }
            };
            match rows_3x3(src, c, py) {
                Some(rows) => {
                    for x in 1..w - 1 {
                        let nb = nb_3x3(&rows, x);
                        let mut e = [nb[0], nb[1], nb[2], nb[3], nb[5], nb[6], nb[7], nb[8]];
                        sort8(&mut e);
                        let d = nb[4] - 0.5 * (e[3] + e[4]);
                        o[x] += 0.84 * d * d;
                    }
                    border(0, &mut o[0]);
                    border(w - 1, &mut o[w - 1]);
                }
                None => o.iter_mut().enumerate().for_each(|(x, o)| border(x, o)),
            }
        }
        for o in o.iter_mut() {
            *o /= 3.0;
        }
    }
    Ok(())
}

/// The 3x3 median (of the in-image pixels) times 1.27: rows `y0 ..` of
/// `dst` from `src` (1 plane each, `src` the whole image). No scratch.
///
/// # Errors
/// `src` not 1 plane, or `dst` not a band of it starting at `y0`.
pub fn median3_rows(src: &View<'_, f32>, dst: &mut ViewMut<'_, f32>, y0: usize) -> Result<()> {
    let s = src.shape();
    check_shape("noise median input", Shape::new(1, s.width, s.height), s)?;
    check_band("noise median output", s, dst.shape(), y0)?;
    let w = s.width;
    for r in 0..dst.height() {
        let py = y0 + r;
        let o = dst.row_mut(0, r);
        let border = |x: usize| 1.27 * median_at(src, 0, x, py, true).unwrap_or(0.0);
        match rows_3x3(src, 0, py) {
            Some(rows) => {
                for x in 1..w - 1 {
                    o[x] = 1.27 * median9(&mut nb_3x3(&rows, x));
                }
                o[0] = border(0);
                o[w - 1] = border(w - 1);
            }
            None => o.iter_mut().enumerate().for_each(|(x, o)| *o = border(x)),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values with many ties and both zeros (xorshift).
    fn values(seed: u64) -> [f32; 9] {
        let mut s = seed.max(1);
        core::array::from_fn(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let v = ((s >> 40) % 11) as f32 - 5.0;
            if v == 0.0 && s & 1 == 1 {
                -0.0
            } else {
                v * 0.37
            }
        })
    }

    #[test]
    fn networks_sort_and_select_like_a_sort() {
        for seed in 1..2000u64 {
            let v = values(seed);
            let mut sorted = v;
            sorted.sort_unstable_by(f32::total_cmp);
            let mut a8: [f32; 8] = core::array::from_fn(|i| v[i]);
            sort8(&mut a8);
            let mut s8: [f32; 8] = core::array::from_fn(|i| v[i]);
            s8.sort_unstable_by(f32::total_cmp);
            assert!(a8.iter().zip(&s8).all(|(a, b)| a == b), "sort8 {v:?}: {a8:?}");
            let mut a9 = v;
            assert_eq!(median9(&mut a9), sorted[4], "median9 {v:?}");
        }
    }
}

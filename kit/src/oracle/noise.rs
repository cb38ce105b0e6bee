//! The single-image noise estimators (local noise, 3x3 median).

use super::{ix, tap};

/// The median of a list (the mean of the middle two of an even count).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len();
    if m % 2 == 1 {
        v[m / 2]
    } else {
        0.5 * (v[m / 2 - 1] + v[m / 2])
    }
}

/// The in-image values of the 3x3 neighbourhood of `(x, y)` in plane `c`.
fn neighbours(src: &[f64], c: usize, x: usize, y: usize, w: usize, h: usize, centre: bool) -> Vec<f64> {
    let mut v = Vec::new();
    for dy in -1..=1 {
        for dx in -1..=1 {
            if !centre && dx == 0 && dy == 0 {
                continue;
            }
            if let Some((yy, xx)) = tap(y, x, dy, dx, w, h) {
                v.push(src[ix(c, yy, xx, w, h)]);
            }
        }
    }
    v
}

/// Local noise variance of a single image: `0.84 |y - median of the in-image
/// 8 neighbours|^2`, mean over 3 channels (0 where a pixel has no neighbour).
pub fn local_noise(src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for c in 0..3 {
                let nb = neighbours(src, c, x, y, w, h, false);
                if !nb.is_empty() {
                    let d = src[ix(c, y, x, w, h)] - median(nb);
                    s += 0.84 * d * d;
                }
            }
            out[y * w + x] = s / 3.0;
        }
    }
    out
}

/// `1.27 x` the median of the in-image 3x3 neighbourhood (centre included).
pub fn median3(src: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = 1.27 * median(neighbours(src, 0, x, y, w, h, true));
        }
    }
    out
}

//! The exact f64 reference of every operator, written from the papers' equations
//! independently of the kernels (no shift tricks, no tiling, no shared code).
//! The property tests compare against it and `mcdenoise precision` measures
//! every precision's error with it. (The oracle lives beside the host, not
//! in the `no_std` core.)
//!
//! One file per operator family (the per-pixel kernels, pooling, the
//! convolution, à-trous, temporal accumulation, the noise estimators, the
//! gradients, cross-regression); every item is re-exported here, so
//! `oracle::NAME` names each of them.
#![allow(clippy::needless_range_loop)]

mod atrous;
mod conv;
mod cross;
mod grad;
mod noise;
mod pool;
mod temporal;
mod unfold;

pub use atrous::*;
pub use conv::*;
pub use cross::*;
pub use grad::*;
pub use noise::*;
pub use pool::*;
pub use temporal::*;
pub use unfold::*;

/// Index of `(c, y, x)` in a planar `w x h` buffer.
#[inline]
fn ix(c: usize, y: usize, x: usize, w: usize, h: usize) -> usize {
    (c * h + y) * w + x
}

fn tap(y: usize, x: usize, dy: isize, dx: isize, w: usize, h: usize) -> Option<(usize, usize)> {
    let yy = y as isize + dy;
    let xx = x as isize + dx;
    (yy >= 0 && xx >= 0 && (yy as usize) < h && (xx as usize) < w).then_some((yy as usize, xx as usize))
}

/// Clamps a logit the way the kernels document (±1e30, NaN to -1e30).
pub fn clamp_logit(v: f64) -> f64 {
    if v.is_nan() {
        -1e30
    } else {
        v.clamp(-1e30, 1e30)
    }
}

//! # mcdenoise-core
//!
//! `no_std`, allocation-free kernels for real-time Monte Carlo denoising: the
//! operators of weight-sharing kernel prediction (WSKP), the adaptive fusion
//! network (AFN), SURE-based à-trous filtering and cross-regression, in f32,
//! f16 and fixed point, each with a scalar path and SIMD paths chosen through
//! an explicit [`Isa`] value.
//!
//! Conventions (see `design.md` in the repository):
//! - Buffers are planar views ([`View`], [`ViewMut`]): one plane per channel;
//!   kernel maps are planar too (tap `j` of every pixel is plane `j`, taps in
//!   row-major order, `j = (dy + r) * k + (dx + r)`).
//! - Nothing allocates. An operator that needs scratch says how much through a
//!   `*_scratch_len` function and takes it as `&mut [f32]`.
//! - Nothing panics on caller input: shapes are checked once and an
//!   [`Error`] comes back.
//! - Output rows can be computed in bands (`*_rows` functions take the first
//!   output row), so the host can split an output with
//!   [`ViewMut::split_rows_at`] and run bands on different threads; the result
//!   does not depend on how the rows are split.
#![no_std]
#![deny(unsafe_op_in_unsafe_fn)]
// NaN handling is deliberate throughout: `!(x >= lo)` and `x.max(lo).min(hi)`
// send NaN to a chosen value where `f32::clamp` would propagate it.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::manual_clamp)]
// SIMD loops index several parallel arrays by lane or channel.
#![allow(clippy::needless_range_loop)]

pub mod atrous;
pub mod conv;
pub mod error;
pub mod fixed;
pub mod isa;
pub mod math;
pub mod pool;
pub mod precision;
pub mod real;
pub mod simd;
pub mod softmax;
pub mod temporal;
pub mod tonemap;
pub mod unfold;
pub mod view;

pub use error::{Error, Result, Shape};
pub use isa::Isa;
pub use precision::{Element, F16Arith, Fixed, FloatElement, FloatPrecision, Precision, F16, F32};
pub use view::{View, ViewMut};

/// Checks that `k` is an odd kernel size in `1..=max`.
pub(crate) fn check_kernel_size(what: &'static str, k: usize, max: usize) -> Result<()> {
    if k % 2 == 1 && k <= max {
        Ok(())
    } else {
        Err(Error::BadParameter { what, expected: "an odd kernel size within the supported range" })
    }
}

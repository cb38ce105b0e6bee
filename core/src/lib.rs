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
//!   [`Error`] comes back. Each operator's documentation gives the shapes it
//!   takes, its scratch (the `*_scratch_len` function to size it) and, under
//!   "Errors", what it refuses; an instruction set the CPU lacks is always
//!   [`Error::IsaUnsupported`].
//! - `examples/fixed_buffers.rs` calls the core as a `no_std` caller would:
//!   fixed-size buffers, scratch sized from `*_scratch_len`, an explicit
//!   [`Isa`], no allocation.
//! - Output rows can be computed in bands (`*_rows` functions take the first
//!   output row), so the host can split an output with
//!   [`ViewMut::split_rows_at`] and run bands on different threads; the result
//!   does not depend on how the rows are split.
//!
//! ## Soundness
//! Safe code cannot reach a kernel around its checks. The per-operator
//! precision traits ([`unfold::UnfoldPrecision`], [`conv::ConvPrecision`], ...)
//! are sealed, and their hidden kernel methods take a token that only this
//! crate's public functions make, after checking the instruction set
//! ([`Isa::check`] returns the [`isa::Supported`] proof every SIMD kernel
//! takes) and every shape. The public function checks and runs:
//!
//! ```
//! use mcdenoise_core::{unfold, Isa, View, ViewMut, F32};
//! let (kernel, src, mut dst) = ([0.0f32; 49], [1.0f32; 1], [0.0f32; 1]);
//! let kv = View::new(&kernel[..1], 1, 1, 1).unwrap(); // one plane: a 7x7 map needs 49
//! let sv = View::new(&src, 1, 1, 1).unwrap();
//! let mut dv = ViewMut::new(&mut dst, 1, 1, 1).unwrap();
//! let err = unfold::apply_rows::<F32>(Isa::Scalar, 7, &kv, &sv, &mut dv, 30, &mut []);
//! assert!(err.is_err()); // a bad kernel map and a band past the image: an error, no call
//! ```
//!
//! while calling the kernel method directly does not compile, by name:
//!
//! ```compile_fail,E0308
//! use mcdenoise_core::{unfold::UnfoldPrecision, Isa, View, ViewMut, F32};
//! let (kernel, src, mut dst) = ([0.0f32; 49], [1.0f32; 1], [0.0f32; 1]);
//! let kv = View::new(&kernel[..1], 1, 1, 1).unwrap();
//! let sv = View::new(&src, 1, 1, 1).unwrap();
//! let mut dv = ViewMut::new(&mut dst, 1, 1, 1).unwrap();
//! <F32 as UnfoldPrecision>::apply_impl(Isa::Avx512, 7, &kv, &sv, &mut dv, 30, &mut []);
//! ```
//!
//! nor through a generic bound, for want of the token:
//!
//! ```compile_fail,E0308
//! use mcdenoise_core::{isa::Supported, unfold::UnfoldPrecision, View, ViewMut};
//! fn sneak<P: UnfoldPrecision>(k: &View<'_, P::Store>, s: &View<'_, P::Store>, d: &mut ViewMut<'_, P::Store>) {
//!     P::apply_impl(Supported::SCALAR, 7, k, s, d, 30, &mut []);
//! }
//! ```
#![no_std]
#![warn(missing_docs)]
#![deny(unsafe_op_in_unsafe_fn)]
// NaN handling is deliberate throughout: `!(x >= lo)` and `x.max(lo).min(hi)`
// send NaN to a chosen value where `f32::clamp` would propagate it.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::manual_clamp)]
// SIMD loops index several parallel arrays by lane or channel.
#![allow(clippy::needless_range_loop)]

/// Runs the closure `body` compiled for the checked ISA: the same portable
/// loops, vectorised by the compiler with that ISA's instructions (the
/// backward passes' SIMD paths). No FMA contraction happens, so every ISA
/// gives the scalar path's bits.
macro_rules! versions {
    ($isa:expr, $body:expr) => {{
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
        unsafe fn avx512<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        let isa: $crate::isa::Supported = $isa;
        match isa.isa() {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
            $crate::Isa::Avx2 => unsafe { avx2($body) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as above.
            $crate::Isa::Avx512 => unsafe { avx512($body) },
            _ => ($body)(),
        }
    }};
}

pub mod atrous;
pub mod conv;
pub mod error;
pub mod fixed;
pub mod isa;
pub(crate) mod math;
pub mod pool;
pub mod precision;
pub mod real;
pub mod regress;
pub(crate) mod simd;
pub mod softmax;
pub mod temporal;
pub mod tonemap;
pub mod unfold;
pub mod view;

pub use error::{Error, Result, Shape};
pub use isa::Isa;
/// The kernels' `e^x` without branches, for host loops that should vectorise
/// (the same values as the SIMD kernels' to a few ulp; 0 below `-87`).
pub use math::scalar::exp_select;
pub use precision::{Element, F16Arith, Fixed, FloatElement, FloatPrecision, Precision, F16, F32};
pub use view::{View, ViewMut};

/// Saturating product of sizes, for the `*_scratch_len` functions: an absurd
/// size saturates to `usize::MAX`, which then fails the scratch check cleanly.
pub(crate) fn sat_prod(v: &[usize]) -> usize {
    v.iter().fold(1usize, |a, &b| a.saturating_mul(b))
}

/// Saturating sum of sizes (see [`sat_prod`]).
pub(crate) fn sat_sum(v: &[usize]) -> usize {
    v.iter().fold(0usize, |a, &b| a.saturating_add(b))
}

/// Checks that `k` is an odd kernel size in `1..=max`.
pub(crate) fn check_kernel_size(what: &'static str, k: usize, max: usize) -> Result<()> {
    if k % 2 == 1 && k <= max {
        Ok(())
    } else {
        Err(Error::BadParameter { what, expected: "an odd kernel size within the supported range" })
    }
}

//! Elementary functions shared by the kernels: one algorithm, written once per
//! instruction set so that the SIMD and scalar paths agree to a few ulp.
//!
//! `exp` uses Cody–Waite range reduction `x = n ln2 + r`, `|r| <= ln2/2`, a
//! degree-6 Taylor polynomial for `e^r` (truncation error `r^7/7! < 1.3e-7`
//! relative) and builds `2^n` from the exponent bits. Arguments below
//! [`EXP_LO`] (and NaN) give exactly 0, never a subnormal, so that a weight is
//! either a normal number or zero. `log` reduces to a mantissa in
//! `[sqrt(1/2), sqrt(2))` and sums the odd series of `2 atanh(z)`,
//! `z = (m - 1)/(m + 1)`, `|z| <= 0.1716`, to `z^9` (error < 3e-9).

pub mod scalar;

#[cfg(target_arch = "x86_64")]
pub mod avx2;

#[cfg(target_arch = "x86_64")]
pub mod avx512;

/// Smallest argument `exp` returns a non-zero value for (`e^-87 ~ 1.6e-38`,
/// just above the smallest normal f32).
pub const EXP_LO: f32 = -87.0;
/// Largest argument `exp` honours; larger arguments are clamped to it.
pub const EXP_HI: f32 = 88.0;

pub(crate) const LOG2E: f32 = core::f32::consts::LOG2_E;
/// ln 2 split in a high part with few mantissa bits (so `n * LN2_HI` is exact
/// for `|n| <= 256`) and the remainder.
pub(crate) const LN2_HI: f32 = 0.693_359_4;
pub(crate) const LN2_LO: f32 = -2.121_944_4e-4;
/// Adding then subtracting 1.5 * 2^23 rounds an f32 in (-2^22, 2^22) to the
/// nearest integer (ties to even) without a conversion instruction.
pub(crate) const ROUND_MAGIC: f32 = 12_582_912.0;
pub(crate) const EXP_C: [f32; 7] = [1.0, 1.0, 0.5, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0];
pub(crate) const LN2: f32 = core::f32::consts::LN_2;
pub(crate) const SQRT_HALF: f32 = core::f32::consts::FRAC_1_SQRT_2;

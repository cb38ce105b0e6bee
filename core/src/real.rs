//! The arithmetic the scalar kernels are written in.
//!
//! Every scalar kernel is generic over a [`Real`]: `f32` for the [`F32`](crate::F32)
//! and [`F16`](crate::F16) precisions (f32 arithmetic; this compiles to the same code
//! as plain f32), and [`H`] for [`F16Arith`](crate::F16Arith), which rounds the result
//! of every `+ - * /` to the nearest f16, emulating hardware with native f16
//! math. Transcendentals (`exp`) are evaluated in f32 and rounded once, like a
//! native f16 instruction would return them. Overflow saturates at ±65504
//! instead of producing infinity (the stability contract); NaN stays NaN.

use core::fmt::Debug;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub};

/// Arithmetic of a scalar kernel.
pub trait Real:
    Copy
    + PartialEq
    + PartialOrd
    + Debug
    + Default
    + Send
    + Sync
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + MulAssign
    + bytemuck::Pod
    + 'static
{
    /// True for plain f32 (the SIMD paths exist only for it).
    const IS_F32: bool;
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// A box-sum window whose weight sum is below this is recomputed with a
    /// window-local shift (f32: 2^-100; f16: 2^-10, a few ulp above the
    /// smallest normal, so that every weight that matters is normal).
    const TINY: Self;
    /// Rounds an f32 into this arithmetic.
    fn of(v: f32) -> Self;
    /// The value as f32 (exact).
    fn f32(self) -> f32;
    /// `e^self`, 0 below the smallest normal result.
    fn exp(self) -> Self;
    /// `MAXPS` semantics: `self` if strictly greater, else `o` (a NaN `self` loses).
    #[inline(always)]
    fn maxps(self, o: Self) -> Self {
        if self > o {
            self
        } else {
            o
        }
    }
    /// `f32::max` semantics: NaN is ignored.
    #[inline(always)]
    fn fmax(self, o: Self) -> Self {
        Self::of(self.f32().max(o.f32()))
    }
}

impl Real for f32 {
    const IS_F32: bool = true;
    const ZERO: f32 = 0.0;
    const ONE: f32 = 1.0;
    const TINY: f32 = 7.888_609e-31; // 2^-100
    #[inline(always)]
    fn of(v: f32) -> f32 {
        v
    }
    #[inline(always)]
    fn f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn exp(self) -> f32 {
        crate::math::scalar::exp(self)
    }
    #[inline(always)]
    fn fmax(self, o: f32) -> f32 {
        self.max(o)
    }
}

/// Largest finite f16.
pub const F16_MAX: f32 = 65504.0;

/// An f16 value in f32 clothing: every operation is done in f32 (exact for
/// one f16 operation's inputs) and rounded to f16, saturating at ±65504.
#[derive(Clone, Copy, Debug, Default, PartialEq, PartialOrd)]
#[repr(transparent)]
pub struct H(pub f32);

// SAFETY: a transparent f32.
unsafe impl bytemuck::Zeroable for H {}
// SAFETY: a transparent f32; every bit pattern is a valid H.
unsafe impl bytemuck::Pod for H {}

/// Rounds to the nearest f16 (ties to even), saturating at ±65504.
#[inline(always)]
pub fn round16(v: f32) -> f32 {
    let c = if v > F16_MAX {
        F16_MAX
    } else if v < -F16_MAX {
        -F16_MAX
    } else {
        v
    };
    let a = f32::from_bits(c.to_bits() & 0x7fff_ffff);
    if !(a >= 6.103_515_6e-5) {
        // f16 subnormals (and 0, NaN): multiples of 2^-24; adding and
        // subtracting 0.75 = 1.5 * 2^(-24 + 23) rounds to them, ties to even;
        // the sign is put back (so -tiny rounds to -0, as half does).
        if c.is_nan() {
            return c;
        }
        let q = (a + 0.75) - 0.75;
        return f32::from_bits(q.to_bits() | (c.to_bits() & 0x8000_0000));
    }
    // Normal range: round the f32 mantissa to f16's 10 bits, ties to even.
    let b = c.to_bits();
    let r = b.wrapping_add(0x0fff + ((b >> 13) & 1)) & 0xffff_e000;
    f32::from_bits(r)
}

impl Add for H {
    type Output = H;
    #[inline(always)]
    fn add(self, o: H) -> H {
        H(round16(self.0 + o.0))
    }
}
impl Sub for H {
    type Output = H;
    #[inline(always)]
    fn sub(self, o: H) -> H {
        H(round16(self.0 - o.0))
    }
}
impl Mul for H {
    type Output = H;
    #[inline(always)]
    fn mul(self, o: H) -> H {
        H(round16(self.0 * o.0))
    }
}
impl Div for H {
    type Output = H;
    #[inline(always)]
    fn div(self, o: H) -> H {
        H(round16(self.0 / o.0))
    }
}
impl Neg for H {
    type Output = H;
    #[inline(always)]
    fn neg(self) -> H {
        H(-self.0)
    }
}
impl AddAssign for H {
    #[inline(always)]
    fn add_assign(&mut self, o: H) {
        *self = *self + o;
    }
}
impl MulAssign for H {
    #[inline(always)]
    fn mul_assign(&mut self, o: H) {
        *self = *self * o;
    }
}

impl Real for H {
    const IS_F32: bool = false;
    const ZERO: H = H(0.0);
    const ONE: H = H(1.0);
    const TINY: H = H(9.765_625e-4); // 2^-10
    #[inline(always)]
    fn of(v: f32) -> H {
        H(round16(v))
    }
    #[inline(always)]
    fn f32(self) -> f32 {
        self.0
    }
    #[inline(always)]
    fn exp(self) -> H {
        H(round16(crate::math::scalar::exp(self.0)))
    }
}

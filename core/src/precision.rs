//! Precision as a type.
//!
//! A [`Precision`] names a storage element (what the buffers hold) and an
//! accumulator (what sums are carried in) separately:
//!
//! | type | storage | accumulator | use |
//! |---|---|---|---|
//! | [`F32`] | `f32` | `f32` | the reference |
//! | [`F16`] | `half::f16` | `f32` | half the memory traffic |
//! | [`F16Arith`] | `half::f16` | `f16` (every op rounded) | emulates native f16 math |
//! | [`Fixed`] | `i16` | `i32` | runtimes without an FPU |
//!
//! Operators are generic over the precision and dispatch through a sealed
//! per-operator trait, so a precision an operator does not implement yet is a
//! compile error, never a silent conversion.

use core::fmt::Debug;

/// A buffer element: plain old data that can be moved between threads.
pub trait Element: Copy + Default + PartialEq + Debug + Send + Sync + bytemuck::Pod + 'static {
    /// Name of the element type.
    const NAME: &'static str;
}

impl Element for f32 {
    const NAME: &'static str = "f32";
}
impl Element for half::f16 {
    const NAME: &'static str = "f16";
}
impl Element for i16 {
    const NAME: &'static str = "i16";
}

/// A numeric precision: storage element plus accumulator.
pub trait Precision: Copy + Default + Debug + Send + Sync + 'static {
    /// What the buffers hold.
    type Store: Element;
    /// What sums are carried in.
    type Acc: Copy + Default + Debug + Send + Sync + 'static;
    /// Name as used on the command line (`f32`, `f16`, `f16-arith`, `fixed`).
    const NAME: &'static str;
}

/// f32 storage, f32 accumulation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct F32;
/// f16 storage, f32 accumulation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct F16;
/// f16 storage with every arithmetic operation rounded to f16.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct F16Arith;
/// i16 fixed-point storage, i32 accumulation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fixed;

impl Precision for F32 {
    type Store = f32;
    type Acc = f32;
    const NAME: &'static str = "f32";
}
impl Precision for F16 {
    type Store = half::f16;
    type Acc = f32;
    const NAME: &'static str = "f16";
}
impl Precision for F16Arith {
    type Store = half::f16;
    type Acc = half::f16;
    const NAME: &'static str = "f16-arith";
}
impl Precision for Fixed {
    type Store = i16;
    type Acc = i32;
    const NAME: &'static str = "fixed";
}

pub(crate) mod sealed {
    /// Keeps the per-operator precision traits closed to this crate.
    pub trait Sealed {}
    impl Sealed for super::F32 {}
    impl Sealed for super::F16 {}
    impl Sealed for super::F16Arith {}
    impl Sealed for super::Fixed {}
    /// Keeps [`super::FloatElement`] closed.
    pub trait SealedElem {}
    impl SealedElem for f32 {}
    impl SealedElem for half::f16 {}

    /// What a public operator function hands its precision trait's kernel
    /// method once it has checked the instruction set and every shape. Code
    /// outside this crate cannot name or make one, so the trait methods (public
    /// only because the traits are) cannot be called around those checks.
    #[derive(Clone, Copy, Debug)]
    pub struct Checked(crate::isa::Supported);

    impl Checked {
        /// Only the operator modules make one, after their checks.
        #[inline(always)]
        pub(crate) fn new(isa: crate::isa::Supported) -> Self {
            Checked(isa)
        }
        /// The checked instruction set.
        #[inline(always)]
        pub(crate) fn isa(self) -> crate::isa::Supported {
            self.0
        }
    }
}

/// A floating-point storage element that is computed on in f32
/// (`f32` itself, and `f16` widened on load and rounded to nearest-even on store).
pub trait FloatElement: Element + sealed::SealedElem {
    /// True for `half::f16`.
    const IS_F16: bool;
    /// Widens to f32 (exact).
    fn to_f32(self) -> f32;
    /// Rounds from f32 (nearest, ties to even); f16 saturates at ±65504
    /// instead of overflowing to infinity (NaN stays NaN).
    fn from_f32(v: f32) -> Self;
}

impl FloatElement for f32 {
    const IS_F16: bool = false;
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
}

impl FloatElement for half::f16 {
    const IS_F16: bool = true;
    #[inline(always)]
    fn to_f32(self) -> f32 {
        f16_to_f32(self.to_bits())
    }
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        let c = if v > crate::real::F16_MAX {
            crate::real::F16_MAX
        } else if v < -crate::real::F16_MAX {
            -crate::real::F16_MAX
        } else {
            v
        };
        half::f16::from_f32(c)
    }
}

/// A precision whose arithmetic is f32 over a [`FloatElement`] storage
/// ([`F32`] and [`F16`]): the kernels for both are one generic body.
pub trait FloatPrecision: Precision<Acc = f32> + sealed::Sealed
where
    Self::Store: FloatElement,
{
}
impl FloatPrecision for F32 {}
impl FloatPrecision for F16 {}

/// Exact f16 -> f32 widening in a few operations, inlined and without
/// branches on the value (the `half` crate may call out of line per
/// element): the magnitude's bits moved into f32's exponent and mantissa
/// fields read as an f32 `2^-112` times the value (subnormal for f16's
/// subnormals), so one multiply by `2^112` gives it exactly, zero included;
/// infinities and NaN (exponent 31) are selected apart.
#[inline(always)]
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h as u32) & 0x8000) << 16;
    let mag = (h & 0x7fff) as u32;
    let scaled = f32::from_bits(mag << 13) * f32::from_bits((127 + 112) << 23);
    let special = f32::from_bits(0x7f80_0000 | ((mag & 0x3ff) << 13));
    let v = if mag >= 0x7c00 { special } else { scaled };
    f32::from_bits(v.to_bits() | sign)
}

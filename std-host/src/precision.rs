//! Precision glue: which core precisions the host runs, and how frames (f32)
//! go in and out of their storage type.
//!
//! Encoding is where the stability contract meets the storage format: f16
//! saturates at ±65504 instead of overflowing to infinity (values above are
//! clamped, NaN was already replaced by 0 on load).

use mcdenoise_core::atrous::AtrousPrecision;
use mcdenoise_core::conv::ConvPrecision;
use mcdenoise_core::pool::PoolPrecision;
use mcdenoise_core::softmax::SoftmaxPrecision;
use mcdenoise_core::temporal::TemporalPrecision;
use mcdenoise_core::tonemap::TonemapPrecision;
use mcdenoise_core::unfold::UnfoldPrecision;
use mcdenoise_core::{F16Arith, Precision, View, ViewMut, F16, F32};

use crate::error::{HostError, Result};

/// The precisions a pipeline can run in, by command-line name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PrecisionKind {
    /// f32 storage and arithmetic.
    F32,
    /// f16 storage, f32 arithmetic.
    F16,
    /// f16 storage, every operation rounded to f16.
    F16Arith,
    /// i16 fixed point, i32 accumulation.
    Fixed,
}

impl PrecisionKind {
    /// All, in command-line order.
    pub const ALL: [PrecisionKind; 4] =
        [PrecisionKind::F32, PrecisionKind::F16, PrecisionKind::F16Arith, PrecisionKind::Fixed];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            PrecisionKind::F32 => "f32",
            PrecisionKind::F16 => "f16",
            PrecisionKind::F16Arith => "f16-arith",
            PrecisionKind::Fixed => "fixed",
        }
    }

    /// Parses a command-line name.
    pub fn parse(s: &str) -> Result<PrecisionKind> {
        PrecisionKind::ALL.into_iter().find(|p| p.name() == s).ok_or_else(|| {
            HostError::Usage(format!("--precision: expected one of f32, f16, f16-arith, fixed; got '{s}'"))
        })
    }
}

/// A precision the host pipelines can run in.
pub trait HostPrecision:
    Precision
    + UnfoldPrecision
    + SoftmaxPrecision
    + PoolPrecision
    + ConvPrecision
    + TonemapPrecision
    + TemporalPrecision
    + AtrousPrecision
{
    /// Encodes f32 values into storage (saturating).
    fn encode(src: &[f32], dst: &mut [Self::Store]);
    /// Decodes storage into f32.
    fn decode(src: &[Self::Store], dst: &mut [f32]);
}

impl HostPrecision for F32 {
    fn encode(src: &[f32], dst: &mut [f32]) {
        dst.copy_from_slice(src);
    }
    fn decode(src: &[f32], dst: &mut [f32]) {
        dst.copy_from_slice(src);
    }
}

/// Largest finite f16.
pub const F16_MAX: f32 = 65504.0;

impl HostPrecision for F16 {
    fn encode(src: &[f32], dst: &mut [half::f16]) {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = half::f16::from_f32(s.clamp(-F16_MAX, F16_MAX));
        }
    }
    fn decode(src: &[half::f16], dst: &mut [f32]) {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = s.to_f32();
        }
    }
}

impl HostPrecision for F16Arith {
    fn encode(src: &[f32], dst: &mut [half::f16]) {
        F16::encode(src, dst)
    }
    fn decode(src: &[half::f16], dst: &mut [f32]) {
        F16::decode(src, dst)
    }
}

/// An owned planar image in a storage type.
#[derive(Clone, Debug, PartialEq)]
pub struct Planes<T> {
    /// Planes.
    pub channels: usize,
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Plane-major, row-major values.
    pub data: Vec<T>,
}

impl<T: Copy + Default> Planes<T> {
    /// Zero-filled.
    pub fn new(channels: usize, width: usize, height: usize) -> Self {
        Planes { channels, width, height, data: vec![T::default(); channels * width * height] }
    }
    /// A shared view.
    pub fn view(&self) -> View<'_, T> {
        View::new(&self.data, self.channels, self.width, self.height).expect("planes have their shape")
    }
    /// An exclusive view.
    pub fn view_mut(&mut self) -> ViewMut<'_, T> {
        ViewMut::new(&mut self.data, self.channels, self.width, self.height).expect("planes have their shape")
    }
}

impl<T: Copy + Default> Planes<T> {
    /// Encodes f32 planes.
    pub fn encode<P: HostPrecision<Store = T>>(channels: usize, width: usize, height: usize, src: &[f32]) -> Self {
        let mut p = Planes::new(channels, width, height);
        P::encode(src, &mut p.data);
        p
    }
    /// Re-encodes f32 planes into this buffer (same shape).
    pub fn encode_from<P: HostPrecision<Store = T>>(&mut self, src: &[f32]) {
        P::encode(src, &mut self.data);
    }
    /// Decodes to f32.
    pub fn decode<P: HostPrecision<Store = T>>(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.data.len()];
        P::decode(&self.data, &mut out);
        out
    }
}

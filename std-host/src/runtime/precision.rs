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
use mcdenoise_core::{F16Arith, Fixed, Precision, View, ViewMut, F16, F32};

use crate::error::{HostError, Result};
use crate::runtime::aligned::Aligned;

/// The precisions a pipeline can run in, by command-line name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PrecisionKind {
    /// f32 storage and arithmetic.
    F32,
    /// f16 storage, f32 arithmetic.
    F16,
    /// f16 storage, every operation rounded to f16 (a study mode, scalar only).
    #[value(name = "f16-arith")]
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

/// What a tensor holds, for choosing its fixed-point format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Radiance-like HDR values: the format keeps the 99.9th percentile of
    /// `|v|` (times 2 for filter overshoot) representable; the brighter tail
    /// (fireflies) saturates.
    Image,
    /// Values in [-1, 1] or [0, 1] (normals, albedo, weights): Q1.14.
    Unit,
    /// Geometry and other tensors without outliers (positions, depth, motion,
    /// variances): the format keeps the maximum `|v|` (times 2) representable.
    Plain,
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
    /// Bytes per value that [`HostPrecision::choose_frac`] allocates for a
    /// moment to pick an image's format (fixed point sorts a copy of
    /// `|v|`), for the memory estimates.
    const FORMAT_COPY_BYTES: u64 = 0;
    /// Fixed point: values carry a per-tensor format (fractional bits), and
    /// formats must be chosen for the network's tensors and the filters'
    /// inputs. The float precisions ignore formats.
    const FIXED_POINT: bool = false;
    /// `frac` in fixed point, 0 (no format) in the float precisions.
    fn frac_or_zero(frac: i8) -> i8 {
        if Self::FIXED_POINT {
            frac
        } else {
            0
        }
    }
    /// Fractional bits to store `src` with (0 for the float precisions).
    fn choose_frac(_src: &[f32], _kind: Kind) -> i8 {
        0
    }
    /// Encodes f32 values into storage (saturating).
    fn encode(src: &[f32], dst: &mut [Self::Store], frac: i8);
    /// Decodes storage into f32.
    fn decode(src: &[Self::Store], dst: &mut [f32], frac: i8);
    /// f32 data as the storage type, without a copy, when that is f32.
    fn borrow_f32(_d: &[f32]) -> Option<&[Self::Store]> {
        None
    }
    /// Storage as f32, without a copy, when it is f32.
    fn store_as_f32(_d: &[Self::Store]) -> Option<&[f32]> {
        None
    }
    /// Storage as f16, without a copy, when it is f16.
    fn store_as_f16(_d: &[Self::Store]) -> Option<&[half::f16]> {
        None
    }
    /// An f32 output view as one of the storage type, when that is f32.
    fn as_store_view_mut<'a, 'b>(_v: &'b mut ViewMut<'a, f32>) -> Option<&'b mut ViewMut<'a, Self::Store>> {
        None
    }
}

impl HostPrecision for F32 {
    fn encode(src: &[f32], dst: &mut [f32], _frac: i8) {
        dst.copy_from_slice(src);
    }
    fn decode(src: &[f32], dst: &mut [f32], _frac: i8) {
        dst.copy_from_slice(src);
    }
    fn borrow_f32(d: &[f32]) -> Option<&[f32]> {
        Some(d)
    }
    fn store_as_f32(d: &[f32]) -> Option<&[f32]> {
        Some(d)
    }
    fn as_store_view_mut<'a, 'b>(v: &'b mut ViewMut<'a, f32>) -> Option<&'b mut ViewMut<'a, f32>> {
        Some(v)
    }
}

/// Bytes of one stored value of `P`.
pub fn store_bytes<P: HostPrecision>() -> u64 {
    size_of::<P::Store>() as u64
}

/// Whether `P` stores f32 (the host then hands the frame's own planes to
/// the kernels, no copy) or f16 (the SURE pass reads those directly too).
pub fn store_is<P: HostPrecision, T: 'static>() -> bool {
    std::any::TypeId::of::<P::Store>() == std::any::TypeId::of::<T>()
}

/// Largest finite f16.
pub const F16_MAX: f32 = 65504.0;

impl HostPrecision for F16 {
    fn encode(src: &[f32], dst: &mut [half::f16], _frac: i8) {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = half::f16::from_f32(s.clamp(-F16_MAX, F16_MAX));
        }
    }
    fn decode(src: &[half::f16], dst: &mut [f32], _frac: i8) {
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = s.to_f32();
        }
    }
    fn store_as_f16(d: &[half::f16]) -> Option<&[half::f16]> {
        Some(d)
    }
}

impl HostPrecision for F16Arith {
    fn encode(src: &[f32], dst: &mut [half::f16], frac: i8) {
        F16::encode(src, dst, frac)
    }
    fn decode(src: &[half::f16], dst: &mut [f32], frac: i8) {
        F16::decode(src, dst, frac)
    }
    fn store_as_f16(d: &[half::f16]) -> Option<&[half::f16]> {
        Some(d)
    }
}

/// The fixed-point format policy: fractional bits that keep `m` (times 2 of
/// headroom) below 2^15, between -8 and 14.
pub fn frac_for_max(m: f32) -> i8 {
    if m.is_nan() || m <= 0.0 || !m.is_finite() {
        return 14;
    }
    let bits = (2.0 * m).log2().ceil() as i32; // integer bits needed
    (15 - bits).clamp(-8, 14) as i8
}

/// The 99.9th percentile of `|v|` (exact, by selection on a copy).
pub fn percentile_abs(src: &[f32], q: f64) -> f32 {
    if src.is_empty() {
        return 0.0;
    }
    let mut a: Vec<f32> = src.iter().map(|v| v.abs()).collect();
    let i = ((a.len() - 1) as f64 * q).round() as usize;
    *a.select_nth_unstable_by(i, f32::total_cmp).1
}

impl HostPrecision for Fixed {
    const FIXED_POINT: bool = true;
    const FORMAT_COPY_BYTES: u64 = 4;
    fn choose_frac(src: &[f32], kind: Kind) -> i8 {
        match kind {
            Kind::Unit => mcdenoise_core::fixed::KERNEL_FRAC,
            Kind::Plain => frac_for_max(src.iter().fold(0.0f32, |m, v| m.max(v.abs()))),
            Kind::Image => frac_for_max(percentile_abs(src, 0.999)),
        }
    }
    fn encode(src: &[f32], dst: &mut [i16], frac: i8) {
        let scale = (frac as f32).exp2();
        for (d, &s) in dst.iter_mut().zip(src) {
            let v = (s * scale).round();
            *d = if v.is_nan() { 0 } else { v.clamp(-32767.0, 32767.0) as i16 };
        }
    }
    fn decode(src: &[i16], dst: &mut [f32], frac: i8) {
        let scale = (-(frac as f32)).exp2();
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = s.max(-32767) as f32 * scale;
        }
    }
}

/// An owned planar image in a storage type.
#[derive(Clone, Debug, PartialEq)]
pub struct Planes<T: bytemuck::Pod> {
    /// Planes.
    pub channels: usize,
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Plane-major, row-major values, starting on a cache line.
    pub data: Aligned<T>,
    /// Fixed-point fractional bits (0 for floats).
    pub frac: i8,
}

impl<T: bytemuck::Pod + Default> Planes<T> {
    /// Zero-filled.
    pub fn new(channels: usize, width: usize, height: usize) -> Self {
        Planes { channels, width, height, data: Aligned::zeroed(channels * width * height), frac: 0 }
    }
    /// A copy of data already in hand (frac 0).
    pub fn from_vec(channels: usize, width: usize, height: usize, data: Vec<T>) -> Self {
        Planes { channels, width, height, data: Aligned::from_slice(&data), frac: 0 }
    }
    /// The same planes with a fixed-point format.
    pub fn with_frac(mut self, frac: i8) -> Self {
        self.frac = frac;
        self
    }
    /// A shared view (carrying the format).
    pub fn view(&self) -> View<'_, T> {
        View::new(&self.data, self.channels, self.width, self.height)
            .expect("planes have their shape")
            .with_frac(self.frac)
    }
    /// An exclusive view (carrying the format).
    pub fn view_mut(&mut self) -> ViewMut<'_, T> {
        ViewMut::new(&mut self.data, self.channels, self.width, self.height)
            .expect("planes have their shape")
            .with_frac(self.frac)
    }
}

impl<T: bytemuck::Pod + Default> Planes<T> {
    /// Encodes f32 planes of radiance-like values.
    pub fn encode<P: HostPrecision<Store = T>>(channels: usize, width: usize, height: usize, src: &[f32]) -> Self {
        Self::encode_as::<P>(channels, width, height, src, Kind::Image)
    }
    /// Encodes f32 planes of the given kind (its format chosen by the policy).
    pub fn encode_as<P: HostPrecision<Store = T>>(
        channels: usize,
        width: usize,
        height: usize,
        src: &[f32],
        kind: Kind,
    ) -> Self {
        Self::encode_frac::<P>(channels, width, height, src, P::choose_frac(src, kind))
    }
    /// Encodes f32 planes with the given fixed-point format (ignored by the
    /// float precisions), saturating what it cannot hold.
    pub fn encode_frac<P: HostPrecision<Store = T>>(
        channels: usize,
        width: usize,
        height: usize,
        src: &[f32],
        frac: i8,
    ) -> Self {
        let frac = P::frac_or_zero(frac);
        let mut p = Planes::new(channels, width, height).with_frac(frac);
        P::encode(src, &mut p.data, frac);
        p
    }
    /// Decodes to f32.
    pub fn decode<P: HostPrecision<Store = T>>(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.data.len()];
        P::decode(&self.data, &mut out, self.frac);
        out
    }
}

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
use crate::runtime::par::Pool;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

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
    /// `|v|` (times 2 for filter overshoot) representable, down to a step of
    /// 2^-22 for dim renders ([`IMAGE_MAX_FRAC`]); the brighter tail
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
    /// The largest `|v|` the storage holds at `frac` (beyond it, encoding
    /// saturates): unbounded for f32.
    fn store_max(_frac: i8) -> f32 {
        f32::INFINITY
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
    fn store_max(_frac: i8) -> f32 {
        F16_MAX
    }
    fn encode(src: &[f32], dst: &mut [half::f16], _frac: i8) {
        // Clamped a block at a time on the stack, then converted by `half`'s
        // slice conversion (F16C where the CPU has it, round to nearest even
        // either way).
        const BLOCK: usize = 1024;
        let mut tmp = [0.0f32; BLOCK];
        for (d, s) in dst.chunks_mut(BLOCK).zip(src.chunks(BLOCK)) {
            let t = &mut tmp[..d.len().min(s.len())];
            for (t, &v) in t.iter_mut().zip(s) {
                *t = v.clamp(-F16_MAX, F16_MAX);
            }
            d[..t.len()].convert_from_f32_slice(t);
        }
    }
    fn decode(src: &[half::f16], dst: &mut [f32], _frac: i8) {
        let n = src.len().min(dst.len());
        src[..n].convert_to_f32_slice(&mut dst[..n]);
    }
    fn store_as_f16(d: &[half::f16]) -> Option<&[half::f16]> {
        Some(d)
    }
}

impl HostPrecision for F16Arith {
    fn store_max(_frac: i8) -> f32 {
        F16_MAX
    }
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

/// The finest format [`frac_for_max`] gives (Q1.14).
pub const MAX_FRAC: i8 = 14;
/// The finest format of an image ([`Kind::Image`], [`frac_for_percentile`]):
/// a step of 2.4e-7, so that a render in units where most radiance
/// is under 1e-3 keeps its bits (at [`MAX_FRAC`] the sample's median
/// radiance divided by 4096 was a third of a step). Every format lies in
/// `MIN_FRAC..=IMAGE_MAX_FRAC`, so any two are at most 30 bits apart.
pub const IMAGE_MAX_FRAC: i8 = 22;
/// The coarsest format (Q23.-8: values to 8.4e6).
pub const MIN_FRAC: i8 = -8;

/// The fixed-point format policy: fractional bits that keep `m` (times 2 of
/// headroom) below 2^15, between [`MIN_FRAC`] and [`MAX_FRAC`]; 14 for
/// nothing to keep (zero, or not finite).
pub fn frac_for_max(m: f32) -> i8 {
    if m.is_nan() || m <= 0.0 || !m.is_finite() {
        return 14;
    }
    frac_for_bucket(bucket(m), MAX_FRAC)
}

/// `ceil(log2 |v|) + 127` from the bits of `|v|`, exactly (no `log2`
/// rounding): the exponent field, plus one when the mantissa is not zero;
/// 0 for zero and subnormals, 256 for infinities and NaN. Nondecreasing in `|v|`.
#[inline(always)]
fn bucket(v: f32) -> usize {
    let b = v.to_bits() & 0x7fff_ffff;
    let e = (b >> 23) as usize;
    match e {
        0 => 0,
        255 => 256,
        _ => e + usize::from(b & 0x7f_ffff != 0),
    }
}

/// The format of a largest value in `bucket` (the integer bits needed for
/// twice it are `ceil(log2 m) + 1`), at most `finest`.
fn frac_for_bucket(k: usize, finest: i8) -> i8 {
    match k {
        0 | 256 => 14,
        _ => (15 - (k as i32 - 127 + 1)).clamp(MIN_FRAC as i32, finest as i32) as i8,
    }
}

/// The format of `percentile_abs(src, q)` as [`frac_for_max`] gives it, but
/// down to [`IMAGE_MAX_FRAC`], without sorting: a histogram of the values'
/// power-of-two buckets (the format depends on nothing finer), and the
/// bucket holding the value of that rank.
pub fn frac_for_percentile(src: &[f32], q: f64) -> i8 {
    if src.is_empty() {
        return frac_for_max(0.0);
    }
    let mut hist = [0usize; 257];
    for &v in src {
        hist[bucket(v)] += 1;
    }
    let rank = ((src.len() - 1) as f64 * q).round() as usize;
    let mut seen = 0;
    for (k, &n) in hist.iter().enumerate() {
        seen += n;
        if seen > rank {
            return frac_for_bucket(k, IMAGE_MAX_FRAC);
        }
    }
    14
}

/// `round(s * scale)` (half away from zero) saturated to the symmetric
/// i16 range, NaN to 0. Written without `f32::round` (a library call on the
/// baseline target) so that it vectorises: with `r = trunc(v)`, `v - r` is
/// exact, and `r` moves one away from zero where that remainder is at least
/// a half.
#[inline(always)]
fn encode_fixed(src: &[f32], dst: &mut [i16], scale: f32) {
    for (d, &s) in dst.iter_mut().zip(src) {
        let v = (s * scale).clamp(-32767.0, 32767.0);
        let r = v.trunc();
        let up = if (v - r).abs() >= 0.5 { 1.0f32.copysign(v) } else { 0.0 };
        // NaN: `clamp` keeps it, and `as` turns it into 0.
        *d = (r + up) as i16;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn encode_fixed_avx2(src: &[f32], dst: &mut [i16], scale: f32) {
    encode_fixed(src, dst, scale)
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
    fn store_max(frac: i8) -> f32 {
        32767.0 * (-(frac as f32)).exp2()
    }
    fn choose_frac(src: &[f32], kind: Kind) -> i8 {
        match kind {
            Kind::Unit => mcdenoise_core::fixed::KERNEL_FRAC,
            Kind::Plain => frac_for_max(max_abs(src)),
            Kind::Image => frac_for_percentile(src, 0.999),
        }
    }
    fn encode(src: &[f32], dst: &mut [i16], frac: i8) {
        let scale = (frac as f32).exp2();
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked on the line above).
            unsafe { encode_fixed_avx2(src, dst, scale) };
            return;
        }
        encode_fixed(src, dst, scale);
    }
    fn decode(src: &[i16], dst: &mut [f32], frac: i8) {
        let scale = (-(frac as f32)).exp2();
        for (d, &s) in dst.iter_mut().zip(src) {
            *d = s.max(-32767) as f32 * scale;
        }
    }
}

/// Moves the part of each value of `c` beyond what `P` stores at `frac`
/// ([`HostPrecision::store_max`]) into `ex` at the same index, so that
/// `c + ex` is unchanged and `c` encodes without saturating. A filter's
/// radiance is stored in a format that keeps its 99.9th percentile
/// ([`Kind::Image`]): a bright region of more pixels than that (a window's
/// reflection in a glossy floor, 0.14 % of the corridor's frames) would
/// lose its top, and the learned filters put `ex` back at its pixel after
/// filtering, as they put back a light's excess. Returns how many values
/// moved; nothing moves in f32, and values that are not finite stay (the
/// encoding saturates them, as before).
pub fn keep_saturated<P: HostPrecision>(c: &mut [f32], ex: &mut [f32], frac: i8) -> usize {
    keep_within(c, ex, P::store_max(frac))
}

/// Where the accumulated colour `ta` (decoded) sits at its format's bound
/// `m` ([`HostPrecision::store_max`] of its `frac`) and the frame's own
/// value `x` at the same index lies beyond it on the same side, takes `x`.
/// The accumulation stores its colour in a format that keeps twice the
/// frame's 99.9th percentile ([`Kind::Image`]); a light smaller than that
/// share of the frame (seven pixels of sky at a corner, 2.3-3.2 against a
/// bound of 2) lost its top and its hue there, before any filter could put
/// it back with the excess ([`keep_saturated`]). A value at the bound is
/// the format's saturation (the blend of a saturated history with anything
/// below the bound is below it), and the frame's own value is then what f32
/// would have accumulated where the history holds the frame alone (a first
/// frame, a rejected history) and the best the frame knows elsewhere.
/// Returns how many values changed; nothing changes at an unbounded `m`
/// (f32), and values that are not finite are not taken.
pub fn restore_saturated(ta: &mut [f32], x: &[f32], m: f32) -> usize {
    if !m.is_finite() {
        return 0;
    }
    let mut changed = 0;
    for (v, &x) in ta.iter_mut().zip(x) {
        if x.is_finite() && ((*v >= m && x > m) || (*v <= -m && x < -m)) {
            *v = x;
            changed += 1;
        }
    }
    changed
}

/// [`keep_saturated`] at the bound `m` (`|v| <= m` stays).
pub fn keep_within(c: &mut [f32], ex: &mut [f32], m: f32) -> usize {
    if !m.is_finite() {
        return 0;
    }
    let mut moved = 0;
    for (v, e) in c.iter_mut().zip(ex.iter_mut()) {
        let k = v.clamp(-m, m);
        if k != *v && v.is_finite() {
            *e += *v - k;
            *v = k;
            moved += 1;
        }
    }
    moved
}

/// Clamps `a` and `b` (the same pixels, two images) to `|v| <= m` and adds
/// to `ex` the part of the excess both share: at each value, the smaller
/// of the two excesses where both lie beyond the bound on the same side,
/// else nothing. Returns how many values of `a` moved.
pub fn keep_shared_within(a: &mut [f32], b: &mut [f32], ex: &mut [f32], m: f32) -> usize {
    if !m.is_finite() {
        return 0;
    }
    let mut moved = 0;
    for ((va, vb), e) in a.iter_mut().zip(b.iter_mut()).zip(ex.iter_mut()) {
        let (ka, kb) = (va.clamp(-m, m), vb.clamp(-m, m));
        let (da, db) = (*va - ka, *vb - kb);
        if da.is_finite() && db.is_finite() {
            *e += if da > 0.0 && db > 0.0 {
                da.min(db)
            } else if da < 0.0 && db < 0.0 {
                da.max(db)
            } else {
                0.0
            };
        }
        if ka != *va && va.is_finite() {
            *va = ka;
            moved += 1;
        }
        if vb.is_finite() {
            *vb = kb;
        }
    }
    moved
}

/// The largest `|v|` (NaN ignored; 0 for none), in eight lanes that vectorise.
pub fn max_abs(src: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let mut chunks = src.chunks_exact(8);
    for c in &mut chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a = a.max(v.abs());
        }
    }
    let tail = chunks.remainder().iter().fold(0.0f32, |m, v| m.max(v.abs()));
    acc.iter().fold(tail, |m, &a| m.max(a))
}

/// Values per piece of the parallel conversions.
const PAR_CHUNK: usize = 1 << 16;

/// [`HostPrecision::encode`] in pieces over `pool`'s threads (the same
/// values: each is converted on its own).
pub fn encode_par<P: HostPrecision>(pool: &Pool, src: &[f32], dst: &mut [P::Store], frac: i8) {
    if pool.threads() <= 1 || src.len() < 2 * PAR_CHUNK {
        return P::encode(src, dst, frac);
    }
    pool.install(|| {
        dst.par_chunks_mut(PAR_CHUNK).zip(src.par_chunks(PAR_CHUNK)).for_each(|(d, s)| P::encode(s, d, frac))
    });
}

/// [`HostPrecision::decode`] in pieces over `pool`'s threads.
pub fn decode_par<P: HostPrecision>(pool: &Pool, src: &[P::Store], dst: &mut [f32], frac: i8) {
    if pool.threads() <= 1 || src.len() < 2 * PAR_CHUNK {
        return P::decode(src, dst, frac);
    }
    pool.install(|| {
        dst.par_chunks_mut(PAR_CHUNK).zip(src.par_chunks(PAR_CHUNK)).for_each(|(d, s)| P::decode(s, d, frac))
    });
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
    /// [`Planes::encode_as`] with the conversion spread over `pool`'s threads.
    pub fn encode_as_par<P: HostPrecision<Store = T>>(
        pool: &Pool,
        channels: usize,
        width: usize,
        height: usize,
        src: &[f32],
        kind: Kind,
    ) -> Self {
        let frac = P::frac_or_zero(P::choose_frac(src, kind));
        let mut p = Planes::new(channels, width, height).with_frac(frac);
        encode_par::<P>(pool, src, &mut p.data, frac);
        p
    }
    /// Decodes to f32.
    pub fn decode<P: HostPrecision<Store = T>>(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.data.len()];
        P::decode(&self.data, &mut out, self.frac);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `restore_saturated` takes the frame's value exactly where the
    /// accumulated value sits at the bound and the frame's lies beyond it
    /// on the same side; nothing at an unbounded format.
    #[test]
    fn restore_saturated_takes_the_frame_only_at_the_bound() {
        let m = 2.0f32;
        let ta = [2.0f32, 2.0, 2.0, 1.9, -2.0, -2.0, 2.0, 2.0, 0.5];
        let x = [3.0f32, 1.5, -3.0, 3.0, -4.0, 4.0, f32::INFINITY, f32::NAN, 0.7];
        let want = [3.0f32, 2.0, 2.0, 1.9, -4.0, -2.0, 2.0, 2.0, 0.5];
        let mut got = ta;
        assert_eq!(restore_saturated(&mut got, &x, m), 2);
        assert_eq!(got, want);
        let mut same = ta;
        assert_eq!(restore_saturated(&mut same, &x, f32::INFINITY), 0);
        assert_eq!(same, ta);
    }

    /// Values around every rounding boundary, the saturation limits, signed
    /// zeros, infinities and NaN, plus a sweep.
    fn probes() -> Vec<f32> {
        let mut v = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.499_999_97,
            -0.499_999_97,
            32766.5,
            32767.0,
            32767.4,
            32768.0,
            -32767.6,
            -40000.0,
            1.0e30,
            -1.0e30,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            65504.0,
            65520.0,
            -70000.0,
            6.0e-8,
            1.0e-8,
        ];
        let mut x = 0.123_456_7f32;
        for i in 0..5000 {
            x = (x * 1.618_034 + 0.377).fract();
            v.push((x - 0.5) * 2.0f32.powi(i % 40 - 20));
        }
        v
    }

    /// `keep_saturated` against its definition: in fixed point, on the
    /// probes at a format 64 times finer than the 99.9th percentile's, every
    /// finite value beyond the format's range moves (in f64, `c + ex` is the
    /// value within an f32 rounding of it) and then encodes and decodes
    /// within half a step; values inside stay bit for bit, as do NaN and the
    /// infinities; f16 moves only the finite values beyond its largest
    /// finite value; f32 moves nothing.
    #[test]
    fn saturated_parts_move_to_the_excess() {
        let src = probes();
        let frac = Fixed::choose_frac(&src, Kind::Image) + 6;
        let m = 32767.0f64 / 2f64.powi(frac as i32);
        let (mut c, mut ex) = (src.clone(), vec![0.0f32; src.len()]);
        let moved = keep_saturated::<Fixed>(&mut c, &mut ex, frac);
        let beyond = src.iter().filter(|v| v.is_finite() && v.abs() as f64 > m).count();
        assert!(beyond > 100, "the probes reach beyond the format ({beyond})");
        assert_eq!(moved, beyond);
        let mut back = vec![0i16; c.len()];
        Fixed::encode(&c, &mut back, frac);
        let mut dec = vec![0.0f32; c.len()];
        Fixed::decode(&back, &mut dec, frac);
        let step = 1.0 / 2f64.powi(frac as i32);
        for (i, &v) in src.iter().enumerate() {
            if v.is_nan() {
                assert!(c[i].is_nan() && ex[i] == 0.0, "NaN moved");
                continue;
            }
            if (v.abs() as f64) <= m {
                assert_eq!((c[i].to_bits(), ex[i]), (v.to_bits(), 0.0), "{v} inside the format moved");
                continue;
            }
            if !v.is_finite() {
                assert_eq!((c[i], ex[i]), (v, 0.0), "an infinity moved");
                continue;
            }
            assert_eq!(c[i].abs() as f64, m, "{v}: kept {}", c[i]);
            let sum = c[i] as f64 + ex[i] as f64;
            assert!((sum - v as f64).abs() <= 1e-6 * (v.abs() as f64), "{v}: {} + {} = {sum}", c[i], ex[i]);
            assert!((dec[i] as f64 - c[i] as f64).abs() <= 0.5 * step, "{v}: {} decodes as {}", c[i], dec[i]);
        }
        let (mut c16, mut ex16) = (src.clone(), vec![0.0f32; src.len()]);
        let moved16 = keep_saturated::<F16>(&mut c16, &mut ex16, 0);
        assert_eq!(moved16, src.iter().filter(|v| v.is_finite() && v.abs() > F16_MAX).count());
        assert!(c16.iter().all(|v| !v.is_finite() || v.abs() <= F16_MAX));
        let (mut c32, mut ex32) = (src.clone(), vec![0.0f32; src.len()]);
        assert_eq!(keep_saturated::<F32>(&mut c32, &mut ex32, 0), 0);
        assert!(c32.iter().zip(&src).all(|(a, b)| a.to_bits() == b.to_bits()) && ex32.iter().all(|&e| e == 0.0));
    }

    /// `keep_shared_within` against its definition in f64: both images end
    /// within the bound (non-finite values of either stay), `ex` gains the
    /// smaller excess where both lie beyond the bound on the same side and
    /// nothing elsewhere (a firefly of one image alone is clamped, not
    /// kept), values within the bound stay bit for bit, and an infinite
    /// bound moves nothing.
    #[test]
    fn only_the_excess_both_images_share_is_kept() {
        let a = probes();
        // The second image: the first's values in another order, so that
        // the probes meet every pairing of inside, beyond and non-finite.
        let b: Vec<f32> = a.iter().rev().copied().collect();
        let m = 0.75f32;
        let (mut ca, mut cb, mut ex) = (a.clone(), b.clone(), vec![0.25f32; a.len()]);
        let moved = keep_shared_within(&mut ca, &mut cb, &mut ex, m);
        assert_eq!(moved, a.iter().filter(|v| v.is_finite() && v.abs() > m).count());
        let (mut both, mut one) = (0, 0);
        for i in 0..a.len() {
            let (va, vb) = (a[i] as f64, b[i] as f64);
            let m64 = m as f64;
            let clamp = |v: f64| v.clamp(-m64, m64);
            for (v, c) in [(a[i], ca[i]), (b[i], cb[i])] {
                if !v.is_finite() {
                    assert!(c.to_bits() == v.to_bits() || (v.is_nan() && c.is_nan()), "{v} moved to {c}");
                } else if v.abs() <= m {
                    assert_eq!(c.to_bits(), v.to_bits(), "{v} inside the bound moved");
                } else {
                    assert_eq!(c as f64, clamp(v as f64), "{v}");
                }
            }
            let (da, db) = (va - clamp(va), vb - clamp(vb));
            let want = if !(da.is_finite() && db.is_finite()) {
                0.0
            } else if da > 0.0 && db > 0.0 {
                both += 1;
                da.min(db)
            } else if da < 0.0 && db < 0.0 {
                both += 1;
                da.max(db)
            } else {
                one += usize::from(da != 0.0 || db != 0.0);
                0.0
            };
            let got = ex[i] as f64 - 0.25;
            assert!((got - want).abs() <= 1e-6 * (1.0 + want.abs()), "{va} {vb}: {got} against {want}");
        }
        assert!(both > 10 && one > 10, "the probes hold both cases ({both}, {one})");
        let (mut ca, mut cb, mut ex) = (a.clone(), b.clone(), vec![0.0f32; a.len()]);
        assert_eq!(keep_shared_within(&mut ca, &mut cb, &mut ex, f32::INFINITY), 0);
        assert!(ca.iter().zip(&a).all(|(x, y)| x.to_bits() == y.to_bits()) && ex.iter().all(|&e| e == 0.0));
    }

    #[test]
    fn the_format_histogram_picks_the_percentile_format() {
        let mut src = probes();
        // Exact powers of two and their neighbours, where log2 rounding would err.
        for k in -30..30 {
            let p = 2f32.powi(k);
            src.extend([p, f32::from_bits(p.to_bits() + 1), f32::from_bits(p.to_bits() - 1), -p]);
        }
        let fin: Vec<f32> = src.iter().copied().filter(|v| v.is_finite()).collect();
        for q in [0.0, 0.5, 0.9, 0.999, 1.0] {
            for data in [&src[..], &fin[..], &fin[..7], &fin[100..101]] {
                let m = percentile_abs(data, q) as f64;
                // f64 reference: the integer bits that keep 2m below 2^bits.
                let want = if m.is_nan() || m <= 0.0 || !m.is_finite() {
                    14
                } else {
                    (15 - (2.0 * m).log2().ceil() as i32).clamp(-8, 22) as i8
                };
                assert_eq!(frac_for_percentile(data, q), want, "q {q}, {} values, m {m:e}", data.len());
            }
        }
        assert_eq!(frac_for_percentile(&[], 0.999), 14);
        for m in [1.0f32, 1.5, 2.0, 3.99, 4.0, 4.01, 16383.0, 16384.0, 16385.0, 1.0e-9, 1.0e9] {
            let want = (15 - (2.0 * m as f64).log2().ceil() as i32).clamp(-8, 14) as i8;
            assert_eq!(frac_for_max(m), want, "{m}");
        }
    }

    #[test]
    fn max_abs_is_the_fold() {
        let src = probes();
        for n in [0, 1, 7, 8, 9, 100, src.len()] {
            let s = &src[..n];
            let want = s.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert_eq!(max_abs(s).to_bits(), want.to_bits(), "{n} values");
        }
    }

    #[test]
    fn fixed_encode_rounds_half_away_and_saturates() {
        let src = probes();
        for frac in [-8i8, 0, 3, 8, 14, 22] {
            let mut got = vec![0i16; src.len()];
            Fixed::encode(&src, &mut got, frac);
            let scale = 2f64.powi(frac as i32);
            for (i, &s) in src.iter().enumerate() {
                // f64 reference: round half away from zero, saturate, NaN -> 0.
                let v = s as f64 * scale;
                let want = if v.is_nan() { 0 } else { v.round().clamp(-32767.0, 32767.0) as i16 };
                // The product is rounded to f32 before rounding to an integer, as
                // the encoder does; a tie in f64 is a tie in f32 here (scale is
                // a power of two).
                assert_eq!(got[i], want, "value {s:e} at frac {frac}");
            }
        }
    }

    #[test]
    fn f16_encode_decode_match_the_scalar_conversions() {
        let src = probes();
        let mut got = vec![half::f16::ZERO; src.len()];
        F16::encode(&src, &mut got, 0);
        for (i, &s) in src.iter().enumerate() {
            let want = half::f16::from_f32(s.clamp(-F16_MAX, F16_MAX));
            assert!(
                got[i].to_bits() == want.to_bits() || (s.is_nan() && got[i].is_nan()),
                "value {s:e}: {:?} against {:?}",
                got[i],
                want
            );
            assert!(got[i].is_finite() || s.is_nan(), "value {s:e} saturates");
        }
        let mut back = vec![0.0f32; src.len()];
        F16::decode(&got, &mut back, 0);
        for (h, b) in got.iter().zip(&back) {
            assert!(h.to_f32().to_bits() == b.to_bits() || h.is_nan(), "{h:?}");
        }
    }
}

//! The operator suite that the emulated Cortex-M4 (`embedded/cortex-m4`) and the
//! WASM module (`embedded/wasm`) run, and that the host checks: five core
//! operators on one 32x32 tile, each in f32 and in fixed point, in static
//! buffers (no heap, no large stack frames), compared against outputs of the
//! host's f64 oracle that are checked in as `expected.bin`.
//!
//! Every input is an integer, generated from a hash of its index, in units
//! of its fixed-point format's resolution (`units / 2^frac`): the f32 value,
//! the stored fixed-point value (`units` itself) and the oracle's f64 value
//! are the same number, so the one oracle output serves both precisions and
//! the fixed-point error measured is the arithmetic's alone, not the inputs'
//! quantisation. The inputs use each format's full resolution, so f32 sums
//! and products round as they would on real data.
//!
//! The operators run through the core's public functions with
//! [`Isa::Scalar`]: the one path every target has.
#![no_std]

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, Ordering};

use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams, AtrousPrecision};
use mcdenoise_core::conv::{self, Activation, Conv2d, ConvPrecision};
use mcdenoise_core::fixed::pow2;
use mcdenoise_core::pool::{self, PoolPrecision};
use mcdenoise_core::softmax::{self, SoftmaxPrecision};
use mcdenoise_core::unfold::{self, UnfoldPrecision};
use mcdenoise_core::{Error, Fixed, Isa, View, ViewMut, F32};

/// Tile width.
pub const W: usize = 32;
/// Tile height.
pub const H: usize = 32;
/// Pixels of the tile.
pub const N: usize = W * H;
/// Width of the compositor's coarse image.
pub const CW: usize = pool::coarse(W);
/// Height of the compositor's coarse image.
pub const CH: usize = pool::coarse(H);
/// Kernel size of the apply.
pub const K: usize = 7;
/// Taps of the apply's kernel map.
pub const TAPS: usize = K * K;
/// Radiance channels of the apply, the compositor and the à-trous level.
pub const RGB: usize = 3;
/// Planes of the channel softmax.
pub const SOFTMAX_PLANES: usize = 4;
/// Convolution: input channels.
pub const CONV_IN: usize = 4;
/// Convolution: output channels.
pub const CONV_OUT: usize = 4;
/// Convolution: kernel size.
pub const CONV_K: usize = 3;
/// Convolution weights.
pub const CONV_WEIGHTS: usize = CONV_OUT * CONV_IN * CONV_K * CONV_K;
/// LeakyReLU slope of the convolution (a power of two: exact in every precision).
pub const CONV_SLOPE: f32 = 0.125;
/// The à-trous level run (hole 2).
pub const ATROUS_LEVEL: u32 = 1;
/// The instruction set every case runs with.
pub const ISA: Isa = Isa::Scalar;

// The core sizes scratch for its x86_64 SIMD paths on x86_64 whatever the
// ISA run; on other targets the scalar paths' needs. `run` checks these
// against the core's `*_scratch_len` on every target (`Failure::Footprint`).
const X86: bool = cfg!(target_arch = "x86_64");
/// Scratch words of the f32 apply (`unfold::scratch_len::<F32>(7, 3, 32)`).
pub const APPLY_SCRATCH_F32: usize = if X86 { 192 } else { RGB * W };
/// Scratch words of the fixed-point apply.
pub const APPLY_SCRATCH_FIXED: usize = 0;
/// Scratch words of the f32 convolution (`conv2d_scratch_len::<F32>(3, 4, 4, 32)`).
pub const CONV_SCRATCH_F32: usize = W + CONV_WEIGHTS;
/// Scratch words of the fixed-point convolution.
pub const CONV_SCRATCH_FIXED: usize = 276;
/// Scratch words of the f32 à-trous level (`step_scratch_len::<F32>(1)`).
pub const ATROUS_SCRATCH_F32: usize = if X86 { 128_076 } else { 0 };
/// Scratch words of the fixed-point à-trous level.
pub const ATROUS_SCRATCH_FIXED: usize = 0;

/// An operator of the suite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// `unfold::apply`, 7x7 per-pixel kernels on 3 channels.
    Apply7,
    /// `pool::composite`, the scale compositor with a one-plane weight.
    Composite,
    /// `softmax::channel_softmax` over 4 planes.
    Softmax,
    /// `conv::conv2d`, 3x3, 4 -> 4 channels, bias, LeakyReLU(1/8).
    Conv3x3,
    /// `atrous::step` at level 1 with noise, normal and position guides.
    Atrous,
}

impl Op {
    /// Every operator, in the order of the expected-output file.
    pub const ALL: [Op; 5] = [Op::Apply7, Op::Composite, Op::Softmax, Op::Conv3x3, Op::Atrous];

    /// Short name.
    pub const fn name(self) -> &'static str {
        match self {
            Op::Apply7 => "apply7x7",
            Op::Composite => "composite",
            Op::Softmax => "softmax",
            Op::Conv3x3 => "conv3x3",
            Op::Atrous => "atrous",
        }
    }

    /// Output planes.
    pub const fn out_channels(self) -> usize {
        match self {
            Op::Apply7 | Op::Composite | Op::Atrous => RGB,
            Op::Softmax => SOFTMAX_PLANES,
            Op::Conv3x3 => CONV_OUT,
        }
    }

    /// Output values (`out_channels * N`).
    pub const fn out_len(self) -> usize {
        self.out_channels() * N
    }

    /// Fractional bits of the fixed-point output.
    pub const fn out_frac(self) -> i8 {
        match self {
            Op::Apply7 | Op::Composite | Op::Conv3x3 => 11,
            Op::Softmax => 14,
            Op::Atrous => 12,
        }
    }
}

/// A storage precision of the suite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prec {
    /// f32 storage and arithmetic (the Cortex-M4F's single-precision FPU).
    F32,
    /// i16 storage, i32/i64 integer arithmetic.
    Fixed,
}

impl Prec {
    /// Short name.
    pub const fn name(self) -> &'static str {
        match self {
            Prec::F32 => "f32",
            Prec::Fixed => "fixed",
        }
    }

    /// Bytes per stored value.
    pub const fn elem_bytes(self) -> usize {
        match self {
            Prec::F32 => 4,
            Prec::Fixed => 2,
        }
    }
}

/// One operator in one precision.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Case {
    /// The operator.
    pub op: Op,
    /// The precision.
    pub prec: Prec,
}

/// Every case, operator-major.
pub const CASES: [Case; 10] = {
    let mut out = [Case { op: Op::Apply7, prec: Prec::F32 }; 10];
    let mut i = 0;
    while i < 5 {
        out[2 * i] = Case { op: Op::ALL[i], prec: Prec::F32 };
        out[2 * i + 1] = Case { op: Op::ALL[i], prec: Prec::Fixed };
        i += 1;
    }
    out
};

impl Case {
    /// The tolerance `(atol, rtol)`: an output `v` passes when
    /// `|v - oracle| <= atol + rtol |oracle|`. Each `atol` is a worst-case
    /// bound of the operator's rounding on these inputs' ranges (derived in
    /// `docs/embedded.md`), rounded up; the oracle's f64 output stored as f32
    /// adds at most half an ulp of values below 8 (5e-7).
    pub const fn tolerance(self) -> (f32, f32) {
        let atol = match (self.op, self.prec) {
            // 49 products summed: gamma_49 * sum |k r| <= 49 * 2^-24 * 8.4.
            (Op::Apply7, Prec::F32) => 2.5e-5,
            // Pairs floored at 2^-19 (25 of them) and the output rounded to Q.11: 25 * 2^-19 + 2^-12.
            (Op::Apply7, Prec::Fixed) => 3.0e-4,
            // At most 24 ulp-of-1 roundings (cell sum, difference, product, sum, all below 16).
            (Op::Composite, Prec::F32) => 2.0e-6,
            // The cell mean and the weighted difference each rounded to Q.12, the output to Q.11: 2^-11.
            (Op::Composite, Prec::Fixed) => 5.0e-4,
            // exp within a few ulp: 0.25 * 2 * 3e-7 plus the sum and the division.
            (Op::Softmax, Prec::F32) => 1.0e-6,
            // exp of a Q.8 logit via 2^(Q.8): 0.14 % per weight, 0.25 * 2 * 0.142 % + roundings.
            (Op::Softmax, Prec::Fixed) => 8.0e-4,
            // 36 products and a bias: gamma_37 * sum |w x| + |b| <= 37 * 2^-24 * 37.
            (Op::Conv3x3, Prec::F32) => 8.5e-5,
            // The exact i32 sum rounded to Q.11 (2^-12), the slope's product rounded again (2^-12 / 8).
            (Op::Conv3x3, Prec::Fixed) => 2.8e-4,
            // Weights within 8.4e-6 relative (exponents up to 17 computed in f32), times twice the
            // spread of a window's values (0.6), plus the 25-term sums.
            (Op::Atrous, Prec::F32) => 2.0e-5,
            // Exponents floored to 1/256 nat and exp_q8's 0.14 %: 0.55 % per weight, times the
            // spread (0.6), plus the output rounding (2^-13).
            (Op::Atrous, Prec::Fixed) => 3.5e-3,
        };
        (atol, 0.0)
    }
}

/// An input tensor: its values are `units(i) / 2^frac()`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tensor {
    /// The apply's kernel map: 49 planes, taps in `[-100, 700) / 2^14`.
    ApplyKernel,
    /// The apply's radiance: 3 planes in `[0, 4)`.
    ApplyRadiance,
    /// The compositor's fine image: 3 planes in `[0, 4)`.
    Fine,
    /// The compositor's coarse image: 3 planes of 16x16 in `[0, 4)`.
    Coarse,
    /// The compositor's weight: 1 plane in `[0, 1]`.
    Alpha,
    /// The softmax's logits: 4 planes in `[-8, 8)`.
    Logits,
    /// The convolution's input: 4 planes in `[-4, 4)`.
    ConvInput,
    /// The convolution's weights `[cout][cin][ky][kx]` in `[-1/4, 1/4)`.
    ConvWeights,
    /// The convolution's biases in `[-1, 1)`.
    ConvBias,
    /// The à-trous radiance: two noisy surfaces meeting along a diagonal edge, 3 planes.
    AtrousRadiance,
    /// The à-trous noise variance: 1 plane in `[3/256, 9/256)`.
    AtrousNoise,
    /// The à-trous normals: (0, 0, 1) left of the edge, (0.6, 0, 0.8) right of it, jittered.
    AtrousNormal,
    /// The à-trous positions: a plane at z = 2 and a plane orthogonal to the right normal.
    AtrousPosition,
}

impl Tensor {
    /// Values.
    pub const fn len(self) -> usize {
        match self {
            Tensor::ApplyKernel => TAPS * N,
            Tensor::ApplyRadiance | Tensor::Fine | Tensor::AtrousRadiance => RGB * N,
            Tensor::AtrousNormal | Tensor::AtrousPosition => 3 * N,
            Tensor::Coarse => RGB * CW * CH,
            Tensor::Alpha | Tensor::AtrousNoise => N,
            Tensor::Logits => SOFTMAX_PLANES * N,
            Tensor::ConvInput => CONV_IN * N,
            Tensor::ConvWeights => CONV_WEIGHTS,
            Tensor::ConvBias => CONV_OUT,
        }
    }

    /// Whether the tensor has no values (never).
    pub const fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// Fractional bits of the fixed-point storage: values are multiples of `2^-frac`.
    pub const fn frac(self) -> i8 {
        match self {
            Tensor::ApplyKernel | Tensor::Alpha | Tensor::AtrousNoise | Tensor::AtrousNormal => 14,
            Tensor::Logits => 8,
            Tensor::ConvWeights => 11,
            // The bias is stored in the output's format.
            Tensor::ConvBias => Op::Conv3x3.out_frac(),
            _ => 12,
        }
    }

    /// The integer value of element `i` (plane-major, then row-major).
    pub fn units(self, i: usize) -> i32 {
        let s = self as u32 + 1;
        let (c, p) = (i / N, i % N);
        let (y, x) = ((p / W) as i32, (p % W) as i32);
        // Two surfaces meet along a diagonal: right of it when 2x > 24 + y.
        let right = 2 * x > 24 + y;
        match self {
            Tensor::ApplyKernel => uniform(s, i, -100, 700),
            Tensor::ApplyRadiance | Tensor::Fine | Tensor::Coarse => uniform(s, i, 0, 16384),
            Tensor::Alpha => uniform(s, i, 0, 16385),
            Tensor::Logits => uniform(s, i, -2048, 2048),
            Tensor::ConvInput => uniform(s, i, -16384, 16384),
            Tensor::ConvWeights => uniform(s, i, -512, 512),
            Tensor::ConvBias => uniform(s, i, -2048, 2048),
            Tensor::AtrousRadiance => {
                let base = if right { [816, 1632, 3680] } else { [3200, 2048, 1232] };
                base[c] + 32 * y + uniform(s, i, -768, 768)
            }
            Tensor::AtrousNoise => uniform(s, i, 192, 576),
            Tensor::AtrousNormal => {
                let n = if right { [9856, 0, 13120] } else { [0, 0, 16384] };
                n[c] + uniform(s, i, -64, 65)
            }
            Tensor::AtrousPosition => {
                // x and y step 1/64 per pixel; the right plane falls 0.75 in z per unit of x,
                // so (0.6, 0, 0.8) is its normal.
                let v = match c {
                    0 => 64 * x,
                    1 => 64 * y,
                    _ if right => 10240 - 48 * x,
                    _ => 8192,
                };
                v + uniform(s, i, -2, 3)
            }
        }
    }

    /// The value of element `i`.
    pub fn value(self, i: usize) -> f32 {
        self.units(i) as f32 * pow2(-self.frac())
    }
}

/// A 32-bit integer hash (two multiply-xorshift rounds).
fn mix(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// An integer in `[lo, hi)` from stream `s`, element `i`.
fn uniform(s: u32, i: usize, lo: i32, hi: i32) -> i32 {
    lo + (mix(mix(s.wrapping_mul(0x9e37_79b9)) ^ i as u32) % (hi - lo) as u32) as i32
}

/// A storage element of the suite.
pub trait Store: Copy + 'static {
    /// Whether views carry a fixed-point format.
    const FIXED: bool;
    /// The stored form of `units / 2^frac` (exact for the suite's inputs).
    fn from_units(units: i32, frac: i8) -> Self;
    /// The value stored, as f32 (exact).
    fn to_f32(self, frac: i8) -> f32;
    /// A value no operator writes, to find outputs left unwritten.
    const SENTINEL: Self;
}

impl Store for f32 {
    const FIXED: bool = false;
    fn from_units(units: i32, frac: i8) -> f32 {
        units as f32 * pow2(-frac)
    }
    fn to_f32(self, _frac: i8) -> f32 {
        self
    }
    const SENTINEL: f32 = f32::NAN;
}

impl Store for i16 {
    const FIXED: bool = true;
    fn from_units(units: i32, _frac: i8) -> i16 {
        units.clamp(-32767, 32767) as i16
    }
    fn to_f32(self, frac: i8) -> f32 {
        self.max(-32767) as f32 * pow2(-frac)
    }
    const SENTINEL: i16 = i16::MIN;
}

fn fill<T: Store>(dst: &mut [T], t: Tensor) {
    for (i, d) in dst.iter_mut().enumerate() {
        *d = T::from_units(t.units(i), t.frac());
    }
}

fn view<T: Store>(data: &[T], c: usize, w: usize, h: usize, frac: i8) -> Result<View<'_, T>, Error> {
    let v = View::new(data, c, w, h)?;
    Ok(if T::FIXED { v.with_frac(frac) } else { v })
}

fn view_mut<T: Store>(data: &mut [T], c: usize, frac: i8) -> Result<ViewMut<'_, T>, Error> {
    data.fill(T::SENTINEL);
    let v = ViewMut::new(data, c, W, H)?;
    Ok(if T::FIXED { v.with_frac(frac) } else { v })
}

/// Something that wraps each operator call: the Cortex-M4 build counts
/// instructions and the stack there; elsewhere it just calls.
pub trait Meter {
    /// Runs `f` (the one core call of a case) and returns its result.
    fn measure<R>(&mut self, f: impl FnOnce() -> R) -> R;
}

/// A meter that measures nothing.
pub struct NoMeter;

impl Meter for NoMeter {
    fn measure<R>(&mut self, f: impl FnOnce() -> R) -> R {
        f()
    }
}

/// A static buffer set, handed out to one caller at a time.
pub struct Slot<T> {
    busy: AtomicBool,
    cell: UnsafeCell<T>,
}

// SAFETY: `with` hands out the contents to one caller at a time (the flag).
unsafe impl<T: Send> Sync for Slot<T> {}

impl<T> Slot<T> {
    /// A slot holding `v`.
    pub const fn new(v: T) -> Self {
        Slot { busy: AtomicBool::new(false), cell: UnsafeCell::new(v) }
    }

    /// Runs `f` on the contents, or returns `None` when another call holds them.
    pub fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> Option<R> {
        if self.busy.swap(true, Ordering::Acquire) {
            return None;
        }
        // SAFETY: the flag was clear, so no other reference exists until it is cleared below.
        let r = f(unsafe { &mut *self.cell.get() });
        self.busy.store(false, Ordering::Release);
        Some(r)
    }
}

/// The apply's buffers.
pub struct ApplyBufs<T, const S: usize> {
    kernel: [T; TAPS * N],
    src: [T; RGB * N],
    dst: [T; RGB * N],
    scratch: [f32; S],
}

impl<T: Copy, const S: usize> ApplyBufs<T, S> {
    const fn new(z: T) -> Self {
        ApplyBufs { kernel: [z; TAPS * N], src: [z; RGB * N], dst: [z; RGB * N], scratch: [0.0; S] }
    }
}

/// The compositor's buffers.
pub struct CompositeBufs<T> {
    fine: [T; RGB * N],
    coarse: [T; RGB * CW * CH],
    alpha: [T; N],
    dst: [T; RGB * N],
}

impl<T: Copy> CompositeBufs<T> {
    const fn new(z: T) -> Self {
        CompositeBufs { fine: [z; RGB * N], coarse: [z; RGB * CW * CH], alpha: [z; N], dst: [z; RGB * N] }
    }
}

/// The channel softmax's buffers.
pub struct SoftmaxBufs<T> {
    src: [T; SOFTMAX_PLANES * N],
    dst: [T; SOFTMAX_PLANES * N],
}

impl<T: Copy> SoftmaxBufs<T> {
    const fn new(z: T) -> Self {
        SoftmaxBufs { src: [z; SOFTMAX_PLANES * N], dst: [z; SOFTMAX_PLANES * N] }
    }
}

/// The convolution's buffers.
pub struct ConvBufs<T, const S: usize> {
    weights: [T; CONV_WEIGHTS],
    bias: [T; CONV_OUT],
    src: [T; CONV_IN * N],
    dst: [T; CONV_OUT * N],
    scratch: [f32; S],
}

impl<T: Copy, const S: usize> ConvBufs<T, S> {
    const fn new(z: T) -> Self {
        ConvBufs {
            weights: [z; CONV_WEIGHTS],
            bias: [z; CONV_OUT],
            src: [z; CONV_IN * N],
            dst: [z; CONV_OUT * N],
            scratch: [0.0; S],
        }
    }
}

/// The à-trous level's buffers.
pub struct AtrousBufs<T, const S: usize> {
    src: [T; RGB * N],
    noise: [T; N],
    normal: [T; 3 * N],
    position: [T; 3 * N],
    dst: [T; RGB * N],
    scratch: [f32; S],
}

impl<T: Copy, const S: usize> AtrousBufs<T, S> {
    const fn new(z: T) -> Self {
        AtrousBufs {
            src: [z; RGB * N],
            noise: [z; N],
            normal: [z; 3 * N],
            position: [z; 3 * N],
            dst: [z; RGB * N],
            scratch: [0.0; S],
        }
    }
}

static APPLY_F32: Slot<ApplyBufs<f32, APPLY_SCRATCH_F32>> = Slot::new(ApplyBufs::new(0.0));
static APPLY_FIXED: Slot<ApplyBufs<i16, APPLY_SCRATCH_FIXED>> = Slot::new(ApplyBufs::new(0));
static COMPOSITE_F32: Slot<CompositeBufs<f32>> = Slot::new(CompositeBufs::new(0.0));
static COMPOSITE_FIXED: Slot<CompositeBufs<i16>> = Slot::new(CompositeBufs::new(0));
static SOFTMAX_F32: Slot<SoftmaxBufs<f32>> = Slot::new(SoftmaxBufs::new(0.0));
static SOFTMAX_FIXED: Slot<SoftmaxBufs<i16>> = Slot::new(SoftmaxBufs::new(0));
static CONV_F32: Slot<ConvBufs<f32, CONV_SCRATCH_F32>> = Slot::new(ConvBufs::new(0.0));
static CONV_FIXED: Slot<ConvBufs<i16, CONV_SCRATCH_FIXED>> = Slot::new(ConvBufs::new(0));
static ATROUS_F32: Slot<AtrousBufs<f32, ATROUS_SCRATCH_F32>> = Slot::new(AtrousBufs::new(0.0));
static ATROUS_FIXED: Slot<AtrousBufs<i16, ATROUS_SCRATCH_FIXED>> = Slot::new(AtrousBufs::new(0));

fn apply<P: UnfoldPrecision, const S: usize>(b: &mut ApplyBufs<P::Store, S>, m: &mut impl Meter) -> Result<(), Error>
where
    P::Store: Store,
{
    fill(&mut b.kernel, Tensor::ApplyKernel);
    fill(&mut b.src, Tensor::ApplyRadiance);
    let kernel = view(&b.kernel, TAPS, W, H, Tensor::ApplyKernel.frac())?;
    let src = view(&b.src, RGB, W, H, Tensor::ApplyRadiance.frac())?;
    let mut dst = view_mut(&mut b.dst, RGB, Op::Apply7.out_frac())?;
    let scratch = &mut b.scratch;
    m.measure(|| unfold::apply::<P>(ISA, K, &kernel, &src, &mut dst, scratch))
}

fn composite<P: PoolPrecision>(b: &mut CompositeBufs<P::Store>, m: &mut impl Meter) -> Result<(), Error>
where
    P::Store: Store,
{
    fill(&mut b.fine, Tensor::Fine);
    fill(&mut b.coarse, Tensor::Coarse);
    fill(&mut b.alpha, Tensor::Alpha);
    let fine = view(&b.fine, RGB, W, H, Tensor::Fine.frac())?;
    let coarse = view(&b.coarse, RGB, CW, CH, Tensor::Coarse.frac())?;
    let alpha = view(&b.alpha, 1, W, H, Tensor::Alpha.frac())?;
    let mut dst = view_mut(&mut b.dst, RGB, Op::Composite.out_frac())?;
    m.measure(|| pool::composite::<P>(ISA, &fine, &coarse, &alpha, &mut dst, 0))
}

fn channel_softmax<P: SoftmaxPrecision>(b: &mut SoftmaxBufs<P::Store>, m: &mut impl Meter) -> Result<(), Error>
where
    P::Store: Store,
{
    fill(&mut b.src, Tensor::Logits);
    let src = view(&b.src, SOFTMAX_PLANES, W, H, Tensor::Logits.frac())?;
    let mut dst = view_mut(&mut b.dst, SOFTMAX_PLANES, Op::Softmax.out_frac())?;
    m.measure(|| softmax::channel_softmax::<P>(ISA, &src, &mut dst))
}

fn conv3x3<P: ConvPrecision, const S: usize>(b: &mut ConvBufs<P::Store, S>, m: &mut impl Meter) -> Result<(), Error>
where
    P::Store: Store,
{
    fill(&mut b.weights, Tensor::ConvWeights);
    fill(&mut b.bias, Tensor::ConvBias);
    fill(&mut b.src, Tensor::ConvInput);
    let layer = Conv2d {
        k: CONV_K,
        cin: CONV_IN,
        cout: CONV_OUT,
        weights: &b.weights,
        bias: Some(&b.bias),
        act: Activation::LeakyRelu(CONV_SLOPE),
        weight_frac: Tensor::ConvWeights.frac(),
    };
    let src = view(&b.src, CONV_IN, W, H, Tensor::ConvInput.frac())?;
    let mut dst = view_mut(&mut b.dst, CONV_OUT, Op::Conv3x3.out_frac())?;
    let scratch = &mut b.scratch;
    m.measure(|| conv::conv2d::<P>(ISA, &layer, &src, &mut dst, 0, scratch))
}

fn atrous_level<P: AtrousPrecision, const S: usize>(
    b: &mut AtrousBufs<P::Store, S>,
    m: &mut impl Meter,
) -> Result<(), Error>
where
    P::Store: Store,
{
    fill(&mut b.src, Tensor::AtrousRadiance);
    fill(&mut b.noise, Tensor::AtrousNoise);
    fill(&mut b.normal, Tensor::AtrousNormal);
    fill(&mut b.position, Tensor::AtrousPosition);
    let guides = AtrousGuides {
        noise: view(&b.noise, 1, W, H, Tensor::AtrousNoise.frac())?,
        normal: Some(view(&b.normal, 3, W, H, Tensor::AtrousNormal.frac())?),
        position: Some(view(&b.position, 3, W, H, Tensor::AtrousPosition.frac())?),
        depth: None,
    };
    let src = view(&b.src, RGB, W, H, Tensor::AtrousRadiance.frac())?;
    let mut dst = view_mut(&mut b.dst, RGB, Op::Atrous.out_frac())?;
    let params = AtrousParams::default();
    let scratch = &mut b.scratch;
    m.measure(|| atrous::step::<P>(ISA, ATROUS_LEVEL, 1, false, &params, &guides, &src, &mut dst, 0, scratch))
}

/// Why a case could not be checked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Failure {
    /// The core refused the call.
    Core(Error),
    /// The case's buffers are in use (a re-entrant call).
    Busy,
    /// `expected.bin` lacks this operator's outputs (regenerate it: see `docs/embedded.md`).
    NoExpected,
    /// The case's static buffers are not [`footprint`] at 32x32 (a scratch
    /// constant differs from what the core asks for on this target).
    Footprint {
        /// Bytes of the static buffers.
        have: usize,
        /// [`footprint`] of the case.
        want: usize,
    },
}

impl From<Error> for Failure {
    fn from(e: Error) -> Self {
        Failure::Core(e)
    }
}

impl core::fmt::Display for Failure {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Failure::Core(e) => write!(f, "core error: {e}"),
            Failure::Busy => f.write_str("buffers busy"),
            Failure::NoExpected => f.write_str("expected.bin has no outputs for this operator"),
            Failure::Footprint { have, want } => {
                write!(f, "static buffers of {have} bytes, but the core's scratch lengths make {want}")
            }
        }
    }
}

/// What a case gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    /// Output values compared.
    pub values: usize,
    /// Largest `|output - oracle|`.
    pub max_abs: f32,
    /// Largest `|output - oracle| / (atol + rtol |oracle|)` (infinite for NaN); `<= 1` passes.
    pub worst_ratio: f32,
    /// Where the worst ratio is.
    pub worst_index: usize,
    /// Bytes of the case's static buffers (inputs, weights, outputs, scratch).
    pub static_bytes: usize,
    /// FNV-1a hash of the outputs' bits as decoded f32 (to compare targets bit for bit).
    pub hash: u32,
}

impl Outcome {
    /// Whether every output is within tolerance.
    pub fn passed(&self) -> bool {
        self.worst_ratio <= 1.0
    }
}

/// The checked-in oracle outputs (see [`expected_in`] for the layout).
pub static EXPECTED_FILE: &[u8] = include_bytes!("../expected.bin");

/// Magic bytes that open the expected-output file.
pub const EXPECTED_MAGIC: &[u8; 8] = b"MCDNEXP1";

/// The oracle outputs of `op` in `file`, as little-endian f32 bytes. Layout:
/// the magic, a `u32` count of operators, then per operator (in
/// [`Op::ALL`] order) a `u32` count of values and the values as f32, all
/// little-endian.
pub fn expected_in(file: &[u8], op: Op) -> Option<&[u8]> {
    let rd = |at: usize| -> Option<usize> {
        let b = file.get(at..at + 4)?;
        Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    if file.get(..8)? != EXPECTED_MAGIC {
        return None;
    }
    let count = rd(8)?;
    let mut at = 12;
    for (k, o) in Op::ALL.iter().enumerate().take(count) {
        let len = rd(at)?;
        let bytes = file.get(at + 4..at + 4 + 4 * len)?;
        if *o == op {
            return (len == op.out_len() && k < count).then_some(bytes);
        }
        at += 4 + 4 * len;
    }
    None
}

fn value_at(bytes: &[u8], i: usize) -> f32 {
    let b = &bytes[4 * i..4 * i + 4];
    f32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

fn check<T: Store>(
    case: Case,
    out: &[T],
    static_bytes: usize,
    visit: &mut dyn FnMut(usize, f32),
) -> Result<Outcome, Failure> {
    let want = expected_in(EXPECTED_FILE, case.op).ok_or(Failure::NoExpected)?;
    let (atol, rtol) = case.tolerance();
    let frac = case.op.out_frac();
    let mut o =
        Outcome { values: out.len(), max_abs: 0.0, worst_ratio: 0.0, worst_index: 0, static_bytes, hash: 0x811c_9dc5 };
    for (i, &v) in out.iter().enumerate() {
        let got = v.to_f32(frac);
        visit(i, got);
        for byte in got.to_bits().to_le_bytes() {
            o.hash = (o.hash ^ byte as u32).wrapping_mul(0x0100_0193);
        }
        let w = value_at(want, i);
        let err = (got - w).abs();
        let mut ratio = err / (atol + rtol * w.abs());
        if ratio.is_nan() {
            ratio = f32::INFINITY;
        }
        if err > o.max_abs || err.is_nan() {
            o.max_abs = if err.is_nan() { f32::INFINITY } else { err };
        }
        if ratio > o.worst_ratio {
            o.worst_ratio = ratio;
            o.worst_index = i;
        }
    }
    Ok(o)
}

/// Runs one case: fills its inputs, runs the core call inside `meter`, then
/// hands every output value (decoded to f32) to `visit` and compares it with
/// the oracle.
pub fn run(case: Case, meter: &mut impl Meter, visit: &mut dyn FnMut(usize, f32)) -> Result<Outcome, Failure> {
    macro_rules! go {
        ($slot:expr, $f:ident::<$($g:tt),+>) => {
            $slot
                .with(|b| {
                    let (have, want) = (core::mem::size_of_val(b), footprint(case.op, case.prec, W));
                    if have != want {
                        return Err(Failure::Footprint { have, want });
                    }
                    $f::<$($g),+>(b, meter)?;
                    check(case, &b.dst, have, visit)
                })
                .unwrap_or(Err(Failure::Busy))
        };
    }
    match (case.op, case.prec) {
        (Op::Apply7, Prec::F32) => go!(APPLY_F32, apply::<F32, APPLY_SCRATCH_F32>),
        (Op::Apply7, Prec::Fixed) => go!(APPLY_FIXED, apply::<Fixed, APPLY_SCRATCH_FIXED>),
        (Op::Composite, Prec::F32) => go!(COMPOSITE_F32, composite::<F32>),
        (Op::Composite, Prec::Fixed) => go!(COMPOSITE_FIXED, composite::<Fixed>),
        (Op::Softmax, Prec::F32) => go!(SOFTMAX_F32, channel_softmax::<F32>),
        (Op::Softmax, Prec::Fixed) => go!(SOFTMAX_FIXED, channel_softmax::<Fixed>),
        (Op::Conv3x3, Prec::F32) => go!(CONV_F32, conv3x3::<F32, CONV_SCRATCH_F32>),
        (Op::Conv3x3, Prec::Fixed) => go!(CONV_FIXED, conv3x3::<Fixed, CONV_SCRATCH_FIXED>),
        (Op::Atrous, Prec::F32) => go!(ATROUS_F32, atrous_level::<F32, ATROUS_SCRATCH_F32>),
        (Op::Atrous, Prec::Fixed) => go!(ATROUS_FIXED, atrous_level::<Fixed, ATROUS_SCRATCH_FIXED>),
    }
}

/// Bytes an `s x s` tile of `op` needs in RAM in `prec`: its inputs,
/// weights, outputs and scratch, laid out as the suite lays out the 32x32
/// tile (the stack comes on top).
pub fn footprint(op: Op, prec: Prec, s: usize) -> usize {
    let n = s * s;
    let e = prec.elem_bytes();
    let scratch = match (op, prec) {
        (Op::Apply7, Prec::F32) => unfold::scratch_len::<F32>(K, RGB, s),
        (Op::Apply7, Prec::Fixed) => unfold::scratch_len::<Fixed>(K, RGB, s),
        (Op::Conv3x3, Prec::F32) => conv::conv2d_scratch_len::<F32>(CONV_K, CONV_IN, CONV_OUT, s),
        (Op::Conv3x3, Prec::Fixed) => conv::conv2d_scratch_len::<Fixed>(CONV_K, CONV_IN, CONV_OUT, s),
        (Op::Atrous, Prec::F32) => atrous::step_scratch_len::<F32>(ATROUS_LEVEL),
        (Op::Atrous, Prec::Fixed) => atrous::step_scratch_len::<Fixed>(ATROUS_LEVEL),
        _ => 0,
    };
    let values = match op {
        Op::Apply7 => (TAPS + 2 * RGB) * n,
        Op::Composite => 2 * RGB * n + n + RGB * pool::coarse(s) * pool::coarse(s),
        Op::Softmax => 2 * SOFTMAX_PLANES * n,
        Op::Conv3x3 => CONV_WEIGHTS + CONV_OUT + (CONV_IN + CONV_OUT) * n,
        Op::Atrous => (RGB + 1 + 3 + 3 + RGB) * n,
    };
    values * e + 4 * scratch
}

/// The largest `s` such that an `s x s` tile of `op` in `prec` plus `stack`
/// bytes of stack fits in `budget` bytes (0 when not even 1x1 does).
pub fn largest_tile(op: Op, prec: Prec, stack: usize, budget: usize) -> usize {
    let mut s = 0;
    while s < 65536 && footprint(op, prec, s + 1) + stack <= budget {
        s += 1;
    }
    s
}

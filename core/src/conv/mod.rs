//! 2-D convolution layers: `k x k` kernels with `k` in {1, 3, 5}, any channel
//! counts, zero padding (`k / 2`, output the size of the input), optional bias
//! and an activation (identity, ReLU, LeakyReLU).
//!
//! Weights are `[cout][cin][k][k]` row-major (PyTorch's layout). Every path
//! sums, per output pixel, the bias first, then input channels ascending,
//! then taps row-major; out-of-image taps are skipped (zero padding).
//!
//! The AVX2 path keeps a block of up to six output channels times sixteen
//! pixels in twelve accumulator registers and streams the input once per
//! block: each input vector feeds up to six FMAs and each broadcast weight two.
//!
//! The backward pass (f32: the activation's, the input's, the weights' and
//! the bias's gradients into caller buffers) is in [`grad`].

use crate::error::{check_scratch, Error, Result, Shape};
use crate::precision::{
    sealed::{Checked, Sealed},
    F16Arith, Fixed, Precision, F16, F32,
};
use crate::unfold::check_band;
use crate::view::{View, ViewMut};
use crate::Isa;

pub(crate) mod fixed;
pub(crate) mod float;
pub mod grad;

/// Supported kernel sizes.
pub const KERNEL_SIZES: [usize; 3] = [1, 3, 5];

/// The nonlinearity after a layer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    /// None.
    Identity,
    /// `max(x, 0)` (NaN becomes 0).
    Relu,
    /// `x` for `x > 0`, `slope * x` otherwise; `slope` in `[0, 1]`.
    LeakyRelu(f32),
}

impl Activation {
    /// Applies the activation to one value (the reference every path matches).
    #[inline(always)]
    pub fn apply(self, x: f32) -> f32 {
        match self {
            Activation::Identity => x,
            Activation::Relu => {
                if x > 0.0 {
                    x
                } else {
                    0.0
                }
            }
            Activation::LeakyRelu(s) => {
                let sx = s * x;
                if x > sx {
                    x
                } else {
                    sx
                }
            }
        }
    }
}

/// One convolution layer's parameters.
#[derive(Clone, Copy, Debug)]
pub struct Conv2d<'a, T> {
    /// Kernel size: 1, 3 or 5.
    pub k: usize,
    /// Input channels.
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
    /// `cout * cin * k * k` weights, `[cout][cin][ky][kx]`.
    pub weights: &'a [T],
    /// `cout` biases, or none.
    pub bias: Option<&'a [T]>,
    /// Nonlinearity applied after the bias.
    pub act: Activation,
    /// Fixed point only: fractional bits of the weights (the bias is in the
    /// output's format). Ignored by the floating-point precisions.
    pub weight_frac: i8,
}

impl<T> Conv2d<'_, T> {
    /// Checks the layer's own consistency.
    pub fn check(&self) -> Result<()> {
        if !KERNEL_SIZES.contains(&self.k) {
            return Err(Error::BadParameter { what: "conv kernel size", expected: "1, 3 or 5" });
        }
        if self.cin == 0 || self.cout == 0 {
            return Err(Error::BadParameter { what: "conv channels", expected: "at least one in and one out" });
        }
        let n = self
            .cout
            .checked_mul(self.cin)
            .and_then(|v| v.checked_mul(self.k * self.k))
            .ok_or(Error::SizeOverflow { what: "conv weights" })?;
        if self.weights.len() != n {
            return Err(Error::BufferTooSmall { what: "conv weights", needed: n, got: self.weights.len() });
        }
        if let Some(b) = self.bias {
            if b.len() != self.cout {
                return Err(Error::BufferTooSmall { what: "conv bias", needed: self.cout, got: b.len() });
            }
        }
        if let Activation::LeakyRelu(s) = self.act {
            if !(0.0..=1.0).contains(&s) {
                return Err(Error::BadParameter { what: "leaky relu slope", expected: "in [0, 1]" });
            }
        }
        Ok(())
    }
}

/// Precisions the convolution is implemented for.
pub trait ConvPrecision: Precision + Sealed {
    #[doc(hidden)]
    fn scratch_len_impl(k: usize, cin: usize, cout: usize, width: usize) -> usize {
        width.saturating_add(cout.saturating_mul(cin).saturating_mul(k.saturating_mul(k)))
    }
    #[doc(hidden)]
    fn check_layer(_layer: &Conv2d<'_, Self::Store>) -> Result<()> {
        Ok(())
    }
    #[doc(hidden)]
    fn forward_impl(
        chk: Checked,
        layer: &Conv2d<'_, Self::Store>,
        src: &View<'_, Self::Store>,
        dst: &mut ViewMut<'_, Self::Store>,
        y0: usize,
        scratch: &mut [f32],
    );
}

macro_rules! float_conv {
    ($p:ty, $a:ty) => {
        impl ConvPrecision for $p {
            fn forward_impl(
                chk: Checked,
                layer: &Conv2d<'_, Self::Store>,
                src: &View<'_, Self::Store>,
                dst: &mut ViewMut<'_, Self::Store>,
                y0: usize,
                scratch: &mut [f32],
            ) {
                float::forward::<_, $a>(chk.isa(), layer, src, dst, y0, scratch)
            }
        }
    };
}
float_conv!(F32, f32);
float_conv!(F16, f32);
float_conv!(F16Arith, crate::real::H);

impl ConvPrecision for Fixed {
    /// Packed weight pairs (one i32 per output channel, channel pair and
    /// tap) and a ring of `k` rows of interleaved channel pairs.
    fn scratch_len_impl(k: usize, cin: usize, cout: usize, width: usize) -> usize {
        fixed::scratch_len(k, cin, cout, width)
    }
    /// The bit budget: with inputs in `[-32767, 32767]`, every output
    /// channel's `sum |w|` up to 65535 keeps the exact i32 sum below 2^31.
    fn check_layer(layer: &Conv2d<'_, i16>) -> Result<()> {
        // The layer's own checks first: they make `weights` exactly
        // `cout * cin * k * k` long (no overflow), so the chunks below are the
        // output channels, whoever calls this.
        layer.check()?;
        let per = layer.cin * layer.k * layer.k;
        for co in layer.weights.chunks_exact(per) {
            let s: i64 = co.iter().map(|&w| (w as i64).abs()).sum();
            if s > 65535 {
                return Err(Error::BadParameter {
                    what: "fixed-point conv weights",
                    expected: "sum of |w| per output channel at most 65535 stored units (use fewer fractional bits)",
                });
            }
        }
        Ok(())
    }
    fn forward_impl(
        chk: Checked,
        layer: &Conv2d<'_, i16>,
        src: &View<'_, i16>,
        dst: &mut ViewMut<'_, i16>,
        y0: usize,
        scratch: &mut [f32],
    ) {
        fixed::forward(chk.isa(), layer, src, dst, y0, bytemuck::cast_slice_mut(scratch))
    }
}

/// Scratch words [`conv2d`] needs for a layer of kernel size `k` from `cin`
/// to `cout` channels on rows of `width` pixels (a row accumulator plus the
/// weights widened to f32).
pub fn conv2d_scratch_len<P: ConvPrecision>(k: usize, cin: usize, cout: usize, width: usize) -> usize {
    P::scratch_len_impl(k, cin, cout, width)
}

/// Forward convolution into output rows `y0 .. y0 + dst.height()`.
/// `src`: `layer.cin` planes; `dst`: `layer.cout` planes of `src`'s width, rows `y0 ..`. Scratch:
/// [`conv2d_scratch_len`] f32 words.
///
/// # Errors
/// [`Error::IsaUnsupported`] when this CPU lacks `isa`; the errors of [`Conv2d::check`]; in fixed
/// point, a layer over the bit budget; [`Error::ShapeMismatch`] or [`Error::BadParameter`] when
/// `src` or `dst` do not fit the layer or the rows are not inside the image;
/// [`Error::ScratchTooSmall`] when `scratch` is shorter than [`conv2d_scratch_len`].
pub fn conv2d<P: ConvPrecision>(
    isa: Isa,
    layer: &Conv2d<'_, P::Store>,
    src: &View<'_, P::Store>,
    dst: &mut ViewMut<'_, P::Store>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let chk = Checked::new(isa.check()?);
    layer.check()?;
    P::check_layer(layer)?;
    let s = src.shape();
    if s.channels != layer.cin {
        return Err(Error::ShapeMismatch {
            what: "conv input channels",
            expected: Shape::new(layer.cin, s.width, s.height),
            got: s,
        });
    }
    check_band("conv output", Shape::new(layer.cout, s.width, s.height), dst.shape(), y0)?;
    check_scratch(conv2d_scratch_len::<P>(layer.k, layer.cin, layer.cout, s.width), scratch.len())?;
    if dst.height() == 0 || s.width == 0 {
        return Ok(());
    }
    P::forward_impl(chk, layer, src, dst, y0, scratch);
    Ok(())
}

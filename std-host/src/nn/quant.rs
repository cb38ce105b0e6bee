//! The fixed-point format of a convolution's weights: one rule for every
//! network (the inference engine, AFN's streamed heads, the operator
//! registry's convolutions).
//!
//! A layer's weights share one format. The core's integer convolution sums
//! `w * x` exactly in i32 over an output's taps; with i16 inputs
//! (`|x| <= 32767`) the sum stays below 2^31 for any input when
//! `sum |w| <= 65535` stored units per output channel. So the weights get
//! as many fractional bits as that budget allows for the output channel with
//! the largest `sum |w|`, at most 14 (Q1.14, the format of unit tensors).

/// Fractional bits for weights laid out output-major, `per_output` values
/// per output channel.
pub fn weight_frac(weights: &[f32], per_output: usize) -> i8 {
    let per = per_output.max(1);
    let maxsum = weights.chunks(per).map(|ch| ch.iter().map(|v| v.abs()).sum::<f32>()).fold(0.0, f32::max);
    ((65535.0 / maxsum.max(1e-6)).log2().floor() as i32).clamp(0, 14) as i8
}

//! Portable versions of the functions in [`crate::math`].

use super::*;

/// `e^x`, 0 for `x < EXP_LO` or NaN, clamped at `EXP_HI`.
#[inline]
pub fn exp(x: f32) -> f32 {
    // Written so that NaN fails the comparison.
    if !(x >= EXP_LO) {
        return 0.0;
    }
    let x = if x > EXP_HI { EXP_HI } else { x };
    let n = (x * LOG2E + ROUND_MAGIC) - ROUND_MAGIC;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    let mut p = EXP_C[6];
    p = p * r + EXP_C[5];
    p = p * r + EXP_C[4];
    p = p * r + EXP_C[3];
    p = p * r + EXP_C[2];
    p = p * r + EXP_C[1];
    p = p * r + EXP_C[0];
    let scale = f32::from_bits(((n as i32 + 127) as u32) << 23);
    p * scale
}

/// The scalar `exp` of this module written without branches (selects only), so that loops calling it
/// vectorise; the same value for every input.
#[inline(always)]
pub fn exp_select(x: f32) -> f32 {
    let valid = x >= EXP_LO;
    let xc = if valid { x } else { 0.0 };
    let xc = if xc > EXP_HI { EXP_HI } else { xc };
    let n = (xc * LOG2E + ROUND_MAGIC) - ROUND_MAGIC;
    let r = (xc - n * LN2_HI) - n * LN2_LO;
    let mut p = EXP_C[6];
    p = p * r + EXP_C[5];
    p = p * r + EXP_C[4];
    p = p * r + EXP_C[3];
    p = p * r + EXP_C[2];
    p = p * r + EXP_C[1];
    p = p * r + EXP_C[0];
    // 2^n from the bits of `n + 127` placed in the low mantissa bits by the
    // rounding constant (`n` is an integer in [-126, 127], so `n + 127` is
    // in [1, 254]): no float-to-integer conversion, whose saturating
    // semantics keep a loop from vectorising.
    let scale = f32::from_bits((n + (ROUND_MAGIC + 127.0)).to_bits() << 23);
    if valid {
        p * scale
    } else {
        0.0
    }
}

/// Natural logarithm for `x > 0`. Outside the domain it stays finite:
/// `x <= 0` or NaN gives `f32::MIN`, `+inf` gives `ln(f32::MAX)`.
#[inline]
pub fn log(x: f32) -> f32 {
    if !(x > 0.0) {
        return f32::MIN;
    }
    let x = if x > f32::MAX { f32::MAX } else { x };
    // Subnormals: scale up by 2^25 first.
    let (x, bias) = if x < f32::MIN_POSITIVE { (x * 33_554_432.0, 25) } else { (x, 0) };
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127 - bias;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // [1, 2)
    if m > 2.0 * SQRT_HALF {
        m *= 0.5;
        e += 1;
    }
    let z = (m - 1.0) / (m + 1.0);
    let z2 = z * z;
    let mut s = 1.0 / 9.0;
    s = s * z2 + 1.0 / 7.0;
    s = s * z2 + 1.0 / 5.0;
    s = s * z2 + 1.0 / 3.0;
    s = s * z2 + 1.0;
    (e as f32) * LN2 + 2.0 * z * s
}

/// `x^p` for `x > 0`; 0 for `x <= 0` or NaN.
#[inline]
pub fn pow(x: f32, p: f32) -> f32 {
    if !(x > 0.0) {
        return 0.0;
    }
    exp(p * log(x))
}

/// `ln(1 + x)` accurate near 0, for `x > -1`.
#[inline]
pub fn log1p(x: f32) -> f32 {
    let u = 1.0 + x;
    let d = u - 1.0;
    if d == 0.0 {
        x
    } else {
        log(u) * (x / d)
    }
}

/// `e^x - 1` accurate near 0.
#[inline]
pub fn expm1(x: f32) -> f32 {
    let x = if x > EXP_HI { EXP_HI } else { x };
    let u = exp(x);
    let d = u - 1.0;
    if d == 0.0 {
        x
    } else if d == -1.0 {
        -1.0
    } else {
        d * (x / log(u))
    }
}

//! Fixed-point formats and the integer arithmetic the `Fixed` precision is
//! built from. Integer operations only: these kernels run where there is no FPU.
//!
//! The integer helpers (rounding shifts, division, `exp`/`log2` polynomials)
//! are private to the crate: each is exact only within the ranges its callers
//! guarantee. Public are the formats' constants, [`from_f32`] and [`pow2`],
//! both total.
//!
//! A tensor stores `i16` values meaning `v / 2^frac`, with `frac` carried by
//! its view ([`View::frac`](crate::View::frac)). The range is symmetric,
//! `[-32767, 32767]`: a stored `-32768` reads as `-32767`, so no product or
//! pair sum can overflow `i32`, and results saturate to that range, never wrap.
//!
//! ## Bit budgets
//! - Kernel taps and blend weights (`alpha`): [`KERNEL_FRAC`] = 14, Q1.14, so
//!   weights in `[-2, 2)` and a normalised kernel sums to 16384.
//! - Logits: [`LOGIT_FRAC`] = 8, Q7.8: `[-128, 128)` (rendered WSKP maps span
//!   -61..47), steps of 1/256 nat (0.4% in a weight).
//! - Softmax weights `e^(l - shift)`: Q.16 in `i32`, `(0, 65536]`.
//! - Accumulators: `i32` sums of PMADDWD-style pairs `a0 b0 + a1 b1`
//!   (at most `2 * 32767^2 < 2^31`); where the number of pairs is not bounded
//!   by a per-layer check, each pair is shifted right by [`PAIR_SHIFT`] before
//!   it is added, so 225 taps (a 15x15 kernel) stay below 2^31 whatever the data.

/// Q1.14: kernel taps, blend weights, albedo.
pub const KERNEL_FRAC: i8 = 14;
/// Q7.8: logits.
pub const LOGIT_FRAC: i8 = 8;
/// One in the Q.16 weight format.
pub const WEIGHT_ONE: i32 = 1 << 16;
/// Largest stored value.
pub const QMAX: i32 = 32767;
/// Pair sums are shifted right by this before accumulation (113 pairs of a
/// 15x15 kernel: `113 * 2^31 / 2^7 < 2^31`).
pub const PAIR_SHIFT: i32 = 7;

/// Reads a stored value into the symmetric range.
#[inline(always)]
pub(crate) fn ld(v: i16) -> i32 {
    (v as i32).max(-QMAX)
}

/// Saturates to the stored range.
#[inline(always)]
pub(crate) fn sat16(v: i64) -> i16 {
    v.clamp(-(QMAX as i64), QMAX as i64) as i16
}

/// `v / 2^s` rounded half up for `s > 0`; `v * 2^-s` (saturating at i64) for `s <= 0`.
#[inline(always)]
pub(crate) fn shr_round(v: i64, s: i32) -> i64 {
    if s > 0 {
        if s >= 63 {
            return if v < 0 { -1 } else { 0 };
        }
        (v + (1i64 << (s - 1))) >> s
    } else {
        let s = (-s).min(62);
        v.saturating_mul(1i64 << s)
    }
}

/// `a / b` rounded to nearest (half away from zero); `b > 0`.
#[inline(always)]
pub(crate) fn div_round(a: i64, b: i64) -> i64 {
    if a >= 0 {
        (a + b / 2) / b
    } else {
        -((-a + b / 2) / b)
    }
}

/// `2^(y / 256)` in Q.16 for `y <= 0` given in Q.8 (0 below `2^-17`).
/// Degree-4 polynomial for the fraction (max relative error 1e-5). Written
/// with branches and `i64` products: the reference [`exp_q8`]'s branch-free
/// form is tested against (tests only).
#[cfg(test)]
pub(crate) fn exp2_q8(y: i32) -> i32 {
    if y > 0 {
        return WEIGHT_ONE; // callers only pass y <= 0
    }
    let n = y >> 8; // floor
    let f = y & 255; // 0..255
    if n < -17 {
        return 0;
    }
    let t = f << 8; // Q.16 in [0, 1)
                    // 2^t - 1 = t (c1 + t (c2 + t (c3 + t c4))), coefficients in Q.16.
    const C: [i64; 4] = [45418, 15821, 3413, 884];
    let t64 = t as i64;
    let mut p = C[3];
    p = C[2] + ((p * t64) >> 16);
    p = C[1] + ((p * t64) >> 16);
    p = C[0] + ((p * t64) >> 16);
    let m = (1i64 << 16) + ((p * t64) >> 16); // Q.16 in [1, 2)
    shr_round(m, -n) as i32
}

/// `e^x` in Q.16 for `x <= 0` given in Q.8 (the logit format's unit; `x > 0`
/// gives 1): `exp2_q8` of `x log2(e)` (log2(e) in Q.14 is 23637, the product
/// rounded as `shr_round`), written without branches on the value so that a
/// row of them vectorises. Below -4096 (e^-16) the result is 0, and above
/// that every product fits 32 bits (the polynomial's in `u32`); the same bits
/// as the composition, tested over every input from -80,000 up.
#[inline(always)]
pub(crate) fn exp_q8(x: i32) -> i32 {
    let x = x.clamp(-4096, 0);
    let y = (x * 23637 + (1 << 13)) >> 14;
    let n = y >> 8;
    let t = ((y & 255) << 8) as u32;
    let mut p: u32 = 884;
    p = 3413 + ((p * t) >> 16);
    p = 15821 + ((p * t) >> 16);
    p = 45418 + ((p * t) >> 16);
    let m = (1u32 << 16) + ((p * t) >> 16);
    let s = (-n) as u32; // 0 ..= 24
    let v = (m + ((1u32 << s) >> 1)) >> s;
    if n < -17 {
        0
    } else {
        v as i32
    }
}

/// `num * inv / 2^shift` rounded half away from zero (as [`div_round`]),
/// with `inv = floor(2^shift / den)`: one division per denominator instead
/// of one per numerator. Callers keep `|num| inv` below 2^63.
#[inline(always)]
pub(crate) fn mul_recip(num: i64, inv: i64, shift: u32) -> i64 {
    let q = (num.abs() * inv + (1i64 << (shift - 1))) >> shift;
    if num < 0 {
        -q
    } else {
        q
    }
}

/// `log2(v / 2^frac)` in Q.16 for `v > 0` (`i32::MIN / 2` for `v <= 0`).
/// Degree-5 polynomial for the mantissa (max error 3e-5).
#[inline(always)]
pub(crate) fn log2_q16(v: i64, frac: i32) -> i64 {
    if v <= 0 {
        return (i32::MIN / 2) as i64;
    }
    let lz = v.leading_zeros() as i32; // 64-bit
    let e = 63 - lz; // floor(log2 v)
                     // Mantissa in [1, 2) as Q.16.
    let m = if e >= 16 { v >> (e - 16) } else { v << (16 - e) };
    let u = m - (1 << 16); // [0, 1) in Q.16
    const C: [i64; 5] = [94491, -46444, 27225, -12741, 3007];
    let mut p = C[4];
    for c in C[..4].iter().rev() {
        p = c + ((p * u) >> 16);
    }
    let frac_part = (p * u) >> 16;
    (((e - frac) as i64) << 16) + frac_part
}

/// `2^(y / 2^16)` as a value with `frac` fractional bits, saturating.
#[inline(always)]
pub(crate) fn exp2_q16(y: i64, frac: i32) -> i64 {
    let n = y >> 16; // floor
    let t = y & 0xffff;
    const C: [i64; 4] = [45418, 15821, 3413, 884];
    let mut p = C[3];
    p = C[2] + ((p * t) >> 16);
    p = C[1] + ((p * t) >> 16);
    p = C[0] + ((p * t) >> 16);
    let m = (1i64 << 16) + ((p * t) >> 16); // 2^frac(t) in Q.16
    shr_round(m, 16 - frac - n.clamp(-64, 64) as i32)
}

/// Converts a stored value from `from` to `to` fractional bits (rounded, unsaturated).
#[inline(always)]
pub(crate) fn rescale(v: i64, from: i32, to: i32) -> i64 {
    shr_round(v, from - to)
}

/// The stored value of `x` in format `frac` (rounded, saturated) — for constants.
pub fn from_f32(x: f32, frac: i8) -> i16 {
    let s = x * pow2(frac);
    let r = if s >= 0.0 { s + 0.5 } else { s - 0.5 };
    if r.is_nan() {
        0
    } else if r >= QMAX as f32 {
        QMAX as i16
    } else if r <= -(QMAX as f32) {
        -QMAX as i16
    } else {
        r as i16
    }
}

/// `2^e` exactly: built from its exponent bits inside the normal range (the
/// value `libm::exp2f` gives for an integer, without its cost: this sits on
/// per-block and per-pixel paths), by `exp2f` outside it.
#[inline]
pub fn pow2(e: i8) -> f32 {
    if (-126..=127).contains(&e) {
        f32::from_bits(((e as i32 + 127) as u32) << 23)
    } else {
        libm::exp2f(e as f32)
    }
}

#[cfg(test)]
mod tests {
    /// `pow2` is `exp2f` of an integer, bit for bit, over the whole `i8` range.
    #[test]
    fn pow2_is_exp2f_of_an_integer() {
        for e in i8::MIN..=i8::MAX {
            assert_eq!(super::pow2(e).to_bits(), libm::exp2f(e as f32).to_bits(), "2^{e}");
        }
    }
}

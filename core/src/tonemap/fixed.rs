//! Per-pixel maps in fixed point, integer only: `log2`/`exp2` polynomials
//! ([`crate::fixed`]) for gamma, `log1p` and `expm1`, an integer rational for
//! the filmic curve, integer division for demodulation. Inputs and outputs in
//! their views' formats; results rounded and saturated.

use super::Map;
use crate::fixed::{div_round, exp2_q16, from_f32, ld, log2_q16, rescale, sat16, shr_round};
use crate::view::{View, ViewMut};

/// `ln 2` in Q.16.
const LN2_Q16: i64 = 45426;
/// `log2 e` in Q.14.
const LOG2E_Q14: i64 = 23637;

/// One value: `v` with `fi` fractional bits to the map's result in Q.16 ("real" units).
fn apply(op: Map, v: i64, fi: i32) -> i64 {
    let one = 1i64 << 16;
    let x16 = rescale(v, fi, 16); // the value in Q.16
    match op {
        Map::Sanitize { limit } => {
            let l = (limit.clamp(0.0, 1e9) as f64 * 65536.0) as i64;
            x16.clamp(-l, l)
        }
        Map::Gamma { gamma, clamp } => {
            let x = if clamp { x16.clamp(0, one) } else { x16.max(0) };
            if x == 0 {
                return 0;
            }
            let p = (65536.0 / gamma.max(1e-6)) as i64; // 1/gamma in Q.16
            let l = log2_q16(x, 16);
            exp2_q16((l * p) >> 16, 16)
        }
        Map::Filmic => {
            let x = x16.clamp(0, 1024 * one);
            let (a, b, c, d, e) = (164_495i64, 1966, 159_252, 38_666, 9175); // 2.51 .03 2.43 .59 .14 in Q.16
            let num = (x * (((a * x) >> 16) + b)) >> 16;
            let den = ((x * (((c * x) >> 16) + d)) >> 16) + e;
            div_round(num << 16, den).clamp(0, one)
        }
        Map::Log1p => {
            let x = x16.max(0);
            (log2_q16(x + one, 16) * LN2_Q16) >> 16
        }
        Map::Expm1 => {
            let x = x16.clamp(-20 * one, 20 * one);
            let y = (x * LOG2E_Q14) >> 14;
            exp2_q16(y, 16) - one
        }
    }
}

pub(crate) fn map(op: Map, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>) {
    let (fi, fo) = (src.frac() as i32, dst.frac() as i32);
    for c in 0..src.channels() {
        for y in 0..src.height() {
            for x in 0..src.width() {
                let r = apply(op, ld(src.at(c, y, x)) as i64, fi);
                dst.row_mut(c, y)[x] = sat16(rescale(r, 16, fo));
            }
        }
    }
}

pub(crate) fn modulate(
    divide: bool,
    src: &View<'_, i16>,
    albedo: &View<'_, i16>,
    eps: f32,
    dst: &mut ViewMut<'_, i16>,
) {
    let (fi, fa, fo) = (src.frac() as i32, albedo.frac() as i32, dst.frac() as i32);
    let eps_q = from_f32(eps, albedo.frac()).max(1) as i64;
    for c in 0..src.channels() {
        for y in 0..src.height() {
            for x in 0..src.width() {
                let v = ld(src.at(c, y, x)) as i64;
                let d = ld(albedo.at(c, y, x)) as i64 + eps_q;
                let out = if divide {
                    if d <= 0 {
                        if v == 0 {
                            0
                        } else {
                            v.signum() * i64::MAX / 4
                        }
                    } else {
                        div_round(shr_round(v, fi - fo - fa), d)
                    }
                } else {
                    shr_round(v * d, fi + fa - fo)
                };
                dst.row_mut(c, y)[x] = sat16(out);
            }
        }
    }
}

//! Unfold in fixed point: i16 kernel taps (any format, usually Q1.14) and
//! i16 radiance, PMADDWD-style pair sums in i32, each pair shifted right by
//! [`PAIR_SHIFT`](crate::fixed::PAIR_SHIFT) before accumulation (no overflow
//! for any data), then rounded to the output's format and saturated.
//! Taps pair up in order `(0, 1), (2, 3), ...`; an odd last tap pairs with 0.

use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;

pub(crate) fn run(
    isa: crate::isa::Supported,
    k: usize,
    kernel: &View<'_, i16>,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 | Isa::Avx512 => unsafe { avx2::run(k, kernel, src, dst, y0) },
        _ => scalar::run(k, kernel, src, dst, y0),
    }
}

/// The final right shift: product format minus output format minus the pair shift.
pub(crate) fn out_shift(kernel: &View<'_, i16>, src: &View<'_, i16>, dst: &ViewMut<'_, i16>) -> i32 {
    kernel.frac() as i32 + src.frac() as i32 - dst.frac() as i32 - crate::fixed::PAIR_SHIFT
}

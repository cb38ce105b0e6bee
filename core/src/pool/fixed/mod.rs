//! Pool operators in fixed point. Means round half up (`(sum + n/2) >> log2
//! n`); every result is rescaled to the output's format, rounded, and
//! saturated. Integer operations only; one body per instruction set, whose
//! row loops (with the format shifts hoisted out, [`Sh`]) vectorise, so
//! every ISA gives the same bits. Cells cut by the image's edge, and formats
//! that shift further than [`Sh`] takes, run the pixel code.

use super::Reduce;
use crate::fixed::{ld, rescale, sat16, shr_round};
use crate::view::{View, ViewMut};

/// The 2x2 cell `xc` between rows `r0` and optional `r1`, in the input's format.
fn cell(op: Reduce, r0: &[i16], r1: Option<&[i16]>, xc: usize, w: usize) -> i64 {
    let x0 = 2 * xc;
    let xs = if x0 + 1 < w { 2 } else { 1 };
    let mut vals = [0i32; 4];
    let mut n = 0;
    for row in [Some(r0), r1].into_iter().flatten() {
        for x in x0..x0 + xs {
            vals[n] = ld(row[x]);
            n += 1;
        }
    }
    match op {
        Reduce::Max => vals[..n].iter().copied().max().unwrap_or(0) as i64,
        Reduce::Mean => {
            let sum: i64 = vals[..n].iter().map(|&v| v as i64).sum();
            shr_round(sum, n.trailing_zeros() as i32)
        }
    }
}

/// `shr_round(v, s)` for a shift fixed over a loop, branch-free: `((v <<
/// left) + half) >> right`, for `-20 <= s < 63` (values below 2^42 do not
/// overflow the left shift, where `shr_round` would saturate).
#[derive(Clone, Copy)]
struct Sh {
    left: u32,
    half: i64,
    right: u32,
}

impl Sh {
    /// No shift.
    const ZERO: Sh = Sh { left: 0, half: 0, right: 0 };

    fn new(s: i32) -> Option<Sh> {
        if s > 0 && s < 63 {
            Some(Sh { left: 0, half: 1i64 << (s - 1), right: s as u32 })
        } else if (-20..=0).contains(&s) {
            Some(Sh { left: (-s) as u32, half: 0, right: 0 })
        } else {
            None
        }
    }
    #[inline(always)]
    fn apply(self, v: i64) -> i64 {
        ((v << self.left) + self.half) >> self.right
    }
}

#[inline(always)]
fn sat(v: i64) -> i16 {
    v.clamp(-(crate::fixed::QMAX as i64), crate::fixed::QMAX as i64) as i16
}

macro_rules! dispatch {
    ($isa:expr, $body:ident ( $($arg:expr),* )) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2,fma")]
            unsafe fn on_avx2(f: impl FnOnce()) {
                f()
            }
            #[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma")]
            unsafe fn on_avx512(f: impl FnOnce()) {
                f()
            }
            match $isa.isa() {
                // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
                crate::Isa::Avx512 => return unsafe { on_avx512(|| $body($($arg),*)) },
                // SAFETY: as above.
                crate::Isa::Avx2 => return unsafe { on_avx2(|| $body($($arg),*)) },
                crate::Isa::Scalar => {}
            }
        }
        let _ = $isa;
        $body($($arg),*)
    }};
}

pub(crate) fn reduce(
    isa: crate::isa::Supported,
    op: Reduce,
    src: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    dispatch!(isa, reduce_body(op, src, dst, y0))
}

#[inline(always)]
fn reduce_body(op: Reduce, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (w, h) = (src.width(), src.height());
    let (fi, fo) = (src.frac() as i32, dst.frac() as i32);
    // Whole cells (both rows, columns 2 xc and 2 xc + 1) in a loop that
    // vectorises when the format shift fits `Sh`; cells cut by the edge, or
    // every cell otherwise, by the pixel code.
    let sh = Sh::new(fi - fo);
    let whole = if sh.is_some() { w / 2 } else { 0 };
    let sh = sh.unwrap_or(Sh::ZERO);
    for yo in 0..dst.height() {
        let yc = y0 + yo;
        for c in 0..src.channels() {
            let r0 = src.row(c, 2 * yc);
            let r1 = (2 * yc + 1 < h).then(|| src.row(c, 2 * yc + 1));
            let out = dst.row_mut(c, yo);
            let from = match r1 {
                Some(r1) => {
                    let (a, b) = (&r0[..2 * whole], &r1[..2 * whole]);
                    for (xc, o) in out[..whole].iter_mut().enumerate() {
                        let v = [ld(a[2 * xc]), ld(a[2 * xc + 1]), ld(b[2 * xc]), ld(b[2 * xc + 1])];
                        let m = match op {
                            Reduce::Max => v[0].max(v[1]).max(v[2]).max(v[3]) as i64,
                            Reduce::Mean => (v[0] as i64 + v[1] as i64 + v[2] as i64 + v[3] as i64 + 2) >> 2,
                        };
                        *o = sat(sh.apply(m));
                    }
                    whole
                }
                None => 0,
            };
            for xc in from..out.len() {
                out[xc] = sat16(rescale(cell(op, r0, r1, xc, w), fi, fo));
            }
        }
    }
}

pub(crate) fn upsample(isa: crate::isa::Supported, src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    dispatch!(isa, upsample_body(src, dst, y0))
}

#[inline(always)]
fn upsample_body(src: &View<'_, i16>, dst: &mut ViewMut<'_, i16>, y0: usize) {
    let (fi, fo) = (src.frac() as i32, dst.frac() as i32);
    if let Some(sh) = Sh::new(fi - fo) {
        for yo in 0..dst.height() {
            let y = y0 + yo;
            for c in 0..src.channels() {
                let s = src.row(c, y / 2);
                let out = dst.row_mut(c, yo);
                let pairs = out.len() / 2;
                for (o, &v) in out.chunks_exact_mut(2).zip(&s[..pairs]) {
                    let v = sat(sh.apply(ld(v) as i64));
                    o[0] = v;
                    o[1] = v;
                }
                if out.len() % 2 == 1 {
                    let x = out.len() - 1;
                    out[x] = sat(sh.apply(ld(s[x / 2]) as i64));
                }
            }
        }
        return;
    }
    for yo in 0..dst.height() {
        let y = y0 + yo;
        for c in 0..src.channels() {
            let s = src.row(c, y / 2);
            for x in 0..dst.width() {
                dst.row_mut(c, yo)[x] = sat16(rescale(ld(s[x / 2]) as i64, fi, fo));
            }
        }
    }
}

pub(crate) fn composite(
    isa: crate::isa::Supported,
    fine: &View<'_, i16>,
    coarse: &View<'_, i16>,
    alpha: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    dispatch!(isa, composite_body(fine, coarse, alpha, dst, y0))
}

/// Pixels per chunk of the vectorised composite.
const CHUNK: usize = 64;

#[inline(always)]
fn composite_body(
    fine: &View<'_, i16>,
    coarse: &View<'_, i16>,
    alpha: &View<'_, i16>,
    dst: &mut ViewMut<'_, i16>,
    y0: usize,
) {
    let (w, h) = (fine.width(), fine.height());
    let (ff, fc, fa, fo) = (fine.frac() as i32, coarse.frac() as i32, alpha.frac() as i32, dst.frac() as i32);
    let per_channel_alpha = alpha.channels() > 1;
    // Whole cells (columns below 2 (w / 2)) in chunks when every format shift
    // fits `Sh`; the odd last column, or every column otherwise, by the pixel code.
    let shifts = match (Sh::new(fc - ff), Sh::new(fa), Sh::new(ff - fo)) {
        (Some(c), Some(a), Some(o)) => Some((c, a, o)),
        _ => None,
    };
    let whole = if shifts.is_some() { 2 * (w / 2) } else { 0 };
    let (s_c, s_a, s_o) = shifts.unwrap_or((Sh::ZERO, Sh::ZERO, Sh::ZERO));
    let mut d = [0i64; CHUNK / 2];
    for yo in 0..dst.height() {
        let y = y0 + yo;
        let yc = y / 2;
        for c in 0..fine.channels() {
            let r0 = fine.row(c, 2 * yc);
            let r1 = (2 * yc + 1 < h).then(|| fine.row(c, 2 * yc + 1));
            let f = fine.row(c, y);
            let crow = coarse.row(c, yc);
            let a = alpha.row(if per_channel_alpha { c } else { 0 }, y);
            let out = dst.row_mut(c, yo);
            let mut x0 = 0;
            while x0 < whole {
                let cw = CHUNK.min(whole - x0);
                let (xc0, nc) = (x0 / 2, cw / 2);
                // The coarse value (in the fine format) minus the cell's mean.
                match r1 {
                    Some(r1) => {
                        for (i, dv) in d[..nc].iter_mut().enumerate() {
                            let x = 2 * (xc0 + i);
                            let sum = ld(r0[x]) as i64 + ld(r0[x + 1]) as i64 + ld(r1[x]) as i64 + ld(r1[x + 1]) as i64;
                            *dv = s_c.apply(ld(crow[xc0 + i]) as i64) - ((sum + 2) >> 2);
                        }
                    }
                    None => {
                        for (i, dv) in d[..nc].iter_mut().enumerate() {
                            let x = 2 * (xc0 + i);
                            let sum = ld(r0[x]) as i64 + ld(r0[x + 1]) as i64;
                            *dv = s_c.apply(ld(crow[xc0 + i]) as i64) - ((sum + 1) >> 1);
                        }
                    }
                }
                for (i, o) in out[x0..x0 + cw].iter_mut().enumerate() {
                    let x = x0 + i;
                    let v = ld(f[x]) as i64 + s_a.apply(ld(a[x]) as i64 * d[i / 2]);
                    *o = sat(s_o.apply(v));
                }
                x0 += cw;
            }
            for x in whole..w {
                let d = rescale(ld(crow[x / 2]) as i64, fc, ff) - cell(Reduce::Mean, r0, r1, x / 2, w);
                let o = ld(f[x]) as i64 + shr_round(ld(a[x]) as i64 * d, fa);
                out[x] = sat16(rescale(o, ff, fo));
            }
        }
    }
}

//! Portable row loops and per-pixel paths of the softmax operators, generic
//! over the arithmetic `A` (f32, or f16-rounded for the f16-arithmetic
//! precision).

use core::marker::PhantomData;

use super::{alpha_pixel, direct_pixel, Ops, SepOps, SEP_LS, SEP_SS};
use crate::precision::FloatElement;
use crate::real::Real;
use crate::softmax::{clamp_logit, FusedInputs, MAX_CHANNELS, MAX_FUSED};
use crate::view::{View, ViewMut};

/// The scalar [`Ops`] in arithmetic `A`.
pub(crate) struct ScalarOps<A>(PhantomData<A>);

impl<A> ScalarOps<A> {
    pub(crate) fn new() -> Self {
        ScalarOps(PhantomData)
    }
}

/// The power-of-two levels of one plane `v`: `s2[i] = v[i] + v[i + 1]`,
/// `s4[i] = s2[i] + s2[i + 2]`, `s8[i] = s4[i] + s4[i + 4]`, each over every
/// index it is defined at (only the levels `k` needs).
pub(crate) fn box_levels<A: Real>(v: &[A], k: usize, lv: &mut [A]) {
    let len = v.len();
    let (s2, rest) = lv.split_at_mut(len);
    let (s4, s8) = rest.split_at_mut(len);
    if k >= 2 {
        for x in 0..len - 1 {
            s2[x] = v[x] + v[x + 1];
        }
    }
    if k >= 4 {
        for x in 0..len - 3 {
            s4[x] = s2[x] + s2[x + 2];
        }
    }
    if k >= 8 {
        for x in 0..len - 7 {
            s8[x] = s4[x] + s4[x + 4];
        }
    }
}

/// The window sum `sum_{t < k} v[x + t]` from the levels: the pieces of `k`'s
/// binary expansion from the largest down, left to right
/// (`k = 13`: `(s8[x] + s4[x + 8]) + v[x + 12]`).
#[inline(always)]
pub(crate) fn box_at<A: Real>(v: &[A], lv: &[A], k: usize, x: usize) -> A {
    let len = v.len();
    let mut acc = None::<A>;
    let mut off = 0;
    for (bit, base) in [(8usize, 2 * len), (4, len), (2, 0)] {
        if k & bit != 0 {
            let t = lv[base + x + off];
            acc = Some(acc.map_or(t, |a| a + t));
            off += bit;
        }
    }
    let t = v[x + off]; // k is odd: the last piece is a single value
    acc.map_or(t, |a| a + t)
}

/// Carried column `u`'s weight `e = exp(clamp(l) - shift)` and `e * r_c`
/// (all 0 outside `u0 .. u1` or without logits).
fn weights_at<S: FloatElement, A: Real>(
    l: Option<&[S]>,
    rad: &[&[S]],
    shift: A,
    u0: usize,
    u1: usize,
    u: usize,
) -> [A; 1 + MAX_CHANNELS] {
    let mut vals = [A::ZERO; 1 + MAX_CHANNELS];
    if let Some(l) = l.filter(|_| u >= u0 && u < u1) {
        let e = (A::of(clamp_logit(l[u - u0].to_f32())) - shift).exp();
        vals[0] = e;
        for (c, r) in rad.iter().enumerate() {
            vals[1 + c] = e * A::of(r[u - u0].to_f32());
        }
    }
    vals
}

impl<A: Real> Ops<A> for ScalarOps<A> {
    fn row_max<S: FloatElement>(&self, row: &[S]) -> f32 {
        row.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v.to_f32()))
    }

    fn forward_row<S: FloatElement>(
        &self,
        l: Option<&[S]>,
        rad: &[&[S]],
        shift: A,
        u0: usize,
        u1: usize,
        a: &mut [A],
        p_prev: Option<&[A]>,
        p: &mut [A],
    ) {
        let np = 1 + rad.len();
        let len = a.len() / np;
        for u in 0..len {
            let vals = weights_at(l, rad, shift, u0, u1, u);
            for q in 0..np {
                let i = q * len + u;
                a[i] = vals[q];
                p[i] = match p_prev {
                    Some(pp) => vals[q] + pp[i],
                    None => vals[q],
                };
            }
        }
    }

    fn backward_row(&self, a: &mut [A], a_next: Option<&[A]>, p_win: Option<&[A]>, mut v: Option<&mut [A]>) {
        for i in 0..a.len() {
            let s = match a_next {
                Some(n) => a[i] + n[i],
                None => a[i],
            };
            a[i] = s;
            if let Some(v) = v.as_deref_mut() {
                v[i] = match p_win {
                    Some(p) => s + p[i],
                    None => s,
                };
            }
        }
    }

    fn horizontal_accumulate(
        &self,
        v: &[A],
        np: usize,
        k: usize,
        alpha: &[A],
        acc: &mut [A],
        acc_plane: usize,
        den: &mut [A],
        lv: &mut [A],
    ) -> bool {
        let len = v.len() / np;
        let tw = alpha.len();
        for q in 0..np {
            box_levels(&v[q * len..(q + 1) * len], k, &mut lv[3 * q * len..3 * (q + 1) * len]);
        }
        let mut any_tiny = false;
        for x in 0..tw {
            let d = box_at(&v[..len], &lv[..3 * len], k, x);
            den[x] = d;
            if d >= A::TINY {
                let inv = alpha[x] / d;
                for q in 1..np {
                    let num = box_at(&v[q * len..(q + 1) * len], &lv[3 * q * len..3 * (q + 1) * len], k, x);
                    acc[(q - 1) * acc_plane + x] += num * inv;
                }
            } else {
                any_tiny = true;
            }
        }
        any_tiny
    }

    fn alphas<S: FloatElement>(&self, f: &View<'_, S>, y: usize, x0: usize, n: usize, out: &mut [A], stride: usize) {
        let m = f.channels();
        let mut a = [A::ZERO; MAX_FUSED];
        for x in 0..n {
            alpha_pixel(f, y, x0 + x, &mut a);
            for i in 0..m {
                out[i * stride + x] = a[i];
            }
        }
    }

    fn finish<S: FloatElement>(&self, acc: &[A], albedo: Option<&[S]>, out: &mut [S]) {
        match albedo {
            Some(al) => {
                for ((o, &a), &b) in out.iter_mut().zip(acc).zip(al) {
                    *o = S::from_f32((a * A::of(b.to_f32())).f32());
                }
            }
            None => {
                for (o, &a) in out.iter_mut().zip(acc) {
                    *o = S::from_f32(a.f32());
                }
            }
        }
    }
}

impl<A: Real> SepOps<A> for ScalarOps<A> {
    fn weights_row<S: FloatElement>(&self, l: Option<&[S]>, rad: &[&[S]], shift: A, u0: usize, u1: usize, w: &mut [A]) {
        let np = 1 + rad.len();
        for u in 0..SEP_LS {
            let vals = weights_at(l, rad, shift, u0, u1, u);
            for q in 0..np {
                w[q * SEP_LS + u] = vals[q];
            }
        }
    }

    fn vertical_sum(&self, ring: &[A], k: usize, v: &mut [A]) {
        for (i, o) in v.iter_mut().enumerate() {
            let mut s = ring[i];
            for slot in 1..k {
                s += ring[slot * SEP_SS + i];
            }
            *o = s;
        }
    }

    fn horizontal_direct(
        &self,
        v: &[A],
        np: usize,
        k: usize,
        alpha: &[A],
        acc: &mut [A],
        acc_plane: usize,
        den: &mut [A],
    ) -> bool {
        let window = |q: usize, x: usize| {
            let row = &v[q * SEP_LS + x..q * SEP_LS + x + k];
            row[1..].iter().fold(row[0], |s, &t| s + t)
        };
        let mut any_tiny = false;
        for x in 0..alpha.len() {
            let d = window(0, x);
            den[x] = d;
            if d >= A::TINY {
                let inv = alpha[x] / d;
                for q in 1..np {
                    acc[(q - 1) * acc_plane + x] += window(q, x) * inv;
                }
            } else {
                any_tiny = true;
            }
        }
        any_tiny
    }
}

/// The fused filter at one pixel with window-local shifts.
pub(crate) fn fused_pixel<S: FloatElement, A: Real>(inp: &FusedInputs<'_, S>, y: usize, x: usize) -> [A; MAX_CHANNELS] {
    let ch = inp.radiance.channels();
    let mut alpha = [A::ONE; MAX_FUSED];
    if let Some(f) = &inp.fusion {
        alpha_pixel(f, y, x, &mut alpha);
    }
    let mut acc = [A::ZERO; MAX_CHANNELS];
    for (i, &k) in inp.sizes.iter().enumerate() {
        let mut rr = [A::ZERO; MAX_CHANNELS];
        direct_pixel(k, &inp.importance, i, &inp.radiance, y, x, &mut rr);
        for c in 0..ch {
            acc[c] += rr[c] * alpha[i];
        }
    }
    if let Some(al) = &inp.albedo {
        for (c, a) in acc.iter_mut().enumerate().take(ch) {
            *a *= A::of(al.at(c, y, x).to_f32());
        }
    }
    acc
}

/// The direct path over a band of output rows.
pub(crate) fn direct<S: FloatElement, A: Real>(inp: &FusedInputs<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let ch = inp.radiance.channels();
    for yo in 0..dst.height() {
        for x in 0..dst.width() {
            let v = fused_pixel::<S, A>(inp, y0 + yo, x);
            for (c, &vc) in v.iter().enumerate().take(ch) {
                dst.row_mut(c, yo)[x] = S::from_f32(vc.f32());
            }
        }
    }
}

/// The weights of the window of size `k` around `(y, x)`, tap `j` into `w[j]`
/// (0 for out-of-image taps).
pub(crate) fn kernel_pixel<S: FloatElement, A: Real>(k: usize, logits: &View<'_, S>, y: usize, x: usize, w: &mut [A]) {
    let (wd, h) = (logits.width(), logits.height());
    let r = k / 2;
    let inside = |yy: usize, xx: usize| {
        let sy = (y + yy).checked_sub(r).filter(|&v| v < h);
        let sx = (x + xx).checked_sub(r).filter(|&v| v < wd);
        sy.zip(sx)
    };
    let mut m = f32::NEG_INFINITY;
    for ky in 0..k {
        for kx in 0..k {
            if let Some((sy, sx)) = inside(ky, kx) {
                m = m.max(clamp_logit(logits.at(0, sy, sx).to_f32()));
            }
        }
    }
    let m = A::of(m);
    let mut den = A::ZERO;
    for ky in 0..k {
        for kx in 0..k {
            let e = match inside(ky, kx) {
                Some((sy, sx)) => (A::of(clamp_logit(logits.at(0, sy, sx).to_f32())) - m).exp(),
                None => A::ZERO,
            };
            w[ky * k + kx] = e;
            den += e;
        }
    }
    let inv = A::ONE / den;
    for v in w[..k * k].iter_mut() {
        *v *= inv;
    }
}

/// Materialised kernels, pixel by pixel.
pub(crate) fn kernels<S: FloatElement, A: Real>(k: usize, logits: &View<'_, S>, dst: &mut ViewMut<'_, S>, y0: usize) {
    let mut w = [A::ZERO; 15 * 15];
    for yo in 0..dst.height() {
        for x in 0..dst.width() {
            kernel_pixel(k, logits, y0 + yo, x, &mut w);
            for (j, &v) in w[..k * k].iter().enumerate() {
                dst.row_mut(j, yo)[x] = S::from_f32(v.f32());
            }
        }
    }
}

/// Channel softmax at pixel `(y, x)`: max pass, exp-and-sum pass, scale pass.
pub(crate) fn channel_at<S: FloatElement, A: Real>(src: &View<'_, S>, dst: &mut ViewMut<'_, S>, y: usize, x: usize) {
    let n = src.channels();
    let mut m = f32::NEG_INFINITY;
    for c in 0..n {
        m = m.max(clamp_logit(src.at(c, y, x).to_f32()));
    }
    let m = A::of(m);
    let mut sum = A::ZERO;
    for c in 0..n {
        sum += (A::of(clamp_logit(src.at(c, y, x).to_f32())) - m).exp();
    }
    let inv = A::ONE / sum;
    for c in 0..n {
        let e = (A::of(clamp_logit(src.at(c, y, x).to_f32())) - m).exp();
        dst.row_mut(c, y)[x] = S::from_f32((e * inv).f32());
    }
}

/// Channel softmax, pixel by pixel (any channel count).
pub(crate) fn channel<S: FloatElement, A: Real>(src: &View<'_, S>, dst: &mut ViewMut<'_, S>) {
    for y in 0..src.height() {
        for x in 0..src.width() {
            channel_at::<S, A>(src, dst, y, x);
        }
    }
}

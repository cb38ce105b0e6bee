//! SURE shrinkage of one level's detail, in one streaming pass per band:
//! per-pixel terms, their 5x5 window sums (a ring of horizontally summed
//! rows), the risk-minimising weight and the update of the reconstruction.
//!
//! The same source is compiled three times: portable, and inside AVX2 and
//! AVX-512 `target_feature` functions where the compiler vectorises the row
//! loops. Rust never contracts `a * b + c` into an FMA, so the three give
//! bit-identical results.

use super::{check_candidates, SureSource, SURE_RADIUS};
use crate::error::{check_shape, Result, Shape};
use crate::precision::FloatElement;
use crate::unfold::check_band;
use crate::view::{View, ViewMut};
use crate::Isa;

/// Rows of the window.
const WIN: usize = 2 * SURE_RADIUS + 1;
// The one-pass window sums below name the five rows.
const _: () = assert!(WIN == 5);

/// Scratch words [`sure_shrink`] needs for images `width` wide.
pub fn sure_scratch_len(width: usize) -> usize {
    (2 * WIN + 5).saturating_mul(width)
}

/// Adds `beta(p) * D(p)` of one level to the reconstruction rows `y0 ..`.
///
/// `D = c_i - c_{i+1}` is the detail of the first image; `beta` minimises
/// the SURE `(1 - b)^2 E + (2 b - 1) S` among `candidates` (the first on
/// ties), with `E` and `S` the sums over the 5x5 window (clipped at the
/// borders) of the detail energy `e = sum_c D_c^2` and its noise variance
/// `s`. The noise comes from `source`:
/// - [`SureSource::Pair`]: `cur = [M, H]`, `next = [M', H']` (6 planes each),
///   `s = sum_c (H_c - H'_c)^2`;
/// - [`SureSource::Single`]: `cur = [c, v]` (4 planes), `next = [c', v', w]`
///   (5 planes: the step's output with variance), `s = 3 (v (1 - 2 w) + v')`,
///   clamped at 0.
///
/// `recon` holds 3 planes (f32) of the band's rows; `scratch` at least
/// [`sure_scratch_len`] words.
///
/// # Errors
/// An instruction set this CPU lacks; candidates empty or outside [0, 1];
/// `cur` and `next` of other sizes or plane counts than `source` needs;
/// `recon` not a 3-plane band starting at `y0`; `scratch` too short.
#[allow(clippy::too_many_arguments)]
pub fn sure_shrink<S: FloatElement>(
    isa: Isa,
    source: SureSource,
    candidates: &[f32],
    cur: &View<'_, S>,
    next: &View<'_, S>,
    recon: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let isa = isa.check()?;
    check_candidates(candidates)?;
    let s = cur.shape();
    let (nc, nn) = match source {
        SureSource::Pair => (6, 6),
        SureSource::Single => (4, 5),
    };
    let plane = |c| Shape::new(c, s.width, s.height);
    check_shape("SURE level input", plane(nc), s)?;
    check_shape("SURE level output", plane(nn), next.shape())?;
    check_band("SURE reconstruction", plane(3), recon.shape(), y0)?;
    let need = sure_scratch_len(s.width);
    if scratch.len() < need {
        return Err(crate::Error::ScratchTooSmall { needed: need, got: scratch.len() });
    }
    if recon.height() == 0 || s.width == 0 {
        return Ok(());
    }
    dispatch(isa, Job { source, candidates, images: &[*cur, *next], into: Sink::Add }, recon, y0, &mut scratch[..need]);
    Ok(())
}

/// Most levels [`sure_shrink_levels`] takes in one call.
pub const MAX_SURE_LEVELS: usize = 8;

/// Scratch words [`sure_shrink_levels`] needs for `levels` levels (level
/// images minus one) on images `width` wide: per level a ring of window
/// rows, plus the row buffers.
pub fn sure_levels_scratch_len(levels: usize, width: usize) -> usize {
    levels.saturating_mul(2 * WIN).saturating_add(8).saturating_mul(width)
}

/// Every level's SURE shrinkage and the reconstruction in one streaming
/// pass: rows `y0 ..` of `out` (3 planes) get `c_N + sum_i beta_i D_i`,
/// `D_i` the detail between `images[i]` and `images[i + 1]`, `c_N` the
/// first three planes of the last image.
///
/// The same values, bit for bit, as [`sure_shrink`] called for each level
/// in turn into a zeroed reconstruction, then `c_N` plus it; but each level
/// image is read once instead of twice and the reconstruction is never
/// stored, so it moves less than half the bytes. `images[0]` is the first
/// level's input (at least 6 planes for [`SureSource::Pair`], 4 for
/// [`SureSource::Single`]; planes past those are ignored) and every later
/// one a level's output (6 or 5 planes), 2 to `MAX_SURE_LEVELS + 1` of them.
/// `scratch` holds at least [`sure_levels_scratch_len`] words.
///
/// # Errors
/// An instruction set this CPU lacks; candidates empty or outside [0, 1];
/// fewer than 2 or more than `MAX_SURE_LEVELS + 1` images, or images of
/// other sizes or too few planes; `out` not a 3-plane band starting at
/// `y0`; `scratch` too short.
pub fn sure_shrink_levels<S: FloatElement>(
    isa: Isa,
    source: SureSource,
    candidates: &[f32],
    images: &[View<'_, S>],
    out: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) -> Result<()> {
    let isa = isa.check()?;
    check_candidates(candidates)?;
    if images.len() < 2 || images.len() > MAX_SURE_LEVELS + 1 {
        return Err(crate::Error::BadParameter {
            what: "SURE level images",
            expected: "2 to MAX_SURE_LEVELS + 1 of them (the first level's input and each output)",
        });
    }
    let s = images[0].shape();
    let (nc, nn) = match source {
        SureSource::Pair => (6, 6),
        SureSource::Single => (4, 5),
    };
    let plane = |c| Shape::new(c, s.width, s.height);
    if s.channels < nc {
        check_shape("SURE level input", plane(nc), s)?;
    }
    for im in &images[1..] {
        check_shape("SURE level output", plane(nn), im.shape())?;
    }
    check_band("SURE reconstruction", plane(3), out.shape(), y0)?;
    let levels = images.len() - 1;
    let need = sure_levels_scratch_len(levels, s.width);
    if scratch.len() < need {
        return Err(crate::Error::ScratchTooSmall { needed: need, got: scratch.len() });
    }
    if out.height() == 0 || s.width == 0 {
        return Ok(());
    }
    dispatch(isa, Job { source, candidates, images, into: Sink::Reconstruct }, out, y0, &mut scratch[..need]);
    Ok(())
}

/// Where the shrunk detail goes.
#[derive(Clone, Copy, PartialEq)]
enum Sink {
    /// Added to the output rows as they are (one level: [`sure_shrink`]).
    Add,
    /// The output gets `c_N` plus every level's (the sum of those kept in
    /// a row accumulator first, in level order).
    Reconstruct,
}

/// What a shrinkage pass runs on, past its checks.
#[derive(Clone, Copy)]
struct Job<'j, 'a, S> {
    source: SureSource,
    candidates: &'j [f32],
    /// Level images: the first level's input, then each level's output.
    images: &'j [View<'a, S>],
    into: Sink,
}

/// Runs `job` with the instruction set's code (checked by the caller).
fn dispatch<S: FloatElement>(
    isa: crate::isa::Supported,
    job: Job<'_, '_, S>,
    out: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 => unsafe { run_avx2(job, out, y0, scratch) },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx512 => unsafe { run_avx512(job, out, y0, scratch) },
        _ => run::<S, false>(job, out, y0, scratch),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn run_avx2<S: FloatElement>(job: Job<'_, '_, S>, out: &mut ViewMut<'_, f32>, y0: usize, scratch: &mut [f32]) {
    run::<S, true>(job, out, y0, scratch)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,fma,f16c")]
unsafe fn run_avx512<S: FloatElement>(job: Job<'_, '_, S>, out: &mut ViewMut<'_, f32>, y0: usize, scratch: &mut [f32]) {
    run::<S, true>(job, out, y0, scratch)
}

/// Per-pixel terms of row `y`: detail energy into `e`, noise into `s`.
#[inline(always)]
fn terms<S: FloatElement>(
    source: SureSource,
    cur: &View<'_, S>,
    next: &View<'_, S>,
    y: usize,
    e: &mut [f32],
    s: &mut [f32],
) {
    let w = e.len();
    // One pass per sum, the channels added in order from 0.0 (as `+=` into
    // a zeroed row would).
    let sq = |c: usize| {
        let (a, b) = (&cur.row(c, y)[..w], &next.row(c, y)[..w]);
        move |x: usize| {
            let d = a[x].to_f32() - b[x].to_f32();
            d * d
        }
    };
    let (d0, d1, d2) = (sq(0), sq(1), sq(2));
    for x in 0..w {
        e[x] = ((0.0 + d0(x)) + d1(x)) + d2(x);
    }
    match source {
        SureSource::Pair => {
            let (d3, d4, d5) = (sq(3), sq(4), sq(5));
            for x in 0..w {
                s[x] = ((0.0 + d3(x)) + d4(x)) + d5(x);
            }
        }
        SureSource::Single => {
            let (v, v1, wc) = (&cur.row(3, y)[..w], &next.row(3, y)[..w], &next.row(4, y)[..w]);
            for x in 0..w {
                let var = v[x].to_f32() * (1.0 - 2.0 * wc[x].to_f32()) + v1[x].to_f32();
                s[x] = 3.0 * if var > 0.0 { var } else { 0.0 };
            }
        }
    }
}

/// `out[x] = sum of t[x - 2 ..= x + 2]` inside the row, left to right.
#[inline(always)]
fn hsum(t: &[f32], out: &mut [f32]) {
    let w = t.len();
    let r = SURE_RADIUS;
    let clipped = |x: usize| {
        let mut a = 0.0;
        for &v in &t[x.saturating_sub(r)..(x + r + 1).min(w)] {
            a += v;
        }
        a
    };
    if w <= 2 * r {
        for (x, o) in out.iter_mut().enumerate().take(w) {
            *o = clipped(x);
        }
        return;
    }
    for x in (0..r).chain(w - r..w) {
        out[x] = clipped(x);
    }
    // The interior, where all five are inside: the same order, vectorisable.
    let n = w - 2 * r;
    let (o, t0, t1, t2, t3, t4) = (&mut out[r..r + n], &t[..n], &t[1..1 + n], &t[2..2 + n], &t[3..3 + n], &t[4..4 + n]);
    for x in 0..n {
        o[x] = ((((0.0 + t0[x]) + t1[x]) + t2[x]) + t3[x]) + t4[x];
    }
}

/// The window rows of one level: the horizontal sums of the detail energy
/// and of the noise, `WIN` rows each, row `q` in slot `q % WIN`.
struct Ring<'a> {
    e: &'a mut [f32],
    s: &'a mut [f32],
}

impl Ring<'_> {
    /// Adds row `q`'s horizontal sums (`te`, `ts`: scratch rows).
    #[inline(always)]
    fn push<S: FloatElement>(
        &mut self,
        source: SureSource,
        (cur, next): (&View<'_, S>, &View<'_, S>),
        q: usize,
        te: &mut [f32],
        ts: &mut [f32],
    ) {
        let w = te.len();
        terms(source, cur, next, q, te, ts);
        let slot = q % WIN;
        hsum(te, &mut self.e[slot * w..(slot + 1) * w]);
        hsum(ts, &mut self.s[slot * w..(slot + 1) * w]);
    }

    /// The window sums of rows `lo .. hi` (top to bottom) into `se`, `ss`.
    #[inline(always)]
    fn vertical(&self, lo: usize, hi: usize, se: &mut [f32], ss: &mut [f32]) {
        let w = se.len();
        if hi - lo == WIN {
            // A whole window (every row but the first and last two): one
            // pass, the rows added in the same order as below.
            fn row(v: &[f32], lo: usize, i: usize, w: usize) -> &[f32] {
                let slot = (lo + i) % WIN;
                &v[slot * w..(slot + 1) * w]
            }
            let row = |v, i| row(v, lo, i, w);
            let (e0, e1, e2, e3, e4) = (row(self.e, 0), row(self.e, 1), row(self.e, 2), row(self.e, 3), row(self.e, 4));
            let (s0, s1, s2, s3, s4) = (row(self.s, 0), row(self.s, 1), row(self.s, 2), row(self.s, 3), row(self.s, 4));
            for x in 0..w {
                se[x] = ((((0.0 + e0[x]) + e1[x]) + e2[x]) + e3[x]) + e4[x];
                ss[x] = ((((0.0 + s0[x]) + s1[x]) + s2[x]) + s3[x]) + s4[x];
            }
            return;
        }
        se.fill(0.0);
        ss.fill(0.0);
        for q in lo..hi {
            let slot = q % WIN;
            let (re, rs) = (&self.e[slot * w..(slot + 1) * w], &self.s[slot * w..(slot + 1) * w]);
            for x in 0..w {
                se[x] += re[x];
                ss[x] += rs[x];
            }
        }
    }
}

/// The risk-minimising weight of each pixel of a row from its window sums,
/// then `o += beta (a - b)` per channel.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn select_update<S: FloatElement, const AVX2: bool>(
    candidates: &[f32],
    (se, ss): (&[f32], &[f32]),
    a: &[&[S]; 3],
    b: &[&[S]; 3],
    o: &mut [&mut [f32]; 3],
    best_b: &mut [f32],
) {
    let w = se.len();
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is only set in code compiled for AVX2.
        unsafe { select_update_avx2(candidates, se, ss, a, b, o, w) };
        return;
    }
    // The risk-minimising weight per pixel, the first candidate on ties.
    for x in 0..w {
        best_b[x] = super::risk_argmin(se[x], ss[x], candidates);
    }
    for c in 0..3 {
        for x in 0..w {
            o[c][x] += best_b[x] * (a[c][x].to_f32() - b[c][x].to_f32());
        }
    }
}

/// A shrinkage pass after its checks: the window rings of every level
/// advance together; per row each level adds its shrunk detail, in level
/// order, into the output rows ([`Sink::Add`]) or into a row accumulator
/// that then goes out added to `c_N` ([`Sink::Reconstruct`]).
#[inline(always)]
fn run<S: FloatElement, const AVX2: bool>(
    job: Job<'_, '_, S>,
    out: &mut ViewMut<'_, f32>,
    y0: usize,
    scratch: &mut [f32],
) {
    let Job { source, candidates, images, into } = job;
    let (w, h) = (images[0].width(), images[0].height());
    let r = SURE_RADIUS;
    let levels = images.len() - 1;
    let (te, rest) = scratch.split_at_mut(w);
    let (ts, rest) = rest.split_at_mut(w);
    let (se, rest) = rest.split_at_mut(w);
    let (ss, rest) = rest.split_at_mut(w);
    let (best_b, mut rest) = rest.split_at_mut(w);
    let mut rings: [Option<Ring<'_>>; MAX_SURE_LEVELS] = Default::default();
    for ring in rings.iter_mut().take(levels) {
        let (e, more) = rest.split_at_mut(WIN * w);
        let (s, more) = more.split_at_mut(WIN * w);
        *ring = Some(Ring { e, s });
        rest = more;
    }
    // The row accumulator (reconstruction only; 3 w words past the rings).
    let acc = rest;
    let y1 = y0 + out.height();
    let last = &images[levels];
    let mut filled = y0.saturating_sub(r);
    for y in y0..y1 {
        let (lo, hi) = (y.saturating_sub(r), (y + r + 1).min(h));
        while filled < hi {
            for (l, ring) in rings.iter_mut().take(levels).enumerate() {
                if let Some(ring) = ring {
                    ring.push(source, (&images[l], &images[l + 1]), filled, te, ts);
                }
            }
            filled += 1;
        }
        if into == Sink::Reconstruct {
            acc[..3 * w].fill(0.0);
        }
        for (l, ring) in rings.iter().take(levels).enumerate() {
            let Some(ring) = ring else { continue };
            ring.vertical(lo, hi, se, ss);
            let (cur, next) = (&images[l], &images[l + 1]);
            let (a, b): ([&[S]; 3], [&[S]; 3]) =
                (core::array::from_fn(|c| &cur.row(c, y)[..w]), core::array::from_fn(|c| &next.row(c, y)[..w]));
            let mut o = match into {
                Sink::Add => out.plane_rows_mut::<3>(y - y0),
                Sink::Reconstruct => {
                    let (a0, rest) = acc.split_at_mut(w);
                    let (a1, a2) = rest.split_at_mut(w);
                    [a0, a1, &mut a2[..w]]
                }
            };
            select_update::<S, AVX2>(candidates, (se, ss), &a, &b, &mut o, best_b);
        }
        if into == Sink::Reconstruct {
            let mut o = out.plane_rows_mut::<3>(y - y0);
            for (c, oc) in o.iter_mut().enumerate() {
                let (base, add) = (&last.row(c, y)[..w], &acc[c * w..(c + 1) * w]);
                for x in 0..w {
                    oc[x] = base[x].to_f32() + add[x];
                }
            }
        }
    }
}

/// The candidate choice and the update of one row, eight pixels at a time:
/// the same operations in the same order as the portable loops (products
/// and sums rounded separately, the first candidate on ties), so the result
/// is bit-identical; the choice stays in registers (conditional stores
/// vectorise into masked stores, which Zen 3 runs slowly).
///
/// # Safety
/// AVX2, FMA and F16C must be supported; every row holds `w` elements.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,f16c")]
unsafe fn select_update_avx2<S: FloatElement>(
    candidates: &[f32],
    se: &[f32],
    ss: &[f32],
    a: &[&[S]; 3],
    b: &[&[S]; 3],
    o: &mut [&mut [f32]; 3],
    w: usize,
) {
    use crate::simd::avx2::{load8, load8_range, store8_first};
    use core::arch::x86_64::*;
    let mut x = 0;
    while x < w {
        let n = (w - x).min(8);
        // SAFETY (loads and stores): lanes below n lie inside the rows.
        let ld = |p: *const S| unsafe {
            if n == 8 {
                load8(p)
            } else {
                load8_range(p, 0, n)
            }
        };
        let lf = |p: *const f32| unsafe {
            if n == 8 {
                _mm256_loadu_ps(p)
            } else {
                load8_range(p, 0, n)
            }
        };
        let (e, sv) = (lf(se.as_ptr().wrapping_add(x)), lf(ss.as_ptr().wrapping_add(x)));
        let mut best_r = _mm256_set1_ps(f32::INFINITY);
        let mut best_b = _mm256_set1_ps(candidates[0]);
        for &bt in candidates {
            let (ce, cs) = (_mm256_set1_ps((1.0 - bt) * (1.0 - bt)), _mm256_set1_ps(2.0 * bt - 1.0));
            let risk = _mm256_add_ps(_mm256_mul_ps(ce, e), _mm256_mul_ps(cs, sv));
            let better = _mm256_cmp_ps::<_CMP_LT_OQ>(risk, best_r);
            best_r = _mm256_blendv_ps(best_r, risk, better);
            best_b = _mm256_blendv_ps(best_b, _mm256_set1_ps(bt), better);
        }
        for c in 0..3 {
            let d = _mm256_sub_ps(ld(a[c].as_ptr().wrapping_add(x)), ld(b[c].as_ptr().wrapping_add(x)));
            let op = o[c].as_mut_ptr().wrapping_add(x);
            let v = _mm256_add_ps(lf(op), _mm256_mul_ps(best_b, d));
            // SAFETY: as above.
            unsafe { store8_first::<f32>(op, n, v) };
        }
        x += n;
    }
}

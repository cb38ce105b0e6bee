//! The softmax operators in f32 arithmetic over f32 or f16 storage.
//!
//! The control flow (tiling, shifts, prefix/suffix, fallback) is written once
//! here; the row loops it calls come from an [`Ops`] implementation per
//! instruction set. The box sums, prefix/suffix sums and ratios are the same
//! sequence of IEEE operations in every implementation, so the paths differ
//! only in the `exp` polynomial's FMA rounding.

use super::{clamp_logit, FusedInputs, WindowPath, MAX_CHANNELS, MAX_FUSED};
use crate::precision::FloatElement;
use crate::real::Real;
use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;

/// How far the box-sum and separable paths' second pass lowers a size's
/// shift (nats) for the windows whose denominator fell under `TINY` (their
/// logits all lie more than ~69 nats under the tile's largest, so at the
/// new shift their weights stay under 1; the tile's other weights stay
/// under e^60, finite). Only what is still under it after that pass is
/// computed window by window. f32 arithmetic only (f16-rounded arithmetic
/// computes window by window, as before).
pub(crate) const FWD_SHIFT_STEP: f32 = 60.0;

/// Output rows per tile of the box-sum path.
pub(crate) const TILE_H: usize = 48;
/// Output columns per tile of the box-sum path.
pub(crate) const TILE_W: usize = 256;

/// Output columns per sub-tile of the separable path. The whole grid cell:
/// 64 and 128 (a ring that fits L1) measured slower, their halos cost more.
pub(crate) const SEP_TW: usize = TILE_W;
/// Plane stride of the separable path's rows: a sub-tile and its widest
/// halo (`MAX_WINDOW - 1`), rounded up to a multiple of 8.
pub(crate) const SEP_LS: usize = SEP_TW + 16;
/// Slot stride of the separable path's ring (the weight plane and up to
/// `MAX_CHANNELS` weighted channels).
pub(crate) const SEP_SS: usize = (1 + MAX_CHANNELS) * SEP_LS;

/// Row loops of the separable path. Rows are plane-interleaved with plane
/// stride [`SEP_LS`]: the weight, then one weighted channel each.
pub(crate) trait SepOps<A: Real> {
    /// One weight row: `e = exp(clamp(l) - shift)` and `e * r_c` at columns
    /// `u0 .. u1`, 0 at every other column below `SEP_LS` (and everywhere
    /// when `l` is `None`). `w` holds `1 + rad.len()` planes.
    fn weights_row<S: FloatElement>(&self, l: Option<&[S]>, rad: &[&[S]], shift: A, u0: usize, u1: usize, w: &mut [A]);
    /// `v[i] = sum_{s < k} ring[s * SEP_SS + i]`, `s` ascending, for `i < v.len()`.
    fn vertical_sum(&self, ring: &[A], k: usize, v: &mut [A]);
    /// Window sums `sum_{j < k} v[q * SEP_LS + x + j]` (`j` ascending) for
    /// the `tw = alpha.len()` output columns, then for every column with
    /// `den >= TINY`: `acc_c += num_c * (alpha / den)`. Writes `den` per
    /// column; returns whether any column had `den < TINY`.
    #[allow(clippy::too_many_arguments)]
    fn horizontal_direct(
        &self,
        v: &[A],
        np: usize,
        k: usize,
        alpha: &[A],
        acc: &mut [A],
        acc_plane: usize,
        den: &mut [A],
    ) -> bool;
}

/// Row loops of the box-sum path. Rows of the carried block are stored
/// plane-interleaved: row `t` is `np` consecutive planes of `len` values
/// (`np = 1 + channels`: the weight sum, then one weighted channel each).
pub(crate) trait Ops<A: Real> {
    /// Maximum of a row of logits, NaN skipped (`-inf` when empty or all NaN).
    fn row_max<S: FloatElement>(&self, row: &[S]) -> f32;
    /// One carried row: `e = exp(clamp(l) - shift)` and `e * r_c` at columns
    /// `u0 .. u1` (0 elsewhere, and everywhere when `l` is `None`) into `a`,
    /// and the block prefix `p = a (+ p_prev)`.
    #[allow(clippy::too_many_arguments)]
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
    );
    /// Block suffix in place, `a = a (+ a_next)`, and when `v` is given the
    /// vertical window sum `v = a (+ p_win)`.
    fn backward_row(&self, a: &mut [A], a_next: Option<&[A]>, p_win: Option<&[A]>, v: Option<&mut [A]>);
    /// Horizontal window sums of the `np` planes of `v` (power-of-two
    /// doubling, see [`scalar::box_levels`]) for the `tw` output columns, then
    /// for every column with `den >= TINY`: `acc_c += num_c * (alpha / den)`.
    /// Writes `den` per column; returns whether any column had `den < TINY`.
    #[allow(clippy::too_many_arguments)]
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
    ) -> bool;
    /// Softmax over the fusion planes at columns `x0 .. x0 + n` of row `y`:
    /// `out[i * stride + x] = alpha_i` for `x < n`.
    fn alphas<S: FloatElement>(&self, f: &View<'_, S>, y: usize, x0: usize, n: usize, out: &mut [A], stride: usize);
    /// `out = from_f32(acc * albedo)` (albedo optional).
    fn finish<S: FloatElement>(&self, acc: &[A], albedo: Option<&[S]>, out: &mut [S]);
    /// Hints that `row` will be read soon (tiles read many short row pieces,
    /// too short for the hardware prefetchers to ramp up on).
    fn prefetch<S: FloatElement>(&self, _row: &[S]) {}
}

/// Prefetches every cache line of `row` into L1 (the SIMD [`Ops`]' hint).
#[cfg(target_arch = "x86_64")]
pub(crate) fn prefetch_row<S: FloatElement>(row: &[S]) {
    use core::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
    let bytes = core::mem::size_of_val(row);
    let p = row.as_ptr() as *const i8;
    let mut off = 0;
    while off < bytes {
        // SAFETY: prefetching never faults; the address is inside `row`.
        unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(off)) };
        off += 64;
    }
}

/// Scratch words of the box-sum path.
pub(crate) fn boxsum_scratch_len(sizes: &[usize], channels: usize, width: usize) -> usize {
    let rmax = sizes.iter().copied().max().unwrap_or(1) / 2;
    let tw = width.min(TILE_W);
    let th = TILE_H;
    // Carried rows: the tile, its halo, and up to k - 1 rows more so that the
    // prefix/suffix blocks start on absolute multiples of k.
    let t = th.saturating_add(rmax.saturating_mul(4));
    let l = tw.saturating_add(rmax.saturating_mul(2));
    let np = channels.saturating_add(1);
    let m = sizes.len();
    crate::sat_sum(&[
        crate::sat_prod(&[channels, th, tw]),
        crate::sat_prod(&[m, th, tw]),
        crate::sat_prod(&[2, np, t, l]),
        crate::sat_prod(&[np, l]),
        tw,
        crate::sat_prod(&[3, np, l]),
        crate::sat_prod(&[th.saturating_add(channels), tw]),
    ])
}

/// Scratch words of the separable path.
pub(crate) fn separable_scratch_len(sizes: &[usize], channels: usize, width: usize) -> usize {
    let kmax = sizes.iter().copied().max().unwrap_or(1);
    let tw = width.min(SEP_TW);
    let np = channels.saturating_add(1);
    crate::sat_sum(&[
        crate::sat_prod(&[channels.saturating_add(sizes.len()), TILE_H, tw]),
        kmax.saturating_mul(SEP_SS),
        np.saturating_mul(SEP_LS),
        tw,
        crate::sat_prod(&[TILE_H.saturating_add(channels), tw]),
    ])
}

pub(crate) fn fused<S: FloatElement>(
    isa: crate::isa::Supported,
    path: WindowPath,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    match (isa.isa(), path) {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        (Isa::Avx2 | Isa::Avx512, WindowPath::Direct) => unsafe { avx2::direct(inp, dst, y0) },
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx2, WindowPath::BoxSum) => {
            // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
            let ops = unsafe { avx2::Avx2Ops::new() };
            boxsum(&ops, inp, dst, y0, scratch)
        }
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx512, WindowPath::BoxSum) => {
            // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
            let ops = unsafe { avx512::Avx512Ops::new() };
            boxsum(&ops, inp, dst, y0, scratch)
        }
        #[cfg(target_arch = "x86_64")]
        (Isa::Avx2 | Isa::Avx512, WindowPath::Separable) => {
            // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA (AVX-512 here implies AVX2, FMA and F16C).
            let ops = unsafe { avx2::Avx2Ops::new() };
            separable(&ops, inp, dst, y0, scratch)
        }
        _ => fused_scalar::<S, f32>(path, inp, dst, y0, scratch),
    }
}

/// The portable paths in arithmetic `A` (f32, or f16-rounded).
pub(crate) fn fused_scalar<S: FloatElement, A: Real>(
    path: WindowPath,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    match path {
        WindowPath::Direct => scalar::direct::<S, A>(inp, dst, y0),
        WindowPath::BoxSum => boxsum(&scalar::ScalarOps::<A>::new(), inp, dst, y0, bytemuck::cast_slice_mut(scratch)),
        WindowPath::Separable => {
            separable(&scalar::ScalarOps::<A>::new(), inp, dst, y0, bytemuck::cast_slice_mut(scratch))
        }
    }
}

pub(crate) fn kernels<S: FloatElement>(
    isa: crate::isa::Supported,
    k: usize,
    logits: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 | Isa::Avx512 => unsafe { avx2::kernels(k, logits, dst, y0) },
        _ => scalar::kernels::<S, f32>(k, logits, dst, y0),
    }
}

pub(crate) fn channel<S: FloatElement>(isa: crate::isa::Supported, src: &View<'_, S>, dst: &mut ViewMut<'_, S>) {
    match isa.isa() {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA.
        Isa::Avx2 | Isa::Avx512 => unsafe { avx2::channel(src, dst) },
        _ => scalar::channel::<S, f32>(src, dst),
    }
}

/// The direct window sum of size `k` at pixel `(y, x)` with the window's own
/// max shift: writes `R_c` for `c < channels` into `out`. Rows then columns
/// ascending, out-of-image taps skipped.
pub(crate) fn direct_pixel<S: FloatElement, A: Real>(
    k: usize,
    logits: &View<'_, S>,
    plane: usize,
    radiance: &View<'_, S>,
    y: usize,
    x: usize,
    out: &mut [A; MAX_CHANNELS],
) {
    let (w, h) = (radiance.width(), radiance.height());
    let r = k / 2;
    let ylo = y.saturating_sub(r);
    let yhi = (y + r + 1).min(h);
    let xlo = x.saturating_sub(r);
    let xhi = (x + r + 1).min(w);
    let mut m = f32::NEG_INFINITY;
    for yy in ylo..yhi {
        for &l in &logits.row(plane, yy)[xlo..xhi] {
            m = m.max(clamp_logit(l.to_f32()));
        }
    }
    let m = A::of(m);
    let ch = radiance.channels();
    let mut den = A::ZERO;
    let mut num = [A::ZERO; MAX_CHANNELS];
    for yy in ylo..yhi {
        let lrow = logits.row(plane, yy);
        for xx in xlo..xhi {
            let e = (A::of(clamp_logit(lrow[xx].to_f32())) - m).exp();
            den += e;
            for (c, n) in num.iter_mut().enumerate().take(ch) {
                *n += e * A::of(radiance.at(c, yy, xx).to_f32());
            }
        }
    }
    // den >= 1: the maximum's weight is exactly exp(0) = 1.
    for c in 0..ch {
        out[c] = num[c] / den;
    }
}

/// Fusion weights at one pixel: softmax over the `m` planes of `f`, max-shifted.
pub(crate) fn alpha_pixel<S: FloatElement, A: Real>(f: &View<'_, S>, y: usize, x: usize, out: &mut [A; MAX_FUSED]) {
    let m = f.channels();
    let mut mx = f32::NEG_INFINITY;
    for i in 0..m {
        mx = mx.max(clamp_logit(f.at(i, y, x).to_f32()));
    }
    let mx = A::of(mx);
    let mut sum = A::ZERO;
    for (i, o) in out.iter_mut().enumerate().take(m) {
        *o = (A::of(clamp_logit(f.at(i, y, x).to_f32())) - mx).exp();
        sum += *o;
    }
    let inv = A::ONE / sum;
    for o in out.iter_mut().take(m) {
        *o *= inv;
    }
}

/// The box-sum path, tile by tile. Tiles sit on a fixed grid of the whole
/// image (multiples of `TILE_H` rows and `TILE_W` columns) and the shift of a
/// tile is the maximum over the whole grid cell and its halo, whatever band of
/// rows is asked for; the vertical blocks start on absolute multiples of `k`.
/// So every output value depends only on its position, never on how the rows
/// were split into bands (the host's threads give bit-identical results).
fn boxsum<S: FloatElement, A: Real, O: Ops<A>>(
    o: &O,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [A],
) {
    let w = inp.radiance.width();
    let y_end = y0 + dst.height();
    let mut y = y0;
    while y < y_end {
        let cell = y - y % TILE_H;
        let rows = (cell + TILE_H).min(y_end) - y;
        let mut tx = 0;
        while tx < w {
            let tw = TILE_W.min(w - tx);
            tile(o, inp, dst, y0, cell, y, rows, tx, tw, scratch);
            tx += tw;
        }
        y += rows;
    }
}

/// The fusion weights of output rows `ytop .. ytop + th`, columns `tx .. tx + tw`,
/// into `alpha` (plane `i` at `i * th * tw`); all 1 without fusion logits.
#[allow(clippy::too_many_arguments)]
fn fusion_weights<S: FloatElement, A: Real, O: Ops<A>>(
    o: &O,
    inp: &FusedInputs<'_, S>,
    ytop: usize,
    th: usize,
    tx: usize,
    tw: usize,
    alpha: &mut [A],
) {
    match &inp.fusion {
        Some(f) => {
            for t in 0..th {
                if t + 2 < th {
                    for q in 0..f.channels() {
                        o.prefetch(&f.row(q, ytop + t + 2)[tx..tx + tw]);
                    }
                }
                o.alphas(f, ytop + t, tx, tw, &mut alpha[t * tw..], th * tw);
            }
        }
        None => alpha[..th * tw].fill(A::ONE),
    }
}

/// The columns of output row `y` (from `tx`) whose window sum of size
/// `sizes[i]` fell below `TINY`: recomputed with the direct path's
/// window-local shift and added to `acc` (plane `c` at `c * acc_plane`).
#[allow(clippy::too_many_arguments)]
fn tiny_fallback<S: FloatElement, A: Real>(
    inp: &FusedInputs<'_, S>,
    i: usize,
    den: &[A],
    alpha: &[A],
    y: usize,
    tx: usize,
    acc: &mut [A],
    acc_plane: usize,
) {
    let ch = inp.radiance.channels();
    for x in 0..alpha.len() {
        if den[x] >= A::TINY {
            continue;
        }
        let mut rr = [A::ZERO; MAX_CHANNELS];
        direct_pixel(inp.sizes[i], &inp.importance, i, &inp.radiance, y, tx + x, &mut rr);
        for c in 0..ch {
            acc[c * acc_plane + x] += rr[c] * alpha[x];
        }
    }
}

/// `dst = acc * albedo` for output rows `ytop .. ytop + th`, columns `tx .. tx + tw`.
#[allow(clippy::too_many_arguments)]
fn finish_tile<S: FloatElement, A: Real, O: Ops<A>>(
    o: &O,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    ytop: usize,
    th: usize,
    tx: usize,
    tw: usize,
    acc: &[A],
) {
    for t in 0..th {
        for c in 0..inp.radiance.channels() {
            let a = &acc[(c * th + t) * tw..(c * th + t + 1) * tw];
            let alb = inp.albedo.as_ref().map(|v| &v.row(c, ytop + t)[tx..tx + tw]);
            o.finish(a, alb, &mut dst.row_mut(c, ytop - y0 + t)[tx..tx + tw]);
        }
    }
}

/// The columns a tile starting at image column `tx` carries for radius `r`
/// (`l` of them, from `tx - r`): carried columns `u0 .. u1` lie inside the
/// image, as image columns `xs .. xe`.
fn carried(tx: usize, l: usize, r: usize, w: usize) -> (usize, usize, usize, usize) {
    let xbase = tx as isize - r as isize;
    let u0 = (-xbase).max(0) as usize;
    let u1 = ((w as isize - xbase).min(l as isize)) as usize;
    let xs = (xbase + u0 as isize) as usize;
    (u0, u1, xs, xs + (u1 - u0))
}

/// The shift of size `i` (radius `r`) in the grid cell from row `cell`: the
/// largest clamped logit of the cell's rows and their halo, columns `xs .. xe`.
#[allow(clippy::too_many_arguments)]
fn cell_shift<S: FloatElement, A: Real, O: Ops<A>>(
    o: &O,
    imp: &View<'_, S>,
    i: usize,
    r: usize,
    cell: usize,
    xs: usize,
    xe: usize,
) -> A {
    let mut shift = f32::NEG_INFINITY;
    let (sy0, sy1) = (cell.saturating_sub(r), (cell + TILE_H + r).min(imp.height()));
    for yy in sy0..sy1 {
        if yy + 4 < sy1 {
            o.prefetch(&imp.row(i, yy + 4)[xs..xe]);
        }
        shift = shift.max(o.row_max(&imp.row(i, yy)[xs..xe]));
    }
    A::of(clamp_logit(shift))
}

/// Image row `yy` of importance plane `i`, columns `xs .. xe` (`None`
/// outside the image), with the radiance rows put in `rads`; prefetches the
/// rows two below.
#[allow(clippy::too_many_arguments)]
fn source_row<'a, S: FloatElement, A: Real, O: Ops<A>>(
    o: &O,
    inp: &FusedInputs<'a, S>,
    i: usize,
    yy: isize,
    xs: usize,
    xe: usize,
    rads: &mut [&'a [S]; MAX_CHANNELS],
) -> Option<&'a [S]> {
    let (imp, rad) = (&inp.importance, &inp.radiance);
    let h = rad.height();
    let ahead = yy + 2;
    if ahead >= 0 && (ahead as usize) < h {
        o.prefetch(&imp.row(i, ahead as usize)[xs..xe]);
        for c in 0..rad.channels() {
            o.prefetch(&rad.row(c, ahead as usize)[xs..xe]);
        }
    }
    if yy < 0 || yy as usize >= h {
        return None;
    }
    for (c, rr) in rads.iter_mut().enumerate().take(rad.channels()) {
        *rr = &rad.row(c, yy as usize)[xs..xe];
    }
    Some(&imp.row(i, yy as usize)[xs..xe])
}

/// Euclidean floor of `a / k` times `k` for possibly negative rows.
fn block_start(a: isize, k: usize) -> isize {
    a.div_euclid(k as isize) * k as isize
}

/// Output rows `ytop .. ytop + th` (inside grid cell `cell ..`), columns `tx .. tx + tw`.
///
/// Vertical first: the weight rows (`e` and `e * r_c`, full carried width)
/// are summed over windows of `k` rows by prefix/suffix blocks, and only the
/// `th` window rows that are output are then summed horizontally, straight
/// into the accumulators.
#[allow(clippy::too_many_arguments)]
fn tile<S: FloatElement, A: Real, O: Ops<A>>(
    o: &O,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    cell: usize,
    ytop: usize,
    th: usize,
    tx: usize,
    tw: usize,
    scratch: &mut [A],
) {
    let rad = &inp.radiance;
    let imp = &inp.importance;
    let (w, ch) = (rad.width(), rad.channels());
    let m = inp.sizes.len();
    let rmax = inp.sizes.iter().copied().max().unwrap_or(1) / 2;
    let np = 1 + ch; // planes carried: weight sum, then one per channel
    let tmax = th + 4 * rmax;
    let lmax = tw + 2 * rmax;
    let (acc, rest) = scratch.split_at_mut(ch * th * tw);
    let (alpha, rest) = rest.split_at_mut(m * th * tw);
    let (a_buf, rest) = rest.split_at_mut(np * tmax * lmax);
    let (p_buf, rest) = rest.split_at_mut(np * tmax * lmax);
    let (v_buf, rest) = rest.split_at_mut(np * lmax);
    let (den, rest) = rest.split_at_mut(tw);
    let (lv, rest) = rest.split_at_mut(3 * np * lmax);
    let (mask, rest) = rest.split_at_mut(th * tw);
    let extra = &mut rest[..ch * tw];
    acc.fill(A::ZERO);
    fusion_weights(o, inp, ytop, th, tx, tw, alpha);
    let passes = if A::IS_F32 { 2 } else { 1 };
    for (i, &k) in inp.sizes.iter().enumerate() {
        let r = k / 2;
        let ri = r as isize;
        let l = tw + 2 * r; // columns carried for this size
        let row = np * l; // words per carried row (all planes)
        let (u0, u1, xs, xe) = carried(tx, l, r, w);

        let shift0 = cell_shift(o, imp, i, r, cell, xs, xe);
        let mut any_left = false;
        for pass in 0..passes {
            if pass > 0 && !any_left {
                break;
            }
            let shift = shift0 - A::of(pass as f32 * FWD_SHIFT_STEP);

            // Carried rows: from the start of the block holding the first window's
            // top row to the last window's bottom row.
            let ybase = block_start(ytop as isize - ri, k);
            let tt = ((ytop + th + r) as isize - ybase) as usize;
            // Absolute row of carried row t is ybase + t; blocks start where that is 0 mod k.
            let block_pos = |t: usize| (ybase + t as isize).rem_euclid(k as isize) as usize;
            let mut rads: [&[S]; MAX_CHANNELS] = [&[]; MAX_CHANNELS];
            for t in 0..tt {
                let yy = ybase + t as isize;
                let lrow = source_row(o, inp, i, yy, xs, xe, &mut rads);
                let a_row = &mut a_buf[t * row..(t + 1) * row];
                let (p_before, p_rest) = p_buf.split_at_mut(t * row);
                let p_prev = (t > 0 && block_pos(t) != 0).then(|| &p_before[(t - 1) * row..]);
                o.forward_row(lrow, &rads[..ch], shift, u0, u1, a_row, p_prev, &mut p_rest[..row]);
            }
            // Suffix within blocks, in place, walking up; emit windows as they complete.
            let first_out = (ytop as isize - ri - ybase) as usize; // carried row of the first window's top
            for t in (0..tt).rev() {
                let block_last = block_pos(t) == k - 1 || t == tt - 1;
                let emit = t >= first_out && t < first_out + th;
                // Window rows t ..= t + k - 1: one whole block, or a suffix plus a prefix.
                let p_win = (emit && block_pos(t) != 0).then(|| &p_buf[(t + k - 1) * row..(t + k) * row]);
                let (a_cur, a_next) = a_buf.split_at_mut((t + 1) * row);
                let next = (!block_last).then(|| &a_next[..row]);
                o.backward_row(&mut a_cur[t * row..], next, p_win, emit.then_some(&mut v_buf[..row]));
                if !emit {
                    continue;
                }
                let ot = t - first_out; // output row within the tile
                let arow = &alpha[(i * th + ot) * tw..(i * th + ot + 1) * tw];
                let mrow = &mut mask[ot * tw..(ot + 1) * tw];
                let last = pass + 1 == passes;
                let any_tiny = if pass == 0 {
                    o.horizontal_accumulate(&v_buf[..row], np, k, arow, &mut acc[ot * tw..], th * tw, den, lv)
                } else {
                    extra.fill(A::ZERO);
                    let t = o.horizontal_accumulate(&v_buf[..row], np, k, arow, extra, tw, den, lv);
                    add_marked(extra, tw, mrow, den, &mut acc[ot * tw..], th * tw);
                    t
                };
                any_left |=
                    after_pass(inp, i, any_tiny, last, den, arow, mrow, ytop + ot, tx, &mut acc[ot * tw..], th * tw);
            }
        }
    }
    finish_tile(o, inp, dst, y0, ytop, th, tx, tw, acc);
}

/// A later pass's sums for the marked columns (those under `TINY` before)
/// whose window sum now reaches it, added into `acc`; the other columns'
/// values (resolved by an earlier pass, and at this pass's lower shift
/// possibly overflowed) are dropped.
#[inline(always)]
fn add_marked<A: Real>(extra: &[A], plane: usize, mask: &[A], den: &[A], acc: &mut [A], acc_plane: usize) {
    for (c, e) in extra.chunks(plane).enumerate() {
        let a = &mut acc[c * acc_plane..c * acc_plane + mask.len()];
        for (((av, &ev), &m), &d) in a.iter_mut().zip(e).zip(mask).zip(den) {
            if m != A::ZERO && d >= A::TINY {
                *av += ev;
            }
        }
    }
}

/// After a pass over one output row: on the last pass the windows still
/// under `TINY` are computed one by one ([`tiny_fallback`]); before it they
/// are marked in `mask` for the next pass (and the rest cleared). Returns
/// whether any was marked.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn after_pass<S: FloatElement, A: Real>(
    inp: &FusedInputs<'_, S>,
    i: usize,
    any_tiny: bool,
    last: bool,
    den: &[A],
    alpha: &[A],
    mask: &mut [A],
    y: usize,
    tx: usize,
    acc: &mut [A],
    acc_plane: usize,
) -> bool {
    match (any_tiny, last) {
        (true, true) => {
            tiny_fallback(inp, i, den, alpha, y, tx, acc, acc_plane);
            false
        }
        (true, false) => {
            mark_tiny(den, mask);
            true
        }
        (false, false) => {
            mask.fill(A::ZERO);
            false
        }
        (false, true) => false,
    }
}

/// Marks the columns whose window sum fell under `TINY` (1) and clears the rest.
#[inline(always)]
fn mark_tiny<A: Real>(den: &[A], mask: &mut [A]) {
    for (m, &d) in mask.iter_mut().zip(den) {
        *m = if d >= A::TINY { A::ZERO } else { A::ONE };
    }
}

/// The separable path: the box-sum path's grid cells and shifts (so the two
/// differ only in the order of their additions), each cell in sub-tiles of
/// [`SEP_TW`] columns.
fn separable<S: FloatElement, A: Real, O: Ops<A> + SepOps<A>>(
    o: &O,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [A],
) {
    let imp = &inp.importance;
    let w = inp.radiance.width();
    let y_end = y0 + dst.height();
    let mut shifts = [A::ZERO; MAX_FUSED];
    let mut y = y0;
    while y < y_end {
        let cell = y - y % TILE_H;
        let rows = (cell + TILE_H).min(y_end) - y;
        let mut cx = 0;
        while cx < w {
            let cw = TILE_W.min(w - cx);
            // The shift of each size: the largest (clamped) logit of the cell and its halo.
            for (i, &k) in inp.sizes.iter().enumerate() {
                let r = k / 2;
                let (_, _, xs, xe) = carried(cx, cw + 2 * r, r, w);
                shifts[i] = cell_shift(o, imp, i, r, cell, xs, xe);
            }
            let mut tx = cx;
            while tx < cx + cw {
                let tw = SEP_TW.min(cx + cw - tx);
                sep_tile(o, inp, dst, y0, y, rows, tx, tw, &shifts, scratch);
                tx += tw;
            }
            cx += cw;
        }
        y += rows;
    }
}

/// Output rows `ytop .. ytop + th`, columns `tx .. tx + tw` of the separable
/// path. Per size: the weight rows `ytop - r ..= ytop + th - 1 + r` go into a
/// ring of `k` slots (slot = image row mod `k`); once a window's `k` rows are
/// in, their vertical sum is summed horizontally straight into the
/// accumulators.
#[allow(clippy::too_many_arguments)]
fn sep_tile<S: FloatElement, A: Real, O: Ops<A> + SepOps<A>>(
    o: &O,
    inp: &FusedInputs<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    ytop: usize,
    th: usize,
    tx: usize,
    tw: usize,
    shifts: &[A; MAX_FUSED],
    scratch: &mut [A],
) {
    let rad = &inp.radiance;
    let (w, ch) = (rad.width(), rad.channels());
    let m = inp.sizes.len();
    let kmax = inp.sizes.iter().copied().max().unwrap_or(1);
    let np = 1 + ch;
    let (acc, rest) = scratch.split_at_mut(ch * th * tw);
    let (alpha, rest) = rest.split_at_mut(m * th * tw);
    let (ring, rest) = rest.split_at_mut(kmax * SEP_SS);
    let (v, rest) = rest.split_at_mut(np * SEP_LS);
    let (den, rest) = rest.split_at_mut(tw);
    let (mask, rest) = rest.split_at_mut(th * tw);
    let extra = &mut rest[..ch * tw];
    acc.fill(A::ZERO);
    fusion_weights(o, inp, ytop, th, tx, tw, alpha);
    let mut rads: [&[S]; MAX_CHANNELS] = [&[]; MAX_CHANNELS];
    let passes = if A::IS_F32 { 2 } else { 1 };
    for (i, &k) in inp.sizes.iter().enumerate() {
        let r = k / 2;
        let ri = r as isize;
        let l = tw + 2 * r; // columns carried for this size
        let (u0, u1, xs, xe) = carried(tx, l, r, w);
        let mut any_left = false;
        for pass in 0..passes {
            if pass > 0 && !any_left {
                break;
            }
            let shift = shifts[i] - A::of(pass as f32 * FWD_SHIFT_STEP);
            for t in 0..th + 2 * r {
                let yy = ytop as isize - ri + t as isize;
                let lrow = source_row(o, inp, i, yy, xs, xe, &mut rads);
                let slot = yy.rem_euclid(k as isize) as usize;
                let wrow = &mut ring[slot * SEP_SS..slot * SEP_SS + np * SEP_LS];
                o.weights_row(lrow, &rads[..ch], shift, u0, u1, wrow);
                if t < 2 * r {
                    continue;
                }
                // Rows yy - 2r ..= yy are in: the windows of output row yy - r.
                let ot = t - 2 * r;
                o.vertical_sum(&ring[..(k - 1) * SEP_SS + np * SEP_LS], k, v);
                let arow = &alpha[(i * th + ot) * tw..(i * th + ot + 1) * tw];
                let mrow = &mut mask[ot * tw..(ot + 1) * tw];
                let last = pass + 1 == passes;
                let any_tiny = if pass == 0 {
                    o.horizontal_direct(v, np, k, arow, &mut acc[ot * tw..], th * tw, den)
                } else {
                    extra.fill(A::ZERO);
                    let t = o.horizontal_direct(v, np, k, arow, extra, tw, den);
                    add_marked(extra, tw, mrow, den, &mut acc[ot * tw..], th * tw);
                    t
                };
                any_left |=
                    after_pass(inp, i, any_tiny, last, den, arow, mrow, ytop + ot, tx, &mut acc[ot * tw..], th * tw);
            }
        }
    }
    finish_tile(o, inp, dst, y0, ytop, th, tx, tw, acc);
}

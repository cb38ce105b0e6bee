//! A trained network over a whole frame in any precision: each layer is the
//! core's operator run over bands of rows on the context's threads, tensors
//! kept only while a later layer reads them (a chain of convolutions holds
//! two at a time), buffers reused from frame to frame.
//!
//! Fixed point needs a format per tensor: [`Inference::new`] takes each
//! tensor's largest magnitude (measured by an f32 run, [`Inference::ranges`])
//! and gives it the format that keeps twice that representable; weights get
//! as many fractional bits as each output channel's bit budget allows.

use mcdenoise_core::conv::{self, Conv2d};
use mcdenoise_core::pool::{self, grad as pgrad, Reduce};
use mcdenoise_core::View;

use super::{Net, Node};
use crate::error::{HostError, Result};
use crate::runtime::precision::{frac_for_max, max_abs, HostPrecision, Planes};
use crate::runtime::Ctx;

/// One conv layer's weights in the precision.
struct Weights<T> {
    w: Vec<T>,
    b: Option<Vec<T>>,
    frac: i8,
}

/// A network ready to run in precision `P`.
pub struct Inference<P: HostPrecision> {
    net: Net,
    weights: Vec<Weights<P::Store>>,
    /// Fixed point: each tensor's format (0 otherwise).
    fracs: Vec<i8>,
    /// Buffers by tensor (None when not live).
    bufs: Vec<Option<Planes<P::Store>>>,
    free: Vec<Planes<P::Store>>,
    /// The frame size of the last run.
    size: (usize, usize),
    last_use: Vec<usize>,
    /// The 8-bit emulation ([`Inference::emulate_int8`]): per tensor, the
    /// step and the integer bounds its values are rounded to (None: kept).
    int8: Option<Vec<Option<(f32, f32, f32)>>>,
}

/// Rounds `data` to multiples of `step` between `lo` and `hi` steps.
fn fake_quantise<P: HostPrecision>(data: &mut [P::Store], (step, lo, hi): (f32, f32, f32)) {
    let mut v = vec![0.0f32; data.len()];
    P::decode(data, &mut v, 0);
    for x in &mut v {
        *x = (*x / step).round().clamp(lo, hi) * step;
    }
    P::encode(&v, data, 0);
}

/// Rounds each output channel's `per` weights to 255 levels symmetric
/// about 0 (`i8` in [-127, 127] times the channel's own scale), as an
/// 8-bit convolution stores them.
pub fn int8_weights(w: &mut [f32], per: usize) {
    for ch in w.chunks_mut(per.max(1)) {
        let m = ch.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        if m > 0.0 && m.is_finite() {
            let s = m / 127.0;
            ch.iter_mut().for_each(|v| *v = (*v / s).round().clamp(-127.0, 127.0) * s);
        }
    }
}

/// The node after which each tensor is read no more (the outputs: never,
/// they stay until the next run).
fn last_uses(net: &Net) -> Vec<usize> {
    let mut last_use = vec![0; net.tensors.len()];
    for (n, node) in net.nodes.iter().enumerate() {
        match *node {
            Node::Conv { x, .. } | Node::Pool { x, .. } | Node::Up { x, .. } => last_use[x] = n,
            Node::Concat { a, b, .. } => {
                last_use[a] = n;
                last_use[b] = n;
            }
        }
    }
    for &o in &net.outputs {
        last_use[o] = usize::MAX;
    }
    last_use
}

/// Bytes per pixel of the network's input frame that tensor `t` takes in
/// storage of `bytes` per value (a tensor `level` times pooled has a
/// quarter of the pixels per level; rounded up).
fn tensor_bytes(net: &Net, t: usize, bytes: u64) -> u64 {
    let spec = net.tensors[t];
    (spec.c as u64 * bytes).div_ceil(1 << (2 * spec.level))
}

/// Bytes per pixel an [`Inference`] of `net` in storage of `bytes` per
/// value holds from its first run on, which is also its peak during a run:
/// a replay of [`Inference::run_view`] (the input borrowed; a buffer whose
/// tensor is read no more waits in the free list for a later tensor of the
/// same size, and is never given back). Buffers of different scales are
/// never shared here, though a frame's sizes may let them be: a bound.
pub fn held_bytes_per_pixel(net: &Net, bytes: u64) -> u64 {
    let last_use = last_uses(net);
    let nt = net.tensors.len();
    let mut live: Vec<Option<usize>> = vec![None; nt];
    let mut free: Vec<usize> = Vec::new();
    let mut total = 0;
    let key = |t: usize| (net.tensors[t].c, net.tensors[t].level);
    for (n, node) in net.nodes.iter().enumerate() {
        let out = match *node {
            Node::Conv { out, .. } | Node::Pool { out, .. } | Node::Up { out, .. } | Node::Concat { out, .. } => out,
        };
        match free.iter().position(|&t| key(t) == key(out)) {
            Some(i) => {
                free.swap_remove(i);
            }
            None => total += tensor_bytes(net, out, bytes),
        }
        live[out] = Some(out);
        for t in 0..nt {
            if last_use[t] == n {
                if let Some(b) = live[t].take() {
                    free.push(b);
                }
            }
        }
    }
    total
}

/// Peak bytes per pixel of [`Inference::ranges`] of `net` (f32, the input
/// handed over as a frame of its own): every tensor kept, then each decoded
/// in turn.
pub fn ranges_bytes_per_pixel(net: &Net) -> u64 {
    let largest = (1..net.tensors.len()).map(|t| tensor_bytes(net, t, 4)).max().unwrap_or(0);
    tensors_bytes_per_pixel(net, 4) + largest.max(4 * net.desc.cin as u64)
}

/// Bytes per pixel of every tensor of `net` but its input together, in
/// storage of `bytes` per value.
pub fn tensors_bytes_per_pixel(net: &Net, bytes: u64) -> u64 {
    (1..net.tensors.len()).map(|t| tensor_bytes(net, t, bytes)).sum()
}

/// Tensor `t`: the borrowed input, or a live buffer.
fn src_of<'a, T: bytemuck::Pod + Default>(bufs: &'a [Option<Planes<T>>], t: usize, input: View<'a, T>) -> View<'a, T> {
    if t == 0 {
        input
    } else {
        bufs[t].as_ref().expect("a live tensor").view()
    }
}

impl<P: HostPrecision> Inference<P> {
    /// From the parameters; `ranges` (one per tensor, e.g. from
    /// [`Inference::ranges`]) set the fixed-point formats, `out_frac` the
    /// last tensor's when given.
    pub fn new(net: &Net, params: &[f32], ranges: Option<&[f32]>, out_frac: Option<i8>) -> Result<Self> {
        let nt = net.tensors.len();
        let mut fracs: Vec<i8> = match ranges {
            Some(r) if r.len() == nt => r.iter().map(|&m| frac_for_max(m)).collect(),
            Some(_) => return Err(HostError::Usage("network ranges: one per tensor".into())),
            None => vec![0; nt],
        };
        if let (Some(f), Some(last)) = (out_frac, fracs.last_mut()) {
            *last = f;
        }
        if !P::FIXED_POINT {
            fracs.iter_mut().for_each(|f| *f = 0);
        } else {
            // A concatenation holds both parts' ranges: the coarser format.
            for node in &net.nodes {
                if let Node::Concat { a, b, out } = *node {
                    fracs[out] = fracs[out].min(fracs[a]).min(fracs[b]);
                }
            }
        }
        let mut weights = Vec::new();
        for (i, c) in net.convs.iter().enumerate() {
            let k = c.k();
            let mut m = vec![0.0f32; c.spec.cout * c.cin * k * k];
            net.merge(params, i, &mut m);
            let frac = P::frac_or_zero(super::quant::weight_frac(&m, c.cin * k * k));
            let mut w = vec![P::Store::default(); m.len()];
            P::encode(&m, &mut w, frac);
            let out_t = net
                .nodes
                .iter()
                .find_map(|n| match *n {
                    Node::Conv { conv, out, .. } if conv == i => Some(out),
                    _ => None,
                })
                .expect("every conv has a node");
            let b = net.bias(params, i).map(|b| {
                let mut s = vec![P::Store::default(); b.len()];
                P::encode(b, &mut s, fracs[out_t]);
                s
            });
            weights.push(Weights { w, b, frac });
        }
        let last_use = last_uses(net);
        Ok(Inference {
            net: net.clone(),
            weights,
            fracs,
            bufs: (0..nt).map(|_| None).collect(),
            free: Vec::new(),
            size: (0, 0),
            last_use,
            int8: None,
        })
    }

    /// Emulates an 8-bit network, in a float precision: each conv's
    /// weights are rounded to `i8` with a scale per output channel
    /// ([`int8_weights`]), and each tensor to `u8` (after a ReLU, where no
    /// value is negative) or `i8` with one scale per tensor set by its
    /// largest magnitude in `ranges` ([`Inference::ranges`] on a first
    /// frame; larger values saturate). These are the values a `u8 x i8 ->
    /// i32` convolution (VNNI's `vpdpbusd`) computes with; biases and the
    /// sums stay exact. `keep_last`: the network's output keeps its
    /// precision (a requantisation of the `i32` sums to 16 bits costs the
    /// same). For measuring what 8 bits cost, not for speed: the arithmetic
    /// is still the precision's.
    pub fn emulate_int8(&mut self, ranges: &[f32], keep_last: bool) -> Result<()> {
        let nt = self.net.tensors.len();
        if P::FIXED_POINT || ranges.len() != nt {
            return Err(HostError::Usage(
                "the 8-bit emulation runs in a float precision, with one range per tensor".into(),
            ));
        }
        let mut nonneg = vec![false; nt];
        for node in &self.net.nodes {
            match *node {
                Node::Conv { conv: i, out, .. } => {
                    nonneg[out] = matches!(self.net.convs[i].spec.act, conv::Activation::Relu)
                }
                Node::Pool { x, out, .. } | Node::Up { x, out, .. } => nonneg[out] = nonneg[x],
                Node::Concat { a, b, out } => nonneg[out] = nonneg[a] && nonneg[b],
            }
        }
        for (i, c) in self.net.convs.iter().enumerate() {
            let wt = &mut self.weights[i];
            let mut v = vec![0.0f32; wt.w.len()];
            P::decode(&wt.w, &mut v, 0);
            int8_weights(&mut v, c.cin * c.k() * c.k());
            P::encode(&v, &mut wt.w, 0);
        }
        self.int8 = Some(
            (0..nt)
                .map(|t| {
                    let r = ranges[t];
                    if (keep_last && t == nt - 1) || !(r > 0.0 && r.is_finite()) {
                        None
                    } else if nonneg[t] {
                        Some((r / 255.0, 0.0, 255.0))
                    } else {
                        Some((r / 127.0, -127.0, 127.0))
                    }
                })
                .collect(),
        );
        Ok(())
    }

    /// Output `k` of the last run (in the network's output order).
    pub fn output(&self, k: usize) -> &Planes<P::Store> {
        self.bufs[self.net.outputs[k]].as_ref().expect("outputs stay live after a run")
    }

    /// Bytes of the buffers held now (live tensors and the free list).
    pub fn held_bytes(&self) -> u64 {
        let size = std::mem::size_of::<P::Store>() as u64;
        self.bufs.iter().flatten().chain(&self.free).map(|p| p.data.len() as u64 * size).sum()
    }

    /// The format the input must be stored in (fixed point).
    pub fn input_frac(&self) -> i8 {
        self.fracs[0]
    }

    fn take(&mut self, c: usize, w: usize, h: usize, frac: i8) -> Planes<P::Store> {
        let n = c * w * h;
        let mut p = match self.free.iter().position(|b| b.data.len() == n) {
            Some(i) => self.free.swap_remove(i),
            None => Planes::new(c, w, h),
        };
        (p.channels, p.width, p.height, p.frac) = (c, w, h, frac);
        p
    }

    /// Runs the network on `input` (the network's input channels, stored in
    /// `P` with [`Inference::input_frac`]); the output stays until the next run.
    pub fn run(&mut self, ctx: &mut Ctx, input: Planes<P::Store>) -> Result<&Planes<P::Store>> {
        let view = View::new(&input.data, input.channels, input.width, input.height)?.with_frac(input.frac);
        self.run_view(ctx, view)?;
        Ok(self.bufs.last().and_then(|b| b.as_ref()).expect("the output is live"))
    }

    /// [`Inference::run`] on a borrowed input (no copy of it is made).
    pub fn run_view(&mut self, ctx: &mut Ctx, input: View<'_, P::Store>) -> Result<&Planes<P::Store>> {
        let (w, h) = (input.width(), input.height());
        if input.channels() != self.net.desc.cin {
            return Err(HostError::Usage(format!(
                "network input: {} channels, expected {}",
                input.channels(),
                self.net.desc.cin
            )));
        }
        for b in self.bufs.iter_mut() {
            if let Some(p) = b.take() {
                self.free.push(p);
            }
        }
        // Buffers are reused by length; a new frame size makes the old ones
        // useless, so they are dropped: memory stays that of one size.
        if self.size != (w, h) {
            self.free.clear();
            self.size = (w, h);
        }
        // The 8-bit emulation rounds the input too: a rounded copy.
        let q_in = match self.int8.as_ref().and_then(|q| q[0]) {
            Some(q) => {
                let mut p = Planes::<P::Store>::new(input.channels(), w, h);
                for ch in 0..input.channels() {
                    for y in 0..h {
                        let o = (ch * h + y) * w;
                        p.data[o..o + w].copy_from_slice(input.row(ch, y));
                    }
                }
                fake_quantise::<P>(&mut p.data, q);
                Some(p)
            }
            None => None,
        };
        let input = match &q_in {
            Some(p) => p.view(),
            None => input,
        };
        let isa = ctx.isa;
        let nodes = self.net.nodes.clone();
        for (n, node) in nodes.iter().enumerate() {
            let out_t = match *node {
                Node::Conv { out, .. } | Node::Pool { out, .. } | Node::Up { out, .. } | Node::Concat { out, .. } => {
                    out
                }
            };
            let (tw, th) = self.net.size(out_t, w, h);
            let mut out = self.take(self.net.tensors[out_t].c, tw, th, self.fracs[out_t]);
            match *node {
                Node::Conv { conv: i, x, .. } => {
                    let c = self.net.convs[i];
                    let wt = &self.weights[i];
                    let layer = Conv2d {
                        k: c.k(),
                        cin: c.cin,
                        cout: c.spec.cout,
                        weights: &wt.w,
                        bias: wt.b.as_deref(),
                        act: c.spec.act,
                        weight_frac: wt.frac,
                    };
                    let src = src_of(&self.bufs, x, input);
                    let len = conv::conv2d_scratch_len::<P>(c.k(), c.cin, c.spec.cout, w);
                    ctx.pool.bands(out.view_mut(), 1, &mut ctx.scratch, len, |b, y0, s| {
                        conv::conv2d::<P>(isa, &layer, &src, b, y0, s)
                    })?;
                }
                Node::Pool { max, x, .. } => {
                    let src = src_of(&self.bufs, x, input);
                    let op = if max { Reduce::Max } else { Reduce::Mean };
                    ctx.pool.bands(out.view_mut(), 1, &mut ctx.scratch, 0, |b, y0, _| {
                        pool::reduce2x2::<P>(isa, op, &src, b, y0)
                    })?;
                }
                Node::Up { bilinear, x, .. } => {
                    let src = src_of(&self.bufs, x, input);
                    if bilinear {
                        // The bilinear upsample is an f32 operator: through f32 and back.
                        let mut s32 = Planes::<f32>::new(src.channels(), src.width(), src.height());
                        for ch in 0..src.channels() {
                            for y in 0..src.height() {
                                let o = (ch * src.height() + y) * src.width();
                                P::decode(src.row(ch, y), &mut s32.data[o..o + src.width()], src.frac());
                            }
                        }
                        let sv = s32.view();
                        let mut o32 = Planes::<f32>::new(out.channels, tw, th);
                        ctx.pool.bands(o32.view_mut(), 2, &mut ctx.scratch, 0, |b, y0, _| {
                            pgrad::upsample_bilinear2x(isa, &sv, b, y0, th)
                        })?;
                        P::encode(&o32.data, &mut out.data, out.frac);
                    } else {
                        ctx.pool.bands(out.view_mut(), 2, &mut ctx.scratch, 0, |b, y0, _| {
                            pool::upsample_nearest2x::<P>(isa, &src, b, y0, th)
                        })?;
                    }
                }
                Node::Concat { a, b, .. } => {
                    let (va, vb) = (src_of(&self.bufs, a, input), src_of(&self.bufs, b, input));
                    let ofrac = out.frac;
                    let mut ov = out.view_mut();
                    let mut row = vec![0.0f32; if va.frac() == ofrac && vb.frac() == ofrac { 0 } else { tw }];
                    for (c0, v) in [(0, va), (va.channels(), vb)] {
                        for ch in 0..v.channels() {
                            for y in 0..v.height() {
                                if v.frac() == ofrac {
                                    ov.row_mut(c0 + ch, y).copy_from_slice(v.row(ch, y));
                                } else {
                                    // Fixed point in another format: through f32.
                                    P::decode(v.row(ch, y), &mut row, v.frac());
                                    P::encode(&row, ov.row_mut(c0 + ch, y), ofrac);
                                }
                            }
                        }
                    }
                }
            }
            if let Some(q) = self.int8.as_ref().and_then(|q| q[out_t]) {
                fake_quantise::<P>(&mut out.data, q);
            }
            self.bufs[out_t] = Some(out);
            for t in 0..self.bufs.len() {
                if self.last_use[t] == n {
                    if let Some(p) = self.bufs[t].take() {
                        self.free.push(p);
                    }
                }
            }
        }
        Ok(self.bufs.last().and_then(|b| b.as_ref()).expect("the output is live"))
    }

    /// Each tensor's largest magnitude on `input` (f32 runs only), for the
    /// fixed-point formats.
    pub fn ranges(&mut self, ctx: &mut Ctx, input: Planes<P::Store>) -> Result<Vec<f32>> {
        let largest = |p: &Planes<P::Store>| match P::store_as_f32(&p.data) {
            Some(v) => max_abs(v),
            None => {
                let mut v = vec![0.0f32; p.data.len()];
                P::decode(&p.data, &mut v, p.frac);
                max_abs(&v)
            }
        };
        let input_max = largest(&input);
        let nt = self.net.tensors.len();
        let saved = std::mem::replace(&mut self.last_use, vec![usize::MAX; nt]);
        let r = self.run(ctx, input).map(|_| ());
        self.last_use = saved;
        r?;
        Ok(self
            .bufs
            .iter()
            .enumerate()
            .map(|(t, b)| {
                if t == 0 {
                    return input_max;
                }
                b.as_ref().map_or(0.0, largest)
            })
            .collect())
    }
}

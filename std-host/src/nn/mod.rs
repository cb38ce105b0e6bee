//! Small convolutional networks on the core's operators: a description that
//! WSKP's ImportanceNet, AFN's kernel predictor and refinement net and the
//! cross-regression U-Net are all written in, their parameters, training
//! (forward and backward in f32 over a batch of crops, one crop per task, the
//! crops' gradients summed in crop order so the result does not depend on the
//! thread count), and inference in any precision over bands of a frame.
//!
//! A network is a sequence of [`Layer`]s over planar tensors. `Save` pushes
//! the current tensor on a stack and `Concat` pops one and appends its
//! channels to the current tensor's (U-Net skips). A [`Conv`] may be a RepVGG
//! block (Ding et al. 2021): at training time the sum of a 5x5, a 3x3 and a
//! 1x1 convolution (and the identity when the channel counts agree); the
//! branches add up to one 5x5 convolution, which is what runs in both
//! training (the merged weights' gradient maps back onto each branch) and
//! inference.

use mcdenoise_core::conv::{self, grad as cgrad, Activation, Conv2d};
use mcdenoise_core::pool::{self, grad as pgrad, Reduce};
use mcdenoise_core::{Isa, View, ViewMut, F32};

use rayon::prelude::*;

use crate::error::{HostError, Result};
use crate::runtime::par::Pool;

pub mod adam;
pub mod infer;
pub mod loss;
pub mod quant;
pub mod weights;

/// One convolution layer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conv {
    /// Kernel size (1, 3 or 5); a RepVGG block is 5.
    pub k: usize,
    /// Output channels.
    pub cout: usize,
    /// The nonlinearity after it.
    pub act: Activation,
    /// A RepVGG block (5x5 + 3x3 + 1x1 (+ identity) branches, no bias).
    pub repvgg: bool,
    /// With a bias (plain convolutions only).
    pub bias: bool,
}

/// A layer of a network.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Layer {
    /// A convolution.
    Conv(Conv),
    /// 2x2 max pool.
    MaxPool,
    /// 2x2 average pool.
    AvgPool,
    /// 2x upsampling to the size of the tensor on top of the skip stack
    /// (nearest or bilinear).
    Upsample {
        /// Bilinear instead of nearest.
        bilinear: bool,
    },
    /// Pushes the current tensor on the skip stack.
    Save,
    /// Pops the skip stack and appends that tensor's channels.
    Concat,
    /// Marks the current tensor as an output of the network (a head); the
    /// last tensor always is one, after every marked one.
    Output,
    /// Pops the skip stack and makes that tensor the current one (to branch
    /// a head off and continue from before it).
    Pop,
}

/// A network: its input channels and layers.
#[derive(Clone, Debug, PartialEq)]
pub struct NetDesc {
    /// Input channels.
    pub cin: usize,
    /// The layers, in order.
    pub layers: Vec<Layer>,
}

/// What a tensor of the network is: planes and size relative to the input
/// (halvings).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct TensorSpec {
    c: usize,
    level: u32,
}

/// A layer resolved to tensor ids.
#[derive(Clone, Copy, Debug)]
enum Node {
    /// Conv `index` (into the convs) from tensor `x` to `out`.
    Conv {
        conv: usize,
        x: usize,
        out: usize,
    },
    Pool {
        max: bool,
        x: usize,
        out: usize,
    },
    Up {
        bilinear: bool,
        x: usize,
        like: usize,
        out: usize,
    },
    Concat {
        a: usize,
        b: usize,
        out: usize,
    },
}

/// A conv layer with its channel counts and where its parameters live.
#[derive(Clone, Copy, Debug)]
pub struct ConvInfo {
    /// The layer.
    pub spec: Conv,
    /// Input channels.
    pub cin: usize,
    /// Offset of its first parameter in the flat parameter vector.
    pub offset: usize,
    /// Parameter count.
    pub count: usize,
}

impl ConvInfo {
    /// The RepVGG branch sizes (largest first), or the plain kernel size.
    pub fn branches(&self) -> &'static [usize] {
        if self.spec.repvgg {
            &[5, 3, 1]
        } else {
            match self.spec.k {
                1 => &[1],
                3 => &[3],
                _ => &[5],
            }
        }
    }
    /// The identity branch is there (RepVGG with equal channel counts).
    pub fn identity(&self) -> bool {
        self.spec.repvgg && self.cin == self.spec.cout
    }
    /// Kernel size of the merged convolution.
    pub fn k(&self) -> usize {
        if self.spec.repvgg {
            5
        } else {
            self.spec.k
        }
    }
    fn merged_len(&self) -> usize {
        self.spec.cout * self.cin * self.k() * self.k()
    }
}

/// A network resolved: tensors, nodes and the parameter layout.
#[derive(Clone, Debug)]
pub struct Net {
    /// The description.
    pub desc: NetDesc,
    tensors: Vec<TensorSpec>,
    nodes: Vec<Node>,
    /// The conv layers.
    pub convs: Vec<ConvInfo>,
    /// Total parameters.
    pub params: usize,
    /// How many nodes read each tensor.
    consumers: Vec<usize>,
    /// The output tensors, in order (the last is the final tensor).
    outputs: Vec<usize>,
}

impl Net {
    /// Resolves a description; an error names a layer that cannot follow the previous ones.
    pub fn new(desc: NetDesc) -> Result<Net> {
        let bad = |i: usize, what: &str| HostError::Usage(format!("network layer {i}: {what}"));
        let mut tensors = vec![TensorSpec { c: desc.cin, level: 0 }];
        let mut nodes = Vec::new();
        let mut convs: Vec<ConvInfo> = Vec::new();
        let mut stack: Vec<usize> = Vec::new();
        let mut outputs: Vec<usize> = Vec::new();
        let mut cur = 0;
        let mut offset = 0;
        for (i, layer) in desc.layers.iter().enumerate() {
            let t = tensors[cur];
            match *layer {
                Layer::Conv(spec) => {
                    if !conv::KERNEL_SIZES.contains(&spec.k) || spec.cout == 0 {
                        return Err(bad(i, "a conv needs k in {1, 3, 5} and at least one output channel"));
                    }
                    if spec.repvgg && (spec.k != 5 || spec.bias) {
                        return Err(bad(i, "a RepVGG block is 5x5 and has no bias"));
                    }
                    let mut info = ConvInfo { spec, cin: t.c, offset, count: 0 };
                    let per = spec.cout * t.c;
                    info.count = info.branches().iter().map(|k| per * k * k).sum::<usize>()
                        + if spec.bias { spec.cout } else { 0 };
                    offset += info.count;
                    convs.push(info);
                    tensors.push(TensorSpec { c: spec.cout, level: t.level });
                    nodes.push(Node::Conv { conv: convs.len() - 1, x: cur, out: tensors.len() - 1 });
                }
                Layer::MaxPool | Layer::AvgPool => {
                    tensors.push(TensorSpec { c: t.c, level: t.level + 1 });
                    nodes.push(Node::Pool { max: *layer == Layer::MaxPool, x: cur, out: tensors.len() - 1 });
                }
                Layer::Upsample { bilinear } => {
                    let like = *stack.last().ok_or_else(|| bad(i, "upsampling needs a saved tensor to size it"))?;
                    if t.level != tensors[like].level + 1 {
                        return Err(bad(i, "upsampling must reach the saved tensor's resolution"));
                    }
                    tensors.push(TensorSpec { c: t.c, level: t.level - 1 });
                    nodes.push(Node::Up { bilinear, x: cur, like, out: tensors.len() - 1 });
                }
                Layer::Save => {
                    stack.push(cur);
                    continue;
                }
                Layer::Output => {
                    if cur == 0 || outputs.contains(&cur) {
                        return Err(bad(i, "an output must be a new layer's tensor"));
                    }
                    outputs.push(cur);
                    continue;
                }
                Layer::Pop => {
                    cur = stack.pop().ok_or_else(|| bad(i, "pop with nothing saved"))?;
                    continue;
                }
                Layer::Concat => {
                    let b = stack.pop().ok_or_else(|| bad(i, "concat with nothing saved"))?;
                    if tensors[b].level != t.level {
                        return Err(bad(i, "concat of tensors at different resolutions"));
                    }
                    tensors.push(TensorSpec { c: t.c + tensors[b].c, level: t.level });
                    nodes.push(Node::Concat { a: cur, b, out: tensors.len() - 1 });
                }
            }
            cur = tensors.len() - 1;
        }
        if cur == 0 || tensors.len() == 1 {
            return Err(HostError::Usage("a network needs at least one layer".into()));
        }
        let last = tensors.len() - 1;
        if cur != last {
            return Err(HostError::Usage("a network must end on its last layer's tensor (not after a pop)".into()));
        }
        if !outputs.contains(&last) {
            outputs.push(last);
        }
        let mut consumers = vec![0; tensors.len()];
        // The model's head reads every output.
        for &o in &outputs {
            consumers[o] += 1;
        }
        for node in &nodes {
            match *node {
                Node::Conv { x, .. } | Node::Pool { x, .. } | Node::Up { x, .. } => consumers[x] += 1,
                Node::Concat { a, b, .. } => {
                    consumers[a] += 1;
                    consumers[b] += 1;
                }
            }
        }
        Ok(Net { desc, tensors, nodes, convs, params: offset, consumers, outputs })
    }

    /// Output channels (of the final tensor).
    pub fn cout(&self) -> usize {
        self.tensors.last().map_or(0, |t| t.c)
    }

    /// The outputs' channels and halvings, in output order.
    pub fn output_specs(&self) -> Vec<(usize, u32)> {
        self.outputs.iter().map(|&t| (self.tensors[t].c, self.tensors[t].level)).collect()
    }

    /// The size of tensor `t` for an input of `w x h`.
    fn size(&self, t: usize, w: usize, h: usize) -> (usize, usize) {
        let l = self.tensors[t].level;
        let (mut w, mut h) = (w, h);
        for _ in 0..l {
            w = w.div_ceil(2);
            h = h.div_ceil(2);
        }
        (w, h)
    }

    /// Inputs must be multiples of this (each pool halves exactly).
    pub fn multiple(&self) -> usize {
        1 << self.tensors.iter().map(|t| t.level).max().unwrap_or(0)
    }

    /// He-normal initial parameters (std `sqrt(2 / fan_in)`, split across a
    /// RepVGG block's branches), biases 0, from `seed`.
    pub fn init(&self, seed: u64) -> Vec<f32> {
        let mut rng = Rng::new(seed);
        let mut p = vec![0.0f32; self.params];
        for c in &self.convs {
            let per = c.spec.cout * c.cin;
            let nb = c.branches().len() as f32;
            let mut at = c.offset;
            for &k in c.branches() {
                let std = (2.0 / (c.cin * k * k) as f32).sqrt() / nb.sqrt();
                for v in &mut p[at..at + per * k * k] {
                    *v = std * rng.normal();
                }
                at += per * k * k;
            }
        }
        p
    }

    /// The merged `[cout][cin][k][k]` weights of conv `i` into `out`.
    pub fn merge(&self, params: &[f32], i: usize, out: &mut [f32]) {
        let c = &self.convs[i];
        let (k, cin, cout) = (c.k(), c.cin, c.spec.cout);
        out.fill(0.0);
        let mut at = c.offset;
        for &b in c.branches() {
            let pad = (k - b) / 2;
            for co in 0..cout {
                for ci in 0..cin {
                    for y in 0..b {
                        for x in 0..b {
                            out[((co * cin + ci) * k + y + pad) * k + x + pad] +=
                                params[at + ((co * cin + ci) * b + y) * b + x];
                        }
                    }
                }
            }
            at += cout * cin * b * b;
        }
        if c.identity() {
            for o in 0..cout {
                out[((o * cin + o) * k + k / 2) * k + k / 2] += 1.0;
            }
        }
    }

    /// The bias of conv `i` (none for RepVGG blocks).
    pub fn bias<'a>(&self, params: &'a [f32], i: usize) -> Option<&'a [f32]> {
        let c = &self.convs[i];
        c.spec.bias.then(|| &params[c.offset + c.count - c.spec.cout..c.offset + c.count])
    }

    /// Maps a merged weight gradient (and bias gradient) of conv `i` onto its
    /// parameters' gradient (each branch gets the taps it covers), added to `grad`.
    fn unmerge_grad(&self, i: usize, gm: &[f32], gb: &[f32], grad: &mut [f32]) {
        let c = &self.convs[i];
        let (k, cin, cout) = (c.k(), c.cin, c.spec.cout);
        let mut at = c.offset;
        for &b in c.branches() {
            let pad = (k - b) / 2;
            for co in 0..cout {
                for ci in 0..cin {
                    for y in 0..b {
                        for x in 0..b {
                            grad[at + ((co * cin + ci) * b + y) * b + x] +=
                                gm[((co * cin + ci) * k + y + pad) * k + x + pad];
                        }
                    }
                }
            }
            at += cout * cin * b * b;
        }
        if c.spec.bias {
            for (g, &v) in grad[c.offset + c.count - cout..c.offset + c.count].iter_mut().zip(gb) {
                *g += v;
            }
        }
    }
}

/// The outputs of a network's heads, their gradients to fill, and the
/// model's per-crop buffers ([`Workspace::heads`]).
pub type Heads<'a> = (Vec<&'a [f32]>, Vec<&'a mut [f32]>, &'a mut Vec<Vec<f32>>);

/// A small deterministic generator (splitmix64), for initialisation and
/// sampling: the same seed gives the same numbers on every machine.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// From a seed.
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x5DEE_CE66_D1CE_4E5B)
    }
    /// The state, to save and restore.
    pub fn state(&self) -> u64 {
        self.0
    }
    /// From a saved state.
    pub fn from_state(s: u64) -> Rng {
        Rng(s)
    }
    /// 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in `0 .. n`.
    pub fn below(&mut self, n: usize) -> usize {
        (((self.next_u64() >> 32) * n as u64) >> 32) as usize
    }
    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f32 {
        let u1 = self.uniform().max(1e-7);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
    }
}

/// Per-step weights: the merged weights of every conv and their transposes.
#[derive(Clone, Debug, Default)]
pub struct Merged {
    /// `[cout][cin][k][k]` per conv.
    pub weights: Vec<Vec<f32>>,
    transposed: Vec<Vec<f32>>,
}

impl Merged {
    /// For `net` (allocates once).
    pub fn new(net: &Net) -> Merged {
        Merged {
            weights: net.convs.iter().map(|c| vec![0.0; c.merged_len()]).collect(),
            transposed: net.convs.iter().map(|c| vec![0.0; c.merged_len()]).collect(),
        }
    }
    /// Recomputes from the parameters.
    pub fn update(&mut self, net: &Net, params: &[f32]) {
        for (i, c) in net.convs.iter().enumerate() {
            net.merge(params, i, &mut self.weights[i]);
            cgrad::transpose_weights(c.k(), c.cin, c.spec.cout, &self.weights[i], &mut self.transposed[i])
                .expect("merged weights have their layer's shape");
        }
    }
}

/// One crop's buffers for a training forward and backward pass, allocated
/// once for a crop size and reused every step.
#[derive(Debug)]
pub struct Workspace {
    w: usize,
    h: usize,
    /// Every tensor (0: the input).
    acts: Vec<Vec<f32>>,
    /// Their gradients.
    grads: Vec<Vec<f32>>,
    tmp: Vec<f32>,
    tmp2: Vec<f32>,
    scratch: Vec<f32>,
    /// This crop's merged weight gradients and bias gradients, per conv.
    gw: Vec<Vec<f32>>,
    gb: Vec<Vec<f32>>,
    /// A model's own per-crop buffers (targets, filter inputs, ...),
    /// allocated by the model on first use and kept.
    pub aux: Vec<Vec<f32>>,
    /// Whether the backward pass also computes the input's gradient
    /// ([`Workspace::input_grad`]), for a network fed by another one.
    pub want_input_grad: bool,
}

impl Workspace {
    /// For crops of `w x h`.
    pub fn new(net: &Net, w: usize, h: usize) -> Workspace {
        let sizes: Vec<usize> = (0..net.tensors.len())
            .map(|t| {
                let (tw, th) = net.size(t, w, h);
                net.tensors[t].c * tw * th
            })
            .collect();
        let largest = sizes.iter().copied().max().unwrap_or(0);
        let scratch = Self::scratch_len(net, w);
        Workspace {
            w,
            h,
            acts: sizes.iter().map(|&n| vec![0.0; n]).collect(),
            grads: sizes.iter().map(|&n| vec![0.0; n]).collect(),
            tmp: vec![0.0; largest],
            tmp2: vec![0.0; largest],
            scratch: vec![0.0; scratch],
            gw: net.convs.iter().map(|c| vec![0.0; c.merged_len()]).collect(),
            gb: net.convs.iter().map(|c| vec![0.0; c.spec.cout]).collect(),
            aux: Vec::new(),
            want_input_grad: false,
        }
    }

    /// Floats a workspace of `net` for crops of `w x h` holds (every tensor
    /// and its gradient, two temporaries of the largest, the conv scratch),
    /// besides a model's own `aux` buffers and the per-parameter gradients.
    pub fn floats(net: &Net, w: usize, h: usize) -> usize {
        let sizes = (0..net.tensors.len()).map(|t| {
            let (tw, th) = net.size(t, w, h);
            net.tensors[t].c * tw * th
        });
        let (sum, largest) = sizes.fold((0, 0), |(s, l), n| (s + n, l.max(n)));
        let scratch = Self::scratch_len(net, w);
        2 * sum + 2 * largest + scratch
    }

    /// The conv scratch a workspace of `net` holds for crops `w` wide: the
    /// largest any layer's forward or input-gradient pass asks for.
    fn scratch_len(net: &Net, w: usize) -> usize {
        net.convs
            .iter()
            .map(|c| {
                conv::conv2d_scratch_len::<F32>(c.k(), c.cin, c.spec.cout, w).max(cgrad::grad_input_scratch_len(
                    c.k(),
                    c.cin,
                    c.spec.cout,
                    w,
                ))
            })
            .max()
            .unwrap_or(0)
    }

    /// The input's gradient after [`Workspace::backward`] (with
    /// [`Workspace::want_input_grad`]).
    pub fn input_grad(&self) -> &[f32] {
        &self.grads[0]
    }

    /// The crop size.
    pub fn size(&self) -> (usize, usize) {
        (self.w, self.h)
    }

    /// The input tensor, to fill (`cin` planes of `w x h`).
    pub fn input_mut(&mut self) -> &mut [f32] {
        &mut self.acts[0]
    }

    /// The input tensor and the model's `aux` buffer `k`, to fill together.
    pub fn input_and_aux_mut(&mut self, k: usize) -> (&mut [f32], &mut [f32]) {
        (&mut self.acts[0], &mut self.aux[k])
    }

    /// The output tensor after [`Workspace::forward`].
    pub fn output(&self) -> &[f32] {
        self.acts.last().map_or(&[], |v| &v[..])
    }

    /// The output and its gradient at once (the gradient to fill before
    /// [`Workspace::backward`]), and the model's buffers.
    pub fn head_parts(&mut self) -> (&[f32], &mut [f32], &mut Vec<Vec<f32>>) {
        let out = self.acts.last().map_or(&[][..], |v| &v[..]);
        let g = self.grads.last_mut().map_or(&mut [][..], |v| &mut v[..]);
        (out, g, &mut self.aux)
    }

    /// Every output of `net` and its gradient (in output order), and the
    /// model's buffers: for networks with several heads.
    pub fn heads(&mut self, net: &Net) -> Heads<'_> {
        let outs: Vec<&[f32]> = net.outputs.iter().map(|&t| &self.acts[t][..]).collect();
        let mut grads: Vec<(usize, &mut [f32])> = self
            .grads
            .iter_mut()
            .enumerate()
            .filter(|(t, _)| net.outputs.contains(t))
            .map(|(t, g)| (t, &mut g[..]))
            .collect();
        grads.sort_by_key(|(t, _)| net.outputs.iter().position(|o| o == t));
        (outs, grads.into_iter().map(|(_, g)| g).collect(), &mut self.aux)
    }

    /// The output's gradient, to fill before [`Workspace::backward`].
    pub fn output_grad_mut(&mut self) -> &mut [f32] {
        self.grads.last_mut().map_or(&mut [], |v| &mut v[..])
    }

    fn view<'a>(net: &Net, buf: &'a [f32], t: usize, w: usize, h: usize) -> View<'a, f32> {
        let (tw, th) = net.size(t, w, h);
        View::new(buf, net.tensors[t].c, tw, th).expect("tensor buffers have their shape")
    }

    fn view_mut<'a>(net: &Net, buf: &'a mut [f32], t: usize, w: usize, h: usize) -> ViewMut<'a, f32> {
        let (tw, th) = net.size(t, w, h);
        ViewMut::new(buf, net.tensors[t].c, tw, th).expect("tensor buffers have their shape")
    }

    /// The forward pass over this crop (f32, one thread).
    pub fn forward(&mut self, net: &Net, m: &Merged, params: &[f32], isa: Isa) -> Result<()> {
        let (w, h) = (self.w, self.h);
        for node in &net.nodes {
            match *node {
                Node::Conv { conv: i, x, out } => {
                    let c = &net.convs[i];
                    let layer = Conv2d {
                        k: c.k(),
                        cin: c.cin,
                        cout: c.spec.cout,
                        weights: &m.weights[i],
                        bias: net.bias(params, i),
                        act: c.spec.act,
                        weight_frac: 0,
                    };
                    let (src, dst) = two(&mut self.acts, x, out);
                    let len = conv::conv2d_scratch_len::<F32>(c.k(), c.cin, c.spec.cout, w);
                    conv::conv2d::<F32>(
                        isa,
                        &layer,
                        &Self::view(net, src, x, w, h),
                        &mut Self::view_mut(net, dst, out, w, h),
                        0,
                        &mut self.scratch[..len],
                    )?;
                }
                Node::Pool { max, x, out } => {
                    let (src, dst) = two(&mut self.acts, x, out);
                    let op = if max { Reduce::Max } else { Reduce::Mean };
                    pool::reduce2x2::<F32>(
                        isa,
                        op,
                        &Self::view(net, src, x, w, h),
                        &mut Self::view_mut(net, dst, out, w, h),
                        0,
                    )?;
                }
                Node::Up { bilinear, x, like, out } => {
                    let (src, dst) = two(&mut self.acts, x, out);
                    let (_, fh) = net.size(like, w, h);
                    let sv = Self::view(net, src, x, w, h);
                    let mut dv = Self::view_mut(net, dst, out, w, h);
                    if bilinear {
                        pgrad::upsample_bilinear2x(isa, &sv, &mut dv, 0, fh)?;
                    } else {
                        pool::upsample_nearest2x::<F32>(isa, &sv, &mut dv, 0, fh)?;
                    }
                }
                Node::Concat { a, b, out } => {
                    let (na, nb) = (self.acts[a].len(), self.acts[b].len());
                    let (lo, hi) = self.acts.split_at_mut(out);
                    hi[0][..na].copy_from_slice(&lo[a]);
                    hi[0][na..na + nb].copy_from_slice(&lo[b]);
                }
            }
        }
        Ok(())
    }

    /// The backward pass from the output's gradient: this crop's weight
    /// gradients into its own buffers (read by [`Trainer::step`]).
    pub fn backward(&mut self, net: &Net, m: &Merged, isa: Isa) -> Result<()> {
        let (w, h) = (self.w, self.h);
        for (t, g) in self.grads.iter_mut().enumerate() {
            if !net.outputs.contains(&t) {
                g.fill(0.0);
            }
        }
        for (gw, gb) in self.gw.iter_mut().zip(&mut self.gb) {
            gw.fill(0.0);
            gb.fill(0.0);
        }
        for node in net.nodes.iter().rev() {
            match *node {
                Node::Conv { conv: i, x, out } => {
                    let c = &net.convs[i];
                    let n = self.acts[out].len();
                    // dz = dy * act'(z), read from the output.
                    let dz = &mut self.tmp[..n];
                    cgrad::activation_grad(
                        c.spec.act,
                        &Self::view(net, &self.acts[out], out, w, h),
                        &Self::view(net, &self.grads[out], out, w, h),
                        &mut Self::view_mut(net, dz, out, w, h),
                    )?;
                    let dzv = Self::view(net, dz, out, w, h);
                    let (_, th) = net.size(out, w, h);
                    let gb = c.spec.bias.then_some(&mut self.gb[i][..]);
                    cgrad::grad_weights(
                        isa,
                        c.k(),
                        &Self::view(net, &self.acts[x], x, w, h),
                        &dzv,
                        0,
                        th,
                        &mut self.gw[i],
                        gb,
                    )?;
                    if x != 0 || self.want_input_grad {
                        // The core writes the input gradient: straight into the
                        // tensor's gradient when this conv is its only consumer,
                        // else into a buffer that is then added (a saved tensor
                        // also gets its Concat's share).
                        let len = cgrad::grad_input_scratch_len(c.k(), c.cin, c.spec.cout, w);
                        let (gx, _) = two(&mut self.grads, x, out);
                        let sole = net.consumers[x] == 1;
                        let nx = gx.len();
                        let dx: &mut [f32] = if sole { gx } else { &mut self.tmp2[..nx] };
                        cgrad::grad_input(
                            isa,
                            c.k(),
                            c.cin,
                            c.spec.cout,
                            &m.transposed[i],
                            &dzv,
                            &mut Self::view_mut(net, dx, x, w, h),
                            0,
                            &mut self.scratch[..len],
                        )?;
                        if !sole {
                            add(&mut self.grads[x], &self.tmp2[..nx]);
                        }
                    }
                }
                Node::Pool { max, x, out } => {
                    let n = self.acts[x].len();
                    let (gx, gy) = two(&mut self.grads, x, out);
                    let tmp = &mut self.tmp[..n];
                    let (_, xh) = net.size(x, w, h);
                    let gyv = Self::view(net, gy, out, w, h);
                    if max {
                        pgrad::max_pool2x2_grad(
                            isa,
                            &Self::view(net, &self.acts[x], x, w, h),
                            &gyv,
                            &mut Self::view_mut(net, tmp, x, w, h),
                            0,
                        )?;
                    } else {
                        pgrad::avg_pool2x2_grad(isa, &gyv, &mut Self::view_mut(net, tmp, x, w, h), 0, xh)?;
                    }
                    add(gx, tmp);
                }
                Node::Up { bilinear, x, out, .. } => {
                    let n = self.acts[x].len();
                    let (gx, gy) = two(&mut self.grads, x, out);
                    let tmp = &mut self.tmp[..n];
                    let gyv = Self::view(net, gy, out, w, h);
                    let mut tv = Self::view_mut(net, tmp, x, w, h);
                    if bilinear {
                        pgrad::upsample_bilinear2x_grad(isa, &gyv, &mut tv, 0)?;
                    } else {
                        pgrad::upsample_nearest2x_grad(isa, &gyv, &mut tv, 0)?;
                    }
                    add(gx, tmp);
                }
                Node::Concat { a, b, out } => {
                    let na = self.acts[a].len();
                    let (lo, hi) = self.grads.split_at_mut(out);
                    let g = &hi[0];
                    add(&mut lo[a], &g[..na]);
                    add(&mut lo[b], &g[na..]);
                }
            }
        }
        Ok(())
    }
}

fn add(dst: &mut [f32], src: &[f32]) {
    for (d, s) in dst.iter_mut().zip(src) {
        *d += s;
    }
}

/// Two distinct elements of a vector, the first shared, the second exclusive.
fn two<T>(v: &mut [T], a: usize, b: usize) -> (&mut T, &mut T) {
    assert!(a != b, "two distinct tensors");
    if a < b {
        let (lo, hi) = v.split_at_mut(b);
        (&mut lo[a], &mut hi[0])
    } else {
        let (lo, hi) = v.split_at_mut(a);
        (&mut hi[0], &mut lo[b])
    }
}

/// What one training step measured.
#[derive(Clone, Debug)]
pub struct StepStats {
    /// The batch's mean loss.
    pub loss: f32,
    /// The gradient's L2 norm before clipping.
    pub grad_norm: f32,
    /// The crops whose loss was not finite (in crop order); a step with any,
    /// or with a gradient that is not finite, leaves the parameters and
    /// Adam's state as they were.
    pub bad_crops: Vec<usize>,
}

impl StepStats {
    /// Whether the step changed nothing (a crop's loss or the gradient not
    /// finite).
    pub fn skipped(&self) -> bool {
        !self.bad_crops.is_empty() || !self.grad_norm.is_finite()
    }
}

/// What a model's head sees of the networks being trained: to run the
/// other networks' passes itself (the first network's passes are the
/// trainer's).
pub struct Nets<'a> {
    nets: &'a [Net],
    merged: &'a [Merged],
    params: &'a [f32],
    offsets: &'a [usize],
    /// The instruction set.
    pub isa: Isa,
}

impl Nets<'_> {
    /// Network `k`.
    pub fn net(&self, k: usize) -> &Net {
        &self.nets[k]
    }
    /// Network `k`'s forward pass on its workspace.
    pub fn forward(&self, k: usize, ws: &mut Workspace) -> Result<()> {
        ws.forward(&self.nets[k], &self.merged[k], &self.params[self.offsets[k]..self.offsets[k + 1]], self.isa)
    }
    /// Network `k`'s backward pass on its workspace.
    pub fn backward(&self, k: usize, ws: &mut Workspace) -> Result<()> {
        ws.backward(&self.nets[k], &self.merged[k], self.isa)
    }
}

/// Fills crop `i`'s inputs (every network's workspace of the crop, and the
/// model's per-crop buffers).
pub type Fill<'a> = dyn Fn(usize, &mut [Workspace]) -> Result<()> + Sync + 'a;
/// Computes crop `i`'s loss after the first network's forward pass: runs
/// any other network's passes, and writes the first network's output
/// gradients (of the batch mean).
pub type Head<'a> = dyn Fn(usize, &Nets<'_>, &mut [Workspace]) -> Result<f32> + Sync + 'a;

/// Networks being trained together: their parameters (one flat vector,
/// network after network), Adam, and per crop of the batch one workspace
/// per network (allocated once).
#[derive(Debug)]
pub struct Trainer {
    /// The networks.
    pub nets: Vec<Net>,
    /// Their parameters, one after the other.
    pub params: Vec<f32>,
    /// Where each network's parameters start (and the total at the end).
    pub offsets: Vec<usize>,
    /// Adam's state.
    pub adam: adam::Adam,
    /// Largest gradient norm (0: no clipping).
    pub clip: f32,
    merged: Vec<Merged>,
    workspaces: Vec<Vec<Workspace>>,
    grad: Vec<f32>,
    gm: Vec<Vec<Vec<f32>>>,
    gb: Vec<Vec<Vec<f32>>>,
}

impl Trainer {
    /// A trainer of one network for `batch` crops of `w x h`.
    pub fn new(net: Net, params: Vec<f32>, batch: usize, w: usize, h: usize, lr: f32, clip: f32) -> Result<Trainer> {
        Trainer::with_nets(vec![(net, params, (w, h))], batch, lr, clip)
    }

    /// A trainer of several networks, each with its parameters and its
    /// workspace size, for `batch` crops; an error when a network's
    /// parameters are not its count, a crop is empty, or the batch is 0.
    pub fn with_nets(nets: Vec<(Net, Vec<f32>, (usize, usize))>, batch: usize, lr: f32, clip: f32) -> Result<Trainer> {
        let mut offsets = vec![0];
        let mut params = Vec::new();
        if batch == 0 || nets.is_empty() {
            return Err(HostError::Usage("trainer: a batch of at least one crop and one network".into()));
        }
        for (n, p, (w, h)) in &nets {
            if n.params != p.len() {
                return Err(HostError::Usage(format!(
                    "trainer: {} parameters given for a network of {}",
                    p.len(),
                    n.params
                )));
            }
            if *w == 0 || *h == 0 {
                return Err(HostError::Usage(format!("trainer: an empty {w}x{h} crop")));
            }
            params.extend_from_slice(p);
            offsets.push(params.len());
        }
        let workspaces =
            (0..batch).map(|_| nets.iter().map(|(n, _, (w, h))| Workspace::new(n, *w, *h)).collect()).collect();
        let nets: Vec<Net> = nets.into_iter().map(|(n, _, _)| n).collect();
        let mut merged: Vec<Merged> = nets.iter().map(Merged::new).collect();
        for (k, n) in nets.iter().enumerate() {
            merged[k].update(n, &params[offsets[k]..offsets[k + 1]]);
        }
        let total = params.len();
        Ok(Trainer {
            gm: nets.iter().map(|n| n.convs.iter().map(|c| vec![0.0; c.merged_len()]).collect()).collect(),
            gb: nets.iter().map(|n| n.convs.iter().map(|c| vec![0.0; c.spec.cout]).collect()).collect(),
            adam: adam::Adam::new(total, lr),
            clip,
            merged,
            workspaces,
            grad: vec![0.0; total],
            params,
            offsets,
            nets,
        })
    }

    /// The first network.
    pub fn net(&self) -> &Net {
        &self.nets[0]
    }

    /// Network `k`'s parameters.
    pub fn net_params(&self, k: usize) -> &[f32] {
        &self.params[self.offsets[k]..self.offsets[k + 1]]
    }

    /// The merged weights the next forward pass of network `k` uses.
    pub fn merged(&self, k: usize) -> &Merged {
        &self.merged[k]
    }

    /// Sets the parameters (all networks', flat) and the merged weights.
    pub fn set_params(&mut self, params: Vec<f32>) -> Result<()> {
        if params.len() != self.params.len() {
            return Err(HostError::Usage(format!(
                "trainer: {} parameters given for networks of {}",
                params.len(),
                self.params.len()
            )));
        }
        self.params = params;
        for (k, n) in self.nets.iter().enumerate() {
            self.merged[k].update(n, &self.params[self.offsets[k]..self.offsets[k + 1]]);
        }
        Ok(())
    }

    /// The crops' workspaces (per crop, one per network).
    pub fn workspaces(&mut self) -> &mut [Vec<Workspace>] {
        &mut self.workspaces
    }

    /// The gradient of the last step (before clipping), one value per parameter.
    pub fn grad(&self) -> &[f32] {
        &self.grad
    }

    /// Forward and backward passes of every crop (one crop per task on the
    /// pool's threads), gradients summed in crop order, then one Adam step.
    /// With `update` false the gradient is computed and left in
    /// [`Trainer::grad`], the parameters unchanged.
    pub fn step(&mut self, pool: &Pool, isa: Isa, fill: &Fill<'_>, head: &Head<'_>, update: bool) -> Result<StepStats> {
        let nets = Nets { nets: &self.nets, merged: &self.merged, params: &self.params, offsets: &self.offsets, isa };
        let losses: Vec<Result<f32>> = pool.install(|| {
            self.workspaces
                .par_iter_mut()
                .enumerate()
                .map(|(i, wss)| {
                    fill(i, wss)?;
                    nets.forward(0, &mut wss[0])?;
                    let loss = head(i, &nets, wss)?;
                    nets.backward(0, &mut wss[0])?;
                    Ok(loss)
                })
                .collect()
        });
        let mut loss = 0.0f64;
        let mut bad_crops = Vec::new();
        for (i, l) in losses.into_iter().enumerate() {
            let l = l?;
            if l.is_finite() {
                loss += l as f64;
            } else {
                bad_crops.push(i);
            }
        }
        // Sum the crops' gradients in crop order (the result does not depend
        // on which thread ran which crop), then onto the branch parameters.
        self.grad.fill(0.0);
        for (k, net) in self.nets.iter().enumerate() {
            let g = &mut self.grad[self.offsets[k]..self.offsets[k + 1]];
            for (i, c) in net.convs.iter().enumerate() {
                let (gm, gb) = (&mut self.gm[k][i], &mut self.gb[k][i]);
                gm.fill(0.0);
                gb.fill(0.0);
                for wss in &self.workspaces {
                    add(gm, &wss[k].gw[i]);
                    add(gb, &wss[k].gb[i]);
                }
                let _ = c;
                // `unmerge_grad` indexes by the network's own offsets.
                net.unmerge_grad(i, gm, gb, g);
            }
        }
        let grad_norm = adam::clip_norm(&mut self.grad, if update { self.clip } else { 0.0 });
        if update && bad_crops.is_empty() && grad_norm.is_finite() {
            self.adam.step(&mut self.params, &self.grad);
            for (k, n) in self.nets.iter().enumerate() {
                self.merged[k].update(n, &self.params[self.offsets[k]..self.offsets[k + 1]]);
            }
        }
        let good = (self.workspaces.len() - bad_crops.len()).max(1);
        Ok(StepStats { loss: (loss / good as f64) as f32, grad_norm, bad_crops })
    }
}

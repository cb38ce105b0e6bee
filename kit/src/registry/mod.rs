//! The operator registry: one description per core operator, which the
//! property tests, the criterion benches, the fuzz target and `mcdenoise
//! precision` all iterate.
//!
//! An [`Op`] says which inputs it synthesises (fields of [`Inputs`], their
//! channels, whether at full or half resolution, and how fixed point stores
//! them), how to run it in a precision and instruction set (a kernel over
//! bands of output rows), its f64 oracle ([`crate::oracle`]) and its
//! tolerance per precision. [`Op::prepare`] stores the inputs in the
//! precision (optionally with row and plane padding filled with poison, to
//! catch reads and writes outside a view) and returns a [`Prepared`] run that
//! can be timed, decoded and checked.
//!
//! Adding an operator (or its backward pass) is one entry in [`ops`] and a
//! kernel function; every consumer picks it up.
//!
//! This file holds the framework; each operator family (the per-pixel
//! kernels and softmax, pooling, convolutions, tone mapping, temporal
//! accumulation, à-trous, the backward passes, the noise estimators,
//! cross-regression) has a file of its own with its kernels, oracle
//! adaptors, tolerances and entries, and [`ops`] concatenates their lists.

use mcdenoise_core::{fixed, F16Arith, Fixed, Isa, Result as CoreResult, View, ViewMut, F16, F32};

use mcdenoise::error::Result;
use mcdenoise::io::frame::{Buffer, Frame};
use mcdenoise::runtime::par::{Pool, Scratch};
use mcdenoise::runtime::precision::{frac_for_max, HostPrecision, Kind, PrecisionKind};

mod atrous;
mod conv;
mod cross;
mod grad;
mod noise;
mod pool;
mod temporal;
mod tonemap;
mod unfold;

pub use tonemap::DEMOD_EPS;

/// The f32 planes every operator draws its inputs from.
#[derive(Clone, Debug)]
pub struct Inputs {
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
    fields: [Vec<f32>; FIELDS],
}

/// What an input plane set holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(usize)]
pub enum Field {
    /// Radiance, 3 planes, HDR-ish `[0, 4)` (or a frame's colour).
    Radiance,
    /// Albedo, 3 planes, `[0.05, 1)`.
    Albedo,
    /// Normal, 3 planes, roughly unit, facing +z.
    Normal,
    /// World position, 3 planes, `[-1, 1)`.
    Position,
    /// A normalised 7x7 kernel map, 49 planes.
    Kernel,
    /// Importance logits, 6 planes, `[-8, 8)`.
    Logits,
    /// Fusion logits, 6 planes, `[-3, 3)`.
    Fusion,
    /// A 14-channel feature map, `[-1, 1)`.
    Features,
    /// 1x1 conv weights 14 -> 14.
    Weights1,
    /// 3x3 conv weights 14 -> 14.
    Weights3,
    /// 5x5 conv weights 14 -> 14.
    Weights5,
    /// 14 biases.
    Bias,
    /// A half-resolution image, 3 planes, `[0, 4)`.
    Coarse,
    /// A blend weight, 1 plane, `[0, 1)`.
    Alpha,
    /// Motion in pixels, 2 planes, `[-3, 3)`.
    Motion,
    /// The previous accumulated colour, 3 planes.
    Previous,
    /// The previous history length, 1 plane, `[0, 8)`.
    History,
    /// A noise variance, 1 plane, `[0.001, 0.02)`.
    Noise,
    /// An output's gradient (for the backward passes), 14 planes, `[-1, 1)`.
    Grad,
    /// Importance logits as wide as a trained network's maps, 6 planes,
    /// `[-50, 50)` (rendered WSKP maps span about -61..47).
    WideLogits,
    /// Motion in pixels whose fractional part stays in `[0.2, 0.8]`, 2
    /// planes: no bilinear weight near 0 and no `floor` near an integer, so
    /// the accepted tap set is the same in every precision.
    SafeMotion,
    /// Block-constant world positions (4x4 blocks, neighbours 0.25 apart),
    /// 3 planes: two pixels' positions agree exactly or differ by >= 0.25.
    Blocks,
    /// The previous frame's world position: [`Field::Position`] moved by
    /// [`PREV_SHIFT`] pixels, and 5 units away where the source pixel is out
    /// of the image; 3 planes.
    PrevPosition,
    /// The previous frame's normal: [`Field::Normal`] negated on one pixel in
    /// five; 3 planes.
    PrevNormal,
}

const FIELDS: usize = Field::PrevNormal as usize + 1;

/// Where a pixel's point was in the previous frame, relative to it:
/// `PrevPosition(x + dx, y + dy) = Position(x, y)` (inside the search radius).
pub const PREV_SHIFT: (usize, usize) = (1, 2);

fn rng(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// A smooth-ish random field in `[lo, hi)`: a coarse grid bilinearly
/// interpolated plus fine noise (logits and kernels of a trained network are
/// not white noise).
pub fn field(c: usize, w: usize, h: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut r = rng(seed);
    let (gw, gh) = (w / 16 + 2, h / 16 + 2);
    let mut out = vec![0.0; c * w * h];
    for ch in 0..c {
        let g: Vec<f32> = (0..gw * gh).map(|_| r()).collect();
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 / 16.0, y as f32 / 16.0);
                let (x0, y0) = (fx as usize, fy as usize);
                let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                let v = g[y0 * gw + x0] * (1.0 - tx) * (1.0 - ty)
                    + g[y0 * gw + x0 + 1] * tx * (1.0 - ty)
                    + g[(y0 + 1) * gw + x0] * (1.0 - tx) * ty
                    + g[(y0 + 1) * gw + x0 + 1] * tx * ty;
                out[ch * w * h + y * w + x] = lo + (hi - lo) * (0.8 * v + 0.2 * r());
            }
        }
    }
    out
}

fn tile(f: &Frame, b: Buffer, w: usize, h: usize) -> Option<Vec<f32>> {
    let d = f.get(b)?;
    let (sw, sh) = (f.width, f.height);
    let ch = b.channels();
    let mut out = vec![0.0; ch * w * h];
    for c in 0..ch {
        for y in 0..h {
            for x in 0..w {
                out[c * w * h + y * w + x] = d[c * sw * sh + (y % sh) * sw + (x % sw)];
            }
        }
    }
    Some(out)
}

impl Inputs {
    /// Synthetic inputs of `w x h` from `seed`.
    pub fn synth(w: usize, h: usize, seed: u64) -> Inputs {
        Inputs::new(w, h, seed, None)
    }

    /// Inputs whose radiance, albedo, normal and position come from a
    /// rendered frame (tiled to the size); the rest synthetic.
    pub fn from_frame(w: usize, h: usize, frame: &Frame) -> Inputs {
        Inputs::new(w, h, 0, Some(frame))
    }

    fn new(w: usize, h: usize, seed: u64, frame: Option<&Frame>) -> Inputs {
        let n = w * h;
        let s = |k: u64| seed.wrapping_mul(131).wrapping_add(k);
        let from = |b: Buffer| frame.and_then(|f| tile(f, b, w, h));
        let rad = from(Buffer::Color).unwrap_or_else(|| field(3, w, h, 0.0, 4.0, s(1)));
        let alb = from(Buffer::Albedo).unwrap_or_else(|| field(3, w, h, 0.05, 1.0, s(2)));
        let normal = from(Buffer::Normal).unwrap_or_else(|| {
            let mut v = field(3, w, h, -0.3, 0.3, s(3));
            v[2 * n..].iter_mut().for_each(|z| *z += 0.9);
            v
        });
        let pos = from(Buffer::Position).unwrap_or_else(|| field(3, w, h, -1.0, 1.0, s(4)));
        let mut kern = field(49, w, h, 0.0, 1.0, s(5));
        for p in 0..n {
            let t: f32 = (0..49).map(|j| kern[j * n + p]).sum();
            (0..49).for_each(|j| kern[j * n + p] /= t);
        }
        let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
        let motion = field(2, w, h, -3.0, 3.0, s(14));
        let mut blocks = vec![0.0; 3 * n];
        let mut prev_pos = vec![0.0; 3 * n];
        let mut prev_normal = normal.clone();
        let (dx, dy) = PREV_SHIFT;
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                let (bx, by) = ((x / 4) as f32, (y / 4) as f32);
                blocks[p] = bx * 0.25 - 1.0;
                blocks[n + p] = by * 0.25 - 1.0;
                blocks[2 * n + p] = 0.5;
                let src = (x >= dx && y >= dy).then(|| (y - dy) * w + (x - dx));
                for c in 0..3 {
                    prev_pos[c * n + p] = src.map_or(pos[c * n + p] + 5.0, |q| pos[c * n + q]);
                }
                if (x * 7 + y * 3) % 5 == 0 {
                    (0..3).for_each(|c| prev_normal[c * n + p] = -prev_normal[c * n + p]);
                }
            }
        }
        let fields = [
            rad,
            alb,
            normal,
            pos,
            kern,
            field(6, w, h, -8.0, 8.0, s(10)),
            field(6, w, h, -3.0, 3.0, s(11)),
            field(14, w, h, -1.0, 1.0, s(6)),
            field(14 * 14, 1, 1, -0.25, 0.25, s(18)),
            field(14 * 14 * 9, 1, 1, -0.08, 0.08, s(7)),
            field(14 * 14 * 25, 1, 1, -0.03, 0.03, s(8)),
            field(14, 1, 1, -0.1, 0.1, s(9)),
            field(3, wc, hc, 0.0, 4.0, s(12)),
            field(1, w, h, 0.0, 1.0, s(13)),
            motion.clone(),
            field(3, w, h, 0.0, 4.0, s(15)),
            field(1, w, h, 0.0, 8.0, s(16)),
            field(1, w, h, 0.001, 0.02, s(17)),
            field(14, w, h, -1.0, 1.0, s(19)),
            field(6, w, h, -50.0, 50.0, s(20)),
            motion.iter().map(|&m| m.floor() + 0.2 + 0.6 * (m - m.floor())).collect(),
            blocks,
            prev_pos,
            prev_normal,
        ];
        Inputs { w, h, fields }
    }

    /// The planes of a field.
    pub fn get(&self, f: Field) -> &[f32] {
        &self.fields[f as usize]
    }

    /// Replaces a field's values (same length), e.g. to push it to an extreme.
    pub fn set(&mut self, f: Field, v: Vec<f32>) {
        assert_eq!(v.len(), self.fields[f as usize].len(), "field {f:?}: wrong length");
        self.fields[f as usize] = v;
    }

    /// A field as f64 (the oracle's input).
    pub fn f64(&self, f: Field) -> Vec<f64> {
        self.get(f).iter().map(|&v| v as f64).collect()
    }
}

/// How the stored planes are laid out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Layout {
    /// Extra elements after each row and extra rows after each plane, filled
    /// with poison (NaN, or `i16::MIN` in fixed point): 0 for packed planes.
    pub pad: usize,
}

/// A planar tensor in a storage type, possibly strided.
#[derive(Clone, Debug)]
pub struct Tensor<T> {
    /// Planes.
    pub c: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
    /// Elements between rows.
    pub rs: usize,
    /// Elements between planes.
    pub ps: usize,
    /// The values (with padding).
    pub data: Vec<T>,
    /// Fixed-point fractional bits.
    pub frac: i8,
}

/// The poison a padding element holds.
pub fn poison<P: HostPrecision>() -> P::Store {
    let mut v = [P::Store::default()];
    if P::FIXED_POINT {
        // i16::MIN: never produced by the saturating kernels (they clamp to ±32767).
        *bytemuck::cast_mut::<_, [u8; 2]>(&mut v[0]) = i16::MIN.to_ne_bytes();
    } else {
        P::encode(&[f32::NAN], &mut v, 0);
    }
    v[0]
}

impl<T: bytemuck::Pod + Default> Tensor<T> {
    /// Filled with `fill` (the padding too).
    pub fn filled(c: usize, w: usize, h: usize, layout: Layout, fill: T) -> Self {
        let rs = w + layout.pad;
        let ps = rs * (h + layout.pad);
        Tensor { c, w, h, rs, ps, data: vec![fill; c * ps], frac: 0 }
    }

    /// A shared view.
    pub fn view(&self) -> View<'_, T> {
        View::with_strides(&self.data, self.c, self.w, self.h, self.rs, self.ps)
            .expect("a tensor has its shape")
            .with_frac(self.frac)
    }

    /// An exclusive view.
    pub fn view_mut(&mut self) -> ViewMut<'_, T> {
        ViewMut::with_strides(&mut self.data, self.c, self.w, self.h, self.rs, self.ps)
            .expect("a tensor has its shape")
            .with_frac(self.frac)
    }

    fn is_padding(&self, i: usize) -> bool {
        let (p, q) = (i / self.ps.max(1), i % self.ps.max(1));
        p >= self.c || q / self.rs.max(1) >= self.h || q % self.rs.max(1) >= self.w
    }

    /// Whether every padding element still has the bits of `poison`.
    pub fn padding_intact(&self, poison: T) -> bool {
        let want = bytemuck::bytes_of(&poison);
        self.data.iter().enumerate().all(|(i, v)| !self.is_padding(i) || bytemuck::bytes_of(v) == want)
    }

    /// Stores packed f32 planes in precision `P` with format `frac`, padding poisoned.
    pub fn encode<P: HostPrecision<Store = T>>(
        c: usize,
        w: usize,
        h: usize,
        src: &[f32],
        frac: i8,
        layout: Layout,
    ) -> Self {
        let mut t = Tensor::filled(c, w, h, layout, poison::<P>());
        t.frac = frac;
        for ch in 0..c {
            for y in 0..h {
                let at = ch * t.ps + y * t.rs;
                P::encode(&src[(ch * h + y) * w..(ch * h + y + 1) * w], &mut t.data[at..at + w], frac);
            }
        }
        t
    }

    /// The values as packed f32 planes.
    pub fn decode<P: HostPrecision<Store = T>>(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.c * self.w * self.h];
        for ch in 0..self.c {
            for y in 0..self.h {
                let at = ch * self.ps + y * self.rs;
                P::decode(
                    &self.data[at..at + self.w],
                    &mut out[(ch * self.h + y) * self.w..(ch * self.h + y + 1) * self.w],
                    self.frac,
                );
            }
        }
        out
    }
}

/// How an input is stored in fixed point.
#[derive(Clone, Copy, Debug)]
pub enum Store {
    /// By the host's policy for the kind (as a pipeline stores it).
    As(Kind),
    /// Logits: [`fixed::LOGIT_FRAC`].
    Logit,
}

/// One input of an operator.
#[derive(Clone, Copy, Debug)]
pub struct In {
    /// Where its values come from.
    pub field: Field,
    /// Planes taken from the field (its first ones).
    pub c: usize,
    /// At half resolution (`ceil(w/2) x ceil(h/2)`).
    pub half: bool,
    /// Fixed-point storage.
    pub store: Store,
}

const fn full(field: Field, c: usize, kind: Kind) -> In {
    In { field, c, half: false, store: Store::As(kind) }
}

/// Allowed error of a precision against the oracle: `|x - r| <= peak * P + rel * |r|`,
/// `P` the largest `|r|` of the output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tol {
    /// In units of the output's peak.
    pub peak: f64,
    /// Relative to each value.
    pub rel: f64,
}

const fn tol(peak: f64, rel: f64) -> Tol {
    Tol { peak, rel }
}

/// The views a kernel reads.
pub struct Args<'a, T> {
    /// The instruction set the kernel is called with.
    pub isa: Isa,
    /// The full-resolution width and height of the run.
    pub size: (usize, usize),
    /// The inputs, in the order of [`Op::inputs`].
    pub ins: Vec<View<'a, T>>,
    /// Flat parameters (weights, biases), stored in the precision.
    pub params: Vec<&'a [T]>,
    /// Fixed point: the weights' fractional bits.
    pub weight_frac: i8,
}

type Kernel<T> = fn(&Args<'_, T>, &mut ViewMut<'_, T>, usize, &mut [f32]) -> CoreResult<()>;
type Kernel2<T> = fn(&Args<'_, T>, &mut ViewMut<'_, T>, &mut ViewMut<'_, T>, usize, &mut [f32]) -> CoreResult<()>;

/// A kernel over bands of output rows, for one precision.
pub enum Run<T> {
    /// One output.
    One(Kernel<T>),
    /// Two outputs of the same height (the second of [`Op::out2`] planes).
    Two(Kernel2<T>),
}

/// The per-precision pieces of an operator.
pub struct Per<P: HostPrecision> {
    /// The kernel.
    pub run: Run<P::Store>,
    /// Scratch words per band for an output `width` wide.
    pub scratch: fn(usize) -> usize,
}

/// What [`Op::prepare`] needs besides the inputs.
#[derive(Clone, Copy, Debug)]
pub struct Config {
    /// Instruction set.
    pub isa: Isa,
    /// Storage layout.
    pub layout: Layout,
    /// Fixed point: the output's fractional bits.
    pub out_frac: i8,
}

/// A run, prepared: the inputs stored, the output allocated and poisoned.
pub trait Prepared {
    /// Runs the operator on `pool`'s threads.
    fn run(&mut self, pool: &Pool) -> Result<()>;
    /// The output, decoded to packed f32 planes.
    fn output(&self) -> Vec<f32>;
    /// Whether the output's padding (and the second output's) is untouched.
    fn padding_intact(&self) -> bool;
}

struct Job<P: HostPrecision> {
    isa: Isa,
    size: (usize, usize),
    ins: Vec<Tensor<P::Store>>,
    params: Vec<Vec<P::Store>>,
    weight_frac: i8,
    out: Tensor<P::Store>,
    out2: Option<Tensor<P::Store>>,
    align: usize,
    per: Per<P>,
    scratch: Scratch,
}

impl<P: HostPrecision> Prepared for Job<P> {
    fn run(&mut self, pool: &Pool) -> Result<()> {
        let args = Args {
            isa: self.isa,
            size: self.size,
            ins: self.ins.iter().map(Tensor::view).collect(),
            params: self.params.iter().map(|p| &p[..]).collect(),
            weight_frac: self.weight_frac,
        };
        let len = (self.per.scratch)(self.out.w);
        match (&self.per.run, self.out2.as_mut()) {
            (Run::One(k), None) => {
                pool.bands(self.out.view_mut(), self.align, &mut self.scratch, len, |b, y0, s| k(&args, b, y0, s))?
            }
            (Run::Two(k), Some(o2)) => {
                pool.bands2(self.out.view_mut(), o2.view_mut(), self.align, &mut self.scratch, len, |a, b, y0, s| {
                    k(&args, a, b, y0, s)
                })?
            }
            _ => unreachable!("an operator's kernel and its outputs agree"),
        }
        Ok(())
    }
    fn output(&self) -> Vec<f32> {
        self.out.decode::<P>()
    }
    fn padding_intact(&self) -> bool {
        let p = poison::<P>();
        self.out.padding_intact(p) && self.out2.as_ref().is_none_or(|o| o.padding_intact(p))
    }
}

/// One operator.
pub struct Op {
    /// Name (as `mcdenoise precision --only` takes it).
    pub name: &'static str,
    /// One line on what it computes.
    pub about: &'static str,
    /// Inputs.
    pub inputs: Vec<In>,
    /// Flat parameters (conv weights, biases), from these fields.
    pub params: Vec<Field>,
    /// Output planes and whether the output is at half resolution.
    pub out: (usize, bool),
    /// A fixed output shape `(planes, width, height)` instead (e.g. a weight gradient).
    pub out_fixed: Option<(usize, usize, usize)>,
    /// Planes of a second output (full resolution), if any.
    pub out2: Option<(usize, i8)>,
    /// Band boundaries on multiples of this many rows.
    pub align: usize,
    /// Precisions it runs in.
    pub precisions: &'static [PrecisionKind],
    /// Tolerance per precision, in the order of [`PrecisionKind::ALL`].
    pub tol: [Tol; 4],
    /// Fixed point: the SIMD paths equal scalar bit for bit.
    pub fixed_exact: bool,
    /// Fixed point: the output's format from the oracle's peak `|r|`.
    pub out_frac: fn(f32) -> i8,
    /// The f64 oracle.
    pub oracle: fn(&Inputs, &Pool) -> Vec<f64>,
    prep: Prep,
}

struct Prep {
    f32: fn() -> Per<F32>,
    f16: Option<fn() -> Per<F16>>,
    f16a: Option<fn() -> Per<F16Arith>>,
    fixed: Option<fn() -> Per<Fixed>>,
}

macro_rules! per {
    ($run:ident, $kernel:ident, $scratch:ident) => {
        Prep {
            f32: || Per { run: Run::$run($kernel::<F32>), scratch: $scratch::<F32> },
            f16: Some(|| Per { run: Run::$run($kernel::<F16>), scratch: $scratch::<F16> }),
            f16a: Some(|| Per { run: Run::$run($kernel::<F16Arith>), scratch: $scratch::<F16Arith> }),
            fixed: Some(|| Per { run: Run::$run($kernel::<Fixed>), scratch: $scratch::<Fixed> }),
        }
    };
}

/// An operator that runs in f32 only.
macro_rules! per_f32 {
    ($run:ident, $kernel:ident) => {
        Prep { f32: || Per { run: Run::$run($kernel), scratch: |_| 0 }, f16: None, f16a: None, fixed: None }
    };
    ($run:ident, $kernel:ident, $scratch:ident) => {
        Prep { f32: || Per { run: Run::$run($kernel), scratch: $scratch }, f16: None, f16a: None, fixed: None }
    };
}

// The entry macros by path, for the family files (`use super::per`).
use {per, per_f32};

impl Op {
    /// The tolerance of a precision.
    pub fn tolerance(&self, p: PrecisionKind) -> Tol {
        self.tol[PrecisionKind::ALL.iter().position(|&q| q == p).expect("a precision")]
    }

    /// Output shape `(planes, width, height)` for inputs of `w x h`.
    pub fn out_shape(&self, w: usize, h: usize) -> (usize, usize, usize) {
        if let Some(s) = self.out_fixed {
            s
        } else if self.out.1 {
            (self.out.0, w.div_ceil(2), h.div_ceil(2))
        } else {
            (self.out.0, w, h)
        }
    }

    /// The fixed-point output format for an oracle output.
    pub fn fixed_frac(&self, want: &[f64]) -> i8 {
        let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs())) as f32;
        (self.out_frac)(peak)
    }

    /// Stores the inputs in precision `p` and allocates the output; an error
    /// when the operator does not run in `p` (not one of [`Op::precisions`]).
    pub fn prepare(&self, p: PrecisionKind, cfg: Config, i: &Inputs) -> Result<Box<dyn Prepared>> {
        let missing = || mcdenoise::HostError::Usage(format!("operator {} does not run in {}", self.name, p.name()));
        Ok(match p {
            PrecisionKind::F32 => Box::new(self.job::<F32>((self.prep.f32)(), cfg, i)),
            PrecisionKind::F16 => Box::new(self.job::<F16>((self.prep.f16.ok_or_else(missing)?)(), cfg, i)),
            PrecisionKind::F16Arith => Box::new(self.job::<F16Arith>((self.prep.f16a.ok_or_else(missing)?)(), cfg, i)),
            PrecisionKind::Fixed => Box::new(self.job::<Fixed>((self.prep.fixed.ok_or_else(missing)?)(), cfg, i)),
        })
    }

    fn job<P: HostPrecision>(&self, per: Per<P>, cfg: Config, i: &Inputs) -> Job<P> {
        let (w, h) = (i.w, i.h);
        let ins = self
            .inputs
            .iter()
            .map(|inp| {
                let (iw, ih) = if inp.half { (w.div_ceil(2), h.div_ceil(2)) } else { (w, h) };
                let src = &i.get(inp.field)[..inp.c * iw * ih];
                let frac = match inp.store {
                    Store::As(kind) => P::choose_frac(src, kind),
                    Store::Logit if P::FIXED_POINT => fixed::LOGIT_FRAC,
                    Store::Logit => 0,
                };
                Tensor::encode::<P>(inp.c, iw, ih, src, frac, cfg.layout)
            })
            .collect();
        // Weights: as many fractional bits as the fixed-point bit budget
        // allows for the largest sum of |w| over one output's taps; biases
        // in the output's format.
        let mut weight_frac = 0;
        let mut params = Vec::new();
        for (k, &f) in self.params.iter().enumerate() {
            let v = i.get(f);
            let frac = if !P::FIXED_POINT {
                0
            } else if k == 0 {
                weight_frac = mcdenoise::nn::quant::weight_frac(v, v.len() / 14);
                weight_frac
            } else {
                cfg.out_frac
            };
            let mut s = vec![P::Store::default(); v.len()];
            P::encode(v, &mut s, frac);
            params.push(s);
        }
        let (oc, ow, oh) = self.out_shape(w, h);
        let mut out = Tensor::filled(oc, ow, oh, cfg.layout, poison::<P>());
        out.frac = P::frac_or_zero(cfg.out_frac);
        let out2 = self.out2.map(|(c, frac)| {
            let mut o = Tensor::filled(c, w, h, cfg.layout, poison::<P>());
            o.frac = P::frac_or_zero(frac);
            o
        });
        Job {
            isa: cfg.isa,
            size: (w, h),
            ins,
            params,
            weight_frac,
            out,
            out2,
            align: self.align,
            per,
            scratch: Scratch::new(),
        }
    }
}

/// Every precision.
const ALL: &[PrecisionKind] = &PrecisionKind::ALL;
/// f32 only.
const F32_ONLY: &[PrecisionKind] = &[PrecisionKind::F32];

/// f32: a few ulp of the inputs' range per accumulated term; f16 storage: the
/// inputs and the output rounded to 11 bits (2^-11 relative each); f16
/// arithmetic: every sum rounded to f16 as well; fixed point: the format's
/// last bit and the inputs' quantisation.
/// (Set about twice to three times the worst error measured over the
/// registry test's sizes, seeds and ISAs: `MCDENOISE_TOL_REPORT=1 cargo test
/// --release -p mcdenoise-tests --test registry -- --nocapture` prints them.)
const IMAGE_TOL: [Tol; 4] = [tol(2e-7, 1e-6), tol(8e-4, 8e-4), tol(3e-3, 3e-3), tol(1e-3, 0.0)];

fn image_frac(peak: f32) -> i8 {
    frac_for_max(peak / 2.0)
}

fn unit_frac(_peak: f32) -> i8 {
    fixed::KERNEL_FRAC
}

#[allow(clippy::extra_unused_type_parameters)] // one signature for every `per!` entry
fn no_scratch<P: HostPrecision>(_w: usize) -> usize {
    0
}

/// An image input: the first 3 planes of `field`, stored as an image.
fn image(field: Field) -> In {
    full(field, 3, Kind::Image)
}

/// `c` planes of importance logits.
fn logits(c: usize) -> In {
    In { field: Field::Logits, c, half: false, store: Store::Logit }
}

/// `c` planes of fusion logits.
fn fusion(c: usize) -> In {
    In { field: Field::Fusion, c, half: false, store: Store::Logit }
}

/// The fused filter's inputs for `m` window sizes: importance logits,
/// fusion logits, albedo, radiance.
fn fused_ins(m: usize) -> Vec<In> {
    vec![logits(m), fusion(m), full(Field::Albedo, 3, Kind::Unit), image(Field::Radiance)]
}

/// A half-resolution image: 3 planes of [`Field::Coarse`].
fn coarse() -> In {
    In { field: Field::Coarse, c: 3, half: true, store: Store::As(Kind::Image) }
}

/// An entry with the defaults every entry starts from: 3 full-resolution
/// output planes, every precision, [`IMAGE_TOL`], an image's fixed-point
/// format, and an empty oracle that every entry replaces.
fn base(name: &'static str, about: &'static str, inputs: Vec<In>, prep: Prep) -> Op {
    Op {
        name,
        about,
        inputs,
        params: vec![],
        out: (3, false),
        out_fixed: None,
        out2: None,
        align: 1,
        precisions: ALL,
        tol: IMAGE_TOL,
        fixed_exact: true,
        out_frac: image_frac,
        oracle: |_, _| Vec::new(),
        prep,
    }
}

/// Every operator, in report order.
pub fn ops() -> Vec<Op> {
    [
        unfold::ops(),
        pool::ops(),
        conv::ops(),
        tonemap::ops(),
        temporal::ops(),
        atrous::ops(),
        grad::ops(),
        noise::ops(),
        cross::ops(),
    ]
    .into_iter()
    .flatten()
    .collect()
}

/// The operator called `name`.
pub fn op(name: &str) -> Option<Op> {
    ops().into_iter().find(|o| o.name == name)
}

/// The names of every operator.
pub fn names() -> Vec<&'static str> {
    ops().iter().map(|o| o.name).collect()
}

/// Errors of `x` against the oracle `r`: maximum absolute, mean relative
/// (`sum |x - r| / sum |r|`), PSNR (`peak = max |r|`), and the worst ratio to
/// the tolerance `t` (<= 1 passes) with its index.
#[derive(Clone, Copy, Debug)]
pub struct Errors {
    /// Largest `|x - r|`.
    pub max_abs: f64,
    /// `sum |x - r| / sum |r|`.
    pub mean_rel: f64,
    /// `10 log10(max |r|^2 / MSE)`.
    pub psnr: f64,
    /// Largest `|x - r| / (peak * t.peak + t.rel |r|)`.
    pub worst: f64,
    /// Where.
    pub at: usize,
}

/// Compares an output with its oracle.
pub fn errors(x: &[f32], r: &[f64], t: Tol) -> Errors {
    let peak = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let (mut max_abs, mut sum_abs, mut sum_ref, mut se) = (0.0f64, 0.0, 0.0, 0.0);
    let (mut worst, mut at) = (0.0f64, 0);
    for (i, (&a, &b)) in x.iter().zip(r).enumerate() {
        let e = if a.is_nan() { f64::INFINITY } else { (a as f64 - b).abs() };
        max_abs = max_abs.max(e);
        sum_abs += e;
        sum_ref += b.abs();
        se += e * e;
        let allowed = peak * t.peak + t.rel * b.abs();
        let ratio = if e == 0.0 { 0.0 } else { e / allowed };
        if ratio > worst || ratio.is_nan() {
            worst = if ratio.is_nan() { f64::INFINITY } else { ratio };
            at = i;
        }
    }
    let mse = se / r.len().max(1) as f64;
    let psnr = if mse == 0.0 { f64::INFINITY } else { 10.0 * (peak * peak / mse).log10() };
    Errors { max_abs, mean_rel: sum_abs / sum_ref.max(1e-300), psnr, worst, at }
}

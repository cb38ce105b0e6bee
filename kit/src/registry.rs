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

use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::regress;
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{fixed, unfold, F16Arith, Fixed, Isa, Result as CoreResult, View, ViewMut, F16, F32};

use crate::oracle;
use mcdenoise::error::Result;
use mcdenoise::io::frame::{Buffer, Frame};
use mcdenoise::runtime::par::{Pool, Scratch};
use mcdenoise::runtime::precision::{frac_for_max, HostPrecision, Kind, PrecisionKind};

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
/// Convolutions sum 14 x k^2 products: more rounding in f32 and f16
/// arithmetic, and fixed point carries the weights' quantisation too.
const CONV_TOL: [Tol; 4] = [tol(1e-6, 5e-6), tol(8e-4, 8e-4), tol(6e-3, 6e-3), tol(4e-3, 0.0)];
/// Softmax weights in [0, 1]: f16 rounds each to 2^-11 relative; fixed
/// point Q1.14 to 2^-15 absolute, plus its exp approximation.
const WEIGHT_TOL: [Tol; 4] = [tol(1e-7, 1e-6), tol(3e-4, 3e-3), tol(1e-3, 4e-3), tol(2e-3, 0.0)];

/// Softmax weights from logits in `[-50, 50)`. A logit error `e` moves a
/// weight `w` by at most `2 w (1 - w) e`. f16 stores a logit near 50 to
/// 2^-6 (`e = 2^-6`): at most 3.1 % of the weight, plus its own 2^-11.
/// f16 arithmetic also rounds `l - max` (up to 100: 2^-5) and the sums.
/// Fixed point stores logits in Q7.8 whatever their size (`e = 2^-9`, the
/// same as at +-8), so the +-8 bound holds; Q1.14 on the weight.
/// (Set from the analysis and checked against the measured worst case, see
/// [`IMAGE_TOL`].)
const WIDE_WEIGHT_TOL: [Tol; 4] = [tol(1e-7, 1e-6), tol(1e-4, 3.3e-2), tol(1e-3, 7e-2), tol(2e-3, 0.0)];

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

// ---- kernels -------------------------------------------------------------

fn k_apply7<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    unfold::apply_rows::<P>(a.isa, 7, &a.ins[0], &a.ins[1], b, y0, s)
}
fn s_apply7<P: HostPrecision>(w: usize) -> usize {
    unfold::scratch_len::<P>(7, 3, w)
}

fn fused_inputs<'a, T>(a: &Args<'a, T>, sizes: &'a [usize]) -> FusedInputs<'a, T> {
    let multi = sizes.len() > 1;
    FusedInputs {
        sizes,
        importance: a.ins[0],
        fusion: multi.then(|| a.ins[1]),
        albedo: multi.then(|| a.ins[2]),
        radiance: a.ins[3],
    }
}

const SIX: [usize; 6] = [3, 5, 7, 9, 11, 13];

fn k_window7<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::BoxSum, &fused_inputs(a, &[7]), b, y0, s)
}
fn s_window7<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::BoxSum, &[7], 3, w)
}
fn k_fused6<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::BoxSum, &fused_inputs(a, &SIX), b, y0, s)
}
fn s_fused6<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::BoxSum, &SIX, 3, w)
}
fn k_fused6_sep<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::Separable, &fused_inputs(a, &SIX), b, y0, s)
}
fn s_fused6_sep<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::Separable, &SIX, 3, w)
}
fn k_fused6_direct<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    softmax::fused_filter::<P>(a.isa, WindowPath::Direct, &fused_inputs(a, &SIX), b, y0, s)
}
fn s_fused6_direct<P: HostPrecision>(w: usize) -> usize {
    softmax::fused_scratch_len::<P>(WindowPath::Direct, &SIX, 3, w)
}
fn k_kernels7<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    softmax::importance_kernels::<P>(a.isa, 7, &a.ins[0], b, y0)
}
fn k_softmax6<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    softmax::channel_softmax::<P>(a.isa, &a.ins[0].rows(y0, b.height())?, b)
}
fn k_avgpool<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::reduce2x2::<P>(a.isa, Reduce::Mean, &a.ins[0], b, y0)
}
fn k_maxpool<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::reduce2x2::<P>(a.isa, Reduce::Max, &a.ins[0], b, y0)
}
fn k_upsample<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::upsample_nearest2x::<P>(a.isa, &a.ins[0], b, y0, a.size.1)
}
fn k_composite<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    pool::composite::<P>(a.isa, &a.ins[0], &a.ins[1], &a.ins[2], b, y0)
}

fn conv_layer<'a, T>(a: &Args<'a, T>, k: usize) -> Conv2d<'a, T> {
    Conv2d {
        k,
        cin: 14,
        cout: 14,
        weights: a.params[0],
        bias: Some(a.params[1]),
        act: Activation::LeakyRelu(0.1),
        weight_frac: a.weight_frac,
    }
}
fn k_conv1<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    conv::conv2d::<P>(a.isa, &conv_layer(a, 1), &a.ins[0], b, y0, s)
}
fn s_conv1<P: HostPrecision>(w: usize) -> usize {
    conv::conv2d_scratch_len::<P>(1, 14, 14, w)
}
fn k_conv3<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    conv::conv2d::<P>(a.isa, &conv_layer(a, 3), &a.ins[0], b, y0, s)
}
fn s_conv3<P: HostPrecision>(w: usize) -> usize {
    conv::conv2d_scratch_len::<P>(3, 14, 14, w)
}
fn k_conv5<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    conv::conv2d::<P>(a.isa, &conv_layer(a, 5), &a.ins[0], b, y0, s)
}
fn s_conv5<P: HostPrecision>(w: usize) -> usize {
    conv::conv2d_scratch_len::<P>(5, 14, 14, w)
}

/// The albedo epsilon the (de)modulation entries use.
pub const DEMOD_EPS: f32 = 1e-3;

fn k_demodulate<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let n = b.height();
    tonemap::demodulate::<P>(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, DEMOD_EPS, b)
}
fn k_remodulate<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let n = b.height();
    tonemap::remodulate::<P>(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, DEMOD_EPS, b)
}
fn k_gamma<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    tonemap::map::<P>(a.isa, Map::Gamma { gamma: 2.2, clamp: true }, &a.ins[0].rows(y0, b.height())?, b)
}

/// The temporal entry's blend floor and history cap.
fn temporal_params() -> TemporalParams {
    TemporalParams { history_cap: 1e6, ..TemporalParams::default() }
}

fn k_temporal<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let inp = TemporalInputs {
        color: a.ins[0],
        normal: None,
        position: None,
        motion: Some(a.ins[1]),
        prev_color: a.ins[2],
        prev_normal: None,
        prev_position: None,
        prev_history: a.ins[3],
    };
    temporal::accumulate::<P>(a.isa, &inp, &temporal_params(), c, hist, y0)
}

/// The rejecting entries' limits: block positions agree exactly or are at
/// least 0.25 apart (limit 0.1); unflipped synthetic normals differ by
/// `|dn|^2 < 1.08`, flipped ones by `>= 1.44` (limit `1.1^2 = 1.21`). So no
/// distance is near a limit in any precision.
fn temporal_reject_params() -> TemporalParams {
    TemporalParams { pos_limit: 0.1, normal_limit: 1.1, history_cap: 1e6, ..TemporalParams::default() }
}

/// The position-search entry's parameters: the true source pixel is an exact
/// match (distance 0, or a few fixed-point units), any other is far more
/// than 0.01 away in all but rare pixels.
fn temporal_search_params() -> TemporalParams {
    TemporalParams { pos_limit: 0.01, history_cap: 6.5, ..TemporalParams::default() }
}

/// Motion with position and normal rejection; inputs: colour, motion,
/// previous colour, history, positions (current, previous), normals
/// (current, previous).
fn k_temporal_reject<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let inp = TemporalInputs {
        color: a.ins[0],
        normal: Some(a.ins[6]),
        position: Some(a.ins[4]),
        motion: Some(a.ins[1]),
        prev_color: a.ins[2],
        prev_normal: Some(a.ins[7]),
        prev_position: Some(a.ins[5]),
        prev_history: a.ins[3],
    };
    temporal::accumulate::<P>(a.isa, &inp, &temporal_reject_params(), c, hist, y0)
}

/// [`k_temporal_reject`] with the history as the checked output.
fn k_temporal_reject_hist<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    k_temporal_reject::<P>(a, c, hist, y0, s)
}

/// Reprojection by world-position search; inputs: colour, previous colour,
/// history, positions (current, previous).
fn k_temporal_search<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let inp = TemporalInputs {
        color: a.ins[0],
        normal: None,
        position: Some(a.ins[3]),
        motion: None,
        prev_color: a.ins[1],
        prev_normal: None,
        prev_position: Some(a.ins[4]),
        prev_history: a.ins[2],
    };
    temporal::accumulate::<P>(a.isa, &inp, &temporal_search_params(), c, hist, y0)
}

/// [`k_temporal_search`] with the history as the checked output.
fn k_temporal_search_hist<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    k_temporal_search::<P>(a, c, hist, y0, s)
}

/// The à-trous entry's parameters (level 1: hole 2).
fn atrous_params() -> AtrousParams {
    AtrousParams { sigma_plane: 0.05, sigma_distance: 0.2, ..AtrousParams::default() }
}

fn k_atrous<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    b: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    let g = AtrousGuides { noise: a.ins[1], normal: Some(a.ins[2]), position: Some(a.ins[3]), depth: None };
    atrous::step::<P>(a.isa, 1, 1, false, &atrous_params(), &g, &a.ins[0], b, y0, s)
}
fn s_atrous<P: HostPrecision>(_w: usize) -> usize {
    atrous::step_scratch_len::<P>(1)
}

// Backward passes (f32): several gradients go out as one tensor, their
// planes one after the other.

fn k_conv3_grad_input(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let (tw, rest) = s.split_at_mut(14 * 14 * 9);
    conv::grad::transpose_weights(3, 14, 14, a.params[0], tw)?;
    conv::grad::grad_input(a.isa, 3, 14, 14, tw, &a.ins[0], b, y0, rest)
}
fn s_conv3_grad_input(w: usize) -> usize {
    14 * 14 * 9 + conv::grad::grad_input_scratch_len(3, 14, 14, w)
}
fn conv_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, k: usize) -> CoreResult<()> {
    // The weights' gradient as one row of cout * cin * k * k values, all image rows summed.
    let dw = b.row_mut(0, 0);
    dw.fill(0.0);
    let rows = a.ins[0].height();
    conv::grad::grad_weights(a.isa, k, &a.ins[0], &a.ins[1], 0, rows, dw, None)
}
fn k_conv3_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, _: usize, _: &mut [f32]) -> CoreResult<()> {
    conv_grad_weights(a, b, 3)
}
fn k_conv5_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, _: usize, _: &mut [f32]) -> CoreResult<()> {
    conv_grad_weights(a, b, 5)
}
fn k_fused6_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let (mut imp, rest) = b.reborrow().split_channels_at(6);
    let (mut fus, mut rad) = rest.split_channels_at(6);
    let out = softmax::grad::FusedGrads { importance: &mut imp, fusion: Some(&mut fus), radiance: &mut rad };
    let g = a.ins[4].channels_range(0, 3)?;
    softmax::grad::fused_filter_grad(a.isa, &fused_inputs(a, &SIX), &g, out, y0, s)
}
fn s_fused6_grad(w: usize) -> usize {
    softmax::grad::fused_grad_scratch_len(6, 3, w)
}
fn k_apply7_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let (mut dk, mut ds) = b.reborrow().split_channels_at(49);
    let g = a.ins[2].channels_range(0, 3)?;
    unfold::grad::apply_grad(a.isa, 7, &a.ins[0], &a.ins[1], &g, Some(&mut dk), Some(&mut ds), y0)
}
fn k_softmax6_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    softmax::grad::channel_softmax_grad(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, b)
}

fn k_conv1_grad_weights(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, _: usize, _: &mut [f32]) -> CoreResult<()> {
    conv_grad_weights(a, b, 1)
}
fn k_avgpool_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::avg_pool2x2_grad(a.isa, &a.ins[0], b, y0, a.size.1)
}
fn k_maxpool_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::max_pool2x2_grad(a.isa, &a.ins[0], &a.ins[1], b, y0)
}
fn k_upsample_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::upsample_nearest2x_grad(a.isa, &a.ins[0], b, y0)
}
fn k_bilinear(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::upsample_bilinear2x(a.isa, &a.ins[0], b, y0, a.size.1)
}
fn k_bilinear_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    pool::grad::upsample_bilinear2x_grad(a.isa, &a.ins[0], b, y0)
}

/// Which gradient of the compositor an entry checks.
#[derive(Clone, Copy, PartialEq)]
enum CompositeGrad {
    Fine,
    Coarse,
    Alpha,
}

/// The compositor's gradients for the band of the checked output (fine rows
/// for `Fine` and `Alpha`, coarse rows for `Coarse`); the other two go to
/// temporaries of the band's size. Inputs: fine, coarse, alpha, gradient.
fn composite_grad_band(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, which: CompositeGrad) -> CoreResult<()> {
    let (w, h) = a.size;
    let (cw, n) = (w.div_ceil(2), b.height());
    // Fine rows y0f .. y0f + nf and coarse rows y0f / 2 .. (y0f + nf + 1) / 2.
    let (y0f, nf) = if which == CompositeGrad::Coarse { (2 * y0, (2 * n).min(h - 2 * y0)) } else { (y0, n) };
    let nc = (y0f + nf).div_ceil(2) - y0f / 2;
    let (mut t1, mut t2) = (vec![0.0f32; 3 * w * nf], vec![0.0f32; 3 * cw * nc.max(nf)]);
    let g = a.ins[3].channels_range(0, 3)?;
    let run = |df: &mut ViewMut<'_, f32>, dc: &mut ViewMut<'_, f32>, da: &mut ViewMut<'_, f32>| {
        pool::grad::composite_grad(a.isa, &a.ins[0], &a.ins[1], &a.ins[2], &g, df, dc, da, y0f)
    };
    match which {
        CompositeGrad::Fine => {
            let mut dc = ViewMut::new(&mut t2[..3 * cw * nc], 3, cw, nc)?;
            let mut da = ViewMut::new(&mut t1[..w * nf], 1, w, nf)?;
            run(b, &mut dc, &mut da)
        }
        CompositeGrad::Coarse => {
            let mut df = ViewMut::new(&mut t1, 3, w, nf)?;
            let mut da = ViewMut::new(&mut t2[..w * nf], 1, w, nf)?;
            run(&mut df, b, &mut da)
        }
        CompositeGrad::Alpha => {
            let mut df = ViewMut::new(&mut t1, 3, w, nf)?;
            let mut dc = ViewMut::new(&mut t2[..3 * cw * nc], 3, cw, nc)?;
            run(&mut df, &mut dc, b)
        }
    }
}
fn k_composite_grad_fine(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    composite_grad_band(a, b, y0, CompositeGrad::Fine)
}
fn k_composite_grad_coarse(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    composite_grad_band(a, b, y0, CompositeGrad::Coarse)
}
fn k_composite_grad_alpha(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    composite_grad_band(a, b, y0, CompositeGrad::Alpha)
}
fn k_sigmoid(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    softmax::grad::sigmoid(a.isa, &a.ins[0].rows(y0, b.height())?, b)
}
fn k_sigmoid_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    softmax::grad::sigmoid_grad(a.isa, &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, b)
}
fn k_activation_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    conv::grad::activation_grad(Activation::LeakyRelu(0.1), &a.ins[0].rows(y0, n)?, &a.ins[1].rows(y0, n)?, b)
}

fn k_local_noise(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    atrous::noise::local_noise_rows(&a.ins[0], b, y0)
}
fn k_median3(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    atrous::noise::median3_rows(&a.ins[0], b, y0)
}

// ---- cross-regression (f32) ---------------------------------------------------

fn k_cross_variance(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, _: &mut [f32]) -> CoreResult<()> {
    regress::variance_rows(a.isa, &a.ins[0], b, y0)
}
fn regression_inputs<'a>(a: &Args<'a, f32>) -> regress::RegressionInputs<'a> {
    regress::RegressionInputs { x: a.ins[0], var: a.ins[1], y: a.ins[2], albedo: a.ins[3], normal: a.ins[4] }
}
fn k_cross_regression(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    regress::regression_rows(a.isa, &regression_inputs(a), b, y0, s)
}
fn s_cross_regression(w: usize) -> usize {
    regress::regression_scratch_len(w)
}
fn filter_inputs<'a>(a: &Args<'a, f32>) -> regress::FilterInputs<'a> {
    regress::FilterInputs {
        pilot_a: a.ins[0],
        pilot_b: a.ins[1],
        albedo: a.ins[2],
        normal: a.ins[3],
        prev: a.ins[4],
        valid: a.ins[5],
    }
}
fn k_cross_filter(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    regress::filter_rows(a.isa, &filter_inputs(a), &a.ins[6].rows(y0, n)?, b, y0, s)
}
fn k_cross_filter_grad(a: &Args<'_, f32>, b: &mut ViewMut<'_, f32>, y0: usize, s: &mut [f32]) -> CoreResult<()> {
    let n = b.height();
    let g = a.ins[7].channels_range(0, 6)?.rows(y0, n)?;
    regress::filter_grad_rows(a.isa, &filter_inputs(a), &a.ins[6].rows(y0, n)?, &g, b, y0, s)
}
fn s_cross_filter(w: usize) -> usize {
    regress::filter_scratch_len(w)
}
fn cross_filter_oracle(i: &Inputs) -> [Vec<f64>; 6] {
    [
        i.f64(Field::Radiance),
        i.f64(Field::Previous),
        i.f64(Field::Albedo),
        i.f64(Field::Normal),
        i.f64(Field::Position),
        i.f64(Field::Alpha),
    ]
}
/// The regression solves 6x6 systems per centre: f32 loses a few digits to
/// their conditioning; the filter sums 121 exponentials.
const REGRESSION_TOL: [Tol; 4] = [tol(5e-4, 5e-4), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const FILTER_TOL: [Tol; 4] = [tol(1e-6, 1e-5), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const FILTER_GRAD_TOL: [Tol; 4] = [tol(1e-5, 1e-4), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];

// ---- oracles ---------------------------------------------------------------

fn o_fused(i: &Inputs, sizes: &[usize]) -> Vec<f64> {
    let m = sizes.len();
    let n = i.w * i.h;
    let imp = &i.f64(Field::Logits)[..m * n];
    if m == 1 {
        oracle::fused_pixelwise(sizes, imp, None, None, &i.f64(Field::Radiance), 3, i.w, i.h)
    } else {
        let fus = &i.f64(Field::Fusion)[..m * n];
        oracle::fused_pixelwise(
            sizes,
            imp,
            Some(fus),
            Some(&i.f64(Field::Albedo)),
            &i.f64(Field::Radiance),
            3,
            i.w,
            i.h,
        )
    }
}

fn o_conv(i: &Inputs, pool: &Pool, k: usize, wf: Field) -> Vec<f64> {
    let per = 14 * k * k;
    let (x, wts, b) = (i.f64(Field::Features), i.f64(wf), i.f64(Field::Bias));
    // One output channel per task: the oracle is the slow part of a report.
    let chans: Vec<Vec<f64>> = pool.map(14, |co| {
        oracle::conv2d(k, 14, 1, &wts[co * per..(co + 1) * per], Some(&b[co..co + 1]), Some(0.1), &x, i.w, i.h)
    });
    chans.concat()
}

fn o_temporal(i: &Inputs) -> Vec<f64> {
    let p = temporal_params();
    oracle::temporal_motion(
        &i.f64(Field::Radiance),
        &i.f64(Field::Motion),
        &i.f64(Field::Previous),
        &i.f64(Field::History),
        p.alpha_min as f64,
        3,
        i.w,
        i.h,
    )
}

/// The general temporal oracle on the registry's fields: `search` picks the
/// position-search entry, else the rejecting motion entry.
fn o_temporal_paths(i: &Inputs, search: bool) -> (Vec<f64>, Vec<f64>) {
    let (col, prev, hist) = (i.f64(Field::Radiance), i.f64(Field::Previous), i.f64(Field::History));
    let (pos, ppos) = (i.f64(Field::Position), i.f64(Field::PrevPosition));
    let (blocks, motion) = (i.f64(Field::Blocks), i.f64(Field::SafeMotion));
    let (n, pn) = (i.f64(Field::Normal), i.f64(Field::PrevNormal));
    let (p, t) = if search {
        let t = oracle::TemporalRef {
            color: &col,
            normal: None,
            position: Some(&pos),
            motion: None,
            prev_color: &prev,
            prev_normal: None,
            prev_position: Some(&ppos),
            prev_history: &hist,
            c: 3,
            w: i.w,
            h: i.h,
        };
        (temporal_search_params(), t)
    } else {
        let t = oracle::TemporalRef {
            color: &col,
            normal: Some(&n),
            position: Some(&blocks),
            motion: Some(&motion),
            prev_color: &prev,
            prev_normal: Some(&pn),
            prev_position: Some(&blocks),
            prev_history: &hist,
            c: 3,
            w: i.w,
            h: i.h,
        };
        (temporal_reject_params(), t)
    };
    let f = |v: f32| v as f64;
    oracle::temporal(&t, f(p.pos_limit), f(p.normal_limit), f(p.alpha_min), f(p.history_cap), p.search_radius)
}

fn o_atrous(i: &Inputs) -> Vec<f64> {
    let p = atrous_params();
    let (noise, normal, pos) = (i.f64(Field::Noise), i.f64(Field::Normal), i.f64(Field::Position));
    let g = oracle::AtrousGuides { noise: &noise, normal: Some(&normal), position: Some(&pos), depth: None };
    oracle::atrous_step(
        1,
        1,
        false,
        p.phi_color as f64,
        p.sigma_normal as f64,
        p.sigma_plane as f64,
        p.sigma_depth as f64,
        p.sigma_distance as f64,
        p.eps as f64,
        &g,
        &i.f64(Field::Radiance),
        i.w,
        i.h,
    )
}

/// Backward passes, f32: gathers to rounding of the inputs' range; the
/// fused filter's cancelling terms and the weight gradient's long sums (every
/// pixel of the image) need more.
const GRAD_TOL: [Tol; 4] = [tol(1e-6, 1e-5), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const FUSED_GRAD_TOL: [Tol; 4] = [tol(1e-6, 1e-5), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];
const WEIGHT_GRAD_TOL: [Tol; 4] = [tol(5e-6, 5e-6), tol(0.0, 0.0), tol(0.0, 0.0), tol(0.0, 0.0)];

/// The half-resolution gradient the pool-gradient entries read.
fn o_half_grad(i: &Inputs) -> Vec<f64> {
    i.f64(Field::Grad)[..3 * i.w.div_ceil(2) * i.h.div_ceil(2)].to_vec()
}

/// The compositor's three gradients on the registry's fields.
fn o_composite_grad(i: &Inputs) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let g = &i.f64(Field::Grad)[..3 * i.w * i.h];
    let (f, c, a) = (i.f64(Field::Radiance), i.f64(Field::Coarse), i.f64(Field::Alpha));
    oracle::composite_grad(&f, &c, &a, g, 3, i.w, i.h)
}

fn concat(parts: [Vec<f64>; 3]) -> Vec<f64> {
    parts.concat()
}

fn o_conv_grad(i: &Inputs, k: usize, wf: Field) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    oracle::conv2d_grad(k, 14, 14, &i.f64(wf), &i.f64(Field::Features), &i.f64(Field::Grad), i.w, i.h)
}

/// Every operator, in report order.
pub fn ops() -> Vec<Op> {
    use Field::*;
    let image = |field| full(field, 3, Kind::Image);
    let logits = |c| In { field: Logits, c, half: false, store: Store::Logit };
    let fusion = |c| In { field: Fusion, c, half: false, store: Store::Logit };
    let fused_ins = |m| vec![logits(m), fusion(m), full(Albedo, 3, Kind::Unit), image(Radiance)];
    let coarse = In { field: Coarse, c: 3, half: true, store: Store::As(Kind::Image) };
    let temporal_reject_ins = vec![
        image(Radiance),
        full(SafeMotion, 2, Kind::Plain),
        image(Previous),
        full(History, 1, Kind::Plain),
        full(Blocks, 3, Kind::Plain),
        full(Blocks, 3, Kind::Plain),
        full(Normal, 3, Kind::Unit),
        full(PrevNormal, 3, Kind::Unit),
    ];
    let temporal_search_ins = vec![
        image(Radiance),
        image(Previous),
        full(History, 1, Kind::Plain),
        full(Position, 3, Kind::Plain),
        full(PrevPosition, 3, Kind::Plain),
    ];
    // A half-resolution gradient: the first planes' worth of the Grad field.
    let half_grad = In { field: Grad, c: 3, half: true, store: Store::As(Kind::Image) };
    let composite_grad_ins = vec![image(Radiance), coarse, full(Alpha, 1, Kind::Unit), full(Grad, 14, Kind::Image)];
    let base = |name, about, inputs, prep| Op {
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
    };
    vec![
        Op {
            oracle: |i, _| oracle::unfold(7, &i.f64(Kernel), &i.f64(Radiance), 3, i.w, i.h),
            ..base(
                "apply7x7",
                "a 7x7 per-pixel kernel map applied to 3 channels (AFN)",
                vec![full(Kernel, 49, Kind::Unit), image(Radiance)],
                per!(One, k_apply7, s_apply7),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &[7]),
            align: 48,
            ..base(
                "window7",
                "the importance-weighted 7x7 window filter (WSKP, one size), box-sum path",
                fused_ins(1),
                per!(One, k_window7, s_window7),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &SIX),
            align: 48,
            ..base(
                "fused6",
                "the fused importance filter, sizes 3..13 with fusion weights and albedo (WSKP), box-sum path",
                fused_ins(6),
                per!(One, k_fused6, s_fused6),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &SIX),
            align: 48,
            ..base(
                "fused6-sep",
                "the fused importance filter through the separable window sums",
                fused_ins(6),
                per!(One, k_fused6_sep, s_fused6_sep),
            )
        },
        Op {
            oracle: |i, _| o_fused(i, &SIX),
            ..base(
                "fused6-direct",
                "the fused importance filter, every window summed tap by tap with its own shift",
                fused_ins(6),
                per!(One, k_fused6_direct, s_fused6_direct),
            )
        },
        Op {
            oracle: |i, _| oracle::importance_kernels(7, &i.f64(Logits)[..i.w * i.h], i.w, i.h),
            out: (49, false),
            tol: WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "kernels7",
                "per-pixel 7x7 softmax kernels from an importance map (WSKP eq. 3)",
                vec![logits(1)],
                per!(One, k_kernels7, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::channel_softmax(&i.f64(Fusion), 6, i.w, i.h),
            out: (6, false),
            tol: WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "softmax6",
                "the softmax across 6 channels per pixel",
                vec![fusion(6)],
                per!(One, k_softmax6, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::importance_kernels(7, &i.f64(WideLogits)[..i.w * i.h], i.w, i.h),
            out: (49, false),
            tol: WIDE_WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "kernels7-wide",
                "per-pixel 7x7 softmax kernels from logits in [-50, 50) (a trained network's range)",
                vec![In { field: WideLogits, c: 1, half: false, store: Store::Logit }],
                per!(One, k_kernels7, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::channel_softmax(&i.f64(WideLogits), 6, i.w, i.h),
            out: (6, false),
            tol: WIDE_WEIGHT_TOL,
            out_frac: unit_frac,
            ..base(
                "softmax6-wide",
                "the softmax across 6 channels of logits in [-50, 50)",
                vec![In { field: WideLogits, c: 6, half: false, store: Store::Logit }],
                per!(One, k_softmax6, no_scratch),
            )
        },
        Op {
            oracle: |i, _| oracle::reduce2x2(&i.f64(Radiance), 3, i.w, i.h, false),
            out: (3, true),
            ..base("avgpool", "2x2 average pool", vec![image(Radiance)], per!(One, k_avgpool, no_scratch))
        },
        Op {
            oracle: |i, _| oracle::reduce2x2(&i.f64(Radiance), 3, i.w, i.h, true),
            out: (3, true),
            ..base("maxpool", "2x2 max pool", vec![image(Radiance)], per!(One, k_maxpool, no_scratch))
        },
        Op {
            oracle: |i, _| oracle::upsample(&i.f64(Coarse), 3, i.w, i.h),
            align: 2,
            ..base("upsample", "nearest-neighbour 2x upsampling", vec![coarse], per!(One, k_upsample, no_scratch))
        },
        Op {
            oracle: |i, _| oracle::composite(&i.f64(Radiance), &i.f64(Coarse), &i.f64(Alpha), 3, i.w, i.h),
            align: 2,
            ..base(
                "composite",
                "the scale compositor d - a U(D(d)) + a U(coarse) (AFN)",
                vec![image(Radiance), coarse, full(Alpha, 1, Kind::Unit)],
                per!(One, k_composite, no_scratch),
            )
        },
        Op {
            oracle: |i, p| o_conv(i, p, 1, Weights1),
            params: vec![Weights1, Bias],
            out: (14, false),
            tol: CONV_TOL,
            ..base(
                "conv1x1",
                "1x1 convolution 14 -> 14, bias, LeakyReLU(0.1)",
                vec![full(Features, 14, Kind::Image)],
                per!(One, k_conv1, s_conv1),
            )
        },
        Op {
            oracle: |i, p| o_conv(i, p, 3, Weights3),
            params: vec![Weights3, Bias],
            out: (14, false),
            tol: CONV_TOL,
            ..base(
                "conv3x3",
                "3x3 convolution 14 -> 14, bias, LeakyReLU(0.1)",
                vec![full(Features, 14, Kind::Image)],
                per!(One, k_conv3, s_conv3),
            )
        },
        Op {
            oracle: |i, p| o_conv(i, p, 5, Weights5),
            params: vec![Weights5, Bias],
            out: (14, false),
            tol: CONV_TOL,
            ..base(
                "conv5x5",
                "5x5 convolution 14 -> 14, bias, LeakyReLU(0.1)",
                vec![full(Features, 14, Kind::Image)],
                per!(One, k_conv5, s_conv5),
            )
        },
        Op {
            oracle: |i, _| {
                i.get(Radiance)
                    .iter()
                    .zip(i.get(Albedo))
                    .map(|(&r, &a)| r as f64 / (a as f64 + DEMOD_EPS as f64))
                    .collect()
            },
            ..base(
                "demodulate",
                "radiance / (albedo + eps)",
                vec![image(Radiance), full(Albedo, 3, Kind::Unit)],
                per!(One, k_demodulate, no_scratch),
            )
        },
        Op {
            oracle: |i, _| {
                i.get(Radiance)
                    .iter()
                    .zip(i.get(Albedo))
                    .map(|(&r, &a)| r as f64 * (a as f64 + DEMOD_EPS as f64))
                    .collect()
            },
            ..base(
                "remodulate",
                "irradiance * (albedo + eps)",
                vec![image(Radiance), full(Albedo, 3, Kind::Unit)],
                per!(One, k_remodulate, no_scratch),
            )
        },
        Op {
            oracle: |i, _| i.get(Radiance).iter().map(|&r| (r as f64).clamp(0.0, 1.0).powf(1.0 / 2.2)).collect(),
            tol: [tol(1e-7, 1e-6), tol(4e-4, 8e-4), tol(1e-3, 2e-3), tol(5e-4, 0.0)],
            out_frac: unit_frac,
            ..base("gamma", "clamp(x, 0, 1)^(1/2.2)", vec![image(Radiance)], per!(One, k_gamma, no_scratch))
        },
        Op {
            oracle: |i, _| o_temporal(i),
            out2: Some((1, 8)),
            ..base(
                "temporal",
                "temporal accumulation: bilinear reprojection by motion, alpha = max(1/(n+1), 0.2)",
                vec![image(Radiance), full(Motion, 2, Kind::Plain), image(Previous), full(History, 1, Kind::Plain)],
                per!(Two, k_temporal, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, false).0,
            out2: Some((1, 8)),
            ..base(
                "temporal-reject",
                "temporal accumulation by motion, taps rejected by position and normal, the rest renormalised",
                temporal_reject_ins.clone(),
                per!(Two, k_temporal_reject, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, false).1,
            out: (1, false),
            out2: Some((3, 12)),
            ..base(
                "temporal-reject-hist",
                "the history the rejecting accumulation writes: min(n + 1, cap), 0 where every tap is rejected",
                temporal_reject_ins,
                per!(Two, k_temporal_reject_hist, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, true).0,
            out2: Some((1, 8)),
            ..base(
                "temporal-search",
                "temporal accumulation without motion: the closest previous world position within 2 pixels",
                temporal_search_ins.clone(),
                per!(Two, k_temporal_search, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, true).1,
            out: (1, false),
            out2: Some((3, 12)),
            ..base(
                "temporal-search-hist",
                "the history of the position-search accumulation, capped at 6.5",
                temporal_search_ins,
                per!(Two, k_temporal_search_hist, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_atrous(i),
            ..base(
                "atrous",
                "one edge-avoiding a-trous level (hole 2) with colour, normal and plane edge-stopping",
                vec![
                    image(Radiance),
                    full(Noise, 1, Kind::Plain),
                    full(Normal, 3, Kind::Unit),
                    full(Position, 3, Kind::Plain),
                ],
                per!(One, k_atrous, s_atrous),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 3, Weights3).0,
            params: vec![Weights3],
            out: (14, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "conv3x3-grad-input",
                "backward: the input gradient of a 3x3 convolution 14 -> 14 (the forward kernel on transposed weights)",
                vec![full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv3_grad_input, s_conv3_grad_input),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 3, Weights3).1,
            out_fixed: Some((1, 14 * 14 * 9, 1)),
            precisions: F32_ONLY,
            tol: WEIGHT_GRAD_TOL,
            ..base(
                "conv3x3-grad-weights",
                "backward: the weight gradient of a 3x3 convolution 14 -> 14, summed over the image",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv3_grad_weights),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 5, Weights5).1,
            out_fixed: Some((1, 14 * 14 * 25, 1)),
            precisions: F32_ONLY,
            tol: WEIGHT_GRAD_TOL,
            ..base(
                "conv5x5-grad-weights",
                "backward: the weight gradient of a 5x5 convolution 14 -> 14, summed over the image",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv5_grad_weights),
            )
        },
        Op {
            oracle: |i, _| {
                let n = i.w * i.h;
                let (di, df, dc) = oracle::fused_grad(
                    &SIX,
                    &i.f64(Logits),
                    Some(&i.f64(Fusion)),
                    Some(&i.f64(Albedo)),
                    &i.f64(Radiance),
                    &i.f64(Grad)[..3 * n],
                    3,
                    i.w,
                    i.h,
                );
                concat([di, df, dc])
            },
            out: (15, false),
            align: 32,
            precisions: F32_ONLY,
            tol: FUSED_GRAD_TOL,
            ..base(
                "fused6-grad",
                "backward: the fused importance filter's gradients (importance, fusion, radiance)",
                vec![logits(6), fusion(6), full(Albedo, 3, Kind::Unit), image(Radiance), full(Grad, 3, Kind::Image)],
                per_f32!(One, k_fused6_grad, s_fused6_grad),
            )
        },
        Op {
            oracle: |i, _| {
                let n = i.w * i.h;
                let (dk, ds) =
                    oracle::unfold_grad(7, &i.f64(Kernel), &i.f64(Radiance), &i.f64(Grad)[..3 * n], 3, i.w, i.h);
                [dk, ds].concat()
            },
            out: (52, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "apply7x7-grad",
                "backward: the 7x7 apply's gradients (kernel map, image)",
                vec![full(Kernel, 49, Kind::Unit), image(Radiance), full(Grad, 3, Kind::Image)],
                per_f32!(One, k_apply7_grad),
            )
        },
        Op {
            oracle: |i, _| {
                let n = i.w * i.h;
                oracle::channel_softmax_grad(&i.f64(Fusion), &i.f64(Grad)[..6 * n], 6, i.w, i.h)
            },
            out: (6, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "softmax6-grad",
                "backward: the channel softmax's gradient y (dy - sum y dy)",
                vec![fusion(6), full(Grad, 6, Kind::Image)],
                per_f32!(One, k_softmax6_grad),
            )
        },
        Op {
            oracle: |i, _| o_conv_grad(i, 1, Weights1).1,
            out_fixed: Some((1, 14 * 14, 1)),
            precisions: F32_ONLY,
            tol: WEIGHT_GRAD_TOL,
            ..base(
                "conv1x1-grad-weights",
                "backward: the weight gradient of a 1x1 convolution 14 -> 14, summed over the image",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_conv1_grad_weights),
            )
        },
        Op {
            oracle: |i, _| oracle::avg_pool_grad(&o_half_grad(i), 3, i.w, i.h),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "avgpool-grad",
                "backward: the 2x2 average pool's gradient (a quarter of the cell's to each pixel)",
                vec![half_grad],
                per_f32!(One, k_avgpool_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::max_pool_grad(&i.f64(Radiance), &o_half_grad(i), 3, i.w, i.h),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "maxpool-grad",
                "backward: the 2x2 max pool's gradient (the cell's to its maximum)",
                vec![image(Radiance), half_grad],
                per_f32!(One, k_maxpool_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::upsample_grad(&i.f64(Grad)[..3 * i.w * i.h], 3, i.w, i.h),
            out: (3, true),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "upsample-grad",
                "backward: the nearest 2x upsample's gradient (each cell's sum)",
                vec![full(Grad, 3, Kind::Image)],
                per_f32!(One, k_upsample_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::upsample_bilinear(&i.f64(Coarse), 3, i.w, i.h),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "upsample-bilinear",
                "bilinear 2x upsampling (align_corners = false), the forward of the next entry",
                vec![coarse],
                per_f32!(One, k_bilinear),
            )
        },
        Op {
            oracle: |i, _| oracle::upsample_bilinear_grad(&i.f64(Grad)[..3 * i.w * i.h], 3, i.w, i.h),
            out: (3, true),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "upsample-bilinear-grad",
                "backward: the bilinear 2x upsample's gradient",
                vec![full(Grad, 3, Kind::Image)],
                per_f32!(One, k_bilinear_grad),
            )
        },
        Op {
            oracle: |i, _| o_composite_grad(i).0,
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "composite-grad-fine",
                "backward: the scale compositor's gradient with respect to the fine image",
                composite_grad_ins.clone(),
                per_f32!(One, k_composite_grad_fine),
            )
        },
        Op {
            oracle: |i, _| o_composite_grad(i).1,
            out: (3, true),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "composite-grad-coarse",
                "backward: the scale compositor's gradient with respect to the coarse image",
                composite_grad_ins.clone(),
                per_f32!(One, k_composite_grad_coarse),
            )
        },
        Op {
            oracle: |i, _| o_composite_grad(i).2,
            out: (1, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            align: 2,
            ..base(
                "composite-grad-alpha",
                "backward: the scale compositor's gradient with respect to its blend weight",
                composite_grad_ins,
                per_f32!(One, k_composite_grad_alpha),
            )
        },
        Op {
            oracle: |i, _| oracle::sigmoid(&i.f64(Features)),
            out: (14, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "sigmoid",
                "1 / (1 + e^-x) (AFN's fusion weight)",
                vec![full(Features, 14, Kind::Image)],
                per_f32!(One, k_sigmoid),
            )
        },
        Op {
            oracle: |i, _| oracle::sigmoid_grad(&i.f64(Alpha), &i.f64(Grad)[..i.w * i.h]),
            out: (1, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "sigmoid-grad",
                "backward: the sigmoid's gradient from its output, dy y (1 - y)",
                vec![full(Alpha, 1, Kind::Unit), full(Grad, 1, Kind::Image)],
                per_f32!(One, k_sigmoid_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::leaky_relu_grad(&i.f64(Features), &i.f64(Grad), 0.1),
            out: (14, false),
            precisions: F32_ONLY,
            tol: GRAD_TOL,
            ..base(
                "activation-grad",
                "backward: LeakyReLU(0.1)'s gradient through its output",
                vec![full(Features, 14, Kind::Image), full(Grad, 14, Kind::Image)],
                per_f32!(One, k_activation_grad),
            )
        },
        Op {
            oracle: |i, _| oracle::local_noise(&i.f64(Radiance), i.w, i.h),
            out: (1, false),
            precisions: F32_ONLY,
            ..base(
                "noise-local",
                "single-image noise variance: 0.84 |y - median of 8 neighbours|^2, mean over channels",
                vec![image(Radiance)],
                per_f32!(One, k_local_noise),
            )
        },
        Op {
            oracle: |i, _| oracle::median3(&i.f64(Noise), i.w, i.h),
            out: (1, false),
            precisions: F32_ONLY,
            ..base(
                "noise-median3",
                "1.27 x the 3x3 median of a noise map",
                vec![full(Noise, 1, Kind::Plain)],
                per_f32!(One, k_median3),
            )
        },
        Op {
            oracle: |i, _| oracle::cross_variance(&i.f64(Radiance), i.w, i.h),
            out: (1, false),
            precisions: F32_ONLY,
            tol: FILTER_TOL,
            ..base(
                "cross-variance",
                "cross-regression: per-pixel variance, |y - mean of the 8 neighbours|^2 over the channels",
                vec![image(Radiance)],
                per_f32!(One, k_cross_variance),
            )
        },
        Op {
            oracle: |i, _| {
                oracle::cross_regression(
                    &i.f64(Radiance),
                    &i.f64(Noise),
                    &i.f64(Previous),
                    &i.f64(Albedo),
                    &i.f64(Normal),
                    i.w,
                    i.h,
                )
            },
            out: (3, false),
            precisions: F32_ONLY,
            tol: REGRESSION_TOL,
            ..base(
                "cross-regression",
                "cross-regression pilot: 17x17 weighted fits at every 4th pixel (Cholesky), blended within +-8 px",
                vec![
                    image(Radiance),
                    full(Noise, 1, Kind::Plain),
                    image(Previous),
                    full(Albedo, 3, Kind::Unit),
                    full(Normal, 3, Kind::Unit),
                ],
                per_f32!(One, k_cross_regression, s_cross_regression),
            )
        },
        Op {
            oracle: |i, _| {
                let [pa, pb, alb, nrm, prev, valid] = cross_filter_oracle(i);
                let f = oracle::CrossFilter {
                    pa: &pa,
                    pb: &pb,
                    alb: &alb,
                    nrm: &nrm,
                    prev: &prev,
                    valid: &valid,
                    w: i.w,
                    h: i.h,
                };
                f.forward(&i.f64(Logits))
            },
            out: (9, false),
            precisions: F32_ONLY,
            tol: FILTER_TOL,
            ..base(
                "cross-filter",
                "cross-regression: 11x11 spatiotemporal cross-bilateral filter of both pilots (outputs A, B, combined)",
                vec![
                    image(Radiance),
                    image(Previous),
                    full(Albedo, 3, Kind::Unit),
                    full(Normal, 3, Kind::Unit),
                    full(Position, 3, Kind::Plain),
                    full(Alpha, 1, Kind::Unit),
                    logits(6),
                ],
                per_f32!(One, k_cross_filter, s_cross_filter),
            )
        },
        Op {
            oracle: |i, _| {
                let [pa, pb, alb, nrm, prev, valid] = cross_filter_oracle(i);
                let f = oracle::CrossFilter {
                    pa: &pa,
                    pb: &pb,
                    alb: &alb,
                    nrm: &nrm,
                    prev: &prev,
                    valid: &valid,
                    w: i.w,
                    h: i.h,
                };
                f.backward(&i.f64(Logits), &i.f64(Grad)[..6 * i.w * i.h])
            },
            out: (6, false),
            precisions: F32_ONLY,
            tol: FILTER_GRAD_TOL,
            ..base(
                "cross-filter-grad",
                "backward: the spatiotemporal filter's gradient by the network's six raw outputs",
                vec![
                    image(Radiance),
                    image(Previous),
                    full(Albedo, 3, Kind::Unit),
                    full(Normal, 3, Kind::Unit),
                    full(Position, 3, Kind::Plain),
                    full(Alpha, 1, Kind::Unit),
                    logits(6),
                    full(Grad, 6, Kind::Image),
                ],
                per_f32!(One, k_cross_filter_grad, s_cross_filter),
            )
        },
    ]
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

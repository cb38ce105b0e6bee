//! The core as a `no_std` caller uses it: every buffer a fixed-size array,
//! scratch sized once from the core's `*_scratch_len` functions, the
//! instruction set picked explicitly, errors as values, and no allocation.
//!
//! The pipeline is a small kernel-predicting filter on a 32x32 tile of
//! 3-channel radiance: per-pixel logits over a 7x7 window (a Gaussian whose
//! width grows from left to right, standing in for a network's output) go
//! through [`softmax::channel_softmax`] into normalised kernels, which
//! [`unfold::apply`] applies to the noisy tile. It runs in f32 on every
//! instruction set this CPU has and in fixed point (i16 storage, integer
//! arithmetic: what a part without an FPU runs), and compares each to f32
//! on the portable scalar path.
//!
//! `denoise_tile` uses nothing but `core`; `main` (std, for printing) counts
//! heap allocations around it to show there are none.
//!
//! ```sh
//! cargo run --release -p mcdenoise-core --example fixed_buffers
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

use mcdenoise_core::fixed::{self, KERNEL_FRAC, LOGIT_FRAC};
use mcdenoise_core::softmax::{self, SoftmaxPrecision};
use mcdenoise_core::unfold::{self, UnfoldPrecision};
use mcdenoise_core::{Error, Fixed, Isa, View, ViewMut, F32};

/// Tile width and height.
const W: usize = 32;
const H: usize = 32;
const N: usize = W * H;
/// Radiance channels.
const RGB: usize = 3;
/// Kernel size and taps.
const K: usize = 7;
const TAPS: usize = K * K;
/// Scratch words reserved for the apply. The core's need depends on the
/// target (its x86_64 SIMD paths stage a row of every channel); `denoise_tile`
/// checks it against `unfold::scratch_len` and refuses to run on too little.
const SCRATCH: usize = 256;
/// Fixed point: radiance in Q7.8 (values below 128, steps of 1/256).
const RADIANCE_FRAC: i8 = 8;

/// Every buffer of one tile, in one place: on a microcontroller this is a
/// `static`, here a local on the stack (about 400 KiB in f32).
struct Tile<T> {
    radiance: [T; RGB * N],
    logits: [T; TAPS * N],
    kernels: [T; TAPS * N],
    out: [T; RGB * N],
    scratch: [f32; SCRATCH],
}

/// What a storage type needs for this example: one value from an f32 in a
/// given fixed-point format, and back.
trait Store: Copy + Default {
    fn from_f32(v: f32, frac: i8) -> Self;
    fn to_f32(self, frac: i8) -> f32;
}
impl Store for f32 {
    fn from_f32(v: f32, _: i8) -> Self {
        v
    }
    fn to_f32(self, _: i8) -> f32 {
        self
    }
}
impl Store for i16 {
    fn from_f32(v: f32, frac: i8) -> Self {
        fixed::from_f32(v, frac)
    }
    fn to_f32(self, frac: i8) -> f32 {
        self as f32 * fixed::pow2(-frac)
    }
}

impl<T: Store> Tile<T> {
    fn new() -> Self {
        Tile {
            radiance: [T::default(); RGB * N],
            logits: [T::default(); TAPS * N],
            kernels: [T::default(); TAPS * N],
            out: [T::default(); RGB * N],
            scratch: [0.0; SCRATCH],
        }
    }

    /// A smooth image with +-50% of deterministic noise, and the logits of a
    /// Gaussian window whose standard deviation goes from 0.6 to 2.5 pixels.
    fn fill(&mut self) {
        let mut state = 0x2545_f491u32;
        for c in 0..RGB {
            for y in 0..H {
                for x in 0..W {
                    state ^= state << 13;
                    state ^= state >> 17;
                    state ^= state << 5;
                    let noise = (state >> 8) as f32 / (1u32 << 24) as f32 - 0.5;
                    let clean = 0.2 + 0.6 * (x + y) as f32 / (W + H) as f32 + 0.1 * c as f32;
                    self.radiance[(c * H + y) * W + x] = T::from_f32(clean * (1.0 + noise), RADIANCE_FRAC);
                }
            }
        }
        for j in 0..TAPS {
            let (dy, dx) = ((j / K) as f32 - 3.0, (j % K) as f32 - 3.0);
            for y in 0..H {
                for x in 0..W {
                    let sigma = 0.6 + 1.9 * x as f32 / (W - 1) as f32;
                    let logit = -(dx * dx + dy * dy) / (2.0 * sigma * sigma);
                    self.logits[(j * H + y) * W + x] = T::from_f32(logit, LOGIT_FRAC);
                }
            }
        }
    }
}

/// The pipeline: logits -> kernels (softmax over the 49 planes at every
/// pixel) -> the kernels applied to the radiance. `core` only: no allocation,
/// no panic on bad shapes (an [`Error`] comes back).
fn denoise_tile<P>(isa: Isa, t: &mut Tile<P::Store>) -> Result<(), Error>
where
    P: SoftmaxPrecision + UnfoldPrecision,
{
    let need = unfold::scratch_len::<P>(K, RGB, W);
    if need > SCRATCH {
        return Err(Error::BufferTooSmall { what: "apply scratch", needed: need, got: SCRATCH });
    }
    // The formats matter in fixed point only (f32 ignores them).
    let logits = View::new(&t.logits, TAPS, W, H)?.with_frac(LOGIT_FRAC);
    let mut kernels = ViewMut::new(&mut t.kernels, TAPS, W, H)?.with_frac(KERNEL_FRAC);
    softmax::channel_softmax::<P>(isa, &logits, &mut kernels)?;
    let kernels = View::new(&t.kernels, TAPS, W, H)?.with_frac(KERNEL_FRAC);
    let radiance = View::new(&t.radiance, RGB, W, H)?.with_frac(RADIANCE_FRAC);
    let mut out = ViewMut::new(&mut t.out, RGB, W, H)?.with_frac(RADIANCE_FRAC);
    unfold::apply::<P>(isa, K, &kernels, &radiance, &mut out, &mut t.scratch[..need])
}

/// Counts allocations, to show `denoise_tile` makes none.
struct Counting;
static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
// SAFETY: forwards to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: the caller's contract is the system allocator's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
}
#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Runs the pipeline and returns the output as f32, checking that it
/// allocated nothing.
fn run<P>(isa: Isa) -> Result<Vec<f32>, Error>
where
    P: SoftmaxPrecision + UnfoldPrecision,
    P::Store: Store,
{
    // The tile is boxed only because 400 KiB is more than a test thread's
    // stack; `denoise_tile` sees plain arrays.
    let mut tile: Box<Tile<P::Store>> = Box::new(Tile::new());
    tile.fill();
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    denoise_tile::<P>(isa, &mut tile)?;
    let allocated = ALLOCATIONS.load(Ordering::Relaxed) - before;
    assert_eq!(allocated, 0, "the core allocated");
    Ok(tile.out.iter().map(|v| v.to_f32(RADIANCE_FRAC)).collect())
}

fn main() -> Result<(), Error> {
    // Scalar is always there; the detected ISA is the widest this CPU runs.
    println!("detected instruction set: {}", Isa::detect().name());
    println!("apply scratch: {} f32 words on this target (reserved {SCRATCH})", unfold::scratch_len::<F32>(K, RGB, W));
    let reference = run::<F32>(Isa::Scalar)?;
    let noisy = {
        let mut t: Box<Tile<f32>> = Box::new(Tile::new());
        t.fill();
        t.radiance.to_vec()
    };
    let spread = |v: &[f32]| {
        // Mean absolute difference between horizontal neighbours in the
        // right half, where the window is widest: lower is smoother.
        let mut s = 0.0;
        for c in 0..RGB {
            for y in 0..H {
                for x in W / 2..W - 1 {
                    s += (v[(c * H + y) * W + x + 1] - v[(c * H + y) * W + x]).abs();
                }
            }
        }
        s / (RGB * H * (W / 2 - 1)) as f32
    };
    println!("neighbour difference, right half: noisy {:.4}, filtered {:.4}", spread(&noisy), spread(&reference));
    for isa in Isa::ALL {
        if !isa.is_supported() {
            println!("{:<7} not on this CPU: skipped", isa.name());
            continue;
        }
        for (precision, out) in [("f32", run::<F32>(isa)?), ("fixed", run::<Fixed>(isa)?)] {
            let max_diff = out.iter().zip(&reference).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            println!("{:<7} {precision:<6} max |difference| from f32 scalar: {max_diff:.2e}", isa.name());
            // Fixed point: the radiance's 1/256 steps and the taps' 1/16384.
            assert!(max_diff < if precision == "f32" { 1e-5 } else { 2e-2 }, "{precision} on {}", isa.name());
        }
    }
    Ok(())
}

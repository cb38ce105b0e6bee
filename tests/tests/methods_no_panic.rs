//! Nothing reachable from the host library's public method API panics on
//! caller input: [`methods::create`] and [`Denoiser::denoise`] of every
//! method in every precision, handed sequences whose frames change size,
//! are empty, lack or gain buffers, hold extreme or non-finite values; and
//! the network engine's public entry points ([`Trainer`], [`Inference`])
//! with wrong parameter counts and varying sizes. `Ok` or `Err`, never a
//! panic.

use std::panic::{catch_unwind, AssertUnwindSafe};

use mcdenoise::io::frame::{Buffer, Frame};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::nn::infer::Inference;
use mcdenoise::nn::Trainer;
use mcdenoise::runtime::precision::{Planes, PrecisionKind};
use mcdenoise::runtime::Ctx;
use mcdenoise_core::F32;
use proptest::prelude::*;

/// One frame of a random sequence.
#[derive(Clone, Debug)]
struct FrameSpec {
    w: usize,
    h: usize,
    /// Which optional buffers it carries (bit per buffer of `OPTIONAL`).
    buffers: u8,
    /// Which value family fills it.
    values: u8,
    seed: u64,
}

const OPTIONAL: [Buffer; 6] =
    [Buffer::ColorB, Buffer::Albedo, Buffer::Normal, Buffer::Depth, Buffer::Position, Buffer::Motion];

fn value(family: u8, i: usize, seed: u64) -> f32 {
    let u = ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ seed).wrapping_mul(0xBF58_476D_1CE4_E5B9) >> 40;
    let u = u as f32 / (1u64 << 24) as f32;
    match family % 6 {
        0 => u,
        1 => u * 1e4,
        2 => [0.0, f32::NAN, f32::INFINITY, -f32::INFINITY, 1e30, -1.0][i % 6],
        3 => 0.0,
        4 => u * 1e-30,
        _ => 65504.0 * (u - 0.5),
    }
}

fn frame(s: &FrameSpec) -> Frame {
    let n = s.w * s.h;
    let color = (0..3 * n).map(|i| value(s.values, i, s.seed)).collect();
    let mut f = Frame::from_color("random.exr", s.w, s.h, color).expect("3 planes");
    for (k, b) in OPTIONAL.iter().enumerate() {
        if s.buffers & (1 << k) != 0 {
            let data =
                (0..b.channels() * n).map(|i| value(s.values.wrapping_add(k as u8), i, s.seed + k as u64)).collect();
            f.set(*b, data).expect("planes of the frame's size");
        }
    }
    f
}

fn frame_spec() -> impl Strategy<Value = FrameSpec> {
    (0usize..12, 0usize..10, any::<u8>(), 0u8..6, any::<u64>()).prop_map(|(w, h, buffers, values, seed)| FrameSpec {
        w,
        h,
        buffers,
        values,
        seed,
    })
}

/// Mostly a consistent sequence (one size, one set of buffers), sometimes
/// not.
fn sequence() -> impl Strategy<Value = Vec<FrameSpec>> {
    (frame_spec(), prop::collection::vec((any::<bool>(), frame_spec()), 1..4)).prop_map(|(first, rest)| {
        let mut v = vec![first.clone()];
        for (same, other) in rest {
            v.push(if same { FrameSpec { seed: other.seed, ..first.clone() } } else { other });
        }
        v
    })
}

fn run_sequence(kind: MethodKind, precision: PrecisionKind, layers: usize, frames: &[Frame]) {
    let settings = Settings { precision, threads: 2, layers, ..Settings::default() };
    let Ok(mut den) = methods::create(kind, &settings, &frames[0]) else { return };
    let mut ctx = methods::context(&settings).expect("a context");
    let mut t = Timings::default();
    for f in frames {
        if let Ok(out) = den.denoise(f, &mut ctx, &mut t) {
            assert_eq!(out.len(), 3 * f.width * f.height, "{kind:?}: the output has the frame's size");
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: mcdenoise_tests::cases(96), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn no_method_panics_on_caller_frames(seq in sequence(), which in 0usize..16) {
        let frames: Vec<Frame> = seq.iter().map(frame).collect();
        let (kind, layers) = match which % 8 {
            0 => (MethodKind::None, 6),
            1 => (MethodKind::Ta, 6),
            2 => (MethodKind::Atrous, 6),
            3 => (MethodKind::SureAtrous, 6),
            4 => (MethodKind::Wskp, 3),
            5 => (MethodKind::Wskp, 6),
            6 => (MethodKind::Afn, 6),
            _ => (MethodKind::Cross, 6),
        };
        let precision = [PrecisionKind::F32, PrecisionKind::F16, PrecisionKind::Fixed][which / 8 % 3];
        let r = catch_unwind(AssertUnwindSafe(|| run_sequence(kind, precision, layers, &frames)));
        prop_assert!(r.is_ok(), "{kind:?} {precision:?} panicked on {seq:?}");
    }
}

/// A frame that changes size mid-sequence is an error naming both sizes,
/// for every method (cross-regression used to panic in a slice copy).
#[test]
fn a_size_change_is_an_error_naming_both_sizes() {
    let spec = |w, h| FrameSpec { w, h, buffers: 0xff, values: 0, seed: 3 };
    for kind in MethodKind::ALL {
        let settings = Settings { threads: 2, ..Settings::default() };
        let first = frame(&spec(9, 7));
        let mut den = match methods::create(kind, &settings, &first) {
            Ok(d) => d,
            Err(e) => panic!("{kind:?}: {e}"),
        };
        let mut ctx = methods::context(&settings).unwrap();
        let mut t = Timings::default();
        den.denoise(&first, &mut ctx, &mut t).unwrap();
        let e = den.denoise(&frame(&spec(10, 7)), &mut ctx, &mut t).unwrap_err().to_string();
        assert!(e.contains("10x7") && e.contains("9x7"), "{kind:?}: {e}");
    }
}

/// An empty frame is refused when a method is built from it.
#[test]
fn an_empty_first_frame_is_refused() {
    for kind in MethodKind::ALL {
        let f = Frame::from_color("empty.exr", 0, 0, Vec::new()).unwrap();
        let e = methods::create(kind, &Settings::default(), &f).err().map(|e| e.to_string());
        assert!(e.as_deref().is_some_and(|e| e.contains("empty")), "{kind:?}: {e:?}");
    }
}

/// The trainer refuses parameters of the wrong count and empty crops.
#[test]
fn trainer_refuses_inconsistent_arguments() {
    let net = mcdenoise::methods::wskp::net(3).unwrap();
    assert!(Trainer::new(net.clone(), vec![0.0; net.params - 1], 1, 8, 8, 1e-3, 0.0).is_err());
    assert!(Trainer::new(net.clone(), net.init(1), 0, 8, 8, 1e-3, 0.0).is_err());
    assert!(Trainer::new(net.clone(), net.init(1), 1, 0, 8, 1e-3, 0.0).is_err());
    let mut tr = Trainer::new(net.clone(), net.init(1), 1, 8, 8, 1e-3, 0.0).unwrap();
    assert!(tr.set_params(vec![0.0; 3]).is_err());
    assert!(tr.set_params(net.init(2)).is_ok());
}

/// Inference over frames of changing sizes keeps the buffers of one size
/// only: its memory does not grow with the number of sizes seen.
#[test]
fn inference_memory_is_bounded_over_sizes() {
    let net = mcdenoise::methods::wskp::net(3).unwrap();
    let params = net.init(5);
    let mut inf = Inference::<F32>::new(&net, &params, None, None).unwrap();
    let mut ctx = Ctx::new(2, mcdenoise_core::Isa::detect()).unwrap();
    let mut held = Vec::new();
    for (w, h) in [(16, 12), (17, 12), (16, 13), (30, 5), (16, 12), (9, 9), (40, 3), (16, 12)] {
        let x = Planes::<f32>::from_vec(mcdenoise::methods::wskp::CIN, w, h, vec![0.25; 10 * w * h]);
        let out = inf.run(&mut ctx, x).unwrap();
        assert_eq!((out.width, out.height), (w, h));
        held.push(inf.held_bytes());
    }
    // After a run the engine holds the buffers of that run's size only.
    let one = |w: usize, h: usize| mcdenoise::nn::infer::tensors_bytes_per_pixel(&net, 4) * (w * h) as u64;
    for (i, (&b, (w, h))) in
        held.iter().zip([(16, 12), (17, 12), (16, 13), (30, 5), (16, 12), (9, 9), (40, 3), (16, 12)]).enumerate()
    {
        assert!(b <= one(w, h), "run {i} ({w}x{h}): {b} bytes held, the tensors of one frame are {}", one(w, h));
    }
}

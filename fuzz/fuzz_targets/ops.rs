//! Differential fuzzing of every operator of the registry: any size, value
//! scale, seed, precision and special value the fuzzer finds, run on the
//! scalar path and on each SIMD path this CPU has, strided with poisoned
//! padding. Fixed point must agree bit for bit (where the registry says its
//! paths are exact), floats within a few ulp of the output's range; the
//! output's padding must stay untouched; and on sanitised radiance (the
//! stability contract) every output must be finite, whatever the logits
//! (NaN and infinities included). A machine without a SIMD path fails the
//! target: it would otherwise compare nothing.
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use mcdenoise::runtime::par::Pool;
use mcdenoise::runtime::precision::PrecisionKind;
use mcdenoise_kit::registry::{self, Config, Field, Inputs, Layout};
use mcdenoise_core::Isa;

#[derive(Arbitrary, Debug)]
struct Case {
    op: u8,
    precision: u8,
    w: u8,
    h: u8,
    pad: u8,
    scale: u8,
    seed: u64,
    specials: Vec<(u16, u8)>,
}

const SPECIALS: [f32; 10] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, 1e-30, 65504.0, 70000.0, 1e6, -5.0];

fn special(v: &mut [f32], at: &[(u16, u8)]) {
    for &(pos, sp) in at {
        let i = pos as usize % v.len();
        v[i] = SPECIALS[sp as usize % SPECIALS.len()];
    }
}

fuzz_target!(|c: Case| {
    assert!(Isa::Avx2.is_supported(), "no SIMD path on this machine: the differential target would compare nothing");
    let ops = registry::ops();
    let op = &ops[c.op as usize % ops.len()];
    let prec = op.precisions[c.precision as usize % op.precisions.len()];
    let (w, h) = (c.w as usize % 48 + 1, c.h as usize % 24 + 1);
    let mut inputs = Inputs::synth(w, h, c.seed);
    // Radiance-like fields scaled, with specials, then sanitised as the host
    // does on load (NaN to 0, clamp to the precision's range).
    let mag = [1.0f32, 100.0, 1e4, 1e-3][c.scale as usize % 4];
    let limit = if prec == PrecisionKind::F32 { 1e20 } else { 65504.0 };
    for (k, f) in [Field::Radiance, Field::Previous, Field::Coarse, Field::Features].into_iter().enumerate() {
        let mut v: Vec<f32> = inputs.get(f).iter().map(|&x| (x - 0.05) * mag).collect();
        special(&mut v, c.specials.get(k * 4..(k * 4 + 4).min(c.specials.len())).unwrap_or(&[]));
        inputs.set(f, v.into_iter().map(|x| if x.is_nan() { 0.0 } else { x.clamp(-limit, limit) }).collect());
    }
    // Logits are taken as they come (NaN weighs 0, infinities are clamped).
    for (k, f) in [Field::Logits, Field::Fusion].into_iter().enumerate() {
        let mut v = inputs.get(f).to_vec();
        special(&mut v, c.specials.get(16 + k * 4..(20 + k * 4).min(c.specials.len())).unwrap_or(&[]));
        inputs.set(f, v);
    }
    let pool = Pool::new(1).unwrap();
    // A fixed output format from the oracle of the unspecialised inputs.
    let out_frac = op.fixed_frac(&(op.oracle)(&Inputs::synth(w, h, c.seed), &pool));
    let layout = Layout { pad: c.pad as usize % 4 };
    let run = |isa: Isa| {
        let mut job = op.prepare(prec, Config { isa, layout, out_frac }, &inputs).unwrap();
        job.run(&pool).unwrap();
        assert!(job.padding_intact(), "{} {} {}: wrote into the padding", op.name, prec.name(), isa.name());
        job.output()
    };
    let scalar = run(Isa::Scalar);
    assert!(
        scalar.iter().all(|x| x.is_finite()),
        "{} {}: non-finite output from sanitised input",
        op.name,
        prec.name()
    );
    let peak = scalar.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for isa in [Isa::Avx2, Isa::Avx512].into_iter().filter(|i| i.is_supported()) {
        let simd = run(isa);
        if prec == PrecisionKind::Fixed && op.fixed_exact {
            assert!(simd == scalar, "{} fixed point: {} differs from scalar", op.name, isa.name());
        } else {
            // f32 differs by FMA and exp rounding; f16 storage can then round
            // to neighbouring f16 values (2^-10 relative).
            let ulp = if prec == PrecisionKind::F32 { 0.0 } else { 1.0 / 1024.0 };
            for (i, (&x, &y)) in simd.iter().zip(&scalar).enumerate() {
                let ok = x == y || (x - y).abs() <= 1e-4 * (peak + 1.0) + (1e-4 + ulp) * y.abs();
                assert!(ok, "{} {} {}: element {i}: SIMD {x} vs scalar {y}", op.name, prec.name(), isa.name());
            }
        }
    }
});

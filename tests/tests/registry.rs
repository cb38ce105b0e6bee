//! Every operator of the registry x every precision x every instruction set
//! this CPU has, at odd sizes (widths 1, 9, 17 so every SIMD remainder loop
//! runs, and a wider one), packed and strided with poisoned padding: against
//! the f64 oracle within the operator's tolerance, the padding of the output
//! untouched (and the poison in the inputs' padding never read: it would
//! show as a NaN or a wrong value), fixed point bit-identical across ISAs,
//! and every result bit-identical for 1 and 3 threads.

use mcdenoise::runtime::par::Pool;
use mcdenoise::runtime::precision::PrecisionKind;
use mcdenoise_core::Isa;
use mcdenoise_kit::registry::{errors, ops, Config, Inputs, Layout};
use mcdenoise_tests::isas_under_test;

const SIZES: [(usize, usize); 5] = [(1, 1), (9, 5), (17, 13), (1, 9), (37, 21)];

#[test]
fn every_operator_precision_and_isa_matches_the_oracle() {
    let one = Pool::new(1).unwrap();
    let three = Pool::new(3).unwrap();
    let isas = isas_under_test();
    let mut checked = 0;
    // MCDENOISE_TOL_REPORT=1: print each operator's and precision's worst
    // ratio to its tolerance instead of failing on the first (for setting them).
    let survey = std::env::var("MCDENOISE_TOL_REPORT").is_ok();
    for op in ops() {
        let mut worst = [0.0f64; 4];
        for (si, &(w, h)) in SIZES.iter().enumerate() {
            let inputs = Inputs::synth(w, h, 11 + si as u64);
            let want = (op.oracle)(&inputs, &one);
            let (oc, ow, oh) = op.out_shape(w, h);
            assert_eq!(want.len(), oc * ow * oh, "{}: oracle length", op.name);
            for &p in op.precisions {
                let tol = op.tolerance(p);
                let out_frac = op.fixed_frac(&want);
                let mut scalar: Option<Vec<f32>> = None;
                for &isa in &isas {
                    for pad in [0, 3] {
                        let cfg = Config { isa, layout: Layout { pad }, out_frac };
                        let what = format!("{} {} {} {w}x{h} pad {pad}", op.name, p.name(), isa.name());
                        let mut run = op.prepare(p, cfg, &inputs).unwrap();
                        run.run(&one).unwrap_or_else(|e| panic!("{what}: {e}"));
                        let got = run.output();
                        assert!(run.padding_intact(), "{what}: wrote into the output's padding");
                        let e = errors(&got, &want, tol);
                        let pi = PrecisionKind::ALL.iter().position(|&q| q == p).unwrap();
                        worst[pi] = worst[pi].max(e.worst);
                        assert!(
                            survey || e.worst <= 1.0,
                            "{what}: element {} is {} but the oracle says {} ({:.2} times the tolerance {:?})",
                            e.at,
                            got[e.at],
                            want[e.at],
                            e.worst,
                            tol
                        );
                        // Thread-count independence, bit for bit.
                        let mut run3 = op.prepare(p, cfg, &inputs).unwrap();
                        run3.run(&three).unwrap();
                        let got3 = run3.output();
                        assert!(
                            got.iter().zip(&got3).all(|(a, b)| a.to_bits() == b.to_bits()),
                            "{what}: 3 threads differ from 1"
                        );
                        if pad == 0 {
                            match (&scalar, isa) {
                                (None, Isa::Scalar) => scalar = Some(got),
                                (Some(s), _) if p == PrecisionKind::Fixed && op.fixed_exact => {
                                    assert!(s == &got, "{what}: fixed point differs from scalar");
                                }
                                _ => {}
                            }
                        }
                        checked += 1;
                    }
                }
            }
        }
        if survey {
            eprintln!(
                "{:<14} worst/tol f32 {:.3} f16 {:.3} f16-arith {:.3} fixed {:.3}",
                op.name, worst[0], worst[1], worst[2], worst[3]
            );
        }
    }
    eprintln!("{checked} operator runs checked");
    assert!(checked > 0);
}

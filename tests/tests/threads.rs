//! Thread-count independence of every method: each method, in every
//! precision and on every instruction set this CPU has, gives bit-identical
//! outputs on 1, 2 and 3 threads over a rendered sequence (the kernels
//! compute each output from its position alone, and the host's bands only
//! decide who computes it). With and without the second estimate, so both
//! à-trous noise paths run.

use std::path::Path;

use mcdenoise::io::frame::{Buffer, Frame, Limits};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::runtime::precision::PrecisionKind;
use mcdenoise_tests::isas_under_test;

fn sequence(drop_b: bool) -> Vec<Frame> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/seq_small");
    (0..4)
        .map(|i| {
            let mut f = Frame::load(&dir.join(format!("frame_{i:04}.exr")), &Limits::default()).unwrap();
            if drop_b {
                f.remove(Buffer::ColorB);
            }
            f
        })
        .collect()
}

#[test]
fn every_method_is_thread_count_independent() {
    for drop_b in [false, true] {
        let frames = sequence(drop_b);
        for kind in MethodKind::ALL {
            for precision in PrecisionKind::ALL {
                // Cross-regression needs the second estimate and trains in f32 whatever the precision.
                if kind == MethodKind::Cross && (drop_b || precision != PrecisionKind::F32) {
                    continue;
                }
                for isa in isas_under_test() {
                    let run = |threads: usize| -> Vec<Vec<f32>> {
                        let settings = mcdenoise_tests::settings_for(
                            kind,
                            Settings { isa, threads, precision, ..Settings::default() },
                        );
                        let mut den = methods::create(kind, &settings, &frames[0]).unwrap();
                        let mut ctx = methods::context(&settings).unwrap();
                        let mut t = Timings::default();
                        frames.iter().map(|f| den.denoise(f, &mut ctx, &mut t).unwrap()).collect()
                    };
                    let one = run(1);
                    for threads in [2, 3] {
                        let many = run(threads);
                        for (i, (a, b)) in one.iter().zip(&many).enumerate() {
                            assert!(
                                a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
                                "{} {} {} (B {}): frame {i} differs between 1 and {threads} threads",
                                kind.name(),
                                precision.name(),
                                isa.name(),
                                if drop_b { "dropped" } else { "kept" }
                            );
                        }
                    }
                }
            }
        }
    }
}

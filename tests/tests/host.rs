//! Host behaviour: thread-count independence, temporal accumulation against
//! an independent recurrence, stage planning from the channels present.

use std::path::Path;

use mcdenoise::frame::{Buffer, Frame, Limits};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::par::{Pool, Scratch};
use mcdenoise::precision::PrecisionKind;
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::{Isa, ViewMut, F32};
use mcdenoise_tests::{isas_under_test, Img};

fn fixture(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join(p)
}

fn run_method(kind: MethodKind, threads: usize, isa: Isa, dir: &Path) -> Vec<Vec<f32>> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "exr"))
        .collect();
    files.sort();
    let settings = mcdenoise_tests::settings_for(
        kind,
        Settings { isa, threads, precision: PrecisionKind::F32, phi_color: None, ..Settings::default() },
    );
    let first = Frame::load(&files[0], &Limits::default()).unwrap();
    let mut den = methods::create(kind, &settings, &first).unwrap();
    let mut ctx = methods::context(&settings).unwrap();
    let mut t = Timings::default();
    files.iter().map(|f| den.denoise(&Frame::load(f, &Limits::default()).unwrap(), &mut ctx, &mut t).unwrap()).collect()
}

#[test]
fn methods_are_bit_identical_for_one_and_two_threads() {
    for isa in isas_under_test() {
        for kind in MethodKind::ALL {
            let one = run_method(kind, 1, isa, &fixture("seq_small"));
            let two = run_method(kind, 2, isa, &fixture("seq_small"));
            assert_eq!(one, two, "{kind:?} {isa:?}");
        }
    }
}

#[test]
fn fused_filter_is_bit_identical_for_any_thread_count() {
    let (w, h) = (301, 203);
    let sizes = [3, 5, 7, 9, 11, 13];
    let imp = Img::random(6, w, h, -30.0, 30.0, 1);
    let fus = Img::random(6, w, h, -5.0, 5.0, 2);
    let rad = Img::random(3, w, h, 0.0, 10.0, 3);
    let inp = FusedInputs {
        sizes: &sizes,
        importance: imp.view(),
        fusion: Some(fus.view()),
        albedo: None,
        radiance: rad.view(),
    };
    for isa in isas_under_test() {
        let mut results = Vec::new();
        for threads in [1, 2, 3] {
            let pool = Pool::new(threads).unwrap();
            let mut scratch = Scratch::new();
            let mut out = vec![0.0f32; 3 * w * h];
            let len = softmax::fused_scratch_len::<F32>(WindowPath::BoxSum, &sizes, 3, w);
            // Bands deliberately not aligned to the kernel's tile grid.
            pool.bands(ViewMut::new(&mut out, 3, w, h).unwrap(), 1, &mut scratch, len, |band, y0, s| {
                softmax::fused_filter::<F32>(isa, WindowPath::BoxSum, &inp, band, y0, s)
            })
            .unwrap();
            results.push(out);
        }
        assert_eq!(results[0], results[1], "{isa:?}");
        assert_eq!(results[0], results[2], "{isa:?}");
    }
}

/// Builds an in-memory frame with colour `c`, zero motion and fixed geometry.
fn static_frame(w: usize, h: usize, c: f32, pos_offset: f32) -> Frame {
    let n = w * h;
    let mut f = Frame::from_color("mem.exr", w, h, vec![c; 3 * n]).unwrap();
    f.set(Buffer::Motion, vec![0.0; 2 * n]).unwrap();
    let mut pos = vec![0.0; 3 * n];
    for i in 0..n {
        pos[i] = (i % w) as f32 * 0.01 + pos_offset;
        pos[n + i] = (i / w) as f32 * 0.01;
        pos[2 * n + i] = 1.0;
    }
    f.set(Buffer::Position, pos).unwrap();
    let mut nrm = vec![0.0; 3 * n];
    nrm[2 * n..].fill(1.0);
    f.set(Buffer::Normal, nrm).unwrap();
    f
}

#[test]
fn temporal_accumulation_follows_the_blend_recurrence() {
    let (w, h) = (9, 7);
    let colours = [1.0f32, 3.0, 0.5, 8.0, 2.0, 2.0, 7.0, 0.0, 1.0];
    for isa in isas_under_test() {
        let settings =
            Settings { isa, threads: 2, precision: PrecisionKind::F32, phi_color: None, ..Settings::default() };
        let first = static_frame(w, h, colours[0], 0.0);
        let mut den = methods::create(MethodKind::Ta, &settings, &first).unwrap();
        let mut ctx = methods::context(&settings).unwrap();
        let mut t = Timings::default();
        // Independent recurrence: n counts accepted history, alpha = max(1/(n+1), 0.2).
        let (mut acc, mut n) = (0.0f64, 0.0f64);
        for (i, &c) in colours.iter().enumerate() {
            let out = den.denoise(&static_frame(w, h, c, 0.0), &mut ctx, &mut t).unwrap();
            if i == 0 {
                acc = c as f64;
            } else {
                let alpha = (1.0 / (n + 1.0)).max(0.2);
                acc = alpha * c as f64 + (1.0 - alpha) * acc;
                n += 1.0;
            }
            for v in &out {
                assert!((*v as f64 - acc).abs() <= 1e-5 * acc.abs().max(1.0), "{isa:?} frame {i}: {v} vs {acc}");
            }
        }
        // A frame whose geometry moved far away restarts every pixel.
        let out = den.denoise(&static_frame(w, h, 5.0, 100.0), &mut ctx, &mut t).unwrap();
        assert!(out.iter().all(|&v| v == 5.0), "{isa:?}: rejected history must restart");
    }
}

#[test]
fn plans_follow_the_channels_present() {
    let settings = Settings::default();
    let mut f = static_frame(4, 4, 1.0, 0.0);
    let ta = methods::create(MethodKind::Ta, &settings, &f).unwrap();
    assert!(ta.plan().skipped.is_empty(), "{:?}", ta.plan());
    f.remove(Buffer::Motion);
    f.remove(Buffer::Normal);
    let ta = methods::create(MethodKind::Ta, &settings, &f).unwrap();
    let line = ta.plan().line("ta");
    assert!(
        line.contains("motion reprojection (no motion vectors") && line.contains("normal test (no normal)"),
        "{line}"
    );
    f.remove(Buffer::Position);
    let err = methods::create(MethodKind::Ta, &settings, &f).err().expect("ta needs motion or position").to_string();
    assert!(err.contains("motion") && err.contains("position"), "{err}");
}

#[test]
fn loader_sanitises_non_finite_values() {
    let t = std::env::temp_dir().join(format!("mcd-nan-{}.exr", std::process::id()));
    let mut v = vec![0.25f32; 12];
    v[0] = f32::NAN;
    v[1] = f32::INFINITY;
    v[2] = f32::NEG_INFINITY;
    mcdenoise::output::write_exr(&t, 4, 3, &[("R", &v), ("G", &v), ("B", &v)], false).unwrap();
    let f = Frame::load(&t, &Limits::default()).unwrap();
    std::fs::remove_file(&t).unwrap();
    let c = f.get(Buffer::Color).unwrap();
    assert_eq!(f.replaced_nonfinite, 9);
    assert_eq!((c[0], c[1], c[2]), (0.0, mcdenoise::frame::VALUE_LIMIT, -mcdenoise::frame::VALUE_LIMIT));
    assert!(c.iter().all(|v| v.is_finite()));
}

//! The classical denoisers on the rendered test corpus (tests/fixtures/corpus,
//! made by tools/render-corpus.sh from tools/scenes/corpus/*.json): Mitsuba's
//! Cornell box at 4, 16 and 64 spp, a written-out Cornell box whose light
//! has albedo 0 (same spp), a glossy room with camera motion, an HDR room
//! (a visible bulb of radiance 1000, near-black walls, Mitsuba's albedo AOV
//! up to ~10 on metals, fireflies through glass), a dim room at 1 spp, and
//! a room of metals, glass, near-black paint and a dark texture rendered
//! with Mitsuba's raw albedo AOV (the demodulation's hard cases).
//! Every frame is used as it is (A and B) and with `B.*` dropped (one
//! estimate). Scores are against the high-spp references, with the display
//! map of `mcdenoise::metrics` (clamp to [0, 1], gamma 1/2.2).

use std::path::{Path, PathBuf};

use mcdenoise::io::frame::{Buffer, Frame, Limits};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::metrics;
use mcdenoise::runtime::precision::PrecisionKind;

fn corpus(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures").join("corpus").join(p)
}

/// A scene of the corpus: frames and the matching references.
struct Scene {
    name: &'static str,
    frames: Vec<Frame>,
    refs: Vec<Vec<f32>>,
}

fn frames_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "exr"))
        .collect();
    v.sort();
    v
}

fn load(name: &'static str, dir: &str, refdir: &str, pair: bool) -> Scene {
    let lim = Limits::default();
    let frames: Vec<Frame> = frames_in(&corpus(dir))
        .iter()
        .map(|p| {
            let mut f = Frame::load(p, &lim).unwrap();
            assert!(f.has(Buffer::ColorB), "{}: the corpus frames carry B.*", p.display());
            if !pair {
                f.remove(Buffer::ColorB);
            }
            f
        })
        .collect();
    let refs: Vec<Vec<f32>> = frames
        .iter()
        .map(|f| {
            let name = f.path.file_name().unwrap();
            Frame::load(&corpus(refdir).join(name), &lim).unwrap().get(Buffer::Color).unwrap().to_vec()
        })
        .collect();
    Scene { name, frames, refs }
}

/// Every scene of the corpus, with (`pair`) or without the second estimate.
fn scenes(pair: bool) -> Vec<Scene> {
    let mut v = Vec::new();
    for (name, dir, r) in [
        ("cornell 4 spp", "cornell_4spp", "cornell_ref"),
        ("cornell 16 spp", "cornell_16spp", "cornell_ref"),
        ("cornell 64 spp", "cornell_64spp", "cornell_ref"),
        ("box 4 spp", "box_4spp", "box_ref"),
        ("box 16 spp", "box_16spp", "box_ref"),
        ("box 64 spp", "box_64spp", "box_ref"),
        ("glossy", "glossy", "glossy/ref"),
        ("hdr", "hdr", "hdr/ref"),
        ("dim", "dim", "dim/ref"),
        ("metals", "metals", "metals/ref"),
    ] {
        v.push(load(name, dir, r, pair));
    }
    v
}

/// The outputs of `kind` over the scene's frames, in sequence.
fn run(kind: MethodKind, precision: PrecisionKind, s: &Scene, firefly_clamp: Option<f32>) -> Vec<Vec<f32>> {
    run_layers(kind, 6, precision, s, firefly_clamp)
}

/// [`run`] with WSKP's network depth.
fn run_layers(
    kind: MethodKind,
    layers: usize,
    precision: PrecisionKind,
    s: &Scene,
    firefly_clamp: Option<f32>,
) -> Vec<Vec<f32>> {
    let mut settings = Settings { precision, threads: 2, layers, ..Settings::default() };
    if let Some(k) = firefly_clamp {
        settings.firefly_clamp = Some(k);
    }
    let mut den = methods::create(kind, &settings, &s.frames[0]).unwrap();
    let mut ctx = methods::context(&settings).unwrap();
    let mut t = Timings::default();
    s.frames
        .iter()
        .map(|f| {
            let o = den.denoise(f, &mut ctx, &mut t).unwrap();
            assert!(o.iter().all(|v| v.is_finite()), "{}: {kind:?} {precision:?} output is finite", s.name);
            o
        })
        .collect()
}

/// Mean over frames of the display MSE of `out` against `refs`.
fn display_mse(s: &Scene, out: &[Vec<f32>], refs: &[Vec<f32>]) -> f64 {
    let (w, h) = (s.frames[0].width, s.frames[0].height);
    let m: f64 = out.iter().zip(refs).map(|(o, r)| 10f64.powf(-metrics::score(o, r, w, h).psnr / 10.0)).sum();
    m / out.len() as f64
}

fn psnr_of(mse: f64) -> f64 {
    -10.0 * mse.log10()
}

/// The input the methods see: the mean of the pair, or the one estimate.
fn input(s: &Scene) -> Vec<Vec<f32>> {
    s.frames
        .iter()
        .map(|f| {
            let a = f.get(Buffer::Color).unwrap();
            match f.get(Buffer::ColorB) {
                Some(b) => a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)).collect(),
                None => a.to_vec(),
            }
        })
        .collect()
}

/// Every denoiser the project has, by the name the tests print, with WSKP's
/// depth: the classical ones, the learned ones with their bundled weights,
/// and cross-regression (which needs the pair).
const DENOISERS: [(&str, MethodKind, usize); 6] = [
    ("atrous", MethodKind::Atrous, 6),
    ("sure-atrous", MethodKind::SureAtrous, 6),
    ("wskp-3", MethodKind::Wskp, 3),
    ("wskp-6", MethodKind::Wskp, 6),
    ("afn", MethodKind::Afn, 6),
    ("cross", MethodKind::Cross, 6),
];

/// Whether a method filters the pair's mean (else it reads `A` only).
fn reads_pair(kind: MethodKind) -> bool {
    matches!(kind, MethodKind::Atrous | MethodKind::SureAtrous | MethodKind::Cross)
}

/// Mean over frames of relMSE (`(x - r)^2 / (r^2 + 0.01)`, linear values).
fn relmse(s: &Scene, out: &[Vec<f32>]) -> f64 {
    let (w, h) = (s.frames[0].width, s.frames[0].height);
    out.iter().zip(&s.refs).map(|(o, r)| metrics::score(o, r, w, h).relmse).sum::<f64>() / out.len() as f64
}

/// The HDR guard of the demodulation issue, for every method in every
/// precision on every scene with either noise source: relMSE (the papers'
/// HDR error) below that of the input the method reads (`A`, or the pair's
/// mean), at most a quarter of it on the 1-spp scenes; and no output
/// pixel brighter than twice the brightest reference pixel (a denoiser
/// removes fireflies, it does not make them). With the old demodulation
/// threshold a gold sphere's raw albedo split it into pixels divided by 1
/// and pixels divided by 0.01, and the filters carried the second into the
/// walls: outputs 80 times the brightest reference.
#[test]
fn every_method_lowers_hdr_error_and_makes_no_fireflies() {
    let mut bad = Vec::new();
    for pair in [true, false] {
        for s in scenes(pair) {
            let one_spp = matches!(s.name, "glossy" | "hdr" | "dim" | "metals");
            let a_only: Vec<Vec<f32>> = s.frames.iter().map(|f| f.get(Buffer::Color).unwrap().to_vec()).collect();
            let mean = input(&s);
            let brightest = s.refs.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
            for (name, kind, layers) in DENOISERS {
                if kind == MethodKind::Cross && !pair {
                    continue;
                }
                let inp = relmse(&s, if reads_pair(kind) { &mean[..] } else { &a_only[..] });
                let bar = if one_spp { inp / 4.0 } else { inp };
                let precisions: &[PrecisionKind] = if kind == MethodKind::Cross {
                    &[PrecisionKind::F32]
                } else {
                    &[PrecisionKind::F32, PrecisionKind::F16, PrecisionKind::Fixed]
                };
                for &p in precisions {
                    let out = run_layers(kind, layers, p, &s, None);
                    let rel = relmse(&s, &out);
                    let top = out.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
                    eprintln!(
                        "{} pair {pair} {name} {p:?}: relMSE {rel:.4} (input {inp:.4}), brightest {:.2}x the reference's",
                        s.name,
                        top / brightest
                    );
                    if rel.is_nan() || rel >= bar {
                        bad.push(format!("{} pair {pair} {name} {p:?}: relMSE {rel:.4}, bar {bar:.4}", s.name));
                    }
                    if top > 2.0 * brightest {
                        bad.push(format!("{} pair {pair} {name} {p:?}: {top} > 2 x {brightest}", s.name));
                    }
                }
            }
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}

/// f16 storage within 50 dB and fixed point within 38 dB (PSNR of the
/// display values) of the f32 output of the same method, on every scene,
/// with either noise source. (Fixed point with the pair on the HDR room was
/// 23 dB from f32 while the noise guide took the image format: its quiet
/// pixels' variance rounded to 0 and closed the colour gate. The bar was
/// 40 dB until the accumulation's history counted its first frame, so that
/// the second frame is a blend of two rounded in fixed point rather than
/// the frame alone, and WSKP and AFN tested their history over 33x33
/// means: WSKP-3 on the metals with one estimate went to 39.25 dB with the
/// first and 38.98 with both.)
#[test]
fn reduced_precisions_follow_f32_on_every_scene() {
    let mut bad = Vec::new();
    for pair in [true, false] {
        for s in scenes(pair) {
            let (w, h) = (s.frames[0].width, s.frames[0].height);
            for (_, kind, layers) in DENOISERS.into_iter().filter(|d| d.1 != MethodKind::Cross) {
                let f32s = run_layers(kind, layers, PrecisionKind::F32, &s, None);
                for (precision, bar) in [(PrecisionKind::F16, 50.0), (PrecisionKind::Fixed, 38.0)] {
                    let out = run_layers(kind, layers, precision, &s, None);
                    let mse = out.iter().zip(&f32s).map(|(o, r)| 10f64.powf(-metrics::score(o, r, w, h).psnr / 10.0));
                    let between = psnr_of(mse.sum::<f64>() / out.len() as f64);
                    eprintln!("{} pair {pair} {kind:?}-{layers} {precision:?}: {between:.2} dB from f32", s.name);
                    if between <= bar {
                        bad.push(format!(
                            "{} pair {pair} {kind:?}-{layers} {precision:?}: {between:.2} dB from f32",
                            s.name
                        ));
                    }
                }
            }
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}

/// The issue this corpus came with: `atrous` on a 16-spp Cornell box gained
/// only 7 dB over its input with one estimate. Now at least 9, with either
/// noise source; and every scene gains at least 5 dB (4 spp and up) or
/// 9 dB (1 spp).
#[test]
fn atrous_cleans_every_scene() {
    let mut bad = Vec::new();
    for pair in [true, false] {
        for s in scenes(pair) {
            let inp = psnr_of(display_mse(&s, &input(&s), &s.refs));
            let out = psnr_of(display_mse(&s, &run(MethodKind::Atrous, PrecisionKind::F32, &s, None), &s.refs));
            eprintln!("{} pair {pair}: input {inp:.2} dB, atrous {out:.2} dB (+{:.2})", s.name, out - inp);
            // The bar on the 16-spp Cornell box; elsewhere round
            // numbers under the measured gains (docs/quality.md), as a guard.
            let bar = match s.name {
                "cornell 16 spp" => 9.0,
                "glossy" | "hdr" | "dim" => 7.5,
                // Conductors and glass, whose albedo AOV is about 0: the
                // filter has only normals and colour to stop at, and the
                // reflections in the spheres blur (+4.3 dB with the pair,
                // +2.2 without; relMSE is 8-10x lower than the input's).
                "metals" => 1.5,
                "cornell 64 spp" | "box 64 spp" => 2.5,
                _ => 4.0,
            };
            if out <= inp + bar {
                bad.push(format!("{} pair {pair}: atrous {out:.2} dB, input {inp:.2} dB", s.name));
            }
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}

/// `sure-atrous` keeps `atrous`'s levels and only shrinks their detail, so
/// it must not be worse: its display MSE is at most `atrous`'s (to 0.02 dB)
/// on every scene with either noise source.
#[test]
fn sure_atrous_is_at_least_as_good_as_atrous() {
    for pair in [true, false] {
        for s in scenes(pair) {
            let a = display_mse(&s, &run(MethodKind::Atrous, PrecisionKind::F32, &s, None), &s.refs);
            let b = display_mse(&s, &run(MethodKind::SureAtrous, PrecisionKind::F32, &s, None), &s.refs);
            eprintln!("{} pair {pair}: atrous {:.3} dB, sure-atrous {:.3} dB", s.name, psnr_of(a), psnr_of(b));
            assert!(
                b <= a * 10f64.powf(0.002),
                "{} pair {pair}: sure {:.3} dB < atrous {:.3} dB",
                s.name,
                psnr_of(b),
                psnr_of(a)
            );
        }
    }
}

/// The firefly clamp (on by default) on every scene: it gains on the
/// 1-spp rooms and costs at most 0.1 dB anywhere.
#[test]
fn firefly_clamp_helps_where_there_are_fireflies() {
    let mut bad = Vec::new();
    for pair in [true, false] {
        for s in scenes(pair) {
            let on = psnr_of(display_mse(&s, &run(MethodKind::Atrous, PrecisionKind::F32, &s, None), &s.refs));
            let off = psnr_of(display_mse(&s, &run(MethodKind::Atrous, PrecisionKind::F32, &s, Some(0.0)), &s.refs));
            eprintln!("{} pair {pair}: clamp on {on:.3} dB, off {off:.3} dB", s.name);
            // On by default: it must not hurt anywhere, and must help on the
            // 1-spp rooms, whose fireflies it is for (in the dim room it
            // backs off with the noise level: +0.2 dB with one estimate,
            // held to not losing with the pair).
            let gain = match s.name {
                "glossy" | "hdr" => 0.3,
                "dim" if !pair => 0.1,
                _ => -0.1,
            };
            if on < off + gain {
                bad.push(format!("{} pair {pair}: clamp on {on:.3} dB, off {off:.3} dB (bar {gain:+})", s.name));
            }
        }
    }
    assert!(bad.is_empty(), "{bad:#?}");
}

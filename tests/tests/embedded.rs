//! The embedded operator suite (`embedded/suite`): its expected outputs come
//! from the f64 oracle and are checked in as `embedded/suite/expected.bin`;
//! these tests regenerate them (so the file cannot drift from the oracle or
//! the inputs), run the suite natively, and run the same code built for
//! `wasm32-unknown-unknown` under wasmi.
//!
//! To rewrite `expected.bin` after changing the inputs or the oracle:
//! `MCDENOISE_BLESS_EMBEDDED=1 cargo test --release -p mcdenoise-tests --test embedded expected`.
//!
//! The wasm module is built by the test itself (`cargo build --release
//! --target wasm32-unknown-unknown -p mcdenoise-embedded-wasm` into
//! `target/embedded-wasm`). Without the target's standard library installed
//! the test says "skipped" and passes, unless `MCDENOISE_REQUIRE_WASM` is set
//! (CI sets it), where it fails.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

use mcdenoise_core::atrous::AtrousParams;
use mcdenoise_core::{atrous, conv, unfold, Fixed, F32};
use mcdenoise_embedded_suite as suite;
use mcdenoise_kit::oracle;
use suite::{Case, Op, Tensor, CASES, H, W};

/// The suite's buffers are statics: one native run at a time.
static NATIVE: Mutex<()> = Mutex::new(());

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

fn expected_path() -> PathBuf {
    root().join("embedded/suite/expected.bin")
}

fn values(t: Tensor) -> Vec<f64> {
    (0..t.len()).map(|i| t.value(i) as f64).collect()
}

/// The f64 oracle's output of `op` on the suite's inputs.
fn oracle_outputs(op: Op) -> Vec<f64> {
    match op {
        Op::Apply7 => oracle::unfold(suite::K, &values(Tensor::ApplyKernel), &values(Tensor::ApplyRadiance), 3, W, H),
        Op::Composite => {
            oracle::composite(&values(Tensor::Fine), &values(Tensor::Coarse), &values(Tensor::Alpha), 3, W, H)
        }
        Op::Softmax => oracle::channel_softmax(&values(Tensor::Logits), suite::SOFTMAX_PLANES, W, H),
        Op::Conv3x3 => oracle::conv2d(
            suite::CONV_K,
            suite::CONV_IN,
            suite::CONV_OUT,
            &values(Tensor::ConvWeights),
            Some(&values(Tensor::ConvBias)),
            Some(suite::CONV_SLOPE as f64),
            &values(Tensor::ConvInput),
            W,
            H,
        ),
        Op::Atrous => {
            // The f32 parameters the kernels get, widened exactly.
            let p = AtrousParams::default();
            let (noise, normal, position) =
                (values(Tensor::AtrousNoise), values(Tensor::AtrousNormal), values(Tensor::AtrousPosition));
            let g =
                oracle::AtrousGuides { noise: &noise, normal: Some(&normal), position: Some(&position), depth: None };
            oracle::atrous_step(
                suite::ATROUS_LEVEL,
                1,
                false,
                p.phi_color as f64,
                p.sigma_normal as f64,
                p.sigma_plane as f64,
                p.sigma_depth as f64,
                p.sigma_distance as f64,
                p.eps as f64,
                &g,
                &values(Tensor::AtrousRadiance),
                W,
                H,
            )
        }
    }
}

/// The expected-output file as the generator writes it (layout: `suite::expected_in`).
fn generate() -> Vec<u8> {
    let mut out = suite::EXPECTED_MAGIC.to_vec();
    out.extend((Op::ALL.len() as u32).to_le_bytes());
    for op in Op::ALL {
        let v = oracle_outputs(op);
        assert_eq!(v.len(), op.out_len(), "{}", op.name());
        out.extend((v.len() as u32).to_le_bytes());
        for x in v {
            out.extend((x as f32).to_le_bytes());
        }
    }
    out
}

/// `expected.bin` is what the oracle gives on the suite's inputs today. A
/// value may differ from a fresh run by one f32 ulp (a platform's f64 `exp`
/// may round its last bit differently); any larger difference fails.
#[test]
fn expected_outputs_are_current() {
    let fresh = generate();
    let path = expected_path();
    if std::env::var_os("MCDENOISE_BLESS_EMBEDDED").is_some() {
        std::fs::write(&path, &fresh).unwrap();
        eprintln!("wrote {} ({} bytes)", path.display(), fresh.len());
        return;
    }
    let file = std::fs::read(&path).unwrap();
    let mut one_ulp = 0;
    for op in Op::ALL {
        let a = suite::expected_in(&file, op).unwrap_or_else(|| {
            panic!("{} has no outputs for {}: regenerate it (see the top of this file)", path.display(), op.name())
        });
        let b = suite::expected_in(&fresh, op).unwrap();
        for (i, (x, y)) in a.chunks_exact(4).zip(b.chunks_exact(4)).enumerate() {
            let x = i32::from_le_bytes(x.try_into().unwrap());
            let y = i32::from_le_bytes(y.try_into().unwrap());
            let ulps = (x as i64 - y as i64).abs();
            assert!(
                ulps <= 1,
                "{} {} value {i}: checked in {} but the oracle gives {} (regenerate: see the top of this file)",
                path.display(),
                op.name(),
                f32::from_bits(x as u32),
                f32::from_bits(y as u32)
            );
            one_ulp += ulps as usize;
        }
    }
    assert_eq!(file.len(), fresh.len(), "{}: trailing bytes", path.display());
    if one_ulp > 0 {
        eprintln!("note: {one_ulp} expected values differ from this platform's oracle by one f32 ulp");
    }
    // The copy compiled into the suite is the file on disk.
    assert!(suite::EXPECTED_FILE == file.as_slice(), "the suite was built from another expected.bin");
}

/// Every input is exact in f32 and in its fixed-point format, and every
/// oracle output fits the fixed-point output format: the fixed-point errors
/// measured are the arithmetic's, not the inputs' quantisation or saturation.
#[test]
fn inputs_and_outputs_are_exact_in_every_format() {
    use suite::Tensor::*;
    let all = [
        ApplyKernel,
        ApplyRadiance,
        Fine,
        Coarse,
        Alpha,
        Logits,
        ConvInput,
        ConvWeights,
        ConvBias,
        AtrousRadiance,
        AtrousNoise,
        AtrousNormal,
        AtrousPosition,
    ];
    for t in all {
        for i in 0..t.len() {
            // The stored fixed-point value is `units` itself; f32 holds it exactly below 2^24.
            let u = t.units(i);
            assert!(u.abs() <= 32767, "{t:?}[{i}] = {} saturates in Q.{}", t.value(i), t.frac());
            assert_eq!(t.value(i) as f64, u as f64 * (-(t.frac() as f64)).exp2(), "{t:?}[{i}] not exact in f32");
        }
    }
    for op in Op::ALL {
        let most = oracle_outputs(op).iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let limit = 32767.0 * (-(op.out_frac() as f64)).exp2();
        assert!(most < 0.95 * limit, "{}: oracle output {most} near the fixed-point limit {limit}", op.name());
        eprintln!("{:<10} largest |output| {most:.4} (fixed-point limit {limit:.3})", op.name());
    }
}

/// The suite's scratch constants are exactly what the core asks for on this
/// host (`suite::run` checks them on every target through `footprint`).
#[test]
fn scratch_constants_are_exact() {
    assert_eq!(suite::APPLY_SCRATCH_F32, unfold::scratch_len::<F32>(suite::K, 3, W));
    assert_eq!(suite::APPLY_SCRATCH_FIXED, unfold::scratch_len::<Fixed>(suite::K, 3, W));
    let (k, ci, co) = (suite::CONV_K, suite::CONV_IN, suite::CONV_OUT);
    assert_eq!(suite::CONV_SCRATCH_F32, conv::conv2d_scratch_len::<F32>(k, ci, co, W));
    assert_eq!(suite::CONV_SCRATCH_FIXED, conv::conv2d_scratch_len::<Fixed>(k, ci, co, W));
    assert_eq!(suite::ATROUS_SCRATCH_F32, atrous::step_scratch_len::<F32>(suite::ATROUS_LEVEL));
    assert_eq!(suite::ATROUS_SCRATCH_FIXED, atrous::step_scratch_len::<Fixed>(suite::ATROUS_LEVEL));
}

/// Independent of the suite's own comparison: `got` against `expected.bin`
/// in f64 with the case's tolerance; returns the worst ratio.
fn worst_ratio(case: Case, got: &[f32]) -> f64 {
    let want = suite::expected_in(suite::EXPECTED_FILE, case.op).expect("expected outputs");
    assert_eq!(got.len() * 4, want.len());
    let (atol, rtol) = case.tolerance();
    let mut worst = 0.0f64;
    for (i, (&g, w)) in got.iter().zip(want.chunks_exact(4)).enumerate() {
        let w = f32::from_le_bytes(w.try_into().unwrap()) as f64;
        let r = (g as f64 - w).abs() / (atol as f64 + rtol as f64 * w.abs());
        assert!(r.is_finite(), "{} {}: output {i} is {g}", case.op.name(), case.prec.name());
        worst = worst.max(r);
    }
    worst
}

/// Runs every case natively; returns each case's outputs and outcome.
fn run_native() -> Vec<(Vec<f32>, suite::Outcome)> {
    let _g = NATIVE.lock().unwrap_or_else(|e| e.into_inner());
    CASES
        .iter()
        .map(|&case| {
            let mut out = vec![f32::NAN; case.op.out_len()];
            let o = suite::run(case, &mut suite::NoMeter, &mut |i, v| out[i] = v)
                .unwrap_or_else(|e| panic!("{} {}: {e}", case.op.name(), case.prec.name()));
            (out, o)
        })
        .collect()
}

/// The suite passes on the host (scalar path), by its own comparison and
/// by this file's; its static buffers are the footprint the docs' tile sizes
/// are computed from.
#[test]
fn suite_passes_natively() {
    for (&case, (out, o)) in CASES.iter().zip(run_native()) {
        let (name, prec) = (case.op.name(), case.prec.name());
        eprintln!(
            "{name:<10} {prec:<5} max |err| {:.3e}  worst ratio {:.3}  static {} B  hash {:08x}",
            o.max_abs, o.worst_ratio, o.static_bytes, o.hash
        );
        assert!(o.passed(), "{name} {prec}: worst ratio {} at output {}", o.worst_ratio, o.worst_index);
        let r = worst_ratio(case, &out);
        assert!(r <= 1.0, "{name} {prec}: worst ratio {r}");
        assert_eq!(o.static_bytes, suite::footprint(case.op, case.prec, W), "{name} {prec}: footprint");
    }
}

/// Builds the wasm module, or says why not (`None`: skipped).
fn build_wasm() -> Option<PathBuf> {
    const TARGET: &str = "wasm32-unknown-unknown";
    let required = std::env::var_os("MCDENOISE_REQUIRE_WASM").is_some();
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let libdir = Command::new(rustc).args(["--print", "target-libdir", "--target", TARGET]).output().ok();
    let installed = libdir
        .and_then(|o| std::fs::read_dir(String::from_utf8_lossy(&o.stdout).trim()).ok())
        .is_some_and(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with("libcore-")));
    if !installed {
        let why = format!("the {TARGET} standard library is not installed (rustup target add {TARGET})");
        assert!(!required, "MCDENOISE_REQUIRE_WASM is set but {why}");
        eprintln!("skipped: the wasm run of the embedded suite: {why}");
        return None;
    }
    let target_dir = root().join("target/embedded-wasm");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(root())
        .args(["build", "--release", "-p", "mcdenoise-embedded-wasm", "--target", TARGET, "--target-dir"])
        .arg(&target_dir)
        // Flags meant for the host (e.g. -C target-cpu=native) must not reach the wasm build.
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env_remove("CARGO_BUILD_RUSTFLAGS")
        .output()
        .expect("running cargo");
    assert!(out.status.success(), "building the wasm module failed:\n{}", String::from_utf8_lossy(&out.stderr));
    Some(target_dir.join(TARGET).join("release/mcdenoise_embedded_wasm.wasm"))
}

/// The same operator code built for wasm32-unknown-unknown, run under
/// wasmi: every case within tolerance of `expected.bin` (by the module's own
/// comparison and by this file's, on the outputs read from its memory), and
/// its outputs bit-identical to the native scalar run's.
#[test]
fn suite_passes_under_wasm() {
    use wasmi::{Engine, Linker, Memory, Module, Store, TypedFunc};
    let Some(path) = build_wasm() else { return };
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let engine = Engine::default();
    let module = Module::new(&engine, &bytes[..]).expect("valid wasm module");
    let mut store = Store::new(&engine, ());
    let linker = Linker::<()>::new(&engine);
    let inst = linker.instantiate_and_start(&mut store, &module).expect("instantiating the module");
    let f0 = |s: &Store<()>, name: &str| inst.get_typed_func::<(), u32>(s, name).expect(name);
    let cases: TypedFunc<(), u32> = f0(&store, "suite_cases");
    let run: TypedFunc<u32, i32> = inst.get_typed_func(&store, "suite_run").expect("suite_run");
    let values = f0(&store, "suite_values");
    let hash = f0(&store, "suite_hash");
    let outputs: TypedFunc<(), i32> = inst.get_typed_func(&store, "suite_outputs").expect("suite_outputs");
    let ratio: TypedFunc<(), f32> = inst.get_typed_func(&store, "suite_worst_ratio").expect("suite_worst_ratio");
    let memory: Memory = inst.get_memory(&store, "memory").expect("exported memory");
    assert_eq!(cases.call(&mut store, ()).unwrap() as usize, CASES.len());
    let native = run_native();
    for (i, &case) in CASES.iter().enumerate() {
        let (name, prec) = (case.op.name(), case.prec.name());
        let code = run.call(&mut store, i as u32).unwrap_or_else(|e| panic!("{name} {prec}: trap {e}"));
        let r = ratio.call(&mut store, ()).unwrap();
        assert_eq!(code, 0, "{name} {prec}: the module reports code {code} (worst ratio {r})");
        let n = values.call(&mut store, ()).unwrap() as usize;
        assert_eq!(n, case.op.out_len());
        let at = outputs.call(&mut store, ()).unwrap() as u32 as usize;
        let got: Vec<f32> = memory.data(&store)[at..at + 4 * n]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let mine = worst_ratio(case, &got);
        assert!(mine <= 1.0, "{name} {prec}: worst ratio {mine}");
        let h = hash.call(&mut store, ()).unwrap();
        eprintln!("wasm {name:<10} {prec:<5} worst ratio {r:.3} (here {mine:.3})  hash {h:08x}");
        let (ref nat, ref o) = native[i];
        assert_eq!(h, o.hash, "{name} {prec}: wasm outputs differ from the native scalar run's");
        assert!(nat.iter().zip(&got).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}

//! The `mcdenoise` binary on bad input: one clear line naming the file,
//! channel or parameter, a non-zero exit, no panic, nothing the user gave
//! overwritten.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use mcdenoise::io::output::write_exr;

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_mcdenoise"));
    c.env("RUST_BACKTRACE", "1");
    c
}

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures")
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("the binary runs")
}

/// Asserts a failed run: exit code, one line on stderr naming `needle`, no panic text.
#[track_caller]
fn assert_fails(out: &Output, code: i32, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "stderr: {err}");
    assert!(err.contains(needle), "stderr should name '{needle}': {err}");
    assert!(!err.contains("panicked") && !err.contains("backtrace") && !err.contains("internal error"), "{err}");
    let lines = err.lines().filter(|l| !l.starts_with("(see")).count();
    assert_eq!(lines, 1, "one line expected: {err}");
}

fn rgb_frame(dir: &Path, name: &str, w: usize, h: usize) -> PathBuf {
    let p = dir.join(name);
    let v = vec![0.5f32; w * h];
    write_exr(&p, w, h, &[("R", &v), ("G", &v), ("B", &v)], false).unwrap();
    p
}

fn digest(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap()
}

#[test]
fn missing_file() {
    let t = tempfile::tempdir().unwrap();
    let out = run(&["denoise", "--method", "none", "/nonexistent/frame.exr", "-o", t.path().to_str().unwrap()]);
    assert_fails(&out, 1, "/nonexistent/frame.exr");
}

#[test]
fn not_an_exr() {
    let t = tempfile::tempdir().unwrap();
    let p = t.path().join("notes.exr");
    std::fs::write(&p, b"this is not an image").unwrap();
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", t.path().join("o").to_str().unwrap()]);
    assert_fails(&out, 1, "not a readable OpenEXR file");
    assert_fails(&out, 1, "notes.exr");
}

#[test]
fn truncated_exr() {
    let t = tempfile::tempdir().unwrap();
    let src = std::fs::read(fixtures().join("seq_small/frame_0000.exr")).unwrap();
    for cut in [10, 400, src.len() / 2, src.len() - 7] {
        let p = t.path().join(format!("cut{cut}.exr"));
        std::fs::write(&p, &src[..cut]).unwrap();
        let out =
            run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", t.path().join("o").to_str().unwrap()]);
        assert_fails(&out, 1, &format!("cut{cut}.exr"));
    }
}

#[test]
fn missing_required_channel() {
    let t = tempfile::tempdir().unwrap();
    let p = t.path().join("albedo_only.exr");
    let v = vec![0.5f32; 16];
    write_exr(&p, 4, 4, &[("albedo.R", &v), ("albedo.G", &v), ("albedo.B", &v)], false).unwrap();
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", t.path().join("o").to_str().unwrap()]);
    assert_fails(&out, 1, "missing colour channels (R,G,B)");
    // ta needs motion or position.
    let q = rgb_frame(t.path(), "rgb_only.exr", 4, 4);
    let out = run(&["denoise", "--method", "ta", q.to_str().unwrap(), "-o", t.path().join("o2").to_str().unwrap()]);
    assert_fails(&out, 1, "motion");
}

#[test]
fn incomplete_channel_set() {
    let t = tempfile::tempdir().unwrap();
    let p = t.path().join("half_normal.exr");
    let v = vec![0.5f32; 16];
    write_exr(&p, 4, 4, &[("R", &v), ("G", &v), ("B", &v), ("normal.X", &v), ("normal.Y", &v)], false).unwrap();
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", t.path().join("o").to_str().unwrap()]);
    assert_fails(&out, 1, "normal channels are incomplete: has normal.X,normal.Y but not normal.Z");
}

#[test]
fn frames_of_different_sizes() {
    let t = tempfile::tempdir().unwrap();
    let a = rgb_frame(t.path(), "a.exr", 8, 8);
    let b = rgb_frame(t.path(), "b.exr", 8, 9);
    let out = run(&[
        "denoise",
        "--method",
        "none",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "-o",
        t.path().join("o").to_str().unwrap(),
    ]);
    assert_fails(&out, 1, "b.exr: frame is 8x9 but");
}

#[test]
fn over_the_size_limit_is_refused_from_the_header() {
    let t = tempfile::tempdir().unwrap();
    let p = rgb_frame(t.path(), "wide.exr", 20_000, 1);
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", t.path().join("o").to_str().unwrap()]);
    assert_fails(&out, 1, "over the limit");
}

#[test]
fn unwritable_output() {
    let t = tempfile::tempdir().unwrap();
    let p = rgb_frame(t.path(), "a.exr", 4, 4);
    let file = t.path().join("plainfile");
    std::fs::write(&file, b"x").unwrap();
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", file.to_str().unwrap()]);
    assert_fails(&out, 1, "not a directory");
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", "/proc/version/out"]);
    assert_fails(&out, 1, "/proc/version/out");
}

#[test]
fn output_onto_input_is_refused_and_input_kept() {
    let t = tempfile::tempdir().unwrap();
    let p = rgb_frame(t.path(), "a.exr", 4, 4);
    let before = digest(&p);
    let out = run(&["denoise", "--method", "none", p.to_str().unwrap(), "-o", t.path().to_str().unwrap()]);
    assert_fails(&out, 1, "would overwrite an input");
    assert_eq!(before, digest(&p));
    // Through another spelling of the same directory.
    let out =
        run(&["denoise", "--method", "none", t.path().to_str().unwrap(), "-o", &format!("{}/./", t.path().display())]);
    assert_fails(&out, 1, "would overwrite an input");
    assert_eq!(before, digest(&p));
    let leftovers: Vec<_> =
        std::fs::read_dir(t.path()).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
    assert_eq!(leftovers.len(), 1, "nothing else written: {leftovers:?}");
}

#[test]
fn bad_arguments_name_the_parameter() {
    let out = run(&["denoise", "--method", "none", "--threads", "abc", "x.exr", "-o", "o"]);
    assert_fails(&out, 2, "--threads: expected a whole number from 1 to 256, got 'abc'");
    let out = run(&["denoise", "--method", "nope", "x.exr", "-o", "o"]);
    assert_fails(&out, 2, "--method: expected one of");
    let out = run(&["denoise", "--method", "none", "--precision", "f8", "x.exr", "-o", "o"]);
    assert_fails(&out, 2, "--precision");
    let out = run(&["denoise", "--method", "none", "x.exr"]);
    assert_fails(&out, 2, "-o OUTDIR is required");
    let out = run(&["frobnicate"]);
    assert_fails(&out, 2, "unknown command 'frobnicate'");
    let out = run(&["denoise", "--method", "none", "--threads", "99999999999999999999999", "x.exr", "-o", "o"]);
    assert_fails(&out, 2, "--threads");
    for bad in ["-1", "nan", "inf", "x"] {
        let arg = format!("--ta-clamp={bad}");
        let out = run(&["denoise", "--method", "ta", &arg, "x.exr", "-o", "o"]);
        assert_fails(&out, 2, &format!("--ta-clamp: expected a number from 0 (off) up to 1e6, got '{bad}'"));
    }
}

#[test]
fn denoise_and_score_a_sequence() {
    let t = tempfile::tempdir().unwrap();
    let seq = fixtures().join("seq_small");
    let o = t.path().join("ta");
    let out =
        run(&["denoise", "--method", "ta", "--png", "--timings", seq.to_str().unwrap(), "-o", o.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for i in 0..4 {
        assert!(o.join(format!("frame_{i:04}.exr")).is_file());
        assert!(o.join(format!("frame_{i:04}.png")).is_file());
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("temporal accumulation"), "{stdout}");
    let out = run(&["score", "--reference", seq.join("ref").to_str().unwrap(), o.to_str().unwrap(), "--json"]);
    assert!(out.status.success());
    let s = String::from_utf8_lossy(&out.stdout);
    assert!(s.starts_with("{\"files\":[") && s.contains("\"mean\":"), "{s}");
}

#[test]
fn a_failed_write_leaves_nothing_behind() {
    let t = tempfile::tempdir().unwrap();
    let target = t.path().join("out.exr");
    std::fs::write(&target, b"previous result").unwrap();
    // The writer fails half-way: the previous file stays, no temporary is left.
    let e = mcdenoise::io::output::atomic_write(&target, |tmp| {
        std::fs::write(tmp, b"half").unwrap();
        Err("disk full".into())
    })
    .unwrap_err();
    assert!(e.to_string().contains("out.exr") && e.to_string().contains("disk full"), "{e}");
    assert_eq!(std::fs::read(&target).unwrap(), b"previous result");
    let names: Vec<_> = std::fs::read_dir(t.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 1, "{names:?}");
}

#[test]
fn bad_weights_file() {
    let t = tempfile::tempdir().unwrap();
    let w = t.path().join("weights.safetensors");
    std::fs::write(&w, b"\x10\x00\x00\x00\x00\x00\x00\x00{\"a\":").unwrap();
    let seq = fixtures().join("seq_small");
    let out = run(&[
        "denoise",
        "--method",
        "wskp",
        "--weights",
        w.to_str().unwrap(),
        seq.to_str().unwrap(),
        "-o",
        t.path().join("o").to_str().unwrap(),
    ]);
    assert_fails(&out, 1, "weights.safetensors: not a safetensors file");
    // A missing file, and --layers out of range.
    let out = run(&[
        "denoise",
        "--method",
        "wskp",
        "--weights",
        "/nonexistent/w.safetensors",
        seq.to_str().unwrap(),
        "-o",
        "x",
    ]);
    assert_fails(&out, 1, "/nonexistent/w.safetensors");
    let out = run(&["denoise", "--method", "wskp", "--layers", "4", seq.to_str().unwrap(), "-o", "x"]);
    assert_fails(&out, 2, "--layers: expected 3 or 6, got '4'");
}

#[test]
fn train_needs_its_arguments() {
    assert_fails(
        &run(&["train", "--method", "wskp", "--steps", "3", "-o", "w.safetensors"]),
        2,
        "--data DIR is required",
    );
    assert_fails(
        &run(&["train", "--method", "wskp", "--data", "x", "-o", "w.safetensors"]),
        2,
        "give --steps N or --minutes M",
    );
    assert_fails(&run(&["train", "--method", "nope", "--data", "x"]), 2, "train --method: expected wskp");
    assert_fails(
        &run(&["train", "--method", "wskp", "--data", "/nonexistent/d", "--steps", "1", "-o", "w.safetensors"]),
        1,
        "/nonexistent/d",
    );
}

/// Output into a pipe whose reader has gone (`mcdenoise --help | head -1`):
/// no "internal error", exit 0 or 141 (SIGPIPE's status).
#[test]
fn a_closed_pipe_ends_quietly() {
    for args in [&["--help"][..], &["completions", "bash"][..]] {
        let mut child =
            bin().args(args).stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn().unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("internal error"), "{args:?}: {err}");
        assert!(matches!(out.status.code(), Some(0) | Some(141)), "{args:?}: {:?} {err}", out.status);
    }
}

/// A training directory with a sequence still being rendered (a frame
/// without its reference) and one that does not load: both are named and
/// skipped, the run trains on the rest; with nothing left it fails.
#[test]
fn train_skips_incomplete_and_broken_sequences() {
    let dir = std::env::temp_dir().join(format!("mcdenoise-cli-train-skip-{}", std::process::id()));
    let data = dir.join("data");
    let good = data.join("a_good");
    std::fs::create_dir_all(good.join("ref")).unwrap();
    let src = fixtures().join("seq_small");
    for name in ["frame_0000.exr", "frame_0001.exr"] {
        std::fs::copy(src.join(name), good.join(name)).unwrap();
        std::fs::copy(src.join("ref").join(name), good.join("ref").join(name)).unwrap();
    }
    let partial = data.join("b_rendering");
    std::fs::create_dir_all(partial.join("ref")).unwrap();
    std::fs::copy(src.join("frame_0000.exr"), partial.join("frame_0000.exr")).unwrap();
    let broken = data.join("c_broken");
    std::fs::create_dir_all(broken.join("ref")).unwrap();
    std::fs::write(broken.join("frame_0000.exr"), b"not an exr").unwrap();
    std::fs::write(broken.join("ref").join("frame_0000.exr"), b"not an exr").unwrap();
    let w = dir.join("w.safetensors");
    let args = |d: &Path| {
        vec![
            "train".to_string(),
            "--method".into(),
            "wskp".into(),
            "--layers".into(),
            "3".into(),
            "--data".into(),
            d.to_str().unwrap().into(),
            "--steps".into(),
            "2".into(),
            "--batch".into(),
            "1".into(),
            "--crop".into(),
            "32".into(),
            "--threads".into(),
            "1".into(),
            "-o".into(),
            w.to_str().unwrap().into(),
        ]
    };
    let a = args(&data);
    let out = run(&a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("b_rendering") && err.contains("has no reference yet"), "{err}");
    assert!(err.contains("c_broken"), "{err}");
    assert!(err.contains("1 sequences"), "{err}");
    assert!(w.exists());
    // With --frame-stride 2, each copy of the two-frame sequence (the
    // estimates, swapped, emulated spp) keeps one of its frames: half the
    // samples.
    let samples = |err: &str| -> usize {
        let at = err.find(" samples (").unwrap_or_else(|| panic!("no sample count in {err}"));
        err[..at].rsplit(' ').next().unwrap().parse().unwrap()
    };
    let all = samples(&err);
    let mut a = args(&data);
    a.extend(["--frame-stride".to_string(), "2".into()]);
    let out = run(&a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(all >= 2 && all % 2 == 0, "{all} samples of two-frame copies");
    assert_eq!(samples(&err), all / 2, "{err}");
    assert!(err.contains("one frame in 2"), "{err}");
    std::fs::remove_dir_all(&good).unwrap();
    let a = args(&data);
    let out = run(&a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("no complete sequence to train on") && err.contains("b_rendering"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// `--method cross` on frames without the second estimate: one line naming
/// `B.R,B.G,B.B`, exit 1; a bad `--seed` names the flag.
#[test]
fn cross_without_second_estimate_names_the_channels() {
    let dir = std::env::temp_dir().join(format!("mcdenoise-cli-cross-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let f = rgb_frame(&dir, "frame_0000.exr", 9, 7);
    let out_dir = dir.join("out");
    let out = run(&["denoise", "--method", "cross", f.to_str().unwrap(), "-o", out_dir.to_str().unwrap()]);
    assert_fails(&out, 1, "B.R,B.G,B.B");
    let out =
        run(&["denoise", "--method", "cross", "--seed", "x", f.to_str().unwrap(), "-o", out_dir.to_str().unwrap()]);
    assert_fails(&out, 2, "--seed");
    let out = run(&[
        "denoise",
        "--method",
        "cross",
        "--load-state",
        dir.join("missing.safetensors").to_str().unwrap(),
        fixtures().join("seq_small").to_str().unwrap(),
        "-o",
        out_dir.to_str().unwrap(),
    ]);
    assert_fails(&out, 1, "missing.safetensors");
    std::fs::remove_dir_all(&dir).ok();
}

/// `--help` of every command exits 0 and shows its usage, its defaults and
/// the allowed values; `--version` names the program.
#[test]
fn every_command_has_help() {
    for (cmd, needles) in [
        ("demo", &["[default: f32]", "f16-arith"][..]),
        (
            "denoise",
            &[
                "--method <METHOD>",
                "sure-atrous",
                "Dammertz",
                "[default: the --weights file's, else 6]",
                "--quiet",
                "--json",
            ][..],
        ),
        ("train", &["[default: l1-log]", "relmse-n2n", "1spp-only", "[default: 128]"][..]),
        ("score", &["--reference <REF>", "<OUT>"][..]),
        ("precision", &["[default: 1280x720]", "--only"][..]),
        ("completions", &["bash", "zsh", "fish"][..]),
        ("man", &["--dir"][..]),
    ] {
        for args in [vec![cmd, "--help"], vec!["help", cmd]] {
            let out = run(&args);
            let text = String::from_utf8_lossy(&out.stdout);
            assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
            assert!(text.contains(&format!("Usage: mcdenoise {cmd}")), "{args:?}: {text}");
            for n in needles {
                assert!(text.contains(n), "{args:?} should show '{n}': {text}");
            }
        }
    }
    let out = run(&["--help"]);
    assert!(out.status.success() && String::from_utf8_lossy(&out.stdout).contains("denoise"));
    for args in [&["--version"][..], &["denoise", "--version"][..]] {
        let out = run(args);
        assert!(out.status.success());
        assert_eq!(String::from_utf8_lossy(&out.stdout), format!("mcdenoise {}\n", env!("CARGO_PKG_VERSION")));
    }
}

/// A mistyped option, value or command is named with the closest one.
#[test]
fn errors_suggest_the_closest_option() {
    assert_fails(
        &run(&["denoise", "--methd", "none", "x.exr", "-o", "o"]),
        2,
        "unknown option '--methd' (did you mean '--method'?)",
    );
    assert_fails(
        &run(&["denoise", "--method", "atrus", "x.exr", "-o", "o"]),
        2,
        "got 'atrus' (did you mean 'atrous'?)",
    );
    assert_fails(&run(&["denoize"]), 2, "unknown command 'denoize'");
    assert_fails(
        &run(&["denoise", "--method", "none", "--isa", "sse9", "x.exr", "-o", "o"]),
        2,
        "--isa: expected one of scalar, avx2, avx512; got 'sse9'",
    );
    assert_fails(
        &run(&["denoise", "--method", "none", "x.exr", "-o", "o", "--quiet", "--json"]),
        2,
        "cannot be used with",
    );
    assert_fails(&run(&["denoise", "--method", "none", "-o", "o"]), 2, "INPUT is required");
    assert_fails(&run(&["denoise", "x.exr", "-o", "o"]), 2, "--method METHOD is required (none, ta, atrous");
    assert_fails(&run(&["score", "out.exr"]), 2, "-r REF is required");
    assert_fails(
        &run(&["precision", "--size", "3x0"]),
        2,
        "--size: height: expected a whole number from 1 to 8192, got '0'",
    );
    assert_fails(&run(&["completions", "tcsh"]), 2, "expected one of bash");
}

/// Completion scripts and man pages come from the same definition.
#[test]
fn completions_and_man_pages() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let out = run(&["completions", shell]);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success() && text.contains("phi-color"), "{shell}: {text}");
        // The shells whose scripts complete values list the methods.
        if ["bash", "zsh", "fish"].contains(&shell) {
            assert!(text.contains("sure-atrous"), "{shell}: {text}");
        }
    }
    let out = run(&["man"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains(".TH mcdenoise") && text.contains("denoise"), "{text}");
    let t = tempfile::tempdir().unwrap();
    let out = run(&["man", "--dir", t.path().to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for page in ["mcdenoise.1", "mcdenoise-denoise.1", "mcdenoise-train.1", "mcdenoise-score.1"] {
        let text = std::fs::read_to_string(t.path().join(page)).unwrap();
        assert!(text.contains(".TH"), "{page}");
    }
    let denoise = std::fs::read_to_string(t.path().join("mcdenoise-denoise.1")).unwrap();
    assert!(denoise.contains("max\\-memory") && denoise.contains("f16\\-arith"), "{denoise}");
}

/// `denoise` prints its plan and buffers once and a one-line summary with
/// ms/frame; `--json` one object on stdout and nothing else; `--quiet` nothing.
#[test]
fn denoise_summary_json_and_quiet() {
    let t = tempfile::tempdir().unwrap();
    let seq = fixtures().join("seq_small");
    let o = t.path().join("o");
    let out = run(&["denoise", "--method", "ta", seq.to_str().unwrap(), "-o", o.to_str().unwrap()]);
    assert!(out.status.success());
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(stderr.starts_with("ta: stages temporal accumulation") && stderr.contains("buffers: colour"), "{stderr}");
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.contains("ta: 4 frames of 64x64") && stdout.contains(" ms/frame "), "{stdout}");

    let out = run(&["denoise", "--method", "ta", "--json", seq.to_str().unwrap(), "-o", o.to_str().unwrap()]);
    assert!(out.status.success());
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(stderr.is_empty(), "{stderr}");
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    for key in [
        "{\"method\":\"ta\",\"frames\":4,",
        "\"ms_per_frame\":",
        "\"plan\":{\"built\":[\"temporal accumulation\"",
        "\"buffers\":[\"colour\"",
        "\"outputs\":[",
        "frame_0003.exr\"]",
    ] {
        assert!(stdout.contains(key), "{key}: {stdout}");
    }

    let out = run(&["denoise", "--method", "ta", "--quiet", seq.to_str().unwrap(), "-o", o.to_str().unwrap()]);
    assert!(out.status.success() && out.stdout.is_empty() && out.stderr.is_empty(), "{out:?}");

    // The history clamp: built by default, skipped and named with 0.
    let plan = |extra: &[&str]| {
        let mut args = vec!["denoise", "--method", "ta", "--json"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&[seq.to_str().unwrap(), "-o", o.to_str().unwrap()]);
        let out = run(&args);
        assert!(out.status.success(), "{out:?}");
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let on = plan(&[]);
    assert!(on.contains("\"built\":[\"temporal accumulation\",\"history clamp"), "{on}");
    let off = plan(&["--ta-clamp", "0"]);
    assert!(
        !off.contains("\"built\":[\"temporal accumulation\",\"history clamp") && off.contains("--ta-clamp 0"),
        "{off}"
    );
}

/// clap's own consistency checks of the definition (they run only in debug
/// builds otherwise, where the fuzz target would trip over them).
#[test]
fn the_definition_is_consistent() {
    mcdenoise_cli::cli::definition().debug_assert();
}

/// The parser is a pure function: no command runs, defaults are filled in.
#[test]
fn parse_is_a_function_of_the_arguments() {
    use mcdenoise_cli::cli::{parse, Command};
    use std::ffi::OsString;
    let args = |v: &[&str]| v.iter().map(OsString::from).collect::<Vec<_>>();
    assert!(matches!(parse(args(&[])), Ok(Command::Demo { .. })));
    match parse(args(&[
        "denoise",
        "--method",
        "afn",
        "--no-refine",
        "--precision",
        "fixed",
        "--threads",
        "3",
        "a.exr",
        "b.exr",
        "-o",
        "out",
        "--max-memory",
        "1G",
    ])) {
        Ok(Command::Denoise(d)) => {
            assert_eq!(d.method, mcdenoise::methods::MethodKind::Afn);
            assert_eq!(d.settings.precision, mcdenoise::runtime::precision::PrecisionKind::Fixed);
            assert_eq!((d.settings.threads, d.settings.refine, d.settings.layers), (3, false, 6));
            assert_eq!(d.inputs.len(), 2);
            assert_eq!(d.sequence.max_memory, Some(1 << 30));
            assert!(!d.quiet && !d.json);
        }
        other => panic!("{other:?}"),
    }
    match parse(args(&[
        "train",
        "--data",
        "d",
        "-o",
        "w.safetensors",
        "--minutes",
        "2",
        "--loss",
        "relmse",
        "--variant",
        "1spp-only",
    ])) {
        Ok(Command::Train(t)) => {
            assert_eq!((t.method.as_str(), t.steps, t.minutes, t.batch, t.crop), ("wskp", None, Some(2.0), 8, 128));
            assert_eq!(t.loss, mcdenoise::nn::loss::Loss::RelMse);
            assert_eq!(t.variant, mcdenoise::methods::afn::Variant::OneSppOnly);
        }
        other => panic!("{other:?}"),
    }
    match parse(args(&["precision", "--size", "64x32", "--only", "conv3x3,atrous"])) {
        Ok(Command::Precision(p)) => assert_eq!((p.width, p.height, p.only.len(), p.threads), (64, 32, 2, 1)),
        other => panic!("{other:?}"),
    }
    assert!(matches!(parse(args(&["--help"])), Ok(Command::Help(h)) if h.contains("Usage: mcdenoise")));
    assert!(matches!(parse(args(&["completions", "zsh"])), Ok(Command::Completions(_))));
}

/// `precision --methods` on the bundled sample: a row per method and
/// precision; each row's PSNR is what `mcdenoise score` gives the outputs
/// it wrote; a reduced precision's worst frame loses at least its mean
/// loss against f32; each method's fastest row is on its Pareto front. A
/// frame an earlier run left in an output folder (a longer sequence's) is
/// gone, so the folder scores as the report says.
#[test]
fn precision_report_per_method() {
    let t = tempfile::tempdir().unwrap();
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("../samples");
    let stale = t.path().join("mcdenoise-out/precision/none-f32");
    std::fs::create_dir_all(&stale).unwrap();
    std::fs::copy(sample.join("frame_0000.exr"), stale.join("frame_9999.exr")).unwrap();
    std::fs::write(stale.join("notes.txt"), "kept").unwrap();
    let out = bin()
        .current_dir(t.path())
        .args(["precision", "--methods", "none,atrous", "--threads", "2", "--sequence"])
        .arg(&sample)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!stale.join("frame_9999.exr").exists(), "the earlier run's frame is removed");
    assert_eq!(std::fs::read_to_string(stale.join("notes.txt")).unwrap(), "kept", "only frames are removed");
    let csv = std::fs::read_to_string(t.path().join("mcdenoise-out/precision-methods.csv")).unwrap();
    let rows: Vec<Vec<String>> = csv.lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect();
    let want = ["none f32", "none f16", "none fixed", "atrous f32", "atrous f16", "atrous fixed"];
    assert_eq!(rows.iter().map(|r| format!("{} {}", r[0], r[1])).collect::<Vec<_>>(), want);
    let num = |s: &str| s.parse::<f64>().unwrap();
    for method in ["none", "atrous"] {
        let mine: Vec<&Vec<String>> = rows.iter().filter(|r| r[0] == method).collect();
        let f32_psnr = num(&mine[0][4]);
        assert!(mine[0][6].is_empty(), "f32 has no loss against itself");
        for r in &mine {
            let dir = t.path().join("mcdenoise-out/precision").join(format!("{}-{}", r[0], r[1]));
            let s =
                bin().arg("score").arg("--reference").arg(sample.join("ref")).arg(&dir).arg("--json").output().unwrap();
            let text = String::from_utf8_lossy(&s.stdout);
            let mean = text.split("\"mean\":{\"file\":\"mean\",\"psnr\":").nth(1).expect("a mean");
            let psnr = num(mean.split(',').next().unwrap());
            assert!((psnr - num(&r[4])).abs() < 1e-3, "{} {}: report {} vs score {psnr}", r[0], r[1], r[4]);
            if r[1] != "f32" {
                // The column is the worst frame against f32 (this minus f32).
                assert!(-num(&r[6]) >= f32_psnr - num(&r[4]) - 1e-3, "{r:?}: worst frame under the mean loss");
            }
        }
        let fastest = mine.iter().min_by(|a, b| num(&a[2]).total_cmp(&num(&b[2]))).unwrap();
        assert_eq!(fastest[7], "1", "{method}: the fastest row is on the front: {mine:?}");
    }
}

/// `precision --methods` without references: one line naming the directory.
#[test]
fn precision_report_without_references() {
    let t = tempfile::tempdir().unwrap();
    let sample = Path::new(env!("CARGO_MANIFEST_DIR")).join("../samples");
    let out = bin()
        .current_dir(t.path())
        .args(["precision", "--methods", "none", "--sequence"])
        .arg(&sample)
        .arg("--reference")
        .arg(t.path().join("nowhere"))
        .output()
        .unwrap();
    assert_fails(&out, 2, "nowhere");
}

/// `--emulate-int8` is for the networks in a float precision: with a method
/// that has none, or in fixed point, it is refused by name and nothing is
/// written.
#[test]
fn emulate_int8_is_refused_where_it_means_nothing() {
    let t = tempfile::tempdir().unwrap();
    let frame = Path::new(env!("CARGO_MANIFEST_DIR")).join("../samples/frame_0000.exr");
    let o = t.path().join("o");
    let run = |args: &[&str]| bin().args(["denoise"]).args(args).arg(&frame).arg("-o").arg(&o).output().unwrap();
    assert_fails(&run(&["--method", "atrous", "--emulate-int8"]), 2, "--emulate-int8: atrous has no network");
    assert_fails(
        &run(&["--method", "wskp", "--precision", "fixed", "--emulate-int8"]),
        2,
        "--emulate-int8 runs in a float precision",
    );
    assert!(!o.exists() || std::fs::read_dir(&o).unwrap().next().is_none(), "nothing written");
}

/// A band weight that is not a number from 0 to 100, a first-frames
/// share that is not one from 0 to 1, or a frame stride that is not a
/// whole number from 1 to 1000, names the flag, exit 2.
#[test]
fn train_names_a_bad_band_weight_or_first_frames_share() {
    for (flag, bads) in [
        ("--band-weight", ["-1", "nan", "x", "101"]),
        ("--first-frames", ["-0.1", "nan", "x", "1.5"]),
        ("--frame-stride", ["0", "1.5", "x", "1001"]),
    ] {
        for bad in bads {
            let arg = format!("{flag}={bad}");
            let out = run(&["train", "--data", ".", "-o", "w.safetensors", "--steps", "1", &arg]);
            assert_fails(&out, 2, flag);
        }
    }
}

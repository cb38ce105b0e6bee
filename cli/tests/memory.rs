//! Memory: the estimates hold the counted heap of every method and
//! precision, the CLI ends cleanly under an address-space limit at the pixel
//! limit (a frame there, and a small ZIP file that decompresses to it), and
//! `--max-memory` refuses from the header.

mod common;

use common::*;

const METHODS: [&str; 6] = ["none", "ta", "atrous", "sure-atrous", "wskp", "afn"];
const PRECISIONS: [&str; 4] = ["f32", "f16", "f16-arith", "fixed"];

/// For each method x precision x channel set, two 2-frame sequences of one
/// width and two heights: the whole run's peak heap (counted by the CLI's
/// allocator) is within the estimate, and the growth of the peak with the
/// pixels is within the estimated bytes per pixel and at least 85 % of it
/// (so the declared figure is an honest bound, not a guess far above).
#[test]
fn estimates_bound_the_counted_heap() {
    let t = tempfile::tempdir().unwrap();
    // Both heights at least 8 ZIP blocks of 16 rows: the loader and the
    // writer work in batches of 4 blocks a thread, a fixed amount that
    // must not show up as bytes per pixel.
    let (w, h1, h2) = (384, 128, 384);
    let sets: [(&str, &[&str]); 2] = [("rgb", &["R", "G", "B"]), ("full", &ALL_CHANNELS)];
    let mut rows = Vec::new();
    let mut bad = Vec::new();
    for (set, channels) in sets {
        let dirs: Vec<_> = [h1, h2]
            .iter()
            .map(|&h| {
                let d = t.path().join(format!("{set}-{h}"));
                std::fs::create_dir(&d).unwrap();
                for i in 0..2 {
                    scene_frame(&d.join(format!("f{i}.exr")), w, h, channels, true, i);
                }
                d
            })
            .collect();
        for method in METHODS {
            if (method == "ta" || method == "wskp" || method == "afn") && set == "rgb" {
                continue; // needs motion or position; the networks need albedo, normal, depth
            }
            for precision in PRECISIONS {
                let mut got = Vec::new();
                for d in &dirs {
                    let out = t.path().join("out");
                    // One frame at a time: the pipeline's read-ahead and
                    // write-behind overlap by timing, so the estimate is
                    // held to the heap here and bounds it below.
                    let mut args = vec![
                        "denoise",
                        "--method",
                        method,
                        "--precision",
                        precision,
                        "--threads",
                        "2",
                        "--no-pipeline",
                    ];
                    // The writer's share: PNG previews and f16 output with every buffer.
                    if set == "full" {
                        args.extend(["--png", "--half"]);
                    }
                    let wf = weights_for(t.path(), method);
                    if let Some(wf) = &wf {
                        args.extend(["--weights", wf.to_str().unwrap()]);
                    }
                    args.extend(["--timings", d.to_str().unwrap(), "-o", out.to_str().unwrap()]);
                    let r = run_limited(&args, &[]);
                    assert_eq!(r.code, Some(0), "{method} {precision} {set}: {}", r.stderr);
                    let m = memory_line(&r.stdout).unwrap_or_else(|| panic!("no memory line: {}", r.stdout));
                    got.push(m);
                }
                let ((pp, est1, heap1), (_, est2, heap2)) = (got[0], got[1]);
                let what = format!("{method} {precision} {set}");
                assert!(
                    heap1 <= est1 && heap2 <= est2,
                    "{what}: heap {heap1} / {heap2} over the estimate {est1} / {est2}"
                );
                let dpx = (w * (h2 - h1)) as f64;
                let per_px = (heap2 as f64 - heap1 as f64) / dpx;
                rows.push(format!("{what:<28} estimate {pp:>4} B/px, counted {per_px:>6.1} B/px"));
                // Decompression and compression run in parallel batches, whose
                // allocations interleave by timing: a few bytes of noise.
                if per_px > pp as f64 + 3.0 {
                    bad.push(format!("{what}: {per_px:.1} bytes per pixel over the estimate {pp}"));
                }
                // Loose: under 80 % of the estimate, with 8 bytes of slack for
                // the smallest footprints (`none` in f16 or fixed point with
                // every buffer and --half: 23 of 30, whose peak phase the
                // estimate bounds from above by the frame and the output).
                if per_px + 8.0 < 0.8 * pp as f64 {
                    bad.push(format!("{what}: {per_px:.1} bytes per pixel, estimate {pp} is loose"));
                }
                // Pipelined (the default), the estimate bounds the heap.
                let out = t.path().join("out-pipelined");
                let mut args = vec!["denoise", "--method", method, "--precision", precision, "--threads", "2"];
                if set == "full" {
                    args.extend(["--png", "--half"]);
                }
                let wf = weights_for(t.path(), method);
                if let Some(wf) = &wf {
                    args.extend(["--weights", wf.to_str().unwrap()]);
                }
                args.extend(["--timings", dirs[1].to_str().unwrap(), "-o", out.to_str().unwrap()]);
                let r = run_limited(&args, &[]);
                assert_eq!(r.code, Some(0), "{what} pipelined: {}", r.stderr);
                let (_, est, heap) = memory_line(&r.stdout).unwrap();
                assert!(heap <= est, "{what} pipelined: heap {heap} over the estimate {est}");
            }
        }
    }
    eprintln!("{}", rows.join("\n"));
    assert!(bad.is_empty(), "{bad:#?}");
}

/// Initial (untrained) weights of a learned method, written into `dir`.
fn weights_for(dir: &std::path::Path, method: &str) -> Option<std::path::PathBuf> {
    let p = dir.join(format!("{method}.safetensors"));
    match method {
        "wskp" => {
            let net = mcdenoise::methods::wskp::net(6).unwrap();
            let params: Vec<f32> = net.init(1).iter().map(|v| v * 0.3).collect();
            mcdenoise::nn::weights::save_params(
                &p,
                &net,
                &params,
                mcdenoise::nn::weights::Form::Branches,
                "wskp",
                &[("layers", "6".into()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
            )
            .unwrap();
        }
        "afn" => {
            let (k, r) =
                (mcdenoise::methods::afn::kernel_net().unwrap(), mcdenoise::methods::afn::refine_net().unwrap());
            let rp: Vec<f32> = r.init(2).iter().map(|v| v * 0.05).collect();
            mcdenoise::methods::afn::save(&p, &k, &k.init(1), &r, &rp, &[]).unwrap();
        }
        _ => return None,
    }
    Some(p)
}

/// The pixel limit's frame: 8192 x 4096 = 2^25 pixels.
const LIMIT_W: usize = 8192;
const LIMIT_H: usize = 4096;

/// Runs `method` on `input` under address-space limits: each run ends
/// cleanly, either with a whole output or with one line and exit 1 (the
/// refusal from the header, or a failed allocation caught by the CLI's
/// allocator); never an abort, a signal or the OOM killer. Returns, per
/// limit, whether the run succeeded.
fn under_address_space_limits(
    input: &std::path::Path,
    method: &str,
    limits: &[u64],
    out: &std::path::Path,
) -> Vec<bool> {
    let mut ok = Vec::new();
    for &limit in limits {
        let _ = std::fs::remove_dir_all(out);
        let r = run_limited(
            &[
                "denoise",
                "--method",
                method,
                "--half",
                "--threads",
                "2",
                input.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ],
            &[(libc::RLIMIT_AS, limit)],
        );
        let what = format!("{method} on {} under ulimit -v {} MiB", input.display(), limit >> 20);
        assert_eq!(r.signal, None, "{what}: killed by a signal; stderr: {}", r.stderr);
        match r.code {
            Some(0) => {
                let name = input.file_name().unwrap();
                assert!(is_whole_frame(&out.join(name), LIMIT_W, LIMIT_H), "{what}: output not whole");
                ok.push(true);
            }
            _ => {
                assert_clean_failure(&r, 1, "mcdenoise: error:");
                assert!(r.stderr.contains("needs about") || r.stderr.contains("out of memory"), "{what}: {}", r.stderr);
                ok.push(false);
            }
        }
        assert!(temporaries(out).is_empty(), "{what}: temporary files left: {:?}", temporaries(out));
        eprintln!("{what}: {}", if r.code == Some(0) { "ok".to_string() } else { r.stderr.trim().to_string() });
    }
    ok
}

/// A frame at the pixel limit (2^25 pixels, f16 `R,G,B`, uncompressed:
/// 192 MiB of pixels) and a ZIP file of 1.5 MiB that decompresses to the
/// same, under address-space limits of 1 and 4 GiB. 1 GiB is below every
/// method's estimate there, so each is refused from the header; at 4 GiB
/// `none` (36 bytes per pixel, 1.1 GiB) runs and `sure-atrous` (164, 5.1 GiB)
/// is refused; `atrous` (84 bytes per pixel, 2.6 GiB) runs.
#[test]
fn the_pixel_limit_under_an_address_space_limit() {
    let t = tempfile::tempdir().unwrap();
    let raw = t.path().join("limit_raw.exr");
    flat_frame(&raw, LIMIT_W, LIMIT_H, 0.5, true, exr::compression::Compression::Uncompressed);
    let zip = t.path().join("limit_zip.exr");
    flat_frame(&zip, LIMIT_W, LIMIT_H, 0.5, false, exr::compression::Compression::ZIP16);
    let zip_len = std::fs::metadata(&zip).unwrap().len();
    assert!(zip_len < 4 << 20, "the ZIP frame is small: {zip_len} bytes");
    assert!(std::fs::metadata(&raw).unwrap().len() > (3 * 2) << 25, "the raw frame holds its pixels");
    let out = t.path().join("out");
    let (gib1, gib4) = (1u64 << 30, 4u64 << 30);
    for input in [&zip, &raw] {
        assert_eq!(under_address_space_limits(input, "none", &[gib1, gib4], &out), [false, true]);
        assert_eq!(under_address_space_limits(input, "sure-atrous", &[gib1, gib4], &out), [false, false]);
    }
    assert_eq!(under_address_space_limits(&zip, "atrous", &[gib1, gib4], &out), [false, true]);
}

/// `--max-memory` refuses from the header, before allocating (the run's
/// peak resident size stays far below the frame's size), naming the file,
/// the need and the limit; a limit above the need runs.
#[test]
fn max_memory_refuses_from_the_header() {
    let t = tempfile::tempdir().unwrap();
    let zip = t.path().join("big.exr");
    flat_frame(&zip, LIMIT_W, LIMIT_H, 0.25, false, exr::compression::Compression::ZIP16);
    let out = t.path().join("out");
    let r = run_limited(
        &["denoise", "--method", "atrous", "--max-memory", "1G", zip.to_str().unwrap(), "-o", out.to_str().unwrap()],
        &[],
    );
    // The figure follows the method's footprint (std-host/src/memory.rs);
    // the message names the file, the method, the need and the frame.
    assert_clean_failure(&r, 1, "big.exr: atrous in f32 needs about ");
    assert!(r.stderr.contains(" GiB for this 8192x4096 frame ("), "{}", r.stderr);
    assert!(r.stderr.contains("more than --max-memory 1.00 GiB; refused before reading its pixels"), "{}", r.stderr);
    assert!(r.max_rss < 64 << 20, "refused before allocating: peak resident {} bytes", r.max_rss);
    assert!(std::fs::read_dir(&out).unwrap().next().is_none(), "nothing written");
    // Small frames fit in a small budget.
    let small = t.path().join("small.exr");
    flat_frame(&small, 64, 64, 0.25, false, exr::compression::Compression::ZIP16);
    let r = run_limited(
        &[
            "denoise",
            "--method",
            "sure-atrous",
            "--max-memory",
            "32M",
            small.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ],
        &[],
    );
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    // A bad size is a usage error.
    let r = run_limited(&["denoise", "--method", "none", "--max-memory", "lots", "x.exr", "-o", "o"], &[]);
    assert_eq!(r.code, Some(2), "{}", r.stderr);
    assert!(r.stderr.contains("--max-memory: expected a size such as 512M"), "{}", r.stderr);
}

/// An allocation that fails anyway (here in the precision report, which has
/// no estimate: its 8192x8192 inputs under a 400 MiB address space) ends in
/// one line and exit 1 from the CLI's allocator, not an abort.
#[test]
fn a_failed_allocation_ends_in_one_line() {
    let t = tempfile::tempdir().unwrap();
    let csv = t.path().join("p.csv");
    let svg = t.path().join("p.svg");
    let r = run_limited(
        &[
            "precision",
            "--only",
            "avgpool",
            "--size",
            "8192x8192",
            "--csv",
            csv.to_str().unwrap(),
            "--svg",
            svg.to_str().unwrap(),
        ],
        &[(libc::RLIMIT_AS, 400 << 20)],
    );
    assert_clean_failure(&r, 1, "mcdenoise: error: out of memory: an allocation of");
    assert!(!csv.exists() && temporaries(t.path()).is_empty());
}

//! Peak memory of `mcdenoise denoise` per method and precision, measured:
//! `cargo build --release -p mcdenoise && cargo run --release -p
//! mcdenoise-benches --example memory_table -- [WxH ...]` (default
//! 1280x720 and 8192x4096, the pixel limit). For each size it writes frames
//! with every buffer of the input contract (18 f16 channels, ZIP, a noisy
//! synthetic scene), runs the CLI (2 threads, f32 output) on one frame (two
//! for `ta`, `wskp` and `afn`, whose history needs a second), and prints a Markdown row per
//! method and precision: the estimate, the heap the CLI's allocator counted
//! at its peak, and the peak resident size from wait4, each in bytes per
//! pixel and in all. `METHODS=a,b` and `PRECISIONS=a,b` narrow the table;
//! `WEIGHTS_WSKP=FILE`, `WEIGHTS_AFN=FILE` pass `--weights` (default: the
//! bundled weights).
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Instant;

use mcdenoise::io::output::write_exr_rows;

const CHANNELS: [&str; 18] = [
    "R",
    "G",
    "B",
    "B.R",
    "B.G",
    "B.B",
    "albedo.R",
    "albedo.G",
    "albedo.B",
    "normal.X",
    "normal.Y",
    "normal.Z",
    "depth.Z",
    "position.X",
    "position.Y",
    "position.Z",
    "motion.X",
    "motion.Y",
];

/// A noisy checker scene on a sloped plane (see `std-host/tests/common`).
fn value(name: &str, x: usize, y: usize, seed: u64) -> f32 {
    let c = name.bytes().fold(0u64, |a, b| a.wrapping_mul(31).wrapping_add(b as u64));
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ c.wrapping_mul(0x27D4_EB2F_1656_67C5);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    let noise = (h >> 40) as f32 / (1u64 << 24) as f32;
    let checker = (((x / 16) + (y / 16)) % 2) as f32 * 0.6 + 0.2;
    match name {
        "R" | "G" | "B" | "B.R" | "B.G" | "B.B" => checker * (0.5 + noise),
        "albedo.R" | "albedo.G" | "albedo.B" => checker,
        "normal.Z" => 1.0,
        "depth.Z" | "position.Z" => 2.0 + y as f32 * 1e-3,
        "position.X" => x as f32 * 1e-2,
        "position.Y" => y as f32 * 1e-2,
        "motion.X" => -1.0,
        _ => 0.0,
    }
}

/// Waits for `pid`: (wait status, peak resident bytes).
fn wait4(pid: i32) -> (i32, u64) {
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid; wait4 fills it and the status.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    while unsafe { libc::wait4(pid, &mut status, 0, &mut u) } != pid {}
    (status, u.ru_maxrss as u64 * 1024)
}

/// Reads a child's standard output to its end, then reaps it with wait4
/// (std's wait would not give the rusage): (stdout, status, peak resident).
fn finish(mut child: std::process::Child) -> (String, i32, u64) {
    let mut stdout = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut stdout).unwrap();
    let (status, rss) = wait4(child.id() as i32);
    (stdout, status, rss)
}

fn list(var: &str, all: &[&'static str]) -> Vec<&'static str> {
    match std::env::var(var) {
        Ok(v) => all.iter().copied().filter(|m| v.split(',').any(|x| x == *m)).collect(),
        Err(_) => all.to_vec(),
    }
}

fn main() {
    let exe = std::env::current_exe().unwrap();
    let cli: PathBuf = exe.parent().unwrap().parent().unwrap().join("mcdenoise");
    assert!(cli.is_file(), "build the CLI first: cargo build --release -p mcdenoise ({})", cli.display());
    let sizes: Vec<(usize, usize)> = {
        let args: Vec<String> = std::env::args().skip(1).collect();
        let parse = |s: &String| {
            let (w, h) = s.split_once('x').expect("WxH");
            (w.parse().unwrap(), h.parse().unwrap())
        };
        if args.is_empty() {
            vec![(1280, 720), (8192, 4096)]
        } else {
            args.iter().map(parse).collect()
        }
    };
    let methods = list("METHODS", &["none", "ta", "atrous", "sure-atrous", "wskp", "afn"]);
    let precisions = list("PRECISIONS", &["f32", "f16", "f16-arith", "fixed"]);
    let root = std::env::temp_dir().join(format!("mcdenoise-memory-{}", std::process::id()));
    println!("| size | method | precision | estimate B/px | counted heap B/px | peak resident B/px | estimate | counted heap | peak resident | s |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (w, h) in sizes {
        let dir = root.join(format!("{w}x{h}"));
        std::fs::create_dir_all(&dir).unwrap();
        let frames: Vec<PathBuf> = (0..2)
            .map(|i| {
                let p = dir.join(format!("frame_{i:04}.exr"));
                let comp = exr::compression::Compression::ZIP16;
                write_exr_rows(&p, w, h, &CHANNELS, true, comp, |c, y, row| {
                    for (x, v) in row.iter_mut().enumerate() {
                        *v = value(CHANNELS[c], x, y, i);
                    }
                })
                .unwrap();
                p
            })
            .collect();
        let px = (w * h) as f64;
        for &m in &methods {
            for &p in &precisions {
                let out = dir.join("out");
                // The methods with a history peak on their second frame.
                let inputs: &[PathBuf] = if matches!(m, "ta" | "wskp" | "afn") { &frames } else { &frames[..1] };
                let weights: Vec<String> = match std::env::var("WEIGHTS_".to_string() + &m.to_uppercase()) {
                    Ok(w) => vec!["--weights".into(), w],
                    Err(_) => Vec::new(),
                };
                let t0 = Instant::now();
                let child = Command::new(&cli)
                    .args(["denoise", "--method", m, "--precision", p, "--threads", "2", "--timings"])
                    .args(&weights)
                    .args(inputs)
                    .arg("-o")
                    .arg(&out)
                    .stdout(Stdio::piped())
                    .stderr(Stdio::null())
                    .spawn()
                    .unwrap();
                let (stdout, status, rss) = finish(child);
                let secs = t0.elapsed().as_secs_f64();
                let line = stdout.lines().find(|l| l.starts_with("memory:")).unwrap_or("");
                let num = |after: &str, before: &str| -> Option<u64> {
                    line.split(after).nth(1)?.split(before).next()?.trim().parse().ok()
                };
                let pp = num("= ", " bytes per pixel").unwrap_or(0);
                let est = line.split(" bytes); peak heap").next().and_then(|s| s.rsplit('(').next()?.parse().ok());
                let heap: Option<u64> =
                    line.split("peak heap ").nth(1).and_then(|s| s.split('(').nth(1)?.split(' ').next()?.parse().ok());
                if !libc::WIFEXITED(status) || libc::WEXITSTATUS(status) != 0 || est.is_none() {
                    println!("| {w}x{h} | {m} | {p} | failed | | | | | | |");
                    continue;
                }
                let (est, heap) = (est.unwrap(), heap.unwrap_or(0));
                let mib = |b: u64| format!("{:.0} MiB", b as f64 / (1u64 << 20) as f64);
                println!(
                    "| {w}x{h} | {m} | {p} | {pp} | {:.1} | {:.1} | {} | {} | {} | {secs:.1} |",
                    heap as f64 / px,
                    rss as f64 / px,
                    mib(est),
                    mib(heap),
                    mib(rss)
                );
                let _ = std::fs::remove_dir_all(&out);
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
    let _ = std::fs::remove_dir_all(&root);
}

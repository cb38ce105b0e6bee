//! Helpers of the CLI tests that make frames, run the binary under limits
//! and inspect what it left behind.
#![allow(dead_code)]

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use mcdenoise::io::output::write_exr_rows;

/// The `mcdenoise` binary.
pub fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_mcdenoise"));
    c.env("RUST_BACKTRACE", "1");
    c
}

/// The test fixtures.
pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures")
}

/// Every channel of the input contract's buffers.
pub const ALL_CHANNELS: [&str; 18] = [
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

/// A value of channel `name` at `(x, y)` of a synthetic scene (a sloped
/// plane in front of the camera, checker radiance with hashed noise, so it
/// does not compress away); `seed` changes the noise.
pub fn scene_value(name: &str, x: usize, y: usize, seed: u64) -> f32 {
    let channel = name.bytes().fold(0u64, |a, b| a.wrapping_mul(31).wrapping_add(b as u64));
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed.wrapping_mul(0x1656_67B1_9E37_79F9)
        ^ channel.wrapping_mul(0x27D4_EB2F_1656_67C5);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    let noise = (h >> 40) as f32 / (1u64 << 24) as f32; // [0, 1)
    let checker = (((x / 16) + (y / 16)) % 2) as f32 * 0.6 + 0.2;
    match name {
        "R" | "G" | "B" | "B.R" | "B.G" | "B.B" => checker * (0.5 + noise),
        "albedo.R" | "albedo.G" | "albedo.B" => checker,
        "normal.X" | "normal.Y" => 0.0,
        "normal.Z" => 1.0,
        "depth.Z" => 2.0 + y as f32 * 1e-3,
        "position.X" => x as f32 * 1e-2,
        "position.Y" => y as f32 * 1e-2,
        "position.Z" => 2.0 + y as f32 * 1e-3,
        "motion.X" => -1.0,
        _ => 0.0,
    }
}

/// Writes a frame of `channels` from [`scene_value`] (row by row: any size
/// costs one row of memory here).
pub fn scene_frame(path: &Path, w: usize, h: usize, channels: &[&str], half: bool, seed: u64) {
    let comp = exr::compression::Compression::ZIP16;
    write_exr_rows(path, w, h, channels, half, comp, |c, y, row| {
        for (x, v) in row.iter_mut().enumerate() {
            *v = scene_value(channels[c], x, y, seed);
        }
    })
    .unwrap();
}

/// Writes an `R,G,B` frame of one value (compresses to almost nothing
/// with ZIP; `compression` NONE for a file as large as its pixels).
pub fn flat_frame(path: &Path, w: usize, h: usize, v: f32, half: bool, compression: exr::compression::Compression) {
    write_exr_rows(path, w, h, &["R", "G", "B"], half, compression, |_, _, row| row.fill(v)).unwrap();
}

/// A resource limit for a child: `(resource, bytes)`.
pub type Rlimit = (libc::__rlimit_resource_t, u64);

/// What a child run gave: its output, exit status and peak resident size.
pub struct Run {
    /// Exit code (None when a signal ended it).
    pub code: Option<i32>,
    /// The signal that ended it, if one did.
    pub signal: Option<i32>,
    /// Standard output.
    pub stdout: String,
    /// Standard error.
    pub stderr: String,
    /// Peak resident size (wait4's ru_maxrss), bytes.
    pub max_rss: u64,
}

/// Sets up `cmd` to run with `limits` and, when `uid` is given, as that
/// user (and group); the child's standard streams are piped.
pub fn limited(cmd: &mut Command, limits: &[Rlimit], uid: Option<u32>) {
    let limits = limits.to_vec();
    cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    // SAFETY: only async-signal-safe calls (setrlimit, setgroups, setgid,
    // setuid) run between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            for &(res, v) in &limits {
                let r = libc::rlimit { rlim_cur: v, rlim_max: v };
                if libc::setrlimit(res, &r) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            if let Some(u) = uid {
                if libc::setgroups(0, std::ptr::null()) != 0 || libc::setgid(u) != 0 || libc::setuid(u) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
}

/// Runs `cmd` (set up by [`limited`]) to the end and reads its peak
/// resident size with wait4.
pub fn run_measured(mut cmd: Command) -> Run {
    collect(cmd.spawn().expect("the binary starts"))
}

/// Waits for child `pid`: its wait status and peak resident size in bytes.
pub fn wait4(pid: i32) -> (i32, u64) {
    let mut status = 0;
    // SAFETY: an all-zero rusage is valid, and wait4 fills it.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: valid pointers to a status and an rusage.
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        if r == pid {
            break;
        }
        assert_eq!(std::io::Error::last_os_error().kind(), std::io::ErrorKind::Interrupted, "wait4 failed");
    }
    (status, usage.ru_maxrss as u64 * 1024)
}

/// Runs the binary with `args` under `limits`.
pub fn run_limited(args: &[&str], limits: &[Rlimit]) -> Run {
    let mut c = bin();
    c.args(args);
    limited(&mut c, limits, None);
    run_measured(c)
}

/// Asserts a clean failure: exit `code`, one line on stderr naming
/// `needle`, no panic, abort or backtrace.
#[track_caller]
pub fn assert_clean_failure(r: &Run, code: i32, needle: &str) {
    assert_eq!(r.signal, None, "ended by a signal; stderr: {}", r.stderr);
    assert_eq!(r.code, Some(code), "stderr: {}", r.stderr);
    assert!(r.stderr.contains(needle), "stderr should name '{needle}': {}", r.stderr);
    for bad in ["panicked", "backtrace", "internal error", "memory allocation of"] {
        assert!(!r.stderr.contains(bad), "{bad}: {}", r.stderr);
    }
    assert_eq!(r.stderr.lines().count(), 1, "one line expected: {}", r.stderr);
}

/// The temporary output files left in `dir`.
pub fn temporaries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.contains("tmp") || n.contains("probe"))
                .collect()
        })
        .unwrap_or_default()
}

/// Whether `path` is a whole EXR frame of `w` x `h` (loads, and has that size).
pub fn is_whole_frame(path: &Path, w: usize, h: usize) -> bool {
    mcdenoise::Frame::load(path, &mcdenoise::Limits::default()).is_ok_and(|f| (f.width, f.height) == (w, h))
}

/// The `--timings` memory line: (estimate bytes per pixel, estimate bytes,
/// peak heap bytes).
pub fn memory_line(stdout: &str) -> Option<(u64, u64, u64)> {
    let line = stdout.lines().find(|l| l.starts_with("memory:"))?;
    let num = |s: &str| s.trim().parse::<u64>().ok();
    let per_pixel = num(line.split(" bytes per pixel").next()?.rsplit("= ").next()?)?;
    let est = num(line.split(" bytes); peak heap").next()?.rsplit('(').next()?)?;
    let heap = num(line.split("peak heap ").nth(1)?.split('(').nth(1)?.split(' ').next()?)?;
    Some((per_pixel, est, heap))
}

/// Makes `p` readable (and enterable) by everyone, for a child run as another user.
pub fn open_up(p: &Path, mode: u32) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap();
}

/// The effective user id.
pub fn euid() -> u32 {
    // SAFETY: geteuid has no preconditions.
    unsafe { libc::geteuid() }
}

/// Makes a FIFO at `p`.
pub fn mkfifo(p: &Path) {
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0, "mkfifo: {}", std::io::Error::last_os_error());
}

/// Writes `bytes` into FIFO `p` from a thread (then, with `endless`, zeros
/// until the reader goes away).
pub fn feed_fifo(p: &Path, bytes: Vec<u8>, endless: bool) -> std::thread::JoinHandle<()> {
    let p = p.to_path_buf();
    std::thread::spawn(move || {
        use std::io::Write;
        let Ok(mut f) = std::fs::OpenOptions::new().write(true).open(&p) else { return };
        if f.write_all(&bytes).is_err() {
            return;
        }
        let zeros = vec![0u8; 1 << 16];
        while endless && f.write_all(&zeros).is_ok() {}
    })
}

/// Polls `cond` every 2 ms for up to 60 s.
#[track_caller]
pub fn wait_for(cond: impl Fn() -> bool, what: &str) {
    let t0 = Instant::now();
    while !cond() {
        assert!(t0.elapsed() < Duration::from_secs(60), "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

pub fn signal(child: &std::process::Child, sig: i32) {
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, sig) }, 0);
}

/// Waits for a child started with piped streams and collects its run.
pub fn collect(mut child: std::process::Child) -> Run {
    let out = child.stdout.take().unwrap();
    let err = child.stderr.take().unwrap();
    let read = |mut r: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut s = String::new();
            r.read_to_string(&mut s).ok();
            s
        })
    };
    let (o, e) = (read(Box::new(out)), read(Box::new(err)));
    let (status, rss) = wait4(child.id() as i32);
    Run {
        code: libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status)),
        signal: libc::WIFSIGNALED(status).then(|| libc::WTERMSIG(status)),
        stdout: o.join().unwrap(),
        stderr: e.join().unwrap(),
        max_rss: rss,
    }
}

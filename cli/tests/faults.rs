//! File-system faults and interruptions: a full disk, a read-only output
//! directory, two processes writing one directory, SIGINT and SIGTERM. Each
//! ends in one clear line and its exit code, with every output written
//! before it whole and no temporary file left behind.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;

/// A sequence of three `R,G,B` frames of `w` x `w`: two flat ones (their
/// ZIP outputs take a few KiB) and a noisy last one (its f32 output takes
/// about `12 w^2` bytes), so that only the last output overflows a small
/// disk or file-size limit.
fn sequence(dir: &Path, w: usize) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let mut files = Vec::new();
    for i in 0..3 {
        let p = dir.join(format!("frame_{i:04}.exr"));
        if i < 2 {
            flat_frame(&p, w, w, 0.25 * (i + 1) as f32, true, exr::compression::Compression::ZIP16);
        } else {
            scene_frame(&p, w, w, &["R", "G", "B"], true, 7);
        }
        files.push(p);
    }
    files
}

/// Asserts the outputs of a sequence stopped at frame `failed`: the ones
/// before it whole, none from it on, no temporary file.
#[track_caller]
fn assert_outputs_before(out: &Path, failed: usize, w: usize) {
    for i in 0..3 {
        let p = out.join(format!("frame_{i:04}.exr"));
        if i < failed {
            assert!(is_whole_frame(&p, w, w), "{} is whole", p.display());
        } else {
            assert!(!p.exists(), "{} not written", p.display());
        }
    }
    assert!(temporaries(out).is_empty(), "temporary files left: {:?}", temporaries(out));
}

/// A tmpfs mounted for the test, unmounted when dropped.
struct Tmpfs(PathBuf);

impl Tmpfs {
    /// Mounts a tmpfs of `size` (mount(8)'s syntax) on `dir`, or says why not.
    fn mount(dir: &Path, size: &str) -> Result<Tmpfs, String> {
        if euid() != 0 {
            return Err("not root, so no tmpfs can be mounted".into());
        }
        std::fs::create_dir_all(dir).unwrap();
        let c = |s: &str| std::ffi::CString::new(s).unwrap();
        let (src, target, fs, opts) =
            (c("tmpfs"), c(dir.to_str().unwrap()), c("tmpfs"), c(&format!("size={size},mode=0755")));
        // SAFETY: valid NUL-terminated strings for mount(2).
        let r = unsafe { libc::mount(src.as_ptr(), target.as_ptr(), fs.as_ptr(), 0, opts.as_ptr().cast()) };
        if r != 0 {
            return Err(format!("mount(tmpfs) failed: {}", std::io::Error::last_os_error()));
        }
        Ok(Tmpfs(dir.to_path_buf()))
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let target = std::ffi::CString::new(self.0.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        unsafe { libc::umount2(target.as_ptr(), libc::MNT_DETACH) };
    }
}

fn denoise(inputs: &[&Path], out: &Path, extra: &[&str]) -> Command {
    denoise_with(Path::new(env!("CARGO_BIN_EXE_mcdenoise")), inputs, out, extra)
}

fn denoise_with(binary: &Path, inputs: &[&Path], out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(binary);
    // f32 outputs, whatever the inputs hold: the sizes above assume them.
    c.args(["denoise", "--method", "none", "--threads", "2", "--float"]).args(extra);
    c.args(inputs).arg("-o").arg(out);
    c
}

/// A full disk: a 512 KiB tmpfs takes the first two outputs, not the third
/// (~770 KiB). Where no tmpfs can be mounted the test says so and
/// [`full_disk_through_the_file_size_limit`] covers the case.
#[test]
fn full_disk_on_a_small_tmpfs() {
    let t = tempfile::tempdir().unwrap();
    let files = sequence(&t.path().join("in"), 256);
    let mnt = t.path().join("mnt");
    let _fs = match Tmpfs::mount(&mnt, "512k") {
        Ok(m) => m,
        Err(why) => {
            eprintln!("skipped: full disk on a tmpfs: {why}; the file-size-limit test covers a full disk");
            return;
        }
    };
    let out = mnt.join("out");
    let mut c = denoise(&[&files[0], &files[1], &files[2]], &out, &[]);
    limited(&mut c, &[], None);
    let r = run_measured(c);
    assert_clean_failure(&r, 1, "frame_0002.exr: cannot write: the disk is full: No space left on device");
    assert_outputs_before(&out, 2, 256);
}

/// The same through `ulimit -f` (setrlimit RLIMIT_FSIZE in the child,
/// 256 KiB): the write past the limit fails (SIGXFSZ is ignored by the
/// CLI) and is reported; no root needed.
#[test]
fn full_disk_through_the_file_size_limit() {
    let t = tempfile::tempdir().unwrap();
    let files = sequence(&t.path().join("in"), 256);
    let out = t.path().join("out");
    let mut c = denoise(&[&files[0], &files[1], &files[2]], &out, &[]);
    limited(&mut c, &[(libc::RLIMIT_FSIZE, 256 << 10)], None);
    let r = run_measured(c);
    assert_clean_failure(&r, 1, "frame_0002.exr: cannot write: the file-size limit (ulimit -f) is reached");
    assert_outputs_before(&out, 2, 256);
}

/// The user the CLI runs as in the permission tests: `nobody` when the
/// tests run as root (who may write anywhere), else the user itself.
fn unprivileged() -> Option<u32> {
    (euid() == 0).then_some(65534)
}

/// A read-only output directory: refused before anything is written, an
/// earlier output in it kept byte for byte; and a directory that becomes
/// read-only in the middle of a sequence (the third input is a FIFO, so
/// the CLI waits while the directory is made read-only): the third output
/// fails in one line, the first two stay whole, nothing temporary is left.
#[test]
fn read_only_output_directory() {
    let t = tempfile::tempdir().unwrap();
    open_up(t.path(), 0o755);
    let files = sequence(&t.path().join("in"), 64);
    let uid = unprivileged();
    // The binary where `nobody` may run it (the build's directory may not
    // be open to it).
    let binary = t.path().join("mcdenoise");
    std::fs::copy(env!("CARGO_BIN_EXE_mcdenoise"), &binary).unwrap();
    open_up(&binary, 0o755);
    // Read-only from the start, with an earlier result in it.
    let out = t.path().join("ro");
    std::fs::create_dir(&out).unwrap();
    let earlier = out.join("frame_0000.exr");
    std::fs::write(&earlier, b"an earlier result").unwrap();
    open_up(&out, 0o555);
    let mut c = denoise_with(&binary, &[&files[0], &files[1]], &out, &[]);
    limited(&mut c, &[], uid);
    let r = run_measured(c);
    assert_clean_failure(&r, 1, "ro: cannot write: directory is not writable (Permission denied");
    assert_eq!(std::fs::read(&earlier).unwrap(), b"an earlier result");
    assert!(temporaries(&out).is_empty());
    // Read-only from the third frame on.
    let out = t.path().join("later");
    std::fs::create_dir(&out).unwrap();
    open_up(&out, 0o777);
    let fifo = t.path().join("in/frame_0002.fifo.exr");
    mkfifo(&fifo);
    let mut c = denoise_with(&binary, &[&files[0], &files[1], &fifo], &out, &[]);
    limited(&mut c, &[], uid);
    let child = c.spawn().unwrap();
    wait_for(|| (0..2).all(|i| out.join(format!("frame_{i:04}.exr")).exists()), "the first two outputs");
    open_up(&out, 0o555);
    feed_fifo(&fifo, std::fs::read(&files[2]).unwrap(), false);
    let r = collect(child);
    assert_clean_failure(&r, 1, "frame_0002.fifo.exr: cannot write: Permission denied");
    open_up(&out, 0o755);
    for i in 0..2 {
        assert!(is_whole_frame(&out.join(format!("frame_{i:04}.exr")), 64, 64));
    }
    assert!(!out.join("frame_0002.fifo.exr").exists());
    assert!(temporaries(&out).is_empty(), "{:?}", temporaries(&out));
}

/// Two processes writing the same outputs into one directory at once
/// (`none` and `atrous`, four 512x512 frames, three rounds): every file
/// there is afterwards the whole output of one of them, byte for byte, and
/// no temporary file is left.
#[test]
fn two_processes_writing_one_directory_leave_whole_files() {
    let t = tempfile::tempdir().unwrap();
    let inp = t.path().join("in");
    std::fs::create_dir(&inp).unwrap();
    for i in 0..4 {
        scene_frame(&inp.join(format!("frame_{i:04}.exr")), 512, 512, &ALL_CHANNELS, true, i);
    }
    let methods = ["none", "atrous"];
    let alone: Vec<PathBuf> = methods.iter().map(|m| t.path().join(format!("alone-{m}"))).collect();
    for (m, dir) in methods.iter().zip(&alone) {
        let s = bin()
            .args(["denoise", "--method", m, inp.to_str().unwrap(), "-o", dir.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(s.status.success(), "{}", String::from_utf8_lossy(&s.stderr));
    }
    let shared = t.path().join("shared");
    for round in 0..3 {
        let children: Vec<_> = methods
            .iter()
            .map(|m| {
                let mut c = bin();
                c.args(["denoise", "--method", m, inp.to_str().unwrap(), "-o", shared.to_str().unwrap()]);
                limited(&mut c, &[], None);
                c.spawn().unwrap()
            })
            .collect();
        for c in children {
            let r = collect(c);
            assert_eq!(r.code, Some(0), "round {round}: {}", r.stderr);
        }
        for i in 0..4 {
            let name = format!("frame_{i:04}.exr");
            let got = std::fs::read(shared.join(&name)).unwrap();
            assert!(
                alone.iter().any(|d| std::fs::read(d.join(&name)).unwrap() == got),
                "round {round}: {name} is not one process's whole output"
            );
        }
        let names: Vec<_> = std::fs::read_dir(&shared).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names.len(), 4, "round {round}: only the outputs: {names:?}");
    }
}

/// SIGTERM while the CLI waits for its third frame (a FIFO nobody writes):
/// exit 143, one line, the two outputs before it whole, nothing temporary.
#[test]
fn sigterm_while_waiting_for_a_frame() {
    let t = tempfile::tempdir().unwrap();
    let files = sequence(&t.path().join("in"), 64);
    let fifo = t.path().join("in/frame_0002.fifo.exr");
    mkfifo(&fifo);
    let out = t.path().join("out");
    let mut c = denoise(&[&files[0], &files[1], &fifo], &out, &[]);
    limited(&mut c, &[], None);
    let child = c.spawn().unwrap();
    wait_for(|| (0..2).all(|i| out.join(format!("frame_{i:04}.exr")).exists()), "the first two outputs");
    signal(&child, libc::SIGTERM);
    let r = collect(child);
    assert_clean_failure(&r, 143, "interrupted by SIGTERM after 2 complete output files; no partial file left");
    for i in 0..2 {
        assert!(is_whole_frame(&out.join(format!("frame_{i:04}.exr")), 64, 64));
    }
    assert!(temporaries(&out).is_empty(), "{:?}", temporaries(&out));
}

/// SIGINT (and, in a second run, SIGTERM) while an output is being written
/// (2048x2048 noisy frames: each f32 output takes a while to compress):
/// the signal comes as soon as a temporary file is seen; exit 130 / 143,
/// the outputs renamed before it whole, the temporary file gone.
#[test]
fn interrupted_while_writing() {
    let t = tempfile::tempdir().unwrap();
    let inp = t.path().join("in");
    std::fs::create_dir(&inp).unwrap();
    let w = 2048;
    for i in 0..3 {
        scene_frame(&inp.join(format!("frame_{i:04}.exr")), w, w, &["R", "G", "B"], true, i);
    }
    for (sig, code) in [(libc::SIGINT, 130), (libc::SIGTERM, 143)] {
        let out = t.path().join(format!("out{sig}"));
        let mut c = bin();
        c.args(["denoise", "--method", "none", inp.to_str().unwrap(), "-o", out.to_str().unwrap()]);
        limited(&mut c, &[], None);
        let child = c.spawn().unwrap();
        wait_for(|| out.join("frame_0000.exr").exists() && !temporaries(&out).is_empty(), "a temporary output");
        signal(&child, sig);
        let r = collect(child);
        assert_eq!(r.code, Some(code), "{}", r.stderr);
        assert_clean_failure(&r, code, "complete output file");
        eprintln!("{}", r.stderr.trim());
        let written: Vec<_> = (0..3).map(|i| out.join(format!("frame_{i:04}.exr"))).filter(|p| p.exists()).collect();
        assert!(!written.is_empty());
        for p in &written {
            assert!(is_whole_frame(p, w, w), "{} whole", p.display());
        }
        assert!(temporaries(&out).is_empty(), "{:?}", temporaries(&out));
    }
}

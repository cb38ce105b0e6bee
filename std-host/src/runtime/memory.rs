//! Memory: what a run will take, weighed from a frame's header before
//! anything is allocated, against what it may take.
//!
//! The estimate of one frame's peak heap is `per_pixel * pixels + fixed`:
//! - the frame's planes (4 bytes per plane of each buffer the file has);
//! - the method's own bytes per pixel: each method declares a
//!   [`Footprint`] for a precision and the buffers present
//!   ([`crate::methods::footprint`], one entry per method), by replaying its
//!   allocations in a [`Ledger`];
//! - the output (3 f32 planes) and the PNG preview while they are written;
//! - fixed: the band scratch of every thread, the loader's block buffers
//!   (one compressed chunk and one decoded block at a time), the writer's
//!   block buffers and a baseline for everything small.
//!
//! The limits it is checked against ([`Budget`]): `--max-memory` when given,
//! else the memory available now (`MemAvailable`, and the cgroup's
//! `memory.max` when one is set); and always the address-space and data
//! limits (`ulimit -v`, `ulimit -d`), less what the process maps already.
//! `docs/memory.md` has the measured figures beside the estimates.
//!
//! [`CountingAlloc`] (the CLI's global allocator) counts the live heap and
//! its peak, for `--timings` and the tests that hold the estimates to what
//! the code allocates; an allocation that fails ends the run with one line
//! (exit 1) after removing the temporary outputs, never with an abort.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Parses a size: a whole or decimal number, optionally followed by `K`,
/// `M`, `G` or `T` (powers of 1024; `KiB`, `MB` and the like mean the same;
/// any case), or `B` for bytes.
pub fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let bad = || format!("expected a size such as 512M, 2G or 1.5GiB, got '{s}'");
    let shift = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => return Err(bad()),
    };
    let v: f64 = num.parse().map_err(|_| bad())?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < 2f64.powi(63)) {
        return Err(format!("expected a size from 1 byte to 8 EiB, got '{s}'"));
    }
    Ok(bytes as u64)
}

/// `bytes` for people: `123 B`, `4.0 KiB`, `512 MiB`, `1.25 GiB`.
pub fn format_bytes(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["KiB", "MiB", "GiB", "TiB", "PiB"];
    if bytes < 1024 {
        return format!("{bytes} B");
    }
    let mut v = bytes as f64 / 1024.0;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if v >= 100.0 {
        format!("{v:.0} {}", UNITS[u])
    } else if v >= 10.0 {
        format!("{v:.1} {}", UNITS[u])
    } else {
        format!("{v:.2} {}", UNITS[u])
    }
}

/// A replay of a method's allocations in bytes per pixel: the bytes live
/// now and the most that were.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ledger {
    now: u64,
    peak: u64,
}

impl Ledger {
    /// Allocates `b` bytes per pixel.
    pub fn alloc(&mut self, b: u64) -> &mut Self {
        self.now += b;
        self.peak = self.peak.max(self.now);
        self
    }
    /// Frees `b` bytes per pixel.
    pub fn free(&mut self, b: u64) -> &mut Self {
        self.now = self.now.checked_sub(b).expect("a ledger frees only what it allocated");
        self
    }
    /// Allocates `b` bytes per pixel and frees them again (a temporary).
    pub fn temp(&mut self, b: u64) -> &mut Self {
        self.alloc(b).free(b)
    }
    /// Bytes per pixel live now.
    pub fn now(&self) -> u64 {
        self.now
    }
    /// The most bytes per pixel that were live.
    pub fn peak(&self) -> u64 {
        self.peak
    }
}

/// What a method takes on top of the frame it is handed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Footprint {
    /// Bytes per pixel kept from one frame to the next (history, level
    /// buffers), live while the next frame is read and the output written.
    pub kept: u64,
    /// Bytes per pixel at the method's peak during a frame, `kept` and the
    /// 3-plane f32 output it returns included.
    pub peak: u64,
    /// Bytes of scratch, every thread's band together (kept).
    pub scratch: u64,
}

/// Heap the CLI takes besides the frames (its threads' bookkeeping, the
/// progress bar, argument and path strings, the per-band job lists).
pub const BASELINE_BYTES: u64 = 8 << 20;

/// A limit on the memory of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LimitKind {
    /// `--max-memory`.
    Flag,
    /// The memory available now (`MemAvailable`, the cgroup's `memory.max`).
    Available,
    /// `RLIMIT_AS` (`ulimit -v`).
    AddressSpace,
    /// `RLIMIT_DATA` (`ulimit -d`).
    Data,
}

/// One limit: how much the run may still take under it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limit {
    /// Which.
    pub kind: LimitKind,
    /// The limit as set.
    pub total: u64,
    /// What is left of it for the run's heap.
    pub free: u64,
}

impl Limit {
    /// The limit in words, for an error message.
    pub fn describe(&self) -> String {
        match self.kind {
            LimitKind::Flag => format!("--max-memory {}", format_bytes(self.total)),
            LimitKind::Available => {
                format!("the {} of memory available now (--max-memory SIZE overrides this)", format_bytes(self.free))
            }
            LimitKind::AddressSpace => format!(
                "the {} of address space left under this process's limit of {} (ulimit -v)",
                format_bytes(self.free),
                format_bytes(self.total)
            ),
            LimitKind::Data => format!(
                "the {} of data segment left under this process's limit of {} (ulimit -d)",
                format_bytes(self.free),
                format_bytes(self.total)
            ),
        }
    }
}

/// Address space reserved per thread beyond the estimate: a glibc malloc
/// arena (64 MiB, reserved whole) and a stack.
const THREAD_RESERVE: u64 = 72 << 20;

/// The limits a run is held to.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Budget {
    /// Every limit that applies.
    pub limits: Vec<Limit>,
}

impl Budget {
    /// The limits now: `max_memory` (or, without it, the memory available),
    /// and the process's address-space and data limits less what it maps
    /// already and a reserve for `threads` threads.
    pub fn detect(max_memory: Option<u64>, threads: usize) -> Budget {
        let mut limits = Vec::new();
        match max_memory {
            Some(m) => limits.push(Limit { kind: LimitKind::Flag, total: m, free: m }),
            None => {
                if let Some(a) = available_memory() {
                    limits.push(Limit { kind: LimitKind::Available, total: a, free: a });
                }
            }
        }
        let reserve = THREAD_RESERVE * (threads as u64 + 1);
        for (kind, res, used) in [
            (LimitKind::AddressSpace, libc::RLIMIT_AS, status_kib("VmSize:")),
            (LimitKind::Data, libc::RLIMIT_DATA, status_kib("VmData:")),
        ] {
            if let Some(total) = rlimit(res) {
                let used = used.unwrap_or(0);
                limits.push(Limit { kind, total, free: total.saturating_sub(used).saturating_sub(reserve) });
            }
        }
        Budget { limits }
    }

    /// The tightest limit.
    pub fn tightest(&self) -> Option<Limit> {
        self.limits.iter().copied().min_by_key(|l| l.free)
    }
}

/// A resource limit's soft value, if one is set.
fn rlimit(resource: libc::__rlimit_resource_t) -> Option<u64> {
    let mut r = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: `r` is a valid rlimit for getrlimit to fill.
    let ok = unsafe { libc::getrlimit(resource, &mut r) } == 0;
    (ok && r.rlim_cur != libc::RLIM_INFINITY).then_some(r.rlim_cur)
}

/// A `kB` field of /proc/self/status, in bytes.
fn status_kib(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    kib_field(&s, field)
}

fn kib_field(text: &str, field: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(field))?;
    let kib: u64 = line[field.len()..].trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kib * 1024)
}

/// The memory available to this process now: `MemAvailable`, and what its
/// cgroup (v2) still allows when it sets `memory.max`.
pub fn available_memory() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| kib_field(&s, "MemAvailable:"));
    let cgroup = (|| {
        let line = std::fs::read_to_string("/proc/self/cgroup").ok()?;
        let rel = line.lines().find_map(|l| l.strip_prefix("0::"))?.trim().trim_start_matches('/').to_string();
        let dir = std::path::Path::new("/sys/fs/cgroup").join(rel);
        let max: u64 = std::fs::read_to_string(dir.join("memory.max")).ok()?.trim().parse().ok()?;
        let cur: u64 = std::fs::read_to_string(dir.join("memory.current")).ok()?.trim().parse().ok()?;
        Some(max.saturating_sub(cur))
    })();
    match (meminfo, cgroup) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// The process's peak resident size so far (`ru_maxrss`), in bytes.
pub fn peak_resident() -> Option<u64> {
    // SAFETY: an all-zero rusage is valid, and getrusage fills it.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `u` is a valid rusage for getrusage to fill.
    let ok = unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } == 0;
    (ok && u.ru_maxrss > 0).then(|| u.ru_maxrss as u64 * 1024)
}

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static COUNTING: AtomicBool = AtomicBool::new(false);

/// The system allocator, counting the live heap and its peak, and ending
/// the run cleanly when an allocation fails (see the module notes). The CLI
/// installs it as its global allocator.
#[derive(Debug, Default)]
pub struct CountingAlloc;

impl CountingAlloc {
    #[inline]
    fn grew(n: usize) {
        let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
        PEAK.fetch_max(now, Ordering::Relaxed);
    }
}

// SAFETY: every call is passed to `System` unchanged; the counters are
// atomics and the failure path allocates nothing.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's layout contract is forwarded.
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            out_of_memory(layout.size());
        }
        Self::grew(layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            out_of_memory(layout.size());
        }
        Self::grew(layout.size());
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            out_of_memory(new_size);
        }
        if new_size >= layout.size() {
            Self::grew(new_size - layout.size());
        } else {
            LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
        }
        p
    }
}

/// Marks the counting allocator as installed (called by the CLI's `main`).
pub fn counting_installed() {
    COUNTING.store(true, Ordering::Relaxed);
}

/// The live heap and its peak so far, in bytes, when the counting allocator
/// is installed.
pub fn heap() -> Option<(u64, u64)> {
    COUNTING.load(Ordering::Relaxed).then(|| (LIVE.load(Ordering::Relaxed) as u64, PEAK.load(Ordering::Relaxed) as u64))
}

/// A failed allocation: remove the temporary outputs, say so in one line
/// and exit 1. Allocates nothing (the line is formatted on the stack).
#[cold]
fn out_of_memory(size: usize) -> ! {
    struct Line {
        buf: [u8; 320],
        len: usize,
    }
    impl std::fmt::Write for Line {
        fn write_str(&mut self, s: &str) -> std::fmt::Result {
            let n = s.len().min(self.buf.len() - self.len);
            self.buf[self.len..self.len + n].copy_from_slice(&s.as_bytes()[..n]);
            self.len += n;
            Ok(())
        }
    }
    let removed = crate::runtime::cleanup::remove_all_now();
    let mut line = Line { buf: [0; 320], len: 0 };
    let _ = std::fmt::Write::write_fmt(
        &mut line,
        format_args!(
            "mcdenoise: error: out of memory: an allocation of {size} bytes failed with {} MiB in use \
             ({removed} temporary file(s) removed, finished outputs kept); see --max-memory\n",
            LIVE.load(Ordering::Relaxed) >> 20
        ),
    );
    // SAFETY: writes `len` initialised bytes of `buf` to stderr, then ends
    // the process without running anything else.
    unsafe {
        libc::write(2, line.buf.as_ptr().cast(), line.len);
        libc::_exit(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_in_powers_of_1024() {
        assert_eq!(parse_size("4096"), Ok(4096));
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("2g"), Ok(2 << 30));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("64KB"), Ok(64 << 10));
        assert_eq!(parse_size("1T"), Ok(1 << 40));
        assert_eq!(parse_size(" 100 B "), Ok(100));
        for bad in ["", "x", "12Q", "-1G", "0", "1e3", "1..2G", "5ibb", "2GiBB", "1e400"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn bytes_read_well() {
        assert_eq!(format_bytes(100), "100 B");
        assert_eq!(format_bytes(4096), "4.00 KiB");
        assert_eq!(format_bytes(512 << 20), "512 MiB");
        assert_eq!(format_bytes(3 << 29), "1.50 GiB");
        assert_eq!(format_bytes(20 << 30), "20.0 GiB");
    }

    #[test]
    fn ledger_keeps_the_peak() {
        let mut l = Ledger::default();
        l.alloc(12).temp(8).alloc(4).free(12);
        assert_eq!((l.now(), l.peak()), (4, 20));
    }

    #[test]
    fn proc_fields_parse() {
        assert_eq!(kib_field("Name: x\nVmSize:\t  2048 kB\n", "VmSize:"), Some(2 << 20));
        assert_eq!(kib_field("MemAvailable:   100 kB", "MemAvailable:"), Some(102_400));
        assert_eq!(kib_field("Other: 1 kB", "VmSize:"), None);
    }
}

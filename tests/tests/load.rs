//! Safety under load: hundreds of frames through the stateful method (the
//! temporal history) and a stateless one; memory must stay flat and every
//! output finite. Alone in its own test binary so no other test's
//! allocations move the counts.
//!
//! Memory is measured two ways: the heap bytes live through this binary's
//! counting allocator (every platform), and the resident set size from
//! `/proc/self/statm` (Linux only: elsewhere that check says it is skipped).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicIsize, AtomicUsize, Ordering};

use mcdenoise::io::frame::{Buffer, Frame};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::runtime::precision::PrecisionKind;

/// The system allocator, counting live bytes and allocation calls.
struct Counting;

static LIVE: AtomicIsize = AtomicIsize::new(0);
static CALLS: AtomicUsize = AtomicUsize::new(0);
static BYTES: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call forwards to `System` with the same arguments; the
// counters are only statistics.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        LIVE.fetch_add(l.size() as isize, Ordering::Relaxed);
        CALLS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(l.size(), Ordering::Relaxed);
        // SAFETY: as the caller's contract.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        LIVE.fetch_sub(l.size() as isize, Ordering::Relaxed);
        // SAFETY: as the caller's contract.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        LIVE.fetch_add(l.size() as isize, Ordering::Relaxed);
        CALLS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(l.size(), Ordering::Relaxed);
        // SAFETY: as the caller's contract.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        LIVE.fetch_add(new as isize - l.size() as isize, Ordering::Relaxed);
        CALLS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(new, Ordering::Relaxed);
        // SAFETY: as the caller's contract.
        unsafe { System.realloc(p, l, new) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Resident set size in bytes, from /proc/self/statm (None off Linux).
fn rss() -> Option<usize> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: usize = s.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

/// Frame `t` of a scene panning one pixel per frame, with a firefly now and then.
fn frame(t: usize, w: usize, h: usize) -> Frame {
    let n = w * h;
    let mut c = vec![0.0f32; 3 * n];
    for y in 0..h {
        for x in 0..w {
            let v = (((x + t) / 4 + y / 4) % 2) as f32 * 0.8 + 0.1;
            for ch in 0..3 {
                c[ch * n + y * w + x] = v * (1.0 + 0.3 * ((x * 7 + y * 13 + t * 31 + ch) % 17) as f32 / 17.0);
            }
        }
    }
    if t.is_multiple_of(7) {
        c[(t * 37) % n] = 1e5;
    }
    let mut f = Frame::from_color(format!("f{t}.exr"), w, h, c).unwrap();
    let mut motion = vec![0.0f32; 2 * n];
    motion[..n].fill(-1.0);
    f.set(Buffer::Motion, motion).unwrap();
    let mut pos = vec![0.0f32; 3 * n];
    for y in 0..h {
        for x in 0..w {
            pos[y * w + x] = (x + t) as f32 * 0.01;
            pos[n + y * w + x] = y as f32 * 0.01;
            pos[2 * n + y * w + x] = 1.0;
        }
    }
    f.set(Buffer::Position, pos).unwrap();
    f
}

#[test]
fn long_sequences_keep_memory_flat_and_outputs_finite() {
    let (w, h) = (64, 40);
    if rss().is_none() {
        eprintln!("skipped: the resident-size check (no /proc/self/statm here); the heap check still runs");
    }
    for (kind, precision) in [
        (MethodKind::Ta, PrecisionKind::F32),
        (MethodKind::Ta, PrecisionKind::Fixed),
        (MethodKind::SureAtrous, PrecisionKind::F16),
        (MethodKind::Atrous, PrecisionKind::F32),
    ] {
        let settings = Settings { threads: 2, precision, ..Settings::default() };
        let mut den = methods::create(kind, &settings, &frame(0, w, h)).unwrap();
        let mut ctx = methods::context(&settings).unwrap();
        let mut t = Timings::default();
        let (mut warm_rss, mut warm_live, mut warm_calls, mut warm_bytes) = (None, 0, 0, 0);
        // What the test itself allocates per frame: the frame's buffers.
        let before = BYTES.load(Ordering::Relaxed);
        drop(frame(0, w, h));
        let frame_bytes = BYTES.load(Ordering::Relaxed) - before;
        let frames = 400;
        for i in 0..frames {
            let f = frame(i, w, h);
            let out = den.denoise(&f, &mut ctx, &mut t).unwrap();
            assert!(out.iter().all(|v| v.is_finite()), "{kind:?} {precision:?} frame {i}");
            drop((out, f));
            if i == 50 {
                warm_rss = rss();
                warm_live = LIVE.load(Ordering::Relaxed);
                warm_calls = CALLS.load(Ordering::Relaxed);
                warm_bytes = BYTES.load(Ordering::Relaxed);
            }
        }
        let live = LIVE.load(Ordering::Relaxed) - warm_live;
        let calls = (CALLS.load(Ordering::Relaxed) - warm_calls) as f64 / (frames - 51) as f64;
        let per_frame = (BYTES.load(Ordering::Relaxed) - warm_bytes) / (frames - 51);
        // Besides the frame and the returned output (3 f32 planes), the
        // à-trous methods allocate only bookkeeping per frame (band lists,
        // the thread pool's jobs): their image buffers are kept across
        // frames. (Temporal accumulation builds each frame's history anew.)
        let own = per_frame.saturating_sub(frame_bytes + 3 * 4 * w * h);
        eprintln!(
            "{kind:?} {precision:?}: live heap grew by {live} bytes over 350 frames; per frame {calls:.1} allocations, \
             {own} bytes besides the frame and the output"
        );
        if matches!(kind, MethodKind::Atrous | MethodKind::SureAtrous) && precision == PrecisionKind::F32 {
            assert!(
                own < 16 << 10,
                "{kind:?} {precision:?}: {own} bytes allocated per frame besides the frame and the output"
            );
        }
        // The per-stage timing table may add a few entries; frames must not accumulate.
        assert!(live < 64 << 10, "{kind:?} {precision:?}: live heap grew by {live} bytes over 350 frames");
        if let (Some(a), Some(b)) = (warm_rss, rss()) {
            let grown = b.saturating_sub(a);
            eprintln!("{kind:?} {precision:?}: resident size grew by {grown} bytes over 350 frames");
            assert!(grown < 4 << 20, "{kind:?} {precision:?}: memory grew by {grown} bytes over 350 frames");
        }
    }
}

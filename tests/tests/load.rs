//! Safety under load: hundreds of frames through the stateful method (the
//! temporal history) and a stateless one; memory must stay flat and every
//! output finite. Alone in its own test binary so no other test's
//! allocations move the resident size.

use mcdenoise::frame::{Buffer, Frame};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::precision::PrecisionKind;

/// Resident set size in bytes, from /proc/self/statm.
fn rss() -> usize {
    let s = std::fs::read_to_string("/proc/self/statm").unwrap_or_default();
    let pages: usize = s.split_whitespace().nth(1).and_then(|v| v.parse().ok()).unwrap_or(0);
    pages * 4096
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
    for (kind, precision) in [
        (MethodKind::Ta, PrecisionKind::F32),
        (MethodKind::Ta, PrecisionKind::Fixed),
        (MethodKind::SureAtrous, PrecisionKind::F16),
    ] {
        let settings = Settings { threads: 2, precision, ..Settings::default() };
        let mut den = methods::create(kind, &settings, &frame(0, w, h)).unwrap();
        let mut ctx = methods::context(&settings).unwrap();
        let mut t = Timings::default();
        let mut warm = 0;
        for i in 0..400 {
            let out = den.denoise(&frame(i, w, h), &mut ctx, &mut t).unwrap();
            assert!(out.iter().all(|v| v.is_finite()), "{kind:?} {precision:?} frame {i}");
            if i == 50 {
                warm = rss();
            }
        }
        let grown = rss().saturating_sub(warm);
        eprintln!("{kind:?} {precision:?}: resident size grew by {grown} bytes over 350 frames");
        assert!(grown < 4 << 20, "{kind:?} {precision:?}: memory grew by {grown} bytes over 350 frames");
    }
}

//! Shared set-up for the benches: deterministic inputs, the naive baselines
//! every kernel is measured beside, and the machine-limit loops (a copy of the
//! same bytes, a streaming read, an FMA-peak loop).

/// Bench frame width.
pub const W: usize = 1280;
/// Bench frame height.
pub const H: usize = 720;

/// Deterministic pseudo-random values in `[lo, hi)` (xorshift; no dependencies).
pub fn values(n: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            lo + (hi - lo) * ((s >> 40) as f32 / (1u64 << 24) as f32)
        })
        .collect()
}

/// The naive fused filter (WSKP eq. 3–5) as a first port would write it:
/// per pixel, per size, a bounds-checked window loop with `f32::exp` of the
/// raw logits (no shift: this overflows beyond 88, which the bench inputs avoid).
#[allow(clippy::too_many_arguments)]
pub fn naive_fused(
    sizes: &[usize],
    imp: &[f32],
    fus: &[f32],
    alb: &[f32],
    rad: &[f32],
    out: &mut [f32],
    w: usize,
    h: usize,
) {
    let plane = w * h;
    for y in 0..h {
        for x in 0..w {
            let mut fsum = 0.0;
            for i in 0..sizes.len() {
                fsum += fus[i * plane + y * w + x].exp();
            }
            let mut acc = [0.0f32; 3];
            for (i, &k) in sizes.iter().enumerate() {
                let r = (k / 2) as isize;
                let (mut den, mut num) = (0.0f32, [0.0f32; 3]);
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (yy, xx) = (y as isize + dy, x as isize + dx);
                        if yy < 0 || xx < 0 || yy >= h as isize || xx >= w as isize {
                            continue;
                        }
                        let q = yy as usize * w + xx as usize;
                        let e = imp[i * plane + q].exp();
                        den += e;
                        for c in 0..3 {
                            num[c] += e * rad[c * plane + q];
                        }
                    }
                }
                let a = fus[i * plane + y * w + x].exp() / fsum;
                for c in 0..3 {
                    acc[c] += a * num[c] / den;
                }
            }
            for c in 0..3 {
                out[c * plane + y * w + x] = acc[c] * alb[c * plane + y * w + x];
            }
        }
    }
}

/// The naive per-pixel kernel apply: bounds-checked taps, one channel at a time.
pub fn naive_unfold(k: usize, kernel: &[f32], src: &[f32], out: &mut [f32], c: usize, w: usize, h: usize) {
    let plane = w * h;
    let r = (k / 2) as isize;
    for ch in 0..c {
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for ky in 0..k {
                    for kx in 0..k {
                        let (yy, xx) = (y as isize + ky as isize - r, x as isize + kx as isize - r);
                        if yy < 0 || xx < 0 || yy >= h as isize || xx >= w as isize {
                            continue;
                        }
                        s +=
                            kernel[(ky * k + kx) * plane + y * w + x] * src[ch * plane + yy as usize * w + xx as usize];
                    }
                }
                out[ch * plane + y * w + x] = s;
            }
        }
    }
}

/// The naive convolution: six nested loops per output pixel, bounds-checked.
#[allow(clippy::too_many_arguments)]
pub fn naive_conv(k: usize, cin: usize, cout: usize, wts: &[f32], src: &[f32], out: &mut [f32], w: usize, h: usize) {
    let plane = w * h;
    let r = (k / 2) as isize;
    for co in 0..cout {
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for ci in 0..cin {
                    for ky in 0..k {
                        for kx in 0..k {
                            let (yy, xx) = (y as isize + ky as isize - r, x as isize + kx as isize - r);
                            if yy < 0 || xx < 0 || yy >= h as isize || xx >= w as isize {
                                continue;
                            }
                            s += wts[((co * cin + ci) * k + ky) * k + kx]
                                * src[ci * plane + yy as usize * w + xx as usize];
                        }
                    }
                }
                out[co * plane + y * w + x] = s;
            }
        }
    }
}

/// Sum of every element, eight independent lanes (the compiler vectorises it):
/// one streaming read of the buffer.
pub fn stream_sum(v: &[f32]) -> f32 {
    let mut acc = [0.0f32; 32];
    let chunks = v.chunks_exact(32);
    let tail: f32 = chunks.remainder().iter().sum();
    for c in chunks {
        for i in 0..32 {
            acc[i] += c[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// `iters` rounds of 12 independent 8-lane FMA chains: `iters * 12 * 8 * 2` flops.
/// The machine's single-thread FMA peak for AVX2.
#[cfg(target_arch = "x86_64")]
pub fn fma_peak(iters: usize) -> f32 {
    #[target_feature(enable = "avx2,fma")]
    fn inner(iters: usize) -> f32 {
        use std::arch::x86_64::*;
        let m = _mm256_set1_ps(0.999_999);
        let a = _mm256_set1_ps(1.0e-7);
        let mut acc = [_mm256_set1_ps(1.0); 12];
        for _ in 0..iters {
            for v in acc.iter_mut() {
                *v = _mm256_fmadd_ps(*v, m, a);
            }
        }
        let mut s = _mm256_setzero_ps();
        for v in acc {
            s = _mm256_add_ps(s, v);
        }
        let mut out = [0.0f32; 8];
        // SAFETY: out holds eight floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), s) };
        out.iter().sum()
    }
    assert!(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma"));
    // SAFETY: checked just above.
    unsafe { inner(iters) }
}

/// The AVX-512 twin of [`fma_peak`]: twelve independent 16-lane FMA chains.
/// Panics unless AVX-512F is available (the bench checks first).
pub fn fma_peak512(iters: usize) -> f32 {
    #[target_feature(enable = "avx512f")]
    fn inner(iters: usize) -> f32 {
        use std::arch::x86_64::*;
        let m = _mm512_set1_ps(0.999_999);
        let a = _mm512_set1_ps(1.0e-7);
        let mut acc = [_mm512_set1_ps(1.0); 12];
        for _ in 0..iters {
            for v in acc.iter_mut() {
                *v = _mm512_fmadd_ps(*v, m, a);
            }
        }
        let mut s = _mm512_setzero_ps();
        for v in acc {
            s = _mm512_add_ps(s, v);
        }
        _mm512_reduce_add_ps(s)
    }
    assert!(std::is_x86_feature_detected!("avx512f"));
    // SAFETY: checked just above.
    unsafe { inner(iters) }
}

/// A 1280x720 frame made by tiling the 256x256 Cornell-box fixture (16 spp,
/// with its second estimate, albedo, normal, depth and position), so the
/// method benches run on rendered content at the bench size.
pub fn tiled_cornell() -> mcdenoise::Frame {
    use mcdenoise::io::frame::{Buffer, Frame, Limits};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/cornell16/frame_0000.exr");
    let src = Frame::load(&dir, &Limits::default()).expect("the Cornell fixture loads");
    let (sw, sh) = (src.width, src.height);
    let tile = |b: Buffer| -> Vec<f32> {
        let d = src.get(b).expect("fixture buffer");
        let ch = b.channels();
        let mut out = vec![0.0f32; ch * W * H];
        for c in 0..ch {
            for y in 0..H {
                for x in 0..W {
                    out[c * W * H + y * W + x] = d[c * sw * sh + (y % sh) * sw + (x % sw)];
                }
            }
        }
        out
    };
    let mut f = Frame::from_color("tiled.exr", W, H, tile(Buffer::Color)).expect("shape");
    for b in [Buffer::ColorB, Buffer::Albedo, Buffer::Normal, Buffer::Depth, Buffer::Position] {
        f.set(b, tile(b)).expect("shape");
    }
    f
}

/// This core's FMA-peak rate in 8-lane FMAs per second: [`fma_peak`] timed
/// (the fastest of five runs of 20M x 12 FMAs).
pub fn fma_peak_rate() -> f64 {
    let iters = 20_000_000;
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t = std::time::Instant::now();
        std::hint::black_box(fma_peak(std::hint::black_box(iters)));
        best = best.min(t.elapsed().as_secs_f64());
    }
    (iters * 12) as f64 / best
}

/// The integer twin of [`fma_peak`]: twelve independent `vpmaddwd` +
/// `vpaddd` chains (16 i16 multiply-adds per pair), the instruction pair the
/// fixed-point convolution is built from. Returns a value to keep it alive.
/// Panics unless AVX2 is available.
pub fn madd_peak(iters: usize) -> i32 {
    #[target_feature(enable = "avx2")]
    fn inner(iters: usize) -> i32 {
        use std::arch::x86_64::*;
        // Each chain multiplies its own accumulator, so nothing hoists.
        let b = _mm256_set1_epi16(1);
        let mut acc: [__m256i; 12] = std::array::from_fn(|i| _mm256_set1_epi32(i as i32));
        for _ in 0..iters {
            for v in acc.iter_mut() {
                *v = _mm256_add_epi32(*v, _mm256_madd_epi16(*v, b));
            }
        }
        let mut s = _mm256_setzero_si256();
        for v in acc {
            s = _mm256_add_epi32(s, v);
        }
        _mm256_extract_epi32::<0>(s)
    }
    assert!(std::is_x86_feature_detected!("avx2"));
    // SAFETY: checked just above.
    unsafe { inner(iters) }
}

/// [`madd_peak`] as a rate: `vpmaddwd` + `vpaddd` pairs per second (the
/// fastest of five runs of 20M x 12 pairs).
pub fn madd_peak_rate() -> f64 {
    let iters = 20_000_000;
    let mut best = f64::MAX;
    for _ in 0..5 {
        let t = std::time::Instant::now();
        std::hint::black_box(madd_peak(std::hint::black_box(iters)));
        best = best.min(t.elapsed().as_secs_f64());
    }
    (iters * 12) as f64 / best
}

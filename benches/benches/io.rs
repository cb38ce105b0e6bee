//! Reading and writing a 1280x720 frame as the CLI does: the loader on
//! every buffer of the input contract (18 f32 channels, ZIP, the bundled
//! sample tiled), on only the colour, on what WSKP reads, each on 1 and 2
//! threads; the writer of the denoised colour (f32 and f16, ZIP and none).
//! `tools/io-side-by-side.sh` runs this and OpenEXR's own reader and writer
//! on the same file, one after the other.

use std::hint::black_box;
use std::path::{Path, PathBuf};
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use mcdenoise::io::frame::{Buffer, Frame, Limits, ReadOptions};
use mcdenoise::io::output::{write_frame, OutCompression, WriteOptions};
use mcdenoise::methods::MethodKind;
use mcdenoise::runtime::par::Pool;

const W: usize = 1280;
const H: usize = 720;

/// The bundled sample's first frame tiled to 1280x720, every channel f32
/// ZIP, written once to `target/bench-io-frame.exr` (returned).
pub fn frame_file() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let path = root.join("target").join("bench-io-frame.exr");
    if path.exists() {
        return path;
    }
    let f = Frame::load(&root.join("samples/frame_0000.exr"), &Limits::default()).unwrap();
    let (sw, sh) = (f.width, f.height);
    let mut planes: Vec<(String, Vec<f32>)> = Vec::new();
    for b in Buffer::ALL {
        let Some(v) = f.get(b) else { continue };
        for (c, name) in b.contract_names().iter().enumerate() {
            let src = &v[c * sw * sh..(c + 1) * sw * sh];
            let tiled: Vec<f32> = (0..W * H).map(|i| src[(i / W % sh) * sw + i % W % sw]).collect();
            planes.push((name.to_string(), tiled));
        }
    }
    let refs: Vec<(&str, &[f32])> = planes.iter().map(|(n, v)| (n.as_str(), v.as_slice())).collect();
    mcdenoise::io::output::write_exr(&path, W, H, &refs, false).unwrap();
    path
}

fn bench_io(c: &mut Criterion) {
    let file = frame_file();
    let mut g = c.benchmark_group("io/read-1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    for threads in [1, 2] {
        let pool = Pool::new(threads).unwrap();
        for (what, buffers) in
            [("all", None), ("colour", Some(MethodKind::None.reads())), ("wskp", Some(MethodKind::Wskp.reads()))]
        {
            let opts = ReadOptions { buffers, ..ReadOptions::default() };
            g.bench_function(BenchmarkId::new(what, format!("{threads}t")), |b| {
                b.iter(|| {
                    black_box(Frame::open_with(&file, &Limits::default(), &opts).unwrap().read_on(&pool).unwrap())
                })
            });
        }
    }
    g.finish();
    let f = Frame::load(&file, &Limits::default()).unwrap();
    let rgb = f.get(Buffer::Color).unwrap().to_vec();
    let out = std::env::temp_dir().join(format!("mcdenoise-bench-io-{}.exr", std::process::id()));
    let mut g = c.benchmark_group("io/write-1280x720");
    g.sample_size(10).measurement_time(Duration::from_secs(4)).warm_up_time(Duration::from_secs(1));
    for threads in [1, 2] {
        let pool = Pool::new(threads).unwrap();
        for (what, half, compression) in [
            ("f32-zip", false, OutCompression::Zip),
            ("f16-zip", true, OutCompression::Zip),
            ("f32-none", false, OutCompression::None),
        ] {
            let opts = WriteOptions { half: Some(half), compression, keep_channels: false };
            g.bench_function(BenchmarkId::new(what, format!("{threads}t")), |b| {
                b.iter(|| pool.install(|| write_frame(&out, f.source.as_deref(), W, H, &rgb, &opts).unwrap()))
            });
        }
    }
    g.finish();
    let _ = std::fs::remove_file(&out);
}

criterion_group!(benches, bench_io);
criterion_main!(benches);

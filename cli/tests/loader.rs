//! The streaming loader: the same frames as the `exr` crate's whole-image
//! reader, never more bytes read than the header's chunks need, and
//! devices, FIFOs and sparse files handled within bounded memory.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::*;
use exr::prelude::*;
use mcdenoise::io::frame::{sanitize, Buffer, Frame, Limits, READ_BUFFER_BYTES};

/// The frame as the `exr` crate's whole-image reader gives it (the
/// loader's previous implementation): the first layer, largest level,
/// every known buffer's channels converted to f32 and sanitised.
fn reference(bytes: &[u8]) -> (usize, usize, Vec<(Buffer, Vec<f32>)>, usize) {
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(std::io::Cursor::new(bytes))
        .unwrap();
    let layer = &image.layer_data;
    let (w, h) = (layer.size.0, layer.size.1);
    let mut out = Vec::new();
    let mut replaced = 0;
    for b in Buffer::ALL {
        let set = mcdenoise::io::names::aliases(b)
            .iter()
            .find(|al| al.names.iter().all(|n| layer.channel_data.list.iter().any(|c| c.name == **n)));
        let Some(set) = set else { continue };
        let mut v = Vec::new();
        for name in set.names.iter() {
            let ch = layer.channel_data.list.iter().find(|c| c.name == **name).unwrap();
            for x in ch.sample_data.values_as_f32() {
                replaced += usize::from(!x.is_finite());
                v.push(sanitize(x));
            }
        }
        out.push((b, v));
    }
    (w, h, out, replaced)
}

#[track_caller]
fn assert_same_as_reference(f: &Frame, bytes: &[u8], what: &str) {
    let (w, h, bufs, replaced) = reference(bytes);
    assert_eq!((f.width, f.height), (w, h), "{what}");
    assert_eq!(f.replaced_nonfinite, replaced, "{what}");
    for b in Buffer::ALL {
        let want = bufs.iter().find(|(bb, _)| *bb == b).map(|(_, v)| v.as_slice());
        let got = f.get(b);
        assert_eq!(got.is_some(), want.is_some(), "{what}: {}", b.name());
        if let (Some(g), Some(wv)) = (got, want) {
            assert!(g.iter().zip(wv).all(|(a, b)| a.to_bits() == b.to_bits()), "{what}: {} differs", b.name());
            assert_eq!(g.len(), wv.len());
        }
    }
}

fn exr_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        // The layout fixtures (parts, Blender names) have tests of their own.
        if p.is_dir() && p.file_name().is_some_and(|n| n != "layouts") {
            exr_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "exr") {
            out.push(p);
        }
    }
}

/// Every fixture and bundled sample (f16 and f32, ZIP, every buffer)
/// loads to the same bits as the whole-image reader.
#[test]
fn loader_equals_the_whole_image_reader_on_every_fixture() {
    let mut files = Vec::new();
    exr_files(&fixtures(), &mut files);
    exr_files(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../samples"), &mut files);
    assert!(files.len() >= 20, "{files:?}");
    for p in &files {
        let f = Frame::load(p, &Limits::default()).unwrap();
        assert_same_as_reference(&f, &std::fs::read(p).unwrap(), &p.display().to_string());
    }
}

/// Tiles (overhanging the image), u32 and mixed sample types, non-finite
/// values, other compressions and a second layer after the first.
#[test]
fn loader_equals_the_whole_image_reader_on_other_layouts() {
    let (w, h) = (37, 23);
    let vals = |k: usize| -> Vec<f32> {
        (0..w * h)
            .map(|i| match (i + k) % 29 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => -1e30,
                j => j as f32 * 0.37 - 3.0,
            })
            .collect()
    };
    let channels = |ty: &str| -> Vec<AnyChannel<FlatSamples>> {
        ALL_CHANNELS
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let v = vals(k);
                let samples = match (ty, k % 3) {
                    ("mixed", 0) => FlatSamples::F16(v.iter().map(|&x| f16::from_f32(x)).collect()),
                    ("mixed", 1) => {
                        FlatSamples::U32(v.iter().map(|&x| if x.is_finite() { x.abs() as u32 } else { 7 }).collect())
                    }
                    ("f16", _) => FlatSamples::F16(v.iter().map(|&x| f16::from_f32(x)).collect()),
                    _ => FlatSamples::F32(v),
                };
                AnyChannel::new(*name, samples)
            })
            .collect()
    };
    let encodings = [
        Encoding {
            compression: Compression::ZIP16,
            blocks: Blocks::Tiles(Vec2(16, 16)),
            line_order: LineOrder::Increasing,
        },
        Encoding { compression: Compression::PIZ, blocks: Blocks::ScanLines, line_order: LineOrder::Decreasing },
        Encoding {
            compression: Compression::RLE,
            blocks: Blocks::Tiles(Vec2(64, 8)),
            line_order: LineOrder::Unspecified,
        },
        Encoding::UNCOMPRESSED,
    ];
    for (i, enc) in encodings.into_iter().enumerate() {
        for ty in ["f32", "f16", "mixed"] {
            let layer = |name: &str| {
                Layer::new(
                    (w, h),
                    LayerAttributes::named(name),
                    enc,
                    AnyChannels::sort(channels(ty).into_iter().collect()),
                )
            };
            let image = Image::from_layers(
                ImageAttributes::new(IntegerBounds::from_dimensions((w, h))),
                vec![layer("first"), layer("second")],
            );
            let mut bytes = Vec::new();
            image.write().to_buffered(std::io::Cursor::new(&mut bytes)).unwrap();
            let what = format!("encoding {i}, {ty}");
            let f = Frame::load_bytes(&bytes, Path::new("mem.exr"), &Limits::default()).unwrap();
            assert_same_as_reference(&f, &bytes, &what);
        }
    }
}

/// Bytes after the file's chunks are not read: with 8 MiB appended, the
/// loader takes at most the file and one read buffer.
#[test]
fn reads_no_further_than_the_header_allows() {
    let t = tempfile::tempdir().unwrap();
    let p = t.path().join("f.exr");
    scene_frame(&p, 96, 64, &ALL_CHANNELS, true, 3);
    let exr_len = std::fs::metadata(&p).unwrap().len();
    let mut bytes = std::fs::read(&p).unwrap();
    bytes.resize(bytes.len() + (8 << 20), 0x55);
    let reader = Frame::open(&p, &Limits::default()).unwrap();
    assert!(reader.info().read_limit >= exr_len);
    let (_, fetched) = reader.read_counted().unwrap();
    assert!(fetched <= exr_len, "a regular file is read to its end at most: {fetched} of {exr_len}");
    let padded = t.path().join("padded.exr");
    std::fs::write(&padded, &bytes).unwrap();
    let (f, fetched) = Frame::open(&padded, &Limits::default()).unwrap().read_counted().unwrap();
    assert!(fetched <= exr_len + READ_BUFFER_BYTES as u64, "read {fetched} bytes of a {exr_len}-byte frame");
    assert_same_as_reference(&f, &bytes[..exr_len as usize], "padded");
}

/// A sparse 3 GiB file whose first bytes are a frame (a file still being
/// written, say) loads under a 512 MiB address space: only the frame's
/// bytes are read.
#[test]
fn a_huge_sparse_file_reads_only_the_frame() {
    let t = tempfile::tempdir().unwrap();
    let p = t.path().join("sparse.exr");
    scene_frame(&p, 64, 64, &["R", "G", "B"], true, 1);
    std::fs::OpenOptions::new().write(true).open(&p).unwrap().set_len(3 << 30).unwrap();
    let out = t.path().join("out");
    let r = timed(&["denoise", "--method", "atrous", p.to_str().unwrap(), "-o", out.to_str().unwrap()], 512 << 20, 60);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(is_whole_frame(&out.join("sparse.exr"), 64, 64));
}

/// Runs the CLI under an address-space limit, killed after `secs` seconds.
fn timed(args: &[&str], address_space: u64, secs: u64) -> Run {
    let mut c = bin();
    c.args(args);
    limited(&mut c, &[(libc::RLIMIT_AS, address_space)], None);
    let child = c.spawn().unwrap();
    let pid = child.id() as i32;
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let d = done.clone();
    let dog = std::thread::spawn(move || {
        let t0 = std::time::Instant::now();
        while !d.load(std::sync::atomic::Ordering::SeqCst) {
            if t0.elapsed() > Duration::from_secs(secs) {
                // SAFETY: kill(2) on our child (not yet waited for).
                unsafe { libc::kill(pid, libc::SIGKILL) };
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    });
    let r = collect(child);
    done.store(true, std::sync::atomic::Ordering::SeqCst);
    dog.join().unwrap();
    assert_eq!(r.signal, None, "killed (a hang, or the memory): {}", r.stderr);
    r
}

/// `/dev/zero` (endless, no size): refused at once from its first bytes,
/// within a 256 MiB address space.
#[test]
fn dev_zero_is_refused_within_bounded_memory() {
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("out");
    let r = timed(&["denoise", "--method", "atrous", "/dev/zero", "-o", out.to_str().unwrap()], 256 << 20, 30);
    assert_clean_failure(&r, 1, "/dev/zero: not a readable OpenEXR file");
}

/// FIFOs (a shell's `<(...)`): a frame followed by endless bytes gives the
/// frame (the same output as from the file) without reading on; a header
/// of a large frame followed by endless garbage, and a header over the
/// limits, end in one line within bounded memory.
#[test]
fn fifos_give_a_frame_or_a_clear_error() {
    let t = tempfile::tempdir().unwrap();
    let frame = t.path().join("frame.exr");
    scene_frame(&frame, 96, 64, &ALL_CHANNELS, true, 5);
    let bytes = std::fs::read(&frame).unwrap();
    let from_file = t.path().join("from_file");
    let r = timed(
        &["denoise", "--method", "sure-atrous", frame.to_str().unwrap(), "-o", from_file.to_str().unwrap()],
        1 << 30,
        60,
    );
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    // The frame, then zeros until the reader goes away.
    let fifo = t.path().join("frame.fifo.exr");
    mkfifo(&fifo);
    let feeder = feed_fifo(&fifo, bytes.clone(), true);
    let out = t.path().join("from_fifo");
    let r = timed(
        &["denoise", "--method", "sure-atrous", fifo.to_str().unwrap(), "-o", out.to_str().unwrap()],
        1 << 30,
        60,
    );
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    feeder.join().unwrap();
    assert_eq!(
        std::fs::read(out.join("frame.fifo.exr")).unwrap(),
        std::fs::read(from_file.join("frame.exr")).unwrap(),
        "the FIFO gives the file's frame"
    );
    // The first 4 KiB of a 4096x4096 frame (its header and the start of
    // its offset table), then endless zeros.
    let big = t.path().join("big.exr");
    flat_frame(&big, 4096, 4096, 0.5, true, Compression::ZIP16);
    let head = std::fs::read(&big).unwrap()[..4096].to_vec();
    let fifo = t.path().join("big.fifo.exr");
    mkfifo(&fifo);
    let feeder = feed_fifo(&fifo, head, true);
    let r = timed(&["denoise", "--method", "none", fifo.to_str().unwrap(), "-o", out.to_str().unwrap()], 2 << 30, 60);
    assert_clean_failure(&r, 1, "big.fifo.exr: not a readable OpenEXR file");
    feeder.join().unwrap();
    // A header over the size limits.
    let wide = t.path().join("wide.exr");
    flat_frame(&wide, 20_000, 1, 0.5, true, Compression::ZIP16);
    let fifo = t.path().join("wide.fifo.exr");
    mkfifo(&fifo);
    let feeder = feed_fifo(&fifo, std::fs::read(&wide).unwrap(), true);
    let r =
        timed(&["denoise", "--method", "atrous", fifo.to_str().unwrap(), "-o", out.to_str().unwrap()], 256 << 20, 30);
    assert_clean_failure(&r, 1, "wide.fifo.exr: image is 20000x1, over the limit");
    feeder.join().unwrap();
}

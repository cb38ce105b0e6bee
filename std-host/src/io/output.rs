//! Writing results: OpenEXR (`R`, `G`, `B`, f32 or f16, ZIP) and tone-mapped
//! PNG previews. Every file is written under a temporary name in the target
//! directory and renamed into place, so an interrupted run never leaves a
//! half-written file; no output may land on an input.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use exr::prelude::*;

use crate::error::{HostError, Result};
pub use crate::runtime::cleanup::{atomic_write, atomic_write_file, io_reason};

/// The reason of an `exr` write error (its I/O errors explained as above).
fn exr_reason(e: exr::error::Error) -> String {
    match e {
        exr::error::Error::Io(io) => io_reason(&io),
        other => other.to_string(),
    }
}

/// Writes three planes as `R`, `G`, `B` (f16 when `half`).
pub fn write_rgb_exr(path: &Path, width: usize, height: usize, rgb: &[f32], half: bool) -> Result<()> {
    let plane = width * height;
    if rgb.len() != 3 * plane {
        return Err(HostError::write(path, "internal: colour is not three planes"));
    }
    let ch = |c: usize| &rgb[c * plane..(c + 1) * plane];
    write_exr(path, width, height, &[("R", ch(0)), ("G", ch(1)), ("B", ch(2))], half)
}

/// Writes named planes (each `width * height` values) as one scanline EXR
/// layer, ZIP-compressed, f16 when `half`, straight from the planes.
pub fn write_exr(path: &Path, width: usize, height: usize, planes: &[(&str, &[f32])], half: bool) -> Result<()> {
    let plane = width * height;
    if let Some((name, _)) = planes.iter().find(|(_, v)| v.len() != plane) {
        return Err(HostError::write(path, format!("internal: channel {name} is not one plane")));
    }
    let names: Vec<&str> = planes.iter().map(|(n, _)| *n).collect();
    write_exr_rows(path, width, height, &names, half, Compression::ZIP16, |c, y, row| {
        row.copy_from_slice(&planes[c].1[y * width..(y + 1) * width])
    })
}

/// Writes channels `names` as one scanline EXR layer (f16 when `half`,
/// f32 otherwise) in `compression`, asking `row(channel, y, values)` for
/// each row of each channel (`channel` indexes `names`) as the blocks are
/// encoded: the image is never held whole, so frames of any size can be
/// written from a formula or from planes without a copy.
pub fn write_exr_rows(
    path: &Path,
    width: usize,
    height: usize,
    names: &[&str],
    half: bool,
    compression: Compression,
    mut row: impl FnMut(usize, usize, &mut [f32]),
) -> Result<()> {
    use exr::block::writer::ChunksWriter as _;
    use exr::meta::attribute::{ChannelDescription, SampleType, Text};
    let sample = if half { SampleType::F16 } else { SampleType::F32 };
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by_key(|&i| names[i]);
    let mut descs = smallvec::SmallVec::new();
    for &i in &order {
        let text = Text::new_or_none(names[i])
            .ok_or_else(|| HostError::write(path, format!("internal: bad channel name {}", names[i])))?;
        descs.push(ChannelDescription::named(text, sample));
    }
    let header = exr::meta::header::Header::new(Text::default(), (width, height), descs).with_encoding(
        compression,
        exr::meta::BlockDescription::ScanLines,
        LineOrder::Increasing,
    );
    let header = exr::meta::header::Header { own_attributes: LayerAttributes::default(), ..header };
    let mut values = vec![0.0f32; width];
    let mut halfs = vec![f16::ZERO; if half { width } else { 0 }];
    atomic_write_file(path, |out| {
        let written = exr::block::write(out, smallvec::smallvec![header], true, |meta, chunks| {
            let channels = meta.headers[0].channels.clone();
            let blocks = meta.collect_ordered_blocks(|index| {
                exr::block::UncompressedBlock::from_lines(&channels, index, |line| {
                    let loc = line.location;
                    let dst = &mut values[..loc.sample_count];
                    row(order[loc.channel], loc.position.1, dst);
                    // Rows are whole: a scan-line block starts at x = 0.
                    let done = if half {
                        for (h, v) in halfs.iter_mut().zip(dst.iter()) {
                            *h = f16::from_f32(*v);
                        }
                        line.write_samples_from_slice(&halfs[..loc.sample_count])
                    } else {
                        line.write_samples_from_slice(dst)
                    };
                    debug_assert!(done.is_ok(), "a line holds its samples");
                })
            });
            chunks.on_progress(|_| ()).compress_all_blocks_sequential(&meta, blocks)
        });
        written.map_err(exr_reason)
    })
}

/// Writes an 8-bit sRGB-ish preview: `clamp(x, 0, 1)^(1/2.2)` per channel.
pub fn write_png_preview(path: &Path, width: usize, height: usize, rgb: &[f32]) -> Result<()> {
    let plane = width * height;
    let mut bytes = Vec::with_capacity(3 * plane);
    for p in 0..plane {
        for c in 0..3 {
            let v = rgb[c * plane + p];
            let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
            bytes.push((v.powf(1.0 / 2.2) * 255.0 + 0.5) as u8);
        }
    }
    let png_reason = |e: png::EncodingError| match e {
        png::EncodingError::IoError(io) => io_reason(&io),
        other => other.to_string(),
    };
    atomic_write_file(path, |out| {
        let mut enc = png::Encoder::new(out, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().map_err(png_reason)?;
        w.write_image_data(&bytes).map_err(png_reason)?;
        w.finish().map_err(png_reason)
    })
}

/// Checks an output directory can be created and written, and that none of
/// the `outputs` is one of the `inputs` (compared after resolving links).
pub fn prepare_outputs(dir: &Path, inputs: &[PathBuf], outputs: &[PathBuf]) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        return Err(HostError::write(dir, "exists and is not a directory"));
    }
    std::fs::create_dir_all(dir).map_err(|e| HostError::write(dir, io_reason(&e)))?;
    // A registered temporary file, removed at once (and by a signal).
    crate::runtime::cleanup::TempFile::create(dir, std::ffi::OsStr::new("mcdenoise-probe"))
        .map_err(|e| HostError::write(dir, format!("directory is not writable ({})", io_reason(&e))))?;
    let canon = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let ins: HashSet<PathBuf> = inputs.iter().map(|p| canon(p)).collect();
    for o in outputs {
        // The output may not exist yet: resolve its directory and append the name.
        let resolved = match (o.parent(), o.file_name()) {
            (Some(d), Some(n)) => canon(if d.as_os_str().is_empty() { Path::new(".") } else { d }).join(n),
            _ => o.clone(),
        };
        if ins.contains(&resolved) {
            return Err(HostError::write(o, "would overwrite an input file; choose another output directory"));
        }
    }
    Ok(())
}

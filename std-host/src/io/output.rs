//! Writing results: OpenEXR and tone-mapped PNG previews. Every file is
//! written under a temporary name in the target directory and renamed into
//! place, so an interrupted run never leaves a half-written file; no output
//! may land on an input.
//!
//! A denoised frame is written as its input was ([`write_frame`]): the
//! input's headers (data and display windows, pixel aspect, line order,
//! every attribute, the part names of a multi-part file), the colour under
//! the input's own channel names and pixel type, and with
//! [`WriteOptions::keep_channels`] every other channel of every part copied
//! through unchanged; always in scan lines, in the chosen compression.
//! Blocks are compressed on the current rayon pool.

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

/// The output's compression, by the names users know.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OutCompression {
    /// No compression (largest files, fastest).
    None,
    /// ZIP over 16 scan lines (lossless; the default).
    Zip,
    /// ZIP over 1 scan line (lossless).
    Zips,
    /// PIZ wavelet (lossless; good on noisy images).
    Piz,
    /// Run-length (lossless).
    Rle,
    /// PXR24 (lossy for f32: 24-bit floats; lossless for f16).
    Pxr24,
    /// DWAA (lossy, 32 scan lines).
    Dwaa,
    /// DWAB (lossy, 256 scan lines).
    Dwab,
}

impl OutCompression {
    /// The `exr` crate's compression.
    pub fn exr(self) -> Compression {
        match self {
            OutCompression::None => Compression::Uncompressed,
            OutCompression::Zip => Compression::ZIP16,
            OutCompression::Zips => Compression::ZIP1,
            OutCompression::Piz => Compression::PIZ,
            OutCompression::Rle => Compression::RLE,
            OutCompression::Pxr24 => Compression::PXR24,
            OutCompression::Dwaa => Compression::DWAA(None),
            OutCompression::Dwab => Compression::DWAB(None),
        }
    }
}

/// How a denoised frame is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WriteOptions {
    /// The colour's pixel type: `Some(true)` f16, `Some(false)` f32, `None`
    /// as the input's colour (f32 for a frame made in memory).
    pub half: Option<bool>,
    /// The compression.
    pub compression: OutCompression,
    /// Copy every channel of the input that the methods do not read (the
    /// frame must have been read with them kept).
    pub keep_channels: bool,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions { half: None, compression: OutCompression::Zip, keep_channels: false }
    }
}

/// Where an output channel's samples come from.
#[derive(Clone, Copy, Debug)]
enum Src {
    /// Plane `c` of the denoised colour.
    Colour(usize),
    /// A kept input channel: (part, channel).
    Kept(usize, usize),
}

/// Writes the denoised colour `rgb` (3 planes of `width x height`) of a
/// frame read from `source` as the input file was (see the module); a
/// frame without a source is written as `R`, `G`, `B`.
pub fn write_frame(
    path: &Path,
    source: Option<&crate::io::frame::Source>,
    width: usize,
    height: usize,
    rgb: &[f32],
    opts: &WriteOptions,
) -> Result<()> {
    use exr::meta::attribute::{ChannelDescription, ChannelList, SampleType};
    let plane = width * height;
    if rgb.len() != 3 * plane {
        return Err(HostError::write(path, "internal: colour is not three planes"));
    }
    let Some(src) = source else {
        let half = opts.half.unwrap_or(false);
        let sample = if half { SampleType::F16 } else { SampleType::F32 };
        let header = exr::meta::header::Header::new(
            Text::default(),
            (width, height),
            smallvec::smallvec![
                ChannelDescription::named("B", sample),
                ChannelDescription::named("G", sample),
                ChannelDescription::named("R", sample),
            ],
        );
        let header = exr::meta::header::Header { own_attributes: LayerAttributes::default(), ..header };
        let srcs = vec![vec![Src::Colour(2), Src::Colour(1), Src::Colour(0)]];
        return write_parts(path, vec![header], srcs, rgb, None, opts.compression, plane);
    };
    let mut headers = Vec::new();
    let mut sources = Vec::new();
    for (pi, h) in src.headers.iter().enumerate() {
        let mut chans: Vec<(ChannelDescription, Src)> = Vec::new();
        for (ci, c) in h.channels.list.iter().enumerate() {
            if let Some(k) = src.colour.iter().position(|&x| x == (pi, ci)) {
                let sample = match opts.half {
                    Some(true) => SampleType::F16,
                    Some(false) => SampleType::F32,
                    None if c.sample_type == SampleType::U32 => SampleType::F32,
                    None => c.sample_type,
                };
                chans.push((ChannelDescription { sample_type: sample, ..c.clone() }, Src::Colour(k)));
            } else if opts.keep_channels && src.kept[pi][ci].is_some() {
                chans.push((c.clone(), Src::Kept(pi, ci)));
            }
        }
        if chans.is_empty() {
            continue;
        }
        chans.sort_by(|a, b| a.0.name.cmp(&b.0.name));
        let line_order = match h.line_order {
            LineOrder::Decreasing => LineOrder::Decreasing,
            _ => LineOrder::Increasing,
        };
        let list = ChannelList::new(chans.iter().map(|c| c.0.clone()).collect());
        let header = exr::meta::header::Header {
            channels: list,
            deep: false,
            deep_data_version: None,
            max_samples_per_pixel: None,
            ..h.clone()
        }
        .with_encoding(opts.compression.exr(), exr::meta::BlockDescription::ScanLines, line_order);
        headers.push(header);
        sources.push(chans.into_iter().map(|c| c.1).collect());
    }
    write_parts(path, headers, sources, rgb, Some(src), opts.compression, plane)
}

/// Writes `headers` (one part each) with each channel's samples from
/// `srcs`, compressing batches of blocks in parallel.
fn write_parts(
    path: &Path,
    headers: Vec<exr::meta::header::Header>,
    srcs: Vec<Vec<Src>>,
    rgb: &[f32],
    source: Option<&crate::io::frame::Source>,
    _compression: OutCompression,
    plane: usize,
) -> Result<()> {
    use exr::block::writer::ChunksWriter as _;
    use exr::meta::attribute::SampleType;
    use rayon::prelude::*;
    let headers: exr::meta::Headers = headers.into_iter().collect();
    let width = headers.first().map_or(0, |h| h.layer_size.0);
    atomic_write_file(path, |out| {
        let written = exr::block::write(out, headers, true, |meta, chunks| {
            let order: Vec<(usize, exr::block::BlockIndex)> =
                exr::block::enumerate_ordered_header_block_indices(&meta.headers).collect();
            let batch = 4 * rayon::current_num_threads().max(1);
            for jobs in order.chunks(batch) {
                let done: Vec<exr::error::Result<(usize, exr::block::chunk::Chunk)>> = jobs
                    .par_iter()
                    .map(|&(index, block)| {
                        let part = block.layer;
                        let channels = &meta.headers[part].channels;
                        let mut tmp = Vec::new();
                        let ub = exr::block::UncompressedBlock::from_lines(channels, block, |line| {
                            let loc = line.location;
                            let (x, y, count) = (loc.position.0, loc.position.1, loc.sample_count);
                            let at = y * width + x;
                            let done = match srcs[part][loc.channel] {
                                Src::Colour(c) => {
                                    let v = &rgb[c * plane + at..c * plane + at + count];
                                    match channels.list[loc.channel].sample_type {
                                        SampleType::F16 => {
                                            tmp.clear();
                                            tmp.extend(v.iter().map(|&x| f16::from_f32(x)));
                                            line.write_samples_from_slice(&tmp)
                                        }
                                        _ => line.write_samples_from_slice(v),
                                    }
                                }
                                Src::Kept(pi, ci) => {
                                    let kept = source.and_then(|s| s.kept[pi][ci].as_deref()).expect("a kept channel");
                                    let bytes = channels.list[loc.channel].sample_type.bytes_per_sample();
                                    line.value.copy_from_slice(&kept[at * bytes..(at + count) * bytes]);
                                    Ok(())
                                }
                            };
                            debug_assert!(done.is_ok(), "a line holds its samples");
                        });
                        Ok((index, ub.compress_to_chunk(&meta.headers)?))
                    })
                    .collect();
                for d in done {
                    let (index, chunk) = d?;
                    chunks.write_chunk(index, chunk)?;
                }
            }
            Ok(())
        });
        written.map_err(exr_reason)
    })
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

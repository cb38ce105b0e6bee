//! Frames in the input contract: one multichannel OpenEXR file per frame,
//! channels found by name (see the README's input contract).
//!
//! Loading reads the header first and refuses sizes over [`Limits`] before
//! any pixel buffer is allocated. Every value is sanitised on the way in (the
//! first step of the stability contract): NaN becomes 0 and ±inf becomes
//! ±[`VALUE_LIMIT`]; the count of replaced values is kept for a warning.

use std::path::{Path, PathBuf};

use exr::prelude::traits::*;
use mcdenoise_core::View;

use crate::aligned::Aligned;
use crate::error::{HostError, Result};

/// Finite values are clamped to `±VALUE_LIMIT` on load (and ±inf becomes it).
pub const VALUE_LIMIT: f32 = 1.0e20;

/// Size limits checked against the file header before anything is allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest width or height.
    pub max_side: usize,
    /// Largest `width * height`.
    pub max_pixels: usize,
    /// Largest number of channels in the file.
    pub max_channels: usize,
    /// Largest file size in bytes.
    pub max_file_bytes: u64,
}

impl Default for Limits {
    /// 16384 pixels a side, 2^25 pixels (33.5 Mpx: 8K x 4K), 64 channels, 4 GiB files.
    fn default() -> Self {
        Limits { max_side: 16_384, max_pixels: 1 << 25, max_channels: 64, max_file_bytes: 4 << 30 }
    }
}

/// The buffers a frame can carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Buffer {
    /// Noisy radiance `R,G,B` (required).
    Color,
    /// Second independent estimate `B.R,B.G,B.B`.
    ColorB,
    /// Albedo.
    Albedo,
    /// World-space shading normal.
    Normal,
    /// Depth (0: no hit).
    Depth,
    /// World-space position.
    Position,
    /// Screen-space motion in pixels (previous = current + motion).
    Motion,
}

impl Buffer {
    /// Every buffer.
    pub const ALL: [Buffer; 7] = [
        Buffer::Color,
        Buffer::ColorB,
        Buffer::Albedo,
        Buffer::Normal,
        Buffer::Depth,
        Buffer::Position,
        Buffer::Motion,
    ];

    /// Short name, as used in messages.
    pub fn name(self) -> &'static str {
        match self {
            Buffer::Color => "colour",
            Buffer::ColorB => "second estimate",
            Buffer::Albedo => "albedo",
            Buffer::Normal => "normal",
            Buffer::Depth => "depth",
            Buffer::Position => "position",
            Buffer::Motion => "motion",
        }
    }

    /// Planes.
    pub fn channels(self) -> usize {
        match self {
            Buffer::Depth => 1,
            Buffer::Motion => 2,
            _ => 3,
        }
    }

    /// Accepted channel-name sets, the contract's names first, then the names
    /// Mitsuba 3's `aovs` integrator and other renderers write.
    pub fn aliases(self) -> &'static [&'static [&'static str]] {
        match self {
            Buffer::Color => &[&["R", "G", "B"]],
            Buffer::ColorB => &[&["B.R", "B.G", "B.B"]],
            Buffer::Albedo => &[&["albedo.R", "albedo.G", "albedo.B"], &["Albedo.R", "Albedo.G", "Albedo.B"]],
            Buffer::Normal => &[
                &["normal.X", "normal.Y", "normal.Z"],
                &["normal.R", "normal.G", "normal.B"],
                &["sh_normal.X", "sh_normal.Y", "sh_normal.Z"],
                &["nn.X", "nn.Y", "nn.Z"],
                &["N.X", "N.Y", "N.Z"],
            ],
            Buffer::Depth => &[&["depth.Z"], &["Z"], &["depth.T"], &["depth.Y"], &["depth.R"], &["dd.T"], &["dd.Y"]],
            Buffer::Position => &[
                &["position.X", "position.Y", "position.Z"],
                &["position.R", "position.G", "position.B"],
                &["pp.X", "pp.Y", "pp.Z"],
                &["P.X", "P.Y", "P.Z"],
            ],
            Buffer::Motion => &[&["motion.X", "motion.Y"], &["motion.R", "motion.G"], &["mv.X", "mv.Y"]],
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// One frame: the buffers its file carries, planar f32.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Where it came from.
    pub path: PathBuf,
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Each buffer starts on a cache line (see [`Aligned`]).
    planes: [Option<Aligned<f32>>; 7],
    /// Non-finite values replaced on load.
    pub replaced_nonfinite: usize,
}

impl Frame {
    /// A frame with only colour, from planar data (for tests and tools).
    pub fn from_color(path: impl Into<PathBuf>, width: usize, height: usize, color: Vec<f32>) -> Result<Frame> {
        let path = path.into();
        if color.len() != 3 * width * height {
            return Err(HostError::bad(&path, "colour needs 3 planes of width x height"));
        }
        let mut planes: [Option<Aligned<f32>>; 7] = Default::default();
        planes[0] = Some(Aligned::from_slice(&color));
        Ok(Frame { path, width, height, planes, replaced_nonfinite: 0 })
    }

    /// Adds or replaces a buffer (planar, `buffer.channels()` planes; kept
    /// as a copy that starts on a cache line).
    pub fn set(&mut self, b: Buffer, data: Vec<f32>) -> Result<()> {
        if data.len() != b.channels() * self.width * self.height {
            return Err(HostError::bad(&self.path, format!("{} needs {} planes", b.name(), b.channels())));
        }
        self.planes[b.index()] = Some(Aligned::from_slice(&data));
        Ok(())
    }

    /// Removes a buffer (the colour cannot be removed).
    pub fn remove(&mut self, b: Buffer) {
        if b != Buffer::Color {
            self.planes[b.index()] = None;
        }
    }

    /// The buffer's planes, if the file had them.
    pub fn get(&self, b: Buffer) -> Option<&[f32]> {
        self.planes[b.index()].as_deref()
    }

    /// Whether the file had the buffer.
    pub fn has(&self, b: Buffer) -> bool {
        self.planes[b.index()].is_some()
    }

    /// The buffer, or an error naming it and who needs it.
    pub fn require(&self, b: Buffer, needed_by: &str) -> Result<&[f32]> {
        self.get(b).ok_or_else(|| HostError::MissingChannel {
            path: self.path.clone(),
            buffer: b.name(),
            wanted: b.aliases()[0].join(","),
            needed_by: needed_by.to_string(),
        })
    }

    /// A core view of the buffer.
    pub fn view(&self, b: Buffer) -> Option<View<'_, f32>> {
        self.get(b)
            .map(|d| View::new(d, b.channels(), self.width, self.height).expect("frame buffers have their shape"))
    }

    /// Loads a frame, checking the header against `limits` first.
    pub fn load(path: &Path, limits: &Limits) -> Result<Frame> {
        let meta = std::fs::metadata(path).map_err(|e| HostError::read(path, e))?;
        if meta.is_dir() {
            return Err(HostError::bad(path, "is a directory, not an EXR file"));
        }
        if meta.len() > limits.max_file_bytes {
            return Err(HostError::bad(
                path,
                format!("file is {} bytes, over the limit of {}", meta.len(), limits.max_file_bytes),
            ));
        }
        let bytes = std::fs::read(path).map_err(|e| HostError::read(path, e))?;
        Frame::load_bytes(&bytes, path, limits)
    }

    /// Parses a frame from the bytes of an EXR file (`path` names it in errors).
    pub fn load_bytes(bytes: &[u8], path: &Path, limits: &Limits) -> Result<Frame> {
        let not_exr = |e: exr::error::Error| HostError::bad(path, format!("not a readable OpenEXR file ({e})"));
        let header = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false).map_err(not_exr)?;
        check_headers(path, &header, limits)?;
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .from_buffered(std::io::Cursor::new(bytes))
            .map_err(not_exr)?;
        let layer = &image.layer_data;
        let (width, height) = (layer.size.0, layer.size.1);
        let names: Vec<String> = layer.channel_data.list.iter().map(|c| c.name.to_string()).collect();
        let mut planes: [Option<Aligned<f32>>; 7] = Default::default();
        let mut replaced = 0;
        for b in Buffer::ALL {
            let Some(set) = find_set(path, b, &names)? else { continue };
            let mut data = Aligned::<f32>::zeroed(b.channels() * width * height);
            for (name, dst) in set.iter().zip(data.chunks_mut(width * height)) {
                let ch = layer.channel_data.list.iter().find(|c| c.name == **name).expect("found above");
                if ch.sample_data.len() != width * height {
                    return Err(HostError::bad(
                        path,
                        format!("channel {name} is subsampled; only full-resolution channels are supported"),
                    ));
                }
                for (d, v) in dst.iter_mut().zip(ch.sample_data.values_as_f32()) {
                    *d = sanitize(v);
                    replaced += usize::from(d.to_bits() != v.to_bits() && !v.is_finite());
                }
            }
            planes[b.index()] = Some(data);
        }
        if planes[0].is_none() {
            return Err(HostError::MissingChannel {
                path: path.to_path_buf(),
                buffer: "colour",
                wanted: "R,G,B".into(),
                needed_by: "every method".into(),
            });
        }
        Ok(Frame { path: path.to_path_buf(), width, height, planes, replaced_nonfinite: replaced })
    }
}

/// NaN to 0, clamp to `±VALUE_LIMIT`.
#[inline]
pub fn sanitize(v: f32) -> f32 {
    if v.is_nan() {
        0.0
    } else {
        v.clamp(-VALUE_LIMIT, VALUE_LIMIT)
    }
}

fn check_headers(path: &Path, meta: &exr::meta::MetaData, limits: &Limits) -> Result<()> {
    if meta.headers.is_empty() {
        return Err(HostError::bad(path, "OpenEXR file has no layers"));
    }
    for h in meta.headers.iter() {
        check_header(path, h, limits)?;
    }
    Ok(())
}

fn check_header(path: &Path, h: &exr::meta::header::Header, limits: &Limits) -> Result<()> {
    let (w, hh) = (h.layer_size.0, h.layer_size.1);
    if w == 0 || hh == 0 {
        return Err(HostError::bad(path, "image is empty (0 pixels)"));
    }
    if w > limits.max_side || hh > limits.max_side || w.saturating_mul(hh) > limits.max_pixels {
        return Err(HostError::bad(
            path,
            format!(
                "image is {w}x{hh}, over the limit of {} pixels a side and {} pixels in all",
                limits.max_side, limits.max_pixels
            ),
        ));
    }
    if h.channels.list.len() > limits.max_channels {
        return Err(HostError::bad(
            path,
            format!("file has {} channels, over the limit of {}", h.channels.list.len(), limits.max_channels),
        ));
    }
    if h.deep {
        return Err(HostError::bad(path, "deep OpenEXR data is not supported"));
    }
    Ok(())
}

/// The first alias set fully present; an error when a set is only partly there.
fn find_set(path: &Path, b: Buffer, names: &[String]) -> Result<Option<&'static [&'static str]>> {
    for set in b.aliases() {
        let present: Vec<&str> = set.iter().copied().filter(|n| names.iter().any(|m| m == n)).collect();
        if present.len() == set.len() {
            return Ok(Some(set));
        }
        if !present.is_empty() && set.len() > 1 {
            let missing: Vec<&str> = set.iter().copied().filter(|n| !present.contains(n)).collect();
            return Err(HostError::bad(
                path,
                format!(
                    "{} channels are incomplete: has {} but not {}",
                    b.name(),
                    present.join(","),
                    missing.join(",")
                ),
            ));
        }
    }
    Ok(None)
}

/// Checks that `f` has the size of the sequence's first frame `first` (`dims`).
pub fn check_same_size(first: &Path, dims: (usize, usize), f: &Frame) -> Result<()> {
    if dims != (f.width, f.height) {
        return Err(HostError::bad(
            &f.path,
            format!(
                "frame is {}x{} but {} is {}x{}; every frame of a sequence must have one size",
                f.width,
                f.height,
                first.display(),
                dims.0,
                dims.1
            ),
        ));
    }
    Ok(())
}

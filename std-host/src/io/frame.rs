//! Frames in the input contract: one multichannel OpenEXR file per frame,
//! channels found by name (see the README's input contract).
//!
//! Loading reads the header first and refuses sizes over [`Limits`] before
//! any pixel buffer is allocated ([`Frame::open`] stops there, so a caller
//! can weigh the memory a frame will take); the pixels then stream from the
//! file block by block into the frame's planes, reading no further than the
//! header's chunks can reach. Every value is sanitised on the way in (the
//! first step of the stability contract): NaN becomes 0 and ±inf becomes
//! ±[`VALUE_LIMIT`]; the count of replaced values is kept for a warning.

use std::cell::Cell;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::rc::Rc;

use exr::block::reader::ChunksReader;

use mcdenoise_core::View;

use crate::error::{HostError, Result};
use crate::runtime::aligned::Aligned;

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

    /// Swaps the two independent estimates `R,G,B` and `B.R,B.G,B.B`
    /// (no copy; nothing happens without `B.*`).
    pub fn swap_estimates(&mut self) {
        if self.has(Buffer::ColorB) {
            self.planes.swap(Buffer::Color.index(), Buffer::ColorB.index());
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

    /// Loads a frame: [`Frame::open`], then [`FrameReader::read`].
    pub fn load(path: &Path, limits: &Limits) -> Result<Frame> {
        Frame::open(path, limits)?.read()
    }

    /// Opens a frame file and reads its header only, checked against
    /// `limits`; the pixels are read by [`FrameReader::read`]. Any file the
    /// OS can open works, a device or a FIFO included: a source without a
    /// size is read at most to the header's need (see [`FrameReader`]).
    pub fn open(path: &Path, limits: &Limits) -> Result<FrameReader<'static>> {
        let file = std::fs::File::open(path).map_err(|e| HostError::read(path, e))?;
        let meta = file.metadata().map_err(|e| HostError::read(path, e))?;
        if meta.is_dir() {
            return Err(HostError::bad(path, "is a directory, not an EXR file"));
        }
        // A regular file has a size; a device, FIFO or socket has none (its
        // metadata says 0), so only the limits bound it.
        let size = meta.is_file().then_some(meta.len());
        FrameReader::new(Box::new(file), size, path, limits)
    }

    /// Parses a frame from the bytes of an EXR file (`path` names it in errors).
    pub fn load_bytes(bytes: &[u8], path: &Path, limits: &Limits) -> Result<Frame> {
        FrameReader::new(Box::new(bytes), Some(bytes.len() as u64), path, limits)?.read()
    }
}

/// The largest header (magic number, version, attributes) read before it
/// is checked: real headers take a few KiB, a preview image a few MiB.
pub const MAX_HEADER_BYTES: u64 = 16 << 20;

/// The loader's read buffer: the most it reads past what it needs.
pub const READ_BUFFER_BYTES: usize = 64 << 10;

/// Bytes per chunk beyond its pixels (part number, coordinates, size), as
/// the `exr` crate counts them.
const CHUNK_OVERHEAD: u64 = 64;

/// What a frame file's header says, read and checked before any pixel.
#[derive(Clone, Debug)]
pub struct FrameInfo {
    /// The file.
    pub path: PathBuf,
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The channel names found for each buffer, if the file has it.
    sets: [Option<&'static [&'static str]>; 7],
    /// Bytes of the largest pixel block once decompressed (the loader holds
    /// one at a time, beside its compressed chunk).
    pub block_bytes: u64,
    /// Bytes of the largest compressed chunk the reader accepts.
    pub chunk_bytes: u64,
    /// Most bytes the whole file can take by its header (header, offset
    /// tables, every chunk at its largest), within the file-size limit; the
    /// loader reads no further.
    pub read_limit: u64,
    /// The file's size, when it has one (a regular file).
    pub file_bytes: Option<u64>,
    /// The most the loader reads whatever the header says: the file's size
    /// or, for a stream, the file-size limit.
    pub cap: u64,
}

impl FrameInfo {
    /// Whether the file has the buffer.
    pub fn has(&self, b: Buffer) -> bool {
        self.sets[b.index()].is_some()
    }

    /// Planes the loaded frame will hold (the buffers the file has).
    pub fn planes(&self) -> usize {
        Buffer::ALL.iter().filter(|b| self.has(**b)).map(|b| b.channels()).sum()
    }

    /// `width * height`.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }
}

/// The shared counters of a [`Bounded`] source.
#[derive(Debug, Default)]
struct ReadState {
    /// Bytes that may be taken from the source in all.
    limit: Cell<u64>,
    /// Bytes taken from the source.
    fetched: Cell<u64>,
    /// Bytes handed to the decoder.
    consumed: Cell<u64>,
    /// Whether a read was refused at the limit.
    hit: Cell<bool>,
}

/// A buffered byte source that takes no more than `state.limit` bytes from
/// the file, device or FIFO beneath it, and reads forward only: it can be
/// handed to the `exr` crate, which asks for `Seek` but reads a whole file
/// in order without seeking (`all_chunks`).
struct Bounded<'a> {
    inner: Box<dyn Read + 'a>,
    buf: Box<[u8]>,
    start: usize,
    end: usize,
    state: Rc<ReadState>,
}

impl Read for Bounded<'_> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        if self.start == self.end && !out.is_empty() {
            let st = &self.state;
            let room = st.limit.get().saturating_sub(st.fetched.get());
            if room == 0 {
                st.hit.set(true);
                return Ok(0);
            }
            let want = self.buf.len().min(usize::try_from(room).unwrap_or(usize::MAX));
            let got = loop {
                match self.inner.read(&mut self.buf[..want]) {
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    r => break r?,
                }
            };
            st.fetched.set(st.fetched.get() + got as u64);
            (self.start, self.end) = (0, got);
        }
        let n = out.len().min(self.end - self.start);
        out[..n].copy_from_slice(&self.buf[self.start..self.start + n]);
        self.start += n;
        self.state.consumed.set(self.state.consumed.get() + n as u64);
        Ok(n)
    }
}

impl Seek for Bounded<'_> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        let here = self.state.consumed.get();
        let target = match pos {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::Current(d) => here.checked_add_signed(d),
            SeekFrom::End(_) => None,
        };
        match target {
            Some(t) if t == here => Ok(here),
            _ => Err(std::io::Error::new(std::io::ErrorKind::Unsupported, "the frame loader reads forward only")),
        }
    }
}

/// A frame file whose header has been read and checked against the limits:
/// [`FrameReader::info`] says what reading the pixels will allocate, before
/// anything is. [`FrameReader::read`] then decodes one block at a time
/// straight into the frame's planes (only the channels of the buffers it
/// knows), never holding the file's bytes or its other channels whole. The
/// source is read forward, at most [`FrameInfo::read_limit`] bytes, through
/// a [`READ_BUFFER_BYTES`] buffer.
pub struct FrameReader<'a> {
    info: FrameInfo,
    reader: exr::block::reader::Reader<Bounded<'a>>,
    state: Rc<ReadState>,
}

impl std::fmt::Debug for FrameReader<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameReader").field("info", &self.info).finish_non_exhaustive()
    }
}

impl<'a> FrameReader<'a> {
    /// Reads and checks the header of `source` (`size`: its length when known).
    fn new(source: Box<dyn Read + 'a>, size: Option<u64>, path: &Path, limits: &Limits) -> Result<Self> {
        if let Some(len) = size.filter(|&l| l > limits.max_file_bytes) {
            return Err(HostError::bad(
                path,
                format!("file is {len} bytes, over the limit of {}", limits.max_file_bytes),
            ));
        }
        let cap = limits.max_file_bytes.min(size.unwrap_or(u64::MAX));
        let state = Rc::new(ReadState::default());
        state.limit.set(cap.min(MAX_HEADER_BYTES));
        let source = Bounded {
            inner: source,
            buf: vec![0u8; READ_BUFFER_BYTES].into_boxed_slice(),
            start: 0,
            end: 0,
            state: state.clone(),
        };
        let reader = exr::block::read(source, false).map_err(|e| {
            if state.hit.get() && cap > MAX_HEADER_BYTES {
                HostError::bad(path, format!("not a readable OpenEXR file (no header within {MAX_HEADER_BYTES} bytes)"))
            } else {
                not_exr(path, e)
            }
        })?;
        let meta = reader.meta_data();
        check_headers(path, meta, limits)?;
        let h0 = &meta.headers[0];
        let names: Vec<String> = h0.channels.list.iter().map(|c| c.name.to_string()).collect();
        let mut sets = [None; 7];
        for b in Buffer::ALL {
            sets[b.index()] = find_set(path, b, &names)?;
        }
        if sets[Buffer::Color.index()].is_none() {
            return Err(HostError::MissingChannel {
                path: path.to_path_buf(),
                buffer: "colour",
                wanted: "R,G,B".into(),
                needed_by: "every method".into(),
            });
        }
        // exr lays out the lines of a block as if every channel were full
        // resolution, so any subsampled channel would shift the others.
        if let Some(c) = h0.channels.list.iter().find(|c| c.sampling != exr::math::Vec2(1, 1)) {
            return Err(HostError::bad(
                path,
                format!("channel {} is subsampled; only full-resolution channels are supported", c.name),
            ));
        }
        // Everything the header lets the file hold after what was read:
        // offset tables, then every chunk at the largest size the reader
        // accepts. Saturating: a hostile header's product only reaches the cap.
        let mut need = state.consumed.get();
        let (mut block_bytes, mut chunk_bytes) = (0u64, 0u64);
        for h in meta.headers.iter() {
            let (clipped, whole) = block_sizes(h);
            block_bytes = block_bytes.max(clipped);
            chunk_bytes = chunk_bytes.max(whole);
            let per_chunk = 8u64.saturating_add(CHUNK_OVERHEAD).saturating_add(whole);
            need = need.saturating_add((h.chunk_count as u64).saturating_mul(per_chunk));
        }
        let read_limit = need.min(cap);
        state.limit.set(read_limit.max(state.fetched.get()));
        let info = FrameInfo {
            path: path.to_path_buf(),
            width: h0.layer_size.0,
            height: h0.layer_size.1,
            sets,
            block_bytes,
            chunk_bytes: chunk_bytes.min(read_limit),
            read_limit,
            file_bytes: size,
            cap,
        };
        Ok(FrameReader { info, reader, state })
    }

    /// What the header says.
    pub fn info(&self) -> &FrameInfo {
        &self.info
    }

    /// Reads the pixels into a frame.
    pub fn read(self) -> Result<Frame> {
        self.read_counted().map(|(f, _)| f)
    }

    /// Reads the pixels into a frame; also returns the bytes taken from the
    /// source in all (header included).
    pub fn read_counted(self) -> Result<(Frame, u64)> {
        let FrameReader { info, reader, state } = self;
        let path = info.path.as_path();
        let (w, h) = (info.width, info.height);
        let n = w * h;
        let channels = reader.headers()[0].channels.clone();
        // Where each channel of the first layer goes: (buffer, plane).
        let mut slots: Vec<Option<(usize, usize)>> = vec![None; channels.list.len()];
        let mut planes: [Option<Aligned<f32>>; 7] = Default::default();
        for b in Buffer::ALL {
            let Some(set) = info.sets[b.index()] else { continue };
            for (plane, name) in set.iter().enumerate() {
                let i = channels.list.iter().position(|c| c.name == **name).expect("found in the header");
                slots[i] = Some((b.index(), plane));
            }
            planes[b.index()] = Some(Aligned::zeroed(b.channels() * n));
        }
        // A read refused at the limit: the header's own bound, or the
        // file-size limit of a stream; a regular file's end is its size,
        // and a file cut short is reported as the decoder sees it.
        let (need_bound, stream) = (info.read_limit < info.cap, info.file_bytes.is_none());
        let err = |e: exr::error::Error| match (state.hit.get(), need_bound, stream) {
            (true, true, _) => HostError::bad(
                path,
                format!(
                    "not a readable OpenEXR file (its data runs past the {} bytes its header allows)",
                    info.read_limit
                ),
            ),
            (true, false, true) => HostError::bad(
                path,
                format!("not a readable OpenEXR file (the stream runs past the file-size limit of {} bytes)", info.cap),
            ),
            _ => not_exr(path, e),
        };
        let mut chunks = reader.all_chunks(false).map_err(err)?;
        let mut replaced = 0;
        while let Some(chunk) = chunks.next() {
            let chunk = chunk.map_err(err)?;
            // The first layer's largest level only (as before: other layers
            // and mip levels are read past, not decoded).
            let wanted = chunk.layer_index == 0
                && match &chunk.compressed_block {
                    exr::block::chunk::CompressedBlock::Tile(t) => t.coordinates.level_index == exr::math::Vec2(0, 0),
                    _ => true,
                };
            if !wanted {
                continue;
            }
            let block =
                exr::block::UncompressedBlock::decompress_chunk(chunk, chunks.meta_data(), false).map_err(err)?;
            for line in block.lines(&channels) {
                let loc = line.location;
                let Some((b, plane)) = slots.get(loc.channel).copied().flatten() else { continue };
                let (x, y, count) = (loc.position.0, loc.position.1, loc.sample_count);
                let sample = channels.list[loc.channel].sample_type;
                if y >= h
                    || x.checked_add(count).is_none_or(|e| e > w)
                    || line.value.len() != count * sample.bytes_per_sample()
                {
                    return Err(HostError::bad(path, "not a readable OpenEXR file (a block lies outside the image)"));
                }
                let data = planes[b].as_mut().expect("allocated above");
                let dst = &mut data[plane * n + y * w + x..][..count];
                replaced += convert_line(sample, line.value, dst);
            }
        }
        let fetched = state.fetched.get();
        Ok((Frame { path: path.to_path_buf(), width: w, height: h, planes, replaced_nonfinite: replaced }, fetched))
    }
}

/// Sanitised f32 samples of one line (native-endian bytes of `sample`);
/// returns how many were not finite.
fn convert_line(sample: exr::meta::attribute::SampleType, src: &[u8], dst: &mut [f32]) -> usize {
    use exr::meta::attribute::SampleType;
    let mut replaced = 0;
    let mut put = |d: &mut f32, v: f32| {
        *d = sanitize(v);
        replaced += usize::from(!v.is_finite());
    };
    match sample {
        SampleType::F16 => {
            for (d, b) in dst.iter_mut().zip(src.chunks_exact(2)) {
                put(d, half::f16::from_ne_bytes([b[0], b[1]]).to_f32());
            }
        }
        SampleType::F32 => {
            for (d, b) in dst.iter_mut().zip(src.chunks_exact(4)) {
                put(d, f32::from_ne_bytes([b[0], b[1], b[2], b[3]]));
            }
        }
        SampleType::U32 => {
            for (d, b) in dst.iter_mut().zip(src.chunks_exact(4)) {
                put(d, u32::from_ne_bytes([b[0], b[1], b[2], b[3]]) as f32);
            }
        }
    }
    replaced
}

/// Bytes of a header's largest block: clipped to the image (what a
/// decompressed block takes) and as the reader bounds a compressed chunk
/// (the whole block, even where it overhangs the image). Saturating.
fn block_sizes(h: &exr::meta::header::Header) -> (u64, u64) {
    let bpp = h.channels.bytes_per_pixel as u64;
    let (w, hh) = (h.layer_size.0 as u64, h.layer_size.1 as u64);
    let (bw, bh) = match h.blocks {
        exr::meta::BlockDescription::ScanLines => (w, h.compression.scan_lines_per_block() as u64),
        exr::meta::BlockDescription::Tiles(t) => (t.tile_size.0 as u64, t.tile_size.1 as u64),
    };
    let whole = bpp.saturating_mul(bw.saturating_mul(bh));
    let clipped = bpp.saturating_mul(bw.min(w).saturating_mul(bh.min(hh)));
    (clipped, whole)
}

fn not_exr(path: &Path, e: exr::error::Error) -> HostError {
    HostError::bad(path, format!("not a readable OpenEXR file ({e})"))
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
    check_same_size_as(first, dims, &f.path, (f.width, f.height))
}

/// Checks that frame `path` of size `size` (from its header) has the size
/// of the sequence's first frame `first` (`dims`).
pub fn check_same_size_as(first: &Path, dims: (usize, usize), path: &Path, size: (usize, usize)) -> Result<()> {
    if dims != size {
        return Err(HostError::bad(
            path,
            format!(
                "frame is {}x{} but {} is {}x{}; every frame of a sequence must have one size",
                size.0,
                size.1,
                first.display(),
                dims.0,
                dims.1
            ),
        ));
    }
    Ok(())
}

//! Frames in the input contract: one multichannel OpenEXR file per frame,
//! channels found by name (docs/exr.md).
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

    /// The contract's channel names of the buffer (the first accepted set;
    /// [`crate::io::names::aliases`] lists every set the loader accepts).
    pub fn contract_names(self) -> &'static [&'static str] {
        crate::io::names::aliases(self)[0].names
    }

    /// The buffer's place in [`Buffer::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }
}

/// A frame's second estimate `B` of the colour's pixels, and whether the
/// colour is the pair's mean ([`Frame::average_pair`]) or the estimate `A`.
#[derive(Clone, Copy, Debug)]
pub struct Pair<'a> {
    /// `B.R, B.G, B.B` (3 planes).
    pub b: &'a [f32],
    /// The colour is `(A + B) / 2`.
    pub colour_is_mean: bool,
}

impl Pair<'_> {
    /// The colour's noise variance from its value `y` and `B`'s value `b`
    /// at a pixel, linear values: one estimate's `(A - B)^2 / 2`, the mean's
    /// `(M - B)^2 = (A - B)^2 / 4`, each with the expectation of the
    /// colour's variance. Through a non-linear map (`log1p`) the mean's
    /// form no longer holds (a firefly in `B` alone drags `M` with it:
    /// [`Pair::spread`]).
    #[inline]
    pub fn variance(&self, y: f32, b: f32) -> f32 {
        let d = y - b;
        if self.colour_is_mean {
            d * d
        } else {
            0.5 * d * d
        }
    }

    /// `A`'s value at a pixel from the colour's `y` and `B`'s `b` (linear):
    /// `y` itself, or `2 y - b` when the colour is the mean.
    #[inline]
    pub fn first(&self, y: f32, b: f32) -> f32 {
        if self.colour_is_mean {
            2.0 * y - b
        } else {
            y
        }
    }

    /// The colour's noise variance through a map `T` applied to each of the
    /// three values: `ty = T(colour)`, `ta = T(A)` ([`Pair::first`]),
    /// `tb = T(B)`; the mean of `(ty - ta)^2` and `(ty - tb)^2`. On linear
    /// values it is [`Pair::variance`] (one estimate: `ty = ta`, half of
    /// `(A - B)^2`; the mean: `(A - B)^2 / 4` from each). Through `log1p`
    /// it stays symmetric in the two estimates: where `B` alone holds a
    /// firefly, `T(M)` lies near `T(B)` and `(T(M) - T(B))^2` alone would
    /// read the pixel as nearly noise-free.
    #[inline]
    pub fn spread(ty: f32, ta: f32, tb: f32) -> f32 {
        let (da, db) = (ty - ta, ty - tb);
        0.5 * (da * da + db * db)
    }

    /// The best estimate from the colour's value `y` and `B`'s `b` (the
    /// pair's mean), and that estimate's noise variance.
    #[inline]
    pub fn mean_and_variance(&self, y: f32, b: f32) -> (f32, f32) {
        let d = y - b;
        if self.colour_is_mean {
            (y, d * d)
        } else {
            (0.5 * (y + b), 0.25 * d * d)
        }
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
    /// The colour is the mean of the frame's two estimates and `B.*` the
    /// second of them ([`Frame::average_pair`]): the pair's difference
    /// `colour - B` is then half of `A - B`, and the colour's noise variance
    /// is `(colour - B)^2` rather than one estimate's `(A - B)^2 / 2`.
    pub colour_is_pair_mean: bool,
    /// The file's headers and the channels kept for writing them back
    /// (`None` for a frame made in memory).
    pub source: Option<std::sync::Arc<Source>>,
}

/// What a loaded frame keeps of its file for the output: the headers
/// (windows, attributes, parts, line order) and, when asked to, every
/// channel the methods do not read, as the file's bytes.
#[derive(Debug)]
pub struct Source {
    /// Every part's header, as read.
    pub headers: std::sync::Arc<Vec<exr::meta::header::Header>>,
    /// The part and channel of each colour plane.
    pub colour: [(usize, usize); 3],
    /// Per part and channel: its samples (native-endian bytes, `width *
    /// height` of the channel's type) when kept.
    pub kept: Vec<Vec<Option<Vec<u8>>>>,
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
        Ok(Frame { path, width, height, planes, replaced_nonfinite: 0, colour_is_pair_mean: false, source: None })
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

    /// Makes the colour the mean `(A + B) / 2` of the two estimates, in
    /// place, and keeps `B` (the noise estimates need it; see
    /// [`Frame::colour_is_pair_mean`]). Nothing happens without `B.*` or a
    /// second time; returns whether the colour is the mean now.
    pub fn average_pair(&mut self) -> bool {
        if !self.colour_is_pair_mean {
            let [Some(a), Some(b), ..] = &mut self.planes else { return false };
            for (x, &y) in a.iter_mut().zip(b.iter()) {
                *x = 0.5 * (*x + y);
            }
            self.colour_is_pair_mean = true;
        }
        true
    }

    /// The colour and `B.*` to change in place, beside the albedo, if the
    /// frame has `B.*` and albedo.
    pub fn pair_planes_mut(&mut self) -> Option<(&mut [f32], &mut [f32], &[f32])> {
        let [Some(c), Some(b), Some(a), ..] = &mut self.planes else { return None };
        Some((&mut c[..], &mut b[..], &a[..]))
    }

    /// The second estimate and the colour's relation to it, if the frame
    /// has `B.*`.
    pub fn pair(&self) -> Option<Pair<'_>> {
        self.get(Buffer::ColorB).map(|b| Pair { b, colour_is_mean: self.colour_is_pair_mean })
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
            wanted: b.contract_names().join(","),
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

    /// Loads a frame with `opts` (layer, part, buffers to read, channels to
    /// keep).
    pub fn load_with(path: &Path, limits: &Limits, opts: &ReadOptions) -> Result<Frame> {
        Frame::open_with(path, limits, opts)?.read()
    }

    /// Opens a frame file and reads its header only, checked against
    /// `limits`; the pixels are read by [`FrameReader::read`]. Any file the
    /// OS can open works, a device or a FIFO included: a source without a
    /// size is read at most to the header's need (see [`FrameReader`]).
    pub fn open(path: &Path, limits: &Limits) -> Result<FrameReader<'static>> {
        Frame::open_with(path, limits, &ReadOptions::default())
    }

    /// [`Frame::open`] with `opts`.
    pub fn open_with(path: &Path, limits: &Limits, opts: &ReadOptions) -> Result<FrameReader<'static>> {
        let file = std::fs::File::open(path).map_err(|e| HostError::read(path, e))?;
        let meta = file.metadata().map_err(|e| HostError::read(path, e))?;
        if meta.is_dir() {
            return Err(HostError::bad(path, "is a directory, not an EXR file"));
        }
        // A regular file has a size; a device, FIFO or socket has none (its
        // metadata says 0), so only the limits bound it.
        let size = meta.is_file().then_some(meta.len());
        FrameReader::new(Box::new(file), size, path, limits, opts)
    }

    /// Parses a frame from the bytes of an EXR file (`path` names it in errors).
    pub fn load_bytes(bytes: &[u8], path: &Path, limits: &Limits) -> Result<Frame> {
        FrameReader::new(Box::new(bytes), Some(bytes.len() as u64), path, limits, &ReadOptions::default())?.read()
    }
}

/// How a frame file is read.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReadOptions {
    /// The layer and part where the file is ambiguous.
    pub selection: crate::io::names::Selection,
    /// The buffers to decode (others are found in the header but not read;
    /// `None`: every buffer).
    pub buffers: Option<[bool; 7]>,
    /// Keep every channel no buffer reads (for writing them back).
    pub keep_channels: bool,
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
    /// Where each buffer's planes are, if the file has it.
    pub found: [Option<crate::io::names::Found>; 7],
    /// The buffers that will be decoded.
    pub wanted: [bool; 7],
    /// The layer prefix the buffers were found under.
    pub layer: Option<String>,
    /// Every part's header.
    pub headers: std::sync::Arc<Vec<exr::meta::header::Header>>,
    /// Keep the channels no buffer reads.
    pub keep_channels: bool,
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
        self.found[b.index()].is_some()
    }

    /// Whether the buffer will be decoded (the file has it and it is wanted).
    pub fn loads(&self, b: Buffer) -> bool {
        self.has(b) && self.wanted[b.index()]
    }

    /// Planes the loaded frame will hold (the buffers it loads), and the
    /// kept channels (in f32 units, rounded up).
    pub fn planes(&self) -> usize {
        let buffers: usize = Buffer::ALL.iter().filter(|b| self.loads(**b)).map(|b| b.channels()).sum();
        let kept = if self.keep_channels {
            let used: Vec<(usize, usize)> = self.found.iter().flatten().flat_map(|f| f.channels.clone()).collect();
            let bytes: usize = self
                .headers
                .iter()
                .enumerate()
                .flat_map(|(pi, h)| h.channels.list.iter().enumerate().map(move |(ci, c)| (pi, ci, c)))
                .filter(|(pi, ci, _)| !used.contains(&(*pi, *ci)))
                .map(|(_, _, c)| c.sample_type.bytes_per_sample())
                .sum();
            bytes.div_ceil(4)
        } else {
            0
        };
        buffers + kept
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
    fn new(
        source: Box<dyn Read + 'a>,
        size: Option<u64>,
        path: &Path,
        limits: &Limits,
        opts: &ReadOptions,
    ) -> Result<Self> {
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
        let parts: Vec<crate::io::names::PartChannels> = meta
            .headers
            .iter()
            .map(|h| crate::io::names::PartChannels {
                name: h.own_attributes.layer_name.as_ref().map(|n| n.to_string()),
                channels: h.channels.list.iter().map(|c| c.name.to_string()).collect(),
            })
            .collect();
        let resolved = crate::io::names::resolve(&parts, &opts.selection, path)?;
        let wanted = opts.buffers.unwrap_or([true; 7]);
        let colour_part =
            resolved.sets[Buffer::Color.index()].as_ref().expect("resolve finds the colour").channels[0].0;
        let h0 = &meta.headers[colour_part];
        // Every part a loaded buffer reads must cover the colour's pixels.
        for b in Buffer::ALL.into_iter().filter(|b| wanted[b.index()]) {
            let Some(f) = &resolved.sets[b.index()] else { continue };
            for &(pi, ci) in &f.channels {
                let h = &meta.headers[pi];
                if h.layer_size != h0.layer_size || h.own_attributes.layer_position != h0.own_attributes.layer_position
                {
                    return Err(HostError::bad(
                        path,
                        format!(
                            "{} ({}) is in a part whose data window differs from the colour's ({}x{} at {},{} against {}x{} at {},{})",
                            b.name(),
                            h.channels.list[ci].name,
                            h.layer_size.0,
                            h.layer_size.1,
                            h.own_attributes.layer_position.0,
                            h.own_attributes.layer_position.1,
                            h0.layer_size.0,
                            h0.layer_size.1,
                            h0.own_attributes.layer_position.0,
                            h0.own_attributes.layer_position.1
                        ),
                    ));
                }
                // exr lays out the lines of a block as if every channel were
                // full resolution, so a subsampled channel would shift the others.
                if let Some(c) = h.channels.list.iter().find(|c| c.sampling != exr::math::Vec2(1, 1)) {
                    return Err(HostError::bad(
                        path,
                        format!("channel {} is subsampled; only full-resolution channels are supported", c.name),
                    ));
                }
            }
        }
        if opts.keep_channels {
            for h in meta.headers.iter() {
                if h.layer_size != h0.layer_size {
                    return Err(HostError::bad(
                        path,
                        "--keep-channels: the parts have different sizes; only files whose parts share one data window can be written back",
                    ));
                }
            }
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
            found: resolved.sets,
            wanted,
            layer: resolved.layer,
            headers: std::sync::Arc::new(meta.headers.to_vec()),
            keep_channels: opts.keep_channels,
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

    /// Reads the pixels into a frame (decompressing on the current rayon
    /// pool).
    pub fn read(self) -> Result<Frame> {
        self.read_counted_on(None).map(|(f, _)| f)
    }

    /// Reads the pixels into a frame, decompressing on `pool`'s threads.
    pub fn read_on(self, pool: &crate::runtime::par::Pool) -> Result<Frame> {
        self.read_counted_on(Some(pool)).map(|(f, _)| f)
    }

    /// Reads the pixels into a frame; also returns the bytes taken from the
    /// source in all (header included).
    pub fn read_counted(self) -> Result<(Frame, u64)> {
        self.read_counted_on(None)
    }

    /// [`FrameReader::read_counted`] on `pool` (or the current rayon pool).
    /// Chunks are read in file order and decompressed in batches on the
    /// pool's threads, each batch's lines then copied into the planes; only
    /// the parts holding a wanted buffer (or a kept channel) are
    /// decompressed, only level 0 of a mip- or rip-mapped tiled file.
    pub fn read_counted_on(self, pool: Option<&crate::runtime::par::Pool>) -> Result<(Frame, u64)> {
        use crate::io::names::Convert;
        use rayon::prelude::*;
        /// What a channel feeds: a buffer's plane, a kept copy, or both.
        #[derive(Clone, Copy, Default)]
        struct Slot {
            plane: Option<(usize, usize, Convert)>,
            keep: bool,
        }
        let FrameReader { info, reader, state } = self;
        let path = info.path.as_path();
        let (w, h) = (info.width, info.height);
        let n = w * h;
        let headers = info.headers.clone();
        let mut slots: Vec<Vec<Slot>> = headers.iter().map(|h| vec![Slot::default(); h.channels.list.len()]).collect();
        let mut planes: [Option<Aligned<f32>>; 7] = Default::default();
        for b in Buffer::ALL.into_iter().filter(|b| info.loads(*b)) {
            let f = info.found[b.index()].as_ref().expect("loads() says found");
            for (plane, &(pi, ci)) in f.channels.iter().enumerate() {
                slots[pi][ci].plane = Some((b.index(), plane, f.convert));
            }
            planes[b.index()] = Some(Aligned::zeroed(b.channels() * n));
        }
        let colour = info.found[Buffer::Color.index()].as_ref().expect("the colour is found").channels.clone();
        let mut kept: Vec<Vec<Option<Vec<u8>>>> = headers.iter().map(|h| vec![None; h.channels.list.len()]).collect();
        if info.keep_channels {
            for (pi, hd) in headers.iter().enumerate() {
                for (ci, c) in hd.channels.list.iter().enumerate() {
                    // Every channel but the colour, read or not, goes back out
                    // as its own bytes.
                    if !colour.contains(&(pi, ci)) {
                        slots[pi][ci].keep = true;
                        kept[pi][ci] = Some(vec![0u8; n * c.sample_type.bytes_per_sample()]);
                    }
                }
            }
        }
        let parts_used: Vec<bool> = slots.iter().map(|p| p.iter().any(|s| s.plane.is_some() || s.keep)).collect();
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
        let meta = chunks.meta_data().clone();
        let batch_len = 4 * pool.map_or_else(rayon::current_num_threads, |p| p.threads()).max(1);
        let mut batch = Vec::with_capacity(batch_len);
        let mut replaced = 0;
        /// A decoded line bound for a plane or a kept channel.
        enum Piece {
            Plane { buffer: usize, at: usize, values: Vec<f32>, replaced: usize },
            Kept { part: usize, channel: usize, at: usize, bytes: Vec<u8> },
        }
        // Level 0's chunks of every part used: once all are read, the rest
        // of the file (other parts, smaller mip levels) is not needed.
        let mut missing: Vec<usize> =
            headers.iter().zip(&parts_used).map(|(hd, &used)| if used { level0_chunks(hd) } else { 0 }).collect();
        loop {
            while batch.len() < batch_len && missing.iter().any(|&m| m > 0) {
                let Some(chunk) = chunks.next() else { break };
                let chunk = chunk.map_err(err)?;
                let level0 = match &chunk.compressed_block {
                    exr::block::chunk::CompressedBlock::Tile(t) => t.coordinates.level_index == exr::math::Vec2(0, 0),
                    _ => true,
                };
                let part = chunk.layer_index;
                if level0 && parts_used.get(part).copied().unwrap_or(false) {
                    missing[part] = missing[part].saturating_sub(1);
                    batch.push(chunk);
                }
            }
            if batch.is_empty() {
                break;
            }
            let jobs: Vec<exr::block::chunk::Chunk> = std::mem::take(&mut batch);
            let decode = |jobs: Vec<exr::block::chunk::Chunk>| -> Vec<Result<Vec<Piece>>> {
                jobs.into_par_iter()
                    .map(|chunk| -> Result<Vec<Piece>> {
                        let part = chunk.layer_index;
                        let block = exr::block::UncompressedBlock::decompress_chunk(chunk, &meta, false)
                            .map_err(|e| not_exr(path, e))?;
                        let list = &meta.headers[part].channels;
                        let mut pieces = Vec::new();
                        for line in block.lines(list) {
                            let loc = line.location;
                            let Some(slot) = slots[part].get(loc.channel).copied() else { continue };
                            if slot.plane.is_none() && !slot.keep {
                                continue;
                            }
                            let (x, y, count) = (loc.position.0, loc.position.1, loc.sample_count);
                            let sample = list.list[loc.channel].sample_type;
                            if y >= h
                                || x.checked_add(count).is_none_or(|e| e > w)
                                || line.value.len() != count * sample.bytes_per_sample()
                            {
                                return Err(HostError::bad(
                                    path,
                                    "not a readable OpenEXR file (a block lies outside the image)",
                                ));
                            }
                            if let Some((buffer, plane, convert)) = slot.plane {
                                let mut values = vec![0.0f32; count];
                                let r = convert_line(sample, line.value, &mut values);
                                match convert {
                                    Convert::Plain => {}
                                    Convert::FlipY if plane == 1 => values.iter_mut().for_each(|v| *v = -*v),
                                    Convert::FlipY => {}
                                    Convert::FarIsZero => {
                                        for v in values.iter_mut().filter(|v| **v >= 1e9) {
                                            *v = 0.0;
                                        }
                                    }
                                }
                                pieces.push(Piece::Plane { buffer, at: plane * n + y * w + x, values, replaced: r });
                            }
                            if slot.keep {
                                let bytes = line.value.to_vec();
                                let at = (y * w + x) * sample.bytes_per_sample();
                                pieces.push(Piece::Kept { part, channel: loc.channel, at, bytes });
                            }
                        }
                        Ok(pieces)
                    })
                    .collect()
            };
            let decoded = match pool {
                Some(p) => p.install(|| decode(jobs)),
                None => decode(jobs),
            };
            for pieces in decoded {
                for piece in pieces? {
                    match piece {
                        Piece::Plane { buffer, at, values, replaced: r } => {
                            let data = planes[buffer].as_mut().expect("allocated above");
                            data[at..at + values.len()].copy_from_slice(&values);
                            replaced += r;
                        }
                        Piece::Kept { part, channel, at, bytes } => {
                            let dst = kept[part][channel].as_mut().expect("allocated above");
                            dst[at..at + bytes.len()].copy_from_slice(&bytes);
                        }
                    }
                }
            }
        }
        let fetched = state.fetched.get();
        let source = Source { headers, colour: [colour[0], colour[1], colour[2]], kept };
        let frame = Frame {
            path: path.to_path_buf(),
            width: w,
            height: h,
            planes,
            replaced_nonfinite: replaced,
            colour_is_pair_mean: false,
            source: Some(std::sync::Arc::new(source)),
        };
        Ok((frame, fetched))
    }
}

/// Chunks of a part's full-resolution level: every chunk of a scan-line or
/// single-level tiled part, the level-0 tiles of a mip- or rip-mapped one.
fn level0_chunks(h: &exr::meta::header::Header) -> usize {
    match h.blocks {
        exr::meta::BlockDescription::Tiles(t) if t.level_mode != exr::meta::attribute::LevelMode::Singular => {
            h.layer_size.0.div_ceil(t.tile_size.0.max(1)) * h.layer_size.1.div_ceil(t.tile_size.1.max(1))
        }
        _ => h.chunk_count,
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

//! The memory a frame will take, weighed from its header before anything
//! is allocated ([`crate::runtime::memory`] has the accounting, the limits
//! and what they are measured against).

use crate::error::{HostError, Result};
use crate::io::frame::{FrameInfo, READ_BUFFER_BYTES};
use crate::runtime::memory::{format_bytes, Budget, Footprint, BASELINE_BYTES};

/// How a sequence is read and written, for the estimate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IoShape {
    /// f16 output.
    pub half: bool,
    /// PNG previews.
    pub png: bool,
    /// A frame read ahead and an output written behind the one denoised.
    pub pipelined: bool,
    /// Threads (decompression and compression batches).
    pub threads: usize,
    /// Rows of an output block (the output compression's).
    pub rows_per_block: usize,
}

/// The estimate of one frame's peak heap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Estimate {
    /// Pixels of the frame.
    pub pixels: u64,
    /// The frame's planes, bytes per pixel.
    pub frame: u64,
    /// The method's footprint.
    pub method: Footprint,
    /// Bytes per pixel while an output is written (the output, the PNG preview).
    pub writer: u64,
    /// Bytes per pixel at the peak: `2 frame + method.peak + writer` when
    /// pipelined (one frame read ahead, one output written behind), else
    /// `max(frame + method.peak, method.kept + writer)`.
    pub per_pixel: u64,
    /// Bytes not proportional to the pixels: scratch, the largest block the
    /// loader or the writer holds, the baseline.
    pub fixed: u64,
    /// Whether the run reads ahead and writes behind.
    pub pipelined: bool,
}

impl Estimate {
    /// Checks the estimate against every limit of `budget`: an error naming the file, the work
    /// and the limit when it does not fit.
    pub fn check(&self, budget: &Budget, info: &FrameInfo, work: &str) -> Result<()> {
        let est = self;
        match budget.limits.iter().filter(|l| est.bytes() > l.free).min_by_key(|l| l.free) {
            None => Ok(()),
            Some(l) => Err(HostError::bad(
                &info.path,
                format!(
                    "{work} needs about {} for this {}x{} frame ({} bytes per pixel + {}), more than {}; \
                     refused before reading its pixels",
                    format_bytes(est.bytes()),
                    info.width,
                    info.height,
                    est.per_pixel,
                    format_bytes(est.fixed),
                    l.describe()
                ),
            )),
        }
    }

    /// The estimate for `info`'s frames through a method of footprint
    /// `method`, read and written as `io` says.
    pub fn new(info: &FrameInfo, method: Footprint, io: &IoShape) -> Estimate {
        let IoShape { half, png, pipelined, threads, rows_per_block } = *io;
        let frame = 4 * info.planes() as u64;
        // The PNG's 8-bit image, and the encoder's filtered and compressed copies of it.
        let writer = 12 + if png { 3 + 2 * 3 } else { 0 };
        // Pipelined: the frame being denoised and the next one read ahead,
        // the method at its peak, the previous output being written. One
        // frame at a time: the frame and the method's peak, or (the frame
        // dropped) what the method keeps beside the output being written.
        let per_pixel =
            if pipelined { 2 * frame + method.peak + writer } else { (frame + method.peak).max(method.kept + writer) };
        let w = info.width as u64;
        // One decoded block and its compressed chunk (each read into a
        // vector that may grow to twice its length), and the read buffer.
        let loader = 2 * info.chunk_bytes + 2 * info.block_bytes + READ_BUFFER_BYTES as u64;
        // One block of the output, raw and compressed, its samples
        // reordered once, and the write buffer.
        let writer_fixed = 3 * rows_per_block as u64 * w * if half { 6 } else { 12 } + (1 << 16);
        // Decompression and compression run in batches of 4 blocks a
        // thread; pipelined, the reader and the writer hold theirs at once.
        let batch = 4 * threads.max(1) as u64;
        let (loader, writer_fixed) = (batch * loader, batch * writer_fixed);
        let io = if pipelined { loader + writer_fixed } else { loader.max(writer_fixed) };
        let fixed = method.scratch + io + BASELINE_BYTES;
        Estimate { pixels: info.pixels(), frame, method, writer, per_pixel, fixed, pipelined }
    }

    /// The estimate in bytes.
    pub fn bytes(&self) -> u64 {
        self.per_pixel.saturating_mul(self.pixels).saturating_add(self.fixed)
    }
}

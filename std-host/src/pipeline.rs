//! A sequence through a method: frames read (each checked from its header
//! for size and memory before its pixels are read), denoised in order and
//! written whole or not at all.
//!
//! The sequence is pipelined: while frame `t` is denoised, a reader thread
//! reads frame `t + 1` and a writer thread writes the output of frame
//! `t - 1`. Both run their decompression and compression on the method's
//! thread pool, so the pool's threads are shared, not added to. At most one
//! frame is read ahead and one output waits to be written: the memory
//! estimate ([`Estimate`]) counts two frames and an output beside the
//! method. Only the buffers the method reads are decoded
//! ([`MethodKind::reads`]).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::error::{HostError, Result};
use crate::io::estimate::{Estimate, IoShape};
use crate::io::frame::{check_same_size, check_same_size_as, Buffer, Frame, Limits, ReadOptions, Source};
use crate::io::output::WriteOptions;
use crate::io::{list_inputs, output};
use crate::methods::{self, MethodKind, Settings, Timings};
use crate::runtime::memory::Budget;
use crate::runtime::par::Pool;

/// What a sequence run produced.
#[derive(Debug, Default)]
pub struct RunReport {
    /// Output files, in frame order.
    pub outputs: Vec<PathBuf>,
    /// Kernel-side times (I/O excluded).
    pub timings: Timings,
    /// Time reading frames (headers, decompression, the extra buffer
    /// files), in the reader thread.
    pub read: Duration,
    /// Time writing outputs (compression and file writes), in the writer
    /// thread.
    pub write: Duration,
    /// Time the denoiser waited for the reader (what the read-ahead did not
    /// hide).
    pub read_wait: Duration,
    /// Time the denoiser waited for the writer.
    pub write_wait: Duration,
    /// Frames processed.
    pub frames: usize,
    /// The method's one-line plan.
    pub plan: String,
    /// The stages the method built and skipped.
    pub stages: methods::Plan,
    /// The buffers the first frame has (by [`Buffer::name`]).
    pub buffers: Vec<&'static str>,
    /// Frame width and height.
    pub size: (usize, usize),
    /// Per-frame warnings (non-finite values replaced).
    pub warnings: Vec<String>,
    /// The memory estimate of the largest frame.
    pub estimate: Option<Estimate>,
}

/// A buffer read from a file of its own (`--albedo FILE|DIR` and the like,
/// as Intel Open Image Denoise's command line takes them): a file for every
/// frame, or a directory whose files match the frames by name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AuxInput {
    /// Which buffer.
    pub buffer: Buffer,
    /// The file or directory.
    pub path: PathBuf,
}

impl AuxInput {
    /// The file holding the buffer for frame `frame`.
    pub fn file_for(&self, frame: &Path) -> PathBuf {
        if self.path.is_dir() {
            self.path.join(frame.file_name().unwrap_or_default())
        } else {
            self.path.clone()
        }
    }
}

/// How a sequence is read and written and how much memory it may take.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SequenceOptions {
    /// How outputs are written.
    pub write: WriteOptions,
    /// PNG previews.
    pub png: bool,
    /// `--max-memory` (without it: the memory available now).
    pub max_memory: Option<u64>,
    /// No progress bar even on a terminal.
    pub quiet: bool,
    /// The layer and part of ambiguous files.
    pub selection: crate::io::names::Selection,
    /// Buffers in files of their own.
    pub aux: Vec<AuxInput>,
    /// Read one frame ahead and write one output behind while a frame is
    /// denoised: `Some(true)` always, `Some(false)` never (one frame at a
    /// time: less memory), `None` when the estimate of it fits the memory
    /// budget.
    pub pipeline: Option<bool>,
}

/// A frame read, with what its header check found.
struct Read {
    frame: Frame,
    info: crate::io::frame::FrameInfo,
    estimate: Estimate,
    seconds: Duration,
}

/// What the writer is handed: the output of frame `index`.
struct Job {
    index: usize,
    out: Vec<f32>,
    source: Option<Arc<Source>>,
    size: (usize, usize),
}

/// The buffers `method` reads under `settings`: under `--pair mean` every
/// method that can use the second estimate reads it (averaged in, or read
/// as its own), under `--pair first` none does.
fn reads(method: MethodKind, settings: &Settings) -> [bool; 7] {
    let mut r = method.reads();
    if settings.pair == methods::PairUse::First {
        r[crate::io::frame::Buffer::ColorB.index()] = false;
    }
    r
}

/// Reads frame `path`: its header checked for size and memory before any
/// pixel, then its pixels (decompressed on `pool`), then the buffers of
/// `aux` from their own files. `pipelined`: the run's mode (`None` for the
/// first frame: pipelined when that fits the budget); the mode taken is in
/// the returned estimate.
#[allow(clippy::too_many_arguments)]
fn read_frame(
    path: &Path,
    limits: &Limits,
    first: Option<(&Path, (usize, usize))>,
    method: MethodKind,
    settings: &Settings,
    opts: &SequenceOptions,
    budget: &Budget,
    pool: &Pool,
    pipelined: Option<bool>,
) -> Result<Read> {
    let t0 = Instant::now();
    let read_opts = ReadOptions {
        selection: opts.selection.clone(),
        buffers: Some(reads(method, settings)),
        keep_channels: opts.write.keep_channels,
    };
    let reader = Frame::open_with(path, limits, &read_opts)?;
    let info = reader.info();
    if let Some((first, dims)) = first {
        check_same_size_as(first, dims, path, (info.width, info.height))?;
    }
    let footprint = methods::footprint(method, settings, info);
    let shape = |pipelined| IoShape {
        half: opts.write.half == Some(true),
        png: opts.png,
        pipelined,
        threads: settings.threads,
        rows_per_block: opts.write.compression.exr().scan_lines_per_block(),
    };
    let work = format!("{} in {}", method.name(), settings.precision.name());
    let est = match pipelined.or(opts.pipeline) {
        Some(p) => {
            let e = Estimate::new(info, footprint, &shape(p));
            e.check(budget, info, &work)?;
            e
        }
        None => {
            let e = Estimate::new(info, footprint, &shape(true));
            match e.check(budget, info, &work) {
                Ok(()) => e,
                Err(_) => {
                    let e = Estimate::new(info, footprint, &shape(false));
                    e.check(budget, info, &work)?;
                    e
                }
            }
        }
    };
    let info = info.clone();
    let mut frame = reader.read_on(pool)?;
    for aux in &opts.aux {
        let file = aux.file_for(path);
        let other = read_aux(&file, aux.buffer, limits, &opts.selection, pool)?;
        if (other.width, other.height) != (frame.width, frame.height) {
            return Err(HostError::bad(
                &file,
                format!(
                    "{} is {}x{}, its frame {} is {}x{}",
                    aux.buffer.name(),
                    other.width,
                    other.height,
                    path.display(),
                    frame.width,
                    frame.height
                ),
            ));
        }
        frame.set(aux.buffer, other.data)?;
    }
    methods::apply_pair(method, settings.pair, &mut frame);
    Ok(Read { frame, info, estimate: est, seconds: t0.elapsed() })
}

/// A buffer from a file of its own: the buffer's own channel names, or the
/// file's colour (`R,G,B` for a 3-plane buffer; for depth `Z`, else `R`;
/// for motion `R,G`), as an image written for that one buffer has it.
fn read_aux(
    file: &Path,
    b: Buffer,
    limits: &Limits,
    sel: &crate::io::names::Selection,
    pool: &Pool,
) -> Result<AuxFrame> {
    let mut wanted = [false; 7];
    wanted[b.index()] = true;
    wanted[Buffer::Color.index()] = true;
    let opts = ReadOptions { selection: sel.clone(), buffers: Some(wanted), keep_channels: false };
    let f = match Frame::open_with(file, limits, &opts).and_then(|r| r.read_on(pool)) {
        Ok(f) => f,
        // A single-channel depth file without R,G,B.
        Err(HostError::MissingChannel { .. }) if b == Buffer::Depth => {
            return Err(HostError::bad(file, "no depth channels (depth.Z, Z, Depth.Z) and no R,G,B"))
        }
        Err(e) => return Err(e),
    };
    let data = match f.get(b) {
        Some(d) => d.to_vec(),
        None => {
            let c = f.get(Buffer::Color).expect("the colour is always read");
            let n = f.width * f.height;
            match b.channels() {
                3 => c.to_vec(),
                2 => c[..2 * n].to_vec(),
                _ => c[..n].to_vec(),
            }
        }
    };
    Ok(AuxFrame { width: f.width, height: f.height, data })
}

/// One buffer read from its own file.
struct AuxFrame {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

/// Denoises `inputs` with `method` into `outdir`. Each frame's header is
/// checked (size, memory) before its pixels are read; each output is
/// written whole or not at all. `on_frame(i, output, frame)` sees every
/// output before it is written.
pub fn denoise_sequence(
    method: MethodKind,
    settings: &Settings,
    inputs: &[PathBuf],
    outdir: &Path,
    opts: &SequenceOptions,
    mut on_frame: impl FnMut(usize, &[f32], &Frame),
) -> Result<RunReport> {
    let files = list_inputs(inputs)?;
    let outputs: Vec<PathBuf> = files.iter().map(|f| outdir.join(f.file_name().expect("a file has a name"))).collect();
    let pngs: Vec<PathBuf> = outputs.iter().map(|o| o.with_extension("png")).collect();
    let mut all_out = outputs.clone();
    if opts.png {
        all_out.extend(pngs.iter().cloned());
    }
    let mut aux_inputs: Vec<PathBuf> = Vec::new();
    for a in &opts.aux {
        aux_inputs.extend(files.iter().map(|f| a.file_for(f)));
    }
    output::prepare_outputs(outdir, &[files.clone(), aux_inputs].concat(), &all_out)?;
    let limits = Limits::default();
    let budget = Budget::detect(opts.max_memory, settings.threads);
    let mut report = RunReport::default();
    let mut ctx = methods::context(settings)?;
    let first = read_frame(&files[0], &limits, None, method, settings, opts, &budget, &ctx.pool, None)?;
    let pipelined = first.estimate.pipelined;
    let mut den = methods::create(method, settings, &first.frame)?;
    report.plan = den.plan().line(den.name());
    report.stages = den.plan().clone();
    report.buffers = {
        let mut b: Vec<&'static str> =
            Buffer::ALL.into_iter().filter(|b| first.info.has(*b)).map(|b| b.name()).collect();
        b.extend(opts.aux.iter().map(|a| a.buffer.name()));
        b
    };
    report.size = (first.frame.width, first.frame.height);
    let bar = (files.len() > 1 && !opts.quiet && std::io::stderr().is_terminal()).then(|| {
        let b = indicatif::ProgressBar::new(files.len() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {msg}")
                .expect("static template")
                .progress_chars("=> "),
        );
        b.set_prefix(method.name());
        b
    });
    let dims = report.size;
    let pool = ctx.pool.clone();
    let read_next = |path: &Path| {
        read_frame(path, &limits, Some((&files[0], dims)), method, settings, opts, &budget, &pool, Some(pipelined))
    };
    // One frame: checks, warnings, the denoiser; returns the job to write.
    let mut step = |i: usize, r: Read, report: &mut RunReport| -> Result<Job> {
        let f = r.frame;
        check_same_size(&files[0], dims, &f)?;
        if report.estimate.is_none_or(|e| e.bytes() < r.estimate.bytes()) {
            report.estimate = Some(r.estimate);
        }
        if f.replaced_nonfinite > 0 {
            report.warnings.push(format!(
                "{}: {} non-finite values replaced (NaN by 0, inf by ±1e20)",
                files[i].display(),
                f.replaced_nonfinite
            ));
        }
        let out = den.denoise(&f, &mut ctx, &mut report.timings)?;
        on_frame(i, &out, &f);
        Ok(Job { index: i, out, source: f.source.clone(), size: (f.width, f.height) })
    };
    report.read = first.seconds;
    let result = if !pipelined {
        // One frame at a time (the pipelined estimate did not fit).
        let mut next = Some(first);
        (|| -> Result<()> {
            for (i, path) in files.iter().enumerate() {
                let r = match next.take() {
                    Some(r) => r,
                    None => {
                        let r = read_next(path)?;
                        report.read += r.seconds;
                        r
                    }
                };
                let job = step(i, r, &mut report)?;
                let t = Instant::now();
                write_job(&job, &outputs, &pngs, opts, &pool)?;
                report.write += t.elapsed();
                report.frames += 1;
                if let Some(b) = &bar {
                    b.inc(1);
                }
            }
            Ok(())
        })()
    } else {
        let (frame_tx, frame_rx) = sync_channel::<Result<Read>>(0);
        let (job_tx, job_rx) = sync_channel::<Job>(0);
        std::thread::scope(|scope| -> Result<()> {
            // The reader: frames 1.. in order, one ahead of the denoiser.
            let reader = scope.spawn(|| {
                for path in &files[1..] {
                    let r = read_next(path);
                    let stop = r.is_err();
                    if frame_tx.send(r).is_err() || stop {
                        break;
                    }
                }
                drop(frame_tx);
            });
            // The writer: outputs in order, one behind the denoiser.
            let writer = scope.spawn(|| writer_loop(job_rx, &outputs, &pngs, opts, &pool));
            let mut next = Some(first);
            let mut job_tx: Option<SyncSender<Job>> = Some(job_tx);
            let run = (|| -> Result<()> {
                for (i, path) in files.iter().enumerate() {
                    let r = match next.take() {
                        Some(r) => r,
                        None => {
                            let t = Instant::now();
                            let r = frame_rx
                                .recv()
                                .map_err(|_| HostError::bad(path, "the reader stopped before this frame"))??;
                            report.read_wait += t.elapsed();
                            report.read += r.seconds;
                            r
                        }
                    };
                    let job = step(i, r, &mut report)?;
                    let t = Instant::now();
                    let sent = job_tx.as_ref().expect("open until the end").send(job);
                    report.write_wait += t.elapsed();
                    if sent.is_err() {
                        // The writer stopped on an error: it reports it below.
                        break;
                    }
                    report.frames += 1;
                    if let Some(b) = &bar {
                        b.inc(1);
                    }
                }
                Ok(())
            })();
            // Closing the channels stops both threads (a reader blocked on
            // a send sees the receiver gone).
            job_tx.take();
            drop(frame_rx);
            let written = writer.join().map_err(|_| HostError::Usage("internal: the writer thread panicked".into()))?;
            reader.join().map_err(|_| HostError::Usage("internal: the reader thread panicked".into()))?;
            run?;
            report.write = written?;
            Ok(())
        })
    };
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    result?;
    report.outputs = outputs;
    Ok(report)
}

/// Writes one output (and its PNG).
fn write_job(job: &Job, outputs: &[PathBuf], pngs: &[PathBuf], opts: &SequenceOptions, pool: &Pool) -> Result<()> {
    let (w, h) = job.size;
    pool.install(|| output::write_frame(&outputs[job.index], job.source.as_deref(), w, h, &job.out, &opts.write))?;
    if opts.png {
        output::write_png_preview(&pngs[job.index], w, h, &job.out)?;
    }
    Ok(())
}

/// Writes every job's output (and PNG) in order; returns the time spent.
fn writer_loop(
    jobs: Receiver<Job>,
    outputs: &[PathBuf],
    pngs: &[PathBuf],
    opts: &SequenceOptions,
    pool: &Pool,
) -> Result<Duration> {
    let mut spent = Duration::ZERO;
    for job in jobs {
        let t = Instant::now();
        write_job(&job, outputs, pngs, opts, pool)?;
        spent += t.elapsed();
    }
    Ok(spent)
}

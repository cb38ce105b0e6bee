//! A sequence through a method: frames read (each checked from its header
//! for size and memory before its pixels are read), denoised in order and
//! written whole or not at all.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use crate::error::Result;
use crate::io::estimate::Estimate;
use crate::io::frame::{check_same_size, check_same_size_as, Frame, Limits};
use crate::io::{list_inputs, output};
use crate::methods::{self, MethodKind, Settings, Timings};
use crate::runtime::memory::Budget;

/// What a sequence run produced.
#[derive(Debug, Default)]
pub struct RunReport {
    /// Output files, in frame order.
    pub outputs: Vec<PathBuf>,
    /// Kernel-side times (I/O excluded).
    pub timings: Timings,
    /// Frames processed.
    pub frames: usize,
    /// The method's one-line plan.
    pub plan: String,
    /// The stages the method built and skipped.
    pub stages: methods::Plan,
    /// The buffers the first frame has (by [`Buffer::name`](crate::io::frame::Buffer::name)).
    pub buffers: Vec<&'static str>,
    /// Frame width and height.
    pub size: (usize, usize),
    /// Per-frame warnings (non-finite values replaced).
    pub warnings: Vec<String>,
    /// The memory estimate of the largest frame.
    pub estimate: Option<Estimate>,
}

/// How a sequence's outputs are written and how much memory it may take.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SequenceOptions {
    /// f16 output.
    pub half: bool,
    /// PNG previews.
    pub png: bool,
    /// `--max-memory` (without it: the memory available now).
    pub max_memory: Option<u64>,
    /// No progress bar even on a terminal.
    pub quiet: bool,
}

/// Opens frame `path` and checks, from its header, its size against the
/// sequence's and the memory its processing takes against `budget`, before
/// any pixel is read.
#[allow(clippy::too_many_arguments)]
fn open_checked(
    path: &Path,
    limits: &Limits,
    first: Option<(&Path, (usize, usize))>,
    method: MethodKind,
    settings: &Settings,
    opts: &SequenceOptions,
    budget: &Budget,
    report: &mut RunReport,
) -> Result<Frame> {
    let reader = Frame::open(path, limits)?;
    let info = reader.info();
    if let Some((first, dims)) = first {
        check_same_size_as(first, dims, path, (info.width, info.height))?;
    }
    let est = Estimate::new(info, methods::footprint(method, settings, info), opts.half, opts.png);
    est.check(budget, info, &format!("{} in {}", method.name(), settings.precision.name()))?;
    if report.estimate.is_none_or(|e| e.bytes() < est.bytes()) {
        report.estimate = Some(est);
    }
    reader.read()
}

/// Denoises `inputs` with `method` into `outdir`. Each frame's header is
/// checked (size, memory) before its pixels are read; each output is
/// written whole or not at all.
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
    output::prepare_outputs(outdir, &files, &all_out)?;
    let limits = Limits::default();
    let budget = Budget::detect(opts.max_memory, settings.threads);
    let mut report = RunReport::default();
    let first = open_checked(&files[0], &limits, None, method, settings, opts, &budget, &mut report)?;
    let mut den = methods::create(method, settings, &first)?;
    let mut ctx = methods::context(settings)?;
    report.plan = den.plan().line(den.name());
    report.stages = den.plan().clone();
    report.buffers = crate::io::frame::Buffer::ALL.into_iter().filter(|b| first.has(*b)).map(|b| b.name()).collect();
    report.size = (first.width, first.height);
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
    let dims = (first.width, first.height);
    let mut frame = Some(first);
    for (i, path) in files.iter().enumerate() {
        let f = match frame.take() {
            Some(f) => f,
            None => open_checked(path, &limits, Some((&files[0], dims)), method, settings, opts, &budget, &mut report)?,
        };
        check_same_size(&files[0], dims, &f)?;
        if f.replaced_nonfinite > 0 {
            report.warnings.push(format!(
                "{}: {} non-finite values replaced (NaN by 0, inf by ±1e20)",
                path.display(),
                f.replaced_nonfinite
            ));
        }
        let out = den.denoise(&f, &mut ctx, &mut report.timings)?;
        on_frame(i, &out, &f);
        output::write_rgb_exr(&outputs[i], f.width, f.height, &out, opts.half)?;
        if opts.png {
            output::write_png_preview(&pngs[i], f.width, f.height, &out)?;
        }
        report.frames += 1;
        if let Some(b) = &bar {
            b.inc(1);
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    report.outputs = outputs;
    Ok(report)
}

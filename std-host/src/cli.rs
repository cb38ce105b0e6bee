//! Command-line parsing: a pure function from arguments to a [`Command`], so
//! every bad argument gets a one-line message naming it (and the parser can be
//! fuzzed without touching files).

use std::ffi::OsString;
use std::path::PathBuf;

use mcdenoise_core::Isa;

use crate::error::{HostError, Result};
use crate::methods::{MethodKind, Settings};
use crate::precision::PrecisionKind;

/// Usage text.
pub const USAGE: &str = "\
mcdenoise: real-time Monte Carlo denoisers

usage:
  mcdenoise                      run every method on the bundled sample, print a table,
                                 write outputs and PNGs under ./mcdenoise-out/
  mcdenoise denoise --method M [options] INPUT... -o OUTDIR
                                 INPUT: frame files in order, or a directory (its .exr files by name)
      --method M                 none | ta | atrous | sure-atrous | wskp | afn | cross
      --no-refine                afn: without the refinement network
      --precision P              f32 (default) | f16 | f16-arith | fixed
      --threads N                worker threads (default: all cores)
      --isa I                    scalar | avx2 | avx512 (default: the best this CPU has)
      --phi-color F              a-trous colour edge-stopping, in noise variances
                                 (default 64 with B.*, 2048 with one estimate)
      --firefly-clamp K          a-trous: clamp pixels brighter than their 5x5 neighbours' mean
                                 + K standard deviations before filtering (default 6; 0: off)
      --layers N                 wskp: 3 or 6 ImportanceNet layers (default 6)
      --weights FILE             learned methods: weights made by 'mcdenoise train' (default: bundled)
      --seed N                   cross: seed of the initial random weights (default 2024)
      --save-state FILE          cross: write the online network's weights and Adam state after each frame
      --load-state FILE          cross: continue from a saved state instead of random weights
      --half                     write f16 EXR (default f32)
      --png                      also write a tone-mapped PNG preview per frame
      --timings                  print per-stage times and the memory taken (estimate, peak heap, peak resident)
      --max-memory SIZE          refuse a frame whose estimated peak memory is over SIZE (e.g. 512M, 4G),
                                 from its header, before allocating (default: the memory available now)
  mcdenoise precision [--frame FILE] [--size WxH] [--threads N] [--only OP,...] [--csv F] [--svg F]
                                 time and error (against the f64 oracle) of every operator in every
                                 precision and instruction set; CSV and an SVG plot (default under
                                 ./mcdenoise-out/); 1 thread and 1280x720 unless told otherwise
  mcdenoise train --method wskp|afn --data DIR (--steps N | --minutes M) -o WEIGHTS [options]
      --val DIR                  validation sequences (mean PSNR printed every --val-every steps)
      --layers N                 3 or 6 (default 6)        --batch N      crops per step (default 8)
      --crop N                   crop side (default 128)   --lr F         Adam learning rate (default 1e-3)
      --loss L                   smape | relmse | l1 (default smape)  --clip F  gradient norm clip (default off)
      --seed N                   initialisation and sampling seed (default 1)
      --threads N, --isa I       as for denoise            --resume CKPT  continue from WEIGHTS.ckpt
      --checkpoint-minutes F     (default 5)               --val-every N  (default 500)
      --log CSV                  step, seconds, loss and validation PSNR per step
      --variant V                afn: fusion (default) | ta-only | 1spp-only (the ablation)
  mcdenoise score --reference REF OUT [--json]
                                 REF and OUT: two files, or two directories (matched by name)
  mcdenoise help | --help | --version
";

/// What to do.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// The main job on the bundled sample.
    Demo {
        /// Shared settings.
        settings: Settings,
    },
    /// Denoise a sequence.
    Denoise(DenoiseArgs),
    /// Score outputs against references.
    Score {
        /// Reference file or directory.
        reference: PathBuf,
        /// Output file or directory.
        output: PathBuf,
        /// Machine-readable output.
        json: bool,
    },
    /// The precision report.
    Precision(crate::report::ReportArgs),
    /// Train a learned method.
    Train(crate::train::TrainArgs),
    /// Print usage.
    Help,
    /// Print the version.
    Version,
}

/// Arguments of `denoise`.
#[derive(Clone, Debug, PartialEq)]
pub struct DenoiseArgs {
    /// Which method.
    pub method: MethodKind,
    /// Shared settings.
    pub settings: Settings,
    /// Input files or directories.
    pub inputs: Vec<PathBuf>,
    /// Output directory.
    pub outdir: PathBuf,
    /// f16 output.
    pub half: bool,
    /// PNG previews.
    pub png: bool,
    /// Per-stage times.
    pub timings: bool,
    /// `--max-memory`, in bytes.
    pub max_memory: Option<u64>,
}

fn usage(msg: impl Into<String>) -> HostError {
    HostError::Usage(msg.into())
}

fn text(flag: &str, v: Option<OsString>) -> Result<String> {
    let v = v.ok_or_else(|| usage(format!("{flag}: expects a value")))?;
    v.into_string().map_err(|_| usage(format!("{flag}: value is not valid UTF-8")))
}

/// Parses a whole number in `lo..=hi` for `flag`.
pub fn number(flag: &str, s: &str, lo: usize, hi: usize) -> Result<usize> {
    match s.trim().parse::<usize>() {
        Ok(v) if (lo..=hi).contains(&v) => Ok(v),
        _ => Err(usage(format!("{flag}: expected a whole number from {lo} to {hi}, got '{s}'"))),
    }
}

/// Default worker threads: every core.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

fn parse_settings(flag: &str, value: &str, s: &mut Settings) -> Result<bool> {
    match flag {
        "--precision" => s.precision = PrecisionKind::parse(value)?,
        "--threads" => s.threads = number("--threads", value, 1, 256)?,
        "--phi-color" => {
            s.phi_color =
                Some(value.trim().parse::<f32>().ok().filter(|v| v.is_finite() && *v > 0.0 && *v <= 1e6).ok_or_else(
                    || usage(format!("--phi-color: expected a positive number up to 1e6, got '{value}'")),
                )?)
        }
        "--firefly-clamp" => {
            s.firefly_clamp =
                value.trim().parse::<f32>().ok().filter(|v| v.is_finite() && *v >= 0.0 && *v <= 1e6).ok_or_else(
                    || usage(format!("--firefly-clamp: expected a number from 0 (off) up to 1e6, got '{value}'")),
                )?
        }
        "--isa" => {
            s.isa = Isa::from_name(value)
                .ok_or_else(|| usage(format!("--isa: expected scalar, avx2 or avx512; got '{value}'")))?
        }
        "--layers" => {
            s.layers = match value.trim() {
                "3" => 3,
                "6" => 6,
                _ => return Err(usage(format!("--layers: expected 3 or 6, got '{value}'"))),
            }
        }
        "--weights" => s.weights = Some(PathBuf::from(value)),
        "--seed" => {
            s.seed = value
                .trim()
                .parse::<u64>()
                .map_err(|_| usage(format!("--seed: expected a whole number, got '{value}'")))?
        }
        "--save-state" => s.save_state = Some(PathBuf::from(value)),
        "--load-state" => s.load_state = Some(PathBuf::from(value)),
        _ => return Ok(false),
    }
    Ok(true)
}

/// Parses the arguments after the program name.
pub fn parse(args: impl IntoIterator<Item = OsString>) -> Result<Command> {
    let mut it = args.into_iter();
    let mut settings = Settings { threads: default_threads(), ..Settings::default() };
    let Some(first) = it.next() else { return Ok(Command::Demo { settings }) };
    let first = first.into_string().map_err(|_| usage("command is not valid UTF-8"))?;
    match first.as_str() {
        "help" | "--help" | "-h" => Ok(Command::Help),
        "--version" | "-V" => Ok(Command::Version),
        "demo" => {
            while let Some(a) = it.next() {
                let a = a.into_string().map_err(|_| usage("argument is not valid UTF-8"))?;
                let v = text(&a, it.next())?;
                if !parse_settings(&a, &v, &mut settings)? {
                    return Err(usage(format!("demo: unknown option '{a}'")));
                }
            }
            Ok(Command::Demo { settings })
        }
        "denoise" => {
            let mut method = None;
            let (mut inputs, mut outdir) = (Vec::new(), None);
            let (mut half, mut png, mut timings) = (false, false, false);
            let mut max_memory = None;
            while let Some(a) = it.next() {
                match a.to_str() {
                    Some("--method") => method = Some(MethodKind::parse(&text("--method", it.next())?)?),
                    Some("-o" | "--output") => {
                        outdir = Some(PathBuf::from(it.next().ok_or_else(|| usage("-o: expects a directory"))?))
                    }
                    Some("--half") => half = true,
                    Some("--png") => png = true,
                    Some("--timings") => timings = true,
                    Some("--no-refine") => settings.refine = false,
                    Some("--max-memory") => {
                        let v = text("--max-memory", it.next())?;
                        max_memory =
                            Some(crate::memory::parse_size(&v).map_err(|e| usage(format!("--max-memory: {e}")))?);
                    }
                    Some(
                        f @ ("--precision" | "--threads" | "--isa" | "--phi-color" | "--firefly-clamp" | "--layers"
                        | "--weights" | "--seed" | "--save-state" | "--load-state"),
                    ) => {
                        let f = f.to_string();
                        let v = text(&f, it.next())?;
                        parse_settings(&f, &v, &mut settings)?;
                    }
                    Some(f) if f.starts_with("--") => return Err(usage(format!("denoise: unknown option '{f}'"))),
                    _ => inputs.push(PathBuf::from(a)),
                }
            }
            let method = method.ok_or_else(|| {
                usage("denoise: --method is required (none, ta, atrous, sure-atrous, wskp, afn, cross)")
            })?;
            let outdir = outdir.ok_or_else(|| usage("denoise: -o OUTDIR is required"))?;
            if inputs.is_empty() {
                return Err(usage("denoise: no INPUT given (frame files or a directory)"));
            }
            Ok(Command::Denoise(DenoiseArgs { method, settings, inputs, outdir, half, png, timings, max_memory }))
        }
        "precision" => {
            let mut a = crate::report::ReportArgs {
                frame: None,
                csv: PathBuf::from("mcdenoise-out/precision.csv"),
                svg: PathBuf::from("mcdenoise-out/precision.svg"),
                threads: 1,
                width: 1280,
                height: 720,
                only: Vec::new(),
            };
            while let Some(f) = it.next() {
                let f = f.into_string().map_err(|_| usage("argument is not valid UTF-8"))?;
                let v = text(&f, it.next())?;
                match f.as_str() {
                    "--frame" => a.frame = Some(PathBuf::from(v)),
                    "--csv" => a.csv = PathBuf::from(v),
                    "--svg" => a.svg = PathBuf::from(v),
                    "--threads" => a.threads = number("--threads", &v, 1, 256)?,
                    "--size" => {
                        let (ws, hs) =
                            v.split_once('x').ok_or_else(|| usage(format!("--size: expected WxH, got '{v}'")))?;
                        a.width = number("--size width", ws, 1, 8192)?;
                        a.height = number("--size height", hs, 1, 8192)?;
                    }
                    "--only" => {
                        let names = crate::registry::names();
                        for op in v.split(',') {
                            if !names.contains(&op) {
                                return Err(usage(format!(
                                    "--only: unknown operator '{op}' (one of {})",
                                    names.join(", ")
                                )));
                            }
                            a.only.push(op.to_string());
                        }
                    }
                    _ => return Err(usage(format!("precision: unknown option '{f}'"))),
                }
            }
            Ok(Command::Precision(a))
        }
        "train" => {
            let mut a = crate::train::TrainArgs { threads: default_threads(), ..Default::default() };
            let mut out = None;
            let mut data = None;
            while let Some(f) = it.next() {
                let f = f.into_string().map_err(|_| usage("argument is not valid UTF-8"))?;
                let v = text(&f, it.next())?;
                let float = |flag: &str, lo: f64, hi: f64| -> Result<f64> {
                    v.trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite() && (lo..=hi).contains(x))
                        .ok_or_else(|| usage(format!("{flag}: expected a number from {lo} to {hi}, got '{v}'")))
                };
                match f.as_str() {
                    "--method" => {
                        if v != "wskp" && v != "afn" {
                            return Err(usage(format!("train --method: expected wskp or afn, got '{v}'")));
                        }
                        a.method = v;
                    }
                    "--data" => data = Some(PathBuf::from(v)),
                    "--val" => a.val = Some(PathBuf::from(v)),
                    "-o" | "--output" => out = Some(PathBuf::from(v)),
                    "--layers" => {
                        let mut s = Settings::default();
                        parse_settings("--layers", &v, &mut s)?;
                        a.layers = s.layers;
                    }
                    "--steps" => a.steps = Some(number("--steps", &v, 1, 1 << 40)? as u64),
                    "--minutes" => a.minutes = Some(float("--minutes", 0.0, 1e6)?),
                    "--batch" => a.batch = number("--batch", &v, 1, 256)?,
                    "--crop" => a.crop = number("--crop", &v, 8, 4096)?,
                    "--lr" => a.lr = float("--lr", 0.0, 1.0)? as f32,
                    "--clip" => a.clip = float("--clip", 0.0, 1e9)? as f32,
                    "--loss" => {
                        a.loss = crate::nn::loss::Loss::parse(&v)
                            .ok_or_else(|| usage(format!("--loss: expected smape, relmse or l1, got '{v}'")))?
                    }
                    "--seed" => a.seed = number("--seed", &v, 0, usize::MAX)? as u64,
                    "--threads" => a.threads = number("--threads", &v, 1, 256)?,
                    "--isa" => {
                        a.isa = Isa::from_name(&v)
                            .ok_or_else(|| usage(format!("--isa: expected scalar, avx2 or avx512; got '{v}'")))?
                    }
                    "--resume" => a.resume = Some(PathBuf::from(v)),
                    "--checkpoint-minutes" => a.checkpoint_minutes = float("--checkpoint-minutes", 0.0, 1e6)?,
                    "--val-every" => a.val_every = number("--val-every", &v, 0, 1 << 40)? as u64,
                    "--log" => a.log = Some(PathBuf::from(v)),
                    "--variant" => {
                        a.variant = crate::afn::Variant::parse(&v).ok_or_else(|| {
                            usage(format!("--variant: expected fusion, ta-only or 1spp-only, got '{v}'"))
                        })?
                    }
                    _ => return Err(usage(format!("train: unknown option '{f}'"))),
                }
            }
            a.data = data.ok_or_else(|| usage("train: --data DIR is required"))?;
            a.out = out.ok_or_else(|| usage("train: -o WEIGHTS is required"))?;
            if a.steps.is_none() && a.minutes.is_none() {
                return Err(usage("train: give --steps N or --minutes M"));
            }
            Ok(Command::Train(a))
        }
        "score" => {
            let (mut reference, mut paths, mut json) = (None, Vec::new(), false);
            while let Some(a) = it.next() {
                match a.to_str() {
                    Some("--reference" | "-r") => {
                        reference = Some(PathBuf::from(it.next().ok_or_else(|| usage("--reference: expects a path"))?))
                    }
                    Some("--json") => json = true,
                    Some(f) if f.starts_with("--") => return Err(usage(format!("score: unknown option '{f}'"))),
                    _ => paths.push(PathBuf::from(a)),
                }
            }
            let reference = reference.ok_or_else(|| usage("score: --reference REF is required"))?;
            if paths.len() != 1 {
                return Err(usage(format!("score: expected one OUT path, got {}", paths.len())));
            }
            Ok(Command::Score { reference, output: paths.remove(0), json })
        }
        other => Err(usage(format!("unknown command '{other}'; try 'mcdenoise help'"))),
    }
}

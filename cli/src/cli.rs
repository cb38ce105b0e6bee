//! Command-line parsing: a pure function from arguments to a [`Command`], so
//! every bad argument gets a one-line message naming it (and the parser can be
//! fuzzed without touching files).
//!
//! The grammar is one `clap` definition ([`definition`]): `--help` of every
//! command, the shell completions and the man page all come from it. Its
//! errors are turned into one line naming the command, the flag and what it
//! expects, with clap's suggestion of the closest option or value when it has
//! one, and come back as [`HostError::Usage`] (exit 2 in the binary).

use std::ffi::OsString;
use std::path::PathBuf;

use clap::error::{ContextKind, ContextValue, ErrorKind};
use clap::{Args, CommandFactory, FromArgMatches, Parser, Subcommand, ValueEnum};
use mcdenoise_core::Isa;

use mcdenoise::error::{HostError, Result};
use mcdenoise::io::output::OutCompression;
use mcdenoise::methods::afn::Variant;
use mcdenoise::methods::{MethodKind, Settings};
use mcdenoise::nn::loss::Loss;
use mcdenoise::runtime::precision::PrecisionKind;

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
    /// Inspect a frame file.
    Inspect {
        /// The file.
        file: PathBuf,
        /// Layer and part.
        selection: mcdenoise::io::names::Selection,
    },
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
    Precision(mcdenoise_kit::report::ReportArgs),
    /// The precision report per method, on a rendered sequence.
    PrecisionMethods {
        /// Which methods (names of [`crate::commands::REPORT_METHODS`]).
        methods: Vec<String>,
        /// The frames.
        sequence: PathBuf,
        /// Their references (default: `SEQUENCE/ref`).
        reference: Option<PathBuf>,
        /// Worker threads.
        threads: usize,
        /// The CSV to write.
        csv: PathBuf,
    },
    /// Train a learned method.
    Train(mcdenoise::train::TrainArgs),
    /// Print a shell completion script.
    Completions(clap_complete::Shell),
    /// Print the man page, or write one page per command into a directory.
    Man {
        /// Where to write `mcdenoise.1` and `mcdenoise-COMMAND.1` (stdout: the main page).
        dir: Option<PathBuf>,
    },
    /// Print this help text (the requested command's).
    Help(String),
    /// Print this version line.
    Version(String),
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
    /// How frames are read and written (`quiet` set from `--quiet` or `--json`).
    pub sequence: mcdenoise::pipeline::SequenceOptions,
    /// Per-stage times.
    pub timings: bool,
    /// Print nothing but warnings and errors.
    pub quiet: bool,
    /// Print one JSON object instead of the text summary.
    pub json: bool,
}

/// Default worker threads: every core.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// Parses a whole number in `lo..=hi` for `flag`.
pub fn number(flag: &str, s: &str, lo: usize, hi: usize) -> Result<usize> {
    whole(s, lo as u64, hi as u64).map(|v| v as usize).map_err(|e| HostError::Usage(format!("{flag}: {e}")))
}

// ---------------------------------------------------------------------------
// Value parsers. Each error says what is expected and repeats the value; the
// flag is added by `one_line` from clap's context.

fn whole(s: &str, lo: u64, hi: u64) -> std::result::Result<u64, String> {
    match s.trim().parse::<u64>() {
        Ok(v) if (lo..=hi).contains(&v) => Ok(v),
        _ => Err(format!("expected a whole number from {lo} to {hi}, got '{s}'")),
    }
}

fn real(s: &str, lo: f64, hi: f64) -> std::result::Result<f64, String> {
    s.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite() && (lo..=hi).contains(x))
        .ok_or_else(|| format!("expected a number from {lo} to {hi}, got '{s}'"))
}

fn threads(s: &str) -> std::result::Result<usize, String> {
    whole(s, 1, 256).map(|v| v as usize)
}

fn phi_color(s: &str) -> std::result::Result<f32, String> {
    s.trim()
        .parse::<f32>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0 && *v <= 1e6)
        .ok_or_else(|| format!("expected a positive number up to 1e6, got '{s}'"))
}

fn firefly(s: &str) -> std::result::Result<f32, String> {
    s.trim()
        .parse::<f32>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0 && *v <= 1e6)
        .ok_or_else(|| format!("expected a number from 0 (off) up to 1e6, got '{s}'"))
}

fn pair_use(s: &str) -> std::result::Result<mcdenoise::methods::PairUse, String> {
    mcdenoise::methods::PairUse::from_name(s.trim()).ok_or_else(|| format!("expected mean or first, got '{s}'"))
}

fn on_off(s: &str) -> std::result::Result<bool, String> {
    match s.trim() {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("expected on or off, got '{s}'")),
    }
}

fn wskp_sizes(s: &str) -> std::result::Result<mcdenoise::methods::wskp::Sizes, String> {
    mcdenoise::methods::wskp::Sizes::parse(s)
}

fn layers(s: &str) -> std::result::Result<usize, String> {
    match s.trim() {
        "3" => Ok(3),
        "6" => Ok(6),
        _ => Err(format!("expected 3 or 6, got '{s}'")),
    }
}

fn seed(s: &str) -> std::result::Result<u64, String> {
    s.trim().parse::<u64>().map_err(|_| format!("expected a whole number, got '{s}'"))
}

fn size(s: &str) -> std::result::Result<u64, String> {
    mcdenoise::runtime::memory::parse_size(s)
}

fn frame_size(s: &str) -> std::result::Result<(usize, usize), String> {
    let (w, h) = s.split_once('x').ok_or_else(|| format!("expected WxH, got '{s}'"))?;
    let side = |v: &str, what: &str| whole(v, 1, 8192).map(|v| v as usize).map_err(|e| format!("{what}: {e}"));
    Ok((side(w, "width")?, side(h, "height")?))
}

fn steps(s: &str) -> std::result::Result<u64, String> {
    whole(s, 1, 1 << 40)
}

fn every(s: &str) -> std::result::Result<u64, String> {
    whole(s, 0, 1 << 40)
}

fn batch(s: &str) -> std::result::Result<usize, String> {
    whole(s, 1, 256).map(|v| v as usize)
}

fn crop(s: &str) -> std::result::Result<usize, String> {
    whole(s, 8, 4096).map(|v| v as usize)
}

fn minutes(s: &str) -> std::result::Result<f64, String> {
    real(s, 0.0, 1e6)
}

/// A number from 0 to 1 (a learning rate, a share).
fn unit(s: &str) -> std::result::Result<f32, String> {
    real(s, 0.0, 1.0).map(|v| v as f32)
}

fn band_weight(s: &str) -> std::result::Result<f32, String> {
    real(s, 0.0, 100.0).map(|v| v as f32)
}

/// `--emulate-spp`'s list (a newtype: clap reads a bare `Vec` as repeats).
#[derive(Clone, Debug)]
struct SppList(Vec<u32>);

fn spp_list(s: &str) -> std::result::Result<SppList, String> {
    if s == "off" {
        return Ok(SppList(Vec::new()));
    }
    s.split(',')
        .map(|t| match t.trim().parse::<u32>() {
            Ok(n) if (2..=65536).contains(&n) => Ok(n),
            _ => Err(format!("expected sample counts 2..65536 separated by commas, or off; got '{t}'")),
        })
        .collect::<std::result::Result<Vec<_>, _>>()
        .map(SppList)
}

fn estimates(s: &str) -> std::result::Result<usize, String> {
    whole(s, 1, 2).map(|v| v as usize)
}

fn frame_stride(s: &str) -> std::result::Result<usize, String> {
    whole(s, 1, 1000).map(|v| v as usize)
}

fn clip(s: &str) -> std::result::Result<f32, String> {
    real(s, 0.0, 1e9).map(|v| v as f32)
}

// ---------------------------------------------------------------------------
// The definition.

/// Instruction set, by command-line name (the core's [`Isa`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum IsaArg {
    /// Portable Rust on every target.
    Scalar,
    /// x86_64 AVX2 with FMA and F16C.
    Avx2,
    /// x86_64 AVX-512 (F, BW, DQ, VL); operators without a 16-lane kernel run their AVX2 one.
    Avx512,
}

impl IsaArg {
    fn isa(self) -> Isa {
        match self {
            IsaArg::Scalar => Isa::Scalar,
            IsaArg::Avx2 => Isa::Avx2,
            IsaArg::Avx512 => Isa::Avx512,
        }
    }
}

/// The learned methods `train` makes weights for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum TrainMethod {
    /// Weight-sharing kernel prediction (Fan et al. 2021).
    Wskp,
    /// The adaptive fusion network (Lee et al. 2024).
    Afn,
}

const AFTER_HELP: &str = "\
Without a command: the main job, every method on the bundled sample (./samples) with a table of time
and quality, outputs, PNGs and a contact sheet (mcdenoise-out/contact-sheet.png) under ./mcdenoise-out/.

Examples:
  mcdenoise denoise --method wskp --png renders/ -o denoised/
  mcdenoise denoise --method sure-atrous --precision fixed --json frame_0001.exr -o out/
  mcdenoise score --reference renders/ref denoised
  mcdenoise completions bash > /etc/bash_completion.d/mcdenoise";

/// Real-time Monte Carlo denoisers for 1-sample-per-pixel path-traced frames.
#[derive(Debug, Parser)]
#[command(name = "mcdenoise", version, propagate_version = true, after_help = AFTER_HELP)]
struct Cli {
    #[command(subcommand)]
    command: Option<Sub>,
}

#[derive(Debug, Subcommand)]
enum Sub {
    /// Every method on the bundled sample: a table, outputs, PNGs and a contact sheet under ./mcdenoise-out/
    /// (the default)
    Demo(DemoCli),
    /// Denoise a sequence of EXR frames (in order) into a directory
    #[command(
        after_help = "INPUT contract: one multichannel OpenEXR file per frame with R,G,B (noisy radiance) and, \
                            when the renderer has them, albedo.R/G/B, normal.X/Y/Z, depth.Z, position.X/Y/Z, \
                            motion.X/Y and B.R,B.G,B.B (a second estimate); see docs/exr.md."
    )]
    Denoise(DenoiseCli),
    /// Train a learned method's weights on rendered sequences
    Train(TrainCli),
    /// Score outputs against references (PSNR, SSIM, relMSE, SMAPE, RMSE, flicker)
    Score(ScoreCli),
    /// What the loader finds in an EXR file (parts, channels, windows, buffers) and what each method
    /// will build from it
    Inspect(InspectCli),
    /// Time and error (against the f64 oracle) of every core operator in every precision and instruction
    /// set; with --methods, each method's time and PSNR in every precision on a rendered sequence
    Precision(PrecisionCli),
    /// Print a completion script for a shell
    Completions {
        /// The shell
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Print the man page (roff), or write one page per command into a directory
    Man {
        /// Write mcdenoise.1 and mcdenoise-COMMAND.1 into DIR instead of printing the main page
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
    },
}

/// The settings every method shares (`demo` and `denoise`).
#[derive(Debug, Args)]
struct SettingsCli {
    /// Storage and arithmetic precision of every stage
    #[arg(long, value_enum, value_name = "P", default_value_t = PrecisionKind::F32)]
    precision: PrecisionKind,
    /// Worker threads [default: every core]
    #[arg(long, value_name = "N", value_parser = threads)]
    threads: Option<usize>,
    /// Instruction set of every kernel [default: the widest this CPU has]
    #[arg(long, value_enum, value_name = "ISA")]
    isa: Option<IsaArg>,
    /// À-trous colour edge-stopping, in noise variances [default: 64 with B.*, 2048 with one estimate]
    #[arg(long, value_name = "F", value_parser = phi_color)]
    phi_color: Option<f32>,
    /// À-trous: clamp pixels brighter than their 5x5 neighbours' mean + K standard deviations before
    /// filtering (0: off) [default: 16 with B.*, 6 with one estimate]
    #[arg(long, value_name = "K", value_parser = firefly)]
    firefly_clamp: Option<f32>,
    /// Temporal accumulation (ta, WSKP, AFN): clamp the reprojected history to the frame's 5x5
    /// mean +- K standard deviations, so that a light that moved is not dragged along (0: off)
    /// [default: 1; for WSKP and AFN the value their weights were trained with, if they say]
    #[arg(long, value_name = "K", value_parser = firefly)]
    ta_clamp: Option<f32>,
    /// Temporal accumulation (ta, WSKP, AFN): let the history go where the frame's 9x9 mean
    /// luminance differs from the accumulated one by more than Z standard errors of the frame's
    /// mean (all of it by 2Z), so that a moving light does not lag (0: off) [default: 3; 2 for
    /// WSKP and AFN]
    #[arg(long, value_name = "Z", value_parser = firefly)]
    ta_reject: Option<f32>,
    /// Temporal accumulation (ta, WSKP, AFN): the history rejection compares the means over 9x9
    /// windows (1), and over 17x17 (2) and 33x33 (3; at 1.5 times Z) as well: a wider mean finds a
    /// lag too small for a narrower one, and lets more history go [default: 1; 3 for WSKP and AFN]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u8).range(1..=3))]
    ta_reject_scales: Option<u8>,
    /// Temporal accumulation (ta, WSKP, AFN): where the frame's and the history's 65x65 mean
    /// luminance differ beyond the rejection's threshold, scale the history by their ratio before
    /// the rejection's tests (where it brings their 17x17 means closer), so that a wall a moving
    /// light brightens or dims keeps its history instead of restarting from one frame (off: let
    /// the rejection alone decide)
    #[arg(long, value_name = "ON|OFF", default_value = "on", value_parser = on_off, action = clap::ArgAction::Set)]
    ta_relight: bool,
    /// A frame with a second estimate B.* of its pixels: 'mean' uses every sample (none, ta, WSKP
    /// and AFN filter (A + B) / 2; atrous, sure-atrous and cross read both as always); 'first'
    /// reads A alone, as if B.* were not there (to compare with a denoiser given one estimate;
    /// cross needs the pair)
    #[arg(long, value_name = "USE", default_value = "mean", value_parser = pair_use)]
    pair: mcdenoise::methods::PairUse,
    /// WSKP: ImportanceNet layers (3 or 6) [default: the --weights file's, else 6]
    #[arg(long, value_name = "N", value_parser = layers, help_heading = "Learned methods")]
    layers: Option<usize>,
    /// Weights made by 'mcdenoise train' [default: the bundled ones]
    #[arg(long, value_name = "FILE", help_heading = "Learned methods")]
    weights: Option<PathBuf>,
    /// Cross: seed of the initial random weights
    #[arg(long, value_name = "N", default_value_t = mcdenoise::methods::cross::SEED, value_parser = seed, help_heading = "Online method (cross)")]
    seed: u64,
    /// Cross: write the network's weights and Adam state here after every frame
    #[arg(long, value_name = "FILE", help_heading = "Online method (cross)")]
    save_state: Option<PathBuf>,
    /// Cross: start from a saved state instead of random weights
    #[arg(long, value_name = "FILE", help_heading = "Online method (cross)")]
    load_state: Option<PathBuf>,
    /// Cross: Adam's learning rate of the one step per frame
    #[arg(long, value_name = "LR", default_value_t = mcdenoise::methods::cross::LR, value_parser = unit, help_heading = "Online method (cross)")]
    cross_lr: f32,
    /// Cross: no temporal reuse (no reprojection, no temporal loss; an ablation)
    #[arg(long, help_heading = "Online method (cross)")]
    cross_spatial_only: bool,
    /// AFN: hold the full-scale kernel maps whole instead of streaming them in bands (to measure what
    /// streaming saves; counted in the memory estimate)
    #[arg(long, help_heading = "Learned methods")]
    afn_whole_maps: bool,
    /// WSKP, AFN: emulate 8-bit networks (weights i8 per output channel, activations u8/i8 per
    /// tensor from the first frame's ranges; --precision f32 or f16). Measures what an 8-bit (VNNI)
    /// mode would cost in accuracy; it is not faster
    #[arg(long, help_heading = "Learned methods")]
    emulate_int8: bool,
}

/// The `layers` recorded in a WSKP weights file, or 6 (no file, another
/// method's file, or one that cannot be read: opening it again later
/// reports the fault).
fn layers_of(weights: Option<&std::path::Path>) -> usize {
    weights
        .and_then(|p| mcdenoise::nn::weights::File::read(p).ok())
        .and_then(|f| f.meta("layers"))
        .and_then(|l| l.parse().ok())
        .filter(|&l| l == 3 || l == 6)
        .unwrap_or(6)
}

impl SettingsCli {
    fn settings(self) -> Settings {
        let mut s = Settings { threads: default_threads(), ..Settings::default() };
        s.precision = self.precision;
        if let Some(t) = self.threads {
            s.threads = t;
        }
        if let Some(i) = self.isa {
            s.isa = i.isa();
        }
        s.phi_color = self.phi_color;
        s.firefly_clamp = self.firefly_clamp;
        s.ta_clamp = self.ta_clamp;
        s.ta_reject = self.ta_reject;
        s.ta_reject_scales = self.ta_reject_scales.map(usize::from);
        s.ta_relight = self.ta_relight;
        s.layers = self.layers.unwrap_or_else(|| layers_of(self.weights.as_deref()));
        s.weights = self.weights;
        s.seed = self.seed;
        s.save_state = self.save_state;
        s.load_state = self.load_state;
        s.cross_lr = self.cross_lr;
        s.cross_spatial_only = self.cross_spatial_only;
        s.afn_whole_maps = self.afn_whole_maps;
        s.emulate_int8 = self.emulate_int8;
        s.pair = self.pair;
        s
    }
}

#[derive(Debug, Args)]
struct DemoCli {
    #[command(flatten)]
    settings: SettingsCli,
}

#[derive(Debug, Args)]
struct DenoiseCli {
    /// The method
    #[arg(long, value_enum, value_name = "METHOD")]
    method: MethodKind,
    /// Frame files in order, or a directory (its .exr files in name order)
    #[arg(value_name = "INPUT", required = true)]
    inputs: Vec<PathBuf>,
    /// Output directory (one file per input, same name)
    #[arg(short = 'o', long = "output", value_name = "OUTDIR")]
    outdir: PathBuf,
    #[command(flatten)]
    settings: SettingsCli,
    /// AFN: without the refinement network
    #[arg(long, help_heading = "Learned methods")]
    no_refine: bool,
    /// WSKP, AFN and cross: without the fallback to the input (where the output differs from the input
    /// by more than its noise explains, e.g. a clean frame blurred); the papers' methods as
    /// published
    #[arg(long, help_heading = "Learned methods")]
    no_fallback: bool,
    /// WSKP and AFN: without the wide pass (an edge-avoiding à-trous filter over the output where
    /// the temporal history is short, for the low-frequency blotches the kernels leave of 1-spp
    /// noise)
    #[arg(long, help_heading = "Learned methods")]
    no_wide_pass: bool,
    /// Write the colour as f16 [default: the input colour's pixel type]
    #[arg(long, help_heading = "Output", conflicts_with = "float")]
    half: bool,
    /// Write the colour as f32 [default: the input colour's pixel type]
    #[arg(long, help_heading = "Output")]
    float: bool,
    /// Output compression
    #[arg(long, value_enum, value_name = "C", default_value_t = OutCompression::Zip, help_heading = "Output")]
    compression: OutCompression,
    /// Copy every input channel the method does not read (and every part of a multi-part file) into
    /// the output unchanged, beside the denoised colour
    #[arg(long, help_heading = "Output")]
    keep_channels: bool,
    /// Read, denoise and write one frame at a time instead of reading the next frame and writing the last
    /// output while a frame is denoised (less memory; by default the overlap is used when its memory
    /// estimate fits)
    #[arg(long, help_heading = "Output")]
    no_pipeline: bool,
    /// Also write a PNG preview per frame (clamp(x,0,1)^(1/2.2))
    #[arg(long, help_heading = "Output")]
    png: bool,
    /// Print per-stage times and the memory taken (estimate, peak heap, peak resident size)
    #[arg(long, help_heading = "Output")]
    timings: bool,
    /// Print nothing but warnings and errors (no plan, no progress bar, no summary)
    #[arg(long, short = 'q', help_heading = "Output", conflicts_with = "json")]
    quiet: bool,
    /// Print one JSON object (plan, ms/frame, stages, memory, outputs) instead of the text
    #[arg(long, help_heading = "Output")]
    json: bool,
    /// Refuse a frame whose estimated peak memory is over SIZE (512M, 4G, 1.5GiB), before reading its pixels
    /// [default: the memory available now]
    #[arg(long, value_name = "SIZE", value_parser = size)]
    max_memory: Option<u64>,
    #[command(flatten)]
    input: InputCli,
}

/// Where the buffers are in the input files (`denoise`, `inspect`).
#[derive(Debug, Args)]
struct InputCli {
    /// The layer whose channels to read: `NAME.` before every channel name (Blender's view layer, e.g.
    /// ViewLayer) [default: none, or the file's one Blender view layer]
    #[arg(long, value_name = "NAME", help_heading = "Input")]
    layer: Option<String>,
    /// The part of a multi-part file whose channels win where two parts have a channel of one name
    #[arg(long, value_name = "NAME", help_heading = "Input")]
    part: Option<String>,
    /// Albedo from its own files: a file, or a directory matched to the frames by file name
    #[arg(long, value_name = "FILE|DIR", help_heading = "Input")]
    albedo: Option<PathBuf>,
    /// World-space normals from their own files (file or directory, as --albedo)
    #[arg(long, value_name = "FILE|DIR", help_heading = "Input")]
    normal: Option<PathBuf>,
    /// Depth from its own files (file or directory, as --albedo)
    #[arg(long, value_name = "FILE|DIR", help_heading = "Input")]
    depth: Option<PathBuf>,
    /// World positions from their own files (file or directory, as --albedo)
    #[arg(long, value_name = "FILE|DIR", help_heading = "Input")]
    position: Option<PathBuf>,
    /// Motion vectors (pixels, previous = current + motion) from their own files (file or directory)
    #[arg(long, value_name = "FILE|DIR", help_heading = "Input")]
    motion: Option<PathBuf>,
    /// The second independent estimate (B.*) from its own files: their R,G,B (file or directory)
    #[arg(long, value_name = "FILE|DIR", help_heading = "Input")]
    second: Option<PathBuf>,
}

impl InputCli {
    fn selection(&self) -> mcdenoise::io::names::Selection {
        mcdenoise::io::names::Selection { part: self.part.clone(), layer: self.layer.clone() }
    }
    fn aux(&self) -> Vec<mcdenoise::pipeline::AuxInput> {
        use mcdenoise::io::frame::Buffer;
        [
            (Buffer::Albedo, &self.albedo),
            (Buffer::Normal, &self.normal),
            (Buffer::Depth, &self.depth),
            (Buffer::Position, &self.position),
            (Buffer::Motion, &self.motion),
            (Buffer::ColorB, &self.second),
        ]
        .into_iter()
        .filter_map(|(buffer, p)| p.clone().map(|path| mcdenoise::pipeline::AuxInput { buffer, path }))
        .collect()
    }
}

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("stop").args(["steps", "minutes"]).required(true).multiple(true)))]
struct TrainCli {
    /// The learned method
    #[arg(long, value_enum, default_value_t = TrainMethod::Wskp)]
    method: TrainMethod,
    /// Training sequences: directories of frames, each with its references in ref/
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// The weights file to write (safetensors)
    #[arg(short = 'o', long = "output", value_name = "WEIGHTS")]
    out: PathBuf,
    /// Train N steps in all (the learning-rate schedule's length; a resumed run counts the steps before it)
    #[arg(long, value_name = "N", value_parser = steps)]
    steps: Option<u64>,
    /// Stop after M minutes of this run (a checkpoint is written; --resume continues)
    #[arg(long, value_name = "M", value_parser = minutes)]
    minutes: Option<f64>,
    /// Validation sequences (mean PSNR printed every --val-every steps)
    #[arg(long, value_name = "DIR")]
    val: Option<PathBuf>,
    /// Steps between validations (0: only at the end)
    #[arg(long, value_name = "N", default_value = "500", value_parser = every)]
    val_every: u64,
    /// WSKP: ImportanceNet layers (3 or 6)
    #[arg(long, value_name = "N", default_value = "6", value_parser = layers)]
    layers: usize,
    /// WSKP: the window sizes, one importance map each (one size alone: no fusion); 1 adds the
    /// input itself, kept per pixel by a learned weight; the weights file records them and
    /// `denoise` reads them from it
    #[arg(long, value_name = "LIST", default_value = "3,5,7,9,11,13", value_parser = wskp_sizes)]
    sizes: mcdenoise::methods::wskp::Sizes,
    /// Crops per step
    #[arg(long, value_name = "N", default_value = "8", value_parser = batch)]
    batch: usize,
    /// Crop side in pixels
    #[arg(long, value_name = "N", default_value = "128", value_parser = crop)]
    crop: usize,
    /// Adam's learning rate
    #[arg(long, value_name = "F", default_value = "1e-3", value_parser = unit)]
    lr: f32,
    /// The loss (l1-log: L1 of sign(v) ln(1+|v|), robust to the fireflies of noisy targets and of
    /// the input; relmse-n2n: relMSE normalised by the output with its gradient stopped, unbiased
    /// for noisy targets such as 128-spp renders but lenient with fireflies left in the output)
    #[arg(long, value_enum, default_value_t = Loss::L1Log)]
    loss: Loss,
    /// Weight of a band term added to the loss: the L1 of the log-space error band-passed as the
    /// 5x5 minus the 17x17 box mean, which prices the low-frequency blotches a per-pixel loss
    /// barely sees (0: off)
    #[arg(long, value_name = "F", default_value = "0", value_parser = band_weight)]
    band_weight: f32,
    /// The learning rate's schedule over --steps (cosine: warm-up, then a cosine down to lr/100)
    #[arg(long, value_enum, default_value_t = mcdenoise::train::Schedule::Cosine)]
    lr_schedule: mcdenoise::train::Schedule,
    /// Independent estimates of a frame used as inputs of its target: 1 (R,G,B) or 2 (also B.* where
    /// the frames have it)
    #[arg(long, value_name = "N", default_value = "2", value_parser = estimates)]
    estimates: usize,
    /// Sample counts emulated by one more copy of each sequence, its noise divided by sqrt(n) (n
    /// cycles through the list; "off": none), so that the filters learn more than 1 spp's noise
    #[arg(long, value_name = "N,N,..", default_value = "4,16,64", value_parser = spp_list)]
    emulate_spp: SppList,
    /// The share of crops drawn from the sequences' first frames, where the accumulation has no
    /// history and the filters see the 1-spp frame itself (0: every frame alike)
    #[arg(long, value_name = "P", default_value = "0", value_parser = unit)]
    first_frames: f32,
    /// Make one frame in K of each sequence a sample (every frame still accumulated; the first
    /// frame kept turns with each copy of the sequence): the samples fill memory (AFN 58 bytes a
    /// pixel, WSKP 46), so a stride of 2 trains on twice the scenes in it
    #[arg(long, value_name = "K", default_value = "1", value_parser = frame_stride)]
    frame_stride: usize,
    /// Gradient norm clip (0: off)
    #[arg(long, value_name = "F", default_value = "0", value_parser = clip)]
    clip: f32,
    /// WSKP: penalise importance and fusion logits beyond +-F nats (0: off), which keeps the fused
    /// filter's windows within its fast paths as the network trains
    #[arg(long, value_name = "F", default_value = "30", value_parser = clip)]
    logit_bound: f32,
    /// The temporal accumulation's history clamp the inputs are made with, in standard deviations
    /// (0: off); recorded in the weights, which denoise with it
    #[arg(long, value_name = "K", default_value_t = mcdenoise::methods::TA_CLAMP, value_parser = firefly)]
    ta_clamp: f32,
    /// Seed of the initialisation and of the crop sampling
    #[arg(long, value_name = "N", default_value = "1", value_parser = seed)]
    seed: u64,
    /// Worker threads [default: every core]
    #[arg(long, value_name = "N", value_parser = threads)]
    threads: Option<usize>,
    /// Instruction set [default: the widest this CPU has]
    #[arg(long, value_enum, value_name = "ISA")]
    isa: Option<IsaArg>,
    /// Continue from a checkpoint (WEIGHTS.ckpt)
    #[arg(long, value_name = "CKPT")]
    resume: Option<PathBuf>,
    /// Start from trained weights of the same model (fine-tuning): a new run from step 0 with its own
    /// schedule and optimiser state; --resume, when given, takes precedence
    #[arg(long, value_name = "WEIGHTS")]
    init: Option<PathBuf>,
    /// Minutes between checkpoints
    #[arg(long, value_name = "F", default_value = "5", value_parser = minutes)]
    checkpoint_minutes: f64,
    /// A CSV of step, seconds, loss, learning rate, validation PSNR and gradient norm
    #[arg(long, value_name = "CSV")]
    log: Option<PathBuf>,
    /// AFN: which images the network filters (the single-input variants are the paper's ablation)
    #[arg(long, value_enum, default_value_t = Variant::Fusion)]
    variant: Variant,
}

#[derive(Debug, Args)]
struct InspectCli {
    /// The EXR file
    #[arg(value_name = "FILE")]
    file: PathBuf,
    /// The layer whose channels to read (see denoise --layer)
    #[arg(long, value_name = "NAME")]
    layer: Option<String>,
    /// The part that wins where parts share a channel name (see denoise --part)
    #[arg(long, value_name = "NAME")]
    part: Option<String>,
}

#[derive(Debug, Args)]
struct ScoreCli {
    /// The reference: a file, or a directory whose files match OUT's by name
    #[arg(short = 'r', long, value_name = "REF")]
    reference: PathBuf,
    /// The output: a file, or a directory of frames
    #[arg(value_name = "OUT")]
    output: PathBuf,
    /// Print one JSON object (per file and the mean)
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct PrecisionCli {
    /// Take the inputs from a rendered frame (tiled to the size) instead of synthetic ones
    #[arg(long, value_name = "FILE")]
    frame: Option<PathBuf>,
    /// Frame size
    #[arg(long, value_name = "WxH", default_value = "1280x720", value_parser = frame_size)]
    size: (usize, usize),
    /// Worker threads of the timed runs
    #[arg(long, value_name = "N", default_value = "1", value_parser = threads)]
    threads: usize,
    /// Only these operators (comma-separated)
    #[arg(long, value_name = "OP", value_delimiter = ',',
          value_parser = clap::builder::PossibleValuesParser::new(mcdenoise_kit::registry::names()))]
    only: Vec<String>,
    /// The CSV to write [default: mcdenoise-out/precision.csv; with --methods
    /// mcdenoise-out/precision-methods.csv]
    #[arg(long, value_name = "FILE")]
    csv: Option<PathBuf>,
    /// The SVG plot to write (per operator)
    #[arg(long, value_name = "FILE", default_value = "mcdenoise-out/precision.svg")]
    svg: PathBuf,
    /// Per method instead of per operator: run these methods (comma-separated) on --sequence in f32,
    /// f16 and fixed point, and report each one's ms/frame against PSNR with its Pareto front (the
    /// outputs in mcdenoise-out/precision/METHOD-PRECISION/, an earlier run's frames there removed)
    #[arg(long, value_name = "M", value_delimiter = ',', requires = "sequence",
          conflicts_with_all = ["frame", "only"],
          value_parser = clap::builder::PossibleValuesParser::new(crate::commands::REPORT_METHODS))]
    methods: Vec<String>,
    /// The frames of the per-method report (a directory of EXR frames)
    #[arg(long, value_name = "DIR", requires = "methods")]
    sequence: Option<PathBuf>,
    /// The references of --sequence's frames, by file name [default: SEQUENCE/ref]
    #[arg(long, value_name = "DIR", requires = "methods")]
    reference: Option<PathBuf>,
}

/// The whole command-line definition (for help, completions and the man page).
pub fn definition() -> clap::Command {
    Cli::command()
}

/// Writes the completion script for `shell` to `out`.
pub fn completions(shell: clap_complete::Shell, out: &mut dyn std::io::Write) {
    clap_complete::generate(shell, &mut definition(), "mcdenoise", out);
}

/// Writes the main man page to `out`, or with `dir` one page per command
/// into that directory.
pub fn man(dir: Option<&std::path::Path>, out: &mut dyn std::io::Write) -> Result<()> {
    let cmd = definition();
    match dir {
        None => clap_mangen::Man::new(cmd).render(out).map_err(|e| HostError::write(std::path::Path::new("-"), e)),
        Some(d) => {
            std::fs::create_dir_all(d).map_err(|e| HostError::write(d, e))?;
            clap_mangen::generate_to(cmd, d).map_err(|e| HostError::write(d, e))
        }
    }
}

// ---------------------------------------------------------------------------
// From clap's result to a Command or one line.

/// Parses the arguments after the program name.
pub fn parse(args: impl IntoIterator<Item = OsString>) -> Result<Command> {
    let args: Vec<OsString> = args.into_iter().collect();
    let cmd = definition();
    let matches = cmd.clone().try_get_matches_from(std::iter::once(OsString::from("mcdenoise")).chain(args.clone()));
    let cli = matches.and_then(|m| Cli::from_arg_matches(&m));
    let cli = match cli {
        Ok(c) => c,
        Err(e) => return from_error(&cmd, &args, e),
    };
    Ok(match cli.command {
        None => Command::Demo { settings: Settings { threads: default_threads(), ..Settings::default() } },
        Some(Sub::Demo(d)) => Command::Demo { settings: d.settings.settings() },
        Some(Sub::Denoise(d)) => {
            let mut settings = d.settings.settings();
            settings.refine = !d.no_refine;
            settings.fallback = !d.no_fallback;
            settings.wide = !d.no_wide_pass;
            let half = if d.half {
                Some(true)
            } else if d.float {
                Some(false)
            } else {
                None
            };
            let sequence = mcdenoise::pipeline::SequenceOptions {
                write: mcdenoise::io::output::WriteOptions {
                    half,
                    compression: d.compression,
                    keep_channels: d.keep_channels,
                },
                png: d.png,
                max_memory: d.max_memory,
                quiet: d.quiet || d.json,
                selection: d.input.selection(),
                aux: d.input.aux(),
                pipeline: if d.no_pipeline { Some(false) } else { None },
            };
            Command::Denoise(DenoiseArgs {
                method: d.method,
                settings,
                inputs: d.inputs,
                outdir: d.outdir,
                sequence,
                timings: d.timings,
                quiet: d.quiet,
                json: d.json,
            })
        }
        Some(Sub::Train(t)) => {
            let mut a = mcdenoise::train::TrainArgs { threads: default_threads(), ..Default::default() };
            a.method = match t.method {
                TrainMethod::Wskp => "wskp".into(),
                TrainMethod::Afn => "afn".into(),
            };
            a.data = t.data;
            a.out = t.out;
            a.steps = t.steps;
            a.minutes = t.minutes;
            a.val = t.val;
            a.val_every = t.val_every;
            a.layers = t.layers;
            a.batch = t.batch;
            a.crop = t.crop;
            a.lr = t.lr;
            a.loss = t.loss;
            a.band = t.band_weight;
            a.clip = t.clip;
            a.logit_bound = t.logit_bound;
            a.ta_clamp = t.ta_clamp;
            a.seed = t.seed;
            if let Some(n) = t.threads {
                a.threads = n;
            }
            if let Some(i) = t.isa {
                a.isa = i.isa();
            }
            a.resume = t.resume;
            a.init = t.init;
            a.checkpoint_minutes = t.checkpoint_minutes;
            a.log = t.log;
            a.variant = t.variant;
            a.sizes = t.sizes;
            a.estimates = t.estimates;
            a.emulate_spp = t.emulate_spp.0;
            a.first_frames = t.first_frames;
            a.frame_stride = t.frame_stride;
            a.schedule = t.lr_schedule;
            Command::Train(a)
        }
        Some(Sub::Score(s)) => Command::Score { reference: s.reference, output: s.output, json: s.json },
        Some(Sub::Inspect(i)) => Command::Inspect {
            file: i.file,
            selection: mcdenoise::io::names::Selection { part: i.part, layer: i.layer },
        },
        Some(Sub::Precision(p)) if !p.methods.is_empty() => Command::PrecisionMethods {
            methods: p.methods,
            sequence: p.sequence.expect("clap requires --sequence with --methods"),
            reference: p.reference,
            threads: p.threads,
            csv: p.csv.unwrap_or_else(|| PathBuf::from("mcdenoise-out/precision-methods.csv")),
        },
        Some(Sub::Precision(p)) => Command::Precision(mcdenoise_kit::report::ReportArgs {
            frame: p.frame,
            csv: p.csv.unwrap_or_else(|| PathBuf::from("mcdenoise-out/precision.csv")),
            svg: p.svg,
            threads: p.threads,
            width: p.size.0,
            height: p.size.1,
            only: p.only,
        }),
        Some(Sub::Completions { shell }) => Command::Completions(shell),
        Some(Sub::Man { dir }) => Command::Man { dir },
    })
}

fn context_strings(e: &clap::Error, kind: ContextKind) -> Vec<String> {
    match e.get(kind) {
        Some(ContextValue::String(s)) => vec![s.clone()],
        Some(ContextValue::Strings(v)) => v.clone(),
        Some(ContextValue::StyledStr(s)) => vec![s.to_string()],
        Some(ContextValue::StyledStrs(v)) => v.iter().map(|s| s.to_string()).collect(),
        _ => Vec::new(),
    }
}

fn context_string(e: &clap::Error, kind: ContextKind) -> Option<String> {
    context_strings(e, kind).into_iter().next()
}

/// `--threads <N>` -> `--threads`; `<INPUT>...` -> `INPUT`.
fn flag_name(rendered: &str) -> String {
    let first = rendered.split_whitespace().next().unwrap_or(rendered);
    first.trim_start_matches('<').trim_end_matches("...").trim_end_matches('>').to_string()
}

/// `a`, `a or b`, `one of a, b, c;`.
fn alternatives(values: &[String]) -> String {
    match values {
        [one] => one.clone(),
        [a, b] => format!("{a} or {b}"),
        _ => format!("one of {};", values.join(", ")),
    }
}

/// An argument of `sub` (or of the top level) by its rendering in an error.
fn find_arg<'a>(cmd: &'a clap::Command, sub: Option<&str>, rendered: &str) -> Option<&'a clap::Arg> {
    let c = match sub {
        Some(s) => cmd.find_subcommand(s)?,
        None => cmd,
    };
    let name = flag_name(rendered);
    c.get_arguments().find(|a| match name.strip_prefix("--") {
        Some(long) => a.get_long() == Some(long),
        None => a.get_value_names().is_some_and(|v| v.iter().any(|v| v.as_str() == name)),
    })
}

/// A missing argument for people: `-o OUTDIR`, `--method METHOD (one of ...)`.
fn missing(cmd: &clap::Command, sub: Option<&str>, rendered: &str) -> String {
    // A required group renders as `<--steps <N>|--minutes <M>>`.
    let plain = |s: &str| s.replace(['<', '>'], "").replace("...", "");
    if rendered.contains('|') {
        let parts: Vec<String> = plain(rendered).split('|').map(|p| p.trim().to_string()).collect();
        return format!("give {}", parts.join(" or "));
    }
    let mut text = plain(rendered);
    let arg = find_arg(cmd, sub, rendered);
    if let (Some(a), Some(long)) = (arg, flag_name(rendered).strip_prefix("--")) {
        if let Some(short) = a.get_short() {
            text = text.replacen(&format!("--{long}"), &format!("-{short}"), 1);
        }
    }
    let values: Vec<String> = arg
        .map(|a| {
            a.get_possible_values().iter().filter(|v| !v.is_hide_set()).map(|v| v.get_name().to_string()).collect()
        })
        .unwrap_or_default();
    if values.is_empty() {
        format!("{text} is required")
    } else {
        format!("{text} is required ({})", values.join(", "))
    }
}

/// Turns a clap error into `Command::Help` or `Command::Version` (`--help`,
/// `--version`) or one usage line naming the command, the flag and the value.
fn from_error(cmd: &clap::Command, args: &[OsString], e: clap::Error) -> Result<Command> {
    let sub = args.first().and_then(|a| a.to_str()).filter(|s| cmd.find_subcommand(s).is_some());
    let at = sub.map(|s| format!("{s} ")).unwrap_or_default();
    let within = sub.map(|s| format!("{s}: ")).unwrap_or_default();
    let arg = context_string(&e, ContextKind::InvalidArg);
    let flag = arg.as_deref().map(flag_name).unwrap_or_default();
    let value = context_string(&e, ContextKind::InvalidValue).unwrap_or_default();
    let suggestion =
        |kind: ContextKind| context_string(&e, kind).map(|s| format!(" (did you mean '{s}'?)")).unwrap_or_default();
    let line = match e.kind() {
        ErrorKind::DisplayHelp | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            return Ok(Command::Help(e.render().to_string()))
        }
        // `mcdenoise denoise --version` too names the program, not `mcdenoise-denoise`.
        ErrorKind::DisplayVersion => return Ok(Command::Version(format!("mcdenoise {}\n", env!("CARGO_PKG_VERSION")))),
        ErrorKind::ValueValidation => {
            let why =
                std::error::Error::source(&e).map(|s| s.to_string()).unwrap_or_else(|| format!("bad value '{value}'"));
            format!("{at}{flag}: {why}")
        }
        ErrorKind::InvalidValue if value.is_empty() => format!("{at}{flag}: expects a value"),
        ErrorKind::InvalidValue => {
            let valid = context_strings(&e, ContextKind::ValidValue);
            let list = alternatives(&valid);
            let sep = if list.ends_with(';') { "" } else { "," };
            format!("{at}{flag}: expected {list}{sep} got '{value}'{}", suggestion(ContextKind::SuggestedValue))
        }
        ErrorKind::UnknownArgument => {
            let what = if arg.as_deref().is_some_and(|a| a.starts_with('-')) {
                "unknown option"
            } else {
                "unexpected argument"
            };
            format!("{within}{what} '{}'{}", arg.unwrap_or_default(), suggestion(ContextKind::SuggestedArg))
        }
        ErrorKind::InvalidSubcommand => format!(
            "unknown command '{}'{}; try 'mcdenoise help'",
            context_string(&e, ContextKind::InvalidSubcommand).unwrap_or_default(),
            suggestion(ContextKind::SuggestedSubcommand)
        ),
        ErrorKind::MissingRequiredArgument => {
            let first = context_strings(&e, ContextKind::InvalidArg).into_iter().next().unwrap_or_default();
            format!("{within}{}", missing(cmd, sub, &first))
        }
        ErrorKind::ArgumentConflict => format!(
            "{within}{} cannot be used with {}",
            arg.unwrap_or_default(),
            context_string(&e, ContextKind::PriorArg).unwrap_or_default()
        ),
        ErrorKind::InvalidUtf8 => format!("{within}an argument is not valid UTF-8"),
        _ => {
            let text = e.render().to_string();
            let first = text.lines().next().unwrap_or("bad arguments");
            format!("{within}{}", first.trim_start_matches("error: "))
        }
    };
    Err(HostError::Usage(line))
}

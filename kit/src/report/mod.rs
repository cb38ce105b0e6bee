//! `mcdenoise precision`: the speed/accuracy trade of every core operator in
//! every precision and instruction set, measured.
//!
//! For each operator of the [registry] x precision x ISA:
//! the median wall time of the operator at the frame size (1280x720 by
//! default), and its error against the f64 oracle evaluated on the same f32
//! inputs (so the error includes the cost of storing the inputs in the
//! precision): maximum absolute error, mean relative error (`sum |x - r| /
//! sum |r|`) and PSNR (`peak = max |r|`). Inputs are synthetic, or built from
//! a rendered frame (`--frame FILE`, tiled to the size): its radiance,
//! albedo, normals and positions. Writes a CSV and an SVG with one panel per
//! operator (time against error, log-log, Pareto front drawn).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use mcdenoise_core::Isa;

use crate::registry::{self, Config, Inputs, Layout};
use mcdenoise::error::{HostError, Result};
use mcdenoise::io::frame::{Frame, Limits};
use mcdenoise::runtime::par::Pool;

mod plot;

/// Options of the report.
#[derive(Clone, Debug, PartialEq)]
pub struct ReportArgs {
    /// A rendered frame to take inputs from.
    pub frame: Option<PathBuf>,
    /// CSV output.
    pub csv: PathBuf,
    /// SVG output.
    pub svg: PathBuf,
    /// Worker threads for the timed runs.
    pub threads: usize,
    /// Frame size.
    pub width: usize,
    /// Frame size.
    pub height: usize,
    /// Only these operators (all when empty).
    pub only: Vec<String>,
}

/// One measurement.
#[derive(Clone, Debug)]
pub struct Row {
    /// Operator.
    pub op: &'static str,
    /// Precision name.
    pub precision: &'static str,
    /// ISA name.
    pub isa: &'static str,
    /// Median milliseconds per frame.
    pub ms: f64,
    /// Largest absolute error.
    pub max_abs: f64,
    /// `sum |x - r| / sum |r|`.
    pub mean_rel: f64,
    /// `10 log10(max |r|^2 / MSE)`.
    pub psnr: f64,
}

/// Runs a prepared operator until about a second has passed (at most seven
/// times, at least twice when that takes under two seconds); the median time.
fn time(run: &mut dyn registry::Prepared, pool: &Pool) -> Result<Duration> {
    let start = Instant::now();
    let mut times = Vec::new();
    loop {
        let t = Instant::now();
        run.run(pool)?;
        times.push(t.elapsed());
        if times.len() >= 7
            || (times.len() >= 2 && start.elapsed() > Duration::from_secs(2))
            || start.elapsed() > Duration::from_secs(1)
        {
            break;
        }
    }
    times.sort();
    Ok(times[times.len() / 2])
}

/// Measures every operator, precision and ISA.
pub fn run(args: &ReportArgs) -> Result<Vec<Row>> {
    let frame = match &args.frame {
        Some(p) => Some(Frame::load(p, &Limits::default())?),
        None => None,
    };
    let inputs = match &frame {
        Some(f) => Inputs::from_frame(args.width, args.height, f),
        None => Inputs::synth(args.width, args.height, 0),
    };
    let pool = Pool::new(args.threads).map_err(HostError::Usage)?;
    let isas: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.is_supported()).collect();
    let mut rows = Vec::new();
    for op in registry::ops() {
        if !args.only.is_empty() && !args.only.iter().any(|o| o == op.name) {
            continue;
        }
        eprintln!("{}: f64 oracle ...", op.name);
        let want = (op.oracle)(&inputs, &pool);
        let out_frac = op.fixed_frac(&want);
        for &prec in op.precisions {
            for &isa in &isas {
                let cfg = Config { isa, layout: Layout::default(), out_frac };
                let mut job = op.prepare(prec, cfg, &inputs)?;
                let t = time(job.as_mut(), &pool)?;
                let e = registry::errors(&job.output(), &want, op.tolerance(prec));
                let row = Row {
                    op: op.name,
                    precision: prec.name(),
                    isa: isa.name(),
                    ms: t.as_secs_f64() * 1e3,
                    max_abs: e.max_abs,
                    mean_rel: e.mean_rel,
                    psnr: e.psnr,
                };
                println!(
                    "{:<13} {:<9} {:<6} {:>9.3} ms {:>8.3} ms/Mpx  max|err| {:>10.3e}  mean rel {:>9.2e}  PSNR {:>6.1} dB",
                    row.op,
                    row.precision,
                    row.isa,
                    row.ms,
                    row.ms / (args.width * args.height) as f64 * 1e6,
                    row.max_abs,
                    row.mean_rel,
                    row.psnr
                );
                rows.push(row);
            }
        }
    }
    plot::write_csv(&args.csv, &rows, args)?;
    plot::write_svg(&args.svg, &rows, args)?;
    eprintln!("wrote {} and {}", args.csv.display(), args.svg.display());
    Ok(rows)
}

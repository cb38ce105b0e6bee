//! `mcdenoise precision`: the speed/accuracy trade of every core operator in
//! every precision and instruction set, measured.
//!
//! For each operator x precision x ISA: the median wall time of the operator
//! at the frame size (1280x720 by default), and its error against the f64
//! oracle evaluated on the same f32 inputs (so the error includes the cost of
//! storing the inputs in the precision): maximum absolute error, mean
//! relative error (`sum |x - r| / sum |r|`) and PSNR (`peak = max |r|`).
//! Inputs are synthetic, or built from a rendered frame (`--frame FILE`,
//! tiled to the size): its radiance, albedo, normals and positions. Writes a
//! CSV and an SVG with one panel per operator (time against error, log-log,
//! Pareto front drawn).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mcdenoise_core::atrous::{self, AtrousGuides, AtrousParams};
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::pool::{self, Reduce};
use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::tonemap::{self, Map};
use mcdenoise_core::{fixed, unfold, F16Arith, Fixed, Isa, F16, F32};

use crate::error::{HostError, Result};
use crate::frame::{Buffer, Frame, Limits};
use crate::oracle;
use crate::output::atomic_write;
use crate::par::{Pool, Scratch};
use crate::precision::{frac_for_max, HostPrecision, Kind, Planes, PrecisionKind};

/// The operators measured.
pub const OPS: [&str; 15] = [
    "apply7x7",
    "window7",
    "fused6",
    "fused6-sep",
    "kernels7",
    "softmax6",
    "avgpool",
    "upsample",
    "composite",
    "conv3x3",
    "conv5x5",
    "demodulate",
    "gamma",
    "temporal",
    "atrous",
];

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

/// The inputs every operator draws from (f32, planar).
struct Inputs {
    w: usize,
    h: usize,
    rad: Vec<f32>,
    alb: Vec<f32>,
    normal: Vec<f32>,
    pos: Vec<f32>,
    kern: Vec<f32>,
    logits: Vec<f32>,
    fus: Vec<f32>,
    conv_in: Vec<f32>,
    w3: Vec<f32>,
    w5: Vec<f32>,
    bias: Vec<f32>,
    coarse: Vec<f32>,
    alpha: Vec<f32>,
    motion: Vec<f32>,
    prev: Vec<f32>,
    hist: Vec<f32>,
    noise: Vec<f32>,
}

fn rng(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Smooth-ish random field in [lo, hi): a coarse grid bilinearly interpolated
/// plus fine noise (logits and kernels of a trained net are not white noise).
fn field(c: usize, w: usize, h: usize, lo: f32, hi: f32, seed: u64) -> Vec<f32> {
    let mut r = rng(seed);
    let (gw, gh) = (w / 16 + 2, h / 16 + 2);
    let mut out = vec![0.0; c * w * h];
    for ch in 0..c {
        let g: Vec<f32> = (0..gw * gh).map(|_| r()).collect();
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 / 16.0, y as f32 / 16.0);
                let (x0, y0) = (fx as usize, fy as usize);
                let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                let v = g[y0 * gw + x0] * (1.0 - tx) * (1.0 - ty)
                    + g[y0 * gw + x0 + 1] * tx * (1.0 - ty)
                    + g[(y0 + 1) * gw + x0] * (1.0 - tx) * ty
                    + g[(y0 + 1) * gw + x0 + 1] * tx * ty;
                out[ch * w * h + y * w + x] = lo + (hi - lo) * (0.8 * v + 0.2 * r());
            }
        }
    }
    out
}

fn tile(f: &Frame, b: Buffer, w: usize, h: usize) -> Option<Vec<f32>> {
    let d = f.get(b)?;
    let (sw, sh) = (f.width, f.height);
    let ch = b.channels();
    let mut out = vec![0.0; ch * w * h];
    for c in 0..ch {
        for y in 0..h {
            for x in 0..w {
                out[c * w * h + y * w + x] = d[c * sw * sh + (y % sh) * sw + (x % sw)];
            }
        }
    }
    Some(out)
}

impl Inputs {
    fn new(w: usize, h: usize, frame: Option<&Frame>) -> Inputs {
        let n = w * h;
        let from = |b: Buffer| frame.and_then(|f| tile(f, b, w, h));
        let rad = from(Buffer::Color).unwrap_or_else(|| field(3, w, h, 0.0, 4.0, 1));
        let alb = from(Buffer::Albedo).unwrap_or_else(|| field(3, w, h, 0.05, 1.0, 2));
        let normal = from(Buffer::Normal).unwrap_or_else(|| {
            let mut v = field(3, w, h, -0.3, 0.3, 3);
            v[2 * n..].iter_mut().for_each(|z| *z += 0.9);
            v
        });
        let pos = from(Buffer::Position).unwrap_or_else(|| field(3, w, h, -1.0, 1.0, 4));
        let mut kern = field(49, w, h, 0.0, 1.0, 5);
        for p in 0..n {
            let s: f32 = (0..49).map(|j| kern[j * n + p]).sum();
            (0..49).for_each(|j| kern[j * n + p] /= s);
        }
        let (wc, hc) = (w.div_ceil(2), h.div_ceil(2));
        Inputs {
            w,
            h,
            conv_in: field(14, w, h, -1.0, 1.0, 6),
            w3: field(14 * 14 * 9, 1, 1, -0.08, 0.08, 7),
            w5: field(14 * 14 * 25, 1, 1, -0.03, 0.03, 8),
            bias: field(14, 1, 1, -0.1, 0.1, 9),
            logits: field(6, w, h, -8.0, 8.0, 10),
            fus: field(6, w, h, -3.0, 3.0, 11),
            coarse: field(3, wc, hc, 0.0, 4.0, 12),
            alpha: field(1, w, h, 0.0, 1.0, 13),
            motion: field(2, w, h, -3.0, 3.0, 14),
            prev: field(3, w, h, 0.0, 4.0, 15),
            hist: field(1, w, h, 0.0, 8.0, 16),
            noise: field(1, w, h, 0.001, 0.02, 17),
            rad,
            alb,
            normal,
            pos,
            kern,
        }
    }
}

/// The operator's f64 oracle on the f32 inputs.
fn oracle_of(op: &str, i: &Inputs, pool: &Pool) -> Vec<f64> {
    let d = |v: &[f32]| -> Vec<f64> { v.iter().map(|&x| x as f64).collect() };
    let (w, h) = (i.w, i.h);
    match op {
        "apply7x7" => oracle::unfold(7, &d(&i.kern), &d(&i.rad), 3, w, h),
        "window7" => oracle::fused_pixelwise(&[7], &d(&i.logits[..w * h]), None, None, &d(&i.rad), 3, w, h),
        "fused6" | "fused6-sep" => oracle::fused_pixelwise(
            &[3, 5, 7, 9, 11, 13],
            &d(&i.logits),
            Some(&d(&i.fus)),
            Some(&d(&i.alb)),
            &d(&i.rad),
            3,
            w,
            h,
        ),
        "kernels7" => oracle::importance_kernels(7, &d(&i.logits[..w * h]), w, h),
        "softmax6" => oracle::channel_softmax(&d(&i.fus), 6, w, h),
        "avgpool" => oracle::reduce2x2(&d(&i.rad), 3, w, h, false),
        "upsample" => oracle::upsample(&d(&i.coarse), 3, w, h),
        "composite" => oracle::composite(&d(&i.rad), &d(&i.coarse), &d(&i.alpha), 3, w, h),
        "conv3x3" | "conv5x5" => {
            let (k, wts) = if op == "conv3x3" { (3, &i.w3) } else { (5, &i.w5) };
            let per = 14 * k * k;
            let (x, b) = (d(&i.conv_in), d(&i.bias));
            // One output channel per task: the oracle is the slow part of the report.
            let chans: Vec<Vec<f64>> = pool.map(14, |co| {
                oracle::conv2d(k, 14, 1, &d(&wts[co * per..(co + 1) * per]), Some(&b[co..co + 1]), Some(0.1), &x, w, h)
            });
            chans.concat()
        }
        "demodulate" => i.rad.iter().zip(&i.alb).map(|(&r, &a)| r as f64 / (a as f64 + 1e-3f32 as f64)).collect(),
        "gamma" => i.rad.iter().map(|&r| (r as f64).clamp(0.0, 1.0).powf(1.0 / 2.2)).collect(),
        "temporal" => oracle::temporal_motion(&d(&i.rad), &d(&i.motion), &d(&i.prev), &d(&i.hist), 0.2, 3, w, h),
        "atrous" => {
            let p = AtrousParams::default();
            let g = oracle::AtrousGuides {
                noise: &d(&i.noise),
                normal: Some(&d(&i.normal)),
                position: Some(&d(&i.pos)),
                depth: None,
            };
            let sp = 0.05;
            oracle::atrous_step(
                1,
                1,
                false,
                p.phi_color as f64,
                p.sigma_normal as f64,
                sp,
                p.sigma_depth as f64,
                p.eps as f64,
                &g,
                &d(&i.rad),
                w,
                h,
            )
        }
        _ => unreachable!("unknown operator"),
    }
}

/// Output planes and fixed format of each operator.
fn out_shape(op: &str, i: &Inputs) -> (usize, usize, usize) {
    let (w, h) = (i.w, i.h);
    match op {
        "kernels7" => (49, w, h),
        "softmax6" => (6, w, h),
        "avgpool" => (3, w.div_ceil(2), h.div_ceil(2)),
        "conv3x3" | "conv5x5" => (14, w, h),
        _ => (3, w, h),
    }
}

/// Stores f32 values in `P` with an explicit format.
fn stored<P: HostPrecision>(c: usize, w: usize, h: usize, v: &[f32], frac: i8) -> Planes<P::Store> {
    let mut p = Planes::<P::Store>::new(c, w, h).with_frac(frac);
    P::encode(v, &mut p.data, frac);
    p
}

/// Runs `op` in precision `P` on `isa`; returns the decoded output and the
/// median time. `out_frac` is the fixed-point output format (calibrated on
/// the oracle's output range).
fn measure<P: HostPrecision>(
    op: &str,
    isa: Isa,
    i: &Inputs,
    pool: &Pool,
    out_frac: i8,
) -> Result<(Vec<f32>, Duration)> {
    let (w, h) = (i.w, i.h);
    let img = |c: usize, v: &[f32]| Planes::<P::Store>::encode_as::<P>(c, w, h, v, Kind::Image);
    let unit = |c: usize, v: &[f32]| Planes::<P::Store>::encode_as::<P>(c, w, h, v, Kind::Unit);
    let plain = |c: usize, v: &[f32]| Planes::<P::Store>::encode_as::<P>(c, w, h, v, Kind::Plain);
    let lfrac = if P::NAME == "fixed" { fixed::LOGIT_FRAC } else { 0 };
    let (oc, ow, oh) = out_shape(op, i);
    let mut out = Planes::<P::Store>::new(oc, ow, oh).with_frac(out_frac);
    let mut scratch = Scratch::new();
    // Inputs stored once, outside the timing.
    let rad = img(3, &i.rad);
    let mut times = Vec::new();
    let start = Instant::now();
    let reps_cap = 7;
    let run = |out: &mut Planes<P::Store>, scratch: &mut Scratch| -> Result<Duration> {
        let dst = out.view_mut();
        let r = match op {
            "apply7x7" => {
                let k = unit(49, &i.kern);
                let len = unfold::scratch_len::<P>(7, 3, w);
                let (kv, rv) = (k.view(), rad.view());
                let t = Instant::now();
                pool.bands(dst, 1, scratch, len, |b, y0, s| unfold::apply_rows::<P>(isa, 7, &kv, &rv, b, y0, s))?;
                Ok::<Duration, HostError>(t.elapsed())
            }
            "window7" | "fused6" | "fused6-sep" => {
                // fused6-sep: the same filter through the separable window sums.
                let path = if op == "fused6-sep" { WindowPath::Separable } else { WindowPath::BoxSum };
                let sizes: &[usize] = if op == "window7" { &[7] } else { &[3, 5, 7, 9, 11, 13] };
                let m = sizes.len();
                let imp = stored::<P>(m, w, h, &i.logits[..m * w * h], lfrac);
                let fus = stored::<P>(m, w, h, &i.fus[..m * w * h], lfrac);
                let alb = unit(3, &i.alb);
                let inp = FusedInputs {
                    sizes,
                    importance: imp.view(),
                    fusion: (m > 1).then(|| fus.view()),
                    albedo: (m > 1).then(|| alb.view()),
                    radiance: rad.view(),
                };
                let len = softmax::fused_scratch_len::<P>(path, sizes, 3, w);
                let t = Instant::now();
                pool.bands(dst, 48, scratch, len, |b, y0, s| softmax::fused_filter::<P>(isa, path, &inp, b, y0, s))?;
                Ok(t.elapsed())
            }
            "kernels7" => {
                let lg = stored::<P>(1, w, h, &i.logits[..w * h], lfrac);
                let lv = lg.view();
                let t = Instant::now();
                pool.bands(dst, 1, scratch, 0, |b, y0, _| softmax::importance_kernels::<P>(isa, 7, &lv, b, y0))?;
                Ok(t.elapsed())
            }
            "softmax6" => {
                let f = stored::<P>(6, w, h, &i.fus, lfrac);
                let t = Instant::now();
                let mut d = dst;
                softmax::channel_softmax::<P>(isa, &f.view(), &mut d)?;
                Ok(t.elapsed())
            }
            "avgpool" => {
                let rv = rad.view();
                let t = Instant::now();
                pool.bands(dst, 1, scratch, 0, |b, y0, _| pool::reduce2x2::<P>(isa, Reduce::Mean, &rv, b, y0))?;
                Ok(t.elapsed())
            }
            "upsample" => {
                let c = Planes::<P::Store>::encode_as::<P>(3, w.div_ceil(2), h.div_ceil(2), &i.coarse, Kind::Image);
                let cv = c.view();
                let t = Instant::now();
                pool.bands(dst, 2, scratch, 0, |b, y0, _| pool::upsample_nearest2x::<P>(isa, &cv, b, y0, h))?;
                Ok(t.elapsed())
            }
            "composite" => {
                let c = Planes::<P::Store>::encode_as::<P>(3, w.div_ceil(2), h.div_ceil(2), &i.coarse, Kind::Image);
                let a = unit(1, &i.alpha);
                let (rv, cv, av) = (rad.view(), c.view(), a.view());
                let t = Instant::now();
                pool.bands(dst, 2, scratch, 0, |b, y0, _| pool::composite::<P>(isa, &rv, &cv, &av, b, y0))?;
                Ok(t.elapsed())
            }
            "conv3x3" | "conv5x5" => {
                let (k, wts) = if op == "conv3x3" { (3, &i.w3) } else { (5, &i.w5) };
                let x = img(14, &i.conv_in);
                // Weight format: as many fractional bits as the fixed bit budget allows.
                let per = 14 * k * k;
                let maxsum = (0..14)
                    .map(|co| wts[co * per..(co + 1) * per].iter().map(|v| v.abs()).sum::<f32>())
                    .fold(0.0, f32::max);
                let wfrac = if P::NAME == "fixed" {
                    ((65535.0 / maxsum.max(1e-6)).log2().floor() as i32).clamp(0, 14) as i8
                } else {
                    0
                };
                let mut ws = vec![<P::Store>::default(); wts.len()];
                P::encode(wts, &mut ws, wfrac);
                let mut bs = vec![<P::Store>::default(); 14];
                P::encode(&i.bias, &mut bs, out_frac);
                let layer = Conv2d {
                    k,
                    cin: 14,
                    cout: 14,
                    weights: &ws,
                    bias: Some(&bs),
                    act: Activation::LeakyRelu(0.1),
                    weight_frac: wfrac,
                };
                let len = conv::conv2d_scratch_len::<P>(k, 14, 14, w);
                let xv = x.view();
                let t = Instant::now();
                pool.bands(dst, 1, scratch, len, |b, y0, s| conv::conv2d::<P>(isa, &layer, &xv, b, y0, s))?;
                Ok(t.elapsed())
            }
            "demodulate" => {
                let a = unit(3, &i.alb);
                let t = Instant::now();
                let mut d = dst;
                tonemap::demodulate::<P>(isa, &rad.view(), &a.view(), 1e-3, &mut d)?;
                Ok(t.elapsed())
            }
            "gamma" => {
                let t = Instant::now();
                let mut d = dst;
                tonemap::map::<P>(isa, Map::Gamma { gamma: 2.2, clamp: true }, &rad.view(), &mut d)?;
                Ok(t.elapsed())
            }
            "temporal" => {
                let m = plain(2, &i.motion);
                let prev = img(3, &i.prev);
                let hist = plain(1, &i.hist);
                let inp = TemporalInputs {
                    color: rad.view(),
                    normal: None,
                    position: None,
                    motion: Some(m.view()),
                    prev_color: prev.view(),
                    prev_normal: None,
                    prev_position: None,
                    prev_history: hist.view(),
                };
                let mut hout = Planes::<P::Store>::new(1, w, h).with_frac(8);
                let params = TemporalParams { history_cap: 1e6, ..TemporalParams::default() };
                let t = Instant::now();
                pool.bands2(dst, hout.view_mut(), 1, scratch, 0, |b, hb, y0, _| {
                    temporal::accumulate::<P>(isa, &inp, &params, b, hb, y0)
                })?;
                Ok(t.elapsed())
            }
            "atrous" => {
                let (noise, normal, pos) = (plain(1, &i.noise), unit(3, &i.normal), plain(3, &i.pos));
                let g = AtrousGuides {
                    noise: noise.view(),
                    normal: Some(normal.view()),
                    position: Some(pos.view()),
                    depth: None,
                };
                let params = AtrousParams { sigma_plane: 0.05, ..AtrousParams::default() };
                let rv = rad.view();
                let t = Instant::now();
                pool.bands(dst, 1, scratch, atrous::step_scratch_len::<P>(1), |b, y0, s| {
                    atrous::step::<P>(isa, 1, 1, false, &params, &g, &rv, b, y0, s)
                })?;
                Ok(t.elapsed())
            }
            _ => unreachable!("unknown operator"),
        };
        r
    };
    loop {
        times.push(run(&mut out, &mut scratch)?);
        if times.len() >= reps_cap
            || (times.len() >= 2 && start.elapsed() > Duration::from_secs(2))
            || start.elapsed() > Duration::from_secs(1)
        {
            break;
        }
    }
    times.sort();
    let median = times[times.len() / 2];
    Ok((out.decode::<P>(), median))
}

fn errors(x: &[f32], r: &[f64]) -> (f64, f64, f64) {
    let (mut max_abs, mut sum_abs, mut sum_ref, mut se, mut peak) = (0.0f64, 0.0, 0.0, 0.0, 0.0f64);
    for (&a, &b) in x.iter().zip(r) {
        let e = (a as f64 - b).abs();
        max_abs = max_abs.max(e);
        sum_abs += e;
        sum_ref += b.abs();
        se += e * e;
        peak = peak.max(b.abs());
    }
    let mse = se / r.len().max(1) as f64;
    let psnr = if mse == 0.0 { f64::INFINITY } else { 10.0 * (peak * peak / mse).log10() };
    (max_abs, sum_abs / sum_ref.max(1e-300), psnr)
}

/// Measures every operator, precision and ISA.
pub fn run(args: &ReportArgs) -> Result<Vec<Row>> {
    let frame = match &args.frame {
        Some(p) => Some(Frame::load(p, &Limits::default())?),
        None => None,
    };
    let inputs = Inputs::new(args.width, args.height, frame.as_ref());
    let pool = Pool::new(args.threads).map_err(HostError::Usage)?;
    let isas: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.is_supported()).collect();
    let mut rows = Vec::new();
    for op in OPS {
        if !args.only.is_empty() && !args.only.iter().any(|o| o == op) {
            continue;
        }
        eprintln!("{op}: f64 oracle ...");
        let want = oracle_of(op, &inputs, &pool);
        // Fixed-point output format calibrated on the reference output's range.
        let peak = want.iter().fold(0.0f64, |m, v| m.max(v.abs())) as f32;
        let out_frac = match op {
            "kernels7" | "softmax6" | "gamma" => fixed::KERNEL_FRAC,
            _ => frac_for_max(peak / 2.0),
        };
        for prec in PrecisionKind::ALL {
            for &isa in &isas {
                let (got, t) = match prec {
                    PrecisionKind::F32 => measure::<F32>(op, isa, &inputs, &pool, out_frac)?,
                    PrecisionKind::F16 => measure::<F16>(op, isa, &inputs, &pool, out_frac)?,
                    PrecisionKind::F16Arith => measure::<F16Arith>(op, isa, &inputs, &pool, out_frac)?,
                    PrecisionKind::Fixed => measure::<Fixed>(op, isa, &inputs, &pool, out_frac)?,
                };
                let (max_abs, mean_rel, psnr) = errors(&got, &want);
                let row = Row {
                    op,
                    precision: prec.name(),
                    isa: isa.name(),
                    ms: t.as_secs_f64() * 1e3,
                    max_abs,
                    mean_rel,
                    psnr,
                };
                println!(
                    "{:<11} {:<9} {:<6} {:>9.3} ms {:>8.3} ms/Mpx  max|err| {:>10.3e}  mean rel {:>9.2e}  PSNR {:>6.1} dB",
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
    write_csv(&args.csv, &rows, args)?;
    write_svg(&args.svg, &rows, args)?;
    eprintln!("wrote {} and {}", args.csv.display(), args.svg.display());
    Ok(rows)
}

fn write_csv(path: &Path, rows: &[Row], a: &ReportArgs) -> Result<()> {
    let mut s = String::from("op,precision,isa,width,height,threads,ms,ms_per_mpx,max_abs,mean_rel,psnr_db\n");
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{:.4},{:.4},{:.6e},{:.6e},{:.3}",
            r.op,
            r.precision,
            r.isa,
            a.width,
            a.height,
            a.threads,
            r.ms,
            r.ms / (a.width * a.height) as f64 * 1e6,
            r.max_abs,
            r.mean_rel,
            r.psnr
        );
    }
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(|e| HostError::write(d, e))?;
    }
    atomic_write(path, |tmp| std::fs::write(tmp, s.as_bytes()).map_err(|e| e.to_string()))
}

/// Colour of a precision in the plot.
fn colour(p: &str) -> &'static str {
    match p {
        "f32" => "#1f77b4",
        "f16" => "#2ca02c",
        "f16-arith" => "#ff7f0e",
        _ => "#d62728",
    }
}

fn write_svg(path: &Path, rows: &[Row], a: &ReportArgs) -> Result<()> {
    let ops: Vec<&str> = OPS.iter().copied().filter(|o| rows.iter().any(|r| r.op == *o)).collect();
    let (cols, pw, ph) = (4usize, 300.0f64, 220.0f64);
    let nrows = ops.len().div_ceil(cols).max(1);
    let (width, height) = (cols as f64 * pw, nrows as f64 * ph + 60.0);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" font-size="10">"#
    );
    let _ = writeln!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="10" y="18" font-size="13">mcdenoise precision: time (x, log) against mean relative error (y, log), {}x{}, {} thread(s); circles scalar, squares SIMD; line: Pareto front</text>"#,
        a.width, a.height, a.threads
    );
    for (pi, p) in ["f32", "f16", "f16-arith", "fixed"].iter().enumerate() {
        let x = 10.0 + pi as f64 * 110.0;
        let _ = writeln!(
            s,
            r#"<circle cx="{}" cy="38" r="5" fill="{}"/><text x="{}" y="42">{p}</text>"#,
            x + 5.0,
            colour(p),
            x + 14.0
        );
    }
    for (k, op) in ops.iter().enumerate() {
        let (ox, oy) = ((k % cols) as f64 * pw, 60.0 + (k / cols) as f64 * ph);
        let pts: Vec<&Row> = rows.iter().filter(|r| r.op == *op).collect();
        let lx: Vec<f64> = pts.iter().map(|r| r.ms.max(1e-3).log10()).collect();
        let ly: Vec<f64> = pts.iter().map(|r| r.mean_rel.max(1e-9).log10()).collect();
        let (x0, x1) = (
            lx.iter().cloned().fold(f64::INFINITY, f64::min) - 0.1,
            lx.iter().cloned().fold(f64::NEG_INFINITY, f64::max) + 0.1,
        );
        let (y0, y1) = (
            ly.iter().cloned().fold(f64::INFINITY, f64::min) - 0.3,
            ly.iter().cloned().fold(f64::NEG_INFINITY, f64::max) + 0.3,
        );
        let (l, t, iw, ih) = (ox + 45.0, oy + 18.0, pw - 60.0, ph - 50.0);
        let px = |v: f64| l + (v - x0) / (x1 - x0).max(1e-9) * iw;
        let py = |v: f64| t + ih - (v - y0) / (y1 - y0).max(1e-9) * ih;
        let _ = writeln!(s, r##"<rect x="{l}" y="{t}" width="{iw}" height="{ih}" fill="none" stroke="#999"/>"##);
        let _ = writeln!(s, r#"<text x="{l}" y="{}" font-size="11" font-weight="bold">{op}</text>"#, t - 5.0);
        let _ = writeln!(s, r#"<text x="{l}" y="{}">{:.2} ms</text>"#, t + ih + 12.0, 10f64.powf(x0));
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="end">{:.1} ms</text>"#,
            l + iw,
            t + ih + 12.0,
            10f64.powf(x1)
        );
        let _ = writeln!(s, r#"<text x="{}" y="{}" text-anchor="end">1e{:.0}</text>"#, l - 3.0, t + 8.0, y1.floor());
        let _ = writeln!(s, r#"<text x="{}" y="{}" text-anchor="end">1e{:.0}</text>"#, l - 3.0, t + ih, y0.ceil());
        // Pareto front: sorted by time, keep points that lower the error.
        let mut idx: Vec<usize> = (0..pts.len()).collect();
        idx.sort_by(|&a, &b| lx[a].total_cmp(&lx[b]));
        let mut best = f64::INFINITY;
        let mut front = Vec::new();
        for &i in &idx {
            if ly[i] < best {
                best = ly[i];
                front.push(format!("{:.1},{:.1}", px(lx[i]), py(ly[i])));
            }
        }
        let _ = writeln!(
            s,
            r##"<polyline points="{}" fill="none" stroke="#555" stroke-dasharray="3,2"/>"##,
            front.join(" ")
        );
        for (i, r) in pts.iter().enumerate() {
            let (cx, cy) = (px(lx[i]), py(ly[i]));
            if r.isa == "scalar" {
                let _ = writeln!(
                    s,
                    r#"<circle cx="{cx:.1}" cy="{cy:.1}" r="4" fill="{}"><title>{} {} {}: {:.3} ms, {:.2e}</title></circle>"#,
                    colour(r.precision),
                    r.op,
                    r.precision,
                    r.isa,
                    r.ms,
                    r.mean_rel
                );
            } else {
                let _ = writeln!(
                    s,
                    r#"<rect x="{:.1}" y="{:.1}" width="8" height="8" fill="{}"><title>{} {} {}: {:.3} ms, {:.2e}</title></rect>"#,
                    cx - 4.0,
                    cy - 4.0,
                    colour(r.precision),
                    r.op,
                    r.precision,
                    r.isa,
                    r.ms,
                    r.mean_rel
                );
            }
        }
    }
    s.push_str("</svg>\n");
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(|e| HostError::write(d, e))?;
    }
    atomic_write(path, |tmp| std::fs::write(tmp, s.as_bytes()).map_err(|e| e.to_string()))
}

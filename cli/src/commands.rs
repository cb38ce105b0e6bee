//! The commands behind the CLI: denoise a sequence, score outputs, the demo.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::cli::DenoiseArgs;
use mcdenoise::error::{HostError, Result};
use mcdenoise::io::estimate::Estimate;
use mcdenoise::io::frame::{check_same_size, Frame, Limits};
use mcdenoise::io::{list_inputs, output};
use mcdenoise::methods::{MethodKind, Settings, Timings};
use mcdenoise::metrics::{self, Scores};
use mcdenoise::pipeline::{denoise_sequence, RunReport, SequenceOptions};

/// `mcdenoise denoise`: the plan and the buffers on stderr and a one-line
/// summary on stdout (`--timings`: the stages' times and the memory too);
/// `--json` prints one JSON object instead, `--quiet` nothing but warnings.
pub fn denoise_cmd(a: &DenoiseArgs) -> Result<()> {
    let t0 = Instant::now();
    let rep = denoise_sequence(a.method, &a.settings, &a.inputs, &a.outdir, &a.sequence, |_, _, _| {})?;
    let seconds = t0.elapsed().as_secs_f64();
    for w in &rep.warnings {
        eprintln!("warning: {w}");
    }
    if a.json {
        println!("{}", json_run(a, &rep, seconds));
        return Ok(());
    }
    if a.quiet {
        return Ok(());
    }
    eprintln!("{}; buffers: {}", rep.plan, rep.buffers.join(", "));
    let frames = rep.frames.max(1) as f64;
    println!(
        "{}: {} frame{} of {}x{} -> {}: {:.1} ms/frame ({:.1} in the kernels, {:.1} reading, {:.1} writing, \
         overlapped), {:.2} s in all ({} threads, {}, {})",
        a.method.name(),
        rep.frames,
        if rep.frames == 1 { "" } else { "s" },
        rep.size.0,
        rep.size.1,
        a.outdir.display(),
        seconds * 1e3 / frames,
        ms(rep.timings.total()) / frames,
        ms(rep.read) / frames,
        ms(rep.write) / frames,
        seconds,
        a.settings.threads,
        a.settings.precision.name(),
        a.settings.isa.name()
    );
    if a.timings {
        print_timings(&rep.timings, rep.frames);
        print_io(&rep);
        print_memory(rep.estimate.as_ref());
    }
    Ok(())
}

/// The I/O lines of `--timings`: reading and writing (in their own
/// threads, beside the kernels) and what of them the denoiser waited for.
fn print_io(rep: &RunReport) {
    let frames = rep.frames.max(1) as f64;
    for (name, d) in [
        ("read (reader thread)", rep.read),
        ("write (writer thread)", rep.write),
        ("waiting for the reader", rep.read_wait),
        ("waiting for the writer", rep.write_wait),
    ] {
        println!("{:<28} {:>10.2} {:>12.3}", name, ms(d), ms(d) / frames);
    }
}

/// `mcdenoise inspect FILE`: the file's parts, channels and windows, the
/// buffers the loader finds (which channels, whose naming), and for each
/// method the stages it builds from the frame or why it cannot run.
pub fn inspect_cmd(file: &Path, selection: &mcdenoise::io::names::Selection) -> Result<()> {
    use mcdenoise::io::frame::{Buffer, ReadOptions};
    let opts = ReadOptions { selection: selection.clone(), ..ReadOptions::default() };
    let reader = Frame::open_with(file, &Limits::default(), &opts)?;
    let info = reader.info().clone();
    println!("{}", file.display());
    for (pi, h) in info.headers.iter().enumerate() {
        let name = h.own_attributes.layer_name.as_ref().map_or("(unnamed)".to_string(), |n| format!("'{n}'"));
        let blocks = match h.blocks {
            exr::meta::BlockDescription::ScanLines => "scan lines".to_string(),
            exr::meta::BlockDescription::Tiles(t) => {
                format!("tiles {}x{} ({:?})", t.tile_size.0, t.tile_size.1, t.level_mode)
            }
        };
        let dw = &h.shared_attributes.display_window;
        println!(
            "part {pi} {name}: data window {}x{} at ({}, {}), display window {}x{} at ({}, {}), pixel aspect {}, {:?}, {}, {:?}",
            h.layer_size.0,
            h.layer_size.1,
            h.own_attributes.layer_position.0,
            h.own_attributes.layer_position.1,
            dw.size.0,
            dw.size.1,
            dw.position.0,
            dw.position.1,
            h.shared_attributes.pixel_aspect,
            h.compression,
            blocks,
            h.line_order
        );
        let chans: Vec<String> = h.channels.list.iter().map(|c| format!("{} ({:?})", c.name, c.sample_type)).collect();
        println!("  channels: {}", chans.join(", "));
    }
    println!("layer: {}", info.layer.as_deref().unwrap_or("(none)"));
    for b in Buffer::ALL {
        match &info.found[b.index()] {
            Some(f) => {
                let at: Vec<String> =
                    f.names.iter().zip(&f.channels).map(|(n, (p, _))| format!("{n} [part {p}]")).collect();
                let conv = match f.convert {
                    mcdenoise::io::names::Convert::Plain => "",
                    mcdenoise::io::names::Convert::FlipY => "; y negated (y up)",
                    mcdenoise::io::names::Convert::FarIsZero => "; 1e9 and beyond read as 0 (no hit)",
                };
                let also = if f.also_in.is_empty() {
                    String::new()
                } else {
                    format!("; also in {} (--part chooses)", f.also_in.join(", "))
                };
                println!("{:<16} {} ({} naming{conv}{also})", b.name(), at.join(", "), f.from);
            }
            None => println!("{:<16} not found", b.name()),
        }
    }
    let frame = reader.read()?;
    println!("methods:");
    for kind in MethodKind::ALL {
        let settings = Settings::default();
        match mcdenoise::methods::create(kind, &settings, &frame) {
            Ok(d) => println!("  {}", d.plan().line(kind.name())),
            Err(e) => println!("  {}: cannot run: {e}", kind.name()),
        }
    }
    Ok(())
}

/// `denoise --json`: everything the text output says, as one object.
fn json_run(a: &DenoiseArgs, rep: &RunReport, seconds: f64) -> String {
    let frames = rep.frames.max(1) as f64;
    let strings =
        |v: &mut dyn Iterator<Item = String>| format!("[{}]", v.map(|s| json_string(&s)).collect::<Vec<_>>().join(","));
    let skipped: Vec<String> = rep
        .stages
        .skipped
        .iter()
        .map(|(st, why)| format!("{{\"stage\":{},\"reason\":{}}}", json_string(st), json_string(why)))
        .collect();
    let timings: Vec<String> = rep
        .timings
        .stages()
        .iter()
        .map(|(name, d, _)| {
            format!("{{\"stage\":{},\"ms\":{:.4},\"ms_per_frame\":{:.4}}}", json_string(name), ms(*d), ms(*d) / frames)
        })
        .collect();
    let opt = |v: Option<u64>| v.map_or("null".to_string(), |v| v.to_string());
    format!(
        concat!(
            "{{\"method\":{},\"frames\":{},\"width\":{},\"height\":{},\"threads\":{},\"precision\":{},\"isa\":{},",
            "\"seconds\":{:.4},\"ms_per_frame\":{:.4},\"kernel_ms_per_frame\":{:.4},",
            "\"read_ms_per_frame\":{:.4},\"write_ms_per_frame\":{:.4},\"read_wait_ms_per_frame\":{:.4},",
            "\"write_wait_ms_per_frame\":{:.4},",
            "\"plan\":{{\"built\":{},\"skipped\":[{}]}},\"buffers\":{},\"timings\":[{}],",
            "\"memory\":{{\"estimate_bytes\":{},\"peak_heap_bytes\":{},\"peak_resident_bytes\":{}}},",
            "\"outputs\":{},\"warnings\":{}}}"
        ),
        json_string(a.method.name()),
        rep.frames,
        rep.size.0,
        rep.size.1,
        a.settings.threads,
        json_string(a.settings.precision.name()),
        json_string(a.settings.isa.name()),
        seconds,
        seconds * 1e3 / frames,
        ms(rep.timings.total()) / frames,
        ms(rep.read) / frames,
        ms(rep.write) / frames,
        ms(rep.read_wait) / frames,
        ms(rep.write_wait) / frames,
        strings(&mut rep.stages.built.iter().map(|s| s.to_string())),
        skipped.join(","),
        strings(&mut rep.buffers.iter().map(|s| s.to_string())),
        timings.join(","),
        opt(rep.estimate.map(|e| e.bytes())),
        opt(mcdenoise::runtime::memory::heap().map(|(_, peak)| peak)),
        opt(mcdenoise::runtime::memory::peak_resident()),
        strings(&mut rep.outputs.iter().map(|p| p.display().to_string())),
        strings(&mut rep.warnings.iter().cloned()),
    )
}

/// Prints per-stage totals and per-frame means.
pub fn print_timings(t: &Timings, frames: usize) {
    let frames = frames.max(1) as f64;
    println!("{:<28} {:>10} {:>12}", "stage", "total ms", "ms/frame");
    for (name, d, _) in t.stages() {
        println!("{:<28} {:>10.2} {:>12.3}", name, ms(*d), ms(*d) / frames);
    }
    println!("{:<28} {:>10.2} {:>12.3}", "all kernels", ms(t.total()), ms(t.total()) / frames);
}

/// The memory line of `--timings`: the estimate, the counted peak heap and
/// the peak resident size.
pub fn print_memory(est: Option<&Estimate>) {
    use mcdenoise::runtime::memory::format_bytes;
    let mut parts = Vec::new();
    if let Some(e) = est {
        parts.push(format!(
            "estimate {} = {} bytes per pixel x {} + {} ({} bytes)",
            format_bytes(e.bytes()),
            e.per_pixel,
            e.pixels,
            format_bytes(e.fixed),
            e.bytes()
        ));
    }
    if let Some((_, peak)) = mcdenoise::runtime::memory::heap() {
        parts.push(format!("peak heap {} ({peak} bytes)", format_bytes(peak)));
    }
    if let Some(rss) = mcdenoise::runtime::memory::peak_resident() {
        parts.push(format!("peak resident {}", format_bytes(rss)));
    }
    println!("memory: {}", parts.join("; "));
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Loads the colour of a result or reference file.
fn load_color(p: &Path) -> Result<Frame> {
    Frame::load(p, &Limits::default())
}

/// Scores `out`, the output of frame `f` read from `file`, against the
/// reference of the same file name in `refdir`.
fn score_frame(refdir: &Path, file: &Path, out: &[f32], f: &Frame) -> Result<Scores> {
    let r = refdir.join(file.file_name().expect("a file has a name"));
    let rf = load_color(&r)?;
    if (rf.width, rf.height) != (f.width, f.height) {
        return Err(HostError::bad(&r, "reference size differs from the frame"));
    }
    Ok(metrics::score(out, rf.get(mcdenoise::io::frame::Buffer::Color).expect("colour"), f.width, f.height))
}

/// Scores one file against one reference.
pub fn score_files(out: &Path, reference: &Path) -> Result<Scores> {
    let o = load_color(out)?;
    let r = load_color(reference)?;
    check_same_size(reference, (r.width, r.height), &o)?;
    Ok(metrics::score(
        o.get(mcdenoise::io::frame::Buffer::Color).expect("colour"),
        r.get(mcdenoise::io::frame::Buffer::Color).expect("colour"),
        o.width,
        o.height,
    ))
}

fn json_scores(name: &str, s: &Scores, flicker: Option<f64>) -> String {
    let num = |v: f64| if v.is_finite() { format!("{v:.6}") } else { "null".into() };
    format!(
        "{{\"file\":{},\"psnr\":{},\"ssim\":{},\"relmse\":{},\"smape\":{},\"rmse\":{},\"flicker\":{}}}",
        json_string(name),
        num(s.psnr),
        num(s.ssim),
        num(s.relmse),
        num(s.smape),
        num(s.rmse),
        flicker.map_or("null".into(), num)
    )
}

/// A JSON string literal.
pub fn json_string(s: &str) -> String {
    let mut o = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            c if (c as u32) < 0x20 => o.push_str(&format!("\\u{:04x}", c as u32)),
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// Mean of scores.
pub fn mean_scores(v: &[Scores]) -> Scores {
    let n = v.len().max(1) as f64;
    let m = |f: fn(&Scores) -> f64| v.iter().map(f).sum::<f64>() / n;
    Scores {
        psnr: m(|s| s.psnr),
        ssim: m(|s| s.ssim),
        relmse: m(|s| s.relmse),
        smape: m(|s| s.smape),
        rmse: m(|s| s.rmse),
    }
}

/// `mcdenoise score`.
pub fn score_cmd(reference: &Path, out: &Path, json: bool) -> Result<()> {
    let pairs: Vec<(PathBuf, PathBuf)> = if out.is_dir() {
        if !reference.is_dir() {
            return Err(HostError::bad(reference, "OUT is a directory, so the reference must be one too"));
        }
        let files = list_inputs(&[out.to_path_buf()])?;
        files
            .into_iter()
            .map(|f| {
                let r = reference.join(f.file_name().expect("file"));
                (f, r)
            })
            .collect()
    } else {
        vec![(out.to_path_buf(), reference.to_path_buf())]
    };
    let mut all = Vec::new();
    let mut lines = Vec::new();
    // A sequence (files in name order): the flicker of each frame against the one before.
    let mut prev: Option<(Vec<f32>, Vec<f32>)> = None;
    let mut flicker = Vec::new();
    for (o, r) in &pairs {
        if !r.exists() {
            return Err(HostError::read(r, "no reference with this name"));
        }
        let of = load_color(o)?;
        let rf = load_color(r)?;
        check_same_size(r, (rf.width, rf.height), &of)?;
        let (ov, rv) = (
            of.get(mcdenoise::io::frame::Buffer::Color).expect("colour"),
            rf.get(mcdenoise::io::frame::Buffer::Color).expect("colour"),
        );
        let s = metrics::score(ov, rv, of.width, of.height);
        let fl = match &prev {
            Some((po, pr)) if po.len() == ov.len() => {
                let f = metrics::flicker_mse(po, ov, pr, rv);
                flicker.push(f);
                Some(f.sqrt())
            }
            _ => None,
        };
        prev = Some((ov.to_vec(), rv.to_vec()));
        let name = o.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if json {
            lines.push(json_scores(&name, &s, fl));
        } else {
            lines.push(format!(
                "{:<28} PSNR {:7.3} dB  SSIM {:.4}  relMSE {:.5}  SMAPE {:.5}  RMSE {:.5}{}",
                name,
                s.psnr,
                s.ssim,
                s.relmse,
                s.smape,
                s.rmse,
                fl.map(|f| format!("  flicker {f:.5}")).unwrap_or_default()
            ));
        }
        all.push(s);
    }
    let mean = mean_scores(&all);
    let seq_flicker = (!flicker.is_empty()).then(|| (flicker.iter().sum::<f64>() / flicker.len() as f64).sqrt());
    if json {
        println!("{{\"files\":[{}],\"mean\":{}}}", lines.join(","), json_scores("mean", &mean, seq_flicker));
    } else {
        for l in lines {
            println!("{l}");
        }
        if all.len() > 1 {
            println!(
                "{:<28} PSNR {:7.3} dB  SSIM {:.4}  relMSE {:.5}  SMAPE {:.5}  RMSE {:.5}{}",
                "mean",
                mean.psnr,
                mean.ssim,
                mean.relmse,
                mean.smape,
                mean.rmse,
                seq_flicker.map(|f| format!("  flicker {f:.5}")).unwrap_or_default()
            );
        }
    }
    Ok(())
}

/// Where the bundled sample is: `./samples`, or the repository's.
pub fn sample_dir() -> Result<PathBuf> {
    let candidates = [PathBuf::from("samples"), Path::new(env!("CARGO_MANIFEST_DIR")).join("../samples")];
    candidates
        .iter()
        .find(|d| d.join("frame_0000.exr").is_file())
        .cloned()
        .ok_or_else(|| HostError::read(Path::new("samples"), "bundled sample not found (run from the repository root)"))
}

/// The main job: every method on the bundled sample, a table, outputs and PNGs.
pub fn demo(settings: &Settings) -> Result<()> {
    let dir = sample_dir()?;
    let out_root = PathBuf::from("mcdenoise-out");
    let files = list_inputs(std::slice::from_ref(&dir))?;
    let first = Frame::open(&files[0], &Limits::default())?;
    println!(
        "bundled sample: {} frames of {}x{} from {} ({} threads, {}, {})",
        files.len(),
        first.info().width,
        first.info().height,
        dir.display(),
        settings.threads,
        settings.precision.name(),
        settings.isa.name()
    );
    println!("{:<14} {:>10} {:>10} {:>10} {:>8}", "method", "ms/frame", "PSNR dB", "relMSE", "SSIM");
    // The contact sheet shows the last frame, where the temporal methods have
    // the most history: the input, every method's output, the reference.
    let last = files.len() - 1;
    let (w, h) = (first.info().width, first.info().height);
    let mut sheet: Vec<(String, Vec<f32>)> = Vec::new();
    let mut failed = Vec::new();
    // WSKP runs twice, with each bundled ImportanceNet.
    for name in REPORT_METHODS {
        let (m, layers) = report_method(name)?;
        let layers = if m == MethodKind::Wskp { layers } else { settings.layers };
        let settings = &Settings { layers, ..settings.clone() };
        let outdir = out_root.join(name);
        let mut scores = Vec::new();
        let mut err = None;
        let opts = SequenceOptions { png: true, ..SequenceOptions::default() };
        let mut shown = None;
        let rep = denoise_sequence(m, settings, std::slice::from_ref(&dir), &outdir, &opts, |i, out, f| {
            if i == last {
                shown = Some(out.to_vec());
            }
            match score_frame(&dir.join("ref"), &files[i], out, f) {
                Ok(s) => scores.push(s),
                Err(e) => err = Some(e),
            }
        });
        let rep = match rep {
            Ok(r) => r,
            Err(e) => {
                println!("{name:<14} failed: {e}");
                failed.push(name.to_string());
                continue;
            }
        };
        if let Some(e) = err {
            return Err(e);
        }
        if let Some(out) = shown {
            sheet.push((if m == MethodKind::None { "input".into() } else { name.to_string() }, out));
        }
        let s = mean_scores(&scores);
        println!(
            "{:<14} {:>10.3} {:>10.3} {:>10.5} {:>8.4}",
            name,
            ms(rep.timings.total()) / rep.frames.max(1) as f64,
            s.psnr,
            s.relmse,
            s.ssim
        );
    }
    println!("outputs and PNG previews: {}/<method>/", out_root.display());
    let reference = load_color(&dir.join("ref").join(files[last].file_name().expect("file")))?;
    sheet.push(("reference".into(), reference.get(mcdenoise::io::frame::Buffer::Color).expect("colour").to_vec()));
    let tiles: Vec<(&str, &[f32])> = sheet.iter().map(|(n, v)| (n.as_str(), v.as_slice())).collect();
    let (rgb, sw, sh) = mcdenoise::io::sheet::contact_sheet(&tiles, w, h, 3, 2);
    let path = out_root.join("contact-sheet.png");
    output::write_png_preview(&path, sw, sh, &rgb)?;
    println!("contact sheet of frame {last} (input, each method, reference): {}", path.display());
    if !failed.is_empty() {
        return Err(HostError::bad(&dir, format!("the demo's {} failed (above)", failed.join(", "))));
    }
    Ok(())
}

/// The methods of the demo and of the per-method precision report, by name
/// (WSKP with each bundled ImportanceNet), in [`MethodKind::ALL`]'s order.
pub const REPORT_METHODS: [&str; 8] = ["none", "ta", "atrous", "sure-atrous", "wskp-3", "wskp-6", "afn", "cross"];

/// A method of the report by name: the kind and its network layers.
fn report_method(name: &str) -> Result<(MethodKind, usize)> {
    match name {
        "wskp-3" => Ok((MethodKind::Wskp, 3)),
        "wskp-6" => Ok((MethodKind::Wskp, 6)),
        _ => MethodKind::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .map(|m| (m, 6))
            .ok_or_else(|| HostError::Usage(format!("--methods: unknown method {name:?}"))),
    }
}

/// One row of the per-method precision report.
struct MethodRow {
    method: String,
    precision: &'static str,
    wall_ms: f64,
    kernel_ms: f64,
    psnr: f64,
    relmse: f64,
    /// Per frame PSNR (for the loss against f32).
    frames: Vec<f64>,
    /// The largest per-frame PSNR loss against the method's f32 run.
    worst_loss: Option<f64>,
    pareto: bool,
}

/// Whether row `i` of `rows` is on its method's Pareto front of wall time
/// against PSNR: no other row of the method is at least as fast and at
/// least as accurate, and better in one.
fn on_front(rows: &[MethodRow], i: usize) -> bool {
    let r = &rows[i];
    !rows.iter().enumerate().any(|(j, o)| {
        j != i
            && o.method == r.method
            && o.wall_ms <= r.wall_ms
            && o.psnr >= r.psnr
            && (o.wall_ms < r.wall_ms || o.psnr > r.psnr)
    })
}

/// `mcdenoise precision --methods ...`: each method run on `sequence` in
/// f32, f16 and fixed point (outputs under `mcdenoise-out/precision/`),
/// scored against the references; a table of wall and kernel time per
/// frame, mean PSNR and relMSE, the largest per-frame loss against f32 and
/// each method's Pareto front, and the same as a CSV.
pub fn precision_methods(
    methods: &[String],
    sequence: &Path,
    reference: Option<&Path>,
    threads: usize,
    csv: &Path,
) -> Result<()> {
    use mcdenoise::runtime::precision::PrecisionKind;
    let files = list_inputs(&[sequence.to_path_buf()])?;
    let refdir = reference.map_or_else(|| sequence.join("ref"), Path::to_path_buf);
    if !refdir.is_dir() {
        return Err(HostError::Usage(format!(
            "{}: no such directory (the references of --sequence's frames, by file name: --reference DIR, \
             by default SEQUENCE/ref)",
            refdir.display()
        )));
    }
    let out_root = PathBuf::from("mcdenoise-out").join("precision");
    let base = Settings { threads, ..Settings::default() };
    println!("{} frames of {} ({} threads, {})", files.len(), sequence.display(), threads, base.isa.name());
    println!(
        "{:<12} {:<9} {:>10} {:>10} {:>9} {:>9} {:>10}  Pareto",
        "method", "precision", "wall ms", "kernel ms", "PSNR dB", "relMSE", "vs f32 dB"
    );
    let mut rows: Vec<MethodRow> = Vec::new();
    // One untimed run first, so that the first timed one does not pay for
    // the thread pool's start and the first touch of the memory.
    if let Some(name) = methods.first() {
        let (kind, layers) = report_method(name)?;
        let opts = SequenceOptions { quiet: true, ..SequenceOptions::default() };
        let outdir = out_root.join("warm-up");
        denoise_sequence(
            kind,
            &Settings { layers, ..base.clone() },
            &[sequence.to_path_buf()],
            &outdir,
            &opts,
            |_, _, _| {},
        )?;
        let _ = std::fs::remove_dir_all(&outdir);
    }
    for name in methods {
        let (kind, layers) = report_method(name)?;
        let first = rows.len();
        for precision in [PrecisionKind::F32, PrecisionKind::F16, PrecisionKind::Fixed] {
            let settings = Settings { layers, precision, ..base.clone() };
            let outdir = out_root.join(format!("{name}-{}", precision.name()));
            // The folder holds this run's frames only: an earlier run's
            // (a longer sequence's) would be scored with them.
            clear_frames(&outdir)?;
            let mut scores = Vec::new();
            let mut err = None;
            let opts = SequenceOptions { quiet: true, ..SequenceOptions::default() };
            let t0 = Instant::now();
            let rep = denoise_sequence(kind, &settings, &[sequence.to_path_buf()], &outdir, &opts, |i, out, f| {
                match score_frame(&refdir, &files[i], out, f) {
                    Ok(s) => scores.push(s),
                    Err(e) => {
                        err.get_or_insert(e);
                    }
                }
            })?;
            let wall = t0.elapsed().as_secs_f64();
            if let Some(e) = err {
                return Err(e);
            }
            let n = rep.frames.max(1) as f64;
            let s = mean_scores(&scores);
            let frames: Vec<f64> = scores.iter().map(|s| s.psnr).collect();
            let worst_loss = (precision != PrecisionKind::F32)
                .then(|| rows[first].frames.iter().zip(&frames).map(|(a, b)| a - b).fold(f64::NEG_INFINITY, f64::max));
            rows.push(MethodRow {
                method: name.clone(),
                precision: precision.name(),
                wall_ms: wall * 1e3 / n,
                kernel_ms: ms(rep.timings.total()) / n,
                psnr: s.psnr,
                relmse: s.relmse,
                frames,
                worst_loss,
                pareto: false,
            });
        }
        for i in first..rows.len() {
            rows[i].pareto = on_front(&rows, i);
            let r = &rows[i];
            println!(
                "{:<12} {:<9} {:>10.1} {:>10.1} {:>9.3} {:>9.5} {:>10}  {}",
                r.method,
                r.precision,
                r.wall_ms,
                r.kernel_ms,
                r.psnr,
                r.relmse,
                r.worst_loss.map_or("".into(), |v| format!("{:+.2}", -v)),
                if r.pareto { "*" } else { "" }
            );
        }
    }
    let mut text = String::from("method,precision,wall_ms,kernel_ms,psnr,relmse,worst_frame_vs_f32_db,pareto\n");
    for r in &rows {
        text.push_str(&format!(
            "{},{},{:.3},{:.3},{:.4},{:.6},{},{}\n",
            r.method,
            r.precision,
            r.wall_ms,
            r.kernel_ms,
            r.psnr,
            r.relmse,
            r.worst_loss.map_or(String::new(), |v| format!("{:.4}", -v)),
            r.pareto as u8
        ));
    }
    if let Some(d) = csv.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(|e| HostError::write(d, e))?;
    }
    std::fs::write(csv, text).map_err(|e| HostError::write(csv, e))?;
    println!("wall: reading, denoising and writing, per frame; vs f32: the worst frame's PSNR against f32's; *: on the method's Pareto front of wall time against PSNR");
    println!("outputs: {}/<method>-<precision>/; table: {}", out_root.display(), csv.display());
    Ok(())
}

/// Removes the EXR files of `dir` (the precision report's own output
/// folder, before a run writes it again); a missing folder is fine.
fn clear_frames(dir: &Path) -> Result<()> {
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(()) };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_file() && p.extension().is_some_and(|x| x.eq_ignore_ascii_case("exr")) {
            std::fs::remove_file(&p).map_err(|err| HostError::write(&p, err))?;
        }
    }
    Ok(())
}

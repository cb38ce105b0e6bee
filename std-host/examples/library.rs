//! The host crate used as a library: load a sequence of EXR frames, denoise
//! it frame by frame with one method, write the results and score them
//! against the references.
//!
//! ```sh
//! cargo run --release -p mcdenoise --example library                  # the bundled sample, sure-atrous
//! cargo run --release -p mcdenoise --example library -- DIR OUT wskp  # your frames (references in DIR/ref/, if any)
//! ```
//!
//! The CLI's `denoise` does the same through `mcdenoise::pipeline::denoise_sequence`, which
//! adds the memory check from each header and the atomic writes.

use std::path::{Path, PathBuf};

use mcdenoise::io::frame::{Buffer, Frame, Limits};
use mcdenoise::io::{list_inputs, output};
use mcdenoise::methods::{self, MethodKind, Settings, Timings};
use mcdenoise::metrics;

fn main() -> mcdenoise::Result<()> {
    let mut args = std::env::args().skip(1);
    let input = args.next().map(PathBuf::from).unwrap_or(Path::new(env!("CARGO_MANIFEST_DIR")).join("../samples"));
    let outdir = args.next().map(PathBuf::from).unwrap_or_else(|| PathBuf::from("mcdenoise-out/library-example"));
    let method = match args.next() {
        Some(name) => MethodKind::parse(&name)?,
        None => MethodKind::SureAtrous,
    };

    // Frames in name order (a directory's .exr files), and the settings every
    // method shares: here two threads and the widest instruction set.
    let files = list_inputs(std::slice::from_ref(&input))?;
    let settings = Settings { threads: 2, ..Settings::default() };
    let limits = Limits::default();

    // The method is built from the first frame: it looks at the buffers the
    // frame has (albedo, normal, motion, ...) and says which stages it runs.
    let first = Frame::load(&files[0], &limits)?;
    let mut denoiser = methods::create(method, &settings, &first)?;
    let mut ctx = methods::context(&settings)?;
    println!("{}", denoiser.plan().line(denoiser.name()));

    std::fs::create_dir_all(&outdir).map_err(|e| mcdenoise::HostError::write(&outdir, e))?;
    let mut timings = Timings::default();
    for (i, path) in files.iter().enumerate() {
        let frame = if i == 0 { first.clone() } else { Frame::load(path, &limits)? };
        // Three f32 planes (R, G, B), width x height each.
        let rgb = denoiser.denoise(&frame, &mut ctx, &mut timings)?;
        let name = path.file_name().expect("a frame file has a name");
        output::write_rgb_exr(&outdir.join(name), frame.width, frame.height, &rgb, false)?;
        output::write_png_preview(&outdir.join(name).with_extension("png"), frame.width, frame.height, &rgb)?;
        print!("{}: {}x{}", name.to_string_lossy(), frame.width, frame.height);
        match reference(&input, name.as_ref(), &limits) {
            Some(r) => {
                let s = metrics::score(&rgb, r.get(Buffer::Color).expect("colour is required"), r.width, r.height);
                println!(", PSNR {:.2} dB, relMSE {:.4}", s.psnr, s.relmse);
            }
            None => println!(),
        }
    }
    let per_frame = timings.total().as_secs_f64() * 1e3 / files.len() as f64;
    println!("{} frames -> {}: {per_frame:.1} ms/frame in the kernels", files.len(), outdir.display());
    Ok(())
}

/// The frame's reference, `DIR/ref/NAME`, when there is one of the same size.
fn reference(dir: &Path, name: &Path, limits: &Limits) -> Option<Frame> {
    let path = dir.join("ref").join(name);
    path.is_file().then(|| Frame::load(&path, limits).ok()).flatten()
}

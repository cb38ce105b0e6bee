//! Writing results: OpenEXR (`R`, `G`, `B`, f32 or f16, ZIP) and tone-mapped
//! PNG previews. Every file is written under a temporary name in the target
//! directory and renamed into place, so an interrupted run never leaves a
//! half-written file; no output may land on an input.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use exr::prelude::*;

use crate::error::{HostError, Result};

/// Writes `path` atomically: `write` fills a temporary file next to it, which is then renamed.
pub fn atomic_write(path: &Path, write: impl FnOnce(&Path) -> std::result::Result<(), String>) -> Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| HostError::write(path, "no file name"))?;
    let tmp = dir.join(format!(".{}.tmp-{}", name.to_string_lossy(), std::process::id()));
    match write(&tmp) {
        Ok(()) => std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            HostError::write(path, e)
        }),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(HostError::write(path, e))
        }
    }
}

/// Writes three planes as `R`, `G`, `B` (f16 when `half`).
pub fn write_rgb_exr(path: &Path, width: usize, height: usize, rgb: &[f32], half: bool) -> Result<()> {
    let plane = width * height;
    if rgb.len() != 3 * plane {
        return Err(HostError::write(path, "internal: colour is not three planes"));
    }
    let ch = |c: usize| &rgb[c * plane..(c + 1) * plane];
    write_exr(path, width, height, &[("R", ch(0)), ("G", ch(1)), ("B", ch(2))], half)
}

/// Writes named planes (each `width * height` values) as one scanline EXR
/// layer, ZIP-compressed, f16 when `half`.
pub fn write_exr(path: &Path, width: usize, height: usize, planes: &[(&str, &[f32])], half: bool) -> Result<()> {
    let plane = width * height;
    let mut list = smallvec::SmallVec::new();
    for (name, v) in planes {
        if v.len() != plane {
            return Err(HostError::write(path, format!("internal: channel {name} is not one plane")));
        }
        let samples = if half {
            FlatSamples::F16(v.iter().map(|&x| f16::from_f32(x)).collect())
        } else {
            FlatSamples::F32(v.to_vec())
        };
        list.push(AnyChannel::new(*name, samples));
    }
    let layer =
        Layer::new((width, height), LayerAttributes::default(), Encoding::SMALL_LOSSLESS, AnyChannels::sort(list));
    let image = Image::from_layer(layer);
    atomic_write(path, |tmp| image.write().to_file(tmp).map_err(|e| e.to_string()))
}

/// Writes an 8-bit sRGB-ish preview: `clamp(x, 0, 1)^(1/2.2)` per channel.
pub fn write_png_preview(path: &Path, width: usize, height: usize, rgb: &[f32]) -> Result<()> {
    let plane = width * height;
    let mut bytes = Vec::with_capacity(3 * plane);
    for p in 0..plane {
        for c in 0..3 {
            let v = rgb[c * plane + p];
            let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
            bytes.push((v.powf(1.0 / 2.2) * 255.0 + 0.5) as u8);
        }
    }
    atomic_write(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|e| e.to_string())?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().map_err(|e| e.to_string())?;
        w.write_image_data(&bytes).map_err(|e| e.to_string())
    })
}

/// Checks an output directory can be created and written, and that none of
/// the `outputs` is one of the `inputs` (compared after resolving links).
pub fn prepare_outputs(dir: &Path, inputs: &[PathBuf], outputs: &[PathBuf]) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        return Err(HostError::write(dir, "exists and is not a directory"));
    }
    std::fs::create_dir_all(dir).map_err(|e| HostError::write(dir, e))?;
    let probe = dir.join(format!(".mcdenoise-probe-{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(|e| HostError::write(dir, format!("directory is not writable ({e})")))?;
    let _ = std::fs::remove_file(&probe);
    let canon = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let ins: HashSet<PathBuf> = inputs.iter().map(|p| canon(p)).collect();
    for o in outputs {
        // The output may not exist yet: resolve its directory and append the name.
        let resolved = match (o.parent(), o.file_name()) {
            (Some(d), Some(n)) => canon(if d.as_os_str().is_empty() { Path::new(".") } else { d }).join(n),
            _ => o.clone(),
        };
        if ins.contains(&resolved) {
            return Err(HostError::write(o, "would overwrite an input file; choose another output directory"));
        }
    }
    Ok(())
}

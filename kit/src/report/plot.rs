//! The report's CSV and its SVG plot (time against error per operator, with
//! the Pareto front).

use std::fmt::Write as _;
use std::path::Path;

use super::{ReportArgs, Row};
use mcdenoise::error::{HostError, Result};
use mcdenoise::io::output::atomic_write;

pub(super) fn write_csv(path: &Path, rows: &[Row], a: &ReportArgs) -> Result<()> {
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

pub(super) fn write_svg(path: &Path, rows: &[Row], a: &ReportArgs) -> Result<()> {
    let mut ops: Vec<&str> = Vec::new();
    for r in rows {
        if !ops.contains(&r.op) {
            ops.push(r.op);
        }
    }
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

//! The edge-avoiding à-trous step and its guides.

/// Guides of the à-trous oracle.
pub struct AtrousGuides<'a> {
    /// Noise variance (1 plane).
    pub noise: &'a [f64],
    /// Normal (3 planes).
    pub normal: Option<&'a [f64]>,
    /// Position (3 planes).
    pub position: Option<&'a [f64]>,
    /// Depth (1 plane).
    pub depth: Option<&'a [f64]>,
}

/// One à-trous step from the definition in `mcdenoise_core::atrous` (f64):
/// returns the filtered `3 * groups` planes, then (with a variance plane as
/// the last input plane) the filtered variance and the centre weight.
#[allow(clippy::too_many_arguments)]
pub fn atrous_step(
    level: u32,
    groups: usize,
    with_var: bool,
    phi: f64,
    sigma_n: f64,
    sigma_plane: f64,
    sigma_depth: f64,
    sigma_dist: f64,
    eps: f64,
    g: &AtrousGuides<'_>,
    src: &[f64],
    w: usize,
    h: usize,
) -> Vec<f64> {
    let b3 = [1.0 / 16.0, 0.25, 0.375, 0.25, 1.0 / 16.0];
    let n = w * h;
    let hole = 1i64 << level;
    let nc = 3 * groups;
    let nout = nc + if with_var { 2 } else { 0 };
    let mut out = vec![0.0; nout * n];
    // The colour guide is the first image.
    let guide = |c: usize, i: usize| src[c * n + i];
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let p = (y * w as i64 + x) as usize;
            let (mut wsum, mut acc, mut accv) = (0.0, vec![0.0; nc], 0.0);
            for dy in 0..5i64 {
                for dx in 0..5i64 {
                    let (qy, qx) = (y + (dy - 2) * hole, x + (dx - 2) * hole);
                    if qy < 0 || qx < 0 || qy >= h as i64 || qx >= w as i64 {
                        continue;
                    }
                    let q = (qy * w as i64 + qx) as usize;
                    let dc: f64 = (0..3).map(|c| (guide(c, p) - guide(c, q)).powi(2)).sum();
                    let v = g.noise[p].min(g.noise[q]).max(0.0);
                    let mut t = dc / (phi / hole as f64 * v + eps);
                    if let Some(nm) = g.normal {
                        let dn: f64 = (0..3).map(|c| (nm[c * n + p] - nm[c * n + q]).powi(2)).sum();
                        t += dn / (sigma_n * sigma_n);
                    }
                    match (g.normal, g.position, g.depth) {
                        (Some(nm), Some(pos), _) => {
                            // The mean of the two pixels' squared tangent-plane distances.
                            let along = |i: usize| -> f64 {
                                (0..3).map(|c| nm[c * n + i] * (pos[c * n + q] - pos[c * n + p])).sum()
                            };
                            let (pd, qd) = (along(p), along(q));
                            t += 0.5 * (pd * pd + qd * qd) / (sigma_plane * sigma_plane);
                            if sigma_dist > 0.0 {
                                let d2: f64 = (0..3).map(|c| (pos[c * n + q] - pos[c * n + p]).powi(2)).sum();
                                t += d2 / (sigma_dist * sigma_dist);
                            }
                        }
                        (None, Some(pos), _) => {
                            let d2: f64 = (0..3).map(|c| (pos[c * n + q] - pos[c * n + p]).powi(2)).sum();
                            t += d2 / (sigma_plane * hole as f64).powi(2);
                        }
                        (_, None, Some(z)) => {
                            // Squared depth difference relative to both depths.
                            let r2 = (z[q] - z[p]).powi(2) / (z[p].max(1e-20) * z[q].max(1e-20));
                            t += r2 / (sigma_depth * hole as f64).powi(2);
                        }
                        _ => {}
                    }
                    let wt = b3[dy as usize] * b3[dx as usize] * (-t).exp();
                    wsum += wt;
                    for (c, a) in acc.iter_mut().enumerate() {
                        *a += wt * src[c * n + q];
                    }
                    if with_var {
                        accv += wt * wt * src[nc * n + q];
                    }
                }
            }
            for c in 0..nc {
                out[c * n + p] = acc[c] / wsum;
            }
            if with_var {
                out[nc * n + p] = accv / (wsum * wsum);
                out[(nc + 1) * n + p] = (9.0 / 64.0) / wsum;
            }
        }
    }
    out
}

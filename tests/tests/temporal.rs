//! Temporal accumulation against an independent f64 oracle of its
//! definition (core `temporal` module docs): bilinear reprojection by motion
//! with per-tap geometry tests, or the nearest previous world position
//! without motion; the blend `alpha = max(1 / (n + 1), alpha_min)` and the
//! capped history. Random frames with sub-pixel and out-of-image motion, NaN
//! motion, rejected taps, odd sizes and bands of rows, in f32 and f16
//! storage.

use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::{View, ViewMut, F16, F32};
use mcdenoise_tests::{isas_under_test, Img};
use proptest::prelude::*;

/// A small deterministic generator (the inputs are built from it so that
/// geometry tests are never near their thresholds).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / ((1u64 << 53) as f64)
    }
}

struct Case {
    w: usize,
    h: usize,
    color: Img,
    normal: Img,
    position: Img,
    motion: Img,
    prev_color: Img,
    prev_normal: Img,
    prev_position: Img,
    prev_history: Img,
    params: TemporalParams,
}

/// Positions on a grid 1 unit apart (so a pixel's own previous position is
/// the unique nearest), each previous pixel either agreeing with the
/// current geometry (off by 0.1 of the limits) or not (3 times them).
fn case(w: usize, h: usize, seed: u64) -> Case {
    let mut r = Lcg(seed);
    let params =
        TemporalParams { pos_limit: 0.5, normal_limit: 0.3, alpha_min: 0.2, history_cap: 16.0, search_radius: 2 };
    let mut c = Case {
        w,
        h,
        color: Img::zeros(3, w, h),
        normal: Img::zeros(3, w, h),
        position: Img::zeros(3, w, h),
        motion: Img::zeros(2, w, h),
        prev_color: Img::zeros(3, w, h),
        prev_normal: Img::zeros(3, w, h),
        prev_position: Img::zeros(3, w, h),
        prev_history: Img::zeros(1, w, h),
        params,
    };
    for y in 0..h {
        for x in 0..w {
            let base = [x as f64, y as f64, 2.0];
            let n = {
                let v = [r.next() - 0.5, r.next() - 0.5, 1.0];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                [v[0] / l, v[1] / l, v[2] / l]
            };
            for ch in 0..3 {
                *c.color.at_mut(ch, y, x) = (r.next() * 4.0) as f32;
                *c.prev_color.at_mut(ch, y, x) = (r.next() * 4.0) as f32;
                *c.position.at_mut(ch, y, x) = base[ch] as f32;
                *c.normal.at_mut(ch, y, x) = n[ch] as f32;
            }
            // The previous frame's geometry at this pixel: the same surface
            // moved a little, or another one.
            let (dp, dn) = match (r.next() * 4.0) as u32 {
                0 => (1.5, 0.0),   // position rejected
                1 => (0.0, 0.9),   // normal rejected
                _ => (0.05, 0.03), // agrees
            };
            for ch in 0..3 {
                *c.prev_position.at_mut(ch, y, x) = (base[ch] + if ch == 0 { dp } else { 0.0 }) as f32;
                *c.prev_normal.at_mut(ch, y, x) = (n[ch] + if ch == 1 { dn } else { 0.0 }) as f32;
            }
            *c.prev_history.at_mut(0, y, x) = (r.next() * 20.0).floor() as f32;
            let m = match (r.next() * 10.0) as u32 {
                0 => [f64::NAN, 0.0],
                1 => [(r.next() - 0.5) * 4.0 * w as f64, (r.next() - 0.5) * 4.0 * h as f64],
                2 => [(r.next() * 6.0).floor() - 3.0, (r.next() * 6.0).floor() - 3.0],
                _ => [(r.next() - 0.5) * 6.0, (r.next() - 0.5) * 6.0],
            };
            *c.motion.at_mut(0, y, x) = m[0] as f32;
            *c.motion.at_mut(1, y, x) = m[1] as f32;
        }
    }
    c
}

fn d2(a: &Img, ya: usize, xa: usize, b: &Img, yb: usize, xb: usize) -> f64 {
    (0..3).map(|ch| (a.at(ch, ya, xa) as f64 - b.at(ch, yb, xb) as f64).powi(2)).sum()
}

/// The definition in f64: (colour, history) of every pixel.
fn oracle(c: &Case, motion: bool) -> (Vec<f64>, Vec<f64>) {
    let (w, h, p) = (c.w, c.h, &c.params);
    let mut out = vec![0.0; 3 * w * h];
    let mut hist = vec![0.0; w * h];
    let agrees = |y: usize, x: usize, py: usize, px: usize| {
        d2(&c.position, y, x, &c.prev_position, py, px) < (p.pos_limit as f64).powi(2)
            && d2(&c.normal, y, x, &c.prev_normal, py, px) < (p.normal_limit as f64).powi(2)
    };
    for y in 0..h {
        for x in 0..w {
            let mut taps: Vec<(usize, usize, f64)> = Vec::new();
            if motion {
                let fx = x as f64 + c.motion.at(0, y, x) as f64;
                let fy = y as f64 + c.motion.at(1, y, x) as f64;
                if fx.is_finite() && fy.is_finite() && fx > -1.0 && fy > -1.0 && fx < w as f64 && fy < h as f64 {
                    let (x0, y0) = (fx.floor(), fy.floor());
                    let (tx, ty) = (fx - x0, fy - y0);
                    for (dy, wy) in [(0.0, 1.0 - ty), (1.0, ty)] {
                        for (dx, wx) in [(0.0, 1.0 - tx), (1.0, tx)] {
                            let (py, px) = (y0 + dy, x0 + dx);
                            let wt = wx * wy;
                            if wt <= 0.0 || py < 0.0 || px < 0.0 || py >= h as f64 || px >= w as f64 {
                                continue;
                            }
                            let (py, px) = (py as usize, px as usize);
                            if agrees(y, x, py, px) {
                                taps.push((py, px, wt));
                            }
                        }
                    }
                }
            } else {
                let r = p.search_radius;
                let mut best: Option<(f64, usize, usize)> = None;
                for py in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for px in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let d = d2(&c.position, y, x, &c.prev_position, py, px);
                        if best.is_none_or(|(bd, _, _)| d < bd) {
                            best = Some((d, py, px));
                        }
                    }
                }
                if let Some((_, py, px)) = best {
                    if agrees(y, x, py, px) {
                        taps.push((py, px, 1.0));
                    }
                }
            }
            let i = y * w + x;
            let wsum: f64 = taps.iter().map(|t| t.2).sum();
            if wsum > 0.0 {
                let n = (taps.iter().map(|&(py, px, wt)| wt * c.prev_history.at(0, py, px) as f64).sum::<f64>() / wsum)
                    .max(0.0);
                let alpha = (1.0 / (n + 1.0)).max(p.alpha_min as f64);
                for ch in 0..3 {
                    let prev =
                        taps.iter().map(|&(py, px, wt)| wt * c.prev_color.at(ch, py, px) as f64).sum::<f64>() / wsum;
                    out[ch * w * h + i] = alpha * c.color.at(ch, y, x) as f64 + (1.0 - alpha) * prev;
                }
                hist[i] = (n + 1.0).min(p.history_cap as f64);
            } else {
                for ch in 0..3 {
                    out[ch * w * h + i] = c.color.at(ch, y, x) as f64;
                }
            }
        }
    }
    (out, hist)
}

/// The kernel in f32 (or f16 storage) over bands of `band` rows.
fn kernel<const F16S: bool>(c: &Case, motion: bool, isa: mcdenoise_core::Isa, band: usize) -> (Vec<f32>, Vec<f32>) {
    let (w, h) = (c.w, c.h);
    let mut out = vec![0.0f32; 3 * w * h];
    let mut hist = vec![0.0f32; w * h];
    if F16S {
        let cv = |i: &Img| i.to_f16();
        let (col, nrm, pos, mot, pc, pn, pp, ph) = (
            cv(&c.color),
            cv(&c.normal),
            cv(&c.position),
            cv(&c.motion),
            cv(&c.prev_color),
            cv(&c.prev_normal),
            cv(&c.prev_position),
            cv(&c.prev_history),
        );
        fn v(d: &[half::f16], ch: usize, w: usize, h: usize) -> View<'_, half::f16> {
            View::new(d, ch, w, h).unwrap()
        }
        let inp = TemporalInputs {
            color: v(&col, 3, w, h),
            normal: Some(v(&nrm, 3, w, h)),
            position: Some(v(&pos, 3, w, h)),
            motion: motion.then(|| v(&mot, 2, w, h)),
            prev_color: v(&pc, 3, w, h),
            prev_normal: Some(v(&pn, 3, w, h)),
            prev_position: Some(v(&pp, 3, w, h)),
            prev_history: v(&ph, 1, w, h),
        };
        let mut o16 = vec![half::f16::ZERO; 3 * w * h];
        let mut h16 = vec![half::f16::ZERO; w * h];
        let mut ov = ViewMut::new(&mut o16, 3, w, h).unwrap();
        let mut hv = ViewMut::new(&mut h16, 1, w, h).unwrap();
        for y0 in (0..h).step_by(band) {
            let n = band.min(h - y0);
            temporal::accumulate::<F16>(
                isa,
                &inp,
                &c.params,
                &mut ov.rows_mut(y0, n).unwrap(),
                &mut hv.rows_mut(y0, n).unwrap(),
                y0,
            )
            .unwrap();
        }
        out.iter_mut().zip(&o16).for_each(|(o, v)| *o = v.to_f32());
        hist.iter_mut().zip(&h16).for_each(|(o, v)| *o = v.to_f32());
    } else {
        let inp = TemporalInputs {
            color: c.color.view(),
            normal: Some(c.normal.view()),
            position: Some(c.position.view()),
            motion: motion.then(|| c.motion.view()),
            prev_color: c.prev_color.view(),
            prev_normal: Some(c.prev_normal.view()),
            prev_position: Some(c.prev_position.view()),
            prev_history: c.prev_history.view(),
        };
        let mut ov = ViewMut::new(&mut out, 3, w, h).unwrap();
        let mut hv = ViewMut::new(&mut hist, 1, w, h).unwrap();
        for y0 in (0..h).step_by(band) {
            let n = band.min(h - y0);
            temporal::accumulate::<F32>(
                isa,
                &inp,
                &c.params,
                &mut ov.rows_mut(y0, n).unwrap(),
                &mut hv.rows_mut(y0, n).unwrap(),
                y0,
            )
            .unwrap();
        }
    }
    (out, hist)
}

fn check(c: &Case, motion: bool, band: usize) {
    let (eo, eh) = oracle(c, motion);
    for isa in isas_under_test() {
        for f16 in [false, true] {
            let (o, hh) =
                if f16 { kernel::<true>(c, motion, isa, band) } else { kernel::<false>(c, motion, isa, band) };
            // f16 storage: inputs and outputs rounded to 11 bits (positions
            // up to 2^5 keep the geometry tests' margins).
            let rtol = if f16 { 4e-3 } else { 2e-6 };
            for (i, (&a, &b)) in o.iter().zip(&eo).enumerate() {
                assert!(
                    (a as f64 - b).abs() <= rtol * (1.0 + b.abs()),
                    "{isa:?} f16 {f16} motion {motion} {}x{} band {band}: colour {i}: {a} vs oracle {b}",
                    c.w,
                    c.h
                );
            }
            for (i, (&a, &b)) in hh.iter().zip(&eh).enumerate() {
                assert!(
                    (a as f64 - b).abs() <= rtol * (1.0 + b),
                    "{isa:?} f16 {f16} motion {motion}: history {i}: {a} vs {b}"
                );
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
    #[test]
    fn accumulation_matches_the_f64_oracle(w in 1usize..20, h in 1usize..12, seed in 0u64..1000, band in 1usize..6, motion in any::<bool>()) {
        check(&case(w, h, seed), motion, band);
    }
}

#[test]
fn accumulation_matches_the_f64_oracle_at_the_widths_that_matter() {
    for (w, h) in [(1, 1), (9, 5), (17, 9), (33, 4)] {
        for motion in [true, false] {
            check(&case(w, h, (w * 31 + h) as u64), motion, 3);
        }
    }
}

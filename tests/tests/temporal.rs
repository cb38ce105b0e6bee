//! Temporal accumulation against the project's f64 oracle
//! (`mcdenoise_kit::oracle::temporal`) on inputs the operator registry's
//! entries do not draw: NaN motion and motion far outside the image, every
//! pixel's geometry either agreeing or rejected by position, by normal or
//! by albedo,
//! history capped, odd sizes and bands of rows, f32 and f16 storage.

use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams, TemporalPrecision};
use mcdenoise_core::{View, ViewMut, F16, F32};
use mcdenoise_kit::oracle::{self, TemporalRef};
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

#[derive(Clone)]
struct Case {
    /// Colour channels.
    ch: usize,
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
    albedo: Img,
    prev_albedo: Img,
    params: TemporalParams,
}

/// Positions on a grid 1 unit apart (so a pixel's own previous position is
/// the unique nearest), each previous pixel either agreeing with the
/// current geometry (off by 0.1 of the limits) or not (3 times them).
fn case(w: usize, h: usize, seed: u64) -> Case {
    case_ch(3, w, h, seed)
}

/// [`case`] with `ch` colour channels (the geometry stays 3 planes).
fn case_ch(ch: usize, w: usize, h: usize, seed: u64) -> Case {
    let mut r = Lcg(seed);
    let params = TemporalParams {
        pos_limit: 0.5,
        normal_limit: 0.3,
        alpha_min: 0.2,
        history_cap: 16.0,
        search_radius: 2,
        albedo_limit: 0.3,
        // Every other seed with the history clamp, at several widths.
        clamp_sigma: if seed % 2 == 1 { [0.5, 1.0, 2.0][(seed / 2 % 3) as usize] } else { 0.0 },
        clamp_radius: (seed % 4) as usize,
        clamp_floor: [0.0, 0.5, 2.0][(seed / 3 % 3) as usize],
    };
    let mut c = Case {
        ch,
        w,
        h,
        color: Img::zeros(ch, w, h),
        normal: Img::zeros(3, w, h),
        position: Img::zeros(3, w, h),
        motion: Img::zeros(2, w, h),
        prev_color: Img::zeros(ch, w, h),
        prev_normal: Img::zeros(3, w, h),
        prev_position: Img::zeros(3, w, h),
        prev_history: Img::zeros(1, w, h),
        albedo: Img::zeros(3, w, h),
        prev_albedo: Img::zeros(3, w, h),
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
            for k in 0..ch {
                *c.color.at_mut(k, y, x) = (r.next() * 4.0) as f32;
                *c.prev_color.at_mut(k, y, x) = (r.next() * 4.0) as f32;
            }
            for ch in 0..3 {
                *c.position.at_mut(ch, y, x) = base[ch] as f32;
                *c.normal.at_mut(ch, y, x) = n[ch] as f32;
            }
            // The previous frame's geometry at this pixel: the same surface
            // moved a little, or another one.
            let (dp, dn, da) = match (r.next() * 5.0) as u32 {
                0 => (1.5, 0.0, 0.0),    // position rejected
                1 => (0.0, 0.9, 0.0),    // normal rejected
                2 => (0.0, 0.0, 0.9),    // albedo rejected
                _ => (0.05, 0.03, 0.03), // agrees
            };
            for ch in 0..3 {
                *c.prev_position.at_mut(ch, y, x) = (base[ch] + if ch == 0 { dp } else { 0.0 }) as f32;
                *c.prev_normal.at_mut(ch, y, x) = (n[ch] + if ch == 1 { dn } else { 0.0 }) as f32;
                let a = r.next();
                *c.albedo.at_mut(ch, y, x) = a as f32;
                *c.prev_albedo.at_mut(ch, y, x) = (a + if ch == 2 { da } else { 0.0 }) as f32;
            }
            *c.prev_history.at_mut(0, y, x) = (r.next() * 20.0).floor() as f32;
            let m = match (r.next() * 10.0) as u32 {
                0 => [f64::NAN, 0.0],
                1 => [(r.next() - 0.5) * 4.0 * w as f64, (r.next() - 0.5) * 4.0 * h as f64],
                2 => [(r.next() * 6.0).floor() - 3.0, (r.next() * 6.0).floor() - 3.0],
                _ => [(r.next() - 0.5) * 6.0, (r.next() - 0.5) * 6.0],
            };
            // A fractional part within 1e-4 of a whole pixel (but not on it)
            // is moved 1e-4 away: the kernels add motion to the pixel's
            // coordinate in f32, and a bilinear weight of 1e-7 that f32
            // rounds to 0 can be a pixel's only accepted tap, its whole
            // history (the renormalisation is discontinuous there).
            let m = m.map(|v| {
                let f = v - v.round();
                if f != 0.0 && f.abs() < 1e-4 {
                    v.round() + 1e-4_f64.copysign(f)
                } else {
                    v
                }
            });
            *c.motion.at_mut(0, y, x) = m[0] as f32;
            *c.motion.at_mut(1, y, x) = m[1] as f32;
        }
    }
    c
}

/// The project's f64 oracle (`mcdenoise_kit::oracle::temporal`) on a case:
/// (colour, history) of every pixel.
fn oracle(c: &Case, motion: bool) -> (Vec<f64>, Vec<f64>) {
    let (col, nrm, pos, mot) = (c.color.to_f64(), c.normal.to_f64(), c.position.to_f64(), c.motion.to_f64());
    let (pc, pn, pp, ph) =
        (c.prev_color.to_f64(), c.prev_normal.to_f64(), c.prev_position.to_f64(), c.prev_history.to_f64());
    let (al, pal) = (c.albedo.to_f64(), c.prev_albedo.to_f64());
    let t = TemporalRef {
        color: &col,
        normal: Some(&nrm),
        position: Some(&pos),
        motion: motion.then_some(&mot[..]),
        prev_color: &pc,
        prev_normal: Some(&pn),
        prev_position: Some(&pp),
        prev_history: &ph,
        albedo: Some(&al),
        prev_albedo: Some(&pal),
        c: c.ch,
        w: c.w,
        h: c.h,
    };
    let p = &c.params;
    let f = |v: f32| v as f64;
    oracle::temporal(
        &t,
        f(p.pos_limit),
        f(p.normal_limit),
        f(p.alpha_min),
        f(p.history_cap),
        p.search_radius,
        f(p.albedo_limit),
        (f(p.clamp_sigma), p.clamp_radius, f(p.clamp_floor)),
    )
}

/// The kernel in precision `P` over bands of `band` rows: the inputs
/// stored by `store`, the outputs read back by `load`.
fn kernel<P: TemporalPrecision>(
    c: &Case,
    motion: bool,
    isa: mcdenoise_core::Isa,
    band: usize,
    store: impl Fn(&Img) -> Vec<P::Store>,
    load: impl Fn(P::Store) -> f32,
) -> (Vec<f32>, Vec<f32>) {
    let (w, h) = (c.w, c.h);
    let bufs: Vec<Vec<P::Store>> = [
        &c.color,
        &c.normal,
        &c.position,
        &c.motion,
        &c.prev_color,
        &c.prev_normal,
        &c.prev_position,
        &c.prev_history,
        &c.albedo,
        &c.prev_albedo,
    ]
    .into_iter()
    .map(&store)
    .collect();
    let v = |i: usize, ch: usize| View::new(&bufs[i], ch, w, h).unwrap();
    let inp = TemporalInputs {
        color: v(0, c.ch),
        normal: Some(v(1, 3)),
        position: Some(v(2, 3)),
        motion: motion.then(|| v(3, 2)),
        prev_color: v(4, c.ch),
        prev_normal: Some(v(5, 3)),
        prev_position: Some(v(6, 3)),
        prev_history: v(7, 1),
        albedo: Some(v(8, 3)),
        prev_albedo: Some(v(9, 3)),
    };
    let mut out = vec![P::Store::default(); c.ch * w * h];
    let mut hist = vec![P::Store::default(); w * h];
    let mut ov = ViewMut::new(&mut out, c.ch, w, h).unwrap();
    let mut hv = ViewMut::new(&mut hist, 1, w, h).unwrap();
    for y0 in (0..h).step_by(band) {
        let n = band.min(h - y0);
        temporal::accumulate::<P>(
            isa,
            &inp,
            &c.params,
            &mut ov.rows_mut(y0, n).unwrap(),
            &mut hv.rows_mut(y0, n).unwrap(),
            y0,
        )
        .unwrap();
    }
    (out.into_iter().map(&load).collect(), hist.into_iter().map(&load).collect())
}

/// `c` as f16 storage holds it: every input rounded to 11 bits.
fn rounded_to_f16(c: &Case) -> Case {
    let mut r = c.clone();
    for img in [
        &mut r.color,
        &mut r.normal,
        &mut r.position,
        &mut r.motion,
        &mut r.prev_color,
        &mut r.prev_normal,
        &mut r.prev_position,
        &mut r.prev_history,
        &mut r.albedo,
        &mut r.prev_albedo,
    ] {
        for v in &mut img.data {
            *v = half::f16::from_f32(*v).to_f32();
        }
    }
    r
}

fn check(c: &Case, motion: bool, band: usize) {
    // The f16 kernels are held to the oracle run on what f16 storage holds,
    // as the fixed-point test below is: reprojection keeps only the taps
    // whose geometry agrees and renormalises their weights, so a motion of
    // -0.99983 px (rounded to -1 in f16) can turn a pixel's only accepted
    // tap, of weight 2e-4, into none, and its output from history into the
    // current colour.
    let exact = oracle(c, motion);
    let f16_stored = oracle(&rounded_to_f16(c), motion);
    for isa in isas_under_test() {
        for f16 in [false, true] {
            let (eo, eh) = if f16 { &f16_stored } else { &exact };
            let (o, hh) = if f16 {
                kernel::<F16>(c, motion, isa, band, |i| i.to_f16(), |v| v.to_f32())
            } else {
                kernel::<F32>(c, motion, isa, band, |i| i.data.clone(), |v| v)
            };
            // f16 storage: inputs and outputs rounded to 11 bits (positions
            // up to 2^5 keep the geometry tests' margins).
            let rtol = if f16 { 4e-3 } else { 2e-6 };
            for (i, (&a, &b)) in o.iter().zip(eo).enumerate() {
                assert!(
                    (a as f64 - b).abs() <= rtol * (1.0 + b.abs()),
                    "{isa:?} f16 {f16} motion {motion} {}x{} band {band}: colour {i}: {a} vs oracle {b}",
                    c.w,
                    c.h
                );
            }
            for (i, (&a, &b)) in hh.iter().zip(eh).enumerate() {
                assert!(
                    (a as f64 - b).abs() <= rtol * (1.0 + b),
                    "{isa:?} f16 {f16} motion {motion}: history {i}: {a} vs {b}"
                );
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: mcdenoise_tests::cases(24), ..ProptestConfig::default() })]
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

/// Two draws of the property above that once failed: a motion of -0.99983
/// px that f16 rounds to -1 (the pixel's only accepted tap, of weight 2e-4,
/// gone), and one whose bilinear weight f32 rounded to 0.
#[test]
fn accumulation_matches_the_f64_oracle_where_a_tap_weight_rounds_away() {
    for (w, h, seed) in [(8, 7, 104), (7, 6, 731), (10, 4, 731)] {
        check(&case(w, h, seed), true, 1);
    }
}

/// Every colour channel is reprojected, however many there are (the kernels
/// once took the history of the first four only and passed the rest
/// through; the cross-regression denoiser reprojects nine planes at once).
#[test]
fn accumulation_reprojects_every_colour_channel() {
    for ch in [1, 5, 9] {
        for motion in [true, false] {
            check(&case_ch(ch, 13, 7, 40 + ch as u64), motion, 2);
        }
    }
}

/// Fixed point against the oracle run on the inputs as fixed point stores
/// them (each buffer in a format that holds its range; NaN motion becomes
/// 0): every path, the albedo test included.
#[test]
fn fixed_point_accumulation_matches_the_f64_oracle() {
    use mcdenoise_core::Fixed;
    let q = |v: f32, frac: i8| -> i16 {
        let s = (v as f64 * f64::from(1u32 << frac)).round();
        if s.is_nan() {
            0
        } else {
            s.clamp(-32767.0, 32767.0) as i16
        }
    };
    // The colours at the sample's scale, and 2^-12 of it in formats 12 bits
    // finer (a dim render: the host's image formats reach 2^-22).
    for (w, h, seed, dim) in
        [(9, 5, 3u64, false), (17, 9, 8, false), (33, 4, 21, false), (17, 9, 8, true), (9, 5, 5, true)]
    {
        let (cs, cf) = if dim { (1.0 / 4096.0, 12) } else { (1.0, 0) };
        for motion in [true, false] {
            let mut c = case(w, h, seed);
            for img in [&mut c.color, &mut c.prev_color] {
                img.data.iter_mut().for_each(|v| *v *= cs);
            }
            // Motion within the format's range (the far-out draws clamp).
            let fracs: [i8; 10] = [10 + cf, 13, 9, 8, 10 + cf, 13, 9, 10, 13, 13];
            let imgs: Vec<&mut Img> = vec![
                &mut c.color,
                &mut c.normal,
                &mut c.position,
                &mut c.motion,
                &mut c.prev_color,
                &mut c.prev_normal,
                &mut c.prev_position,
                &mut c.prev_history,
                &mut c.albedo,
                &mut c.prev_albedo,
            ];
            let mut stored: Vec<Vec<i16>> = Vec::new();
            for (img, &f) in imgs.into_iter().zip(&fracs) {
                let s: Vec<i16> = img.data.iter().map(|&v| q(v, f)).collect();
                // The oracle sees what fixed point stores.
                for (d, &v) in img.data.iter_mut().zip(&s) {
                    *d = v as f32 / (1u32 << f) as f32;
                }
                stored.push(s);
            }
            let (eo, eh) = oracle(&c, motion);
            let v = |i: usize, ch: usize| View::new(&stored[i], ch, w, h).unwrap().with_frac(fracs[i]);
            let inp = TemporalInputs {
                color: v(0, 3),
                normal: Some(v(1, 3)),
                position: Some(v(2, 3)),
                motion: motion.then(|| v(3, 2)),
                prev_color: v(4, 3),
                prev_normal: Some(v(5, 3)),
                prev_position: Some(v(6, 3)),
                prev_history: v(7, 1),
                albedo: Some(v(8, 3)),
                prev_albedo: Some(v(9, 3)),
            };
            let mut out = vec![0i16; 3 * w * h];
            let mut hist = vec![0i16; w * h];
            temporal::accumulate::<Fixed>(
                mcdenoise_core::Isa::Scalar,
                &inp,
                &c.params,
                &mut ViewMut::new(&mut out, 3, w, h).unwrap().with_frac(10 + cf),
                &mut ViewMut::new(&mut hist, 1, w, h).unwrap().with_frac(10),
                0,
            )
            .unwrap();
            for (i, (&a, &b)) in out.iter().zip(&eo).enumerate() {
                let a = a as f64 / f64::from(1u32 << (10 + cf));
                let tol = 4e-3 * cs as f64;
                assert!((a - b).abs() <= tol, "{w}x{h} motion {motion} dim {dim}: colour {i}: {a} vs oracle {b}");
            }
            for (i, (&a, &b)) in hist.iter().zip(&eh).enumerate() {
                let a = a as f64 / 1024.0;
                assert!((a - b).abs() <= 4e-3, "{w}x{h} motion {motion} dim {dim}: history {i}: {a} vs oracle {b}");
            }
        }
    }
}

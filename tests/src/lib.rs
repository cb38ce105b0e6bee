//! The exact f64 reference every property test compares against, plus small
//! helpers. Written from the papers' equations, independently of the kernel
//! crate: no shift tricks, no tiling, no shared code. `exp` of a raw logit
//! would overflow f64 beyond 709, so the oracle subtracts the window maximum —
//! the one mathematically exact rewrite — and sums in f64.

pub use mcdenoise_kit::oracle;

use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};

/// A planar f32 image.
#[derive(Clone, Debug, PartialEq)]
pub struct Img {
    /// Planes.
    pub c: usize,
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
    /// `c * w * h` values, plane-major then row-major.
    pub data: Vec<f32>,
}

impl Img {
    /// All zeros.
    pub fn zeros(c: usize, w: usize, h: usize) -> Self {
        Img { c, w, h, data: vec![0.0; c * w * h] }
    }
    /// Filled with `v`.
    pub fn filled(c: usize, w: usize, h: usize, v: f32) -> Self {
        Img { c, w, h, data: vec![v; c * w * h] }
    }
    /// Uniform random values in `[lo, hi)`.
    pub fn random(c: usize, w: usize, h: usize, lo: f32, hi: f32, seed: u64) -> Self {
        let mut rng = SmallRng::seed_from_u64(seed);
        let data = (0..c * w * h).map(|_| rng.random_range(lo..hi)).collect();
        Img { c, w, h, data }
    }
    /// Element `(c, y, x)`.
    pub fn at(&self, c: usize, y: usize, x: usize) -> f32 {
        self.data[(c * self.h + y) * self.w + x]
    }
    /// Mutable element.
    pub fn at_mut(&mut self, c: usize, y: usize, x: usize) -> &mut f32 {
        &mut self.data[(c * self.h + y) * self.w + x]
    }
    /// A core view.
    pub fn view(&self) -> mcdenoise_core::View<'_, f32> {
        mcdenoise_core::View::new(&self.data, self.c, self.w, self.h).unwrap()
    }
    /// A core mutable view.
    pub fn view_mut(&mut self) -> mcdenoise_core::ViewMut<'_, f32> {
        mcdenoise_core::ViewMut::new(&mut self.data, self.c, self.w, self.h).unwrap()
    }
    /// As f64.
    pub fn to_f64(&self) -> Vec<f64> {
        self.data.iter().map(|&v| v as f64).collect()
    }
    /// Converted to f16 bits.
    pub fn to_f16(&self) -> Vec<half::f16> {
        self.data.iter().map(|&v| half::f16::from_f32(v)).collect()
    }
}

/// Largest `|a - b| / (atol + rtol |b|)` over two slices; `<= 1` means within tolerance.
pub fn worst_ratio(a: &[f32], b: &[f64], atol: f64, rtol: f64) -> (f64, usize) {
    assert_eq!(a.len(), b.len());
    let mut worst = (0.0, 0);
    for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
        let err = if x.is_nan() || y.is_nan() {
            if x.is_nan() && y.is_nan() {
                0.0
            } else {
                f64::INFINITY
            }
        } else {
            (x as f64 - y).abs() / (atol + rtol * y.abs())
        };
        if err > worst.0 {
            worst = (err, i);
        }
    }
    worst
}

/// Asserts `a` matches `b` within `atol + rtol |b|` everywhere, with a message naming the worst element.
#[track_caller]
pub fn assert_close(what: &str, a: &[f32], b: &[f64], atol: f64, rtol: f64) {
    let (r, i) = worst_ratio(a, b, atol, rtol);
    assert!(
        r <= 1.0,
        "{what}: element {i} is {} but the oracle says {} (ratio {r:.3} of atol {atol} + rtol {rtol})",
        a[i],
        b[i]
    );
}

/// Asserts two f32 slices are within `atol + rtol |b|` (NaN equal to NaN).
#[track_caller]
pub fn assert_close32(what: &str, a: &[f32], b: &[f32], atol: f32, rtol: f32) {
    assert_eq!(a.len(), b.len(), "{what}: lengths differ");
    for (i, (&x, &y)) in a.iter().zip(b).enumerate() {
        let ok = (x.is_nan() && y.is_nan()) || x == y || (x - y).abs() <= atol + rtol * y.abs();
        assert!(ok, "{what}: element {i}: {x} vs {y}");
    }
}

/// A property test's case count: `n` times the whole number in the
/// environment variable `MCDENOISE_PROPTEST_SCALE` (unset: 1). CI runs the
/// counts as written; a larger scale soaks the same properties on more
/// draws (`MCDENOISE_PROPTEST_SCALE=50 cargo test --release -p
/// mcdenoise-tests`), which is how a rare failing draw is looked for before
/// CI meets it.
///
/// # Panics
/// If the variable is set to anything but a positive whole number.
pub fn cases(n: u32) -> u32 {
    match std::env::var("MCDENOISE_PROPTEST_SCALE") {
        Err(_) => n,
        Ok(v) => match v.trim().parse::<u32>() {
            Ok(k) if k > 0 => n.saturating_mul(k),
            _ => panic!("MCDENOISE_PROPTEST_SCALE must be a positive whole number, got '{v}'"),
        },
    }
}

/// The instruction sets to test: every supported one; an unsupported one is
/// reported as skipped on stderr (once per test process), and is a failure when it is listed in the
/// environment variable `MCDENOISE_REQUIRE_ISAS` (comma-separated names), so a
/// CI machine known to have AVX2 cannot pass by skipping it.
pub fn isas_under_test() -> Vec<mcdenoise_core::Isa> {
    use mcdenoise_core::Isa;
    let required = std::env::var("MCDENOISE_REQUIRE_ISAS").unwrap_or_default();
    let mut out = Vec::new();
    for isa in Isa::ALL {
        if isa.is_supported() {
            out.push(isa);
        } else if required.split(',').any(|r| r.trim() == isa.name()) {
            panic!("instruction set {} is required by MCDENOISE_REQUIRE_ISAS but this CPU lacks it", isa.name());
        } else {
            static SAID: std::sync::Mutex<Vec<mcdenoise_core::Isa>> = std::sync::Mutex::new(Vec::new());
            let mut said = SAID.lock().unwrap_or_else(|e| e.into_inner());
            if !said.contains(&isa) {
                said.push(isa);
                eprintln!("skipped: instruction set {} is not supported here", isa.name());
            }
        }
    }
    out
}

/// The SIMD instruction sets under test (every supported one but scalar).
pub fn simd_isas() -> Vec<mcdenoise_core::Isa> {
    isas_under_test().into_iter().filter(|&i| i != mcdenoise_core::Isa::Scalar).collect()
}

/// A WSKP weights file of `layers` layers with initial (untrained, seeded)
/// parameters, written once per test process into the temporary directory:
/// for tests of the method's plumbing, not of its quality.
pub fn wskp_test_weights(layers: usize) -> std::path::PathBuf {
    use mcdenoise::nn::weights::{save_params, Form};
    let dir = std::env::temp_dir().join(format!("mcdenoise-test-{}", std::process::id()));
    let path = dir.join(format!("wskp{layers}.safetensors"));
    if !path.exists() {
        let net = mcdenoise::methods::wskp::net(layers).unwrap();
        // Small weights: logits of a few nats, every window carrying weight.
        let params: Vec<f32> = net.init(7).iter().map(|v| v * 0.3).collect();
        save_params(
            &path,
            &net,
            &params,
            Form::Branches,
            "wskp",
            &[("layers", layers.to_string()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
        )
        .unwrap();
    }
    path
}

/// Settings for `kind` with the test weights a learned method needs.
pub fn settings_for(
    kind: mcdenoise::methods::MethodKind,
    base: mcdenoise::methods::Settings,
) -> mcdenoise::methods::Settings {
    match kind {
        mcdenoise::methods::MethodKind::Wskp => {
            mcdenoise::methods::Settings { weights: Some(wskp_test_weights(base.layers)), ..base }
        }
        mcdenoise::methods::MethodKind::Afn => {
            mcdenoise::methods::Settings { weights: Some(afn_test_weights()), ..base }
        }
        _ => base,
    }
}

/// An AFN weights file with initial (untrained, seeded) parameters, written
/// once per test process: for tests of the method's plumbing.
pub fn afn_test_weights() -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("mcdenoise-test-{}", std::process::id()));
    let path = dir.join("afn.safetensors");
    if !path.exists() {
        let (k, r) = (mcdenoise::methods::afn::kernel_net().unwrap(), mcdenoise::methods::afn::refine_net().unwrap());
        // A small residual: the refinement starts near the identity.
        let rp: Vec<f32> = r.init(8).iter().map(|v| v * 0.05).collect();
        mcdenoise::methods::afn::save(&path, &k, &k.init(7), &r, &rp, &[]).unwrap();
    }
    path
}

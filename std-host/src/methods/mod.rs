//! The denoising methods behind `mcdenoise denoise --method M`.
//!
//! A method looks at the first frame's channels and builds only the stages
//! they allow: without albedo there is no (de)modulation, without motion and
//! position no temporal accumulation. It says in one line what it built and
//! what it skipped ([`Plan`]), allocates nothing for skipped stages, and a
//! method that cannot run without a buffer names it.

use std::time::{Duration, Instant};

use mcdenoise_core::Isa;

use crate::error::{HostError, Result};
use crate::io::frame::{Frame, FrameInfo};
use crate::runtime::memory::Footprint;
use crate::runtime::precision::{HostPrecision, PrecisionKind};
pub use crate::runtime::Ctx;

pub mod afn;
mod atrous;
mod basic;
pub mod bundled;
pub mod cross;
pub mod fallback;
pub mod features;
pub mod wide;
pub mod wskp;

pub use atrous::Atrous;
pub(crate) use basic::ta_builders;

pub use basic::{
    check_clamp, check_reject, check_reject_scales, clamp_plan, reject_plan, reject_stale, relight, relight_plan,
    scene_scale, ta_clamp_for, ta_clamp_of, Passthrough, TemporalAccumulation, CLAMP_STAGE, LEARNED_TA_REJECT,
    LEARNED_TA_REJECT_SCALES, POSITION_TOLERANCE, REJECT_SCALES, REJECT_STAGE, REJECT_STAGES, RELIGHT_CHECK_RADIUS,
    RELIGHT_COUNT, RELIGHT_MAX, RELIGHT_RADIUS, RELIGHT_STAGE, TA_CLAMP, TA_CLAMP_RADIUS, TA_REJECT, TA_REJECT_SCALES,
};

/// The methods, by command-line name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodKind {
    /// The input, through the same I/O and precision (for scoring the input).
    None,
    /// Temporal accumulation only (the baseline every learned method is compared with).
    Ta,
    /// Edge-avoiding à-trous wavelet filter, 5 levels (Dammertz et al. 2010).
    Atrous,
    /// À-trous with per-pixel SURE shrinkage of the detail coefficients (Kim, Moon, Yoon 2016).
    SureAtrous,
    /// Weight-sharing kernel prediction: TA, the ImportanceNet, the fused filter (Fan et al. 2021).
    Wskp,
    /// The adaptive fusion network: 1 spp and TA filtered at two scales, fused, refined (Lee et al. 2024).
    Afn,
    /// Cross-regression pilots and a U-Net trained online, one step per frame (Choi et al. 2024).
    Cross,
}

impl MethodKind {
    /// Every method.
    pub const ALL: [MethodKind; 7] = [
        MethodKind::None,
        MethodKind::Ta,
        MethodKind::Atrous,
        MethodKind::SureAtrous,
        MethodKind::Wskp,
        MethodKind::Afn,
        MethodKind::Cross,
    ];

    /// The command-line name.
    pub fn name(self) -> &'static str {
        match self {
            MethodKind::None => "none",
            MethodKind::Ta => "ta",
            MethodKind::Atrous => "atrous",
            MethodKind::Wskp => "wskp",
            MethodKind::Afn => "afn",
            MethodKind::SureAtrous => "sure-atrous",
            MethodKind::Cross => "cross",
        }
    }

    /// The buffers the method reads (in [`Buffer::ALL`](crate::io::frame::Buffer::ALL)
    /// order); the loader decodes no other.
    pub fn reads(self) -> [bool; 7] {
        use crate::io::frame::Buffer as B;
        let set = |bs: &[B]| {
            let mut m = [false; 7];
            for b in bs {
                m[*b as usize] = true;
            }
            m
        };
        match self {
            // (B, where the frame has it, for the pair's mean; see PairUse.)
            MethodKind::None => set(&[B::Color, B::ColorB]),
            // (B for the pair's mean and the history rejection's noise.)
            MethodKind::Ta => set(&[B::Color, B::ColorB, B::Albedo, B::Normal, B::Depth, B::Position, B::Motion]),
            MethodKind::Atrous | MethodKind::SureAtrous => {
                set(&[B::Color, B::ColorB, B::Albedo, B::Normal, B::Depth, B::Position])
            }
            // (B for the pair's mean and the fallback's and the history
            // rejection's noise, where the frame has it.)
            MethodKind::Wskp | MethodKind::Afn => {
                set(&[B::Color, B::ColorB, B::Albedo, B::Normal, B::Depth, B::Position, B::Motion])
            }
            MethodKind::Cross => set(&[B::Color, B::ColorB, B::Albedo, B::Normal, B::Position, B::Motion]),
        }
    }

    /// Parses a command-line name.
    pub fn parse(s: &str) -> Result<MethodKind> {
        MethodKind::ALL.into_iter().find(|m| m.name() == s).ok_or_else(|| {
            let names: Vec<&str> = MethodKind::ALL.iter().map(|m| m.name()).collect();
            HostError::Usage(format!("--method: expected one of {}; got '{s}'", names.join(", ")))
        })
    }
}

/// What a method built for a sequence and what it skipped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Plan {
    /// Stages that run, in order.
    pub built: Vec<&'static str>,
    /// Stages left out, with the reason.
    pub skipped: Vec<(&'static str, String)>,
}

impl Plan {
    /// One line for the user.
    pub fn line(&self, method: &str) -> String {
        let mut s =
            format!("{method}: stages {}", if self.built.is_empty() { "none".into() } else { self.built.join(" -> ") });
        if !self.skipped.is_empty() {
            let sk: Vec<String> = self.skipped.iter().map(|(st, why)| format!("{st} ({why})")).collect();
            s.push_str(&format!("; skipped: {}", sk.join(", ")));
        }
        s
    }
}

/// Accumulated wall time per stage.
#[derive(Clone, Debug, Default)]
pub struct Timings {
    stages: Vec<(&'static str, Duration, u32)>,
}

impl Timings {
    /// Runs `f`, adding its time to `stage`.
    pub fn time<T>(&mut self, stage: &'static str, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let r = f();
        let d = t.elapsed();
        match self.stages.iter_mut().find(|s| s.0 == stage) {
            Some(s) => {
                s.1 += d;
                s.2 += 1;
            }
            None => self.stages.push((stage, d, 1)),
        }
        r
    }
    /// `(stage, total, calls)` in first-use order.
    pub fn stages(&self) -> &[(&'static str, Duration, u32)] {
        &self.stages
    }
    /// Adds a measured duration to `stage` (one call).
    pub fn add(&mut self, stage: &'static str, d: Duration) {
        match self.stages.iter_mut().find(|s| s.0 == stage) {
            Some(s) => {
                s.1 += d;
                s.2 += 1;
            }
            None => self.stages.push((stage, d, 1)),
        }
    }
    /// Sum over stages.
    pub fn total(&self) -> Duration {
        self.stages.iter().map(|s| s.1).sum()
    }
}

/// Helpers the methods' unit tests share: deterministic noise.
#[cfg(test)]
pub(crate) mod test_noise {
    /// Standard normal draws, deterministic from `seed` (xorshift64, then
    /// Box-Muller).
    pub(crate) fn normal(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            let mut u = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (u1, u2) = (u(), u());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    /// Marsaglia's xorshift32 from `seed`: each call the next value.
    pub(crate) fn xorshift32(mut seed: u32) -> impl FnMut() -> u32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        }
    }

    /// The next of a linear congruential sequence (Numerical Recipes'
    /// constants), uniform in [0, 1).
    pub(crate) fn lcg(s: &mut u32) -> f32 {
        *s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (*s >> 8) as f32 / (1u32 << 24) as f32
    }
}

/// Settings every method shares.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// Instruction set for every kernel.
    pub isa: Isa,
    /// Worker threads.
    pub threads: usize,
    /// Storage/arithmetic precision.
    pub precision: PrecisionKind,
    /// À-trous colour edge-stopping multiple (`None`: the default, 64 with
    /// the second estimate, 2048 without).
    pub phi_color: Option<f32>,
    /// À-trous: the firefly clamp's threshold in local standard deviations
    /// (0: off; `None`: the default, 16 with the second estimate, 6 without).
    pub firefly_clamp: Option<f32>,
    /// Learned methods: network layers (WSKP: 3 or 6).
    pub layers: usize,
    /// Learned methods: a weights file instead of the bundled weights.
    pub weights: Option<std::path::PathBuf>,
    /// AFN: with the refinement network.
    pub refine: bool,
    /// WSKP, AFN and cross: fall back towards the input where the output differs
    /// from it by more than its noise explains ([`fallback`]).
    pub fallback: bool,
    /// WSKP and AFN: the wide pass where the history is short ([`wide`]).
    pub wide: bool,
    /// Temporal accumulation's history clamp, in standard deviations of
    /// the frame's 5x5 neighbourhood (0: off; `None`: `ta`'s default
    /// [`TA_CLAMP`], the learned methods' [`ta_clamp_for`] their weights).
    pub ta_clamp: Option<f32>,
    /// Temporal accumulation's history rejection, in standard errors of the
    /// frame's window means (9x9, and at [`REJECT_SCALES`] more;
    /// [`reject_stale`]; 0: off; `None`: [`TA_REJECT`], WSKP's and AFN's
    /// [`LEARNED_TA_REJECT`]).
    pub ta_reject: Option<f32>,
    /// How many of the history rejection's scales ([`REJECT_SCALES`]: 9x9,
    /// 17x17 and 33x33 means) it tests (`None`: [`TA_REJECT_SCALES`],
    /// WSKP's and AFN's [`LEARNED_TA_REJECT_SCALES`]).
    pub ta_reject_scales: Option<usize>,
    /// Temporal accumulation (ta, WSKP, AFN): relight the history where a
    /// light moved ([`relight`]; within the rejection).
    pub ta_relight: bool,
    /// Online methods: the seed of the initial weights.
    pub seed: u64,
    /// Online methods: write the network's state here after every frame.
    pub save_state: Option<std::path::PathBuf>,
    /// Online methods: start from this saved state instead of random weights.
    pub load_state: Option<std::path::PathBuf>,
    /// Cross: Adam's learning rate of the online step.
    pub cross_lr: f32,
    /// Cross: without temporal reuse (an ablation).
    pub cross_spatial_only: bool,
    /// AFN: hold the full-scale logits and kernels whole instead of
    /// streaming them in bands (for measuring what streaming saves; counted
    /// in the memory estimate).
    pub afn_whole_maps: bool,
    /// WSKP and AFN: emulate 8-bit networks (weights and activations
    /// rounded to `i8`/`u8`; float precisions only), to measure their error.
    pub emulate_int8: bool,
    /// What the methods make of a frame's second estimate `B.*`.
    pub pair: PairUse,
}

/// What the methods make of a frame's second estimate `B.*` (an independent
/// estimate of the same pixels, e.g. the second half of the samples).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PairUse {
    /// Every sample: `none`, `ta`, WSKP and AFN filter the mean `(A + B) / 2`
    /// ([`Frame::average_pair`]; their noise estimates take the mean's
    /// smaller variance from the pair), `atrous`, `sure-atrous` and `cross`
    /// read both estimates as they always do.
    #[default]
    Mean,
    /// `A` alone, as if the frame had no `B.*` (it is not read): the
    /// frame as a render of `A`'s samples, for comparing with denoisers
    /// that see one estimate. `cross` regresses on the pair and refuses it.
    First,
}

impl PairUse {
    /// The option's value: `mean` or `first`.
    pub fn name(self) -> &'static str {
        match self {
            PairUse::Mean => "mean",
            PairUse::First => "first",
        }
    }

    /// From the option's value.
    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "mean" => Some(PairUse::Mean),
            "first" => Some(PairUse::First),
            _ => None,
        }
    }
}

/// Readies a frame for `kind` under `pair`, in place (before the denoiser
/// sees it; the CLI and the Python package both do): under
/// [`PairUse::Mean`] the colour becomes the pair's mean for the methods
/// that filter one image (for WSKP and AFN without a firefly one estimate
/// alone holds where there is no albedo: [`features::clamp_pair_fireflies`]),
/// under [`PairUse::First`] `B.*` is dropped.
pub fn apply_pair(kind: MethodKind, pair: PairUse, frame: &mut Frame) {
    match pair {
        PairUse::Mean => {
            if matches!(kind, MethodKind::None | MethodKind::Ta | MethodKind::Wskp | MethodKind::Afn) {
                frame.average_pair();
            }
            if matches!(kind, MethodKind::Wskp | MethodKind::Afn) {
                features::clamp_pair_fireflies(frame);
            }
        }
        PairUse::First => frame.remove(crate::io::frame::Buffer::ColorB),
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            isa: Isa::detect(),
            threads: 1,
            precision: PrecisionKind::F32,
            phi_color: None,
            firefly_clamp: None,
            layers: 6,
            weights: None,
            refine: true,
            fallback: true,
            wide: true,
            ta_clamp: None,
            ta_reject: None,
            ta_reject_scales: None,
            ta_relight: true,
            seed: crate::methods::cross::SEED,
            save_state: None,
            load_state: None,
            cross_lr: crate::methods::cross::LR,
            cross_spatial_only: false,
            afn_whole_maps: false,
            emulate_int8: false,
            pair: PairUse::Mean,
        }
    }
}

/// A denoiser for one sequence: frames go in in order.
pub trait Denoiser: Send {
    /// The method's name.
    fn name(&self) -> &'static str;
    /// What it built and skipped.
    fn plan(&self) -> &Plan;
    /// Denoises the next frame into three f32 planes.
    fn denoise(&mut self, frame: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>>;
    /// Writes the method's learned state (cross-regression's network and
    /// Adam's state) to `path`; the other methods keep none.
    fn save_state(&self, _path: &std::path::Path) -> Result<()> {
        Err(HostError::Usage(format!("{} keeps no state to save (only cross does)", self.name())))
    }
}

/// Builds the denoiser for `kind` from the sequence's first frame. Every
/// later frame must have the first one's size (a denoiser keeps history and
/// buffers of that size; another size is an error naming both, never a
/// panic); an empty frame is refused.
pub fn create(kind: MethodKind, settings: &Settings, first: &Frame) -> Result<Box<dyn Denoiser>> {
    if first.width == 0 || first.height == 0 {
        return Err(HostError::bad(&first.path, format!("an empty {}x{} frame", first.width, first.height)));
    }
    let inner = create_unchecked(kind, settings, first)?;
    Ok(Box::new(OneSize { inner, size: (first.width, first.height) }))
}

/// A denoiser that refuses frames of another size than its first.
struct OneSize {
    inner: Box<dyn Denoiser>,
    size: (usize, usize),
}

impl Denoiser for OneSize {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn plan(&self) -> &Plan {
        self.inner.plan()
    }
    fn denoise(&mut self, frame: &Frame, ctx: &mut Ctx, t: &mut Timings) -> Result<Vec<f32>> {
        if (frame.width, frame.height) != self.size {
            return Err(HostError::bad(
                &frame.path,
                format!(
                    "a {}x{} frame, but this {} denoiser's sequence is {}x{} (make a new denoiser for another size)",
                    frame.width,
                    frame.height,
                    self.inner.name(),
                    self.size.0,
                    self.size.1
                ),
            ));
        }
        self.inner.denoise(frame, ctx, t)
    }
    fn save_state(&self, path: &std::path::Path) -> Result<()> {
        self.inner.save_state(path)
    }
}

fn create_unchecked(kind: MethodKind, settings: &Settings, first: &Frame) -> Result<Box<dyn Denoiser>> {
    if kind == MethodKind::Cross && settings.pair == PairUse::First {
        return Err(HostError::Usage(
            "--pair first: cross regresses on the two estimates A and B.*; it needs the pair".into(),
        ));
    }
    if settings.emulate_int8 && !matches!(kind, MethodKind::Wskp | MethodKind::Afn) {
        return Err(HostError::Usage(format!("--emulate-int8: {} has no network to emulate (wskp, afn)", kind.name())));
    }
    if kind == MethodKind::Cross {
        // Trained online in f32 whatever the storage precision asked for.
        let mut c = crate::methods::cross::Cross::new(
            first,
            settings.seed,
            settings.load_state.as_deref(),
            settings.save_state.clone(),
        )?
        .with_learning_rate(settings.cross_lr)?
        .with_fallback(settings.fallback);
        if settings.cross_spatial_only {
            c = c.spatial_only();
        }
        if settings.precision != PrecisionKind::F32 {
            c.note_precision(settings.precision.name());
        }
        return Ok(Box::new(c));
    }
    match settings.precision {
        PrecisionKind::F32 => create_in::<mcdenoise_core::F32>(kind, settings, first),
        PrecisionKind::F16 => create_in::<mcdenoise_core::F16>(kind, settings, first),
        PrecisionKind::F16Arith => create_in::<mcdenoise_core::F16Arith>(kind, settings, first),
        PrecisionKind::Fixed => create_in::<mcdenoise_core::Fixed>(kind, settings, first),
    }
}

fn create_in<P: HostPrecision>(kind: MethodKind, settings: &Settings, first: &Frame) -> Result<Box<dyn Denoiser>> {
    Ok(match kind {
        MethodKind::None => Box::new(Passthrough::<P>::new(first)),
        MethodKind::Ta => Box::new(
            TemporalAccumulation::<P>::new(first, true)?
                .with_clamp(settings.ta_clamp.unwrap_or(basic::TA_CLAMP))?
                .with_reject(settings.ta_reject.unwrap_or(basic::TA_REJECT))?
                .with_reject_scales(settings.ta_reject_scales.unwrap_or(basic::TA_REJECT_SCALES))?
                .with_relight(settings.ta_relight),
        ),
        MethodKind::Atrous => Box::new(Atrous::<P>::new(first, false, settings)?),
        MethodKind::SureAtrous => Box::new(Atrous::<P>::new(first, true, settings)?),
        MethodKind::Wskp => {
            let file = crate::methods::bundled::wskp(settings.weights.as_deref(), settings.layers)?;
            let mut m = crate::methods::wskp::Wskp::<P>::new(first, &file, settings.layers)?
                .with_fallback(settings.fallback)
                .with_wide(settings.wide)
                .with_int8(settings.emulate_int8)?;
            if let Some(k) = settings.ta_clamp {
                m = m.with_ta_clamp(k)?;
            }
            if let Some(z) = settings.ta_reject {
                m = m.with_ta_reject(z)?;
            }
            if let Some(k) = settings.ta_reject_scales {
                m = m.with_ta_reject_scales(k)?;
            }
            let m = m.with_ta_relight(settings.ta_relight);
            Box::new(m)
        }
        MethodKind::Afn => {
            let file = crate::methods::bundled::afn(settings.weights.as_deref())?;
            let mut m = crate::methods::afn::Afn::<P>::new(first, &file, settings.refine)?
                .with_whole_maps(settings.afn_whole_maps)
                .with_fallback(settings.fallback)
                .with_wide(settings.wide)
                .with_int8(settings.emulate_int8)?;
            if let Some(k) = settings.ta_clamp {
                m = m.with_ta_clamp(k)?;
            }
            if let Some(z) = settings.ta_reject {
                m = m.with_ta_reject(z)?;
            }
            if let Some(k) = settings.ta_reject_scales {
                m = m.with_ta_reject_scales(k)?;
            }
            let m = m.with_ta_relight(settings.ta_relight);
            Box::new(m)
        }
        MethodKind::Cross => unreachable!("built above"),
    })
}

/// The memory `kind` takes in `settings`' precision for frames like `info`,
/// declared by the method itself (see [`crate::runtime::memory`]): a new method adds
/// its entry here (the match is exhaustive, so it cannot be forgotten).
pub fn footprint(kind: MethodKind, settings: &Settings, info: &FrameInfo) -> Footprint {
    match settings.precision {
        PrecisionKind::F32 => footprint_in::<mcdenoise_core::F32>(kind, settings, info),
        PrecisionKind::F16 => footprint_in::<mcdenoise_core::F16>(kind, settings, info),
        PrecisionKind::F16Arith => footprint_in::<mcdenoise_core::F16Arith>(kind, settings, info),
        PrecisionKind::Fixed => footprint_in::<mcdenoise_core::Fixed>(kind, settings, info),
    }
}

fn footprint_in<P: HostPrecision>(kind: MethodKind, settings: &Settings, info: &FrameInfo) -> Footprint {
    let learned_scales = settings.ta_reject_scales.unwrap_or(basic::LEARNED_TA_REJECT_SCALES);
    match kind {
        MethodKind::None => Passthrough::<P>::footprint(info),
        MethodKind::Ta => {
            TemporalAccumulation::<P>::footprint(info, settings.ta_reject_scales.unwrap_or(basic::TA_REJECT_SCALES))
        }
        MethodKind::Atrous => Atrous::<P>::footprint(info, false, settings),
        MethodKind::SureAtrous => Atrous::<P>::footprint(info, true, settings),
        MethodKind::Wskp => crate::methods::wskp::Wskp::<P>::footprint(
            info,
            settings.layers,
            settings.threads,
            settings.wide,
            learned_scales,
        ),
        MethodKind::Afn => crate::methods::afn::Afn::<P>::footprint(
            info,
            settings.threads,
            settings.afn_whole_maps,
            settings.wide,
            learned_scales,
        ),
        MethodKind::Cross => crate::methods::cross::Cross::footprint(info),
    }
}

/// A context for `settings`.
pub fn context(settings: &Settings) -> Result<Ctx> {
    Ctx::new(settings.threads, settings.isa)
}

//! Instruction sets as an explicit, forceable value.
//!
//! Every operator takes an [`Isa`]. [`Isa::detect`] picks the best one this CPU
//! has; tests and benches force each in turn. Detection works without `std`:
//! on x86_64 it reads CPUID and XCR0 directly (cached in an atomic), and a
//! build with the features enabled at compile time (`-C target-feature=+avx2,+fma,+f16c`)
//! needs no run-time check at all. A forced ISA the CPU lacks is an error, never
//! a silent fallback to scalar.

/// An instruction-set family a kernel can be run with.
///
/// Which operators have their own kernel for each ISA (every other operator
/// runs the next ISA down; all paths agree with the scalar one to the
/// tolerances the tests state, and bit for bit where they say so):
///
/// | operator | `Avx2` | `Avx512` |
/// |---|---|---|
/// | 7x7 and other per-pixel kernel apply (f32, f16) | yes | yes |
/// | the same, fixed point | yes | AVX2 kernel |
/// | importance / fused filter (f32, f16): direct, separable | yes | AVX2 kernel |
/// | importance / fused filter (f32, f16): box-sum | yes | yes |
/// | importance kernels, channel softmax (f32, f16) | yes | AVX2 kernel |
/// | convolution 1x1 / 3x3 / 5x5 (f32, f16, fixed) | yes | yes (fixed: VNNI when present; over 400 taps or under 36 columns, the AVX2 kernel) |
/// | average / max pool, nearest upsample, scale compositor (f32, f16) | yes | AVX2 kernel |
/// | tone maps, (de)modulation (f32, f16) | yes | AVX2 kernel |
/// | à-trous step (f32, f16) | yes | AVX2 kernel |
/// | SURE shrinkage (f32, f16) | yes | yes |
/// | temporal accumulation | scalar | scalar |
/// | noise estimators: local noise, 3x3 median (f32) | scalar | scalar |
/// | backward: conv weight gradient (f32) | yes | yes |
/// | backward: conv input gradient (f32; the forward conv on transposed weights) | yes | yes |
/// | backward: fused filter, channel softmax, sigmoid, pools, nearest and bilinear upsample, compositor, per-pixel kernel apply; the bilinear upsample forward (f32) | compiled for AVX2 + FMA | compiled for AVX-512 |
/// | backward: activation gradient (f32) | scalar | scalar |
///
/// "Compiled for" means the portable loops built a second and third time
/// with that ISA's `target_feature`s (the `versions!` macro, or a
/// `#[target_feature]` copy of the tile function for the fused filter's
/// gradient): the compiler vectorises them, with no FMA contraction, so they
/// give the scalar path's bits.
///
/// `F16Arith` (every operation rounded to f16) is scalar only, and the fixed
/// point importance filters, pools, tone maps and à-trous step are scalar.
/// There is no aarch64 SIMD yet: on aarch64 everything runs [`Isa::Scalar`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Isa {
    /// Portable Rust, always available; the reference path.
    Scalar,
    /// x86_64 AVX2 with FMA and F16C (Haswell, Zen and later).
    Avx2,
    /// x86_64 AVX-512 (F, BW, DQ, VL) on top of AVX2, FMA and F16C (Skylake-SP,
    /// Ice Lake, Zen 4 and later); see the table above for the operators with a
    /// 16-lane kernel.
    Avx512,
}

impl Isa {
    /// Every ISA this crate knows, from the portable one to the widest.
    pub const ALL: [Isa; 3] = [Isa::Scalar, Isa::Avx2, Isa::Avx512];

    /// Short lower-case name (`scalar`, `avx2`, `avx512`).
    pub const fn name(self) -> &'static str {
        match self {
            Isa::Scalar => "scalar",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }

    /// Parses a name as printed by [`Isa::name`].
    pub fn from_name(s: &str) -> Option<Isa> {
        Isa::ALL.into_iter().find(|i| i.name() == s)
    }

    /// Whether this CPU (and this build) can run the ISA.
    pub fn is_supported(self) -> bool {
        match self {
            Isa::Scalar => true,
            Isa::Avx2 => avx2_fma_f16c(),
            Isa::Avx512 => avx2_fma_f16c() && avx512(),
        }
    }

    /// The best supported ISA.
    pub fn detect() -> Isa {
        if Isa::Avx512.is_supported() {
            Isa::Avx512
        } else if Isa::Avx2.is_supported() {
            Isa::Avx2
        } else {
            Isa::Scalar
        }
    }

    /// A [`Supported`] token when this CPU runs the ISA, else
    /// [`crate::Error::IsaUnsupported`]. The token is the only way to reach a
    /// SIMD kernel: every kernel takes one instead of a bare [`Isa`].
    pub fn check(self) -> crate::Result<Supported> {
        if self.is_supported() {
            Ok(Supported(self))
        } else {
            Err(crate::Error::IsaUnsupported { isa: self })
        }
    }
}

/// Proof that an [`Isa`] runs on this CPU. Only [`Isa::check`] (and
/// [`Supported::SCALAR`]) make one, so a kernel given a `Supported` may use the
/// ISA's instructions without checking again.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Supported(Isa);

impl Supported {
    /// The portable path, supported everywhere.
    pub const SCALAR: Supported = Supported(Isa::Scalar);

    /// The checked instruction set.
    #[inline(always)]
    pub const fn isa(self) -> Isa {
        self.0
    }
}

/// The result of `probe`, run once and kept in `state` (0: not probed yet,
/// 1: absent, 2: present; a race only probes twice).
#[cfg(target_arch = "x86_64")]
fn cached(state: &core::sync::atomic::AtomicU8, probe: fn() -> bool) -> bool {
    use core::sync::atomic::Ordering;
    match state.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => {
            let present = probe();
            state.store(if present { 2 } else { 1 }, Ordering::Relaxed);
            present
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn avx2_fma_f16c() -> bool {
    use core::sync::atomic::AtomicU8;
    if cfg!(all(target_feature = "avx2", target_feature = "fma", target_feature = "f16c")) {
        return true;
    }
    static STATE: AtomicU8 = AtomicU8::new(0);
    cached(&STATE, probe_avx2_fma_f16c)
}

#[cfg(not(target_arch = "x86_64"))]
fn avx2_fma_f16c() -> bool {
    false
}

#[cfg(target_arch = "x86_64")]
fn avx512() -> bool {
    use core::sync::atomic::AtomicU8;
    if cfg!(all(
        target_feature = "avx512f",
        target_feature = "avx512bw",
        target_feature = "avx512dq",
        target_feature = "avx512vl"
    )) {
        return true;
    }
    static STATE: AtomicU8 = AtomicU8::new(0);
    cached(&STATE, probe_avx512)
}

#[cfg(not(target_arch = "x86_64"))]
fn avx512() -> bool {
    false
}

/// AVX512_VNNI (CPUID leaf 7, ECX bit 11) beside [`Isa::Avx512`]: the
/// fixed-point convolution's AVX-512 kernel uses `vpdpwssd` when it is there
/// (the same exact sums as `vpmaddwd` + `vpaddd`).
#[cfg(target_arch = "x86_64")]
#[allow(unused_unsafe)]
pub(crate) fn avx512_vnni() -> bool {
    use core::sync::atomic::AtomicU8;
    if !avx512() {
        return false;
    }
    static STATE: AtomicU8 = AtomicU8::new(0);
    cached(&STATE, || {
        // SAFETY: the AVX2 probe behind avx512() checked max_leaf >= 7.
        let l7 = unsafe { core::arch::x86_64::__cpuid_count(7, 0) };
        l7.ecx & (1 << 11) != 0
    })
}

/// Leaf 7: AVX512F (EBX bit 16), DQ (17), BW (30), VL (31); XCR0 bits 5-7:
/// the OS saves the opmask registers and the upper ZMM state (checked after
/// the AVX2 probe, which established OSXSAVE).
#[cfg(target_arch = "x86_64")]
#[allow(unused_unsafe)]
fn probe_avx512() -> bool {
    use core::arch::x86_64::__cpuid_count;
    if !avx2_fma_f16c() {
        return false;
    }
    // SAFETY: OSXSAVE was checked by the AVX2 probe.
    let xcr0 = unsafe { xgetbv0() };
    if xcr0 & 0b1110_0110 != 0b1110_0110 {
        return false;
    }
    // SAFETY: the AVX2 probe checked max_leaf >= 7.
    let l7 = unsafe { __cpuid_count(7, 0) };
    let bit = |b: u32| l7.ebx & (1 << b) != 0;
    bit(16) && bit(17) && bit(30) && bit(31)
}

/// CPUID leaf 1: FMA (ECX bit 12), OSXSAVE (27), AVX (28), F16C (29);
/// leaf 7: AVX2 (EBX bit 5); XCR0 bits 1 and 2: the OS saves XMM and YMM state.
#[cfg(target_arch = "x86_64")]
#[allow(unused_unsafe)] // __cpuid is a safe fn on newer toolchains
fn probe_avx2_fma_f16c() -> bool {
    use core::arch::x86_64::{__cpuid, __cpuid_count};
    // SAFETY: CPUID exists on every x86_64 processor.
    let max_leaf = unsafe { __cpuid(0) }.eax;
    if max_leaf < 7 {
        return false;
    }
    // SAFETY: as above; leaf 1 is always valid.
    let l1 = unsafe { __cpuid(1) };
    let bit = |r: u32, b: u32| r & (1 << b) != 0;
    if !(bit(l1.ecx, 12) && bit(l1.ecx, 27) && bit(l1.ecx, 28) && bit(l1.ecx, 29)) {
        return false;
    }
    // SAFETY: OSXSAVE is set, so XGETBV is available.
    let xcr0 = unsafe { xgetbv0() };
    if xcr0 & 0b110 != 0b110 {
        return false;
    }
    // SAFETY: max_leaf >= 7.
    let l7 = unsafe { __cpuid_count(7, 0) };
    bit(l7.ebx, 5)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "xsave")]
unsafe fn xgetbv0() -> u64 {
    // SAFETY: the caller checked OSXSAVE.
    unsafe { core::arch::x86_64::_xgetbv(0) }
}

//! À-trous steps in f32 arithmetic over f32 or f16 storage.

use super::{AtrousGuides, AtrousParams, B3};
use crate::precision::FloatElement;
use crate::view::{View, ViewMut};
#[cfg(target_arch = "x86_64")]
use crate::Isa;

pub(crate) mod scalar;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;

/// How geometry stops edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Geometry {
    /// Distance from the tangent plane (normal and position).
    Plane,
    /// Euclidean position distance.
    Position,
    /// Relative depth difference.
    Depth,
    /// No geometry test.
    None,
}

/// Everything a step needs, resolved once.
pub(crate) struct Ctx<'c, 'a, S> {
    pub hole: usize,
    pub groups: usize,
    pub with_variance: bool,
    /// `phi_color * 2^-level`.
    pub color_scale: f32,
    pub eps: f32,
    /// `1 / sigma_normal^2` (0 without normals).
    pub inv_normal2: f32,
    pub geometry: Geometry,
    /// `1 / sigma^2` of the geometry term at this level.
    pub inv_geom2: f32,
    /// `1 / sigma_distance^2` of the plane geometry's distance term (0: off).
    pub inv_dist2: f32,
    pub guides: &'c AtrousGuides<'a, S>,
    pub src: &'c View<'a, S>,
}

impl<'c, 'a, S: FloatElement> Ctx<'c, 'a, S> {
    pub(crate) fn new(
        level: u32,
        groups: usize,
        with_variance: bool,
        p: &AtrousParams,
        guides: &'c AtrousGuides<'a, S>,
        src: &'c View<'a, S>,
    ) -> Self {
        let hole = 1usize << level;
        let scale = hole as f32;
        let (geometry, inv_geom2) = match (guides.normal.is_some(), guides.position.is_some(), guides.depth.is_some()) {
            (true, true, _) => (Geometry::Plane, 1.0 / (p.sigma_plane * p.sigma_plane)),
            (false, true, _) => (Geometry::Position, 1.0 / ((p.sigma_plane * scale) * (p.sigma_plane * scale))),
            (_, false, true) => (Geometry::Depth, 1.0 / ((p.sigma_depth * scale) * (p.sigma_depth * scale))),
            _ => (Geometry::None, 0.0),
        };
        Ctx {
            hole,
            groups,
            with_variance,
            color_scale: p.phi_color / scale,
            eps: p.eps,
            inv_normal2: if guides.normal.is_some() { 1.0 / (p.sigma_normal * p.sigma_normal) } else { 0.0 },
            geometry,
            inv_geom2,
            inv_dist2: if geometry == Geometry::Plane && p.sigma_distance > 0.0 {
                1.0 / (p.sigma_distance * p.sigma_distance)
            } else {
                0.0
            },
            guides,
            src,
        }
    }
}

/// The B3 tap weight of `(dy, dx)` in `0..5`.
#[inline(always)]
pub(crate) fn h2(dy: usize, dx: usize) -> f32 {
    B3[dy] * B3[dx]
}

/// Scratch floats [`step`] needs (the pair kernel's weight rings; the
/// scalar pixel needs none, but callers size it once for any ISA).
pub(crate) fn scratch_len(level: u32) -> usize {
    #[cfg(target_arch = "x86_64")]
    {
        avx2::scratch_len(level)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = level;
        0
    }
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn step<S: FloatElement, A: crate::real::Real>(
    isa: crate::isa::Supported,
    level: u32,
    groups: usize,
    with_variance: bool,
    params: &AtrousParams,
    guides: &AtrousGuides<'_, S>,
    src: &View<'_, S>,
    dst: &mut ViewMut<'_, S>,
    y0: usize,
    scratch: &mut [f32],
) {
    let ctx = Ctx::new(level, groups, with_variance, params, guides, src);
    match isa.isa() {
        // AVX-512 runs the AVX2 pair kernel: it does half the weight work of
        // the 16-lane per-tap kernel it replaced.
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `isa` is a `Supported` token: this CPU runs the ISA (AVX-512 implies AVX2/FMA/F16C
        // in `Isa`) and the scratch length.
        Isa::Avx2 | Isa::Avx512 if A::IS_F32 => unsafe { avx2::step(&ctx, dst, y0, scratch) },
        _ => {
            let _ = scratch;
            scalar::step::<S, A>(&ctx, dst, y0)
        }
    }
}

/// Pointers to one row of every plane a tap reads (the SIMD steps).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct RowPtrs<S> {
    pub(crate) src: [*const S; scalar::MAX_OUT],
    pub(crate) noise: *const S,
    pub(crate) normal: [*const S; 3],
    pub(crate) position: [*const S; 3],
    pub(crate) depth: *const S,
}

#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) fn rows<S: FloatElement>(c: &Ctx<'_, '_, S>, yy: usize) -> RowPtrs<S> {
    let null = core::ptr::null::<S>();
    let g = c.guides;
    let nsrc = 3 * c.groups + usize::from(c.with_variance);
    RowPtrs {
        src: core::array::from_fn(|ch| if ch < nsrc { c.src.ptr(ch, yy) } else { null }),
        noise: g.noise.ptr(0, yy),
        normal: core::array::from_fn(|k| g.normal.as_ref().map_or(null, |v| v.ptr(k, yy))),
        position: core::array::from_fn(|k| g.position.as_ref().map_or(null, |v| v.ptr(k, yy))),
        depth: g.depth.as_ref().map_or(null, |v| v.ptr(0, yy)),
    }
}

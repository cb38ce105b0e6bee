//! Entries of temporal accumulation: by motion, with position and normal rejection, by position search.

use mcdenoise_core::temporal::{self, TemporalInputs, TemporalParams};
use mcdenoise_core::{F16Arith, Fixed, Result as CoreResult, ViewMut, F16, F32};

use super::{base, full, image, no_scratch, per, Args, Field, Inputs, Op, Per, Prep, Run};
use crate::oracle;
use mcdenoise::runtime::precision::{HostPrecision, Kind};

/// The temporal entry's blend floor and history cap.
fn temporal_params() -> TemporalParams {
    TemporalParams { history_cap: 1e6, ..TemporalParams::default() }
}

fn k_temporal<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let inp = TemporalInputs {
        color: a.ins[0],
        normal: None,
        position: None,
        motion: Some(a.ins[1]),
        prev_color: a.ins[2],
        prev_normal: None,
        prev_position: None,
        prev_history: a.ins[3],
        albedo: None,
        prev_albedo: None,
    };
    temporal::accumulate::<P>(a.isa, &inp, &temporal_params(), c, hist, y0)
}

/// The rejecting entries' limits: block positions agree exactly or are at
/// least 0.25 apart (limit 0.1); unflipped synthetic normals differ by
/// `|dn|^2 < 1.08`, flipped ones by `>= 1.44` (limit `1.1^2 = 1.21`). So no
/// distance is near a limit in any precision.
fn temporal_reject_params() -> TemporalParams {
    TemporalParams { pos_limit: 0.1, normal_limit: 1.1, history_cap: 1e6, ..TemporalParams::default() }
}

/// The position-search entry's parameters: the true source pixel is an exact
/// match (distance 0, or a few fixed-point units), any other is far more
/// than 0.01 away in all but rare pixels.
fn temporal_search_params() -> TemporalParams {
    TemporalParams { pos_limit: 0.01, history_cap: 6.5, ..TemporalParams::default() }
}

/// Motion with position and normal rejection; inputs: colour, motion,
/// previous colour, history, positions (current, previous), normals
/// (current, previous).
fn k_temporal_reject<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let inp = TemporalInputs {
        color: a.ins[0],
        normal: Some(a.ins[6]),
        position: Some(a.ins[4]),
        motion: Some(a.ins[1]),
        prev_color: a.ins[2],
        prev_normal: Some(a.ins[7]),
        prev_position: Some(a.ins[5]),
        prev_history: a.ins[3],
        albedo: None,
        prev_albedo: None,
    };
    temporal::accumulate::<P>(a.isa, &inp, &temporal_reject_params(), c, hist, y0)
}

/// [`k_temporal_reject`] with the history as the checked output.
fn k_temporal_reject_hist<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    k_temporal_reject::<P>(a, c, hist, y0, s)
}

/// Reprojection by world-position search; inputs: colour, previous colour,
/// history, positions (current, previous).
fn k_temporal_search<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    y0: usize,
    _: &mut [f32],
) -> CoreResult<()> {
    let inp = TemporalInputs {
        color: a.ins[0],
        normal: None,
        position: Some(a.ins[3]),
        motion: None,
        prev_color: a.ins[1],
        prev_normal: None,
        prev_position: Some(a.ins[4]),
        prev_history: a.ins[2],
        albedo: None,
        prev_albedo: None,
    };
    temporal::accumulate::<P>(a.isa, &inp, &temporal_search_params(), c, hist, y0)
}

/// [`k_temporal_search`] with the history as the checked output.
fn k_temporal_search_hist<P: HostPrecision>(
    a: &Args<'_, P::Store>,
    hist: &mut ViewMut<'_, P::Store>,
    c: &mut ViewMut<'_, P::Store>,
    y0: usize,
    s: &mut [f32],
) -> CoreResult<()> {
    k_temporal_search::<P>(a, c, hist, y0, s)
}

fn o_temporal(i: &Inputs) -> Vec<f64> {
    let p = temporal_params();
    oracle::temporal_motion(
        &i.f64(Field::Radiance),
        &i.f64(Field::Motion),
        &i.f64(Field::Previous),
        &i.f64(Field::History),
        p.alpha_min as f64,
        3,
        i.w,
        i.h,
    )
}

/// The general temporal oracle on the registry's fields: `search` picks the
/// position-search entry, else the rejecting motion entry.
fn o_temporal_paths(i: &Inputs, search: bool) -> (Vec<f64>, Vec<f64>) {
    let (col, prev, hist) = (i.f64(Field::Radiance), i.f64(Field::Previous), i.f64(Field::History));
    let (pos, ppos) = (i.f64(Field::Position), i.f64(Field::PrevPosition));
    let (blocks, motion) = (i.f64(Field::Blocks), i.f64(Field::SafeMotion));
    let (n, pn) = (i.f64(Field::Normal), i.f64(Field::PrevNormal));
    let (p, t) = if search {
        let t = oracle::TemporalRef {
            color: &col,
            normal: None,
            position: Some(&pos),
            motion: None,
            prev_color: &prev,
            prev_normal: None,
            prev_position: Some(&ppos),
            prev_history: &hist,
            albedo: None,
            prev_albedo: None,
            c: 3,
            w: i.w,
            h: i.h,
        };
        (temporal_search_params(), t)
    } else {
        let t = oracle::TemporalRef {
            color: &col,
            normal: Some(&n),
            position: Some(&blocks),
            motion: Some(&motion),
            prev_color: &prev,
            prev_normal: Some(&pn),
            prev_position: Some(&blocks),
            prev_history: &hist,
            albedo: None,
            prev_albedo: None,
            c: 3,
            w: i.w,
            h: i.h,
        };
        (temporal_reject_params(), t)
    };
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

/// The temporal entries of [`ops`](super::ops), in report order.
pub(super) fn ops() -> Vec<Op> {
    use Field::*;
    let temporal_reject_ins = vec![
        image(Radiance),
        full(SafeMotion, 2, Kind::Plain),
        image(Previous),
        full(History, 1, Kind::Plain),
        full(Blocks, 3, Kind::Plain),
        full(Blocks, 3, Kind::Plain),
        full(Normal, 3, Kind::Unit),
        full(PrevNormal, 3, Kind::Unit),
    ];
    let temporal_search_ins = vec![
        image(Radiance),
        image(Previous),
        full(History, 1, Kind::Plain),
        full(Position, 3, Kind::Plain),
        full(PrevPosition, 3, Kind::Plain),
    ];
    vec![
        Op {
            oracle: |i, _| o_temporal(i),
            out2: Some((1, 8)),
            ..base(
                "temporal",
                "temporal accumulation: bilinear reprojection by motion, alpha = max(1/(n+1), 0.2)",
                vec![image(Radiance), full(Motion, 2, Kind::Plain), image(Previous), full(History, 1, Kind::Plain)],
                per!(Two, k_temporal, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, false).0,
            out2: Some((1, 8)),
            ..base(
                "temporal-reject",
                "temporal accumulation by motion, taps rejected by position and normal, the rest renormalised",
                temporal_reject_ins.clone(),
                per!(Two, k_temporal_reject, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, false).1,
            out: (1, false),
            out2: Some((3, 12)),
            ..base(
                "temporal-reject-hist",
                "the history the rejecting accumulation writes: min(n + 1, cap), 0 where every tap is rejected",
                temporal_reject_ins,
                per!(Two, k_temporal_reject_hist, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, true).0,
            out2: Some((1, 8)),
            ..base(
                "temporal-search",
                "temporal accumulation without motion: the closest previous world position within 2 pixels",
                temporal_search_ins.clone(),
                per!(Two, k_temporal_search, no_scratch),
            )
        },
        Op {
            oracle: |i, _| o_temporal_paths(i, true).1,
            out: (1, false),
            out2: Some((3, 12)),
            ..base(
                "temporal-search-hist",
                "the history of the position-search accumulation, capped at 6.5",
                temporal_search_ins,
                per!(Two, k_temporal_search_hist, no_scratch),
            )
        },
    ]
}

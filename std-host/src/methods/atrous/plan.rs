//! What `atrous` and `sure-atrous` build for a sequence: the stages its
//! first frame's buffers allow (the plan the CLI prints) and the filter's
//! parameters.

use std::marker::PhantomData;

use mcdenoise_core::atrous::AtrousParams;

use super::{Atrous, DISTANCE_TOLERANCE, FIREFLY_K, FIREFLY_K_PAIR, PHI_PAIR, PHI_SINGLE, PLANE_TOLERANCE};
use crate::error::Result;
use crate::io::frame::{Buffer, Frame};
use crate::methods::{scene_scale, Plan, Settings};
use crate::runtime::precision::HostPrecision;

impl<P: HostPrecision> Atrous<P> {
    /// For a sequence starting with `first`; `sure` selects `sure-atrous`.
    pub fn new(first: &Frame, sure: bool, settings: &Settings) -> Result<Self> {
        let name = if sure { "sure-atrous" } else { "atrous" };
        let pair = first.has(Buffer::ColorB);
        let demod = first.has(Buffer::Albedo);
        let use_normal = first.has(Buffer::Normal);
        let use_position = first.has(Buffer::Position);
        let use_depth = !use_position && first.has(Buffer::Depth);
        let mut plan = Plan::default();
        if demod {
            plan.built.push("demodulate");
        } else {
            plan.skipped.push(("demodulation", "no albedo".into()));
        }
        let clamp = settings.firefly_clamp.unwrap_or(if pair { FIREFLY_K_PAIR } else { FIREFLY_K });
        if clamp > 0.0 {
            plan.built.push("firefly clamp");
        } else {
            plan.skipped.push(("firefly clamp", "--firefly-clamp 0".into()));
        }
        plan.built.push(if pair { "noise from A-B" } else { "local noise estimate" });
        if pair {
            plan.built.push("mean of A and B");
        } else {
            plan.skipped.push(("second estimate", "no B.R,B.G,B.B: noise estimated locally".into()));
        }
        plan.built.push("5 a-trous levels");
        if sure {
            plan.built.push("SURE shrinkage");
        }
        if demod {
            plan.built.push("remodulate");
        }
        if !use_normal {
            plan.skipped.push(("normal edge-stopping", "no normal".into()));
        }
        if !use_position && !use_depth {
            plan.skipped.push(("geometry edge-stopping", "no position or depth".into()));
        }
        let scale = scene_scale(first);
        let params = AtrousParams {
            sigma_plane: PLANE_TOLERANCE * scale,
            sigma_distance: DISTANCE_TOLERANCE * scale,
            phi_color: settings.phi_color.unwrap_or(if pair { PHI_PAIR } else { PHI_SINGLE }),
            ..AtrousParams::default()
        };
        Ok(Atrous {
            name,
            plan,
            sure,
            pair,
            demod,
            use_normal,
            use_position,
            use_depth,
            params,
            phi_auto: settings.phi_color.is_none(),
            clamp,
            bufs: None,
            _p: PhantomData,
        })
    }
}

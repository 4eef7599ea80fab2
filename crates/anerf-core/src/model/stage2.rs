//! Stage 2: blend-weight fields for novel poses, trained against the frozen canonical field
//! (paper §3.4 "Animation", docs/REFERENCE.md §3.6).

use burn::prelude::*;

use super::animatable::{consistency_mask, residual_penalty};
use super::culling::surviving_indices;
use super::{AnimatableNerf, CanonicalInputs, FrameInputs};
use crate::tensor::to_host;

/// The terms of one stage-2 step, which the training crate's objective weighs: two consistency directions
/// and the new field's residual.
#[derive(Debug, Clone)]
pub struct Stage2Terms {
    /// Points sampled in the frame's box, warped to canonical space with `w_new`: `w_new(x)` vs `w^can(x')`.
    pub observation: Tensor<1>,
    /// Points sampled in the canonical box, skinned forward with `w^can`: `w_new(x)` vs `w^can(x_can)`.
    /// This second direction is in the authors' code, not in the paper.
    pub canonical: Tensor<1>,
    /// `mean(F²)` of the new field's residual over both point sets (zero without the neural field).
    pub residual: Tensor<1>,
}

impl Stage2Terms {
    /// Both consistency directions, `observation + canonical` (the authors' code weighs them alike).
    pub fn consistency(&self) -> Tensor<1> {
        self.observation.clone() + self.canonical.clone()
    }
}

impl AnimatableNerf {
    /// The stage-2 terms of one novel-pose frame (`frame.code` must be [`super::FrameCode::Novel`]).
    ///
    /// `pose_points` (`[P, 3]`, pose space) are uniform in the frame's body box; `canonical_points` (`[Q, 3]`)
    /// uniform in the canonical box. Points of the first set farther than `cull_distance` from the body are
    /// dropped before any MLP (the closest is always kept); in both sets only points whose frozen raw density
    /// is positive inside the canonical box (plus the densest) count.
    pub fn stage2_terms(
        &self,
        frame: &FrameInputs,
        canonical: &CanonicalInputs,
        pose_points: Tensor<2>,
        canonical_points: Tensor<2>,
    ) -> Stage2Terms {
        let kind = self.config().consistency;
        let device = pose_points.device();

        let distance = frame.volume.sample_distance(pose_points.clone());
        let keep = surviving_indices(&to_host(distance), self.config().cull_distance);
        let m = keep.len();
        let index = Tensor::<1, Int>::from_data(TensorData::new(keep, [m]), &device);
        let points = pose_points.select(0, index);
        let prior = frame.volume.sample(points.clone()).weights;
        let (w_new, residual_pose) = self.frame_blend(points.clone(), prior, frame.code);
        let warped = frame.bones.inverse(points, w_new.clone());
        let w_can = self.canonical_weights(warped.clone(), canonical);
        // Density is zero outside the canonical box, so the mask keeps only points inside it (and the densest).
        let mask = consistency_mask(self.canonical_density(warped, canonical));
        let observation = crate::render::blend_consistency(w_new, w_can, mask, kind);

        let w_can = self
            .canonical_weights(canonical_points.clone(), canonical)
            .detach();
        let posed = frame.bones.forward(canonical_points.clone(), w_can.clone());
        let prior = frame.volume.sample(posed.clone()).weights;
        let (w_new, residual_canonical) = self.frame_blend(posed, prior, frame.code);
        let mask = consistency_mask(self.canonical_density(canonical_points, canonical));
        let canonical_term = crate::render::blend_consistency(w_new, w_can, mask, kind);
        let residual = (residual_penalty(residual_pose, &device)
            + residual_penalty(residual_canonical, &device))
            * 0.5;

        Stage2Terms {
            observation,
            canonical: canonical_term,
            residual,
        }
    }
}

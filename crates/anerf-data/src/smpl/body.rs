//! The subject's body model ([`BodyModel`]: skeleton, canonical vertices, weights, faces) derived from an
//! SMPL-family model and one set of betas, as the authors' `prepare_lbs_meta.py` derives `lbs/` for
//! ZJU-MoCap: canonical = the T-pose with the subject's shape (`v_template + shapedirs · betas`), rest
//! joints regressed from it, the model's weights, parents and faces.
//!
//! Fits often drive only the first joints (SMPL-H/SMPL-X body poses drive 22 of 52/55). A joint that is
//! never rotated moves exactly as its parent (`A_k = G_parent · [I | −J_parent] = A_parent`), so its
//! skinning weight is folded into its nearest driven ancestor: the body has the driven joints only, and
//! LBS with it equals LBS with the full model.

use anerf_core::geometry::Skeleton;
use glam::Vec3;

use super::SmplModel;
use crate::subject::{BodyModel, SkinningWeights};

impl SmplModel {
    /// The canonical body for `betas`, over the first `driven` joints (1 ≤ driven ≤ K; the others folded
    /// into their nearest driven ancestor). Panics on counts outside the model (loaders check them).
    pub fn body(&self, betas: &[f64], driven: usize) -> BodyModel {
        let k = self.num_joints();
        assert!((1..=k).contains(&driven), "{driven} driven joints of {k}");
        let shaped = self.shaped(betas);
        let joints = self.regress_joints(&shaped);
        let owner = self.driven_owner(driven);
        let mut weights = vec![0f32; self.num_vertices() * driven];
        for (v, row) in weights.chunks_exact_mut(driven).enumerate() {
            for (j, &w) in self.vertex_weights(v).iter().enumerate() {
                row[owner[j]] += w as f32;
            }
        }
        let table: Vec<i64> = self.parents[..driven]
            .iter()
            .map(|p| p.map_or(-1, |p| p as i64))
            .collect();
        let rest: Vec<Vec3> = joints[..driven].iter().map(|j| j.as_vec3()).collect();
        BodyModel {
            skeleton: Skeleton::from_parent_table(rest, &table)
                .expect("a model's parents precede their joints"),
            canonical_vertices: shaped.iter().map(|v| v.as_vec3()).collect(),
            faces: self.faces.clone(),
            weights: SkinningWeights::new(weights, driven)
                .expect("folded convex weights stay convex"),
        }
    }

    /// For each joint, the driven joint (index < `driven`) it moves with: itself or its nearest driven
    /// ancestor (parents precede their joints, so the walk ends).
    fn driven_owner(&self, driven: usize) -> Vec<usize> {
        let mut owner: Vec<usize> = Vec::with_capacity(self.num_joints());
        for j in 0..self.num_joints() {
            owner.push(match self.parents[j] {
                _ if j < driven => j,
                Some(p) => owner[p],
                None => 0,
            });
        }
        owner
    }
}

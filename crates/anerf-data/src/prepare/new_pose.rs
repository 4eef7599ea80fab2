//! Poses from outside the dataset (pose files of the `params/{i}.npy` format): the body posed by forward
//! LBS of the canonical vertices, with the pose-space volume and world box a prepared dataset frame gets.

use std::path::Path;

use anerf_core::geometry::BlendWeightVolume;
use anerf_core::geometry::{Aabb, BoneTransforms, CanonicalPose, Pose};

use super::volumes::{compute_volume, NearestMethod};
use super::PreparedSubject;
use crate::error::DataError;
use crate::motion::TargetBody;

/// The subject's body in a new pose: what a [`super::PreparedFrame`] and its cached volume hold for a
/// dataset frame.
#[derive(Debug, Clone)]
pub struct PosedBody {
    pub pose: Pose,
    /// Canonical (T-pose) → pose space.
    pub bones: BoneTransforms,
    /// World-space box around the posed vertices, padded by the entry's `box_padding` (metres).
    pub bounds: Aabb,
    /// Blend weights and distance to the posed body in pose space.
    pub volume: BlendWeightVolume,
}

impl PreparedSubject {
    /// The body motions are retargeted onto: the subject's skeleton and canonical mesh.
    pub fn target_body(&self) -> TargetBody<'_> {
        TargetBody {
            skeleton: &self.skeleton,
            vertices: &self.canonical.vertices,
            weights: &self.canonical.weights,
        }
    }

    /// Poses the canonical body with `pose` (read from `source`, which errors name).
    ///
    /// The posed vertices are the canonical vertices skinned with the body model's weights; the datasets'
    /// own `new_vertices` also carry SMPL's pose-dependent corrective offsets, which a pose file cannot
    /// supply, so a dataset pose posed here differs from its frame by those offsets (millimetres). Volumes
    /// use the entry's nearest-point method and grid; entries prepared from the dataset's own volumes use
    /// the nearest vertex, as those were made.
    pub fn pose_body(&self, pose: &Pose, source: &Path) -> Result<PosedBody, DataError> {
        let invalid = |detail: String| DataError::invalid(source, detail);
        let bones = self
            .skeleton
            .bone_transforms(pose, CanonicalPose::TPose)
            .map_err(|e| invalid(e.to_string()))?;
        let k = self.skeleton.num_joints();
        let pose_space = self
            .target_body()
            .skinned(&bones)
            .map_err(|e| invalid(format!("{k}-joint body: {e}")))?;
        let bounds = Aabb::from_points(pose_space.iter().map(|&x| pose.global.pose_to_world(x)))
            .ok_or_else(|| invalid("the body has no vertices".into()))?
            .padded(self.options.box_padding);
        let nearest = if self.options.dataset_volumes {
            NearestMethod::Vertex
        } else {
            self.options.nearest
        };
        let volume = compute_volume(
            &pose_space,
            &self.canonical.faces,
            &self.canonical.weights,
            nearest,
            self.options.grid,
        );
        Ok(PosedBody {
            pose: pose.clone(),
            bones,
            bounds,
            volume,
        })
    }
}

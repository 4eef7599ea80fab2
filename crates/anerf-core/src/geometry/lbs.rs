//! Linear blend skinning for single points (glam): the per-vertex work of data preparation, synthetic
//! subjects and mesh reposing. The batched, differentiable version is [`super::skinning`].

use glam::{Mat3, Mat4, Vec3};

use super::skeleton::BoneTransforms;
use crate::GeometryError;

/// Tolerance on `Σ w_k = 1` accepted by [`validate_weights`].
pub const WEIGHT_SUM_TOLERANCE: f32 = 1e-3;

/// Smallest `|det|` of a blended rotation part that [`inverse_lbs_point`] accepts.
pub const MIN_BLEND_DET: f32 = 1e-6;

/// Checks one row of blend weights against the skeleton: right length, finite, non-negative, sums to 1.
pub fn validate_weights(weights: &[f32], num_joints: usize) -> Result<(), GeometryError> {
    if weights.len() != num_joints {
        return Err(GeometryError::WeightCountMismatch {
            expected: num_joints,
            got: weights.len(),
        });
    }
    if let Some(w) = weights.iter().find(|w| !w.is_finite()) {
        return Err(GeometryError::NonFinite {
            what: "blend weight".into(),
            value: w.to_string(),
        });
    }
    let sum: f32 = weights.iter().sum();
    if weights.iter().any(|&w| w < -WEIGHT_SUM_TOLERANCE)
        || (sum - 1.0).abs() > WEIGHT_SUM_TOLERANCE
    {
        return Err(GeometryError::WeightsNotNormalised {
            sum,
            tolerance: WEIGHT_SUM_TOLERANCE,
        });
    }
    Ok(())
}

/// `M = Σ_k w_k A_k`: the linearly blended 4×4 transform (not rigid in general).
pub fn blend_transforms(
    weights: &[f32],
    transforms: &BoneTransforms,
) -> Result<Mat4, GeometryError> {
    validate_weights(weights, transforms.len())?;
    Ok(weights
        .iter()
        .zip(transforms.matrices())
        .fold(Mat4::ZERO, |acc, (&w, a)| acc + *a * w))
}

/// Forward LBS, canonical → pose space: `x_pose = rot(M) x + t(M)`.
pub fn forward_lbs_point(
    x_canonical: Vec3,
    weights: &[f32],
    transforms: &BoneTransforms,
) -> Result<Vec3, GeometryError> {
    Ok(blend_transforms(weights, transforms)?.transform_point3(x_canonical))
}

/// [`forward_lbs_point`] of every point (a mesh's vertices, canonical → pose space): point `i` takes the
/// `K = transforms.len()` weights `weights[i·K..(i+1)·K]` (row-major, as body models store them). An error
/// names the point.
pub fn forward_lbs_points(
    points: &[Vec3],
    weights: &[f32],
    transforms: &BoneTransforms,
) -> Result<Vec<Vec3>, GeometryError> {
    let k = transforms.len();
    if weights.len() != points.len() * k {
        return Err(GeometryError::WeightRows {
            points: points.len(),
            joints: k,
            got: weights.len(),
        });
    }
    points
        .iter()
        .zip(weights.chunks_exact(k))
        .enumerate()
        .map(|(index, (&x, w))| {
            forward_lbs_point(x, w, transforms).map_err(|e| GeometryError::AtPoint {
                index,
                source: Box::new(e),
            })
        })
        .collect()
}

/// Inverse LBS, pose space → canonical: `x_can = rot(M)⁻¹ (x_pose − t(M))`, with `M` blended from the
/// observation-space weights. Fails when the blended rotation part is (nearly) singular.
pub fn inverse_lbs_point(
    x_pose: Vec3,
    weights: &[f32],
    transforms: &BoneTransforms,
) -> Result<Vec3, GeometryError> {
    let m = blend_transforms(weights, transforms)?;
    let r = Mat3::from_mat4(m);
    let det = r.determinant();
    if det.is_nan() || det.abs() < MIN_BLEND_DET {
        return Err(GeometryError::SingularBlend { det });
    }
    Ok(r.inverse() * (x_pose - m.w_axis.truncate()))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::{CanonicalPose, Pose, Skeleton};

    /// A small deterministic generator for property tests (SplitMix64).
    pub(crate) struct TestRng(pub u64);
    impl TestRng {
        pub(crate) fn next_f32(&mut self) -> f32 {
            self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
            ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
        }
        pub(crate) fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.next_f32()
        }
        pub(crate) fn vec3(&mut self, scale: f32) -> Vec3 {
            Vec3::new(
                self.range(-scale, scale),
                self.range(-scale, scale),
                self.range(-scale, scale),
            )
        }
        /// Random convex weights concentrated on a few joints, like skinning weights.
        pub(crate) fn weights(&mut self, k: usize) -> Vec<f32> {
            let mut w: Vec<f32> = (0..k).map(|_| self.next_f32().powi(8)).collect();
            let s: f32 = w.iter().sum();
            w.iter_mut().for_each(|v| *v /= s);
            w
        }
    }

    pub(crate) fn random_skeleton_and_pose(rng: &mut TestRng) -> (Skeleton, Pose) {
        let joints = (0..24).map(|_| rng.vec3(0.8)).collect();
        let skeleton = Skeleton::from_parent_table(joints, &Skeleton::SMPL_PARENTS).unwrap();
        let mut pose = Pose::zero(24);
        for r in &mut pose.joint_rotations {
            *r = rng.vec3(0.6);
        }
        pose.global.rh = rng.vec3(2.0);
        pose.global.th = rng.vec3(1.0);
        (skeleton, pose)
    }

    #[test]
    fn inverse_undoes_forward_for_random_weights_and_poses() {
        let mut rng = TestRng(7);
        for _ in 0..50 {
            let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
            let a = skeleton
                .bone_transforms(&pose, CanonicalPose::TPose)
                .unwrap();
            for _ in 0..20 {
                let x = rng.vec3(1.0);
                let w = rng.weights(24);
                let posed = forward_lbs_point(x, &w, &a).unwrap();
                let back = inverse_lbs_point(posed, &w, &a).unwrap();
                assert!((back - x).length() < 1e-4, "{x} -> {posed} -> {back}");
            }
        }
    }

    #[test]
    fn skinning_many_points_is_skinning_each_and_names_a_bad_one() {
        let mut rng = TestRng(11);
        let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
        let a = skeleton
            .bone_transforms(&pose, CanonicalPose::TPose)
            .unwrap();
        let points: Vec<Vec3> = (0..30).map(|_| rng.vec3(1.0)).collect();
        let mut weights: Vec<f32> = (0..30).flat_map(|_| rng.weights(24)).collect();
        let all = forward_lbs_points(&points, &weights, &a).unwrap();
        for (i, (x, p)) in points.iter().zip(&all).enumerate() {
            let one = forward_lbs_point(*x, &weights[i * 24..(i + 1) * 24], &a).unwrap();
            assert_eq!(*p, one, "point {i}");
        }
        assert!(matches!(
            forward_lbs_points(&points, &weights[..24 * 29], &a),
            Err(GeometryError::WeightRows { points: 30, joints: 24, got }) if got == 24 * 29
        ));
        weights[17 * 24 + 3] = f32::NAN;
        let err = forward_lbs_points(&points, &weights, &a).unwrap_err();
        assert!(
            matches!(&err, GeometryError::AtPoint { index: 17, source } if matches!(**source, GeometryError::NonFinite { .. })),
            "{err}"
        );
    }

    #[test]
    fn bad_weights_and_singular_blends_are_errors() {
        let a = BoneTransforms::from_matrices(vec![
            Mat4::IDENTITY,
            Mat4::from_rotation_z(std::f32::consts::PI),
        ])
        .unwrap();
        assert!(matches!(
            forward_lbs_point(Vec3::ONE, &[0.5, 0.4], &a),
            Err(GeometryError::WeightsNotNormalised { .. })
        ));
        assert!(matches!(
            forward_lbs_point(Vec3::ONE, &[1.0], &a),
            Err(GeometryError::WeightCountMismatch { .. })
        ));
        assert!(matches!(
            forward_lbs_point(Vec3::ONE, &[f32::NAN, 1.0], &a),
            Err(GeometryError::NonFinite { .. })
        ));
        // Half identity, half a half-turn about z: the blended x/y axes cancel.
        assert!(matches!(
            inverse_lbs_point(Vec3::ONE, &[0.5, 0.5], &a),
            Err(GeometryError::SingularBlend { .. })
        ));
    }
}

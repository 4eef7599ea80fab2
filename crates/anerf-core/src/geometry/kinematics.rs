//! Differentiable forward kinematics on Burn tensors: a frame's bone transforms under small corrections of
//! its body fit (each joint's rotation and the global motion), so that rendering losses reach the
//! corrections (pose refinement, docs/POSE-REFINEMENT.md).
//!
//! Frames and units: rotations are axis-angle (radians); a joint's correction is composed on the right of
//! its given rotation, `R'_k = R_k · exp(δ_k)`; the global correction on the right of `R_h`,
//! `R'_h = R_h · exp(δ_r)`, and `T'_h = T_h + δ_t` (metres, world space). The corrected bones are expressed
//! in the *given* fit's pose space (`x_pose = R_hᵀ (x_world − T_h)`), so that everything placed there from
//! the given fit (rays, the prior volume, culling) stays as it is:
//! `B_k = [exp(δ_r) | R_hᵀ δ_t] · A'_k` with `A'_k` the bone transforms of the corrected joint rotations.
//! Matrices are row-major `[.., 3, 3]` / `[.., 3, 1]` tensors acting on column vectors.

use burn::prelude::*;
use glam::{Mat3, Mat4, Vec3};

use super::rotation::{axis_angle_to_matrix, matrix_to_axis_angle};
use super::skeleton::{CanonicalPose, Pose, Skeleton};
use super::skinning::BoneMatrices;

/// A frame's given body fit on a device, ready for corrected bone transforms ([`PoseBasis::bones`]).
#[derive(Debug, Clone)]
pub struct PoseBasis {
    /// Joints in order of their depth in the tree, root first, and where each joint's parent lies in that
    /// order.
    levels: Vec<Level>,
    /// `[K]` position of each joint in the concatenated levels (to put joints back in index order).
    order: Tensor<1, Int>,
    /// `[K, 3, 3]` the given rotations `R_k`.
    given: Tensor<3>,
    /// `[K, 3, 1]` rest joints `J_k` (canonical space, metres).
    rest: Tensor<3>,
    /// The canonical pose's inverse transforms `B_k⁻¹` (`[K, 3, 3]`, `[K, 3, 1]`), `None` for the T-pose.
    canonical_inverse: Option<(Tensor<3>, Tensor<3>)>,
    /// `[3, 3]` `R_hᵀ` of the given fit.
    global_transposed: Tensor<2>,
    /// `[K, 12]` the given fit's bones as the host computes them, and as [`Self::corrected`] computes them
    /// at zero: [`Self::bones`] adds the difference a correction makes to the former, so that zero
    /// corrections give exactly the given bones.
    given_bones: Tensor<2>,
    zero_bones: Tensor<2>,
}

/// The joints of one depth of the tree.
#[derive(Debug, Clone)]
struct Level {
    /// `[n]` joint indices.
    joints: Tensor<1, Int>,
    /// `[n]` each joint's parent's position in the previous level (empty for the root level).
    parents: Option<Tensor<1, Int>>,
    /// `[n, 3, 1]` each joint's offset from its parent at rest, `J_k − J_parent` (the root: `J_0`).
    offsets: Tensor<3>,
}

impl PoseBasis {
    /// The basis of `pose` (the given fit) on `skeleton`, with canonical space `canonical`.
    pub fn new(
        skeleton: &Skeleton,
        pose: &Pose,
        canonical: CanonicalPose,
        device: &Device,
    ) -> Self {
        let k = skeleton.num_joints();
        let rest = skeleton.rest_joints();
        let parents = skeleton.parents();
        let mut depth = vec![0usize; k];
        for j in 1..k {
            depth[j] = depth[parents[j].expect("only joint 0 is a root")] + 1;
        }
        let deepest = depth.iter().copied().max().unwrap_or(0);
        let by_depth: Vec<Vec<usize>> = (0..=deepest)
            .map(|d| (0..k).filter(|&j| depth[j] == d).collect())
            .collect();
        let ints = |v: Vec<i64>| {
            Tensor::<1, Int>::from_data(TensorData::new(v.clone(), [v.len()]), device)
        };
        let mut levels = Vec::new();
        let mut order = vec![0i64; k];
        let mut placed = 0;
        for (d, joints) in by_depth.iter().enumerate() {
            let offsets: Vec<f32> = joints
                .iter()
                .flat_map(|&j| match parents[j] {
                    Some(p) => (rest[j] - rest[p]).to_array(),
                    None => rest[j].to_array(),
                })
                .collect();
            let parents_at = (d > 0).then(|| {
                ints(
                    joints
                        .iter()
                        .map(|&j| {
                            let p = parents[j].expect("joints below the root have parents");
                            by_depth[d - 1]
                                .iter()
                                .position(|&q| q == p)
                                .expect("the parent is one level up")
                                as i64
                        })
                        .collect(),
                )
            });
            for &j in joints {
                order[j] = placed as i64;
                placed += 1;
            }
            levels.push(Level {
                joints: ints(joints.iter().map(|&j| j as i64).collect()),
                parents: parents_at,
                offsets: column_vectors(&offsets, device),
            });
        }
        let given: Vec<Mat3> = pose
            .joint_rotations
            .iter()
            .map(|&r| axis_angle_to_matrix(r))
            .collect();
        let canonical_inverse = match canonical {
            CanonicalPose::TPose => None,
            CanonicalPose::BigPose => {
                let big = skeleton
                    .bone_transforms(&skeleton.big_pose(), CanonicalPose::TPose)
                    .expect("the big pose is valid");
                let inverse: Vec<Mat4> = big.matrices().iter().map(|m| m.inverse()).collect();
                let rotations: Vec<Mat3> = inverse.iter().map(|m| Mat3::from_mat4(*m)).collect();
                let translations: Vec<f32> = inverse
                    .iter()
                    .flat_map(|m| m.w_axis.truncate().to_array())
                    .collect();
                Some((
                    matrices(&rotations, device),
                    column_vectors(&translations, device),
                ))
            }
        };
        let rest_flat: Vec<f32> = rest.iter().flat_map(|j| j.to_array()).collect();
        let given_bones = skeleton
            .bone_transforms(pose, canonical)
            .expect("a prepared pose is valid");
        let mut basis = Self {
            levels,
            order: ints(order),
            given: matrices(&given, device),
            rest: column_vectors(&rest_flat, device),
            canonical_inverse,
            global_transposed: matrices(&[pose.global.rotation().transpose()], device)
                .reshape([3, 3]),
            given_bones: BoneMatrices::new(&given_bones, device).rows(),
            zero_bones: Tensor::zeros([k, 12], device),
        };
        let zeros = |rows| Tensor::<2>::zeros([rows, 3], device);
        basis.zero_bones = basis.corrected(zeros(k), zeros(1), zeros(1));
        basis
    }

    /// The bone transforms `[K, 12]` in the given fit's pose space under corrections `joints` `[K, 3]`
    /// (radians), `rotation` `[1, 3]` (radians) and `translation` `[1, 3]` (metres, world space): the given
    /// bones plus the change the corrections make, so that zero corrections give exactly the given bones.
    /// Differentiable in the corrections.
    pub fn bones(
        &self,
        joints: Tensor<2>,
        rotation: Tensor<2>,
        translation: Tensor<2>,
    ) -> BoneMatrices {
        let change = self.corrected(joints, rotation, translation) - self.zero_bones.clone();
        BoneMatrices::from_rows(self.given_bones.clone() + change)
    }

    /// The corrected bone rows `[K, 12]` by forward kinematics on the device.
    fn corrected(
        &self,
        joints: Tensor<2>,
        rotation: Tensor<2>,
        translation: Tensor<2>,
    ) -> Tensor<2> {
        let [k, _] = joints.dims();
        let local = self.given.clone().matmul(exp_so3(joints));
        let (mut rotations, mut translations) = (Vec::new(), Vec::new());
        for level in &self.levels {
            let own = local.clone().select(0, level.joints.clone());
            let (rot, t) = match &level.parents {
                None => (own, level.offsets.clone()),
                Some(parents) => {
                    let parent_rot: Tensor<3> = rotations.last().cloned().expect("the level above");
                    let parent_t: Tensor<3> =
                        translations.last().cloned().expect("the level above");
                    let parent_rot = parent_rot.select(0, parents.clone());
                    let parent_t = parent_t.select(0, parents.clone());
                    (
                        parent_rot.clone().matmul(own),
                        parent_rot.matmul(level.offsets.clone()) + parent_t,
                    )
                }
            };
            rotations.push(rot);
            translations.push(t);
        }
        // G_k in joint order; A_k = G_k · [I | −J_k].
        let rot = Tensor::cat(rotations, 0).select(0, self.order.clone());
        let t = Tensor::cat(translations, 0).select(0, self.order.clone());
        let t = t - rot.clone().matmul(self.rest.clone());
        let (rot, t) = match &self.canonical_inverse {
            None => (rot, t),
            Some((inv_rot, inv_t)) => (
                rot.clone().matmul(inv_rot.clone()),
                rot.matmul(inv_t.clone()) + t,
            ),
        };
        // [exp(δ_r) | R_hᵀ δ_t] · A'_k.
        let global = exp_so3(rotation).expand([k, 3, 3]);
        let shift = translation
            .matmul(self.global_transposed.clone().transpose())
            .reshape([1, 3, 1]);
        let rot_out = global.clone().matmul(rot);
        let t_out = global.matmul(t) + shift;
        Tensor::cat(vec![rot_out, t_out], 2).reshape([k, 12])
    }
}

/// Rotation matrices `[N, 3, 3]` of axis-angle rows `[N, 3]` (radians): Rodrigues'
/// `I + a [v]ₓ + b [v]ₓ²` with `a = sin θ/θ` and `b = (1 − cos θ)/θ²` from their Taylor series to θ⁶,
/// smooth at zero (where corrections start) and accurate to 1e-7 up to 0.5 rad, beyond any correction
/// allowed ([`MAX_CORRECTION_RADIANS`]).
pub fn exp_so3(v: Tensor<2>) -> Tensor<3> {
    let [n, _] = v.dims();
    let device = v.device();
    let t2 = v.clone().powi_scalar(2).sum_dim(1); // [N, 1]
    let series = |c: [f32; 4]| {
        let t4 = t2.clone().powi_scalar(2);
        let t6 = t4.clone() * t2.clone();
        (t2.clone() * c[1] + t4 * c[2] + t6 * c[3] + c[0]).reshape([n, 1, 1])
    };
    let a = series([1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0]);
    let b = series([0.5, -1.0 / 24.0, 1.0 / 720.0, -1.0 / 40320.0]);
    let c = |i: usize| v.clone().narrow(1, i, 1);
    let zero = Tensor::<2>::zeros([n, 1], &device);
    let skew = Tensor::cat(
        vec![
            zero.clone(),
            -c(2),
            c(1),
            c(2),
            zero.clone(),
            -c(0),
            -c(1),
            c(0),
            zero,
        ],
        1,
    )
    .reshape([n, 3, 3]);
    let identity = Tensor::<2>::eye(3, &device)
        .reshape([1, 3, 3])
        .expand([n, 3, 3]);
    identity + skew.clone() * a + skew.clone().matmul(skew) * b
}

/// Largest correction of a joint's or the global rotation accepted, radians (20°): beyond it the series of
/// [`exp_so3`] loses accuracy and a fit that far off is not a fit error to refine.
pub const MAX_CORRECTION_RADIANS: f32 = 0.35;

/// One frame's correction of its body fit, on the host (radians; metres, world space), as [`PoseBasis`]
/// composes it.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseCorrection {
    /// Per joint, composed on the right of its rotation.
    pub joints: Vec<Vec3>,
    /// Composed on the right of `R_h`.
    pub rotation: Vec3,
    /// Added to `T_h`.
    pub translation: Vec3,
}

impl PoseCorrection {
    /// `pose` corrected: `R'_k = R_k exp(δ_k)`, `R'_h = R_h exp(δ_r)`, `T'_h = T_h + δ_t`.
    pub fn apply(&self, pose: &Pose) -> Pose {
        let compose = |given: Vec3, delta: Vec3| {
            matrix_to_axis_angle(axis_angle_to_matrix(given) * axis_angle_to_matrix(delta))
        };
        let mut out = pose.clone();
        for (r, &d) in out.joint_rotations.iter_mut().zip(&self.joints) {
            *r = compose(*r, d);
        }
        out.global.rh = compose(pose.global.rh, self.rotation);
        out.global.th = pose.global.th + self.translation;
        out
    }
}

/// Row-major `[N, 3, 3]` of `mats`.
fn matrices(mats: &[Mat3], device: &Device) -> Tensor<3> {
    let rows: Vec<f32> = mats
        .iter()
        .flat_map(|m| m.transpose().to_cols_array())
        .collect();
    Tensor::<1>::from_floats(rows.as_slice(), device).reshape([mats.len(), 3, 3])
}

/// `[N, 3, 1]` column vectors of a flat `3·N` list.
fn column_vectors(flat: &[f32], device: &Device) -> Tensor<3> {
    Tensor::<1>::from_floats(flat, device).reshape([flat.len() / 3, 3, 1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::lbs::tests::{random_skeleton_and_pose, TestRng};
    use crate::tensor::{from_rows, to_host};
    use anerf_device::cpu_device;
    use anerf_testing::{assert_close, Tolerance};

    fn rows_of(bones: &crate::geometry::BoneTransforms) -> Vec<f32> {
        bones
            .matrices()
            .iter()
            .flat_map(|m| m.transpose().to_cols_array()[..12].to_vec())
            .collect()
    }

    /// Zero corrections give exactly the given fit's own bone transforms, and the device's forward
    /// kinematics agrees with the host's, for both canonical poses.
    #[test]
    fn zero_corrections_give_the_given_bones() {
        let device = cpu_device();
        let mut rng = TestRng(5);
        let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
        for canonical in [CanonicalPose::TPose, CanonicalPose::BigPose] {
            let basis = PoseBasis::new(&skeleton, &pose, canonical, &device);
            let zeros = |r| Tensor::<2>::zeros([r, 3], &device);
            let bones = basis.bones(zeros(24), zeros(1), zeros(1));
            let expected = skeleton.bone_transforms(&pose, canonical).unwrap();
            assert_eq!(
                to_host(bones.rows()),
                rows_of(&expected),
                "{canonical:?} bones"
            );
            assert_close(
                &format!("{canonical:?} bones by forward kinematics on the device"),
                &to_host(basis.zero_bones.clone()),
                &rows_of(&expected),
                Tolerance::Absolute(2e-6),
            );
        }
    }

    /// Corrected bones in the given pose space carry the canonical body where the corrected pose puts it:
    /// `R_h B_k x + T_h = R'_h A''_k x + T'_h`, with `A''` the host bone transforms of
    /// [`PoseCorrection::apply`]'s pose (an independent composition: glam, matrix logarithm included).
    #[test]
    fn corrected_bones_place_the_body_as_the_corrected_pose_does() {
        let device = cpu_device();
        let mut rng = TestRng(8);
        let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
        let correction = PoseCorrection {
            joints: (0..24).map(|_| rng.vec3(0.2)).collect(),
            rotation: rng.vec3(0.2),
            translation: rng.vec3(0.05),
        };
        let corrected = correction.apply(&pose);
        for canonical in [CanonicalPose::TPose, CanonicalPose::BigPose] {
            let basis = PoseBasis::new(&skeleton, &pose, canonical, &device);
            let flat = |v: &[Vec3]| -> Vec<f32> { v.iter().flat_map(|x| x.to_array()).collect() };
            let bones = basis.bones(
                from_rows(&flat(&correction.joints), 24, 3, &device),
                from_rows(&correction.rotation.to_array(), 1, 3, &device),
                from_rows(&correction.translation.to_array(), 1, 3, &device),
            );
            let got = to_host(bones.rows());
            let expected = skeleton.bone_transforms(&corrected, canonical).unwrap();
            let given = pose.global.pose_to_world_matrix();
            let wanted = corrected.global.pose_to_world_matrix();
            for (k, a) in expected.matrices().iter().enumerate() {
                let row = &got[k * 12..(k + 1) * 12];
                let mut b = Mat4::IDENTITY.to_cols_array_2d();
                for r in 0..3 {
                    for c in 0..4 {
                        b[c][r] = row[r * 4 + c];
                    }
                }
                let world_got = given * Mat4::from_cols_array_2d(&b);
                let world_expected = wanted * *a;
                assert_close(
                    &format!("{canonical:?} bone {k} in world space"),
                    &world_got.to_cols_array(),
                    &world_expected.to_cols_array(),
                    Tolerance::Absolute(2e-5),
                );
            }
        }
    }

    /// The series rotation equals Rodrigues' closed form (glam) up to the correction bound.
    #[test]
    fn the_series_rotation_matches_rodrigues() {
        let device = cpu_device();
        let mut rng = TestRng(3);
        let v: Vec<Vec3> = (0..64)
            .map(|i| rng.vec3(1.0).normalize() * MAX_CORRECTION_RADIANS * i as f32 / 63.0)
            .collect();
        let flat: Vec<f32> = v.iter().flat_map(|x| x.to_array()).collect();
        let got = to_host(exp_so3(from_rows(&flat, 64, 3, &device)));
        let expected: Vec<f32> = v
            .iter()
            .flat_map(|&x| axis_angle_to_matrix(x).transpose().to_cols_array())
            .collect();
        assert_close("exp", &got, &expected, Tolerance::Absolute(2e-7));
    }
}

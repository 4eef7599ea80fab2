//! Kinematic skeletons, per-frame poses and the bone transforms `A_k` that carry the canonical body
//! into pose space (docs/REFERENCE.md §2).

use glam::{Mat3, Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use super::rotation::axis_angle_to_matrix;
use crate::GeometryError;

/// A joint tree: rest-pose joint positions (canonical space, metres) and each joint's parent.
///
/// Invariants (checked by [`Skeleton::new`]): joint 0 is the only root and every other joint's parent has
/// a smaller index, so chaining transforms in index order visits parents first. The joint count comes
/// from the data; nothing assumes SMPL's 24.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    rest_joints: Vec<Vec3>,
    parents: Vec<Option<usize>>,
}

impl Skeleton {
    /// SMPL's parent table (24 joints), for synthetic bodies and tests.
    pub const SMPL_PARENTS: [i64; 24] = [
        -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
    ];

    /// Validates and builds a skeleton. `parents[0]` must be `None`; every other entry `Some(p)` with `p < k`.
    pub fn new(rest_joints: Vec<Vec3>, parents: Vec<Option<usize>>) -> Result<Self, GeometryError> {
        if rest_joints.is_empty() {
            return Err(GeometryError::EmptySkeleton);
        }
        if rest_joints.len() != parents.len() {
            return Err(GeometryError::ParentCountMismatch {
                joints: rest_joints.len(),
                parents: parents.len(),
            });
        }
        if let Some(p) = parents[0] {
            return Err(GeometryError::RootNotFirst { parent: p });
        }
        for (k, parent) in parents.iter().enumerate().skip(1) {
            match *parent {
                None => return Err(GeometryError::SecondRoot { joint: k }),
                Some(p) if p >= k => {
                    return Err(GeometryError::ParentNotBefore {
                        joint: k,
                        parent: p,
                    })
                }
                Some(_) => {}
            }
        }
        for (k, j) in rest_joints.iter().enumerate() {
            check_finite(&format!("rest joint {k}"), *j)?;
        }
        Ok(Self {
            rest_joints,
            parents,
        })
    }

    /// Builds a skeleton from a parent table in the datasets' integer form, where the root's entry is any
    /// negative number or the uint32 sentinel 4294967295 (`lbs/parents.npy`).
    pub fn from_parent_table(rest_joints: Vec<Vec3>, table: &[i64]) -> Result<Self, GeometryError> {
        let parents = table
            .iter()
            .map(|&p| {
                if p < 0 || p >= u32::MAX as i64 {
                    None
                } else {
                    Some(p as usize)
                }
            })
            .collect();
        Self::new(rest_joints, parents)
    }

    /// Number of joints `K`.
    pub fn num_joints(&self) -> usize {
        self.rest_joints.len()
    }

    /// Rest-pose joint positions in canonical space (metres).
    pub fn rest_joints(&self) -> &[Vec3] {
        &self.rest_joints
    }

    /// Parent of each joint (`None` for the root).
    pub fn parents(&self) -> &[Option<usize>] {
        &self.parents
    }

    /// World transforms `G_k` of each joint frame for per-joint rotations `rotations` (canonical → pose
    /// space, before removing the rest position): `G_0 = [R_0 | J_0]`, `G_k = G_parent · [R_k | J_k − J_parent]`.
    fn chain(&self, rotations: &[Mat3]) -> Vec<Mat4> {
        let mut global: Vec<Mat4> = Vec::with_capacity(self.num_joints());
        for (k, (rot, joint)) in rotations.iter().zip(&self.rest_joints).enumerate() {
            let local_t = match self.parents[k] {
                Some(p) => *joint - self.rest_joints[p],
                None => *joint,
            };
            let local = rigid(*rot, local_t);
            global.push(match self.parents[k] {
                Some(p) => global[p] * local,
                None => local,
            });
        }
        global
    }

    /// Bone transforms `A_k` (canonical → pose space) for `pose`, computed as the reference does:
    /// `A_k = G_k · [I | −J_k]`. With `canonical = BigPose`, the canonical space is the big pose and the
    /// transforms are `A_k · B_k⁻¹` with `B_k` the big pose's own transforms.
    pub fn bone_transforms(
        &self,
        pose: &Pose,
        canonical: CanonicalPose,
    ) -> Result<BoneTransforms, GeometryError> {
        pose.validate(self.num_joints())?;
        let rotations: Vec<Mat3> = pose
            .joint_rotations
            .iter()
            .map(|&t| axis_angle_to_matrix(t))
            .collect();
        let posed = self.rest_relative(&rotations);
        let mats = match canonical {
            CanonicalPose::TPose => posed,
            CanonicalPose::BigPose => {
                let big = self.rest_relative(&self.big_pose_rotations());
                posed
                    .iter()
                    .zip(big)
                    .map(|(a, b)| *a * b.inverse())
                    .collect()
            }
        };
        Ok(BoneTransforms { mats })
    }

    fn rest_relative(&self, rotations: &[Mat3]) -> Vec<Mat4> {
        self.chain(rotations)
            .into_iter()
            .zip(&self.rest_joints)
            .map(|(g, j)| g * Mat4::from_translation(-*j))
            .collect()
    }

    /// The TPAMI code's "big pose": T-pose with the hips (joints 1 and 2) abducted by ±30° about z, at
    /// the origin. Skeletons with fewer than three joints have no hips and stay in T-pose.
    pub fn big_pose(&self) -> Pose {
        let mut pose = Pose::zero(self.num_joints());
        if self.num_joints() > 2 {
            let a = 30f32.to_radians();
            pose.joint_rotations[1] = Vec3::Z * a;
            pose.joint_rotations[2] = Vec3::Z * -a;
        }
        pose
    }

    fn big_pose_rotations(&self) -> Vec<Mat3> {
        self.big_pose()
            .joint_rotations
            .iter()
            .map(|&t| axis_angle_to_matrix(t))
            .collect()
    }
}

/// Which canonical space the model lives in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CanonicalPose {
    /// Zero pose, as in the ICCV code (`tvertices.npy`, `tbw.npy`).
    #[default]
    TPose,
    /// Hips abducted ±30°, as in the TPAMI code (fewer self-contacts between the legs).
    BigPose,
}

/// The global rigid motion of a frame: `x_world = R_h x_pose + T_h`, with `R_h = Rodrigues(Rh)`
/// (rotation about the origin, EasyMocap/ZJU convention) and `T_h` in metres.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct GlobalTransform {
    /// Axis-angle `Rh` (radians).
    pub rh: Vec3,
    /// Translation `Th` (metres).
    pub th: Vec3,
}

impl GlobalTransform {
    /// `R_h` as a matrix.
    pub fn rotation(&self) -> Mat3 {
        axis_angle_to_matrix(self.rh)
    }

    /// World → pose space: `R_hᵀ (x − T_h)`.
    pub fn world_to_pose(&self, x_world: Vec3) -> Vec3 {
        self.rotation().transpose() * (x_world - self.th)
    }

    /// Pose space → world: `R_h x + T_h`.
    pub fn pose_to_world(&self, x_pose: Vec3) -> Vec3 {
        self.rotation() * x_pose + self.th
    }

    /// The 4×4 matrix of [`GlobalTransform::pose_to_world`].
    pub fn pose_to_world_matrix(&self) -> Mat4 {
        rigid(self.rotation(), self.th)
    }
}

/// One frame's body pose: per-joint axis-angle rotations (radians, relative to the parent) and the
/// global rigid motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub joint_rotations: Vec<Vec3>,
    pub global: GlobalTransform,
}

impl Pose {
    /// The zero pose of `k` joints at the world origin.
    pub fn zero(k: usize) -> Self {
        Self {
            joint_rotations: vec![Vec3::ZERO; k],
            global: GlobalTransform::default(),
        }
    }

    /// Builds a pose from a flat `3·K` axis-angle array (the datasets' `poses`), `Rh` and `Th`.
    pub fn from_flat(poses: &[f32], rh: [f32; 3], th: [f32; 3]) -> Result<Self, GeometryError> {
        if !poses.len().is_multiple_of(3) {
            return Err(GeometryError::PoseLength { len: poses.len() });
        }
        let pose = Self {
            joint_rotations: poses
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect(),
            global: GlobalTransform {
                rh: rh.into(),
                th: th.into(),
            },
        };
        pose.validate(pose.joint_rotations.len())?;
        Ok(pose)
    }

    /// Checks the joint count and that every number is finite.
    pub fn validate(&self, num_joints: usize) -> Result<(), GeometryError> {
        if self.joint_rotations.len() != num_joints {
            return Err(GeometryError::PoseSizeMismatch {
                expected: num_joints,
                got: self.joint_rotations.len(),
            });
        }
        for (k, r) in self.joint_rotations.iter().enumerate() {
            check_finite(&format!("rotation of joint {k}"), *r)?;
        }
        check_finite("Rh", self.global.rh)?;
        check_finite("Th", self.global.th)
    }
}

/// Per-joint 4×4 rigid transforms `A_k` mapping canonical space to pose space (metres, column vectors).
#[derive(Debug, Clone, PartialEq)]
pub struct BoneTransforms {
    mats: Vec<Mat4>,
}

impl BoneTransforms {
    /// Wraps already computed matrices (e.g. read from disk); their last rows must be `[0, 0, 0, 1]`.
    pub fn from_matrices(mats: Vec<Mat4>) -> Result<Self, GeometryError> {
        for (k, m) in mats.iter().enumerate() {
            if m.to_cols_array().iter().any(|v| !v.is_finite()) || m.row(3) != Vec4::W {
                return Err(GeometryError::NonFinite {
                    what: format!("bone transform {k}"),
                    value: format!("{m:?} (expected finite entries and last row 0 0 0 1)"),
                });
            }
        }
        Ok(Self { mats })
    }

    /// The matrices, one per joint.
    pub fn matrices(&self) -> &[Mat4] {
        &self.mats
    }

    /// Number of joints.
    pub fn len(&self) -> usize {
        self.mats.len()
    }

    /// True for an empty skeleton (never produced by [`Skeleton::bone_transforms`]).
    pub fn is_empty(&self) -> bool {
        self.mats.is_empty()
    }
}

/// `[R | t]` as a 4×4 matrix.
pub(crate) fn rigid(r: Mat3, t: Vec3) -> Mat4 {
    Mat4::from_cols(
        r.x_axis.extend(0.0),
        r.y_axis.extend(0.0),
        r.z_axis.extend(0.0),
        t.extend(1.0),
    )
}

fn check_finite(what: &str, v: Vec3) -> Result<(), GeometryError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(GeometryError::NonFinite {
            what: what.to_string(),
            value: format!("{v}"),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn smpl_like() -> Skeleton {
        let joints = (0..24)
            .map(|k| Vec3::new(0.01 * k as f32, 0.1 * (k % 5) as f32, -0.02 * k as f32))
            .collect();
        Skeleton::from_parent_table(joints, &Skeleton::SMPL_PARENTS).unwrap()
    }

    #[test]
    fn zero_pose_gives_identity_transforms() {
        let s = smpl_like();
        let a = s
            .bone_transforms(&Pose::zero(24), CanonicalPose::TPose)
            .unwrap();
        for m in a.matrices() {
            assert!(m.abs_diff_eq(Mat4::IDENTITY, 1e-6));
        }
    }

    #[test]
    fn joints_move_with_their_transforms() {
        // A_k maps rest joint k to its posed position G_k's translation.
        let s = smpl_like();
        let mut pose = Pose::zero(24);
        for (k, r) in pose.joint_rotations.iter_mut().enumerate() {
            *r = Vec3::new(0.1 * k as f32, -0.05, 0.2).normalize() * 0.4;
        }
        let a = s.bone_transforms(&pose, CanonicalPose::TPose).unwrap();
        let g = s.chain(
            &pose
                .joint_rotations
                .iter()
                .map(|&t| axis_angle_to_matrix(t))
                .collect::<Vec<_>>(),
        );
        for ((m, j), g) in a.matrices().iter().zip(s.rest_joints()).zip(&g) {
            assert!((m.transform_point3(*j) - g.w_axis.truncate()).length() < 1e-5);
        }
        // A child joint, moved by its parent's transform, lands where its own frame says.
        let child = 4; // L_knee, parent 1
        let via_parent = a.matrices()[1].transform_point3(s.rest_joints()[child]);
        assert!((via_parent - g[child].w_axis.truncate()).length() < 1e-5);
    }

    #[test]
    fn big_pose_canonical_is_identity_at_the_big_pose() {
        let s = smpl_like();
        let mut pose = Pose::zero(24);
        pose.joint_rotations[1] = Vec3::Z * 30f32.to_radians();
        pose.joint_rotations[2] = Vec3::Z * -30f32.to_radians();
        let a = s.bone_transforms(&pose, CanonicalPose::BigPose).unwrap();
        for m in a.matrices() {
            assert!(m.abs_diff_eq(Mat4::IDENTITY, 1e-5));
        }
    }

    #[test]
    fn malformed_trees_are_rejected() {
        let j = |n: usize| vec![Vec3::ZERO; n];
        assert_eq!(
            Skeleton::new(vec![], vec![]),
            Err(GeometryError::EmptySkeleton)
        );
        assert_eq!(
            Skeleton::new(j(2), vec![Some(1), None]),
            Err(GeometryError::RootNotFirst { parent: 1 })
        );
        assert_eq!(
            Skeleton::new(j(3), vec![None, Some(2), Some(1)]),
            Err(GeometryError::ParentNotBefore {
                joint: 1,
                parent: 2
            })
        );
        assert_eq!(
            Skeleton::new(j(2), vec![None, Some(7)]),
            Err(GeometryError::ParentNotBefore {
                joint: 1,
                parent: 7
            })
        );
        assert_eq!(
            Skeleton::new(j(2), vec![None, None]),
            Err(GeometryError::SecondRoot { joint: 1 })
        );
        assert!(matches!(
            Skeleton::new(j(2), vec![None]),
            Err(GeometryError::ParentCountMismatch { .. })
        ));
        let nan = vec![Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0)];
        assert!(matches!(
            Skeleton::new(nan, vec![None, Some(0)]),
            Err(GeometryError::NonFinite { .. })
        ));
    }

    #[test]
    fn uint32_sentinel_marks_the_root() {
        let s = Skeleton::from_parent_table(vec![Vec3::ZERO; 3], &[4294967295, 0, 1]).unwrap();
        assert_eq!(s.parents(), &[None, Some(0), Some(1)]);
    }

    #[test]
    fn non_finite_or_missized_poses_are_rejected() {
        let s = smpl_like();
        let mut pose = Pose::zero(24);
        pose.global.th.y = f32::INFINITY;
        let err = s.bone_transforms(&pose, CanonicalPose::TPose).unwrap_err();
        assert!(err.to_string().contains("Th"), "{err}");
        pose = Pose::zero(23);
        assert_eq!(
            s.bone_transforms(&pose, CanonicalPose::TPose).unwrap_err(),
            GeometryError::PoseSizeMismatch {
                expected: 24,
                got: 23
            }
        );
        assert!(Pose::from_flat(&[0.0; 7], [0.0; 3], [0.0; 3]).is_err());
    }

    #[test]
    fn world_pose_round_trip() {
        let g = GlobalTransform {
            rh: Vec3::new(0.3, -1.2, 0.5),
            th: Vec3::new(0.1, 2.0, -0.4),
        };
        let x = Vec3::new(0.5, -0.25, 1.5);
        assert!((g.pose_to_world(g.world_to_pose(x)) - x).length() < 1e-6);
        assert!(
            (g.pose_to_world_matrix().transform_point3(x) - g.pose_to_world(x)).length() < 1e-6
        );
    }
}

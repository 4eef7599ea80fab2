//! A motion retargeted onto the trained subject: the subject's own body (skeleton, canonical mesh) with
//! the motion's joint rotations, the standard-SMPL root converted to the datasets' `Rh`/`Th` with the
//! pelvis offset (EasyMocap's `convert_from_standard_smpl`), and optionally the motion's world placed in
//! the capture's: on its floor, starting where the subject stood, facing a camera.
//!
//! Frames: world space of the capture (metres) after placement; pose space as in [`Pose`]; the canonical
//! body is Y-up and faces +Z, as SMPL's T-pose does.

use anerf_core::geometry::{
    forward_lbs_points, BoneTransforms, CanonicalPose, GlobalTransform, Pose, Skeleton,
};
use anerf_core::GeometryError;
use glam::{DQuat, DVec3, Vec3};

use super::{Motion, Root, BODY_JOINTS};
use crate::error::DataError;
use crate::subject::SkinningWeights;

/// The body a motion is put on: the subject's skeleton and canonical (T-pose) mesh with its weights.
#[derive(Debug, Clone, Copy)]
pub struct TargetBody<'a> {
    pub skeleton: &'a Skeleton,
    /// Canonical vertices (metres).
    pub vertices: &'a [Vec3],
    pub weights: &'a SkinningWeights,
}

impl TargetBody<'_> {
    /// The canonical vertices skinned into pose space with `pose`'s joint rotations (its global
    /// transform is not applied).
    pub fn pose_space_vertices(&self, pose: &Pose) -> Result<Vec<Vec3>, GeometryError> {
        let bones = self.skeleton.bone_transforms(pose, CanonicalPose::TPose)?;
        self.skinned(&bones)
    }

    /// The canonical vertices skinned with bone transforms `bones` (canonical → pose space).
    pub fn skinned(&self, bones: &BoneTransforms) -> Result<Vec<Vec3>, GeometryError> {
        forward_lbs_points(self.vertices, self.weights.as_slice(), bones)
    }
}

/// Where the motion's body goes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Placement {
    /// Where the motion's own world puts it (a motion recorded in this capture; round-trip checks).
    AsRecorded,
    /// Into the capture's world as [`Scene`] says.
    InScene(Scene),
}

/// The capture's world as a placed motion needs it (world space, metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// Unit up direction.
    pub up: DVec3,
    /// Height of the floor along `up` (the lowest training-frame vertex): the motion's lowest vertex
    /// over all its frames is put there.
    pub floor: f64,
    /// The first frame's pelvis is put above this point.
    pub start: DVec3,
    /// The first frame faces this point (its horizontal direction from `start`).
    pub toward: DVec3,
    /// Added to every frame's translation after placement.
    pub offset: DVec3,
}

/// The subject's poses for the motion's frames, placed as `placement` says.
///
/// Joints: a motion of the subject's joint count drives every joint; otherwise (SMPL+H or SMPL-X onto
/// SMPL, …) the 22 joints all SMPL-family models share drive the subject's first 22 and the others stay
/// unrotated. The motion's body shape is not used: the subject keeps its own.
pub fn retarget(
    motion: &Motion,
    body: TargetBody<'_>,
    placement: &Placement,
) -> Result<Vec<Pose>, DataError> {
    let invalid = |detail: String| DataError::invalid(&motion.source, detail);
    let k = body.skeleton.num_joints();
    let driven = if motion.model_joints == k {
        k
    } else if k >= BODY_JOINTS && motion.model_joints >= BODY_JOINTS {
        BODY_JOINTS
    } else {
        return Err(invalid(format!(
            "has poses of {} joints ({}); the subject's skeleton has {k}, and only bodies of the same \
             joint count or SMPL-family bodies (at least {BODY_JOINTS} joints) can share a motion",
            motion.model_joints, motion.format
        )));
    };
    let pelvis = body.skeleton.rest_joints()[0].as_dvec3();
    let mut frames: Vec<Placed> = motion
        .frames
        .iter()
        .map(|f| {
            let mut joints = vec![DVec3::ZERO; k];
            joints[..driven].copy_from_slice(&f.joints[..driven]);
            match f.root {
                Root::Placed { rh, th } => Placed {
                    joints,
                    rotation: DQuat::from_scaled_axis(rh),
                    th,
                },
                Root::Standard { trans } => {
                    // x = R₀(x' − J₀) + J₀ + trans = R₀ x' + (trans + J₀ − R₀ J₀), with R₀ taken out of the pose.
                    let rotation = DQuat::from_scaled_axis(joints[0]);
                    joints[0] = DVec3::ZERO;
                    Placed {
                        joints,
                        rotation,
                        th: trans + pelvis - rotation * pelvis,
                    }
                }
            }
        })
        .collect();
    if let Placement::InScene(scene) = placement {
        place(&mut frames, motion, body, pelvis, scene)?;
    }
    frames
        .into_iter()
        .enumerate()
        .map(|(i, f)| f.pose().map_err(|e| invalid(format!("frame {i}: {e}"))))
        .collect()
}

/// A frame in the datasets' convention, kept in f64 until placed.
struct Placed {
    joints: Vec<DVec3>,
    /// `R(Rh)`.
    rotation: DQuat,
    th: DVec3,
}

impl Placed {
    fn pose(&self) -> Result<Pose, GeometryError> {
        let pose = Pose {
            joint_rotations: self.joints.iter().map(|j| j.as_vec3()).collect(),
            global: GlobalTransform {
                rh: self.rotation.to_scaled_axis().as_vec3(),
                th: self.th.as_vec3(),
            },
        };
        pose.validate(self.joints.len())?;
        Ok(pose)
    }

    /// World position of the pelvis: the root turns about it, so only `Rh`/`Th` move it.
    fn pelvis(&self, rest: DVec3) -> DVec3 {
        self.rotation * rest + self.th
    }

    /// The direction the body faces in the world: canonical +Z through the root's rotations.
    fn facing(&self) -> DVec3 {
        self.rotation * (DQuat::from_scaled_axis(self.joints[0]) * DVec3::Z)
    }

    /// The body's up direction in the world: canonical +Y through the root's rotations.
    fn up(&self) -> DVec3 {
        self.rotation * (DQuat::from_scaled_axis(self.joints[0]) * DVec3::Y)
    }
}

/// Rotates the motion's world so that its up is the scene's and its first frame faces `toward`, then
/// moves it so that the first pelvis is above `start` and the lowest vertex of all frames is on the floor.
fn place(
    frames: &mut [Placed],
    motion: &Motion,
    body: TargetBody<'_>,
    pelvis: DVec3,
    scene: &Scene,
) -> Result<(), DataError> {
    let up = scene.up.normalize();
    let flat = |v: DVec3| v - v.dot(up) * up;
    let first = &frames[0];
    let motion_up = motion.up.unwrap_or_else(|| first.up());
    let tilt = DQuat::from_rotation_arc(motion_up.normalize(), up);
    let (facing, wanted) = (
        flat(tilt * first.facing()),
        flat(scene.toward - scene.start),
    );
    let turn = if facing.length() > 1e-6 && wanted.length() > 1e-6 {
        let (a, b) = (facing.normalize(), wanted.normalize());
        DQuat::from_axis_angle(up, a.cross(b).dot(up).atan2(a.dot(b)))
    } else {
        DQuat::IDENTITY
    };
    let q = turn * tilt;
    for f in frames.iter_mut() {
        f.rotation = q * f.rotation;
        f.th = q * f.th;
    }
    let shift = flat(scene.start - frames[0].pelvis(pelvis));
    let mut lowest = f64::INFINITY;
    for (i, f) in frames.iter().enumerate() {
        let pose = f
            .pose()
            .map_err(|e| DataError::invalid(&motion.source, format!("frame {i}: {e}")))?;
        let vertices = body
            .pose_space_vertices(&pose)
            .map_err(|e| DataError::invalid(&motion.source, format!("frame {i}: {e}")))?;
        for x in vertices {
            lowest = lowest.min((f.rotation * x.as_dvec3() + f.th + shift).dot(up));
        }
    }
    let lift = (scene.floor - lowest) * up;
    for f in frames.iter_mut() {
        f.th += shift + lift + scene.offset;
    }
    Ok(())
}

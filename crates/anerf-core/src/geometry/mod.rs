//! Geometry of a posed human seen by calibrated cameras: rotations, skeletons and bone transforms,
//! linear blend skinning (glam for single points, Burn tensors for batches), cameras, rays and boxes, and the
//! body prior's blend-weight volumes (SMPL-derived weights and distance to the body on a grid).

pub mod aabb;
pub mod camera;
pub mod kinematics;
pub mod lbs;
pub mod orbit;
pub mod rotation;
pub mod skeleton;
pub mod skinning;
pub mod volume;

pub use aabb::{Aabb, RayHit};
pub use camera::{Camera, Distortion, PixelConvention, Ray};
pub use kinematics::{PoseBasis, PoseCorrection};
pub use lbs::{
    blend_transforms, forward_lbs_point, forward_lbs_points, inverse_lbs_point, validate_weights,
};
pub use orbit::{mean_up, orbit, orbit_camera};
pub use rotation::{axis_angle_to_matrix, matrix_to_axis_angle};
pub use skeleton::{BoneTransforms, CanonicalPose, GlobalTransform, Pose, Skeleton};
pub use skinning::BoneMatrices;
pub use volume::{BlendWeightVolume, FieldBound, VolumeTensor};

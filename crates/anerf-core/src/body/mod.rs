//! The body prior: blend-weight volumes (SMPL-derived weights and distance to the body on a grid).

pub mod volume;

pub use volume::{BlendWeightVolume, VolumeTensor};

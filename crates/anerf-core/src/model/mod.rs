//! The Burn modules of Animatable NeRF and the model configuration.

pub mod animatable;
pub mod blend;
pub mod codes;
pub mod config;
pub mod culling;
pub mod encoding;
pub mod hash_grid;
pub mod march;
pub mod mlp;
pub mod nerf;
pub mod occupancy;
pub mod pose_refinement;
pub mod stage2;

pub use animatable::{
    AnimatableNerf, CanonicalInputs, ConsistencyTerms, FrameCode, FrameInputs, FrameRays,
    ModelSizes, RenderOutput, ShadedSamples,
};
pub use blend::BlendWeightField;
pub use config::{
    BlendParameterisation, ConsistencyLoss, ModelConfig, ModelPreset, PointEncoding, ResidualInit,
    ViewDirection,
};
pub use encoding::PositionalEncoding;
pub use march::MarchedRays;
pub use nerf::CanonicalNerf;
pub use occupancy::{OccupancyConfig, OccupancyGrid};
pub use pose_refinement::{PoseRefinement, PoseRefinementConfig};
#[cfg(test)]
mod tests;

//! The Burn modules of Animatable NeRF and the model configuration.

pub mod animatable;
pub mod blend;
pub mod config;
pub mod encoding;
pub mod mlp;
pub mod nerf;
pub mod stage2;

pub use animatable::{
    AnimatableNerf, CanonicalInputs, ConsistencyTerms, FrameCode, FrameInputs, ModelSizes,
    RenderOutput, ShadedSamples,
};
pub use blend::BlendWeightField;
pub use config::{BlendParameterisation, ConsistencyLoss, ModelConfig, ModelPreset};
pub use encoding::PositionalEncoding;
pub use nerf::CanonicalNerf;
#[cfg(test)]
mod tests;

//! Volume rendering: depth samples along rays, compositing and the training losses.

pub mod composite;
pub mod loss;
pub mod rays;
pub mod sampling;

pub use composite::{composite, Composited};
pub use loss::{
    blend_consistency, blend_consistency_parts, color_mse, psnr_from_mse, ConsistencyParts,
};
pub use rays::{HostRays, RayBatch};
pub use sampling::{sample_fractions, stratified_depths};

//! Volume rendering: depth samples along rays (and, with the model, compositing and losses).

pub mod rays;
pub mod sampling;

pub use rays::{HostRays, RayBatch};
pub use sampling::stratified_depths;

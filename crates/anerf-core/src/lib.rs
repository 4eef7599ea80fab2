//! Core of anerf: geometry (skeletons, skinning, cameras, rays), the Burn modules of Animatable NeRF,
//! the volume renderer and the losses. No file I/O lives here.
//!
//! Conventions used throughout (see `docs/CONVENTIONS.md` at the repository root):
//! * lengths are metres;
//! * vectors are column vectors, `x' = R x + t`; glam matrices are column-major in memory;
//! * frames: **world** (calibrated capture frame) → **pose space** (`x_pose = R_hᵀ (x_world − T_h)`) →
//!   **canonical** (T-pose) through inverse linear blend skinning.

pub mod error;
pub mod gaussians;
pub mod geometry;
pub mod ids;
pub mod kernels;
pub mod mesh;
pub mod model;
pub mod named;
pub mod render;
pub mod tensor;

pub use anerf_device::DeviceChoice;
pub use error::{GeometryError, InvalidValue};
pub use ids::{FrameId, ViewId};

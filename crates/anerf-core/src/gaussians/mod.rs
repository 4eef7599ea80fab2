//! Avatars of skinned 3D Gaussians, the real-time form of a trained run: a learned cloud of anisotropic
//! Gaussians in canonical space ([`GaussianCloud`]), each carrying blend weights, posed by linear blend
//! skinning with the same bones the NeRF warps with and projected into a camera as splats
//! ([`project`], differentiable; [`project_host`], the same rows on host arrays for drawing) for the
//! rasteriser ([`crate::kernels::splat`]). Colours are spherical harmonics of the
//! view direction in canonical space ([`sh`]).

pub mod cloud;
pub mod host;
pub mod project;
pub mod sh;

/// Most Gaussians anerf reads into one avatar (16.8 million, 300 times the bake's default budget): a baked
/// folder or splat file claiming more is refused before anything is allocated for them.
pub const MAX_GAUSSIANS: usize = 1 << 24;

pub use cloud::GaussianCloud;
pub use host::{project_host, HostCloud, Splats};
pub use project::{project, render, SplatView};

#[cfg(test)]
mod tests;

//! The warp's fused operations: inverse linear blend skinning, the log-softmax blend weights and the
//! trilinear lookup of a body-model volume, each one hand-written kernel forward and one backward instead of
//! a few dozen autodiff tensor operations on `[N, 3]`, `[N, 12]` and `[N, K]` tensors (whose allocations and
//! passes dominate the small models' step).
//!
//! Used on the flex backend ([`cpu`]) and, with the `wgpu` or `cuda` feature, on Burn's CubeCL backend
//! (`cube`), with or without autodiff ([`super::available`]); every other backend runs the tensor references
//! (`BoneMatrices::inverse_reference`, `blend::prior_softmax_reference`,
//! `VolumeTensor::interpolate_reference`), which the tests compare the kernels against.

pub mod cpu;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube;
pub mod extension;

use burn::backend::Dispatch;
use burn::prelude::*;

pub use cpu::{TrilinearGrid, PRIOR_EPSILON};
use extension::FusedBackend;

/// Canonical points `[N, 3]` of pose-space points `[N, 3]` (metres) under blend weights `[N, K]` and bones
/// `[K, 12]` (row-major top 3×4 of each `A_k`); differentiable in the points and the weights, constant in
/// the bones. Only where [`super::available`].
pub fn inverse_skinning(points: Tensor<2>, weights: Tensor<2>, bones: Tensor<2>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as FusedBackend>::inverse_skinning(
        points.into_dispatch(),
        weights.into_dispatch(),
        bones.into_dispatch(),
    ))
}

/// `softmax(log(prior + ε) + residual)` per row of `[N, K]`; differentiable in both. Only where
/// [`super::available`].
pub fn prior_softmax(prior: Tensor<2>, residual: Tensor<2>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as FusedBackend>::prior_softmax(
        prior.into_dispatch(),
        residual.into_dispatch(),
    ))
}

/// Trilinear interpolation of the rows of `table` (`[nodes, C]`, laid out as `grid`) at points `[N, 3]`
/// → `[N, C]`; differentiable in the points, constant in the table. Only where [`super::available`].
pub fn trilinear(points: Tensor<2>, table: Tensor<2>, grid: TrilinearGrid) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as FusedBackend>::trilinear(
        points.into_dispatch(),
        table.into_dispatch(),
        grid,
    ))
}

#[cfg(test)]
pub(crate) mod tests;

#[cfg(all(test, any(feature = "wgpu", feature = "cuda")))]
mod cube_tests;

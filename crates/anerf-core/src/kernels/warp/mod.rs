//! The warp's fused operations: inverse linear blend skinning, the log-softmax blend weights and the
//! trilinear lookup of a body-model volume, each one hand-written kernel forward and one backward instead of
//! a few dozen autodiff tensor operations on `[N, 3]`, `[N, 12]` and `[N, K]` tensors (whose allocations and
//! passes dominate the small models' step).
//!
//! Each function here is the one place that picks its implementation: the kernels on the flex backend
//! ([`cpu`]) and, with the `wgpu` or `cuda` feature, on Burn's CubeCL backend (`cube`), with or without
//! autodiff ([`super::available`]); on every other backend the plain-tensor [`reference`], which the tests
//! compare the kernels against.

pub mod cpu;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube;
pub mod extension;
pub mod reference;

use burn::backend::Dispatch;
use burn::prelude::*;

pub use cpu::{TrilinearGrid, PRIOR_EPSILON};
use extension::FusedBackend;

/// Smallest `|det|` used when inverting a blended rotation part in [`inverse_skinning`]: where weights
/// split between opposing bones the determinant is replaced by it, so the output stays finite (and far
/// outside the body, where the canonical box check zeroes its density) instead of becoming NaN; no gradient
/// flows through the replaced value.
pub const DET_GUARD: f32 = 1e-6;

/// Canonical points `[N, 3]` of pose-space points `[N, 3]` (metres) under blend weights `[N, K]` and bones
/// `[K, 12]` (row-major top 3×4 of each `A_k`); differentiable in all three (the kernels give the bones
/// their gradient from the points' one).
pub fn inverse_skinning(points: Tensor<2>, weights: Tensor<2>, bones: Tensor<2>) -> Tensor<2> {
    if !super::available(&points.device()) {
        return reference::inverse_skinning(points, weights, bones);
    }
    Tensor::from_dispatch(<Dispatch as FusedBackend>::inverse_skinning(
        points.into_dispatch(),
        weights.into_dispatch(),
        bones.into_dispatch(),
    ))
}

/// `softmax(log(prior + ε) + residual)` per row of `[N, K]`; differentiable in both.
pub fn prior_softmax(prior: Tensor<2>, residual: Tensor<2>) -> Tensor<2> {
    if !super::available(&prior.device()) {
        return reference::prior_softmax(prior, residual);
    }
    Tensor::from_dispatch(<Dispatch as FusedBackend>::prior_softmax(
        prior.into_dispatch(),
        residual.into_dispatch(),
    ))
}

/// Trilinear interpolation of the rows of `table` (`[nodes, C]`, laid out as `grid`) at points `[N, 3]`
/// → `[N, C]`; differentiable in the points, constant in the table.
pub fn trilinear(points: Tensor<2>, table: Tensor<2>, grid: TrilinearGrid) -> Tensor<2> {
    if !super::available(&points.device()) {
        return reference::trilinear(points, table, &grid);
    }
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

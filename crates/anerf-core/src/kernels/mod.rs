//! Hand-written kernels behind Burn backend extensions, for the operations whose tensor form would dominate
//! a step with small allocations and passes: the warp ([`warp`]: inverse skinning, the log-softmax blend
//! weights, the volume lookup), the hash-grid encoding ([`hash_grid`]) and the Gaussian splat rasteriser
//! ([`splat`]). Each has a forward and a
//! backward kernel and a plain-tensor reference in its folder (`reference.rs`), which the kernels' tests
//! compare against and which every backend without kernels runs; each operation's function in its folder's
//! `mod.rs` is the one place that picks between them ([`available`]), so callers never ask.
//!
//! Shared by the CPU kernels: slice access to flex tensors (`flex`), trilinear corner weights
//! (`trilinear`) and vectorisable elementary functions (`fastmath`); by the CubeCL kernels of the GPU
//! backends (`wgpu`, `cuda` features): launch grids, contiguous tensors and the trilinear side weights
//! (`cube`), and device-wide scans and radix sorts of `u32` arrays (`cube_sort`).

#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube_sort;
mod fastmath;
mod flex;
pub mod hash_grid;
pub mod splat;
mod trilinear;
pub mod warp;

use burn::backend::DispatchDevice;
use burn::prelude::Device;

/// Whether `device` runs the hand-written kernels (both families): the flex backend and, with the `wgpu` or
/// `cuda` feature, the CubeCL backend (its runtimes share the kernels); with or without autodiff. Elsewhere
/// the callers take the plain-tensor references.
pub(crate) fn available(device: &Device) -> bool {
    match device.as_dispatch().clone().inner() {
        DispatchDevice::Flex(_) => true,
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        DispatchDevice::Cube(_) => true,
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

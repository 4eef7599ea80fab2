//! Hand-written kernels behind Burn backend extensions, for the operations whose tensor form would dominate
//! a step with small allocations and passes: the warp ([`warp`]: inverse skinning, the log-softmax blend
//! weights, the volume lookup) and the hash-grid encoding ([`hash_grid`]). Each has a forward and a
//! backward kernel and a plain-tensor reference beside the module that uses it, which the kernels' tests
//! compare against and which every backend without kernels runs.
//!
//! Shared by the CPU kernels: slice access to flex tensors (`flex`), trilinear corner weights
//! (`trilinear`) and vectorisable elementary functions (`fastmath`).

mod fastmath;
mod flex;
pub mod hash_grid;
mod trilinear;
pub mod warp;

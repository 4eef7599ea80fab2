//! What the CubeCL kernels share (the `wgpu` and `cuda` features): launching one unit per work item,
//! contiguous `f32` inputs and outputs, and the trilinear side weights of a cell corner ([`super::warp`]'s
//! volume lookup and [`super::hash_grid`]'s encoding interpolate the same way).

use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_contiguous_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::client::Client;
use cubecl::prelude::*;
use cubecl::{calculate_cube_count_elemwise, CubeDim};

/// A launch grid of one unit per work item on a tensor's device.
pub(crate) struct Units {
    pub client: Client,
    pub count: CubeCount,
    pub dim: CubeDim,
}

impl Units {
    /// `units` units on the device of `like`; `None` when there is nothing to do.
    pub fn on(like: &CubeTensor, units: usize) -> Option<Self> {
        if units == 0 {
            return None;
        }
        let client = like.client.clone();
        let dim = CubeDim::new(&client, units);
        Some(Self {
            count: calculate_cube_count_elemwise(&client, units, dim),
            dim,
            client,
        })
    }
}

/// `t` as a contiguous `f32` tensor (the kernels index their inputs as dense rows); `what` names it in the
/// panic for another dtype.
pub(crate) fn contiguous_f32(t: CubeTensor, what: &str) -> CubeTensor {
    assert_eq!(t.dtype, DType::F32, "the CubeCL kernels take f32 {what}");
    into_contiguous(t)
}

/// A new contiguous `f32` tensor of `dims` on the device of `like`.
pub(crate) fn empty_f32(like: &CubeTensor, dims: [usize; 2]) -> CubeTensor {
    empty_device_contiguous_dtype(
        like.client.clone(),
        like.device.clone(),
        Shape::new(dims),
        DType::F32,
    )
}

/// `[rows, columns]` of a 2-D tensor.
pub(crate) fn dims(t: &CubeTensor) -> [usize; 2] {
    t.meta.shape().dims::<2>()
}

/// The weight of one side of a cell along an axis: `t` on the high side (`high == 1`), `1 − t` on the low.
#[cube]
pub(crate) fn side_weight(t: f32, high: u32) -> f32 {
    select(high == 1, t, 1.0f32 - t)
}

/// `±1`: the sign of `∂ side_weight / ∂ t`.
#[cube]
pub(crate) fn side_sign(high: u32) -> f32 {
    select(high == 1, 1.0f32, -1.0f32)
}

//! What the CubeCL kernels share (the `wgpu` and `cuda` features): launching one unit per work item,
//! contiguous `f32` inputs and outputs, atomic `f32` adds where the device has them or not, and the trilinear side weights of a cell corner ([`super::warp`]'s
//! volume lookup and [`super::hash_grid`]'s encoding interpolate the same way).

use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::ops::numeric::empty_device_contiguous_dtype;
use burn_cubecl::tensor::CubeTensor;
use cubecl::client::Client;
use cubecl::features::AtomicUsage;
use cubecl::ir::{ElemType, FloatKind, Type, UIntKind};
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

/// How the gradient kernels add into a shared output ([`atomic_add`]): the hash grid's table, the splats.
///
/// Float atomics are optional on GPUs, and WGSL (what Burn's `wgpu` feature compiles to) has them only
/// through wgpu's `SHADER_FLOAT32_ATOMIC` extension. Where the device adds `f32` atomically the kernel
/// does; elsewhere it emulates the add with `u32` atomic exchanges. (A compare-exchange loop is the usual
/// emulation, but CubeCL's WGSL `atomicCompareExchangeWeak` returns only the old value, so a spurious
/// failure would pass for a success and lose an update; an exchange never fails.) Either way the order of
/// the adds is not fixed, so a sum's rounding can differ from run to run and from the CPU kernel's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum AtomicScheme {
    /// The device's `f32` atomic add, where it has one.
    Native,
    /// `u32` atomic exchanges, everywhere.
    Exchange,
}

impl AtomicScheme {
    /// Whether the kernels add natively, and the word they read the `f32` outputs as.
    pub(crate) fn word(self) -> (bool, ElemType) {
        match self {
            Self::Native => (true, ElemType::Float(FloatKind::F32)),
            Self::Exchange => (false, ElemType::UInt(UIntKind::U32)),
        }
    }

    /// The scheme the device of `t` supports best.
    pub(crate) fn for_device(t: &CubeTensor) -> Self {
        let usage = t
            .client
            .properties()
            .atomic_type_usage(Type::atomic(ElemType::Float(FloatKind::F32)));
        if usage.contains(AtomicUsage::Add) {
            Self::Native
        } else {
            Self::Exchange
        }
    }
}

/// Adds `value` to entry `index` of a table of `f32` read as `Atomic<W>`: with the device's `f32` atomic
/// add (`native`, `W = f32`), or with `u32` exchanges of the bit patterns (`W = u32`): take the entry's
/// value out (leaving `0`), put back that value plus the carry, and carry whatever another unit put there
/// in between; done when nothing was displaced. Every unit adding to the table follows the same protocol,
/// so no contribution is lost. (An entry holding `−0.0` counts as nothing to carry: dropping it changes no
/// sum.) See [`AtomicScheme`] for why.
#[cube]
pub(crate) fn atomic_add<W: Numeric>(
    table: &Tensor<Atomic<W>>,
    index: usize,
    value: f32,
    #[comptime] native: bool,
) {
    if comptime!(native) {
        table[index].fetch_add(W::cast_from(value));
    } else {
        let mut carry = value;
        while carry != 0.0f32 {
            let taken = f32::reinterpret(table[index].exchange(W::cast_from(0u32)));
            let displaced = table[index].exchange(W::reinterpret(taken + carry));
            carry = f32::reinterpret(displaced);
        }
    }
}

/// What the kernels' GPU tests share: the CubeCL tensor behind a Burn tensor, and the atomic schemes to
/// check on a device.
#[cfg(test)]
pub(crate) mod testing {
    use burn::backend::{BackendTensor, DispatchTensorKind};
    use burn::prelude::*;
    use burn_cubecl::tensor::CubeTensor;

    use super::AtomicScheme;

    /// The CubeCL tensor behind `t`.
    pub(crate) fn cube_tensor(t: Tensor<2>) -> CubeTensor {
        match t.into_dispatch().kind {
            DispatchTensorKind::Cube(BackendTensor::Float(t)) => t,
            other => panic!("expected a float tensor on a CubeCL device, got {other:?}"),
        }
    }

    /// The atomic schemes the device of `gpu` runs: the exchange scheme everywhere, the float add where
    /// the device has it.
    pub(crate) fn atomic_schemes(gpu: &Device) -> Vec<AtomicScheme> {
        let probe = cube_tensor(Tensor::zeros([1, 1], gpu));
        if AtomicScheme::for_device(&probe) == AtomicScheme::Native {
            vec![AtomicScheme::Native, AtomicScheme::Exchange]
        } else {
            eprintln!("the device has no f32 atomic add: checking the exchange scheme alone");
            vec![AtomicScheme::Exchange]
        }
    }
}

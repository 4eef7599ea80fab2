//! Plain-slice access to flex tensors, for the hand-written CPU kernels behind Burn backend extensions
//! ([`super::hash_grid`], [`super::warp`]).

use std::borrow::Cow;

use burn::backend::flex::{FlexTensor, Layout};
use burn::backend::TensorMetadata;
use burn::tensor::{Bytes, DType, Shape};

/// A contiguous `f32` view of a flex tensor (copying only when it is strided).
pub(crate) fn values(t: &FlexTensor) -> Cow<'_, [f32]> {
    assert_eq!(t.dtype(), DType::F32, "the CPU kernels take f32 tensors");
    match t.as_slice::<f32>() {
        Some(s) => Cow::Borrowed(s),
        None => Cow::Owned(
            t.to_contiguous()
                .as_slice::<f32>()
                .expect("contiguous")
                .to_vec(),
        ),
    }
}

/// A contiguous `f32` flex tensor of `dims` holding `data`.
pub(crate) fn tensor(data: Vec<f32>, dims: [usize; 2]) -> FlexTensor {
    FlexTensor::new(
        Bytes::from_elems(data),
        Layout::contiguous(Shape::new(dims)),
        DType::F32,
    )
}

/// `[rows, columns]` of a 2-D flex tensor.
pub(crate) fn dims(t: &FlexTensor) -> [usize; 2] {
    t.shape().dims::<2>()
}

#[cfg(test)]
mod tests {
    use burn::tensor::activation::relu;

    use crate::tensor::{from_rows, to_host};
    use anerf_device::cpu_device;

    /// The vendored burn-flex splits element-wise loops over large buffers across threads
    /// (`vendor/burn-flex/src/par.rs`). Above its threshold (2^16 elements), on unique and shared, dense,
    /// broadcast and strided operands, every op must give exactly the host's per-element f32 result.
    #[test]
    fn parallel_element_wise_ops_match_host_arithmetic() {
        let (rows, cols) = (40_000, 5);
        let n = rows * cols;
        let a: Vec<f32> = (0..n)
            .map(|i| ((i * 7919) % 1000) as f32 / 250.0 - 2.0)
            .collect();
        let b: Vec<f32> = (0..n)
            .map(|i| ((i * 104_729) % 997) as f32 / 300.0 - 1.5)
            .collect();
        let bias: Vec<f32> = (0..cols).map(|j| j as f32 * 0.25 - 0.5).collect();
        let device = cpu_device();
        let ta = from_rows(&a, rows, cols, &device);
        let tb = from_rows(&b, rows, cols, &device);
        let tbias = from_rows(&bias, 1, cols, &device);
        let host = |f: &dyn Fn(usize) -> f32| (0..n).map(f).collect::<Vec<f32>>();

        // Unique operands: the in-place paths.
        assert_eq!(
            to_host(relu(ta.clone() * 1.0)),
            host(&|i| a[i].max(0.0)),
            "relu (in place)"
        );
        assert_eq!(
            to_host((ta.clone() * 1.0) * 3.0 - 0.5),
            host(&|i| a[i] * 3.0 - 0.5),
            "scalar ops (in place)"
        );
        assert_eq!(
            to_host((ta.clone() * 1.0) + tbias.clone()),
            host(&|i| a[i] + bias[i % cols]),
            "row-broadcast add (in place)"
        );
        assert_eq!(
            to_host((ta.clone() * 1.0).max_pair(tb.clone())),
            host(&|i| a[i].max(b[i])),
            "non-SIMD binary op (in place)"
        );
        // Shared operands (`ta`, `tb` are still held): the allocating paths.
        assert_eq!(
            to_host(ta.clone().exp()),
            host(&|i| a[i].exp()),
            "exp (allocating)"
        );
        assert_eq!(
            to_host(ta.clone() * 2.0),
            host(&|i| a[i] * 2.0),
            "scalar op (allocating)"
        );
        assert_eq!(
            to_host(ta.clone().max_pair(tb.clone())),
            host(&|i| a[i].max(b[i])),
            "non-SIMD binary op (allocating)"
        );
        // A strided operand: the transposed view of a `[cols, rows]` tensor against a unique dense one.
        let tt = from_rows(&b, cols, rows, &device).transpose();
        assert_eq!(
            to_host((ta.clone() * 1.0) - tt),
            host(&|i| a[i] - b[(i % cols) * rows + i / cols]),
            "strided sub (in place)"
        );
    }
}

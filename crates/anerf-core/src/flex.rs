//! Plain-slice access to flex tensors, for the hand-written CPU kernels behind Burn backend extensions
//! ([`crate::model::hash_grid`], [`crate::fused`]).

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

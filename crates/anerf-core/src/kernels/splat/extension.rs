//! The rasteriser as a Burn backend extension: the flex backend runs [`super::cpu`], the CubeCL backend
//! (`wgpu`, `cuda` features) the `cube` kernels; the autodiff backend wraps either with the hand-written
//! backward pass. Other backends use [`super::reference::rasterize`] (see [`super::rasterize`]).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::autodiff::Autodiff;
use burn::backend::flex::{Flex, FlexTensor};
use burn::backend::tensor::FloatTensor;
use burn::backend::AutodiffBackend;
use burn::backend::{backend_extension, Dispatch};
use burn::prelude::*;

use super::{cpu, RasterSpec, PIXEL_WIDTH, SPLAT_WIDTH};
use crate::kernels::flex::{dims, tensor as flex_tensor, values};

/// The rasteriser's primitive operations (`f32`, row-major; shapes in [`super`]).
#[backend_extension(Flex, Cube: cfg(any(feature = "wgpu", feature = "cuda")), Autodiff)]
pub trait SplatBackend: burn::backend::Backend {
    /// `[N, SPLAT_WIDTH]` splats → `[H·W, PIXEL_WIDTH]` pixels.
    fn splat_rasterize(splats: FloatTensor<Self>, spec: RasterSpec) -> FloatTensor<Self>;

    /// The splats' gradient `[N, SPLAT_WIDTH]` from the splats and the pixels' gradient.
    fn splat_rasterize_grad(
        splats: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: RasterSpec,
    ) -> FloatTensor<Self>;
}

/// The rasteriser through the extension; `splats` must live on a device with the kernels.
pub fn rasterize(splats: Tensor<2>, spec: &RasterSpec) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SplatBackend>::splat_rasterize(
        splats.into_dispatch(),
        *spec,
    ))
}

impl SplatBackend for Flex {
    fn splat_rasterize(splats: FlexTensor, spec: RasterSpec) -> FlexTensor {
        assert_eq!(dims(&splats)[1], SPLAT_WIDTH, "splat rows");
        let mut out = vec![0.0; spec.pixels() * PIXEL_WIDTH];
        cpu::forward(&values(&splats), &spec, &mut out);
        flex_tensor(out, [spec.pixels(), PIXEL_WIDTH])
    }

    fn splat_rasterize_grad(splats: FlexTensor, grad: FlexTensor, spec: RasterSpec) -> FlexTensor {
        let shape = dims(&splats);
        let mut out = vec![0.0; shape[0] * SPLAT_WIDTH];
        cpu::backward(&values(&splats), &values(&grad), &spec, &mut out);
        flex_tensor(out, shape)
    }
}

/// The backward step of [`SplatBackend::splat_rasterize`]: the state holds the splats and the image.
#[derive(Debug)]
struct RasterizeBackward;

impl<B: SplatBackend> Backward<B, 1> for RasterizeBackward {
    type State = (FloatTensor<B>, RasterSpec);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [splats_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (splats, spec) = ops.state;
        if let Some(node) = splats_node {
            grads.register::<B>(node.id, B::splat_rasterize_grad(splats, grad, spec));
        }
    }
}

impl<B: SplatBackend, C: CheckpointStrategy> SplatBackend for Autodiff<B, C> {
    fn splat_rasterize(splats: FloatTensor<Self>, spec: RasterSpec) -> FloatTensor<Self> {
        match RasterizeBackward
            .prepare::<C>([splats.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let s = splats.into_primitive();
                let out = B::splat_rasterize(s.clone(), spec);
                prep.finish((s, spec), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::splat_rasterize(splats.into_primitive(), spec))
            }
        }
    }

    // Computed on the inner backend inside the backward pass; called on autodiff tensors directly it is a
    // constant.
    fn splat_rasterize_grad(
        splats: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: RasterSpec,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::splat_rasterize_grad(
            splats.into_primitive(),
            grad.into_primitive(),
            spec,
        ))
    }
}

//! The hash-grid encoding as a Burn backend extension: the flex backend runs the CPU [`super::cpu`],
//! the CubeCL backend (with the `wgpu` or `cuda` feature) the kernels of `super::cube`; the autodiff backend wraps
//! either with a hand-written backward pass (table gradient and point gradient). Other backends use
//! [`super::reference::encode`] (see [`super::encode`]).

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

use super::{cpu, GridSpec};
use crate::kernels::flex::{dims, tensor as flex_tensor, values};

/// The encoding's primitive operations (all tensors `f32`, row-major; see [`super::cpu`] for shapes).
#[backend_extension(Flex, Cube: cfg(any(feature = "wgpu", feature = "cuda")), Autodiff)]
pub trait HashGridBackend: burn::backend::Backend {
    /// `[N, 3]` points and the `[L·T, F]` table → `[N, L·F]` features.
    fn hash_grid_encode(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        spec: GridSpec,
    ) -> FloatTensor<Self>;

    /// The table's gradient `[L·T, F]` from the points and the output gradient `[N, L·F]`.
    fn hash_grid_table_grad(
        points: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: GridSpec,
    ) -> FloatTensor<Self>;

    /// The points' gradient `[N, 3]` from the points, the table and the output gradient.
    fn hash_grid_points_grad(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: GridSpec,
    ) -> FloatTensor<Self>;

    /// Both gradients, `(table [L·T, F], points [N, 3])`; backends with a fused kernel override this.
    fn hash_grid_grads(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: GridSpec,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        (
            Self::hash_grid_table_grad(points.clone(), grad.clone(), spec.clone()),
            Self::hash_grid_points_grad(points, table, grad, spec),
        )
    }
}

/// The encoding through the extension; `points` and `table` must live on a device where [`crate::kernels::available`].
pub fn encode(points: Tensor<2>, table: Tensor<2>, spec: &GridSpec) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as HashGridBackend>::hash_grid_encode(
        points.into_dispatch(),
        table.into_dispatch(),
        spec.clone(),
    ))
}

fn rows(t: &FlexTensor) -> usize {
    dims(t)[0]
}

impl HashGridBackend for Flex {
    fn hash_grid_encode(points: FlexTensor, table: FlexTensor, spec: GridSpec) -> FlexTensor {
        let n = rows(&points);
        assert_eq!(
            dims(&table),
            [spec.table_rows(), spec.features],
            "hash grid table"
        );
        let mut out = vec![0.0; n * spec.output_dim()];
        cpu::encode(&values(&points), &values(&table), &spec, &mut out);
        flex_tensor(out, [n, spec.output_dim()])
    }

    fn hash_grid_table_grad(points: FlexTensor, grad: FlexTensor, spec: GridSpec) -> FlexTensor {
        let mut out = vec![0.0; spec.table_rows() * spec.features];
        cpu::table_grad(&values(&points), &values(&grad), &spec, &mut out);
        flex_tensor(out, [spec.table_rows(), spec.features])
    }

    fn hash_grid_points_grad(
        points: FlexTensor,
        table: FlexTensor,
        grad: FlexTensor,
        spec: GridSpec,
    ) -> FlexTensor {
        let n = rows(&points);
        let mut out = vec![0.0; n * 3];
        cpu::points_grad(
            &values(&points),
            &values(&table),
            &values(&grad),
            &spec,
            &mut out,
        );
        flex_tensor(out, [n, 3])
    }

    fn hash_grid_grads(
        points: FlexTensor,
        table: FlexTensor,
        grad: FlexTensor,
        spec: GridSpec,
    ) -> (FlexTensor, FlexTensor) {
        let n = rows(&points);
        let mut table_grad = vec![0.0; spec.table_rows() * spec.features];
        let mut points_grad = vec![0.0; n * 3];
        cpu::grads(
            &values(&points),
            &values(&table),
            &values(&grad),
            &spec,
            &mut table_grad,
            &mut points_grad,
        );
        (
            flex_tensor(table_grad, [spec.table_rows(), spec.features]),
            flex_tensor(points_grad, [n, 3]),
        )
    }
}

/// The backward step of [`HashGridBackend::hash_grid_encode`]: the state holds the points, the table and
/// the grid.
#[derive(Debug)]
struct EncodeBackward;

impl<B: HashGridBackend> Backward<B, 2> for EncodeBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, GridSpec);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [points_node, table_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (points, table, spec) = ops.state;
        match (table_node, points_node) {
            (Some(table_node), Some(points_node)) => {
                let (table_grad, points_grad) = B::hash_grid_grads(points, table, grad, spec);
                grads.register::<B>(table_node.id, table_grad);
                grads.register::<B>(points_node.id, points_grad);
            }
            (Some(node), None) => {
                grads.register::<B>(node.id, B::hash_grid_table_grad(points, grad, spec));
            }
            (None, Some(node)) => {
                grads.register::<B>(node.id, B::hash_grid_points_grad(points, table, grad, spec));
            }
            (None, None) => {}
        }
    }
}

impl<B: HashGridBackend, C: CheckpointStrategy> HashGridBackend for Autodiff<B, C> {
    fn hash_grid_encode(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        spec: GridSpec,
    ) -> FloatTensor<Self> {
        match EncodeBackward
            .prepare::<C>([points.node(), table.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (p, t) = (points.into_primitive(), table.into_primitive());
                let out = B::hash_grid_encode(p.clone(), t.clone(), spec.clone());
                prep.finish((p, t, spec), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::hash_grid_encode(
                points.into_primitive(),
                table.into_primitive(),
                spec,
            )),
        }
    }

    // The gradients are computed on the inner backend inside the backward pass; called on autodiff
    // tensors directly they are constants.
    fn hash_grid_table_grad(
        points: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: GridSpec,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::hash_grid_table_grad(
            points.into_primitive(),
            grad.into_primitive(),
            spec,
        ))
    }

    fn hash_grid_points_grad(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: GridSpec,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::hash_grid_points_grad(
            points.into_primitive(),
            table.into_primitive(),
            grad.into_primitive(),
            spec,
        ))
    }

    fn hash_grid_grads(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: GridSpec,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (table_grad, points_grad) = B::hash_grid_grads(
            points.into_primitive(),
            table.into_primitive(),
            grad.into_primitive(),
            spec,
        );
        (Self::from_inner(table_grad), Self::from_inner(points_grad))
    }
}

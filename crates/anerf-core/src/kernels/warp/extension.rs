//! The fused warp operations as a Burn backend extension: the flex backend runs [`super::cpu`], the CubeCL
//! backend (with the `wgpu` or `cuda` feature) the kernels of `super::cube`; the autodiff backend wraps
//! either with the hand-written backward passes. Other backends are not listed (calling them there panics);
//! [`super::available`] keeps them on the tensor reference.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::autodiff::Autodiff;
use burn::backend::flex::{Flex, FlexTensor};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, AutodiffBackend};

use super::cpu::{self, TrilinearGrid};
use crate::kernels::flex::{dims, tensor, values};

/// The fused operations (all tensors `f32`, row-major; shapes as in [`super::cpu`]).
#[backend_extension(Flex, Cube: cfg(any(feature = "wgpu", feature = "cuda")), Autodiff)]
pub trait FusedBackend: burn::backend::Backend {
    /// Inverse skinning: points `[N, 3]`, weights `[N, K]`, bones `[K, 12]` → canonical points `[N, 3]`.
    fn inverse_skinning(
        points: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        bones: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// The gradients of [`Self::inverse_skinning`] from its output gradient: `(points, weights)`.
    fn inverse_skinning_grads(
        points: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        bones: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>);

    /// `softmax(log(prior + ε) + residual)` per row, `[N, K]`.
    fn prior_softmax(prior: FloatTensor<Self>, residual: FloatTensor<Self>) -> FloatTensor<Self>;

    /// The logits' gradient of [`Self::prior_softmax`] from its output `weights` and output gradient.
    fn prior_softmax_logit_grad(
        weights: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// Trilinear interpolation of the table's rows `[nodes, C]` at points `[N, 3]` → `[N, C]`.
    fn trilinear(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: TrilinearGrid,
    ) -> FloatTensor<Self>;

    /// The points' gradient `[N, 3]` of [`Self::trilinear`] from its output gradient (the table is constant).
    fn trilinear_points_grad(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        grid: TrilinearGrid,
    ) -> FloatTensor<Self>;
}

impl FusedBackend for Flex {
    fn inverse_skinning(points: FlexTensor, weights: FlexTensor, bones: FlexTensor) -> FlexTensor {
        let n = check_skinning(dims(&points), dims(&weights), dims(&bones));
        let mut out = vec![0.0; n * 3];
        cpu::inverse_skinning(
            &values(&points),
            &values(&weights),
            &values(&bones),
            &mut out,
        );
        tensor(out, [n, 3])
    }

    fn inverse_skinning_grads(
        points: FlexTensor,
        weights: FlexTensor,
        bones: FlexTensor,
        grad: FlexTensor,
    ) -> (FlexTensor, FlexTensor) {
        let n = check_skinning(dims(&points), dims(&weights), dims(&bones));
        assert_eq!(dims(&grad), [n, 3], "inverse skinning: output gradient");
        let k = dims(&bones)[0];
        let (mut grad_points, mut grad_weights) = (vec![0.0; n * 3], vec![0.0; n * k]);
        cpu::inverse_skinning_grads(
            &values(&points),
            &values(&weights),
            &values(&bones),
            &values(&grad),
            &mut grad_points,
            &mut grad_weights,
        );
        (tensor(grad_points, [n, 3]), tensor(grad_weights, [n, k]))
    }

    fn prior_softmax(prior: FlexTensor, residual: FlexTensor) -> FlexTensor {
        let [n, k] = dims(&prior);
        assert_eq!(dims(&residual), [n, k], "prior softmax: residual");
        let mut out = vec![0.0; n * k];
        cpu::prior_softmax(&values(&prior), &values(&residual), k, &mut out);
        tensor(out, [n, k])
    }

    fn prior_softmax_logit_grad(weights: FlexTensor, grad: FlexTensor) -> FlexTensor {
        let [n, k] = dims(&weights);
        assert_eq!(dims(&grad), [n, k], "prior softmax: output gradient");
        let mut out = vec![0.0; n * k];
        cpu::prior_softmax_logit_grad(&values(&weights), &values(&grad), k, &mut out);
        tensor(out, [n, k])
    }

    fn trilinear(points: FlexTensor, table: FlexTensor, grid: TrilinearGrid) -> FlexTensor {
        let (n, c) = check_trilinear(dims(&points), dims(&table), &grid);
        let mut out = vec![0.0; n * c];
        cpu::trilinear(&values(&points), &values(&table), &grid, &mut out);
        tensor(out, [n, c])
    }

    fn trilinear_points_grad(
        points: FlexTensor,
        table: FlexTensor,
        grad: FlexTensor,
        grid: TrilinearGrid,
    ) -> FlexTensor {
        let (n, c) = check_trilinear(dims(&points), dims(&table), &grid);
        assert_eq!(dims(&grad), [n, c], "trilinear: output gradient");
        let mut out = vec![0.0; n * 3];
        cpu::trilinear_points_grad(
            &values(&points),
            &values(&table),
            &values(&grad),
            &grid,
            &mut out,
        );
        tensor(out, [n, 3])
    }
}

/// Checks the shapes `[rows, columns]` of a trilinear call (any backend); returns `(N, C)`.
pub(super) fn check_trilinear(
    points: [usize; 2],
    table: [usize; 2],
    grid: &TrilinearGrid,
) -> (usize, usize) {
    let [n, three] = points;
    let [nodes, c] = table;
    assert_eq!(three, 3, "trilinear: points [N, 3]");
    assert_eq!(
        nodes,
        grid.dims.iter().product::<usize>(),
        "trilinear: table rows = grid nodes"
    );
    (n, c)
}

/// Checks the shapes `[rows, columns]` of an inverse-skinning call (any backend); returns `N`.
pub(super) fn check_skinning(points: [usize; 2], weights: [usize; 2], bones: [usize; 2]) -> usize {
    let [n, three] = points;
    let [k, twelve] = bones;
    assert_eq!(
        (three, twelve),
        (3, 12),
        "inverse skinning: points [N, 3], bones [K, 12]"
    );
    assert_eq!(weights, [n, k], "inverse skinning: weights [N, K]");
    n
}

/// The backward step of [`FusedBackend::inverse_skinning`]; the state holds points, weights, bones and the
/// output (the canonical points).
#[derive(Debug)]
struct InverseSkinningBackward;

impl<B: FusedBackend> Backward<B, 3> for InverseSkinningBackward {
    type State = (
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
        FloatTensor<B>,
    );

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [points_node, weights_node, bones_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (points, weights, bones, canonical) = ops.state;
        let (grad_points, grad_weights) =
            B::inverse_skinning_grads(points, weights.clone(), bones, grad);
        if let Some(node) = bones_node {
            let grad_bones =
                inverse_skinning_bones_grad::<B>(weights, canonical, grad_points.clone());
            grads.register::<B>(node.id, grad_bones);
        }
        if let Some(node) = points_node {
            grads.register::<B>(node.id, grad_points);
        }
        if let Some(node) = weights_node {
            grads.register::<B>(node.id, grad_weights);
        }
    }
}

/// The bones' gradient `[K, 12]` of inverse skinning `y = rot(M)⁻¹ (x − t(M))`, `M = W · A`, from the
/// weights `W` `[N, K]`, the output `y` `[N, 3]` and the points' gradient `u = ∂L/∂x = rot(M)⁻ᵀ ∂L/∂y`
/// `[N, 3]` (which the kernel's backward already computes): differentiating `rot(M) y + t(M) = x` gives
/// `∂L/∂rot(M) = −u yᵀ` and `∂L/∂t(M) = −u`, so `∂L/∂M = −u [yᵀ 1]` (each row's top 3×4) and
/// `∂L/∂A = Wᵀ · ∂L/∂M`. Plain tensor operations, so it serves every backend of the fused kernel.
fn inverse_skinning_bones_grad<B: burn::backend::Backend>(
    weights: FloatTensor<B>,
    canonical: FloatTensor<B>,
    grad_points: FloatTensor<B>,
) -> FloatTensor<B> {
    use burn::backend::{Shape, TensorMetadata};
    let n = canonical.shape()[0];
    let u = B::float_reshape(grad_points, Shape::new([n, 3, 1]));
    let y = B::float_reshape(canonical, Shape::new([n, 1, 3]));
    let rotation = B::float_matmul(u.clone(), y);
    let per_point = B::float_reshape(B::float_cat(vec![rotation, u], 2), Shape::new([n, 12]));
    B::float_neg(B::float_matmul(
        B::float_swap_dims(weights, 0, 1),
        per_point,
    ))
}

/// The backward step of [`FusedBackend::prior_softmax`]; the state holds the prior and the output.
#[derive(Debug)]
struct PriorSoftmaxBackward;

impl<B: FusedBackend> Backward<B, 2> for PriorSoftmaxBackward {
    type State = (FloatTensor<B>, FloatTensor<B>);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [prior_node, residual_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (prior, weights) = ops.state;
        let logits = B::prior_softmax_logit_grad(weights, grad);
        if let Some(node) = prior_node {
            // ∂ log(w^s + ε) / ∂ w^s = 1 / (w^s + ε).
            let shifted = B::float_add_scalar(prior, cpu::PRIOR_EPSILON.into());
            grads.register::<B>(node.id, B::float_div(logits.clone(), shifted));
        }
        if let Some(node) = residual_node {
            grads.register::<B>(node.id, logits);
        }
    }
}

/// The backward step of [`FusedBackend::trilinear`]; the state holds the points, the table and the grid.
#[derive(Debug)]
struct TrilinearBackward;

impl<B: FusedBackend> Backward<B, 1> for TrilinearBackward {
    type State = (FloatTensor<B>, FloatTensor<B>, TrilinearGrid);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [points_node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        let (points, table, grid) = ops.state;
        if let Some(node) = points_node {
            grads.register::<B>(node.id, B::trilinear_points_grad(points, table, grad, grid));
        }
    }
}

impl<B: FusedBackend, C: CheckpointStrategy> FusedBackend for Autodiff<B, C> {
    fn inverse_skinning(
        points: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        bones: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        match InverseSkinningBackward
            .prepare::<C>([points.node(), weights.node(), bones.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (p, w, b) = (
                    points.into_primitive(),
                    weights.into_primitive(),
                    bones.into_primitive(),
                );
                let out = B::inverse_skinning(p.clone(), w.clone(), b.clone());
                prep.finish((p, w, b, out.clone()), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::inverse_skinning(
                points.into_primitive(),
                weights.into_primitive(),
                bones.into_primitive(),
            )),
        }
    }

    fn inverse_skinning_grads(
        points: FloatTensor<Self>,
        weights: FloatTensor<Self>,
        bones: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        let (p, w) = B::inverse_skinning_grads(
            points.into_primitive(),
            weights.into_primitive(),
            bones.into_primitive(),
            grad.into_primitive(),
        );
        (Self::from_inner(p), Self::from_inner(w))
    }

    fn prior_softmax(prior: FloatTensor<Self>, residual: FloatTensor<Self>) -> FloatTensor<Self> {
        match PriorSoftmaxBackward
            .prepare::<C>([prior.node(), residual.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let p = prior.into_primitive();
                let out = B::prior_softmax(p.clone(), residual.into_primitive());
                prep.finish((p, out.clone()), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::prior_softmax(
                prior.into_primitive(),
                residual.into_primitive(),
            )),
        }
    }

    fn prior_softmax_logit_grad(
        weights: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::prior_softmax_logit_grad(
            weights.into_primitive(),
            grad.into_primitive(),
        ))
    }

    fn trilinear(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grid: TrilinearGrid,
    ) -> FloatTensor<Self> {
        // The table is constant: only the points are a parent.
        let table = table.into_primitive();
        match TrilinearBackward
            .prepare::<C>([points.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let p = points.into_primitive();
                let out = B::trilinear(p.clone(), table.clone(), grid);
                prep.finish((p, table, grid), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::trilinear(points.into_primitive(), table, grid))
            }
        }
    }

    fn trilinear_points_grad(
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        grid: TrilinearGrid,
    ) -> FloatTensor<Self> {
        Self::from_inner(B::trilinear_points_grad(
            points.into_primitive(),
            table.into_primitive(),
            grad.into_primitive(),
            grid,
        ))
    }
}

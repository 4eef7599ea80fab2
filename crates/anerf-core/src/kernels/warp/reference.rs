//! The warp's operations in plain tensor operations: what every backend without the kernels runs, and what
//! the kernels' tests compare against (values and gradients through Burn's autodiff).

use burn::prelude::*;
use burn::tensor::activation::softmax;

use super::{TrilinearGrid, DET_GUARD, PRIOR_EPSILON};

/// [`super::inverse_skinning`]: `x_can = rot(M)⁻¹ (x_pose − t(M))` with `M = W · A`, points `[N, 3]`
/// (metres, pose space), weights `[N, K]`, bones `[K, 12]`; differentiable in all three.
pub fn inverse_skinning(points: Tensor<2>, weights: Tensor<2>, bones: Tensor<2>) -> Tensor<2> {
    let m = weights.matmul(bones);
    let row = |i: usize| m.clone().narrow(1, 4 * i, 3);
    let (r0, r1, r2) = (row(0), row(1), row(2));
    let t = Tensor::cat(
        vec![
            m.clone().narrow(1, 3, 1),
            m.clone().narrow(1, 7, 1),
            m.narrow(1, 11, 1),
        ],
        1,
    );
    let d = points - t;
    // rot(M)⁻¹ = [r1×r2, r2×r0, r0×r1] / det (columns), det = r0·(r1×r2).
    let c0 = r1.clone().cross(r2.clone(), 1);
    let c1 = r2.cross(r0.clone(), 1);
    let c2 = r0.clone().cross(r1, 1);
    let det = (r0 * c0.clone()).sum_dim(1);
    let small = det.clone().abs().lower_elem(DET_GUARD);
    let det = det.mask_fill(small, DET_GUARD);
    let d0 = d.clone().narrow(1, 0, 1);
    let d1 = d.clone().narrow(1, 1, 1);
    let d2 = d.narrow(1, 2, 1);
    (c0 * d0 + c1 * d1 + c2 * d2) / det
}

/// [`super::prior_softmax`]: `softmax(log(prior + ε) + residual)` per row of `[N, K]`.
pub fn prior_softmax(prior: Tensor<2>, residual: Tensor<2>) -> Tensor<2> {
    softmax((prior + PRIOR_EPSILON).log() + residual, 1)
}

/// [`super::trilinear`]: the rows of `table` (`[nodes, C]`, laid out as `grid`) interpolated at points
/// `[N, 3]` → `[N, C]`, border clamped; differentiable in the points.
pub fn trilinear(points: Tensor<2>, table: Tensor<2>, grid: &TrilinearGrid) -> Tensor<2> {
    let [n, _] = points.dims();
    let channels = table.dims()[1];
    let dims = grid.dims;
    let mut base = Vec::with_capacity(3);
    let mut frac = Vec::with_capacity(3);
    for a in 0..3 {
        let cells = (dims[a] - 1) as f32;
        let u = ((points.clone().narrow(1, a, 1) - grid.min[a]) * grid.scale[a]).clamp(0.0, cells);
        let i0 = u
            .clone()
            .detach()
            .floor()
            .clamp(0.0, (dims[a] as f32 - 2.0).max(0.0));
        frac.push(u - i0.clone());
        base.push(i0);
    }
    let (ny, nz) = (dims[1] as f32, dims[2] as f32);
    let mut indices = Vec::with_capacity(8);
    let mut weights = Vec::with_capacity(8);
    for c in 0..8 {
        let mut idx: Vec<Tensor<2>> = Vec::with_capacity(3);
        let mut w: Option<Tensor<2>> = None;
        for a in 0..3 {
            let hi = (c >> a) & 1 == 1;
            let i = if hi {
                (base[a].clone() + 1.0).clamp_max((dims[a] - 1) as f32)
            } else {
                base[a].clone()
            };
            idx.push(i);
            let wa = if hi {
                frac[a].clone()
            } else {
                frac[a].clone().neg() + 1.0
            };
            w = Some(match w {
                Some(w) => w * wa,
                None => wa,
            });
        }
        let flat = (idx[0].clone() * ny + idx[1].clone()) * nz + idx[2].clone();
        indices.push(flat.reshape([n]));
        weights.push(w.expect("three axes"));
    }
    let index = Tensor::cat(indices, 0).int();
    let gathered = table.select(0, index).reshape([8, n, channels]);
    let w = Tensor::stack::<3>(weights, 0);
    (gathered * w).sum_dim(0).reshape([n, channels])
}

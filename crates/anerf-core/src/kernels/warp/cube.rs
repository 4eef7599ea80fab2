//! CubeCL kernels of the fused warp for Burn's CubeCL backend (the `wgpu` and `cuda` features): the six
//! operations of [`super::extension::FusedBackend`] with the arithmetic of the CPU kernels ([`super::cpu`]),
//! one unit per point (or per row of weights), compiled just in time for the device. No unit writes where
//! another does, so no atomics are needed.
//!
//! Shapes as in [`super::cpu`]: points `[N, 3]` (metres), weights, priors and residuals `[N, K]`, bones
//! `[K, 12]` (row-major top three rows of each `A_k`), volume tables `[nodes, C]`; all `f32`. Inputs are
//! made contiguous first; outputs are new contiguous tensors.

use burn::backend::Cube;
use burn_cubecl::cubecl;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::cpu::{TrilinearGrid, PRIOR_EPSILON};
use super::extension::{check_skinning, check_trilinear, FusedBackend};
use super::DET_GUARD;
use crate::kernels::cube::{contiguous_f32, dims, empty_f32, side_sign, side_weight, Units};

/// A 3-vector of the kernels' arithmetic.
#[derive(CubeType)]
struct V3 {
    x: f32,
    y: f32,
    z: f32,
}

#[cube]
fn row3(t: &Tensor<f32>, i: usize) -> V3 {
    V3 {
        x: t[3 * i],
        y: t[3 * i + 1],
        z: t[3 * i + 2],
    }
}

#[cube]
fn write3(t: &mut Tensor<f32>, i: usize, v: &V3) {
    t[3 * i] = v.x;
    t[3 * i + 1] = v.y;
    t[3 * i + 2] = v.z;
}

#[cube]
fn dot(a: &V3, b: &V3) -> f32 {
    a.x * b.x + a.y * b.y + a.z * b.z
}

#[cube]
fn cross(a: &V3, b: &V3) -> V3 {
    V3 {
        x: a.y * b.z - a.z * b.y,
        y: a.z * b.x - a.x * b.z,
        z: a.x * b.y - a.y * b.x,
    }
}

#[cube]
fn plus(a: &V3, b: &V3) -> V3 {
    V3 {
        x: a.x + b.x,
        y: a.y + b.y,
        z: a.z + b.z,
    }
}

#[cube]
fn times(a: &V3, s: f32) -> V3 {
    V3 {
        x: a.x * s,
        y: a.y * s,
        z: a.z * s,
    }
}

#[cube]
fn over(a: &V3, s: f32) -> V3 {
    V3 {
        x: a.x / s,
        y: a.y / s,
        z: a.z / s,
    }
}

/// Point `i`'s blended transform `M = Σ_k w_k A_k` and the pieces of `rot(M)⁻¹` both passes use (as the CPU
/// kernels' `Blended`).
#[derive(CubeType)]
struct Blended {
    /// Rows of `rot(M)`.
    r0: V3,
    r1: V3,
    r2: V3,
    /// Columns of the adjugate: `r1×r2`, `r2×r0`, `r0×r1`.
    c0: V3,
    c1: V3,
    c2: V3,
    /// `x − t(M)`.
    offset: V3,
    /// `det rot(M)`, or `DET_GUARD` where `|det| < DET_GUARD`.
    det: f32,
    /// Whether the determinant was replaced (no gradient flows through it then).
    guarded: bool,
}

#[cube]
fn blended(points: &Tensor<f32>, weights: &Tensor<f32>, bones: &Tensor<f32>, i: usize) -> Blended {
    let k = bones.shape(0);
    let mut m = Array::<f32>::new(12usize);
    #[unroll]
    for j in 0..12usize {
        m[j] = 0.0f32;
    }
    for b in 0..k {
        let w = weights[i * k + b];
        #[unroll]
        for j in 0..12usize {
            m[j] += w * bones[b * 12 + j];
        }
    }
    let r0 = V3 {
        x: m[0],
        y: m[1],
        z: m[2],
    };
    let r1 = V3 {
        x: m[4],
        y: m[5],
        z: m[6],
    };
    let r2 = V3 {
        x: m[8],
        y: m[9],
        z: m[10],
    };
    let c0 = cross(&r1, &r2);
    let c1 = cross(&r2, &r0);
    let c2 = cross(&r0, &r1);
    let det = dot(&r0, &c0);
    let guarded = f32::abs(det) < DET_GUARD;
    let p = row3(points, i);
    Blended {
        offset: V3 {
            x: p.x - m[3],
            y: p.y - m[7],
            z: p.z - m[11],
        },
        r0,
        r1,
        r2,
        c0,
        c1,
        c2,
        det: select(guarded, DET_GUARD, det),
        guarded,
    }
}

/// `rot(M)⁻¹ (x − t(M))`.
#[cube]
fn canonical(b: &Blended) -> V3 {
    let d = &b.offset;
    let sum = plus(
        &plus(&times(&b.c0, d.x), &times(&b.c1, d.y)),
        &times(&b.c2, d.z),
    );
    over(&sum, b.det)
}

/// `out[i] = rot(M_i)⁻¹ (x_i − t(M_i))`, one unit per point.
#[cube(launch_unchecked)]
fn inverse_skinning_kernel(
    points: &Tensor<f32>,
    weights: &Tensor<f32>,
    bones: &Tensor<f32>,
    out: &mut Tensor<f32>,
) {
    if ABSOLUTE_POS >= points.shape(0) {
        terminate!();
    }
    let b = blended(points, weights, bones, ABSOLUTE_POS);
    write3(out, ABSOLUTE_POS, &canonical(&b));
}

/// The gradients of inverse skinning from the output gradient, one unit per point (the derivation is
/// [`super::cpu::inverse_skinning_grads`]'s).
#[cube(launch_unchecked)]
fn inverse_skinning_grads_kernel(
    points: &Tensor<f32>,
    weights: &Tensor<f32>,
    bones: &Tensor<f32>,
    grad: &Tensor<f32>,
    grad_points: &mut Tensor<f32>,
    grad_weights: &mut Tensor<f32>,
) {
    if ABSOLUTE_POS >= points.shape(0) {
        terminate!();
    }
    let i = ABSOLUTE_POS;
    let b = blended(points, weights, bones, i);
    let g = row3(grad, i);
    let v = over(&g, b.det);
    let u = V3 {
        x: dot(&b.c0, &v),
        y: dot(&b.c1, &v),
        z: dot(&b.c2, &v),
    };
    let q0 = times(&v, b.offset.x);
    let q1 = times(&v, b.offset.y);
    let q2 = times(&v, b.offset.z);
    // Unless guarded, `∂L/∂s = −⟨∂L/∂y, y⟩ / s` reaches row `a` through adjugate column `c_a`.
    let gs = select(b.guarded, 0.0f32, -dot(&g, &canonical(&b)) / b.det);
    let g0 = plus(
        &plus(&cross(&q1, &b.r2), &cross(&b.r1, &q2)),
        &times(&b.c0, gs),
    );
    let g1 = plus(
        &plus(&cross(&b.r2, &q0), &cross(&q2, &b.r0)),
        &times(&b.c1, gs),
    );
    let g2 = plus(
        &plus(&cross(&q0, &b.r1), &cross(&b.r0, &q1)),
        &times(&b.c2, gs),
    );
    write3(grad_points, i, &u);
    // `∂L/∂w_k = ⟨∂L/∂M, A_k⟩` with `∂L/∂M` = rows `(g_a, −u_a)`.
    let k = bones.shape(0);
    for bone in 0..k {
        let a = bone * 12;
        grad_weights[i * k + bone] = g0.x * bones[a] + g0.y * bones[a + 1] + g0.z * bones[a + 2]
            - u.x * bones[a + 3]
            + g1.x * bones[a + 4]
            + g1.y * bones[a + 5]
            + g1.z * bones[a + 6]
            - u.y * bones[a + 7]
            + g2.x * bones[a + 8]
            + g2.y * bones[a + 9]
            + g2.z * bones[a + 10]
            - u.z * bones[a + 11];
    }
}

/// `out = softmax(log(prior + ε) + residual)` per row, computed as `(prior + ε) · e^(F − max F)`,
/// normalised; one unit per row.
#[cube(launch_unchecked)]
fn prior_softmax_kernel(prior: &Tensor<f32>, residual: &Tensor<f32>, out: &mut Tensor<f32>) {
    if ABSOLUTE_POS >= prior.shape(0) {
        terminate!();
    }
    let k = prior.shape(1);
    let base = ABSOLUTE_POS * k;
    let mut largest = residual[base];
    for j in 1..k {
        largest = max(largest, residual[base + j]);
    }
    let mut total = 0.0f32;
    for j in 0..k {
        let term = (prior[base + j] + PRIOR_EPSILON) * f32::exp(residual[base + j] - largest);
        out[base + j] = term;
        total += term;
    }
    let scale = 1.0f32 / total;
    for j in 0..k {
        out[base + j] *= scale;
    }
}

/// `out = w ⊙ (g − ⟨g, w⟩)` per row: the logits' gradient of the prior softmax; one unit per row.
#[cube(launch_unchecked)]
fn prior_softmax_logit_grad_kernel(
    weights: &Tensor<f32>,
    grad: &Tensor<f32>,
    out: &mut Tensor<f32>,
) {
    if ABSOLUTE_POS >= weights.shape(0) {
        terminate!();
    }
    let k = weights.shape(1);
    let base = ABSOLUTE_POS * k;
    let mut inner = 0.0f32;
    for j in 0..k {
        inner += weights[base + j] * grad[base + j];
    }
    for j in 0..k {
        out[base + j] = weights[base + j] * (grad[base + j] - inner);
    }
}

/// A point's cell along one axis of a [`TrilinearGrid`]: its low and high node (border clamped), its
/// position between them and whether it lies strictly inside the box (else clamped: zero derivative).
#[derive(CubeType)]
struct Axis {
    low: u32,
    high: u32,
    frac: f32,
    inside: bool,
}

/// The cell along an axis of `nodes` nodes starting at `min` (metres) with `scale` cells per metre.
#[cube]
fn axis_cell(p: f32, min_corner: f32, scale: f32, nodes: u32) -> Axis {
    let cells = f32::cast_from(nodes - 1);
    let raw = (p - min_corner) * scale;
    let u = clamp(raw, 0.0f32, cells);
    // `u ≥ 0`, so the conversion truncates to the floor; the far face belongs to the last cell.
    let low = min(u32::cast_from(u), select(nodes >= 2, nodes - 2, 0u32));
    Axis {
        low,
        high: min(low + 1, nodes - 1),
        frac: u - f32::cast_from(low),
        inside: raw > 0.0f32 && raw < cells,
    }
}

/// Point `i`'s cell in the grid: one [`Axis`] per coordinate.
#[derive(CubeType)]
struct GridCell {
    x: Axis,
    y: Axis,
    z: Axis,
}

/// The grid's layout as kernel scalars (a [`TrilinearGrid`]).
#[derive(CubeType, CubeLaunch)]
struct GridArgs {
    min_x: f32,
    min_y: f32,
    min_z: f32,
    scale_x: f32,
    scale_y: f32,
    scale_z: f32,
    nodes_x: u32,
    nodes_y: u32,
    nodes_z: u32,
}

#[cube]
fn grid_cell(points: &Tensor<f32>, i: usize, grid: &GridArgs) -> GridCell {
    let p = row3(points, i);
    GridCell {
        x: axis_cell(p.x, grid.min_x, grid.scale_x, grid.nodes_x),
        y: axis_cell(p.y, grid.min_y, grid.scale_y, grid.nodes_y),
        z: axis_cell(p.z, grid.min_z, grid.scale_z, grid.nodes_z),
    }
}

#[cube]
fn pick(axis: &Axis, high: u32) -> u32 {
    select(high == 1, axis.high, axis.low)
}

/// Table row of corner `corner` (bit `a` set: the high side along axis `a`): node `(i, j, k)` is row
/// `(i·n_y + j)·n_z + k`.
#[cube]
fn corner_row(cell: &GridCell, corner: u32, grid: &GridArgs) -> usize {
    let x = pick(&cell.x, corner & 1);
    let y = pick(&cell.y, (corner >> 1) & 1);
    let z = pick(&cell.z, (corner >> 2) & 1);
    usize::cast_from((x * grid.nodes_y + y) * grid.nodes_z + z)
}

/// `out[i, c] = Σ_corners w · table[row, c]`, one unit per point.
#[cube(launch_unchecked)]
fn trilinear_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    out: &mut Tensor<f32>,
    grid: GridArgs,
) {
    if ABSOLUTE_POS >= points.shape(0) {
        terminate!();
    }
    let i = ABSOLUTE_POS;
    let cell = grid_cell(points, i, &grid);
    let mut rows = Array::<usize>::new(8usize);
    let mut weights = Array::<f32>::new(8usize);
    #[unroll]
    for c in 0..8u32 {
        let slot = usize::cast_from(c);
        rows[slot] = corner_row(&cell, c, &grid);
        weights[slot] = side_weight(cell.x.frac, c & 1)
            * side_weight(cell.y.frac, (c >> 1) & 1)
            * side_weight(cell.z.frac, (c >> 2) & 1);
    }
    let channels = table.shape(1);
    for ch in 0..channels {
        let mut acc = 0.0f32;
        #[unroll]
        for c in 0..8usize {
            acc += weights[c] * table[rows[c] * channels + ch];
        }
        out[i * channels + ch] = acc;
    }
}

/// `out[i, a] = scale_a · Σ_corners ∂w/∂frac_a · ⟨grad_i, table[row]⟩`, zero along an axis where the point
/// is clamped; one unit per point.
#[cube(launch_unchecked)]
fn trilinear_points_grad_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    grad: &Tensor<f32>,
    out: &mut Tensor<f32>,
    grid: GridArgs,
) {
    if ABSOLUTE_POS >= points.shape(0) {
        terminate!();
    }
    let i = ABSOLUTE_POS;
    let cell = grid_cell(points, i, &grid);
    let channels = table.shape(1);
    let mut dx = 0.0f32;
    let mut dy = 0.0f32;
    let mut dz = 0.0f32;
    #[unroll]
    for c in 0..8u32 {
        let row = corner_row(&cell, c, &grid);
        let mut inner = 0.0f32;
        for ch in 0..channels {
            inner += grad[i * channels + ch] * table[row * channels + ch];
        }
        let (hx, hy, hz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let sx = side_weight(cell.x.frac, hx);
        let sy = side_weight(cell.y.frac, hy);
        let sz = side_weight(cell.z.frac, hz);
        dx += inner * (side_sign(hx) * sy * sz);
        dy += inner * (side_sign(hy) * sx * sz);
        dz += inner * (side_sign(hz) * sx * sy);
    }
    out[3 * i] = select(cell.x.inside, dx * grid.scale_x, 0.0f32);
    out[3 * i + 1] = select(cell.y.inside, dy * grid.scale_y, 0.0f32);
    out[3 * i + 2] = select(cell.z.inside, dz * grid.scale_z, 0.0f32);
}

/// The grid as launch arguments.
fn grid_args(grid: &TrilinearGrid) -> GridArgsLaunch {
    let [min_x, min_y, min_z] = grid.min;
    let [scale_x, scale_y, scale_z] = grid.scale;
    let [nodes_x, nodes_y, nodes_z] = grid.dims.map(|n| {
        u32::try_from(n).expect("volume nodes per axis fit in u32 (checked by BlendWeightVolume)")
    });
    GridArgsLaunch::new(
        min_x, min_y, min_z, scale_x, scale_y, scale_z, nodes_x, nodes_y, nodes_z,
    )
}

impl FusedBackend for Cube {
    fn inverse_skinning(points: CubeTensor, weights: CubeTensor, bones: CubeTensor) -> CubeTensor {
        let n = check_skinning(dims(&points), dims(&weights), dims(&bones));
        let out = empty_f32(&points, [n, 3]);
        let Some(units) = Units::on(&points, n) else {
            return out;
        };
        // SAFETY: the kernel reads rows `< N` of `[N, 3]` and `[N, K]` and bones `< K` of `[K, 12]`, all
        // contiguous, and writes row `i < N` of the new `[N, 3]` output.
        unsafe {
            inverse_skinning_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                contiguous_f32(points, "points").into_tensor_arg(),
                contiguous_f32(weights, "weights").into_tensor_arg(),
                contiguous_f32(bones, "bones").into_tensor_arg(),
                out.clone().into_tensor_arg(),
            )
        }
        out
    }

    fn inverse_skinning_grads(
        points: CubeTensor,
        weights: CubeTensor,
        bones: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor) {
        let n = check_skinning(dims(&points), dims(&weights), dims(&bones));
        assert_eq!(dims(&grad), [n, 3], "inverse skinning: output gradient");
        let k = dims(&bones)[0];
        let grad_points = empty_f32(&points, [n, 3]);
        let grad_weights = empty_f32(&points, [n, k]);
        let Some(units) = Units::on(&points, n) else {
            return (grad_points, grad_weights);
        };
        // SAFETY: as the forward; the outputs are new contiguous `[N, 3]` and `[N, K]` tensors.
        unsafe {
            inverse_skinning_grads_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                contiguous_f32(points, "points").into_tensor_arg(),
                contiguous_f32(weights, "weights").into_tensor_arg(),
                contiguous_f32(bones, "bones").into_tensor_arg(),
                contiguous_f32(grad, "gradients").into_tensor_arg(),
                grad_points.clone().into_tensor_arg(),
                grad_weights.clone().into_tensor_arg(),
            )
        }
        (grad_points, grad_weights)
    }

    fn prior_softmax(prior: CubeTensor, residual: CubeTensor) -> CubeTensor {
        let [n, k] = dims(&prior);
        assert_eq!(dims(&residual), [n, k], "prior softmax: residual");
        let out = empty_f32(&prior, [n, k]);
        let Some(units) = Units::on(&prior, if k == 0 { 0 } else { n }) else {
            return out;
        };
        // SAFETY: unit `i < N` reads and writes row `i` of contiguous `[N, K]` tensors.
        unsafe {
            prior_softmax_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                contiguous_f32(prior, "priors").into_tensor_arg(),
                contiguous_f32(residual, "residuals").into_tensor_arg(),
                out.clone().into_tensor_arg(),
            )
        }
        out
    }

    fn prior_softmax_logit_grad(weights: CubeTensor, grad: CubeTensor) -> CubeTensor {
        let [n, k] = dims(&weights);
        assert_eq!(dims(&grad), [n, k], "prior softmax: output gradient");
        let out = empty_f32(&weights, [n, k]);
        let Some(units) = Units::on(&weights, n) else {
            return out;
        };
        // SAFETY: unit `i < N` reads and writes row `i` of contiguous `[N, K]` tensors.
        unsafe {
            prior_softmax_logit_grad_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                contiguous_f32(weights, "weights").into_tensor_arg(),
                contiguous_f32(grad, "gradients").into_tensor_arg(),
                out.clone().into_tensor_arg(),
            )
        }
        out
    }

    fn trilinear(points: CubeTensor, table: CubeTensor, grid: TrilinearGrid) -> CubeTensor {
        let (n, c) = check_trilinear(dims(&points), dims(&table), &grid);
        let out = empty_f32(&points, [n, c]);
        let Some(units) = Units::on(&points, n) else {
            return out;
        };
        // SAFETY: every corner row is a clamped node `< nodes` of the `[nodes, C]` table; unit `i < N`
        // writes row `i` of the new `[N, C]` output.
        unsafe {
            trilinear_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                contiguous_f32(points, "points").into_tensor_arg(),
                contiguous_f32(table, "volume tables").into_tensor_arg(),
                out.clone().into_tensor_arg(),
                grid_args(&grid),
            )
        }
        out
    }

    fn trilinear_points_grad(
        points: CubeTensor,
        table: CubeTensor,
        grad: CubeTensor,
        grid: TrilinearGrid,
    ) -> CubeTensor {
        let (n, c) = check_trilinear(dims(&points), dims(&table), &grid);
        assert_eq!(dims(&grad), [n, c], "trilinear: output gradient");
        let out = empty_f32(&points, [n, 3]);
        let Some(units) = Units::on(&points, n) else {
            return out;
        };
        // SAFETY: as the forward; unit `i < N` writes row `i` of the new `[N, 3]` output.
        unsafe {
            trilinear_points_grad_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                contiguous_f32(points, "points").into_tensor_arg(),
                contiguous_f32(table, "volume tables").into_tensor_arg(),
                contiguous_f32(grad, "gradients").into_tensor_arg(),
                out.clone().into_tensor_arg(),
                grid_args(&grid),
            )
        }
        out
    }
}

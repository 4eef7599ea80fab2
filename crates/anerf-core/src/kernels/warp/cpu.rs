//! Hand-written CPU kernels of the warp's fused operations, on row-major slices, rayon-parallel over blocks
//! of points. Shapes: points `[N, 3]` (metres), weights, priors and residuals `[N, K]`, bones `[K, 12]` (the
//! top three rows of each 4×4 `A_k`, row-major, as [`crate::geometry::BoneMatrices`]).

use glam::Vec3;
use rayon::prelude::*;

use super::DET_GUARD;
use crate::kernels::fastmath;
use crate::kernels::trilinear::{cell_position_gradient, corner_weights};

/// Points per rayon task: one point's work is a few hundred flops, a task needs thousands.
const BLOCK: usize = 512;

/// Added to the prior before its logarithm (the reference's `log(w^s + 1e-9)`).
pub const PRIOR_EPSILON: f32 = 1e-9;

/// One point's blended transform `M = Σ_k w_k A_k` and the pieces of `rot(M)⁻¹` both passes use.
struct Blended {
    /// Rows of `rot(M)`.
    rows: [Vec3; 3],
    /// Columns of the adjugate: `r1×r2`, `r2×r0`, `r0×r1`.
    adjugate: [Vec3; 3],
    /// `x − t(M)`.
    offset: Vec3,
    /// `det rot(M)`, or [`DET_GUARD`] where `|det| < DET_GUARD`.
    det: f32,
    /// Whether the determinant was replaced (no gradient flows through it then).
    guarded: bool,
}

impl Blended {
    #[inline(always)]
    fn new(point: &[f32], weights: &[f32], bones: &[f32]) -> Self {
        let mut m = [0.0f32; 12];
        for (&w, bone) in weights.iter().zip(bones.chunks_exact(12)) {
            for (m, b) in m.iter_mut().zip(bone) {
                *m += w * b;
            }
        }
        let rows = [
            Vec3::new(m[0], m[1], m[2]),
            Vec3::new(m[4], m[5], m[6]),
            Vec3::new(m[8], m[9], m[10]),
        ];
        let adjugate = [
            rows[1].cross(rows[2]),
            rows[2].cross(rows[0]),
            rows[0].cross(rows[1]),
        ];
        let det = rows[0].dot(adjugate[0]);
        let guarded = det.abs() < DET_GUARD;
        Self {
            rows,
            adjugate,
            offset: Vec3::from_slice(point) - Vec3::new(m[3], m[7], m[11]),
            det: if guarded { DET_GUARD } else { det },
            guarded,
        }
    }

    /// `rot(M)⁻¹ (x − t(M))`.
    #[inline(always)]
    fn canonical(&self) -> Vec3 {
        let [c0, c1, c2] = self.adjugate;
        let d = self.offset;
        (c0 * d.x + c1 * d.y + c2 * d.z) / self.det
    }
}

/// Inverse skinning `x_can = rot(M)⁻¹ (x − t(M))` of every point into `out` (`[N, 3]`), with the guard of
/// [`crate::geometry::BoneMatrices::inverse`].
pub fn inverse_skinning(points: &[f32], weights: &[f32], bones: &[f32], out: &mut [f32]) {
    let k = bones.len() / 12;
    out.par_chunks_mut(3 * BLOCK)
        .zip(points.par_chunks(3 * BLOCK))
        .zip(weights.par_chunks(k * BLOCK))
        .for_each(|((out, points), weights)| {
            for ((o, p), w) in out
                .chunks_exact_mut(3)
                .zip(points.chunks_exact(3))
                .zip(weights.chunks_exact(k))
            {
                o.copy_from_slice(&Blended::new(p, w, bones).canonical().to_array());
            }
        });
}

/// Gradients of [`inverse_skinning`] from the output gradient `grad` (`[N, 3]`): into `grad_points`
/// (`[N, 3]`) and `grad_weights` (`[N, K]`); the bones are constants.
///
/// With `y = adj(R) d / s` (`d = x − t`, `s = det R` unless guarded) and `v = ∂L/∂y / s`: `∂L/∂d = adjᵀ v`
/// (so `∂L/∂x = adjᵀ v`, `∂L/∂t = −adjᵀ v`), each adjugate column `c_a = r_b × r_c` passes `q_a = v d_a` to
/// its two rows (`∂⟨q, r_b×r_c⟩/∂r_b = r_c×q`, `∂/∂r_c = q×r_b`), and unless guarded `∂L/∂s = −⟨∂L/∂y, y⟩ / s`
/// reaches row `a` as `c_a` (`∂ det/∂r_a = c_a`); finally `∂L/∂w_k = ⟨∂L/∂M, A_k⟩`.
pub fn inverse_skinning_grads(
    points: &[f32],
    weights: &[f32],
    bones: &[f32],
    grad: &[f32],
    grad_points: &mut [f32],
    grad_weights: &mut [f32],
) {
    let k = bones.len() / 12;
    grad_points
        .par_chunks_mut(3 * BLOCK)
        .zip(grad_weights.par_chunks_mut(k * BLOCK))
        .zip(points.par_chunks(3 * BLOCK))
        .zip(weights.par_chunks(k * BLOCK))
        .zip(grad.par_chunks(3 * BLOCK))
        .for_each(|((((gp, gw), points), weights), grad)| {
            for ((((gp, gw), p), w), g) in gp
                .chunks_exact_mut(3)
                .zip(gw.chunks_exact_mut(k))
                .zip(points.chunks_exact(3))
                .zip(weights.chunks_exact(k))
                .zip(grad.chunks_exact(3))
            {
                let b = Blended::new(p, w, bones);
                let g = Vec3::from_slice(g);
                let v = g / b.det;
                let [c0, c1, c2] = b.adjugate;
                let [r0, r1, r2] = b.rows;
                let u = Vec3::new(c0.dot(v), c1.dot(v), c2.dot(v));
                let q = [v * b.offset.x, v * b.offset.y, v * b.offset.z];
                let mut gr = [
                    q[1].cross(r2) + r1.cross(q[2]),
                    r2.cross(q[0]) + q[2].cross(r0),
                    q[0].cross(r1) + r0.cross(q[1]),
                ];
                if !b.guarded {
                    let gs = -g.dot(b.canonical()) / b.det;
                    for (gr, c) in gr.iter_mut().zip(b.adjugate) {
                        *gr += c * gs;
                    }
                }
                gp.copy_from_slice(&u.to_array());
                let dm = [
                    gr[0].x, gr[0].y, gr[0].z, -u.x, gr[1].x, gr[1].y, gr[1].z, -u.y, gr[2].x,
                    gr[2].y, gr[2].z, -u.z,
                ];
                for (gw, bone) in gw.iter_mut().zip(bones.chunks_exact(12)) {
                    *gw = dm.iter().zip(bone).map(|(a, b)| a * b).sum();
                }
            }
        });
}

/// `w = softmax(log(w^s + ε) + F)` per row (`[N, K]` each) into `out`: the log-softmax blend parameterisation,
/// computed without the logarithm as `(w^s + ε) · e^(F − max F)`, normalised, with the vectorising
/// `fastmath::exp` (crate-private). The row's largest `F` gives a term of at least `ε`, so the sum is
/// positive.
pub fn prior_softmax(prior: &[f32], residual: &[f32], k: usize, out: &mut [f32]) {
    out.par_chunks_mut(k * BLOCK)
        .zip(prior.par_chunks(k * BLOCK))
        .zip(residual.par_chunks(k * BLOCK))
        .for_each(|((out, prior), residual)| {
            for ((o, p), f) in out
                .chunks_exact_mut(k)
                .zip(prior.chunks_exact(k))
                .zip(residual.chunks_exact(k))
            {
                let max = f.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                // Two loops: the first vectorises, the sum (an ordered float reduction) would stop it.
                for ((o, p), f) in o.iter_mut().zip(p).zip(f) {
                    *o = (p + PRIOR_EPSILON) * fastmath::exp(f - max);
                }
                let scale = 1.0 / o.iter().sum::<f32>();
                o.iter_mut().for_each(|o| *o *= scale);
            }
        });
}

/// The gradient of [`prior_softmax`]'s logits, `w ⊙ (g − ⟨g, w⟩)` per row, from its output `w` and the output
/// gradient `g` (`[N, K]` each): the residual's gradient, and the prior's after division by `w^s + ε`.
pub fn prior_softmax_logit_grad(weights: &[f32], grad: &[f32], k: usize, out: &mut [f32]) {
    out.par_chunks_mut(k * BLOCK)
        .zip(weights.par_chunks(k * BLOCK))
        .zip(grad.par_chunks(k * BLOCK))
        .for_each(|((out, weights), grad)| {
            for ((o, w), g) in out
                .chunks_exact_mut(k)
                .zip(weights.chunks_exact(k))
                .zip(grad.chunks_exact(k))
            {
                let dot: f32 = w.iter().zip(g).map(|(w, g)| w * g).sum();
                for ((o, w), g) in o.iter_mut().zip(w).zip(g) {
                    *o = w * (g - dot);
                }
            }
        });
}

/// A regular grid of nodes over a box (a [`crate::geometry::BlendWeightVolume`]'s layout): node `(i, j, k)` is
/// row `(i·n_y + j)·n_z + k` of the table, points are in the volume's frame (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrilinearGrid {
    /// The box's least corner, metres.
    pub min: [f32; 3],
    /// Cells per metre along each axis, `(n_a − 1) / size_a`.
    pub scale: [f32; 3],
    /// Nodes per axis.
    pub dims: [usize; 3],
}

/// A point's eight surrounding nodes (border clamped) and its position in their cell.
struct Cell {
    rows: [usize; 8],
    frac: [f32; 3],
    /// Per axis, whether the point lies strictly inside the box (else clamped: zero derivative).
    inside: [bool; 3],
}

impl TrilinearGrid {
    #[inline(always)]
    fn cell(&self, p: &[f32]) -> Cell {
        let mut low = [0usize; 3];
        let mut high = [0usize; 3];
        let mut frac = [0.0f32; 3];
        let mut inside = [false; 3];
        for a in 0..3 {
            let cells = (self.dims[a] - 1) as f32;
            let raw = (p[a] - self.min[a]) * self.scale[a];
            inside[a] = raw > 0.0 && raw < cells;
            let u = raw.clamp(0.0, cells);
            // `u ≥ 0`, so truncation is the floor.
            let i0 = (u as usize).min(self.dims[a].saturating_sub(2));
            low[a] = i0;
            high[a] = (i0 + 1).min(self.dims[a] - 1);
            frac[a] = u - i0 as f32;
        }
        let [_, ny, nz] = self.dims;
        let rows = std::array::from_fn(|c| {
            let pick = |a: usize| if (c >> a) & 1 == 1 { high[a] } else { low[a] };
            (pick(0) * ny + pick(1)) * nz + pick(2)
        });
        Cell { rows, frac, inside }
    }
}

/// Trilinear interpolation of the rows of `table` (`[nodes, C]`) at points `[N, 3]` into `out` (`[N, C]`).
pub fn trilinear(points: &[f32], table: &[f32], grid: &TrilinearGrid, out: &mut [f32]) {
    let c = table.len() / grid.dims.iter().product::<usize>();
    out.par_chunks_mut(c * BLOCK)
        .zip(points.par_chunks(3 * BLOCK))
        .for_each(|(out, points)| {
            for (o, p) in out.chunks_exact_mut(c).zip(points.chunks_exact(3)) {
                let cell = grid.cell(p);
                o.fill(0.0);
                for (&r, w) in cell.rows.iter().zip(corner_weights(cell.frac)) {
                    for (o, t) in o.iter_mut().zip(&table[r * c..(r + 1) * c]) {
                        *o += w * t;
                    }
                }
            }
        });
}

/// The points' gradient `[N, 3]` of [`trilinear`] from the output gradient `[N, C]` (the table is constant):
/// `Σ_c ∂w_c/∂frac_a · ⟨grad, table[row_c]⟩ · scale_a`, zero along an axis where the point is clamped.
pub fn trilinear_points_grad(
    points: &[f32],
    table: &[f32],
    grad: &[f32],
    grid: &TrilinearGrid,
    out: &mut [f32],
) {
    let c = table.len() / grid.dims.iter().product::<usize>();
    out.par_chunks_mut(3 * BLOCK)
        .zip(points.par_chunks(3 * BLOCK))
        .zip(grad.par_chunks(c * BLOCK))
        .for_each(|((out, points), grad)| {
            for ((o, p), g) in out
                .chunks_exact_mut(3)
                .zip(points.chunks_exact(3))
                .zip(grad.chunks_exact(c))
            {
                let cell = grid.cell(p);
                let d = cell_position_gradient(&cell.rows, cell.frac, g, table);
                for a in 0..3 {
                    o[a] = if cell.inside[a] {
                        d[a] * grid.scale[a]
                    } else {
                        0.0
                    };
                }
            }
        });
}

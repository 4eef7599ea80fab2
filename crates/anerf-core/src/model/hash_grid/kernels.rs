//! Hand-written CPU kernels of the hash-grid encoding on plain slices (rayon-parallel, no atomics): the
//! forward gather, the table gradient (a scatter, partitioned by level so each thread owns its rows) and the
//! gradient with respect to the points.
//!
//! Shapes: points `[N, 3]` (metres), table `[L·T, F]`, encodings and their gradients `[N, L·F]`, all
//! row-major.

use rayon::prelude::*;

use super::GridSpec;
use crate::trilinear::{cell_position_gradient, corner_weight_derivatives, corner_weights};

/// Fewest points per rayon task of the per-point kernels.
const MIN_CHUNK: usize = 256;

/// One level's constants, resolved once per kernel call.
#[derive(Debug, Clone, Copy)]
struct Level {
    /// Cells per axis `N`, as an integer and as a float.
    res: u32,
    res_f: f32,
    /// `(N + 1)³ ≤ T`: vertices are stored densely, at `x + (N+1)·(y + (N+1)·z)`.
    dense: bool,
    /// Metres → cells: `N / 2h`.
    cells_per_metre: f32,
}

impl GridSpec {
    fn level_constants(&self) -> Vec<Level> {
        (0..self.levels())
            .map(|l| {
                let res = self.resolutions[l];
                Level {
                    res,
                    res_f: res as f32,
                    dense: self.is_dense(l),
                    cells_per_metre: res as f32 / (2.0 * self.half_extent),
                }
            })
            .collect()
    }

    /// Point `p` (metres) in the grid's unit cube, clamped, and per axis whether it lies strictly inside:
    /// the same at every level, so the kernels compute it once per point.
    #[inline(always)]
    fn unit(&self, p: &[f32]) -> Unit {
        let mut u = [0.0f32; 3];
        let mut inside = [false; 3];
        for a in 0..3 {
            let v = (p[a] + self.half_extent) / (2.0 * self.half_extent);
            inside[a] = v > 0.0 && v < 1.0;
            u[a] = v.clamp(0.0, 1.0);
        }
        Unit { u, inside }
    }

    /// [`Self::unit`] of every point of `points` (`[N, 3]`).
    fn units(&self, points: &[f32]) -> Vec<Unit> {
        points.chunks_exact(3).map(|p| self.unit(p)).collect()
    }

    /// The eight corners around a point (its [`Unit`] position) at `level`: their rows in the level's table
    /// (corner `c` has bit `a` set on the high side along axis `a`), and per axis the position in the cell and
    /// whether the point lies strictly inside the grid (outside, the position is clamped and its derivative is
    /// zero).
    #[inline(always)]
    fn corners(&self, level: &Level, unit: &Unit) -> Corners {
        let mut frac = [0.0f32; 3];
        let mut base = [0u32; 3];
        for a in 0..3 {
            let x = unit.u[a] * level.res_f;
            // `x ≥ 0`, so truncation is the floor (and needs no libm call on baseline x86-64).
            let i0 = (x as u32).min(level.res - 1);
            base[a] = i0;
            frac[a] = x - i0 as f32;
        }
        // Per axis, the two vertex terms of the row index (low, high).
        let mask = self.table_size as u32 - 1;
        let terms: [[u32; 2]; 3] = if level.dense {
            let side = level.res + 1;
            let stride = [1, side, side * side];
            std::array::from_fn(|a| [base[a] * stride[a], (base[a] + 1) * stride[a]])
        } else {
            std::array::from_fn(|a| {
                [
                    base[a].wrapping_mul(HASH_PRIMES[a]),
                    (base[a] + 1).wrapping_mul(HASH_PRIMES[a]),
                ]
            })
        };
        let rows = std::array::from_fn(|c| {
            let (x, y, z) = (
                terms[0][c & 1],
                terms[1][(c >> 1) & 1],
                terms[2][(c >> 2) & 1],
            );
            if level.dense {
                (x + y + z) as usize
            } else {
                ((x ^ y ^ z) & mask) as usize
            }
        });
        Corners {
            rows,
            frac,
            inside: unit.inside,
        }
    }
}

/// A point's clamped position in the grid's unit cube (see [`GridSpec::unit`]).
#[derive(Debug, Clone, Copy)]
struct Unit {
    u: [f32; 3],
    inside: [bool; 3],
}

/// The corners of a point's cell at one level (see [`GridSpec::corners`]).
#[derive(Debug, Clone, Copy)]
struct Corners {
    rows: [usize; 8],
    frac: [f32; 3],
    inside: [bool; 3],
}

/// The primes of Instant-NGP's spatial hash (the first is 1).
pub(crate) const HASH_PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

/// Points per rayon task of the per-point kernels: each task walks the levels in its outer loop, so that one
/// level's table (a few hundred KiB) stays in cache while the task's points read it at random rows. (Walking
/// the levels inside the point loop touches every level's table per point and is several times slower.)
fn chunk_rows(n: usize) -> usize {
    n.div_ceil(4 * rayon::current_num_threads()).max(MIN_CHUNK)
}

/// The feature width `F` of a kernel instantiated with `WIDTH` (the width as a constant, so that the
/// per-corner loops unroll) or `WIDTH = 0` (read from `spec`, for uncommon widths).
#[inline(always)]
fn features<const WIDTH: usize>(spec: &GridSpec) -> usize {
    debug_assert!(WIDTH == 0 || WIDTH == spec.features);
    if WIDTH == 0 {
        spec.features
    } else {
        WIDTH
    }
}

/// Calls `$kernel::<F>` with the spec's feature width as a constant where it is a common one.
macro_rules! with_width {
    ($spec:expr, $kernel:ident ( $($arg:expr),* )) => {
        match $spec.features {
            1 => $kernel::<1>($($arg),*),
            2 => $kernel::<2>($($arg),*),
            4 => $kernel::<4>($($arg),*),
            8 => $kernel::<8>($($arg),*),
            _ => $kernel::<0>($($arg),*),
        }
    };
}

/// `out[i, l·F + f] = Σ_c w_c(p_i) · table[l·T + row_c, f]`.
pub fn encode(points: &[f32], table: &[f32], spec: &GridSpec, out: &mut [f32]) {
    with_width!(spec, encode_with(points, table, spec, out))
}

fn encode_with<const WIDTH: usize>(
    points: &[f32],
    table: &[f32],
    spec: &GridSpec,
    out: &mut [f32],
) {
    let (f, width) = (features::<WIDTH>(spec), spec.output_dim());
    let levels = spec.level_constants();
    let rows = chunk_rows(points.len() / 3);
    out.par_chunks_mut(width * rows)
        .zip(points.par_chunks(3 * rows))
        .for_each(|(block, points)| {
            let units = spec.units(points);
            for (l, level) in levels.iter().enumerate() {
                let level_table = &table[l * spec.table_size * f..(l + 1) * spec.table_size * f];
                for (row, unit) in block.chunks_exact_mut(width).zip(&units) {
                    let corners = spec.corners(level, unit);
                    // Accumulated in registers and stored once (`F ≤ 8`, HashGridConfig::validate):
                    // accumulating in the output row made every corner wait for the previous one's store.
                    let mut acc = [0.0f32; 8];
                    for (&r, w) in corners.rows.iter().zip(corner_weights(corners.frac)) {
                        for (o, t) in acc[..f].iter_mut().zip(&level_table[r * f..(r + 1) * f]) {
                            *o += w * t;
                        }
                    }
                    row[l * f..(l + 1) * f].copy_from_slice(&acc[..f]);
                }
            }
        });
}

/// `grad_table[l·T + row, f] = Σ_i Σ_c [row_c(p_i) = row] · w_c(p_i) · grad[i, l·F + f]`; `grad_table` must
/// be zero on entry. Each level's rows belong to one task, so the scatter needs no atomics.
pub fn table_grad(points: &[f32], grad: &[f32], spec: &GridSpec, grad_table: &mut [f32]) {
    with_width!(spec, table_grad_with(points, grad, spec, grad_table))
}

fn table_grad_with<const WIDTH: usize>(
    points: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    grad_table: &mut [f32],
) {
    let (f, width) = (features::<WIDTH>(spec), spec.output_dim());
    let levels = spec.level_constants();
    let units = spec.units(points);
    grad_table
        .par_chunks_mut(spec.table_size * f)
        .zip(&levels)
        .enumerate()
        .for_each(|(l, (rows, level))| {
            for (unit, g) in units.iter().zip(grad.chunks_exact(width)) {
                let g = &g[l * f..(l + 1) * f];
                if g.iter().all(|&v| v == 0.0) {
                    continue;
                }
                let corners = spec.corners(level, unit);
                for (&r, w) in corners.rows.iter().zip(corner_weights(corners.frac)) {
                    for (t, gv) in rows[r * f..(r + 1) * f].iter_mut().zip(g) {
                        *t += w * gv;
                    }
                }
            }
        });
}

/// `grad_points[i, a] = Σ_l Σ_f grad[i, l·F + f] · ∂ out[i, l·F + f] / ∂ p_{i,a}`: the trilinear weights'
/// derivatives times the table entries, zero along an axis where the point lies outside the grid.
pub fn points_grad(
    points: &[f32],
    table: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    grad_points: &mut [f32],
) {
    with_width!(
        spec,
        points_grad_with(points, table, grad, spec, grad_points)
    )
}

fn points_grad_with<const WIDTH: usize>(
    points: &[f32],
    table: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    grad_points: &mut [f32],
) {
    let (f, width) = (features::<WIDTH>(spec), spec.output_dim());
    let levels = spec.level_constants();
    let rows = chunk_rows(points.len() / 3);
    grad_points
        .par_chunks_mut(3 * rows)
        .zip(points.par_chunks(3 * rows))
        .zip(grad.par_chunks(width * rows))
        .for_each(|((block, points), grad)| {
            block.fill(0.0);
            let units = spec.units(points);
            for (l, level) in levels.iter().enumerate() {
                let level_table = &table[l * spec.table_size * f..(l + 1) * spec.table_size * f];
                for ((acc, unit), g) in block
                    .chunks_exact_mut(3)
                    .zip(&units)
                    .zip(grad.chunks_exact(width))
                {
                    let g = &g[l * f..(l + 1) * f];
                    let corners = spec.corners(level, unit);
                    let d = cell_position_gradient(&corners.rows, corners.frac, g, level_table);
                    for a in 0..3 {
                        if corners.inside[a] {
                            acc[a] += d[a] * level.cells_per_metre;
                        }
                    }
                }
            }
        });
}

/// Both gradients at once, [`table_grad`] into `grad_table` (zero on entry) and [`points_grad`] into
/// `grad_points`: one walk over the levels computes each point's corners once for both. Each task owns its
/// levels' table rows; the point gradients of its levels are summed into one buffer per task, and the
/// buffers are added at the end.
pub fn grads(
    points: &[f32],
    table: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    grad_table: &mut [f32],
    grad_points: &mut [f32],
) {
    with_width!(
        spec,
        grads_with(points, table, grad, spec, grad_table, grad_points)
    )
}

fn grads_with<const WIDTH: usize>(
    points: &[f32],
    table: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    grad_table: &mut [f32],
    grad_points: &mut [f32],
) {
    let (f, width) = (features::<WIDTH>(spec), spec.output_dim());
    let levels = spec.level_constants();
    let units = spec.units(points);
    let level_len = spec.table_size * f;
    let per_task = levels.len().div_ceil(rayon::current_num_threads()).max(1);
    let summed = grad_table
        .par_chunks_mut(level_len)
        .zip(&levels)
        .enumerate()
        .with_min_len(per_task)
        .fold(
            || vec![0.0f32; units.len() * 3],
            |mut acc, (l, (rows, level))| {
                let level_table = &table[l * level_len..(l + 1) * level_len];
                for ((unit, g), acc) in units
                    .iter()
                    .zip(grad.chunks_exact(width))
                    .zip(acc.chunks_exact_mut(3))
                {
                    let g = &g[l * f..(l + 1) * f];
                    if g.iter().all(|&v| v == 0.0) {
                        continue;
                    }
                    let corners = spec.corners(level, unit);
                    let (weights, derivatives) = (
                        corner_weights(corners.frac),
                        corner_weight_derivatives(corners.frac),
                    );
                    let mut d = [0.0f32; 3];
                    for ((&r, w), dw) in corners.rows.iter().zip(weights).zip(derivatives) {
                        let mut dot = 0.0;
                        for ((t, gv), e) in rows[r * f..(r + 1) * f]
                            .iter_mut()
                            .zip(g)
                            .zip(&level_table[r * f..(r + 1) * f])
                        {
                            *t += w * gv;
                            dot += gv * e;
                        }
                        for (d, dw) in d.iter_mut().zip(dw) {
                            *d += dot * dw;
                        }
                    }
                    for a in 0..3 {
                        if corners.inside[a] {
                            acc[a] += d[a] * level.cells_per_metre;
                        }
                    }
                }
                acc
            },
        )
        .reduce_with(|mut a, b| {
            a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
            a
        });
    match summed {
        Some(sum) => grad_points.copy_from_slice(&sum),
        None => grad_points.fill(0.0),
    }
}

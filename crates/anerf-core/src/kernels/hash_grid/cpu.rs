//! Hand-written CPU kernels of the hash-grid encoding on plain slices (rayon-parallel, no atomics): the
//! forward gather, and the gradients with respect to the table (a scatter, partitioned by level so each
//! task owns its rows) and to the points.
//!
//! The kernels walk points in blocks of `LANES`: a block's corners at one level (cells, rows, trilinear
//! weights) are computed axis by axis in lane arrays, which the compiler vectorises, and only the table
//! reads and writes go point by point. `cargo bench -p anerf-core --bench hash_grid_kernels` times them
//! (figures in docs/PERFORMANCE.md).
//!
//! Shapes: points `[N, 3]` (metres), table `[L·T, F]`, encodings and their gradients `[N, L·F]`, all
//! row-major.

// Lane loops index several arrays by lane (and axis loops by axis): clearer as index loops.
#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;

use super::GridSpec;

/// Points per block (see the module doc).
const LANES: usize = 16;

/// Fewest points per rayon task of the encoding.
const MIN_CHUNK: usize = 256;

/// The primes of Instant-NGP's spatial hash (the first is 1).
pub const HASH_PRIMES: [u32; 3] = [1, 2_654_435_761, 805_459_861];

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

/// Up to [`LANES`] points' positions in the grid's unit cube, clamped, axis-major, and per axis whether each
/// lies strictly inside the grid (outside, the position is clamped and its derivative is zero). The same at
/// every level, so the kernels compute it once per point. Lanes past `len` hold zeros (the grid's least
/// corner) and are never read or written back.
#[derive(Debug, Clone)]
struct UnitBlock {
    u: [[f32; LANES]; 3],
    inside: [[bool; LANES]; 3],
    len: usize,
}

/// The cells of a [`UnitBlock`]'s points at one level: per corner the row in the level's table (corner `c`
/// has bit `a` set on the high side along axis `a`), and per axis the position in the cell, `[0, 1]`.
#[derive(Debug, Clone)]
struct CornerBlock {
    rows: [[u32; LANES]; 8],
    frac: [[f32; LANES]; 3],
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

    /// The [`UnitBlock`]s of `points` (`[N, 3]`, metres), in order.
    fn unit_blocks(&self, points: &[f32]) -> Vec<UnitBlock> {
        let scale = 1.0 / (2.0 * self.half_extent);
        points
            .chunks(3 * LANES)
            .map(|chunk| {
                let mut block = UnitBlock {
                    u: [[0.0; LANES]; 3],
                    inside: [[false; LANES]; 3],
                    len: chunk.len() / 3,
                };
                for (j, p) in chunk.chunks_exact(3).enumerate() {
                    for a in 0..3 {
                        let v = (p[a] + self.half_extent) * scale;
                        block.inside[a][j] = v > 0.0 && v < 1.0;
                        block.u[a][j] = v.clamp(0.0, 1.0);
                    }
                }
                block
            })
            .collect()
    }

    /// Fills `out` with the corners of `units` at `level`.
    #[inline(always)]
    fn corner_block(&self, level: &Level, units: &UnitBlock, out: &mut CornerBlock) {
        // Per axis, the low and high vertex's term of the row index.
        let mut terms = [[[0u32; LANES]; 2]; 3];
        let mut stride = 1u32;
        let last = level.res as i32 - 1;
        for a in 0..3 {
            let factor = if level.dense { stride } else { HASH_PRIMES[a] };
            for j in 0..LANES {
                let x = units.u[a][j] * level.res_f;
                // `0 ≤ x ≤ N ≤ 2^20`: truncation is the floor and exact in i32.
                let i0 = (x as i32).min(last);
                out.frac[a][j] = x - i0 as f32;
                terms[a][0][j] = (i0 as u32).wrapping_mul(factor);
                terms[a][1][j] = (i0 as u32 + 1).wrapping_mul(factor);
            }
            stride = stride.wrapping_mul(level.res + 1);
        }
        let mask = self.table_size as u32 - 1;
        for c in 0..8 {
            let (x, y, z) = (&terms[0][c & 1], &terms[1][(c >> 1) & 1], &terms[2][c >> 2]);
            let rows = &mut out.rows[c];
            if level.dense {
                for j in 0..LANES {
                    rows[j] = x[j] + y[j] + z[j];
                }
            } else {
                for j in 0..LANES {
                    rows[j] = (x[j] ^ y[j] ^ z[j]) & mask;
                }
            }
        }
    }
}

impl CornerBlock {
    fn new() -> Self {
        Self {
            rows: [[0; LANES]; 8],
            frac: [[0.0; LANES]; 3],
        }
    }

    /// Per axis, the two linear factors `1 − frac` and `frac`.
    #[inline(always)]
    fn factors(&self) -> [[[f32; LANES]; 2]; 3] {
        let mut s = [[[0.0f32; LANES]; 2]; 3];
        for a in 0..3 {
            for j in 0..LANES {
                s[a][0][j] = 1.0 - self.frac[a][j];
                s[a][1][j] = self.frac[a][j];
            }
        }
        s
    }

    /// Fills `out` with the eight corners' trilinear weights `Π_a (frac_a or 1 − frac_a)`.
    #[inline(always)]
    fn weights(&self, out: &mut [[f32; LANES]; 8]) {
        let s = self.factors();
        for (c, w) in out.iter_mut().enumerate() {
            let (x, y, z) = (&s[0][c & 1], &s[1][(c >> 1) & 1], &s[2][c >> 2]);
            for j in 0..LANES {
                w[j] = x[j] * y[j] * z[j];
            }
        }
    }

    /// Fills `out` per axis `a` with `Σ_c ∂weight_c/∂frac_a · dots[c]`: the derivative, with respect to the
    /// position in the cell, of a sum of the corners' values `dots` weighted by the trilinear weights.
    #[inline(always)]
    fn position_derivative(&self, dots: &[[f32; LANES]; 8], out: &mut [[f32; LANES]; 3]) {
        let s = self.factors();
        *out = [[0.0; LANES]; 3];
        for (c, dot) in dots.iter().enumerate() {
            for (a, d) in out.iter_mut().enumerate() {
                let sign = if (c >> a) & 1 == 1 { 1.0 } else { -1.0 };
                let (o1, o2) = ((a + 1) % 3, (a + 2) % 3);
                let (s1, s2) = (&s[o1][(c >> o1) & 1], &s[o2][(c >> o2) & 1]);
                for j in 0..LANES {
                    d[j] += sign * s1[j] * s2[j] * dot[j];
                }
            }
        }
    }
}

/// Points per rayon task of the encoding: each task walks the levels in its outer loop, so that one level's
/// table (a few hundred KiB) stays in cache while the task's points read it at random rows. (Walking the
/// levels inside the point loop touches every level's table per point and is several times slower.) A
/// multiple of [`LANES`], so that tasks split the points at block boundaries.
fn chunk_rows(n: usize) -> usize {
    n.div_ceil(4 * rayon::current_num_threads())
        .max(MIN_CHUNK)
        .next_multiple_of(LANES)
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

/// Calls `$kernel::<F, ..>` with the spec's feature width as a constant where it is a common one.
macro_rules! with_width {
    ($spec:expr, $kernel:ident $(::<$($flag:tt),*>)? ( $($arg:expr),* )) => {
        match $spec.features {
            1 => $kernel::<1 $($(, $flag)*)?>($($arg),*),
            2 => $kernel::<2 $($(, $flag)*)?>($($arg),*),
            4 => $kernel::<4 $($(, $flag)*)?>($($arg),*),
            8 => $kernel::<8 $($(, $flag)*)?>($($arg),*),
            _ => $kernel::<0 $($(, $flag)*)?>($($arg),*),
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
        .for_each(|(out, points)| {
            let blocks = spec.unit_blocks(points);
            let (mut corners, mut weights) = (CornerBlock::new(), [[0.0; LANES]; 8]);
            for (l, level) in levels.iter().enumerate() {
                let level_table = &table[l * spec.table_size * f..(l + 1) * spec.table_size * f];
                for (out, units) in out.chunks_mut(width * LANES).zip(&blocks) {
                    spec.corner_block(level, units, &mut corners);
                    corners.weights(&mut weights);
                    for (j, out) in out.chunks_exact_mut(width).enumerate() {
                        // Accumulated in registers and stored once (`F ≤ 8`, HashGridConfig::validate).
                        let mut acc = [0.0f32; 8];
                        for (rows, w) in corners.rows.iter().zip(&weights) {
                            let r = rows[j] as usize * f;
                            for (o, t) in acc[..f].iter_mut().zip(&level_table[r..r + f]) {
                                *o += w[j] * t;
                            }
                        }
                        out[l * f..(l + 1) * f].copy_from_slice(&acc[..f]);
                    }
                }
            }
        });
}

/// `grad_table[l·T + row, f] = Σ_i Σ_c [row_c(p_i) = row] · w_c(p_i) · grad[i, l·F + f]`; `grad_table` must
/// be zero on entry.
pub fn table_grad(points: &[f32], grad: &[f32], spec: &GridSpec, grad_table: &mut [f32]) {
    with_width!(
        spec,
        grads_with::<true, false>(points, &[], grad, spec, grad_table, &mut [])
    )
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
        grads_with::<false, true>(points, table, grad, spec, &mut [], grad_points)
    )
}

/// Both gradients, [`table_grad`] into `grad_table` (zero on entry) and [`points_grad`] into
/// `grad_points`, computing each point's corners once for both.
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
        grads_with::<true, true>(points, table, grad, spec, grad_table, grad_points)
    )
}

/// The gradients with respect to the table (`TABLE`) and to the points (`POINTS`). Tasks own whole levels:
/// a level's table rows are written by one task, so the scatter needs no atomics. Levels are dealt to the
/// tasks in turn, so that each gets some of the coarse, densely stored levels (cheap: their rows are few
/// and close together) and some of the fine, hashed ones. Each task sums the point gradients of its levels
/// into its own buffer, and the buffers are added at the end.
fn grads_with<const WIDTH: usize, const TABLE: bool, const POINTS: bool>(
    points: &[f32],
    table: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    grad_table: &mut [f32],
    grad_points: &mut [f32],
) {
    let f = features::<WIDTH>(spec);
    let levels = spec.level_constants();
    let blocks = spec.unit_blocks(points);
    let level_len = spec.table_size * f;
    let tasks = rayon::current_num_threads().clamp(1, levels.len());
    // Per task, its levels and their slices of the table gradient (empty when it is not wanted).
    let mut dealt: Vec<Vec<(usize, &mut [f32])>> = (0..tasks).map(|_| Vec::new()).collect();
    let mut table_levels = grad_table.chunks_mut(level_len);
    for l in 0..levels.len() {
        let rows: &mut [f32] = if TABLE {
            table_levels.next().expect("a table gradient of L·T rows")
        } else {
            &mut []
        };
        dealt[l % tasks].push((l, rows));
    }
    let sums: Vec<Vec<f32>> = dealt
        .into_par_iter()
        .map(|task| {
            let mut acc = vec![0.0f32; if POINTS { points.len() } else { 0 }];
            for (l, rows) in task {
                let level_table = if POINTS {
                    &table[l * level_len..(l + 1) * level_len]
                } else {
                    &[][..]
                };
                level_grads::<WIDTH, TABLE, POINTS>(
                    spec,
                    &levels[l],
                    l,
                    &blocks,
                    level_table,
                    grad,
                    rows,
                    &mut acc,
                );
            }
            acc
        })
        .collect();
    if POINTS {
        grad_points.fill(0.0);
        for sum in sums {
            grad_points.iter_mut().zip(&sum).for_each(|(g, s)| *g += s);
        }
    }
}

/// One level's share of [`grads_with`]: scatters into the level's table gradient `rows` (with `TABLE`) and
/// adds the point gradients into `grad_points` (with `POINTS`, reading the level's table `level_table`).
#[allow(clippy::too_many_arguments)]
fn level_grads<const WIDTH: usize, const TABLE: bool, const POINTS: bool>(
    spec: &GridSpec,
    level: &Level,
    l: usize,
    blocks: &[UnitBlock],
    level_table: &[f32],
    grad: &[f32],
    rows: &mut [f32],
    grad_points: &mut [f32],
) {
    let (f, width) = (features::<WIDTH>(spec), spec.output_dim());
    let (mut corners, mut weights) = (CornerBlock::new(), [[0.0; LANES]; 8]);
    let mut d = [[0.0; LANES]; 3];
    for (b, units) in blocks.iter().enumerate() {
        let grad = &grad[b * LANES * width..(b * LANES + units.len) * width];
        spec.corner_block(level, units, &mut corners);
        corners.weights(&mut weights);
        // Per corner and lane, `⟨grad, table[row]⟩`.
        let mut dots = [[0.0f32; LANES]; 8];
        for (j, g) in grad.chunks_exact(width).enumerate() {
            let g = &g[l * f..(l + 1) * f];
            if g.iter().all(|&v| v == 0.0) {
                continue;
            }
            for c in 0..8 {
                let r = corners.rows[c][j] as usize * f;
                if TABLE {
                    let w = weights[c][j];
                    for (t, gv) in rows[r..r + f].iter_mut().zip(g) {
                        *t += w * gv;
                    }
                }
                if POINTS {
                    dots[c][j] = g
                        .iter()
                        .zip(&level_table[r..r + f])
                        .map(|(a, b)| a * b)
                        .sum();
                }
            }
        }
        if POINTS {
            corners.position_derivative(&dots, &mut d);
            let acc = &mut grad_points[3 * b * LANES..3 * (b * LANES + units.len)];
            for (j, acc) in acc.chunks_exact_mut(3).enumerate() {
                for a in 0..3 {
                    if units.inside[a][j] {
                        acc[a] += d[a][j] * level.cells_per_metre;
                    }
                }
            }
        }
    }
}

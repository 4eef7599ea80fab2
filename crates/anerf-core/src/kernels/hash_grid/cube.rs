//! CubeCL kernels of the hash-grid encoding for Burn's CubeCL backend (the `wgpu` and `cuda` features): the same three
//! operations and the same arithmetic as the CPU [`super::cpu`] (hash, unit-cube clamping, corner
//! weights), compiled just in time for the device.
//!
//! * encode: one unit per (point, level) gathers the eight corners and writes the level's `F` features;
//! * table gradient: one unit per (point, level) scatters `w_c · grad` into the eight corners' rows with
//!   atomic adds (see [`AtomicScheme`] for how an `f32` is added atomically where the device has no float
//!   atomics);
//! * point gradient: one unit per point walks the levels and writes its three derivatives (no atomics);
//! * both gradients (what a backward pass through points and table asks for): one unit per (point, level)
//!   does the table gradient's adds and adds its level's share of the point derivative atomically.
//!
//! Shapes as in [`super::cpu`]: points `[N, 3]` (metres), table `[L·T, F]`, encodings `[N, L·F]`; all
//! `f32`. Inputs are made contiguous first; outputs are indexed through their strides.

use burn::backend::Cube;
use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl;
use burn_cubecl::ops::numeric::zeros_client;
use burn_cubecl::tensor::CubeTensor;
use cubecl::ir::ElemType;
use cubecl::prelude::*;

use super::cpu::HASH_PRIMES;
use super::extension::HashGridBackend;
use super::GridSpec;
use crate::kernels::cube::{
    atomic_add, contiguous_f32, dims, empty_f32, side_sign, side_weight, AtomicScheme, Units,
};

// The hash multiplies x by the first prime, 1, which `corner_row` leaves out.
const _: () = assert!(HASH_PRIMES[0] == 1);
const PRIME_Y: u32 = HASH_PRIMES[1];
const PRIME_Z: u32 = HASH_PRIMES[2];

/// A point's cell at one level: the low corner's vertex along each axis and the position inside the cell
/// (`[0, 1]` per axis).
#[derive(CubeType)]
struct Cell {
    x0: u32,
    y0: u32,
    z0: u32,
    fx: f32,
    fy: f32,
    fz: f32,
}

/// Coordinate `axis` of point `i` (metres) in the grid's unit cube, before clamping.
#[cube]
fn unit_coord(points: &Tensor<f32>, i: usize, axis: usize, half_extent: f32) -> f32 {
    (points[i * 3 + axis] + half_extent) / (2.0f32 * half_extent)
}

/// The cell's low vertex along one axis, from the clamped unit coordinate `u`.
#[cube]
fn axis_base(u: f32, res: u32) -> u32 {
    // `u ≥ 0`, so the conversion truncates to the floor; the far face belongs to the last cell.
    min(u32::cast_from(u * f32::cast_from(res)), res - 1)
}

/// The cell at a level of `res` cells per axis of the clamped unit position `(ux, uy, uz)`.
#[cube]
fn cell_at(ux: f32, uy: f32, uz: f32, res: u32) -> Cell {
    let x0 = axis_base(ux, res);
    let y0 = axis_base(uy, res);
    let z0 = axis_base(uz, res);
    let r = f32::cast_from(res);
    Cell {
        x0,
        y0,
        z0,
        fx: ux * r - f32::cast_from(x0),
        fy: uy * r - f32::cast_from(y0),
        fz: uz * r - f32::cast_from(z0),
    }
}

/// The cell of point `i` at a level of `res` cells per axis.
#[cube]
fn point_cell(points: &Tensor<f32>, i: usize, half_extent: f32, res: u32) -> Cell {
    cell_at(
        clamp(unit_coord(points, i, 0, half_extent), 0.0f32, 1.0f32),
        clamp(unit_coord(points, i, 1, half_extent), 0.0f32, 1.0f32),
        clamp(unit_coord(points, i, 2, half_extent), 0.0f32, 1.0f32),
        res,
    )
}

/// Row of corner `corner` (bit `a` set: the high side along axis `a`) in its level's table of
/// `mask + 1` rows: dense `x + (N+1)·(y + (N+1)·z)` or the spatial hash (u32 arithmetic, wrapping; the
/// dense formula wraps too on hashed levels, where its value is discarded).
#[cube]
fn corner_row(cell: &Cell, corner: u32, res: u32, dense: bool, mask: u32) -> u32 {
    let x = cell.x0 + (corner & 1);
    let y = cell.y0 + ((corner >> 1) & 1);
    let z = cell.z0 + ((corner >> 2) & 1);
    let side = res + 1;
    select(
        dense,
        x + side * (y + side * z),
        (x ^ (y * PRIME_Y) ^ (z * PRIME_Z)) & mask,
    )
}

/// Trilinear weight of corner `corner`.
#[cube]
fn corner_weight(cell: &Cell, corner: u32) -> f32 {
    side_weight(cell.fx, corner & 1)
        * side_weight(cell.fy, (corner >> 1) & 1)
        * side_weight(cell.fz, (corner >> 2) & 1)
}

/// One level's constants, read from the `[res, dense]` pairs of the kernels' `levels` tensor.
#[derive(CubeType)]
struct Level {
    res: u32,
    dense: bool,
    /// The level's first row in the whole table, `l · T`.
    first_row: usize,
    /// `T − 1`.
    mask: u32,
}

#[cube]
fn level_at(levels: &Tensor<u32>, l: usize, table_size: u32) -> Level {
    Level {
        res: levels[2 * l],
        dense: levels[2 * l + 1] == 1,
        first_row: l * usize::cast_from(table_size),
        mask: table_size - 1,
    }
}

/// Row of corner `corner` of `cell` in the whole table.
#[cube]
fn table_row(level: &Level, cell: &Cell, corner: u32) -> usize {
    level.first_row + usize::cast_from(corner_row(cell, corner, level.res, level.dense, level.mask))
}

/// The work of one unit of a launch with a unit per (point, level): point `i` and level `l` of unit
/// `i·L + l`, the level and the point's cell there.
#[derive(CubeType)]
struct PointLevel {
    i: usize,
    l: usize,
    level: Level,
    cell: Cell,
}

#[cube]
fn point_level(
    points: &Tensor<f32>,
    levels: &Tensor<u32>,
    half_extent: f32,
    table_size: u32,
) -> PointLevel {
    let n_levels = levels.shape(0) / 2;
    let i = ABSOLUTE_POS / n_levels;
    let l = ABSOLUTE_POS % n_levels;
    let level = level_at(levels, l, table_size);
    let cell = point_cell(points, i, half_extent, level.res);
    PointLevel { i, l, level, cell }
}

/// `out[i, l·F + f] = Σ_c w_c(p_i) · table[l·T + row_c, f]`, one unit per `(i, l)`. `levels` holds per
/// level its resolution and whether it is dense (`[res, dense]` pairs).
#[cube(launch_unchecked)]
fn encode_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    levels: &Tensor<u32>,
    out: &mut Tensor<f32>,
    half_extent: f32,
    table_size: u32,
    #[comptime] features: usize,
) {
    if ABSOLUTE_POS >= points.shape(0) * (levels.shape(0) / 2) {
        terminate!();
    }
    let unit = point_level(points, levels, half_extent, table_size);
    let mut acc = Array::<f32>::new(features);
    #[unroll]
    for f in 0..features {
        acc[f] = 0.0f32;
    }
    #[unroll]
    for c in 0..8u32 {
        let row = table_row(&unit.level, &unit.cell, c);
        let w = corner_weight(&unit.cell, c);
        #[unroll]
        for f in 0..features {
            acc[f] += w * table[row * features + f];
        }
    }
    let (row_stride, col_stride) = (out.stride(0), out.stride(1));
    #[unroll]
    for f in 0..features {
        out[unit.i * row_stride + (unit.l * features + f) * col_stride] = acc[f];
    }
}

/// `grad_table[l·T + row_c(p_i), f] += w_c(p_i) · grad[i, l·F + f]`, one unit per `(i, l)`; `grad_table`
/// must be zero on entry.
#[cube(launch_unchecked)]
fn table_grad_kernel<W: Numeric>(
    points: &Tensor<f32>,
    grad: &Tensor<f32>,
    levels: &Tensor<u32>,
    grad_table: &Tensor<Atomic<W>>,
    half_extent: f32,
    table_size: u32,
    #[comptime] features: usize,
    #[comptime] native: bool,
    #[define(W)] _word: ElemType,
) {
    let n_levels = levels.shape(0) / 2;
    if ABSOLUTE_POS >= points.shape(0) * n_levels {
        terminate!();
    }
    let unit = point_level(points, levels, half_extent, table_size);
    let grad_row = (unit.i * n_levels + unit.l) * features;
    #[unroll]
    for c in 0..8u32 {
        let row = table_row(&unit.level, &unit.cell, c);
        let w = corner_weight(&unit.cell, c);
        #[unroll]
        for f in 0..features {
            let value = w * grad[grad_row + f];
            if value != 0.0f32 {
                let index = row * grad_table.stride(0) + f * grad_table.stride(1);
                atomic_add::<W>(grad_table, index, value, native);
            }
        }
    }
}

/// `out[i, a] = Σ_l Σ_f grad[i, l·F + f] · ∂ out[i, l·F + f] / ∂ p_{i,a}`, zero along an axis where the
/// point lies outside the grid; one unit per point.
#[cube(launch_unchecked)]
fn points_grad_kernel(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    grad: &Tensor<f32>,
    levels: &Tensor<u32>,
    out: &mut Tensor<f32>,
    half_extent: f32,
    table_size: u32,
    #[comptime] features: usize,
) {
    if ABSOLUTE_POS >= points.shape(0) {
        terminate!();
    }
    let i = ABSOLUTE_POS;
    let n_levels = levels.shape(0) / 2;
    let vx = unit_coord(points, i, 0, half_extent);
    let vy = unit_coord(points, i, 1, half_extent);
    let vz = unit_coord(points, i, 2, half_extent);
    let ux = clamp(vx, 0.0f32, 1.0f32);
    let uy = clamp(vy, 0.0f32, 1.0f32);
    let uz = clamp(vz, 0.0f32, 1.0f32);
    let mut dx = 0.0f32;
    let mut dy = 0.0f32;
    let mut dz = 0.0f32;
    for l in 0..n_levels {
        let level = level_at(levels, l, table_size);
        let cell = cell_at(ux, uy, uz, level.res);
        let grad_row = (i * n_levels + l) * features;
        let mut lx = 0.0f32;
        let mut ly = 0.0f32;
        let mut lz = 0.0f32;
        #[unroll]
        for c in 0..8u32 {
            let row = table_row(&level, &cell, c);
            let mut dot = 0.0f32;
            #[unroll]
            for f in 0..features {
                dot += grad[grad_row + f] * table[row * features + f];
            }
            let hx = c & 1;
            let hy = (c >> 1) & 1;
            let hz = (c >> 2) & 1;
            let sx = side_weight(cell.fx, hx);
            let sy = side_weight(cell.fy, hy);
            let sz = side_weight(cell.fz, hz);
            lx += dot * side_sign(hx) * sy * sz;
            ly += dot * side_sign(hy) * sx * sz;
            lz += dot * side_sign(hz) * sx * sy;
        }
        let cells_per_metre = f32::cast_from(level.res) / (2.0f32 * half_extent);
        dx += lx * cells_per_metre;
        dy += ly * cells_per_metre;
        dz += lz * cells_per_metre;
    }
    let first = i * out.stride(0);
    let step = out.stride(1);
    out[first] = select(inside(vx), dx, 0.0f32);
    out[first + step] = select(inside(vy), dy, 0.0f32);
    out[first + 2 * step] = select(inside(vz), dz, 0.0f32);
}

/// Both gradients in one pass, one unit per `(i, l)`: the table adds of [`table_grad_kernel`] and the
/// level's share of [`points_grad_kernel`]'s derivative, added atomically into `grad_points` (the `L` adds
/// into a point's row contend only with each other). Both outputs must be zero on entry.
#[cube(launch_unchecked)]
fn grads_kernel<W: Numeric>(
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    grad: &Tensor<f32>,
    levels: &Tensor<u32>,
    grad_table: &Tensor<Atomic<W>>,
    grad_points: &Tensor<Atomic<W>>,
    half_extent: f32,
    table_size: u32,
    #[comptime] features: usize,
    #[comptime] native: bool,
    #[define(W)] _word: ElemType,
) {
    let n_levels = levels.shape(0) / 2;
    if ABSOLUTE_POS >= points.shape(0) * n_levels {
        terminate!();
    }
    let unit = point_level(points, levels, half_extent, table_size);
    let grad_row = (unit.i * n_levels + unit.l) * features;
    let mut lx = 0.0f32;
    let mut ly = 0.0f32;
    let mut lz = 0.0f32;
    #[unroll]
    for c in 0..8u32 {
        let row = table_row(&unit.level, &unit.cell, c);
        let w = corner_weight(&unit.cell, c);
        let mut dot = 0.0f32;
        #[unroll]
        for f in 0..features {
            let g = grad[grad_row + f];
            let value = w * g;
            if value != 0.0f32 {
                let index = row * grad_table.stride(0) + f * grad_table.stride(1);
                atomic_add::<W>(grad_table, index, value, native);
            }
            dot += g * table[row * features + f];
        }
        let hx = c & 1;
        let hy = (c >> 1) & 1;
        let hz = (c >> 2) & 1;
        let sx = side_weight(unit.cell.fx, hx);
        let sy = side_weight(unit.cell.fy, hy);
        let sz = side_weight(unit.cell.fz, hz);
        lx += dot * side_sign(hx) * sy * sz;
        ly += dot * side_sign(hy) * sx * sz;
        lz += dot * side_sign(hz) * sx * sy;
    }
    let cells_per_metre = f32::cast_from(unit.level.res) / (2.0f32 * half_extent);
    add_axis_derivative::<W>(
        grad_points,
        points,
        unit.i,
        0,
        lx * cells_per_metre,
        half_extent,
        native,
    );
    add_axis_derivative::<W>(
        grad_points,
        points,
        unit.i,
        1,
        ly * cells_per_metre,
        half_extent,
        native,
    );
    add_axis_derivative::<W>(
        grad_points,
        points,
        unit.i,
        2,
        lz * cells_per_metre,
        half_extent,
        native,
    );
}

/// Adds one level's derivative along `axis` into point `i`'s gradient, unless the point lies outside the
/// grid along that axis (where the clamped position has no derivative).
#[cube]
fn add_axis_derivative<W: Numeric>(
    grad_points: &Tensor<Atomic<W>>,
    points: &Tensor<f32>,
    i: usize,
    axis: usize,
    derivative: f32,
    half_extent: f32,
    #[comptime] native: bool,
) {
    if inside(unit_coord(points, i, axis, half_extent)) && derivative != 0.0f32 {
        let index = i * grad_points.stride(0) + axis * grad_points.stride(1);
        atomic_add::<W>(grad_points, index, derivative, native);
    }
}

/// Whether an unclamped unit coordinate lies strictly inside the grid (outside, the clamped position has
/// no derivative).
#[cube]
fn inside(v: f32) -> bool {
    v > 0.0f32 && v < 1.0f32
}

/// The per-level constants as a `[2 L]` `u32` tensor on `like`'s device: `[res, dense]` per level.
fn level_table(spec: &GridSpec, like: &CubeTensor) -> CubeTensor {
    let values: Vec<u8> = (0..spec.levels())
        .flat_map(|l| [spec.resolutions[l], u32::from(spec.is_dense(l))])
        .flat_map(u32::to_ne_bytes)
        .collect();
    let handle = like.client.create_from_slice(&values);
    CubeTensor::new_contiguous(
        like.client.clone(),
        like.device.clone(),
        Shape::new([2 * spec.levels()]),
        handle,
        DType::U32,
    )
}

/// Rows of a `[rows, cols]` tensor.
fn rows(t: &CubeTensor) -> usize {
    dims(t)[0]
}

/// What a kernel launch needs besides its tensors: a grid of one unit per work item and the level table.
struct Launch {
    units: Units,
    levels: TensorArg,
}

impl Launch {
    /// A launch of `units` units on the device of `points`; `None` when there is nothing to do.
    fn new(points: &CubeTensor, spec: &GridSpec, units: usize) -> Option<Self> {
        Some(Self {
            units: Units::on(points, units)?,
            levels: level_table(spec, points).into_tensor_arg(),
        })
    }
}

/// The table gradient with the given atomic scheme (the tests run both where the device has float
/// atomics).
pub(super) fn table_grad(
    points: CubeTensor,
    grad: CubeTensor,
    spec: &GridSpec,
    scheme: AtomicScheme,
) -> CubeTensor {
    let points = contiguous_f32(points, "hash-grid points");
    let grad = contiguous_f32(grad, "hash-grid gradients");
    let out = zeros_client(
        points.client.clone(),
        points.device.clone(),
        Shape::new([spec.table_rows(), spec.features]),
        DType::F32,
    );
    let Some(launch) = Launch::new(&points, spec, rows(&points) * spec.levels()) else {
        return out;
    };
    let (native, word) = scheme.word();
    // SAFETY: every index the kernel forms is in range: `i < N`, `l < L`, rows `< T`, `f < F`; the f32
    // output is read as `u32` words of the same size by the exchange scheme.
    unsafe {
        table_grad_kernel::launch_unchecked(
            &launch.units.client,
            launch.units.count,
            launch.units.dim,
            points.into_tensor_arg(),
            grad.into_tensor_arg(),
            launch.levels,
            out.clone().into_tensor_arg(),
            spec.half_extent,
            spec.table_size as u32,
            spec.features,
            native,
            word,
        )
    }
    out
}

/// Both gradients `(table [L·T, F], points [N, 3])` in one launch of [`grads_kernel`], added with the given
/// atomic scheme.
pub(super) fn grads(
    points: CubeTensor,
    table: CubeTensor,
    grad: CubeTensor,
    spec: &GridSpec,
    scheme: AtomicScheme,
) -> (CubeTensor, CubeTensor) {
    let points = contiguous_f32(points, "hash-grid points");
    let table = contiguous_f32(table, "hash-grid tables");
    let grad = contiguous_f32(grad, "hash-grid gradients");
    let zeros = |dims: [usize; 2]| {
        zeros_client(
            points.client.clone(),
            points.device.clone(),
            Shape::new(dims),
            DType::F32,
        )
    };
    let grad_table = zeros([spec.table_rows(), spec.features]);
    let grad_points = zeros([rows(&points), 3]);
    let Some(launch) = Launch::new(&points, spec, rows(&points) * spec.levels()) else {
        return (grad_table, grad_points);
    };
    let (native, word) = scheme.word();
    // SAFETY: every index the kernel forms is in range: `i < N`, `l < L`, rows `< T`, `f < F`, axes `< 3`;
    // the f32 outputs are read as `u32` words of the same size by the exchange scheme.
    unsafe {
        grads_kernel::launch_unchecked(
            &launch.units.client,
            launch.units.count,
            launch.units.dim,
            points.into_tensor_arg(),
            table.into_tensor_arg(),
            grad.into_tensor_arg(),
            launch.levels,
            grad_table.clone().into_tensor_arg(),
            grad_points.clone().into_tensor_arg(),
            spec.half_extent,
            spec.table_size as u32,
            spec.features,
            native,
            word,
        )
    }
    (grad_table, grad_points)
}

impl HashGridBackend for Cube {
    fn hash_grid_encode(points: CubeTensor, table: CubeTensor, spec: GridSpec) -> CubeTensor {
        let points = contiguous_f32(points, "hash-grid points");
        let table = contiguous_f32(table, "hash-grid tables");
        assert_eq!(
            table.meta.shape().dims::<2>(),
            [spec.table_rows(), spec.features],
            "hash grid table"
        );
        let n = rows(&points);
        let out = empty_f32(&points, [n, spec.output_dim()]);
        let Some(launch) = Launch::new(&points, &spec, n * spec.levels()) else {
            return out;
        };
        // SAFETY: every index the kernel forms is in range: `i < N`, `l < L`, rows `< T`, `f < F`.
        unsafe {
            encode_kernel::launch_unchecked(
                &launch.units.client,
                launch.units.count,
                launch.units.dim,
                points.into_tensor_arg(),
                table.into_tensor_arg(),
                launch.levels,
                out.clone().into_tensor_arg(),
                spec.half_extent,
                spec.table_size as u32,
                spec.features,
            )
        }
        out
    }

    fn hash_grid_table_grad(points: CubeTensor, grad: CubeTensor, spec: GridSpec) -> CubeTensor {
        let scheme = AtomicScheme::for_device(&points);
        table_grad(points, grad, &spec, scheme)
    }

    fn hash_grid_grads(
        points: CubeTensor,
        table: CubeTensor,
        grad: CubeTensor,
        spec: GridSpec,
    ) -> (CubeTensor, CubeTensor) {
        let scheme = AtomicScheme::for_device(&points);
        grads(points, table, grad, &spec, scheme)
    }

    fn hash_grid_points_grad(
        points: CubeTensor,
        table: CubeTensor,
        grad: CubeTensor,
        spec: GridSpec,
    ) -> CubeTensor {
        let points = contiguous_f32(points, "hash-grid points");
        let table = contiguous_f32(table, "hash-grid tables");
        let grad = contiguous_f32(grad, "hash-grid gradients");
        let out = empty_f32(&points, [rows(&points), 3]);
        let Some(launch) = Launch::new(&points, &spec, rows(&points)) else {
            return out;
        };
        // SAFETY: every index the kernel forms is in range: `i < N`, `l < L`, rows `< T`, `f < F`.
        unsafe {
            points_grad_kernel::launch_unchecked(
                &launch.units.client,
                launch.units.count,
                launch.units.dim,
                points.into_tensor_arg(),
                table.into_tensor_arg(),
                grad.into_tensor_arg(),
                launch.levels,
                out.clone().into_tensor_arg(),
                spec.half_extent,
                spec.table_size as u32,
                spec.features,
            )
        }
        out
    }
}

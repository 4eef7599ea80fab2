//! The splats binned into tiles on the device (the `wgpu` and `cuda` features), as the CPU kernel's
//! [`cpu::bin`] bins them on the host: each tile's list front to back, equal depths in splat order.
//!
//! As brush and 3DGS do, in passes over device arrays with no read-back but the number of tile entries:
//! the splats sorted by depth ([`sort_pairs`] of their depth's bits made to sort as unsigned integers),
//! each splat's count of the tiles its cut-off box touches (the CPU kernel's box), an exclusive scan of the
//! counts, one `(tile, splat)` entry per touched tile written in depth order, a stable sort of the entries
//! by tile, and each tile's start found by a binary search over the sorted tiles. A scene whose entries
//! could pass 2³² (splats × tiles) is binned on the host instead.

use burn_cubecl::cubecl;
use burn_cubecl::ops::into_data_sync;
use burn_cubecl::tensor::CubeTensor;
use cubecl::prelude::*;

use super::cpu;
use super::{RasterSpec, ALPHA_MIN, EXTENT_MARGIN, EXTENT_SCALE, SPLAT_WIDTH, TILE};
use crate::kernels::cube::{dims, Units};
use crate::kernels::cube_sort::{empty_u32, exclusive_scan, read_one, sort_pairs, upload_u32};

/// Each tile's splats, front to back, on the device: tile `t`'s are `order[starts[t]..starts[t + 1]]`.
pub(super) struct DeviceBins {
    pub tiles_x: u32,
    /// `[tiles + 1]` `u32`.
    pub starts: CubeTensor,
    /// `[entries]` `u32` splat rows (one slot when there is none, to bind).
    pub order: CubeTensor,
}

/// `splats` binned for `spec`: on the device, or on the host where the entries could overflow `u32`.
pub(super) fn bin(splats: &CubeTensor, spec: &RasterSpec) -> DeviceBins {
    let n = dims(splats)[0];
    let tiles = spec.width.div_ceil(TILE) as u64 * spec.height.div_ceil(TILE) as u64;
    if n as u64 * tiles < u32::MAX as u64 {
        bin_on_device(splats, spec)
    } else {
        bin_on_host(splats, spec)
    }
}

/// A depth's bits, reordered so that unsigned comparison orders them as `f32::total_cmp` does: negative
/// values have every bit flipped, the others only the sign.
#[cube]
fn depth_key(depth: f32) -> u32 {
    let bits = u32::reinterpret(depth);
    select(
        bits >= 0x8000_0000u32,
        bits ^ 0xFFFF_FFFFu32,
        bits | 0x8000_0000u32,
    )
}

/// Each splat's depth key and its row.
#[cube(launch_unchecked)]
fn depth_keys(splats: &Tensor<f32>, keys: &mut Tensor<u32>, rows: &mut Tensor<u32>, n: u32) {
    let s = ABSOLUTE_POS;
    if s >= n as usize {
        terminate!();
    }
    keys[s] = depth_key(splats[s * SPLAT_WIDTH + 9]);
    rows[s] = s as u32;
}

/// The tiles a splat's cut-off box touches, inclusive, and how many (0: none, the rest unset).
#[derive(CubeType)]
struct TileRect {
    x0: u32,
    x1: u32,
    y0: u32,
    y1: u32,
    count: u32,
}

/// Splat `s`'s [`TileRect`] with the CPU kernel's box (`Splat::extent`) and clipping (`bin_boxes`): none
/// for a splat that is not finite, too transparent, or not positive definite.
#[cube]
fn tile_rect(splats: &Tensor<f32>, s: usize, width: u32, height: u32) -> TileRect {
    let row = s * SPLAT_WIDTH;
    let mx = splats[row];
    let my = splats[row + 1];
    let a = splats[row + 2];
    let b = splats[row + 3];
    let c = splats[row + 4];
    let opacity = splats[row + 8];
    let finite = !(f32::is_nan(mx)
        || f32::is_inf(mx)
        || f32::is_nan(my)
        || f32::is_inf(my)
        || f32::is_nan(a)
        || f32::is_inf(a)
        || f32::is_nan(b)
        || f32::is_inf(b)
        || f32::is_nan(c)
        || f32::is_inf(c));
    let det = a * c - b * b;
    let valid = finite && opacity >= ALPHA_MIN && a > 0.0f32 && det > 0.0f32;
    // o · exp(−q/2) ≥ 1/255 ⇔ q ≤ 2 ln(255 o); the ellipse's box, widened as the CPU kernel widens it.
    let r2 = 2.0f32 * f32::ln(opacity / ALPHA_MIN);
    let ex = f32::sqrt(r2 * c / det) * EXTENT_SCALE + EXTENT_MARGIN;
    let ey = f32::sqrt(r2 * a / det) * EXTENT_SCALE + EXTENT_MARGIN;
    let lx = max(f32::ceil(mx - ex), 0.0f32);
    let hx = min(f32::floor(mx + ex), f32::cast_from(width - 1));
    let ly = max(f32::ceil(my - ey), 0.0f32);
    let hy = min(f32::floor(my + ey), f32::cast_from(height - 1));
    let inside = valid && lx <= hx && ly <= hy;
    let x0 = select(inside, u32::cast_from(lx) / TILE, 0u32);
    let x1 = select(inside, u32::cast_from(hx) / TILE, 0u32);
    let y0 = select(inside, u32::cast_from(ly) / TILE, 0u32);
    let y1 = select(inside, u32::cast_from(hy) / TILE, 0u32);
    TileRect {
        x0,
        x1,
        y0,
        y1,
        count: select(inside, (x1 - x0 + 1) * (y1 - y0 + 1), 0u32),
    }
}

/// `counts[i]`: the tiles of the splat `by_depth[i]` touches.
#[cube(launch_unchecked)]
fn tile_counts(
    splats: &Tensor<f32>,
    by_depth: &Tensor<u32>,
    counts: &mut Tensor<u32>,
    n: u32,
    width: u32,
    height: u32,
) {
    let i = ABSOLUTE_POS;
    if i >= n as usize {
        terminate!();
    }
    counts[i] = tile_rect(splats, by_depth[i] as usize, width, height).count;
}

/// The `(tile, splat)` entries of the splat `by_depth[i]` from slot `offsets[i]` on, its tiles row by row.
#[cube(launch_unchecked)]
fn emit_entries(
    splats: &Tensor<f32>,
    by_depth: &Tensor<u32>,
    offsets: &Tensor<u32>,
    tile_keys: &mut Tensor<u32>,
    entries: &mut Tensor<u32>,
    n: u32,
    width: u32,
    height: u32,
    tiles_x: u32,
) {
    let i = ABSOLUTE_POS;
    if i >= n as usize {
        terminate!();
    }
    let s = by_depth[i];
    let rect = tile_rect(splats, s as usize, width, height);
    if rect.count > 0u32 {
        let mut at = offsets[i] as usize;
        for ty in rect.y0..rect.y1 + 1 {
            for tx in rect.x0..rect.x1 + 1 {
                tile_keys[at] = ty * tiles_x + tx;
                entries[at] = s;
                at += 1;
            }
        }
    }
}

/// `starts[t]`: the first of the `count` sorted entries whose tile is not below `t` (`t ≤ tiles`).
#[cube(launch_unchecked)]
fn tile_starts(tile_keys: &Tensor<u32>, starts: &mut Tensor<u32>, count: u32, tiles: u32) {
    let t = ABSOLUTE_POS as u32;
    if t > tiles {
        terminate!();
    }
    let mut lo = 0u32;
    let mut hi = count;
    while lo < hi {
        let mid = (lo + hi) / 2;
        if tile_keys[mid as usize] < t {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    starts[t as usize] = lo;
}

/// The passes of the module's doc; the caller has checked that the entries fit `u32`.
pub(super) fn bin_on_device(splats: &CubeTensor, spec: &RasterSpec) -> DeviceBins {
    let n = dims(splats)[0];
    let tiles_x = spec.width.div_ceil(TILE);
    let tiles = tiles_x * spec.height.div_ceil(TILE);
    let (mut tile_keys, mut order) = (empty_u32(splats, 0), empty_u32(splats, 0));
    let mut count = 0;
    if let Some(units) = Units::on(splats, n) {
        let (keys, rows) = (empty_u32(splats, n), empty_u32(splats, n));
        // SAFETY: units < n read row s of `splats` ([n, SPLAT_WIDTH]) and write slot s of `keys` and `rows`.
        unsafe {
            depth_keys::launch_unchecked(
                &units.client,
                units.count.clone(),
                units.dim,
                splats.clone().into_tensor_arg(),
                keys.clone().into_tensor_arg(),
                rows.clone().into_tensor_arg(),
                n as u32,
            )
        }
        let (_, by_depth) = sort_pairs(&keys, &rows, 32);
        let counts = empty_u32(splats, n);
        // SAFETY: units < n read `by_depth[i]` (a row < n) and write `counts[i]`.
        unsafe {
            tile_counts::launch_unchecked(
                &units.client,
                units.count.clone(),
                units.dim,
                splats.clone().into_tensor_arg(),
                by_depth.clone().into_tensor_arg(),
                counts.clone().into_tensor_arg(),
                n as u32,
                spec.width,
                spec.height,
            )
        }
        let offsets = exclusive_scan(&counts);
        count = read_one(&offsets, n) as usize;
        if count > 0 {
            let (keys, entries) = (empty_u32(splats, count), empty_u32(splats, count));
            // SAFETY: the scan gives splat i the slots offsets[i]..offsets[i] + counts[i], within `count`;
            // tiles < tiles_x · tiles_y.
            unsafe {
                emit_entries::launch_unchecked(
                    &units.client,
                    units.count,
                    units.dim,
                    splats.clone().into_tensor_arg(),
                    by_depth.into_tensor_arg(),
                    offsets.into_tensor_arg(),
                    keys.clone().into_tensor_arg(),
                    entries.clone().into_tensor_arg(),
                    n as u32,
                    spec.width,
                    spec.height,
                    tiles_x,
                )
            }
            let bits = u32::BITS - (tiles - 1).leading_zeros();
            (tile_keys, order) = sort_pairs(&keys, &entries, bits);
        }
    }
    let starts = empty_u32(splats, tiles as usize + 1);
    let units = Units::on(splats, tiles as usize + 1).expect("a tile at least");
    // SAFETY: units ≤ tiles write `starts[t]` ([tiles + 1]); the search reads `tile_keys` below `count`.
    unsafe {
        tile_starts::launch_unchecked(
            &units.client,
            units.count,
            units.dim,
            tile_keys.into_tensor_arg(),
            starts.clone().into_tensor_arg(),
            count as u32,
            tiles,
        )
    }
    DeviceBins {
        tiles_x,
        starts,
        order,
    }
}

/// The splats read back and binned by [`cpu::bin`], the lists uploaded.
pub(super) fn bin_on_host(splats: &CubeTensor, spec: &RasterSpec) -> DeviceBins {
    let rows = into_data_sync(splats.clone())
        .try_into_vec::<f32>()
        .expect("f32 splat rows");
    let bins = cpu::bin(&rows, spec);
    let starts: Vec<u32> = bins
        .starts
        .iter()
        .map(|&s| u32::try_from(s).expect("fewer than 2³² tile entries"))
        .collect();
    DeviceBins {
        tiles_x: bins.tiles_x as u32,
        starts: upload_u32(splats, &starts),
        order: upload_u32(splats, &bins.order),
    }
}

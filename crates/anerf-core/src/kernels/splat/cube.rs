//! CubeCL kernels of the splat rasteriser for the GPU backends (the `wgpu` and `cuda` features). The
//! projected splats are binned on the device ([`cube_bins`]: tiles of 16 × 16 pixels, each tile's splats
//! sorted front to back, as the CPU kernel's `cpu::bin` does), and one unit per pixel composites its tile's
//! list with the CPU kernel's rules (alpha capped at
//! [`ALPHA_MAX`], splats under [`ALPHA_MIN`] skipped, the stop before transmittance falls under [`T_MIN`]).
//!
//! The backward pass replays the pixel's compositing to find its last splat and final transmittance, then
//! walks the list back to front as 3DGS does, recovering the transmittance in front of each splat by
//! division (`T_k = T_{k+1} / (1 − α_k)`, with `1 − α ≥ 0.01` by the cap) instead of keeping the list of
//! contributions the CPU kernel keeps, and adds each splat's gradient atomically ([`AtomicScheme`]).
//!
//! Shapes as in [`super`]: splats `[N, SPLAT_WIDTH]`, pixels `[H·W, PIXEL_WIDTH]`; all `f32`.

use burn::backend::Cube;
use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl;
use burn_cubecl::ops::numeric::zeros_client;
use burn_cubecl::tensor::CubeTensor;
use cubecl::ir::ElemType;
use cubecl::prelude::*;

use super::cube_bins;
use super::extension::SplatBackend;
use super::{RasterSpec, ALPHA_MAX, ALPHA_MIN, PIXEL_WIDTH, SPLAT_WIDTH, TILE, T_MIN};
use crate::kernels::cube::{atomic_add, contiguous_f32, dims, empty_f32, AtomicScheme, Units};

/// One splat's exponent and alpha at a pixel (`alpha` is 0 where the splat is skipped there).
#[derive(CubeType)]
struct Hit {
    /// Offsets of the pixel from the splat's mean.
    dx: f32,
    dy: f32,
    /// `exp(power)`.
    gaussian: f32,
    /// The alpha composited, capped; 0 where the splat does not count at this pixel.
    alpha: f32,
    /// Whether `opacity · gaussian` was under the cap (above it alpha is constant).
    uncapped: bool,
}

/// Splat `s` (its row's first value at `s · SPLAT_WIDTH`) at pixel `(px, py)`, by the CPU kernel's
/// formulas.
#[cube]
fn hit(splats: &Tensor<f32>, s: usize, px: f32, py: f32) -> Hit {
    let row = s * SPLAT_WIDTH;
    let dx = px - splats[row];
    let dy = py - splats[row + 1];
    let power = -0.5f32 * (splats[row + 2] * dx * dx + splats[row + 4] * dy * dy)
        - splats[row + 3] * dx * dy;
    let gaussian = f32::exp(power);
    let raw = splats[row + 8] * gaussian;
    let alpha = min(raw, ALPHA_MAX);
    let counts = power <= 0.0f32 && alpha >= ALPHA_MIN;
    Hit {
        dx,
        dy,
        gaussian,
        alpha: select(counts, alpha, 0.0f32),
        uncapped: raw < ALPHA_MAX,
    }
}

/// The pixel of unit `ABSOLUTE_POS`, row-major, and the range of its tile's list in `order`.
#[derive(CubeType)]
struct PixelTile {
    px: f32,
    py: f32,
    begin: usize,
    end: usize,
}

#[cube]
fn pixel_tile(starts: &Tensor<u32>, width: u32, tiles_x: u32) -> PixelTile {
    let pixel = ABSOLUTE_POS as u32;
    let x = pixel % width;
    let y = pixel / width;
    let tile = ((y / TILE) * tiles_x + x / TILE) as usize;
    PixelTile {
        px: f32::cast_from(x),
        py: f32::cast_from(y),
        begin: starts[tile] as usize,
        end: starts[tile + 1] as usize,
    }
}

/// `out[p] = (Σ T_k α_k c_k, 1 − T)` for pixel `p`, one unit per pixel.
#[cube(launch_unchecked)]
fn forward_kernel(
    splats: &Tensor<f32>,
    starts: &Tensor<u32>,
    order: &Tensor<u32>,
    out: &mut Tensor<f32>,
    width: u32,
    tiles_x: u32,
) {
    if ABSOLUTE_POS >= out.shape(0) {
        terminate!();
    }
    let tile = pixel_tile(starts, width, tiles_x);
    let mut r = 0.0f32;
    let mut g = 0.0f32;
    let mut b = 0.0f32;
    let mut t = 1.0f32;
    for k in tile.begin..tile.end {
        let s = order[k] as usize;
        let h = hit(splats, s, tile.px, tile.py);
        if h.alpha > 0.0f32 {
            let after = t * (1.0f32 - h.alpha);
            if after < T_MIN {
                break;
            }
            let row = s * SPLAT_WIDTH;
            let w = t * h.alpha;
            r += w * splats[row + 5];
            g += w * splats[row + 6];
            b += w * splats[row + 7];
            t = after;
        }
    }
    let at = ABSOLUTE_POS * PIXEL_WIDTH;
    out[at] = r;
    out[at + 1] = g;
    out[at + 2] = b;
    out[at + 3] = 1.0f32 - t;
}

/// Adds pixel `p`'s share of the splats' gradient (from `grad[p]`) into `out`, one unit per pixel; `out`
/// must be zero on entry. See [`cpu`]'s `pixel_backward` for the derivatives.
#[cube(launch_unchecked)]
fn backward_kernel<W: Numeric>(
    splats: &Tensor<f32>,
    starts: &Tensor<u32>,
    order: &Tensor<u32>,
    grad: &Tensor<f32>,
    out: &Tensor<Atomic<W>>,
    width: u32,
    tiles_x: u32,
    #[comptime] native: bool,
    #[define(W)] _word: ElemType,
) {
    if ABSOLUTE_POS >= grad.shape(0) {
        terminate!();
    }
    let tile = pixel_tile(starts, width, tiles_x);
    // The forward pass again: where the pixel stopped and what transmittance it kept.
    let mut t_final = 1.0f32;
    let mut last = tile.begin;
    for k in tile.begin..tile.end {
        let h = hit(splats, order[k] as usize, tile.px, tile.py);
        if h.alpha > 0.0f32 {
            let after = t_final * (1.0f32 - h.alpha);
            if after < T_MIN {
                break;
            }
            t_final = after;
            last = k + 1;
        }
    }
    let g = ABSOLUTE_POS * PIXEL_WIDTH;
    let g_r = grad[g];
    let g_g = grad[g + 1];
    let g_b = grad[g + 2];
    let g_alpha = grad[g + 3];
    // The colour behind the splat being visited.
    let mut b_r = 0.0f32;
    let mut b_g = 0.0f32;
    let mut b_b = 0.0f32;
    let mut t_after = t_final;
    let count = last - tile.begin;
    for j in 0..count {
        let s = order[last - 1 - j] as usize;
        let h = hit(splats, s, tile.px, tile.py);
        if h.alpha > 0.0f32 {
            let row = s * SPLAT_WIDTH;
            let keep = 1.0f32 - h.alpha;
            let before = t_after / keep;
            let weight = before * h.alpha;
            let c_r = splats[row + 5];
            let c_g = splats[row + 6];
            let c_b = splats[row + 7];
            atomic_add::<W>(out, row + 5, weight * g_r, native);
            atomic_add::<W>(out, row + 6, weight * g_g, native);
            atomic_add::<W>(out, row + 7, weight * g_b, native);
            let g_a = g_alpha * t_final / keep
                + g_r * (before * c_r - b_r / keep)
                + g_g * (before * c_g - b_g / keep)
                + g_b * (before * c_b - b_b / keep);
            b_r += weight * c_r;
            b_g += weight * c_g;
            b_b += weight * c_b;
            if h.uncapped {
                atomic_add::<W>(out, row + 8, g_a * h.gaussian, native);
                let g_p = g_a * h.alpha;
                let a = splats[row + 2];
                let b = splats[row + 3];
                let cc = splats[row + 4];
                // p = −(a dx² + c dy²)/2 − b dx dy with dx = x − mean_x.
                atomic_add::<W>(out, row, g_p * (a * h.dx + b * h.dy), native);
                atomic_add::<W>(out, row + 1, g_p * (cc * h.dy + b * h.dx), native);
                atomic_add::<W>(out, row + 2, g_p * -0.5f32 * h.dx * h.dx, native);
                atomic_add::<W>(out, row + 3, g_p * -h.dx * h.dy, native);
                atomic_add::<W>(out, row + 4, g_p * -0.5f32 * h.dy * h.dy, native);
            }
            t_after = before;
        }
    }
}

/// The splats' gradient with the given atomic scheme (the tests run both where the device has float
/// atomics).
pub(super) fn backward(
    splats: CubeTensor,
    grad: CubeTensor,
    spec: &RasterSpec,
    scheme: AtomicScheme,
) -> CubeTensor {
    let splats = contiguous_f32(splats, "splats");
    let grad = contiguous_f32(grad, "pixel gradients");
    assert_eq!(dims(&grad), [spec.pixels(), PIXEL_WIDTH], "pixel gradients");
    let out = zeros_client(
        splats.client.clone(),
        splats.device.clone(),
        Shape::new(dims(&splats)),
        DType::F32,
    );
    let Some(units) = Units::on(&splats, spec.pixels()) else {
        return out;
    };
    let bins = cube_bins::bin(&splats, spec);
    let (native, word) = scheme.word();
    // SAFETY: pixels `< H·W` (checked in the kernel), tiles `< tiles_x · tiles_y` with `starts` one longer,
    // list positions `< order.len()`, splat rows `< N` (the binning's indices); the f32 output is read as
    // `u32` words of the same size by the exchange scheme.
    unsafe {
        backward_kernel::launch_unchecked(
            &units.client,
            units.count,
            units.dim,
            splats.into_tensor_arg(),
            bins.starts.into_tensor_arg(),
            bins.order.into_tensor_arg(),
            grad.into_tensor_arg(),
            out.clone().into_tensor_arg(),
            spec.width,
            bins.tiles_x,
            native,
            word,
        )
    }
    out
}

impl SplatBackend for Cube {
    fn splat_rasterize(splats: CubeTensor, spec: RasterSpec) -> CubeTensor {
        let splats = contiguous_f32(splats, "splats");
        assert_eq!(dims(&splats)[1], SPLAT_WIDTH, "splat rows");
        let out = empty_f32(&splats, [spec.pixels(), PIXEL_WIDTH]);
        let Some(units) = Units::on(&splats, spec.pixels()) else {
            return out;
        };
        let bins = cube_bins::bin(&splats, &spec);
        // SAFETY: as in [`backward`].
        unsafe {
            forward_kernel::launch_unchecked(
                &units.client,
                units.count,
                units.dim,
                splats.into_tensor_arg(),
                bins.starts.into_tensor_arg(),
                bins.order.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                spec.width,
                bins.tiles_x,
            )
        }
        out
    }

    fn splat_rasterize_grad(splats: CubeTensor, grad: CubeTensor, spec: RasterSpec) -> CubeTensor {
        let scheme = AtomicScheme::for_device(&splats);
        backward(splats, grad, &spec, scheme)
    }
}

//! The Gaussian splat rasteriser (3D Gaussian Splatting's tile-based, depth-sorted alpha compositing) for
//! avatars baked into Gaussians: projected splats in, a premultiplied colour and alpha image out, with its
//! backward pass. The CPU kernel ([`cpu`]) runs on the flex backend and the CubeCL kernels (`cube`: the
//! `wgpu` and `cuda` features) on the GPU backends, behind one Burn backend extension ([`extension`]); the
//! plain-tensor [`reference`] evaluates every splat at every pixel (for tests, and for the backends without
//! a kernel); [`rasterize`] picks between them.
//!
//! A splat is a row of [`SPLAT_WIDTH`] values: mean `x, y` (pixels; pixel `(x, y)` is evaluated at the
//! point `(x, y)`, so the projection owns the pixel-centre convention), conic `a, b, c` (the inverse 2-D
//! covariance `[[a, b], [b, c]]`, pixels⁻²), colour `r, g, b`, opacity, and depth (metres along the view
//! axis; it orders the splats and has no gradient).

pub mod cpu;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod cube_bins;
pub mod extension;
pub mod reference;

use burn::prelude::*;

/// Values per splat row.
pub const SPLAT_WIDTH: usize = 10;
/// Values per output pixel: colour `r, g, b` (premultiplied by coverage, no background) and alpha.
pub const PIXEL_WIDTH: usize = 4;
/// Tile side in pixels.
pub const TILE: u32 = 16;
/// A splat whose alpha at a pixel is under this is skipped there (3DGS: 1/255).
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Alphas are capped here, so that no splat alone makes a pixel opaque (3DGS: 0.99).
pub const ALPHA_MAX: f32 = 0.99;
/// A pixel stops before the splat that would bring its transmittance under this (3DGS: 1e-4).
pub const T_MIN: f32 = 1e-4;
/// A splat's cut-off box is its exact `ALPHA_MIN` extent times this plus [`EXTENT_MARGIN`] pixels, so that
/// binning never drops a pixel the per-pixel test keeps; the CPU and GPU binnings share it so that their
/// tile lists agree.
pub const EXTENT_SCALE: f32 = 1.001;
/// See [`EXTENT_SCALE`] (pixels).
pub const EXTENT_MARGIN: f32 = 0.01;

/// The image the splats are rasterised into.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RasterSpec {
    pub width: u32,
    pub height: u32,
}

impl RasterSpec {
    /// Pixels in the image.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Rasterises `splats` (`[N, SPLAT_WIDTH]`) into `[H·W, PIXEL_WIDTH]` (row-major pixels), differentiable in
/// every splat value but the depth: the kernels where the device has them, the [`reference`] elsewhere.
pub fn rasterize(splats: Tensor<2>, spec: &RasterSpec) -> Tensor<2> {
    if super::available(&splats.device()) {
        extension::rasterize(splats, spec)
    } else {
        reference::rasterize(splats, spec)
    }
}

#[cfg(test)]
mod tests;

#[cfg(all(test, any(feature = "wgpu", feature = "cuda")))]
mod cube_tests;

//! The rasteriser in plain tensor operations: every splat evaluated at every pixel (`[H·W, N]` values, so
//! for small images), with the kernel's rules as masks. The CPU kernel's tests compare against it, and
//! backends without a rasteriser kernel run it.

use burn::prelude::*;

use super::{RasterSpec, ALPHA_MAX, ALPHA_MIN, PIXEL_WIDTH, T_MIN};
use crate::tensor::{from_rows, to_host};

/// [`super::rasterize`] in tensor operations; differentiable through Burn's autodiff.
pub fn rasterize(splats: Tensor<2>, spec: &RasterSpec) -> Tensor<2> {
    let device = splats.device();
    let [n, _] = splats.dims();
    let pixels = spec.pixels();
    if n == 0 {
        return Tensor::zeros([pixels, PIXEL_WIDTH], &device);
    }
    // Front to back: by depth, then by index.
    let depth = to_host(splats.clone().slice([0..n, 9..10]));
    let mut order: Vec<i64> = (0..n as i64).collect();
    order.sort_by(|&i, &j| {
        depth[i as usize]
            .total_cmp(&depth[j as usize])
            .then(i.cmp(&j))
    });
    let sorted = splats.select(0, Tensor::<1, Int>::from_ints(order.as_slice(), &device));
    // One value per splat as a row `[1, N]`, against pixels as a column `[H·W, 1]`.
    let row = |k: usize| sorted.clone().slice([0..n, k..k + 1]).transpose();
    let (a, b, c, opacity) = (row(2), row(3), row(4), row(8));
    let width = spec.width as usize;
    let coordinate = |f: &dyn Fn(usize) -> usize| {
        let values: Vec<f32> = (0..pixels).map(|i| f(i) as f32).collect();
        from_rows(&values, pixels, 1, &device)
    };
    let dx = coordinate(&|i| i % width) - row(0);
    let dy = coordinate(&|i| i / width) - row(1);
    let power = (a.clone() * dx.clone().powi_scalar(2) + c.clone() * dy.clone().powi_scalar(2))
        * -0.5
        - b.clone() * dx * dy;
    // The kernel skips splats that are not positive definite or too transparent anywhere, and pixels where
    // the exponent is positive (rounding at a splat's centre).
    let det = a.clone() * c - b.clone() * b;
    let touches = a.greater_elem(0.0).float()
        * det.greater_elem(0.0).float()
        * opacity.clone().greater_equal_elem(ALPHA_MIN).float();
    let inside = power.clone().lower_equal_elem(0.0).float();
    let alpha = (opacity * power.clamp_max(0.0).exp()).clamp_max(ALPHA_MAX);
    let visible = alpha.clone().greater_equal_elem(ALPHA_MIN).float();
    let alpha = alpha * visible * touches * inside;
    // A pixel stops before the splat whose inclusion would leave less than T_MIN transmittance; since
    // transmittance only falls, every later splat is dropped too.
    let after = (alpha.clone().neg() + 1.0).log().cumsum(1).exp();
    let alpha = alpha * after.greater_equal_elem(T_MIN).float();
    let log_keep = (alpha.clone().neg() + 1.0).log();
    let through = log_keep.clone().cumsum(1);
    let before = (through.clone() - log_keep).exp();
    let rgb = (before * alpha).matmul(sorted.slice([0..n, 5..8]));
    let left = through.slice([0..pixels, n - 1..n]).exp();
    Tensor::cat(vec![rgb, left.neg() + 1.0], 1)
}

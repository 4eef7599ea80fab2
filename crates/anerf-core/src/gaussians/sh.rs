//! Real spherical harmonics of degree 0 and 1 for view-dependent colour, in 3D Gaussian Splatting's
//! convention: `c = 0.5 + C0·k₀ + C1·(−y·k₁ + z·k₂ − x·k₃)` for a unit direction `(x, y, z)`, clamped at 0.

use burn::prelude::*;

/// `Y₀⁰`: `1 / (2√π)`.
pub const C0: f32 = 0.282_094_8;
/// The degree-1 factor `√3 / (2√π)`.
pub const C1: f32 = 0.488_602_5;

/// Coefficients per colour channel for `degree` (0 or 1).
pub fn coefficients(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// The degree of a cloud whose colour rows hold `width` values (3 per coefficient), if it is 0 or 1.
pub fn degree_of(width: usize) -> Option<usize> {
    (0..=1).find(|&d| 3 * coefficients(d) == width)
}

/// Colours `[N, 3]` of coefficients `[N, 3·(d+1)²]` (coefficient-major: `k₀ r g b, k₁ r g b, …`) seen along
/// unit directions `dirs` `[N, 3]` (from the camera to the Gaussian, in canonical space).
pub fn colour(coefficients: Tensor<2>, dirs: Tensor<2>) -> Tensor<2> {
    let [n, width] = coefficients.dims();
    let k = |i: usize| coefficients.clone().slice([0..n, 3 * i..3 * i + 3]);
    let mut c = k(0) * C0 + 0.5;
    if degree_of(width) == Some(1) {
        let axis = |a: usize| dirs.clone().slice([0..n, a..a + 1]);
        c = c + (k(2) * axis(2) - k(1) * axis(1) - k(3) * axis(0)) * C1;
    } else {
        assert_eq!(width, 3, "colour coefficients of degree 0 or 1");
    }
    c.clamp_min(0.0)
}

//! Trilinear interpolation weights of one point, for the fused warp kernels' volume lookup
//! ([`super::warp::cpu`]; the hash-grid kernels compute the same weights for blocks of points, in lane
//! arrays). Corner `c` of a cell has bit `a` set when it lies on the high side along axis `a`; `frac` is the
//! point's position in the cell, `[0, 1]` per axis.

/// The eight corners' weights `Π_a (frac_a or 1 − frac_a)`.
#[inline(always)]
pub(crate) fn corner_weights(frac: [f32; 3]) -> [f32; 8] {
    let s = frac.map(|t| [1.0 - t, t]);
    std::array::from_fn(|c| s[0][c & 1] * s[1][(c >> 1) & 1] * s[2][(c >> 2) & 1])
}

/// `∂ weight_c / ∂ frac_a` for every corner and axis.
#[inline(always)]
pub(crate) fn corner_weight_derivatives(frac: [f32; 3]) -> [[f32; 3]; 8] {
    let s = frac.map(|t| [1.0 - t, t]);
    let sign = |c: usize, a: usize| if (c >> a) & 1 == 1 { 1.0 } else { -1.0 };
    std::array::from_fn(|c| {
        let (x, y, z) = (s[0][c & 1], s[1][(c >> 1) & 1], s[2][(c >> 2) & 1]);
        [sign(c, 0) * y * z, sign(c, 1) * x * z, sign(c, 2) * x * y]
    })
}

/// `Σ_c ∂weight_c/∂frac · ⟨grad, table[row_c]⟩`: the derivative of `grad`'s product with the interpolation of
/// the `grad.len()`-wide rows `rows` of `table`, with respect to the point's position in its cell.
#[inline(always)]
pub(crate) fn cell_position_gradient(
    rows: &[usize; 8],
    frac: [f32; 3],
    grad: &[f32],
    table: &[f32],
) -> [f32; 3] {
    let width = grad.len();
    let mut d = [0.0f32; 3];
    for (&r, dw) in rows.iter().zip(corner_weight_derivatives(frac)) {
        let dot: f32 = grad
            .iter()
            .zip(&table[r * width..(r + 1) * width])
            .map(|(a, b)| a * b)
            .sum();
        for (d, dw) in d.iter_mut().zip(dw) {
            *d += dot * dw;
        }
    }
    d
}

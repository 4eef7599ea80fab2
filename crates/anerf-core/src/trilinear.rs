//! Trilinear interpolation weights, shared by the CPU kernels that interpolate on grids
//! ([`crate::model::hash_grid::kernels`], [`crate::fused::kernels`]). Corner `c` of a cell has bit `a` set
//! when it lies on the high side along axis `a`; `frac` is the point's position in the cell, `[0, 1]` per axis.

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

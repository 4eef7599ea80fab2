//! The learned Gaussians of an avatar, in canonical space.

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

/// `N` anisotropic 3D Gaussians in canonical space (the NeRF's canonical frame, metres). Covariance
/// `Σ = R S² Rᵀ` with `S = diag(exp(log_scales))` and `R` the rotation of the normalised quaternion.
#[derive(Module, Debug)]
pub struct GaussianCloud {
    /// Means `[N, 3]`, metres.
    pub means: Param<Tensor<2>>,
    /// Logarithms of the standard deviations along the Gaussian's own axes `[N, 3]` (log metres).
    pub log_scales: Param<Tensor<2>>,
    /// Orientations, quaternions `(w, x, y, z)` `[N, 4]`, normalised where used.
    pub rotations: Param<Tensor<2>>,
    /// Opacities before the sigmoid `[N, 1]`.
    pub opacity_logits: Param<Tensor<2>>,
    /// Spherical-harmonic colour coefficients `[N, 3·(d+1)²]`, coefficient-major ([`super::sh`]).
    pub colours: Param<Tensor<2>>,
}

impl GaussianCloud {
    /// A cloud of the given values (shapes as the fields').
    pub fn new(
        means: Tensor<2>,
        log_scales: Tensor<2>,
        rotations: Tensor<2>,
        opacity_logits: Tensor<2>,
        colours: Tensor<2>,
    ) -> Self {
        let n = means.dims()[0];
        for (name, t, width) in [
            ("log_scales", &log_scales, Some(3)),
            ("rotations", &rotations, Some(4)),
            ("opacity_logits", &opacity_logits, Some(1)),
            ("colours", &colours, None),
        ] {
            let [rows, cols] = t.dims();
            assert_eq!(rows, n, "{name}: one row per Gaussian");
            if let Some(w) = width {
                assert_eq!(cols, w, "{name}: {w} values per Gaussian");
            }
        }
        Self {
            means: Param::from_tensor(means),
            log_scales: Param::from_tensor(log_scales),
            rotations: Param::from_tensor(rotations),
            opacity_logits: Param::from_tensor(opacity_logits),
            colours: Param::from_tensor(colours),
        }
    }

    /// Number of Gaussians `N`.
    pub fn len(&self) -> usize {
        self.means.dims()[0]
    }

    /// Whether the cloud holds no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Opacities in `(0, 1)`, `[N, 1]`.
    pub fn opacities(&self) -> Tensor<2> {
        sigmoid(self.opacity_logits.val())
    }

    /// `R S` `[N, 3, 3]`, so that `Σ = (R S)(R S)ᵀ`.
    pub fn covariance_factor(&self) -> Tensor<3> {
        let n = self.len();
        let scales = self.log_scales.val().exp().reshape([n, 1, 3]);
        rotation_matrices(self.rotations.val()) * scales
    }
}

/// Rotation matrices `[N, 3, 3]` (row-major rows) of quaternions `(w, x, y, z)` `[N, 4]`, normalised first.
pub fn rotation_matrices(quaternions: Tensor<2>) -> Tensor<3> {
    let [n, _] = quaternions.dims();
    let norm = quaternions
        .clone()
        .powi_scalar(2)
        .sum_dim(1)
        .sqrt()
        .clamp_min(1e-12);
    let q = quaternions / norm;
    let c = |i: usize| q.clone().slice([0..n, i..i + 1]);
    let (w, x, y, z) = (c(0), c(1), c(2), c(3));
    let two = |a: Tensor<2>, b: Tensor<2>| a * b * 2.0;
    let entries = vec![
        (two(y.clone(), y.clone()) + two(z.clone(), z.clone())).neg() + 1.0,
        two(x.clone(), y.clone()) - two(w.clone(), z.clone()),
        two(x.clone(), z.clone()) + two(w.clone(), y.clone()),
        two(x.clone(), y.clone()) + two(w.clone(), z.clone()),
        (two(x.clone(), x.clone()) + two(z.clone(), z.clone())).neg() + 1.0,
        two(y.clone(), z.clone()) - two(w.clone(), x.clone()),
        two(x.clone(), z.clone()) - two(w.clone(), y.clone()),
        two(y.clone(), z.clone()) + two(w, x.clone()),
        (two(x.clone(), x) + two(y.clone(), y)).neg() + 1.0,
    ];
    Tensor::cat(entries, 1).reshape([n, 3, 3])
}

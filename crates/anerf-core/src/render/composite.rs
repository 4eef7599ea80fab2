//! Volume rendering of per-sample density and colour along rays (black background).

use burn::prelude::*;
use burn::tensor::activation::relu;

/// Per-ray results of compositing.
#[derive(Debug, Clone)]
pub struct Composited {
    /// `[R, 3]` colour on a black background.
    pub rgb: Tensor<2>,
    /// `[R]` accumulated opacity `Σ w_k`.
    pub acc: Tensor<1>,
    /// `[R]` expected depth `Σ w_k z_k` (metres; not normalised by `acc`).
    pub depth: Tensor<1>,
    /// `[R, S]` compositing weights `w_k = α_k T_k`.
    pub weights: Tensor<2>,
    /// `[R, S]` the samples' opacities `α_k`.
    pub alpha: Tensor<2>,
}

/// Composites raw densities `[R, S]` (ReLU applied here), colours `[R, S, 3]` at depths `[R, S]`.
///
/// The reference's conventions: `α_k = 1 − exp(−ReLU(σ_k) δ_k)` with `δ_k = z_{k+1} − z_k` and the last
/// interval duplicated (not 1e10), directions of unit length. Transmittance is computed as
/// `T_k = exp(−Σ_{j<k} σ_j δ_j)`, which equals the reference's `Π_{j<k}(1 − α_j + 1e-10)` up to the 1e-10.
pub fn composite(density: Tensor<2>, rgb: Tensor<3>, depths: Tensor<2>) -> Composited {
    let [r, s] = depths.dims();
    let deltas = if s > 1 {
        let d = depths.clone().narrow(1, 1, s - 1) - depths.clone().narrow(1, 0, s - 1);
        Tensor::cat(vec![d.clone(), d.narrow(1, s - 2, 1)], 1)
    } else {
        Tensor::zeros([r, 1], &depths.device())
    };
    let tau = relu(density) * deltas;
    let alpha = tau.clone().neg().exp().neg() + 1.0;
    let transmittance = (tau.clone().cumsum(1) - tau).neg().exp();
    let weights = alpha.clone() * transmittance;
    let rgb = (rgb * weights.clone().unsqueeze_dim::<3>(2))
        .sum_dim(1)
        .reshape([r, 3]);
    let acc = weights.clone().sum_dim(1).reshape([r]);
    let depth = (weights.clone() * depths).sum_dim(1).reshape([r]);
    Composited {
        rgb,
        acc,
        depth,
        weights,
        alpha,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::stratified_depths;
    use crate::tensor::to_host;
    use anerf_device::cpu_device;

    /// A slab of constant density σ and colour c between depths a and b, sampled densely: the rendered
    /// colour must approach c·(1 − exp(−σ (b − a))) and the opacity 1 − exp(−σ (b − a)).
    #[test]
    fn constant_slab_matches_closed_form_transmittance() {
        let device = cpu_device();
        let (near, far, a, b, sigma) = (1.0f32, 3.0f32, 1.6f32, 2.3f32, 2.5f32);
        let s = 2001;
        let z = stratified_depths(
            Tensor::from_floats([near], &device),
            Tensor::from_floats([far], &device),
            s,
            None,
        );
        let zs = to_host(z.clone());
        // Each sample represents [z_k, z_k + δ): density σ where that interval lies in the slab.
        let dens: Vec<f32> = zs
            .iter()
            .map(|&t| if t >= a && t < b { sigma } else { 0.0 })
            .collect();
        let color = [0.2f32, 0.5, 0.9];
        let rgb: Vec<f32> = (0..s).flat_map(|_| color).collect();
        let out = composite(
            Tensor::<1>::from_floats(dens.as_slice(), &device).reshape([1, s]),
            Tensor::<1>::from_floats(rgb.as_slice(), &device).reshape([1, s, 3]),
            z,
        );
        let expected_acc = 1.0 - (-sigma * (b - a)).exp();
        let acc = to_host(out.acc)[0];
        assert!((acc - expected_acc).abs() < 2e-3, "{acc} vs {expected_acc}");
        for (got, c) in to_host(out.rgb).iter().zip(color) {
            assert!((got - c * expected_acc).abs() < 2e-3);
        }
        // Expected depth: ∫ z σ e^{−σ(z−a)} dz over [a, b].
        let e = (-sigma * (b - a)).exp();
        let expected_depth = a + 1.0 / sigma - (b + 1.0 / sigma) * e;
        let depth = to_host(out.depth)[0];
        assert!(
            (depth - expected_depth).abs() < 3e-3,
            "{depth} vs {expected_depth}"
        );
    }

    #[test]
    fn empty_space_renders_black_and_opaque_first_sample_wins() {
        let device = cpu_device();
        let z = Tensor::<2>::from_floats([[1.0, 1.5, 2.0]], &device);
        let rgb = Tensor::<3>::from_floats(
            [[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]],
            &device,
        );
        let empty = composite(
            Tensor::from_floats([[-5.0, 0.0, -1.0]], &device),
            rgb.clone(),
            z.clone(),
        );
        assert!(to_host(empty.rgb).iter().all(|v| *v == 0.0));
        let opaque = composite(Tensor::from_floats([[1e4, 1e4, 1e4]], &device), rgb, z);
        let c = to_host(opaque.rgb);
        assert!((c[0] - 1.0).abs() < 1e-5 && c[1].abs() < 1e-5 && c[2].abs() < 1e-5);
        assert!((to_host(opaque.depth)[0] - 1.0).abs() < 1e-5);
    }
}

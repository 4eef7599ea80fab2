//! Training losses: colour MSE and the blend-weight consistency loss.

use burn::prelude::*;

use crate::model::ConsistencyLoss;

/// Mean squared error over rays × channels (`[R, 3]` each): the reference's `L_rgb`.
pub fn color_mse(predicted: Tensor<2>, target: Tensor<2>) -> Tensor<1> {
    (predicted - target).powi_scalar(2).mean()
}

/// PSNR (dB) of a mean squared error of colours in `[0, 1]`.
pub fn psnr_from_mse(mse: f32) -> f32 {
    -10.0 * mse.max(1e-12).log10()
}

/// Consistency between observation weights and canonical weights (`[M, K]` each) over the points where
/// `mask` (`[M, 1]`, 0 or 1) is set: the mean over selected points × K of smooth-L1 (β = 1) or L1.
pub fn blend_consistency(
    observed: Tensor<2>,
    canonical: Tensor<2>,
    mask: Tensor<2>,
    kind: ConsistencyLoss,
) -> Tensor<1> {
    let k = observed.dims()[1];
    let parts = blend_consistency_parts(observed, canonical, mask, kind);
    parts.sum / (parts.selected.clamp_min(1.0) * k as f32)
}

/// [`blend_consistency`]'s numerator and the count its denominator is made of, so that the shards of one
/// batch can divide their sums by the count over all of them.
pub struct ConsistencyParts {
    /// `Σ` over the selected points × K of the per-entry loss, `[1]`.
    pub sum: Tensor<1>,
    /// Selected points, `[1]`.
    pub selected: Tensor<1>,
}

/// The parts of [`blend_consistency`]: its loss is `sum / (max(selected, 1) · K)`.
pub fn blend_consistency_parts(
    observed: Tensor<2>,
    canonical: Tensor<2>,
    mask: Tensor<2>,
    kind: ConsistencyLoss,
) -> ConsistencyParts {
    let d = (observed - canonical).abs();
    let per = match kind {
        ConsistencyLoss::L1 => d,
        ConsistencyLoss::SmoothL1 => {
            let inner = d.clone().clamp_max(1.0);
            inner.clone().powi_scalar(2) * 0.5 + (d - inner)
        }
    };
    ConsistencyParts {
        sum: (per * mask.clone()).sum(),
        selected: mask.sum(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor::to_host;
    use anerf_device::cpu_device;

    #[test]
    fn consistency_is_a_masked_mean_with_smooth_l1_branches() {
        let device = cpu_device();
        let obs = Tensor::<2>::from_floats([[0.5, 0.5], [3.0, 0.0], [9.0, 9.0]], &device);
        let can = Tensor::<2>::from_floats([[0.1, 0.5], [0.0, 0.0], [0.0, 0.0]], &device);
        let mask = Tensor::<2>::from_floats([[1.0], [1.0], [0.0]], &device);
        let smooth = to_host(blend_consistency(
            obs.clone(),
            can.clone(),
            mask.clone(),
            ConsistencyLoss::SmoothL1,
        ))[0];
        // (0.5·0.4² + 0 + (3 − 0.5) + 0) / (2 points · 2 joints)
        assert!((smooth - (0.08 + 2.5) / 4.0).abs() < 1e-6, "{smooth}");
        let l1 = to_host(blend_consistency(obs, can, mask, ConsistencyLoss::L1))[0];
        assert!((l1 - (0.4 + 3.0) / 4.0).abs() < 1e-6, "{l1}");
    }

    #[test]
    fn psnr_of_known_errors() {
        assert!((psnr_from_mse(0.01) - 20.0).abs() < 1e-5);
        assert!((color_mse_value(0.1) - 0.01).abs() < 1e-7);
    }

    fn color_mse_value(err: f32) -> f32 {
        let device = cpu_device();
        let p = Tensor::<2>::full([4, 3], 0.5 + err, &device);
        let t = Tensor::<2>::full([4, 3], 0.5, &device);
        to_host(color_mse(p, t))[0]
    }
}

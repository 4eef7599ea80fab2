//! Depth samples along rays.

use burn::prelude::*;

/// `S` depths per ray between `near` and `far` (`[R]` each, metres) → `[R, S]`.
///
/// Without `jitter` the depths are evenly spaced with both ends included (`linspace`, the reference's
/// test-time sampling). With `jitter` (`[R, S]` uniform numbers in `[0, 1)`, drawn by the caller so that
/// runs are reproducible) each depth is redrawn uniformly inside its stratum, whose edges are the midpoints
/// between neighbouring evenly spaced depths and the two ends (the reference's `perturb = 1`).
pub fn stratified_depths(
    near: Tensor<1>,
    far: Tensor<1>,
    samples: usize,
    jitter: Option<Tensor<2>>,
) -> Tensor<2> {
    let device = near.device();
    let t = Tensor::<1>::from_floats(sample_fractions(samples).as_slice(), &device)
        .reshape([1, samples]);
    let near = near.unsqueeze_dim::<2>(1);
    let far = far.unsqueeze_dim::<2>(1);
    let z = near.clone() + (far - near) * t;
    let Some(u) = jitter else { return z };
    if samples < 2 {
        return z;
    }
    let mids = (z.clone().narrow(1, 1, samples - 1) + z.clone().narrow(1, 0, samples - 1)) * 0.5;
    let upper = Tensor::cat(vec![mids.clone(), z.clone().narrow(1, samples - 1, 1)], 1);
    let lower = Tensor::cat(vec![z.narrow(1, 0, 1), mids], 1);
    lower.clone() + (upper - lower) * u
}

/// `S` fractions `i / (S − 1)` from the near (0) to the far (1) bound: where unjittered samples lie.
pub fn sample_fractions(samples: usize) -> Vec<f32> {
    (0..samples)
        .map(|i| {
            if samples > 1 {
                i as f32 / (samples - 1) as f32
            } else {
                0.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tensor::to_host;

    #[test]
    fn evenly_spaced_without_jitter_and_inside_strata_with_it() {
        let device = anerf_device::cpu_device();
        let near = Tensor::<1>::from_floats([1.0, 2.0], &device);
        let far = Tensor::<1>::from_floats([3.0, 2.5], &device);
        let z = to_host(stratified_depths(near.clone(), far.clone(), 5, None));
        let expect = [1.0, 1.5, 2.0, 2.5, 3.0, 2.0, 2.125, 2.25, 2.375, 2.5];
        for (a, b) in z.iter().zip(expect) {
            assert!((a - b).abs() < 1e-6);
        }
        let lo = stratified_depths(
            near.clone(),
            far.clone(),
            5,
            Some(Tensor::zeros([2, 5], &device)),
        );
        let hi = stratified_depths(
            near.clone(),
            far.clone(),
            5,
            Some(Tensor::ones([2, 5], &device)),
        );
        let (lo, hi) = (to_host(lo), to_host(hi));
        // Strata tile [near, far] exactly: each upper edge is the next lower edge.
        assert!((lo[0] - 1.0).abs() < 1e-6 && (hi[4] - 3.0).abs() < 1e-6);
        for i in 0..4 {
            assert!((hi[i] - lo[i + 1]).abs() < 1e-6);
        }
        let mid = stratified_depths(near, far, 5, Some(Tensor::full([2, 5], 0.5, &device)));
        let mid = to_host(mid);
        assert!((mid[1] - 1.5).abs() < 1e-6 && (mid[0] - 1.125).abs() < 1e-6);
    }
}

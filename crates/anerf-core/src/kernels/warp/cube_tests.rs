//! The warp's CubeCL kernels on each compiled GPU runtime (wgpu, CUDA) against the CPU kernels (flex), the
//! plain-tensor reference on the same device and central differences of their own forward pass. Each test
//! first checks every GPU backend in a child process (`anerf_device::probe`) and runs on those that work,
//! printing why for the others.
//!
//! Tolerances: the kernels compute in f32 with the CPU kernels' formulas but other rounding (the device may
//! contract `a·b + c` into one fused operation, divides to within 2.5 ulp in WGSL and has its own `exp`), so
//! values and gradients agree to `1e-4 · (1 + |x|)`; the prior's gradient, divided by `w^s + 1e-9`, is
//! compared relative to its own magnitude as the CPU tests do.

use burn::prelude::*;

use super::reference::prior_softmax as prior_softmax_reference;
use super::tests::{
    compare, differentiate, objective_coefficients, singular_blends, skinning, skinning_inputs,
    softmax_inputs,
};
use super::*;
use crate::geometry::lbs::tests::TestRng;
use crate::geometry::volume::tests::wavy_lookup;
use crate::geometry::BoneMatrices;
use crate::tensor::{from_rows, to_host};
use crate::DeviceChoice;
use anerf_device::cpu_device;
use anerf_device::testing::gpu_devices_for_test;
use anerf_testing::{assert_close, Tolerance};

/// The GPU devices (wgpu, CUDA) for the test `test` (under `kernels::warp::cube_tests::`) that pass the
/// probe; each one missing is printed with the reason.
fn gpus(test: &str) -> Vec<(DeviceChoice, Device)> {
    gpu_devices_for_test(&format!("kernels::warp::cube_tests::{test}"))
}

#[test]
fn cube_inverse_skinning_matches_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_inverse_skinning_matches_flex_and_the_reference") {
        eprintln!("on {choice}");
        assert!(
            crate::kernels::available(&gpu) && crate::kernels::available(&gpu.clone().autodiff())
        );
        // More points than one launch cube holds.
        let (bones, points, weights) = skinning_inputs(21, 1_500);
        let got = skinning(&gpu, &bones, &points, &weights, true);
        let flex = skinning(&cpu_device(), &bones, &points, &weights, true);
        let reference = skinning(&gpu, &bones, &points, &weights, false);
        compare(
            &format!("inverse skinning on {choice} vs flex"),
            &got,
            &flex,
            1e-4,
        );
        // The reference blends the bone matrices with a matmul: TF32 on CUDA.
        compare(
            &format!("inverse skinning on {choice} vs the reference there"),
            &got,
            &reference,
            anerf_device::testing::matmul_tolerance(choice, 1e-4) as f32,
        );
        // Singular blends: the guard replaces the determinant on the GPU as on the CPU.
        let (bones, points, weights) = singular_blends();
        let got = skinning(&gpu, &bones, &points, &weights, true);
        let flex = skinning(&cpu_device(), &bones, &points, &weights, true);
        assert!(got.value.iter().chain(&got.grad_b).all(|v| v.is_finite()));
        compare(
            &format!("guarded skinning on {choice} vs flex"),
            &got,
            &flex,
            1e-4,
        );
    }
}

#[test]
fn cube_prior_softmax_matches_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_prior_softmax_matches_flex_and_the_reference") {
        eprintln!("on {choice}");
        let (n, k) = (1_200, 24);
        let (prior, residual) = softmax_inputs(7, n, k);
        let got = differentiate(&gpu, &prior, &residual, n, prior_softmax);
        for row in got.value.chunks_exact(k) {
            assert!(
                (row.iter().sum::<f32>() - 1.0).abs() < 1e-5,
                "rows sum to 1"
            );
        }
        let flex = differentiate(&cpu_device(), &prior, &residual, n, prior_softmax);
        let reference = differentiate(&gpu, &prior, &residual, n, prior_softmax_reference);
        compare(
            &format!("prior softmax on {choice} vs flex"),
            &got,
            &flex,
            1e-4,
        );
        compare(
            &format!("prior softmax on {choice} vs the reference there"),
            &got,
            &reference,
            1e-4,
        );
    }
}

#[test]
fn cube_volume_lookup_matches_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_volume_lookup_matches_flex_and_the_reference") {
        eprintln!("on {choice}");
        let (value, grad) = wavy_lookup(&gpu, true);
        let (flex_value, flex_grad) = wavy_lookup(&cpu_device(), true);
        let (reference_value, reference_grad) = wavy_lookup(&gpu, false);
        // Points beyond the border have no gradient along the clamped axes; some exist in the sample.
        assert!(grad.contains(&0.0) && grad.iter().any(|g| *g != 0.0));
        for (against, v, g) in [
            ("flex", &flex_value, &flex_grad),
            ("the reference there", &reference_value, &reference_grad),
        ] {
            let what = |of: &str| format!("volume lookup {of} on {choice} vs {against}");
            assert_close(&what("values"), &value, v, Tolerance::Relative(1e-5));
            assert_close(
                &what("point gradients"),
                &grad,
                g,
                Tolerance::Relative(1e-4),
            );
        }
    }
}

/// Central differences along every entry of the `rows`-row inputs `a` and `b` of `Σ c ⊙ f(a, b)` (the
/// coefficients of [`differentiate`]'s objective): `f` runs once on `gpu` over all the perturbed copies
/// stacked (it must act row by row), the sums in f64 on the host. Returns `(∂/∂a, ∂/∂b)`.
fn central_differences(
    gpu: &Device,
    (a, b): (&[f32], &[f32]),
    rows: usize,
    h: f32,
    f: impl Fn(Tensor<2>, Tensor<2>) -> Tensor<2>,
) -> (Vec<f64>, Vec<f64>) {
    let entries = a.len() + b.len();
    let (mut batch_a, mut batch_b) = (Vec::new(), Vec::new());
    for e in 0..entries {
        for sign in [1.0, -1.0] {
            let (mut ca, mut cb) = (a.to_vec(), b.to_vec());
            match e.checked_sub(a.len()) {
                None => ca[e] += sign * h,
                Some(j) => cb[j] += sign * h,
            }
            batch_a.extend(ca);
            batch_b.extend(cb);
        }
    }
    let copies = 2 * entries;
    let out = to_host(f(
        from_rows(&batch_a, copies * rows, a.len() / rows, gpu),
        from_rows(&batch_b, copies * rows, b.len() / rows, gpu),
    ));
    let width = out.len() / copies;
    let coeff = objective_coefficients(width);
    let objective = |copy: usize| -> f64 {
        out[copy * width..(copy + 1) * width]
            .iter()
            .zip(&coeff)
            .map(|(v, c)| *v as f64 * *c as f64)
            .sum()
    };
    let fd: Vec<f64> = (0..entries)
        .map(|e| (objective(2 * e) - objective(2 * e + 1)) / (2.0 * h as f64))
        .collect();
    let (fa, fb) = fd.split_at(a.len());
    (fa.to_vec(), fb.to_vec())
}

/// `|fd − analytic| ≤ tolerance · (1 + |fd|)` for every entry.
fn assert_matches_differences(what: &str, analytic: &[f32], fd: &[f64], tolerance: f64) {
    assert_eq!(analytic.len(), fd.len(), "{what}: lengths");
    for (i, (a, d)) in analytic.iter().zip(fd).enumerate() {
        assert!(
            (*a as f64 - d).abs() <= tolerance * (1.0 + d.abs()),
            "{what} {i}: kernel {a}, central difference {d}"
        );
    }
}

/// The backward kernels of inverse skinning and the prior softmax against central differences of their
/// forward kernels, all on the GPU. Steps: `1e-2` (m for points, absolute for weights and logits), where the
/// smooth maps' `h²` truncation error and the f32 forward's rounding (`≈ 1e-6 / h`) both stay near `1e-4`,
/// well inside the `2e-3 · (1 + |fd|)` allowed.
#[test]
fn cube_warp_gradients_match_central_differences() {
    for (choice, gpu) in gpus("cube_warp_gradients_match_central_differences") {
        eprintln!("on {choice}");
        let n = 6;
        let (bones, points, weights) = skinning_inputs(5, n);
        let skin =
            |p: Tensor<2>, w: Tensor<2>| BoneMatrices::new(&bones, &p.device()).inverse(p, w);
        let analytic = differentiate(&gpu, &points, &weights, n, skin);
        let (fd_points, fd_weights) = central_differences(&gpu, (&points, &weights), n, 1e-2, skin);
        let what = |of: &str| format!("inverse skinning on {choice}: d/d{of}");
        assert_matches_differences(&what("points"), &analytic.grad_a, &fd_points, 2e-3);
        assert_matches_differences(&what("weights"), &analytic.grad_b, &fd_weights, 2e-3);

        let (n, k) = (5, 24);
        let (mut prior, residual) = softmax_inputs(3, n, k);
        // Away from zero, where `log(prior)` curves little over `± h` (its third derivative is `2 / prior³`).
        prior.iter_mut().for_each(|w| *w += 0.3);
        let analytic = differentiate(&gpu, &prior, &residual, n, prior_softmax);
        let (fd_prior, fd_residual) =
            central_differences(&gpu, (&prior, &residual), n, 1e-2, prior_softmax);
        let what = |of: &str| format!("prior softmax on {choice}: d/d{of}");
        assert_matches_differences(&what("prior"), &analytic.grad_a, &fd_prior, 2e-3);
        assert_matches_differences(&what("residual"), &analytic.grad_b, &fd_residual, 2e-3);
    }
}

/// The volume lookup's point gradient against central differences of its forward kernel on the GPU. The
/// points lie in the middle of their cells (fraction 0.3–0.7 of 0.5 m cells), so `x ± h` (h = 1 cm) stays in
/// one cell, where the lookup is linear along each axis: the difference quotient is exact up to rounding.
#[test]
fn cube_volume_lookup_gradient_matches_central_differences() {
    for (choice, gpu) in gpus("cube_volume_lookup_gradient_matches_central_differences") {
        eprintln!("on {choice}");
        let grid = TrilinearGrid {
            min: [-1.0, -1.0, -1.0],
            scale: [2.0, 2.0, 2.0],
            dims: [5, 5, 5],
        };
        let (nodes, channels) = (125, 4);
        let mut rng = TestRng(8);
        let table: Vec<f32> = (0..nodes * channels)
            .map(|_| rng.range(-1.0, 1.0))
            .collect();
        let n = 10;
        let points: Vec<f32> = (0..3 * n)
            .map(|_| {
                let cell = rng.range(0.0, 3.99).floor();
                -1.0 + (cell + rng.range(0.3, 0.7)) / 2.0
            })
            .collect();
        let lookup = |p: Tensor<2>| {
            trilinear(
                p.clone(),
                from_rows(&table, nodes, channels, &p.device()),
                grid,
            )
        };

        let device = gpu.clone().autodiff();
        let p = from_rows(&points, n, 3, &device).require_grad();
        let c = from_rows(&objective_coefficients(n * channels), n, channels, &device);
        let grads = (lookup(p.clone()) * c).sum().backward();
        let analytic = to_host(p.grad(&grads).expect("points are tracked"));
        // The second input is unused: its differences are zero and not checked.
        let unused = vec![0.0; n];
        let (fd, _) = central_differences(&gpu, (&points, &unused), n, 1e-2, |p, _| lookup(p));
        assert!(
            analytic.iter().any(|g| g.abs() > 0.1),
            "non-trivial gradients"
        );
        assert_matches_differences(
            &format!("volume lookup on {choice}: d/dpoints"),
            &analytic,
            &fd,
            1e-3,
        );
    }
}

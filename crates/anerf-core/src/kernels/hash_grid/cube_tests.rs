//! The CubeCL kernels on each compiled GPU runtime (wgpu, CUDA) against the CPU kernels (flex), the
//! plain-tensor reference and finite differences. Each test first checks every GPU backend in a child
//! process (`anerf_device::probe`) and runs on those that work, printing why for the others.
//!
//! Tolerances: the kernels compute in f32 like the CPU kernels, with the same formulas but other rounding
//! (the device may contract `a·b + c` into one fused operation and divides to within 2.5 ulp in WGSL) and,
//! for the table gradient, sums in another order (atomic adds). Forward values (sums of eight products of
//! magnitude ≤ 1) agree to `1e-5`; gradients within the CPU tests' bounds, `1e-3 · (1 + |x|)` for points
//! (sums over 4 levels of derivatives scaled by up to 8 cells per metre) and `1e-4 · (1 + |x|)` for the
//! table; see each test for the atomic-add bound.

use burn::prelude::*;
use burn_cubecl::ops::into_data_sync;

use super::cube;
use super::reference::encode as encode_reference;
use super::tests::{gradients, points, spec_with, wave};
use super::*;
use crate::kernels::cube::testing::{atomic_schemes, cube_tensor};
use crate::kernels::cube::AtomicScheme;
use crate::tensor::{from_rows, to_host};
use crate::DeviceChoice;
use anerf_device::cpu_device;
use anerf_device::testing::gpu_devices_for_test;
use anerf_testing::{assert_close, Tolerance};

/// The GPU devices (wgpu, CUDA) for the test at `path` (under `kernels::hash_grid::cube_tests::`) that
/// pass the probe; each one missing is printed with the reason.
fn gpus(test: &str) -> Vec<(DeviceChoice, Device)> {
    gpu_devices_for_test(&format!("kernels::hash_grid::cube_tests::{test}"))
}

/// A test table `[L·T, F]` of deterministic values in `[−1, 1]`.
fn table_values(spec: &GridSpec) -> Vec<f32> {
    wave(spec.table_rows() * spec.features, 0.37)
}

#[test]
fn cube_encode_matches_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_encode_matches_flex_and_the_reference") {
        eprintln!("on {choice}");
        assert!(
            crate::kernels::available(&gpu) && crate::kernels::available(&gpu.clone().autodiff())
        );
        for features in [2, 3] {
            let spec = spec_with(features);
            let n = 300;
            // Points in [−1.2, 1.2]³: some outside the grid's [−1, 1]³ read its clamped border.
            let p = points(n);
            assert!(p.iter().any(|v| v.abs() > 1.0) && p.iter().any(|v| v.abs() < 1.0));
            let table = table_values(&spec);
            let encode_on = |device: &Device, kernels: bool| {
                let p = from_rows(&p, n, 3, device);
                let t = from_rows(&table, spec.table_rows(), spec.features, device);
                to_host(if kernels {
                    extension::encode(p, t, &spec)
                } else {
                    encode_reference(p, t, &spec)
                })
            };
            let got = encode_on(&gpu, true);
            assert_eq!(got.len(), n * spec.output_dim());
            let what = |against: &str| format!("F = {features}: encoding vs {against}");
            assert_close(
                &what("flex"),
                &got,
                &encode_on(&cpu_device(), true),
                Tolerance::Relative(1e-5),
            );
            assert_close(
                &what(&format!("reference on {choice}")),
                &got,
                &encode_on(&gpu, false),
                Tolerance::Relative(1e-5),
            );
        }
    }
}

#[test]
fn cube_gradients_match_flex_and_the_reference() {
    for (choice, gpu) in gpus("cube_gradients_match_flex_and_the_reference") {
        eprintln!("on {choice}");
        let gpu = gpu.autodiff();
        for features in [2, 3] {
            let (gp, gt) = gradients(&gpu, true, 150, features);
            let (fp, ft) = gradients(&cpu_device().autodiff(), true, 150, features);
            let (rp, rt) = gradients(&gpu, false, 150, features);
            // Points outside the grid have no gradient along the clamped axes; some exist in the sample.
            assert!(gp.contains(&0.0) && gp.iter().any(|&v| v != 0.0));
            assert!(gt.iter().any(|&v| v != 0.0));
            let what = |of: &str, against: &str| format!("F = {features}: d/d{of} vs {against}");
            assert_close(&what("points", "flex"), &gp, &fp, Tolerance::Relative(1e-3));
            assert_close(
                &what("points", &format!("reference on {choice}")),
                &gp,
                &rp,
                Tolerance::Relative(1e-3),
            );
            assert_close(&what("table", "flex"), &gt, &ft, Tolerance::Relative(1e-4));
            assert_close(
                &what("table", &format!("reference on {choice}")),
                &gt,
                &rt,
                Tolerance::Relative(1e-4),
            );
        }
    }
}

/// `2⁻²⁴`, the relative rounding error of one f32 operation.
const UNIT_ROUNDOFF: f32 = f32::EPSILON / 2.0;

/// The table gradient of `n` points `p` and output gradient `grad` on `gpu`, added with `scheme`.
fn gpu_table_grad(
    gpu: &Device,
    p: &[f32],
    grad: &[f32],
    spec: &GridSpec,
    scheme: AtomicScheme,
) -> Vec<f32> {
    let n = p.len() / 3;
    let out = cube::table_grad(
        cube_tensor(from_rows(p, n, 3, gpu)),
        cube_tensor(from_rows(grad, n, spec.output_dim(), gpu)),
        spec,
        scheme,
    );
    into_data_sync(out).try_to_vec::<f32>().expect("f32 values")
}

/// The CPU kernel's table gradient.
fn cpu_table_grad(p: &[f32], grad: &[f32], spec: &GridSpec) -> Vec<f32> {
    let mut out = vec![0.0; spec.table_rows() * spec.features];
    cpu::table_grad(p, grad, spec, &mut out);
    out
}

/// No atomic add is lost under heavy contention: 4096 points at the grid's centre, a vertex of every level
/// (0.5 in the unit cube; 2, 4, 8, 16 cells per axis), with unit gradients put weight exactly 1 on one row
/// per level, so each of its entries must read exactly 4096 (an integer sum, exact in f32 in any order).
#[test]
fn cube_table_gradient_loses_no_contended_add() {
    for (choice, gpu) in gpus("cube_table_gradient_loses_no_contended_add") {
        eprintln!("on {choice}");
        let spec = spec_with(2);
        let n = 4096;
        let p = vec![0.0; 3 * n];
        let grad = vec![1.0; n * spec.output_dim()];
        let expected = cpu_table_grad(&p, &grad, &spec);
        let full = expected.iter().filter(|&&v| v == n as f32).count();
        assert_eq!(full, spec.output_dim(), "one row of F entries per level");
        assert_eq!(expected.iter().sum::<f32>(), (n * spec.output_dim()) as f32);
        for scheme in atomic_schemes(&gpu) {
            let got = gpu_table_grad(&gpu, &p, &grad, &spec, scheme);
            if let Some(r) = (0..expected.len()).find(|&r| got[r] != expected[r]) {
                panic!(
                    "{scheme:?}: table gradient {r} is {} on {choice}, {} on flex",
                    got[r], expected[r]
                );
            }
        }
    }
}

/// Both ways of adding atomically give the CPU kernel's table gradient on points spread over and beyond
/// the grid, half of them crowded into a 5 cm cube so that the adds contend.
///
/// Bound: any order of summing `k` terms is within `(k − 1) · 2⁻²⁴ · Σ|terms|` of the exact sum; each entry
/// here sums at most `8N` terms, and both sides round, so `|wgpu − flex| ≤ 2 · 8N · 2⁻²⁴ · Σ|terms|` (with
/// `Σ|terms|` the table gradient of `|grad|`: the weights are positive). This catches a wrong row or
/// weight; [`cube_table_gradient_loses_no_contended_add`] checks that no add is lost.
#[test]
fn cube_table_gradient_matches_flex_with_either_atomic_add() {
    for (choice, gpu) in gpus("cube_table_gradient_matches_flex_with_either_atomic_add") {
        eprintln!("on {choice}");
        let spec = spec_with(2);
        let spread = 1000;
        let mut p = points(spread);
        p.extend(points(spread).iter().map(|v| 0.3 + 0.02 * v));
        let n = 2 * spread;
        let grad = wave(n * spec.output_dim(), 0.91);
        let abs_grad: Vec<f32> = grad.iter().map(|v| v.abs()).collect();
        let expected = cpu_table_grad(&p, &grad, &spec);
        let magnitude = cpu_table_grad(&p, &abs_grad, &spec);
        assert!(magnitude.iter().any(|&m| m > 50.0), "the adds contend");
        let bound: Vec<f32> = magnitude
            .iter()
            .map(|m| 2.0 * 8.0 * n as f32 * UNIT_ROUNDOFF * m)
            .collect();
        for scheme in atomic_schemes(&gpu) {
            let got = gpu_table_grad(&gpu, &p, &grad, &spec, scheme);
            assert_eq!(got.len(), expected.len());
            let mut worst = 0.0f32;
            for (r, ((g, e), b)) in got.iter().zip(&expected).zip(&bound).enumerate() {
                assert!(
                    (g - e).abs() <= *b,
                    "{scheme:?}: table gradient {r} is {g} on {choice}, {e} on flex (bound {b:e})"
                );
                worst = worst.max((g - e).abs() / b.max(f32::MIN_POSITIVE));
            }
            eprintln!("{scheme:?}: worst difference {worst:.1e} of the bound");
        }
    }
}

/// The one-pass kernel of both gradients, with either atomic add, against the CPU kernel of both: points
/// spread over and beyond the grid. Its point gradient sums each point's levels in another order (atomic
/// adds), within the point tolerance; its table gradient is the table kernel's, within its tolerance.
#[test]
fn cube_fused_gradients_match_flex_with_either_atomic_add() {
    for (choice, gpu) in gpus("cube_fused_gradients_match_flex_with_either_atomic_add") {
        eprintln!("on {choice}");
        for features in [2, 3] {
            let spec = spec_with(features);
            let n = 400;
            let p = points(n);
            let table = table_values(&spec);
            let grad = wave(n * spec.output_dim(), 0.91);
            let mut expected_table = vec![0.0; spec.table_rows() * spec.features];
            let mut expected_points = vec![0.0; n * 3];
            cpu::grads(
                &p,
                &table,
                &grad,
                &spec,
                &mut expected_table,
                &mut expected_points,
            );
            assert!(expected_points.contains(&0.0), "some points lie outside");
            for scheme in atomic_schemes(&gpu) {
                let (got_table, got_points) = cube::grads(
                    cube_tensor(from_rows(&p, n, 3, &gpu)),
                    cube_tensor(from_rows(&table, spec.table_rows(), spec.features, &gpu)),
                    cube_tensor(from_rows(&grad, n, spec.output_dim(), &gpu)),
                    &spec,
                    scheme,
                );
                let host = |t| into_data_sync(t).try_to_vec::<f32>().expect("f32 values");
                let what = |of: &str| format!("F = {features}, {scheme:?}: d/d{of} on {choice}");
                assert_close(
                    &what("table"),
                    &host(got_table),
                    &expected_table,
                    Tolerance::Relative(1e-4),
                );
                assert_close(
                    &what("points"),
                    &host(got_points),
                    &expected_points,
                    Tolerance::Relative(1e-3),
                );
            }
        }
    }
}

/// Central differences of `Σ c ⊙ encode(x)` (the encodings computed on wgpu, the sum in f64 on the host)
/// against the wgpu point gradient. Step `h = 1e-2` m: the test points lie in the middle half of the finest
/// cells (12.5 cm), so `x ± h` stays in one cell at every level where the encoding is trilinear; the
/// difference quotient's rounding error is about `1e-7 · |encoding| / h ≈ 1e-5`, far below the `1e-2 · (1 +
/// |fd|)` allowed.
#[test]
fn cube_point_gradient_matches_finite_differences() {
    for (choice, gpu) in gpus("cube_point_gradient_matches_finite_differences") {
        eprintln!("on {choice}");
        let spec = super::tests::config().spec();
        let n = 12;
        let base = points(n);
        let table = table_values(&spec);
        let coeff = wave(n * spec.output_dim(), 0.91);

        let device = gpu.clone().autodiff();
        let p = from_rows(&base, n, 3, &device).require_grad();
        let t = from_rows(&table, spec.table_rows(), spec.features, &device);
        let c = from_rows(&coeff, n, spec.output_dim(), &device);
        let grads = (extension::encode(p.clone(), t, &spec) * c)
            .sum()
            .backward();
        let analytic = to_host(p.grad(&grads).expect("points gradient"));

        // Every perturbed copy of the points (+h and −h along each of the 3n coordinates) in one batch.
        let h = 1e-2f32;
        let mut batch = Vec::with_capacity(6 * n * 3 * n);
        for i in 0..3 * n {
            for sign in [1.0, -1.0] {
                let mut moved = base.clone();
                moved[i] += sign * h;
                batch.extend(moved);
            }
        }
        let copies = 6 * n;
        let encoded = to_host(extension::encode(
            from_rows(&batch, copies * n, 3, &gpu),
            from_rows(&table, spec.table_rows(), spec.features, &gpu),
            &spec,
        ));
        let objective = |copy: usize| -> f64 {
            let width = n * spec.output_dim();
            encoded[copy * width..(copy + 1) * width]
                .iter()
                .zip(&coeff)
                .map(|(a, b)| *a as f64 * *b as f64)
                .sum()
        };
        let mut outside = 0;
        for i in 0..3 * n {
            let fd = (objective(2 * i) - objective(2 * i + 1)) / (2.0 * h as f64);
            assert!(
                (fd - analytic[i] as f64).abs() < 1e-2 * (1.0 + fd.abs()),
                "d/dx {i}: finite difference {fd}, {choice} kernel {}",
                analytic[i]
            );
            outside += usize::from(base[i].abs() > 1.0);
        }
        assert!(
            outside > 0 && analytic.iter().any(|v| v.abs() > 1.0),
            "the sample has clamped coordinates and non-trivial gradients"
        );
    }
}

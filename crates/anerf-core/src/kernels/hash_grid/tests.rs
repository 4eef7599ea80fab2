//! The kernels against the plain-tensor reference, and both against finite differences.

use burn::prelude::*;
use burn::tensor::Distribution;

use super::reference::encode as encode_reference;
use super::*;
use crate::model::hash_grid::HashGridConfig;
use crate::tensor::{from_rows, to_host};
use anerf_device::cpu_device;

/// Four levels (2, 4, 8, 16 cells per axis) over `[−1, 1]³` with 256-row tables: the two coarse levels are
/// stored densely, the two fine ones hashed.
pub(super) fn config() -> HashGridConfig {
    HashGridConfig {
        levels: 4,
        log2_table_size: 8,
        features_per_level: 2,
        base_resolution: 2,
        finest_resolution: 16,
        half_extent: 1.0,
    }
}

/// Deterministic points in `[−1.2, 1.2]³` (some outside the grid), kept away from cell faces of the finest
/// level so that finite differences stay inside one cell.
pub(super) fn points(n: usize) -> Vec<f32> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    (0..3 * n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 40) as f32 / (1u64 << 24) as f32;
            // Snap to the middle half of a finest-level cell (width 1/8 m).
            let cell = ((u * 2.4 - 1.2) * 8.0).floor();
            (cell + 0.25 + 0.5 * ((state >> 8) & 0xff) as f32 / 255.0) / 8.0
        })
        .collect()
}

#[test]
fn resolutions_grow_geometrically_and_coarse_levels_are_dense() {
    let spec = config().spec();
    assert_eq!(spec.resolutions, vec![2, 4, 8, 16]);
    assert_eq!(spec.output_dim(), 8);
    assert_eq!(
        (0..4).map(|l| spec.is_dense(l)).collect::<Vec<_>>(),
        [true, true, false, false]
    );
    assert!(config().validate("model.grid").is_ok());
    let bad = HashGridConfig {
        finest_resolution: 1,
        ..config()
    };
    assert_eq!(
        bad.validate("model.grid").unwrap_err().key,
        "model.grid.base_resolution"
    );
}

/// The test grid with `features` per level: 2 runs the kernels' constant-width instance, 3 the instance that
/// reads the width at run time.
pub(super) fn spec_with(features: usize) -> GridSpec {
    HashGridConfig {
        features_per_level: features,
        ..config()
    }
    .spec()
}

#[test]
fn kernels_match_the_reference_forward() {
    for features in [2, 3] {
        forward_matches(features);
    }
}

fn forward_matches(features: usize) {
    let device = cpu_device();
    assert!(crate::kernels::available(&device));
    let spec = spec_with(features);
    let n = 200;
    let p = from_rows(&points(n), n, 3, &device);
    let table = Tensor::<2>::random(
        [spec.table_rows(), spec.features],
        Distribution::Uniform(-1.0, 1.0),
        &device,
    );
    let got = to_host(extension::encode(p.clone(), table.clone(), &spec));
    let expect = to_host(encode_reference(p, table, &spec));
    assert_eq!(got.len(), n * spec.output_dim());
    for (i, (g, e)) in got.iter().zip(&expect).enumerate() {
        assert!((g - e).abs() < 1e-5, "value {i}: kernel {g}, reference {e}");
    }
}

/// `len` deterministic values in `[−1, 1]` (a function of the index, not of the device's global RNG, which
/// tests running in parallel would draw from between two calls compared).
pub(super) fn wave(len: usize, scale: f32) -> Vec<f32> {
    (0..len).map(|i| (i as f32 * scale).sin()).collect()
}

/// The gradients of `Σ c ⊙ encode(x)` with respect to the points and the table on `device` (an autodiff
/// device), through the kernels or the reference.
pub(super) fn gradients(
    device: &Device,
    use_kernels: bool,
    n: usize,
    features: usize,
) -> (Vec<f32>, Vec<f32>) {
    let spec = spec_with(features);
    let p = from_rows(&points(n), n, 3, device).require_grad();
    let table = from_rows(
        &wave(spec.table_rows() * spec.features, 0.37),
        spec.table_rows(),
        spec.features,
        device,
    );
    let coeff = from_rows(
        &wave(n * spec.output_dim(), 0.91),
        n,
        spec.output_dim(),
        device,
    );
    let table = table.require_grad();
    let out = if use_kernels {
        extension::encode(p.clone(), table.clone(), &spec)
    } else {
        encode_reference(p.clone(), table.clone(), &spec)
    };
    let grads = (out * coeff).sum().backward();
    (
        to_host(p.grad(&grads).expect("points gradient")),
        to_host(table.grad(&grads).expect("table gradient")),
    )
}

#[test]
fn kernels_match_the_reference_backward() {
    for features in [2, 3] {
        backward_matches(features);
    }
}

fn backward_matches(features: usize) {
    let device = cpu_device().autodiff();
    let (kp, kt) = gradients(&device, true, 150, features);
    let (rp, rt) = gradients(&device, false, 150, features);
    for (i, (a, b)) in kp.iter().zip(&rp).enumerate() {
        assert!(
            (a - b).abs() < 1e-3 * (1.0 + b.abs()),
            "d/dx {i}: {a} vs {b}"
        );
    }
    // Points outside the grid have no gradient along the clamped axes; some exist in the sample.
    assert!(kp.contains(&0.0) && kp.iter().any(|&v| v != 0.0));
    for (i, (a, b)) in kt.iter().zip(&rt).enumerate() {
        assert!(
            (a - b).abs() < 1e-4 * (1.0 + b.abs()),
            "d/dtable {i}: {a} vs {b}"
        );
    }
}

/// Central differences of `Σ c ⊙ encode(x)` (in f64) against the kernels' backward pass.
#[test]
fn kernel_gradients_match_finite_differences() {
    let device = cpu_device().autodiff();
    let spec = config().spec();
    let n = 12;
    let base = points(n);
    let mut table = vec![0.0f32; spec.table_rows() * spec.features];
    let mut coeff = vec![0.0f32; n * spec.output_dim()];
    for (i, v) in table.iter_mut().enumerate() {
        *v = ((i * 7919) % 1000) as f32 / 500.0 - 1.0;
    }
    for (i, v) in coeff.iter_mut().enumerate() {
        *v = ((i * 104_729) % 997) as f32 / 498.5 - 1.0;
    }
    let objective = |p: &[f32], t: &[f32]| -> f64 {
        let mut out = vec![0.0; n * spec.output_dim()];
        cpu::encode(p, t, &spec, &mut out);
        out.iter()
            .zip(&coeff)
            .map(|(a, b)| (*a as f64) * (*b as f64))
            .sum()
    };
    let p = from_rows(&base, n, 3, &device).require_grad();
    let t = from_rows(&table, spec.table_rows(), spec.features, &device).require_grad();
    let c = from_rows(&coeff, n, spec.output_dim(), &device);
    let grads = (extension::encode(p.clone(), t.clone(), &spec) * c)
        .sum()
        .backward();
    let (gp, gt) = (
        to_host(p.grad(&grads).unwrap()),
        to_host(t.grad(&grads).unwrap()),
    );

    let h = 1e-2f32;
    for i in 0..3 * n {
        let (mut plus, mut minus) = (base.clone(), base.clone());
        plus[i] += h;
        minus[i] -= h;
        let fd = (objective(&plus, &table) - objective(&minus, &table)) / (2.0 * h as f64);
        assert!(
            (fd - gp[i] as f64).abs() < 1e-2 * (1.0 + fd.abs()),
            "d/dx {i}: finite difference {fd}, kernel {}",
            gp[i]
        );
    }
    // The encoding is linear in the table: check the rows the points touch and some they do not.
    for r in (0..table.len()).step_by(37) {
        let (mut plus, mut minus) = (table.clone(), table.clone());
        plus[r] += 0.5;
        minus[r] -= 0.5;
        let fd = objective(&base, &plus) - objective(&base, &minus);
        assert!(
            (fd - gt[r] as f64).abs() < 1e-3 * (1.0 + fd.abs()),
            "d/dtable {r}: finite difference {fd}, kernel {}",
            gt[r]
        );
    }
}

/// The fused backward kernel against the two separate ones, for the constant and the run-time width, with
/// some output gradients zero (the kernels skip those points).
#[test]
fn fused_gradients_match_the_separate_kernels() {
    for features in [2, 3] {
        let spec = spec_with(features);
        let n = 300;
        let p = points(n);
        let table: Vec<f32> = (0..spec.table_rows() * spec.features)
            .map(|i| (i as f32 * 0.37).sin())
            .collect();
        let grad: Vec<f32> = (0..n * spec.output_dim())
            .map(|i| {
                if i % 11 == 0 {
                    0.0
                } else {
                    (i as f32 * 0.91).cos()
                }
            })
            .collect();
        let mut table_grad = vec![0.0; table.len()];
        let mut points_grad = vec![0.0; 3 * n];
        cpu::table_grad(&p, &grad, &spec, &mut table_grad);
        cpu::points_grad(&p, &table, &grad, &spec, &mut points_grad);
        let mut fused_table = vec![0.0; table.len()];
        let mut fused_points = vec![1.0; 3 * n];
        cpu::grads(
            &p,
            &table,
            &grad,
            &spec,
            &mut fused_table,
            &mut fused_points,
        );
        assert_eq!(
            fused_table, table_grad,
            "F = {features}: same scatter order per level"
        );
        for (i, (a, b)) in fused_points.iter().zip(&points_grad).enumerate() {
            assert!(
                (a - b).abs() < 1e-5 * (1.0 + b.abs()),
                "F = {features}, d/dx {i}: fused {a}, separate {b}"
            );
        }
    }
}

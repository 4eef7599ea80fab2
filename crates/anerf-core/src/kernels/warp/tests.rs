use burn::prelude::*;
use glam::{Mat4, Vec3};

use super::reference::prior_softmax as prior_softmax_reference;
use super::*;
use crate::geometry::lbs::tests::{random_skeleton_and_pose, TestRng};
use crate::geometry::{BoneMatrices, BoneTransforms, CanonicalPose};
use crate::tensor::{from_rows, to_host};
use anerf_device::cpu_device;
use anerf_testing::{assert_close, Tolerance};

/// Values and input gradients of `Σ f(a, b) ⊙ c` for a fixed random `c` ([`objective_coefficients`]).
pub(super) struct Differentiated {
    pub value: Vec<f32>,
    pub grad_a: Vec<f32>,
    pub grad_b: Vec<f32>,
}

/// The fixed coefficients `c` of [`differentiate`]'s objective for an output of `len` values.
pub(super) fn objective_coefficients(len: usize) -> Vec<f32> {
    let mut rng = TestRng(99);
    (0..len).map(|_| rng.range(-1.0, 1.0)).collect()
}

/// `f` of `rows`-row inputs `a` and `b` on `device` (with autodiff), differentiated.
pub(super) fn differentiate(
    device: &Device,
    a: &[f32],
    b: &[f32],
    rows: usize,
    f: impl Fn(Tensor<2>, Tensor<2>) -> Tensor<2>,
) -> Differentiated {
    let device = device.clone().autodiff();
    let ta = from_rows(a, rows, a.len() / rows, &device).require_grad();
    let tb = from_rows(b, rows, b.len() / rows, &device).require_grad();
    let out = f(ta.clone(), tb.clone());
    let [_, cols] = out.dims();
    let coeff = objective_coefficients(rows * cols);
    let grads = (out.clone() * from_rows(&coeff, rows, cols, &device))
        .sum()
        .backward();
    Differentiated {
        value: to_host(out),
        grad_a: to_host(ta.grad(&grads).expect("a is tracked")),
        grad_b: to_host(tb.grad(&grads).expect("b is tracked")),
    }
}

pub(super) fn compare(what: &str, got: &Differentiated, expected: &Differentiated, tolerance: f32) {
    let tolerance = Tolerance::Relative(tolerance.into());
    assert_close(
        &format!("{what}: value"),
        &got.value,
        &expected.value,
        tolerance,
    );
    assert_close(
        &format!("{what}: first input's gradient"),
        &got.grad_a,
        &expected.grad_a,
        tolerance,
    );
    assert_close(
        &format!("{what}: second input's gradient"),
        &got.grad_b,
        &expected.grad_b,
        tolerance,
    );
}

/// Points and skinning-like weights for `n` samples of a random posed skeleton's 24 bones.
pub(super) fn skinning_inputs(seed: u64, n: usize) -> (BoneTransforms, Vec<f32>, Vec<f32>) {
    let mut rng = TestRng(seed);
    let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
    let bones = skeleton
        .bone_transforms(&pose, CanonicalPose::TPose)
        .expect("a valid pose");
    let points = (0..n).flat_map(|_| rng.vec3(1.0).to_array()).collect();
    let weights = (0..n).flat_map(|_| rng.weights(24)).collect();
    (bones, points, weights)
}

/// Inverse skinning on `device`, by the fused kernel or the tensor reference, differentiated.
pub(super) fn skinning(
    device: &Device,
    bones: &BoneTransforms,
    points: &[f32],
    weights: &[f32],
    fused: bool,
) -> Differentiated {
    let n = points.len() / 3;
    differentiate(device, points, weights, n, |p, w| {
        let matrices = BoneMatrices::new(bones, &p.device());
        assert!(
            crate::kernels::available(&p.device()),
            "the test device runs the kernels"
        );
        if fused {
            matrices.inverse(p, w)
        } else {
            reference::inverse_skinning(p, w, matrices.rows())
        }
    })
}

#[test]
fn inverse_skinning_matches_the_tensor_reference_in_value_and_gradients() {
    // More points than one kernel block, so that several rayon tasks split them.
    let (bones, points, weights) = skinning_inputs(21, 1_500);
    let got = skinning(&cpu_device(), &bones, &points, &weights, true);
    let expected = skinning(&cpu_device(), &bones, &points, &weights, false);
    compare("inverse skinning", &got, &expected, 2e-5);
}

/// The bones' gradient of the fused kernel (derived from the points' gradient) equals the tensor
/// reference's autodiff gradient, with the points' gradient alongside.
#[test]
fn inverse_skinning_passes_the_bones_their_gradient() {
    let (bones, points, weights) = skinning_inputs(23, 720);
    let rows: Vec<f32> = bones
        .matrices()
        .iter()
        .flat_map(|m| {
            let t = m.transpose().to_cols_array();
            t[..12].to_vec()
        })
        .collect();
    let n = points.len() / 3;
    let run = |fused: bool| {
        let device = cpu_device().autodiff();
        let w = from_rows(&weights, n, 24, &device);
        differentiate(&cpu_device(), &rows, &points, 24, |b, p| {
            let p = p.reshape([n, 3]);
            let matrices = BoneMatrices::from_rows(b);
            let out = if fused {
                matrices.inverse(p, w.clone())
            } else {
                reference::inverse_skinning(p, w.clone(), matrices.rows())
            };
            out.reshape([24, n * 3 / 24])
        })
    };
    compare("inverse skinning, bones", &run(true), &run(false), 5e-5);
}

/// Three bones, points and weights whose rows 0 and 1 blend a bone with its half-turn (a singular
/// rotation, guarded) and whose row 2 is an ordinary blend.
pub(super) fn singular_blends() -> (BoneTransforms, [f32; 9], [f32; 9]) {
    let bones = BoneTransforms::from_matrices(vec![
        Mat4::from_translation(Vec3::new(0.1, 0.0, 0.0)),
        Mat4::from_rotation_z(std::f32::consts::PI),
        Mat4::from_rotation_x(0.3),
    ])
    .expect("finite transforms");
    let points = [0.2, -0.4, 0.5, 1.0, 1.0, 1.0, -0.3, 0.1, 0.0];
    let weights = [0.5, 0.5, 0.0, 0.5, 0.5, 0.0, 0.2, 0.1, 0.7];
    (bones, points, weights)
}

/// Weights split between a bone and its half-turn leave a singular blended rotation: the guard replaces the
/// determinant, and neither implementation passes a gradient through the replaced value.
#[test]
fn guarded_singular_blends_match_the_reference() {
    let (bones, points, weights) = singular_blends();
    let got = skinning(&cpu_device(), &bones, &points, &weights, true);
    let expected = skinning(&cpu_device(), &bones, &points, &weights, false);
    assert!(got.value.iter().chain(&got.grad_b).all(|v| v.is_finite()));
    compare("guarded inverse skinning", &got, &expected, 2e-5);
}

pub(super) fn softmax_inputs(seed: u64, n: usize, k: usize) -> (Vec<f32>, Vec<f32>) {
    let mut rng = TestRng(seed);
    let mut prior: Vec<f32> = (0..n).flat_map(|_| rng.weights(k)).collect();
    // Exact zeros, as outside a joint's support: log(ε) must stay finite.
    prior.iter_mut().step_by(5).for_each(|w| *w = 0.0);
    let residual = (0..n * k).map(|_| rng.range(-3.0, 3.0)).collect();
    (prior, residual)
}

#[test]
fn prior_softmax_matches_the_tensor_reference_in_value_and_gradients() {
    let (n, k) = (1_200, 24);
    let (prior, residual) = softmax_inputs(7, n, k);
    let got = differentiate(&cpu_device(), &prior, &residual, n, prior_softmax);
    let expected = differentiate(&cpu_device(), &prior, &residual, n, prior_softmax_reference);
    for row in got.value.chunks_exact(k) {
        assert!(
            (row.iter().sum::<f32>() - 1.0).abs() < 1e-5,
            "rows sum to 1"
        );
    }
    // The prior's gradient is divided by w^s + 1e-9: relative to values up to 1e9.
    compare("prior softmax", &got, &expected, 2e-5);
}

//! The GPU backends (wgpu, and CUDA when compiled) against flex: an MLP forward and backward pass, tensor
//! skinning and the blend-weight volume lookup must give the same values and gradients on each.
//!
//! Compiled only with the `wgpu` feature: `cargo test -p anerf-core --features wgpu[,cuda] --test
//! gpu_backends` (add `-- --nocapture` to see the adapter and the differences). Each test first checks each
//! GPU backend in a child process (`anerf_device::probe`); where one does not work (not compiled, no
//! driver, or one that fails or crashes) it prints why and goes on with the others. Where the check passes, the comparison runs and must pass. On a machine
//! without a GPU, Mesa's lavapipe serves (docs/PERFORMANCE.md, "GPU backends"; `scripts/gpu/lavapipe.sh`).
//!
//! Tolerance: `|gpu − flex| ≤ 1e-4 · (1 + |flex|)` elementwise. Both compute in f32; they differ only in
//! the order of sums (matmul tiling, reductions), which for these sizes moves results by at most 2e-6 on
//! lavapipe (Mesa 22.3 and 25.0, Vulkan and OpenGL) and on an H200 through Vulkan. CUDA's matmuls run on
//! TF32 tensor cores, so results that pass through one are compared within `matmul_tolerance` (1e-2).

use anerf_core::geometry::skinning::points_tensor;
use anerf_core::geometry::BlendWeightVolume;
use anerf_core::geometry::{
    Aabb, BoneMatrices, BoneTransforms, CanonicalPose, GlobalTransform, Pose, Skeleton,
};
use anerf_core::model::codes::CodeRows;
use anerf_core::model::mlp::SkipMlpConfig;
use anerf_core::tensor::{parameter_gradients, to_host};
use anerf_device::cpu_device;
use anerf_device::testing::{gpu_devices_for_test, matmul_tolerance};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::Distribution;
use glam::Vec3;

/// Relative tolerance of the comparisons (see the module documentation).
const TOLERANCE: f64 = 1e-4;

/// Asserts `got` (GPU) `≈ expected` (flex) within [`TOLERANCE`].
fn assert_close(what: &str, got: &[f32], expected: &[f32]) {
    assert_close_within(what, got, expected, TOLERANCE);
}

/// Asserts `got` `≈ expected` within the relative `tolerance`.
fn assert_close_within(what: &str, got: &[f32], expected: &[f32], tolerance: f64) {
    anerf_testing::assert_close(
        what,
        got,
        expected,
        anerf_testing::Tolerance::Relative(tolerance),
    );
}

#[test]
fn mlp_forward_and_backward_match_flex() {
    for (choice, gpu) in gpu_devices_for_test("mlp_forward_and_backward_match_flex") {
        eprintln!("on {choice}");
        let flex = cpu_device().autodiff();
        flex.seed(11);
        // The NeRF trunk's shape at a smaller width: encoded input, a latent code, the input re-joined.
        let mlp = SkipMlpConfig {
            input: 27,
            conditioning: 16,
            width: 64,
            depth: 6,
            skip: Some(3),
        }
        .init(&flex);
        let input = Tensor::<2>::random([300, 27], Distribution::Normal(0.0, 1.0), &flex);
        let code = Tensor::<2>::random([1, 16], Distribution::Normal(0.0, 1.0), &flex);
        let mix = Tensor::<2>::random([300, 64], Distribution::Normal(0.0, 1.0), &flex);

        let run = |device: &Device| {
            let mlp = mlp.clone().fork(device);
            let codes = CodeRows::One(0).codes(code.clone().to_device(device));
            let out = mlp.forward(input.clone().to_device(device), Some(&codes));
            let loss = (out.clone() * mix.clone().to_device(device)).sum();
            let grads = GradientsParams::from_grads(loss.backward(), &mlp);
            (to_host(out), parameter_gradients(&mlp, &grads))
        };
        let (out_flex, grads_flex) = run(&flex);
        let (out_gpu, grads_gpu) = run(&gpu.autodiff());

        assert!(
            out_flex.iter().any(|v| *v > 0.1),
            "the MLP output is not all zero"
        );
        let tolerance = matmul_tolerance(choice, TOLERANCE);
        assert_close_within("MLP output", &out_gpu, &out_flex, tolerance);
        assert_eq!(grads_gpu.len(), grads_flex.len());
        for (i, (g, f)) in grads_gpu.iter().zip(&grads_flex).enumerate() {
            let (Some(g), Some(f)) = (g, f) else {
                panic!(
                    "parameter {i}: gradient on {choice}: {}, on flex: {}",
                    g.is_some(),
                    f.is_some()
                );
            };
            assert_close_within(&format!("gradient of parameter {i}"), g, f, tolerance);
        }
    }
}

/// A 4-joint chain (hip, spine, neck, leg) in a non-trivial pose: its bone transforms.
fn posed_bones() -> BoneTransforms {
    let joints = [
        [0.0, 0.0, 0.0],
        [0.0, 0.3, 0.0],
        [0.0, 0.6, 0.0],
        [0.1, -0.3, 0.0],
    ];
    let skeleton = Skeleton::from_parent_table(
        joints.iter().map(|j| Vec3::from(*j)).collect(),
        &[-1, 0, 1, 0],
    )
    .unwrap();
    let pose = Pose {
        joint_rotations: vec![
            Vec3::new(0.1, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 0.5),
            Vec3::new(0.3, -0.2, 0.0),
            Vec3::new(-0.4, 0.1, 0.2),
        ],
        global: GlobalTransform {
            rh: Vec3::ZERO,
            th: Vec3::ZERO,
        },
    };
    skeleton
        .bone_transforms(&pose, CanonicalPose::TPose)
        .unwrap()
}

#[test]
fn skinning_and_volume_lookup_match_flex() {
    for (choice, gpu) in gpu_devices_for_test("skinning_and_volume_lookup_match_flex") {
        eprintln!("on {choice}");
        let bones = posed_bones();
        // A 6×7×5 volume over the body's box with smooth, positive weights (rows sum to 1) and a distance.
        let bounds = Aabb {
            min: Vec3::new(-0.4, -0.6, -0.3),
            max: Vec3::new(0.4, 0.9, 0.3),
        };
        let volume = BlendWeightVolume::from_fn(bounds, [6, 7, 5], 4, |p| {
            let raw: Vec<f32> = (0..4)
                .map(|k| 1.5 + (3.0 * p.x + 2.0 * p.y * k as f32 - p.z).sin())
                .collect();
            let sum: f32 = raw.iter().sum();
            let mut values: Vec<f32> = raw.iter().map(|v| v / sum).collect();
            values.push(p.length());
            values
        })
        .unwrap();
        // Points inside and a few outside the box (border clamping), on a skewed grid.
        let points: Vec<Vec3> = (0..200)
            .map(|i| {
                let t = i as f32;
                Vec3::new(
                    0.5 * (0.37 * t).sin(),
                    -0.7 + 1.7 * ((0.11 * t).fract()),
                    0.35 * (0.23 * t).cos(),
                )
            })
            .collect();
        let mix = Tensor::<2>::random([200, 3], Distribution::Normal(0.0, 1.0), &cpu_device());

        let run = |device: &Device| {
            let p = points_tensor(&points, device).require_grad();
            let sample = volume.to_tensor(device).sample(p.clone());
            let bones = BoneMatrices::new(&bones, device);
            let canonical = bones.inverse(p.clone(), sample.weights.clone());
            let reposed = bones.forward(canonical.clone(), sample.weights.clone());
            let loss = (canonical.clone() * mix.clone().to_device(device)).sum()
                + sample.distance.clone().sum();
            let grad = p.grad(&loss.backward()).expect("points gradient");
            [
                to_host(sample.weights),
                to_host(sample.distance),
                to_host(canonical),
                to_host(reposed),
                to_host(grad),
            ]
        };
        let expected = run(&cpu_device().autodiff());
        let got = run(&gpu.autodiff());
        for (what, (g, e)) in [
            "weights",
            "distance",
            "inverse LBS",
            "forward LBS",
            "gradient",
        ]
        .iter()
        .zip(got.iter().zip(&expected))
        {
            // Forward LBS blends bone matrices with a matmul (TF32 on CUDA).
            let tolerance = if *what == "forward LBS" {
                matmul_tolerance(choice, TOLERANCE)
            } else {
                TOLERANCE
            };
            assert_close_within(what, g, e, tolerance);
        }
        // Forward ∘ inverse LBS is the identity: the flex reference itself is sound.
        let input: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
        assert_close("flex forward ∘ inverse", &expected[3], &input);
    }
}

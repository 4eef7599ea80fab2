//! One bake step's differentiable work without the data: `cargo bench -p anerf-core --bench splat_pipeline
//! [-- GAUSSIANS]`. A cloud of 50,000 (or `GAUSSIANS`) Gaussians in a body-sized box (metres, canonical
//! space), each skinned to four of 24 bones, seen by a 256 × 512 camera 3 m away (a training crop's size on
//! a 512² subject). Prints the median and range of the wall time of posing and projection, of the whole
//! render, each forward alone and forward with backward (the gradient of the sum of the outputs), on the
//! flex backend.

use anerf_core::gaussians::{project, render, GaussianCloud, SplatView};
use anerf_core::geometry::{
    BoneMatrices, BoneTransforms, Camera, GlobalTransform, PixelConvention,
};
use anerf_core::tensor::from_rows;
use anerf_device::cpu_device;
use anerf_testing::{report_ms, Xorshift};
use burn::prelude::*;
use glam::{Mat4, Quat, Vec3};

/// Timed calls per measurement, after one untimed call.
const REPEATS: usize = 9;
const BONES: usize = 24;

fn main() {
    let n: usize = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .map(|a| a.parse().expect("GAUSSIANS: a number of Gaussians"))
        .unwrap_or(50_000);
    let mut random = Xorshift::default();
    let mut uniform = move || random.uniform();
    let mut rows = |count: usize, width: usize, lo: f32, hi: f32| -> Vec<f32> {
        (0..count * width)
            .map(|_| lo + (hi - lo) * uniform())
            .collect()
    };
    let device = cpu_device();
    let mut means = rows(n, 3, -0.25, 0.25);
    for m in means.chunks_mut(3) {
        m[1] *= 3.0; // a standing body: 1.5 m tall, 0.5 m wide
    }
    let tensor = |v: &[f32], width: usize| from_rows(v, n, width, &device);
    let (log_scales, rotations, opacity, colours, skin) = (
        rows(n, 3, -5.5, -4.0),
        rows(n, 4, -1.0, 1.0),
        rows(n, 1, -1.0, 3.0),
        rows(n, 12, -0.3, 0.6),
        rows(n, BONES, 0.0, 1.0),
    );
    let mut sparse = vec![0.0f32; n * BONES];
    for (i, row) in skin.chunks(BONES).enumerate() {
        // The four largest of each row, normalised: a baked Gaussian's skin.
        let mut order: Vec<usize> = (0..BONES).collect();
        order.sort_by(|&a, &b| row[b].total_cmp(&row[a]));
        let sum: f32 = order[..4].iter().map(|&j| row[j]).sum();
        for &j in &order[..4] {
            sparse[i * BONES + j] = row[j] / sum;
        }
    }
    let cloud = GaussianCloud::new(
        tensor(&means, 3),
        tensor(&log_scales, 3),
        tensor(&rotations, 4),
        tensor(&opacity, 1),
        tensor(&colours, 12),
    );
    let weights = from_rows(&sparse, n, BONES, &device);
    let turns: Vec<Mat4> = (0..BONES)
        .map(|j| {
            let angle = 0.05 * j as f32;
            Mat4::from_rotation_translation(
                Quat::from_axis_angle(Vec3::new(1.0, 1.0, 0.0).normalize(), angle),
                Vec3::new(0.0, 0.01 * j as f32, 0.0),
            )
        })
        .collect();
    let bones = BoneMatrices::new(&BoneTransforms::from_matrices(turns).unwrap(), &device);
    let camera = Camera::from_rows(
        [[600.0, 0.0, 128.0], [0.0, 600.0, 256.0], [0.0, 0.0, 1.0]],
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0, 0.0, 3.0],
        [0.0; 5],
        256,
        512,
    )
    .unwrap();
    let global = GlobalTransform::default();
    let view = SplatView {
        camera: &camera,
        global: &global,
        convention: PixelConvention::Integer,
    };
    println!(
        "{n} Gaussians, {BONES} bones, 256 x 512 pixels, {} threads",
        rayon::current_num_threads()
    );
    let tracked = || {
        let v = |p: &burn::module::Param<Tensor<2>>| p.val().autodiff().require_grad();
        GaussianCloud::new(
            v(&cloud.means),
            v(&cloud.log_scales),
            v(&cloud.rotations),
            v(&cloud.opacity_logits),
            v(&cloud.colours),
        )
    };
    report_ms("project", REPEATS, || {
        let rows = project(&cloud, weights.clone(), &bones, &view);
        let _: f32 = rows.sum().into_scalar();
    });
    report_ms("project + backward", REPEATS, || {
        let cloud = tracked();
        let rows = project(&cloud, weights.clone().autodiff(), &bones, &view);
        let _ = rows.sum().backward();
    });
    report_ms("render", REPEATS, || {
        let image = render(&cloud, weights.clone(), &bones, &view);
        let _: f32 = image.sum().into_scalar();
    });
    report_ms("render + backward", REPEATS, || {
        let cloud = tracked();
        let image = render(&cloud, weights.clone().autodiff(), &bones, &view);
        let _ = image.sum().backward();
    });
}

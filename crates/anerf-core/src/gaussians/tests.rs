//! Posing and projection against glam's skinning and camera (means, covariances by a finite-difference
//! Jacobian, canonical view directions), a rendered Gaussian against its closed form, and the whole
//! pipeline's gradients against central differences.

use burn::prelude::*;
use glam::{Mat3, Quat, Vec3};

use super::*;
use crate::geometry::lbs::tests::{random_skeleton_and_pose, TestRng};
use crate::geometry::{
    forward_lbs_point, BoneMatrices, BoneTransforms, Camera, CanonicalPose, Distortion,
    GlobalTransform, PixelConvention,
};
use crate::kernels::splat::PIXEL_WIDTH;
use crate::tensor::{from_rows, to_host};
use anerf_device::cpu_device;

/// Host values of a cloud, one row per Gaussian.
#[derive(Debug, Clone)]
struct Host {
    means: Vec<Vec3>,
    log_scales: Vec<Vec3>,
    rotations: Vec<Quat>,
    opacity_logits: Vec<f32>,
    colours: Vec<Vec<f32>>,
}

impl Host {
    fn random(rng: &mut TestRng, n: usize, degree: usize) -> Self {
        let width = 3 * sh::coefficients(degree);
        Self {
            means: (0..n).map(|_| rng.vec3(0.8)).collect(),
            log_scales: (0..n)
                .map(|_| {
                    Vec3::new(
                        rng.range(-4.0, -2.0),
                        rng.range(-4.0, -2.0),
                        rng.range(-4.0, -2.0),
                    )
                })
                .collect(),
            rotations: (0..n)
                .map(|_| {
                    Quat::from_xyzw(
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                        rng.range(0.2, 1.0),
                    )
                })
                .collect(),
            opacity_logits: (0..n).map(|_| rng.range(-1.0, 1.0)).collect(),
            colours: (0..n)
                .map(|_| {
                    (0..width)
                        .map(|i| {
                            if i < 3 {
                                rng.range(0.0, 1.0)
                            } else {
                                rng.range(-0.3, 0.3)
                            }
                        })
                        .collect()
                })
                .collect(),
        }
    }

    fn cloud(&self, device: &Device) -> GaussianCloud {
        let n = self.means.len();
        let flat3 = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<_>>();
        // Quaternions as (w, x, y, z).
        let quats: Vec<f32> = self
            .rotations
            .iter()
            .flat_map(|q| [q.w, q.x, q.y, q.z])
            .collect();
        let colours: Vec<f32> = self.colours.iter().flatten().copied().collect();
        GaussianCloud::new(
            from_rows(&flat3(&self.means), n, 3, device),
            from_rows(&flat3(&self.log_scales), n, 3, device),
            from_rows(&quats, n, 4, device),
            from_rows(&self.opacity_logits, n, 1, device),
            from_rows(&colours, n, self.colours[0].len(), device),
        )
    }

    /// Canonical covariance of Gaussian `i`, `R S² Rᵀ`.
    fn covariance(&self, i: usize) -> Mat3 {
        let r = Mat3::from_quat(self.rotations[i].normalize());
        let s = Mat3::from_diagonal(self.log_scales[i].exp());
        r * s * s * r.transpose()
    }
}

/// A camera `distance` metres in front of `target` (world), looking at it along its own `+z`, turned by
/// `turn` radians about the world's `y`.
fn camera(target: Vec3, distance: f32, turn: f32, k: [[f32; 3]; 3], size: (u32, u32)) -> Camera {
    let rotation = Mat3::from_rotation_y(turn);
    Camera {
        intrinsics: Mat3::from_cols_array_2d(&k).transpose(),
        rotation,
        translation: Vec3::new(0.0, 0.0, distance) - rotation * target,
        distortion: Distortion::default(),
        width: size.0,
        height: size.1,
    }
}

struct Scene {
    host: Host,
    weights: Vec<Vec<f32>>,
    bones: BoneTransforms,
    global: GlobalTransform,
    camera: Camera,
}

fn scene(seed: u64, n: usize, degree: usize) -> Scene {
    let mut rng = TestRng(seed);
    let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
    let bones = skeleton
        .bone_transforms(&pose, CanonicalPose::TPose)
        .unwrap();
    let host = Host::random(&mut rng, n, degree);
    let weights = (0..n).map(|_| rng.weights(24)).collect();
    let target = pose.global.rotation() * Vec3::ZERO + pose.global.th;
    let k = [[300.0, 4.0, 256.0], [0.0, 310.0, 192.0], [0.0, 0.0, 1.0]];
    Scene {
        host,
        weights,
        bones,
        camera: camera(target, 6.0, 0.4, k, (512, 384)),
        global: pose.global,
    }
}

impl Scene {
    fn project(&self, convention: PixelConvention) -> Vec<f32> {
        let device = cpu_device();
        let view = SplatView {
            camera: &self.camera,
            global: &self.global,
            convention,
        };
        let flat: Vec<f32> = self.weights.iter().flatten().copied().collect();
        let w = from_rows(&flat, self.weights.len(), 24, &device);
        to_host(project(
            &self.host.cloud(&device),
            w,
            &BoneMatrices::new(&self.bones, &device),
            &view,
        ))
    }

    /// Canonical point → world, by glam.
    fn to_world(&self, i: usize, x: Vec3) -> Vec3 {
        let posed = forward_lbs_point(x, &self.weights[i], &self.bones).unwrap();
        self.global.rotation() * posed + self.global.th
    }
}

#[test]
fn means_land_where_the_camera_projects_their_skinned_centres() {
    let s = scene(3, 40, 0);
    for convention in [PixelConvention::Integer, PixelConvention::Center] {
        let rows = s.project(convention);
        for (i, row) in rows.chunks(10).enumerate() {
            let expected = s
                .camera
                .project(s.to_world(i, s.host.means[i]), convention)
                .unwrap();
            assert!(
                (row[0] - expected.x).abs() < 2e-3 && (row[1] - expected.y).abs() < 2e-3,
                "Gaussian {i}: ({}, {}) vs {expected}",
                row[0],
                row[1]
            );
            let depth = s.camera.world_to_camera(s.to_world(i, s.host.means[i])).z;
            assert!((row[9] - depth).abs() < 1e-4);
        }
    }
}

/// `Σ₂ = J Σ Jᵀ + DILATION·I`, with `J` the Jacobian of canonical point → pixel (skinning, global transform
/// and camera together) by central differences of glam's functions.
#[test]
fn covariances_project_through_the_jacobian_of_the_whole_chain() {
    let s = scene(5, 30, 0);
    let rows = s.project(PixelConvention::Integer);
    // The projection bends over metres, so a centimetre's step is exact to about 1e-5; f32 pixels.
    let h = 1e-2;
    for (i, row) in rows.chunks(10).enumerate() {
        let pixel = |x: Vec3| {
            s.camera
                .project(s.to_world(i, x), PixelConvention::Integer)
                .unwrap()
        };
        let mut j = [[0.0f32; 3]; 2];
        for (a, axis) in [Vec3::X, Vec3::Y, Vec3::Z].into_iter().enumerate() {
            let m = s.host.means[i];
            let d = (pixel(m + axis * h) - pixel(m - axis * h)) / (2.0 * h);
            j[0][a] = d.x;
            j[1][a] = d.y;
        }
        let sigma = s.host.covariance(i);
        let sandwich = |r: usize, c: usize| {
            (0..3)
                .map(|p| {
                    (0..3)
                        .map(|q| j[r][p] * sigma.col(q)[p] * j[c][q])
                        .sum::<f32>()
                })
                .sum::<f32>()
        };
        let expected = [
            sandwich(0, 0) + projection_dilation(),
            sandwich(0, 1),
            sandwich(1, 1) + projection_dilation(),
        ];
        let [a, b, c] = [row[2], row[3], row[4]];
        let det = a * c - b * b;
        let got = [c / det, -b / det, a / det];
        let scale = 1.0 + expected[0] + expected[2];
        for (g, e) in got.iter().zip(expected) {
            assert!(
                (g - e).abs() < 1e-3 * scale,
                "Gaussian {i}: {got:?} vs {expected:?}"
            );
        }
    }
}

fn projection_dilation() -> f32 {
    project::DILATION
}

/// Degree-1 colours depend on the view direction in canonical space: one rigid bone turned by 90°, the
/// colour is the harmonics' of the direction turned back.
#[test]
fn colours_follow_the_view_direction_in_canonical_space() {
    let mut s = scene(9, 12, 1);
    let turn = glam::Mat4::from_rotation_translation(
        Quat::from_rotation_z(std::f32::consts::FRAC_PI_2),
        Vec3::new(0.1, -0.2, 0.3),
    );
    s.bones = BoneTransforms::from_matrices(vec![turn; 24]).unwrap();
    let rows = s.project(PixelConvention::Integer);
    let eye = s.global.world_to_pose(s.camera.center());
    for (i, row) in rows.chunks(10).enumerate() {
        let posed = turn.transform_point3(s.host.means[i]);
        let dir = (turn.inverse().transform_vector3(posed - eye)).normalize();
        let k = &s.host.colours[i];
        for ch in 0..3 {
            let expected = (0.5
                + sh::C0 * k[ch]
                + sh::C1 * (-dir.y * k[3 + ch] + dir.z * k[6 + ch] - dir.x * k[9 + ch]))
                .max(0.0);
            assert!((row[5 + ch] - expected).abs() < 1e-5, "Gaussian {i}");
        }
    }
}

#[test]
fn gaussians_behind_the_camera_are_transparent() {
    let mut s = scene(13, 20, 0);
    // Half of the cloud ends up behind the camera once it sits among the points.
    s.camera = camera(
        s.to_world(0, Vec3::ZERO),
        0.0,
        0.0,
        [[300.0, 0.0, 256.0], [0.0, 300.0, 192.0], [0.0, 0.0, 1.0]],
        (512, 384),
    );
    let rows = s.project(PixelConvention::Integer);
    let mut behind = 0;
    for (i, row) in rows.chunks(10).enumerate() {
        let z = s.camera.world_to_camera(s.to_world(i, s.host.means[i])).z;
        let opacity = 1.0 / (1.0 + (-s.host.opacity_logits[i]).exp());
        let expected = if z > project::NEAR { opacity } else { 0.0 };
        behind += usize::from(z <= project::NEAR);
        assert!(
            (row[8] - expected).abs() < 1e-6,
            "Gaussian {i} at depth {z}"
        );
        assert!(row.iter().all(|v| v.is_finite()), "Gaussian {i}: {row:?}");
    }
    assert!(behind > 0 && behind < 20, "{behind} behind");
}

/// One round Gaussian on the optical axis: a splat of standard deviation `f·σ/D` widened by the dilation,
/// peaked at the principal point with the Gaussian's opacity.
#[test]
fn a_rendered_gaussian_is_its_closed_form() {
    let device = cpu_device();
    let (sigma, distance, f, logit) = (0.05f32, 2.0f32, 200.0f32, 1.0f32);
    let colour = [0.9f32, 0.2, 0.4];
    let k0: Vec<f32> = colour.iter().map(|c| (c - 0.5) / sh::C0).collect();
    let cloud = GaussianCloud::new(
        from_rows(&[0.0, 0.0, 0.0], 1, 3, &device),
        from_rows(&[sigma.ln(); 3], 1, 3, &device),
        from_rows(&[1.0, 0.0, 0.0, 0.0], 1, 4, &device),
        from_rows(&[logit], 1, 1, &device),
        from_rows(&k0, 1, 3, &device),
    );
    let cam = camera(
        Vec3::ZERO,
        distance,
        0.0,
        [[f, 0.0, 32.0], [0.0, f, 24.0], [0.0, 0.0, 1.0]],
        (64, 48),
    );
    let global = GlobalTransform::default();
    let bones = BoneTransforms::from_matrices(vec![glam::Mat4::IDENTITY]).unwrap();
    let view = SplatView {
        camera: &cam,
        global: &global,
        convention: PixelConvention::Integer,
    };
    let image = to_host(render(
        &cloud,
        Tensor::ones([1, 1], &device),
        &BoneMatrices::new(&bones, &device),
        &view,
    ));
    let opacity = 1.0 / (1.0 + (-logit).exp());
    let variance = (f * sigma / distance).powi(2) + project::DILATION;
    for (i, pixel) in image.chunks(PIXEL_WIDTH).enumerate() {
        let (dx, dy) = ((i % 64) as f32 - 32.0, (i / 64) as f32 - 24.0);
        let alpha = opacity * (-(dx * dx + dy * dy) / (2.0 * variance)).exp();
        let alpha = if alpha < crate::kernels::splat::ALPHA_MIN {
            0.0
        } else {
            alpha
        };
        let expected = [
            alpha * colour[0],
            alpha * colour[1],
            alpha * colour[2],
            alpha,
        ];
        for (g, e) in pixel.iter().zip(expected) {
            assert!(
                (g - e).abs() < 1e-5,
                "pixel ({dx}, {dy}): {pixel:?} vs {expected:?}"
            );
        }
    }
}

/// The whole pipeline (skinning, projection, harmonics, rasteriser) against central differences of every
/// value of two Gaussians, in a scene where their splats cover the whole image (no cut-off crossed).
#[test]
fn pipeline_gradients_match_central_differences() {
    let device = cpu_device().autodiff();
    let mut rng = TestRng(21);
    let mut host = Host::random(&mut rng, 2, 1);
    host.log_scales = vec![Vec3::new(-1.2, -1.1, -1.3), Vec3::new(-1.1, -1.3, -1.2)];
    host.means = vec![Vec3::new(0.02, -0.03, 0.0), Vec3::new(-0.04, 0.02, 0.1)];
    host.opacity_logits = vec![-0.5, 0.3];
    let (skeleton, pose) = random_skeleton_and_pose(&mut rng);
    let bones = skeleton
        .bone_transforms(&pose, CanonicalPose::TPose)
        .unwrap();
    let weights: Vec<Vec<f32>> = (0..2).map(|_| rng.weights(24)).collect();
    let target = forward_lbs_point(host.means[0], &weights[0], &bones).unwrap();
    let target = pose.global.rotation() * target + pose.global.th;
    let cam = camera(
        target,
        2.0,
        0.3,
        [[40.0, 0.0, 8.0], [0.0, 40.0, 6.0], [0.0, 0.0, 1.0]],
        (16, 12),
    );
    let view = SplatView {
        camera: &cam,
        global: &pose.global,
        convention: PixelConvention::Integer,
    };
    let pixel_weights: Vec<f32> = (0..16 * 12 * PIXEL_WIDTH)
        .map(|i| ((i * 7919) % 1000) as f32 / 500.0 - 1.0)
        .collect();
    let flat_w: Vec<f32> = weights.iter().flatten().copied().collect();
    let objective = |host: &Host, device: &Device| {
        let cloud = host.cloud(device);
        let image = render(
            &cloud,
            from_rows(&flat_w, 2, 24, device),
            &BoneMatrices::new(&bones, device),
            &view,
        );
        let loss = (image * from_rows(&pixel_weights, 16 * 12, PIXEL_WIDTH, device)).sum();
        (cloud, loss)
    };
    let (cloud, loss) = objective(&host, &device);
    let grads = loss.backward();
    let grad =
        |p: &burn::module::Param<Tensor<2>>| to_host(p.val().grad(&grads).expect("gradient"));
    let analytic = [
        grad(&cloud.means),
        grad(&cloud.log_scales),
        grad(&cloud.rotations),
        grad(&cloud.opacity_logits),
        grad(&cloud.colours),
    ];
    let plain = cpu_device();
    let value = |h: &Host| objective(h, &plain).1.into_scalar::<f32>() as f64;
    let step = 1e-3;
    for (field, g) in analytic.iter().enumerate() {
        for (j, &a) in g.iter().enumerate() {
            let nudge = |delta: f32| {
                let mut h = host.clone();
                match field {
                    0 => h.means[j / 3][j % 3] += delta,
                    1 => h.log_scales[j / 3][j % 3] += delta,
                    2 => {
                        let q = &mut h.rotations[j / 4];
                        let mut v = [q.w, q.x, q.y, q.z];
                        v[j % 4] += delta;
                        *q = Quat::from_xyzw(v[1], v[2], v[3], v[0]);
                    }
                    3 => h.opacity_logits[j] += delta,
                    _ => h.colours[j / 12][j % 12] += delta,
                }
                value(&h)
            };
            let numeric = (nudge(step) - nudge(-step)) / (2.0 * step as f64);
            assert!(
                (numeric - a as f64).abs() < 3e-2 * (1.0 + numeric.abs()),
                "field {field} value {j}: numeric {numeric}, autodiff {a}"
            );
        }
    }
}

/// The host projection gives the tensor projection's rows, for Gaussians skinned by four joints each, in
/// both pixel conventions and with harmonics of degree 1.
#[test]
fn host_projection_matches_the_tensor_projection() {
    let mut s = scene(11, 60, 1);
    let mut joints = Vec::new();
    let mut weights = Vec::new();
    for w in &mut s.weights {
        let mut order: Vec<usize> = (0..w.len()).collect();
        order.sort_by(|&a, &b| w[b].total_cmp(&w[a]));
        let top: [usize; 4] = [order[0], order[1], order[2], order[3]];
        let sum: f32 = top.iter().map(|&j| w[j]).sum();
        let kept = top.map(|j| w[j] / sum);
        w.iter_mut().for_each(|v| *v = 0.0);
        for (&j, &v) in top.iter().zip(&kept) {
            w[j] = v;
        }
        joints.push(top.map(|j| j as u16));
        weights.push(kept);
    }
    let h = &s.host;
    let means: Vec<[f32; 3]> = h.means.iter().map(|v| v.to_array()).collect();
    let log_scales: Vec<[f32; 3]> = h.log_scales.iter().map(|v| v.to_array()).collect();
    let rotations: Vec<[f32; 4]> = h.rotations.iter().map(|q| [q.w, q.x, q.y, q.z]).collect();
    let colours: Vec<f32> = h.colours.iter().flatten().copied().collect();
    let cloud = HostCloud {
        splats: Splats {
            means: &means,
            log_scales: &log_scales,
            rotations: &rotations,
            opacity_logits: &h.opacity_logits,
            colours: &colours,
        },
        skin_joints: &joints,
        skin_weights: &weights,
    };
    for convention in [PixelConvention::Integer, PixelConvention::Center] {
        let tensor = s.project(convention);
        let view = SplatView {
            camera: &s.camera,
            global: &s.global,
            convention,
        };
        let host = project_host(&cloud, &s.bones, &view);
        assert_eq!(host.len(), tensor.len());
        for (i, (a, b)) in host.iter().zip(&tensor).enumerate() {
            assert!(
                (a - b).abs() <= 1e-4 * (1.0 + b.abs()),
                "Gaussian {} value {}: host {a}, tensor {b}",
                i / 10,
                i % 10
            );
        }
    }
}

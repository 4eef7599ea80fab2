//! Tests of the composed model on a small analytic scene: a 4-joint body whose prior weights and distance
//! to the body come from closed-form fields sampled onto volumes.

use burn::module::{ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::optim::GradientsParams;
use burn::prelude::*;
use glam::Vec3;

use super::culling::{cull_on_device, cull_samples, pose_samples, CorrectionWarp, SampleRays};
use super::*;
use crate::geometry::skinning::{points_tensor, BoneMatrices};
use crate::geometry::BlendWeightVolume;
use crate::geometry::{
    inverse_lbs_point, Aabb, Camera, CanonicalPose, GlobalTransform, Pose, PoseBasis, Skeleton,
};
use crate::model::{OccupancyConfig, OccupancyGrid};
use crate::render::{color_mse, composite, stratified_depths, HostRays, RayBatch};
use crate::tensor::{from_rows, parameter_gradients, to_host};
use crate::FrameId;
use anerf_device::cpu_device;

const JOINTS: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [0.0, 0.3, 0.0],
    [0.0, 0.6, 0.0],
    [0.0, -0.3, 0.0],
];

/// Prior weights (a softmax of squared distances to the joints) and the distance outside an ellipsoid.
fn analytic_node(p: Vec3) -> Vec<f32> {
    let logits: Vec<f32> = JOINTS
        .iter()
        .map(|j| -(p - Vec3::from(*j)).length_squared() / 0.05)
        .collect();
    let max = logits.iter().cloned().fold(f32::MIN, f32::max);
    let e: Vec<f32> = logits.iter().map(|l| (l - max).exp()).collect();
    let s: f32 = e.iter().sum();
    let mut out: Vec<f32> = e.iter().map(|v| v / s).collect();
    let q = (p - Vec3::new(0.0, 0.15, 0.0)) / Vec3::new(0.2, 0.45, 0.15);
    out.push(((q.length() - 1.0) * 0.15).max(0.0));
    out
}

fn analytic_volume(bounds: Aabb) -> BlendWeightVolume {
    BlendWeightVolume::from_fn(bounds, [9, 13, 7], 4, analytic_node).unwrap()
}

pub(crate) struct Scene {
    pub frame: FrameInputs,
    pub canonical: CanonicalInputs,
    pub rays: RayBatch,
    /// The same rays on the host.
    pub host_rays: HostRays,
    pub host_volume: BlendWeightVolume,
    pub bones: crate::geometry::BoneTransforms,
    /// The frame's given fit, for models that refine it.
    pub basis: PoseBasis,
    pub pose: Pose,
}

fn scene(device: &Device, code: FrameCode) -> Scene {
    let skeleton = Skeleton::from_parent_table(
        JOINTS.iter().map(|j| Vec3::from(*j)).collect(),
        &[-1, 0, 1, 0],
    )
    .unwrap();
    let pose = Pose {
        joint_rotations: vec![
            Vec3::ZERO,
            Vec3::new(0.0, 0.0, 0.4),
            Vec3::new(0.3, 0.0, 0.0),
            Vec3::new(-0.2, 0.1, 0.0),
        ],
        global: GlobalTransform {
            rh: Vec3::new(0.0, 0.3, 0.0),
            th: Vec3::new(0.1, 0.0, -0.1),
        },
    };
    let bones = skeleton
        .bone_transforms(&pose, CanonicalPose::TPose)
        .unwrap();
    let body = Aabb {
        min: Vec3::new(-0.4, -0.6, -0.3),
        max: Vec3::new(0.4, 0.9, 0.3),
    };
    let host_volume = analytic_volume(body);
    let frame = FrameInputs {
        bones: BoneMatrices::new(&bones, device),
        global: pose.global,
        volume: host_volume.to_tensor(device),
        code,
        appearance: 1,
        basis: None,
        warp: None,
    };
    let canonical = CanonicalInputs {
        volume: host_volume.to_tensor(device),
        bounds: body.padded(-0.05),
    };
    // An 8×8 image of a camera 2.5 m in front of the body (1 m field of view there), rays clipped to the
    // world box.
    let camera = Camera::from_rows(
        [[20.0, 0.0, 3.5], [0.0, 20.0, 3.5], [0.0, 0.0, 1.0]],
        [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0, 0.15, 2.5],
        [0.0; 5],
        8,
        8,
    )
    .unwrap();
    let world_box = Aabb {
        min: body.min + pose.global.th - 0.2,
        max: body.max + pose.global.th + 0.2,
    };
    let (mut host, _) = HostRays::from_rays(&camera.image_rays(Default::default()), &world_box);
    host.colors = (0..host.len())
        .map(|i| [0.1 * (i % 7) as f32, 0.5, 0.9 - 0.05 * (i % 5) as f32])
        .collect();
    let rays = RayBatch::new(&host, FrameId(1), device);
    Scene {
        frame,
        canonical,
        rays,
        host_rays: host,
        host_volume,
        bones,
        basis: PoseBasis::new(&skeleton, &pose, CanonicalPose::TPose, device),
        pose,
    }
}

/// A tiny model whose raw density is shifted up by 2 (through the bias of the one-output density head) so
/// that the untrained field is visible: at PyTorch's initialisation the density is mostly negative.
fn tiny_model(device: &Device) -> AnimatableNerf {
    tiny_model_with(ModelPreset::Tiny.config(), device)
}

/// The tiny preset with a zero residual head.
fn zero_residual() -> ModelConfig {
    ModelConfig {
        residual_init: ResidualInit::Zero,
        ..ModelPreset::Tiny.config()
    }
}

/// [`tiny_model`] from `config` (12 samples per ray).
fn tiny_model_with(config: ModelConfig, device: &Device) -> AnimatableNerf {
    shifted_model(config, device, 2.0, 12)
}

/// A model of `config` with its raw density shifted up by `shift` (per metre), `samples` per ray.
fn shifted_model(
    config: ModelConfig,
    device: &Device,
    shift: f32,
    samples: usize,
) -> AnimatableNerf {
    lift_density(new_model(config, device, samples), shift)
}

/// What the test models are built for: the scene's 3 training frames and 4 joints.
const SIZES: ModelSizes = ModelSizes {
    training_frames: 3,
    joints: 4,
};

/// A fresh model of `config` with `samples` per ray.
fn new_model(mut config: ModelConfig, device: &Device, samples: usize) -> AnimatableNerf {
    config.samples_per_ray = samples;
    AnimatableNerf::new(&config, SIZES, device)
}

/// `model` with its raw density shifted up by `shift` (per metre), through the bias of the one-output
/// density head.
fn lift_density(model: AnimatableNerf, shift: f32) -> AnimatableNerf {
    let mut list = ParamList(Vec::new());
    model.nerf.visit(&mut list);
    let density_bias = list
        .0
        .iter()
        .find(|p| p.1 == 1)
        .expect("the density head's bias")
        .0;
    model.map(&mut Nudge {
        target: density_bias,
        index: 0,
        delta: shift,
    })
}

/// A model of `config` (12 samples per ray) whose fields hold values drawn from `seed`'s own stream (the
/// device's is shared with the tests running at the same time), its density lifted by 2 as [`tiny_model`]'s
/// is, and its pose corrections (if any) zero.
fn seeded_model(config: ModelConfig, device: &Device, seed: u64) -> AnimatableNerf {
    let refinement = config.pose_refinement;
    let seeded =
        new_model(config, device, 12).map(&mut Seeded(rand::SeedableRng::seed_from_u64(seed)));
    let mut model = lift_density(seeded, 2.0);
    if refinement.enabled {
        model.pose = Some(PoseRefinement::new(
            refinement,
            SIZES.training_frames,
            SIZES.joints,
            device,
        ));
    }
    model
}

/// How many float parameters of `module` received a non-zero gradient, and how many there are.
fn params_with_gradient<M: Module>(module: &M, grads: &GradientsParams) -> (usize, usize) {
    let all = parameter_gradients(module, grads);
    let with = all
        .iter()
        .filter(|g| g.as_ref().is_some_and(|g| g.iter().any(|v| *v != 0.0)))
        .count();
    (with, all.len())
}

#[test]
fn stage1_gradients_reach_every_parameter() {
    let device = cpu_device().autodiff();
    device.seed(1);
    let s = scene(&device, FrameCode::Training(1));
    let model = tiny_model(&device);
    let out = model.render(&s.rays, &s.frame, &s.canonical, None, true);
    assert!(out.surviving_samples > 0 && out.surviving_samples < out.total_samples);
    let loss = color_mse(out.rgb, s.rays.colors.clone().unwrap())
        + out.consistency.unwrap().loss(model.config().consistency);
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    let (with, total) = params_with_gradient(&model, &grads);
    assert_eq!(
        with, total,
        "{with} of {total} parameters received a non-zero gradient"
    );
}

#[test]
fn stage2_trains_only_the_novel_field() {
    let device = cpu_device().autodiff();
    device.seed(2);
    let s = scene(&device, FrameCode::Novel(1));
    // A random head on the novel field, so that its trunk's gradient is non-zero at the first step too
    // (with the default zero head only the head learns at first).
    let config = ModelConfig {
        novel_residual_init: ResidualInit::Random,
        ..ModelPreset::Tiny.config()
    };
    let model = tiny_model_with(config, &device).with_novel_field(2, &device);
    let pose_points = points_tensor(
        &grid_points(Vec3::new(-0.3, -0.5, -0.2), Vec3::new(0.3, 0.8, 0.2)),
        &device,
    );
    let can_points = points_tensor(
        &grid_points(s.canonical.bounds.min, s.canonical.bounds.max),
        &device,
    );
    let loss = model
        .stage2_terms(&s.frame, &s.canonical, pose_points, can_points)
        .consistency();
    assert!(to_host(loss.clone())[0] > 0.0);
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    let (nerf, nerf_total) = params_with_gradient(&model.nerf, &grads);
    let (blend, _) = params_with_gradient(&model.blend, &grads);
    assert_eq!(
        (nerf, blend),
        (0, 0),
        "frozen stage-1 parameters received gradients"
    );
    assert!(nerf_total > 0);
    let novel = model.novel_blend.as_ref().unwrap();
    let (with, total) = params_with_gradient(novel, &grads);
    assert_eq!(
        with, total,
        "{with} of {total} novel-field parameters received a gradient"
    );
}

fn grid_points(min: Vec3, max: Vec3) -> Vec<Vec3> {
    let n = 6;
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let t = Vec3::new(i as f32, j as f32, k as f32) / (n - 1) as f32;
                out.push(min + (max - min) * t);
            }
        }
    }
    out
}

#[test]
fn without_residual_the_warp_is_inverse_lbs_with_the_prior_weights() {
    let device = cpu_device();
    let mut s = scene(&device, FrameCode::Training(0));
    s.frame.appearance = 0;
    let mut config = ModelPreset::Tiny.config();
    config.neural_blend_weights = false;
    let model = AnimatableNerf::new(
        &config,
        ModelSizes {
            training_frames: 1,
            joints: 4,
        },
        &device,
    );
    let pts = grid_points(Vec3::new(-0.3, -0.5, -0.2), Vec3::new(0.3, 0.8, 0.2));
    let p = points_tensor(&pts, &device);
    let prior = s.frame.volume.sample(p.clone()).weights;
    let shaded = model.shade(p.clone(), prior, p, &s.frame, &s.canonical);
    let got = to_host(shaded.canonical_points);
    for (i, x) in pts.iter().enumerate() {
        let w = s.host_volume.sample(*x);
        let sum: f32 = w[..4].iter().sum();
        let w: Vec<f32> = w[..4].iter().map(|v| v / sum).collect();
        let expect = inverse_lbs_point(*x, &w, &s.bones).unwrap();
        assert!(
            (Vec3::from_slice(&got[3 * i..3 * i + 3]) - expect).length() < 1e-4,
            "{x}"
        );
    }
}

/// Every sample of the scene's rays shaded without culling: the samples, which of them lie at least
/// `cull_distance` from the body (`[R·S, 1]`), and the depths `[R, S]`.
fn shade_every_sample(
    model: &AnimatableNerf,
    s: &Scene,
) -> (ShadedSamples, Tensor<2, Bool>, Tensor<2>) {
    let samples = model.config().samples_per_ray;
    let r = s.rays.len();
    let depths = stratified_depths(s.rays.near.clone(), s.rays.far.clone(), samples, None);
    let pose = pose_samples(&s.rays, depths.clone(), &s.frame.global);
    let dirs = s
        .rays
        .directions
        .clone()
        .unsqueeze_dim::<3>(1)
        .repeat_dim(1, samples)
        .reshape([r * samples, 3]);
    let prior = s.frame.volume.sample(pose.clone());
    let far = prior
        .distance
        .clone()
        .greater_equal_elem(model.config().cull_distance);
    let shaded = model.shade(pose, prior.weights, dirs, &s.frame, &s.canonical);
    (shaded, far, depths)
}

#[test]
fn culling_matches_evaluating_every_sample_and_zeroing_the_far_ones() {
    let device = cpu_device();
    device.seed(3);
    let s = scene(&device, FrameCode::Training(2));
    let model = tiny_model(&device);
    let culled = model.render(&s.rays, &s.frame, &s.canonical, None, false);

    // Reference: shade all samples, then zero the density of those ≥ cull_distance from the body.
    let (samples, r) = (model.config().samples_per_ray, s.rays.len());
    let (shaded, far, depths) = shade_every_sample(&model, &s);
    let density = shaded.density.mask_fill(far, 0.0).reshape([r, samples]);
    let all = composite(density, shaded.rgb.reshape([r, samples, 3]), depths);

    let (a, b) = (to_host(culled.rgb), to_host(all.rgb));
    assert!(
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5),
        "{a:?}\n{b:?}"
    );
    assert!(b.iter().any(|v| *v > 1e-3), "the scene renders something");
}

/// Bones that move the scene's body by `shift` (pose space of the given fit, metres): each of `given`'s
/// followed by a translation.
fn shifted_bones(
    given: &crate::geometry::BoneTransforms,
    shift: Vec3,
) -> crate::geometry::BoneTransforms {
    moved_bones(given, |_| glam::Mat4::from_translation(shift))
}

/// Each of `given`'s bones followed by its own rigid motion `motion(k)` (pose space of the given fit).
fn moved_bones(
    given: &crate::geometry::BoneTransforms,
    motion: impl Fn(usize) -> glam::Mat4,
) -> crate::geometry::BoneTransforms {
    crate::geometry::BoneTransforms::from_matrices(
        given
            .matrices()
            .iter()
            .enumerate()
            .map(|(k, m)| motion(k) * *m)
            .collect(),
    )
    .unwrap()
}

/// A refinement that moves every bone differently, as a fitter's per-joint errors do: bone `k` turned by
/// `3°·(k + 1)` about its own axis through a point of the body and shifted by up to 4 cm.
fn bones_moved_one_by_one(
    given: &crate::geometry::BoneTransforms,
) -> crate::geometry::BoneTransforms {
    moved_bones(given, |k| {
        let k = k as f32;
        let pivot = Vec3::new(0.05 * k, 0.2 - 0.1 * k, 0.0);
        let axis = Vec3::new(1.0, k, 0.5 - k).normalize();
        glam::Mat4::from_translation(Vec3::new(0.01 * k, -0.02, 0.04 - 0.015 * k) + pivot)
            * glam::Mat4::from_axis_angle(axis, (3.0 * (k + 1.0)).to_radians())
            * glam::Mat4::from_translation(-pivot)
    })
}

/// The GPU backends' culling on the device keeps the host culling's samples, in the same order, at the same
/// pose-space positions, with the same view directions and prior weights (both run here on flex), with and
/// without a refinement's [`CorrectionWarp`]; for rays turned away from the body, both keep the closest
/// sample alone.
#[test]
fn culling_on_the_device_keeps_the_host_cullings_samples() {
    let device = cpu_device();
    device.seed(3);
    let s = scene(&device, FrameCode::Training(2));
    let model = tiny_model(&device);
    let away = RayBatch {
        directions: -s.rays.directions.clone(),
        ..s.rays.clone()
    };
    let moved = BoneMatrices::new(&shifted_bones(&s.bones, Vec3::new(0.12, 0.0, 0.0)), &device);
    let warp = CorrectionWarp::new(&s.frame.bones, &moved);
    let one_by_one = BoneMatrices::new(&bones_moved_one_by_one(&s.bones), &device);
    let bone_warp = CorrectionWarp::new(&s.frame.bones, &one_by_one);
    for (name, rays, turned_away, warp) in [
        ("the scene's rays", &s.rays, false, None),
        (
            "the scene's rays, a moved body",
            &s.rays,
            false,
            Some(&warp),
        ),
        (
            "the scene's rays, bones moved one by one",
            &s.rays,
            false,
            Some(&bone_warp),
        ),
        ("rays turned away", &away, true, None),
    ] {
        let samples = model.config().samples_per_ray;
        let depths = stratified_depths(rays.near.clone(), rays.far.clone(), samples, None);
        let on_device = cull_on_device(
            rays,
            depths.clone(),
            &s.frame.global,
            &s.frame.volume,
            model.config().cull_distance,
            warp,
        );
        let host = cull_samples(
            &SampleRays {
                origins: &to_host(rays.origins.clone()),
                directions: &to_host(rays.directions.clone()),
                depths: &to_host(depths),
                samples,
            },
            &s.frame.global,
            &s.frame.volume,
            model.config().cull_distance,
            warp.map(CorrectionWarp::host),
        );
        let index: Vec<i64> = on_device.index.into_data().iter::<i64>().collect();
        assert_eq!(index, host.index, "{name}");
        if turned_away {
            assert_eq!(index.len(), 1, "{name}: only the closest sample");
        } else {
            let total = rays.len() * samples;
            assert!(
                index.len() > 1 && index.len() < total,
                "{name}: some kept, some culled"
            );
        }
        let close = |what: &str, got: Tensor<2>, expected: &[f32]| {
            anerf_testing::assert_close(
                &format!("{name}: {what}"),
                &to_host(got),
                expected,
                anerf_testing::Tolerance::Relative(1e-5),
            );
        };
        let host_points: Vec<f32> = host.points.iter().flat_map(|p| p.to_array()).collect();
        close("points", on_device.points, &host_points);
        close("directions", on_device.directions, &host.directions);
        close(
            "prior weights",
            on_device.prior,
            &to_host(s.frame.volume.weights_at(&host.points)),
        );
    }
}

/// A refinement that moves the whole body by `v` (every bone followed by the same translation): the warp
/// carries every point back by `−v` whatever its weights, so culling keeps exactly the samples near the
/// moved body, as the volume's distance at `p − v` says; and a warp between equal bones is exactly zero, so
/// zero corrections cull as the given fit does.
#[test]
fn a_correction_warp_keeps_the_samples_near_the_moved_body() {
    let device = cpu_device();
    let s = scene(&device, FrameCode::Training(2));
    let same = CorrectionWarp::new(&s.frame.bones, &s.frame.bones);
    assert!(to_host(same.rows()).iter().all(|&v| v == 0.0));
    let v = Vec3::new(0.0, 0.0, 0.15);
    let moved = BoneMatrices::new(&shifted_bones(&s.bones, v), &device);
    let warp = CorrectionWarp::new(&s.frame.bones, &moved);
    let cull = 0.05;
    let samples = 64;
    let depths = stratified_depths(s.rays.near.clone(), s.rays.far.clone(), samples, None);
    let rays = SampleRays {
        origins: &to_host(s.rays.origins.clone()),
        directions: &to_host(s.rays.directions.clone()),
        depths: &to_host(depths.clone()),
        samples,
    };
    let given = cull_samples(&rays, &s.frame.global, &s.frame.volume, cull, None);
    let zero = cull_samples(
        &rays,
        &s.frame.global,
        &s.frame.volume,
        cull,
        Some(same.host()),
    );
    assert_eq!(zero, given, "zero corrections");
    let with = cull_samples(
        &rays,
        &s.frame.global,
        &s.frame.volume,
        cull,
        Some(warp.host()),
    );
    let pose = to_host(pose_samples(&s.rays, depths, &s.frame.global));
    let near = |shift: Vec3| -> Vec<i64> {
        (0..pose.len() / 3)
            .filter(|&i| {
                s.host_volume
                    .distance_at(Vec3::from_slice(&pose[3 * i..3 * i + 3]) - shift)
                    < cull
            })
            .map(|i| i as i64)
            .collect()
    };
    assert_eq!(with.index, near(v));
    assert_eq!(given.index, near(Vec3::ZERO));
    assert_ne!(
        with.index, given.index,
        "the moved body keeps other samples"
    );
}

/// Adds `delta` to element `index` of the parameter `target`.
struct Nudge {
    target: ParamId,
    index: usize,
    delta: f32,
}

impl ModuleMapper for Nudge {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        if param.id != self.target {
            return param;
        }
        let requires_grad = param.val().is_require_grad();
        let (id, t, _) = param.consume();
        let shape = t.shape();
        let flat = t.detach().reshape([shape.num_elements()]);
        let mut bump = vec![0.0f32; flat.dims()[0]];
        bump[self.index] = self.delta;
        let value = (flat.clone() + Tensor::<1>::from_floats(bump.as_slice(), &flat.device()))
            .reshape(shape);
        // A fresh leaf with the same id, so that it still receives gradients.
        Param::initialized(
            id,
            if requires_grad {
                value.detach().require_grad()
            } else {
                value
            },
        )
    }
}

/// Sets every parameter to seeded uniform values of a fixed scale (1/√fan-in for matrices, 0.1 for vectors),
/// so a model's values do not depend on the device's random stream, which tests running in parallel share.
struct Seeded(rand_chacha::ChaCha8Rng);

impl ModuleMapper for Seeded {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        use rand::Rng;
        let requires_grad = param.val().is_require_grad();
        let (id, t, _) = param.consume();
        let shape = t.shape();
        let scale = match D {
            1 => 0.1,
            _ => 1.0 / (shape.dims::<D>()[0] as f32).sqrt(),
        };
        let values: Vec<f32> = (0..shape.num_elements())
            .map(|_| scale * (2.0 * self.0.random::<f32>() - 1.0))
            .collect();
        let value = Tensor::<1>::from_floats(values.as_slice(), &t.device()).reshape(shape);
        Param::initialized(
            id,
            if requires_grad {
                value.require_grad()
            } else {
                value
            },
        )
    }
}

/// Every float parameter: id, element count and rank.
struct ParamList(Vec<(ParamId, usize, usize)>);
impl ModuleVisitor for ParamList {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0
            .push((param.id, param.val().shape().num_elements(), D));
    }
}

/// Counts the float parameters Burn has not yet initialised (drawn from the device's random stream).
struct Undrawn(usize);
impl ModuleVisitor for Undrawn {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0 += usize::from(!param.is_initialized());
    }
}

#[test]
fn a_new_model_and_its_novel_field_hold_every_parameter_drawn() {
    // A lazily drawn parameter takes its value when first read, so the same seed would give another model
    // when the first reader differs (a forward pass or a copy to a data-parallel replica).
    let device = cpu_device().autodiff();
    let mut config = ModelPreset::Tiny.config();
    config.pose_refinement.enabled = true;
    let model = AnimatableNerf::new(&config, SIZES, &device);
    let count = |m: &AnimatableNerf| {
        let mut undrawn = Undrawn(0);
        m.visit(&mut undrawn);
        let mut all = ParamList(Vec::new());
        m.visit(&mut all);
        (undrawn.0, all.0.len())
    };
    let (undrawn, all) = count(&model);
    assert!(all > 10, "{all} parameters");
    assert_eq!(undrawn, 0, "{undrawn} of {all} parameters not drawn");
    let animated = model.with_novel_field(3, &device);
    assert_eq!(count(&animated).0, 0);
}

#[test]
fn rendered_colour_gradients_match_finite_differences() {
    let device = cpu_device().autodiff();
    device.seed(4);
    let s = scene(&device, FrameCode::Training(1));
    let model = seeded_model(ModelPreset::Tiny.config(), &device, 4);
    let weights = Tensor::<2>::from_floats([[0.7, -0.4, 1.1]], &device);
    let objective = |m: &AnimatableNerf| {
        (m.render(&s.rays, &s.frame, &s.canonical, None, false).rgb * weights.clone()).sum()
    };
    let value = objective(&model);
    let grads = GradientsParams::from_grads(value.clone().backward(), &model);
    let mut list = ParamList(Vec::new());
    model.visit(&mut list);
    // A few parameters across the NeRF trunk, the colour head, the blend field and the codes.
    let h = 1e-2f32;
    // The objective is an f32 sum: a difference quotient cannot resolve less than a few of its ulps over 2h
    // (about 4e-4 for this scene).
    let resolution = 8.0 * f32::EPSILON as f64 * to_host(value)[0].abs() as f64 / (2.0 * h as f64);
    let mut checked = 0;
    for (id, numel, rank) in list.0.iter().copied().step_by(3) {
        let index = numel / 2;
        let analytic = match rank {
            1 => grads.get::<1>(id).map(to_host),
            _ => grads.get::<2>(id).map(to_host),
        }
        .map(|g| g[index]);
        let Some(analytic) = analytic else { continue };
        let eval = |delta| {
            let nudged = model.clone().map(&mut Nudge {
                target: id,
                index,
                delta,
            });
            to_host(objective(&nudged))[0] as f64
        };
        let fd = (eval(h) - eval(-h)) / (2.0 * h as f64);
        let tol = 0.05 * fd.abs().max(analytic.abs() as f64) + resolution;
        assert!(
            (fd - analytic as f64).abs() < tol,
            "param {checked}: fd {fd} vs autodiff {analytic}"
        );
        checked += 1;
    }
    assert!(checked >= 5, "checked {checked} parameters");
}

#[test]
fn flex_and_ndarray_render_the_same_image() {
    let flex = cpu_device();
    flex.seed(5);
    let model = tiny_model(&flex);
    let on = |device: Device| {
        let s = scene(&device, FrameCode::Training(0));
        to_host(
            model
                .clone()
                .to_device(&device)
                .render(&s.rays, &s.frame, &s.canonical, None, false)
                .rgb,
        )
    };
    let a = on(flex.clone());
    let b = on(crate::DeviceChoice::Ndarray.device().unwrap());
    // Tolerance: f32 sums in a different order across backends.
    assert!(
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5),
        "{a:?}\n{b:?}"
    );
}

/// An analytic occupancy grid over `bounds`: occupied within 0.35 m of a point of the canonical body
/// (about half its box).
fn ball_grid(bounds: Aabb, device: &Device) -> OccupancyGrid {
    let config = OccupancyConfig {
        resolution: 16,
        density_threshold: 0.5,
        update_every: 1,
        warmup_steps: 0,
    };
    OccupancyGrid::build(&config, bounds, device, |p: Tensor<2>| {
        let c = Tensor::<2>::from_floats([[0.0, 0.3, 0.0]], &p.device());
        (p - c)
            .powi_scalar(2)
            .sum_dim(1)
            .sqrt()
            .lower_elem(0.35)
            .float()
    })
}

/// With an occupancy grid, samples whose canonical position falls in an empty cell skip the canonical NeRF:
/// the image equals shading every surviving sample and zeroing the density of those in empty cells.
#[test]
fn occupancy_grid_matches_zeroing_samples_in_empty_cells() {
    let device = cpu_device();
    device.seed(4);
    let s = scene(&device, FrameCode::Training(1));
    let mut model = tiny_model(&device);
    let grid = ball_grid(s.canonical.bounds, &device);
    let fraction = grid.occupied_fraction();
    assert!(fraction > 0.1 && fraction < 0.9, "{fraction}");
    model.set_occupancy(Some(grid.clone()));
    let skipped = model.render(&s.rays, &s.frame, &s.canonical, None, false);
    model.set_occupancy(None);
    let full = model.render(&s.rays, &s.frame, &s.canonical, None, false);
    assert!(skipped.occupied_samples < full.occupied_samples);
    assert_eq!(full.occupied_samples, full.surviving_samples);

    // Reference: every sample shaded, density zeroed where culled or where the warped point's cell is empty.
    let (samples, r) = (model.config().samples_per_ray, s.rays.len());
    let (shaded, far, depths) = shade_every_sample(&model, &s);
    let far = to_host(far.float());
    let canonical = to_host(shaded.canonical_points.clone());
    let keep: Vec<f32> = canonical
        .chunks_exact(3)
        .zip(&far)
        .map(|(p, f)| (*f == 0.0 && grid.contains(Vec3::from_slice(p))) as u8 as f32)
        .collect();
    let keep = from_rows(&keep, r * samples, 1, &device);
    let density = (shaded.density * keep).reshape([r, samples]);
    let reference = composite(density, shaded.rgb.reshape([r, samples, 3]), depths);
    let (a, b, c) = (
        to_host(skipped.rgb),
        to_host(reference.rgb),
        to_host(full.rgb),
    );
    assert!(
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5),
        "{a:?}\n{b:?}"
    );
    assert!(
        a.iter().zip(&c).any(|(x, y)| (x - y).abs() > 1e-3),
        "the grid changed nothing: the test would not see a mistake"
    );
}

/// The same image and the same parameter gradients on each GPU backend (wgpu, CUDA) as on flex, where it
/// works (checked in a child process first; skipped with the reason printed where not), for the tiny model
/// with frequency encodings and with hash grids (the CubeCL kernels on the GPU, the CPU kernels on flex).
/// Tolerance as in `tests/gpu_backends.rs`: `|gpu − flex| ≤ 1e-4 · (1 + |flex|)`, f32 sums in another order.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
#[test]
fn flex_and_gpu_backends_render_and_differentiate_the_same() {
    for (choice, gpu) in anerf_device::testing::gpu_devices_for_test(
        "model::tests::flex_and_gpu_backends_render_and_differentiate_the_same",
    ) {
        eprintln!("on {choice}");
        assert!(crate::kernels::available(&gpu));
        let grid = |levels, log2_table_size, finest_resolution| super::hash_grid::HashGridConfig {
            levels,
            log2_table_size,
            features_per_level: 2,
            base_resolution: 4,
            finest_resolution,
            half_extent: 1.3,
        };
        let hash_grids = ModelConfig {
            encoding: PointEncoding::HashGrid {
                nerf: grid(4, 10, 32),
                blend: grid(3, 9, 16),
            },
            ..ModelPreset::Tiny.config()
        };
        for (name, config) in [
            ("frequencies", ModelPreset::Tiny.config()),
            ("hash grids", hash_grids),
        ] {
            let flex = cpu_device().autodiff();
            flex.seed(6);
            let model = tiny_model_with(config, &flex);
            let on = |device: Device| {
                let s = scene(&device, FrameCode::Training(1));
                let model = model.clone().fork(&device);
                let out = model.render(&s.rays, &s.frame, &s.canonical, None, true);
                let weights = Tensor::<2>::from_floats([[0.7, -0.4, 1.1]], &device);
                let objective = (out.rgb.clone() * weights).sum()
                    + out.consistency.unwrap().loss(model.config().consistency);
                let grads = GradientsParams::from_grads(objective.backward(), &model);
                let mut values = vec![to_host(out.rgb)];
                values.extend(parameter_gradients(&model, &grads).into_iter().flatten());
                values
            };
            let expected = on(flex.clone());
            let got = on(gpu.clone().autodiff());
            assert!(
                expected[0].iter().any(|v| *v > 1e-3),
                "{name}: the scene renders something"
            );
            assert_eq!(
                got.len(),
                expected.len(),
                "{name}: the same parameters received gradients"
            );
            let mut overall = 0.0f32;
            for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
                let what = if i == 0 {
                    format!("{name}: image")
                } else {
                    format!("{name}: gradient {}", i - 1)
                };
                let worst = anerf_testing::assert_close(
                    &format!("{what} ({choice} against flex)"),
                    g,
                    e,
                    // The MLPs' matmuls run on TF32 tensor cores on CUDA.
                    anerf_testing::Tolerance::Relative(anerf_device::testing::matmul_tolerance(
                        choice, 1e-4,
                    )),
                );
                overall = overall.max(worst as f32);
            }
            eprintln!(
                "{name}: worst relative difference over the image and gradients: {overall:.1e}"
            );
        }
    }
}

/// A fresh hash-grid model can start learning whatever its seed: its raw density is positive (alive under
/// the ReLU) at points all over the canonical box. Before the density head's bias was set, seed 1 of the
/// demo started negative everywhere and never learned.
#[test]
fn a_fresh_hash_grid_model_has_positive_density_for_every_seed() {
    let device = cpu_device();
    let config = ModelPreset::Fast.config();
    let points = points_tensor(
        &grid_points(Vec3::splat(-1.0), Vec3::new(1.0, 1.0, 1.0)),
        &device,
    );
    for seed in 0..8 {
        device.seed(seed);
        let nerf = super::nerf::CanonicalNerf::new(&config, 4, &device);
        let density = to_host(nerf.density(points.clone()));
        let lowest = density.iter().copied().fold(f32::INFINITY, f32::min);
        assert!(lowest > 0.0, "seed {seed}: raw density down to {lowest}");
    }
}

#[test]
fn marching_every_sample_renders_the_tensor_renderers_image() {
    let device = cpu_device();
    device.seed(5);
    let s = scene(&device, FrameCode::Training(1));
    let model = tiny_model(&device);
    let full = model.render(&s.rays, &s.frame, &s.canonical, None, false);
    let marched = model.march(&s.host_rays, &s.frame, &s.canonical, 0.0);
    assert_eq!(marched.surviving_samples, full.surviving_samples);
    assert_eq!(marched.shaded_samples, marched.surviving_samples);
    assert_eq!(marched.total_samples, full.total_samples);
    for (name, a, b) in [
        ("rgb", &marched.rgb, to_host(full.rgb)),
        ("acc", &marched.acc, to_host(full.acc)),
        ("depth", &marched.depth, to_host(full.depth)),
    ] {
        assert_eq!(a.len(), b.len(), "{name}");
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(
            worst < 1e-5,
            "{name}: marched and tensor renders differ by {worst}"
        );
    }
    assert!(
        marched.acc.iter().any(|&a| a > 0.1),
        "the scene must be visible"
    );
}

/// An opaque body: rays stop behind its surface, so fewer samples are shaded, and each pixel changes by less
/// than the termination threshold.
#[test]
fn early_termination_skips_samples_behind_an_opaque_surface_within_its_bound() {
    let device = cpu_device();
    device.seed(6);
    let s = scene(&device, FrameCode::Training(1));
    // 64 samples per ray, as the presets: the first round shades 8 of each ray's survivors.
    let model = shifted_model(ModelPreset::Tiny.config(), &device, 60.0, 64);
    let every = model.march(&s.host_rays, &s.frame, &s.canonical, 0.0);
    let threshold = 1e-3;
    let stopped = model.march(&s.host_rays, &s.frame, &s.canonical, threshold);
    assert!(
        every.acc.iter().any(|&a| a > 1.0 - threshold),
        "some ray must be opaque: {:?}",
        every.acc
    );
    assert!(
        (stopped.shaded_samples as f32) < 0.8 * every.shaded_samples as f32,
        "{} of {} samples shaded",
        stopped.shaded_samples,
        every.shaded_samples
    );
    for (a, b) in stopped
        .rgb
        .iter()
        .zip(&every.rgb)
        .chain(stopped.acc.iter().zip(&every.acc))
    {
        assert!((a - b).abs() <= threshold, "{a} vs {b}");
    }
}

#[test]
fn a_zero_residual_head_starts_at_the_prior_and_learns_from_the_first_step() {
    let device = cpu_device().autodiff();
    device.seed(4);
    let s = scene(&device, FrameCode::Training(1));
    let model = tiny_model_with(zero_residual(), &device);
    let pts = grid_points(Vec3::new(-0.3, -0.5, -0.2), Vec3::new(0.3, 0.8, 0.2));
    let p = points_tensor(&pts, &device);
    let prior = s.frame.volume.sample(p.clone()).weights;
    let (weights, residual) = model.frame_blend(p.clone(), prior.clone(), FrameCode::Training(1));
    assert!(to_host(residual.clone().unwrap()).iter().all(|&f| f == 0.0));
    let expected = to_host(model.blend.prior_only(prior));
    let got = to_host(weights);
    assert!(got.iter().zip(&expected).all(|(a, b)| (a - b).abs() < 1e-6));
    // The penalty's and the colour loss's gradients reach the head at once, the trunk only through it.
    let out = model.render(&s.rays, &s.frame, &s.canonical, None, true);
    let terms = out.consistency.unwrap();
    let loss = color_mse(out.rgb, s.rays.colors.clone().unwrap())
        + terms.loss(model.config().consistency)
        + terms.residual_penalty();
    let grads = GradientsParams::from_grads(loss.backward(), &model);
    // Of the blend field's parameters only the head's weight and bias: the trunk, codes and grid feed it
    // through zero weights.
    let (with, total) = params_with_gradient(&model.blend, &grads);
    assert_eq!(
        with, 2,
        "{with} of {total} blend-field parameters got a gradient"
    );
}

/// Frames whose bones are one rigid motion `Q` (so the warp is `Q⁻¹` whatever the weights) under a global
/// rotation `G`: a sample at `Q c` seen along world direction `G Q d` is the canonical point `c` seen along
/// `d`.
#[test]
fn the_colour_head_sees_the_direction_in_the_configured_frame() {
    use glam::{Mat4, Quat};
    let device = cpu_device();
    let s = scene(&device, FrameCode::Training(0));
    let q = Mat4::from_rotation_translation(
        Quat::from_axis_angle(Vec3::new(0.3, 1.0, -0.2).normalize(), 1.1),
        Vec3::new(0.05, -0.02, 0.1),
    );
    let g = Vec3::new(0.0, 0.0, 0.9);
    let frame = |bones: Mat4, rh: Vec3| FrameInputs {
        bones: BoneMatrices::new(
            &crate::geometry::BoneTransforms::from_matrices(vec![bones; 4]).unwrap(),
            &device,
        ),
        global: GlobalTransform {
            rh,
            th: Vec3::new(0.3, -0.1, 0.2),
        },
        ..s.frame.clone()
    };
    let (posed, rest) = (frame(q, g), frame(Mat4::IDENTITY, Vec3::ZERO));
    let rotation = GlobalTransform {
        rh: g,
        th: Vec3::ZERO,
    }
    .rotation()
        * glam::Mat3::from_mat4(q);
    let canonical = grid_points(Vec3::new(-0.2, -0.3, -0.1), Vec3::new(0.2, 0.6, 0.1));
    let dirs: Vec<Vec3> = (0..canonical.len())
        .map(|i| Vec3::new((i as f32 * 0.7).sin(), 0.5, (i as f32 * 1.3).cos()).normalize())
        .collect();
    let posed_points: Vec<Vec3> = canonical.iter().map(|&c| q.transform_point3(c)).collect();
    let posed_dirs: Vec<Vec3> = dirs.iter().map(|&d| rotation * d).collect();
    // Each comparison is between two shadings by one model: no two models need equal parameters.
    let rgb = |model: &AnimatableNerf, f: &FrameInputs, points: &[Vec3], d: &[Vec3]| {
        let p = points_tensor(points, &device);
        let prior = f.volume.sample(p.clone()).weights;
        let shaded = model.shade(p, prior, points_tensor(d, &device), f, &s.canonical);
        to_host(shaded.rgb)
    };
    let largest = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    };
    let with = |view_direction| {
        tiny_model_with(
            ModelConfig {
                view_direction,
                ..ModelPreset::Tiny.config()
            },
            &device,
        )
    };
    // For each frame: the posed frame's samples seen along `G Q d`, and the rest frame's along `d`.
    let pair = |model: &AnimatableNerf| {
        (
            rgb(model, &posed, &posed_points, &posed_dirs),
            rgb(model, &rest, &canonical, &dirs),
        )
    };
    // Canonical: the same colours as the rest frame seen along the canonical direction.
    let (a, b) = pair(&with(ViewDirection::Canonical));
    assert!(largest(&a, &b) < 1e-4, "{}", largest(&a, &b));
    // World: the head sees the world direction, which differs, and so do the colours.
    let model = with(ViewDirection::World);
    let (a, b) = pair(&model);
    assert!(largest(&a, &b) > 1e-3, "the direction changed nothing");
    let c = rgb(&model, &rest, &canonical, &posed_dirs);
    assert!(largest(&a, &c) < 1e-4, "{}", largest(&a, &c));
    // None: no direction reaches the head.
    let (a, b) = pair(&with(ViewDirection::None));
    assert!(largest(&a, &b) < 1e-4, "{}", largest(&a, &b));
}

/// By default the stage-1 field starts random (the authors' code) and the stage-2 field at the body model's
/// weights.
#[test]
fn the_novel_pose_field_starts_at_the_prior() {
    let device = cpu_device();
    device.seed(5);
    let s = scene(&device, FrameCode::Novel(1));
    let model = tiny_model(&device).with_novel_field(2, &device);
    let p = points_tensor(
        &grid_points(Vec3::new(-0.3, -0.5, -0.2), Vec3::new(0.3, 0.8, 0.2)),
        &device,
    );
    let prior = s.frame.volume.sample(p.clone()).weights;
    let (novel, residual) = model.frame_blend(p.clone(), prior.clone(), FrameCode::Novel(1));
    assert!(to_host(residual.unwrap()).iter().all(|&f| f == 0.0));
    let expected = to_host(model.blend.prior_only(prior.clone()));
    assert!(to_host(novel)
        .iter()
        .zip(&expected)
        .all(|(a, b)| (a - b).abs() < 1e-6));
    let (_, training) = model.frame_blend(p, prior, FrameCode::Training(1));
    assert!(to_host(training.unwrap()).iter().any(|&f| f.abs() > 1e-3));
}

/// With pose refinement on, zero corrections render exactly what the given fit renders (the corrections
/// start there), and the colours' gradient reaches the frame's corrections, matching central differences;
/// the other frames' corrections get none.
#[test]
fn pose_corrections_start_at_the_given_render_and_learn_from_the_colours() {
    let device = cpu_device().autodiff();
    device.seed(6);
    let s = scene(&device, FrameCode::Training(1));
    let config = ModelConfig {
        pose_refinement: PoseRefinementConfig {
            enabled: true,
            rotation_scale: 4.0,
            translation_scale: 1.0,
            ..Default::default()
        },
        ..ModelPreset::Tiny.config()
    };
    let model = seeded_model(config, &device, 6);
    let refined = FrameInputs {
        basis: Some(s.basis.clone()),
        ..s.frame.clone()
    };
    // Without a basis the model renders the given bones, as a model without refinement does.
    let given = model.render(&s.rays, &s.frame, &s.canonical, None, false);
    let corrected = model.render(&s.rays, &refined, &s.canonical, None, false);
    assert_eq!(to_host(given.rgb), to_host(corrected.rgb));
    assert_eq!(to_host(given.acc), to_host(corrected.acc));

    let weights = Tensor::<2>::from_floats([[0.7, -0.4, 1.1]], &device);
    let objective = |m: &AnimatableNerf| {
        (m.render(&s.rays, &refined, &s.canonical, None, false).rgb * weights.clone()).sum()
    };
    let value = objective(&model);
    let grads = GradientsParams::from_grads(value.backward(), &model);
    let pose = model.pose.as_ref().unwrap();
    let (joints, root) = (
        to_host(grads.get::<2>(pose.joints.id).unwrap()),
        to_host(grads.get::<2>(pose.root.id).unwrap()),
    );
    // Frame 1's rows only (4 joints × 3 values; 6 global values).
    for (f, (j, r)) in joints.chunks(12).zip(root.chunks(6)).enumerate() {
        let moved = j.iter().chain(r).any(|g| *g != 0.0);
        assert_eq!(moved, f == 1, "frame {f}: joints {j:?}, global {r:?}");
    }
    let h = 1e-3f32;
    for (id, index, analytic) in [
        (pose.joints.id, 12 + 3 + 2, joints[12 + 3 + 2]),
        (pose.joints.id, 12 + 6, joints[12 + 6]),
        (pose.root.id, 6 + 1, root[6 + 1]),
        (pose.root.id, 6 + 3, root[6 + 3]),
    ] {
        let eval = |delta| {
            let nudged = model.clone().map(&mut Nudge {
                target: id,
                index,
                delta,
            });
            to_host(objective(&nudged))[0] as f64
        };
        let fd = (eval(h) - eval(-h)) / (2.0 * h as f64);
        assert!(
            (fd - analytic as f64).abs() < 0.05 * fd.abs().max(analytic.abs() as f64) + 2e-3,
            "parameter {index}: central difference {fd} vs autodiff {analytic}"
        );
        assert!(
            analytic.abs() > 1e-3,
            "parameter {index}: gradient {analytic}"
        );
    }
}

/// The colours' gradient recovers a known correction: images rendered with the fit corrected by a known
/// global rotation and translation are the target, the fields are frozen, and fitting the corrections from
/// zero (Adam, 200 steps on two 48×48 views in turn) closes 70% of the way to its translation and 15% to its
/// rotation. Culling stays at the given body (the frame's [`CorrectionWarp`] removed): the untrained field
/// has density everywhere, so a culling shell that followed the correction would draw the images' outline
/// itself, and culling passes no gradient; what culling keeps is tested on its own.
#[test]
fn fitting_the_corrections_to_images_of_a_known_correction_recovers_it() {
    use burn::optim::AdamConfig;
    let device = cpu_device().autodiff();
    device.seed(9);
    let s = scene(&device, FrameCode::Training(1));
    let config = ModelConfig {
        pose_refinement: PoseRefinementConfig {
            enabled: true,
            rotation_scale: 1.0,
            translation_scale: 0.5,
            prior_weight: 0.0,
            ..Default::default()
        },
        ..ModelPreset::Tiny.config()
    };
    let mut model = seeded_model(config, &device, 9);
    model.nerf = model.nerf.no_grad();
    model.blend = model.blend.no_grad();
    let frame = FrameInputs {
        basis: Some(s.basis.clone()),
        ..s.frame.clone()
    };
    // Two 48×48 cameras 2.5 m from the body, front and side (about 2 cm a pixel at the body).
    let body = Aabb {
        min: Vec3::new(-0.4, -0.6, -0.3),
        max: Vec3::new(0.4, 0.9, 0.3),
    };
    let world_box = Aabb {
        min: body.min + s.pose.global.th - 0.2,
        max: body.max + s.pose.global.th + 0.2,
    };
    let rays: Vec<RayBatch> = [
        (
            [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0, 0.15, 2.5],
        ),
        (
            [[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]],
            [0.0, 0.15, 2.4],
        ),
    ]
    .into_iter()
    .map(|(rotation, translation)| {
        let camera = Camera::from_rows(
            [[120.0, 0.0, 23.5], [0.0, 120.0, 23.5], [0.0, 0.0, 1.0]],
            rotation,
            translation,
            [0.0; 5],
            48,
            48,
        )
        .unwrap();
        let (host, _) = HostRays::from_rays(&camera.image_rays(Default::default()), &world_box);
        RayBatch::new(&host, FrameId(1), &device)
    })
    .collect();
    // The known correction of training frame 1 (parameters = correction / scale), and its images.
    let (rotation, translation) = (Vec3::new(0.04, -0.05, 0.03), Vec3::new(0.02, -0.015, 0.01));
    let mut known = vec![0.0f32; 3 * 6];
    known[6..9].copy_from_slice(&rotation.to_array());
    known[9..12].copy_from_slice(&(translation / 0.5).to_array());
    let set_root = |model: &mut AnimatableNerf, values: &[f32]| {
        model.pose.as_mut().unwrap().root =
            Param::from_tensor(from_rows(values, 3, 6, &device).require_grad());
    };
    set_root(&mut model, &known);
    let at_given_body = |model: &AnimatableNerf| FrameInputs {
        warp: None,
        ..model.posed_frame(&frame)
    };
    let targets: Vec<Tensor<2>> = rays
        .iter()
        .map(|r| {
            model
                .render(r, &at_given_body(&model), &s.canonical, None, false)
                .rgb
                .detach()
        })
        .collect();
    set_root(&mut model, &[0.0; 18]);
    let error = |model: &AnimatableNerf| {
        let c = model.pose.as_ref().unwrap().correction(1);
        (
            (c.rotation - rotation).length(),
            (c.translation - translation).length(),
        )
    };
    let mut optim = AdamConfig::new().init();
    for step in 0..200 {
        let out = model.render(
            &rays[step % 2],
            &at_given_body(&model),
            &s.canonical,
            None,
            false,
        );
        let loss = color_mse(out.rgb, targets[step % 2].clone());
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(5e-3, model, grads);
    }
    // The translation is recovered closely; the rotation less (the untrained field is nearly symmetric
    // about the body's long axis, so a turn about it barely changes the images).
    let (r, t) = error(&model);
    assert!(
        r < 0.85 * rotation.length() && t < 0.3 * translation.length(),
        "left {r:.4} of {:.4} rad and {t:.4} of {:.4} m",
        rotation.length(),
        translation.length()
    );
}

/// A render of several frames at once gives each frame what its own render gives: the same colours,
/// opacities, depths, sample counts and consistency terms, and the same parameter gradients for a loss
/// over all of them, with refined fits (each frame's corrections and codes its own), canonical view
/// directions and an occupancy grid that leaves one frame a single sample.
#[test]
fn rendering_frames_together_gives_each_frames_own_render() {
    let device = cpu_device().autodiff();
    device.seed(9);
    let config = ModelConfig {
        view_direction: ViewDirection::Canonical,
        pose_refinement: PoseRefinementConfig {
            enabled: true,
            ..Default::default()
        },
        ..ModelPreset::Tiny.config()
    };
    let mut model = seeded_model(config, &device, 9);
    // Every frame's corrections non-zero and different, so that each frame's bones are its own.
    let mut list = ParamList(Vec::new());
    model.pose.as_ref().unwrap().visit(&mut list);
    for &(id, len, _) in &list.0 {
        for index in 0..len {
            model = model.map(&mut Nudge {
                target: id,
                index,
                delta: 0.02 * ((index * 7 + len) % 11) as f32 - 0.1,
            });
        }
    }
    let scenes: Vec<Scene> = (0..3)
        .map(|f| {
            let mut s = scene(&device, FrameCode::Training(f));
            s.frame.appearance = 2 - f;
            s.frame.basis = Some(s.basis.clone());
            s.frame.bones = BoneMatrices::new(
                &shifted_bones(&s.bones, Vec3::new(0.03 * f as f32, 0.0, -0.02)),
                &device,
            );
            s
        })
        .collect();
    // Most samples of the frames lie in the grid's occupied ball; the third frame's rays are moved far
    // off the body, where culling keeps one sample that the grid drops.
    let grid = ball_grid(scenes[0].canonical.bounds, &device);
    model.set_occupancy(Some(grid));
    let mut far = scenes[2].host_rays.clone();
    for o in &mut far.origins {
        o[0] += 3.0;
    }
    let far = RayBatch::new(&far, FrameId(2), &device);
    let rays = [&scenes[0].rays, &scenes[1].rays, &far];
    let jitter = |f: usize| {
        let (r, s) = (rays[f].len(), model.config().samples_per_ray);
        let values: Vec<f32> = (0..r * s)
            .map(|i| ((i * 37 + f * 11) % 97) as f32 / 97.0)
            .collect();
        from_rows(&values, r, s, &device)
    };
    let canonical = &scenes[0].canonical;
    let together = model.render_frames(
        (0..3)
            .map(|f| FrameRays {
                rays: rays[f],
                frame: &scenes[f].frame,
                jitter: Some(jitter(f)),
            })
            .collect(),
        canonical,
        true,
    );
    let alone: Vec<RenderOutput> = (0..3)
        .map(|f| model.render(rays[f], &scenes[f].frame, canonical, Some(jitter(f)), true))
        .collect();
    assert_eq!(
        alone[2].occupied_samples, 1,
        "the far frame keeps one sample"
    );
    let close = |what: &str, a: Tensor<2>, b: Tensor<2>| {
        let (a, b) = (to_host(a), to_host(b));
        assert_eq!(a.len(), b.len(), "{what}");
        for (x, y) in a.iter().zip(&b) {
            assert!(
                (x - y).abs() <= 1e-5 * (1.0 + y.abs()),
                "{what}: {x} vs {y}"
            );
        }
    };
    for (f, (t, a)) in together.iter().zip(&alone).enumerate() {
        assert_eq!(
            (t.surviving_samples, t.occupied_samples, t.total_samples),
            (a.surviving_samples, a.occupied_samples, a.total_samples),
            "frame {f}"
        );
        close(&format!("frame {f} rgb"), t.rgb.clone(), a.rgb.clone());
        close(
            &format!("frame {f} acc"),
            t.acc.clone().unsqueeze_dim(1),
            a.acc.clone().unsqueeze_dim(1),
        );
        close(
            &format!("frame {f} depth"),
            t.depth.clone().unsqueeze_dim(1),
            a.depth.clone().unsqueeze_dim(1),
        );
        close(
            &format!("frame {f} alpha"),
            t.alpha.clone(),
            a.alpha.clone(),
        );
        let (tc, ac) = (
            t.consistency.as_ref().unwrap(),
            a.consistency.as_ref().unwrap(),
        );
        close(
            &format!("frame {f} observed"),
            tc.observed.clone(),
            ac.observed.clone(),
        );
        close(
            &format!("frame {f} canonical"),
            tc.canonical.clone(),
            ac.canonical.clone(),
        );
        close(&format!("frame {f} mask"), tc.mask.clone(), ac.mask.clone());
        close(
            &format!("frame {f} residual"),
            tc.residual.clone().unwrap(),
            ac.residual.clone().unwrap(),
        );
    }
    // Each frame's colours weighed by its own weights, plus its consistency loss.
    let loss = |outs: &[RenderOutput]| {
        outs.iter()
            .enumerate()
            .map(|(f, out)| {
                let w = Tensor::<2>::from_floats([[0.7 - 0.2 * f as f32, -0.4, 1.1]], &device);
                (out.rgb.clone() * w).sum()
                    + out
                        .consistency
                        .as_ref()
                        .unwrap()
                        .loss(model.config().consistency)
            })
            .reduce(|a, b| a + b)
            .unwrap()
    };
    let grads = |outs: &[RenderOutput]| {
        parameter_gradients(
            &model,
            &GradientsParams::from_grads(loss(outs).backward(), &model),
        )
    };
    let (gt, ga) = (grads(&together), grads(&alone));
    let mut compared = 0;
    for (t, a) in gt.iter().zip(&ga) {
        match (t, a) {
            (Some(t), Some(a)) => {
                let scale = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                for (x, y) in t.iter().zip(a) {
                    assert!((x - y).abs() <= 1e-4 * (1.0 + scale), "gradient {x} vs {y}");
                }
                compared += 1;
            }
            (None, None) => {}
            _ => panic!("a parameter has a gradient one way only"),
        }
    }
    assert!(
        compared >= gt.len() - 1,
        "{compared} of {} parameters compared",
        gt.len()
    );
}

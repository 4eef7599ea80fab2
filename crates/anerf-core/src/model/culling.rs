//! Culling: the samples along a batch of rays that lie farther than `cull_distance` from the body never
//! reach a network. [`Culling`] is the one decision of where that runs, from the device: on the host for
//! the CPU backends (only the survivors' positions and directions are uploaded), on the device for the GPU
//! backends (reading the batch back and uploading the survivors would cost more than the lookups).

use std::sync::{Arc, OnceLock};

use burn::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use crate::geometry::skinning::world_to_pose;
use crate::geometry::{BoneMatrices, FieldBound, GlobalTransform, VolumeTensor};
use crate::render::RayBatch;
use crate::tensor::to_host;

/// Where a pose refinement moved the body, for culling. Per bone, the rigid motion `D_k = A_k · Â_k⁻¹`
/// (pose space of the given fit) carries a point of the body where the corrected bones `Â_k` put it back to
/// where the given bones `A_k` have it; culling measures a sample's distance to the body at
/// `x + Σ_k w_k(x) (D_k − I) x` (the prior weights `w` at `x` blend the displacements), i.e. its distance to
/// the *corrected* body, which a refinement may have moved by more than `cull_distance` (under fits 4 cm off,
/// a quarter of the vertices lie farther than 5 cm from where the fit has them, a hand up to 20 cm). The rows
/// hold `D_k − I = (A_k − Â_k) Â_k⁻¹` (`[K, 12]`, top rows of 4×4, row-major), exactly zero where the bones
/// agree, so zero corrections cull exactly as the given fit does. No gradient flows through culling.
#[derive(Debug, Clone)]
pub struct CorrectionWarp {
    rows: Tensor<2>,
    /// The rows on the host, read back once (shared by clones) for the host culling of every chunk of rays.
    host: Arc<OnceLock<HostWarp>>,
}

impl CorrectionWarp {
    /// The displacements from `corrected` bones back to `given` ones (both rigid, canonical → pose space).
    pub fn new(given: &BoneMatrices, corrected: &BoneMatrices) -> Self {
        let k = given.num_joints();
        let split = |b: &BoneMatrices| {
            let m = b.rows().detach().reshape([k, 3, 4]);
            (m.clone().narrow(2, 0, 3), m.narrow(2, 3, 1))
        };
        let ((r, t), (r_hat, t_hat)) = (split(given), split(corrected));
        // A Â⁻¹ − I = [(R − R̂) R̂ᵀ | (t − t̂) − (R − R̂) R̂ᵀ t̂] for rigid bones.
        let rotation = (r - r_hat.clone()).matmul(r_hat.swap_dims(1, 2));
        let translation = (t - t_hat.clone()) - rotation.clone().matmul(t_hat);
        Self {
            rows: Tensor::cat(vec![rotation, translation], 2).reshape([k, 12]),
            host: Arc::default(),
        }
    }

    /// The `[K, 12]` displacements `D_k − I`.
    pub fn rows(&self) -> Tensor<2> {
        self.rows.clone()
    }

    /// The displacements on the host, for [`cull_samples`] (read back on the first call).
    pub fn host(&self) -> &HostWarp {
        self.host.get_or_init(|| HostWarp {
            rows: to_host(self.rows.clone())
                .chunks_exact(12)
                .map(|r| r.try_into().expect("12 values a bone"))
                .collect(),
        })
    }

    /// Points `[N, 3]` carried back by the displacements blended with `weights` (`[N, K]`).
    fn apply(&self, points: Tensor<2>, weights: Tensor<2>) -> Tensor<2> {
        points.clone() + BoneMatrices::from_rows(self.rows()).forward(points, weights)
    }
}

/// [`CorrectionWarp`] on the host.
#[derive(Debug, Clone, PartialEq)]
pub struct HostWarp {
    rows: Vec<[f32; 12]>,
}

impl HostWarp {
    /// A bound on the warp's displacement field in each block of `volume` ([`VolumeTensor::field_bound`]).
    fn bound(&self, volume: &VolumeTensor) -> FieldBound {
        volume.field_bound(&self.rows)
    }
}

/// The pose-space positions `[R·S, 3]` (metres, ray-major) of the samples along `rays` at `depths` (`[R, S]`,
/// metres along each ray): `x_pose = R_hᵀ (o + z·d − T_h)`.
pub(super) fn pose_samples(
    rays: &RayBatch,
    depths: Tensor<2>,
    global: &GlobalTransform,
) -> Tensor<2> {
    let [r, s] = depths.dims();
    let world = rays.origins.clone().unsqueeze_dim::<3>(1)
        + rays.directions.clone().unsqueeze_dim::<3>(1) * depths.unsqueeze_dim::<3>(2);
    world_to_pose(world.reshape([r * s, 3]), global)
}

/// Where a render culls its samples (the module's doc says why each backend culls where it does).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Culling {
    Host,
    Device,
}

impl Culling {
    /// The culling `device` runs.
    pub fn for_device(device: &Device) -> Self {
        if anerf_device::runs_on_gpu(device) {
            Culling::Device
        } else {
            Culling::Host
        }
    }
}

/// The samples that survive culling, on the device ([`cull_on_device`]).
pub(super) struct DeviceSurvivors {
    /// `[M]` flat indices `ray · S + sample`.
    pub index: Tensor<1, Int>,
    /// `[M, 3]` pose-space positions (metres).
    pub points: Tensor<2>,
    /// `[M, 3]` world-space unit view directions.
    pub directions: Tensor<2>,
    /// `[M, K]` the body model's blend weights `w^s` there.
    pub prior: Tensor<2>,
}

/// The samples along a batch of rays, on the host.
pub struct SampleRays<'a> {
    /// `[R·3]` world-space origins (metres) and unit directions.
    pub origins: &'a [f32],
    pub directions: &'a [f32],
    /// `[R·S]` depths along each ray (metres).
    pub depths: &'a [f32],
    /// `S`.
    pub samples: usize,
}

/// The samples that survive culling: their flat indices `ray · S + sample`, pose-space positions `[M]`
/// (metres) and world-space view directions `[M·3]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Survivors {
    pub index: Vec<i64>,
    pub points: Vec<Vec3>,
    pub directions: Vec<f32>,
}

/// Places the samples of `rays` in pose space (`x_pose = R_hᵀ (o + z·d − T_h)`) and keeps those closer than
/// `threshold` to the body by the host copy of the frame volume's distance channel
/// ([`VolumeTensor::is_near`]), measured with a `warp` where a refinement moved the body
/// ([`CorrectionWarp`]); when none is, the closest sample (as [`surviving_indices`]).
pub fn cull_samples(
    rays: &SampleRays,
    global: &GlobalTransform,
    volume: &VolumeTensor,
    threshold: f32,
    warp: Option<&HostWarp>,
) -> Survivors {
    let rotation_t = global.rotation().transpose();
    let s = rays.samples;
    let ray_vec = |v: &[f32], r: usize| Vec3::from_slice(&v[3 * r..3 * r + 3]);
    let pose: Vec<Vec3> = (0..rays.depths.len())
        .into_par_iter()
        .map(|i| {
            let r = i / s;
            rotation_t
                * (ray_vec(rays.origins, r) + ray_vec(rays.directions, r) * rays.depths[i]
                    - global.th)
        })
        .collect();
    // Where the sample's distance is measured: where the given body has its point. The warp's bound, block
    // by block of the volume, settles most samples far from the body; the rest are displaced.
    let bounded = warp.map(|w| (w, w.bound(volume)));
    let mut near: Vec<(i64, Vec3)> = pose
        .par_iter()
        .enumerate()
        .filter_map(|(i, &p)| {
            let near = match &bounded {
                Some((w, bound)) => volume
                    .settled_under(p, threshold, bound)
                    .unwrap_or_else(|| volume.is_near_displaced(p, threshold, &w.rows)),
                None => volume.is_near(p, threshold),
            };
            near.then_some((i as i64, p))
        })
        .collect();
    if near.is_empty() && !pose.is_empty() {
        // Every sample's measured distance.
        let measured = |p: Vec3| match warp {
            Some(w) => p + volume.displacement(&w.rows, p),
            None => p,
        };
        let distance: Vec<f32> = pose
            .par_iter()
            .map(|&p| volume.distance_at(measured(p)))
            .collect();
        near = surviving_indices(&distance, threshold)
            .into_iter()
            .map(|i| (i, pose[i as usize]))
            .collect();
    }
    let (index, points): (Vec<i64>, Vec<Vec3>) = near.into_iter().unzip();
    let directions = index
        .iter()
        .flat_map(|&i| ray_vec(rays.directions, i as usize / s).to_array())
        .collect();
    Survivors {
        index,
        points,
        directions,
    }
}

/// Indices of samples closer than `threshold` to the body; the closest sample is always included.
pub fn surviving_indices(distance: &[f32], threshold: f32) -> Vec<i64> {
    let mut keep: Vec<i64> = (0..distance.len())
        .filter(|&i| distance[i] < threshold)
        .map(|i| i as i64)
        .collect();
    if keep.is_empty() {
        if let Some((closest, _)) = distance
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
        {
            keep.push(closest as i64);
        }
    }
    keep
}

/// [`cull_samples`] on the device, for the GPU backends: the samples along `rays` at `depths` (`[R, S]`,
/// metres) placed in pose space by `global`, their distance to the body looked up in the frame's `volume`
/// (with a `warp`, to the body where the refinement moved it), and those closer than `cull_distance`
/// (metres; or else the closest) selected with their view directions and prior weights. Only the survivors'
/// indices cross to the host and back (their count fixes the batch's shape); the rays, depths and survivors
/// stay on the device.
pub(super) fn cull_on_device(
    rays: &RayBatch,
    depths: Tensor<2>,
    global: &GlobalTransform,
    volume: &VolumeTensor,
    cull_distance: f32,
    warp: Option<&CorrectionWarp>,
) -> DeviceSurvivors {
    let [r, s] = depths.dims();
    let pose = pose_samples(rays, depths, global);
    let measured = match warp {
        Some(warp) => warp.apply(pose.clone(), volume.sample(pose.clone()).weights),
        None => pose.clone(),
    };
    let distance = volume.sample_distance(measured).reshape([r * s]);
    let near = distance.clone().lower_elem(cull_distance).argwhere();
    let index = match near.dims() {
        [0, _] => distance.argmin(0),
        [m, _] => near.reshape([m]),
    };
    let points = pose.select(0, index.clone());
    DeviceSurvivors {
        directions: rays
            .directions
            .clone()
            .select(0, index.clone().div_scalar(s as i64)),
        prior: volume.sample(points.clone()).weights,
        points,
        index,
    }
}

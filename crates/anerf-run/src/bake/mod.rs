//! Baking a trained run into skinned 3D Gaussians (`anerf bake`): Gaussians start on the canonical
//! surface with the NeRF's colours and canonical blend weights ([`init`]), are fine-tuned against the
//! run's training images through the splat rasteriser ([`fit`]), and are stored in `<run>/baked/`
//! ([`store`]).

mod adam;
mod export;
pub mod fit;
mod init;
pub mod store;

use std::path::{Path, PathBuf};

use anerf_core::gaussians::{project_host, render, GaussianCloud, SplatView};
use anerf_core::geometry::{
    BoneMatrices, BoneTransforms, Camera, CanonicalPose, GlobalTransform, PixelConvention, Pose,
};
use anerf_core::kernels::splat::{self, PIXEL_WIDTH};
use anerf_core::model::AnimatableNerf;
use anerf_core::tensor::to_host;
use anerf_core::FrameId;
use anyhow::{bail, Context, Result};
use burn::prelude::{Device, Tensor};

use crate::memory::Work;
use crate::mesh::{probed_surface, MeshJob};
use crate::{device, newest_checkpoint, open_run, JobOptions};
use anerf_train::experiment::Experiment;
pub use export::{export_splats, PosedSplats, SplatExportJob, SplatExported};
use fit::{FitSettings, Shot};
pub use store::{AvatarInfo, BakedAvatar};

/// What `anerf bake` makes.
#[derive(Debug, Clone)]
pub struct BakeJob {
    /// The canonical surface the Gaussians start on (voxel, iso level, smoothing; frames unused).
    pub surface: MeshJob,
    /// Most Gaussians the avatar may hold.
    pub budget: usize,
    /// Spherical-harmonic degree of the colours: 0 (one colour) or 1 (view-dependent).
    pub sh_degree: usize,
    /// Fine-tuning steps, one training image each.
    pub iterations: usize,
    /// Replace an existing `<run>/baked/`.
    pub overwrite: bool,
}

/// What a bake wrote.
#[derive(Debug, Clone)]
pub struct Baked {
    pub dir: PathBuf,
    pub info: AvatarInfo,
}

/// Bakes the run at `run_path` into `<run>/baked/` (kept unless `job.overwrite`). A run whose model has no
/// surface at the iso level is refused, as `export` refuses it.
pub fn bake(run_path: &Path, job: &BakeJob, options: &JobOptions) -> Result<Baked> {
    if job.sh_degree > 1 {
        bail!("--sh-degree {}: expected 0 or 1", job.sh_degree);
    }
    if job.budget == 0 || job.iterations == 0 {
        bail!("--budget and --iterations must be at least 1");
    }
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let dir = run.baked();
    if dir.exists() && !job.overwrite {
        bail!("{} exists; give --overwrite to bake again", dir.display());
    }
    let device = device(&config, options)?;
    let restored = newest_checkpoint(&run, &config, &device)?;
    let model = restored.model;
    let seed = config.seed;
    let log_every = config.train.log_every;
    let exp = Experiment::open(config, device.clone(), options.progress)?;
    let image_pixels: u64 = exp
        .train_views
        .iter()
        .map(|v| {
            let c = &exp.prepared.cameras[v.0];
            u64::from(c.width) * u64::from(c.height)
        })
        .sum();
    crate::memory::check_bake(job.budget, image_pixels * exp.train_frames.len() as u64)?;
    let (surface, probes) = probed_surface(&model, &exp, &job.surface).context(
        "the canonical surface the Gaussians start on (a run whose model has no density above the iso \
         level cannot be baked)",
    )?;
    let source = restored
        .checkpoint
        .dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let start = init::on_surface(
        &surface,
        &probes,
        job.surface.voxel,
        job.budget,
        job.sh_degree,
        source,
    );
    let shots = training_shots(&model, &exp)?;
    let settings = FitSettings {
        iterations: job.iterations,
        budget: job.budget,
        seed,
        log_every,
    };
    let bar = options.bar("bake", job.iterations);
    let (avatar, report) = fit::fit(&start, &shots, &settings, &device, &bar)?;
    bar.finish(report.steps, "baked");
    avatar.save(&dir)?;
    Ok(Baked {
        dir,
        info: avatar.info,
    })
}

/// Frame `frame`'s pose as the NeRF renders it (the refined fit where the model refines training frames)
/// and its bone transforms (canonical → pose space).
pub(crate) fn frame_bones(
    model: &AnimatableNerf,
    exp: &Experiment,
    frame: FrameId,
) -> Result<(Pose, BoneTransforms)> {
    let pose = exp.frame_pose(model, frame)?;
    let bones = exp
        .prepared
        .skeleton
        .bone_transforms(&pose, CanonicalPose::TPose)?;
    Ok((pose, bones))
}

/// Every training view of every training frame, cropped to the body, posed as the NeRF renders it, with
/// the mask-edge band the silhouette term leaves out.
fn training_shots(model: &AnimatableNerf, exp: &Experiment) -> Result<Vec<Shot>> {
    let mut shots = Vec::new();
    for &frame in &exp.train_frames {
        let (pose, bones) = frame_bones(model, exp, frame)?;
        let corners = exp.frame_bounds(frame)?.corners();
        for &view in &exp.train_views {
            let camera = &exp.prepared.cameras[view.0];
            let (mask, band) = exp.prepared.mask_and_edge(frame, view)?;
            shots.push(Shot::crop(
                camera,
                &corners,
                &exp.prepared.image(frame, view)?,
                (&mask, &band),
                pose.global,
                bones.clone(),
            ));
        }
    }
    Ok(shots)
}

/// A baked avatar ready to draw: on the host where the run computes on the CPU (projected with glam and
/// rasterised by the CPU kernel directly, no tensor operations), as tensors on GPU backends (the
/// differentiable projection and the device's rasteriser).
pub struct DeviceAvatar {
    form: Form,
}

enum Form {
    Host(BakedAvatar),
    Tensors {
        cloud: GaussianCloud,
        /// Dense blend weights `[N, K]`.
        skin: Tensor<2>,
    },
}

impl DeviceAvatar {
    /// `avatar` made ready on `device`.
    pub fn new(avatar: &BakedAvatar, device: &Device) -> Self {
        let form = if anerf_device::runs_on_gpu(device) {
            Form::Tensors {
                cloud: avatar.cloud(device),
                skin: avatar.skin(device),
            }
        } else {
            Form::Host(avatar.clone())
        };
        Self { form }
    }

    /// The Gaussians posed by `bones` (canonical → pose space) and `global` (pose space → world) seen by
    /// `camera`: `[H·W]` row-major colour on black and opacity, on the host. What a real-time viewer pays
    /// per image (posing, projection, rasterisation, read-back).
    pub fn pixels(
        &self,
        bones: &BoneTransforms,
        global: &GlobalTransform,
        camera: &Camera,
    ) -> Vec<[f32; 4]> {
        let view = SplatView {
            camera,
            global,
            convention: PixelConvention::Integer,
        };
        let flat = match &self.form {
            Form::Host(avatar) => {
                let rows = project_host(&avatar.host_cloud(), bones, &view);
                let spec = view.spec();
                let mut out = vec![0.0; spec.pixels() * PIXEL_WIDTH];
                splat::cpu::forward(&rows, &spec, &mut out);
                out
            }
            Form::Tensors { cloud, skin } => {
                let device = skin.device();
                to_host(render(
                    cloud,
                    skin.clone(),
                    &BoneMatrices::new(bones, &device),
                    &view,
                ))
            }
        };
        flat.chunks_exact(PIXEL_WIDTH)
            .map(|p| [p[0], p[1], p[2], p[3]])
            .collect()
    }
}

/// The run's baked avatar, read and checked.
pub fn load_baked(run: &anerf_train::run_dir::RunDir) -> Result<BakedAvatar> {
    BakedAvatar::load(&run.baked()).with_context(|| {
        format!(
            "the baked avatar of {} (`anerf bake` makes it)",
            run.root.display()
        )
    })
}

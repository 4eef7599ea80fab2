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

use anerf_core::gaussians::{render, GaussianCloud, SplatView};
use anerf_core::geometry::{
    BoneMatrices, BoneTransforms, Camera, CanonicalPose, PixelConvention, Pose,
};
use anerf_core::model::AnimatableNerf;
use anerf_core::tensor::to_host;
use anerf_core::{FrameId, ViewId};
use anerf_train::render::RenderedImage;
use anyhow::{bail, Context, Result};
use burn::prelude::{Device, Tensor};

use crate::memory::Work;
use crate::mesh::{canonical_surface, MeshJob};
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
    let surface = canonical_surface(&model, &exp, &job.surface).context(
        "the canonical surface the Gaussians start on (a run whose model has no density above the iso \
         level cannot be baked)",
    )?;
    let source = restored
        .checkpoint
        .dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let probes = init::probe_along_normals(
        &model,
        exp.canonical(),
        &surface.mesh.vertices,
        &surface.mesh.vertex_normals(),
        exp.train_frames.len() / 2,
        exp.config.eval.chunk,
    );
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
fn frame_bones(
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

/// Every training view of every training frame, cropped to the body, posed as the NeRF renders it.
fn training_shots(model: &AnimatableNerf, exp: &Experiment) -> Result<Vec<Shot>> {
    let mut shots = Vec::new();
    for &frame in &exp.train_frames {
        let (pose, bones) = frame_bones(model, exp, frame)?;
        let corners = exp.frame_bounds(frame)?.corners();
        for &view in &exp.train_views {
            let camera = &exp.prepared.cameras[view.0];
            shots.push(Shot::crop(
                camera,
                &corners,
                &exp.prepared.image(frame, view)?,
                &exp.prepared.mask(frame, view)?,
                pose.global,
                bones.clone(),
            ));
        }
    }
    Ok(shots)
}

/// A baked avatar on a device, ready to render.
pub struct DeviceAvatar {
    pub cloud: GaussianCloud,
    /// Dense blend weights `[N, K]`.
    pub skin: Tensor<2>,
}

impl DeviceAvatar {
    /// Uploads `avatar` to `device`.
    pub fn new(avatar: &BakedAvatar, device: &Device) -> Self {
        Self {
            cloud: avatar.cloud(device),
            skin: avatar.skin(device),
        }
    }
}

/// The avatar at frame `frame`'s pose (the refined fit where the model refines training frames) seen by
/// `camera`: `[H·W, 4]` row-major colour on black and opacity, on the host. What a real-time viewer pays
/// per image (posing, projection, rasterisation, read-back).
pub fn render_pixels(
    avatar: &DeviceAvatar,
    model: &AnimatableNerf,
    exp: &Experiment,
    frame: FrameId,
    camera: &Camera,
) -> Result<Vec<f32>> {
    let (pose, bones) = frame_bones(model, exp, frame)?;
    let view = SplatView {
        camera,
        global: &pose.global,
        convention: PixelConvention::Integer,
    };
    let device = avatar.skin.device();
    Ok(to_host(render(
        &avatar.cloud,
        avatar.skin.clone(),
        &BoneMatrices::new(&bones, &device),
        &view,
    )))
}

/// Renders frame `frame` of the experiment with the baked avatar, as [`anerf_train::render::render_view`]
/// renders it with the NeRF: the same pose (the refined fit where the model refines training frames), the
/// same pixels (those whose ray meets the body's box; black elsewhere) and the same ground truth.
pub fn render_view(
    avatar: &DeviceAvatar,
    model: &AnimatableNerf,
    exp: &Experiment,
    frame: FrameId,
    camera: &Camera,
    view: Option<ViewId>,
) -> Result<RenderedImage> {
    let images = match view {
        Some(v) => Some((exp.prepared.image(frame, v)?, exp.prepared.mask(frame, v)?)),
        None => None,
    };
    let options = anerf_data::SamplerOptions::default();
    let rays = anerf_data::image_rays(
        camera,
        &exp.frame_bounds(frame)?,
        images.as_ref().map(|(i, m)| (i, m)),
        &options,
    )
    .context("the pixels the body's box covers")?;
    debug_assert_eq!(options.convention, PixelConvention::Integer);
    let pixels = render_pixels(avatar, model, exp, frame, camera)?;
    let width = rays.width;
    let shaded: Vec<[f32; 4]> = rays
        .rays
        .pixels
        .iter()
        .map(|&[u, v]| {
            let i = 4 * (v * width + u) as usize;
            [pixels[i], pixels[i + 1], pixels[i + 2], pixels[i + 3]]
        })
        .collect();
    Ok(RenderedImage::from_rays(
        rays,
        images.as_ref().map(|(_, m)| m),
        &shaded,
    ))
}

/// The avatar posed by `pose` (through `skeleton`'s bones) seen by `camera`, on black.
pub fn render_pose(
    avatar: &DeviceAvatar,
    skeleton: &anerf_core::geometry::Skeleton,
    pose: &Pose,
    camera: &Camera,
) -> Result<image::Rgb32FImage> {
    let bones = skeleton.bone_transforms(pose, CanonicalPose::TPose)?;
    let view = SplatView {
        camera,
        global: &pose.global,
        convention: PixelConvention::Integer,
    };
    let device = avatar.skin.device();
    let pixels = to_host(render(
        &avatar.cloud,
        avatar.skin.clone(),
        &BoneMatrices::new(&bones, &device),
        &view,
    ));
    let rgb: Vec<f32> = pixels
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    image::Rgb32FImage::from_raw(camera.width, camera.height, rgb)
        .context("an image of the camera's size")
}

/// `request`'s motion played by the run's baked avatar: no stage-2 fit, the Gaussians carry their skin.
/// Returns the output name, the images and their frame rate.
pub(crate) fn render_motion(
    run: &anerf_train::run_dir::RunDir,
    config: anerf_train::config::ExperimentConfig,
    request: &crate::motion::MotionRequest,
    camera: crate::motion::MotionCamera,
    size: Option<u32>,
    options: &JobOptions,
) -> Result<(String, Vec<image::Rgb32FImage>, f64)> {
    let device = device(&config, options)?;
    let avatar = DeviceAvatar::new(&load_baked(run)?, &device);
    let exp = Experiment::open(config, device, options.progress)?;
    let seen = crate::motion::MotionView::new(&exp, camera, size)?;
    let clip = crate::motion::MotionClip::new(request, &exp, seen.view)?;
    let skeleton = &exp.prepared.skeleton;
    let n = clip.poses.len();
    let bar = options.bar("render", n);
    let mut images = Vec::with_capacity(n);
    for (i, pose) in clip.poses.iter().enumerate() {
        let bones = skeleton.bone_transforms(pose, CanonicalPose::TPose)?;
        let joints: Vec<glam::Vec3> = skeleton
            .rest_joints()
            .iter()
            .zip(bones.matrices())
            .map(|(j, a)| pose.global.pose_to_world(a.transform_point3(*j)))
            .collect();
        let center = joints.iter().sum::<glam::Vec3>() / joints.len().max(1) as f32;
        let image = render_pose(&avatar, skeleton, pose, &seen.camera(i, n, center))
            .with_context(|| format!("rendering frame {i} of motion {}", clip.name))?;
        images.push(image);
        bar.set_step(i + 1);
    }
    bar.finish(n, "finished");
    Ok((format!("baked_{}", seen.name(&clip.name)), images, clip.fps))
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

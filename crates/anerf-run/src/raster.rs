//! The avatars drawn by a rasteriser (the baked Gaussians, the exported mesh), posed by their own skin, and
//! their images on the NeRF's terms: the pixels whose ray meets the frame's body box keep what was drawn
//! there, the others are black, with the dataset's ground truth and mask, so that `eval` and `render` treat
//! them as they treat the NeRF's renders.

use anerf_core::geometry::{
    BoneTransforms, Camera, CanonicalPose, GlobalTransform, PixelConvention,
};
use anerf_core::model::AnimatableNerf;
use anerf_core::{FrameId, ViewId};
use anerf_train::experiment::Experiment;
use anerf_train::render::RenderedImage;
use anerf_train::run_dir::RunDir;
use anyhow::{Context, Result};
use glam::Vec3;

use crate::bake::{self, DeviceAvatar};
use crate::mesh::SkinnedSurface;
use crate::motion::{MotionCamera, MotionClip, MotionRequest, MotionView};
use crate::{Avatar, JobOptions};

/// `pixels` (`[H·W]` row-major colour on black and opacity, drawn by `camera` with pixel centres at
/// integer coordinates) as [`anerf_train::render::render_view`] would give frame `frame`'s image: the same
/// pixels (those whose ray meets the body's box) and, for a dataset `view`, the same ground truth.
pub fn boxed_image(
    exp: &Experiment,
    frame: FrameId,
    camera: &Camera,
    view: Option<ViewId>,
    pixels: &[[f32; 4]],
) -> Result<RenderedImage> {
    let images = match view {
        Some(v) => Some((exp.prepared.image(frame, v)?, exp.prepared.mask(frame, v)?)),
        None => None,
    };
    let options = anerf_data::SamplerOptions::default();
    debug_assert_eq!(options.convention, PixelConvention::Integer);
    let rays = anerf_data::image_rays(
        camera,
        &exp.frame_bounds(frame)?,
        images.as_ref().map(|(i, m)| (i, m)),
        &options,
    )
    .context("the pixels the body's box covers")?;
    let width = rays.width;
    let shaded: Vec<[f32; 4]> = rays
        .rays
        .pixels
        .iter()
        .map(|&[u, v]| pixels[(v * width + u) as usize])
        .collect();
    Ok(RenderedImage::from_rays(
        rays,
        images.as_ref().map(|(_, m)| m),
        &shaded,
    ))
}

/// An avatar posed by its own canonical skin, so that novel poses and motions need no stage-2 field: the
/// Gaussians of `anerf bake` or the vertex-coloured mesh of `anerf export`.
pub(crate) enum Skinned {
    Gaussians(DeviceAvatar),
    Mesh(SkinnedSurface),
}

impl Skinned {
    /// `avatar`'s skinned form for the run (`None` for the NeRF).
    pub fn open(
        avatar: Avatar,
        run: &RunDir,
        model: &AnimatableNerf,
        exp: &Experiment,
    ) -> Result<Option<Self>> {
        Ok(match avatar {
            Avatar::Nerf => None,
            Avatar::Baked => Some(Self::Gaussians(DeviceAvatar::new(
                &bake::load_baked(run)?,
                &model.device(),
            ))),
            Avatar::Mesh(surface) => Some(Self::Mesh(
                SkinnedSurface::extract(model, exp, &surface.job())
                    .context("the exported mesh (`anerf export` extracts it the same way)")?,
            )),
        })
    }

    /// The start of its output names: `baked_` or `mesh_`.
    pub fn prefix(&self) -> &'static str {
        match self {
            Self::Gaussians(_) => "baked_",
            Self::Mesh(_) => "mesh_",
        }
    }

    /// The avatar posed by `bones` (canonical → pose space) and `global` (pose space → world) seen by
    /// `camera`: `[H·W]` row-major colour on black and opacity.
    pub fn pixels(
        &self,
        bones: &BoneTransforms,
        global: &GlobalTransform,
        camera: &Camera,
    ) -> Result<Vec<[f32; 4]>> {
        match self {
            Self::Gaussians(g) => Ok(g.pixels(bones, global, camera)),
            Self::Mesh(m) => m.pixels(bones, global, camera),
        }
    }

    /// Frame `frame` of the experiment as [`anerf_train::render::render_view`] renders it with the NeRF:
    /// the same pose (the refined fit where the model refines training frames), pixels and ground truth.
    pub fn view(
        &self,
        model: &AnimatableNerf,
        exp: &Experiment,
        frame: FrameId,
        camera: &Camera,
        view: Option<ViewId>,
    ) -> Result<RenderedImage> {
        let (pose, bones) = bake::frame_bones(model, exp, frame)?;
        let pixels = self.pixels(&bones, &pose.global, camera)?;
        boxed_image(exp, frame, camera, view, &pixels)
    }
}

/// `request`'s motion played by a skinned avatar (no stage-2 fit): the output name, the images (colour on
/// black) and their frame rate.
pub(crate) fn skinned_motion(
    avatar: &Skinned,
    exp: &Experiment,
    request: &MotionRequest,
    camera: MotionCamera,
    size: Option<u32>,
    options: &JobOptions,
) -> Result<(String, Vec<image::Rgb32FImage>, f64)> {
    let seen = MotionView::new(exp, camera, size)?;
    let clip = MotionClip::new(request, exp, seen.view)?;
    let skeleton = &exp.prepared.skeleton;
    let n = clip.poses.len();
    let bar = options.bar("render", n);
    let mut images = Vec::with_capacity(n);
    for (i, pose) in clip.poses.iter().enumerate() {
        let bones = skeleton.bone_transforms(pose, CanonicalPose::TPose)?;
        let joints: Vec<Vec3> = skeleton
            .rest_joints()
            .iter()
            .zip(bones.matrices())
            .map(|(j, a)| pose.global.pose_to_world(a.transform_point3(*j)))
            .collect();
        let center = joints.iter().sum::<Vec3>() / joints.len().max(1) as f32;
        let camera = seen.camera(i, n, center);
        let pixels = avatar
            .pixels(&bones, &pose.global, &camera)
            .with_context(|| format!("rendering frame {i} of motion {}", clip.name))?;
        let rgb: Vec<f32> = pixels.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
        images.push(
            image::Rgb32FImage::from_raw(camera.width, camera.height, rgb)
                .context("an image of the camera's size")?,
        );
        bar.set_step(i + 1);
    }
    bar.finish(n, "finished");
    Ok((
        format!("{}{}", avatar.prefix(), seen.name(&clip.name)),
        images,
        clip.fps,
    ))
}

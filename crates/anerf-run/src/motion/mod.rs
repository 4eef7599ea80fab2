//! A motion on a run: its stage-2 field fitted once and stored (`anerf animate --motion`), then rendered
//! from a dataset camera or an orbiting one (`anerf render --motion`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anerf_core::model::AnimatableNerf;
use anerf_core::ViewId;
use anyhow::{Context, Result};
use burn::prelude::Device;

use crate::memory::Work;
use crate::{device, open_run, JobOptions};
use anerf_train::config::ExperimentConfig;
use anerf_train::experiment::Experiment;
use anerf_train::render::{render_shot, Shot};
use anerf_train::run_dir::RunDir;
use anerf_train::training::checkpoint::Checkpoint;
use anerf_train::training::fit_pose_codes;

mod clip;

pub use clip::{ClipTargets, MotionClip, MotionRequest, Place, StoredFit};

/// What `anerf animate --motion` did.
#[derive(Debug, Clone)]
pub struct FittedMotion {
    /// `<run>/motions/<name>-<key>/`.
    pub dir: PathBuf,
    pub frames: usize,
    /// True when a stored fit of the same poses was found and nothing was fitted.
    pub reused: bool,
    /// Seconds spent posing the frames (volumes) and fitting their field.
    pub seconds: f64,
}

/// Fits the stage-2 field of `request`'s frames (facing dataset camera `view` by default) and stores it in
/// the run, unless a fit of the same poses from the same stage-1 checkpoint is stored already.
pub fn animate_motion(
    run_path: &Path,
    request: &MotionRequest,
    view: Option<usize>,
    options: &JobOptions,
) -> Result<FittedMotion> {
    let (run, config) = open_run(run_path, options, Work::Animate)?;
    let device = device(&config, options)?.autodiff();
    let (model, checkpoint) = stage1(&run, &config, &device)?;
    let exp = Experiment::open(config, device.clone(), options.progress)?;
    let view = MotionView::new(&exp, MotionCamera::View(view), None)?.view;
    let clip = MotionClip::new(request, &exp, view)?;
    fit_clip(&run, &exp, model, &clip, request, &checkpoint, options)
}

/// Fits and stores `clip`'s field (or finds it stored) on `exp`'s autodiff device.
fn fit_clip(
    run: &RunDir,
    exp: &Experiment,
    model: AnimatableNerf,
    clip: &MotionClip,
    request: &MotionRequest,
    checkpoint: &str,
    options: &JobOptions,
) -> Result<FittedMotion> {
    let stored = StoredFit::new(&run.motions(), clip);
    let fitted = |reused, seconds| FittedMotion {
        dir: stored.dir.clone(),
        frames: clip.poses.len(),
        reused,
        seconds,
    };
    if stored
        .load(clip, checkpoint, model.clone(), &exp.device)?
        .is_some()
    {
        return Ok(fitted(true, 0.0));
    }
    let start = Instant::now();
    let model = fit_pose_codes(
        model,
        &mut ClipTargets::new(clip, exp),
        exp.canonical(),
        &exp.config.animate,
        exp.config.seed,
        options.progress,
    )?;
    stored.save(&model, clip, &request.path, checkpoint)?;
    Ok(fitted(false, start.elapsed().as_secs_f64()))
}

/// The camera a motion is seen from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionCamera {
    /// A dataset camera (default: the first training view).
    View(Option<usize>),
    /// The first training view's camera circling the body once over the clip.
    Orbit,
}

/// A rendered motion: its frames and the fit they used.
pub(crate) struct MotionFrames {
    pub name: String,
    pub fps: f64,
    pub images: Vec<image::Rgb32FImage>,
    pub fit: FittedMotion,
    /// Seconds spent rendering.
    pub seconds: f64,
}

/// Renders `request` on the run (fitting and storing its field first when none is stored).
pub(crate) fn render_motion(
    run: &RunDir,
    config: ExperimentConfig,
    request: &MotionRequest,
    camera: MotionCamera,
    size: Option<u32>,
    options: &JobOptions,
) -> Result<MotionFrames> {
    let device = device(&config, options)?;
    let (model, checkpoint) = stage1(run, &config, &device)?;
    let exp = Experiment::open(config.clone(), device.clone(), options.progress)?;
    let seen = MotionView::new(&exp, camera, size)?;
    let clip = MotionClip::new(request, &exp, seen.view)?;
    let stored = StoredFit::new(&run.motions(), &clip);
    let (model, fit) = match stored.load(&clip, &checkpoint, model.clone(), &device)? {
        Some(m) => (
            m,
            FittedMotion {
                dir: stored.dir.clone(),
                frames: clip.poses.len(),
                reused: true,
                seconds: 0.0,
            },
        ),
        None => {
            // Fitting takes gradients: on an autodiff device, then read back from the stored fit.
            let grad_device = device.clone().autodiff();
            let (grad_model, _) = stage1(run, &config, &grad_device)?;
            let grad_exp = Experiment::open(config, grad_device, false)?;
            let fit = fit_clip(
                run,
                &grad_exp,
                grad_model,
                &clip,
                request,
                &checkpoint,
                options,
            )?;
            let model = stored
                .load(&clip, &checkpoint, model, &device)?
                .context("the fit just stored does not read back")?;
            (model, fit)
        }
    };
    let start = Instant::now();
    let n = clip.poses.len();
    let bar = options.bar("render", n);
    let mut images = Vec::with_capacity(n);
    for i in 0..n {
        let target = clip.target(&exp, i, &device)?;
        let camera = seen.camera(i, n, (target.bounds.min + target.bounds.max) * 0.5);
        let shot = Shot {
            inputs: &target.inputs,
            bounds: target.bounds,
            camera: &camera,
            ground_truth: None,
        };
        let image = render_shot(&model, exp.canonical(), &shot, &exp.config.eval)
            .with_context(|| format!("rendering frame {i} of motion {}", clip.name))?;
        images.push(image.prediction);
        bar.set_step(i + 1);
        if (i + 1) % (n / 10).max(1) == 0 {
            bar.report(i + 1, "frames");
        }
    }
    bar.finish(n, "finished");
    Ok(MotionFrames {
        name: seen.name(&clip.name),
        fps: clip.fps,
        images,
        fit,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Where a motion's images are seen from: a dataset camera at the output size, fixed or circling the body
/// once over the clip.
pub struct MotionView {
    kind: MotionCamera,
    /// The dataset view the camera starts from (and the body faces by default).
    pub view: ViewId,
    reference: anerf_core::geometry::Camera,
    /// The world's up (the cameras' mean), the axis an orbit turns about.
    up: glam::Vec3,
}

impl MotionView {
    /// `kind`'s camera in `exp` (a view must exist; the orbit starts at the first training view), resized to
    /// `size` pixels wide.
    pub(crate) fn new(exp: &Experiment, kind: MotionCamera, size: Option<u32>) -> Result<Self> {
        let view = match kind {
            MotionCamera::View(v) => v.unwrap_or(exp.train_views[0].0),
            MotionCamera::Orbit => exp.train_views[0].0,
        };
        let Some(camera) = exp.prepared.cameras.get(view) else {
            anyhow::bail!(
                "view {view} does not exist (the dataset has {} cameras)",
                exp.prepared.cameras.len()
            );
        };
        let reference = match size {
            Some(s) => camera.resized(s as f32 / camera.width as f32),
            None => camera.clone(),
        };
        Ok(Self {
            kind,
            view: ViewId(view),
            reference,
            up: anerf_core::geometry::mean_up(&exp.prepared.cameras),
        })
    }

    /// The camera of image `i` of `n`, the body's centre at `center` (world, metres).
    pub(crate) fn camera(
        &self,
        i: usize,
        n: usize,
        center: glam::Vec3,
    ) -> anerf_core::geometry::Camera {
        match self.kind {
            MotionCamera::View(_) => self.reference.clone(),
            MotionCamera::Orbit => anerf_core::geometry::orbit_camera(
                &self.reference,
                center,
                self.up,
                i as f32 / n as f32,
            ),
        }
    }

    /// The output name of clip `clip`'s images from this camera.
    pub(crate) fn name(&self, clip: &str) -> String {
        let suffix = match self.kind {
            MotionCamera::View(_) => format!("view{:02}", self.view.0),
            MotionCamera::Orbit => "orbit".into(),
        };
        format!("motion_{clip}_{suffix}")
    }
}

/// The run's newest intact stage-1 model and its checkpoint's name.
fn stage1(
    run: &RunDir,
    config: &ExperimentConfig,
    device: &Device,
) -> Result<(AnimatableNerf, String)> {
    let restored = Checkpoint::restore_stage1(run, &config.model, device)?;
    let name = restored
        .checkpoint
        .dir
        .file_name()
        .map_or(String::new(), |n| n.to_string_lossy().into_owned());
    Ok((restored.model, name))
}

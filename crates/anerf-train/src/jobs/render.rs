//! Rendering a run: an orbit around a dataset frame, the novel-pose frames, or the poses of pose files.

use std::path::{Path, PathBuf};

use anerf_core::model::AnimatableNerf;
use anerf_core::FrameId;
use anerf_eval::images::{write_gif, write_mp4, write_png, PngDepth, VideoOutcome};
use anyhow::{bail, Context, Result};

use super::{device, load_trained, open_run, JobOptions};
use crate::experiment::Experiment;
use crate::memory::Work;
use crate::render::{render_shot, render_view, Shot};
use crate::run_dir::RunDir;

/// What `anerf render` draws.
#[derive(Debug, Clone)]
pub enum RenderJob {
    /// `views` cameras orbiting dataset frame `frame` (default: the first training frame).
    Orbit {
        frame: Option<usize>,
        views: usize,
        size: Option<u32>,
    },
    /// Every novel-pose frame of the run from dataset camera `view` (needs stage 2).
    NovelPoses { view: usize },
    /// The poses of a pose file or folder (`params/{i}.npy` format) from dataset camera `view` (default:
    /// the first training view), after fitting their blend-weight codes as stage 2 does.
    PoseFiles { path: PathBuf, view: Option<usize> },
}

/// Dataset camera `view` at the working resolution.
fn dataset_camera(exp: &Experiment, view: usize) -> Result<anerf_core::geometry::Camera> {
    exp.prepared.cameras.get(view).cloned().with_context(|| {
        format!(
            "view {view} does not exist (the dataset has {} cameras)",
            exp.prepared.cameras.len()
        )
    })
}

/// What a render wrote under `<run>/renders/`.
#[derive(Debug, Clone)]
pub struct Rendered {
    /// The folder of PNG frames.
    pub dir: PathBuf,
    /// The animated GIF.
    pub gif: PathBuf,
    /// The MP4, written when ffmpeg is on PATH.
    pub mp4: Option<PathBuf>,
    /// Images rendered.
    pub frames: usize,
}

/// Renders `job`: PNG frames, an animated GIF and (with ffmpeg on PATH) an MP4 under `<run>/renders/`.
pub fn render(run_path: &Path, job: RenderJob, options: &JobOptions) -> Result<Rendered> {
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let device = device(&config, options)?;
    // Pose files need their blend-weight codes fitted first, which takes gradients.
    let device = match job {
        RenderJob::PoseFiles { .. } => device.autodiff(),
        _ => device,
    };
    let model = load_trained(&run, &config, &device)?;
    let mut exp = Experiment::open(config, device, options.progress)?;
    let (name, frames) = match job {
        RenderJob::PoseFiles { path, view } => {
            render_pose_files(model, &exp, &path, view, options)?
        }
        RenderJob::Orbit { frame, views, size } => {
            let (name, shots) = orbit_shots(&exp, &model, frame, views, size)?;
            (
                name,
                render_dataset_shots(&model, &mut exp, &shots, options)?,
            )
        }
        RenderJob::NovelPoses { view } => {
            let (name, shots) = novel_pose_shots(&exp, &model, &run, view)?;
            (
                name,
                render_dataset_shots(&model, &mut exp, &shots, options)?,
            )
        }
    };
    let dir = run.renders().join(&name);
    for (i, frame) in frames.iter().enumerate() {
        write_png(&dir.join(format!("{i:04}.png")), frame, PngDepth::Eight)?;
    }
    let gif = run.renders().join(format!("{name}.gif"));
    write_gif(&gif, &frames, 12)?;
    let mp4 = match write_mp4(&run.renders().join(format!("{name}.mp4")), &frames, 12)? {
        VideoOutcome::Written(path) => Some(path),
        _ => None,
    };
    Ok(Rendered {
        dir,
        gif,
        mp4,
        frames: frames.len(),
    })
}

/// Fits a stage-2 field for the poses of `path` and renders them from dataset camera `view` (default: the
/// first training view): the output name and the images.
fn render_pose_files(
    model: AnimatableNerf,
    exp: &Experiment,
    path: &Path,
    view: Option<usize>,
    options: &JobOptions,
) -> Result<(String, Vec<image::Rgb32FImage>)> {
    let view = view.unwrap_or(exp.train_views[0].0);
    let camera = dataset_camera(exp, view)?;
    let sequence = crate::poses::PoseSequence::load(path, &exp.prepared)?;
    let targets = sequence.targets(exp.novel_appearance(), &exp.device);
    let model = crate::training::fit_pose_codes(
        model,
        &targets,
        exp.canonical(),
        &exp.config.animate,
        exp.config.seed,
        options.progress,
    )?;
    let bar = options.bar("render", targets.len());
    let mut frames = Vec::with_capacity(targets.len());
    for (target, file) in targets.iter().zip(&sequence.files) {
        let shot = Shot {
            inputs: &target.inputs,
            bounds: target.bounds,
            camera: &camera,
            ground_truth: None,
        };
        let image = render_shot(&model, exp.canonical(), &shot, &exp.config.eval)
            .with_context(|| format!("rendering the pose of {}", file.display()))?;
        frames.push(image.prediction);
        bar.set_step(frames.len());
    }
    bar.finish(frames.len(), "finished");
    let stem = path
        .file_stem()
        .map_or("poses".into(), |s| s.to_string_lossy().into_owned());
    Ok((format!("poses_{stem}_view{view:02}"), frames))
}

/// A dataset frame seen by a camera.
type DatasetShot = (FrameId, anerf_core::geometry::Camera);

/// Renders dataset frames from cameras (no ground truth).
fn render_dataset_shots(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    shots: &[DatasetShot],
    options: &JobOptions,
) -> Result<Vec<image::Rgb32FImage>> {
    let bar = options.bar("render", shots.len());
    let mut frames = Vec::with_capacity(shots.len());
    for (frame, camera) in shots {
        frames.push(render_view(model, exp, *frame, camera, None)?.prediction);
        bar.set_step(frames.len());
    }
    bar.finish(frames.len(), "finished");
    Ok(frames)
}

/// The output name and cameras of an orbit around dataset frame `frame` (default: the first training one).
fn orbit_shots(
    exp: &Experiment,
    model: &AnimatableNerf,
    frame: Option<usize>,
    views: usize,
    size: Option<u32>,
) -> Result<(String, Vec<DatasetShot>)> {
    let frame = frame.map(FrameId).unwrap_or(exp.train_frames[0]);
    exp.check_renderable(frame, model)?;
    let bounds = exp.frame_bounds(frame)?;
    let mut reference = exp.prepared.cameras[exp.train_views[0].0].clone();
    if let Some(s) = size {
        reference = reference.resized(s as f32 / reference.width as f32);
    }
    let up = crate::render::mean_up(&exp.prepared.cameras);
    let center = (bounds.min + bounds.max) * 0.5;
    let cams = crate::render::orbit(&reference, center, up, views.max(1));
    Ok((
        format!("orbit_frame{:06}", frame.0),
        cams.into_iter().map(|c| (frame, c)).collect(),
    ))
}

/// The output name and shots of the run's novel-pose frames from dataset camera `view`.
fn novel_pose_shots(
    exp: &Experiment,
    model: &AnimatableNerf,
    run: &RunDir,
    view: usize,
) -> Result<(String, Vec<DatasetShot>)> {
    if model.novel_blend.is_none() {
        bail!(
            "{} has no stage-2 checkpoint; run `anerf animate` first",
            run.root.display()
        );
    }
    let camera = dataset_camera(exp, view)?;
    Ok((
        format!("novel_poses_view{view:02}"),
        exp.novel_frames
            .iter()
            .map(|&f| (f, camera.clone()))
            .collect(),
    ))
}

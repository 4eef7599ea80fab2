//! Rendering a run: an orbit around a dataset frame, the novel-pose frames, or a motion.

use std::path::{Path, PathBuf};

use anerf_core::model::AnimatableNerf;
use anerf_core::FrameId;
use anerf_eval::images::{write_gif, write_mp4, write_png, PngDepth, VideoOutcome};
use anyhow::{bail, Context, Result};

use crate::memory::Work;
use crate::motion::MotionRequest;
use crate::motion::{render_motion, MotionCamera, MotionFrames};
use crate::raster::{skinned_motion, Skinned};
use crate::Avatar;
use crate::{device, load_trained, open_run, JobOptions};
use anerf_train::experiment::Experiment;
use anerf_train::render::render_view;
use anerf_train::run_dir::RunDir;

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
    /// A motion (any file [`anerf_data::motion::Motion::read`] reads), its stage-2 field fitted and
    /// stored first when the run has none for its poses.
    Motion {
        request: MotionRequest,
        camera: MotionCamera,
        size: Option<u32>,
    },
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

/// Renders `job` with `avatar`: PNG frames, an animated GIF and (with ffmpeg on PATH) an MP4 under
/// `<run>/renders/` (the baked avatar's names start with `baked_`, the mesh's with `mesh_`). The skinned
/// avatars play novel poses and motions without a stage-2 field.
pub fn render(
    run_path: &Path,
    job: RenderJob,
    avatar: Avatar,
    options: &JobOptions,
) -> Result<Rendered> {
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let (name, frames, fps) = match (job, avatar) {
        (
            RenderJob::Motion {
                request,
                camera,
                size,
            },
            Avatar::Nerf,
        ) => {
            let m = render_motion(&run, config, &request, camera, size, options)?;
            report_motion(&m);
            (m.name, m.images, m.fps)
        }
        (
            RenderJob::Motion {
                request,
                camera,
                size,
            },
            avatar,
        ) => {
            let (_, exp, skinned) = open_model(&run, config, avatar, options)?;
            let skinned = skinned.expect("a skinned avatar");
            skinned_motion(&skinned, &exp, &request, camera, size, options)?
        }
        (RenderJob::Orbit { frame, views, size }, avatar) => {
            let (model, mut exp, skinned) = open_model(&run, config, avatar, options)?;
            let (name, shots) = orbit_shots(&exp, &model, skinned.is_some(), frame, views, size)?;
            let frames = render_dataset_shots(&model, &mut exp, skinned.as_ref(), &shots, options)?;
            (prefixed(name, &skinned), frames, 12.0)
        }
        (RenderJob::NovelPoses { view }, avatar) => {
            let (model, mut exp, skinned) = open_model(&run, config, avatar, options)?;
            let (name, shots) = novel_pose_shots(&exp, &model, &run, skinned.is_some(), view)?;
            let frames = render_dataset_shots(&model, &mut exp, skinned.as_ref(), &shots, options)?;
            (prefixed(name, &skinned), frames, 12.0)
        }
    };
    let dir = run.renders().join(&name);
    for (i, frame) in frames.iter().enumerate() {
        write_png(&dir.join(format!("{i:04}.png")), frame, PngDepth::Eight)?;
    }
    let fps = (fps.round() as u32).max(1);
    let gif = run.renders().join(format!("{name}.gif"));
    write_gif(&gif, &frames, fps)?;
    let mp4 = match write_mp4(&run.renders().join(format!("{name}.mp4")), &frames, fps)? {
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

/// The run's trained model, its experiment and, for a skinned `avatar`, that avatar.
fn open_model(
    run: &RunDir,
    config: anerf_train::config::ExperimentConfig,
    avatar: Avatar,
    options: &JobOptions,
) -> Result<(AnimatableNerf, Experiment, Option<Skinned>)> {
    let device = device(&config, options)?;
    let model = load_trained(run, &config, &device)?;
    let exp = Experiment::open(config, device, options.progress)?;
    let skinned = Skinned::open(avatar, run, &model, &exp)?;
    Ok((model, exp, skinned))
}

/// A render's output name, with the skinned avatar's prefix.
fn prefixed(name: String, skinned: &Option<Skinned>) -> String {
    match skinned {
        Some(s) => format!("{}{name}", s.prefix()),
        None => name,
    }
}

/// Prints what a motion render cost, per frame.
fn report_motion(m: &MotionFrames) {
    let n = m.images.len().max(1) as f64;
    let fit = if m.fit.reused {
        format!("stored fit {}", m.fit.dir.display())
    } else {
        format!(
            "fitted in {:.1} s ({:.2} s/frame), stored in {}",
            m.fit.seconds,
            m.fit.seconds / n,
            m.fit.dir.display()
        )
    };
    eprintln!(
        "motion: {} frames at {} fps; {fit}; rendered in {:.1} s ({:.2} s/frame)",
        m.images.len(),
        m.fps,
        m.seconds,
        m.seconds / n
    );
}

/// A dataset frame seen by a camera.
type DatasetShot = (FrameId, anerf_core::geometry::Camera);

/// Renders dataset frames from cameras (no ground truth), with the NeRF or a `skinned` avatar.
fn render_dataset_shots(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    skinned: Option<&Skinned>,
    shots: &[DatasetShot],
    options: &JobOptions,
) -> Result<Vec<image::Rgb32FImage>> {
    let bar = options.bar("render", shots.len());
    let mut frames = Vec::with_capacity(shots.len());
    for (frame, camera) in shots {
        let image = match skinned {
            Some(avatar) => avatar.view(model, exp, *frame, camera, None)?,
            None => render_view(model, exp, *frame, camera, None)?,
        };
        frames.push(image.prediction);
        bar.set_step(frames.len());
    }
    bar.finish(frames.len(), "finished");
    Ok(frames)
}

/// The output name and cameras of an orbit around dataset frame `frame` (default: the first training one).
/// `skinned`: a skinned avatar renders novel poses without a stage-2 field.
fn orbit_shots(
    exp: &Experiment,
    model: &AnimatableNerf,
    skinned: bool,
    frame: Option<usize>,
    views: usize,
    size: Option<u32>,
) -> Result<(String, Vec<DatasetShot>)> {
    let frame = frame.map(FrameId).unwrap_or(exp.train_frames[0]);
    if skinned {
        exp.frame_code(frame)?;
    } else {
        exp.check_renderable(frame, model)?;
    }
    let bounds = exp.frame_bounds(frame)?;
    let mut reference = exp.prepared.cameras[exp.train_views[0].0].clone();
    if let Some(s) = size {
        reference = reference.resized(s as f32 / reference.width as f32);
    }
    let up = anerf_core::geometry::mean_up(&exp.prepared.cameras);
    let center = (bounds.min + bounds.max) * 0.5;
    let cams = anerf_core::geometry::orbit(&reference, center, up, views.max(1));
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
    skinned: bool,
    view: usize,
) -> Result<(String, Vec<DatasetShot>)> {
    if !skinned && model.novel_blend.is_none() {
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

//! Evaluating a run with the paper's protocol: every test view of every `eval.frame_interval`-th frame of
//! a split, rendered and compared within the body's box.

use std::path::{Path, PathBuf};

use anerf_core::named::Named;
use anerf_core::FrameId;
use anerf_eval::report::{EvalRecorder, EvalSplit, Summary};
use anerf_eval::silhouette::Silhouettes;
use anyhow::{bail, Result};

use crate::memory::Work;
use crate::mesh::MeshJob;
use crate::raster::Skinned;
use crate::{device, load_trained, open_run, JobOptions};
use anerf_train::experiment::Experiment;
use anerf_train::render::render_view;

/// What an evaluation wrote.
#[derive(Debug, Clone)]
pub struct Evaluated {
    /// The run's experiment name.
    pub name: String,
    pub summary: Summary,
    /// `<run>/eval/<split>/`: per-image metrics, images and the summary.
    pub dir: PathBuf,
}

/// Which form of the avatar an evaluation renders.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Avatar {
    /// The NeRF (results in `<run>/eval/<split>/`).
    Nerf,
    /// The Gaussians of `anerf bake` (results in `<run>/baked/eval/<split>/`).
    Baked,
    /// The vertex-coloured mesh `anerf export` writes into the glb, extracted with these settings (results
    /// in `<run>/meshes/eval/<split>/`).
    Mesh(Surface),
}

/// How a canonical surface is extracted: voxel (metres), iso level on raw density, Taubin smoothing steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    pub voxel: f32,
    pub level: f32,
    pub smooth: usize,
}

impl Surface {
    /// A mesh job of these settings with no frames to repose.
    pub fn job(&self) -> MeshJob {
        MeshJob {
            voxel: self.voxel,
            level: self.level,
            smooth: self.smooth,
            frames: Vec::new(),
            posed_frames: Vec::new(),
            carve: true,
        }
    }
}

/// Renders the views of `split` with `avatar` and writes its evaluation folder.
pub fn eval(
    run_path: &Path,
    split: EvalSplit,
    avatar: Avatar,
    options: &JobOptions,
) -> Result<Evaluated> {
    let (run, config) = open_run(run_path, options, Work::Render)?;
    let device = device(&config, options)?;
    let model = load_trained(&run, &config, &device)?;
    let mut exp = Experiment::open(config, device, options.progress)?;
    let skinned = Skinned::open(avatar, &run, &model, &exp)?;
    let frames: Vec<FrameId> = match split {
        EvalSplit::TrainingView | EvalSplit::NovelView => exp.train_frames.clone(),
        EvalSplit::NovelPose => {
            // The Gaussians and the mesh are posed by their own canonical skin: no stage-2 field is needed.
            if skinned.is_none() && model.novel_blend.is_none() {
                bail!(
                    "{} has no stage-2 checkpoint; run `anerf animate {}` before a novel-pose evaluation",
                    run.root.display(),
                    run.root.display()
                );
            }
            exp.novel_frames.clone()
        }
    };
    let frames: Vec<FrameId> = frames
        .into_iter()
        .step_by(exp.config.eval.frame_interval)
        .collect();
    let views = match split {
        EvalSplit::TrainingView => exp.train_views.clone(),
        EvalSplit::NovelView | EvalSplit::NovelPose => exp.test_views.clone(),
    };
    if frames.is_empty() || views.is_empty() {
        bail!(
            "the {split} split of {} has no frames or no test views",
            run.root.display()
        );
    }
    let dir = match avatar {
        Avatar::Nerf => run.eval(),
        Avatar::Baked => run.baked().join("eval"),
        Avatar::Mesh(_) => run.meshes().join("eval"),
    }
    .join(split.name());
    let mut recorder = EvalRecorder::new(&dir, split);
    let bar = options.bar("eval", frames.len() * views.len());
    let mut done = 0;
    for &frame in &frames {
        for &view in &views {
            let camera = exp.prepared.cameras[view.0].clone();
            let image = match &skinned {
                Some(avatar) => avatar.view(&model, &exp, frame, &camera, Some(view))?,
                None => render_view(&model, &mut exp, frame, &camera, Some(view))?,
            };
            let gt = image
                .ground_truth
                .as_ref()
                .expect("dataset views have images");
            let silhouettes = image.silhouette.as_ref().map(|truth| Silhouettes {
                truth,
                opacity: &image.opacity,
            });
            recorder.add(
                frame,
                view,
                &image.prediction,
                gt,
                &image.mask,
                silhouettes.as_ref(),
            )?;
            done += 1;
            bar.set_step(done);
        }
    }
    bar.finish(done, "finished");
    Ok(Evaluated {
        name: exp.config.name.clone(),
        summary: recorder.finish()?,
        dir,
    })
}

//! The optimisation loops: one driver (`driver`) that owns stopping, logging windows, checkpoint
//! cadence, validation and progress, and one step per fit — stage 1 fits the canonical radiance field
//! and the blend-weight fields to the training video (`stage1`); stage 2 fits blend-weight fields for
//! novel poses against the frozen canonical field, for the run's novel-pose frames or for poses from
//! files (`stage2`). Stage 1's loss is `objective`'s; a stage-1 fit on several devices runs data-parallel
//! (`parallel`).

pub mod body_silhouette;
pub mod checkpoint;
mod driver;
mod loop_state;
pub mod objective;
mod parallel;
pub mod schedule;
pub mod seeds;
mod stage1;
mod stage2;
pub mod window;

use anerf_core::model::{AnimatableNerf, ModelConfig};
use anyhow::{bail, Context, Result};
use burn::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::prelude::Device;

pub use loop_state::LoopState;
pub use stage1::train_stage1;
pub use stage2::{fit_pose_codes, train_stage2, PoseTarget, PoseTargets};

use crate::experiment::Experiment;
use crate::run_dir::RunDir;
use crate::stage::Stage;
use checkpoint::{Checkpoint, TrainerState};

/// How a stage runs.
#[derive(Debug, Clone, Copy)]
pub struct TrainOptions {
    /// Continue from the stage's latest checkpoint.
    pub resume: bool,
    /// Draw a progress bar on stderr.
    pub progress: bool,
    /// Stop (with a checkpoint) after this many steps of this invocation, e.g. to split a run into sessions.
    pub max_steps: Option<usize>,
}

/// How a stage ended.
#[derive(Debug, Clone, PartialEq)]
pub struct StageOutcome {
    /// Steps completed in total (including those before a resume).
    pub steps: usize,
    /// Loss of the last step (NaN when no step ran).
    pub loss: f32,
    /// True when stopped before the last iteration (Ctrl-C or `max_steps`; a checkpoint was written).
    pub interrupted: bool,
    pub seconds: f64,
}

/// The optimiser of every fit: Adam with ε = 1e-8, gradient values clipped to ±`grad_clip` (0: none).
pub fn optimizer(grad_clip: f32) -> ModuleOptimizer {
    let clip = (grad_clip > 0.0).then_some(GradientClippingConfig::Value(grad_clip));
    AdamConfig::new()
        .with_epsilon(1e-8)
        .with_grad_clipping(clip)
        .init()
}

/// The model, optimiser and state of `stage`'s newest intact checkpoint, to resume from; an error when the
/// stage has none.
fn resume_point(
    run: &RunDir,
    stage: Stage,
    model: &ModelConfig,
    grad_clip: f32,
    device: &Device,
) -> Result<(AnimatableNerf, ModuleOptimizer, TrainerState)> {
    let r = Checkpoint::restore_newest(
        &run.checkpoints(),
        stage,
        model,
        device,
        Some(&|| optimizer(grad_clip)),
    )?
    .with_context(|| {
        format!(
            "--resume: {} has no stage-{} checkpoint (start the stage without --resume)",
            run.root.display(),
            stage.number()
        )
    })?;
    Ok((r.model, r.optim.expect("asked for the optimiser"), r.state))
}

/// Fails when a checkpoint's model was sized for other frames or joints than the experiment selects.
fn check_sizes(state: &TrainerState, exp: &Experiment) -> Result<()> {
    let sizes = exp.model_sizes();
    if state.training_frames != sizes.training_frames || state.joints != sizes.joints {
        bail!(
            "the checkpoint was trained on {} frames and {} joints, the config selects {} frames and {} joints",
            state.training_frames,
            state.joints,
            sizes.training_frames,
            sizes.joints
        );
    }
    Ok(())
}

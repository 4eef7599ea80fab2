//! Stage 2: blend-weight fields for poses the canonical field was not trained on, fitted with every
//! stage-1 parameter frozen — for the run's novel-pose frames ([`train_stage2`], recorded in the run) or
//! for poses from files ([`fit_pose_codes`], nothing written).

use std::sync::atomic::AtomicBool;

use anerf_core::geometry::skinning::points_tensor;
use anerf_core::geometry::Aabb;
use anerf_core::model::{AnimatableNerf, CanonicalInputs, FrameInputs};
use anerf_core::tensor::to_host;
use anyhow::{bail, Result};
use burn::prelude::*;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::checkpoint::{Checkpoint, TrainerState};
use super::driver::{drive, Record, RenderFigures, Single, Step};
use super::loop_state::LoopState;
use super::objective::Stage2Objective;
use super::seeds::{stream_seed, Stream};
use super::window::{StepValues, WindowMeans};
use super::{check_sizes, optimizer, resume_point, StageOutcome, TrainOptions};
use crate::config::StageConfig;
use crate::experiment::Experiment;
use crate::run_dir::RunDir;
use crate::stage::Stage;

/// A pose stage 2 fits a blend-weight code for: its model inputs (`code` =
/// [`anerf_core::model::FrameCode::Novel`]) and the world-space box around its body (metres).
#[derive(Debug, Clone)]
pub struct PoseTarget {
    pub inputs: FrameInputs,
    pub bounds: Aabb,
}

/// Stage 2: fits novel-pose blend-weight fields (starting from the latest stage-1 checkpoint, or resuming
/// stage 2) with every stage-1 parameter frozen.
pub fn train_stage2(
    exp: &mut Experiment,
    run: &RunDir,
    options: TrainOptions,
    stop: &AtomicBool,
) -> Result<StageOutcome> {
    let cfg = exp.config.animate.clone();
    let model_cfg = exp.config.model.clone();
    let device = exp.device.clone();
    if exp.novel_frames.is_empty() {
        bail!("the config selects no novel-pose frames (dataset.*.novel_pose_frames); nothing to animate");
    }
    let (model, optim, mut state) = if options.resume {
        let (model, optim, state) =
            resume_point(run, Stage::Animate, &model_cfg, cfg.grad_clip, &device)?;
        (model.freeze_stage1(), optim, state)
    } else {
        let stage1 = Checkpoint::restore_stage1(run, &model_cfg, &device)?;
        check_sizes(&stage1.state, exp)?;
        let seed = exp.config.seed;
        device.seed(stream_seed(seed, Stream::Stage2Device));
        let state = TrainerState {
            stage: Stage::Animate,
            counters: LoopState::default(),
            novel_frames: Some(exp.novel_frames.len()),
            sampler: None,
            rng: ChaCha8Rng::seed_from_u64(stream_seed(seed, Stream::Stage2Host)),
            ..stage1.state
        };
        let model = stage1
            .model
            .with_novel_field(exp.novel_frames.len(), &device);
        (model, optimizer(cfg.grad_clip), state)
    };
    if !model_cfg.neural_blend_weights {
        // Without the residual the novel-pose weights are the body model's: nothing to fit.
        state.counters.step = cfg.iterations;
        Checkpoint::save(&run.checkpoints(), &state, &model, &optim)?;
        eprintln!(
            "stage 2: model.neural_blend_weights = false, novel poses use the body model's weights"
        );
        return Ok(StageOutcome {
            steps: state.counters.step,
            loss: 0.0,
            interrupted: false,
            seconds: 0.0,
        });
    }
    let mut step = Stage2 {
        record: Record::open(run, Stage::Animate, state.counters.step)?,
        exp,
        cfg: &cfg,
        state,
    };
    let (_, outcome) = drive(&mut step, Single::new(model, optim), &cfg, options, stop)?;
    Ok(outcome)
}

/// A stage-2 step over the run's novel-pose frames.
struct Stage2<'a> {
    exp: &'a mut Experiment,
    cfg: &'a StageConfig,
    state: TrainerState,
    record: Record<'a>,
}

impl Step for Stage2<'_> {
    fn label(&self) -> &'static str {
        "stage 2"
    }

    fn counters(&mut self) -> &mut LoopState {
        &mut self.state.counters
    }

    fn loss(&mut self, model: &AnimatableNerf) -> Result<(Tensor<1>, StepValues)> {
        let exp = &mut *self.exp;
        let j = self.state.rng.random_range(0..exp.novel_frames.len());
        let frame = exp.novel_frames[j];
        let target = PoseTarget {
            inputs: exp.frame_inputs(frame)?,
            bounds: exp.frame_bounds(frame)?,
        };
        Ok(stage2_loss(
            model,
            &mut self.state.rng,
            self.cfg,
            &target,
            exp.canonical(),
        ))
    }

    fn figures(&self, means: &WindowMeans, _: Option<f64>) -> (Option<RenderFigures>, String) {
        let message = format!(
            "loss {:.6} {:.0} points/s",
            means.loss, means.items_per_second
        );
        (None, message)
    }

    fn record(&self) -> Option<(&Record<'_>, &TrainerState)> {
        Some((&self.record, &self.state))
    }
}

/// The stage-2 loss of `target` on `batch` points uniform in its world box (moved to pose space) and
/// `batch` uniform in the canonical box, plus `residual_weight` times the residual's penalty; with its
/// value on the host.
fn stage2_loss(
    model: &AnimatableNerf,
    rng: &mut ChaCha8Rng,
    cfg: &StageConfig,
    target: &PoseTarget,
    canonical: &CanonicalInputs,
) -> (Tensor<1>, StepValues) {
    let device = model.device();
    let global = target.inputs.global;
    let pose: Vec<Vec3> = uniform_in_box(rng, target.bounds, cfg.batch)
        .into_iter()
        .map(|p| global.world_to_pose(p))
        .collect();
    let canonical_points = uniform_in_box(rng, canonical.bounds, cfg.batch);
    let terms = model.stage2_terms(
        &target.inputs,
        canonical,
        points_tensor(&pose, &device),
        points_tensor(&canonical_points, &device),
    );
    let loss = Stage2Objective { cfg }.weigh(terms);
    let value = to_host(loss.clone())[0];
    let logged = StepValues {
        loss: value,
        blend: value,
        items: 2 * cfg.batch,
        ..StepValues::default()
    };
    (loss, logged)
}

/// `n` points uniform in `bounds`.
fn uniform_in_box(rng: &mut ChaCha8Rng, bounds: Aabb, n: usize) -> Vec<Vec3> {
    let (min, max) = (bounds.min, bounds.max);
    (0..n)
        .map(|_| min + (max - min) * Vec3::new(rng.random(), rng.random(), rng.random()))
        .collect()
}

/// The poses a pose-code fit draws from, each built when a step draws it, so that a long motion's
/// volumes need not all be in memory at once.
pub trait PoseTargets {
    /// Number of poses (codes `Novel(0..len)`).
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Pose `i`'s inputs and box.
    fn target(&mut self, i: usize) -> Result<PoseTarget>;
}

impl PoseTargets for Vec<PoseTarget> {
    fn len(&self) -> usize {
        Vec::len(self)
    }

    fn target(&mut self, i: usize) -> Result<PoseTarget> {
        Ok(self[i].clone())
    }
}

/// Fits blend-weight codes for `targets` (poses outside the run's data, e.g. from pose files) as stage 2
/// does — the `[animate]` steps of `cfg.batch` points, poses drawn at random, stopping on a plateau as
/// stage 2 does — and returns the model with them as its novel-pose field, every parameter frozen.
/// Nothing is written to the run. With the residual off the body model's weights need no fit. The model
/// must live on an autodiff device.
pub fn fit_pose_codes(
    model: AnimatableNerf,
    targets: &mut dyn PoseTargets,
    canonical: &CanonicalInputs,
    cfg: &StageConfig,
    seed: u64,
    progress: bool,
) -> Result<AnimatableNerf> {
    let device = model.device();
    let model = model.with_novel_field(targets.len(), &device);
    if !model.config().neural_blend_weights || targets.is_empty() {
        return Ok(model.no_grad());
    }
    device.seed(stream_seed(seed, Stream::PoseFitDevice));
    let mut step = PoseFit {
        targets,
        canonical,
        cfg,
        rng: ChaCha8Rng::seed_from_u64(stream_seed(seed, Stream::PoseFitHost)),
        counters: LoopState::default(),
    };
    let options = TrainOptions {
        resume: false,
        progress,
        max_steps: None,
    };
    let never = AtomicBool::new(false);
    let optim = optimizer(cfg.grad_clip);
    let (model, _) = drive(&mut step, Single::new(model, optim), cfg, options, &never)?;
    Ok(model.no_grad())
}

/// A step of a pose-file fit.
struct PoseFit<'a> {
    targets: &'a mut dyn PoseTargets,
    canonical: &'a CanonicalInputs,
    cfg: &'a StageConfig,
    rng: ChaCha8Rng,
    counters: LoopState,
}

impl Step for PoseFit<'_> {
    fn label(&self) -> &'static str {
        "pose codes"
    }

    fn counters(&mut self) -> &mut LoopState {
        &mut self.counters
    }

    fn loss(&mut self, model: &AnimatableNerf) -> Result<(Tensor<1>, StepValues)> {
        let j = self.rng.random_range(0..self.targets.len());
        let target = self.targets.target(j)?;
        Ok(stage2_loss(
            model,
            &mut self.rng,
            self.cfg,
            &target,
            self.canonical,
        ))
    }

    fn figures(&self, means: &WindowMeans, _: Option<f64>) -> (Option<RenderFigures>, String) {
        (None, format!("loss {:.6}", means.loss))
    }

    fn record(&self) -> Option<(&Record<'_>, &TrainerState)> {
        None
    }
}

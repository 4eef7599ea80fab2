//! The loop every fit runs: it stops on Ctrl-C, a step limit or a loss plateau, checks each loss, steps
//! the optimiser, keeps the log window, validates, logs, checkpoints and draws progress. What a step
//! computes is the [`Step`] of its stage.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anerf_core::model::AnimatableNerf;
use anyhow::{bail, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use serde::Serialize;

use super::checkpoint::{Checkpoint, TrainerState};
use super::loop_state::LoopState;
use super::schedule::learning_rate;
use super::window::{StepValues, WindowMeans};
use super::{StageOutcome, TrainOptions};
use crate::config::StageConfig;
use crate::progress::StageProgress;
use crate::run_dir::{MetricsLog, RunDir};
use crate::stage::Stage;

/// What one stage computes in a step; [`drive`] does everything around it.
pub(super) trait Step {
    /// The progress label ("stage 1").
    fn label(&self) -> &'static str;
    /// The loop's counters (inside the checkpointed state for the recorded stages).
    fn counters(&mut self) -> &mut LoopState;
    /// The loss of the next step, on the device, and its values for the log (`loss` on the host).
    fn loss(&mut self, model: &AnimatableNerf) -> Result<(Tensor<1>, StepValues)>;
    /// After the optimiser step that completed step `step`, on each copy of the model (replica `replica` of
    /// a data-parallel fit; stage 1 refreshes its occupancy grid and checks its pose refinement); an error
    /// stops the fit without a checkpoint.
    fn after_step(
        &mut self,
        _model: &mut AnimatableNerf,
        _replica: usize,
        _step: usize,
    ) -> Result<()> {
        Ok(())
    }
    /// A held-out PSNR at `step`, when the stage validates.
    fn validate(&mut self, _model: &AnimatableNerf, _step: usize) -> Result<Option<f64>> {
        Ok(None)
    }
    /// The stage's own figures of a log line, and the progress message for it.
    fn figures(
        &self,
        means: &WindowMeans,
        validation_psnr: Option<f64>,
    ) -> (Option<RenderFigures>, String);
    /// Where a recorded fit writes and the state its checkpoints save; `None`: nothing is written.
    fn record(&self) -> Option<(&Record<'_>, &TrainerState)>;
}

/// Stage 1's figures in a line of `metrics.jsonl`: the rendering's.
#[derive(Debug, Serialize)]
pub(super) struct RenderFigures {
    pub color_mse: f32,
    pub psnr: f32,
    /// Samples that survive culling / all samples.
    pub surviving_fraction: f32,
    /// Samples that reach the canonical NeRF (culling and the occupancy grid) / all samples.
    pub nerf_fraction: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_psnr: Option<f64>,
}

/// One line of `metrics.jsonl`.
#[derive(Debug, Serialize)]
struct LogLine {
    stage: Stage,
    step: usize,
    loss: f32,
    blend: f32,
    lr: f64,
    items_per_second: f64,
    #[serde(flatten)]
    rendering: Option<RenderFigures>,
}

/// Where a recorded fit writes: checkpoints and the metrics log of its run folder.
pub(super) struct Record<'a> {
    run: &'a RunDir,
    stage: Stage,
    log: MetricsLog,
}

impl<'a> Record<'a> {
    /// Records `stage` of `run` from step `step` on (later lines of an earlier attempt are dropped).
    pub fn open(run: &'a RunDir, stage: Stage, step: usize) -> Result<Self> {
        Ok(Self {
            run,
            stage,
            log: MetricsLog::open(run.metrics_log(), stage, step)?,
        })
    }

    /// The run folder this record writes into.
    pub fn run(&self) -> &'a RunDir {
        self.run
    }
}

/// How one step of a fit went.
pub(super) enum Advance {
    /// The optimiser stepped; the step's values.
    Stepped(StepValues),
    /// The loss was not finite (this value); nothing was stepped.
    NonFinite(f32),
}

/// What a fit optimises and how a step advances it: one model and its optimiser ([`Single`]), or the
/// replicas of a data-parallel run ([`super::parallel::Replicas`]).
pub(super) trait Fit<S: Step> {
    /// Computes the step's loss and, when it is finite, steps the optimiser(s) at learning rate `lr`.
    fn advance(&mut self, step: &mut S, lr: f64) -> Result<Advance>;
    /// The model validated, checkpointed and returned.
    fn model(&self) -> &AnimatableNerf;
    /// Its optimiser, checkpointed with it.
    fn optim(&self) -> &ModuleOptimizer;
    /// Every copy of the model, in replica order.
    fn models_mut(&mut self) -> Vec<&mut AnimatableNerf>;
    fn into_model(self) -> AnimatableNerf;
}

/// One model and its optimiser on one device.
pub(super) struct Single {
    /// Always present: taken out only for the optimiser's step, which consumes and returns it (a clone
    /// would keep the parameters' buffers shared and stop their in-place updates).
    model: Option<AnimatableNerf>,
    optim: ModuleOptimizer,
}

impl Single {
    pub fn new(model: AnimatableNerf, optim: ModuleOptimizer) -> Self {
        Self {
            model: Some(model),
            optim,
        }
    }
}

impl<S: Step> Fit<S> for Single {
    fn advance(&mut self, step: &mut S, lr: f64) -> Result<Advance> {
        let (loss, values) = step.loss(Fit::<S>::model(self))?;
        if !values.loss.is_finite() {
            return Ok(Advance::NonFinite(values.loss));
        }
        let model = self.model.take().expect("the model is present");
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        self.model = Some(self.optim.step(lr, model, grads));
        Ok(Advance::Stepped(values))
    }

    fn model(&self) -> &AnimatableNerf {
        self.model.as_ref().expect("the model is present")
    }

    fn optim(&self) -> &ModuleOptimizer {
        &self.optim
    }

    fn models_mut(&mut self) -> Vec<&mut AnimatableNerf> {
        self.model.iter_mut().collect()
    }

    fn into_model(self) -> AnimatableNerf {
        self.model.expect("the model is present")
    }
}

/// Runs `step` from its counters to `cfg.iterations` steps (or a stop) and returns the model and how the
/// fit ended. For a recorded step ([`Step::record`]), every `cfg.checkpoint_every` steps and at the end a
/// checkpoint is written and every `cfg.log_every` steps a line of `metrics.jsonl`; else nothing is written.
pub(super) fn drive<S: Step>(
    step: &mut S,
    mut fit: impl Fit<S>,
    cfg: &StageConfig,
    options: TrainOptions,
    stop: &AtomicBool,
) -> Result<(AnimatableNerf, StageOutcome)> {
    let first_step = step.counters().step;
    let bar = StageProgress::new(step.label(), first_step, cfg.iterations, options.progress);
    let started = Instant::now();
    step.counters().window.start_clock();
    let mut last_loss = f32::NAN;
    let mut interrupted = false;
    while step.counters().step < cfg.iterations && !step.counters().plateau.reached {
        let done = step.counters().step;
        if stop.load(Ordering::SeqCst) || options.max_steps.is_some_and(|m| done - first_step >= m)
        {
            interrupted = true;
            break;
        }
        let lr = learning_rate(cfg, done);
        let values = match fit.advance(step, lr)? {
            Advance::Stepped(values) => values,
            Advance::NonFinite(loss) => bail!(
                "{} stopped at step {done}: the loss is {loss}; {}",
                step.label(),
                match step.record() {
                    Some((r, _)) => format!(
                        "the last good checkpoint in {} is kept (lower the learning rate or check the \
                         data, then `--resume`)",
                        r.run.checkpoints().display()
                    ),
                    None => "lower the learning rate".into(),
                }
            ),
        };
        let done = done + 1;
        step.counters().step = done;
        for (replica, model) in fit.models_mut().into_iter().enumerate() {
            step.after_step(model, replica, done)?;
        }
        last_loss = values.loss;
        step.counters().window.add(values);

        let validation_psnr = if cfg.validate_every > 0 && done.is_multiple_of(cfg.validate_every) {
            step.validate(fit.model(), done)?
        } else {
            None
        };
        if done.is_multiple_of(cfg.log_every) || done == cfg.iterations || validation_psnr.is_some()
        {
            let means = step.counters().window.close();
            let (rendering, message) = step.figures(&means, validation_psnr);
            bar.report(done, &message);
            if let Some((r, _)) = step.record() {
                r.log.append(&LogLine {
                    stage: r.stage,
                    step: done,
                    loss: means.loss,
                    blend: means.blend,
                    lr,
                    items_per_second: means.items_per_second,
                    rendering,
                })?;
            }
            step.counters().plateau.update(done, means.loss, cfg);
        }
        bar.set_step(done);
        if cfg.checkpoint_every > 0 && done.is_multiple_of(cfg.checkpoint_every) {
            save(step, fit.model(), fit.optim())?;
        }
    }
    save(step, fit.model(), fit.optim())?;
    let steps = step.counters().step;
    let ending = match (interrupted, step.counters().plateau.reached) {
        (true, _) => "interrupted",
        (false, true) => "stopped on a loss plateau",
        (false, false) => "finished",
    };
    bar.finish(steps, ending);
    let outcome = StageOutcome {
        steps,
        loss: last_loss,
        interrupted,
        seconds: started.elapsed().as_secs_f64(),
    };
    Ok((fit.into_model(), outcome))
}

/// A checkpoint of the step's state, when the fit is recorded.
fn save(step: &impl Step, model: &AnimatableNerf, optim: &ModuleOptimizer) -> Result<()> {
    match step.record() {
        Some((r, state)) => Checkpoint::save(&r.run.checkpoints(), state, model, optim).map(drop),
        None => Ok(()),
    }
}

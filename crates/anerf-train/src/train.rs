//! The two optimisation stages: stage 1 fits the canonical radiance field and the blend-weight fields to the
//! training video; stage 2 fits blend-weight fields for the novel poses against the frozen canonical field.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anerf_core::geometry::skinning::points_tensor;
use anerf_core::geometry::Aabb;
use anerf_core::model::{AnimatableNerf, CanonicalInputs, FrameInputs, ModelConfig};
use anerf_core::render::{color_mse, psnr_from_mse, RayBatch};
use anerf_core::tensor::{from_rows, to_host};
use anerf_data::{RaySampler, SamplerOptions};
use anerf_eval::images::{write_png, PngDepth};
use anerf_eval::ImageMetrics;
use anyhow::{bail, Context, Result};
use burn::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::checkpoint::{Checkpoint, TrainerState};
use crate::config::StageConfig;
use crate::experiment::Experiment;
use crate::progress::StageProgress;
use crate::render::render_view;
use crate::run_dir::{MetricsLog, RunDir};
use crate::schedule::{learning_rate, Plateau};
use crate::stage::Stage;
use crate::window::StepValues;

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
    /// Mean loss over the last logged interval.
    pub loss: f32,
    /// True when stopped before the last iteration (Ctrl-C or `max_steps`; a checkpoint was written).
    pub interrupted: bool,
    pub seconds: f64,
}

/// One line of `metrics.jsonl`.
#[derive(Debug, Serialize)]
struct LogLine {
    stage: Stage,
    step: usize,
    loss: f32,
    #[serde(skip_serializing_if = "Option::is_none")]
    color_mse: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    psnr: Option<f32>,
    blend: f32,
    lr: f64,
    items_per_second: f64,
    /// Samples that survive culling / all samples.
    #[serde(skip_serializing_if = "Option::is_none")]
    surviving_fraction: Option<f32>,
    /// Samples that reach the canonical NeRF (culling and the occupancy grid) / all samples.
    #[serde(skip_serializing_if = "Option::is_none")]
    nerf_fraction: Option<f32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    validation_psnr: Option<f64>,
}

fn optimizer(stage: &StageConfig) -> ModuleOptimizer {
    let clip = (stage.grad_clip > 0.0).then_some(GradientClippingConfig::Value(stage.grad_clip));
    AdamConfig::new()
        .with_epsilon(1e-8)
        .with_grad_clipping(clip)
        .init()
}

/// Uniform numbers in `[0, 1)` as an `[rows, cols]` tensor, from the trainer's own stream.
fn uniform(rng: &mut ChaCha8Rng, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    let values: Vec<f32> = (0..rows * cols).map(|_| rng.random::<f32>()).collect();
    from_rows(&values, rows, cols, device)
}

/// `n` points uniform in the box `[min, max]`.
fn uniform_in_box(rng: &mut ChaCha8Rng, min: Vec3, max: Vec3, n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|_| min + (max - min) * Vec3::new(rng.random(), rng.random(), rng.random()))
        .collect()
}

fn check_finite(loss: f32, stage: Stage, step: usize, run: &RunDir) -> Result<()> {
    if !loss.is_finite() {
        bail!(
            "{stage} stopped at step {step}: the loss is {loss}; the last good checkpoint in {} is kept \
             (lower the learning rate or check the data, then `--resume`)",
            run.checkpoints().display()
        );
    }
    Ok(())
}

/// Stage 1: trains (or resumes) on the training frames and views, writing checkpoints, logs and validation
/// renders into `run`.
pub fn train_stage1(
    exp: &mut Experiment,
    run: &RunDir,
    options: TrainOptions,
    stop: &AtomicBool,
) -> Result<StageOutcome> {
    let cfg = exp.config.train.clone();
    let model_cfg = exp.config.model.clone();
    let device = exp.device.clone();
    let resumed = if options.resume {
        let resumed = resume_point(run, Stage::Train, &model_cfg, &cfg, &device)?;
        check_sizes(&resumed.2, exp)?;
        Some(resumed)
    } else {
        None
    };
    let (mut model, mut optim, mut state) = match resumed {
        Some(r) => r,
        None => {
            device.seed(exp.config.seed);
            let sampler = RaySampler::new(
                exp.config.seed,
                SamplerOptions {
                    rays: cfg.batch,
                    skip_mask_edges: cfg.skip_mask_edges,
                    ..SamplerOptions::default()
                },
            );
            let state = TrainerState {
                stage: Stage::Train,
                step: 0,
                model: model_cfg.clone(),
                training_frames: exp.train_frames.len(),
                joints: exp.prepared.skeleton.num_joints(),
                novel_frames: None,
                sampler: Some(sampler),
                rng: ChaCha8Rng::seed_from_u64(exp.config.seed ^ 0x5eed_0001),
                plateau: Plateau::default(),
                window: Default::default(),
            };
            (
                AnimatableNerf::new(&model_cfg, exp.model_sizes(), &device),
                optimizer(&cfg),
                state,
            )
        }
    };
    let log = MetricsLog::open(run.metrics_log(), Stage::Train, state.step)?;
    let bar = StageProgress::new("stage 1", state.step, cfg.iterations, options.progress);
    let started = Instant::now();
    state.window.start_clock();
    let mut last_loss = f32::NAN;
    let samples = model_cfg.samples_per_ray;
    let mut interrupted = false;
    let first_step = state.step;
    while state.step < cfg.iterations && !state.plateau.reached {
        if stop.load(Ordering::SeqCst)
            || options
                .max_steps
                .is_some_and(|m| state.step - first_step >= m)
        {
            interrupted = true;
            break;
        }
        let sampler = state.sampler.as_mut().expect("stage 1 keeps a sampler");
        let (frame, view) = sampler
            .pick(&exp.train_frames, &exp.train_views)
            .expect("frames and views exist");
        let host = sampler
            .sample_prepared(&exp.prepared, frame, view)
            .with_context(|| format!("sampling rays of {frame}, {view}"))?;
        let rays = RayBatch::new(&host, frame, view, &device);
        let jitter = uniform(&mut state.rng, rays.len(), samples, &device);
        let inputs = exp.frame_inputs(frame)?;
        let out = model.render(
            &rays,
            &inputs,
            exp.canonical(),
            Some(jitter),
            model_cfg.neural_blend_weights,
        );
        let mse = color_mse(
            out.rgb,
            rays.colors.clone().expect("training rays carry colours"),
        );
        let colour_loss = match (&rays.foreground, cfg.mask_weight > 0.0) {
            (Some(mask), true) => {
                mse.clone() + silhouette_loss(out.acc.clone(), mask.clone()) * cfg.mask_weight
            }
            _ => mse.clone(),
        };
        let blend = out.consistency.map(|c| {
            let consistency = c.loss(model_cfg.consistency);
            if cfg.residual_weight > 0.0 {
                consistency + c.residual_penalty() * cfg.residual_weight
            } else {
                consistency
            }
        });
        let loss = match &blend {
            Some(b) => colour_loss + b.clone(),
            None => colour_loss,
        };
        let values = to_host(Tensor::cat(
            vec![
                loss.clone(),
                mse,
                blend.unwrap_or_else(|| Tensor::zeros([1], &device)),
            ],
            0,
        ));
        check_finite(values[0], Stage::Train, state.step, run)?;
        let lr = learning_rate(&cfg, state.step);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(lr, model, grads);
        state.step += 1;
        model.update_occupancy(exp.canonical(), state.step);
        last_loss = values[0];
        state.window.add(StepValues {
            loss: values[0],
            mse: values[1],
            blend: values[2],
            surviving: out.surviving_samples as f32 / out.total_samples as f32,
            occupied: out.occupied_samples as f32 / out.total_samples as f32,
            items: rays.len(),
        });

        let validation_psnr = if cfg.validate_every > 0 && state.step % cfg.validate_every == 0 {
            Some(validate(&model, exp, run, state.step)?)
        } else {
            None
        };
        if state.step % cfg.log_every == 0
            || state.step == cfg.iterations
            || validation_psnr.is_some()
        {
            let means = state.window.close();
            let mse = means.mse;
            let line = LogLine {
                stage: Stage::Train,
                step: state.step,
                loss: means.loss,
                color_mse: Some(mse),
                psnr: Some(psnr_from_mse(mse)),
                blend: means.blend,
                lr,
                items_per_second: means.items_per_second,
                surviving_fraction: Some(means.surviving),
                nerf_fraction: Some(means.occupied),
                validation_psnr,
            };
            bar.report(
                state.step,
                &format!(
                    "loss {:.5} psnr {:.2} dB {:.0} rays/s",
                    line.loss,
                    psnr_from_mse(mse),
                    line.items_per_second
                ),
            );
            log.append(&line)?;
            state.plateau.update(state.step, line.loss, &cfg);
        }
        bar.set_step(state.step);
        if cfg.checkpoint_every > 0 && state.step % cfg.checkpoint_every == 0 {
            Checkpoint::save(&run.checkpoints(), &state, &model, &optim)?;
        }
    }
    Checkpoint::save(&run.checkpoints(), &state, &model, &optim)?;
    bar.finish(state.step, ending(interrupted, &state.plateau));
    Ok(StageOutcome {
        steps: state.step,
        loss: last_loss,
        interrupted,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// `mean((acc − m)²)`: the rendered opacity `[R]` against the rays' foreground mask `[R]` (1 on the body).
pub fn silhouette_loss(acc: Tensor<1>, foreground: Tensor<1>) -> Tensor<1> {
    (acc - foreground).powf_scalar(2.0).mean()
}

/// How a stage's loop ended, for its last progress line.
fn ending(interrupted: bool, plateau: &Plateau) -> &'static str {
    match (interrupted, plateau.reached) {
        (true, _) => "interrupted",
        (false, true) => "stopped on a loss plateau",
        (false, false) => "finished",
    }
}

/// The model, optimiser and state of `stage`'s newest intact checkpoint, to resume from; an error when the
/// stage has none.
fn resume_point(
    run: &RunDir,
    stage: Stage,
    model: &ModelConfig,
    cfg: &StageConfig,
    device: &Device,
) -> Result<(AnimatableNerf, ModuleOptimizer, TrainerState)> {
    let r = Checkpoint::restore_newest(
        &run.checkpoints(),
        stage,
        model,
        device,
        Some(&|| optimizer(cfg)),
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

/// Renders a held-out view of a middle training frame, saves it and returns its protocol PSNR.
fn validate(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    run: &RunDir,
    step: usize,
) -> Result<f64> {
    let frame = exp.train_frames[exp.train_frames.len() / 2];
    let view = *exp.test_views.first().unwrap_or(&exp.train_views[0]);
    let camera = exp.prepared.cameras[view.0].clone();
    // The training model renders directly; no backward pass follows, so its graph is simply dropped.
    let image = render_view(model, exp, frame, &camera, Some(view))?;
    let gt = image
        .ground_truth
        .as_ref()
        .expect("a dataset view has ground truth");
    let metrics = ImageMetrics::compute(&image.prediction, gt, Some(&image.mask))
        .context("validation metrics")?;
    write_png(
        &run.renders().join(format!("validation_{step:08}.png")),
        &image.prediction,
        PngDepth::Eight,
    )?;
    Ok(metrics.psnr)
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
    let model_cfg: ModelConfig = exp.config.model.clone();
    let device = exp.device.clone();
    if exp.novel_frames.is_empty() {
        bail!("the config selects no novel-pose frames (dataset.*.novel_pose_frames); nothing to animate");
    }
    let resumed = if options.resume {
        Some(resume_point(
            run,
            Stage::Animate,
            &model_cfg,
            &cfg,
            &device,
        )?)
    } else {
        None
    };
    let (mut model, mut optim, mut state) = match resumed {
        Some((model, optim, state)) => (model.freeze_stage1(), optim, state),
        None => {
            let stage1 = Checkpoint::restore_newest(
                &run.checkpoints(),
                Stage::Train,
                &model_cfg,
                &device,
                None,
            )?
            .with_context(|| {
                format!(
                    "{} has no stage-1 checkpoint; run `anerf train` first",
                    run.root.display()
                )
            })?;
            check_sizes(&stage1.state, exp)?;
            device.seed(exp.config.seed ^ 2);
            let state = TrainerState {
                stage: Stage::Animate,
                step: 0,
                novel_frames: Some(exp.novel_frames.len()),
                sampler: None,
                rng: ChaCha8Rng::seed_from_u64(exp.config.seed ^ 0x5eed_0002),
                plateau: Plateau::default(),
                window: Default::default(),
                ..stage1.state
            };
            (
                stage1
                    .model
                    .with_novel_field(exp.novel_frames.len(), &device),
                optimizer(&cfg),
                state,
            )
        }
    };
    if !model_cfg.neural_blend_weights {
        // Without the residual the novel-pose weights are the body model's: nothing to fit.
        state.step = cfg.iterations;
        Checkpoint::save(&run.checkpoints(), &state, &model, &optim)?;
        eprintln!(
            "stage 2: model.neural_blend_weights = false, novel poses use the body model's weights"
        );
        return Ok(StageOutcome {
            steps: state.step,
            loss: 0.0,
            interrupted: false,
            seconds: 0.0,
        });
    }
    let log = MetricsLog::open(run.metrics_log(), Stage::Animate, state.step)?;
    let bar = StageProgress::new("stage 2", state.step, cfg.iterations, options.progress);
    let started = Instant::now();
    state.window.start_clock();
    let mut last_loss = f32::NAN;
    let mut interrupted = false;
    let first_step = state.step;
    while state.step < cfg.iterations && !state.plateau.reached {
        if stop.load(Ordering::SeqCst)
            || options
                .max_steps
                .is_some_and(|m| state.step - first_step >= m)
        {
            interrupted = true;
            break;
        }
        let j = state.rng.random_range(0..exp.novel_frames.len());
        let frame = exp.novel_frames[j];
        let target = PoseTarget {
            inputs: exp.frame_inputs(frame)?,
            bounds: exp.frame_bounds(frame)?,
        };
        let (loss, value) = stage2_loss(&model, &mut state.rng, &cfg, &target, exp.canonical());
        check_finite(value, Stage::Animate, state.step, run)?;
        let lr = learning_rate(&cfg, state.step);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(lr, model, grads);
        state.step += 1;
        last_loss = value;
        state.window.add(StepValues {
            loss: value,
            blend: value,
            items: 2 * cfg.batch,
            ..StepValues::default()
        });
        if state.step % cfg.log_every == 0 || state.step == cfg.iterations {
            let means = state.window.close();
            let line = LogLine {
                stage: Stage::Animate,
                step: state.step,
                loss: means.loss,
                color_mse: None,
                psnr: None,
                blend: means.blend,
                lr,
                items_per_second: means.items_per_second,
                surviving_fraction: None,
                nerf_fraction: None,
                validation_psnr: None,
            };
            bar.report(
                state.step,
                &format!(
                    "loss {:.6} {:.0} points/s",
                    line.loss, line.items_per_second
                ),
            );
            log.append(&line)?;
            state.plateau.update(state.step, line.loss, &cfg);
        }
        bar.set_step(state.step);
        if cfg.checkpoint_every > 0 && state.step % cfg.checkpoint_every == 0 {
            Checkpoint::save(&run.checkpoints(), &state, &model, &optim)?;
        }
    }
    Checkpoint::save(&run.checkpoints(), &state, &model, &optim)?;
    bar.finish(state.step, ending(interrupted, &state.plateau));
    Ok(StageOutcome {
        steps: state.step,
        loss: last_loss,
        interrupted,
        seconds: started.elapsed().as_secs_f64(),
    })
}

/// A pose stage 2 fits a blend-weight code for: its model inputs (`code` = [`anerf_core::model::FrameCode::Novel`]) and the
/// world-space box around its body (metres).
pub struct PoseTarget {
    pub inputs: FrameInputs,
    pub bounds: Aabb,
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
) -> (Tensor<1>, f32) {
    let device = model.device();
    let global = target.inputs.global;
    let pose: Vec<Vec3> = uniform_in_box(rng, target.bounds.min, target.bounds.max, cfg.batch)
        .into_iter()
        .map(|p| global.world_to_pose(p))
        .collect();
    let canonical_points =
        uniform_in_box(rng, canonical.bounds.min, canonical.bounds.max, cfg.batch);
    let terms = model.stage2_loss(
        &target.inputs,
        canonical,
        points_tensor(&pose, &device),
        points_tensor(&canonical_points, &device),
    );
    let loss = if cfg.residual_weight > 0.0 {
        terms.total + terms.residual * cfg.residual_weight
    } else {
        terms.total
    };
    let value = to_host(loss.clone())[0];
    (loss, value)
}

/// Fits blend-weight codes for `targets` (poses outside the run's data, e.g. from pose files) as stage 2
/// does — `cfg.iterations` steps of `cfg.batch` points, poses drawn at random — and returns the model with
/// them as its novel-pose field, every parameter frozen. Nothing is written to the run. With the residual
/// off the body model's weights need no fit. The model must live on an autodiff device.
pub fn fit_pose_codes(
    model: AnimatableNerf,
    targets: &[PoseTarget],
    canonical: &CanonicalInputs,
    cfg: &StageConfig,
    seed: u64,
    progress: bool,
) -> Result<AnimatableNerf> {
    let device = model.device();
    let mut model = model.with_novel_field(targets.len(), &device);
    if !model.config().neural_blend_weights || targets.is_empty() {
        return Ok(model.no_grad());
    }
    device.seed(seed ^ 3);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_0003);
    let mut optim = optimizer(cfg);
    let bar = StageProgress::new("pose codes", 0, cfg.iterations, progress);
    for step in 0..cfg.iterations {
        let j = rng.random_range(0..targets.len());
        let (loss, value) = stage2_loss(&model, &mut rng, cfg, &targets[j], canonical);
        if !value.is_finite() {
            bail!("fitting the poses' blend-weight codes: the loss is {value} at step {step} (lower animate.lr)");
        }
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(learning_rate(cfg, step), model, grads);
        bar.set_step(step + 1);
        if (step + 1) % cfg.log_every == 0 {
            bar.report(step + 1, &format!("loss {value:.6}"));
        }
    }
    bar.finish(cfg.iterations, "finished");
    Ok(model.no_grad())
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_core::device::cpu_device;

    #[test]
    fn the_silhouette_loss_is_the_mean_squared_opacity_error() {
        let device = cpu_device();
        let acc = Tensor::<1>::from_floats([0.2, 0.9, 1.0, 0.0], &device);
        let mask = Tensor::<1>::from_floats([0.0, 1.0, 1.0, 1.0], &device);
        let got = to_host(silhouette_loss(acc, mask))[0];
        assert!(
            (got - (0.04 + 0.01 + 0.0 + 1.0) / 4.0).abs() < 1e-7,
            "{got}"
        );
    }
}

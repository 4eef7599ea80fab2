//! Stage 1: the canonical radiance field and the training frames' blend-weight fields, fitted to rays of
//! the training views.

use std::sync::atomic::AtomicBool;

use anerf_core::model::AnimatableNerf;
use anerf_core::render::{color_mse, psnr_from_mse, RayBatch};
use anerf_core::tensor::{from_rows, to_host};
use anerf_data::{RaySampler, SamplerOptions};
use anerf_eval::images::{write_png, PngDepth};
use anerf_eval::ImageMetrics;
use anyhow::{Context, Result};
use burn::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::driver::{drive, LoopState, Record, RenderFigures, Step};
use super::seeds::{stream_seed, Stream};
use super::window::{StepValues, WindowMeans};
use super::{check_sizes, optimizer, resume_point, StageOutcome, TrainOptions};
use crate::checkpoint::TrainerState;
use crate::config::StageConfig;
use crate::experiment::Experiment;
use crate::render::render_view;
use crate::run_dir::RunDir;
use crate::stage::Stage;

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
    let (model, optim, state) = if options.resume {
        let resumed = resume_point(run, Stage::Train, &model_cfg, cfg.grad_clip, &device)?;
        check_sizes(&resumed.2, exp)?;
        resumed
    } else {
        let seed = exp.config.seed;
        device.seed(stream_seed(seed, Stream::Stage1Device));
        let sampler = RaySampler::new(
            stream_seed(seed, Stream::Stage1Rays),
            SamplerOptions {
                rays: cfg.batch,
                skip_mask_edges: cfg.skip_mask_edges,
                ..SamplerOptions::default()
            },
        );
        let state = TrainerState {
            stage: Stage::Train,
            counters: LoopState::default(),
            model: model_cfg.clone(),
            training_frames: exp.train_frames.len(),
            joints: exp.prepared.skeleton.num_joints(),
            novel_frames: None,
            sampler: Some(sampler),
            rng: ChaCha8Rng::seed_from_u64(stream_seed(seed, Stream::Stage1Host)),
        };
        let model = AnimatableNerf::new(&model_cfg, exp.model_sizes(), &device);
        (model, optimizer(cfg.grad_clip), state)
    };
    let mut step = Stage1 {
        record: Record::open(run, Stage::Train, state.counters.step)?,
        exp,
        cfg: &cfg,
        state,
    };
    let (_, outcome) = drive(&mut step, model, optim, &cfg, options, stop)?;
    Ok(outcome)
}

/// A stage-1 step: one ray batch of a random training frame and view, rendered and compared.
struct Stage1<'a> {
    exp: &'a mut Experiment,
    cfg: &'a StageConfig,
    state: TrainerState,
    record: Record<'a>,
}

impl Step for Stage1<'_> {
    fn label(&self) -> &'static str {
        "stage 1"
    }

    fn counters(&mut self) -> &mut LoopState {
        &mut self.state.counters
    }

    /// Colour MSE (plus the silhouette term) plus the blend-weight consistency (plus the residual
    /// penalty), as weighted by `[train]`.
    fn loss(&mut self, model: &AnimatableNerf) -> Result<(Tensor<1>, StepValues)> {
        let (exp, cfg) = (&mut *self.exp, self.cfg);
        let device = exp.device.clone();
        let model_cfg = model.config();
        let sampler = self
            .state
            .sampler
            .as_mut()
            .expect("stage 1 keeps a sampler");
        let (frame, view) = sampler
            .pick(&exp.train_frames, &exp.train_views)
            .expect("frames and views exist");
        let host = sampler
            .sample_prepared(&exp.prepared, frame, view)
            .with_context(|| format!("sampling rays of {frame}, {view}"))?;
        let rays = RayBatch::new(&host, frame, view, &device);
        let jitter = uniform(
            &mut self.state.rng,
            rays.len(),
            model_cfg.samples_per_ray,
            &device,
        );
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
        // One transfer for the three logged values.
        let values = to_host(Tensor::cat(
            vec![
                loss.clone(),
                mse,
                blend.unwrap_or_else(|| Tensor::zeros([1], &device)),
            ],
            0,
        ));
        let logged = StepValues {
            loss: values[0],
            mse: values[1],
            blend: values[2],
            surviving: out.surviving_samples as f32 / out.total_samples as f32,
            occupied: out.occupied_samples as f32 / out.total_samples as f32,
            items: rays.len(),
        };
        Ok((loss, logged))
    }

    fn after_step(&mut self, model: &mut AnimatableNerf, step: usize) {
        model.update_occupancy(self.exp.canonical(), step);
    }

    /// Renders a held-out view of a middle training frame, saves it and returns its protocol PSNR.
    fn validate(&mut self, model: &AnimatableNerf, step: usize) -> Result<Option<f64>> {
        let exp = &mut *self.exp;
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
            &self
                .record
                .run()
                .renders()
                .join(format!("validation_{step:08}.png")),
            &image.prediction,
            PngDepth::Eight,
        )?;
        Ok(Some(metrics.psnr))
    }

    fn figures(
        &self,
        means: &WindowMeans,
        validation_psnr: Option<f64>,
    ) -> (Option<RenderFigures>, String) {
        let psnr = psnr_from_mse(means.mse);
        let message = format!(
            "loss {:.5} psnr {psnr:.2} dB {:.0} rays/s",
            means.loss, means.items_per_second
        );
        let figures = RenderFigures {
            color_mse: means.mse,
            psnr,
            surviving_fraction: means.surviving,
            nerf_fraction: means.occupied,
            validation_psnr,
        };
        (Some(figures), message)
    }

    fn record(&self) -> Option<(&Record<'_>, &TrainerState)> {
        Some((&self.record, &self.state))
    }
}

/// `mean((acc − m)²)`: the rendered opacity `[R]` against the rays' foreground mask `[R]` (1 on the body).
pub fn silhouette_loss(acc: Tensor<1>, foreground: Tensor<1>) -> Tensor<1> {
    (acc - foreground).powf_scalar(2.0).mean()
}

/// Uniform numbers in `[0, 1)` as an `[rows, cols]` tensor, from the trainer's own stream.
fn uniform(rng: &mut ChaCha8Rng, rows: usize, cols: usize, device: &Device) -> Tensor<2> {
    let values: Vec<f32> = (0..rows * cols).map(|_| rng.random::<f32>()).collect();
    from_rows(&values, rows, cols, device)
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

//! Stage 1: the canonical radiance field and the training frames' blend-weight fields, fitted to rays of
//! the training views.

use std::collections::HashMap;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, OnceLock};

use anerf_core::model::{AnimatableNerf, FrameCode, FrameInputs, FrameRays};
use anerf_core::render::{psnr_from_mse, HostRays, RayBatch};
use anerf_core::tensor::{from_rows, to_host};
use anerf_core::{FrameId, ViewId};
use anerf_data::mask_distance::MaskDistance;
use anerf_data::{Backgrounds, MaskEdges, Prefetch, RaySampler, SamplerOptions, StepPlan};
use anerf_eval::images::{write_png, PngDepth};
use anerf_eval::ImageMetrics;
use anyhow::{bail, Context, Result};
use burn::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::body_silhouette::{
    silhouette_evidence, silhouette_loss, SilhouetteBody, SilhouetteEvidence, SilhouetteView,
    MASK_MARGIN,
};
use super::checkpoint::TrainerState;
use super::driver::{drive, Record, RenderFigures, Single, Step};
use super::loop_state::LoopState;
use super::objective::{Objective, TermSums, WeighedTerms};
use super::parallel::{whole_loss, Replicas, Shard, ShardedStep};
use super::seeds::{stream_seed, Stream};
use super::window::{StepValues, WindowMeans};
use super::{check_sizes, optimizer, resume_point, StageOutcome, TrainOptions};
use crate::config::StageConfig;
use crate::experiment::Experiment;
use crate::render::render_view;
use crate::run_dir::RunDir;
use crate::stage::Stage;

/// Under `mask_edges = "backdrop"`, a training camera whose background is known at fewer than this share
/// of its pixels is named in a warning (a body rarely covers half of a camera's picture).
const SPARSE_BACKGROUND: f32 = 0.5;

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
        let (model, state) = fresh_start(exp, &cfg);
        (model, optimizer(cfg.grad_clip), state)
    };
    let devices = exp.data_parallel().map(<[Device]>::to_vec);
    let record = Record::open(run, Stage::Train, state.counters.step)?;
    let mut step = Stage1::new(exp, &cfg, state, record)?;
    let (model, outcome) = match devices {
        None => drive(&mut step, Single::new(model, optim), &cfg, options, stop)?,
        Some(devices) => {
            if cfg.batch < devices.len() {
                bail!(
                    "train.batch = {}: a data-parallel fit gives each of its {} devices at least one ray",
                    cfg.batch,
                    devices.len()
                );
            }
            // Every replica's optimiser starts as the first one's: fresh, or restored on its device.
            let mut optims = vec![optim];
            for device in &devices[1..] {
                optims.push(if options.resume {
                    resume_point(run, Stage::Train, &model_cfg, cfg.grad_clip, device)?.1
                } else {
                    optimizer(cfg.grad_clip)
                });
            }
            let replicas = Replicas::new(model, optims, &devices);
            drive(&mut step, replicas, &cfg, options, stop)?
        }
    };
    if model.pose.is_some() {
        write_refined_poses(run, step.exp, &model)?;
    }
    Ok(outcome)
}

/// One training frame's body fit, as the data gives it and as stage 1 refined it.
#[derive(serde::Serialize)]
struct RefinedPose {
    /// Dataset frame index.
    frame: usize,
    given: anerf_core::geometry::Pose,
    refined: anerf_core::geometry::Pose,
}

/// Writes every training frame's given and refined fit to [`RunDir::refined_poses`] (axis-angle radians,
/// metres; `Rh`/`Th` as the datasets place the body), for the user and for comparing with true poses.
fn write_refined_poses(run: &RunDir, exp: &Experiment, model: &AnimatableNerf) -> Result<()> {
    let poses = exp
        .train_frames
        .iter()
        .map(|&id| {
            let given = exp
                .prepared
                .frame(id)
                .context("a prepared frame")?
                .pose
                .clone();
            Ok(RefinedPose {
                frame: id.0,
                refined: exp.frame_pose(model, id)?,
                given,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let path = run.refined_poses();
    let text = serde_json::to_string_pretty(&poses).expect("poses serialise");
    anerf_data::atomic::write_bytes(&path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// A fresh stage-1 model (seeded by the experiment) and the trainer state that starts it.
fn fresh_start(exp: &Experiment, cfg: &StageConfig) -> (AnimatableNerf, TrainerState) {
    let model_cfg = &exp.config.model;
    let device = &exp.device;
    let seed = exp.config.seed;
    device.seed(stream_seed(seed, Stream::Stage1Device));
    let sampler = RaySampler::new(
        stream_seed(seed, Stream::Stage1Rays),
        SamplerOptions {
            rays: cfg.batch,
            mask_edges: cfg.mask_edges,
            detail_fraction: cfg.detail_fraction,
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
    let model = AnimatableNerf::new(model_cfg, exp.model_sizes(), device);
    (model, state)
}

/// One stage-1 step's rays on the host: `train.frames_per_step` random training frames, each with
/// the rays sampled from `train.views_per_step` of its views.
struct RayStep {
    frames: Vec<StepFrame>,
}

/// One frame's part of a step: its rays, their depth jitter, and the frame's inputs on each replica's
/// device.
struct StepFrame {
    frame: FrameId,
    rays: HostRays,
    /// `[R·S]` uniform numbers in `[0, 1)`, `S` per ray.
    jitter: Vec<f32>,
    inputs: Vec<FrameInputs>,
    /// The step's views of the frame with their masks' distances, where the body silhouette term is on.
    silhouette: Vec<SilhouetteView>,
}

impl RayStep {
    fn rays(&self) -> usize {
        self.frames.iter().map(|f| f.rays.len()).sum()
    }
}

/// A stage-1 step: one ray batch of some random training frames and some of their views, rendered and
/// compared.
struct Stage1<'a> {
    exp: &'a mut Experiment,
    cfg: &'a StageConfig,
    state: TrainerState,
    record: Record<'a>,
    /// Draws each step's rays while the step before computes.
    prefetch: Prefetch,
    /// The training masks' signed distances, computed once each, where the body silhouette term is on.
    masks: HashMap<(FrameId, ViewId), Arc<MaskDistance>>,
    /// The body model as the silhouette term reads it, derived on first use.
    silhouette_body: OnceLock<SilhouetteBody>,
}

impl<'a> Stage1<'a> {
    /// The step, with the training views' backgrounds estimated from the training frames where
    /// `mask_edges = "backdrop"` composites over them.
    fn new(
        exp: &'a mut Experiment,
        cfg: &'a StageConfig,
        state: TrainerState,
        record: Record<'a>,
    ) -> Result<Self> {
        let backgrounds = match cfg.mask_edges {
            MaskEdges::Backdrop => {
                let backgrounds = Backgrounds::estimate(
                    &exp.prepared,
                    &exp.train_frames,
                    &exp.train_views,
                )
                .context(
                    "estimating the training views' backgrounds (train.mask_edges = \"backdrop\")",
                )?;
                for (view, share) in backgrounds.sparse(SPARSE_BACKGROUND) {
                    eprintln!(
                        "warning: camera {view}'s background is known at only {:.0} % of its pixels \
                         (its backdrop changes between frames, or the camera moved): its mask-edge band \
                         is not trained where it is unknown; train.mask_edges = \"robust\" trains it \
                         with the masks' labels",
                        100.0 * share
                    );
                }
                Some(Arc::new(backgrounds))
            }
            _ => None,
        };
        let plan = StepPlan {
            frames: exp.train_frames.clone(),
            views: exp.train_views.clone(),
            frames_per_step: cfg.frames_per_step,
            views_per_step: cfg.views_per_step.min(exp.train_views.len()),
            backgrounds,
        };
        Ok(Self {
            prefetch: Prefetch::new(Arc::clone(&exp.prepared), plan),
            exp,
            cfg,
            state,
            record,
            masks: HashMap::new(),
            silhouette_body: OnceLock::new(),
        })
    }

    /// Frame `frame`'s views `views` with their masks' signed distances (computed on first use; a view
    /// whose mask is empty has no outline to match and is left out).
    fn silhouette_views(
        &mut self,
        frame: FrameId,
        views: &[ViewId],
    ) -> Result<Vec<SilhouetteView>> {
        let mut out = Vec::new();
        for &view in views {
            if !self.masks.contains_key(&(frame, view)) {
                let mask = self
                    .exp
                    .prepared
                    .mask(frame, view)
                    .with_context(|| format!("the mask of {frame}, {view}"))?;
                let (w, h) = mask.dimensions();
                if let Some(distance) =
                    MaskDistance::new(mask.as_raw(), w as usize, h as usize, MASK_MARGIN)
                {
                    self.masks.insert((frame, view), Arc::new(distance));
                }
            }
            if let Some(mask) = self.masks.get(&(frame, view)) {
                out.push(SilhouetteView {
                    camera: self.exp.prepared.cameras[view.0].clone(),
                    mask: Arc::clone(mask),
                });
            }
        }
        Ok(out)
    }
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
        whole_loss(self, model)
    }

    /// Refreshes the occupancy grid; every [`POSE_CHECK_EVERY`] steps (and at the first), stops a pose
    /// refinement whose corrections left their bounds or are not finite, naming the frame.
    fn after_step(
        &mut self,
        model: &mut AnimatableNerf,
        replica: usize,
        step: usize,
    ) -> Result<()> {
        model.update_occupancy(self.exp.canonical_on(replica), step);
        if let (Some(pose), 0) = (&model.pose, replica) {
            if step == 1 || step.is_multiple_of(POSE_CHECK_EVERY) {
                if let Err(d) = pose.check() {
                    bail!(
                        "stage 1 stopped at step {step}: the pose refinement of training frame {} ({}) \
                         diverged: {}; lower model.pose_refinement.rotation_scale or translation_scale, or \
                         raise prior_weight (the last good checkpoint is kept)",
                        d.frame,
                        self.exp.train_frames[d.frame],
                        d.what
                    );
                }
            }
        }
        Ok(())
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

impl ShardedStep for Stage1<'_> {
    type Batch = RayStep;

    fn batch(&mut self, replicas: usize) -> Result<RayStep> {
        let sampler = self
            .state
            .sampler
            .as_mut()
            .expect("stage 1 keeps a sampler");
        let drawn = self.prefetch.next(sampler)?;
        *sampler = drawn.sampler;
        let (images, rays) = (drawn.images, drawn.rays);
        let samples = self.exp.config.model.samples_per_ray;
        // Before the refinement's start the frames render with their given fits (and their corrections
        // get no gradient and no penalty).
        let refinement = self.exp.config.model.pose_refinement;
        let refining =
            self.state.counters.step as f32 >= refinement.start * self.cfg.iterations as f32;
        let silhouettes = if refining && refinement.enabled && refinement.silhouette_weight > 0.0 {
            images
                .iter()
                .map(|image| self.silhouette_views(image.frame, &image.views))
                .collect::<Result<Vec<_>>>()?
        } else {
            vec![Vec::new(); images.len()]
        };
        let exp = &mut *self.exp;
        let rng = &mut self.state.rng;
        let frames = images
            .iter()
            .zip(rays)
            .zip(silhouettes)
            .map(|((image, rays), silhouette)| {
                let jitter = (0..rays.len() * samples)
                    .map(|_| rng.random::<f32>())
                    .collect();
                let inputs = (0..replicas)
                    .map(|k| {
                        let inputs = exp.frame_inputs_on(image.frame, k)?;
                        Ok(if refining {
                            inputs
                        } else {
                            FrameInputs {
                                basis: None,
                                ..inputs
                            }
                        })
                    })
                    .collect::<Result<_>>()?;
                Ok(StepFrame {
                    frame: image.frame,
                    rays,
                    jitter,
                    inputs,
                    silhouette,
                })
            })
            .collect::<Result<_>>()?;
        Ok(RayStep { frames })
    }

    /// The [`Objective`] of this shard's rays, plus the pose refinement's regulariser: each frame's
    /// terms weighed by its share of the step's rays, so that a step of several frames weighs every ray
    /// as one frame a step does.
    fn shard_loss(
        &self,
        batch: &RayStep,
        shard: &Shard<'_>,
        model: &AnimatableNerf,
    ) -> Result<(Tensor<1>, StepValues)> {
        // The replica's device as the experiment holds it (with autodiff): the model's parameters report
        // theirs without, and the renderer builds its outputs on the rays' device.
        let device = self.exp.replica_device(shard.index);
        let total = batch.rays() as f32;
        let mut sum: Option<WeighedTerms> = None;
        let (mut surviving, mut occupied, mut samples, mut items) = (0, 0, 0, 0);
        for (frame, (terms, out)) in batch
            .frames
            .iter()
            .zip(self.frames_terms(batch, shard, model, device)?)
        {
            let share = frame.rays.len() as f32 / total;
            surviving += out.surviving_samples;
            occupied += out.occupied_samples;
            samples += out.total_samples;
            items += out.rays;
            sum = Some(terms.weighed_onto(share, sum));
        }
        let WeighedTerms { loss, mse, blend } = sum.expect("a step has a frame at least");
        // One transfer for the three logged values.
        let values = to_host(Tensor::cat(
            vec![
                loss.clone(),
                mse,
                blend.unwrap_or_else(|| Tensor::zeros([1], device)),
            ],
            0,
        ));
        let logged = StepValues {
            loss: values[0],
            mse: values[1],
            blend: values[2],
            surviving: surviving as f32 / samples as f32,
            occupied: occupied as f32 / samples as f32,
            items,
        };
        Ok((loss, logged))
    }
}

/// What [`Stage1::frame_terms`] counted of one frame's render.
struct RenderCounts {
    rays: usize,
    surviving_samples: usize,
    occupied_samples: usize,
    total_samples: usize,
}

/// Steps between checks that the pose refinement stayed within its bounds.
const POSE_CHECK_EVERY: usize = 100;

impl Stage1<'_> {
    /// Each frame's rays of this shard rendered (one render of all the step's frames), and the
    /// [`Objective`]'s terms of each frame's rays plus the frame's pose regulariser and body silhouette
    /// term, as a one-frame step weighs them.
    fn frames_terms(
        &self,
        batch: &RayStep,
        shard: &Shard<'_>,
        model: &AnimatableNerf,
        device: &Device,
    ) -> Result<Vec<(WeighedTerms, RenderCounts)>> {
        let cfg = self.cfg;
        let model_cfg = model.config();
        let samples = model_cfg.samples_per_ray;
        // Each frame's part of this shard: its rays and their depth jitter.
        let (rays, jitter): (Vec<RayBatch>, Vec<Tensor<2>>) = batch
            .frames
            .iter()
            .map(|frame| {
                let part = shard.part(frame.rays.len());
                let jitter = from_rows(
                    &frame.jitter[part.start * samples..part.end * samples],
                    part.len(),
                    samples,
                    device,
                );
                (
                    RayBatch::new(&frame.rays.slice(part), frame.frame, device),
                    jitter,
                )
            })
            .unzip();
        // Each frame with its bones corrected once, for its render and its silhouette term.
        let posed: Vec<FrameInputs> = batch
            .frames
            .iter()
            .map(|frame| model.posed_frame(&frame.inputs[shard.index]))
            .collect();
        let parts = posed
            .iter()
            .zip(&rays)
            .zip(jitter)
            .map(|((frame, rays), jitter)| FrameRays {
                rays,
                frame,
                jitter: Some(jitter),
            })
            .collect();
        let evidence = self.silhouette_evidences(model, batch, shard)?;
        let outs = model.render_frames(
            parts,
            self.exp.canonical_on(shard.index),
            model_cfg.neural_blend_weights,
        );
        outs.into_iter()
            .zip(&rays)
            .zip(&batch.frames)
            .zip(posed.iter().zip(evidence))
            .map(|(((out, rays), frame), (posed, evidence))| {
                let sums = TermSums::new(&out, rays, cfg, model_cfg.consistency);
                let totals = sums.totals(shard, device);
                let mut terms = Objective { cfg }.weigh(sums, totals, shard.count);
                let inputs = &frame.inputs[shard.index];
                if let Some(penalty) = self.pose_penalty(model, inputs) {
                    terms.loss = terms.loss + penalty;
                }
                if let Some(evidence) = evidence {
                    terms.loss = terms.loss + silhouette_loss(&evidence, posed.bones.rows());
                }
                let counts = RenderCounts {
                    rays: rays.len(),
                    surviving_samples: out.surviving_samples,
                    occupied_samples: out.occupied_samples,
                    total_samples: out.total_samples,
                };
                Ok((terms, counts))
            })
            .collect()
    }

    /// The body silhouette term of each of the batch's frames (the same on every shard, as the
    /// regulariser), from its refined pose now, computed on the host for all frames at once; `None` for a
    /// frame where the term is off, before the refinement's start, or where no view of it has a mask.
    fn silhouette_evidences(
        &self,
        model: &AnimatableNerf,
        batch: &RayStep,
        shard: &Shard<'_>,
    ) -> Result<Vec<Option<SilhouetteEvidence>>> {
        let prepared = &self.exp.prepared;
        let convention = self
            .state
            .sampler
            .as_ref()
            .expect("stage 1 keeps a sampler")
            .options
            .convention;
        let weight = model.config().pose_refinement.silhouette_weight;
        let body = self
            .silhouette_body
            .get_or_init(|| SilhouetteBody::new(prepared.canonical.clone()));
        // The refined poses are read on this thread; posing and projecting the body runs per frame in
        // parallel.
        let work = batch
            .frames
            .iter()
            .map(|frame| {
                let inputs = &frame.inputs[shard.index];
                let (Some(_), Some(_), FrameCode::Training(_), false) = (
                    model.pose.as_ref(),
                    &inputs.basis,
                    inputs.code,
                    frame.silhouette.is_empty(),
                ) else {
                    return Ok(None);
                };
                let given = &prepared
                    .frame(frame.frame)
                    .with_context(|| format!("{} was not prepared", frame.frame))?
                    .pose;
                Ok(Some((
                    frame,
                    self.exp.frame_pose(model, frame.frame)?,
                    given,
                )))
            })
            .collect::<Result<Vec<_>>>()?;
        work.into_par_iter()
            .map(|job| {
                let Some((frame, refined, given)) = job else {
                    return Ok(None);
                };
                silhouette_evidence(
                    body,
                    &prepared.skeleton,
                    &refined,
                    &given.global,
                    &frame.silhouette,
                    convention,
                    weight,
                )
                .map(Some)
                .with_context(|| format!("the body silhouette term of {}", frame.frame))
            })
            .collect()
    }

    /// The pose refinement's regulariser for the batch's frame (the same on every shard, so that the
    /// shards' average is it); `None` without refinement or before its start.
    fn pose_penalty(&self, model: &AnimatableNerf, inputs: &FrameInputs) -> Option<Tensor<1>> {
        let (pose, Some(_), FrameCode::Training(f)) =
            (model.pose.as_ref()?, &inputs.basis, inputs.code)
        else {
            return None;
        };
        let frames = &self.exp.train_frames;
        let given = |i: usize| self.exp.prepared.frame(frames[i]).map(|p| &p.pose);
        let neighbours = (f > 0 && f + 1 < frames.len())
            .then(|| Some([given(f - 1)?, given(f)?, given(f + 1)?]))
            .flatten();
        Some(pose.penalty(f, neighbours))
    }
}

#[cfg(test)]
mod tests {
    use super::super::parallel::run_shards;
    use super::*;
    use crate::config::{self, Settings};
    use anerf_core::model::ModelPreset;
    use anerf_core::tensor::parameter_gradients;
    use anerf_data::synthetic::{write_subject, SyntheticSpec};
    use anerf_device::cpu_device;
    use anerf_testing::{assert_close, Tolerance};
    use burn::optim::GradientsParams;

    /// The tiny synthetic subject's stage-1 experiment (batch 256, every loss term on, `set` on top) with
    /// `replicas` data-parallel flex devices, and a run folder, in `dir`.
    fn tiny_experiment(
        dir: &std::path::Path,
        set: &[&str],
        replicas: usize,
    ) -> (Experiment, RunDir) {
        let subject = dir.join("subject");
        write_subject(&SyntheticSpec::tiny(), &subject).unwrap();
        let settings = Settings {
            root: Some(subject),
            cache: Some(dir.join("cache")),
            preset: Some(ModelPreset::Tiny),
            train_views: Some(vec![0, 2]),
            train_frames: Some("0:6".parse().unwrap()),
            novel_pose_frames: Some("6:10".parse().unwrap()),
            ..Settings::default()
        };
        let set: Vec<String> = [
            "train.batch=256",
            "train.mask_weight=0.1",
            "train.mask_edges=robust",
            "train.residual_weight=0.01",
        ]
        .iter()
        .chain(set)
        .map(|s| s.to_string())
        .collect();
        let config = config::assemble(config::demo_table(), &settings, &set).unwrap();
        let device = cpu_device().autodiff();
        let mut exp = Experiment::open(config, device.clone(), false).unwrap();
        if replicas > 1 {
            exp = exp.with_data_parallel(vec![device; replicas]).unwrap();
        }
        (exp, RunDir::create(&dir.join("run")).unwrap())
    }

    /// A fresh model and the stage-1 step that trains it from its first step.
    fn fresh_stage1<'a>(
        exp: &'a mut Experiment,
        cfg: &'a StageConfig,
        run: &'a RunDir,
    ) -> (AnimatableNerf, Stage1<'a>) {
        let (model, state) = fresh_start(exp, cfg);
        let record = Record::open(run, Stage::Train, 0).unwrap();
        (model, Stage1::new(exp, cfg, state, record).unwrap())
    }

    /// Each of `count` shards' logged values and parameter gradients for `batch`.
    fn loss_and_gradients(
        step: &Stage1<'_>,
        batch: &RayStep,
        model: &AnimatableNerf,
        count: usize,
    ) -> Vec<(StepValues, Vec<f32>)> {
        run_shards(count, |shard| {
            let (loss, values) = step.shard_loss(batch, &shard, model).unwrap();
            let grads = GradientsParams::from_grads(loss.backward(), model);
            let grads: Vec<f32> = parameter_gradients(model, &grads)
                .into_iter()
                .flatten()
                .flatten()
                .collect();
            (values, grads)
        })
    }

    /// The weighted losses of a batch split into shards average to the whole batch's loss, and their
    /// gradients (as Burn's all-reduce averages them) to its gradients: every term (colour, silhouette,
    /// consistency, residual penalty) is a mean over the batch, not over a shard. Both shards run here on
    /// the same flex device, the average taken on the host.
    #[test]
    fn shards_of_a_batch_average_to_its_loss_and_gradients() {
        let dir = tempfile::tempdir().unwrap();
        let (mut exp, run) = tiny_experiment(dir.path(), &[], 3);
        let cfg = exp.config.train.clone();
        let (model, mut step) = fresh_stage1(&mut exp, &cfg, &run);
        let batch = step.batch(3).unwrap();
        let split = |count: usize| loss_and_gradients(&step, &batch, &model, count);
        let whole = split(1).remove(0);
        assert!(
            whole.0.blend > 0.0 && whole.0.mse > 0.0,
            "every term is present"
        );
        let shards = split(3);
        let mean =
            |f: &dyn Fn(&StepValues) -> f32| shards.iter().map(|(v, _)| f(v)).sum::<f32>() / 3.0;
        let terms = [
            ("loss", mean(&|v| v.loss), whole.0.loss),
            ("colour MSE", mean(&|v| v.mse), whole.0.mse),
            ("blend terms", mean(&|v| v.blend), whole.0.blend),
        ];
        for (what, got, expected) in terms {
            eprintln!("{what}: shards {got}, whole {expected}");
        }
        for (what, got, expected) in terms {
            assert!(
                (got - expected).abs() <= 1e-5 * expected.abs(),
                "{what}: shards {got}, whole batch {expected}"
            );
        }
        assert_eq!(shards.iter().map(|(v, _)| v.items).sum::<usize>(), 256);
        let averaged: Vec<f32> = (0..whole.1.len())
            .map(|i| shards.iter().map(|(_, g)| g[i]).sum::<f32>() / 3.0)
            .collect();
        assert_eq!(shards[0].1.len(), whole.1.len(), "the same parameters");
        assert_close(
            "averaged shard gradients vs the whole batch's",
            &averaged,
            &whole.1,
            Tolerance::Relative(1e-4),
        );
    }

    /// A step of several frames weighs each frame's terms (colour, silhouette, consistency, residual, and
    /// its pose regulariser) by its share of the step's rays: its loss and gradients are the
    /// share-weighted sums of the one-frame steps of the same rays.
    #[test]
    fn a_step_of_several_frames_weighs_each_by_its_share_of_the_rays() {
        let dir = tempfile::tempdir().unwrap();
        let (mut exp, run) = tiny_experiment(
            dir.path(),
            &[
                "train.frames_per_step=3",
                "train.batch=250",
                "model.pose_refinement.enabled=true",
            ],
            1,
        );
        let cfg = exp.config.train.clone();
        let (model, mut step) = fresh_stage1(&mut exp, &cfg, &run);
        let batch = step.batch(1).unwrap();
        let frames: Vec<FrameId> = batch.frames.iter().map(|f| f.frame).collect();
        assert_eq!(frames.len(), 3);
        assert!(frames[0] != frames[1] && frames[1] != frames[2] && frames[0] != frames[2]);
        assert!(batch.frames.iter().all(|f| f.inputs[0].basis.is_some()));
        let whole = loss_and_gradients(&step, &batch, &model, 1).remove(0);
        let shares: Vec<f32> = batch
            .frames
            .iter()
            .map(|f| f.rays.len() as f32 / 250.0)
            .collect();
        assert!((shares.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        let singles: Vec<_> = batch
            .frames
            .into_iter()
            .map(|f| {
                let one = RayStep { frames: vec![f] };
                loss_and_gradients(&step, &one, &model, 1).remove(0)
            })
            .collect();
        let weighed = |f: &dyn Fn(&StepValues) -> f32| {
            singles
                .iter()
                .zip(&shares)
                .map(|((v, _), w)| w * f(v))
                .sum::<f32>()
        };
        for (what, got, expected) in [
            ("loss", whole.0.loss, weighed(&|v| v.loss)),
            ("colour MSE", whole.0.mse, weighed(&|v| v.mse)),
            ("blend terms", whole.0.blend, weighed(&|v| v.blend)),
        ] {
            assert!(
                expected > 0.0 && (got - expected).abs() <= 1e-5 * expected,
                "{what}: three frames {got}, share-weighted single frames {expected}"
            );
        }
        assert_eq!(whole.0.items, 250);
        let expected: Vec<f32> = (0..whole.1.len())
            .map(|i| {
                singles
                    .iter()
                    .zip(&shares)
                    .map(|((_, g), w)| w * g[i])
                    .sum()
            })
            .collect();
        assert_close(
            "three frames' gradients vs the share-weighted single frames'",
            &whole.1,
            &expected,
            Tolerance::Relative(1e-4),
        );
    }
}

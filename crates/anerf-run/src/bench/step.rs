//! The timed training step of `anerf bench`: the model's per-point work at training time, with every point
//! surviving culling (the frame's blend weights, inverse skinning, the canonical NeRF, the canonical blend
//! weights at the warped points), stage 1's objective on top, then backward and an Adam step.
//! `scripts/bench/torch_reference.py` runs the same networks on the same batch in PyTorch.

use std::time::Instant;

use anerf_core::geometry::skinning::BoneMatrices;
use anerf_core::geometry::BlendWeightVolume;
use anerf_core::geometry::{Aabb, BoneTransforms, GlobalTransform};
use anerf_core::model::{
    AnimatableNerf, CanonicalInputs, FrameCode, FrameInputs, ModelConfig, ModelPreset, ModelSizes,
};
use anerf_core::named::Named;
use anerf_core::tensor::from_rows;
use anerf_train::config::{self, Settings, StageConfig};
use anerf_train::training::objective::{Objective, TermSums};
use anerf_train::training::optimizer;
use anyhow::{Context, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use glam::{Mat4, Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What one timed step trains: a model and the stage-1 settings its loss and optimiser take.
#[derive(Debug, Clone)]
pub struct StepPreset {
    pub model: ModelConfig,
    pub stage: StageConfig,
}

impl StepPreset {
    /// `preset`'s model with the stage-1 settings a config of that preset gets.
    pub fn of(preset: ModelPreset) -> Result<Self> {
        let settings = Settings {
            preset: Some(preset),
            ..Settings::default()
        };
        let config = config::assemble(config::demo_table(), &settings, &[])
            .with_context(|| format!("the {} preset's config", preset.name()))?;
        Ok(Self {
            model: config.model,
            stage: config.train,
        })
    }
}

/// Joints of the benchmark's body (the SMPL skeleton's count).
const JOINTS: usize = 24;
/// Training frames the model is built for (sizes of the code tables).
const FRAMES: usize = 8;

/// The fixed inputs of one benchmark step: `points` pose-space samples with prior weights, view directions
/// and target colours, one frame's bone transforms and a canonical blend-weight volume. Random but seeded;
/// the timing does not depend on the values.
pub struct StepWorkload {
    points: Tensor<2>,
    prior: Tensor<2>,
    dirs: Tensor<2>,
    target: Tensor<2>,
    frame: FrameInputs,
    canonical: CanonicalInputs,
}

impl StepWorkload {
    /// Draws the inputs on `device`: points uniform in a 1 m box around the origin (metres, pose space),
    /// Dirichlet-like prior weights, unit directions, colours in `[0, 1]`; bones are small random rotations
    /// with small translations so inverse skinning stays well conditioned.
    pub fn new(points: usize, seed: u64, device: &Device) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut uniform = |n: usize, lo: f32, hi: f32| -> Vec<f32> {
            (0..n)
                .map(|_| lo + (hi - lo) * rng.random::<f32>())
                .collect()
        };
        let xyz = uniform(points * 3, -0.5, 0.5);
        let mut prior = uniform(points * JOINTS, 0.0, 1.0);
        for row in prior.chunks_mut(JOINTS) {
            let s: f32 = row.iter().sum();
            row.iter_mut().for_each(|w| *w /= s);
        }
        let mut dirs = uniform(points * 3, -1.0, 1.0);
        for d in dirs.chunks_mut(3) {
            let n = Vec3::from_slice(d).length().max(1e-3);
            d.iter_mut().for_each(|v| *v /= n);
        }
        let target = uniform(points * 3, 0.0, 1.0);
        let angles = uniform(JOINTS * 6, -0.3, 0.3);
        let matrices = angles
            .chunks(6)
            .map(|a| {
                Mat4::from_rotation_translation(
                    Quat::from_scaled_axis(Vec3::new(a[0], a[1], a[2])),
                    Vec3::new(a[3], a[4], a[5]) * 0.1,
                )
            })
            .collect();
        let bones = BoneTransforms::from_matrices(matrices).expect("24 finite transforms");
        let bounds = Aabb {
            min: Vec3::splat(-1.0),
            max: Vec3::splat(1.0),
        };
        let dims = [32, 32, 32];
        let nodes: usize = dims.iter().product();
        let mut table = uniform(nodes * (JOINTS + 1), 0.0, 1.0);
        for row in table.chunks_mut(JOINTS + 1) {
            let s: f32 = row[..JOINTS].iter().sum();
            row[..JOINTS].iter_mut().for_each(|w| *w /= s);
        }
        let volume = BlendWeightVolume::new(bounds, dims, JOINTS, table)
            .expect("a valid random volume")
            .to_tensor(device);
        Self {
            points: from_rows(&xyz, points, 3, device),
            prior: from_rows(&prior, points, JOINTS, device),
            dirs: from_rows(&dirs, points, 3, device),
            target: from_rows(&target, points, 3, device),
            frame: FrameInputs {
                bones: BoneMatrices::new(&bones, device),
                global: GlobalTransform {
                    rh: Vec3::ZERO,
                    th: Vec3::ZERO,
                },
                volume: volume.clone(),
                code: FrameCode::Training(1),
                appearance: 1,
                basis: None,
                warp: None,
            },
            canonical: CanonicalInputs {
                volume,
                bounds: Aabb {
                    min: Vec3::splat(-0.8),
                    max: Vec3::splat(0.8),
                },
            },
        }
    }

    /// A model of `config` sized for the workload.
    pub fn model(&self, config: &ModelConfig, device: &Device) -> AnimatableNerf {
        AnimatableNerf::new(
            config,
            ModelSizes {
                training_frames: FRAMES,
                joints: JOINTS,
            },
            device,
        )
    }

    /// The step's loss: stage 1's [`Objective`] with `stage`'s weights, each point a ray of its own
    /// ([`TermSums::of_points`]: colour MSE + blend-weight consistency, + the residual penalty where
    /// `stage` weighs it).
    pub fn loss(&self, model: &AnimatableNerf, stage: &StageConfig) -> Tensor<1> {
        let shaded = model.shade(
            self.points.clone(),
            self.prior.clone(),
            self.dirs.clone(),
            &self.frame,
            &self.canonical,
        );
        let terms = model.consistency_terms(&shaded, &self.canonical);
        let sums = TermSums::of_points(
            shaded.rgb,
            self.target.clone(),
            &terms,
            stage,
            model.config().consistency,
        );
        let totals = sums.local_totals();
        Objective { cfg: stage }.weigh(sums, totals, 1).loss
    }
}

/// Wall-clock and CPU time of one step, seconds.
#[derive(Debug, Clone, Copy)]
pub struct StepTime {
    pub wall: f64,
    pub cpu: f64,
}

/// One preset's training step on a fixed workload: its inputs, model, loss weights and optimiser.
struct StepRunner {
    work: StepWorkload,
    model: Option<AnimatableNerf>,
    stage: StageConfig,
    optim: ModuleOptimizer,
    device: Device,
}

impl StepRunner {
    fn new(preset: &StepPreset, points: usize, device: &Device) -> Self {
        let work = StepWorkload::new(points, 7, device);
        let model = work.model(&preset.model, device);
        Self {
            work,
            model: Some(model),
            // The training loop's optimiser with the stage's gradient clip.
            optim: optimizer(preset.stage.grad_clip),
            stage: preset.stage.clone(),
            device: device.clone(),
        }
    }

    /// One forward, backward and Adam step, timed.
    fn step(&mut self) -> StepTime {
        let (started, cpu) = (Instant::now(), process_cpu_seconds());
        let model = self
            .model
            .take()
            .expect("the model is back after every step");
        let loss = self.work.loss(&model, &self.stage);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        self.model = Some(self.optim.step(5e-4, model, grads));
        self.device.sync().expect("the device finishes its queue");
        StepTime {
            wall: started.elapsed().as_secs_f64(),
            cpu: process_cpu_seconds() - cpu,
        }
    }
}

/// One warm-up step, then `steps` timed steps of forward, backward and Adam on an autodiff `device`.
pub fn time_steps(
    preset: &StepPreset,
    points: usize,
    steps: usize,
    device: &Device,
) -> Vec<StepTime> {
    let mut runner = StepRunner::new(preset, points, device);
    runner.step();
    (0..steps).map(|_| runner.step()).collect()
}

/// Untimed rounds before [`time_steps_interleaved`] times any: with one, the first timed step of every
/// configuration but the last, run right after the others' first steps, was the slowest of its run (the
/// `fast` step by 15–20 % after the `paper` warm-up, in every run).
const WARM_UP_ROUNDS: usize = 2;

/// [`time_steps`] of several configurations in rounds: [`WARM_UP_ROUNDS`] untimed rounds, then per round one
/// timed step of each in turn. Returns each configuration's step times.
pub fn time_steps_interleaved(
    presets: &[StepPreset],
    points: usize,
    steps: usize,
    device: &Device,
) -> Vec<Vec<StepTime>> {
    let mut runners: Vec<StepRunner> = presets
        .iter()
        .map(|p| StepRunner::new(p, points, device))
        .collect();
    for _ in 0..WARM_UP_ROUNDS {
        runners.iter_mut().for_each(|r| {
            r.step();
        });
    }
    let mut times = vec![Vec::with_capacity(steps); presets.len()];
    for _ in 0..steps {
        for (runner, times) in runners.iter_mut().zip(&mut times) {
            times.push(runner.step());
        }
    }
    times
}

/// User + system CPU time of this process (all threads), seconds, from `/proc/self/stat` (clock ticks of
/// 1/100 s); NaN where unavailable.
fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15 (1-based).
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok());
    match (ticks(11), ticks(12)) {
        (Some(u), Some(s)) => (u + s) / 100.0,
        _ => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tiny preset's timed step runs and lowers its own loss on the fixed batch.
    #[test]
    fn steps_run_and_train() {
        let device = anerf_device::cpu_device().autodiff();
        let preset = StepPreset::of(ModelPreset::Tiny).unwrap();
        let mut runner = StepRunner::new(&preset, 256, &device);
        let loss = |r: &StepRunner| {
            r.work
                .loss(r.model.as_ref().unwrap(), &r.stage)
                .into_scalar::<f32>()
        };
        let first = loss(&runner);
        for _ in 0..20 {
            let t = runner.step();
            assert!(t.wall > 0.0 && t.wall.is_finite());
        }
        let last = loss(&runner);
        assert!(last.is_finite() && last < first, "{first} → {last}");
    }

    /// Interleaved rounds give every configuration its own timed steps.
    #[test]
    fn interleaved_rounds_time_every_configuration() {
        let device = anerf_device::cpu_device().autodiff();
        let tiny = StepPreset::of(ModelPreset::Tiny).unwrap();
        let wider = StepPreset {
            model: ModelConfig {
                width: 48,
                ..tiny.model.clone()
            },
            ..tiny.clone()
        };
        let times = time_steps_interleaved(&[tiny, wider], 128, 3, &device);
        assert_eq!(times.len(), 2);
        for t in &times {
            assert_eq!(t.len(), 3);
            assert!(t.iter().all(|s| s.wall > 0.0 && s.wall.is_finite()));
        }
    }
}

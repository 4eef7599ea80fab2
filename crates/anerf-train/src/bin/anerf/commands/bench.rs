//! `anerf bench`: the training-step time and throughput of each model preset on a fixed batch of points,
//! the time to render a square image of the demo subject, and the peak memory of each.
//!
//! The step is the model's per-point work at training time, with every point surviving culling: the frame's
//! blend weights (MLP 1), inverse skinning, the canonical NeRF (MLP 2), the canonical blend weights at the
//! warped points (MLP 3), a colour loss, the consistency loss and a small density penalty; then backward and
//! an Adam step. `scripts/bench/torch_reference.py` runs the same networks on the same batch in PyTorch.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anerf_core::geometry::skinning::BoneMatrices;
use anerf_core::geometry::BlendWeightVolume;
use anerf_core::geometry::{Aabb, BoneTransforms, GlobalTransform};
use anerf_core::model::{
    AnimatableNerf, CanonicalInputs, ConsistencyTerms, FrameCode, FrameInputs, ModelConfig,
    ModelPreset, ModelSizes,
};
use anerf_core::render::color_mse;
use anerf_core::tensor::from_rows;
use anerf_core::DeviceChoice;
use anerf_train::config::{self, Settings};
use anerf_train::experiment::Experiment;
use anerf_train::jobs::{load_trained, open_checked_device};
use anerf_train::render::render_view;
use anerf_train::run_dir::RunDir;
use anerf_train::training::optimizer;
use anyhow::{Context, Result};
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use glam::{Mat4, Quat, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Options of `anerf bench`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// Model presets to measure, comma-separated (default: every preset).
    #[arg(long, value_delimiter = ',')]
    pub presets: Vec<ModelPreset>,
    /// Points per training step.
    #[arg(long, default_value_t = 65_536)]
    pub points: usize,
    /// Timed training steps per preset, after one untimed warm-up step (two rounds with `--interleave`; 0
    /// skips the step benchmark).
    #[arg(long, default_value_t = 3)]
    pub steps: usize,
    /// Side in pixels of the square render of the demo subject (0 skips the render).
    #[arg(long, default_value_t = 512)]
    pub render_size: u32,
    /// Demo subject to render (written there by `anerf synth --preset demo` when missing).
    #[arg(long, default_value = "target/bench/subject")]
    pub subject: PathBuf,
    /// Render with this trained run's model (and its preset) instead of a freshly initialised one.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Compute backend.
    #[arg(long, default_value = "flex")]
    pub device: DeviceChoice,
    /// One JSON object per preset on stdout instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Only print each preset's model configuration as one JSON object per line (the input of
    /// `scripts/bench/torch_reference.py`), measuring nothing.
    #[arg(long)]
    pub describe: bool,
    /// Use the system allocator's behaviour instead of the `anerf` binary's block cache (to measure what the
    /// cache buys).
    #[arg(long)]
    pub system_allocator: bool,
    /// Time the presets' steps in turn (one step of each, then the next round) instead of one preset after
    /// the other, so that drift in the machine's speed reaches every preset alike; also prints the median of
    /// the per-round ratios to the first preset. Step memory is then not reported (one process holds every
    /// model).
    #[arg(long)]
    pub interleave: bool,
}

/// One line of `--describe`.
#[derive(Debug, Serialize)]
struct Described {
    preset: &'static str,
    model: ModelConfig,
}

/// What was measured for one preset.
#[derive(Debug, Clone, Serialize)]
pub struct PresetFigures {
    pub preset: &'static str,
    /// The GPU adapter the device runs on, as its probe reported it; `None` on CPU backends.
    pub adapter: Option<String>,
    pub points: usize,
    /// Seconds of each timed step (forward, backward, Adam).
    pub step_seconds: Vec<f64>,
    /// Median of `step_seconds`.
    pub step_median: Option<f64>,
    /// CPU seconds (user + system, all threads) of each timed step: less sensitive than wall time to other
    /// programs sharing the cores.
    pub step_cpu_seconds: Vec<f64>,
    /// `points / step_median`.
    pub points_per_second: Option<f64>,
    /// Peak resident memory during the steps, MiB (`VmHWM`).
    pub step_peak_mib: Option<f64>,
    pub render: Option<RenderFigures>,
    /// One-minute load average before the preset started (other users of the machine).
    pub load_before: f64,
}

/// Renders timed after the first: the warm figure.
const WARM_RENDERS: usize = 3;

/// One view rendered once cold, then [`WARM_RENDERS`] times again.
#[derive(Debug, Clone, Serialize)]
pub struct RenderFigures {
    pub width: u32,
    pub height: u32,
    /// The first render: it also uploads the frame's inputs and, on a GPU, compiles and autotunes every
    /// kernel the render launches.
    pub seconds: f64,
    /// The renders after it, and their median: what an interactive viewer or a long render pays per image.
    pub warm_seconds: Vec<f64>,
    pub warm_median: Option<f64>,
    /// Rays that hit the body box (the others are black without any work).
    pub rays: usize,
    /// Samples that survive culling / all samples along those rays.
    pub surviving_fraction: f64,
    /// Samples shaded before their ray stopped (early termination) / all samples.
    pub shaded_fraction: f64,
    /// Peak resident memory during the render, MiB.
    pub peak_mib: Option<f64>,
    /// Whether a trained run's model was rendered.
    pub trained: bool,
}

/// Runs the benchmark, printing each preset's figures as they are measured.
pub fn run(args: &BenchArgs) -> Result<Vec<PresetFigures>> {
    let presets = if args.presets.is_empty() {
        ModelPreset::ALL.to_vec()
    } else {
        args.presets.clone()
    };
    if args.describe {
        for preset in presets {
            let line = Described {
                preset: preset.name(),
                model: preset.config(),
            };
            println!("{}", serde_json::to_string(&line)?);
        }
        return Ok(Vec::new());
    }
    // Probed like every job's device, so a broken driver is an error and the figures name the adapter.
    let checked = open_checked_device(args.device)?;
    let (device, adapter) = (checked.device, checked.adapter);
    if !args.json {
        println!(
            "{:<6} {:>9} {:>12} {:>10} {:>9} {:>7} {:>10} {:>8} {:>10} {:>6}",
            "preset",
            "step s",
            "points/s",
            "step MiB",
            "render s",
            "1st s",
            "surviving",
            "shaded",
            "render MiB",
            "load"
        );
    }
    let mut all = Vec::new();
    let mut interleaved = if args.interleave && args.steps > 0 {
        let configs: Vec<ModelConfig> = presets.iter().map(|p| p.config()).collect();
        time_steps_interleaved(
            &configs,
            args.points,
            args.steps,
            &device.clone().autodiff(),
        )
    } else {
        Vec::new()
    }
    .into_iter();
    for preset in presets {
        let load_before = load_average();
        let config = preset.config();
        let (step_times, step_peak_mib) = if let Some(times) = interleaved.next() {
            (times, None)
        } else if args.steps > 0 {
            reset_peak_memory();
            let times = time_steps(&config, args.points, args.steps, &device.clone().autodiff());
            (times, peak_memory_mib())
        } else {
            (Vec::new(), None)
        };
        let step_seconds: Vec<f64> = step_times.iter().map(|t| t.wall).collect();
        let render = if args.render_size > 0 {
            Some(time_render(args, preset, &device)?)
        } else {
            None
        };
        let step_median = median(&step_seconds);
        let figures = PresetFigures {
            preset: preset.name(),
            adapter: adapter.clone(),
            points: args.points,
            points_per_second: step_median.map(|s| args.points as f64 / s),
            step_median,
            step_cpu_seconds: step_times.iter().map(|t| t.cpu).collect(),
            step_seconds,
            step_peak_mib,
            render,
            load_before,
        };
        if args.json {
            println!("{}", serde_json::to_string(&figures)?);
        } else {
            print_row(&figures);
        }
        all.push(figures);
    }
    if args.interleave && !args.json {
        print_round_ratios(&all);
    }
    Ok(all)
}

/// With `--interleave`: each preset's step time over the first preset's, round by round (the steps of one
/// round ran back to back), and the median of those ratios.
fn print_round_ratios(all: &[PresetFigures]) {
    let Some((first, rest)) = all.split_first() else {
        return;
    };
    for other in rest {
        let ratios: Vec<f64> = other
            .step_seconds
            .iter()
            .zip(&first.step_seconds)
            .map(|(o, f)| o / f)
            .collect();
        if let Some(m) = median(&ratios) {
            let rounds: Vec<String> = ratios.iter().map(|r| format!("{r:.2}")).collect();
            println!(
                "{} / {} step, per round: {}; median {m:.2}",
                other.preset,
                first.preset,
                rounds.join(" ")
            );
        }
    }
}

fn print_row(f: &PresetFigures) {
    let opt =
        |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    println!(
        "{:<6} {:>9} {:>12} {:>10} {:>9} {:>7} {:>10} {:>8} {:>10} {:>6.2}",
        f.preset,
        opt(f.step_median, 3),
        opt(f.points_per_second, 0),
        opt(f.step_peak_mib, 0),
        opt(f.render.as_ref().and_then(|r| r.warm_median), 3),
        opt(f.render.as_ref().map(|r| r.seconds), 2),
        opt(f.render.as_ref().map(|r| r.surviving_fraction), 3),
        opt(f.render.as_ref().map(|r| r.shaded_fraction), 3),
        opt(f.render.as_ref().and_then(|r| r.peak_mib), 0),
        f.load_before
    );
}

/// Median of a list of timings.
pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
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

    /// The step's loss: colour MSE + blend-weight consistency + 1e-4 · mean raw density².
    pub fn loss(&self, model: &AnimatableNerf) -> Tensor<1> {
        let shaded = model.shade(
            self.points.clone(),
            self.prior.clone(),
            self.dirs.clone(),
            &self.frame,
            &self.canonical,
        );
        let terms = ConsistencyTerms::new(
            shaded.weights.clone(),
            model.canonical_weights(shaded.canonical_points.clone(), &self.canonical),
            shaded.density.clone(),
            shaded.residual.clone(),
        );
        color_mse(shaded.rgb, self.target.clone())
            + terms.loss(model.config().consistency)
            + shaded.density.powi_scalar(2).mean() * 1e-4
    }
}

/// Wall-clock and CPU time of one step, seconds.
#[derive(Debug, Clone, Copy)]
pub struct StepTime {
    pub wall: f64,
    pub cpu: f64,
}

/// One preset's training step on a fixed workload: its inputs, model and optimiser.
struct StepRunner {
    work: StepWorkload,
    model: Option<AnimatableNerf>,
    optim: ModuleOptimizer,
    device: Device,
}

impl StepRunner {
    fn new(config: &ModelConfig, points: usize, device: &Device) -> Self {
        let work = StepWorkload::new(points, 7, device);
        let model = work.model(config, device);
        Self {
            work,
            model: Some(model),
            // The training loop's optimiser with the shipped configs' clip (`grad_clip = 40.0`).
            optim: optimizer(40.0),
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
        let loss = self.work.loss(&model);
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
    config: &ModelConfig,
    points: usize,
    steps: usize,
    device: &Device,
) -> Vec<StepTime> {
    let mut runner = StepRunner::new(config, points, device);
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
    configs: &[ModelConfig],
    points: usize,
    steps: usize,
    device: &Device,
) -> Vec<Vec<StepTime>> {
    let mut runners: Vec<StepRunner> = configs
        .iter()
        .map(|c| StepRunner::new(c, points, device))
        .collect();
    for _ in 0..WARM_UP_ROUNDS {
        runners.iter_mut().for_each(|r| {
            r.step();
        });
    }
    let mut times = vec![Vec::with_capacity(steps); configs.len()];
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

/// Renders one `size`×`size` view of the demo subject (or of `args.run`'s subject with its model).
fn time_render(args: &BenchArgs, preset: ModelPreset, device: &Device) -> Result<RenderFigures> {
    let (model, mut exp, trained) = match &args.run {
        Some(run) => {
            let run = RunDir::open(run)?;
            let config = run.read_config()?;
            let model = load_trained(&run, &config, device)?;
            (
                model,
                Experiment::open(config, device.clone(), false)?,
                true,
            )
        }
        None => {
            let config = demo_frame_config(&args.subject, preset)?;
            let exp = Experiment::open(config, device.clone(), false)?;
            let model = AnimatableNerf::new(&exp.config.model, exp.model_sizes(), device);
            (model, exp, false)
        }
    };
    let frame = exp.train_frames[0];
    let view = *exp.test_views.first().unwrap_or(&exp.train_views[0]);
    let base = exp.prepared.cameras[view.0].clone();
    let camera = base.resized(args.render_size as f32 / base.width.max(base.height) as f32);
    reset_peak_memory();
    let mut timed = || -> Result<_> {
        let started = Instant::now();
        let image = render_view(&model, &mut exp, frame, &camera, None)?;
        Ok((started.elapsed().as_secs_f64(), image))
    };
    let (seconds, image) = timed()?;
    let warm_seconds = (0..WARM_RENDERS)
        .map(|_| Ok(timed()?.0))
        .collect::<Result<Vec<_>>>()?;
    Ok(RenderFigures {
        width: camera.width,
        height: camera.height,
        seconds,
        warm_median: median(&warm_seconds),
        warm_seconds,
        rays: image.rays,
        surviving_fraction: image.surviving_samples as f64 / image.total_samples.max(1) as f64,
        shaded_fraction: image.shaded_samples as f64 / image.total_samples.max(1) as f64,
        peak_mib: peak_memory_mib(),
        trained,
    })
}

/// The demo experiment cut to its first frame (quick to prepare), with `preset`'s model; the subject is
/// synthesised into `subject` when it is missing, its cache goes beside it.
fn demo_frame_config(subject: &Path, preset: ModelPreset) -> Result<config::ExperimentConfig> {
    if !subject.join("annots.npy").is_file() {
        super::synth::write(subject, &anerf_data::synthetic::SynthPreset::Demo.spec())?;
    }
    let cache = subject
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .join("cache");
    let one = |start| config::FrameRange {
        start,
        end: start + 1,
        step: 1,
    };
    let settings = Settings {
        root: Some(subject.to_path_buf()),
        cache: Some(cache),
        preset: Some(preset),
        train_frames: Some(one(0)),
        novel_pose_frames: Some(one(1)),
        ..Settings::default()
    };
    config::assemble(config::demo_table(), &settings, &[]).context("the benchmark's demo config")
}

/// One-minute load average (`/proc/loadavg`), NaN where unavailable.
pub fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}

/// Resets the peak resident set size of this process (Linux: `5` into `/proc/self/clear_refs`).
fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Peak resident set size since the last reset, MiB (`VmHWM` of `/proc/self/status`); `None` off Linux.
fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_lists() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&[]), None);
    }

    /// The tiny preset's timed step runs and lowers its own loss on the fixed batch.
    #[test]
    fn steps_run_and_train() {
        let device = anerf_core::device::cpu_device().autodiff();
        let mut runner = StepRunner::new(&ModelPreset::Tiny.config(), 256, &device);
        let loss = |r: &StepRunner| r.work.loss(r.model.as_ref().unwrap()).into_scalar::<f32>();
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
        let device = anerf_core::device::cpu_device().autodiff();
        let tiny = ModelPreset::Tiny.config();
        let wider = ModelConfig {
            width: 48,
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

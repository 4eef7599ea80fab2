//! What each `anerf` subcommand does, as library functions (the binary only parses arguments).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use anerf_core::device::probe::checked_device;
use anerf_core::model::{AnimatableNerf, ModelPreset};
use anerf_core::{DeviceChoice, FrameId};
use anerf_data::synthetic::{write_subject, SynthPreset};
use anerf_data::visual_hull::VisualHull;
use anerf_data::DatasetKind;
use anerf_eval::report::{markdown_table, EvalRecorder, EvalSplit, Summary};
use anyhow::{bail, Context, Result};
use burn::prelude::Device;
use toml::Table;

use crate::checkpoint::Checkpoint;
use crate::cli::Common;
use crate::config::{self, ExperimentConfig, FrameRange};
use crate::experiment::Experiment;
use crate::memory::{self, Work};
use crate::render::{render_shot, render_view, Shot};
use crate::run_dir::RunDir;
use crate::run_start::{self, RunStart};
use crate::stage::Stage;
use crate::train::{train_stage1, train_stage2, StageOutcome, TrainOptions};

/// The device named by `--device`, else by the config.
pub fn device(config: &ExperimentConfig, common: &Common) -> Result<Device> {
    open_device(common.device.unwrap_or(config.device), common)
}

/// The device of `choice`. A GPU backend is first checked in a child process that re-runs the current
/// executable (the `anerf` binary, whose `main` answers such a check), so that a driver crash becomes an
/// error instead of killing the run; the check runs once per process, and the adapter it ran on is printed
/// then unless `--quiet`.
fn open_device(choice: DeviceChoice, common: &Common) -> Result<Device> {
    static ANNOUNCED: std::sync::Once = std::sync::Once::new();
    let exe = std::env::current_exe().context("locating the anerf executable")?;
    let checked =
        checked_device(choice, || std::process::Command::new(exe)).with_context(|| {
            format!("cannot use device '{choice}' (`--device flex` runs on the CPU)")
        })?;
    if let (Some(adapter), false) = (&checked.adapter, common.quiet) {
        ANNOUNCED.call_once(|| eprintln!("device {choice}: {adapter}"));
    }
    Ok(checked.device)
}

/// Loads a config file with `--set` overrides.
pub fn load_config(path: &Path, common: &Common) -> Result<ExperimentConfig> {
    load_config_with(path, &common.overrides)
}

fn load_config_with(path: &Path, overrides: &[String]) -> Result<ExperimentConfig> {
    config::load(path, overrides).map_err(|e| match e {
        // These name the file already.
        config::ConfigError::Read { .. }
        | config::ConfigError::Parse { .. }
        | config::ConfigError::BaseCycle { .. } => e.into(),
        _ => anyhow::Error::new(e).context(format!("in config {}", path.display())),
    })
}

/// The config of `anerf train`: the file (or `--data` folder), then the flags, then `--set`.
pub fn train_config(args: &crate::cli::TrainArgs) -> Result<ExperimentConfig> {
    match (&args.config, &args.data) {
        (Some(path), None) => {
            let mut overrides = train_flag_overrides(args)?;
            overrides.extend(args.common.overrides.iter().cloned());
            load_config_with(path, &overrides)
        }
        (None, Some(data)) => config_for_folder(data, args),
        _ => bail!("give a config file or --data <folder>"),
    }
}

/// `anerf train`'s flags (`--train-views`, `--train-frames`, `--novel-pose-frames`, `--preset`,
/// `--iterations`) as `section.key=value` overrides. Frame flags define the ICCV split and select it.
fn train_flag_overrides(args: &crate::cli::TrainArgs) -> Result<Vec<String>> {
    let mut overrides = Vec::new();
    if let Some(v) = &args.train_views {
        overrides.push(format!("dataset.train_views={v:?}"));
    }
    let ranges = [
        ("train_frames", &args.train_frames),
        ("novel_pose_frames", &args.novel_pose_frames),
    ];
    for (key, value) in ranges {
        if let Some(v) = value {
            v.parse::<FrameRange>()
                .map_err(|e| anyhow::anyhow!("--{}: {e}", key.replace('_', "-")))?;
            overrides.push(format!("dataset.iccv.{key}=\"{v}\""));
        }
    }
    // Frame flags set the `iccv` ranges, so those are the ones used.
    if ranges.iter().any(|(_, v)| v.is_some()) {
        overrides.push("dataset.ranges=\"iccv\"".into());
    }
    if let Some(p) = args.preset {
        overrides.push(format!("model.preset=\"{}\"", p.name()));
    }
    if let Some(n) = args.iterations {
        overrides.push(format!("train.iterations={n}"));
    }
    Ok(overrides)
}

/// `anerf synth`.
pub fn synth(out: &Path, preset: SynthPreset, seed: Option<u64>) -> Result<()> {
    let mut spec = preset.spec();
    if let Some(s) = seed {
        spec.seed = s;
    }
    let summary = write_subject(&spec, out)
        .with_context(|| format!("writing the synthetic subject to {}", out.display()))?;
    println!(
        "wrote {} ({} cameras, {} frames) in {:.1} s",
        out.display(),
        summary.subject.cameras.len(),
        summary.subject.frames.len(),
        summary.timings.total.as_secs_f64()
    );
    Ok(())
}

/// Config of a folder trained without a config file (`anerf train --data`): the folder's `splits.json`
/// (written by `anerf synth`) or sensible defaults, then the flags, then `--set`.
pub fn config_for_folder(data: &Path, args: &crate::cli::TrainArgs) -> Result<ExperimentConfig> {
    let kind = anerf_data::loaders::detect_kind(data);
    let subject = anerf_data::load(data, kind, &Default::default()).with_context(|| {
        format!(
            "reading {} (expected a subject folder in the ZJU-MoCap layout)",
            data.display()
        )
    })?;
    let cameras = subject.cameras.len();
    let frames = subject.frames.len();
    let splits: Option<anerf_data::synthetic::Splits> =
        std::fs::read_to_string(data.join("splits.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
    let (views, train, novel) = match &splits {
        Some(s) => (
            s.training_views.clone(),
            span(&s.training_frames),
            span(&s.novel_pose_frames),
        ),
        None => {
            let views: Vec<usize> = (0..4.min(cameras))
                .map(|i| i * cameras / 4.min(cameras))
                .collect();
            let cut = (frames * 2 / 3).max(1);
            (views, format!("0:{cut}"), format!("{cut}:{frames}"))
        }
    };
    let name = data
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or("subject")
        .replace(['/', '\\'], "_");
    let ratio = if subject.cameras.first().is_some_and(|c| c.width >= 1000) {
        0.5
    } else {
        1.0
    };
    let mut table: Table = toml::from_str(&format!(
        r#"
name = "{name}"
[dataset]
format = "{format}"
root = "{root}"
ratio = {ratio}
train_views = {views:?}
iccv = {{ train_frames = "{train}", novel_pose_frames = "{novel}" }}
[model]
preset = "cpu"
"#,
        format = if kind == DatasetKind::H36m {
            "h36m"
        } else {
            "zju_mocap"
        },
        root = data.display().to_string().replace('\\', "/"),
    ))?;
    let mut merged = config::defaults();
    config::merge(&mut merged, std::mem::take(&mut table));
    for o in train_flag_overrides(args)?
        .iter()
        .chain(&args.common.overrides)
    {
        config::apply_override(&mut merged, o)?;
    }
    Ok(config::from_table(merged)?)
}

/// `"a:b"` covering a sorted list of consecutive frame indices (`splits.json` lists them explicitly).
fn span(frames: &[usize]) -> String {
    match (frames.first(), frames.last()) {
        (Some(a), Some(b)) => format!("{a}:{}", b + 1),
        _ => "0:0".into(),
    }
}

/// `anerf train`: stage 1 into `run`. The start is checked (`start`), the config validated and the data
/// opened before the folder is touched; a start that fails before its first checkpoint removes what it made.
pub fn train(
    mut config: ExperimentConfig,
    run: &Path,
    common: &Common,
    start: RunStart,
    max_steps: Option<usize>,
    stop: &AtomicBool,
) -> Result<StageOutcome> {
    run_start::check_stage1(run, start)?;
    if start == RunStart::Resume {
        let existing = RunDir::open(run)?;
        if existing.read_config()?.model != config.model {
            bail!(
                "--resume: the config's [model] differs from the run's {}",
                existing.config_path().display()
            );
        }
    }
    config.dataset.make_paths_absolute()?;
    memory::check(&config, Work::Train)?;
    let device = device(&config, common)?.autodiff();
    let mut exp = Experiment::open(config, device, !common.quiet)?;
    let run = run_start::begin_stage1(run, start)?;
    let result = run.write_config(&exp.config).and_then(|()| {
        train_stage1(
            &mut exp,
            &run,
            stage_options(start, common, max_steps),
            stop,
        )
    });
    let outcome = match result {
        Ok(o) => o,
        Err(e) => {
            if start != RunStart::Resume
                && Checkpoint::latest(&run.checkpoints(), Stage::Train)
                    .ok()
                    .flatten()
                    .is_none()
            {
                // Nothing worth keeping was made: leave no half-made run behind.
                let _ = std::fs::remove_dir_all(&run.root);
            }
            return Err(e);
        }
    };
    report_outcome("stage 1", &outcome, &run);
    Ok(outcome)
}

/// `anerf animate`: stage 2 of a run (`start` as for [`train`], over stage 2's checkpoints).
pub fn animate(
    run: &Path,
    common: &Common,
    start: RunStart,
    max_steps: Option<usize>,
    stop: &AtomicBool,
) -> Result<StageOutcome> {
    let (run, config) = open_run(run, common, Work::Animate)?;
    run_start::check_stage2(&run, start)?;
    let device = device(&config, common)?.autodiff();
    let mut exp = Experiment::open(config, device, !common.quiet)?;
    run_start::begin_stage2(&run, start)?;
    let outcome = train_stage2(
        &mut exp,
        &run,
        stage_options(start, common, max_steps),
        stop,
    )?;
    report_outcome("stage 2", &outcome, &run);
    Ok(outcome)
}

fn stage_options(start: RunStart, common: &Common, max_steps: Option<usize>) -> TrainOptions {
    TrainOptions {
        resume: start == RunStart::Resume,
        progress: !common.quiet,
        max_steps,
    }
}

/// Opens a run folder and its config with the command's `--set` overrides, and checks that a step of
/// `work` fits in memory.
fn open_run(path: &Path, common: &Common, work: Work) -> Result<(RunDir, ExperimentConfig)> {
    let run = RunDir::open(path)?;
    let mut config = run.read_config()?;
    apply_overrides(&mut config, common)?;
    memory::check(&config, work)?;
    Ok((run, config))
}

fn apply_overrides(config: &mut ExperimentConfig, common: &Common) -> Result<()> {
    if common.overrides.is_empty() {
        return Ok(());
    }
    let mut table: Table = toml::from_str(&config::to_toml(config))?;
    for o in &common.overrides {
        config::apply_override(&mut table, o)?;
    }
    *config = config::from_table(table)?;
    Ok(())
}

fn report_outcome(stage: &str, o: &StageOutcome, run: &RunDir) {
    if o.loss.is_nan() && !o.interrupted {
        // No step ran: the stage had already finished (a resumed or re-run demo).
        eprintln!(
            "{stage} was already complete at step {}; checkpoints in {}",
            o.steps,
            run.checkpoints().display()
        );
        return;
    }
    let how = if o.interrupted {
        "interrupted"
    } else {
        "finished"
    };
    eprintln!(
        "{stage} {how} after {} steps in {:.0} s (last loss {:.5}); checkpoints in {}",
        o.steps,
        o.seconds,
        o.loss,
        run.checkpoints().display()
    );
}

/// The run's newest intact model: stage 2 if it has one, else stage 1.
pub fn load_trained(
    run: &RunDir,
    config: &ExperimentConfig,
    device: &Device,
) -> Result<AnimatableNerf> {
    for stage in [Stage::Animate, Stage::Train] {
        if let Some(r) =
            Checkpoint::restore_newest(&run.checkpoints(), stage, &config.model, device, None)?
        {
            return Ok(r.model);
        }
    }
    bail!(
        "{} has no checkpoint; run `anerf train` first",
        run.root.display()
    )
}

/// `anerf eval`: renders every test view of every `eval.frame_interval`-th frame of the split and writes
/// `<run>/eval/<split>/` (per-image metrics, images, summary).
pub fn eval(run_path: &Path, split: EvalSplit, common: &Common) -> Result<Summary> {
    let (run, config) = open_run(run_path, common, Work::Render)?;
    let device = device(&config, common)?;
    let model = load_trained(&run, &config, &device)?;
    let mut exp = Experiment::open(config, device, !common.quiet)?;
    let frames: Vec<FrameId> = match split {
        EvalSplit::TrainingView | EvalSplit::NovelView => exp.train_frames.clone(),
        EvalSplit::NovelPose => {
            if model.novel_blend.is_none() {
                bail!("{} has no stage-2 checkpoint; run `anerf animate {}` before a novel-pose evaluation", run.root.display(), run.root.display());
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
    let dir = run.eval().join(split.name());
    let mut recorder = EvalRecorder::new(&dir, split);
    let bar = indicatif::ProgressBar::new((frames.len() * views.len()) as u64);
    if common.quiet {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    for &frame in &frames {
        for &view in &views {
            let camera = exp.prepared.cameras[view.0].clone();
            let image = render_view(&model, &mut exp, frame, &camera, Some(view))?;
            let gt = image
                .ground_truth
                .as_ref()
                .expect("dataset views have images");
            recorder.add(frame, view, &image.prediction, gt, &image.mask)?;
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let summary = recorder.finish()?;
    println!(
        "{}",
        markdown_table(
            "split",
            &[(format!("{} {split}", exp.config.name), summary)]
        )
    );
    println!("per-image metrics and images in {}", dir.display());
    Ok(summary)
}

/// `anerf compare`.
pub fn compare(pred: &Path, gt: &Path, mask: Option<&Path>) -> Result<()> {
    let c = anerf_eval::compare_files(pred, gt, mask)?;
    println!("{c}");
    Ok(())
}

/// `anerf info`: for a config, its dataset folder with its layout and body-model file; returns false when a
/// problem is fatal.
pub fn info(path: &Path) -> Result<bool> {
    let (root, options) = if path.extension().is_some_and(|e| e == "toml") {
        let d = config::load(path, &[])?.dataset;
        if !d.root.is_dir() {
            bail!(
                "dataset.root = {} in {} is not a folder (expected the subject folder)",
                d.root.display(),
                path.display()
            );
        }
        let load = anerf_data::LoadOptions {
            body_model: d.body_model,
        };
        (
            d.root,
            anerf_data::InspectOptions {
                kind: Some(d.format.kind()),
                load,
            },
        )
    } else if path.is_file() {
        bail!(
            "{} is a file; expected a subject folder or an experiment config (.toml)",
            path.display()
        );
    } else {
        (path.to_path_buf(), Default::default())
    };
    let report = anerf_data::inspect(&root, &options);
    println!("{report}");
    Ok(!report.has_fatal())
}

/// `anerf prepare`.
pub fn prepare(config: ExperimentConfig, common: &Common) -> Result<()> {
    let device = device(&config, common)?;
    let exp = Experiment::open(config, device, !common.quiet)?;
    println!(
        "prepared {} frames of {} in {}",
        exp.prepared.frames.len(),
        exp.prepared.name,
        exp.prepared.dir.display()
    );
    Ok(())
}

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
    /// The poses of a pose file or folder (`params/{i}.npy` format) from dataset camera `view` (default:
    /// the first training view), after fitting their blend-weight codes as stage 2 does.
    PoseFiles { path: PathBuf, view: Option<usize> },
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

/// A progress bar over `n` images, hidden with `--quiet`.
fn image_bar(n: usize, common: &Common) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(n as u64);
    if common.quiet {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar
}

/// `anerf render`: PNG frames, an animated GIF and (with ffmpeg on PATH) an MP4 under `<run>/renders/`.
/// Returns the GIF's path.
pub fn render(run_path: &Path, job: RenderJob, common: &Common) -> Result<PathBuf> {
    let (run, config) = open_run(run_path, common, Work::Render)?;
    let device = device(&config, common)?;
    // Pose files need their blend-weight codes fitted first, which takes gradients.
    let device = match job {
        RenderJob::PoseFiles { .. } => device.autodiff(),
        _ => device,
    };
    let model = load_trained(&run, &config, &device)?;
    let mut exp = Experiment::open(config, device, !common.quiet)?;
    let (name, frames) = match job {
        RenderJob::PoseFiles { path, view } => render_pose_files(model, &exp, &path, view, common)?,
        RenderJob::Orbit { frame, views, size } => {
            let (name, shots) = orbit_shots(&exp, &model, frame, views, size)?;
            (
                name,
                render_dataset_shots(&model, &mut exp, &shots, common)?,
            )
        }
        RenderJob::NovelPoses { view } => {
            let (name, shots) = novel_pose_shots(&exp, &model, &run, view)?;
            (
                name,
                render_dataset_shots(&model, &mut exp, &shots, common)?,
            )
        }
    };
    let dir = run.renders().join(&name);
    for (i, frame) in frames.iter().enumerate() {
        anerf_eval::images::write_png(
            &dir.join(format!("{i:04}.png")),
            frame,
            anerf_eval::images::PngDepth::Eight,
        )?;
    }
    let gif = run.renders().join(format!("{name}.gif"));
    anerf_eval::images::write_gif(&gif, &frames, 12)?;
    if let anerf_eval::images::VideoOutcome::Written(mp4) =
        anerf_eval::images::write_mp4(&run.renders().join(format!("{name}.mp4")), &frames, 12)?
    {
        println!("wrote {}", mp4.display());
    }
    println!(
        "wrote {} frames to {} and {}",
        frames.len(),
        dir.display(),
        gif.display()
    );
    Ok(gif)
}

/// Fits a stage-2 field for the poses of `path` and renders them from dataset camera `view` (default: the
/// first training view): the output name and the images.
fn render_pose_files(
    model: AnimatableNerf,
    exp: &Experiment,
    path: &Path,
    view: Option<usize>,
    common: &Common,
) -> Result<(String, Vec<anerf_eval::RgbImageF32>)> {
    let view = view.unwrap_or(exp.train_views[0].0);
    let camera = dataset_camera(exp, view)?;
    let sequence = crate::poses::PoseSequence::load(path, &exp.prepared)?;
    let targets = sequence.targets(exp.novel_appearance(), &exp.device);
    let model = crate::train::fit_pose_codes(
        model,
        &targets,
        exp.canonical(),
        &exp.config.animate,
        exp.config.seed,
        !common.quiet,
    )?;
    let bar = image_bar(targets.len(), common);
    let mut frames = Vec::with_capacity(targets.len());
    for (target, file) in targets.iter().zip(&sequence.files) {
        let shot = Shot {
            inputs: &target.inputs,
            bounds: target.bounds,
            camera: &camera,
            ground_truth: None,
        };
        let image = render_shot(&model, exp.canonical(), &shot, &exp.config.eval)
            .with_context(|| format!("rendering the pose of {}", file.display()))?;
        frames.push(image.prediction);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let stem = path
        .file_stem()
        .map_or("poses".into(), |s| s.to_string_lossy().into_owned());
    Ok((format!("poses_{stem}_view{view:02}"), frames))
}

/// A dataset frame seen by a camera.
type DatasetShot = (FrameId, anerf_core::geometry::Camera);

/// Renders dataset frames from cameras (no ground truth).
fn render_dataset_shots(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    shots: &[DatasetShot],
    common: &Common,
) -> Result<Vec<anerf_eval::RgbImageF32>> {
    let bar = image_bar(shots.len(), common);
    let mut frames = Vec::with_capacity(shots.len());
    for (frame, camera) in shots {
        frames.push(render_view(model, exp, *frame, camera, None)?.prediction);
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(frames)
}

/// The output name and cameras of an orbit around dataset frame `frame` (default: the first training one).
fn orbit_shots(
    exp: &Experiment,
    model: &AnimatableNerf,
    frame: Option<usize>,
    views: usize,
    size: Option<u32>,
) -> Result<(String, Vec<DatasetShot>)> {
    let frame = frame.map(FrameId).unwrap_or(exp.train_frames[0]);
    exp.check_renderable(frame, model)?;
    let bounds = exp.frame_bounds(frame)?;
    let mut reference = exp.prepared.cameras[exp.train_views[0].0].clone();
    if let Some(s) = size {
        reference = reference.resized(s as f32 / reference.width as f32);
    }
    let up = crate::render::mean_up(&exp.prepared.cameras);
    let center = (bounds.min + bounds.max) * 0.5;
    let cams = crate::render::orbit(&reference, center, up, views.max(1));
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
    view: usize,
) -> Result<(String, Vec<DatasetShot>)> {
    if model.novel_blend.is_none() {
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

/// The experiment of `anerf demo` (also `configs/demo.toml`).
pub const DEMO_CONFIG: &str = include_str!("../../../configs/demo.toml");

/// `anerf demo`: synthesises the demo subject (once), trains both stages, evaluates novel views and novel
/// poses, renders a turntable of a novel pose and prints a summary. Re-running continues where it stopped.
pub fn demo(
    out: &Path,
    preset: Option<ModelPreset>,
    common: &Common,
    stop: &AtomicBool,
) -> Result<()> {
    let started = std::time::Instant::now();
    let subject = out.join("subject");
    if let Some(choice) = common.device {
        // A GPU backend that cannot run fails here, not after the subject has been generated.
        open_device(choice, common)?;
    }
    if !subject.join("annots.npy").is_file() {
        synth(&subject, SynthPreset::Demo, None)?;
    }
    let mut table = config::defaults();
    config::merge(
        &mut table,
        toml::from_str(DEMO_CONFIG).expect("the demo config is valid TOML"),
    );
    let quote = |p: &Path| format!("\"{}\"", p.display().to_string().replace('\\', "/"));
    config::apply_override(&mut table, &format!("dataset.root={}", quote(&subject)))?;
    config::apply_override(
        &mut table,
        &format!("dataset.cache={}", quote(&out.join("cache"))),
    )?;
    if let Some(preset) = preset {
        config::apply_override(&mut table, &format!("model.preset=\"{}\"", preset.name()))?;
    }
    for o in &common.overrides {
        config::apply_override(&mut table, o)?;
    }
    let config = config::from_table(table)?;
    let run = out.join("run");
    let mut times = Vec::new();

    // The demo owns its run folder: it continues what is there, or starts it again.
    let continue_or_replace = |stage| -> Result<RunStart> {
        Ok(
            match Checkpoint::latest(&run.join("checkpoints"), stage)?.is_some() {
                true => RunStart::Resume,
                false => RunStart::Overwrite,
            },
        )
    };
    let t = std::time::Instant::now();
    let start = continue_or_replace(Stage::Train)?;
    if train(config, &run, common, start, None, stop)?.interrupted {
        return Ok(());
    }
    times.push(("stage 1 (train)", t.elapsed()));
    let start = continue_or_replace(Stage::Animate)?;
    let t = std::time::Instant::now();
    if animate(&run, common, start, None, stop)?.interrupted {
        return Ok(());
    }
    times.push(("stage 2 (animate)", t.elapsed()));
    let t = std::time::Instant::now();
    let nv = eval(&run, EvalSplit::NovelView, common)?;
    let np = eval(&run, EvalSplit::NovelPose, common)?;
    times.push(("evaluation", t.elapsed()));
    let t = std::time::Instant::now();
    let rundir = RunDir::open(&run)?;
    let cfg = rundir.read_config()?;
    let novel = cfg.dataset.split().novel_pose_frames;
    let frame = (novel.start + novel.end) / 2;
    let gif = render(
        &run,
        RenderJob::Orbit {
            frame: Some(frame),
            views: 24,
            size: None,
        },
        common,
    )?;
    times.push(("turntable render", t.elapsed()));

    let preset = preset.map_or("fast (configs/demo.toml)", |p| p.name());
    println!("\nanerf demo: {} (preset {preset})", run.display());
    println!(
        "{}",
        markdown_table(
            "split",
            &[("novel view".into(), nv), ("novel pose".into(), np)]
        )
    );
    for (what, d) in &times {
        println!("  {what:<20} {:>7.1} s", d.as_secs_f64());
    }
    println!(
        "  {:<20} {:>7.1} s",
        "total",
        started.elapsed().as_secs_f64()
    );
    println!("turntable of a novel pose: {}", gif.display());
    Ok(())
}

/// `anerf mesh`: the canonical mesh (PLY with colours and `w^can` per vertex, and OBJ) and its reposed
/// copies under `<run>/meshes/`.
pub fn mesh(run_path: &Path, job: &crate::mesh::MeshJob, common: &Common) -> Result<PathBuf> {
    use anerf_eval::mesh_io::{write_obj, write_ply, MeshView, VertexAttribute};
    let (run, config) = open_run(run_path, common, Work::Render)?;
    if !(job.voxel.is_finite() && job.voxel > 0.0) {
        bail!("--voxel {}: expected a positive size in metres", job.voxel);
    }
    let device = device(&config, common)?;
    let model = load_trained(&run, &config, &device)?;
    let mut exp = Experiment::open(config, device.clone(), !common.quiet)?;
    let appearance = exp.train_frames.len() / 2;
    let volume = exp.prepared.canonical_volume()?;
    let chunk = exp.config.eval.chunk;
    let mut cm = crate::mesh::canonical_mesh(
        &model,
        exp.canonical(),
        &volume,
        job,
        appearance,
        chunk,
        &device,
    )?;
    if job.smooth > 0 {
        let smoothing = anerf_eval::mesh_smooth::Smoothing::taubin(job.smooth);
        cm.mesh.vertices =
            anerf_eval::mesh_smooth::smooth_vertices(&cm.mesh.vertices, &cm.mesh.faces, smoothing)?;
    }
    let k = cm.num_joints;
    let columns: Vec<Vec<f32>> = (0..k)
        .map(|j| cm.weights.iter().skip(j).step_by(k).copied().collect())
        .collect();
    let names: Vec<String> = (0..k).map(|j| format!("w{j:02}")).collect();
    let attributes: Vec<VertexAttribute> = names
        .iter()
        .zip(&columns)
        .map(|(name, values)| VertexAttribute { name, values })
        .collect();
    let dir = run.meshes();
    let canonical = MeshView::new(&cm.mesh.vertices, &cm.mesh.faces)
        .with_colors(&cm.colors)
        .with_attributes(&attributes);
    write_ply(&dir.join("canonical.ply"), &canonical)?;
    write_obj(&dir.join("canonical.obj"), &canonical)?;
    println!(
        "canonical mesh: {} vertices, {} faces → {}",
        cm.mesh.vertices.len(),
        cm.mesh.faces.len(),
        dir.join("canonical.ply").display()
    );
    for &f in &job.frames {
        let frame = exp
            .prepared
            .frame(FrameId(f))
            .with_context(|| format!("frame {f} was not prepared (--frames)"))?;
        let posed = crate::mesh::repose(
            &cm.mesh.vertices,
            &cm.weights,
            &frame.bones,
            &frame.pose.global,
        )?;
        let view = MeshView::new(&posed, &cm.mesh.faces).with_colors(&cm.colors);
        write_ply(&dir.join(format!("frame_{f:06}.ply")), &view)?;
        write_obj(&dir.join(format!("frame_{f:06}.obj")), &view)?;
        println!(
            "reposed to frame {f} → {}",
            dir.join(format!("frame_{f:06}.ply")).display()
        );
    }
    for &f in &job.posed_frames {
        let mesh = reference_posed_mesh(&model, &mut exp, FrameId(f), job)
            .with_context(|| format!("the posed mesh of frame {f} (--posed-frames)"))?;
        let path = dir.join(format!("posed_frame_{f:06}.ply"));
        let view = MeshView::new(&mesh.vertices, &mesh.faces);
        write_ply(&path, &view)?;
        write_obj(&path.with_extension("obj"), &view)?;
        println!(
            "posed mesh of frame {f}: {} vertices → {}",
            mesh.vertices.len(),
            path.display()
        );
    }
    Ok(dir.join("canonical.ply"))
}

/// The reference's posed mesh of dataset frame `frame`, carved by the training views when `job.carve`.
fn reference_posed_mesh(
    model: &AnimatableNerf,
    exp: &mut Experiment,
    frame: FrameId,
    job: &crate::mesh::MeshJob,
) -> Result<anerf_core::mesh::TriMesh> {
    exp.check_renderable(frame, model)?;
    let inputs = exp.frame_inputs(frame)?;
    let hull = if job.carve {
        let radius = VisualHull::reference_radius(exp.config.dataset.ratio);
        Some(VisualHull::of_frame(
            &exp.prepared,
            frame,
            &exp.train_views,
            radius,
        )?)
    } else {
        None
    };
    let body = crate::mesh::PosedFrame {
        inputs: &inputs,
        volume: &exp.prepared.volume(frame)?,
        bounds: exp.frame_bounds(frame)?,
    };
    crate::mesh::posed_mesh(
        model,
        exp.canonical(),
        &body,
        hull.as_ref(),
        job,
        exp.config.eval.chunk,
    )
}

//! Training a run's stages: stage 1 into a new (or resumed) run folder, stage 2 over a trained one.

use std::path::Path;
use std::sync::atomic::AtomicBool;

use anyhow::{bail, Result};

use crate::memory::{self, Work};
use crate::{data_parallel_devices, device, open_run, JobOptions};
use anerf_train::config::ExperimentConfig;
use anerf_train::experiment::Experiment;
use anerf_train::run_dir::RunDir;
use anerf_train::run_start::{self, RunStart};
use anerf_train::stage::Stage;
use anerf_train::training::checkpoint::Checkpoint;
use anerf_train::training::{train_stage1, train_stage2, StageOutcome, TrainOptions};

/// Stage 1 of `config` into `run`. The start is checked (`start`), the config validated and the data
/// opened before the folder is touched; a start that fails before its first checkpoint removes what it
/// made. `max_steps` stops early with a checkpoint; so does `stop` (set by Ctrl-C).
pub fn train(
    mut config: ExperimentConfig,
    run: &Path,
    options: &JobOptions,
    start: RunStart,
    max_steps: Option<usize>,
    stop: &AtomicBool,
) -> Result<StageOutcome> {
    // The devices first: a refused list reads and writes nothing.
    let parallel = options
        .devices
        .as_deref()
        .map(|specs| data_parallel_devices(specs, options))
        .transpose()?;
    config.dataset.make_paths_absolute()?;
    let dataset = &config.dataset;
    let inputs: Vec<&Path> = std::iter::once(dataset.root.as_path())
        .chain(dataset.body_model.as_deref())
        .collect();
    run_start::check_stage1(run, start, &inputs)?;
    if start == RunStart::Resume {
        let existing = RunDir::open(run)?;
        if existing.read_config()?.model != config.model {
            bail!(
                "--resume: the config's [model] differs from the run's {}",
                existing.config_path().display()
            );
        }
    }
    memory::check(&config, Work::Train)?;
    let mut exp = match parallel {
        None => {
            let device = device(&config, options)?.autodiff();
            Experiment::open(config, device, options.progress)?
        }
        Some(devices) => Experiment::open(config, devices[0].clone(), options.progress)?
            .with_data_parallel(devices)?,
    };
    let run = run_start::begin_stage1(run, start)?;
    let result = run.write_config(&exp.config).and_then(|()| {
        train_stage1(
            &mut exp,
            &run,
            stage_options(start, options, max_steps),
            stop,
        )
    });
    result.inspect(|_| plot(&run)).inspect_err(|_| {
        let kept = Checkpoint::latest(&run.checkpoints(), Stage::Train)
            .ok()
            .flatten()
            .is_some();
        if start != RunStart::Resume && !kept {
            // Nothing worth keeping was made: leave no half-made run behind.
            let _ = std::fs::remove_dir_all(&run.root);
        }
    })
}

/// Stage 2 of the run at `run` (`start` as for [`train`], over stage 2's checkpoints).
pub fn animate(
    run: &Path,
    options: &JobOptions,
    start: RunStart,
    max_steps: Option<usize>,
    stop: &AtomicBool,
) -> Result<StageOutcome> {
    let (run, config) = open_run(run, options, Work::Animate)?;
    run_start::check_stage2(&run, start)?;
    let device = device(&config, options)?.autodiff();
    let mut exp = Experiment::open(config, device, options.progress)?;
    run_start::begin_stage2(&run, start)?;
    train_stage2(
        &mut exp,
        &run,
        stage_options(start, options, max_steps),
        stop,
    )
    .inspect(|_| plot(&run))
}

/// Redraws the run's training curves after a stage; a figure that cannot be drawn is a warning, not a
/// failed stage.
fn plot(run: &RunDir) {
    if let Err(e) = anerf_train::plots::write_run_plots(run) {
        eprintln!("warning: the training curves were not drawn: {e:#}");
    }
}

fn stage_options(start: RunStart, options: &JobOptions, max_steps: Option<usize>) -> TrainOptions {
    TrainOptions {
        resume: start == RunStart::Resume,
        progress: options.progress,
        max_steps,
    }
}

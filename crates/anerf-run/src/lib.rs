//! The jobs on a run folder: train its two stages, evaluate, render, mesh and export it, fit and render
//! motions, each after checking that its work fits in memory. Each job takes typed arguments and
//! [`JobOptions`]; the `anerf` app parses command lines into them and prints what they return.

pub mod bake;
pub mod bench;
pub mod demo;
mod eval;
mod export;
pub mod memory;
pub mod mesh;
pub mod motion;
mod raster;
mod render;
mod stages;

use std::path::Path;

use anerf_core::model::AnimatableNerf;
use anerf_core::DeviceChoice;
use anerf_device::probe::{checked_device, CheckedDevice};
use anerf_device::DeviceSpec;
use anyhow::{bail, Context, Result};
use burn::prelude::Device;

pub use eval::{eval, Avatar, Evaluated, Surface};
pub use export::{capture_to_gltf, export, joint_frame, ExportJob, Exported, TRAINING_FPS};
pub use mesh::{mesh, MeshFile, MeshFiles};
pub use motion::{animate_motion, FittedMotion, MotionCamera};
pub use render::{render, RenderJob, Rendered};
pub use stages::{animate, train};

use crate::memory::Work;
use anerf_train::config::{self, ExperimentConfig};
use anerf_train::progress::StageProgress;
use anerf_train::run_dir::RunDir;
use anerf_train::stage::Stage;
use anerf_train::training::checkpoint::{Checkpoint, Restored};

/// What every job takes besides its own arguments.
#[derive(Debug, Clone, Default)]
pub struct JobOptions {
    /// Compute backend; `None` runs on the config's `device`.
    pub device: Option<DeviceChoice>,
    /// Train data-parallel on these devices (`anerf train --devices`) instead of on `device`.
    pub devices: Option<Vec<DeviceSpec>>,
    /// `section.key=value` overrides over the config (`--set`).
    pub set: Vec<String>,
    /// Draw progress bars, and name the GPU adapter a run uses.
    pub progress: bool,
}

impl JobOptions {
    /// The progress display of `n` items (images), hidden without [`JobOptions::progress`].
    pub(crate) fn bar(&self, label: &str, n: usize) -> StageProgress {
        StageProgress::new(label, 0, n, self.progress)
    }
}

/// The device named by the options, else by the config.
pub fn device(config: &ExperimentConfig, options: &JobOptions) -> Result<Device> {
    open_device(options.device.unwrap_or(config.device), options)
}

/// The devices of a data-parallel fit (with autodiff), checked ([`DeviceSpec::check_data_parallel`]) and
/// their backend probed as [`open_device`] does.
pub fn data_parallel_devices(specs: &[DeviceSpec], options: &JobOptions) -> Result<Vec<Device>> {
    DeviceSpec::check_data_parallel(specs).map_err(anyhow::Error::msg)?;
    open_device(specs[0].choice, options)?;
    specs
        .iter()
        .map(|s| Ok(s.device().map_err(anyhow::Error::msg)?.autodiff()))
        .collect()
}

/// The device of `choice`. A GPU backend is first checked in a child process that re-runs the current
/// executable (the `anerf` binary, whose `main` answers such a check), so that a driver crash becomes an
/// error instead of killing the run; the check runs once per process, and the adapter it ran on is printed
/// then with [`JobOptions::progress`].
pub fn open_device(choice: DeviceChoice, options: &JobOptions) -> Result<Device> {
    static ANNOUNCED: std::sync::Once = std::sync::Once::new();
    let checked = open_checked_device(choice)?;
    if let (Some(adapter), true) = (&checked.adapter, options.progress) {
        ANNOUNCED.call_once(|| eprintln!("device {choice}: {adapter}"));
    }
    Ok(checked.device)
}

/// The device of `choice` with the adapter its probe child ran on, checked as [`open_device`] does.
pub fn open_checked_device(choice: DeviceChoice) -> Result<CheckedDevice> {
    let exe = std::env::current_exe().context("locating the anerf executable")?;
    checked_device(choice, || std::process::Command::new(exe))
        .with_context(|| format!("cannot use device '{choice}' (`--device flex` runs on the CPU)"))
}

/// Opens a run folder and its config with the options' overrides, and checks that a step of `work` fits
/// in memory.
fn open_run(path: &Path, options: &JobOptions, work: Work) -> Result<(RunDir, ExperimentConfig)> {
    let run = RunDir::open(path)?;
    let config = config::with_overrides(run.read_config()?, &options.set)?;
    memory::check(&config, work)?;
    Ok((run, config))
}

/// The run's newest intact model: stage 2 if it has one, else stage 1.
pub fn load_trained(
    run: &RunDir,
    config: &ExperimentConfig,
    device: &Device,
) -> Result<AnimatableNerf> {
    Ok(newest_checkpoint(run, config, device)?.model)
}

/// The run's newest intact checkpoint, as [`load_trained`] chooses it.
fn newest_checkpoint(run: &RunDir, config: &ExperimentConfig, device: &Device) -> Result<Restored> {
    for stage in [Stage::Animate, Stage::Train] {
        if let Some(r) =
            Checkpoint::restore_newest(&run.checkpoints(), stage, &config.model, device, None)?
        {
            return Ok(r);
        }
    }
    bail!(
        "{} has no checkpoint; run `anerf train` first",
        run.root.display()
    )
}

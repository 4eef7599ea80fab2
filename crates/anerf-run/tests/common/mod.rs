//! The tiny synthetic subject and a config that trains on it, shared by the integration tests (each test
//! crate uses a part of it).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use anerf_data::synthetic::{write_subject, SyntheticSpec};
use anerf_run::JobOptions;
use anerf_train::config::{self, ExperimentConfig};
use anerf_train::run_start::RunStart;
use anerf_train::training::StageOutcome;

/// The canonical surface at `voxel` metres and iso `level`, with no frames to repose.
pub fn surface(voxel: f32, level: f32) -> anerf_run::mesh::MeshJob {
    anerf_run::mesh::MeshJob {
        voxel,
        level,
        smooth: 0,
        frames: Vec::new(),
        posed_frames: Vec::new(),
        carve: true,
    }
}

/// Job options without progress bars, on the config's device.
pub fn quiet() -> JobOptions {
    JobOptions::default()
}

/// Trains stage 1 of `config` into `run` (no resume, no step limit).
pub fn train(config: &ExperimentConfig, run: &Path) -> anyhow::Result<StageOutcome> {
    anerf_run::train(
        config.clone(),
        run,
        &quiet(),
        RunStart::Fresh,
        None,
        &AtomicBool::new(false),
    )
}

/// Trains stage 1 of `config` to the end into `dir/run` and returns the run folder.
pub fn trained(config: &ExperimentConfig, dir: &Path) -> PathBuf {
    let run = dir.join("run");
    train(config, &run).unwrap();
    run
}

/// Writes the tiny subject into `dir/subject` and returns a config training on it.
pub fn tiny(dir: &Path, overrides: &[&str]) -> ExperimentConfig {
    tiny_config(dir, overrides).unwrap()
}

/// [`tiny`], or the config error its overrides cause.
pub fn tiny_config(
    dir: &Path,
    overrides: &[&str],
) -> Result<ExperimentConfig, config::ConfigError> {
    let subject = dir.join("subject");
    if !subject.exists() {
        write_subject(&SyntheticSpec::tiny(), &subject).unwrap();
    }
    let text = format!(
        r#"
name = "tiny"
[dataset]
format = "zju_mocap"
root = "{}"
cache = "{}"
ratio = 1.0
train_views = [0, 2]
iccv = {{ train_frames = "0:6", novel_pose_frames = "6:10" }}
[model]
preset = "tiny"
[train]
iterations = 60
batch = 256
lr = 2e-3
lr_final = 1e-3
checkpoint_every = 20
validate_every = 0
log_every = 1
[animate]
iterations = 4
batch = 1024
log_every = 1
[eval]
frame_interval = 1
chunk = 4096
"#,
        subject.display(),
        dir.join("cache").display()
    );
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    for o in overrides {
        config::apply_override(&mut table, o)?;
    }
    config::from_table(table)
}

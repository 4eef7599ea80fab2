//! One module per `anerf` subcommand: its arguments and what it does with the library, including what it
//! prints.

pub mod animate;
pub mod bake;
pub mod bench;
pub mod compare;
pub mod demo;
pub mod eval;
pub mod export;
pub mod import;
pub mod info;
pub mod mesh;
pub mod plot;
pub mod prepare;
pub mod render;
pub mod synth;
pub mod train;
pub mod view;

use std::path::Path;

use anerf_train::config::{self, ConfigError, ExperimentConfig, Settings};
use anerf_train::run_dir::RunDir;
use anerf_train::stage::Stage;
use anerf_train::training::StageOutcome;
use anyhow::Result;

/// Loads a config file with typed `settings` and `--set` overrides, naming the file in errors that do not.
fn load_config(path: &Path, settings: &Settings, set: &[String]) -> Result<ExperimentConfig> {
    config::load_with(path, settings, set).map_err(|e| match e {
        // These name the file already.
        ConfigError::Read { .. } | ConfigError::Parse { .. } | ConfigError::BaseCycle { .. } => {
            e.into()
        }
        _ => anyhow::Error::new(e).context(format!("in config {}", path.display())),
    })
}

/// Says on stderr how a stage ended and where its checkpoints are.
fn report_outcome(stage: Stage, o: &StageOutcome, run: &Path) {
    let checkpoints = RunDir {
        root: run.to_path_buf(),
    }
    .checkpoints();
    if o.loss.is_nan() && !o.interrupted {
        // No step ran: the stage had already finished (a resumed or re-run demo).
        eprintln!(
            "{stage} was already complete at step {}; checkpoints in {}",
            o.steps,
            checkpoints.display()
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
        checkpoints.display()
    );
}

//! `anerf plot`: the training curves of a run, drawn again from its `metrics.jsonl`.

use std::path::PathBuf;

use anerf_train::plots::write_run_plots;
use anerf_train::run_dir::RunDir;
use anyhow::{bail, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
}

pub fn run(args: &PlotArgs) -> Result<Vec<PathBuf>> {
    let run = RunDir::open(&args.run)?;
    let written = write_run_plots(&run)?;
    if written.is_empty() {
        bail!("{} has no logged step yet", run.metrics_log().display());
    }
    for path in &written {
        println!("wrote {}", path.display());
    }
    Ok(written)
}

//! `anerf prepare`: a config's data undistorted, resized and given blend-weight volumes in the cache.

use std::path::PathBuf;

use anerf_train::config::Settings;
use anerf_train::experiment::Experiment;
use anyhow::Result;
use clap::Args;

use crate::args::Common;

#[derive(Debug, Args)]
pub struct PrepareArgs {
    /// Experiment config (e.g. configs/zju_mocap/313.toml).
    pub config: PathBuf,
    #[command(flatten)]
    pub common: Common,
}

pub fn run(args: &PrepareArgs) -> Result<()> {
    let config = super::load_config(&args.config, &Settings::default(), &args.common.overrides)?;
    let options = args.common.options();
    let device = anerf_run::device(&config, &options)?;
    let exp = Experiment::open(config, device, options.progress)?;
    println!(
        "prepared {} frames of {} in {}",
        exp.prepared.frames.len(),
        exp.prepared.name,
        exp.prepared.dir.display()
    );
    Ok(())
}

//! `anerf animate`: stage 2 of a trained run.

use std::path::PathBuf;

use anerf_train::jobs;
use anerf_train::training::StageOutcome;
use anyhow::Result;
use clap::Args;

use crate::cli::{interrupt_flag, Common, StartArgs};

#[derive(Debug, Args)]
pub struct AnimateArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
    #[command(flatten)]
    pub start: StartArgs,
    #[command(flatten)]
    pub common: Common,
}

/// Fits stage 2; the outcome says whether Ctrl-C stopped it.
pub fn run(args: &AnimateArgs) -> Result<StageOutcome> {
    let outcome = jobs::animate(
        &args.run,
        &args.common.options(),
        args.start.run_start(),
        args.start.steps,
        &interrupt_flag(),
    )?;
    super::report_outcome("stage 2", &outcome, &args.run);
    Ok(outcome)
}

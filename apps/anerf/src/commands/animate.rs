//! `anerf animate`: stage 2 of a trained run, or the stage-2 field of a motion (`--motion`).

use std::path::PathBuf;

use anerf_train::stage::Stage;
use anyhow::Result;
use clap::Args;

use crate::args::{interrupt_flag, Common, MotionArgs, StartArgs};

#[derive(Debug, Args)]
pub struct AnimateArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
    #[command(flatten)]
    pub start: StartArgs,
    #[command(flatten)]
    pub motion: MotionArgs,
    #[command(flatten)]
    pub common: Common,
}

/// Fits stage 2, or a motion's field; true when Ctrl-C stopped stage 2.
pub fn run(args: &AnimateArgs) -> Result<bool> {
    let options = args.common.options();
    if let Some(request) = args.motion.request() {
        let fitted = anerf_run::animate_motion(&args.run, &request, None, &options)?;
        if fitted.reused {
            eprintln!(
                "{} already holds the fit of these {} frames; nothing to do",
                fitted.dir.display(),
                fitted.frames
            );
        } else {
            eprintln!(
                "fitted {} frames in {:.1} s ({:.2} s/frame); stored in {}",
                fitted.frames,
                fitted.seconds,
                fitted.seconds / fitted.frames.max(1) as f64,
                fitted.dir.display()
            );
        }
        return Ok(false);
    }
    let outcome = anerf_run::animate(
        &args.run,
        &options,
        args.start.run_start(),
        args.start.steps,
        &interrupt_flag(),
    )?;
    super::report_outcome(Stage::Animate, &outcome, &args.run);
    Ok(outcome.interrupted)
}

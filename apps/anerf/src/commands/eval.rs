//! `anerf eval`: PSNR and SSIM of a run on one split, with the paper's protocol.

use std::path::PathBuf;

use anerf_eval::report::{markdown_table, EvalSplit};
use anerf_run::Evaluated;
use anyhow::Result;
use clap::Args;

use crate::args::{AvatarArgs, Common};

#[derive(Debug, Args)]
pub struct EvalArgs {
    pub run: PathBuf,
    /// novel-view (training frames, test views), novel-pose (novel-pose frames, test views) or
    /// training-view (training frames, training views: the fit, for the gap to the held-out splits).
    #[arg(long, default_value = "novel-view")]
    pub split: EvalSplit,
    #[command(flatten)]
    pub avatar: AvatarArgs,
    #[command(flatten)]
    pub common: Common,
}

pub fn run(args: &EvalArgs) -> Result<Evaluated> {
    let evaluated = anerf_run::eval(
        &args.run,
        args.split,
        args.avatar.avatar(),
        &args.common.options(),
    )?;
    print(&evaluated, args.split);
    Ok(evaluated)
}

/// The split's figures as a table, and where the per-image ones are.
pub fn print(e: &Evaluated, split: EvalSplit) {
    println!(
        "{}",
        markdown_table("split", &[(format!("{} {split}", e.name), e.summary)])
    );
    println!("per-image metrics and images in {}", e.dir.display());
}

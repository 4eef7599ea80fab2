//! `anerf compare`: PSNR and SSIM of two image files.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

#[derive(Debug, Args)]
pub struct CompareArgs {
    pub prediction: PathBuf,
    pub ground_truth: PathBuf,
    #[arg(long)]
    pub mask: Option<PathBuf>,
}

pub fn run(args: &CompareArgs) -> Result<()> {
    let c = anerf_eval::compare_files(&args.prediction, &args.ground_truth, args.mask.as_deref())?;
    println!("{c}");
    Ok(())
}

//! `anerf bake`: a trained run as skinned 3D Gaussians for real-time rendering.

use std::path::PathBuf;

use anerf_run::bake::{BakeJob, Baked};
use anyhow::Result;
use clap::Args;

use crate::args::{Common, SurfaceArgs};

#[derive(Debug, Args)]
pub struct BakeArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
    /// Most Gaussians the avatar may hold.
    #[arg(long, default_value_t = 50_000)]
    pub budget: usize,
    /// Spherical-harmonic degree of the colours: 0 (one colour each) or 1 (view-dependent).
    #[arg(long, default_value_t = 1)]
    pub sh_degree: usize,
    /// Fine-tuning steps (one training image each).
    #[arg(long, default_value_t = 3_000)]
    pub iterations: usize,
    /// Replace an existing <run>/baked/.
    #[arg(long)]
    pub overwrite: bool,
    /// The canonical surface the Gaussians start on.
    #[command(flatten)]
    pub surface: SurfaceArgs,
    #[command(flatten)]
    pub common: Common,
}

pub fn run(args: &BakeArgs) -> Result<Baked> {
    let job = BakeJob {
        surface: args.surface.job(),
        budget: args.budget,
        sh_degree: args.sh_degree,
        iterations: args.iterations,
        overwrite: args.overwrite,
    };
    let baked = anerf_run::bake::bake(&args.run, &job, &args.common.options())?;
    println!(
        "wrote {}: {} Gaussians (degree {} colours), {} steps in {:.0} s, training crops at {:.2} dB",
        baked.dir.display(),
        baked.info.gaussians,
        baked.info.sh_degree,
        baked.info.steps,
        baked.info.seconds,
        baked.info.training_psnr
    );
    Ok(baked)
}

//! `anerf export`: a run as a skinned glTF binary with the training motion or any motion.

use std::path::PathBuf;

use anerf_run::{ExportJob, Exported};
use anyhow::{bail, Result};
use clap::{Args, ValueEnum};

use crate::args::{Common, MotionArgs, SurfaceArgs};

/// Export file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ExportFormat {
    /// Binary glTF 2.0: skinned mesh, skeleton, animation.
    Glb,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
    #[arg(long, value_enum, default_value_t = ExportFormat::Glb)]
    pub format: ExportFormat,
    /// The file to write (default: <run>/export/avatar.glb).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace the file if it exists.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub surface: SurfaceArgs,
    /// The animation: this motion instead of the training frames (at 30 fps).
    #[command(flatten)]
    pub motion: MotionArgs,
    #[command(flatten)]
    pub common: Common,
}

pub fn run(args: &ExportArgs) -> Result<Exported> {
    if let Some(out) = &args.out {
        if out.extension().is_none_or(|e| e != "glb") {
            bail!("--out {}: expected a .glb file name", out.display());
        }
    }
    let job = ExportJob {
        surface: args.surface.job(),
        motion: args.motion.request(),
        view: None,
        out: args.out.clone(),
        overwrite: args.overwrite,
    };
    let exported = anerf_run::export(&args.run, &job, &args.common.options())?;
    println!(
        "wrote {}: {} vertices, {} joints, {} frames at {} fps",
        exported.path.display(),
        exported.vertices,
        exported.joints,
        exported.frames,
        exported.fps
    );
    Ok(exported)
}

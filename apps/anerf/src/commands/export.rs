//! `anerf export`: a run as a skinned glTF binary with the training motion or any motion, or its baked
//! Gaussians as PLY files.

use std::path::PathBuf;

use anerf_run::bake::{export_splats, SplatExportJob};
use anerf_run::{ExportJob, Exported};
use anyhow::{bail, Result};
use clap::{Args, ValueEnum};

use crate::args::{Common, MotionArgs, SurfaceArgs};

/// Export file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ExportFormat {
    /// Binary glTF 2.0: skinned mesh, skeleton, animation.
    Glb,
    /// The baked Gaussians (`anerf bake`) in 3D Gaussian Splatting's PLY layout: the canonical avatar
    /// with its skin (skin.json) and one posed file per animation frame.
    Ply,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
    #[arg(long, value_enum, default_value_t = ExportFormat::Glb)]
    pub format: ExportFormat,
    /// The file to write (glb; default: <run>/export/avatar.glb) or the folder (ply; default:
    /// <run>/export/splats/).
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

pub fn run(args: &ExportArgs) -> Result<()> {
    match args.format {
        ExportFormat::Glb => glb(args).map(|_| ()),
        ExportFormat::Ply => ply(args),
    }
}

fn ply(args: &ExportArgs) -> Result<()> {
    let job = SplatExportJob {
        motion: args.motion.request(),
        view: None,
        out: args.out.clone(),
        overwrite: args.overwrite,
    };
    let exported = export_splats(&args.run, &job, &args.common.options())?;
    println!(
        "wrote {}: avatar.ply ({} Gaussians), skin.json, {} posed frames at {} fps in frames/",
        exported.dir.display(),
        exported.gaussians,
        exported.frames,
        exported.fps
    );
    Ok(())
}

fn glb(args: &ExportArgs) -> Result<Exported> {
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

//! `anerf mesh`: the canonical mesh of a run, reposed copies and the reference's posed meshes.

use std::path::PathBuf;

use anerf_run::mesh::MeshJob;
use anerf_run::MeshFiles;
use anyhow::Result;
use clap::Args;

use crate::args::{Common, SurfaceArgs};

#[derive(Debug, Args)]
pub struct MeshArgs {
    pub run: PathBuf,
    #[command(flatten)]
    pub surface: SurfaceArgs,
    /// Also repose the canonical mesh to these dataset frames, e.g. --frames 0,30,60.
    #[arg(long, value_delimiter = ',')]
    pub frames: Vec<usize>,
    /// Also extract the reference's posed meshes of these dataset frames: a world-space grid over the
    /// frame's box, warped back with the frame's blend weights, carved by the training views' masks.
    #[arg(long, value_delimiter = ',')]
    pub posed_frames: Vec<usize>,
    /// Do not carve the posed meshes' grids with the training views' visual hull.
    #[arg(long)]
    pub no_carve: bool,
    #[command(flatten)]
    pub common: Common,
}

pub fn run(args: &MeshArgs) -> Result<MeshFiles> {
    let job = MeshJob {
        frames: args.frames.clone(),
        posed_frames: args.posed_frames.clone(),
        carve: !args.no_carve,
        ..args.surface.job()
    };
    let files = anerf_run::mesh(&args.run, &job, &args.common.options())?;
    let c = &files.canonical;
    println!(
        "canonical mesh: {} vertices, {} faces → {}",
        c.vertices,
        c.faces,
        c.ply.display()
    );
    for (frame, file) in &files.reposed {
        println!("reposed to frame {} → {}", frame.0, file.ply.display());
    }
    for (frame, file) in &files.posed {
        println!(
            "posed mesh of frame {}: {} vertices → {}",
            frame.0,
            file.vertices,
            file.ply.display()
        );
    }
    Ok(files)
}

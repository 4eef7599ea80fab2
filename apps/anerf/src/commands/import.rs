//! `anerf import`: a capture rewritten in the authors' ZJU-MoCap layout, so that their Python code (and
//! any tool that reads ZJU-MoCap) can use it too.

use std::path::PathBuf;

use anerf_data::{loaders, zju_layout, DatasetKind};
use anyhow::{Context, Result};
use clap::{Args, ValueEnum};

use crate::args::CaptureArgs;

/// The layouts `import` reads.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum ImportFormat {
    /// An EasyMocap folder (`intri.yml`, `extri.yml`, `images/`, `mask/`, SMPL fits) with `--body-model`.
    Easymocap,
}

#[derive(Debug, Args)]
pub struct ImportArgs {
    pub format: ImportFormat,
    /// The capture folder.
    pub folder: PathBuf,
    /// The ZJU-MoCap folder to write (must not exist unless `--overwrite`; never inside or around the
    /// capture or the body model).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing `--out` folder that an earlier `anerf import` wrote (only once the new one is
    /// complete; a folder without its `.anerf-import` marker is never deleted).
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub capture: CaptureArgs,
}

pub fn run(args: &ImportArgs) -> Result<()> {
    let kind = match args.format {
        ImportFormat::Easymocap => DatasetKind::EasyMocap,
    };
    let subject = loaders::load(&args.folder, kind, &args.capture.load_options())
        .with_context(|| format!("reading the capture {}", args.folder.display()))?;
    for note in &subject.notes {
        eprintln!("note: {note}");
    }
    let inputs: Vec<&std::path::Path> = args.capture.body_model.as_deref().into_iter().collect();
    zju_layout::write_subject(&subject, &args.out, &inputs, args.overwrite)
        .with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "wrote {} ({} cameras, {} frames, {} vertices) in the ZJU-MoCap layout",
        args.out.display(),
        subject.cameras.len(),
        subject.frames.len(),
        subject.body.canonical_vertices.len()
    );
    Ok(())
}

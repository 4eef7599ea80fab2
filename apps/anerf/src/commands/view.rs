//! `anerf view`: serves a run's page on 127.0.0.1 until Ctrl-C.

use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use anerf_view::Viewer;
use anyhow::Result;
use clap::Args;

#[derive(Debug, Args)]
pub struct ViewArgs {
    /// A run folder written by `anerf train` (it may still be training).
    pub run: PathBuf,
    /// Port on 127.0.0.1 (0: any free port; the address is printed).
    #[arg(long, default_value_t = 7007)]
    pub port: u16,
}

pub fn run(args: &ViewArgs) -> Result<()> {
    let viewer = Viewer::bind(&args.run, args.port)?;
    println!(
        "viewing {} at {} (Ctrl-C to stop)",
        args.run.display(),
        viewer.url()
    );
    std::io::stdout().flush()?;
    viewer.serve(&AtomicBool::new(false));
    Ok(())
}

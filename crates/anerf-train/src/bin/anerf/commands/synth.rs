//! `anerf synth`: a synthetic subject in the ZJU-MoCap layout.

use std::path::{Path, PathBuf};

use anerf_data::synthetic::{write_subject, SynthPreset};
use anyhow::{Context, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Output folder (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// tiny (4 views, 10 frames, 64 px), demo (8 views, 90 frames, 256 px), realistic (8 views at three
    /// heights, 150 frames, 512 px, studio lights with shadows and highlights, clothing over the given
    /// body) or realistic-exact (the same without clothing: the given body is the rendered one).
    #[arg(long, default_value = "demo")]
    pub preset: SynthPreset,
    #[arg(long)]
    pub seed: Option<u64>,
}

pub fn run(args: &SynthArgs) -> Result<()> {
    write(&args.out, args.preset, args.seed)
}

/// Writes subject `preset` (with `seed`, else the preset's) to `out` and says so.
pub fn write(out: &Path, preset: SynthPreset, seed: Option<u64>) -> Result<()> {
    let mut spec = preset.spec();
    if let Some(s) = seed {
        spec.seed = s;
    }
    let summary = write_subject(&spec, out)
        .with_context(|| format!("writing the synthetic subject to {}", out.display()))?;
    println!(
        "wrote {} ({} cameras, {} frames) in {:.1} s",
        out.display(),
        summary.subject.cameras.len(),
        summary.subject.frames.len(),
        summary.timings.total.as_secs_f64()
    );
    Ok(())
}

//! `anerf synth`: a synthetic subject in the ZJU-MoCap layout.

use std::path::{Path, PathBuf};

use anerf_data::synthetic::{
    write_subject, Backdrop, PoseNoise, SynthPreset, SyntheticSpec, SyntheticSummary,
};
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
    /// Fit errors in the training frames' new_params/ and new_vertices/: `<degrees>[,<cm>]`, the standard
    /// deviation of each joint's per-axis error angle (Rh gets a third of it) and of Th's per-axis offset
    /// (default degrees / 1.5), each 0 to 20. The images keep the true poses, saved in true_params/.
    #[arg(long, value_name = "DEGREES[,CM]")]
    pub pose_noise: Option<PoseNoise>,
    /// Segmentation-like mask edge errors of up to this many pixels (a real number, 0 to 10): the edge
    /// moves in and out smoothly along the contour; the images stay exact.
    #[arg(long, value_name = "PX", default_value_t = 0.0)]
    pub mask_noise: f32,
    /// What the images show behind the body: black (the NeRF's convention), room (a floor, panelled
    /// walls and a ceiling fixed in the world, as a capture's backdrop; training masks it as it masks a
    /// capture's) or busy-room (the room with screens on a third of its panels whose colour changes every
    /// frame, a backdrop no one image describes). The masks are the body's either way.
    #[arg(long, default_value = "black")]
    pub backdrop: Backdrop,
}

pub fn run(args: &SynthArgs) -> Result<()> {
    let mut spec = args.preset.spec();
    if let Some(s) = args.seed {
        spec.seed = s;
    }
    spec.pose_noise = args.pose_noise;
    spec.mask_noise = args.mask_noise;
    spec.backdrop = args.backdrop;
    let summary = write_subject(&spec, &args.out)
        .with_context(|| format!("writing the synthetic subject to {}", args.out.display()))?;
    print_written(&args.out, &spec, &summary);
    Ok(())
}

/// Says that the subject of `spec` was written to `out`, with what pose noise did to the vertices.
pub fn print_written(out: &Path, spec: &SyntheticSpec, summary: &SyntheticSummary) {
    println!(
        "wrote {} ({} cameras, {} frames) in {:.1} s",
        out.display(),
        summary.subject.cameras.len(),
        summary.subject.frames.len(),
        summary.timings.total.as_secs_f64()
    );
    if let (Some(noise), Some(report)) = (&spec.pose_noise, &summary.pose_noise) {
        println!(
            "pose noise: {noise}: mean vertex error {:.2} cm over {} training frames (true poses in true_params/)",
            report.mean_vertex_error * 100.0,
            report.true_poses.len()
        );
    }
    if spec.mask_noise > 0.0 {
        println!("mask noise: edges moved by up to {} px", spec.mask_noise);
    }
    if spec.backdrop != Backdrop::Black {
        println!("backdrop: {}", spec.backdrop);
    }
}

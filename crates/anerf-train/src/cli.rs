//! The `anerf` command line: argument parsing only; every command calls library functions.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anerf_core::model::ModelPreset;
use anerf_core::DeviceChoice;
use clap::{Args, Parser, Subcommand};

/// Animatable human avatars from multi-view video (Animatable NeRF, Peng et al., ICCV 2021).
#[derive(Debug, Parser)]
#[command(name = "anerf", version)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Generate a synthetic subject, train both stages, evaluate and render: the whole pipeline on a CPU.
    Demo(DemoArgs),
    /// Write a synthetic multi-view video of an animated human in the ZJU-MoCap layout.
    Synth(SynthArgs),
    /// Validate a dataset folder (or the folder a config names) and summarise it.
    Info(InfoArgs),
    /// Undistort, resize and compute blend-weight volumes into the cache (train does this on demand).
    Prepare(ConfigArgs),
    /// Stage 1: fit the canonical radiance field and blend-weight fields to the training video.
    Train(TrainArgs),
    /// Stage 2: fit blend-weight fields for the novel-pose frames of a trained run.
    Animate(RunArgs),
    /// Render the test views of a run and measure PSNR and SSIM with the paper's protocol.
    Eval(EvalArgs),
    /// Render a free-viewpoint orbit or a novel-pose sequence of a run.
    Render(RenderArgs),
    /// Extract the canonical mesh of a run (marching cubes on density) and repose it.
    Mesh(MeshArgs),
    /// PSNR and SSIM of two images (with a mask: the paper's protocol).
    Compare(CompareArgs),
    /// Training-step time, throughput, render time and peak memory of each model preset.
    Bench(crate::bench::BenchArgs),
}

/// Options every command that computes takes.
#[derive(Debug, Clone, Args)]
pub struct Common {
    /// Compute backend (flex, ndarray, wgpu); overrides the config's `device`.
    #[arg(long)]
    pub device: Option<DeviceChoice>,
    /// Override a config value, e.g. `--set train.iterations=1000` (repeatable).
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    pub overrides: Vec<String>,
    /// No progress bars.
    #[arg(long)]
    pub quiet: bool,
}

#[derive(Debug, Args)]
pub struct ConfigArgs {
    /// Experiment config (e.g. configs/zju_mocap/313.toml).
    pub config: PathBuf,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Experiment config; or use `--data` to train on a folder without one.
    pub config: Option<PathBuf>,
    /// A subject folder in the ZJU-MoCap layout (instead of a config).
    #[arg(long, conflicts_with = "config")]
    pub data: Option<PathBuf>,
    /// Training cameras, e.g. 0,2,4,6 (default: four evenly spaced cameras).
    #[arg(long, value_delimiter = ',')]
    pub train_views: Option<Vec<usize>>,
    /// Training frames start:end[:step] (default: the first two thirds of the frames).
    #[arg(long)]
    pub train_frames: Option<String>,
    /// Novel-pose frames start:end[:step] (default: the frames after the training frames).
    #[arg(long)]
    pub novel_pose_frames: Option<String>,
    #[arg(long, long_help = crate::config::preset_help(), help = crate::config::preset_short_help())]
    pub preset: Option<ModelPreset>,
    /// Training iterations (default: the preset's schedule).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Run folder (default runs/<name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue from the run's newest intact checkpoint.
    #[arg(long, conflicts_with = "overwrite")]
    pub resume: bool,
    /// Replace an existing run in the output folder (deleted whole once the new run's config and data
    /// have been checked).
    #[arg(long)]
    pub overwrite: bool,
    /// Stop (with a checkpoint) after this many steps; `--resume` continues.
    #[arg(long)]
    pub steps: Option<usize>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// A run folder written by `anerf train`.
    pub run: PathBuf,
    /// Continue stage 2 from its newest intact checkpoint.
    #[arg(long, conflicts_with = "overwrite")]
    pub resume: bool,
    /// Fit stage 2 again, replacing its earlier checkpoints.
    #[arg(long)]
    pub overwrite: bool,
    /// Stop (with a checkpoint) after this many steps; `--resume` continues.
    #[arg(long)]
    pub steps: Option<usize>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    pub run: PathBuf,
    /// novel-view (training frames, test views), novel-pose (novel-pose frames, test views) or
    /// training-view (training frames, training views: the fit, for the gap to the held-out splits).
    #[arg(long, default_value = "novel-view")]
    pub split: anerf_eval::report::EvalSplit,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct RenderArgs {
    pub run: PathBuf,
    /// Frame to orbit around (a training or novel-pose frame index of the dataset).
    #[arg(long)]
    pub frame: Option<usize>,
    /// Number of orbit views.
    #[arg(long, default_value_t = 36)]
    pub views: usize,
    /// Render the run's novel-pose frames from this camera instead of an orbit.
    #[arg(long, conflicts_with = "poses")]
    pub novel_poses_from_view: Option<usize>,
    /// Render the poses of this pose file, or of every pose file in this folder (`params/{i}.npy` format:
    /// `poses`, `Rh`, `Th`), after fitting their blend-weight codes with the run's `[animate]` settings.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Dataset camera of `--poses` (default: the first training view).
    #[arg(long, requires = "poses")]
    pub view: Option<usize>,
    /// Output image size (width = height) of the orbit; default: the dataset's.
    #[arg(long)]
    pub size: Option<u32>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct MeshArgs {
    pub run: PathBuf,
    /// Voxel size in metres.
    #[arg(long, default_value_t = 0.005)]
    pub voxel: f32,
    /// Iso level on raw density (the reference uses 5).
    #[arg(long, default_value_t = 5.0)]
    pub level: f32,
    /// Taubin smoothing iterations (0 = none).
    #[arg(long, default_value_t = 0)]
    pub smooth: usize,
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

#[derive(Debug, Args)]
pub struct SynthArgs {
    /// Output folder (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// tiny (4 views, 10 frames, 64 px), demo (8 views, 90 frames, 256 px), realistic (8 views at three
    /// heights, 150 frames, 512 px, studio lights with shadows and highlights, clothing over the given
    /// body) or realistic-exact (the same without clothing: the given body is the rendered one).
    #[arg(long, default_value = "demo")]
    pub preset: anerf_data::synthetic::SynthPreset,
    #[arg(long)]
    pub seed: Option<u64>,
}

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A dataset folder or an experiment config.
    pub path: PathBuf,
}

#[derive(Debug, Args)]
pub struct CompareArgs {
    pub prediction: PathBuf,
    pub ground_truth: PathBuf,
    #[arg(long)]
    pub mask: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Where the synthetic subject, cache and run go.
    #[arg(long, default_value = "demo")]
    pub out: PathBuf,
    /// Model preset for the demo (default: configs/demo.toml's, `fast`).
    #[arg(long)]
    pub preset: Option<ModelPreset>,
    #[command(flatten)]
    pub common: Common,
}

/// An error and its causes on one line, as `anyhow`'s `{:#}` writes them, leaving out each cause whose
/// text the line already holds (errors that print their source and also return it from `source()`).
pub fn error_chain(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

/// Installs the Ctrl-C handler once; the flag it sets makes the training loops checkpoint and stop.
pub fn interrupt_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let handler_flag = flag.clone();
    if let Err(e) = ctrlc::set_handler(move || {
        eprintln!("\ninterrupted: writing a checkpoint, then stopping (run again with --resume)");
        handler_flag.store(true, std::sync::atomic::Ordering::SeqCst);
    }) {
        eprintln!("warning: cannot install the Ctrl-C handler ({e}); an interrupt will not write a checkpoint");
    }
    flag
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn train_help_lists_every_preset_of_the_registry() {
        use clap::CommandFactory;
        let mut cli = Cli::command();
        let train = cli.find_subcommand_mut("train").expect("a train command");
        let short = train.render_help().to_string();
        let long = train.render_long_help().to_string();
        for preset in anerf_core::model::ModelPreset::ALL {
            assert!(short.contains(preset.name()), "{short}");
            assert!(
                long.contains(&format!("  {:<6} stage 1", preset.name())),
                "{long}"
            );
        }
    }

    #[test]
    fn an_error_chain_says_each_cause_once() {
        // `ConfigError::Read` prints its io::Error and returns it as its source: `{:#}` says it twice.
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::new(crate::config::ConfigError::Read {
            path: "a.toml".into(),
            source: io,
        })
        .context("loading the experiment");
        assert_eq!(format!("{e:#}").matches("no such file").count(), 2);
        assert_eq!(
            error_chain(&e),
            "loading the experiment: cannot read config a.toml: no such file"
        );
    }
}

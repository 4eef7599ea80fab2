//! The `anerf` command line: the subcommands, and how errors reach the user.

use clap::{Parser, Subcommand};

use crate::commands;

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
    Demo(commands::demo::DemoArgs),
    /// Write a synthetic multi-view video of an animated human in the ZJU-MoCap layout.
    Synth(commands::synth::SynthArgs),
    /// Validate a dataset folder (or the folder a config names) and summarise it.
    Info(commands::info::InfoArgs),
    /// Rewrite a capture (EasyMocap) in the ZJU-MoCap layout, for the authors' code and other tools.
    Import(commands::import::ImportArgs),
    /// Undistort, resize and compute blend-weight volumes into the cache (train does this on demand).
    Prepare(commands::prepare::PrepareArgs),
    /// Stage 1: fit the canonical radiance field and blend-weight fields to the training video.
    Train(commands::train::TrainArgs),
    /// Stage 2: fit blend-weight fields for the novel-pose frames of a trained run.
    Animate(commands::animate::AnimateArgs),
    /// Render the test views of a run and measure PSNR and SSIM with the paper's protocol.
    Eval(commands::eval::EvalArgs),
    /// Render a free-viewpoint orbit or a novel-pose sequence of a run.
    Render(commands::render::RenderArgs),
    /// Extract the canonical mesh of a run (marching cubes on density) and repose it.
    Mesh(commands::mesh::MeshArgs),
    /// Draw a run's training curves (loss, PSNR, learning rate) from its log into <run>/plots/.
    Plot(commands::plot::PlotArgs),
    /// Write a run as a skinned, animated glTF binary (.glb) for Blender, three.js, Unity, Unreal.
    Export(commands::export::ExportArgs),
    /// Bake a run into skinned 3D Gaussians that render in real time (<run>/baked/).
    Bake(commands::bake::BakeArgs),
    /// Serve a local web page of a run (curves, evaluation images, videos, the avatar in 3D) on 127.0.0.1.
    View(commands::view::ViewArgs),
    /// PSNR and SSIM of two images (with a mask: the paper's protocol).
    Compare(commands::compare::CompareArgs),
    /// Training-step time, throughput, render time and peak memory of each model preset.
    Bench(commands::bench::BenchArgs),
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

#[cfg(test)]
mod tests {
    use anerf_core::named::Named;

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
        let e = anyhow::Error::new(anerf_train::config::ConfigError::Read {
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

//! `anerf train`: stage 1 of an experiment (a config file, or a subject folder with `--data`).

use std::path::{Path, PathBuf};

use anerf_core::model::ModelPreset;
use anerf_device::DeviceSpec;
use anerf_train::config::{self, ExperimentConfig, FrameRange, Settings};
use anerf_train::stage::Stage;
use anerf_train::training::StageOutcome;
use anyhow::{bail, Result};
use clap::Args;

use crate::args::{interrupt_flag, CaptureArgs, Common, StartArgs};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Experiment config; or use `--data` to train on a folder without one.
    pub config: Option<PathBuf>,
    /// A subject folder (ZJU-MoCap layout, or an EasyMocap capture with --body-model) instead of a config.
    #[arg(long, conflicts_with = "config")]
    pub data: Option<PathBuf>,
    #[command(flatten)]
    pub capture: CaptureArgs,
    /// Training cameras, e.g. 0,2,4,6 (default: four evenly spaced cameras).
    #[arg(long, value_delimiter = ',')]
    pub train_views: Option<Vec<usize>>,
    /// Training frames start:end[:step] (default: the first two thirds of the frames).
    #[arg(long)]
    pub train_frames: Option<FrameRange>,
    /// Novel-pose frames start:end[:step] (default: the frames after the training frames).
    #[arg(long)]
    pub novel_pose_frames: Option<FrameRange>,
    #[arg(long, long_help = config::preset_help(), help = config::preset_short_help())]
    pub preset: Option<ModelPreset>,
    /// Training iterations (default: the preset's schedule).
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Run folder (default runs/<name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Train data-parallel on these CUDA devices, e.g. cuda:0,cuda:1: each step's rays are split across
    /// them and their gradients all-reduced by Burn (docs/GPU.md); one device runs the same code path.
    #[arg(long, value_delimiter = ',', conflicts_with = "device")]
    pub devices: Option<Vec<DeviceSpec>>,
    #[command(flatten)]
    pub start: StartArgs,
    #[command(flatten)]
    pub common: Common,
}

impl TrainArgs {
    /// The flags that set config values.
    fn settings(&self) -> Settings {
        Settings {
            preset: self.preset,
            train_views: self.train_views.clone(),
            train_frames: self.train_frames,
            novel_pose_frames: self.novel_pose_frames,
            iterations: self.iterations,
            ..Settings::default()
        }
    }
}

/// The config of `anerf train`: the file (or `--data` folder), then the flags, then `--set`.
pub fn config(args: &TrainArgs) -> Result<ExperimentConfig> {
    let set = &args.common.overrides;
    match (&args.config, &args.data) {
        (Some(path), None) => {
            if args.capture.load_options() != anerf_data::LoadOptions::default() {
                bail!(
                    "--body-model, --person and --masks go with --data; with a config, set \
                     dataset.body_model, dataset.person and dataset.masks in it (or with --set)"
                );
            }
            super::load_config(path, &args.settings(), set)
        }
        (None, Some(data)) => Ok(config::assemble(
            config::folder_table(data, &args.capture.load_options())?,
            &args.settings(),
            set,
        )?),
        _ => bail!("give a config file or --data <folder>"),
    }
}

/// Trains; the outcome says whether Ctrl-C stopped it.
pub fn run(args: &TrainArgs) -> Result<StageOutcome> {
    let config = config(args)?;
    let run = args
        .out
        .clone()
        .unwrap_or_else(|| Path::new("runs").join(&config.name));
    let options = anerf_run::JobOptions {
        devices: args.devices.clone(),
        ..args.common.options()
    };
    let outcome = anerf_run::train(
        config,
        &run,
        &options,
        args.start.run_start(),
        args.start.steps,
        &interrupt_flag(),
    )?;
    super::report_outcome(Stage::Train, &outcome, &run);
    Ok(outcome)
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;

    /// `anerf train`'s flags alone, parsed as the app parses them.
    #[derive(Debug, Parser)]
    struct Train {
        #[command(flatten)]
        args: TrainArgs,
    }

    fn configs_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs")
    }

    /// `anerf train <config>` applies its flags over the file, and `--set` over the flags.
    #[test]
    fn train_flags_override_a_config_file_and_set_overrides_the_flags() {
        let file = configs_dir().join("zju_mocap/313.toml");
        let args = Train::parse_from([
            "train",
            file.to_str().unwrap(),
            "--preset",
            "tiny",
            "--iterations",
            "7",
            "--train-views",
            "1,3",
            "--train-frames",
            "0:10",
            "--novel-pose-frames",
            "10:20:5",
            "--set",
            "train.iterations=9",
        ])
        .args;
        let c = config(&args).unwrap();
        let file_config = config::load(&file, &[]).unwrap();
        assert_ne!(file_config.model, c.model, "the file's preset is not tiny");
        assert_eq!(c.model, anerf_core::model::ModelPreset::Tiny.config());
        assert_eq!(c.train.iterations, 9);
        assert_eq!(c.dataset.train_views, vec![1, 3]);
        assert_eq!(
            c.dataset.split().train_frames.frames(),
            (0..10).collect::<Vec<_>>()
        );
        assert_eq!(c.dataset.split().novel_pose_frames.frames(), vec![10, 15]);
        let bad = Train::try_parse_from(["train", file.to_str().unwrap(), "--train-frames", "9:3"]);
        let err = bad.unwrap_err().to_string();
        assert!(err.contains("--train-frames"), "{err}");
    }

    /// `--devices` takes a list of devices, conflicts with `--device`, and refuses non-CUDA devices before
    /// anything is read or written.
    #[test]
    fn devices_take_a_cuda_list_and_conflict_with_device() {
        let file = configs_dir().join("zju_mocap/313.toml");
        let parse = |extra: &[&str]| {
            let mut argv = vec!["train", file.to_str().unwrap()];
            argv.extend(extra);
            Train::try_parse_from(argv).map(|t| t.args)
        };
        let args = parse(&["--devices", "cuda:0,cuda:1"]).unwrap();
        let devices = args.devices.clone().unwrap();
        assert_eq!(
            devices.iter().map(ToString::to_string).collect::<Vec<_>>(),
            ["cuda:0", "cuda:1"]
        );
        let both = parse(&["--devices", "cuda:0", "--device", "cuda"]).unwrap_err();
        assert!(both.to_string().contains("--device"), "{both}");
        let args = parse(&["--devices", "flex,flex:1"]).unwrap();
        let out = std::env::temp_dir().join("anerf-devices-refused");
        let err = anerf_run::train(
            config(&args).unwrap(),
            &out,
            &anerf_run::JobOptions {
                devices: args.devices.clone(),
                ..args.common.options()
            },
            args.start.run_start(),
            None,
            &std::sync::atomic::AtomicBool::new(false),
        )
        .unwrap_err();
        assert!(
            format!("{err:#}").contains("only between CUDA devices"),
            "{err:#}"
        );
        assert!(!out.exists(), "nothing was written");
    }
}

//! `anerf info`: a dataset folder (or the folder a config names) checked and summarised.

use std::path::PathBuf;

use anerf_train::config;
use anyhow::{bail, Result};
use clap::Args;

use crate::args::CaptureArgs;

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A dataset folder or an experiment config.
    pub path: PathBuf,
    #[command(flatten)]
    pub capture: CaptureArgs,
}

/// Prints the report; false when a problem in it is fatal.
pub fn run(args: &InfoArgs) -> Result<bool> {
    let path = &args.path;
    let (root, options) = if path.extension().is_some_and(|e| e == "toml") {
        let d = config::load(path, &[])?.dataset;
        if !d.root.is_dir() {
            bail!(
                "dataset.root = {} in {} is not a folder (expected the subject folder)",
                d.root.display(),
                path.display()
            );
        }
        let load = d.load_options();
        (
            d.root,
            anerf_data::InspectOptions {
                kind: Some(d.format.kind()),
                load,
            },
        )
    } else if path.is_file() {
        bail!(
            "{} is a file; expected a subject folder or an experiment config (.toml)",
            path.display()
        );
    } else {
        let options = anerf_data::InspectOptions {
            kind: None,
            load: args.capture.load_options(),
        };
        (path.to_path_buf(), options)
    };
    let report = anerf_data::inspect(&root, &options);
    println!("{report}");
    Ok(!report.has_fatal())
}

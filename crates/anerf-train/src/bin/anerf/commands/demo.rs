//! `anerf demo`: the whole pipeline on the built-in synthetic subject, continuing where it stopped.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anerf_core::model::ModelPreset;
use anerf_data::synthetic::SynthPreset;
use anerf_eval::report::{markdown_table, EvalSplit};
use anerf_train::checkpoint::Checkpoint;
use anerf_train::config::{self, Settings};
use anerf_train::jobs::{self, JobOptions, RenderJob};
use anerf_train::run_dir::RunDir;
use anerf_train::run_start::RunStart;
use anerf_train::stage::Stage;
use anyhow::Result;
use clap::Args;

use crate::cli::{interrupt_flag, Common};

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

pub fn run(args: &DemoArgs) -> Result<()> {
    demo(&args.out, args.preset, &args.common, &interrupt_flag())
}

/// Synthesises the demo subject (once), trains both stages, evaluates novel views and novel poses,
/// renders a turntable of a novel pose and prints a summary. Re-running continues where it stopped.
fn demo(out: &Path, preset: Option<ModelPreset>, common: &Common, stop: &AtomicBool) -> Result<()> {
    let started = Instant::now();
    let options = common.options();
    let subject = out.join("subject");
    if let Some(choice) = options.device {
        // A GPU backend that cannot run fails here, not after the subject has been generated.
        jobs::open_device(choice, &options)?;
    }
    if !subject.join("annots.npy").is_file() {
        super::synth::write(&subject, &SynthPreset::Demo.spec())?;
    }
    let settings = Settings {
        root: Some(subject),
        cache: Some(out.join("cache")),
        preset,
        ..Settings::default()
    };
    let config = config::assemble(config::demo_table(), &settings, &options.set)?;
    let run = out.join("run");
    let mut times = Vec::new();

    // The demo owns its run folder: it continues what is there, or starts it again.
    let rundir = RunDir { root: run.clone() };
    let continue_or_replace = |stage| -> Result<RunStart> {
        Ok(
            match Checkpoint::latest(&rundir.checkpoints(), stage)?.is_some() {
                true => RunStart::Resume,
                false => RunStart::Overwrite,
            },
        )
    };
    let t = Instant::now();
    let start = continue_or_replace(Stage::Train)?;
    let outcome = jobs::train(config, &run, &options, start, None, stop)?;
    super::report_outcome("stage 1", &outcome, &run);
    if outcome.interrupted {
        return Ok(());
    }
    times.push(("stage 1 (train)", t.elapsed()));
    let start = continue_or_replace(Stage::Animate)?;
    let t = Instant::now();
    let outcome = jobs::animate(&run, &options, start, None, stop)?;
    super::report_outcome("stage 2", &outcome, &run);
    if outcome.interrupted {
        return Ok(());
    }
    times.push(("stage 2 (animate)", t.elapsed()));
    let t = Instant::now();
    let nv = evaluate(&run, EvalSplit::NovelView, &options)?;
    let np = evaluate(&run, EvalSplit::NovelPose, &options)?;
    times.push(("evaluation", t.elapsed()));
    let t = Instant::now();
    let novel = RunDir::open(&run)?
        .read_config()?
        .dataset
        .split()
        .novel_pose_frames;
    let frame = (novel.start + novel.end) / 2;
    let job = RenderJob::Orbit {
        frame: Some(frame),
        views: 24,
        size: None,
    };
    let rendered = jobs::render(&run, job, &options)?;
    super::render::print(&rendered);
    times.push(("turntable render", t.elapsed()));

    let preset = preset.map_or("fast (configs/demo.toml)", |p| p.name());
    println!("\nanerf demo: {} (preset {preset})", run.display());
    println!(
        "{}",
        markdown_table(
            "split",
            &[("novel view".into(), nv), ("novel pose".into(), np)]
        )
    );
    for (what, d) in &times {
        println!("  {what:<20} {:>7.1} s", d.as_secs_f64());
    }
    println!(
        "  {:<20} {:>7.1} s",
        "total",
        started.elapsed().as_secs_f64()
    );
    println!("turntable of a novel pose: {}", rendered.gif.display());
    Ok(())
}

/// One split evaluated and printed, as `anerf eval` does.
fn evaluate(
    run: &Path,
    split: EvalSplit,
    options: &JobOptions,
) -> Result<anerf_eval::report::Summary> {
    let e = jobs::eval(run, split, options)?;
    super::eval::print(&e, split);
    Ok(e.summary)
}

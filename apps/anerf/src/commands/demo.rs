//! `anerf demo`: runs `anerf_run::demo` on the built-in synthetic subject and prints what it did.

use std::path::PathBuf;

use anerf_core::model::ModelPreset;
use anerf_core::named::Named;
use anerf_eval::report::markdown_table;
use anerf_run::demo::{demo, DemoEvent};
use anyhow::Result;
use clap::Args;

use crate::args::{interrupt_flag, Common};

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

/// Synthesises the demo subject (once), trains both stages, evaluates novel views and novel poses,
/// renders a turntable of a novel pose and prints a summary. Re-running continues where it stopped.
pub fn run(args: &DemoArgs) -> Result<()> {
    let options = args.common.options();
    let outcome = demo(
        &args.out,
        args.preset,
        &options,
        &interrupt_flag(),
        |event| match event {
            DemoEvent::Synthesised(out, spec, summary) => {
                super::synth::print_written(out, spec, summary)
            }
            DemoEvent::Stage(stage, o, run) => super::report_outcome(stage, o, run),
            DemoEvent::Evaluated(split, e) => super::eval::print(e, split),
            DemoEvent::Rendered(r) => super::render::print(r),
        },
    )?;
    let Some(results) = outcome.finished else {
        return Ok(());
    };
    let preset = args.preset.map_or("fast (configs/demo.toml)", |p| p.name());
    println!("\nanerf demo: {} (preset {preset})", outcome.run.display());
    let rows = [
        ("novel view".into(), results.novel_view.summary),
        ("novel pose".into(), results.novel_pose.summary),
    ];
    println!("{}", markdown_table("split", &rows));
    for (what, d) in &results.times {
        println!("  {what:<20} {:>7.1} s", d.as_secs_f64());
    }
    println!(
        "turntable of a novel pose: {}",
        results.turntable.gif.display()
    );
    Ok(())
}

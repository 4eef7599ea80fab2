//! `anerf bench`: parses the flags into a [`BenchJob`] (`anerf_run::bench`, which measures) and prints its
//! figures as a table or JSON lines; `--describe` prints each preset's model for
//! `scripts/bench/torch_reference.py`.

use std::path::PathBuf;

use anerf_core::model::{ModelConfig, ModelPreset};
use anerf_core::named::Named;
use anerf_core::DeviceChoice;
use anerf_run::bench::{bench, median, BenchJob, PresetFigures};
use anyhow::Result;
use serde::Serialize;

/// Options of `anerf bench`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// Model presets to measure, comma-separated (default: every preset).
    #[arg(long, value_delimiter = ',')]
    pub presets: Vec<ModelPreset>,
    /// Points per training step.
    #[arg(long, default_value_t = 65_536)]
    pub points: usize,
    /// Timed training steps per preset, after one untimed warm-up step (two rounds with `--interleave`; 0
    /// skips the step benchmark).
    #[arg(long, default_value_t = 3)]
    pub steps: usize,
    /// Side in pixels of the square render of the demo subject (0 skips the render).
    #[arg(long, default_value_t = 512)]
    pub render_size: u32,
    /// Demo subject to render (written there by `anerf synth --preset demo` when missing).
    #[arg(long, default_value = "target/bench/subject")]
    pub subject: PathBuf,
    /// Render with this trained run's model (and its preset) instead of a freshly initialised one.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Compute backend.
    #[arg(long, default_value = "flex")]
    pub device: DeviceChoice,
    /// One JSON object per preset on stdout instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Only print each preset's model configuration as one JSON object per line (the input of
    /// `scripts/bench/torch_reference.py`), measuring nothing.
    #[arg(long)]
    pub describe: bool,
    /// Use the system allocator's behaviour instead of the `anerf` binary's block cache (to measure what the
    /// cache buys).
    #[arg(long)]
    pub system_allocator: bool,
    /// Time the presets' steps in turn (one step of each, then the next round) instead of one preset after
    /// the other, so that drift in the machine's speed reaches every preset alike; also prints the median of
    /// the per-round ratios to the first preset. Step memory is then not reported (one process holds every
    /// model).
    #[arg(long)]
    pub interleave: bool,
}

/// One line of `--describe`.
#[derive(Debug, Serialize)]
struct Described {
    preset: &'static str,
    model: ModelConfig,
}

/// Runs the benchmark, printing each preset's figures as they are measured.
pub fn run(args: &BenchArgs) -> Result<Vec<PresetFigures>> {
    let presets = if args.presets.is_empty() {
        ModelPreset::ALL.to_vec()
    } else {
        args.presets.clone()
    };
    if args.describe {
        for preset in presets {
            let line = Described {
                preset: preset.name(),
                model: preset.config(),
            };
            println!("{}", serde_json::to_string(&line)?);
        }
        return Ok(Vec::new());
    }
    let job = BenchJob {
        presets,
        points: args.points,
        steps: args.steps,
        render_size: args.render_size,
        subject: args.subject.clone(),
        run: args.run.clone(),
        device: args.device,
        interleave: args.interleave,
    };
    let mut first = true;
    let all = bench(&job, |figures| {
        if args.json {
            println!("{}", serde_json::to_string(figures)?);
        } else {
            if std::mem::take(&mut first) {
                print_header();
            }
            print_row(figures);
        }
        Ok(())
    })?;
    if args.interleave && !args.json {
        print_round_ratios(&all);
    }
    Ok(all)
}

fn print_header() {
    println!(
        "{:<6} {:>9} {:>12} {:>10} {:>9} {:>7} {:>10} {:>8} {:>10} {:>6}",
        "preset",
        "step s",
        "points/s",
        "step MiB",
        "render s",
        "1st s",
        "surviving",
        "shaded",
        "render MiB",
        "load"
    );
}

/// With `--interleave`: each preset's step time over the first preset's, round by round (the steps of one
/// round ran back to back), and the median of those ratios.
fn print_round_ratios(all: &[PresetFigures]) {
    let Some((first, rest)) = all.split_first() else {
        return;
    };
    for other in rest {
        let ratios: Vec<f64> = other
            .step_seconds
            .iter()
            .zip(&first.step_seconds)
            .map(|(o, f)| o / f)
            .collect();
        if let Some(m) = median(&ratios) {
            let rounds: Vec<String> = ratios.iter().map(|r| format!("{r:.2}")).collect();
            println!(
                "{} / {} step, per round: {}; median {m:.2}",
                other.preset,
                first.preset,
                rounds.join(" ")
            );
        }
    }
}

fn print_row(f: &PresetFigures) {
    let opt =
        |v: Option<f64>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    println!(
        "{:<6} {:>9} {:>12} {:>10} {:>9} {:>7} {:>10} {:>8} {:>10} {:>6.2}",
        f.preset,
        opt(f.step_median, 3),
        opt(f.points_per_second, 0),
        opt(f.step_peak_mib, 0),
        opt(f.render.as_ref().and_then(|r| r.warm_median), 3),
        opt(f.render.as_ref().map(|r| r.seconds), 2),
        opt(f.render.as_ref().map(|r| r.surviving_fraction), 3),
        opt(f.render.as_ref().map(|r| r.shaded_fraction), 3),
        opt(f.render.as_ref().and_then(|r| r.peak_mib), 0),
        f.load_before
    );
    if let Some(b) = &f.baked_render {
        println!(
            "{:<6} baked Gaussians: {:.4} s per {}×{} render ({:.1} frames per second), first {:.2} s",
            f.preset,
            b.warm_median.unwrap_or(b.seconds),
            b.width,
            b.height,
            1.0 / b.warm_median.unwrap_or(b.seconds),
            b.seconds
        );
    }
}

//! The training curves of a run (`<run>/plots/stage1.svg`, `stage2.svg`): loss, PSNR with validation
//! PSNR, and learning rate against step, drawn from `metrics.jsonl` at the end of each stage and by
//! `anerf plot`.

use std::path::PathBuf;

use anerf_eval::plots::{write_panels, Curve, Panel};
use anyhow::{Context, Result};

use crate::run_dir::RunDir;

/// The values of `key` against `step` over the log lines of `stage` (lines without the key are skipped).
pub fn series(lines: &[serde_json::Value], stage: u64, key: &str) -> Vec<(f64, f64)> {
    lines
        .iter()
        .filter(|l| l["stage"].as_u64() == Some(stage))
        .filter_map(|l| Some((l["step"].as_f64()?, l[key].as_f64()?)))
        .collect()
}

/// The log lines of `metrics.jsonl` (a partial last line, from a crash, is left out).
pub fn read_log(run: &RunDir) -> Result<Vec<serde_json::Value>> {
    let path = run.metrics_log();
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {} (the run's training log)", path.display()))?;
    Ok(text
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect())
}

fn curve(name: &str, points: Vec<(f64, f64)>) -> Curve {
    Curve {
        name: name.into(),
        points,
    }
}

fn panel(title: &str, y_label: &str, log_y: bool, curves: Vec<Curve>) -> Panel {
    Panel {
        title: title.into(),
        x_label: "step".into(),
        y_label: y_label.into(),
        log_y,
        curves,
    }
}

/// Writes the figure of every stage the log has; returns the files written.
pub fn write_run_plots(run: &RunDir) -> Result<Vec<PathBuf>> {
    let lines = read_log(run)?;
    let mut written = Vec::new();
    for stage in [1, 2] {
        let Some(panels) = stage_panels(&lines, stage) else {
            continue;
        };
        let path = run.plots().join(format!("stage{stage}.svg"));
        write_panels(&path, &panels)?;
        written.push(path);
    }
    Ok(written)
}

/// Whether the log lines hold a step of `stage` (a line of it with a loss).
pub fn has_stage(lines: &[serde_json::Value], stage: u64) -> bool {
    lines
        .iter()
        .any(|l| l["stage"].as_u64() == Some(stage) && l["loss"].is_number())
}

/// The panels of `stage`'s figure from the log lines, or `None` when the log has no step of it.
pub fn stage_panels(lines: &[serde_json::Value], stage: u64) -> Option<Vec<Panel>> {
    if !has_stage(lines, stage) {
        return None;
    }
    let s = |key| series(lines, stage, key);
    Some(if stage == 1 {
        vec![
            panel("stage 1 loss", "loss", true, vec![curve("loss", s("loss"))]),
            panel(
                "stage 1 PSNR",
                "PSNR (dB)",
                false,
                vec![
                    curve("training rays", s("psnr")),
                    curve("validation view", s("validation_psnr")),
                ],
            ),
            panel(
                "stage 1 learning rate",
                "learning rate",
                true,
                vec![curve("lr", s("lr"))],
            ),
        ]
    } else {
        vec![
            panel(
                "stage 2 consistency loss",
                "loss",
                true,
                vec![curve("loss", s("loss"))],
            ),
            panel(
                "stage 2 learning rate",
                "learning rate",
                true,
                vec![curve("lr", s("lr"))],
            ),
        ]
    })
}

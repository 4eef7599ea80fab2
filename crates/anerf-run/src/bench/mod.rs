//! `anerf bench`: the training-step time and throughput of each model preset on a fixed batch of points
//! ([`step`]), the time to render a square image of the demo subject ([`render`]), and the peak memory of
//! each, measured on one device.

mod render;
mod step;

use std::path::PathBuf;

use anerf_core::model::ModelPreset;
use anerf_core::named::Named;
use anerf_core::DeviceChoice;
use anyhow::Result;
use serde::Serialize;

use step::{time_steps, time_steps_interleaved, StepPreset};

use crate::open_checked_device;

/// What `anerf bench` measures.
#[derive(Debug, Clone)]
pub struct BenchJob {
    /// Model presets to measure, in this order.
    pub presets: Vec<ModelPreset>,
    /// Points per training step.
    pub points: usize,
    /// Timed training steps per preset, after one untimed warm-up step (0 skips the step benchmark).
    pub steps: usize,
    /// Side in pixels of the square render (0 skips the render).
    pub render_size: u32,
    /// The demo subject to render (written there when missing).
    pub subject: PathBuf,
    /// Render this trained run's model (and its subject) instead of a fresh model of each preset.
    pub run: Option<PathBuf>,
    pub device: DeviceChoice,
    /// Time the presets' steps in turn, round by round ([`time_steps_interleaved`]); step memory is then
    /// not measured.
    pub interleave: bool,
}

/// What was measured for one preset.
#[derive(Debug, Clone, Serialize)]
pub struct PresetFigures {
    pub preset: &'static str,
    /// The GPU adapter the device runs on, as its probe reported it; `None` on CPU backends.
    pub adapter: Option<String>,
    pub points: usize,
    /// Seconds of each timed step (forward, backward, Adam).
    pub step_seconds: Vec<f64>,
    /// Median of `step_seconds`.
    pub step_median: Option<f64>,
    /// CPU seconds (user + system, all threads) of each timed step: less sensitive than wall time to other
    /// programs sharing the cores.
    pub step_cpu_seconds: Vec<f64>,
    /// `points / step_median`.
    pub points_per_second: Option<f64>,
    /// Peak resident memory during the steps, MiB (`VmHWM`).
    pub step_peak_mib: Option<f64>,
    pub render: Option<RenderFigures>,
    /// The same view rendered by the run's baked Gaussians (`--run` with a baked avatar), in turns with
    /// the NeRF's renders.
    pub baked_render: Option<RenderFigures>,
    /// One-minute load average before the preset started (other users of the machine).
    pub load_before: f64,
}

/// Renders timed after the first: the warm figure.
pub(crate) const WARM_RENDERS: usize = 3;

/// One view rendered once cold, then [`WARM_RENDERS`] times again.
#[derive(Debug, Clone, Serialize)]
pub struct RenderFigures {
    pub width: u32,
    pub height: u32,
    /// The first render: it also uploads the frame's inputs and, on a GPU, compiles and autotunes every
    /// kernel the render launches.
    pub seconds: f64,
    /// The renders after it, and their median: what an interactive viewer or a long render pays per image.
    pub warm_seconds: Vec<f64>,
    pub warm_median: Option<f64>,
    /// Rays that hit the body box (the others are black without any work).
    pub rays: usize,
    /// Samples that survive culling / all samples along those rays.
    pub surviving_fraction: f64,
    /// Samples shaded before their ray stopped (early termination) / all samples.
    pub shaded_fraction: f64,
    /// Peak resident memory during the render, MiB.
    pub peak_mib: Option<f64>,
    /// Whether a trained run's model was rendered.
    pub trained: bool,
}

/// Measures each of `job`'s presets in turn and hands its figures to `report` as soon as they are known
/// (the device is probed first, as every job's is, so a broken driver is an error and the figures name the
/// adapter); returns them all.
pub fn bench(
    job: &BenchJob,
    mut report: impl FnMut(&PresetFigures) -> Result<()>,
) -> Result<Vec<PresetFigures>> {
    let checked = open_checked_device(job.device)?;
    let (device, adapter) = (checked.device, checked.adapter);
    let steps = job
        .presets
        .iter()
        .map(|&p| StepPreset::of(p))
        .collect::<Result<Vec<_>>>()?;
    let mut interleaved = if job.interleave && job.steps > 0 {
        time_steps_interleaved(&steps, job.points, job.steps, &device.clone().autodiff())
    } else {
        Vec::new()
    }
    .into_iter();
    let mut all = Vec::new();
    for (&preset, step) in job.presets.iter().zip(&steps) {
        let load_before = load_average();
        let (step_times, step_peak_mib) = if let Some(times) = interleaved.next() {
            (times, None)
        } else if job.steps > 0 {
            reset_peak_memory();
            let times = time_steps(step, job.points, job.steps, &device.clone().autodiff());
            (times, peak_memory_mib())
        } else {
            (Vec::new(), None)
        };
        let step_seconds: Vec<f64> = step_times.iter().map(|t| t.wall).collect();
        let (render, baked_render) = if job.render_size > 0 {
            let (nerf, baked) = render::time_render(job, preset, &device)?;
            (Some(nerf), baked)
        } else {
            (None, None)
        };
        let step_median = median(&step_seconds);
        let figures = PresetFigures {
            preset: preset.name(),
            adapter: adapter.clone(),
            points: job.points,
            points_per_second: step_median.map(|s| job.points as f64 / s),
            step_median,
            step_cpu_seconds: step_times.iter().map(|t| t.cpu).collect(),
            step_seconds,
            step_peak_mib,
            render,
            baked_render,
            load_before,
        };
        report(&figures)?;
        all.push(figures);
    }
    Ok(all)
}

/// Median of a list of timings.
pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// One-minute load average (`/proc/loadavg`), NaN where unavailable.
fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}

/// Resets the peak resident set size of this process (Linux: `5` into `/proc/self/clear_refs`).
pub(crate) fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Peak resident set size since the last reset, MiB (`VmHWM` of `/proc/self/status`); `None` off Linux.
pub(crate) fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_lists() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&[]), None);
    }
}

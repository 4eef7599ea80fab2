//! The timed render of `anerf bench`: one square view of the demo subject, with a fresh model of a preset
//! or a trained run's.

use std::path::Path;
use std::time::Instant;

use anerf_core::model::{AnimatableNerf, ModelPreset};
use anerf_data::synthetic::{write_subject, SynthPreset};
use anerf_train::config::{self, Settings};
use anerf_train::experiment::Experiment;
use anerf_train::render::render_view;
use anerf_train::run_dir::RunDir;
use anyhow::{Context, Result};
use burn::prelude::Device;

use super::{median, peak_memory_mib, reset_peak_memory, BenchJob, RenderFigures, WARM_RENDERS};
use crate::load_trained;

/// Renders one `size`×`size` view of the demo subject (or of `job.run`'s subject with its model).
pub(crate) fn time_render(
    job: &BenchJob,
    preset: ModelPreset,
    device: &Device,
) -> Result<RenderFigures> {
    let (model, mut exp, trained) = match &job.run {
        Some(run) => {
            let run = RunDir::open(run)?;
            let config = run.read_config()?;
            let model = load_trained(&run, &config, device)?;
            (
                model,
                Experiment::open(config, device.clone(), false)?,
                true,
            )
        }
        None => {
            let config = demo_frame_config(&job.subject, preset)?;
            let exp = Experiment::open(config, device.clone(), false)?;
            let model = AnimatableNerf::new(&exp.config.model, exp.model_sizes(), device);
            (model, exp, false)
        }
    };
    let frame = exp.train_frames[0];
    let view = *exp.test_views.first().unwrap_or(&exp.train_views[0]);
    let base = exp.prepared.cameras[view.0].clone();
    let camera = base.resized(job.render_size as f32 / base.width.max(base.height) as f32);
    reset_peak_memory();
    let mut timed = || -> Result<_> {
        let started = Instant::now();
        let image = render_view(&model, &mut exp, frame, &camera, None)?;
        Ok((started.elapsed().as_secs_f64(), image))
    };
    let (seconds, image) = timed()?;
    let warm_seconds = (0..WARM_RENDERS)
        .map(|_| Ok(timed()?.0))
        .collect::<Result<Vec<_>>>()?;
    Ok(RenderFigures {
        width: camera.width,
        height: camera.height,
        seconds,
        warm_median: median(&warm_seconds),
        warm_seconds,
        rays: image.rays,
        surviving_fraction: image.surviving_samples as f64 / image.total_samples.max(1) as f64,
        shaded_fraction: image.shaded_samples as f64 / image.total_samples.max(1) as f64,
        peak_mib: peak_memory_mib(),
        trained,
    })
}

/// The demo experiment cut to its first frame (quick to prepare), with `preset`'s model; the subject is
/// synthesised into `subject` when it is missing, its cache goes beside it.
fn demo_frame_config(subject: &Path, preset: ModelPreset) -> Result<config::ExperimentConfig> {
    if !subject.join("annots.npy").is_file() {
        write_subject(&SynthPreset::Demo.spec(), subject)
            .with_context(|| format!("writing the demo subject to {}", subject.display()))?;
    }
    let cache = subject
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .join("cache");
    let one = |start| config::FrameRange {
        start,
        end: start + 1,
        step: 1,
    };
    let settings = Settings {
        root: Some(subject.to_path_buf()),
        cache: Some(cache),
        preset: Some(preset),
        train_frames: Some(one(0)),
        novel_pose_frames: Some(one(1)),
        ..Settings::default()
    };
    config::assemble(config::demo_table(), &settings, &[]).context("the benchmark's demo config")
}

//! The timed render of `anerf bench`: one square view of the demo subject, with a fresh model of a preset
//! or a trained run's; with a run that has a baked avatar, the same view rendered by its Gaussians too,
//! the two renderers taking turns.

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
use crate::bake::{self, BakedAvatar, DeviceAvatar};
use crate::load_trained;

/// Renders one `size`×`size` view of the demo subject (or of `job.run`'s subject with its model, and with
/// its baked avatar where it has one: the second figures).
pub(crate) fn time_render(
    job: &BenchJob,
    preset: ModelPreset,
    device: &Device,
) -> Result<(RenderFigures, Option<RenderFigures>)> {
    let mut baked = None;
    let (model, mut exp, trained) = match &job.run {
        Some(run) => {
            let run = RunDir::open(run)?;
            let config = run.read_config()?;
            let model = load_trained(&run, &config, device)?;
            if run.baked().exists() {
                baked = Some(DeviceAvatar::new(&BakedAvatar::load(&run.baked())?, device));
            }
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
    // The NeRF's render as `eval` pays it; the Gaussians' as a viewer does (every pixel, no box mask or
    // ground truth).
    let timed = |exp: &mut Experiment, gaussians: Option<&DeviceAvatar>| -> Result<Timed> {
        let started = Instant::now();
        Ok(match gaussians {
            Some(avatar) => {
                let (pose, bones) = bake::frame_bones(&model, exp, frame)?;
                avatar.pixels(&bones, &pose.global, &camera);
                Timed {
                    seconds: started.elapsed().as_secs_f64(),
                    rays: (camera.width * camera.height) as usize,
                    samples: None,
                }
            }
            None => {
                let image = render_view(&model, exp, frame, &camera, None)?;
                let total = image.total_samples.max(1) as f64;
                Timed {
                    seconds: started.elapsed().as_secs_f64(),
                    rays: image.rays,
                    samples: Some((
                        image.surviving_samples as f64 / total,
                        image.shaded_samples as f64 / total,
                    )),
                }
            }
        })
    };
    let nerf = timed(&mut exp, None)?;
    let first_baked = baked
        .as_ref()
        .map(|b| timed(&mut exp, Some(b)))
        .transpose()?;
    let (mut nerf_warm, mut baked_warm) = (Vec::new(), Vec::new());
    for _ in 0..WARM_RENDERS {
        nerf_warm.push(timed(&mut exp, None)?.seconds);
        if let Some(b) = &baked {
            baked_warm.push(timed(&mut exp, Some(b))?.seconds);
        }
    }
    let figures = |first: Timed, warm_seconds: Vec<f64>| {
        let (surviving_fraction, shaded_fraction) = first.samples.unwrap_or((0.0, 0.0));
        RenderFigures {
            width: camera.width,
            height: camera.height,
            seconds: first.seconds,
            warm_median: median(&warm_seconds),
            warm_seconds,
            rays: first.rays,
            surviving_fraction,
            shaded_fraction,
            peak_mib: peak_memory_mib(),
            trained,
        }
    };
    Ok((
        figures(nerf, nerf_warm),
        first_baked.map(|b| figures(b, baked_warm)),
    ))
}

/// One timed render: its seconds, the rays (pixels) it rendered and, for the NeRF, the fractions of samples
/// that survived culling and that were shaded.
struct Timed {
    seconds: f64,
    rays: usize,
    samples: Option<(f64, f64)>,
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

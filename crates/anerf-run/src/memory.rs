//! Refuses step sizes that cannot fit in this machine's memory, before any work: an upper bound on what
//! one step needs ([`ModelConfig::bytes_per_sample`] times the samples of a step) against the host's
//! physical memory. (On GPU devices the device's own memory is not queried; the host bound still catches
//! sizes that fit nowhere.)

use anerf_core::model::ModelConfig;
use anerf_device::host_memory_bytes;
use anyhow::{bail, Result};

use anerf_train::config::ExperimentConfig;

/// Joints counted for the blend-weight outputs (SMPL's; the estimate is an upper bound, and the joint
/// term is small beside the trunks').
const JOINTS: usize = 24;

/// What the step is part of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Work {
    /// Stage 1: `train.batch` rays of `model.samples_per_ray` samples, with gradients.
    Train,
    /// Stage 2: `animate.batch` points in pose space and as many in canonical space, with gradients.
    Animate,
    /// Evaluation and rendering: `eval.chunk` rays of `model.samples_per_ray` samples, no gradients.
    Render,
}

/// Fails, naming the keys and their values, when a step of `work` cannot fit in this machine's memory.
pub fn check(config: &ExperimentConfig, work: Work) -> Result<()> {
    let Some(available) = host_memory_bytes() else {
        return Ok(());
    };
    check_against(config, work, available)
}

fn check_against(config: &ExperimentConfig, work: Work, available: u64) -> Result<()> {
    let m: &ModelConfig = &config.model;
    let spr = m.samples_per_ray as u64;
    let (what, samples, radiance, lower) = match work {
        Work::Train => (
            format!(
                "train.batch × model.samples_per_ray = {} × {spr}",
                config.train.batch
            ),
            (config.train.batch as u64).saturating_mul(spr),
            true,
            "train.batch or model.samples_per_ray",
        ),
        Work::Animate => (
            format!("2 × animate.batch = 2 × {}", config.animate.batch),
            (config.animate.batch as u64).saturating_mul(2),
            false,
            "animate.batch",
        ),
        Work::Render => (
            format!(
                "eval.chunk × model.samples_per_ray = {} × {spr}",
                config.eval.chunk
            ),
            (config.eval.chunk as u64).saturating_mul(spr),
            true,
            "eval.chunk or model.samples_per_ray",
        ),
    };
    let needed = samples.saturating_mul(m.bytes_per_sample(JOINTS, radiance, work != Work::Render));
    if needed > available {
        let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
        bail!(
            "{what} samples need up to {:.1} GiB in one step, more than this machine's {:.1} GiB of memory; \
             lower {lower}",
            gib(needed),
            gib(available)
        );
    }
    Ok(())
}

/// Floats a bake holds per Gaussian, an upper bound: its 23 values (mean, log-scales, quaternion, opacity,
/// degree-1 colours) with their gradient and Adam's two moments, a dense skin row of [`JOINTS`] weights,
/// and the projection's intermediates kept for the backward pass (about 40 tensors of up to 12 values).
const BAKE_FLOATS_PER_GAUSSIAN: u64 = 4 * 23 + JOINTS as u64 + 40 * 12;

/// Fails, naming `--budget`, when a bake of `budget` Gaussians fitted to training crops of at most
/// `crop_pixels` pixels in all cannot fit in this machine's memory.
pub fn check_bake(budget: usize, crop_pixels: u64) -> Result<()> {
    let Some(available) = host_memory_bytes() else {
        return Ok(());
    };
    check_bake_against(budget, crop_pixels, available)
}

fn check_bake_against(budget: usize, crop_pixels: u64, available: u64) -> Result<()> {
    let gaussians = (budget as u64).saturating_mul(BAKE_FLOATS_PER_GAUSSIAN * 4);
    let crops = crop_pixels.saturating_mul(crate::bake::fit::Shot::BYTES_PER_PIXEL);
    let needed = gaussians.saturating_add(crops);
    if needed > available {
        let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
        bail!(
            "--budget {budget}: a bake of that many Gaussians ({:.1} GiB) and its training crops ({:.1} GiB, \
             every training view of every training frame) needs up to {:.1} GiB, more than this machine's \
             {:.1} GiB of memory; lower --budget or train on fewer views or frames",
            gib(gaussians),
            gib(crops),
            gib(needed),
            gib(available)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_train::config;

    /// A config of `preset` with its own schedule (batches) and the default eval chunk.
    fn preset(name: &str) -> ExperimentConfig {
        let text = format!(
            r#"
name = "s"
[dataset]
format = "zju_mocap"
root = "s"
ratio = 1.0
train_views = [0]
iccv = {{ train_frames = "0:1", novel_pose_frames = "1:2" }}
[model]
preset = "{name}"
"#
        );
        config::from_table(toml::from_str(&text).unwrap()).unwrap()
    }

    #[test]
    fn every_preset_fits_a_16_gib_machine_and_absurd_batches_do_not() {
        let machine = 16u64 << 30;
        for name in ["paper", "cpu", "fast", "tiny"] {
            let c = preset(name);
            for work in [Work::Train, Work::Animate, Work::Render] {
                check_against(&c, work, machine).unwrap_or_else(|e| panic!("{name} {work:?}: {e}"));
            }
        }
        let mut c = preset("fast");
        c.train.batch = 99_999_999_999;
        let e = check_against(&c, Work::Train, machine)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("train.batch") && e.contains("99999999999"),
            "{e}"
        );
    }

    #[test]
    fn a_bake_budget_that_cannot_fit_is_refused() {
        let machine = 16u64 << 30;
        // The realistic subject's bake: 50,000 Gaussians, 100 frames × 4 views of 512².
        let crops = 400 * 512 * 512;
        check_bake_against(50_000, crops, machine).unwrap();
        check_bake_against(1_000_000, crops, machine).unwrap();
        let e = check_bake_against(usize::MAX / 2, crops, machine)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--budget") && e.contains("more than"), "{e}");
        // 5,000 frames × 4 views of 1024² hold 5 bytes a pixel: 98 GiB of crops.
        let e = check_bake_against(50_000, 5_000 * 4 * 1024 * 1024, machine)
            .unwrap_err()
            .to_string();
        assert!(e.contains("training crops (97.7 GiB"), "{e}");
    }
}

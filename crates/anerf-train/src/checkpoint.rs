//! Checkpoints: model, optimiser state, step and random state, written atomically (a temporary folder
//! renamed into place, then a `latest` pointer replaced), so a crash or a full disk never damages the
//! previous checkpoint.

use std::fs;
use std::path::{Path, PathBuf};

use anerf_core::model::{AnimatableNerf, ModelConfig, ModelSizes, OccupancyGrid};
use anerf_data::RaySampler;
use anyhow::{bail, Context, Result};
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::prelude::Device;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::run_dir::write_atomic;

/// Everything besides tensors that a resumed run needs.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainerState {
    /// 1 = radiance field and blend fields, 2 = novel-pose blend fields.
    pub stage: u8,
    /// Steps completed.
    pub step: usize,
    pub model: ModelConfig,
    pub training_frames: usize,
    pub joints: usize,
    /// Novel-pose codes (stage 2).
    pub novel_frames: Option<usize>,
    /// The ray sampler with its random state (stage 1).
    pub sampler: Option<RaySampler>,
    /// The trainer's own random stream (jitter, frame choice, stage-2 points).
    pub rng: ChaCha8Rng,
    /// The stage's early stop on a loss plateau (absent in checkpoints written before it existed).
    #[serde(default)]
    pub plateau: crate::schedule::Plateau,
}

impl TrainerState {
    /// The model sizes recorded in the checkpoint.
    pub fn sizes(&self) -> ModelSizes {
        ModelSizes {
            training_frames: self.training_frames,
            joints: self.joints,
        }
    }

    /// An untrained model of the recorded shape (with the stage-2 field when one was recorded).
    pub fn empty_model(&self, device: &Device) -> AnimatableNerf {
        let model = AnimatableNerf::new(&self.model, self.sizes(), device);
        match self.novel_frames {
            Some(n) => model.with_novel_field(n, device),
            None => model,
        }
    }
}

/// A checkpoint folder `checkpoints/stage<k>-<step>`.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    pub dir: PathBuf,
}

const MODEL: &str = "model.bpk";
/// The model's occupancy grid (JSON), when its config has one.
const OCCUPANCY: &str = "occupancy.json";
const OPTIM: &str = "optim.bpk";
const STATE: &str = "state.json";
/// Checkpoints kept per stage (older ones are removed after a new one is in place).
const KEEP: usize = 2;

impl Checkpoint {
    /// Writes a checkpoint of `stage` at `state.step` and points `latest` at it.
    pub fn save(
        root: &Path,
        state: &TrainerState,
        model: &AnimatableNerf,
        optim: &ModuleOptimizer,
    ) -> Result<Checkpoint> {
        let name = format!("stage{}-{:08}", state.stage, state.step);
        let tmp = root.join(format!(".tmp-{name}"));
        let dir = root.join(&name);
        if tmp.exists() {
            fs::remove_dir_all(&tmp)
                .with_context(|| format!("removing leftover {}", tmp.display()))?;
        }
        let write = || -> Result<()> {
            fs::create_dir_all(&tmp)?;
            model
                .clone()
                .save_file(tmp.join(MODEL))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            optim
                .save(tmp.join(OPTIM))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            write_atomic(
                &tmp.join(STATE),
                serde_json::to_string_pretty(state)?.as_bytes(),
            )?;
            if let Some(grid) = model.occupancy() {
                write_atomic(
                    &tmp.join(OCCUPANCY),
                    serde_json::to_string(grid)?.as_bytes(),
                )?;
            }
            for f in [MODEL, OPTIM] {
                fs::File::open(tmp.join(f))?.sync_all()?;
            }
            if dir.exists() {
                fs::remove_dir_all(&dir)?;
            }
            fs::rename(&tmp, &dir)?;
            Ok(())
        };
        if let Err(e) = write() {
            let _ = fs::remove_dir_all(&tmp);
            return Err(e.context(format!(
                "writing checkpoint {} (the previous checkpoint is unchanged)",
                dir.display()
            )));
        }
        write_atomic(
            &root.join(format!("latest-stage{}", state.stage)),
            name.as_bytes(),
        )?;
        prune(root, state.stage, &name)?;
        Ok(Checkpoint { dir })
    }

    /// The newest complete checkpoint of `stage`, if any.
    pub fn latest(root: &Path, stage: u8) -> Result<Option<Checkpoint>> {
        let pointer = root.join(format!("latest-stage{stage}"));
        if !pointer.is_file() {
            return Ok(None);
        }
        let name = fs::read_to_string(&pointer)
            .with_context(|| format!("reading {}", pointer.display()))?;
        let dir = root.join(name.trim());
        if !dir.join(STATE).is_file() {
            bail!(
                "{} points at {}, which is not a complete checkpoint",
                pointer.display(),
                dir.display()
            );
        }
        Ok(Some(Checkpoint { dir }))
    }

    /// The recorded state.
    pub fn state(&self) -> Result<TrainerState> {
        let path = self.dir.join(STATE);
        let text =
            fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("{} is not a checkpoint state", path.display()))
    }

    /// The model, checked against the config the caller expects.
    pub fn load_model(
        &self,
        expected: &ModelConfig,
        device: &Device,
    ) -> Result<(AnimatableNerf, TrainerState)> {
        let state = self.state()?;
        if &state.model != expected {
            bail!(
                "checkpoint {} was trained with another model config ({}); expected {}",
                self.dir.display(),
                serde_json::to_string(&state.model)?,
                serde_json::to_string(expected)?
            );
        }
        let mut model = state
            .empty_model(device)
            .try_load_file(self.dir.join(MODEL))
            .map_err(|e| anyhow::anyhow!("loading {}: {e}", self.dir.join(MODEL).display()))?;
        model.set_occupancy(self.occupancy()?);
        Ok((model, state))
    }

    /// The occupancy grid saved with the model, if it had one.
    fn occupancy(&self) -> Result<Option<OccupancyGrid>> {
        let path = self.dir.join(OCCUPANCY);
        if !path.exists() {
            return Ok(None);
        }
        let text =
            fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let grid: OccupancyGrid = serde_json::from_str(&text)
            .with_context(|| format!("{} is not an occupancy grid", path.display()))?;
        grid.validate()
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(Some(grid))
    }

    /// The optimiser state into `optim`.
    pub fn load_optimizer(&self, optim: ModuleOptimizer) -> Result<ModuleOptimizer> {
        optim
            .load(self.dir.join(OPTIM))
            .map_err(|e| anyhow::anyhow!("loading {}: {e}", self.dir.join(OPTIM).display()))
    }
}

fn prune(root: &Path, stage: u8, keep_name: &str) -> Result<()> {
    let prefix = format!("stage{stage}-");
    let mut names: Vec<String> = fs::read_dir(root)?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with(&prefix))
        .collect();
    names.sort();
    let excess = names.len().saturating_sub(KEEP);
    for n in names.into_iter().take(excess).filter(|n| n != keep_name) {
        fs::remove_dir_all(root.join(n))?;
    }
    Ok(())
}

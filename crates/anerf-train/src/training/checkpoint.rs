//! Checkpoints: model, optimiser state, step and random state, written atomically (a temporary folder
//! renamed into place, then a `latest` pointer replaced), so a crash or a full disk never damages the
//! previous checkpoint. Each folder carries a manifest of its files' lengths and SHA-256 digests; a
//! damaged checkpoint (truncated, altered, half-deleted) is reported and the newest intact one is used.

use std::fs;
use std::path::{Path, PathBuf};

use anerf_core::model::{AnimatableNerf, ModelConfig, ModelSizes, OccupancyGrid};
use anerf_data::atomic::write_bytes;
use anerf_data::RaySampler;
use anyhow::{anyhow, bail, Context, Result};
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::prelude::Device;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::loop_state::LoopState;
use crate::manifest::Manifest;
use crate::stage::Stage;

/// Everything besides tensors that a resumed run needs.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainerState {
    pub stage: Stage,
    /// Steps completed, the early stop's watch and the open log window (`step`, `plateau` and `window`
    /// in `state.json`).
    #[serde(flatten)]
    pub counters: LoopState,
    pub model: ModelConfig,
    pub training_frames: usize,
    pub joints: usize,
    /// Novel-pose codes (stage 2).
    pub novel_frames: Option<usize>,
    /// The ray sampler with its random state (stage 1).
    pub sampler: Option<RaySampler>,
    /// The trainer's own random stream (jitter, frame choice, stage-2 points).
    pub rng: ChaCha8Rng,
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
#[derive(Debug, Clone, PartialEq, Eq)]
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

/// A checkpoint read back whole: model, recorded state and (when asked for) the optimiser.
pub struct Restored {
    pub checkpoint: Checkpoint,
    pub model: AnimatableNerf,
    pub state: TrainerState,
    pub optim: Option<ModuleOptimizer>,
}

/// Why one checkpoint could not be restored.
enum Failure {
    /// Its files are damaged: an older checkpoint may serve.
    Damaged(anyhow::Error),
    /// It is intact but does not fit the caller's config: older ones would not either.
    Refused(anyhow::Error),
}

/// The step in a checkpoint folder's name `stage<k>-<step>`.
fn step_of(name: &str, stage: Stage) -> Option<usize> {
    name.strip_prefix(&format!("stage{}-", stage.number()))?
        .parse()
        .ok()
}

impl Checkpoint {
    /// Writes a checkpoint of `state.stage` at `state.counters.step`, points `latest` at it and removes older
    /// checkpoints beyond the newest two, and any of a higher step (left by an abandoned or damaged
    /// continuation).
    pub fn save(
        root: &Path,
        state: &TrainerState,
        model: &AnimatableNerf,
        optim: &ModuleOptimizer,
    ) -> Result<Checkpoint> {
        let name = format!("stage{}-{:08}", state.stage.number(), state.counters.step);
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
                .map_err(|e| anyhow!("{e}"))?;
            optim.save(tmp.join(OPTIM)).map_err(|e| anyhow!("{e}"))?;
            write_bytes(
                &tmp.join(STATE),
                serde_json::to_string_pretty(state)?.as_bytes(),
            )?;
            let mut names = vec![MODEL, OPTIM, STATE];
            if let Some(grid) = model.occupancy() {
                write_bytes(
                    &tmp.join(OCCUPANCY),
                    serde_json::to_string(grid)?.as_bytes(),
                )?;
                names.push(OCCUPANCY);
            }
            for f in [MODEL, OPTIM] {
                fs::File::open(tmp.join(f))?.sync_all()?;
            }
            Manifest::write(&tmp, &names)?;
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
        write_bytes(&pointer(root, state.stage), name.as_bytes())?;
        prune(root, state.stage, state.counters.step)?;
        Ok(Checkpoint { dir })
    }

    /// Every checkpoint folder of `stage` under `root`, newest first: the one the `latest` pointer names
    /// (when it exists), then the others by falling step. Nothing is read or checked.
    pub fn candidates(root: &Path, stage: Stage) -> Result<Vec<Checkpoint>> {
        if !root.is_dir() {
            return Ok(Vec::new());
        }
        let mut steps: Vec<(usize, String)> = fs::read_dir(root)
            .with_context(|| format!("listing {}", root.display()))?
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter_map(|n| Some((step_of(&n, stage)?, n)))
            .filter(|(_, n)| root.join(n).is_dir())
            .collect();
        steps.sort_unstable_by(|a, b| b.cmp(a));
        let named = fs::read_to_string(pointer(root, stage))
            .ok()
            .map(|s| s.trim().to_string());
        if let Some(i) = named
            .as_ref()
            .and_then(|n| steps.iter().position(|(_, s)| s == n))
        {
            let first = steps.remove(i);
            steps.insert(0, first);
        }
        Ok(steps
            .into_iter()
            .map(|(_, n)| Checkpoint { dir: root.join(n) })
            .collect())
    }

    /// The newest checkpoint folder of `stage` ([`Self::candidates`]' first), unchecked.
    pub fn latest(root: &Path, stage: Stage) -> Result<Option<Checkpoint>> {
        Ok(Self::candidates(root, stage)?.into_iter().next())
    }

    /// The newest intact stage-1 checkpoint of `run` (model only); an error when it has none.
    pub fn restore_stage1(
        run: &crate::run_dir::RunDir,
        expected: &ModelConfig,
        device: &Device,
    ) -> Result<Restored> {
        Self::restore_newest(&run.checkpoints(), Stage::Train, expected, device, None)?
            .with_context(|| {
                format!(
                    "{} has no stage-1 checkpoint; run `anerf train` first",
                    run.root.display()
                )
            })
    }

    /// Restores the newest intact checkpoint of `stage`: each damaged one is named on stderr with what is
    /// wrong and the next older one is tried. `optimizer` builds the optimiser to load the saved state into
    /// (none: the model alone). `Ok(None)` when the stage has no checkpoint; an error when every one is
    /// damaged or the newest intact one was trained with another model config than `expected`.
    pub fn restore_newest(
        root: &Path,
        stage: Stage,
        expected: &ModelConfig,
        device: &Device,
        optimizer: Option<&dyn Fn() -> ModuleOptimizer>,
    ) -> Result<Option<Restored>> {
        let candidates = Self::candidates(root, stage)?;
        if candidates.is_empty() {
            return Ok(None);
        }
        let latest = pointer(root, stage);
        if let Ok(named) = fs::read_to_string(&latest) {
            if !root.join(named.trim()).is_dir() {
                eprintln!(
                    "warning: {} names {}, which does not exist; trying the checkpoints that do",
                    latest.display(),
                    named.trim()
                );
            }
        }
        let mut damaged = Vec::new();
        for ck in candidates {
            match ck.restore(expected, device, optimizer) {
                Ok(restored) => {
                    if !damaged.is_empty() {
                        eprintln!(
                            "warning: using {}, the newest intact {stage} checkpoint",
                            ck.dir.display()
                        );
                    }
                    return Ok(Some(restored));
                }
                Err(Failure::Refused(e)) => return Err(e),
                Err(Failure::Damaged(e)) => {
                    eprintln!("warning: checkpoint {} is damaged: {e:#}", ck.dir.display());
                    damaged.push(format!("{}: {e:#}", ck.dir.display()));
                }
            }
        }
        bail!(
            "every {stage} checkpoint in {} is damaged:\n  {}",
            root.display(),
            damaged.join("\n  ")
        )
    }

    /// Reads this checkpoint whole, telling damage from a config that does not fit.
    fn restore(
        &self,
        expected: &ModelConfig,
        device: &Device,
        optimizer: Option<&dyn Fn() -> ModuleOptimizer>,
    ) -> Result<Restored, Failure> {
        self.verify().map_err(Failure::Damaged)?;
        let state = self.state().map_err(Failure::Damaged)?;
        check_model_config(self, &state, expected).map_err(Failure::Refused)?;
        let model = self.read_model(&state, device).map_err(Failure::Damaged)?;
        let optim = optimizer
            .map(|build| self.load_optimizer(build()))
            .transpose()
            .map_err(Failure::Damaged)?;
        Ok(Restored {
            checkpoint: self.clone(),
            model,
            state,
            optim,
        })
    }

    /// Checks every file against the manifest (checkpoints written before manifests existed pass).
    pub fn verify(&self) -> Result<()> {
        match Manifest::read(&self.dir)? {
            Some(manifest) => manifest.check(&self.dir),
            None => Ok(()),
        }
    }

    /// The recorded state.
    pub fn state(&self) -> Result<TrainerState> {
        let path = self.dir.join(STATE);
        let text =
            fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("{} is not a checkpoint state", path.display()))
    }

    /// The model, checked against the config the caller expects (no integrity check beyond what loading
    /// does: [`Self::restore_newest`] is the checked path).
    pub fn load_model(
        &self,
        expected: &ModelConfig,
        device: &Device,
    ) -> Result<(AnimatableNerf, TrainerState)> {
        let state = self.state()?;
        check_model_config(self, &state, expected)?;
        Ok((self.read_model(&state, device)?, state))
    }

    fn read_model(&self, state: &TrainerState, device: &Device) -> Result<AnimatableNerf> {
        let path = self.dir.join(MODEL);
        let mut model = state
            .empty_model(device)
            .try_load_file(&path)
            .map_err(|e| anyhow!("loading {}: {e}", path.display()))?;
        model.set_occupancy(self.occupancy()?);
        Ok(model)
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
            .map_err(|e| anyhow!("{}: {e}", path.display()))?;
        Ok(Some(grid))
    }

    /// The optimiser state into `optim`.
    pub fn load_optimizer(&self, optim: ModuleOptimizer) -> Result<ModuleOptimizer> {
        let path = self.dir.join(OPTIM);
        optim
            .load(&path)
            .map_err(|e| anyhow!("loading {}: {e}", path.display()))
    }

    /// Removes every checkpoint of `stage` and its pointer (to fit the stage again from scratch).
    pub fn remove_stage(root: &Path, stage: Stage) -> Result<()> {
        for ck in Self::candidates(root, stage)? {
            fs::remove_dir_all(&ck.dir)
                .with_context(|| format!("removing {}", ck.dir.display()))?;
        }
        let p = pointer(root, stage);
        if p.exists() {
            fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
        }
        Ok(())
    }
}

fn check_model_config(ck: &Checkpoint, state: &TrainerState, expected: &ModelConfig) -> Result<()> {
    if &state.model != expected {
        bail!(
            "checkpoint {} was trained with another model config ({}); expected {}",
            ck.dir.display(),
            serde_json::to_string(&state.model)?,
            serde_json::to_string(expected)?
        );
    }
    Ok(())
}

/// The file naming the newest checkpoint of `stage`.
fn pointer(root: &Path, stage: Stage) -> PathBuf {
    root.join(format!("latest-stage{}", stage.number()))
}

/// Keeps the checkpoint at `step` and the `KEEP − 1` newest below it; removes the rest of `stage`'s,
/// including any above `step`.
fn prune(root: &Path, stage: Stage, step: usize) -> Result<()> {
    let mut older = 0;
    for ck in Checkpoint::candidates(root, stage)? {
        let name = ck.dir.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let s = step_of(name, stage).unwrap_or(usize::MAX);
        let keep = s == step
            || (s < step && {
                older += 1;
                older < KEEP
            });
        if !keep {
            fs::remove_dir_all(&ck.dir)
                .with_context(|| format!("removing old checkpoint {}", ck.dir.display()))?;
        }
    }
    Ok(())
}

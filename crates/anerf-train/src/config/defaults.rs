//! What a config takes where no file, flag or override gives a value, in typed values. Defaults that
//! depend on nothing are serde defaults on the section types (`[dataset]`'s optional keys, `[eval]`,
//! `seed`, `device`); the model's come from its preset ([`ModelPreset::config`]); a stage's depend on the
//! stage, the preset's schedule and the model's encoding, so [`StageConfig::defaults`] builds them once
//! the model is known, and [`lay_beneath`] puts them under the section the files and overrides wrote.

use anerf_core::model::{ModelPreset, PointEncoding};
use anerf_data::MaskEdges;
use toml::{Table, Value};

use super::presets::PresetSchedule;
use super::table::merge;
use super::{ConfigError, LrSchedule, StageConfig};
use crate::stage::Stage;

/// The preset of a config that names none: the paper's model.
pub const DEFAULT_PRESET: ModelPreset = ModelPreset::Paper;

/// The learning rate at the first and the last step of a stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearningRates {
    pub lr: f64,
    pub lr_final: f64,
}

impl LearningRates {
    /// The rates that train `encoding`: the paper's 5e-4 → 5e-5 for frequency encodings, Instant-NGP's
    /// 1e-2 → 1e-3 for hash grids (whose tables barely move at the paper's rate).
    pub fn of(encoding: &PointEncoding) -> Self {
        match encoding {
            PointEncoding::Frequency => Self {
                lr: 5e-4,
                lr_final: 5e-5,
            },
            PointEncoding::HashGrid { .. } => Self {
                lr: 1e-2,
                lr_final: 1e-3,
            },
        }
    }
}

impl StageConfig {
    /// Every value of `stage`'s section where nothing else gives one: the step counts, stage-2 batch,
    /// early stop and silhouette weight of the preset's `schedule`, the `encoding`'s learning rates, a
    /// checkpoint every 5,000 steps in stage 1 (2,000 in stage 2, which validates never) and the settings
    /// both stages share (the authors' gradient clip of 40, a log line every 100 steps).
    pub fn defaults(stage: Stage, schedule: &PresetSchedule, encoding: &PointEncoding) -> Self {
        let LearningRates { lr, lr_final } = LearningRates::of(encoding);
        let shared = StageConfig {
            iterations: schedule.train_iterations,
            batch: 1024,
            views_per_step: schedule.train_views_per_step,
            frames_per_step: 1,
            lr,
            lr_final,
            schedule: LrSchedule::Paper,
            grad_clip: 40.0,
            checkpoint_every: 5000,
            validate_every: 5000,
            log_every: 100,
            mask_edges: MaskEdges::default(),
            detail_fraction: 0.0,
            edge_scale: 0.1,
            mask_weight: schedule.train_mask_weight,
            hard_surface_weight: 0.0,
            residual_weight: 0.0,
            plateau_steps: 0,
            plateau_tolerance: 0.01,
        };
        match stage {
            Stage::Train => shared,
            Stage::Animate => StageConfig {
                iterations: schedule.animate_iterations,
                batch: schedule.animate_batch,
                checkpoint_every: 2000,
                validate_every: 0,
                mask_weight: 0.0,
                plateau_steps: schedule.animate_plateau_steps,
                ..shared
            },
        }
    }
}

/// Puts `defaults` under `stage`'s section of `table` (`[train]`, `[animate]`): the section's own keys
/// win. Earlier versions' boolean `skip_mask_edges` is read as `mask_edges` (it cannot stand beside it).
/// An error names a section written as a plain value (`train = 5`).
pub(super) fn lay_beneath(
    table: &mut Table,
    stage: Stage,
    defaults: &StageConfig,
) -> Result<(), ConfigError> {
    let section = stage.section();
    let mut merged = Table::try_from(defaults).expect("config sections serialise to TOML");
    match table.remove(section) {
        Some(Value::Table(mut given)) => {
            if let Some(skip) = given.remove(EARLIER_MASK_EDGES) {
                if given.contains_key("mask_edges") {
                    return Err(ConfigError::Malformed {
                        key: format!("{section}.{EARLIER_MASK_EDGES}"),
                        message: format!("given beside {section}.mask_edges, which replaces it"),
                    });
                }
                given.insert("mask_edges".into(), skip);
            }
            merge(&mut merged, given)
        }
        None => {}
        Some(_) => {
            return Err(ConfigError::NotASection {
                key: section.into(),
                what: format!("the settings of {stage}"),
            })
        }
    }
    table.insert(section.into(), Value::Table(merged));
    Ok(())
}

/// Earlier versions' name of `mask_edges`, a boolean (true: `skip`, false: `train`).
const EARLIER_MASK_EDGES: &str = "skip_mask_edges";

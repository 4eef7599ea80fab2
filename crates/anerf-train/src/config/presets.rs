//! Model presets in configs: `[model] preset = "…"` expands to the preset's model, and each preset brings
//! the schedule it trains with where no file, flag or override gives one.

use anerf_core::model::ModelPreset;
use anerf_core::named::Named;
use anerf_core::InvalidValue;
use toml::{Table, Value};

use super::defaults::DEFAULT_PRESET;
use super::table::merge;
use super::{ConfigError, RESOLVED};

/// The step counts, stage-2 batch, silhouette weight and views a step a model preset trains with where no
/// file, flag or override gives them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PresetSchedule {
    /// `train.iterations`.
    pub train_iterations: usize,
    /// `animate.iterations`.
    pub animate_iterations: usize,
    /// `animate.batch` (points per set).
    pub animate_batch: usize,
    /// `animate.plateau_steps` (0: no early stop).
    pub animate_plateau_steps: usize,
    /// `train.mask_weight` (0: colours alone, as the paper).
    pub train_mask_weight: f32,
    /// `train.views_per_step` (1: one image a step, as the reference).
    pub train_views_per_step: usize,
}

/// The schedule of each model preset.
pub fn preset_schedule(preset: ModelPreset) -> PresetSchedule {
    match preset {
        // The paper's 200k stage-1 steps and its 10k stage-2 steps, at the authors' code's 65,536 points
        // per set (docs/REFERENCE.md §3.6); the CPU-sized frequency model keeps them (it converges no
        // faster).
        ModelPreset::Paper | ModelPreset::Cpu => PresetSchedule {
            train_iterations: 200_000,
            animate_iterations: 10_000,
            animate_batch: 65_536,
            animate_plateau_steps: 0,
            train_mask_weight: 0.0,
            train_views_per_step: 1,
        },
        // Hash grids: 5,000 steps train the realistic subject in under eight minutes on 2 cores; stage 2
        // starts at the body model's weights and its novel-pose PSNR moves by less than 0.1 dB after that
        // (docs/QUALITY.md), so a few hundred steps of 16,384 points, stopped once the consistency loss
        // stops falling. The silhouette loss clears the hash grid's floaters and edge haze: held-out views
        // and novel poses gain on the realistic and demo subjects (docs/QUALITY.md). Four views a step: held-out
        // views gain with exact fits and more with refined ones (docs/POSE-REFINEMENT.md).
        ModelPreset::Fast => PresetSchedule {
            train_iterations: 5_000,
            animate_iterations: 300,
            animate_batch: 16_384,
            animate_plateau_steps: 100,
            train_mask_weight: 0.1,
            train_views_per_step: 4,
        },
        ModelPreset::Tiny => PresetSchedule {
            train_iterations: 200,
            animate_iterations: 50,
            animate_batch: 4_096,
            animate_plateau_steps: 0,
            train_mask_weight: 0.0,
            train_views_per_step: 1,
        },
    }
}

/// The short help of `--preset`: every preset's name, from the registry.
pub fn preset_short_help() -> String {
    let names: Vec<&str> = ModelPreset::ALL.iter().map(|p| p.name()).collect();
    format!(
        "Model preset ({}); --help lists each one's schedule",
        names.join(", ")
    )
}

/// The long help of `--preset`: each preset's schedule.
pub fn preset_help() -> String {
    let mut text = String::from(
        "Model preset; without --iterations (or train.iterations in the config) each trains its own schedule:",
    );
    for p in ModelPreset::ALL {
        let s = preset_schedule(p);
        text.push_str(&format!(
            "\n  {:<6} stage 1 {} iterations{}, stage 2 {} iterations of {} points{}",
            p.name(),
            s.train_iterations,
            mask_note(s.train_mask_weight),
            s.animate_iterations,
            s.animate_batch,
            plateau_note(s.animate_plateau_steps)
        ));
    }
    text
}

/// How `--help` says that a stage stops early.
pub(super) fn plateau_note(steps: usize) -> String {
    if steps == 0 {
        String::new()
    } else {
        format!(" (stops once its loss has not fallen for {steps} steps)")
    }
}

pub(super) fn mask_note(weight: f32) -> String {
    if weight == 0.0 {
        String::new()
    } else {
        format!(" with a silhouette loss of weight {weight}")
    }
}

/// Replaces `[model] preset = "…"` by the preset's full configuration with the other `[model]` keys on top,
/// and returns the preset ([`DEFAULT_PRESET`] where none is named). With `preset = "none"` no preset
/// applies and the section must list every field, as a saved, resolved config does.
pub(super) fn expand_model_preset(table: &mut Table) -> Result<Option<ModelPreset>, ConfigError> {
    let mut model = match table.remove("model") {
        Some(Value::Table(t)) => t,
        None => Table::new(),
        Some(_) => {
            return Err(ConfigError::NotASection {
                key: "model".into(),
                what: "the model's settings".into(),
            })
        }
    };
    let preset = match model.remove("preset") {
        // A resolved config (as saved in a run folder) lists every field itself.
        Some(Value::String(name)) if name == RESOLVED => None,
        None => Some(DEFAULT_PRESET),
        Some(Value::String(name)) => Some(name.parse::<ModelPreset>().map_err(|e| {
            InvalidValue::new(
                "model.preset",
                &name,
                format!("one of {}", e.names.join(", ")),
            )
        })?),
        Some(other) => return Err(InvalidValue::new("model.preset", other, "a preset name").into()),
    };
    let Some(preset) = preset else {
        table.insert("model".into(), Value::Table(model));
        return Ok(None);
    };
    let mut full = Table::try_from(preset.config()).expect("model configs serialise to TOML");
    merge(&mut full, model);
    table.insert("model".into(), Value::Table(full));
    Ok(Some(preset))
}

//! Where a config's values come from, in the order they apply: the typed defaults (`defaults.rs`, the
//! model preset), a file and its `base` chain (or another table), a command's typed [`Settings`], then
//! `--set` strings.

use std::path::{Path, PathBuf};

use anerf_core::named::Named;
use toml::{Table, Value};

use anerf_core::model::ModelPreset;

use anerf_core::model::ModelConfig;

use super::defaults::{lay_beneath, DEFAULT_PRESET};
use super::presets::{expand_model_preset, preset_schedule};
use super::table::{merge, set_value};
use super::{validate, ConfigError, ExperimentConfig, FrameRange, RangeSet, StageConfig};
use crate::stage::Stage;

/// Reads `path`, follows its `base` chain (paths relative to the file naming them), applies `overrides`
/// (`section.key=value`, the value parsed as TOML or taken as a string), expands `[model] preset`, and
/// validates.
pub fn load(path: &Path, overrides: &[String]) -> Result<ExperimentConfig, ConfigError> {
    load_with(path, &Settings::default(), overrides)
}

/// [`load`] with typed `settings` between the file and the overrides.
pub fn load_with(
    path: &Path,
    settings: &Settings,
    overrides: &[String],
) -> Result<ExperimentConfig, ConfigError> {
    assemble(read_chain(path, &mut Vec::new())?, settings, overrides)
}

/// Builds a config from a merged table of files, settings and overrides: expands the model preset, lays
/// each stage's defaults beneath its section (they follow the preset's schedule and the model's encoding),
/// reads the typed config and validates it.
pub fn from_table(mut table: Table) -> Result<ExperimentConfig, ConfigError> {
    table.remove("base");
    let preset = expand_model_preset(&mut table)?;
    // The preset leaves a `[model]` section in every case.
    let model: ModelConfig = typed(table["model"].clone(), "model")?;
    let schedule = preset_schedule(preset.unwrap_or(DEFAULT_PRESET));
    for stage in Stage::ALL {
        let defaults = StageConfig::defaults(stage, &schedule, &model.encoding);
        lay_beneath(&mut table, stage, &defaults)?;
    }
    let config: ExperimentConfig = typed(Value::Table(table), "")?;
    validate(&config)?;
    Ok(config)
}

/// Reads `value`, found at key path `at` (empty at the top), as a `T`; an error names the full key.
fn typed<T: serde::de::DeserializeOwned>(value: Value, at: &str) -> Result<T, ConfigError> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let inner = e.path().to_string();
        let key = match (at, inner.as_str()) {
            (_, ".") => at.to_string(),
            ("", _) => inner,
            _ => format!("{at}.{inner}"),
        };
        ConfigError::Malformed {
            key,
            message: e.inner().message().to_string(),
        }
    })
}

fn read_chain(path: &Path, seen: &mut Vec<PathBuf>) -> Result<Table, ConfigError> {
    let canonical = path.canonicalize().map_err(|source| ConfigError::Read {
        path: path.into(),
        source,
    })?;
    if seen.contains(&canonical) {
        return Err(ConfigError::BaseCycle {
            path: path.into(),
            again: canonical,
        });
    }
    seen.push(canonical.clone());
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.into(),
        source,
    })?;
    let mut table: Table = toml::from_str(&text).map_err(|e| ConfigError::Parse {
        path: path.into(),
        message: e.to_string(),
    })?;
    let dir = canonical
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let base = match table.remove("base") {
        Some(Value::String(b)) => read_chain(&dir.join(b), seen)?,
        Some(other) => {
            return Err(ConfigError::Malformed {
                key: format!("{}: base", path.display()),
                message: format!("{other}: expected the file name of the base config"),
            })
        }
        None => Table::new(),
    };
    let mut merged = base;
    merge(&mut merged, table);
    Ok(merged)
}

/// Applies one `section.key=value` override (`--set`): the value is parsed as TOML, else taken as a string.
pub fn apply_override(table: &mut Table, text: &str) -> Result<(), ConfigError> {
    let (key, value) = text
        .split_once('=')
        .ok_or_else(|| ConfigError::BadOverride(text.into()))?;
    let path: Vec<&str> = key.trim().split('.').collect();
    if path.iter().any(|p| p.is_empty()) {
        return Err(ConfigError::BadOverride(text.into()));
    }
    let value = value.trim();
    let parsed = toml::from_str::<Table>(&format!("v = {value}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| Value::String(value.to_string()));
    set_value(table, &path, parsed).map_err(|key| ConfigError::NotASection {
        key,
        what: format!("override `{text}`"),
    })
}

/// Values a command sets over a config's tables, typed (command-line flags, the demo's and the benchmark's
/// folders). They apply after the tables and before `--set`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Settings {
    /// `dataset.root`: the subject folder.
    pub root: Option<PathBuf>,
    /// `dataset.cache`: where prepared data goes.
    pub cache: Option<PathBuf>,
    /// `model.preset`, which also brings the preset's schedule where nothing else gives one.
    pub preset: Option<ModelPreset>,
    /// `dataset.train_views`.
    pub train_views: Option<Vec<usize>>,
    /// `dataset.iccv.train_frames`; a frame range also selects the ICCV ranges (`dataset.ranges`).
    pub train_frames: Option<FrameRange>,
    /// `dataset.iccv.novel_pose_frames`, as `train_frames`.
    pub novel_pose_frames: Option<FrameRange>,
    /// `train.iterations`.
    pub iterations: Option<usize>,
}

impl Settings {
    /// Writes the given values into `table`; an error names a key of the file that holds a value where a
    /// section is expected (`dataset = 5`).
    pub fn apply(&self, table: &mut Table) -> Result<(), ConfigError> {
        let path_value = |p: &Path| Value::String(p.display().to_string());
        let mut set = |path: &[&str], value: Value| {
            set_value(table, path, value).map_err(|key| ConfigError::NotASection {
                key,
                what: format!("setting {}", path.join(".")),
            })
        };
        if let Some(p) = &self.root {
            set(&["dataset", "root"], path_value(p))?;
        }
        if let Some(p) = &self.cache {
            set(&["dataset", "cache"], path_value(p))?;
        }
        if let Some(p) = self.preset {
            set(&["model", "preset"], Value::String(p.name().into()))?;
        }
        if let Some(v) = &self.train_views {
            set(
                &["dataset", "train_views"],
                Value::Array(v.iter().map(|&i| Value::Integer(i as i64)).collect()),
            )?;
        }
        let ranges = [
            ("train_frames", self.train_frames),
            ("novel_pose_frames", self.novel_pose_frames),
        ];
        for (key, range) in ranges {
            if let Some(r) = range {
                set(&["dataset", "iccv", key], Value::String(r.to_string()))?;
            }
        }
        if ranges.iter().any(|(_, r)| r.is_some()) {
            set(
                &["dataset", "ranges"],
                Value::String(RangeSet::Iccv.key().into()),
            )?;
        }
        if let Some(n) = self.iterations {
            set(&["train", "iterations"], Value::Integer(n as i64))?;
        }
        Ok(())
    }
}

/// A config from `table`, then `settings`, then the `--set` strings, over the defaults.
pub fn assemble(
    mut table: Table,
    settings: &Settings,
    set: &[String],
) -> Result<ExperimentConfig, ConfigError> {
    settings.apply(&mut table)?;
    for o in set {
        apply_override(&mut table, o)?;
    }
    from_table(table)
}

/// `config` with `--set` strings applied over it (a run's saved config, for one command).
pub fn with_overrides(
    config: ExperimentConfig,
    set: &[String],
) -> Result<ExperimentConfig, ConfigError> {
    if set.is_empty() {
        return Ok(config);
    }
    let table: Table = toml::from_str(&super::to_toml(&config)).expect("a saved config reads back");
    assemble(table, &Settings::default(), set)
}

/// The experiment of `anerf demo` (also `configs/demo.toml`).
pub const DEMO_CONFIG: &str = include_str!("../../../../configs/demo.toml");

/// `configs/demo.toml` as a table; the demo and the benchmark set its folders.
pub fn demo_table() -> Table {
    toml::from_str(DEMO_CONFIG).expect("the demo config is valid TOML")
}

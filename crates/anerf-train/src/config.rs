//! Experiment configuration: TOML files with inheritance (`base = "…"`), command-line overrides
//! (`--set section.key=value`) and validation whose errors name the key and the allowed values.

use std::path::{Path, PathBuf};

use anerf_core::model::{ModelConfig, ModelPreset};
use anerf_core::DeviceChoice;
use serde::{Deserialize, Serialize};
use toml::{Table, Value};

/// Errors while reading, merging or validating a configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("config {path} is not valid TOML: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("config {path}: `base` chain loops back to {again}")]
    BaseCycle { path: PathBuf, again: PathBuf },
    #[error("override `{0}` is not of the form section.key=value")]
    BadOverride(String),
    #[error("invalid config: {0}")]
    Invalid(String),
}

/// A half-open range of frame indices `start..end` stepping by `step`, written `"start:end"` or
/// `"start:end:step"` in configs and on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameRange {
    pub start: usize,
    pub end: usize,
    pub step: usize,
}

impl FrameRange {
    /// The frame indices.
    pub fn frames(&self) -> Vec<usize> {
        (self.start..self.end).step_by(self.step.max(1)).collect()
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames().len()
    }

    /// True when the range holds no frame.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl std::str::FromStr for FrameRange {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<&str> = s.split(':').collect();
        let num = |p: &str| {
            p.trim()
                .parse::<usize>()
                .map_err(|_| format!("'{s}' is not a frame range start:end[:step]"))
        };
        let range = match parts.as_slice() {
            [a, b] => FrameRange {
                start: num(a)?,
                end: num(b)?,
                step: 1,
            },
            [a, b, c] => FrameRange {
                start: num(a)?,
                end: num(b)?,
                step: num(c)?,
            },
            _ => return Err(format!("'{s}' is not a frame range start:end[:step]")),
        };
        if range.end < range.start || range.step == 0 {
            return Err(format!("'{s}': expected start ≤ end and a positive step"));
        }
        Ok(range)
    }
}

impl std::fmt::Display for FrameRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.step == 1 {
            write!(f, "{}:{}", self.start, self.end)
        } else {
            write!(f, "{}:{}:{}", self.start, self.end, self.step)
        }
    }
}

impl Serialize for FrameRange {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for FrameRange {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

/// Dataset layouts anerf reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetFormat {
    /// ZJU-MoCap (also the layout `anerf synth` writes).
    ZjuMocap,
    /// The processed Human3.6M layout of the authors.
    H36m,
}

impl DatasetFormat {
    /// The loader's name for the layout.
    pub fn kind(self) -> anerf_data::DatasetKind {
        match self {
            DatasetFormat::ZjuMocap => anerf_data::DatasetKind::ZjuMocap,
            DatasetFormat::H36m => anerf_data::DatasetKind::H36m,
        }
    }
}

/// Which published frame ranges a subject config uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RangeSet {
    /// The ICCV configs of the paper.
    #[default]
    Iccv,
    /// The TPAMI / Neural Body ranges.
    Tpami,
}

impl RangeSet {
    /// The set's key in `[dataset]` (`iccv`, `tpami`).
    pub fn key(self) -> &'static str {
        match self {
            RangeSet::Iccv => "iccv",
            RangeSet::Tpami => "tpami",
        }
    }
}

/// Training and novel-pose frames of one range set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameSplit {
    pub train_frames: FrameRange,
    pub novel_pose_frames: FrameRange,
}

/// How blend-weight volumes are obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum VolumeSource {
    /// Nearest surface point with barycentric weights (the paper), computed by `anerf prepare`.
    #[default]
    Surface,
    /// Nearest vertex (the reference's `bweights/`), computed by `anerf prepare`.
    NearestVertex,
    /// The dataset's own `lbs/tbw.npy` and `lbs/bweights/` files.
    Dataset,
}

/// `[dataset]`: where the data is and which views and frames to use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    pub format: DatasetFormat,
    /// The subject folder (relative paths are relative to the directory anerf runs in).
    pub root: PathBuf,
    /// Image scale factor applied after undistortion (0.5 for ZJU-MoCap, 1 for H36M).
    pub ratio: f32,
    pub train_views: Vec<usize>,
    /// Views used for evaluation; empty means every view not used for training.
    #[serde(default)]
    pub test_views: Vec<usize>,
    #[serde(default)]
    pub ranges: RangeSet,
    pub iccv: FrameSplit,
    /// The TPAMI / Neural Body ranges (defaults to the ICCV ones where they agree).
    #[serde(default)]
    pub tpami: Option<FrameSplit>,
    /// Every n-th frame of the ranges (5 for H36M).
    #[serde(default = "one")]
    pub frame_interval: usize,
    #[serde(default)]
    pub volumes: VolumeSource,
    /// A body-model file (SMPL `.npz` or `.pkl`) when `lbs/` has no weights and faces.
    #[serde(default)]
    pub body_model: Option<PathBuf>,
    /// Where `anerf prepare` writes its cache.
    #[serde(default = "default_cache")]
    pub cache: PathBuf,
}

fn one() -> usize {
    1
}

fn default_cache() -> PathBuf {
    PathBuf::from("cache")
}

impl DatasetConfig {
    /// Resolves `root`, `cache` and `body_model` against the working directory, as written into a run's
    /// config, so that the run can be evaluated from any folder.
    pub fn make_paths_absolute(&mut self) -> Result<(), ConfigError> {
        let absolute = |key: &str, p: &Path| {
            std::path::absolute(p).map_err(|e| {
                ConfigError::Invalid(format!(
                    "dataset.{key}: cannot resolve {}: {e}",
                    p.display()
                ))
            })
        };
        self.root = absolute("root", &self.root)?;
        self.cache = absolute("cache", &self.cache)?;
        if let Some(b) = &self.body_model {
            self.body_model = Some(absolute("body_model", b)?);
        }
        Ok(())
    }

    /// The frame split selected by `ranges`.
    pub fn split(&self) -> &FrameSplit {
        match (self.ranges, &self.tpami) {
            (RangeSet::Tpami, Some(t)) => t,
            _ => &self.iccv,
        }
    }
}

/// The learning-rate schedule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum LrSchedule {
    /// Exponential decay from `lr` to `lr_final` over the run (the paper).
    #[default]
    Paper,
    /// `lr · 0.1^(epoch/1000)` with 500-iteration epochs (the authors' code).
    Code,
}

/// `[train]` and `[animate]`: one optimisation stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    pub iterations: usize,
    /// Rays per batch (stage 1) or points per set (stage 2).
    pub batch: usize,
    pub lr: f64,
    pub lr_final: f64,
    #[serde(default)]
    pub schedule: LrSchedule,
    /// Gradient values are clipped to ±this (the code uses 40); 0 disables clipping.
    pub grad_clip: f32,
    pub checkpoint_every: usize,
    pub validate_every: usize,
    pub log_every: usize,
    /// Stage 1: never draw rays from the 5×5 band around mask edges (the reference's `erode_edge`, for the
    /// imprecise masks of real captures). Synthetic subjects have exact masks and turn it off.
    #[serde(default = "default_true")]
    pub skip_mask_edges: bool,
    /// Stage 1: weight of the silhouette loss `mean((acc − m)²)`, the rendered opacity against the mask
    /// (1 on body pixels, 0 elsewhere); 0 disables it (the paper fits colours alone).
    #[serde(default)]
    pub mask_weight: f32,
    /// Weight of `mean(F²)`, the penalty on the blend-weight residual that keeps the neural weights at the
    /// body model's where the data does not ask otherwise; 0 disables it.
    #[serde(default)]
    pub residual_weight: f32,
    /// Stop early once the loss, averaged over each `log_every` window, has not fallen by
    /// `plateau_tolerance` (relative) below its best for this many steps; 0 never stops early.
    #[serde(default)]
    pub plateau_steps: usize,
    /// Relative improvement that counts as progress for `plateau_steps`.
    #[serde(default = "default_plateau_tolerance")]
    pub plateau_tolerance: f32,
}

fn default_plateau_tolerance() -> f32 {
    0.01
}

fn default_true() -> bool {
    true
}

/// `[eval]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvalConfig {
    /// Every n-th frame of a split is evaluated (30 on ZJU-MoCap, 6 on H36M).
    pub frame_interval: usize,
    /// Rays rendered per chunk.
    pub chunk: usize,
    /// A rendered ray stops once its transmittance falls below this (early ray termination): the colour and
    /// opacity it would still gather are smaller. 0 shades every sample that survives culling.
    #[serde(default = "default_termination")]
    pub termination: f32,
}

/// The default [`EvalConfig::termination`]: a 40th of an 8-bit grey level.
fn default_termination() -> f32 {
    1e-4
}

/// A whole experiment, as resolved from its files and overrides.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentConfig {
    pub name: String,
    pub seed: u64,
    pub device: DeviceChoice,
    pub dataset: DatasetConfig,
    pub model: ModelConfig,
    pub train: StageConfig,
    pub animate: StageConfig,
    pub eval: EvalConfig,
}

/// Reads `path`, follows its `base` chain (paths relative to the file naming them), applies `overrides`
/// (`section.key=value`, the value parsed as TOML or taken as a string), expands `[model] preset`, and
/// validates.
pub fn load(path: &Path, overrides: &[String]) -> Result<ExperimentConfig, ConfigError> {
    let mut table = read_chain(path, &mut Vec::new())?;
    for o in overrides {
        apply_override(&mut table, o)?;
    }
    from_table(table)
}

/// Builds a config from an already merged table (defaults, presets, validation).
pub fn from_table(mut table: Table) -> Result<ExperimentConfig, ConfigError> {
    table.remove("base");
    if let Some(preset) = expand_model_preset(&mut table)? {
        default_schedule(&mut table, preset_schedule(preset));
    }
    default_learning_rates(&mut table);
    let config: ExperimentConfig = serde_path_to_error::deserialize(Value::Table(table))
        .map_err(|e| ConfigError::Invalid(format!("{}: {}", e.path(), e.inner().message())))?;
    validate(&config)?;
    Ok(config)
}

/// The built-in defaults every config starts from (`configs/` files override them).
pub fn defaults() -> Table {
    toml::from_str(DEFAULTS).expect("built-in defaults are valid TOML")
}

const DEFAULTS: &str = r#"
seed = 0
device = "flex"

[model]
preset = "paper"

[train]
batch = 1024
schedule = "paper"
grad_clip = 40.0
checkpoint_every = 5000
validate_every = 5000
log_every = 100

[animate]
schedule = "paper"
grad_clip = 40.0
checkpoint_every = 2000
validate_every = 0
log_every = 100

[eval]
frame_interval = 30
chunk = 4096
"#;

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
            return Err(ConfigError::Invalid(format!(
                "{}: `base` must be a file name, got {other}",
                path.display()
            )))
        }
        None => defaults(),
    };
    let mut merged = base;
    merge(&mut merged, table);
    Ok(merged)
}

/// Deep-merges `over` into `base`: tables merge key by key, anything else replaces.
pub fn merge(base: &mut Table, over: Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(Value::Table(b)), Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Applies one `section.key=value` override.
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
    let mut node = table;
    for p in &path[..path.len() - 1] {
        node = match node
            .entry(p.to_string())
            .or_insert_with(|| Value::Table(Table::new()))
        {
            Value::Table(t) => t,
            _ => {
                return Err(ConfigError::Invalid(format!(
                    "override `{text}`: `{p}` is not a section"
                )))
            }
        };
    }
    node.insert(path[path.len() - 1].to_string(), parsed);
    Ok(())
}

/// The step counts, stage-2 batch and silhouette weight a model preset trains with where no file, flag or
/// override gives them.
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
}

/// The schedule of each model preset.
pub fn preset_schedule(preset: ModelPreset) -> PresetSchedule {
    match preset {
        // The paper's 200k steps and the authors' stage 2 (10k steps of 65,536 points); the CPU-sized
        // frequency model keeps them (it converges no faster).
        ModelPreset::Paper | ModelPreset::Cpu => PresetSchedule {
            train_iterations: 200_000,
            animate_iterations: 10_000,
            animate_batch: 65_536,
            animate_plateau_steps: 0,
            train_mask_weight: 0.0,
        },
        // Hash grids: 5,000 steps train the realistic subject in under eight minutes on 2 cores; stage 2
        // starts at the body model's weights and its novel-pose PSNR moves by less than 0.1 dB after that
        // (docs/QUALITY.md), so a few hundred steps of 16,384 points, stopped once the consistency loss
        // stops falling. The silhouette loss clears the hash grid's floaters and edge haze: held-out views
        // and novel poses gain on the realistic and demo subjects (docs/QUALITY.md).
        ModelPreset::Fast => PresetSchedule {
            train_iterations: 5_000,
            animate_iterations: 300,
            animate_batch: 16_384,
            animate_plateau_steps: 100,
            train_mask_weight: 0.1,
        },
        ModelPreset::Tiny => PresetSchedule {
            train_iterations: 200,
            animate_iterations: 50,
            animate_batch: 4_096,
            animate_plateau_steps: 0,
            train_mask_weight: 0.0,
        },
    }
}

/// The `--preset` help of `anerf train`: each preset's schedule.
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
fn plateau_note(steps: usize) -> String {
    if steps == 0 {
        String::new()
    } else {
        format!(" (stops once its loss has not fallen for {steps} steps)")
    }
}

fn mask_note(weight: f32) -> String {
    if weight == 0.0 {
        String::new()
    } else {
        format!(" with a silhouette loss of weight {weight}")
    }
}

/// Fills `train.iterations`, `train.mask_weight`, `animate.iterations`, `animate.batch` and
/// `animate.plateau_steps` where no file or override gave them.
fn default_schedule(table: &mut Table, schedule: PresetSchedule) {
    let as_int = |n: usize| Value::Integer(n as i64);
    for (stage, key, value) in [
        ("train", "iterations", as_int(schedule.train_iterations)),
        ("animate", "iterations", as_int(schedule.animate_iterations)),
        ("animate", "batch", as_int(schedule.animate_batch)),
        (
            "animate",
            "plateau_steps",
            as_int(schedule.animate_plateau_steps),
        ),
        (
            "train",
            "mask_weight",
            Value::Float(schedule.train_mask_weight as f64),
        ),
    ] {
        if let Some(Value::Table(t)) = table.get_mut(stage) {
            t.entry(key).or_insert(value);
        }
    }
}

/// Replaces `[model] preset = "…"` by the preset's full configuration with the other `[model]` keys on top,
/// and returns the preset. With `preset = "none"` (or none at all) the section must list every field, as a
/// saved, resolved config does.
fn expand_model_preset(table: &mut Table) -> Result<Option<ModelPreset>, ConfigError> {
    let mut model = match table.remove("model") {
        Some(Value::Table(t)) => t,
        None => Table::new(),
        Some(_) => return Err(ConfigError::Invalid("`model` must be a section".into())),
    };
    let preset = match model.remove("preset") {
        // A resolved config (as saved in a run folder) lists every field itself.
        Some(Value::String(name)) if name == RESOLVED => None,
        None => None,
        Some(Value::String(name)) => Some(
            name.parse::<ModelPreset>()
                .map_err(|e| ConfigError::Invalid(format!("model.preset: {e}")))?,
        ),
        Some(other) => {
            return Err(ConfigError::Invalid(format!(
                "model.preset = {other}: expected a preset name"
            )))
        }
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

/// Fills `lr` and `lr_final` of `[train]` and `[animate]` where no file or override gave them, from the
/// model's point encoding: the paper's 5e-4 → 5e-5 for frequency encodings, Instant-NGP's 1e-2 → 1e-3 for
/// hash grids (whose tables barely move at the paper's rate).
fn default_learning_rates(table: &mut Table) {
    let hash_grid = table
        .get("model")
        .and_then(|m| m.get("encoding"))
        .and_then(|e| e.get("kind"))
        .and_then(Value::as_str)
        == Some("hash_grid");
    let (lr, lr_final) = if hash_grid {
        (1e-2, 1e-3)
    } else {
        (5e-4, 5e-5)
    };
    for stage in ["train", "animate"] {
        if let Some(Value::Table(t)) = table.get_mut(stage) {
            t.entry("lr").or_insert(Value::Float(lr));
            t.entry("lr_final").or_insert(Value::Float(lr_final));
        }
    }
}

/// Checks values serde cannot: ranges, sizes and positivity. Errors name the key.
pub fn validate(c: &ExperimentConfig) -> Result<(), ConfigError> {
    let bad = |key: &str, why: String| Err(ConfigError::Invalid(format!("{key}: {why}")));
    c.model.validate().map_err(ConfigError::Invalid)?;
    let d = &c.dataset;
    if !(d.ratio.is_finite() && d.ratio > 0.0 && d.ratio <= 1.0) {
        return bad(
            "dataset.ratio",
            format!("{} (expected 0 < ratio ≤ 1)", d.ratio),
        );
    }
    if d.train_views.is_empty() {
        return bad(
            "dataset.train_views",
            "empty (expected at least one camera index)".into(),
        );
    }
    if d.frame_interval == 0 {
        return bad(
            "dataset.frame_interval",
            "0 (expected a positive integer)".into(),
        );
    }
    for (name, split) in [
        ("dataset.iccv", Some(&d.iccv)),
        ("dataset.tpami", d.tpami.as_ref()),
    ] {
        if let Some(s) = split {
            if s.train_frames.is_empty() {
                return bad(
                    &format!("{name}.train_frames"),
                    format!("{} holds no frame", s.train_frames),
                );
            }
            let train = s.train_frames.frames();
            if let Some(f) = s
                .novel_pose_frames
                .frames()
                .into_iter()
                .find(|f| train.binary_search(f).is_ok())
            {
                return bad(
                    &format!("{name}.novel_pose_frames"),
                    format!(
                        "{} shares frame {f} with {name}.train_frames = {} (novel poses must be frames the \
                         model was not trained on)",
                        s.novel_pose_frames, s.train_frames
                    ),
                );
            }
        }
    }
    if d.ranges == RangeSet::Tpami && d.tpami.is_none() {
        return bad(
            "dataset.ranges",
            "\"tpami\" but the config has no [dataset.tpami] section".into(),
        );
    }
    for (name, s) in [("train", &c.train), ("animate", &c.animate)] {
        if s.iterations == 0 {
            return bad(
                &format!("{name}.iterations"),
                "0 (expected at least one step)".into(),
            );
        }
        if s.batch == 0 {
            return bad(
                &format!("{name}.batch"),
                "0 (expected a positive integer)".into(),
            );
        }
        for (key, rate) in [("lr", s.lr), ("lr_final", s.lr_final)] {
            if !(rate.is_finite() && rate > 0.0) {
                return bad(
                    &format!("{name}.{key}"),
                    format!("{rate} (expected a positive, finite rate)"),
                );
            }
        }
        if s.grad_clip.is_nan() || s.grad_clip < 0.0 {
            return bad(
                &format!("{name}.grad_clip"),
                format!("{} (expected ≥ 0; 0 disables)", s.grad_clip),
            );
        }
        if !(s.mask_weight.is_finite() && s.mask_weight >= 0.0) {
            return bad(
                &format!("{name}.mask_weight"),
                format!("{} (expected ≥ 0; 0 disables)", s.mask_weight),
            );
        }
        if !(s.residual_weight.is_finite() && s.residual_weight >= 0.0) {
            return bad(
                &format!("{name}.residual_weight"),
                format!("{} (expected ≥ 0; 0 disables)", s.residual_weight),
            );
        }
        if !(s.plateau_tolerance.is_finite() && (0.0..1.0).contains(&s.plateau_tolerance)) {
            return bad(
                &format!("{name}.plateau_tolerance"),
                format!("{} (expected 0 ≤ tolerance < 1)", s.plateau_tolerance),
            );
        }
        if s.log_every == 0 {
            return bad(
                &format!("{name}.log_every"),
                "0 (expected a positive integer)".into(),
            );
        }
    }
    if c.eval.frame_interval == 0 || c.eval.chunk == 0 {
        return bad("eval", "frame_interval and chunk must be positive".into());
    }
    if !(0.0..1.0).contains(&c.eval.termination) {
        return bad(
            "eval.termination",
            format!("{} (expected 0 ≤ termination < 1)", c.eval.termination),
        );
    }
    if c.name.is_empty() || c.name.contains(['/', '\\']) {
        return bad(
            "name",
            format!("'{}' (expected a non-empty name without slashes)", c.name),
        );
    }
    Ok(())
}

/// `[model] preset` of a resolved config: every model field is listed, no preset applies.
const RESOLVED: &str = "none";

/// The config as TOML, as written into a run folder: loadable as a config file again, with
/// `[model] preset = "none"` because the section lists every field.
pub fn to_toml(c: &ExperimentConfig) -> String {
    let mut table = Table::try_from(c).expect("configs serialise to TOML");
    if let Some(Value::Table(model)) = table.get_mut("model") {
        model.insert("preset".into(), Value::String(RESOLVED.into()));
    }
    toml::to_string_pretty(&table).expect("configs serialise to TOML")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    const SUBJECT: &str = r#"
name = "s"
[dataset]
format = "zju_mocap"
root = "data/x"
ratio = 0.5
train_views = [0, 6]
iccv = { train_frames = "0:60", novel_pose_frames = "60:1060" }
[model]
preset = "tiny"
width = 48
"#;

    #[test]
    fn inheritance_overrides_and_presets() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "base.toml", SUBJECT);
        let child = write(
            dir.path(),
            "child.toml",
            "base = \"base.toml\"\nname = \"child\"\n[train]\niterations = 7\n",
        );
        let c = load(
            &child,
            &["train.batch=64".into(), "dataset.ranges=iccv".into()],
        )
        .unwrap();
        assert_eq!(c.name, "child");
        assert_eq!(
            (c.train.iterations, c.train.batch, c.train.lr),
            (7, 64, 5e-4)
        );
        // The preset's sizes with the file's override on top.
        let tiny = ModelPreset::Tiny.config();
        assert_eq!((c.model.width, c.model.depth), (48, tiny.depth));
        assert_eq!(
            c.dataset.split().train_frames.frames(),
            (0..60).collect::<Vec<_>>()
        );
        // The resolved config round-trips through its TOML.
        let again = from_table(toml::from_str(&to_toml(&c)).unwrap()).unwrap();
        assert_eq!(again, c);
        let saved = write(dir.path(), "resolved.toml", &to_toml(&c));
        assert_eq!(load(&saved, &[]).unwrap(), c);
    }

    /// Without `lr` in any file, the rates follow the encoding; a given rate is kept.
    #[test]
    fn learning_rates_default_by_encoding() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "s.toml", SUBJECT);
        let rates = |c: &ExperimentConfig| {
            (
                c.train.lr,
                c.train.lr_final,
                c.animate.lr,
                c.animate.lr_final,
            )
        };
        assert_eq!(rates(&load(&p, &[]).unwrap()), (5e-4, 5e-5, 5e-4, 5e-5));
        let fast = load(&p, &["model.preset=fast".into()]).unwrap();
        assert_eq!(rates(&fast), (1e-2, 1e-3, 1e-2, 1e-3));
        let given = load(&p, &["model.preset=fast".into(), "train.lr=3e-3".into()]).unwrap();
        assert_eq!(rates(&given), (3e-3, 1e-3, 1e-2, 1e-3));
    }

    #[test]
    fn errors_name_the_key_and_the_allowed_values() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "s.toml", SUBJECT);
        let err = load(&p, &["model.preset=huge".into()])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("model.preset") && err.contains("paper, cpu, tiny"),
            "{err}"
        );
        let err = load(&p, &["dataset.ratio=2".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("dataset.ratio"), "{err}");
        let err = load(&p, &["train.schedule=cosine".into()])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("cosine") && err.contains("paper") && err.contains("code"),
            "{err}"
        );
        let err = load(&p, &["train.typo=1".into()]).unwrap_err().to_string();
        assert!(err.contains("typo"), "{err}");
        let err = load(&p, &["device=tpu".into()]).unwrap_err().to_string();
        assert!(err.contains("tpu") && err.contains("flex"), "{err}");
        let err = load(&p, &["dataset.iccv.train_frames=9:3".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("9:3"), "{err}");
        assert!(matches!(
            load(&p, &["nonsense".into()]),
            Err(ConfigError::BadOverride(_))
        ));
    }

    /// Without step counts in any file, each preset trains its own schedule; given ones are kept.
    #[test]
    fn presets_carry_their_schedules() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "s.toml", SUBJECT);
        let steps =
            |c: &ExperimentConfig| (c.train.iterations, c.animate.iterations, c.animate.batch);
        for preset in ModelPreset::ALL {
            let c = load(&p, &[format!("model.preset={}", preset.name())]).unwrap();
            let s = preset_schedule(preset);
            assert_eq!(
                steps(&c),
                (s.train_iterations, s.animate_iterations, s.animate_batch)
            );
        }
        assert_eq!(preset_schedule(ModelPreset::Fast).train_iterations, 5_000);
        assert_eq!(
            preset_schedule(ModelPreset::Paper).train_iterations,
            200_000
        );
        let given = load(
            &p,
            &["model.preset=fast".into(), "train.iterations=7".into()],
        )
        .unwrap();
        assert_eq!(steps(&given), (7, 300, 16_384));
        assert_eq!(given.animate.plateau_steps, 100);
        assert_eq!(given.train.mask_weight, 0.1);
        let paper = load(&p, &["model.preset=paper".into()]).unwrap();
        assert_eq!(paper.train.mask_weight, 0.0, "the paper fits colours alone");
        let set = load(
            &p,
            &["model.preset=fast".into(), "train.mask_weight=0".into()],
        )
        .unwrap();
        assert_eq!(set.train.mask_weight, 0.0, "a config's value wins");
        let help = preset_help();
        for preset in ModelPreset::ALL {
            let s = preset_schedule(preset);
            assert!(
                help.contains(&format!(
                    "{:<6} stage 1 {} iterations{}, stage 2 {} iterations of {} points{}",
                    preset.name(),
                    s.train_iterations,
                    mask_note(s.train_mask_weight),
                    s.animate_iterations,
                    s.animate_batch,
                    plateau_note(s.animate_plateau_steps)
                )),
                "{help}"
            );
        }
    }

    #[test]
    fn base_cycles_are_reported() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "a.toml", "base = \"b.toml\"");
        let b = write(dir.path(), "b.toml", "base = \"a.toml\"");
        assert!(matches!(load(&b, &[]), Err(ConfigError::BaseCycle { .. })));
    }

    #[test]
    fn frame_ranges_parse_and_print() {
        let r: FrameRange = "10:20:5".parse().unwrap();
        assert_eq!(r.frames(), vec![10, 15]);
        assert_eq!(r.to_string(), "10:20:5");
        assert!("5".parse::<FrameRange>().is_err());
        assert!("0:10:0".parse::<FrameRange>().is_err());
    }
}

//! Experiment configuration: TOML files with inheritance (`base = "…"`), command-line overrides
//! (`--set section.key=value`) and validation whose errors name the key and the allowed values.

use std::path::{Path, PathBuf};

use anerf_core::model::ModelConfig;
use anerf_core::DeviceChoice;
use anerf_core::InvalidValue;
use anerf_data::prepare::ImageScale;
pub use anerf_data::MaskEdges;
use serde::{Deserialize, Serialize};
use toml::{Table, Value};

mod defaults;
mod folder;
mod frames;
mod presets;
mod sources;
mod table;
#[cfg(test)]
mod tests;
mod validate;

pub use defaults::{LearningRates, DEFAULT_PRESET};
pub use folder::{folder_table, REFINED_FRAMES_PER_STEP, REFINED_SILHOUETTE_WEIGHT};
pub use frames::FrameRange;
pub use presets::{preset_help, preset_schedule, preset_short_help, PresetSchedule};
pub use sources::{
    apply_override, assemble, demo_table, from_table, load, load_with, with_overrides, Settings,
    DEMO_CONFIG,
};
pub use table::merge;
pub use validate::validate;

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
    /// A value outside what its key accepts.
    #[error("invalid config: {0}")]
    Invalid(#[from] InvalidValue),
    /// A value of the wrong type or shape for its key (serde's message), or an unknown key.
    #[error("invalid config: {key}: {message}")]
    Malformed { key: String, message: String },
    /// A value where a section is expected (`model = 5`; `--set dataset=1 --set dataset.root=x`); `what`
    /// says what was being set.
    #[error("invalid config: `{key}` is not a section ({what})")]
    NotASection { key: String, what: String },
    #[error("invalid config: dataset.{key}: cannot resolve {path} to an absolute path: {source}")]
    Unresolvable {
        key: &'static str,
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Dataset layouts anerf reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetFormat {
    /// ZJU-MoCap (also the layout `anerf synth` writes).
    ZjuMocap,
    /// The processed Human3.6M layout of the authors.
    H36m,
    /// An EasyMocap capture folder (`intri.yml`, `extri.yml`, images, masks, SMPL fits); needs
    /// `dataset.body_model`.
    Easymocap,
}

impl DatasetFormat {
    /// The loader's name for the layout.
    pub fn kind(self) -> anerf_data::DatasetKind {
        match self {
            DatasetFormat::ZjuMocap => anerf_data::DatasetKind::ZjuMocap,
            DatasetFormat::H36m => anerf_data::DatasetKind::H36m,
            DatasetFormat::Easymocap => anerf_data::DatasetKind::EasyMocap,
        }
    }

    /// The config's name for a layout the loaders detected (the synthetic layout is ZJU-MoCap's).
    pub fn of(kind: anerf_data::DatasetKind) -> Self {
        match kind {
            anerf_data::DatasetKind::H36m => DatasetFormat::H36m,
            anerf_data::DatasetKind::EasyMocap => DatasetFormat::Easymocap,
            anerf_data::DatasetKind::ZjuMocap | anerf_data::DatasetKind::Synthetic => {
                DatasetFormat::ZjuMocap
            }
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
    pub ratio: ImageScale,
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
    /// A body-model file (SMPL-family `.npz` or `.pkl`): the body of an EasyMocap capture, or the weights
    /// and faces of a ZJU folder whose `lbs/` has none.
    #[serde(default)]
    pub body_model: Option<PathBuf>,
    /// EasyMocap: the id of the person to train on (default: the only person of the fits).
    #[serde(default)]
    pub person: Option<i64>,
    /// EasyMocap: the mask folder inside the capture (default `mask/`, else `mask-schp/`).
    #[serde(default)]
    pub masks: Option<String>,
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
    /// What the loader needs besides the folder.
    pub fn load_options(&self) -> anerf_data::LoadOptions {
        anerf_data::LoadOptions {
            body_model: self.body_model.clone(),
            person: self.person,
            masks: self.masks.clone(),
        }
    }

    /// Resolves `root`, `cache` and `body_model` against the working directory, as written into a run's
    /// config, so that the run can be evaluated from any folder.
    pub fn make_paths_absolute(&mut self) -> Result<(), ConfigError> {
        let absolute = |key: &'static str, p: &Path| {
            std::path::absolute(p).map_err(|source| ConfigError::Unresolvable {
                key,
                path: p.to_path_buf(),
                source,
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
    /// Stage 1: how many training views of the step's frame its rays are drawn from, split evenly (all of
    /// them where there are fewer; 1: one image a step, as the reference). Several views give a pose
    /// refinement's corrections a multi-view gradient every time their frame is drawn, and every step's
    /// rays more variety (the `fast` preset draws 4).
    #[serde(default = "one")]
    pub views_per_step: usize,
    /// Stage 1: how many distinct training frames a step's rays are drawn from, split evenly, each with
    /// `views_per_step` views (all of them where there are fewer; 1: one frame a step, as the reference).
    /// Several frames let a pose refinement's per-frame corrections move on more steps, and give the
    /// canonical field rays of more poses a step.
    #[serde(default = "one")]
    pub frames_per_step: usize,
    pub lr: f64,
    pub lr_final: f64,
    pub schedule: LrSchedule,
    /// Gradient values are clipped to ±this (the code uses 40); 0 disables clipping.
    pub grad_clip: f32,
    pub checkpoint_every: usize,
    pub validate_every: usize,
    pub log_every: usize,
    /// Stage 1: what is drawn from the 5×5 band around mask edges: `backdrop` (the default: against the
    /// image over each training camera's static background, estimated from the training frames, without
    /// the band's labels except where a pixel outside the mask shows that background, for captures from
    /// cameras that stand still), `robust` (with the mask's labels,
    /// each band ray's loss made robust by [`Self::edge_scale`]), `train` (with the mask's labels and the
    /// plain loss: exact masks) or `skip` (never: the reference's `erode_edge`, kept by the paper's
    /// experiment configs). Earlier versions' boolean (`skip_mask_edges`) is
    /// read as `skip` (true) or `train` (false).
    #[serde(deserialize_with = "MaskEdges::deserialize_compatible")]
    pub mask_edges: MaskEdges,
    /// Stage 1: share of a step's rays drawn where the training image has detail, in proportion to its
    /// colours' gradient magnitude (the silhouette's and the texture's edges, where a body or a fit off
    /// by a fraction of a pixel shows); the rest as the reference draws them. 0 (the default) draws none.
    #[serde(default)]
    pub detail_fraction: f32,
    /// Stage 1, `mask_edges = "robust"`: a band ray's loss is the pseudo-Huber `2c²(√(1 + e/c²) − 1)` of
    /// its squared error `e` (colour plus weighted silhouette) with this scale `c`: about `e` for errors
    /// well below `c²`, growing as `2c·√e` above, so a band label the other views contradict pulls with a
    /// bounded force.
    pub edge_scale: f32,
    /// Stage 1: weight of the silhouette loss `mean((acc − m)²)`, the rendered opacity against the mask
    /// (1 on body pixels, 0 elsewhere); 0 disables it (the paper fits colours alone).
    pub mask_weight: f32,
    /// Stage 1: weight of the hard-surface prior, each ray's `Σ_k α_k (1 − α_k)` over its samples' opacities
    /// (mean over rays): it pushes every sample to empty or opaque, so that a faint shell around the body,
    /// which explains one view's dilated mask labels while the other views see through it, cannot form;
    /// 0 disables it.
    #[serde(default)]
    pub hard_surface_weight: f32,
    /// Weight of `mean(F²)`, the penalty on the blend-weight residual that keeps the neural weights at the
    /// body model's where the data does not ask otherwise; 0 disables it.
    pub residual_weight: f32,
    /// Stop early once the loss, averaged over each `log_every` window, has not fallen by
    /// `plateau_tolerance` (relative) below its best for this many steps; 0 never stops early.
    pub plateau_steps: usize,
    /// Relative improvement that counts as progress for `plateau_steps`.
    pub plateau_tolerance: f32,
}

/// `[eval]`; a key it leaves out takes [`EvalConfig::default`]'s value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Every n-th frame of a split is evaluated (30 on ZJU-MoCap, 6 on H36M).
    pub frame_interval: usize,
    /// Rays rendered per chunk.
    pub chunk: usize,
    /// A rendered ray stops once its transmittance falls below this (early ray termination): the colour and
    /// opacity it would still gather are smaller. 0 shades every sample that survives culling.
    pub termination: f32,
}

impl Default for EvalConfig {
    /// ZJU-MoCap's frame interval, 4,096 rays per chunk, and rays stopped at a transmittance of 1e-4 (a
    /// 40th of an 8-bit grey level).
    fn default() -> Self {
        Self {
            frame_interval: 30,
            chunk: 4096,
            termination: 1e-4,
        }
    }
}

/// A whole experiment, as resolved from its files and overrides.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentConfig {
    pub name: String,
    /// Seeds the model's initialisation and the ray sampler (default 0).
    #[serde(default)]
    pub seed: u64,
    /// The backend that runs (default `flex`, the CPU); `--device` sets it.
    #[serde(default)]
    pub device: DeviceChoice,
    pub dataset: DatasetConfig,
    pub model: ModelConfig,
    pub train: StageConfig,
    pub animate: StageConfig,
    #[serde(default)]
    pub eval: EvalConfig,
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

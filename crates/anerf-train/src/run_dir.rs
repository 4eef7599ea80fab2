//! The folder of one run: resolved config, checkpoints, metrics log, renders, evaluation and meshes.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::Serialize;

use crate::config::{self, ExperimentConfig};

/// Paths inside `runs/<experiment>/`.
#[derive(Debug, Clone)]
pub struct RunDir {
    pub root: PathBuf,
}

impl RunDir {
    /// Opens (and creates) a run folder.
    pub fn create(root: &Path) -> Result<Self> {
        fs::create_dir_all(root)
            .with_context(|| format!("creating run folder {}", root.display()))?;
        Ok(Self {
            root: root.to_path_buf(),
        })
    }

    /// Opens an existing run folder (one holding `config.toml`).
    pub fn open(root: &Path) -> Result<Self> {
        let dir = Self {
            root: root.to_path_buf(),
        };
        if !dir.config_path().is_file() {
            anyhow::bail!("{} is not a run folder: it has no config.toml (expected the output of `anerf train`)", root.display());
        }
        Ok(dir)
    }

    pub fn config_path(&self) -> PathBuf {
        self.root.join("config.toml")
    }

    pub fn checkpoints(&self) -> PathBuf {
        self.root.join("checkpoints")
    }

    pub fn metrics_log(&self) -> PathBuf {
        self.root.join("metrics.jsonl")
    }

    pub fn renders(&self) -> PathBuf {
        self.root.join("renders")
    }

    pub fn eval(&self) -> PathBuf {
        self.root.join("eval")
    }

    pub fn meshes(&self) -> PathBuf {
        self.root.join("meshes")
    }

    /// Writes the resolved config (atomically).
    pub fn write_config(&self, config: &ExperimentConfig) -> Result<()> {
        write_atomic(&self.config_path(), config::to_toml(config).as_bytes())
    }

    /// Reads the resolved config back.
    pub fn read_config(&self) -> Result<ExperimentConfig> {
        let path = self.config_path();
        let text =
            fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let table = toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
        config::from_table(table).with_context(|| format!("in {}", path.display()))
    }
}

/// Writes `bytes` to `path` atomically ([`anerf_data::atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    anerf_data::atomic::write_bytes(path, bytes)
        .with_context(|| format!("writing {}", path.display()))
}

/// Appends JSON lines to `metrics.jsonl`.
pub struct MetricsLog {
    path: PathBuf,
}

impl MetricsLog {
    /// Opens the log; when resuming from `step`, drops lines of the same stage written after it so that the
    /// log reads as if the run had never stopped.
    pub fn open(path: PathBuf, stage: u8, resume_step: Option<usize>) -> Result<Self> {
        if let (Some(step), true) = (resume_step, path.is_file()) {
            let text =
                fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
            let kept: Vec<&str> = text
                .lines()
                .filter(|line| {
                    let v: serde_json::Value = serde_json::from_str(line).unwrap_or_default();
                    let same_stage = v["stage"].as_u64() == Some(stage as u64);
                    !(same_stage && v["step"].as_u64().is_some_and(|s| s as usize > step))
                })
                .collect();
            let mut out = kept.join("\n");
            if !out.is_empty() {
                out.push('\n');
            }
            write_atomic(&path, out.as_bytes())?;
        }
        Ok(Self { path })
    }

    /// Appends one record.
    pub fn append(&self, record: &impl Serialize) -> Result<()> {
        let mut f = fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .with_context(|| format!("opening {}", self.path.display()))?;
        let line = serde_json::to_string(record)?;
        writeln!(f, "{line}").with_context(|| format!("appending to {}", self.path.display()))
    }
}

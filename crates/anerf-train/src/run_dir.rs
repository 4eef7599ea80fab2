//! The folder of one run: resolved config, checkpoints, metrics log, renders, evaluation and meshes.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use anerf_data::atomic::write_bytes;
use anyhow::{Context, Result};
use serde::Serialize;

use crate::config::{self, ExperimentConfig};
use crate::stage::Stage;

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

    /// True when `root` holds a run's `config.toml`.
    pub fn looks_like_run(root: &Path) -> bool {
        root.join("config.toml").is_file()
    }

    /// Opens an existing run folder (one holding `config.toml`).
    pub fn open(root: &Path) -> Result<Self> {
        let dir = Self {
            root: root.to_path_buf(),
        };
        if !Self::looks_like_run(root) {
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

    /// Stored motion fits (`anerf animate --motion`), one folder per motion.
    pub fn motions(&self) -> PathBuf {
        self.root.join("motions")
    }

    /// Training-curve figures ([`crate::plots`]).
    pub fn plots(&self) -> PathBuf {
        self.root.join("plots")
    }

    /// The training frames' body fits as given and as refined (`model.pose_refinement`), written after stage 1.
    pub fn refined_poses(&self) -> PathBuf {
        self.root.join("refined_poses.json")
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

    /// The avatar baked into Gaussians (`anerf bake`).
    pub fn baked(&self) -> PathBuf {
        self.root.join("baked")
    }

    /// Exported avatars (`anerf export`).
    pub fn exports(&self) -> PathBuf {
        self.root.join("export")
    }

    /// Writes the resolved config (atomically).
    pub fn write_config(&self, config: &ExperimentConfig) -> Result<()> {
        Ok(write_bytes(
            &self.config_path(),
            config::to_toml(config).as_bytes(),
        )?)
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

/// Appends JSON lines to `metrics.jsonl`, each line whole.
pub struct MetricsLog {
    path: PathBuf,
}

impl MetricsLog {
    /// Opens the log of a stage that starts (or resumes) at `step`: drops lines of the same stage written
    /// after it, so that the log reads as if the run had never stopped, and any line a fault left half
    /// written or unreadable (named on stderr).
    pub fn open(path: PathBuf, stage: Stage, step: usize) -> Result<Self> {
        if path.is_file() {
            let text =
                fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
            let mut kept = String::with_capacity(text.len());
            let mut broken = 0;
            for line in text.split_inclusive('\n') {
                let record = line
                    .strip_suffix('\n')
                    .and_then(|l| serde_json::from_str::<serde_json::Value>(l).ok());
                let Some(v) = record else {
                    broken += 1;
                    continue;
                };
                let later = v["stage"].as_u64() == Some(stage.number() as u64)
                    && v["step"].as_u64().is_some_and(|s| s as usize > step);
                if !later {
                    kept.push_str(line);
                }
            }
            if broken > 0 {
                eprintln!(
                    "warning: {}: dropped {broken} half-written or unreadable line(s)",
                    path.display()
                );
            }
            if kept.len() != text.len() {
                write_bytes(&path, kept.as_bytes())?;
            }
        }
        Ok(Self { path })
    }

    /// Appends one record as a single write; when that write fails (a full disk) the file is cut back to
    /// its previous length, so no partial line stays behind.
    pub fn append(&self, record: &impl Serialize) -> Result<()> {
        let mut f = fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&self.path)
            .with_context(|| format!("opening {}", self.path.display()))?;
        let before = f
            .metadata()
            .with_context(|| format!("reading the length of {}", self.path.display()))?
            .len();
        let mut line = serde_json::to_string(record)?;
        line.push('\n');
        if let Err(e) = f.write_all(line.as_bytes()) {
            let _ = f.set_len(before);
            return Err(e).with_context(|| format!("appending to {}", self.path.display()));
        }
        Ok(())
    }
}

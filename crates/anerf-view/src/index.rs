//! What the viewer page shows of a run, read afresh from the run folder on every request: the config, the
//! last logged step, the curves, every evaluation with its images, the videos and the exported avatars.
//! Every file is named by its URL under [`RUN_PREFIX`], with its size and modification time in the query so
//! that the page fetches a file again exactly when it changed.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use anerf_eval::report::{read_records_json, read_summary_json, EvalSplit, SavedImages};
use anerf_eval::silhouette::SilhouetteMetrics;
use anyhow::{Context, Result};
use percent_encoding::{AsciiSet, NON_ALPHANUMERIC};
use serde::Serialize;

use super::inside::{inside_run, Outside};
use anerf_train::plots::{has_stage, read_log};
use anerf_train::run_dir::RunDir;

/// URL prefix of the run folder's own files.
pub const RUN_PREFIX: &str = "/run/";

/// Characters escaped in a URL's path segment (file names keep `-`, `_` and `.` readable).
const SEGMENT: &AsciiSet = &NON_ALPHANUMERIC.remove(b'-').remove(b'_').remove(b'.');

/// The page's data (`/api/run`).
#[derive(Debug, Serialize)]
pub struct RunIndex {
    /// The experiment's name (the config's `name`, else the folder's).
    pub name: String,
    /// The run folder as given to `anerf view`.
    pub folder: String,
    /// Changes whenever a file the page shows changes; the page polls it to refresh.
    pub version: String,
    /// `config.toml` as written.
    pub config: String,
    /// The last logged step, if any.
    pub last: Option<serde_json::Value>,
    /// Seconds since the log was last written (a run that is training writes it every few seconds).
    pub log_age_s: Option<f64>,
    /// Curves drawn from the current log, one figure per logged stage.
    pub curves: Vec<String>,
    pub evaluations: Vec<Evaluation>,
    pub videos: Vec<Video>,
    /// Exported `.glb` files.
    pub avatars: Vec<String>,
    /// The baked avatar exported as Gaussians (`anerf export --format ply`), if it is.
    pub splats: Option<SplatFiles>,
}

/// The files of `<run>/export/splats/` a splat viewer that skins reads.
#[derive(Debug, Serialize)]
pub struct SplatFiles {
    /// The canonical Gaussians, 3DGS's PLY layout.
    pub ply: String,
    /// Each Gaussian's four joints and weights.
    pub skin: String,
    /// The frames' joint matrices and the dataset's cameras.
    pub motion: String,
}

impl SplatFiles {
    /// The splat export of `run`, when all three files are there.
    fn read(run: &RunDir, stamps: &mut Stamps) -> Option<Self> {
        let dir = run.exports().join("splats");
        let mut url = |name: &str| {
            let path = dir.join(name);
            inside_run(run, &path).ok()?;
            stamps.add(&path);
            Some(file_url(run, &path))
        };
        Some(Self {
            ply: url("avatar.ply")?,
            skin: url("skin.json")?,
            motion: url("motion.json")?,
        })
    }
}

/// One evaluation split (`<run>/eval/<split>/`).
#[derive(Debug, Serialize)]
pub struct Evaluation {
    pub split: String,
    pub psnr: Option<f64>,
    pub ssim: Option<f64>,
    /// Where the error lies against the true silhouette (evaluations that measured it).
    pub silhouette: Option<SilhouetteMetrics>,
    /// Per-view bar charts, where written.
    pub charts: Vec<String>,
    pub images: Vec<EvalImage>,
}

/// One evaluated image: its metrics and its saved prediction, ground truth and error map.
#[derive(Debug, Serialize)]
pub struct EvalImage {
    pub frame: usize,
    pub view: usize,
    pub psnr: f64,
    pub ssim: f64,
    pub pred: Option<String>,
    pub gt: Option<String>,
    pub error: Option<String>,
}

/// A rendered clip (`<run>/renders/*.gif|mp4`).
#[derive(Debug, Serialize)]
pub struct Video {
    pub name: String,
    pub url: String,
    /// `gif` or `mp4`.
    pub kind: String,
}

impl RunIndex {
    /// Reads the index of `run`.
    pub fn read(run: &RunDir) -> Result<Self> {
        let mut stamps = Stamps::default();
        let config_path = run.config_path();
        let config = inside_run(run, &config_path)
            .map_err(|why| anyhow::anyhow!("{} {why}", config_path.display()))
            .and_then(|p| {
                std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))
            })?;
        stamps.add(&config_path);
        let log = run.metrics_log();
        stamps.add(&log);
        let lines = match inside_run(run, &log) {
            Ok(_) => read_log(run)?,
            Err(Outside::Missing) => Vec::new(),
            Err(why) => anyhow::bail!("{} {why}", log.display()),
        };
        let log_stamp = Stamps::of(&log);
        let curves = [1u64, 2]
            .into_iter()
            .filter(|&s| has_stage(&lines, s))
            .map(|s| format!("/live/stage{s}.svg?v={log_stamp}"))
            .collect();
        let log_age_s = std::fs::metadata(&log)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| SystemTime::now().duration_since(t).ok())
            .map(|age| age.as_secs_f64());
        let name = toml::from_str::<toml::Table>(&config)
            .ok()
            .and_then(|t| t.get("name")?.as_str().map(str::to_string))
            .unwrap_or_else(|| file_stem(&run.root));
        let evaluations = evaluations(run, &mut stamps)?;
        let videos = files_with(run, &run.renders(), &["gif", "mp4"], &mut stamps)
            .into_iter()
            .map(|p| Video {
                name: file_stem(&p),
                kind: p.extension().unwrap().to_string_lossy().into_owned(),
                url: file_url(run, &p),
            })
            .collect();
        let avatars = files_with(run, &run.exports(), &["glb"], &mut stamps)
            .iter()
            .map(|p| file_url(run, p))
            .collect();
        let splats = SplatFiles::read(run, &mut stamps);
        Ok(Self {
            name,
            folder: run.root.display().to_string(),
            version: stamps.digest(),
            config,
            last: lines.last().cloned(),
            log_age_s,
            curves,
            evaluations,
            videos,
            avatars,
            splats,
        })
    }
}

fn evaluations(run: &RunDir, stamps: &mut Stamps) -> Result<Vec<Evaluation>> {
    let mut out = Vec::new();
    for split in EvalSplit::ALL {
        let dir = run.eval().join(split.to_string());
        let records_path = dir.join("metrics.json");
        let Ok(records_file) = inside_run(run, &records_path) else {
            continue;
        };
        stamps.add(&records_path);
        let records = read_records_json(&records_file)?;
        let summary = inside_run(run, &dir.join("summary.json"))
            .ok()
            .and_then(|p| read_summary_json(&p).ok());
        let url_if_file = |p: PathBuf| inside_run(run, &p).is_ok().then(|| file_url(run, &p));
        let images = records
            .iter()
            .map(|r| {
                let saved = SavedImages::new(&dir, &r.stem());
                EvalImage {
                    frame: r.frame.0,
                    view: r.view.0,
                    psnr: r.psnr,
                    ssim: r.ssim,
                    pred: url_if_file(saved.pred),
                    gt: url_if_file(saved.gt),
                    error: url_if_file(saved.error),
                }
            })
            .collect();
        let charts = ["psnr_by_view.svg", "ssim_by_view.svg"]
            .into_iter()
            .filter_map(|name| url_if_file(dir.join(name)))
            .collect();
        out.push(Evaluation {
            split: split.to_string(),
            psnr: summary.map(|s| s.psnr),
            ssim: summary.map(|s| s.ssim),
            silhouette: summary.and_then(|s| s.silhouette),
            charts,
            images,
        });
    }
    Ok(out)
}

/// The regular files of `dir` inside the run (not recursive) whose extension is one of `extensions`, sorted by name.
fn files_with(run: &RunDir, dir: &Path, extensions: &[&str], stamps: &mut Stamps) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| inside_run(run, p).is_ok())
        .filter(|p| {
            p.extension()
                .is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
        })
        .collect();
    files.sort();
    for f in &files {
        stamps.add(f);
    }
    files
}

fn file_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The URL of a file inside the run folder: [`RUN_PREFIX`] and its relative path, each segment
/// percent-encoded, and the file's stamp as `?v=`.
fn file_url(run: &RunDir, path: &Path) -> String {
    let rel = path.strip_prefix(&run.root).unwrap_or(path);
    let segments: Vec<String> = rel
        .components()
        .map(|c| {
            percent_encoding::utf8_percent_encode(&c.as_os_str().to_string_lossy(), SEGMENT)
                .to_string()
        })
        .collect();
    format!("{RUN_PREFIX}{}?v={}", segments.join("/"), Stamps::of(path))
}

/// Sizes and modification times of the files an index was read from.
#[derive(Default)]
struct Stamps(DefaultHasher);

impl Stamps {
    fn add(&mut self, path: &Path) {
        path.hash(&mut self.0);
        if let Ok(meta) = std::fs::metadata(path) {
            meta.len().hash(&mut self.0);
            meta.modified().ok().hash(&mut self.0);
        }
    }

    /// The stamp of one file.
    fn of(path: &Path) -> String {
        let mut one = Self::default();
        one.add(path);
        one.digest()
    }

    fn digest(&self) -> String {
        format!("{:016x}", self.0.finish())
    }
}

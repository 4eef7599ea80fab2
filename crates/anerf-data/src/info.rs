//! `anerf info`: validates a dataset folder and summarises it, listing every problem found.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::formats;
use crate::loaders::check::{Checker, Problem};
use crate::loaders::{self, detect_kind, LoadOptions};
use crate::splits::{reference_split, Split};
use crate::subject::DatasetKind;

/// What to inspect.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct InspectOptions {
    /// The layout; guessed from the path when `None`.
    pub kind: Option<DatasetKind>,
    pub load: LoadOptions,
}

/// An optional file or folder and whether it exists.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OptionalFile {
    pub name: &'static str,
    pub present: bool,
}

/// The summary and every problem of a dataset folder.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Report {
    pub root: PathBuf,
    pub kind: DatasetKind,
    pub name: Option<String>,
    pub cameras: Option<usize>,
    pub frames: Option<usize>,
    /// Distinct image sizes `(width, height)` and how many cameras have each.
    pub image_sizes: Vec<((u32, u32), usize)>,
    pub joints: Option<usize>,
    pub vertices: Option<usize>,
    pub faces: Option<usize>,
    /// The range of `{i}` in `new_params/{i}.npy` (ZJU 313/315 start at 1).
    pub file_indices: Option<(usize, usize)>,
    pub optional_files: Vec<OptionalFile>,
    pub split: Option<Split>,
    pub notes: Vec<String>,
    pub problems: Vec<Problem>,
}

impl Report {
    /// True when a problem stops the dataset from loading.
    pub fn has_fatal(&self) -> bool {
        self.problems.iter().any(|p| p.fatal)
    }
}

/// Inspects the dataset at `root`: reads everything a loader reads, carrying on past problems.
pub fn inspect(root: &Path, options: &InspectOptions) -> Report {
    let kind = options.kind.unwrap_or_else(|| detect_kind(root));
    let mut ck = Checker::collecting();
    // In collecting mode `read` records problems instead of returning them.
    let subject = loaders::read(root, kind, &options.load, &mut ck).unwrap_or(None);
    let (problems, notes) = ck.finish();
    let mut report = Report {
        root: root.to_path_buf(),
        kind,
        name: None,
        cameras: None,
        frames: None,
        image_sizes: Vec::new(),
        joints: None,
        vertices: None,
        faces: None,
        file_indices: None,
        optional_files: optional_files(kind)
            .iter()
            .map(|&name| OptionalFile {
                name,
                present: root.join(name).exists(),
            })
            .collect(),
        split: None,
        notes,
        problems,
    };
    match subject {
        Some(s) => {
            report.image_sizes = loaders::tally(s.cameras.iter().map(|c| (c.width, c.height)));
            report.split = reference_split(kind, &s.name, s.cameras.len(), s.frames.len());
            report.name = Some(s.name);
            report.cameras = Some(s.cameras.len());
            report.frames = Some(s.frames.len());
            report.joints = Some(s.body.skeleton.num_joints());
            report.vertices = Some(s.body.canonical_vertices.len());
            report.faces = Some(s.body.faces.len());
            let idx = s.frames.iter().map(|f| f.file_index);
            report.file_indices = idx.clone().min().zip(idx.max());
        }
        None => partial_summary(root, &mut report),
    }
    report
}

/// The optional files and folders of a layout, to show which are there.
fn optional_files(kind: DatasetKind) -> &'static [&'static str] {
    match kind {
        DatasetKind::EasyMocap => &[
            "mask",
            "mask-schp",
            loaders::easymocap::FIT_FOLDERS[0],
            loaders::easymocap::FIT_FOLDERS[1],
        ],
        _ => &[
            "new_params",
            "new_vertices",
            "params",
            "vertices",
            "mask_cihp",
            "mask",
            "lbs/weights.npy",
            "lbs/faces.npy",
            "lbs/bigpose_vertices.npy",
            "lbs/tbw.npy",
            "lbs/bweights",
        ],
    }
}

/// What can still be counted when the dataset does not load.
fn partial_summary(root: &Path, report: &mut Report) {
    if report.kind == DatasetKind::EasyMocap {
        let names = formats::opencv_yaml::FileStorage::read(&root.join("intri.yml"))
            .ok()
            .and_then(|fs| fs.strings("names").ok().flatten());
        report.cameras = names.as_ref().map(Vec::len);
        report.frames = names
            .and_then(|n| std::fs::read_dir(root.join("images").join(n.first()?)).ok())
            .map(|entries| entries.count());
        return;
    }
    if let Ok(annots) = formats::read_npy_object(&root.join("annots.npy")) {
        report.cameras = annots
            .get("cams")
            .and_then(|c| c.get("K"))
            .and_then(|k| k.as_seq().map(<[_]>::len));
        report.frames = annots.get("ims").and_then(|i| i.as_seq().map(<[_]>::len));
    }
    let rows = |name: &str| {
        formats::read_npy(&root.join("lbs").join(name))
            .ok()
            .and_then(|a| a.shape().first().copied())
    };
    report.joints = rows("joints.npy");
    report.vertices = rows("tvertices.npy");
    report.faces = rows("faces.npy");
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let opt = |v: Option<usize>| v.map_or("?".to_string(), |n| n.to_string());
        writeln!(
            f,
            "{} ({:?}{})",
            self.root.display(),
            self.kind,
            self.name
                .as_ref()
                .map_or(String::new(), |n| format!(", {n}"))
        )?;
        writeln!(
            f,
            "  cameras: {}   frames: {}",
            opt(self.cameras),
            opt(self.frames)
        )?;
        if !self.image_sizes.is_empty() {
            let sizes: Vec<String> = self
                .image_sizes
                .iter()
                .map(|((w, h), n)| format!("{w}×{h} ({n} cameras)"))
                .collect();
            writeln!(f, "  image sizes: {}", sizes.join(", "))?;
        }
        writeln!(
            f,
            "  skeleton: {} joints   body: {} vertices, {} faces",
            opt(self.joints),
            opt(self.vertices),
            opt(self.faces)
        )?;
        if let Some((a, b)) = self.file_indices {
            writeln!(f, "  params file indices: {a}..={b}")?;
        }
        let present: Vec<&str> = self
            .optional_files
            .iter()
            .filter(|o| o.present)
            .map(|o| o.name)
            .collect();
        let absent: Vec<&str> = self
            .optional_files
            .iter()
            .filter(|o| !o.present)
            .map(|o| o.name)
            .collect();
        writeln!(f, "  present: {}", present.join(", "))?;
        writeln!(f, "  absent: {}", absent.join(", "))?;
        if let Some(s) = &self.split {
            let r = |r: &crate::splits::FrameRange| match r.frames().last() {
                Some(last) => format!(
                    "{}..={} step {} ({} frames)",
                    r.start, last, r.step, r.count
                ),
                None => "none".into(),
            };
            writeln!(
                f,
                "  train views {:?}, test views {:?}",
                s.train_views, s.test_views
            )?;
            writeln!(
                f,
                "  train frames {}; novel-pose frames {}",
                r(&s.train_frames),
                r(&s.novel_pose_frames)
            )?;
        }
        if self.problems.is_empty() {
            writeln!(f, "  no problems found")?;
        }
        for p in &self.problems {
            writeln!(f, "  {p}")?;
        }
        Ok(())
    }
}

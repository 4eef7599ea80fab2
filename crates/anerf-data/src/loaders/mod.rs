//! Loaders from the authors' on-disk layouts (docs/REFERENCE.md §1) to one [`Subject`]. ZJU-MoCap and the
//! processed Human3.6M share the schema (`annots.npy`, image folders, `mask_cihp/`/`mask/`,
//! `new_params/`, `new_vertices/`, `lbs/`) and differ in a few rules captured by [`DatasetKind`].

mod annots;
pub mod check;
pub mod easymocap;
mod image_files;
mod lbs;
pub(crate) mod poses;

use std::path::{Path, PathBuf};

use anerf_core::geometry::Camera;
use anerf_core::FrameId;
use serde::{Deserialize, Serialize};

pub use check::Problem;
pub(crate) use image_files::tally;
pub use poses::{pose_files, read_pose_file};

use self::annots::{FramePaths, RawCamera};
use self::check::Checker;
use self::image_files::MaskRule;
use crate::error::DataError;
use crate::formats;
use crate::paths::Folder;
use crate::subject::{read_posed_vertices, DatasetKind, FrameRecord, PosedVertices, Subject};

/// What a loader needs besides the dataset folder.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LoadOptions {
    /// A body-model file (SMPL-family `.npz`, or `.pkl` read by the restricted unpickler): the body of an
    /// EasyMocap capture, or the skinning weights and faces of a ZJU folder whose `lbs/` has no
    /// `weights.npy`/`faces.npy`.
    pub body_model: Option<PathBuf>,
    /// EasyMocap: the id of the person whose fits to use (default: the only person of the first fit).
    pub person: Option<i64>,
    /// EasyMocap: the mask folder inside the capture (default: `mask/`, else `mask-schp/`).
    pub masks: Option<String>,
}

/// Reads a ZJU-MoCap sequence folder (`…/CoreView_313`).
pub fn load_zju_mocap(root: &Path, options: &LoadOptions) -> Result<Subject, DataError> {
    load(root, DatasetKind::ZjuMocap, options)
}

/// Reads a processed Human3.6M subject folder (`…/S9/Posing`).
pub fn load_h36m(root: &Path, options: &LoadOptions) -> Result<Subject, DataError> {
    load(root, DatasetKind::H36m, options)
}

/// Reads a dataset folder of the given layout, stopping at the first problem.
pub fn load(root: &Path, kind: DatasetKind, options: &LoadOptions) -> Result<Subject, DataError> {
    let mut ck = Checker::fail_fast();
    let subject = read(root, kind, options, &mut ck)?;
    Ok(subject.expect("fail-fast reading returns a subject or an error"))
}

/// Guesses the layout: an EasyMocap capture has `intri.yml` and `extri.yml`; H36M folders are
/// `S<n>/<action>` or live under a folder named `h36m`.
pub fn detect_kind(root: &Path) -> DatasetKind {
    if easymocap::is_capture(root) {
        return DatasetKind::EasyMocap;
    }
    let lower = root.to_string_lossy().to_lowercase();
    let parent_is_subject = root
        .parent()
        .and_then(Path::file_name)
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.starts_with('S') && n[1..].parse::<u32>().is_ok());
    if lower.contains("h36m") || lower.contains("human36m") || parent_is_subject {
        DatasetKind::H36m
    } else {
        DatasetKind::ZjuMocap
    }
}

/// The subject's name: the folder name, or `S9` for H36M's `S9/Posing`.
fn subject_name(root: &Path, kind: DatasetKind) -> String {
    let name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
    match kind {
        DatasetKind::H36m => root.parent().and_then(name).or_else(|| name(root)),
        _ => name(root),
    }
    .unwrap_or_else(|| "subject".into())
}

/// Reads everything; with a collecting checker, carries on past problems (each file checked on its own)
/// and returns `None` when a complete subject could not be built.
pub(crate) fn read(
    root: &Path,
    kind: DatasetKind,
    options: &LoadOptions,
    ck: &mut Checker,
) -> Result<Option<Subject>, DataError> {
    if !root.is_dir() {
        ck.check::<()>(Err(DataError::Missing {
            path: root.to_path_buf(),
            what: "a dataset folder".into(),
        }))?;
        return Ok(None);
    }
    if kind == DatasetKind::EasyMocap {
        return easymocap::read(root, options, ck);
    }
    let body = lbs::read_body(root, options.body_model.as_deref(), ck)?;
    let annots_path = root.join("annots.npy");
    let Some(annots) = ck.check(formats::read_npy_object(&annots_path))? else {
        return Ok(None);
    };
    let raw = annots::read_cameras(&annots, &annots_path, ck)?;
    let cameras_listed = raw.as_ref().map(Vec::len);
    let Some(ims) = annots::read_image_lists(&annots, &annots_path, cameras_listed, ck)? else {
        return Ok(None);
    };
    let inside = Folder::new(root, "dataset folder");
    let mut sizes = None;
    let mut cameras = None;
    if let Some(raw) = &raw {
        let folders = ck.check(check_camera_folders(root, &annots_path, raw.len(), &ims))?;
        note_unlisted_camera_folders(root, &ims, ck);
        if folders.is_some() {
            let found = image_files::check_images(root, &inside, raw, &ims, ck)?;
            cameras = build_cameras(&annots_path, raw, &found, ck)?;
            sizes = Some(found);
        }
    }
    let masks = image_files::resolve_masks(root, &inside, &MaskRule::of(kind), &ims, ck)?;
    if ck.whole_files() {
        image_files::check_masks(&inside, &masks, sizes.as_deref().unwrap_or(&[]), ck)?;
    }
    let params_dir = pick_dir(root, "new_params", "params", ck);
    let vertices_dir = pick_dir(root, "new_vertices", "vertices", ck);
    let num_joints = body.skeleton.as_ref().map(|s| s.num_joints());
    let num_vertices = body.canonical_vertices.as_ref().map(Vec::len);
    let mut frames = Vec::with_capacity(ims.len());
    for (f, (paths, masks)) in ims.iter().zip(&masks).enumerate() {
        let Some(Some(first)) = paths.as_ref().and_then(|p| p.first()) else {
            continue;
        };
        let Some(file_index) = ck.check(file_index(&annots_path, first))? else {
            continue;
        };
        let ppath = params_dir.join(format!("{file_index}.npy"));
        let pose = ck.check(poses::read_pose(&ppath, num_joints))?;
        let vpath = vertices_dir.join(format!("{file_index}.npy"));
        if !vpath.is_file() {
            ck.check::<()>(Err(DataError::Missing {
                path: vpath.clone(),
                what: format!("posed vertices of frame {f} (file index {file_index})"),
            }))?;
        } else if ck.whole_files() {
            ck.check(read_posed_vertices(&vpath, num_vertices))?;
        }
        if let (Some(pose), Some((images, masks))) =
            (pose, image_files::frame_files(root, paths, masks))
        {
            frames.push(FrameRecord {
                id: FrameId(f),
                file_index,
                images,
                masks,
                pose,
                vertices: PosedVertices::File(vpath),
            });
        }
    }
    let complete = frames.len() == ims.len();
    Ok(match (body.complete(), cameras) {
        (Some(body), Some(cameras)) if complete => Some(Subject {
            name: subject_name(root, kind),
            root: root.to_path_buf(),
            kind,
            cameras,
            frames,
            body,
            notes: ck.notes.clone(),
        }),
        _ => None,
    })
}

/// The image folder of each camera, from the first frame whose paths were all accepted.
fn camera_folders(root: &Path, ims: &[Option<FramePaths>]) -> Option<Vec<PathBuf>> {
    let frame = ims
        .iter()
        .flatten()
        .find(|f| f.iter().all(Option::is_some))?;
    Some(
        frame
            .iter()
            .flatten()
            .map(|p| {
                root.join(p)
                    .parent()
                    .map(Path::to_path_buf)
                    .unwrap_or_default()
            })
            .collect(),
    )
}

/// Each camera's images live in a folder of their own, which exists.
fn check_camera_folders(
    root: &Path,
    annots_path: &Path,
    cameras: usize,
    ims: &[Option<FramePaths>],
) -> Result<(), DataError> {
    let Some(folders) = camera_folders(root, ims) else {
        return Ok(()); // every frame has a refused path, each already reported
    };
    let mut distinct = folders.clone();
    distinct.sort();
    distinct.dedup();
    if distinct.len() != cameras {
        return Err(DataError::invalid(
            annots_path,
            format!(
                "the {cameras} cameras' images of a frame lie in {} distinct folders; expected one folder per camera",
                distinct.len()
            ),
        ));
    }
    if let Some(missing) = folders.iter().find(|d| !d.is_dir()) {
        return Err(DataError::Missing {
            path: missing.clone(),
            what: format!("an image folder named in {}", annots_path.display()),
        });
    }
    Ok(())
}

/// Camera folders on disk that `annots.npy` never names (harmless, but worth knowing: the reference only
/// ever uses the cameras listed in annots).
fn note_unlisted_camera_folders(root: &Path, ims: &[Option<FramePaths>], ck: &mut Checker) {
    let used = camera_folders(root, ims).unwrap_or_default();
    let Ok(entries) = std::fs::read_dir(root) else {
        return;
    };
    let mut unlisted: Vec<String> = entries
        .filter_map(Result::ok)
        .filter(|e| e.path().is_dir() && e.file_name().to_string_lossy().starts_with("Camera"))
        .filter(|e| !used.contains(&e.path()))
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    unlisted.sort();
    if !unlisted.is_empty() {
        ck.note(
            root,
            format!(
                "camera folders not listed in annots.npy (ignored): {}",
                unlisted.join(", ")
            ),
        );
    }
}

/// Cameras with their image size; `None` unless every camera could be built.
fn build_cameras(
    annots_path: &Path,
    raw: &[Option<RawCamera>],
    sizes: &[Option<image_files::Size>],
    ck: &mut Checker,
) -> Result<Option<Vec<Camera>>, DataError> {
    let mut cameras = Vec::with_capacity(raw.len());
    for (c, (r, size)) in raw.iter().zip(sizes).enumerate() {
        let (Some(r), Some((w, h))) = (r, size) else {
            return Ok(None);
        };
        let camera = Camera::from_rows(r.k, r.r, r.t, r.d, *w, *h)
            .map_err(|e| DataError::invalid(annots_path, format!("camera {c}: {e}")));
        match ck.check(camera)? {
            Some(camera) => cameras.push(camera),
            None => return Ok(None),
        }
    }
    Ok(Some(cameras))
}

/// `new_*` when present (what Animatable NeRF uses), else the older fits, with a note.
fn pick_dir(root: &Path, preferred: &str, fallback: &str, ck: &mut Checker) -> PathBuf {
    let p = root.join(preferred);
    if p.is_dir() || !root.join(fallback).is_dir() {
        return p;
    }
    ck.note(
        &p,
        format!(
            "{preferred}/ is missing; using the older {fallback}/ (fits without pose blend shapes)"
        ),
    );
    root.join(fallback)
}

/// The `{i}` of `new_params/{i}.npy`: the image's file stem as a number, or for ZJU-MoCap 313/315
/// (`CoreView_313_Camera_(1)_0001_….jpg`) the fourth `_`-separated field, which starts at 1.
fn file_index(annots_path: &Path, image: &str) -> Result<usize, DataError> {
    let stem = Path::new(image)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    stem.parse()
        .ok()
        .or_else(|| stem.split('_').nth(4).and_then(|s| s.parse().ok()))
        .ok_or_else(|| {
            DataError::invalid(
                annots_path,
                format!(
                    "cannot derive a frame file index from image {image:?} (expected a numeric name like \
                     000123.jpg or CoreView_313_Camera_(1)_0001_….jpg)"
                ),
            )
        })
}

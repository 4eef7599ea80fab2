//! Loaders from the authors' on-disk layouts (REFERENCE.md §1) to one [`Subject`]. ZJU-MoCap and the
//! processed Human3.6M share the schema (`annots.npy`, image folders, `mask_cihp/`/`mask/`,
//! `new_params/`, `new_vertices/`, `lbs/`) and differ in a few rules captured by [`DatasetKind`].

mod arrays;
pub mod check;
mod lbs;
mod poses;

use std::path::{Component, Path, PathBuf};

use anerf_core::geometry::Camera;
use anerf_core::FrameId;
use serde::{Deserialize, Serialize};

pub(crate) use arrays::points as finite_points;
pub use check::Problem;
pub use lbs::read_body_model_file;
pub use poses::{pose_files, read_pose_file};

use self::check::Checker;
use crate::error::DataError;
use crate::formats::{self, Value};
use crate::subject::{DatasetKind, FrameRecord, Subject};

/// What a loader needs besides the dataset folder.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LoadOptions {
    /// A body-model file (SMPL `.npz`, or `.pkl` read by the restricted unpickler) supplying skinning
    /// weights and faces when `lbs/` has no `weights.npy`/`faces.npy`.
    pub body_model: Option<PathBuf>,
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

/// Guesses the layout: H36M folders are `S<n>/<action>` or live under a folder named `h36m`.
pub fn detect_kind(root: &Path) -> DatasetKind {
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

/// Cameras (K, R, T in metres, D) as stored, before the image size is known.
struct RawCamera {
    k: [[f32; 3]; 3],
    r: [[f32; 3]; 3],
    t: [f32; 3],
    d: [f32; 5],
}

/// Reads everything; with a collecting checker, carries on past problems and returns `None` when a
/// complete subject could not be built.
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
    let body = lbs::read_body(root, options.body_model.as_deref(), ck)?;
    let annots_path = root.join("annots.npy");
    let annots = ck.check(formats::read_npy_object(&annots_path))?;
    let Some(annots) = annots else {
        return Ok(None);
    };
    let raw = ck.check(read_cameras(&annots, &annots_path))?;
    let ims = ck.check(read_image_lists(&annots, &annots_path))?;
    let (Some(raw), Some(ims)) = (raw, ims) else {
        return Ok(None);
    };
    let cams_ok = ck.check(check_camera_counts(root, &annots_path, raw.len(), &ims))?;
    note_unlisted_camera_folders(root, &ims, ck);
    let cameras = if cams_ok.is_some() {
        ck.check(build_cameras(root, &raw, &ims))?
    } else {
        None
    };
    if let Some(cameras) = &cameras {
        check_images(root, cameras, &ims, ck)?;
    }
    let masks = resolve_masks(root, kind, &ims, ck)?;
    let params_dir = pick_dir(root, "new_params", "params", ck);
    let vertices_dir = pick_dir(root, "new_vertices", "vertices", ck);
    let num_joints = body.as_ref().map(|b| b.skeleton.num_joints());
    let mut frames = Vec::with_capacity(ims.len());
    for (f, paths) in ims.iter().enumerate() {
        let Some(first) = paths.first() else { continue };
        let Some(file_index) = ck.check(file_index(&annots_path, first))? else {
            continue;
        };
        let ppath = params_dir.join(format!("{file_index}.npy"));
        let pose = match num_joints {
            Some(k) => ck.check(read_pose_file(&ppath, k))?,
            None => None,
        };
        let vpath = vertices_dir.join(format!("{file_index}.npy"));
        if !vpath.is_file() {
            ck.check::<()>(Err(DataError::Missing {
                path: vpath.clone(),
                what: format!("posed vertices of frame {f} (file index {file_index})"),
            }))?;
        }
        if let (Some(pose), Some(masks)) = (pose, &masks) {
            frames.push(FrameRecord {
                id: FrameId(f),
                file_index,
                images: paths.iter().map(|p| root.join(p)).collect(),
                masks: masks[f].clone(),
                pose,
                vertices: vpath,
            });
        }
    }
    let complete = frames.len() == ims.len();
    Ok(match (body, cameras) {
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

/// `annots['cams']`: K, D, R, T lists of equal length (T in millimetres → metres).
fn read_cameras(annots: &Value, path: &Path) -> Result<Vec<RawCamera>, DataError> {
    let cams = annots.get("cams").ok_or_else(|| {
        DataError::invalid(
            path,
            format!("has no 'cams' (keys: {})", annots.keys().join(", ")),
        )
    })?;
    let per_camera = |key: &str, sizes: &[usize]| -> Result<Vec<Vec<f64>>, DataError> {
        let v = cams
            .get(key)
            .ok_or_else(|| DataError::invalid(path, format!("cams has no '{key}'")))?;
        let items: Vec<Vec<f64>> = match v {
            Value::Array(a) if a.shape().len() >= 2 => {
                let n = a.shape()[0];
                let all = a.to_f64();
                let per = all.len() / n.max(1);
                all.chunks(per.max(1)).map(<[f64]>::to_vec).collect()
            }
            _ => v
                .as_seq()
                .ok_or_else(|| {
                    DataError::invalid(
                        path,
                        format!("cams['{key}'] is {}, expected a list of arrays", v.kind()),
                    )
                })?
                .iter()
                .map(|x| {
                    x.as_array().map(|a| a.to_f64()).ok_or_else(|| {
                        DataError::invalid(
                            path,
                            format!("cams['{key}'] holds {}, expected arrays", x.kind()),
                        )
                    })
                })
                .collect::<Result<_, _>>()?,
        };
        for (c, item) in items.iter().enumerate() {
            if !sizes.contains(&item.len()) {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "cams['{key}'][{c}] has {} numbers, expected {sizes:?}",
                        item.len()
                    ),
                ));
            }
            if item.iter().any(|x| !x.is_finite()) {
                return Err(DataError::invalid(
                    path,
                    format!("cams['{key}'][{c}] is not finite"),
                ));
            }
        }
        Ok(items)
    };
    let k = per_camera("K", &[9])?;
    let r = per_camera("R", &[9])?;
    let t = per_camera("T", &[3])?;
    let d = per_camera("D", &[4, 5, 8, 12, 14])?;
    if [r.len(), t.len(), d.len()].iter().any(|&n| n != k.len()) || k.is_empty() {
        return Err(DataError::invalid(
            path,
            format!(
                "cams lists {} K, {} R, {} T and {} D; expected one of each per camera",
                k.len(),
                r.len(),
                t.len(),
                d.len()
            ),
        ));
    }
    let m3 = |v: &[f64]| -> [[f32; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| v[3 * i + j] as f32))
    };
    Ok((0..k.len())
        .map(|c| RawCamera {
            k: m3(&k[c]),
            r: m3(&r[c]),
            t: std::array::from_fn(|i| (t[c][i] / 1000.0) as f32),
            // OpenCV's first five coefficients (k1, k2, p1, p2, k3); a 4-vector has no k3.
            d: std::array::from_fn(|i| d[c].get(i).copied().unwrap_or(0.0) as f32),
        })
        .collect())
}

/// `annots['ims'][f]['ims']`: one relative image path per camera, checked to stay inside the folder.
fn read_image_lists(annots: &Value, path: &Path) -> Result<Vec<Vec<String>>, DataError> {
    let ims = annots
        .get("ims")
        .and_then(Value::as_seq)
        .ok_or_else(|| DataError::invalid(path, "has no 'ims' list of frames"))?;
    if ims.is_empty() {
        return Err(DataError::invalid(path, "'ims' lists no frame"));
    }
    ims.iter()
        .enumerate()
        .map(|(f, frame)| {
            let list = frame.get("ims").and_then(Value::as_seq).ok_or_else(|| {
                DataError::invalid(path, format!("ims[{f}] has no 'ims' list of image paths"))
            })?;
            list.iter()
                .enumerate()
                .map(|(c, p)| {
                    let s = p.as_str().ok_or_else(|| {
                        DataError::invalid(
                            path,
                            format!("ims[{f}]['ims'][{c}] is {}, expected a path", p.kind()),
                        )
                    })?;
                    check_relative(&s).map_err(|why| {
                        DataError::invalid(
                            path,
                            format!("image path {s:?} (frame {f}, camera {c}) {why}"),
                        )
                    })?;
                    Ok(s)
                })
                .collect()
        })
        .collect()
}

/// Image paths must stay inside the dataset folder: relative, without `..`.
fn check_relative(p: &str) -> Result<(), &'static str> {
    let path = Path::new(p);
    if p.is_empty() {
        return Err("is empty");
    }
    for c in path.components() {
        match c {
            Component::ParentDir => return Err("leaves the dataset folder through '..'"),
            Component::RootDir | Component::Prefix(_) => {
                return Err("is absolute; expected a path relative to the dataset folder")
            }
            _ => {}
        }
    }
    Ok(())
}

/// Every frame lists one image per camera, and each camera's images live in their own folder.
fn check_camera_counts(
    root: &Path,
    annots_path: &Path,
    cameras: usize,
    ims: &[Vec<String>],
) -> Result<(), DataError> {
    for (f, paths) in ims.iter().enumerate() {
        if paths.len() != cameras {
            return Err(DataError::invalid(
                annots_path,
                format!(
                    "frame {f} lists {} images but cams describes {cameras} cameras",
                    paths.len()
                ),
            ));
        }
    }
    let folders: Vec<PathBuf> = ims[0]
        .iter()
        .map(|p| {
            root.join(p)
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_default()
        })
        .collect();
    let mut distinct = folders.clone();
    distinct.sort();
    distinct.dedup();
    if distinct.len() != cameras {
        return Err(DataError::invalid(
            annots_path,
            format!(
                "the {cameras} cameras' images of frame 0 lie in {} distinct folders; expected one folder per camera",
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
fn note_unlisted_camera_folders(root: &Path, ims: &[Vec<String>], ck: &mut Checker) {
    let used: Vec<PathBuf> = ims[0]
        .iter()
        .filter_map(|p| root.join(p).parent().map(Path::to_path_buf))
        .collect();
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

/// Cameras with their image size, read from each camera's first image.
fn build_cameras(
    root: &Path,
    raw: &[RawCamera],
    ims: &[Vec<String>],
) -> Result<Vec<Camera>, DataError> {
    raw.iter()
        .enumerate()
        .map(|(c, r)| {
            let first = root.join(&ims[0][c]);
            let (w, h) = formats::images::image_size(&first)?;
            Camera::from_rows(r.k, r.r, r.t, r.d, w, h).map_err(|e| {
                DataError::invalid(root.join("annots.npy"), format!("camera {c}: {e}"))
            })
        })
        .collect()
}

/// Every image exists and has its camera's size (header reads only).
fn check_images(
    root: &Path,
    cameras: &[Camera],
    ims: &[Vec<String>],
    ck: &mut Checker,
) -> Result<(), DataError> {
    for paths in ims {
        for (c, p) in paths.iter().enumerate() {
            let path = root.join(p);
            if let Some((w, h)) = ck.check(formats::images::image_size(&path))? {
                let cam = &cameras[c];
                if (w, h) != (cam.width, cam.height) {
                    ck.check::<()>(Err(DataError::invalid(
                        &path,
                        format!(
                            "image is {w}×{h}, but camera {c}'s first image is {}×{}; a camera's images must share one size",
                            cam.width, cam.height
                        ),
                    )))?;
                }
            }
        }
    }
    Ok(())
}

/// The mask of each image: `mask_cihp/<image>.png`, else `mask/<image>.png`, else (H36M) the image path
/// with `images` replaced by `mask`. All candidates are named when none exists.
fn resolve_masks(
    root: &Path,
    kind: DatasetKind,
    ims: &[Vec<String>],
    ck: &mut Checker,
) -> Result<Option<Vec<Vec<PathBuf>>>, DataError> {
    let mut all = Some(Vec::with_capacity(ims.len()));
    for paths in ims {
        let mut frame = Vec::with_capacity(paths.len());
        for p in paths {
            match ck.check(resolve_mask(root, kind, p))? {
                Some(m) => frame.push(m),
                None => all = None,
            }
        }
        if let Some(all) = &mut all {
            all.push(frame);
        }
    }
    Ok(all)
}

fn resolve_mask(root: &Path, kind: DatasetKind, image: &str) -> Result<PathBuf, DataError> {
    let stem = Path::new(image).with_extension("png");
    let mut candidates = vec![
        root.join("mask_cihp").join(&stem),
        root.join("mask").join(&stem),
    ];
    if kind == DatasetKind::H36m {
        candidates.push(root.join(stem.to_string_lossy().replace("images", "mask")));
    }
    candidates
        .iter()
        .find(|c| c.is_file())
        .cloned()
        .ok_or_else(|| {
            let tried: Vec<String> = candidates.iter().map(|c| c.display().to_string()).collect();
            DataError::Missing {
                path: candidates[0].clone(),
                what: format!("a mask for image {image}: tried {}", tried.join(", ")),
            }
        })
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

//! Writing the authors' ZJU-MoCap layout (`annots.npy`, `new_params/`, `new_vertices/`, `lbs/`) with the
//! dtypes and shapes of the released data, so that their Python code reads it as it reads ZJU-MoCap:
//! float64 calibration (`T` in millimetres, `D` as 5×1), float64 parameters, float32 vertices and weights,
//! int64 faces and parents (root = the uint32 sentinel 4294967295, as SMPL's `kintree_table`). Used by the
//! synthetic subjects and by `anerf import` ([`write_subject`]: any loaded subject, e.g. an EasyMocap
//! capture, rewritten in this layout).

use std::collections::HashSet;
use std::io;
use std::path::{Path, PathBuf};

use anerf_core::geometry::{forward_lbs_point, Camera, CanonicalPose, Skeleton};
use glam::Vec3;
use rayon::prelude::*;

use crate::atomic::{self, WriteError};
use crate::error::DataError;
use crate::formats::{write_npy, write_object_npy, ArrayData, FormatWriteError, NdArray, PyValue};
use crate::paths::{self, Overlap};
use crate::subject::{PosedVertices, SkinningWeights, Subject};

/// One frame's fitted parameters as `new_params/{i}.npy` holds them (axis-angle `poses` of the driven
/// joints, `Rh` axis-angle, `Th` metres, the shape coefficients).
#[derive(Debug, Clone, Copy)]
pub struct FrameParams<'a> {
    pub poses: &'a [f64],
    pub rh: [f64; 3],
    pub th: [f64; 3],
    pub shapes: &'a [f64],
}

fn f64_array(shape: Vec<usize>, values: Vec<f64>) -> Result<PyValue, FormatWriteError> {
    Ok(PyValue::Array(NdArray::new(shape, ArrayData::F64(values))?))
}

fn f32_points(points: &[Vec3]) -> Result<NdArray, FormatWriteError> {
    let values = points.iter().flat_map(|p| p.to_array()).collect();
    Ok(NdArray::new(vec![points.len(), 3], ArrayData::F32(values))?)
}

/// Row-major 3×3 entries of a glam (column-major) matrix.
fn rows(m: glam::Mat3) -> Vec<f64> {
    m.transpose().to_cols_array().map(f64::from).to_vec()
}

/// `annots.npy`: the cameras (`cams`: K, D, R, T lists) and each frame's image paths (`ims`, relative to
/// the folder, one per camera in camera order).
pub fn write_annots(
    path: &Path,
    cameras: &[Camera],
    images: &[Vec<String>],
) -> Result<(), FormatWriteError> {
    let cams = |f: &dyn Fn(&Camera) -> Result<PyValue, FormatWriteError>| {
        cameras
            .iter()
            .map(f)
            .collect::<Result<Vec<_>, _>>()
            .map(PyValue::List)
    };
    let millimetres = |c: &Camera| {
        c.translation
            .to_array()
            .map(|t| f64::from(t) * 1000.0)
            .to_vec()
    };
    let annots = PyValue::dict([
        (
            "cams",
            PyValue::dict([
                ("K", cams(&|c| f64_array(vec![3, 3], rows(c.intrinsics)))?),
                (
                    "D",
                    cams(&|c| f64_array(vec![5, 1], c.distortion.0.map(f64::from).to_vec()))?,
                ),
                ("R", cams(&|c| f64_array(vec![3, 3], rows(c.rotation)))?),
                ("T", cams(&|c| f64_array(vec![3, 1], millimetres(c)))?),
            ]),
        ),
        (
            "ims",
            PyValue::List(
                images
                    .iter()
                    .map(|paths| {
                        let paths = paths.iter().cloned().map(PyValue::Str).collect();
                        PyValue::dict([("ims", PyValue::List(paths))])
                    })
                    .collect(),
            ),
        ),
    ]);
    write_object_npy(path, &annots)
}

/// `new_params/{index}.npy` and `new_vertices/{index}.npy` (posed world vertices, metres) under `dir`.
pub fn write_frame(
    dir: &Path,
    index: usize,
    params: &FrameParams<'_>,
    vertices: &[Vec3],
) -> Result<(), FormatWriteError> {
    write_params(&dir.join(format!("new_params/{index}.npy")), params)?;
    write_npy(
        &dir.join(format!("new_vertices/{index}.npy")),
        &f32_points(vertices)?,
    )
}

/// One frame's parameters at `path`, as `new_params/{i}.npy` holds them (a pickled dict of float64
/// `poses`, `Rh`, `Th` and `shapes`, each `1 × n`).
pub fn write_params(path: &Path, params: &FrameParams<'_>) -> Result<(), FormatWriteError> {
    let p = PyValue::dict([
        (
            "poses",
            f64_array(vec![1, params.poses.len()], params.poses.to_vec())?,
        ),
        ("Rh", f64_array(vec![1, 3], params.rh.to_vec())?),
        ("Th", f64_array(vec![1, 3], params.th.to_vec())?),
        (
            "shapes",
            f64_array(vec![1, params.shapes.len()], params.shapes.to_vec())?,
        ),
    ]);
    write_object_npy(path, &p)
}

/// `lbs/joints.npy`, `parents.npy`, `tvertices.npy` (canonical vertices), `weights.npy` and `faces.npy`
/// under `lbs`.
pub fn write_lbs(
    lbs: &Path,
    skeleton: &Skeleton,
    canonical: &[Vec3],
    weights: &SkinningWeights,
    faces: &[[u32; 3]],
) -> Result<(), FormatWriteError> {
    write_npy(
        &lbs.join("joints.npy"),
        &f32_points(skeleton.rest_joints())?,
    )?;
    let parents = skeleton
        .parents()
        .iter()
        .map(|p| p.map_or(i64::from(u32::MAX), |p| p as i64))
        .collect();
    write_npy(
        &lbs.join("parents.npy"),
        &NdArray::new(vec![skeleton.num_joints()], ArrayData::I64(parents))?,
    )?;
    write_npy(&lbs.join("tvertices.npy"), &f32_points(canonical)?)?;
    write_npy(
        &lbs.join("weights.npy"),
        &NdArray::new(
            vec![weights.num_vertices(), weights.num_joints()],
            ArrayData::F32(weights.as_slice().to_vec()),
        )?,
    )?;
    let faces_flat = faces.iter().flat_map(|f| f.map(i64::from)).collect();
    write_npy(
        &lbs.join("faces.npy"),
        &NdArray::new(vec![faces.len(), 3], ArrayData::I64(faces_flat))?,
    )
}

/// A `V × 3` float32 array of points (metres), e.g. `lbs/bigpose_vertices.npy`.
pub fn write_points(path: &Path, points: &[Vec3]) -> Result<(), FormatWriteError> {
    write_npy(path, &f32_points(points)?)
}

/// Why a subject could not be written in the ZJU-MoCap layout.
#[derive(Debug, thiserror::Error)]
pub enum LayoutError {
    #[error("{} already exists (pass --overwrite to replace it)", .0.display())]
    Exists(PathBuf),
    #[error("the output folder {} lies inside the input {} it is written from", out.display(), root.display())]
    InsideSource { out: PathBuf, root: PathBuf },
    #[error("the output folder {} holds the input {}: replacing it would delete that input; choose another --out", out.display(), input.display())]
    HoldsSource { out: PathBuf, input: PathBuf },
    #[error("{} exists and was not written by `anerf import` (it has no .anerf-import marker); refusing to delete it: choose another --out or remove it yourself", .0.display())]
    NotOurs(PathBuf),
    #[error("frames {first} and {second} share the file index {index}: their files would collide")]
    SharedIndex {
        index: usize,
        first: usize,
        second: usize,
    },
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Format(#[from] FormatWriteError),
    #[error(transparent)]
    Write(#[from] WriteError),
    #[error("cannot {what} {}: {source}", path.display())]
    Io {
        what: &'static str,
        path: PathBuf,
        #[source]
        source: io::Error,
    },
}

fn io_error<'a>(what: &'static str, path: &'a Path) -> impl Fn(io::Error) -> LayoutError + 'a {
    move |source| LayoutError::Io {
        what,
        path: path.to_path_buf(),
        source,
    }
}

/// Each camera's folder name: the folder its first image lies in when those names are distinct (EasyMocap's
/// `images/<cam>/`, ZJU's `Camera_B1/`), else `Camera_<n>` counted from 1.
fn camera_folders(subject: &Subject) -> Vec<String> {
    let from_images: Option<Vec<String>> = subject.frames.first().and_then(|f| {
        f.images
            .iter()
            .map(|p| {
                p.parent()
                    .and_then(Path::file_name)
                    .map(|n| n.to_string_lossy().into_owned())
            })
            .collect()
    });
    match from_images {
        Some(names)
            if names.iter().collect::<HashSet<_>>().len() == names.len()
                && names.iter().all(|n| !n.starts_with('.') && n != "mask") =>
        {
            names
        }
        _ => (1..=subject.cameras.len())
            .map(|c| format!("Camera_{c}"))
            .collect(),
    }
}

/// Writes `subject` as a new ZJU-MoCap folder `out`: images copied to `<cam>/<index:06>.<ext>`, masks to
/// `mask/<cam>/<index:06>.png`, `annots.npy`, `new_params/` (poses of the skeleton's joints, `Rh`, `Th`,
/// and the fit's betas, or ten zeros), `new_vertices/` (posed with pose correctives for fitted bodies) and
/// `lbs/` (with `bigpose_vertices.npy`). Everything is written into a sibling folder that is renamed to
/// `out` at the end, so `out` is never half-written. `out` must neither lie inside nor hold the dataset
/// folder or any of `inputs` (e.g. the body-model file); an existing `out` is replaced only with
/// `overwrite`, and only when it holds the marker this function writes ([`IMPORT_MARKER`]).
pub fn write_subject(
    subject: &Subject,
    out: &Path,
    inputs: &[&Path],
    overwrite: bool,
) -> Result<(), LayoutError> {
    for input in std::iter::once(subject.root.as_path()).chain(inputs.iter().copied()) {
        check_apart(out, input)?;
    }
    if out.exists() {
        if !overwrite {
            return Err(LayoutError::Exists(out.to_path_buf()));
        }
        if !paths::has_marker(out, IMPORT_MARKER) {
            return Err(LayoutError::NotOurs(out.to_path_buf()));
        }
    }
    let mut seen = std::collections::HashMap::new();
    for (f, frame) in subject.frames.iter().enumerate() {
        if let Some(first) = seen.insert(frame.file_index, f) {
            return Err(LayoutError::SharedIndex {
                index: frame.file_index,
                first,
                second: f,
            });
        }
    }
    let staging = atomic::temp_dir_beside(out)?;
    write_into(subject, staging.path())?;
    let marker = paths::marker(staging.path(), IMPORT_MARKER);
    atomic::write_bytes(
        &marker,
        b"written by anerf import; --overwrite may replace this folder\n",
    )?;
    Ok(atomic::replace_dir(staging, out)?)
}

/// The purpose [`paths::marker`] names in a folder [`write_subject`] made.
pub const IMPORT_MARKER: &str = "import";

/// Refuses an output folder at, under or above an input (it would be read while written, and `overwrite`
/// could delete the input).
fn check_apart(out: &Path, input: &Path) -> Result<(), LayoutError> {
    let overlap = paths::overlap(out, input).map_err(io_error("resolve", out))?;
    let (out, input) = (out.to_path_buf(), input.to_path_buf());
    match overlap {
        None => Ok(()),
        Some(Overlap::Inside) => Err(LayoutError::InsideSource { out, root: input }),
        Some(Overlap::Holds) => Err(LayoutError::HoldsSource { out, input }),
    }
}

fn write_into(subject: &Subject, dir: &Path) -> Result<(), LayoutError> {
    let folders = camera_folders(subject);
    let body = &subject.body;
    let num_joints = body.skeleton.num_joints();
    let num_vertices = body.canonical_vertices.len();
    let images: Vec<Vec<String>> = subject
        .frames
        .iter()
        .map(|frame| {
            frame
                .images
                .iter()
                .zip(&folders)
                .map(|(image, cam)| {
                    let ext = image
                        .extension()
                        .map_or_else(|| "jpg".into(), |e| e.to_string_lossy().to_lowercase());
                    format!("{cam}/{:06}.{ext}", frame.file_index)
                })
                .collect()
        })
        .collect();
    for cam in &folders {
        for d in [dir.join(cam), dir.join("mask").join(cam)] {
            std::fs::create_dir_all(&d).map_err(io_error("create", &d))?;
        }
    }
    subject.frames.par_iter().zip(&images).try_for_each(
        |(frame, names)| -> Result<(), LayoutError> {
            for ((image, mask), (name, cam)) in frame
                .images
                .iter()
                .zip(&frame.masks)
                .zip(names.iter().zip(&folders))
            {
                std::fs::copy(image, dir.join(name)).map_err(io_error("copy", image))?;
                let to = dir
                    .join("mask")
                    .join(cam)
                    .join(format!("{:06}.png", frame.file_index));
                std::fs::copy(mask, to).map_err(io_error("copy", mask))?;
            }
            let mut poses: Vec<f64> = frame
                .pose
                .joint_rotations
                .iter()
                .take(num_joints)
                .flat_map(|r| r.to_array())
                .map(f64::from)
                .collect();
            poses.resize(3 * num_joints, 0.0);
            let shapes = match &frame.vertices {
                PosedVertices::Fitted(fit) => fit.params.betas.clone(),
                PosedVertices::File(_) => vec![0.0; 10],
            };
            let params = FrameParams {
                poses: &poses,
                rh: frame.pose.global.rh.to_array().map(f64::from),
                th: frame.pose.global.th.to_array().map(f64::from),
                shapes: &shapes,
            };
            let vertices = frame.vertices.read(Some(num_vertices))?;
            write_frame(dir, frame.file_index, &params, &vertices)?;
            Ok(())
        },
    )?;
    write_annots(&dir.join("annots.npy"), &subject.cameras, &images)?;
    let lbs = dir.join("lbs");
    write_lbs(
        &lbs,
        &body.skeleton,
        &body.canonical_vertices,
        &body.weights,
        &body.faces,
    )?;
    write_points(
        &lbs.join("bigpose_vertices.npy"),
        &big_pose_vertices(subject)?,
    )?;
    Ok(())
}

/// The canonical vertices skinned into the skeleton's big pose (metres, canonical space).
fn big_pose_vertices(subject: &Subject) -> Result<Vec<Vec3>, LayoutError> {
    let body = &subject.body;
    let invalid = |e: anerf_core::GeometryError| {
        DataError::invalid(&subject.root, format!("the body's big pose: {e}"))
    };
    let transforms = body
        .skeleton
        .bone_transforms(&body.skeleton.big_pose(), CanonicalPose::TPose)
        .map_err(invalid)?;
    body.canonical_vertices
        .iter()
        .enumerate()
        .map(|(v, &x)| {
            forward_lbs_point(x, body.weights.row(v), &transforms).map_err(|e| invalid(e).into())
        })
        .collect()
}

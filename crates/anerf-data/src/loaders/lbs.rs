//! The body model of a subject: `lbs/joints.npy`, `lbs/parents.npy`, `lbs/tvertices.npy`, and skinning
//! weights and faces from `lbs/weights.npy` + `lbs/faces.npy` or, when those are absent, from a body-model
//! file the user names (SMPL-style `.npz`, or `.pkl` through the restricted unpickler).

use std::path::Path;

use anerf_core::geometry::Skeleton;

use super::arrays::{faces, field, finite, points};
use super::check::Checker;
use crate::error::DataError;
use crate::formats::{self, NdArray, Value};
use crate::subject::{BodyModel, SkinningWeights};

/// Reads the body model of the dataset at `root`. `None` only when collecting problems.
pub(crate) fn read_body(
    root: &Path,
    body_model: Option<&Path>,
    ck: &mut Checker,
) -> Result<Option<BodyModel>, DataError> {
    let lbs = root.join("lbs");
    let skeleton = ck.check(read_skeleton(&lbs))?;
    let tpath = lbs.join("tvertices.npy");
    let tverts =
        ck.check(formats::read_npy(&tpath).and_then(|a| points(&a, &tpath, "tvertices")))?;
    let mesh = match (&skeleton, &tverts) {
        (Some(s), Some(v)) => ck.check(read_mesh(&lbs, body_model, s.num_joints(), v.len()))?,
        _ => None,
    };
    Ok(match (skeleton, tverts, mesh) {
        (Some(skeleton), Some(canonical_vertices), Some((weights, faces))) => Some(BodyModel {
            skeleton,
            canonical_vertices,
            faces,
            weights,
        }),
        _ => None,
    })
}

fn read_skeleton(lbs: &Path) -> Result<Skeleton, DataError> {
    let jpath = lbs.join("joints.npy");
    let joints = points(&formats::read_npy(&jpath)?, &jpath, "joints")?;
    let ppath = lbs.join("parents.npy");
    let parents = formats::read_npy(&ppath)?
        .to_i64()
        .ok_or_else(|| DataError::invalid(&ppath, "parents are not integers"))?;
    if parents.len() != joints.len() {
        return Err(DataError::invalid(
            &ppath,
            format!(
                "{} parents for the {} joints of {}",
                parents.len(),
                joints.len(),
                jpath.display()
            ),
        ));
    }
    Skeleton::from_parent_table(joints, &parents)
        .map_err(|e| DataError::invalid(&ppath, e.to_string()))
}

/// Weights (`V × K`) and faces, from `lbs/` when both files exist, else from the named body-model file.
fn read_mesh(
    lbs: &Path,
    body_model: Option<&Path>,
    num_joints: usize,
    num_vertices: usize,
) -> Result<(SkinningWeights, Vec<[u32; 3]>), DataError> {
    let (wpath, fpath) = (lbs.join("weights.npy"), lbs.join("faces.npy"));
    if wpath.is_file() && fpath.is_file() {
        let w = formats::read_npy(&wpath)?;
        let f = formats::read_npy(&fpath)?;
        return Ok((
            weights(&w, &wpath, num_joints, num_vertices)?,
            faces(&f, &fpath, num_vertices)?,
        ));
    }
    let Some(model) = body_model else {
        return Err(DataError::Missing {
            path: wpath,
            what: format!(
                "lbs/weights.npy and lbs/faces.npy, or a body-model file (SMPL .npz or .pkl with 'weights' \
                 ({num_vertices}, {num_joints}) and 'f') named in the options"
            ),
        });
    };
    let (w, f) = read_body_model_file(model)?;
    Ok((
        weights(&w, model, num_joints, num_vertices)?,
        faces(&f, model, num_vertices)?,
    ))
}

/// `weights` and `f` of a body-model file (`.npz`, or `.pkl` read by the restricted unpickler).
pub fn read_body_model_file(path: &Path) -> Result<(NdArray, NdArray), DataError> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    match ext {
        "npz" => {
            let mut members = formats::npz::read_npz(path)?;
            let mut take = |key: &str| {
                members.remove(key).ok_or_else(|| {
                    DataError::invalid(
                        path,
                        format!("has no '{key}' array (expected 'weights' and 'f')"),
                    )
                })
            };
            Ok((take("weights")?, take("f")?))
        }
        "pkl" => {
            let v: Value = formats::read_pickle(path)?;
            Ok((
                field(&v, "weights", path)?.clone(),
                field(&v, "f", path)?.clone(),
            ))
        }
        _ => Err(DataError::invalid(
            path,
            "unknown body-model format (expected a .npz or .pkl file)",
        )),
    }
}

fn weights(
    arr: &NdArray,
    path: &Path,
    num_joints: usize,
    num_vertices: usize,
) -> Result<SkinningWeights, DataError> {
    let v = finite(
        arr,
        path,
        "weights",
        &[Some(num_vertices), Some(num_joints)],
    )?;
    SkinningWeights::new(v.into_iter().map(|x| x as f32).collect(), num_joints)
        .map_err(|e| DataError::invalid(path, e))
}

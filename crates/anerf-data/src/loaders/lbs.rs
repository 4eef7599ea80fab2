//! The body model of a subject: `lbs/joints.npy`, `lbs/parents.npy`, `lbs/tvertices.npy`, and skinning
//! weights and faces from `lbs/weights.npy` + `lbs/faces.npy` or, when those are absent, from a body-model
//! file the user names (SMPL-style `.npz`, or `.pkl` through the restricted unpickler).

use std::path::Path;

use anerf_core::geometry::Skeleton;
use glam::Vec3;

use super::check::Checker;
use crate::error::DataError;
use crate::formats::arrays::{faces, finite, points};
use crate::formats::{self, NdArray};
use crate::smpl;
use crate::subject::{check_body_size, BodyModel, SkinningWeights};

/// What could be read of a body model; each file is checked on its own, so one bad file hides no other.
pub(crate) struct BodyParts {
    pub skeleton: Option<Skeleton>,
    pub canonical_vertices: Option<Vec<Vec3>>,
    pub weights: Option<SkinningWeights>,
    pub faces: Option<Vec<[u32; 3]>>,
}

impl BodyParts {
    /// The body model, when every part was read.
    pub fn complete(self) -> Option<BodyModel> {
        Some(BodyModel {
            skeleton: self.skeleton?,
            canonical_vertices: self.canonical_vertices?,
            weights: self.weights?,
            faces: self.faces?,
        })
    }
}

/// Reads the body model of the dataset at `root`, recording each part's problem (collecting) or returning
/// the first (fail-fast).
pub(crate) fn read_body(
    root: &Path,
    body_model: Option<&Path>,
    ck: &mut Checker,
) -> Result<BodyParts, DataError> {
    let lbs = root.join("lbs");
    let skeleton = ck.check(read_skeleton(&lbs))?;
    let tpath = lbs.join("tvertices.npy");
    let canonical_vertices = ck.check(formats::read_npy(&tpath).and_then(|a| {
        let v = points(&a, &tpath, "tvertices")?;
        check_body_size(&v, &tpath, "the canonical body")?;
        Ok(v)
    }))?;
    let joints = skeleton.as_ref().map(Skeleton::num_joints);
    let vertices = canonical_vertices.as_ref().map(Vec::len);
    let (wpath, fpath) = (lbs.join("weights.npy"), lbs.join("faces.npy"));
    let (weights, faces) = if wpath.is_file() && fpath.is_file() {
        let w = formats::read_npy(&wpath).and_then(|w| weights(&w, &wpath, joints, vertices));
        let f = formats::read_npy(&fpath).and_then(|f| faces(&f, &fpath, vertices));
        (ck.check(w)?, ck.check(f)?)
    } else {
        let mesh = read_mesh_file(&wpath, body_model, joints, vertices);
        ck.check(mesh)?.unzip()
    };
    Ok(BodyParts {
        skeleton,
        canonical_vertices,
        weights,
        faces,
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

/// Weights (`V × K`) and faces from the body-model file named in the options, when `lbs/` lacks them.
fn read_mesh_file(
    wpath: &Path,
    body_model: Option<&Path>,
    joints: Option<usize>,
    vertices: Option<usize>,
) -> Result<(SkinningWeights, Vec<[u32; 3]>), DataError> {
    let Some(model) = body_model else {
        let shape = |n: Option<usize>| n.map_or("…".to_string(), |n| n.to_string());
        return Err(DataError::Missing {
            path: wpath.to_path_buf(),
            what: format!(
                "lbs/weights.npy and lbs/faces.npy, or a body-model file (SMPL .npz or .pkl with 'weights' \
                 ({}, {}) and 'f') named in the options",
                shape(vertices),
                shape(joints)
            ),
        });
    };
    let arrays = smpl::read_model_arrays(model)?;
    let take = |key: &str| {
        arrays.get(key).ok_or_else(|| {
            DataError::invalid(
                model,
                format!("has no '{key}' array (expected 'weights' and 'f')"),
            )
        })
    };
    Ok((
        weights(take("weights")?, model, joints, vertices)?,
        faces(take("f")?, model, vertices)?,
    ))
}

/// `V × K` weights; a count left `None` (its own file was unreadable) is taken as stored.
fn weights(
    arr: &NdArray,
    path: &Path,
    num_joints: Option<usize>,
    num_vertices: Option<usize>,
) -> Result<SkinningWeights, DataError> {
    let v = finite(arr, path, "weights", &[num_vertices, num_joints])?;
    SkinningWeights::new(v.into_iter().map(|x| x as f32).collect(), arr.shape()[1])
        .map_err(|e| DataError::invalid(path, e))
}

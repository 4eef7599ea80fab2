//! SMPL-family body models (SMPL, SMPL-H, SMPL-X and any other joint count) read from the files users have:
//! `.npz`, or `.pkl` through the restricted unpickler (arrays, numbers and containers only). The joint and
//! vertex counts come from the file. The forward model ([`SmplModel::pose`]) is in `forward.rs`.
//!
//! Units and frames: metres; the model's own frame (canonical, the T-pose at the origin) until the global
//! `R(Rh) x + Th` of EasyMocap's fits places the body in the world. Vectors are column vectors.

mod body;
mod forward;

use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec3;

pub(crate) use forward::rodrigues;
pub use forward::{PosedSmpl, SmplParams};

use crate::error::DataError;
use crate::formats::arrays::{faces, finite, shape_text};
use crate::formats::{self, NdArray, Value};

/// An SMPL-family model: template, blend shapes, joint regressor, skinning weights, kinematic tree and
/// triangles. `V` vertices, `K` joints, `B` shape coefficients; arrays keep the files' layouts, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct SmplModel {
    /// `V` template vertices (metres, model frame).
    pub v_template: Vec<DVec3>,
    /// `V × 3 × B` shape blend shapes (metres per unit coefficient).
    shapedirs: Vec<f64>,
    num_betas: usize,
    /// `V × 3 × 9(K−1)` pose correctives, driven by the entries of `R_k − I` of joints `1..K`.
    posedirs: Vec<f64>,
    /// `K × V` joint regressor (rows are convex combinations of vertices in the SMPL files).
    j_regressor: Vec<f64>,
    /// `V × K` skinning weights, rows summing to 1.
    weights: Vec<f64>,
    /// Parent of each joint (`None` for the root); parents precede their children.
    pub parents: Vec<Option<usize>>,
    /// Triangles as vertex indices.
    pub faces: Vec<[u32; 3]>,
}

impl SmplModel {
    /// Reads a `.npz` or `.pkl` model file; errors name the file, the key and the expected shape.
    pub fn read(path: &Path) -> Result<Self, DataError> {
        Self::from_arrays(&read_model_arrays(path)?, path)
    }

    /// Builds the model from its named arrays (`path` names the file in errors).
    pub fn from_arrays(arrays: &BTreeMap<String, NdArray>, path: &Path) -> Result<Self, DataError> {
        let get = |key: &str| {
            arrays.get(key).ok_or_else(|| {
                DataError::invalid(
                    path,
                    format!(
                        "has no '{key}' array (an SMPL-family model needs v_template, shapedirs, posedirs, \
                         J_regressor, weights, kintree_table and f; it has {})",
                        arrays.keys().cloned().collect::<Vec<_>>().join(", ")
                    ),
                )
            })
        };
        let template = finite(get("v_template")?, path, "v_template", &[None, Some(3)])?;
        let v = template.len() / 3;
        if v == 0 {
            return Err(DataError::invalid(
                path,
                "v_template has no vertex (expected V × 3 with V > 0)",
            ));
        }
        let weights_arr = get("weights")?;
        let weights = finite(weights_arr, path, "weights", &[Some(v), None])?;
        let k = weights_arr.shape()[1];
        if k == 0 {
            return Err(DataError::invalid(path, "weights has no joint column"));
        }
        let shapedirs_arr = get("shapedirs")?;
        let shapedirs = finite(shapedirs_arr, path, "shapedirs", &[Some(v), Some(3), None])?;
        let num_betas = shapedirs_arr.shape()[2];
        let posedirs = finite(
            get("posedirs")?,
            path,
            "posedirs",
            &[Some(v), Some(3), Some(9 * (k - 1))],
        )?;
        let j_regressor = finite(
            get("J_regressor")?,
            path,
            "J_regressor",
            &[Some(k), Some(v)],
        )?;
        let parents = parents(get("kintree_table")?, path, k)?;
        let faces = faces(get("f")?, path, Some(v))?;
        for (i, row) in weights.chunks_exact(k).enumerate() {
            let sum: f64 = row.iter().sum();
            if row.iter().any(|&w| w < 0.0) || (sum - 1.0).abs() > 1e-3 {
                return Err(DataError::invalid(
                    path,
                    format!("weights row {i} sums to {sum} or has a negative entry; expected convex weights"),
                ));
            }
        }
        Ok(Self {
            v_template: template
                .chunks_exact(3)
                .map(|c| DVec3::new(c[0], c[1], c[2]))
                .collect(),
            shapedirs,
            num_betas,
            posedirs,
            j_regressor,
            weights,
            parents,
            faces,
        })
    }

    /// Number of joints `K`.
    pub fn num_joints(&self) -> usize {
        self.parents.len()
    }

    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.v_template.len()
    }

    /// Number of shape coefficients `B` the file holds.
    pub fn num_betas(&self) -> usize {
        self.num_betas
    }

    /// Weights of vertex `v` over the joints.
    pub fn vertex_weights(&self, v: usize) -> &[f64] {
        let k = self.num_joints();
        &self.weights[v * k..(v + 1) * k]
    }
}

/// The arrays of an SMPL-family model file that [`SmplModel::from_arrays`] reads.
pub const MODEL_KEYS: [&str; 7] = [
    "v_template",
    "shapedirs",
    "posedirs",
    "J_regressor",
    "weights",
    "kintree_table",
    "f",
];

/// The named arrays of a body-model file: an `.npz`, or a `.pkl` dict read by the restricted unpickler
/// (entries that are not arrays, such as `bs_style`, are left out).
pub fn read_model_arrays(path: &Path) -> Result<BTreeMap<String, NdArray>, DataError> {
    match path.extension().and_then(|e| e.to_str()).unwrap_or("") {
        "npz" => {
            // Only the arrays a model needs are inflated: other members (however large) cost nothing.
            let mut npz = formats::npz::Npz::open(path)?;
            let present: Vec<&str> = MODEL_KEYS
                .into_iter()
                .filter(|k| matches!(npz.kind(k), Some(formats::npz::MemberKind::Numeric { .. })))
                .collect();
            present
                .into_iter()
                .map(|k| Ok((k.to_string(), npz.array(k)?)))
                .collect()
        }
        "pkl" => match formats::read_pickle(path)? {
            Value::Dict(entries) => Ok(entries
                .iter()
                .filter_map(|(k, v)| Some((k.as_str()?.to_string(), v.as_array()?.clone())))
                .collect()),
            other => Err(DataError::invalid(
                path,
                format!("holds {}, expected a dict of arrays", other.kind()),
            )),
        },
        _ => Err(DataError::invalid(
            path,
            "unknown body-model format (expected an SMPL-family .npz or .pkl file)",
        )),
    }
}

/// Parents from `kintree_table` (`2 × K`: parents, then the joints' own ids; the root's parent is −1 or
/// `2³² − 1`); every parent must precede its joint.
fn parents(arr: &NdArray, path: &Path, k: usize) -> Result<Vec<Option<usize>>, DataError> {
    let ints = arr.to_i64().filter(|_| arr.shape() == [2, k]).ok_or_else(|| {
        DataError::invalid(
            path,
            format!(
                "kintree_table has shape {} of {:?}, expected integers of shape (2, {k}) (K from weights)",
                shape_text(arr.shape()),
                arr.dtype()
            ),
        )
    })?;
    (0..k)
        .map(|j| {
            let p = ints[j];
            match (j, p) {
                (0, -1 | 4_294_967_295) => Ok(None),
                (j, p) if p >= 0 && (p as usize) < j => Ok(Some(p as usize)),
                _ => Err(DataError::invalid(
                    path,
                    format!("kintree_table gives joint {j} the parent {p}; expected a joint before it (the root's is -1)"),
                )),
            }
        })
        .collect()
}

//! One captured person: calibrated cameras, per-frame images, masks and poses, and the body model.
//! Every loader (ZJU-MoCap, Human3.6M, synthetic) produces this type.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anerf_core::geometry::{Camera, Pose, Skeleton};
use anerf_core::{FrameId, GeometryError};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::error::DataError;
use crate::formats::arrays::points;
use crate::formats::read_npy;
use crate::smpl::{SmplModel, SmplParams};

/// Which layout a subject was read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DatasetKind {
    ZjuMocap,
    H36m,
    Synthetic,
    /// An EasyMocap capture folder (`intri.yml`, `extri.yml`, `images/`, SMPL fits), with a body-model file.
    EasyMocap,
}

/// A multi-view video of one person, as calibrated and fitted.
#[derive(Debug, Clone)]
pub struct Subject {
    pub name: String,
    /// The dataset folder (e.g. `data/zju_mocap/CoreView_313`).
    pub root: PathBuf,
    pub kind: DatasetKind,
    /// Cameras in the dataset's order (index = [`anerf_core::ViewId`]), at the stored image resolution, with
    /// their lens distortion; `T` in metres.
    pub cameras: Vec<Camera>,
    /// Frames in the dataset's order (index = [`FrameId`]).
    pub frames: Vec<FrameRecord>,
    pub body: BodyModel,
    /// What the loader had to fall back on (e.g. `params/` instead of `new_params/`), for `anerf info`.
    pub notes: Vec<String>,
}

/// One time step: an image and a mask per camera, and the fitted body pose.
#[derive(Debug, Clone)]
pub struct FrameRecord {
    pub id: FrameId,
    /// The `{i}` of `new_params/{i}.npy`, `new_vertices/{i}.npy` and `bweights/{i}.npy` (starts at 1 for
    /// ZJU-MoCap 313/315).
    pub file_index: usize,
    /// Absolute image path per camera.
    pub images: Vec<PathBuf>,
    /// Absolute mask path per camera (non-zero = foreground).
    pub masks: Vec<PathBuf>,
    pub pose: Pose,
    /// Posed body-model vertices in world space (metres).
    pub vertices: PosedVertices,
}

/// Where a frame's posed body-model vertices (world space, metres) come from.
#[derive(Debug, Clone)]
pub enum PosedVertices {
    /// A `V × 3` `.npy` file (`new_vertices/{i}.npy`).
    File(PathBuf),
    /// The body model posed by the frame's fit (with pose correctives), computed when asked for.
    Fitted(FittedPose),
}

/// A body model, its file and one frame's fitted parameters (from the fit file `fit`).
#[derive(Debug, Clone)]
pub struct FittedPose {
    pub model: Arc<SmplModel>,
    pub model_file: PathBuf,
    pub fit: PathBuf,
    pub params: SmplParams,
}

impl PosedVertices {
    /// The vertices, `expected` of them when the count is known; a file must hold finite `V × 3` values,
    /// and either source a body of a person's size ([`check_body_size`]).
    pub fn read(&self, expected: Option<usize>) -> Result<Vec<Vec3>, DataError> {
        match self {
            PosedVertices::File(path) => read_posed_vertices(path, expected),
            PosedVertices::Fitted(f) => {
                let vertices: Vec<Vec3> = f
                    .model
                    .pose(&f.params, true)
                    .vertices
                    .iter()
                    .map(|v| v.as_vec3())
                    .collect();
                check_body_size(&vertices, &f.fit, "the body this fit poses (its shapes)")?;
                Ok(vertices)
            }
        }
    }

    /// The `.npy` file, for vertices stored in one.
    pub fn file(&self) -> Option<&Path> {
        match self {
            PosedVertices::File(path) => Some(path),
            PosedVertices::Fitted(_) => None,
        }
    }

    /// The files the vertices depend on (for cache fingerprints).
    pub fn sources(&self) -> Vec<&Path> {
        match self {
            PosedVertices::File(path) => vec![path],
            PosedVertices::Fitted(f) => vec![&f.fit, &f.model_file],
        }
    }
}

/// The subject's body model in canonical space.
#[derive(Debug, Clone)]
pub struct BodyModel {
    pub skeleton: Skeleton,
    /// Canonical (T-pose) vertices, metres (`lbs/tvertices.npy`).
    pub canonical_vertices: Vec<Vec3>,
    /// Triangles as vertex indices (counter-clockwise seen from outside).
    pub faces: Vec<[u32; 3]>,
    pub weights: SkinningWeights,
}

/// Per-vertex skinning weights, `V × K` row-major, rows summing to 1.
#[derive(Debug, Clone, PartialEq)]
pub struct SkinningWeights {
    num_joints: usize,
    data: Vec<f32>,
}

impl SkinningWeights {
    /// Validates `V × K` weights: finite, non-negative, rows summing to 1 within 1e-3.
    /// An error names the first vertex whose row is wrong ([`GeometryError::AtPoint`]).
    pub fn new(data: Vec<f32>, num_joints: usize) -> Result<Self, GeometryError> {
        if num_joints == 0 || !data.len().is_multiple_of(num_joints) {
            return Err(GeometryError::RaggedWeights {
                got: data.len(),
                joints: num_joints,
            });
        }
        for (index, row) in data.chunks_exact(num_joints).enumerate() {
            anerf_core::geometry::validate_weights(row, num_joints).map_err(|e| {
                GeometryError::AtPoint {
                    index,
                    source: Box::new(e),
                }
            })?;
        }
        Ok(Self { num_joints, data })
    }

    /// Number of joints `K`.
    pub fn num_joints(&self) -> usize {
        self.num_joints
    }

    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.data.len() / self.num_joints
    }

    /// Weights of vertex `v`.
    pub fn row(&self, v: usize) -> &[f32] {
        &self.data[v * self.num_joints..(v + 1) * self.num_joints]
    }

    /// All weights, row-major.
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }
}

/// Posed world vertices of a frame (`new_vertices/{i}.npy`, `V × 3` metres, finite), `expected` of them
/// when `lbs/tvertices.npy` gave the count.
pub(crate) fn read_posed_vertices(
    path: &Path,
    expected: Option<usize>,
) -> Result<Vec<Vec3>, DataError> {
    let v = points(&read_npy(path)?, path, "vertices")?;
    match expected {
        Some(n) if v.len() != n => Err(DataError::invalid(
            path,
            format!(
                "holds {} vertices, expected {n} like lbs/tvertices.npy",
                v.len()
            ),
        )),
        _ => {
            check_body_size(&v, path, "the posed body")?;
            Ok(v)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_are_validated_per_row() {
        assert!(SkinningWeights::new(vec![0.5, 0.5, 1.0, 0.0], 2).is_ok());
        let err = SkinningWeights::new(vec![0.5, 0.5, 0.7, 0.0], 2).unwrap_err();
        assert!(
            matches!(&err, GeometryError::AtPoint { index: 1, source }
                if matches!(**source, GeometryError::WeightsNotNormalised { .. })),
            "{err}"
        );
        assert_eq!(
            SkinningWeights::new(vec![0.5, 0.5, 1.0], 2),
            Err(GeometryError::RaggedWeights { got: 3, joints: 2 })
        );
    }
}

/// The extent a body (canonical or posed, metres) may have: the largest side of its bounding box.
pub const BODY_SIZE_METRES: std::ops::RangeInclusive<f32> = 0.3..=3.0;

/// Refuses vertices that are not a person's body in metres: none at all, a non-finite one, or a bounding
/// box whose largest side is outside [`BODY_SIZE_METRES`], naming `path`, `what` and the unit the body is
/// probably in. Volumes and boxes are sized from bodies, so this keeps a millimetre model or absurd
/// shape coefficients from asking for petabytes.
pub fn check_body_size(vertices: &[Vec3], path: &Path, what: &str) -> Result<(), DataError> {
    let Some(bounds) = anerf_core::geometry::Aabb::from_points(vertices.iter().copied()) else {
        return Err(DataError::invalid(path, format!("{what} has no vertex")));
    };
    let persons = format!(
        "a person's body is between {} and {} m tall in metres",
        BODY_SIZE_METRES.start(),
        BODY_SIZE_METRES.end()
    );
    if let Some(v) = vertices.iter().position(|v| !v.is_finite()) {
        return Err(DataError::invalid(
            path,
            format!(
                "{what}: vertex {v} is {}, not finite; {persons}: are its shape coefficients (betas) \
                 or scale far outside a person's?",
                vertices[v]
            ),
        ));
    }
    let size = bounds.size().max_element();
    if BODY_SIZE_METRES.contains(&size) {
        return Ok(());
    }
    let unit = match size {
        s if (300.0..=3000.0).contains(&s) => "; it is probably in millimetres",
        s if (30.0..=300.0).contains(&s) => "; it is probably in centimetres",
        s if s > 3.0 => "; are its shape coefficients (betas) or scale far outside a person's?",
        _ => "",
    };
    Err(DataError::invalid(
        path,
        format!(
            "{what} is {size:.4} m tall (the largest side of its bounding box); {persons}{unit}"
        ),
    ))
}

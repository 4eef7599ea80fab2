//! Writing the authors' ZJU-MoCap layout (`annots.npy`, `new_params/`, `new_vertices/`, `lbs/`) with the
//! dtypes and shapes of the released data, so that their Python code reads it as it reads ZJU-MoCap:
//! float64 calibration (`T` in millimetres, `D` as 5×1), float64 parameters, float32 vertices and weights,
//! int64 faces and parents (root = the uint32 sentinel 4294967295, as SMPL's `kintree_table`). Used by the
//! synthetic subjects and by `anerf import`.

use std::path::Path;

use anerf_core::geometry::{Camera, Skeleton};
use glam::Vec3;

use crate::formats::{write_npy, write_object_npy, ArrayData, FormatWriteError, NdArray, PyValue};
use crate::subject::SkinningWeights;

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
    write_object_npy(&dir.join(format!("new_params/{index}.npy")), &p)?;
    write_npy(
        &dir.join(format!("new_vertices/{index}.npy")),
        &f32_points(vertices)?,
    )
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

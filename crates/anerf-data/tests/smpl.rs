//! The SMPL-family forward model against numpy's (`scripts/fixtures/smpl.py`), on random SMPL-like models
//! written as `.npz`, plain-array `.pkl` and chumpy/scipy-sparse `.pkl`, and the model files' bad input.

use std::collections::BTreeMap;
use std::path::Path;

use anerf_data::formats::{ArrayData, NdArray};
use anerf_data::smpl::{SmplModel, SmplParams};
use anerf_testing::{assert_close, fixture, floats, json, Tolerance};
use glam::DVec3;

fn vec3(v: &serde_json::Value) -> DVec3 {
    let f = floats(v);
    DVec3::new(f[0], f[1], f[2])
}

fn flat(points: &[DVec3]) -> Vec<f64> {
    points.iter().flat_map(|p| p.to_array()).collect()
}

#[test]
fn posed_vertices_and_joints_match_numpy_for_npz_and_pkl_with_and_without_correctives() {
    let index = json("smpl/index.json");
    for model in index["models"].as_array().unwrap() {
        let name = model["name"].as_str().unwrap();
        // The .npz and plain-array .pkl conversions, and the original releases' layout: chumpy arrays and a
        // scipy CSC J_regressor.
        for ext in ["npz", "pkl", "chumpy.pkl"] {
            let file = if ext == "chumpy.pkl" {
                format!("smpl/{name}_chumpy.pkl")
            } else {
                format!("smpl/{name}.{ext}")
            };
            let smpl = SmplModel::read(&fixture(&file)).unwrap();
            assert_eq!(
                (smpl.num_joints(), smpl.num_vertices(), smpl.num_betas()),
                (
                    model["joints"].as_u64().unwrap() as usize,
                    model["vertices"].as_u64().unwrap() as usize,
                    model["betas"].as_u64().unwrap() as usize
                ),
                "{name}.{ext}: sizes from the file"
            );
            for (i, case) in model["cases"].as_array().unwrap().iter().enumerate() {
                let params = SmplParams {
                    betas: floats(&case["betas"]),
                    poses: floats(&case["poses"]),
                    rh: vec3(&case["Rh"]),
                    th: vec3(&case["Th"]),
                };
                for (correctives, key) in [(true, "with"), (false, "without")] {
                    let posed = smpl.pose(&params, correctives);
                    let what = format!("{name}.{ext} case {i} {key} correctives");
                    // Metres: the bound is 1e-5 m; f64 against f64 agrees far closer.
                    assert_close(
                        &format!("{what}: vertices"),
                        &flat(&posed.vertices),
                        &floats(&case[format!("vertices_{key}")]),
                        Tolerance::Absolute(1e-9),
                    );
                    assert_close(
                        &format!("{what}: joints"),
                        &flat(&posed.joints),
                        &floats(&case[format!("joints_{key}")]),
                        Tolerance::Absolute(1e-9),
                    );
                }
            }
        }
    }
}

#[test]
fn the_correctives_move_the_body_so_the_comparison_can_tell_them_apart() {
    let index = json("smpl/index.json");
    let case = &index["models"][0]["cases"][0];
    let with = floats(&case["vertices_with"]);
    let without = floats(&case["vertices_without"]);
    let moved = with
        .iter()
        .zip(&without)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(moved > 1e-4, "pose correctives move vertices by {moved} m");
}

/// The arrays of fixture model `name`, to break one at a time.
fn arrays(name: &str) -> BTreeMap<String, NdArray> {
    anerf_data::formats::npz::read_npz_arrays(&fixture(&format!("smpl/{name}.npz"))).unwrap()
}

fn error_of(arrays: &BTreeMap<String, NdArray>) -> String {
    SmplModel::from_arrays(arrays, Path::new("model.npz"))
        .unwrap_err()
        .to_string()
}

/// A model whose every array agrees on zero vertices is refused naming v_template (it used to panic
/// regressing joints over chunks of zero vertices).
#[test]
fn a_consistent_model_with_zero_vertices_is_refused() {
    let mut a = arrays("tree9");
    let k = a["weights"].shape()[1];
    let betas = a["shapedirs"].shape()[2];
    let empty = |shape: Vec<usize>| NdArray::new(shape, ArrayData::F64(Vec::new())).unwrap();
    a.insert("v_template".into(), empty(vec![0, 3]));
    a.insert("weights".into(), empty(vec![0, k]));
    a.insert("shapedirs".into(), empty(vec![0, 3, betas]));
    a.insert("posedirs".into(), empty(vec![0, 3, 9 * (k - 1)]));
    a.insert("J_regressor".into(), empty(vec![k, 0]));
    a.insert(
        "f".into(),
        NdArray::new(vec![0, 3], ArrayData::I64(Vec::new())).unwrap(),
    );
    let err = error_of(&a);
    assert!(
        err.contains("model.npz") && err.contains("v_template has no vertex"),
        "{err}"
    );
}

#[test]
fn a_missing_key_or_inconsistent_shapes_name_the_key_and_the_expected_shape() {
    let mut a = arrays("tree9");
    a.remove("posedirs");
    let err = error_of(&a);
    assert!(
        err.contains("model.npz") && err.contains("'posedirs'"),
        "{err}"
    );

    let mut a = arrays("tree9");
    let w = a["weights"].clone();
    let rows = w.shape()[0] - 1;
    a.insert(
        "weights".into(),
        NdArray::new(
            vec![rows, w.shape()[1]],
            ArrayData::F64(w.to_f64()[..rows * w.shape()[1]].to_vec()),
        )
        .unwrap(),
    );
    let err = error_of(&a);
    assert!(
        err.contains("weights has shape (59, 9), expected (60, any)"),
        "{err}"
    );

    let mut a = arrays("tree9");
    let j = a["J_regressor"].clone();
    a.insert(
        "J_regressor".into(),
        NdArray::new(vec![9, 30], ArrayData::F64(j.to_f64()[..270].to_vec())).unwrap(),
    );
    let err = error_of(&a);
    assert!(
        err.contains("J_regressor has shape (9, 30), expected (9, 60)"),
        "{err}"
    );

    let mut a = arrays("tree9");
    let mut pd = a["posedirs"].to_f64();
    pd[5] = f64::NAN;
    a.insert(
        "posedirs".into(),
        NdArray::new(a["posedirs"].shape().to_vec(), ArrayData::F64(pd)).unwrap(),
    );
    let err = error_of(&a);
    assert!(err.contains("posedirs holds a non-finite value"), "{err}");

    let mut a = arrays("tree9");
    let mut tree = a["kintree_table"].to_i64().unwrap();
    tree[3] = 5; // joint 3's parent after it
    a.insert(
        "kintree_table".into(),
        NdArray::new(vec![2, 9], ArrayData::I64(tree)).unwrap(),
    );
    let err = error_of(&a);
    assert!(err.contains("joint 3 the parent 5"), "{err}");
}

#[test]
fn a_sparse_matrix_index_outside_it_and_a_chumpy_object_without_its_array_are_refused_naming_the_file(
) {
    for (file, expected) in [
        ("bad_sparse.pkl", "indptr, indices and data disagree"),
        ("chumpy_without_x.pkl", "has no 'x' array"),
    ] {
        let path = fixture(&format!("smpl/{file}"));
        let err = anerf_data::formats::read_pickle(&path)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(file) && err.contains(expected),
            "{file}: {err}"
        );
    }
}

/// The body derived for the subject (`SmplModel::body`), posed by anerf's own skinning (core's bone
/// transforms and LBS, f32), lands where the model's forward pass without correctives puts it: for fully
/// driven fits and for fits that drive only the first joints (the rest folded into their ancestors).
#[test]
fn the_derived_body_skinned_by_core_equals_the_model_without_correctives() {
    use anerf_core::geometry::{forward_lbs_point, CanonicalPose, Pose};
    let index = json("smpl/index.json");
    for model in index["models"].as_array().unwrap() {
        let name = model["name"].as_str().unwrap();
        let smpl = SmplModel::read(&fixture(&format!("smpl/{name}.npz"))).unwrap();
        for (i, case) in model["cases"].as_array().unwrap().iter().enumerate() {
            let params = SmplParams {
                betas: floats(&case["betas"]),
                poses: floats(&case["poses"]),
                rh: vec3(&case["Rh"]),
                th: vec3(&case["Th"]),
            };
            let driven = params.poses.len() / 3;
            let body = smpl.body(&params.betas, driven);
            assert_eq!(body.skeleton.num_joints(), driven);
            assert_eq!(body.weights.num_joints(), driven);
            let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
            let rh = params.rh.as_vec3().to_array();
            let th = params.th.as_vec3().to_array();
            let pose = Pose::from_flat(&f32s(&params.poses), rh, th).unwrap();
            let bones = body
                .skeleton
                .bone_transforms(&pose, CanonicalPose::TPose)
                .unwrap();
            let ours: Vec<f64> = body
                .canonical_vertices
                .iter()
                .enumerate()
                .flat_map(|(v, &x)| {
                    let p = forward_lbs_point(x, body.weights.row(v), &bones).unwrap();
                    pose.global.pose_to_world(p).as_dvec3().to_array()
                })
                .collect();
            // f32 skinning of f64 reference values: the 1e-5 m bound.
            assert_close(
                &format!(
                    "{name} case {i} ({driven} of {} joints driven)",
                    smpl.num_joints()
                ),
                &ours,
                &floats(&case["vertices_without"]),
                Tolerance::Absolute(1e-5),
            );
        }
    }
}

//! Rodrigues and bone transforms against fixtures written by numpy/scipy (`scripts/fixtures/generate.py`).

use anerf_core::geometry::{
    axis_angle_to_matrix, matrix_to_axis_angle, CanonicalPose, Pose, Skeleton,
};
use glam::{Mat3, Mat4, Vec3};
use serde_json::Value;

fn load(name: &str) -> Value {
    anerf_testing::json(&format!("geometry/{name}"))
}

/// The fixture's numbers as the `f32` values glam takes.
fn floats(v: &Value) -> Vec<f32> {
    anerf_testing::floats(v)
        .into_iter()
        .map(|x| x as f32)
        .collect()
}

#[test]
fn rodrigues_matches_scipy() {
    let fixture = load("rodrigues.json");
    let cases = fixture["cases"].as_array().unwrap();
    assert!(cases.len() > 40);
    for case in cases {
        let rotvec = Vec3::from_slice(&floats(&case["rotvec"]));
        let expected = Mat3::from_cols_slice(&floats(&case["matrix"])).transpose();
        let got = axis_angle_to_matrix(rotvec);
        assert!(
            got.abs_diff_eq(expected, 1e-6),
            "{rotvec}: {got} vs {expected}"
        );
        // The inverse map recovers the rotation (the vector itself is ambiguous only at exactly π).
        assert!(
            axis_angle_to_matrix(matrix_to_axis_angle(expected)).abs_diff_eq(expected, 3e-5),
            "{rotvec}"
        );
    }
}

#[test]
fn bone_transforms_match_the_numpy_reference() {
    let fixture = load("bone_transforms.json");
    for case in fixture["cases"].as_array().unwrap() {
        let parents: Vec<i64> = case["parents"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p.as_i64().unwrap())
            .collect();
        let joints: Vec<Vec3> = floats(&case["joints"])
            .chunks(3)
            .map(Vec3::from_slice)
            .collect();
        let poses = floats(&case["poses"]);
        let expected = floats(&case["transforms"]);
        let skeleton = Skeleton::from_parent_table(joints, &parents).unwrap();
        let pose = Pose::from_flat(&poses, [0.0; 3], [0.0; 3]).unwrap();
        let a = skeleton
            .bone_transforms(&pose, CanonicalPose::TPose)
            .unwrap();
        for (k, m) in a.matrices().iter().enumerate() {
            let e = Mat4::from_cols_slice(&expected[16 * k..16 * k + 16]).transpose();
            assert!(
                m.abs_diff_eq(e, 2e-5),
                "joint {k} of {}: {m} vs {e}",
                parents.len()
            );
        }
    }
}

//! Helpers shared by the data integration tests: running the numpy checker on written files, copying and
//! cutting files (fixtures and comparison: the `anerf-testing` crate).

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use anerf_data::{BodyModel, Subject};
use glam::{Mat3, Vec3};
use serde_json::{json, Value};

/// Runs `scripts/fixtures/check_synthetic.py <folder> <manifest>` and fails the test, with the script's
/// output, when python3 or numpy is missing or any file does not read back as the manifest says.
pub fn numpy_check(folder: &Path, manifest: &serde_json::Value) {
    let manifest_path = folder.with_extension("manifest.json");
    std::fs::write(&manifest_path, serde_json::to_vec(manifest).unwrap()).unwrap();
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/fixtures/check_synthetic.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(folder)
        .arg(&manifest_path)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run python3 {}: {e} (python3 with numpy is required)",
                script.display()
            )
        });
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{} failed ({}):\n{stdout}\n{stderr}\n(install numpy: pip install -r scripts/fixtures/requirements.txt)",
        script.display(),
        out.status
    );
    println!("{}", stdout.trim());
}

/// Copies a fixture folder into a fresh temporary folder (for tests that break it).
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// Cuts the file at `path` to its first `keep(len)` bytes, as an interrupted copy leaves it.
pub fn cut_file(path: &Path, keep: impl FnOnce(usize) -> usize) {
    let bytes = std::fs::read(path).unwrap();
    std::fs::write(path, &bytes[..keep(bytes.len())]).unwrap();
}

/// A numpy array in a [`numpy_check`] manifest.
pub fn array(dtype: &str, shape: &[usize], data: Value) -> Value {
    json!({"__array__": {"dtype": dtype, "shape": shape, "data": data}})
}

/// A dict whose key order numpy must give back.
pub fn ordered(items: &[(&str, Value)]) -> Value {
    json!({"__dict__": items.iter().map(|(k, v)| json!([k, v])).collect::<Vec<_>>()})
}

pub fn f64s(values: impl IntoIterator<Item = f32>) -> Value {
    json!(values.into_iter().map(f64::from).collect::<Vec<_>>())
}

/// Row-major entries of a (column-major) glam matrix.
pub fn row_major(m: Mat3) -> Vec<f32> {
    (0..3)
        .flat_map(|r| (0..3).map(move |c| m.col(c)[r]))
        .collect()
}

pub fn flat(v: &[Vec3]) -> Vec<f32> {
    v.iter().flat_map(|p| p.to_array()).collect()
}

pub fn relative(root: &Path, path: &Path) -> String {
    path.strip_prefix(root)
        .unwrap()
        .to_string_lossy()
        .into_owned()
}

/// `annots.npy` as the ZJU-MoCap layout holds `subject`'s cameras (float64, `T` in millimetres) and image
/// paths (relative to its folder).
pub fn annots_entry(subject: &Subject) -> Value {
    let cams = &subject.cameras;
    let root = &subject.root;
    json!({
        "path": "annots.npy",
        "kind": "object",
        "expected": ordered(&[
            ("cams", ordered(&[
                ("K", cams.iter().map(|c| array("<f8", &[3, 3], f64s(row_major(c.intrinsics)))).collect()),
                ("D", cams.iter().map(|c| array("<f8", &[5, 1], f64s(c.distortion.0))).collect()),
                ("R", cams.iter().map(|c| array("<f8", &[3, 3], f64s(row_major(c.rotation)))).collect()),
                ("T", cams.iter().map(|c| array("<f8", &[3, 1], json!(c.translation.to_array().map(|t| f64::from(t) * 1000.0)))).collect()),
            ])),
            ("ims", subject.frames.iter().map(|f| json!({"ims": f.images.iter().map(|p| relative(root, p)).collect::<Vec<_>>()})).collect()),
        ])
    })
}

/// `lbs/{joints,parents,tvertices,weights,faces}.npy` of `body`, with their dtypes (parents: the root is
/// the uint32 sentinel, as SMPL's `kintree_table`).
pub fn lbs_entries(body: &BodyModel) -> Vec<Value> {
    let n = body.canonical_vertices.len();
    let k = body.skeleton.num_joints();
    let parents: Vec<i64> = body
        .skeleton
        .parents()
        .iter()
        .map(|p| p.map_or(4294967295, |p| p as i64))
        .collect();
    vec![
        json!({"path": "lbs/joints.npy", "kind": "npy", "expected": array("<f4", &[k, 3], json!(flat(body.skeleton.rest_joints())))}),
        json!({"path": "lbs/parents.npy", "kind": "npy", "expected": array("<i8", &[k], json!(parents))}),
        json!({"path": "lbs/tvertices.npy", "kind": "npy", "expected": array("<f4", &[n, 3], json!(flat(&body.canonical_vertices)))}),
        json!({"path": "lbs/weights.npy", "kind": "npy", "expected": array("<f4", &[n, k], json!(body.weights.as_slice()))}),
        json!({"path": "lbs/faces.npy", "kind": "npy", "expected": array("<i8", &[body.faces.len(), 3], json!(body.faces.iter().flatten().collect::<Vec<_>>()))}),
    ]
}

/// Every file under `root`, relative to it, sorted.
pub fn files_under(root: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

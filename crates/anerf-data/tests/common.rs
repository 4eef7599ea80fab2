//! Helpers shared by the integration tests: fixture paths and JSON.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// A fixture path; panics with the script to run when it is missing.
pub fn fixture(rel: &str) -> PathBuf {
    let path = anerf_core::fixtures_dir().join(rel);
    assert!(
        path.exists(),
        "fixture {} is missing; run `python3 scripts/fixtures/generate.py` (module datasets.py) first",
        path.display()
    );
    path
}

pub fn json(rel: &str) -> serde_json::Value {
    let path = fixture(rel);
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

pub fn floats(v: &serde_json::Value) -> Vec<f64> {
    match v {
        serde_json::Value::Array(items) => items.iter().flat_map(floats).collect(),
        serde_json::Value::Number(n) => vec![n.as_f64().unwrap()],
        other => panic!("not a number array: {other}"),
    }
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

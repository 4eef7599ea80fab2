//! Fixture files: written by `python3 scripts/fixtures/generate.py` (what `bash scripts/test.sh` runs first)
//! into `target/fixtures` of the workspace, or into `$ANERF_FIXTURES`.

use std::path::{Path, PathBuf};

use serde_json::Value;

/// The folder holding the fixtures: `$ANERF_FIXTURES`, else `target/fixtures` of the workspace.
pub fn fixtures_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("ANERF_FIXTURES") {
        return dir.into();
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/fixtures")
}

/// The path of fixture `rel` (relative to [`fixtures_dir`]); when it is missing the test fails with the
/// one line that makes it.
pub fn fixture(rel: &str) -> PathBuf {
    let path = fixtures_dir().join(rel);
    assert!(
        path.exists(),
        "fixture {} is missing: run `python3 scripts/fixtures/generate.py` (or `bash scripts/test.sh`, which \
         runs it and then the tests)",
        path.display()
    );
    path
}

/// Fixture `rel` parsed as JSON.
pub fn json(rel: &str) -> Value {
    let path = fixture(rel);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read fixture {}: {e}", path.display()));
    serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("fixture {} is not valid JSON: {e}", path.display()))
}

/// Every number of a (nested) JSON array, in order; panics on anything else.
pub fn floats(v: &Value) -> Vec<f64> {
    match v {
        Value::Array(items) => items.iter().flat_map(floats).collect(),
        Value::Number(n) => vec![n.as_f64().expect("a JSON number is an f64")],
        other => panic!("not a number array: {other}"),
    }
}

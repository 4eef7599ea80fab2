//! Helpers shared by the integration tests: reading fixtures written by `scripts/fixtures/generate.py`.
#![allow(dead_code)] // each test crate uses its own subset of these helpers

use std::path::PathBuf;

use serde_json::Value;

/// Path of fixture `name` written by `scripts/fixtures/<module>.py`.
pub fn fixture_path(module: &str, name: &str) -> PathBuf {
    anerf_core::fixtures_dir().join(module).join(name)
}

/// Parses a JSON fixture; panics with the script to run when it is missing.
pub fn load_json(module: &str, name: &str) -> Value {
    let path = fixture_path(module, name);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "cannot read fixture {}: {e}; run `python3 scripts/fixtures/generate.py` (module {module}.py) first",
            path.display()
        )
    });
    serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("fixture {} is not valid JSON: {e}", path.display()))
}

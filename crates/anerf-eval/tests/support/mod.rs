//! Helpers shared by the eval integration tests: the fixtures written by `scripts/fixtures/<module>.py`.
#![allow(dead_code)] // each test crate uses its own subset of these helpers

use std::path::PathBuf;

use serde_json::Value;

/// Path of fixture `name` written by `scripts/fixtures/<module>.py`.
pub fn fixture_path(module: &str, name: &str) -> PathBuf {
    anerf_testing::fixture(&format!("{module}/{name}"))
}

/// Fixture `name` of `scripts/fixtures/<module>.py`, parsed as JSON.
pub fn load_json(module: &str, name: &str) -> Value {
    anerf_testing::json(&format!("{module}/{name}"))
}

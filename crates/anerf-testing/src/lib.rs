//! Test support for the anerf crates, used only as a dev-dependency: the fixtures that
//! `scripts/fixtures/generate.py` writes with numpy, scipy and scikit-image, one way to compare values, and
//! a folder's snapshot, hand-written `.npy` headers, and the benches' timing.
//! It depends on no anerf crate, so every crate's unit and integration tests can use it.

pub mod close;
pub mod fixtures;
pub mod npy;
pub mod timing;
pub mod tree;

pub use close::{assert_close, worst_difference, Tolerance};
pub use fixtures::{fixture, fixtures_dir, floats, json};
pub use npy::npy_f64_header;
pub use timing::{report_ms, Xorshift};
pub use tree::tree_snapshot;

//! Synthetic subjects: a procedural animated human filmed by a ring of calibrated cameras, written in
//! the ZJU-MoCap layout (REFERENCE.md §1.1, §1.3) with ground truth for novel views and novel poses.
//! Needs no dataset and no SMPL licence; deterministic under a seed.

pub mod appearance;
pub mod body;
pub mod cameras;
pub mod motion;
pub mod raster;
mod rng;

use thiserror::Error;

pub use body::{build_body, Body, BodyShape};
pub use cameras::RigSpec;
pub use motion::{ClipSpec, MotionKind};

/// Errors of the generator; each names the option, file or folder at fault.
#[derive(Debug, Error)]
pub enum SynthError {
    #[error("invalid synthetic subject option {field}: {reason}")]
    InvalidSpec { field: String, reason: String },
}

impl SynthError {
    pub(crate) fn invalid(field: impl Into<String>, reason: impl Into<String>) -> Self {
        SynthError::InvalidSpec {
            field: field.into(),
            reason: reason.into(),
        }
    }
}

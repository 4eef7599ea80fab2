//! Errors of the geometry layer, and the error of a configuration value out of its range.

use std::fmt::Display;

use thiserror::Error;

/// A configuration value that is not allowed: its key (`model.width`), the value as given and what the key
/// accepts.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[error("{key} = {value}: expected {expected}")]
pub struct InvalidValue {
    pub key: String,
    pub value: String,
    pub expected: String,
}

impl InvalidValue {
    pub fn new(key: impl Into<String>, value: impl Display, expected: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            value: value.to_string(),
            expected: expected.into(),
        }
    }
}

/// Invalid skeletons, poses, weights or cameras, with the offending index and value.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum GeometryError {
    #[error("skeleton is empty: it needs at least one joint")]
    EmptySkeleton,
    #[error("skeleton has {joints} rest joints but {parents} parent entries")]
    ParentCountMismatch { joints: usize, parents: usize },
    #[error("joint 0 must be the root (no parent), but its parent is {parent}")]
    RootNotFirst { parent: usize },
    #[error("joint {joint} has no parent: only joint 0 may be the root")]
    SecondRoot { joint: usize },
    #[error(
        "joint {joint} has parent {parent}, expected an index below {joint} (parents must come before their \
         children; anything else is out of range or a cycle)"
    )]
    ParentNotBefore { joint: usize, parent: usize },
    #[error("{what} is not finite: {value}")]
    NonFinite { what: String, value: String },
    #[error("pose array has {len} numbers, expected 3 per joint")]
    PoseLength { len: usize },
    #[error("pose has {got} joint rotations, the skeleton has {expected} joints")]
    PoseSizeMismatch { expected: usize, got: usize },
    #[error("blend weights have {got} entries, the skeleton has {expected} joints")]
    WeightCountMismatch { expected: usize, got: usize },
    #[error("{got} blend weights for {points} points of {joints} joints; expected {points} rows of {joints}")]
    WeightRows {
        points: usize,
        joints: usize,
        got: usize,
    },
    #[error("point {index}: {source}")]
    AtPoint {
        index: usize,
        source: Box<GeometryError>,
    },
    #[error("blend weights must be non-negative and sum to 1 (±{tolerance}), got sum {sum}")]
    WeightsNotNormalised { sum: f32, tolerance: f32 },
    #[error(
        "blended skinning matrix is singular (|det| = {det:e}); the point cannot be un-skinned"
    )]
    SingularBlend { det: f32 },
    #[error("camera {what} is invalid: {detail}")]
    InvalidCamera { what: &'static str, detail: String },
    #[error("{got} blend weights do not form rows of {joints} joints")]
    RaggedWeights { got: usize, joints: usize },
    #[error("volume of {dims:?} nodes × {channels} channels needs {expected} values, got {got}")]
    VolumeSize {
        dims: [usize; 3],
        channels: usize,
        expected: usize,
        got: usize,
    },
    /// A box (volume bounds, grid origin and cell) that is empty, inverted or not finite.
    #[error("{what} {value} is empty or not finite")]
    EmptyBox { what: &'static str, value: String },
    #[error("occupancy grid: {cells} cells for dimensions {dims:?}")]
    GridCells { cells: usize, dims: [usize; 3] },
}

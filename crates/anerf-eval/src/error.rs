//! Errors of the evaluation layer: file errors that name the file, and the in-memory metric errors
//! (defined with the image types they are about, in `pixels`).

use std::path::PathBuf;

use thiserror::Error;

use crate::pixels::ImageSize;
pub use crate::pixels::MetricError;

/// Errors while reading, measuring or writing evaluation files; every variant names its file.
#[derive(Debug, Error)]
pub enum EvalError {
    #[error(transparent)]
    Write(#[from] anerf_data::atomic::WriteError),
    #[error("{path}: file not found; expected {expected}", path = path.display())]
    MissingFile {
        path: PathBuf,
        expected: &'static str,
    },
    #[error("{path}: unreadable image ({source}); expected a PNG or JPEG image", path = path.display())]
    UnreadableImage {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(
        "{path} is {got} pixels but {reference} is {expected}; expected the same size",
        path = path.display(),
        reference = reference.display()
    )]
    SizeMismatch {
        path: PathBuf,
        got: ImageSize,
        reference: PathBuf,
        expected: ImageSize,
    },
    #[error("mask {path} has no non-zero pixel; expected at least one foreground pixel", path = path.display())]
    EmptyMask { path: PathBuf },
    #[error("drawing a figure: {0}")]
    Draw(String),
    #[error("{context}: {source}")]
    Metric {
        context: String,
        source: MetricError,
    },
    #[error("{path}: {source}", path = path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: cannot encode ({source})", path = path.display())]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: invalid JSON ({source})", path = path.display())]
    Json {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: {detail}", path = path.display())]
    Format { path: PathBuf, detail: String },
    #[error("{what} is invalid: {detail}")]
    InvalidInput { what: &'static str, detail: String },
    #[error("ffmpeg failed writing {path} ({status}): {stderr}", path = path.display())]
    Ffmpeg {
        path: PathBuf,
        status: String,
        stderr: String,
    },
}

impl EvalError {
    /// An I/O error on `path`; a missing file becomes [`EvalError::MissingFile`] saying what was expected.
    pub(crate) fn io(
        path: impl Into<PathBuf>,
        expected: &'static str,
        source: std::io::Error,
    ) -> Self {
        let path = path.into();
        if source.kind() == std::io::ErrorKind::NotFound {
            EvalError::MissingFile { path, expected }
        } else {
            EvalError::Io { path, source }
        }
    }
}

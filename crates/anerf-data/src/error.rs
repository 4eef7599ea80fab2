//! Errors of the data layer: every one names the file (or folder) it is about and what was expected.

use std::path::PathBuf;

use thiserror::Error;

use crate::formats::npy::NpyError;
use crate::formats::pickle::PickleError;

/// A dataset or cache file that could not be used.
#[derive(Debug, Error)]
pub enum DataError {
    #[error("{}: cannot read: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: missing; expected {what}", path.display())]
    Missing { path: PathBuf, what: String },
    #[error("{}: {source}", path.display())]
    Npy {
        path: PathBuf,
        #[source]
        source: NpyError,
    },
    #[error("{}: {source}", path.display())]
    Pickle {
        path: PathBuf,
        #[source]
        source: PickleError,
    },
    #[error("{}: cannot decode image: {source}", path.display())]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    /// Readable, but the content is not what the layout requires (shape, value, count, path).
    #[error("{}: {detail}", path.display())]
    Invalid { path: PathBuf, detail: String },
    #[error(transparent)]
    Write(#[from] crate::atomic::WriteError),
}

impl DataError {
    /// The file or folder the error is about.
    pub fn path(&self) -> &std::path::Path {
        match self {
            DataError::Io { path, .. }
            | DataError::Missing { path, .. }
            | DataError::Npy { path, .. }
            | DataError::Pickle { path, .. }
            | DataError::Image { path, .. }
            | DataError::Invalid { path, .. } => path,
            DataError::Write(e) => &e.path,
        }
    }

    /// The content of `path` is not what its layout requires; `detail` (a message or a typed error) says
    /// how.
    pub(crate) fn invalid(path: impl Into<PathBuf>, detail: impl std::fmt::Display) -> Self {
        DataError::Invalid {
            path: path.into(),
            detail: detail.to_string(),
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        DataError::Io {
            path: path.into(),
            source,
        }
    }
}

//! On-disk formats of the datasets: `.npy`, `.npz`, restricted pickles, images and masks, and the writers of
//! `.npy` arrays and `np.save(dict)` pickles used by the synthetic subjects. The parsers work on bytes; the
//! functions here read files and attach the path to every error.

pub mod image_structure;
pub mod images;
pub mod npy;
pub mod npy_write;
pub mod npz;
pub mod opencv_yaml;
pub mod pickle;
pub mod pickle_write;

use std::path::Path;

use thiserror::Error;

use crate::error::DataError;
pub use npy::{ArrayData, DType, NdArray, ShapeMismatch};
pub use npy_write::write_npy;
pub use pickle::Value;
pub use pickle_write::{write_object_npy, PyValue};

/// Reads a whole regular file, naming it in the error. Anything else (a named pipe, a device, a socket, a
/// folder) is refused before it is opened: reading a FIFO would block forever.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    check_regular(path)?;
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// Refuses a path that is not a regular file (after following links), naming what it is.
pub fn check_regular(path: &Path) -> Result<(), DataError> {
    let meta = std::fs::metadata(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            DataError::Missing {
                path: path.to_path_buf(),
                what: "the file to exist".into(),
            }
        } else {
            DataError::io(path, e)
        }
    })?;
    let kind = meta.file_type();
    if kind.is_file() {
        return Ok(());
    }
    #[cfg(unix)]
    let what = {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() {
            "a named pipe (FIFO)"
        } else if kind.is_socket() {
            "a socket"
        } else if kind.is_block_device() || kind.is_char_device() {
            "a device"
        } else if kind.is_dir() {
            "a folder"
        } else {
            "not a regular file"
        }
    };
    #[cfg(not(unix))]
    let what = if kind.is_dir() {
        "a folder"
    } else {
        "not a regular file"
    };
    Err(DataError::invalid(
        path,
        format!("is {what}; expected a regular file"),
    ))
}

/// Reads a numeric `.npy` file.
pub fn read_npy(path: &Path) -> Result<NdArray, DataError> {
    npy::parse_array(&read_bytes(path)?).map_err(|source| DataError::Npy {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads an object `.npy` file written by `np.save(dict)` and returns the object (`.item()`).
pub fn read_npy_object(path: &Path) -> Result<Value, DataError> {
    npy::parse_object(&read_bytes(path)?).map_err(|source| DataError::Npy {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a `.pkl` file through the restricted unpickler.
pub fn read_pickle(path: &Path) -> Result<Value, DataError> {
    pickle::parse(&read_bytes(path)?).map_err(|source| DataError::Pickle {
        path: path.to_path_buf(),
        source,
    })
}

/// Errors of the `.npy` and pickle writers, naming the file or the array at fault.
#[derive(Debug, Error)]
pub enum FormatWriteError {
    #[error(transparent)]
    Shape(#[from] ShapeMismatch),
    #[error(
        "npy header for shape {shape:?} is {len} bytes; format version 1 allows at most 65535"
    )]
    HeaderTooLong { shape: Vec<usize>, len: usize },
    #[error("array of shape {shape:?} has {bytes} bytes; a protocol-3 pickle holds at most 4 GiB per buffer")]
    PickledArrayTooLarge { shape: Vec<usize>, bytes: usize },
    #[error("writing the .npz archive: {0}")]
    Archive(String),
    #[error(transparent)]
    Io(#[from] crate::atomic::WriteError),
}

//! On-disk formats of the datasets: `.npy`, `.npz`, restricted pickles, images and masks, and the writers of
//! `.npy` arrays and `np.save(dict)` pickles used by the synthetic subjects. The parsers work on bytes; the
//! functions here read files and attach the path to every error.

pub(crate) mod arrays;
pub mod image_structure;
pub mod images;
pub mod ndarray;
pub mod npy;
pub mod npy_write;
pub mod npz;
pub mod opencv_yaml;
pub mod pickle;
pub mod pickle_write;

use std::path::Path;

use thiserror::Error;

use crate::error::DataError;
pub use ndarray::{ArrayData, DType, NdArray, ShapeMismatch};
pub use npy_write::write_npy;
pub use pickle::Value;
pub use pickle_write::{write_object_npy, PyValue};

/// Reads a whole regular file, naming it in the error. Anything else (a named pipe, a device, a socket, a
/// folder) is refused before it is opened: reading a FIFO would block forever.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    check_regular(path)?;
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// Reads a whole regular file of at most `max` bytes, refusing a larger one before reading it; `what`
/// names the kind of file in the error ("an OpenCV calibration file"). A file that grows while it is
/// read is still cut at `max + 1` bytes and refused.
pub fn read_bytes_at_most(path: &Path, max: u64, what: &str) -> Result<Vec<u8>, DataError> {
    use std::io::Read;
    let too_large =
        |len: u64| DataError::invalid(path, format!("is {len} bytes; {what} may be at most {max}"));
    let len = check_regular(path)?.len();
    if len > max {
        return Err(too_large(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    std::fs::File::open(path)
        .and_then(|f| f.take(max + 1).read_to_end(&mut bytes))
        .map_err(|e| DataError::io(path, e))?;
    if bytes.len() as u64 > max {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// Refuses a path that is not a regular file (after following links), naming what it is; returns the
/// file's metadata otherwise.
pub fn check_regular(path: &Path) -> Result<std::fs::Metadata, DataError> {
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
        return Ok(meta);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A file of exactly the bound is read whole; one byte more is refused naming the file, its size and
    /// the bound; a folder is refused as not a regular file.
    #[test]
    fn files_past_the_bound_are_refused_before_reading() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("intri.yml");
        std::fs::write(&path, vec![b'x'; 100]).unwrap();
        assert_eq!(
            read_bytes_at_most(&path, 100, "a test file").unwrap().len(),
            100
        );
        let err = read_bytes_at_most(&path, 99, "a test file")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("intri.yml")
                && err.contains("is 100 bytes; a test file may be at most 99"),
            "{err}"
        );
        let err = read_bytes_at_most(dir.path(), 99, "a test file")
            .unwrap_err()
            .to_string();
        assert!(err.contains("is a folder"), "{err}");
    }
}

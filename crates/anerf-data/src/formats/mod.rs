//! On-disk formats of the datasets: `.npy`, `.npz`, restricted pickles, images and masks. The parsers work
//! on bytes; the functions here read files and attach the path to every error.

pub mod images;
pub mod npy;
pub mod npz;
pub mod pickle;

use std::path::Path;

use crate::error::DataError;
pub use npy::{ArrayData, DType, NdArray};
pub use pickle::Value;

/// Reads a whole file, naming it in the error.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            DataError::Missing {
                path: path.to_path_buf(),
                what: "the file to exist".into(),
            }
        } else {
            DataError::io(path, e)
        }
    })
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

//! On-disk formats of the datasets: numpy `.npy` arrays and the pickled dicts that `np.save` writes for
//! `annots.npy` and `new_params/*.npy`.

pub mod npy_write;
pub mod pickle_write;

use std::io::Write;
use std::path::{Path, PathBuf};

use thiserror::Error;

pub use npy_write::{write_npy, NpyArray, NpyData};
pub use pickle_write::{write_object_npy, PyValue};

/// Errors of the `.npy` and pickle writers, naming the file or the array at fault.
#[derive(Debug, Error)]
pub enum FormatWriteError {
    #[error("array of shape {shape:?} needs {expected} elements, got {got}")]
    ShapeMismatch {
        shape: Vec<usize>,
        expected: usize,
        got: usize,
    },
    #[error(
        "npy header for shape {shape:?} is {len} bytes; format version 1 allows at most 65535"
    )]
    HeaderTooLong { shape: Vec<usize>, len: usize },
    #[error("array of shape {shape:?} has {bytes} bytes; a protocol-3 pickle holds at most 4 GiB per buffer")]
    PickledArrayTooLarge { shape: Vec<usize>, bytes: usize },
    #[error("cannot write {}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// Writes `bytes` to `path` atomically: into a temporary file in the same folder, then renamed, so a
/// reader never sees a half-written file.
pub(crate) fn write_file_atomic(path: &Path, bytes: &[u8]) -> Result<(), FormatWriteError> {
    let io_err = |source| FormatWriteError::Io {
        path: path.to_path_buf(),
        source,
    };
    let name = path
        .file_name()
        .ok_or_else(|| io_err(std::io::Error::other("path has no file name")))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp-{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let result = std::fs::File::create(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.sync_data()))
        .and_then(|()| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io_err)
}

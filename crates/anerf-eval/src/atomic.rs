//! Atomic file writing: a temporary file in the destination's folder, renamed over it when complete, so a
//! failed or interrupted write never leaves a half-written file behind.

use std::io::Write;
use std::path::Path;

use crate::error::EvalError;

/// Creates `path`'s folder if needed, lets `write` fill a temporary file beside `path`, then renames it to
/// `path` ([`anerf_data::atomic`]). When `write` fails, an existing `path` is left untouched.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<(), EvalError>,
) -> Result<(), EvalError> {
    anerf_data::atomic::write_with(path, write, |e| io_error(path, e))
}

/// A temporary folder beside `path` (removed when dropped) for multi-file work whose result is then
/// renamed to `path`.
pub(crate) fn temp_dir_beside(path: &Path) -> Result<tempfile::TempDir, EvalError> {
    tempfile::Builder::new()
        .prefix(".anerf-")
        .tempdir_in(parent_dir(path)?)
        .map_err(|e| io_error(path, e))
}

/// `path`'s folder, created if missing.
fn parent_dir(path: &Path) -> Result<&Path, EvalError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| io_error(path, e))?;
    Ok(dir)
}

fn io_error(path: &Path, source: std::io::Error) -> EvalError {
    EvalError::Io {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn a_failed_write_leaves_neither_a_partial_file_nor_a_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nested").join("out.txt");
        write_atomic(&path, |w| {
            w.write_all(b"first").map_err(|e| EvalError::Io {
                path: "x".into(),
                source: e,
            })
        })
        .unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"first");

        let failure = write_atomic(&path, |w| {
            w.write_all(b"half of the sec").unwrap();
            Err(EvalError::InvalidInput {
                what: "test",
                detail: "fails mid-write".into(),
            })
        });
        assert!(matches!(failure, Err(EvalError::InvalidInput { .. })));
        assert_eq!(
            std::fs::read(&path).unwrap(),
            b"first",
            "the old file must survive a failed write"
        );
        assert_eq!(entries(&dir.path().join("nested")), ["out.txt"]);
    }
}

//! Atomic file writing, shared by every crate that writes results: a temporary file in the destination's
//! folder is filled, synced and renamed over the destination, so a failed or interrupted write (a full
//! disk, Ctrl-C) never leaves a half-written file and never damages an existing one.

use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// A write that failed, naming the file. Each crate's error type converts from it.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {source}", path.display())]
pub struct WriteError {
    pub path: PathBuf,
    #[source]
    pub source: io::Error,
}

impl WriteError {
    fn at(path: &Path) -> impl Fn(io::Error) -> WriteError + '_ {
        move |source| WriteError {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Lets `write` fill a temporary file beside `path` (creating the folder if needed), then renames it to
/// `path`. On any failure the temporary file is removed and `path` is untouched; `write`'s own error is
/// returned as it is.
pub fn write_with<E: From<WriteError>>(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<(), E>,
) -> Result<(), E> {
    let failed = WriteError::at(path);
    let dir = parent_dir(path)?;
    let mut builder = tempfile::Builder::new();
    builder.prefix(".anerf-").suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        // Results are for people to read: ordinary permissions, not tempfile's private 0600.
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    let temp = builder.tempfile_in(dir).map_err(&failed)?;
    {
        let mut writer = BufWriter::new(temp.as_file());
        write(&mut writer)?;
        writer.flush().map_err(&failed)?;
    }
    temp.as_file().sync_all().map_err(&failed)?;
    temp.persist(path).map_err(|e| failed(e.error))?;
    Ok(())
}

/// [`write_with`] for bytes already in memory.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_with(path, |w| w.write_all(bytes).map_err(WriteError::at(path)))
}

/// A temporary folder beside `path` (removed when dropped) for multi-file work whose result is then
/// renamed to `path`.
pub fn temp_dir_beside(path: &Path) -> Result<tempfile::TempDir, WriteError> {
    tempfile::Builder::new()
        .prefix(".anerf-")
        .tempdir_in(parent_dir(path)?)
        .map_err(WriteError::at(path))
}

/// Puts the finished folder `staging` (from [`temp_dir_beside`]) at `dest`: an existing `dest` is removed
/// only now that its replacement is complete, then `staging` takes its name.
pub fn replace_dir(staging: tempfile::TempDir, dest: &Path) -> Result<(), WriteError> {
    if dest.exists() {
        std::fs::remove_dir_all(dest).map_err(WriteError::at(dest))?;
    }
    let staged = staging.keep();
    std::fs::rename(&staged, dest).map_err(|e| {
        let _ = std::fs::remove_dir_all(&staged);
        WriteError::at(dest)(e)
    })
}

/// `path`'s folder, created if missing.
fn parent_dir(path: &Path) -> Result<&Path, WriteError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(WriteError::at(path))?;
    Ok(dir)
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
    fn a_failed_write_keeps_the_old_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/file.txt");
        write_bytes(&path, b"first").unwrap();
        let failed: Result<(), WriteError> = write_with(&path, |w| {
            w.write_all(b"half").map_err(WriteError::at(&path))?;
            Err(WriteError::at(&path)(io::Error::other("disk full")))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        assert_eq!(entries(path.parent().unwrap()), ["file.txt"]);
        write_bytes(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
    }

    /// The caller's own error comes back unchanged (here an error type of the caller's crate).
    #[test]
    fn a_failed_write_leaves_neither_a_partial_file_nor_a_temporary() {
        #[derive(Debug)]
        enum CallerError {
            Write,
            Invalid(&'static str),
        }
        impl From<WriteError> for CallerError {
            fn from(_: WriteError) -> Self {
                CallerError::Write
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nested").join("out.txt");
        write_with(&path, |w| {
            w.write_all(b"first").map_err(|_| CallerError::Write)
        })
        .unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        let failure = write_with(&path, |w| {
            w.write_all(b"half of the sec").unwrap();
            Err(CallerError::Invalid("fails mid-write"))
        });
        assert!(matches!(
            failure,
            Err(CallerError::Invalid("fails mid-write"))
        ));
        assert_eq!(
            std::fs::read(&path).unwrap(),
            b"first",
            "the old file must survive a failed write"
        );
        assert_eq!(entries(&dir.path().join("nested")), ["out.txt"]);
    }

    #[test]
    fn a_write_error_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        // A folder where the file's parent should be.
        let blocker = dir.path().join("blocker");
        std::fs::write(&blocker, b"a file").unwrap();
        let e = write_bytes(&blocker.join("out.txt"), b"x").unwrap_err();
        assert!(e.to_string().contains("out.txt"), "{e}");
    }
}

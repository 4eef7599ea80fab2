//! Atomic file writing, shared by every crate that writes results: a temporary file in the destination's
//! folder is filled, synced and renamed over the destination, so a failed or interrupted write (a full
//! disk, Ctrl-C) never leaves a half-written file and never damages an existing one.

use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Lets `write` fill a temporary file beside `path` (creating the folder if needed), then renames it to
/// `path`. On any failure the temporary file is removed and `path` is untouched. I/O errors of the
/// mechanism itself are turned into `E` by `io_error`.
pub fn write_with<E>(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<(), E>,
    io_error: impl Fn(io::Error) -> E,
) -> Result<(), E> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(&io_error)?;
    let mut builder = tempfile::Builder::new();
    builder.prefix(".anerf-").suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        // Results are for people to read: ordinary permissions, not tempfile's private 0600.
        builder.permissions(std::fs::Permissions::from_mode(0o644));
    }
    let temp = builder.tempfile_in(dir).map_err(&io_error)?;
    {
        let mut writer = BufWriter::new(temp.as_file());
        write(&mut writer)?;
        writer.flush().map_err(&io_error)?;
    }
    temp.as_file().sync_all().map_err(&io_error)?;
    temp.persist(path).map_err(|e| io_error(e.error))?;
    Ok(())
}

/// [`write_with`] for bytes already in memory.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_with(path, |w| w.write_all(bytes), |e| e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_write_keeps_the_old_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/file.txt");
        write_bytes(&path, b"first").unwrap();
        let failed: Result<(), io::Error> = write_with(
            &path,
            |w| w.write_all(b"half").and(Err(io::Error::other("disk full"))),
            |e| e,
        );
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"first");
        let names: Vec<_> = std::fs::read_dir(path.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("file.txt")]);
        write_bytes(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
    }
}

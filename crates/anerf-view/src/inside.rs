//! The one rule for every file the viewer reads or sends: a regular file inside the run folder, after
//! following links.

use std::path::{Path, PathBuf};

use anerf_data::paths::{Folder, Located};
use anerf_train::run_dir::RunDir;

/// Why [`inside_run`] refused a path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outside {
    Missing,
    /// Not a regular file (a folder, a FIFO, a device).
    NotAFile,
    /// Resolved through symbolic links, it lies outside the run folder.
    LeadsOut,
}

impl std::fmt::Display for Outside {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Outside::Missing => "does not exist",
            Outside::NotAFile => "is not a regular file",
            Outside::LeadsOut => "leads outside the run folder (a symbolic link); refused",
        })
    }
}

/// `path` resolved, when it is a regular file inside the run folder: the one rule for every file the
/// viewer reads or sends, so that a link inside the run never serves what lies outside it.
pub fn inside_run(run: &RunDir, path: &Path) -> Result<PathBuf, Outside> {
    match Folder::new(&run.root, "run folder").locate(path) {
        Located::Inside(file) if file.is_file() => Ok(file),
        Located::Inside(_) => Err(Outside::NotAFile),
        Located::Outside(_) => Err(Outside::LeadsOut),
        Located::Missing => Err(Outside::Missing),
    }
}

//! The path policy of everything anerf writes: a name that comes from input (a file's stem, a config's
//! `name`) becomes one plain path component before it is joined to a folder, so it never leaves that
//! folder; an output folder never holds, nor lies inside, an input of the same command; and a folder is
//! replaced (`--overwrite`) only when anerf's marker says anerf made it for that purpose. And the policy of
//! everything anerf reads from a folder (a dataset, a run): a file must lie inside it after symbolic links
//! are followed ([`Folder`]).

use std::io;
use std::path::{Component, Path, PathBuf};

/// Longest name [`safe_component`] returns, in bytes (well under every file system's 255).
const MAX_NAME: usize = 80;

/// `raw` as one safe path component: ASCII letters, digits, `-`, `_`, `+` and `.` kept, every other
/// character replaced by `_`, leading dots dropped (no `.`, `..` or hidden names), at most 80 bytes;
/// `fallback` when nothing is left.
pub fn safe_component(raw: &str, fallback: &str) -> String {
    let mapped: String = raw
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '+' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    let trimmed = mapped.trim_start_matches('.');
    let mut name: String = trimmed.chars().take(MAX_NAME).collect();
    while name.ends_with('.') {
        name.pop();
    }
    if name.is_empty() {
        fallback.to_string()
    } else {
        name
    }
}

/// Why a name cannot be one folder's: its message completes "the name …".
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    #[error("is empty")]
    Empty,
    #[error("contains a path separator or NUL")]
    Separator,
    #[error("is '.' or '..', which name a folder that already exists")]
    Dots,
}

/// Whether `name` is one plain path component (not empty, `.` or `..`, no separator or NUL): what a
/// name from a config must be before it names a folder.
pub fn check_component(name: &str) -> Result<(), NameError> {
    if name.is_empty() {
        return Err(NameError::Empty);
    }
    if name.contains(['/', '\\', '\0']) {
        return Err(NameError::Separator);
    }
    match Path::new(name).components().collect::<Vec<_>>().as_slice() {
        [Component::Normal(_)] => Ok(()),
        _ => Err(NameError::Dots),
    }
}

/// `path` made absolute with its existing part resolved through symbolic links (the part that does not
/// exist yet appended as written), so that two paths to one place compare equal.
pub fn resolved(path: &Path) -> io::Result<PathBuf> {
    let mut existing = std::path::absolute(path)?;
    let mut rest = Vec::new();
    while !existing.exists() {
        match (
            existing.file_name().map(ToOwned::to_owned),
            existing.parent(),
        ) {
            (Some(name), Some(parent)) => {
                rest.push(name);
                existing = parent.to_path_buf();
            }
            _ => break,
        }
    }
    let mut out = existing.canonicalize().unwrap_or(existing);
    out.extend(rest.iter().rev());
    Ok(out)
}

/// A folder whose files must lie inside it after symbolic links are followed: a dataset read by the
/// loaders, a run served by the viewer. `what` names it in errors ("dataset folder").
pub struct Folder {
    /// The folder resolved through symbolic links (as given when it cannot be resolved).
    root: PathBuf,
    what: &'static str,
}

/// Where a path leads, resolved through symbolic links.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Located {
    /// Inside the folder, at this resolved path.
    Inside(PathBuf),
    /// Outside it, at this resolved path.
    Outside(PathBuf),
    /// Nothing there (or it cannot be resolved).
    Missing,
}

impl Folder {
    pub fn new(root: &Path, what: &'static str) -> Self {
        Self {
            root: root.canonicalize().unwrap_or_else(|_| root.to_path_buf()),
            what,
        }
    }

    /// Where `path` leads.
    pub fn locate(&self, path: &Path) -> Located {
        match path.canonicalize() {
            Ok(real) if real.starts_with(&self.root) => Located::Inside(real),
            Ok(real) => Located::Outside(real),
            Err(_) => Located::Missing,
        }
    }

    /// Refuses a file that resolves outside the folder, naming where it leads, never what it holds. A file
    /// that does not exist is left for its reader to report.
    pub fn check(&self, path: &Path) -> Result<(), crate::error::DataError> {
        match self.locate(path) {
            Located::Outside(real) => Err(crate::error::DataError::invalid(
                path,
                format!(
                    "leads through a symbolic link to {}, outside the {} {}; its files must lie inside it",
                    real.display(),
                    self.what,
                    self.root.display()
                ),
            )),
            Located::Inside(_) | Located::Missing => Ok(()),
        }
    }
}

/// How an output folder and an input of the same command overlap.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overlap {
    /// The output is the input or lies inside it.
    Inside,
    /// The output holds the input: replacing the output would delete the input.
    Holds,
}

/// Whether the output folder `out` and the input `input` (a file or folder) overlap, after both are
/// resolved ([`resolved`]).
pub fn overlap(out: &Path, input: &Path) -> io::Result<Option<Overlap>> {
    let (out, input) = (resolved(out)?, resolved(input)?);
    Ok(if out.starts_with(&input) {
        Some(Overlap::Inside)
    } else if input.starts_with(&out) {
        Some(Overlap::Holds)
    } else {
        None
    })
}

/// The file anerf writes into a folder it makes for `purpose` (e.g. `"import"`), so that `--overwrite` can
/// tell that folder from one it did not make.
pub fn marker(dir: &Path, purpose: &str) -> PathBuf {
    dir.join(format!(".anerf-{purpose}"))
}

/// Whether `dir` holds anerf's marker for `purpose` (a regular file, not a link).
pub fn has_marker(dir: &Path, purpose: &str) -> bool {
    std::fs::symlink_metadata(marker(dir, purpose)).is_ok_and(|m| m.is_file())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_safe_component_is_one_plain_name_that_stays_in_its_folder() {
        for raw in [
            "..",
            ".",
            "...",
            "../../etc",
            "/etc/passwd",
            "a/b",
            "a\\b",
            "",
            "\0",
            ".hidden",
        ] {
            let name = safe_component(raw, "motion");
            assert!(check_component(&name).is_ok(), "{raw:?} -> {name:?}");
            assert!(!name.starts_with('.'), "{raw:?} -> {name:?}");
            let dir = Path::new("/runs/x/motions");
            let joined = dir.join(&name);
            assert_eq!(joined.parent(), Some(dir), "{raw:?} -> {name:?}");
        }
        assert_eq!(safe_component("..", "motion"), "motion");
        assert_eq!(safe_component("walk_01-b.v2", "m"), "walk_01-b.v2");
        assert_eq!(safe_component("tänzer 1", "m"), "t_nzer_1");
        assert_eq!(safe_component(&"x".repeat(300), "m").len(), MAX_NAME);
    }

    #[test]
    fn check_component_refuses_what_would_name_another_folder() {
        for (bad, why) in [
            ("", NameError::Empty),
            (".", NameError::Dots),
            ("..", NameError::Dots),
            ("a/b", NameError::Separator),
            ("/", NameError::Separator),
            ("a\\b", NameError::Separator),
            ("a\0b", NameError::Separator),
        ] {
            assert_eq!(check_component(bad), Err(why), "{bad:?}");
        }
        for good in ["subject", "my run", "...x", "a.b"] {
            assert!(check_component(good).is_ok(), "{good:?}");
        }
    }

    #[test]
    fn overlap_sees_through_dots_and_links() {
        let dir = tempfile::tempdir().unwrap();
        let capture = dir.path().join("work/capture");
        std::fs::create_dir_all(&capture).unwrap();
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(dir.path().join("work"), &link).unwrap();
        let work = dir.path().join("work");
        assert_eq!(overlap(&work, &capture).unwrap(), Some(Overlap::Holds));
        assert_eq!(overlap(&link, &capture).unwrap(), Some(Overlap::Holds));
        assert_eq!(
            overlap(&capture.join("../capture/out"), &capture).unwrap(),
            Some(Overlap::Inside)
        );
        assert_eq!(overlap(&capture, &capture).unwrap(), Some(Overlap::Inside));
        assert_eq!(
            overlap(&dir.path().join("elsewhere"), &capture).unwrap(),
            None
        );
        // A sibling whose name starts with the input's is not inside it.
        assert_eq!(
            overlap(&dir.path().join("work/capture2"), &capture).unwrap(),
            None
        );
    }
}

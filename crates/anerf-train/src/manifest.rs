//! `manifest.json`: the length and SHA-256 digest of each file a folder was written with (checkpoints,
//! baked avatars). It is written last, so a folder whose manifest reads back was written whole, and its
//! files are checked against it before they are trusted (truncated, altered or half-deleted files are
//! named).

use std::fs;
use std::path::Path;

use anerf_data::atomic::write_bytes;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// The manifest's file name.
pub const MANIFEST: &str = "manifest.json";

/// What each file of a folder held when it was written.
#[derive(Debug, Serialize, Deserialize)]
pub struct Manifest {
    files: Vec<FileRecord>,
}

#[derive(Debug, Serialize, Deserialize)]
struct FileRecord {
    name: String,
    bytes: u64,
    /// SHA-256 of the contents, lower-case hex.
    sha256: String,
}

impl FileRecord {
    fn of(dir: &Path, name: &str) -> Result<Self> {
        let path = dir.join(name);
        let bytes = fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        Ok(Self {
            name: name.into(),
            bytes: bytes.len() as u64,
            sha256: hex_digest(&bytes),
        })
    }

    /// Fails, naming the file, when it is missing or differs from the record.
    fn check(&self, dir: &Path) -> Result<()> {
        let path = dir.join(&self.name);
        let bytes = fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        if bytes.len() as u64 != self.bytes {
            bail!(
                "{} has {} bytes, {} were written (truncated or replaced)",
                path.display(),
                bytes.len(),
                self.bytes
            );
        }
        if hex_digest(&bytes) != self.sha256 {
            bail!(
                "{} differs from what was written (its SHA-256 does not match the manifest)",
                path.display()
            );
        }
        Ok(())
    }
}

fn hex_digest(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

impl Manifest {
    /// Records the files `names` of `dir` (written and synced already) in `dir/manifest.json`.
    pub fn write(dir: &Path, names: &[&str]) -> Result<()> {
        let manifest = Manifest {
            files: names
                .iter()
                .map(|n| FileRecord::of(dir, n))
                .collect::<Result<_>>()?,
        };
        write_bytes(
            &dir.join(MANIFEST),
            serde_json::to_string_pretty(&manifest)?.as_bytes(),
        )?;
        Ok(())
    }

    /// The manifest of `dir`, `None` where it has none.
    pub fn read(dir: &Path) -> Result<Option<Manifest>> {
        let path = dir.join(MANIFEST);
        if !path.exists() {
            return Ok(None);
        }
        let text =
            fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let manifest = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a manifest of files", path.display()))?;
        Ok(Some(manifest))
    }

    /// Checks every recorded file of `dir` against its record.
    pub fn check(&self, dir: &Path) -> Result<()> {
        self.files.iter().try_for_each(|f| f.check(dir))
    }
}

//! `.npz` archives (`np.savez` / `np.savez_compressed`): a zip of `.npy` members.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use super::npy::{self, Descr, NdArray};
use super::npy_write::npy_bytes;
use super::FormatWriteError;
use crate::atomic::write_bytes;
use crate::error::DataError;

/// An opened `.npz` archive: every member's name and header (kind, shape) read, no array data inflated
/// yet. [`Npz::array`] reads one member, so members a reader does not use cost nothing, and each read is
/// checked against a byte budget before anything is inflated or allocated.
pub struct Npz {
    path: PathBuf,
    archive: zip::ZipArchive<std::fs::File>,
    members: BTreeMap<String, Member>,
    budget: u64,
}

/// One member as its headers describe it.
#[derive(Debug, Clone)]
struct Member {
    index: usize,
    kind: MemberKind,
    /// The uncompressed size the zip directory declares.
    declared: u64,
}

/// What a member holds, from its `.npy` header.
#[derive(Debug, Clone, PartialEq)]
pub enum MemberKind {
    Numeric {
        shape: Vec<usize>,
        bytes: u64,
    },
    /// `"strings"`, `"bytes"` or `"pickled objects"`: named, never unpickled.
    Other(&'static str),
}

/// Bytes one member may inflate to ([`Npz::array`]): four times the largest array of the SMPL-family
/// models (SMPL-X's `posedirs`, 10475 × 3 × 486 float64, 122 MB) with room to spare.
pub const MEMBER_BUDGET: u64 = 1 << 30;

/// Largest accepted ratio of a member's uncompressed size to the archive's size (deflate reaches ~1000).
pub const MAX_EXPANSION: u64 = 1024;

/// Bytes read of a member to parse its `.npy` header (numpy writes headers of a few hundred bytes).
const HEADER_PEEK: u64 = 64 * 1024;

impl Npz {
    /// Opens `path` with the [`MEMBER_BUDGET`].
    pub fn open(path: &Path) -> Result<Self, DataError> {
        Self::open_with_budget(path, MEMBER_BUDGET)
    }

    /// Opens `path`, reading the zip directory and each member's `.npy` header only.
    pub fn open_with_budget(path: &Path, budget: u64) -> Result<Self, DataError> {
        super::check_regular(path)?;
        let invalid = |detail: String| DataError::invalid(path, detail);
        let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
        let archive_len = file.metadata().map_err(|e| DataError::io(path, e))?.len();
        let mut archive = zip::ZipArchive::new(file)
            .map_err(|e| invalid(format!("not a readable .npz (zip) archive: {e}")))?;
        let budget = budget.min(archive_len.max(1).saturating_mul(MAX_EXPANSION));
        let mut members = BTreeMap::new();
        for index in 0..archive.len() {
            let member = archive
                .by_index(index)
                .map_err(|e| invalid(format!("zip member {index}: {e}")))?;
            let name = member.name().trim_end_matches(".npy").to_string();
            let declared = member.size();
            let mut head = Vec::new();
            member
                .take(HEADER_PEEK)
                .read_to_end(&mut head)
                .map_err(|e| invalid(format!("member {name}: {e}")))?;
            let header =
                npy::peek_header(&head).map_err(|e| invalid(format!("member {name}: {e}")))?;
            let kind = match header.descr {
                Descr::Numeric { dtype, .. } => MemberKind::Numeric {
                    bytes: npy::element_count(&header.shape)
                        .and_then(|n| n.checked_mul(dtype.size()))
                        .map_or(u64::MAX, |b| b as u64),
                    shape: header.shape,
                },
                Descr::Unicode { .. } => MemberKind::Other("strings"),
                Descr::Bytes { .. } => MemberKind::Other("bytes"),
                Descr::Object => MemberKind::Other("pickled objects"),
            };
            if members.contains_key(&name) {
                return Err(invalid(format!("holds the member {name} twice")));
            }
            members.insert(
                name,
                Member {
                    index,
                    kind,
                    declared,
                },
            );
        }
        Ok(Self {
            path: path.to_path_buf(),
            archive,
            members,
            budget,
        })
    }

    /// Every member's name, in order.
    pub fn names(&self) -> Vec<&str> {
        self.members.keys().map(String::as_str).collect()
    }

    /// What member `name` holds; `None` when there is no such member.
    pub fn kind(&self, name: &str) -> Option<&MemberKind> {
        self.members.get(name).map(|m| &m.kind)
    }

    /// Reads the numeric member `name`. Its size from the header and from the zip directory must both be
    /// within the budget (and the directory's must hold the header's data) before it is inflated; no more
    /// than the declared bytes are inflated.
    pub fn array(&mut self, name: &str) -> Result<NdArray, DataError> {
        let invalid = |detail: String| DataError::invalid(&self.path, detail);
        let member = self.members.get(name).cloned().ok_or_else(|| {
            invalid(format!(
                "has no member {name} (it has {})",
                self.names().join(", ")
            ))
        })?;
        let bytes = match &member.kind {
            MemberKind::Numeric { bytes, .. } => *bytes,
            MemberKind::Other(kind) => {
                return Err(invalid(format!(
                    "member {name} holds {kind}; expected a numeric array (object arrays are never \
                     unpickled)"
                )))
            }
        };
        for (what, size) in [
            ("its header's shape needs", bytes),
            ("the archive declares", member.declared),
        ] {
            if size > self.budget {
                return Err(invalid(format!(
                    "member {name}: {what} {size} bytes; at most {} may be read (the lesser of {} and \
                     {MAX_EXPANSION}× the archive's size)",
                    self.budget, MEMBER_BUDGET
                )));
            }
        }
        if member.declared < bytes {
            return Err(invalid(format!(
                "member {name}: its header's shape needs {bytes} bytes of data but the archive declares only \
                 {} bytes for it (truncated)",
                member.declared
            )));
        }
        let mut data = Vec::with_capacity(member.declared as usize);
        self.archive
            .by_index(member.index)
            .map_err(|e| invalid(format!("member {name}: {e}")))?
            .take(member.declared)
            .read_to_end(&mut data)
            .map_err(|e| invalid(format!("member {name}: {e}")))?;
        npy::parse_array(&data).map_err(|e| invalid(format!("member {name}: {e}")))
    }
}

/// Reads every numeric member of an `.npz` file (small archives whose every array is wanted, e.g. tests
/// and fixtures), keyed by member name without `.npy`.
pub fn read_npz_arrays(path: &Path) -> Result<BTreeMap<String, NdArray>, DataError> {
    let mut npz = Npz::open(path)?;
    let names: Vec<String> = npz
        .members
        .iter()
        .filter(|(_, m)| matches!(m.kind, MemberKind::Numeric { .. }))
        .map(|(n, _)| n.clone())
        .collect();
    names
        .into_iter()
        .map(|n| Ok((n.clone(), npz.array(&n)?)))
        .collect()
}

/// Writes `members` as an uncompressed `.npz` archive (as `np.savez` does), atomically.
pub fn write_npz(path: &Path, members: &[(&str, &NdArray)]) -> Result<(), FormatWriteError> {
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let options =
        zip::write::FileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for (name, array) in members {
        let bytes = npy_bytes(array)?;
        zip.start_file(format!("{name}.npy"), options)
            .and_then(|()| zip.write_all(&bytes).map_err(Into::into))
            .map_err(|e| FormatWriteError::Archive(format!("member {name}: {e}")))?;
    }
    let archive = zip
        .finish()
        .map_err(|e| FormatWriteError::Archive(e.to_string()))?
        .into_inner();
    Ok(write_bytes(path, &archive)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::ArrayData;

    #[test]
    fn written_archives_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npz");
        let x = NdArray::new(vec![2, 3], ArrayData::F64((0..6).map(f64::from).collect())).unwrap();
        let rate = NdArray::new(vec![], ArrayData::F32(vec![120.0])).unwrap();
        write_npz(&path, &[("poses", &x), ("mocap_framerate", &rate)]).unwrap();
        let mut npz = Npz::open(&path).unwrap();
        assert_eq!(npz.names(), ["mocap_framerate", "poses"]);
        assert_eq!(
            npz.kind("poses"),
            Some(&MemberKind::Numeric {
                shape: vec![2, 3],
                bytes: 48
            })
        );
        assert_eq!(npz.array("poses").unwrap(), x);
        assert_eq!(npz.array("mocap_framerate").unwrap(), rate);
        assert!(npz
            .array("trans")
            .unwrap_err()
            .to_string()
            .contains("has no member trans"));
    }
}

//! `.npz` archives (`np.savez` / `np.savez_compressed`): a zip of `.npy` members.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::Path;

use super::npy::{self, Descr, NdArray};
use super::npy_write::npy_bytes;
use super::FormatWriteError;
use crate::atomic::write_bytes;
use crate::error::DataError;

/// The members of an `.npz` archive: numeric arrays, and what the others hold (strings, pickled objects),
/// named but never unpickled.
#[derive(Debug, Clone, PartialEq)]
pub struct Npz {
    pub arrays: BTreeMap<String, NdArray>,
    /// Non-numeric members by name: `"strings"`, `"bytes"` or `"pickled objects"`.
    pub others: BTreeMap<String, &'static str>,
}

impl Npz {
    /// Every member's name, in order.
    pub fn names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = self
            .arrays
            .keys()
            .chain(self.others.keys())
            .map(String::as_str)
            .collect();
        names.sort_unstable();
        names
    }
}

/// Reads an `.npz` file, keyed by member name without `.npy`.
///
/// A member may not claim more uncompressed bytes than [`MAX_EXPANSION`] times the archive's size, so a
/// zip bomb is refused before it is inflated.
pub fn read_npz(path: &Path) -> Result<Npz, DataError> {
    let bytes = super::read_bytes(path)?;
    let invalid = |detail: String| DataError::invalid(path, detail);
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(&bytes))
        .map_err(|e| invalid(format!("not a readable .npz (zip) archive: {e}")))?;
    let limit = (bytes.len() as u64).saturating_mul(MAX_EXPANSION);
    let mut out = Npz {
        arrays: BTreeMap::new(),
        others: BTreeMap::new(),
    };
    for i in 0..archive.len() {
        let mut member = archive
            .by_index(i)
            .map_err(|e| invalid(format!("zip member {i}: {e}")))?;
        let name = member.name().trim_end_matches(".npy").to_string();
        if member.size() > limit {
            return Err(invalid(format!(
                "member {name} claims {} bytes, more than {MAX_EXPANSION}× the archive",
                member.size()
            )));
        }
        let mut data = Vec::with_capacity(member.size() as usize);
        (&mut member)
            .take(limit)
            .read_to_end(&mut data)
            .map_err(|e| invalid(format!("member {name}: {e}")))?;
        let member_error = |e: npy::NpyError| invalid(format!("member {name}: {e}"));
        let kind = match npy::peek_descr(&data).map_err(member_error)? {
            Descr::Numeric { .. } => {
                let arr = npy::parse_array(&data).map_err(member_error)?;
                out.arrays.insert(name, arr);
                continue;
            }
            Descr::Unicode { .. } => "strings",
            Descr::Bytes { .. } => "bytes",
            Descr::Object => "pickled objects",
        };
        out.others.insert(name, kind);
    }
    Ok(out)
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

/// Largest accepted ratio of uncompressed member size to archive size.
pub const MAX_EXPANSION: u64 = 1024;

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
        let npz = read_npz(&path).unwrap();
        assert_eq!(npz.arrays["poses"], x);
        assert_eq!(npz.arrays["mocap_framerate"], rate);
        assert_eq!(npz.names(), ["mocap_framerate", "poses"]);
    }
}

//! `.npz` archives (`np.savez` / `np.savez_compressed`): a zip of `.npy` members.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use super::npy::{self, NdArray};
use crate::error::DataError;

/// Reads every numeric member of an `.npz` file, keyed by name without `.npy`.
///
/// A member may not claim more uncompressed bytes than [`MAX_EXPANSION`] times the archive's size, so a
/// zip bomb is refused before it is inflated.
pub fn read_npz(path: &Path) -> Result<BTreeMap<String, NdArray>, DataError> {
    let bytes = super::read_bytes(path)?;
    let invalid = |detail: String| DataError::invalid(path, detail);
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(&bytes))
        .map_err(|e| invalid(format!("not a readable .npz (zip) archive: {e}")))?;
    let limit = (bytes.len() as u64).saturating_mul(MAX_EXPANSION);
    let mut out = BTreeMap::new();
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
        let arr = npy::parse_array(&data).map_err(|e| invalid(format!("member {name}: {e}")))?;
        out.insert(name, arr);
    }
    Ok(out)
}

/// Largest accepted ratio of uncompressed member size to archive size.
pub const MAX_EXPANSION: u64 = 1024;

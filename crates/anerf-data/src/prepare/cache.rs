//! The preparation cache: a folder per input fingerprint (`<cache>/v2/<hash>/`), files written atomically
//! (temporary file in the same folder, then rename), and a small binary format for volumes.

use std::path::{Path, PathBuf};

use anerf_core::geometry::Aabb;
use anerf_core::geometry::BlendWeightVolume;
use glam::Vec3;
use sha2::{Digest, Sha256};

use crate::error::DataError;

/// Bumped whenever the cache layout or any preparation algorithm changes.
pub const CACHE_VERSION: &str = "v2";

/// A SHA-256 fingerprint of everything a prepared subject depends on.
pub struct Fingerprint(Sha256);

impl Default for Fingerprint {
    /// A fingerprint seeded with [`CACHE_VERSION`].
    fn default() -> Self {
        let mut h = Sha256::new();
        h.update(CACHE_VERSION.as_bytes());
        Self(h)
    }
}

impl Fingerprint {
    /// Adds a labelled value (labels keep adjacent fields from running together).
    pub fn add(&mut self, label: &str, bytes: &[u8]) {
        self.0.update((label.len() as u64).to_le_bytes());
        self.0.update(label.as_bytes());
        self.0.update((bytes.len() as u64).to_le_bytes());
        self.0.update(bytes);
    }

    /// Adds a file by path, size and modification time (reading every image would cost as much as
    /// preparing it; any edit changes the size or the time).
    pub fn add_file(&mut self, path: &Path) -> Result<(), DataError> {
        let meta = std::fs::metadata(path).map_err(|e| DataError::io(path, e))?;
        let mtime = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        self.add("file", path.to_string_lossy().as_bytes());
        self.0.update(meta.len().to_le_bytes());
        self.0.update(mtime.to_le_bytes());
        Ok(())
    }

    /// The hex digest (first 16 bytes: ample to tell inputs apart).
    pub fn hex(self) -> String {
        self.0.finalize()[..16]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

const VOLUME_MAGIC: &[u8; 8] = b"ANBWV1\0\0";

/// Serialises a volume: magic, dims (3 × u64), joints (u64), bounds (6 × f32), then the values, all
/// little-endian.
pub fn volume_bytes(v: &BlendWeightVolume) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + 4 * v.data.len());
    out.extend(VOLUME_MAGIC);
    for d in v.dims {
        out.extend((d as u64).to_le_bytes());
    }
    out.extend((v.num_joints as u64).to_le_bytes());
    for x in v
        .bounds
        .min
        .to_array()
        .into_iter()
        .chain(v.bounds.max.to_array())
    {
        out.extend(x.to_le_bytes());
    }
    for x in &v.data {
        out.extend(x.to_le_bytes());
    }
    out
}

/// Reads a volume written by [`volume_bytes`].
pub fn read_volume(path: &Path) -> Result<BlendWeightVolume, DataError> {
    let bytes = crate::formats::read_bytes(path)?;
    let bad =
        |why: &str| DataError::invalid(path, format!("not a blend-weight volume file: {why}"));
    if bytes.len() < 64 || &bytes[..8] != VOLUME_MAGIC {
        return Err(bad("bad magic or too short"));
    }
    let u = |i: usize| {
        u64::from_le_bytes(bytes[8 + 8 * i..16 + 8 * i].try_into().expect("8 bytes")) as usize
    };
    let dims = [u(0), u(1), u(2)];
    let joints = u(3);
    let f =
        |i: usize| f32::from_le_bytes(bytes[40 + 4 * i..44 + 4 * i].try_into().expect("4 bytes"));
    let bounds = Aabb {
        min: Vec3::new(f(0), f(1), f(2)),
        max: Vec3::new(f(3), f(4), f(5)),
    };
    let body = &bytes[64..];
    let expected = dims
        .iter()
        .try_fold(joints.saturating_add(1), |acc, &d| acc.checked_mul(d))
        .and_then(|n| n.checked_mul(4));
    if expected != Some(body.len()) {
        return Err(bad("size does not match its header"));
    }
    let data = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    BlendWeightVolume::new(bounds, dims, joints, data).map_err(|e| DataError::invalid(path, e))
}

/// `<cache>/v2/<hash>`.
pub fn entry_dir(cache: &Path, hash: &str) -> PathBuf {
    cache.join(CACHE_VERSION).join(hash)
}

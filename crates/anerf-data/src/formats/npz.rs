//! `.npz` archives (`np.savez` / `np.savez_compressed`): a zip of `.npy` members.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use super::ndarray::{element_count, DType, Descr, NdArray};
use super::npy;
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
    /// Bytes one read may materialise: the lesser of [`MEMBER_BUDGET`] and `expansion`.
    budget: u64,
    /// Bytes any member may inflate to: [`MAX_EXPANSION`] × the archive's size.
    expansion: u64,
}

/// One member as its headers describe it.
#[derive(Debug, Clone)]
struct Member {
    index: usize,
    kind: MemberKind,
    /// The uncompressed size the zip directory declares.
    declared: u64,
    /// Where a numeric member's data starts and how it is laid out.
    data: Option<DataLayout>,
}

/// How a numeric member's data is stored after its `.npy` header.
#[derive(Debug, Clone, Copy)]
struct DataLayout {
    /// Bytes of the `.npy` header before the data.
    offset: u64,
    dtype: DType,
    big_endian: bool,
    fortran: bool,
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
        let archive_len = super::check_regular(path)?.len();
        let invalid = |detail: String| DataError::invalid(path, detail);
        let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
        let mut archive = zip::ZipArchive::new(file)
            .map_err(|e| invalid(format!("not a readable .npz (zip) archive: {e}")))?;
        let expansion = archive_len.max(1).saturating_mul(MAX_EXPANSION);
        let budget = budget.min(expansion);
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
            let (header, offset) =
                npy::peek_header(&head).map_err(|e| invalid(format!("member {name}: {e}")))?;
            let data = match header.descr {
                Descr::Numeric { dtype, big_endian } => Some(DataLayout {
                    offset: offset as u64,
                    dtype,
                    big_endian,
                    fortran: header.fortran,
                }),
                _ => None,
            };
            let kind = match header.descr {
                Descr::Numeric { dtype, .. } => MemberKind::Numeric {
                    bytes: element_count(&header.shape)
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
                    data,
                },
            );
        }
        Ok(Self {
            path: path.to_path_buf(),
            archive,
            members,
            budget,
            expansion,
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
        let (member, bytes, _) = self.numeric(name)?;
        self.within_budget(name, "its header's shape needs", bytes)?;
        self.within_budget(name, "the archive declares", member.declared)?;
        if member.declared < bytes {
            return Err(self.invalid(format!(
                "member {name}: its header's shape needs {bytes} bytes of data but the archive declares \
                 only {} bytes for it (truncated)",
                member.declared
            )));
        }
        let data = self.inflate(&member, name, 0, member.declared)?;
        npy::parse_array(&data).map_err(|e| self.invalid(format!("member {name}: {e}")))
    }

    /// Rows `rows` (along the first axis) of the numeric member `name`. The member is inflated only up to
    /// the last of them, streaming past the rows before, and only the rows wanted are kept: a long motion
    /// cut to a few frames costs the memory of those frames. Those rows must fit the budget; the bytes
    /// streamed past, [`MAX_EXPANSION`] × the archive's size. A Fortran-order member is read whole (within
    /// the budget) and cut.
    pub fn rows(&mut self, name: &str, rows: Range<usize>) -> Result<NdArray, DataError> {
        let (member, bytes, layout) = self.numeric(name)?;
        let shape = match &member.kind {
            MemberKind::Numeric { shape, .. } => shape.clone(),
            MemberKind::Other(_) => unreachable!("numeric() returns numeric members"),
        };
        let Some(&count) = shape.first() else {
            return Err(self.invalid(format!(
                "member {name} is a single value; expected rows to read {}..{} of",
                rows.start, rows.end
            )));
        };
        if rows.start > rows.end || rows.end > count {
            return Err(self.invalid(format!(
                "member {name} has {count} rows; rows {}..{} were asked for",
                rows.start, rows.end
            )));
        }
        let row_bytes = if count == 0 { 0 } else { bytes / count as u64 };
        let wanted = (rows.len() as u64).saturating_mul(row_bytes);
        self.within_budget(name, "the rows asked for need", wanted)?;
        let mut cut_shape = shape.clone();
        cut_shape[0] = rows.len();
        if layout.fortran {
            let le = self.array(name)?.le_bytes();
            let at = |row: usize| (row as u64 * row_bytes) as usize;
            return NdArray::from_bytes(
                layout.dtype,
                false,
                cut_shape,
                false,
                &le[at(rows.start)..at(rows.end)],
            )
            .map_err(|e| self.invalid(format!("member {name}: {e}")));
        }
        let skip = layout.offset + rows.start as u64 * row_bytes;
        let end = skip + wanted;
        if end > member.declared {
            return Err(self.invalid(format!(
                "member {name}: rows {}..{} end at byte {end} but the archive declares only {} bytes for                  it (truncated)",
                rows.start, rows.end, member.declared
            )));
        }
        if end > self.expansion {
            return Err(self.invalid(format!(
                "member {name}: rows {}..{} end at byte {end}, past {MAX_EXPANSION}× the archive's size                  ({} bytes), which no real compressed data reaches",
                rows.start, rows.end, self.expansion
            )));
        }
        let data = self.inflate(&member, name, skip, wanted)?;
        NdArray::from_bytes(layout.dtype, layout.big_endian, cut_shape, false, &data)
            .map_err(|e| self.invalid(format!("member {name}: {e}")))
    }

    /// Inflates `member`'s bytes `skip..skip + take`, streaming past the first `skip` (at most `take`
    /// bytes come back when the member is shorter than declared).
    fn inflate(
        &mut self,
        member: &Member,
        name: &str,
        skip: u64,
        take: u64,
    ) -> Result<Vec<u8>, DataError> {
        let path = &self.path;
        let invalid =
            |e: &dyn std::fmt::Display| DataError::invalid(path, format!("member {name}: {e}"));
        let mut reader = self
            .archive
            .by_index(member.index)
            .map_err(|e| invalid(&e))?;
        std::io::copy(&mut (&mut reader).take(skip), &mut std::io::sink())
            .map_err(|e| invalid(&e))?;
        let mut data = Vec::with_capacity(take as usize);
        reader
            .take(take)
            .read_to_end(&mut data)
            .map_err(|e| invalid(&e))?;
        Ok(data)
    }

    /// The numeric member `name`, the bytes its header's shape needs and its data layout; an error naming
    /// what it holds otherwise.
    fn numeric(&self, name: &str) -> Result<(Member, u64, DataLayout), DataError> {
        let member = self.members.get(name).cloned().ok_or_else(|| {
            self.invalid(format!(
                "has no member {name} (it has {})",
                self.names().join(", ")
            ))
        })?;
        match (&member.kind, member.data) {
            (&MemberKind::Numeric { bytes, .. }, Some(layout)) => Ok((member, bytes, layout)),
            (MemberKind::Other(kind), _) => Err(self.invalid(format!(
                "member {name} holds {kind}; expected a numeric array (object arrays are never unpickled)"
            ))),
            (MemberKind::Numeric { .. }, None) => unreachable!("numeric members have a data layout"),
        }
    }

    /// Refuses reading `size` bytes of member `name` past the budget; `what` says whose size it is.
    fn within_budget(&self, name: &str, what: &str, size: u64) -> Result<(), DataError> {
        if size > self.budget {
            return Err(self.invalid(format!(
                "member {name}: {what} {size} bytes; at most {} may be read (the lesser of {} and \
                 {MAX_EXPANSION}× the archive's size)",
                self.budget, MEMBER_BUDGET
            )));
        }
        Ok(())
    }

    fn invalid(&self, detail: String) -> DataError {
        DataError::invalid(&self.path, detail)
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

    /// A `.npy` member of float64 `values` in `shape`, its header declaring `fortran` order.
    fn npy_member(shape: &[usize], fortran: bool, values: &[f64]) -> Vec<u8> {
        let mut out = anerf_testing::npy_f64_header(shape, fortran);
        out.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        out
    }

    /// Rows read alone equal the same rows of the whole array, for C- and Fortran-order members, deflated
    /// or stored; rows outside the array and rows a truncated member lacks are refused by name.
    #[test]
    fn rows_are_the_whole_arrays_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rows.npz");
        // A 7 × 3 array: element (r, c) = 10 r + c. C order lists rows; Fortran order lists columns.
        let c_order: Vec<f64> = (0..7)
            .flat_map(|r| (0..3).map(move |c| (10 * r + c) as f64))
            .collect();
        let f_order: Vec<f64> = (0..3)
            .flat_map(|c| (0..7).map(move |r| (10 * r + c) as f64))
            .collect();
        let mut truncated = npy_member(&[7, 3], false, &c_order);
        truncated.truncate(truncated.len() - 3 * 8 * 2);
        let mut zip = zip::ZipWriter::new(std::fs::File::create(&path).unwrap());
        for (name, method, bytes) in [
            (
                "c",
                zip::CompressionMethod::Deflated,
                npy_member(&[7, 3], false, &c_order),
            ),
            (
                "stored",
                zip::CompressionMethod::Stored,
                npy_member(&[7, 3], false, &c_order),
            ),
            (
                "f",
                zip::CompressionMethod::Deflated,
                npy_member(&[7, 3], true, &f_order),
            ),
            ("short", zip::CompressionMethod::Stored, truncated),
        ] {
            let options = zip::write::FileOptions::default().compression_method(method);
            zip.start_file(format!("{name}.npy"), options).unwrap();
            zip.write_all(&bytes).unwrap();
        }
        zip.finish().unwrap();

        let mut npz = Npz::open(&path).unwrap();
        let whole = npz.array("c").unwrap();
        assert_eq!(whole.to_f64(), c_order);
        assert_eq!(
            npz.array("f").unwrap(),
            whole,
            "Fortran order is read as C order"
        );
        for rows in [0..7, 2..5, 6..7, 3..3] {
            let want = NdArray::new(
                vec![rows.len(), 3],
                ArrayData::F64(c_order[rows.start * 3..rows.end * 3].to_vec()),
            )
            .unwrap();
            for name in ["c", "stored", "f"] {
                assert_eq!(
                    npz.rows(name, rows.clone()).unwrap(),
                    want,
                    "{name} {rows:?}"
                );
            }
        }
        assert_eq!(npz.rows("short", 0..5).unwrap().shape(), [5, 3]);
        let err = npz.rows("short", 4..6).unwrap_err().to_string();
        assert!(
            err.contains("rows.npz") && err.contains("truncated"),
            "{err}"
        );
        let err = npz.rows("c", 5..8).unwrap_err().to_string();
        assert!(err.contains("member c has 7 rows; rows 5..8"), "{err}");
    }
}
